"""Fused RATTLE step: one thread block per column, several steps per launch.

The one-kernel-per-stage path (:mod:`warp_tensegrity.kernels`) runs the constraint solves one
thread per column over arrays of the whole batch, so every Newton sweep streams the band from
DRAM and the step is latency-bound (``benchmarks/results/ncu_*``). Here a block owns a column:

* its lanes take nodes (kick, drift, force gather, impulses) and members (residuals, Gram rows)
  in turn, ``for n in range(lane, n_nodes, block_dim)``;
* lane 0 alone runs the sequential banded Cholesky factor and the two triangular sweeps;
* the column's working set (state, band, multipliers) sits in per-column scratch rows
  ``s*[w, item]``, contiguous per column so it stays in L1/L2 across the projection iterations
  and the ``n_sub`` steps of a launch; the canonical ``(n, B)`` state is read once and written
  once per launch.

Barriers are Warp's tile barrier (``__syncthreads()`` on CUDA). On the CPU a block has one
thread (Warp's CPU tile semantics), which then runs every loop itself, so the same kernel is
exact there too; with ``wp.config.enable_cpu_blocks`` the CPU emulates the lanes (tests).
The band stores the inverse of the Cholesky diagonal, so lane 0 multiplies instead of dividing.
"""

import functools
from types import SimpleNamespace

import warp as wp

from .kernels import STATUS_CONSTRAINT, STATUS_NONFINITE, STATUS_OK

# __syncthreads() on CUDA; on the CPU a no-op unless wp.config.enable_cpu_blocks emulates lanes
_SYNC = "WP_TILE_SYNC();"


@wp.func_native(_SYNC)
def block_sync(): ...


SHARED_BUCKET = 512  # shared-memory capacities are rounded up to a multiple of this many reals
SHARED_BYTES_MAX = 40 * 1024  # static shared memory a block may take for the solver rows


def shared_capacity(n_constraints: int, bandwidth: int, real_bytes: int) -> int:
    """Reals of block shared memory for the band and multipliers of one column, or 0 when they
    do not fit (the rows then live in global scratch)."""
    need = n_constraints * (bandwidth + 2)
    cap = -(-max(need, 1) // SHARED_BUCKET) * SHARED_BUCKET
    return cap if cap * real_bytes <= SHARED_BYTES_MAX else 0


@functools.cache
def make_fused_kernels(real, shared_cap: int = 0, bandwidth: int = 3):
    """Fused kernels for scalar type ``real`` (wp.float32 or wp.float64). With ``shared_cap`` > 0
    the column's band and multipliers (n_constraints*(bandwidth+2) reals) live in that many reals
    of block shared memory, where lane 0's dependent Cholesky chain reads back what it just wrote
    in ~30 cycles instead of a round trip to L2; else in the global rows ``sx``. The Gram-matrix
    half-bandwidth is compiled in, so lane 0's loops unroll and rows sit in registers."""
    vec = wp.types.vector(3, real)
    BW = int(bandwidth)
    LD = BW + 1
    rowvec = wp.types.vector(LD, real)
    winvec = wp.types.vector(max(BW, 1), real)
    ctype = "double" if real == wp.float64 else "float"
    cap = int(shared_cap)

    # one static buffer per block: __shared__ on CUDA; on the CPU a static array (blocks run one
    # after another there, and emulated lanes of one block share it like shared memory)
    snippet = f"""
#if defined(__CUDA_ARCH__)
    __shared__ {ctype} buf[{max(cap, 1)}];
#else
    static {ctype} buf[{max(cap, 1)}];
#endif
    if (store != 0) buf[i] = value;
    return buf[i];
"""

    @wp.func_native(snippet)
    def shared_rw(i: int, value: real, store: int) -> real: ...

    @wp.func
    def sget(sx: wp.array2d(dtype=real), w: int, i: int):
        if wp.static(cap > 0):
            return shared_rw(i, real(0.0), 0)
        else:
            return sx[w, i]

    @wp.func
    def sset(sx: wp.array2d(dtype=real), w: int, i: int, value: real):
        if wp.static(cap > 0):
            shared_rw(i, value, 1)
        else:
            sx[w, i] = value

    @wp.func
    def pget(p: wp.array2d(dtype=real), k: int, w: int):
        return p[k, w % p.shape[1]]

    @wp.func
    def bar(dref: wp.array(dtype=vec), ni: wp.array(dtype=int), nj: wp.array(dtype=int),
            su: wp.array2d(dtype=vec), k: int, w: int):
        return dref[k] + su[w, nj[k]] - su[w, ni[k]]

    @wp.func
    def block_max(red: wp.array2d(dtype=real), x: real, w: int, lane: int, bd: int):
        """Max of x over the block's lanes (NaN wins), the same on every lane."""
        red[w, lane] = x
        block_sync()
        m = red[w, 0]
        for t in range(1, bd):
            y = red[w, t]
            if wp.isnan(y) or y > m:
                m = y
        block_sync()
        return m

    @wp.func
    def band_factor(sx: wp.array2d(dtype=real), nc: int, w: int):
        """In-place banded Cholesky of row-banded A (row k: A[k, k-d] at k*(BW+1)+d, zero for
        k-d < 0); the diagonal slot keeps 1/L_kk. Row k is worked in registers. Returns 0 if a
        pivot is not positive."""
        ok = int(1)
        for k in range(nc):
            r = rowvec()
            for e in range(LD):
                r[e] = sget(sx, w, k * LD + e)
            for dd in range(BW):
                d = BW - dd
                l = k - d
                if l >= 0:
                    s = r[d]
                    for e in range(1, LD):
                        if e > d:
                            s -= r[e] * sget(sx, w, l * LD + e - d)
                    r[d] = s * sget(sx, w, l * LD)
            s = r[0]
            for e in range(1, LD):
                s -= r[e] * r[e]
            if s > real(0.0):
                r[0] = real(1.0) / wp.sqrt(s)
            else:
                r[0] = real(1.0)
                ok = 0
            for e in range(LD):
                sset(sx, w, k * LD + e, r[e])
        return ok

    @wp.func
    def band_solve(sx: wp.array2d(dtype=real), nc: int, w: int):
        """Solve L L^T x = rhs in place; rhs and x are the multiplier rows at nc*(BW+1). The last
        BW unknowns ride in a register window."""
        lo = nc * LD
        xw = winvec()  # xw[e] = x[k - 1 - e] (forward), x[k + 1 + e] (backward)
        for k in range(nc):
            s = sget(sx, w, lo + k)
            for e in range(BW):
                s -= sget(sx, w, k * LD + e + 1) * xw[e]  # zero band entries before row 0
            xk = s * sget(sx, w, k * LD)
            sset(sx, w, lo + k, xk)
            for e in range(BW - 1):
                xw[BW - 1 - e] = xw[BW - 2 - e]
            xw[0] = xk
        xw = winvec()
        for kk in range(nc):
            k = nc - 1 - kk
            s = sget(sx, w, lo + k)
            for e in range(BW):
                if k + e + 1 < nc:
                    s -= sget(sx, w, (k + e + 1) * LD + e + 1) * xw[e]
            xk = s * sget(sx, w, k * LD)
            sset(sx, w, lo + k, xk)
            for e in range(BW - 1):
                xw[BW - 1 - e] = xw[BW - 2 - e]
            xw[0] = xk

    @wp.func
    def apply_impulse(
        con_i: wp.array(dtype=int), con_j: wp.array(dtype=int), con_dref: wp.array(dtype=vec),
        ncon_start: wp.array(dtype=int), ncon_member: wp.array(dtype=int),
        partner: wp.array(dtype=int), minv_self: wp.array2d(dtype=real), minv_cross: wp.array2d(dtype=real),
        sg: wp.array2d(dtype=vec), sx: wp.array2d(dtype=real), lo: int, simp: wp.array2d(dtype=vec),
        su: wp.array2d(dtype=vec), scale_u: real, sv: wp.array2d(dtype=vec), scale_v: real,
        w: int, lane: int, bd: int,
    ):
        """d = M^-1 G(sg)^T lam (lam at sx[lo:]); su -= scale_u d; sv -= scale_v d. Each node gathers
        its own bars."""
        nn = su.shape[1]
        for n in range(lane, nn, bd):
            g = vec()
            for t in range(ncon_start[n], ncon_start[n + 1]):
                k = ncon_member[t]
                gk = bar(con_dref, con_i, con_j, sg, k, w) * sget(sx, w, lo + k)
                if con_j[k] == n:
                    g += gk
                else:
                    g -= gk
            simp[w, n] = g
        block_sync()
        for n in range(lane, nn, bd):
            dn = simp[w, n] * pget(minv_self, n, w)
            p = partner[n]
            if p >= 0:
                dn = dn + simp[w, p] * pget(minv_cross, n, w)
            if scale_u != real(0.0):
                su[w, n] = su[w, n] - dn * scale_u
            sv[w, n] = sv[w, n] - dn * scale_v
        block_sync()

    @wp.func
    def cable_force(b: vec, EA: real, EAc: real, L: real):
        s = wp.length(b)
        stretch = s - L
        k = EA
        if stretch < real(0.0):
            k = EAc
        return b * (k / L * stretch / s)

    @wp.func
    def node_force(
        cab_i: wp.array(dtype=int), cab_j: wp.array(dtype=int), cab_dref: wp.array(dtype=vec),
        cab_EA: wp.array2d(dtype=real), cab_EAc: wp.array2d(dtype=real), cab_L: wp.array2d(dtype=real),
        node_start: wp.array(dtype=int), node_member: wp.array(dtype=int),
        su: wp.array2d(dtype=vec), n: int, w: int,
    ):
        f = vec()
        for t in range(node_start[n], node_start[n + 1]):
            c = node_member[t]
            fc = cable_force(bar(cab_dref, cab_i, cab_j, su, c, w), pget(cab_EA, c, w), pget(cab_EAc, c, w),
                             pget(cab_L, c, w))
            if cab_i[c] == n:
                f += fc
            else:
                f -= fc
        return f

    @wp.func
    def gather_kick(
        cab_i: wp.array(dtype=int), cab_j: wp.array(dtype=int), cab_dref: wp.array(dtype=vec),
        cab_EA: wp.array2d(dtype=real), cab_EAc: wp.array2d(dtype=real), cab_L: wp.array2d(dtype=real),
        node_start: wp.array(dtype=int), node_member: wp.array(dtype=int),
        partner: wp.array(dtype=int), minv_self: wp.array2d(dtype=real), minv_cross: wp.array2d(dtype=real),
        su: wp.array2d(dtype=vec), sv: wp.array2d(dtype=vec), sa: wp.array2d(dtype=vec), kick: real,
        w: int, lane: int, bd: int,
    ):
        """sa = M^-1 f(su); sv += kick * sa."""
        for n in range(lane, su.shape[1], bd):
            f = node_force(cab_i, cab_j, cab_dref, cab_EA, cab_EAc, cab_L, node_start, node_member, su, n, w)
            acc = f * pget(minv_self, n, w)
            p = partner[n]
            if p >= 0:
                fp = node_force(cab_i, cab_j, cab_dref, cab_EA, cab_EAc, cab_L, node_start, node_member, su, p, w)
                acc = acc + fp * pget(minv_cross, n, w)
            sa[w, n] = acc
            sv[w, n] = sv[w, n] + acc * kick
        block_sync()

    @wp.func
    def factor_gram(
        con_i: wp.array(dtype=int), con_j: wp.array(dtype=int), con_dref: wp.array(dtype=vec),
        con_active: wp.array2d(dtype=real), cpl_start: wp.array(dtype=int), cpl_l: wp.array(dtype=int),
        cpl_a: wp.array(dtype=int), cpl_cross: wp.array(dtype=int), cpl_sign: wp.array(dtype=real),
        minv_self: wp.array2d(dtype=real), minv_cross: wp.array2d(dtype=real), bw: int,
        su: wp.array2d(dtype=vec), sx: wp.array2d(dtype=real), red: wp.array2d(dtype=real),
        w: int, lane: int, bd: int,
    ):
        """Rows of A = G M^-1 G^T at su in parallel, then lane 0 factors. Returns 1 if positive definite."""
        nc = con_i.shape[0]
        ld = bw + 1
        for k in range(lane, nc, bd):
            for d in range(ld):
                sset(sx, w, k * ld + d, real(0.0))
            if pget(con_active, k, w) > real(0.0):
                bk = bar(con_dref, con_i, con_j, su, k, w)
                for t in range(cpl_start[k], cpl_start[k + 1]):
                    l = cpl_l[t]
                    if pget(con_active, l, w) > real(0.0):
                        na = cpl_a[t]
                        m = pget(minv_self, na, w)
                        if cpl_cross[t] != 0:
                            m = pget(minv_cross, na, w)
                        i = k * ld + k - l
                        sset(sx, w, i, sget(sx, w, i) + cpl_sign[t] * m * wp.dot(
                            bk, bar(con_dref, con_i, con_j, su, l, w)))
            else:
                sset(sx, w, k * ld, real(1.0))
        block_sync()
        ok = real(0.0)
        if lane == 0:
            ok = real(band_factor(sx, nc, w))
        return block_max(red, ok, w, lane, bd) > real(0.5)

    @wp.func
    def project_velocities(
        con_i: wp.array(dtype=int), con_j: wp.array(dtype=int), con_dref: wp.array(dtype=vec),
        con_active: wp.array2d(dtype=real), ncon_start: wp.array(dtype=int), ncon_member: wp.array(dtype=int),
        partner: wp.array(dtype=int), minv_self: wp.array2d(dtype=real), minv_cross: wp.array2d(dtype=real),
        bw: int, su: wp.array2d(dtype=vec), sv: wp.array2d(dtype=vec), sx: wp.array2d(dtype=real),
        simp: wp.array2d(dtype=vec), red: wp.array2d(dtype=real),
        w: int, lane: int, bd: int,
    ):
        """sv -= M^-1 G^T lam with A lam = G sv (band holds the factor of A(su)). Returns 1 if sv is finite."""
        nc = con_i.shape[0]
        lo = nc * (bw + 1)
        for k in range(lane, nc, bd):
            r = real(0.0)
            if pget(con_active, k, w) > real(0.0):
                r = wp.dot(bar(con_dref, con_i, con_j, su, k, w), sv[w, con_j[k]] - sv[w, con_i[k]])
            sset(sx, w, lo + k, r)
        block_sync()
        if lane == 0:
            band_solve(sx, nc, w)
        block_sync()
        apply_impulse(con_i, con_j, con_dref, ncon_start, ncon_member, partner, minv_self, minv_cross,
                      su, sx, lo, simp, su, real(0.0), sv, real(1.0), w, lane, bd)
        bad = real(0.0)
        for n in range(lane, su.shape[1], bd):
            vn = sv[w, n]
            if not (wp.isfinite(vn[0]) and wp.isfinite(vn[1]) and wp.isfinite(vn[2])):
                bad = real(1.0)
        return block_max(red, bad, w, lane, bd) < real(0.5)

    @wp.func
    def fail(status: wp.array(dtype=int), fail_step: wp.array(dtype=int), at_step: int, w: int, code: int,
             lane: int):
        if lane == 0 and status[w] == STATUS_OK:
            status[w] = code
            fail_step[w] = at_step

    @wp.kernel(enable_backward=False, module="unique")
    def rattle_columns(
        # Model:
        con_i: wp.array(dtype=int), con_j: wp.array(dtype=int), con_dref: wp.array(dtype=vec),
        con_L: wp.array(dtype=real), con_active: wp.array2d(dtype=real),
        cpl_start: wp.array(dtype=int), cpl_l: wp.array(dtype=int), cpl_a: wp.array(dtype=int),
        cpl_cross: wp.array(dtype=int), cpl_sign: wp.array(dtype=real),
        ncon_start: wp.array(dtype=int), ncon_member: wp.array(dtype=int),
        cab_i: wp.array(dtype=int), cab_j: wp.array(dtype=int), cab_dref: wp.array(dtype=vec),
        cab_EA: wp.array2d(dtype=real), cab_EAc: wp.array2d(dtype=real), cab_L: wp.array2d(dtype=real),
        node_start: wp.array(dtype=int), node_member: wp.array(dtype=int),
        partner: wp.array(dtype=int), minv_self: wp.array2d(dtype=real), minv_cross: wp.array2d(dtype=real),
        bw: int, tol: real, max_iter: int, fail_tol: real,
        h: real, n_sub: int, init: int, step: wp.array(dtype=int),
        # Data in/out:
        u: wp.array2d(dtype=vec), v: wp.array2d(dtype=vec), a: wp.array2d(dtype=vec),
        bar_err: wp.array(dtype=real), iters: wp.array(dtype=int),
        status: wp.array(dtype=int), fail_step: wp.array(dtype=int),
        # Scratch (B, items), one row per column:
        su: wp.array2d(dtype=vec), sv: wp.array2d(dtype=vec), sa: wp.array2d(dtype=vec),
        sup: wp.array2d(dtype=vec), simp: wp.array2d(dtype=vec), sx: wp.array2d(dtype=real),
        red: wp.array2d(dtype=real),
    ):
        """n_sub RATTLE steps of size h for column w (init = 1: make v admissible and compute a(u)
        instead). Each launch first factors A(u), which the first position projection uses."""
        w, lane = wp.tid()
        if status[w] != STATUS_OK:
            return
        bd = wp.block_dim()
        nn = u.shape[0]
        nc = con_i.shape[0]
        lo = nc * (bw + 1)
        half = real(0.5) * h
        for n in range(lane, nn, bd):
            su[w, n] = u[n, w]
            sv[w, n] = v[n, w]
            sa[w, n] = a[n, w]
        block_sync()
        s0 = step[0]
        steps = n_sub
        if init != 0:
            if nc > 0:
                if not factor_gram(con_i, con_j, con_dref, con_active, cpl_start, cpl_l, cpl_a, cpl_cross,
                                   cpl_sign, minv_self, minv_cross, bw, su, sx, red, w, lane, bd):
                    fail(status, fail_step, s0 + 1, w, STATUS_CONSTRAINT, lane)
                    return
                project_velocities(con_i, con_j, con_dref, con_active, ncon_start, ncon_member, partner,
                                   minv_self, minv_cross, bw, su, sv, sx, simp, red, w, lane, bd)
            gather_kick(cab_i, cab_j, cab_dref, cab_EA, cab_EAc, cab_L, node_start, node_member, partner,
                        minv_self, minv_cross, su, sv, sa, real(0.0), w, lane, bd)
            steps = 0
        elif nc > 0 and steps > 0:
            # the factor of A(u) from the previous launch's velocity projection: shared memory does
            # not outlive a launch, so factor again (the same numbers: u is unchanged)
            if not factor_gram(con_i, con_j, con_dref, con_active, cpl_start, cpl_l, cpl_a, cpl_cross,
                               cpl_sign, minv_self, minv_cross, bw, su, sx, red, w, lane, bd):
                fail(status, fail_step, s0 + 1, w, STATUS_CONSTRAINT, lane)
                steps = 0
        worst = real(0.0)
        most = int(0)
        for sub in range(steps):
            # kick and drift
            for n in range(lane, nn, bd):
                vn = sv[w, n] + sa[w, n] * half
                sv[w, n] = vn
                un = su[w, n]
                sup[w, n] = un
                su[w, n] = un + vn * h
            block_sync()
            # simplified Newton onto |b_k| = L_k along M^-1 G(u_prev)^T (band: factor of A(u_prev))
            err = real(0.0)
            prev = real(0.0)
            it = int(0)
            while nc > 0:
                prev = err
                e_lane = real(0.0)
                for k in range(lane, nc, bd):
                    r = real(0.0)
                    if pget(con_active, k, w) > real(0.0):
                        b = bar(con_dref, con_i, con_j, su, k, w)
                        L = con_L[k]
                        bb = wp.dot(b, b)
                        r = real(0.5) * (bb - L * L)
                        e = wp.abs(wp.sqrt(bb) - L) / L
                        if wp.isnan(e) or e > e_lane:
                            e_lane = e
                    sset(sx, w, lo + k, r)
                err = block_max(red, e_lane, w, lane, bd)
                if err <= tol or it >= max_iter:
                    break
                if it > 0 and err > real(0.5) * prev and err < real(10.0) * tol:
                    break  # stalled at round-off just above tol
                if lane == 0:
                    band_solve(sx, nc, w)
                block_sync()
                apply_impulse(con_i, con_j, con_dref, ncon_start, ncon_member, partner, minv_self, minv_cross,
                              sup, sx, lo, simp, su, real(1.0), sv, real(1.0) / h, w, lane, bd)
                it += 1
            most = wp.max(most, it)
            if err > worst:
                worst = err
            if not wp.isfinite(err):
                fail(status, fail_step, s0 + sub + 1, w, STATUS_NONFINITE, lane)
                break
            if err > fail_tol:
                fail(status, fail_step, s0 + sub + 1, w, STATUS_CONSTRAINT, lane)
                break
            # force, second half kick, velocity projection at the new positions
            gather_kick(cab_i, cab_j, cab_dref, cab_EA, cab_EAc, cab_L, node_start, node_member, partner,
                        minv_self, minv_cross, su, sv, sa, half, w, lane, bd)
            if nc > 0:
                if not factor_gram(con_i, con_j, con_dref, con_active, cpl_start, cpl_l, cpl_a, cpl_cross,
                                   cpl_sign, minv_self, minv_cross, bw, su, sx, red, w, lane, bd):
                    fail(status, fail_step, s0 + sub + 1, w, STATUS_CONSTRAINT, lane)
                    break
                if not project_velocities(con_i, con_j, con_dref, con_active, ncon_start, ncon_member, partner,
                                          minv_self, minv_cross, bw, su, sv, sx, simp, red, w, lane, bd):
                    fail(status, fail_step, s0 + sub + 1, w, STATUS_NONFINITE, lane)
                    break
        if lane == 0:
            iters[w] = wp.max(iters[w], most)
            if worst > bar_err[w]:
                bar_err[w] = worst
        for n in range(lane, nn, bd):
            u[n, w] = su[w, n]
            v[n, w] = sv[w, n]
            a[n, w] = sa[w, n]

    @wp.kernel(enable_backward=False, module="unique")
    def advance_counter_by(step: wp.array(dtype=int), n: int):
        step[0] = step[0] + n

    return SimpleNamespace(real=real, vec=vec, rattle_columns=rattle_columns, advance_counter_by=advance_counter_by)
