"""Fused RATTLE step: one thread block per column, every lane through the whole step.

A block owns a column for ``n_sub`` steps per launch. Its lanes take nodes (kick, drift, force
gather, impulses), members (residuals, Gram rows) and blocks of the Gram matrix in turn
(``for i in range(lane, n, block_dim)``); barriers are Warp's tile barrier (``__syncthreads()``).

Constraint solve (:mod:`.coop`), a compile-time choice (``solver``): ``"cr"``, block cyclic
reduction of the block-tridiagonal Gram matrix across the lanes, its stored reduction reused by
every Newton iteration and the velocity projection; or ``"serial"``: lanes assemble the Gram rows
into a band, then lane 0 alone factors and solves it with the staged threads' sequential banded
Cholesky (:func:`.common.make_band_funcs`, the same bodies) while the other lanes wait at a
barrier. Which is faster depends on the bandwidth, precision and batch
(``benchmarks/results/throughput_h100_solver.json``; the policy is ``engine.choose_path``). Same
Newton / RATTLE semantics and tolerances as the staged path.

On chip (:class:`FusedStep` owns the rows): the column's CR storage and node rows live in block
shared memory when they fit (:func:`shared_plan`), else in per-column global rows (contiguous, so
they stay in L1/L2); the canonical ``(n, B)`` state is read and written once per launch; the
accelerations, used twice a step, keep a global row per column (``sa[w]``). On the CPU a block
has one lane unless ``wp.config.enable_cpu_blocks`` emulates the lanes (the tests do).
"""

import functools
from typing import NamedTuple

import warp as wp

from ... import types
from ..common import (NQ, STATUS_CONSTRAINT, STATUS_NONFINITE, STATUS_OK, I, P, U, V, array_type, bar_residual, finite3, force_columns,
                     make_band_funcs, make_gram_row, member_vec, newton_stop, node_force, node_impulse, projection_status,
                     set_failure)
from .coop import block_size, block_sync, make_block_max, make_cr_funcs, shared_snippet, solver_reals

SHARED_BYTES_MAX = 46 * 1024  # static shared memory a block may take (48 KiB CUDA limit, some slack)
SHARED_NODES = True  # node rows in shared memory too when they fit after the solver rows
# the serial solver keeps node rows in global rows for bands wider than this: the extra shared memory
# costs resident blocks, which lane 0's latency-bound chain needs (H100, 50-prism RB, 1,024-16,384
# columns: 1.1-1.4x faster, results/throughput_h100_solver_globalnodes.json vs _solver.json)
SERIAL_SHARED_NODES_MAX_BANDWIDTH = 3


def shared_plan(n_nodes: int, n_constraints: int, bandwidth: int, block_dim: int, real_bytes: int,
                budget: int | None = None, solver: str = "cr") -> tuple[int, int]:
    """(solver reals, node vectors) to place in block shared memory: the solver rows first (the
    CR levels read them most), then the node rows, each only if it fits whole; 0 = global rows.
    ``budget``: bytes (None: SHARED_BYTES_MAX)."""
    budget = SHARED_BYTES_MAX if budget is None else budget
    xs = solver_reals(n_constraints, bandwidth, block_dim, solver)
    qs = n_nodes * NQ * 3 * real_bytes
    x_cap = xs if xs * real_bytes <= budget else 0
    nodes = SHARED_NODES and not (solver == "serial" and bandwidth > SERIAL_SHARED_NODES_MAX_BANDWIDTH)
    q_cap = n_nodes * NQ if nodes and x_cap * real_bytes + qs <= budget else 0
    return x_cap, q_cap


class NodeFuncs(NamedTuple):
    """The fused step's per-node bodies and its model struct."""

    ColumnModel: type
    block_max: wp.Function
    gather_kick: wp.Function
    apply_impulse: wp.Function
    vec: type


@functools.cache
def make_node_funcs(real):
    """The model struct (the "fused" group of :data:`warp_tensegrity.types.MODEL_FIELDS`) and the
    node passes of the fused step (lanes over nodes), plus the block reduction (:func:`.coop.make_block_max`)."""
    vec = wp.types.vector(3, real)
    block_max = make_block_max(real)
    ColumnModel = wp.struct(type("ColumnModel", (), {"__module__": __name__, "__annotations__": {
        f.name: array_type(f.dtype, f.ndim, real) for f in types.group_fields("fused")}}))

    @wp.func
    def minv_apply(m: ColumnModel, q: wp.array2d(dtype=vec), n: int, ws: int, wx: int):
        """(M^-1 g)_n for the per-node vectors g in slot I."""
        dn = q[n, I] * m.minv_self[n, ws]
        p = m.partner[n]
        if p >= 0:
            dn = dn + q[p, I] * m.minv_cross[n, wx]
        return dn

    @wp.func
    def gather_kick(m: ColumnModel, q: wp.array2d(dtype=vec), qa: wp.array(dtype=vec), kick: real, w: int, lane: int,
                    bd: int):
        """qa = M^-1 f(U); V += kick qa. Forces go through slot I first, so each is evaluated once."""
        nn = m.partner.shape[0]
        wE, wC, wL, wF, ws, wx = force_columns(m.cab_EA, m.cab_EAc, m.cab_L, m.ext_force, m.minv_self, m.minv_cross, w)
        for n in range(lane, nn, bd):
            q[n, I] = node_force(m.node_start, m.node_member, m.node_other, m.node_dref, m.cab_EA, m.cab_EAc,
                                 m.cab_L, m.ext_force, q, n, U, wE, wC, wL, wF)
        block_sync()
        for n in range(lane, nn, bd):
            acc = minv_apply(m, q, n, ws, wx)
            qa[n] = acc
            q[n, V] = q[n, V] + acc * kick
        block_sync()

    @wp.func
    def apply_impulse(m: ColumnModel, q: wp.array2d(dtype=vec), g_slot: int, x: wp.array2d(dtype=real),
                      scale_u: real, scale_v: real, w: int, lane: int, bd: int):
        """d = M^-1 G(u in g_slot)^T lam (lam = x[0:nc, 0]); U -= scale_u d; V -= scale_v d."""
        nn = m.partner.shape[0]
        ws = w % m.minv_self.shape[1]
        wx = w % m.minv_cross.shape[1]
        for n in range(lane, nn, bd):
            q[n, I] = node_impulse(m.con_i, m.con_j, m.con_dref, m.ncon_start, m.ncon_member, q, g_slot, x, 0, n)
        block_sync()
        for n in range(lane, nn, bd):
            dn = minv_apply(m, q, n, ws, wx)
            if scale_u != real(0.0):
                q[n, U] = q[n, U] - dn * scale_u
            q[n, V] = q[n, V] - dn * scale_v
        block_sync()

    return NodeFuncs(ColumnModel=ColumnModel, block_max=block_max, gather_kick=gather_kick,
                     apply_impulse=apply_impulse, vec=vec)


class FactorFuncs(NamedTuple):
    """The fused step's Gram factor and solve."""

    rows: wp.Function
    solve: wp.Function
    factor_gram: wp.Function


@functools.cache
def make_factor_funcs(real, bandwidth: int, solver: str = "cr"):
    """The fused step's factor and solve over the model struct ``ColumnModel``: Gram assembly with
    the factor (CR: into blocks, all lanes; serial: into the band, lane 0), and the solve with the
    stored factor. ``band``: the serial solver's band (nc, bw+1, 1); unused by CR."""
    serial = solver == "serial"
    vec = wp.types.vector(3, real)
    BW = int(bandwidth)
    S = block_size(BW)
    SS = S * S
    LD = BW + 1
    gram_row, rowvec = make_gram_row(real, BW)
    cr = make_cr_funcs(real, S)
    sb = make_band_funcs(real, BW)
    nf = make_node_funcs(real)
    ColumnModel, block_max = nf.ColumnModel, nf.block_max

    @wp.func
    def rows(nc: int):
        """Multiplier rows a solve works on: nb S (CR pads the last block), nc (serial)."""
        if wp.static(serial):
            return nc
        else:
            return (nc + S - 1) // S * S

    @wp.func
    def solve(x: wp.array2d(dtype=real), band: wp.array3d(dtype=real), nc: int, lane: int, bd: int):
        """A y = x[0 : rows(nc), 0] in place with the stored factor; ends with a barrier."""
        if wp.static(serial):
            if lane == 0:
                sb.band_solve(band, x, nc, 0)
            block_sync()
        else:
            cr.cr_solve(x, (nc + S - 1) // S, lane, bd)

    @wp.func
    def factor_band(m: ColumnModel, q: wp.array2d(dtype=vec), x: wp.array2d(dtype=real), band: wp.array3d(dtype=real),
                    red: int, w: int, lane: int, bd: int):
        """Rows of A(U) into the band (lane per row), then lane 0 factors it row by row. True if A is SPD."""
        nc = m.con_i.shape[0]
        wa = w % m.con_active.shape[1]
        ws = w % m.minv_self.shape[1]
        wx = w % m.minv_cross.shape[1]
        for k in range(lane, nc, bd):
            r = gram_row(m.con_i, m.con_j, m.con_dref, m.con_active, m.cpl_start, m.cpl_l, m.cpl_a,
                         m.cpl_cross, m.cpl_sign, m.minv_self, m.minv_cross, q, U, k, wa, ws, wx)
            for d in range(LD):
                band[k, d, 0] = r[d]
        block_sync()
        bad = real(0.0)
        if lane == 0:
            for k in range(nc):
                if not sb.factor_store_row(band, sb.band_row(band, k, 0), k, 0):
                    bad = real(1.0)
        return block_max(x, red, bad, lane, bd) < real(0.5)

    @wp.func
    def factor_blocks(m: ColumnModel, q: wp.array2d(dtype=vec), x: wp.array2d(dtype=real), red: int,
                      w: int, lane: int, bd: int):
        """Rows of A(U) into the blocks D_i, E_i (lane per row), then CR. True if A is SPD."""
        nc = m.con_i.shape[0]
        nb = (nc + S - 1) // S
        D = nb * S
        E = D + nb * SS
        wa = w % m.con_active.shape[1]
        ws = w % m.minv_self.shape[1]
        wx = w % m.minv_cross.shape[1]
        for k in range(lane, nb * S, bd):
            r = rowvec()
            if k < nc:
                r = gram_row(m.con_i, m.con_j, m.con_dref, m.con_active, m.cpl_start, m.cpl_l, m.cpl_a,
                             m.cpl_cross, m.cpl_sign, m.minv_self, m.minv_cross, q, U, k, wa, ws, wx)
            else:  # padding row of the last block: identity
                r[0] = real(1.0)
            i = k / S
            rr = k - i * S
            for c in range(S):
                x[E + i * SS + rr * S + c, 0] = real(0.0)
            for d in range(LD):
                c = rr - d  # column of A[k, k-d] within block i, or within block i-1 if negative
                if c >= 0:
                    x[D + i * SS + rr * S + c, 0] = r[d]
                    x[D + i * SS + c * S + rr, 0] = r[d]
                elif i > 0:
                    x[E + i * SS + rr * S + c + S, 0] = r[d]
        block_sync()
        bad = real(1.0) - real(cr.cr_factor(x, nb, lane, bd))
        return block_max(x, red, bad, lane, bd) < real(0.5)

    @wp.func
    def factor_gram(m: ColumnModel, q: wp.array2d(dtype=vec), x: wp.array2d(dtype=real), band: wp.array3d(dtype=real),
                    red: int, w: int, lane: int, bd: int):
        """Factor A(U) with the compiled-in solver. True if A is SPD."""
        if wp.static(serial):
            return factor_band(m, q, x, band, red, w, lane, bd)
        else:
            return factor_blocks(m, q, x, red, w, lane, bd)

    return FactorFuncs(rows=rows, solve=solve, factor_gram=factor_gram)


class ColumnFuncs(NamedTuple):
    """The fused step's projections."""

    ColumnModel: type
    gather_kick: wp.Function
    factor_gram: wp.Function
    project_velocities: wp.Function
    project_positions: wp.Function
    vec: type


@functools.cache
def make_column_funcs(real, bandwidth: int, solver: str = "cr"):
    """The fused step's constraint pieces over the model struct ``ColumnModel``: the factor of A(U)
    (:func:`make_factor_funcs`) and the position and velocity projections."""
    vec = wp.types.vector(3, real)
    ff = make_factor_funcs(real, bandwidth, solver)
    rows, solve = ff.rows, ff.solve
    nf = make_node_funcs(real)
    ColumnModel, block_max, apply_impulse = nf.ColumnModel, nf.block_max, nf.apply_impulse

    @wp.func
    def project_velocities(m: ColumnModel, q: wp.array2d(dtype=vec), x: wp.array2d(dtype=real),
                           band: wp.array3d(dtype=real), red: int, w: int, lane: int, bd: int):
        """V -= M^-1 G^T lam with A lam = G V (x holds the reduction of A(U)). True if V is finite."""
        nc = m.con_i.shape[0]
        wa = w % m.con_active.shape[1]
        for k in range(lane, rows(nc), bd):
            r = real(0.0)
            if k < nc:
                if m.con_active[k, wa] > real(0.0):
                    r = wp.dot(member_vec(m.con_dref, m.con_i, m.con_j, q, k, U),
                               q[m.con_j[k], V] - q[m.con_i[k], V])
            x[k, 0] = r
        block_sync()
        solve(x, band, nc, lane, bd)
        apply_impulse(m, q, U, x, real(0.0), real(1.0), w, lane, bd)
        bad = real(0.0)
        for n in range(lane, m.partner.shape[0], bd):
            if not finite3(q[n, V]):
                bad = real(1.0)
        return block_max(x, red, bad, lane, bd) < real(0.5)

    @wp.func
    def project_positions(m: ColumnModel, q: wp.array2d(dtype=vec), x: wp.array2d(dtype=real),
                          band: wp.array3d(dtype=real), red: int, tol: real, max_iter: int, h: real, w: int,
                          lane: int, bd: int):
        """Simplified Newton onto |b_k| = L_k along M^-1 G(P)^T (x: reduction of A(P)); V gets
        the RATTLE update. Returns (max relative bar error, iterations)."""
        nc = m.con_i.shape[0]
        wa = w % m.con_active.shape[1]
        err = real(0.0)
        prev = real(0.0)
        it = int(0)
        while nc > 0:
            prev = err
            e_lane = real(0.0)
            for k in range(lane, rows(nc), bd):
                r = real(0.0)
                if k < nc:
                    if m.con_active[k, wa] > real(0.0):
                        r, e = bar_residual(member_vec(m.con_dref, m.con_i, m.con_j, q, k, U), m.con_L[k])
                        if wp.isnan(e) or e > e_lane:
                            e_lane = e
                x[k, 0] = r
            err = block_max(x, red, e_lane, lane, bd)
            if newton_stop(err, prev, tol, it, max_iter):
                break
            solve(x, band, nc, lane, bd)
            apply_impulse(m, q, P, x, real(1.0), real(1.0) / h, w, lane, bd)
            it += 1
        return err, it

    return ColumnFuncs(ColumnModel=ColumnModel, gather_kick=nf.gather_kick, factor_gram=ff.factor_gram,
                       project_velocities=project_velocities, project_positions=project_positions, vec=vec)


class StepFuncs(NamedTuple):
    """The fused step's RATTLE steps."""

    first_factor: wp.Function
    rattle_steps: wp.Function
    ColumnModel: type
    vec: type


@functools.cache
def make_step_funcs(real, bandwidth: int, solver: str = "cr"):
    """The RATTLE steps of one launch over the lanes' pieces (:func:`make_column_funcs`)."""
    f = make_column_funcs(real, bandwidth, solver)
    vec, ColumnModel = f.vec, f.ColumnModel

    @wp.func
    def first_factor(m: ColumnModel, q: wp.array2d(dtype=vec), qa: wp.array(dtype=vec), x: wp.array2d(dtype=real),
                     band: wp.array3d(dtype=real), red: int, init: int,
                     s0: int, status: wp.array(dtype=int), fail_step: wp.array(dtype=int), w: int, lane: int, bd: int):
        """init = 1: make V admissible and compute A(U), returns 0 steps to take; else factor A(U)
        for the first position projection (shared memory does not outlive a launch: the same
        numbers as the previous launch's last factor). Returns False on failure."""
        if m.con_i.shape[0] > 0:
            if not f.factor_gram(m, q, x, band, red, w, lane, bd):
                if lane == 0:
                    set_failure(status, fail_step, w, STATUS_CONSTRAINT, s0 + 1)
                return False
            if init != 0:
                f.project_velocities(m, q, x, band, red, w, lane, bd)
        if init != 0:
            f.gather_kick(m, q, qa, real(0.0), w, lane, bd)
        return True

    @wp.func
    def rattle_steps(m: ColumnModel, q: wp.array2d(dtype=vec), qa: wp.array(dtype=vec), x: wp.array2d(dtype=real),
                     band: wp.array3d(dtype=real), red: int,
                     tol: real, max_iter: int, fail_tol: real, h: real, n_sub: int, s0: int,
                     status: wp.array(dtype=int), fail_step: wp.array(dtype=int), w: int, lane: int, bd: int):
        """n_sub RATTLE steps (x holds the reduction of A(U) on entry). Returns (worst bar error,
        most Newton iterations)."""
        nn = m.partner.shape[0]
        nc = m.con_i.shape[0]
        half = real(0.5) * h
        worst = real(0.0)
        most = int(0)
        for sub in range(n_sub):
            for n in range(lane, nn, bd):  # kick and drift
                vn = q[n, V] + qa[n] * half
                q[n, V] = vn
                un = q[n, U]
                q[n, P] = un
                q[n, U] = un + vn * h
            block_sync()
            err, it = f.project_positions(m, q, x, band, red, tol, max_iter, h, w, lane, bd)
            most = wp.max(most, it)
            if err > worst:
                worst = err
            code = projection_status(err, fail_tol)
            if code == STATUS_OK:
                f.gather_kick(m, q, qa, half, w, lane, bd)  # force, second half kick
                if nc > 0:  # velocity projection at the new positions
                    if not f.factor_gram(m, q, x, band, red, w, lane, bd):
                        code = STATUS_CONSTRAINT
                    elif not f.project_velocities(m, q, x, band, red, w, lane, bd):
                        code = STATUS_NONFINITE
            if code != STATUS_OK:
                if lane == 0:
                    set_failure(status, fail_step, w, code, s0 + sub + 1)
                break
        return worst, most

    return StepFuncs(first_factor=first_factor, rattle_steps=rattle_steps, ColumnModel=ColumnModel, vec=vec)


class FusedKernels(NamedTuple):
    """The fused step's kernel and its types."""

    real: type
    vec: type
    ColumnModel: type
    rattle_columns: wp.Kernel


@functools.cache
def make_fused_kernels(real, bandwidth: int, x_cap: int = 0, q_cap: int = 0, solver: str = "cr", b_len: int = 0):
    """The fused kernel for scalar type ``real``, Gram half-bandwidth ``bandwidth`` and constraint
    solver ``solver`` ("cr" or "serial"), with ``x_cap`` solver reals and ``q_cap`` node vectors in
    block shared memory (0: in the global rows ``sx[w]``, ``sq[w]``; the serial band in ``sb[w]``).
    ``b_len``: rows of the serial band (n_constraints; its reals lead the shared solver rows)."""
    st = make_step_funcs(real, bandwidth, solver)
    LD = int(bandwidth) + 1
    b_reals = int(b_len) * LD if solver == "serial" else 0
    b_bytes = b_reals * (8 if real == wp.float64 else 4)
    vec, ColumnModel = st.vec, st.ColumnModel
    ctype = "double" if real == wp.float64 else "float"

    # Warp keys functions by name: one native function of its own name per buffer
    @wp.func_native(shared_snippet(ctype, x_cap, "wt_solver"))
    def xptr() -> wp.uint64: ...

    @wp.func_native(shared_snippet(ctype, 3 * q_cap, "wt_nodes"))
    def qptr() -> wp.uint64: ...

    @wp.kernel(enable_backward=False, module="unique")
    def rattle_columns(
        # Model:
        m: ColumnModel, tol: real, max_iter: int, fail_tol: real, h: real, n_sub: int, init: int,
        step: wp.array(dtype=int),
        # Data in/out:
        u: wp.array2d(dtype=vec), v: wp.array2d(dtype=vec), a: wp.array2d(dtype=vec),
        bar_err: wp.array(dtype=real), iters: wp.array(dtype=int),
        status: wp.array(dtype=int), fail_step: wp.array(dtype=int),
        # Scratch, one row per column unless in shared memory:
        sq: wp.array3d(dtype=vec), sx: wp.array3d(dtype=real), sb: wp.array4d(dtype=real),
        sa: wp.array2d(dtype=vec),
    ):
        """n_sub RATTLE steps of size h for column w (init = 1: make v admissible and compute a(u)
        instead)."""
        w, lane = wp.tid()
        if status[w] != STATUS_OK:
            return
        bd = wp.block_dim()
        if wp.static(x_cap > 0):
            x = wp.array(ptr=xptr() + wp.uint64(b_bytes), shape=(x_cap - b_reals, 1), dtype=real)
        else:
            x = sx[w]
        if wp.static(x_cap > 0 and b_reals > 0):
            band = wp.array(ptr=xptr(), shape=(b_reals // LD, LD, 1), dtype=real)
        else:
            band = sb[w % sb.shape[0]]  # (1, 1, 1, 1) placeholder for CR
        if wp.static(q_cap > 0):
            q = wp.array(ptr=qptr(), shape=(q_cap // NQ, NQ), dtype=vec)
        else:
            q = sq[w]
        qa = sa[w]  # accelerations: a global row per column, used twice a step (keeps shared memory for the rest)
        red = x.shape[0] - bd
        nn = u.shape[0]
        for n in range(lane, nn, bd):
            q[n, U] = u[n, w]
            q[n, V] = v[n, w]
            qa[n] = a[n, w]
        block_sync()
        s0 = step[0]
        if init == 0 and n_sub == 0:
            return
        if not st.first_factor(m, q, qa, x, band, red, init, s0, status, fail_step, w, lane, bd):
            return
        if init == 0:
            worst, most = st.rattle_steps(m, q, qa, x, band, red, tol, max_iter, fail_tol, h, n_sub, s0, status, fail_step,
                                          w, lane, bd)
            if lane == 0:
                iters[w] = wp.max(iters[w], most)
                if worst > bar_err[w]:
                    bar_err[w] = worst
        for n in range(lane, nn, bd):
            u[n, w] = q[n, U]
            v[n, w] = q[n, V]
            a[n, w] = qa[n]
        block_sync()  # CPU fibers may start the next block as lanes finish: its loads must wait for our stores

    return FusedKernels(real=real, vec=vec, ColumnModel=ColumnModel, rattle_columns=rattle_columns)
