"""Fused RATTLE step: one thread block per column, several steps per launch.

The one-kernel-per-stage path (:mod:`warp_tensegrity.kernels`) runs the constraint solves one
thread per column over arrays of the whole batch, so every Newton sweep streams the band from
DRAM and the step is latency-bound (``benchmarks/results/ncu_*``). Here a block owns a column:

* its lanes take nodes (kick, drift, force gather, impulses) and members (residuals, Gram rows)
  in turn, ``for n in range(lane, n_nodes, block_dim)``;
* lane 0 alone runs the sequential banded Cholesky factor and the two triangular sweeps, with
  the band and multipliers in block shared memory when they fit (else in the global rows
  ``sx[w, :]``) and the current row in registers;
* the node state sits in per-column scratch rows ``sq[w, :]``, contiguous per column so it stays
  in L1/L2 across the projection iterations and the ``n_sub`` steps of a launch; the canonical
  ``(n, B)`` state is read once and written once per launch.

Barriers are Warp's tile barrier (``__syncthreads()`` on CUDA). On the CPU a block has one
thread (Warp's CPU tile semantics), which then runs every loop itself, so the same kernel is
exact there too; with ``wp.config.enable_cpu_blocks`` the CPU emulates the lanes (tests).
The band stores the inverse of the Cholesky diagonal, so lane 0 multiplies instead of dividing.
"""

import functools
from types import SimpleNamespace

import warp as wp

from .kernels import STATUS_CONSTRAINT, STATUS_NONFINITE, STATUS_OK, make_kernels

# __syncthreads() on CUDA; on the CPU a no-op unless wp.config.enable_cpu_blocks emulates lanes
_SYNC = "WP_TILE_SYNC();"


@wp.func_native(_SYNC)
def block_sync(): ...


NQ = 5  # node state slots per node: U, V, A, P, I (see make_fused_kernels)
U, V, A, P, I = (wp.constant(i) for i in range(NQ))
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
    half-bandwidth is compiled in, so lane 0's loops unroll and rows sit in registers. (Node rows
    in shared memory too were measured and gained nothing: benchmarks/results/fused_tuning_h200.json.)"""
    vec = wp.types.vector(3, real)
    staged = make_kernels(real)
    pget, cable_force = staged.pget, staged.cable_force  # the same per-column read and cable law
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

    # node state rows: entry n*NQ + slot, slots U (displacement), V (velocity), A (acceleration),
    # P (displacement at the step start), I (G^T lambda)
    @wp.func
    def qget(sq: wp.array2d(dtype=vec), w: int, n: int, slot: int):
        return sq[w, n * NQ + slot]

    @wp.func
    def qset(sq: wp.array2d(dtype=vec), w: int, n: int, slot: int, value: vec):
        sq[w, n * NQ + slot] = value

    @wp.func
    def bar(dref: wp.array(dtype=vec), ni: wp.array(dtype=int), nj: wp.array(dtype=int),
            sq: wp.array2d(dtype=vec), slot: int, k: int, w: int):
        """Member k's vector at the displacement in ``slot`` (U or P)."""
        return dref[k] + qget(sq, w, nj[k], slot) - qget(sq, w, ni[k], slot)

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
        sq: wp.array2d(dtype=vec), g_slot: int, sx: wp.array2d(dtype=real), lo: int,
        scale_u: real, scale_v: real, nn: int, w: int, lane: int, bd: int,
    ):
        """d = M^-1 G(u in g_slot)^T lam (lam at sx[lo:]); U -= scale_u d; V -= scale_v d. Each node
        gathers its own bars."""
        for n in range(lane, nn, bd):
            g = vec()
            for t in range(ncon_start[n], ncon_start[n + 1]):
                k = ncon_member[t]
                gk = bar(con_dref, con_i, con_j, sq, g_slot, k, w) * sget(sx, w, lo + k)
                if con_j[k] == n:
                    g += gk
                else:
                    g -= gk
            qset(sq, w, n, I, g)
        block_sync()
        for n in range(lane, nn, bd):
            dn = qget(sq, w, n, I) * pget(minv_self, n, w)
            p = partner[n]
            if p >= 0:
                dn = dn + qget(sq, w, p, I) * pget(minv_cross, n, w)
            if scale_u != real(0.0):
                qset(sq, w, n, U, qget(sq, w, n, U) - dn * scale_u)
            qset(sq, w, n, V, qget(sq, w, n, V) - dn * scale_v)
        block_sync()

    @wp.func
    def node_force(
        cab_i: wp.array(dtype=int), cab_j: wp.array(dtype=int), cab_dref: wp.array(dtype=vec),
        cab_EA: wp.array2d(dtype=real), cab_EAc: wp.array2d(dtype=real), cab_L: wp.array2d(dtype=real),
        node_start: wp.array(dtype=int), node_member: wp.array(dtype=int),
        sq: wp.array2d(dtype=vec), n: int, w: int,
    ):
        f = vec()
        for t in range(node_start[n], node_start[n + 1]):
            c = node_member[t]
            fc = cable_force(bar(cab_dref, cab_i, cab_j, sq, U, c, w), pget(cab_EA, c, w), pget(cab_EAc, c, w),
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
        sq: wp.array2d(dtype=vec), kick: real, nn: int, w: int, lane: int, bd: int,
    ):
        """A = M^-1 f(U); V += kick * A."""
        for n in range(lane, nn, bd):
            f = node_force(cab_i, cab_j, cab_dref, cab_EA, cab_EAc, cab_L, node_start, node_member, sq, n, w)
            acc = f * pget(minv_self, n, w)
            p = partner[n]
            if p >= 0:
                fp = node_force(cab_i, cab_j, cab_dref, cab_EA, cab_EAc, cab_L, node_start, node_member, sq, p, w)
                acc = acc + fp * pget(minv_cross, n, w)
            qset(sq, w, n, A, acc)
            qset(sq, w, n, V, qget(sq, w, n, V) + acc * kick)
        block_sync()

    @wp.func
    def factor_gram(
        con_i: wp.array(dtype=int), con_j: wp.array(dtype=int), con_dref: wp.array(dtype=vec),
        con_active: wp.array2d(dtype=real), cpl_start: wp.array(dtype=int), cpl_l: wp.array(dtype=int),
        cpl_a: wp.array(dtype=int), cpl_cross: wp.array(dtype=int), cpl_sign: wp.array(dtype=real),
        minv_self: wp.array2d(dtype=real), minv_cross: wp.array2d(dtype=real),
        sq: wp.array2d(dtype=vec), sx: wp.array2d(dtype=real), red: wp.array2d(dtype=real),
        w: int, lane: int, bd: int,
    ):
        """Rows of A = G M^-1 G^T at U in parallel, then lane 0 factors. Returns 1 if positive definite."""
        nc = con_i.shape[0]
        for k in range(lane, nc, bd):
            for d in range(LD):
                sset(sx, w, k * LD + d, real(0.0))
            if pget(con_active, k, w) > real(0.0):
                bk = bar(con_dref, con_i, con_j, sq, U, k, w)
                for t in range(cpl_start[k], cpl_start[k + 1]):
                    l = cpl_l[t]
                    if pget(con_active, l, w) > real(0.0):
                        na = cpl_a[t]
                        m = pget(minv_self, na, w)
                        if cpl_cross[t] != 0:
                            m = pget(minv_cross, na, w)
                        i = k * LD + k - l
                        sset(sx, w, i, sget(sx, w, i) + cpl_sign[t] * m * wp.dot(
                            bk, bar(con_dref, con_i, con_j, sq, U, l, w)))
            else:
                sset(sx, w, k * LD, real(1.0))
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
        sq: wp.array2d(dtype=vec), sx: wp.array2d(dtype=real), red: wp.array2d(dtype=real),
        nn: int, w: int, lane: int, bd: int,
    ):
        """V -= M^-1 G^T lam with A lam = G V (band holds the factor of A(U)). Returns 1 if V is finite."""
        nc = con_i.shape[0]
        lo = nc * LD
        for k in range(lane, nc, bd):
            r = real(0.0)
            if pget(con_active, k, w) > real(0.0):
                r = wp.dot(bar(con_dref, con_i, con_j, sq, U, k, w), qget(sq, w, con_j[k], V) - qget(sq, w, con_i[k], V))
            sset(sx, w, lo + k, r)
        block_sync()
        if lane == 0:
            band_solve(sx, nc, w)
        block_sync()
        apply_impulse(con_i, con_j, con_dref, ncon_start, ncon_member, partner, minv_self, minv_cross,
                      sq, U, sx, lo, real(0.0), real(1.0), nn, w, lane, bd)
        bad = real(0.0)
        for n in range(lane, nn, bd):
            vn = qget(sq, w, n, V)
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
        tol: real, max_iter: int, fail_tol: real,
        h: real, n_sub: int, init: int, step: wp.array(dtype=int),
        # Data in/out:
        u: wp.array2d(dtype=vec), v: wp.array2d(dtype=vec), a: wp.array2d(dtype=vec),
        bar_err: wp.array(dtype=real), iters: wp.array(dtype=int),
        status: wp.array(dtype=int), fail_step: wp.array(dtype=int),
        # Scratch (B, items), one row per column:
        sq: wp.array2d(dtype=vec), sx: wp.array2d(dtype=real), red: wp.array2d(dtype=real),
    ):
        """n_sub RATTLE steps of size h for column w (init = 1: make v admissible and compute a(u)
        instead). Each launch first factors A(u), which the first position projection uses."""
        w, lane = wp.tid()
        if status[w] != STATUS_OK:
            return
        bd = wp.block_dim()
        nn = u.shape[0]
        nc = con_i.shape[0]
        lo = nc * LD
        half = real(0.5) * h
        for n in range(lane, nn, bd):
            qset(sq, w, n, U, u[n, w])
            qset(sq, w, n, V, v[n, w])
            qset(sq, w, n, A, a[n, w])
        block_sync()
        s0 = step[0]
        steps = n_sub
        if init != 0:
            if nc > 0:
                if not factor_gram(con_i, con_j, con_dref, con_active, cpl_start, cpl_l, cpl_a, cpl_cross,
                                   cpl_sign, minv_self, minv_cross, sq, sx, red, w, lane, bd):
                    fail(status, fail_step, s0 + 1, w, STATUS_CONSTRAINT, lane)
                    return
                project_velocities(con_i, con_j, con_dref, con_active, ncon_start, ncon_member, partner,
                                   minv_self, minv_cross, sq, sx, red, nn, w, lane, bd)
            gather_kick(cab_i, cab_j, cab_dref, cab_EA, cab_EAc, cab_L, node_start, node_member, partner,
                        minv_self, minv_cross, sq, real(0.0), nn, w, lane, bd)
            steps = 0
        elif nc > 0 and steps > 0:
            # the factor of A(u) from the previous launch's velocity projection: shared memory does
            # not outlive a launch, so factor again (the same numbers: u is unchanged)
            if not factor_gram(con_i, con_j, con_dref, con_active, cpl_start, cpl_l, cpl_a, cpl_cross,
                               cpl_sign, minv_self, minv_cross, sq, sx, red, w, lane, bd):
                fail(status, fail_step, s0 + 1, w, STATUS_CONSTRAINT, lane)
                steps = 0
        worst = real(0.0)
        most = int(0)
        for sub in range(steps):
            # kick and drift
            for n in range(lane, nn, bd):
                vn = qget(sq, w, n, V) + qget(sq, w, n, A) * half
                qset(sq, w, n, V, vn)
                un = qget(sq, w, n, U)
                qset(sq, w, n, P, un)
                qset(sq, w, n, U, un + vn * h)
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
                        b = bar(con_dref, con_i, con_j, sq, U, k, w)
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
                              sq, P, sx, lo, real(1.0), real(1.0) / h, nn, w, lane, bd)
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
                        minv_self, minv_cross, sq, half, nn, w, lane, bd)
            if nc > 0:
                if not factor_gram(con_i, con_j, con_dref, con_active, cpl_start, cpl_l, cpl_a, cpl_cross,
                                   cpl_sign, minv_self, minv_cross, sq, sx, red, w, lane, bd):
                    fail(status, fail_step, s0 + sub + 1, w, STATUS_CONSTRAINT, lane)
                    break
                if not project_velocities(con_i, con_j, con_dref, con_active, ncon_start, ncon_member, partner,
                                          minv_self, minv_cross, sq, sx, red, nn, w, lane, bd):
                    fail(status, fail_step, s0 + sub + 1, w, STATUS_NONFINITE, lane)
                    break
        if lane == 0:
            iters[w] = wp.max(iters[w], most)
            if worst > bar_err[w]:
                bar_err[w] = worst
        for n in range(lane, nn, bd):
            u[n, w] = qget(sq, w, n, U)
            v[n, w] = qget(sq, w, n, V)
            a[n, w] = qget(sq, w, n, A)

    @wp.kernel(enable_backward=False, module="unique")
    def advance_counter_by(step: wp.array(dtype=int), n: int):
        step[0] = step[0] + n

    return SimpleNamespace(real=real, vec=vec, rattle_columns=rattle_columns, advance_counter_by=advance_counter_by)
