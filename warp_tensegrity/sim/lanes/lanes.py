"""The one-warp-per-column RATTLE step: the kernel (its pieces in :mod:`.lane_funcs`, the lane map
there too), its lane arrays and its launches; which batches it takes is
:mod:`warp_tensegrity.policy.lane_fit` (NumPy only). The Integrator drives it through
:class:`.step.LanesStep`, the Step interface (the step counter is the interface's one kernel).

It takes T3 columns (column_batch's layout) with lumped masses: flexible or elastic bases up to
:data:`~warp_tensegrity.policy.lane_fit.MAX_LEVELS_PER_LANE` levels per lane (128 prisms), and batches with rigid-base columns
(ring links as constraints, :mod:`.lane_rigid`) up to 2 levels per lane (64 prisms). Longer columns
run the same kernel on k warps per column, one block of G = 32 k threads each, its primitives through
shared memory (:func:`.lane_ops.make_block_ops`; :func:`~warp_tensegrity.policy.lane_fit.lane_map`).
Massive bars and other networks run the other paths; :func:`~warp_tensegrity.policy.lane_fit.lane_support` says why.
"""

import functools
from typing import TYPE_CHECKING, NamedTuple

import numpy as np
import warp as wp

from ..common import (PI, STATUS_CONSTRAINT, STATUS_NONFINITE, STATUS_OK, bar_residual, cable_energy2, cable_force,
                     feasibility_record, member_excess2, newton_stop, output_slot, prism_twist_of, projection_status,
                     set_failure)
from ...policy.lane_fit import WARP, lane_map, lane_support
from .lane_funcs import make_lane_funcs, make_mixed_funcs
from .lane_ops import make_block_ops, make_lane_ops
from .lane_rigid import make_rigid_funcs

if TYPE_CHECKING:
    from ..model import Model
    from ...scene.batch import NetworkBatch


class LaneKernels(NamedTuple):
    """The lane step's kernel and its types, by name (:func:`make_lane_kernel`)."""

    real: type
    P: int
    G: int
    vec: type
    vec2: type
    lane_steps: wp.Kernel


@functools.cache
def make_lane_kernel(real, P: int, G: int, max_registers: int | None = None, rigid: bool = False,
                     fast_math: bool = False, smem_spill_block: int = 0, loaded: bool = False,
                     a_mem: bool = False, mixed: bool = False, block_min: int = 1,
                     record_call: bool = False):
    """The warp-per-column RATTLE kernel for ``real``, P levels per lane, G lanes per column
    (``max_registers``: a cap per CUDA thread, None: the compiler's choice; ``rigid``: the batch
    has ring links, active in its rigid-base columns, :mod:`.lane_rigid`; ``fast_math``: CUDA's
    approximate fp32 division and square root; ``smem_spill_block``: the launch's threads per block,
    with which register spills may go to shared memory instead of local memory, 0: not; ``loaded``:
    the batch has a dead load (the end preload), added to the cable forces; compiled out otherwise, so
    an unloaded batch runs today's code; ``a_mem``: the accelerations live in ``a`` (global memory)
    from the forces to the next half kick instead of in registers through the factor, the velocity
    projection and Newton, where only a failure store would read them; ``mixed``: fp64 only, the
    factor and solves in fp32 with fp64 residuals and refinement, :func:`.lane_funcs.make_mixed_funcs`;
    ``block_min``: k warps per column only, the blocks the compiler must fit on one SM at once, which
    caps its registers at 65,536 / (G block_min), 255 at most; ``record_call``: the output records a
    function the kernel calls (CUDA ``__noinline__``) instead of code inlined in the step's loop). Launch
    with ``dim`` = B G rounded up to a multiple of 32, one warp per block (or a few)."""
    blockwide = G > WARP  # k warps per column, one block of G threads each (lane_ops.make_block_ops)
    ops = make_block_ops(real, G) if blockwide else make_lane_ops(real)
    vote = ops.any
    f = make_lane_funcs(real, P, G, ops, cable_force, bar_residual, cable_energy2, robust_check=bool(fast_math))
    fr = make_rigid_funcs(real, P, G, ops, f) if rigid else None
    RFac = fr.RFac if rigid else f.Fac
    # mixed precision on one warp per column only: the k-warp exchanges keep one parity per precision
    mixed = bool(mixed) and real == wp.float64 and not blockwide
    mx = None
    if mixed:
        ops32 = make_lane_ops(wp.float32)
        f32 = make_lane_funcs(wp.float32, P, G, ops32, cable_force, bar_residual, cable_energy2)
        mx = make_mixed_funcs(real, P, f, f32, fr, make_rigid_funcs(wp.float32, P, G, ops32, f32) if rigid else None)
    FacQ = mx.Fac if mixed else f.Fac  # (a placeholder without mixed: compiled out)
    target_v, target_n = (real(t) for t in MIXED_TARGET)
    most_passes = int(MIXED_MOST_PASSES)
    vec = f.vec
    Nodes, XY, Lv, Rows, Pv = f.Nodes, f.XY, f.Lv, f.Rows, f.Pv
    zero = real(0.0)
    vec2 = wp.types.vector(2, real)

    @wp.func(inline=True)
    def seg_ok(ok: int, g: int, wl: int):
        """1 if ok is 1 on every lane of the segment."""
        return ops.segment_max(real(1 - ok), g, wl) < real(0.5)

    @wp.func(inline=True)
    def store(U: Nodes, V: Nodes, A: Nodes, u: wp.array2d(dtype=vec), v: wp.array2d(dtype=vec),
              a: wp.array2d(dtype=vec), lane: int, n: int, w: int):
        """Write the lane's nodes of column w."""
        for j in range(1, wp.static(P + 1)):
            L = wp.static(P) * lane + j
            if L <= n:
                for k in range(3):
                    node = 3 * L + k
                    u[node, w] = U[3 * j - 3 + k]
                    v[node, w] = V[3 * j - 3 + k]
                    if wp.static(not a_mem):  # (a_mem: a holds them already)
                        a[node, w] = A[3 * j - 3 + k]

    @wp.func(inline=True)
    def store_a(A: Nodes, a: wp.array2d(dtype=vec), lane: int, n: int, w: int):
        """Write the lane's accelerations of column w (a_mem)."""
        for j in range(1, wp.static(P + 1)):
            L = wp.static(P) * lane + j
            if L <= n:
                for k in range(3):
                    a[3 * L + k, w] = A[3 * j - 3 + k]

    @wp.func(inline=True)
    def load_a(a: wp.array2d(dtype=vec), lane: int, n: int, w: int):
        """The lane's accelerations of column w (a_mem; 0 past the column)."""
        A = Nodes()
        for j in range(1, wp.static(P + 1)):
            L = wp.static(P) * lane + j
            if L <= n:
                for k in range(3):
                    A[3 * j - 3 + k] = a[3 * L + k, w]
        return A

    @wp.func(inline=not record_call)
    def record(U: Nodes, V: Nodes, Fx: Nodes, xyl: XY, hzl: Pv, hnd: Pv, ex: Pv, cross: vec, base_ea: vec,
               rest: wp.array2d(dtype=real), wr: int, n: int, lane: int, g: int, wl: int, w: int, wM: int, slot: int,
               alive: int, h0: wp.array(dtype=real), static_dz: wp.array2d(dtype=real), level_ref: wp.array2d(dtype=vec),
               prism_hand: wp.array(dtype=real), m_self: wp.array2d(dtype=real), strain: wp.array3d(dtype=real),
               kinetic: wp.array2d(dtype=real), elastic: wp.array2d(dtype=real), twist: wp.array2d(dtype=real),
               twist_max: wp.array2d(dtype=real), twist_min: wp.array2d(dtype=real),
               height_min: wp.array2d(dtype=real), left_slot: wp.array3d(dtype=int), below_node: int, end_node: int,
               below: wp.array2d(dtype=real), end: wp.array2d(dtype=real)):
        """The output records of the step that just ended, in the kernel (the staged record kernels'
        outputs: strain and the feasibility record through the same ``@wp.func`` bodies, so the same
        bits; the energies, and the energy parts of the energy measures where ``below`` has rows
        (record_energy_parts, measure.energy), summed lane by lane, so their last bits may differ):
        only a live column's."""
        X = f.extend(U, U, lane, g, wl)
        mass = Lv()
        for j in range(1, wp.static(P + 1)):
            L = wp.static(P) * lane + j
            if L <= n:
                mass[j] = m_self[3 * L, wM]
        e = f.energies(X, V, Fx, xyl, hzl, hnd, ex, cross, base_ea, rest, wr, n, mass, lane, g, wl)
        if below.shape[0] > 0:  # the energy parts: nodes and members by their first node (record_energy_parts)
            eb = zero
            et = zero
            for q in range(wp.static(P)):
                if ex[q] != zero:
                    m = wp.static(P) * lane + q
                    for k in range(3):
                        vv = V[3 * q + k]
                        ke = mass[q + 1] * wp.dot(vv, vv) - real(2.0) * wp.dot(Fx[3 * q + k], X[3 * q + 3 + k])
                        node = 3 * (m + 1) + k
                        b0, du = f.base_ends(xyl, X, 3 * q + 3, k)
                        eb_ = member_excess2(b0, du, base_ea[0], base_ea[1], rest[wr, 3 * n + 3 * m + 3 + k])
                        first_b = 3 * (m + 1) + wp.min(k, (k + 1) % 3)
                        c0, dc = f.cross_ends(xyl, X, hzl, hnd, q, k)
                        ec_ = member_excess2(c0, dc, cross[0], cross[1], rest[wr, 3 * m + k])
                        first_c = 3 * m + k
                        if node < below_node:
                            eb += ke
                        if node >= end_node:
                            et += ke
                        if first_b < below_node:
                            eb += eb_
                        if first_b >= end_node:
                            et += eb_
                        if first_c < below_node:
                            eb += ec_
                        if first_c >= end_node:
                            et += ec_
            # (the clamped level 0's base members: no displacement, no excess)
            sp = ops.segment_sum3(vec(eb, et, zero), g, wl)
            if alive == 1 and lane == 0:
                below[slot, w] = real(0.5) * sp[0]
                end[slot, w] = real(0.5) * sp[1]
        if alive == 1:
            if lane == 0:
                kinetic[slot, w] = real(0.5) * e[0]
                elastic[slot, w] = real(0.5) * e[1] - e[2]  # with the dead load's potential -f . u
            for q in range(wp.static(P)):
                if ex[q] != zero:
                    m = wp.static(P) * lane + q  # the prism: levels m (rows 3 q ..) and m + 1 of X
                    Db = wp.matrix_from_rows(X[3 * q], X[3 * q + 1], X[3 * q + 2])
                    Dt = wp.matrix_from_rows(X[3 * q + 3], X[3 * q + 4], X[3 * q + 5])
                    Rb = wp.matrix_from_rows(level_ref[m, 0], level_ref[m, 1], level_ref[m, 2])
                    Rt = wp.matrix_from_rows(level_ref[m + 1, 0], level_ref[m + 1, 1], level_ref[m + 1, 2])
                    near = real(PI)
                    if slot > 0:
                        near = twist[m, w]
                    phi, h = prism_twist_of(Db, Dt, Rb, Rt, h0[m], prism_hand[m], near)
                    feasibility_record(phi, h, h0[m], near, slot, m, w, twist, twist_max, twist_min, height_min,
                                       left_slot)
                    if strain.shape[0] > 0:
                        strain[slot, m, w] = (h - (h0[m] + static_dz[m, w % static_dz.shape[1]])) / h

    spill = {"enable_cuda_smem_spilling": True, "launch_bounds": smem_spill_block} if smem_spill_block else {}
    if blockwide:  # a block of G threads per column: the compiler fits their registers in one SM (G = 512: 128 each)
        # with the blocks per SM stated (1 at least): ptxas given only the block size held a block of 512
        # threads to 64 registers, half what one block per SM allows (spilling 15 KB a thread for rigid
        # bases in fp64; 9 KB at 128: lanes_ptxas)
        spill.setdefault("launch_bounds", (G, max(1, int(block_min))))

    @wp.kernel(enable_backward=False, module="unique", cuda_max_registers=max_registers,
               module_options={"fast_math": bool(fast_math)}, **spill)
    def lane_steps(
        # Model:
        xy: wp.array(dtype=vec2), hz: wp.array(dtype=real), hand: wp.array(dtype=int),
        cab_EA: wp.array2d(dtype=real), cab_EAc: wp.array2d(dtype=real),
        minv_self: wp.array2d(dtype=real), rest: wp.array2d(dtype=real), con_active: wp.array2d(dtype=real),
        ext_force: wp.array2d(dtype=vec), n_columns: int,
        h0: wp.array(dtype=real), static_dz: wp.array2d(dtype=real), level_ref: wp.array2d(dtype=vec),
        prism_hand: wp.array(dtype=real), m_self: wp.array2d(dtype=real), every: int,
        tol: real, max_iter: int, fail_tol: real, h: real, n_sub: int, init: int, step: wp.array(dtype=int),
        # Data in/out:
        u: wp.array2d(dtype=vec), v: wp.array2d(dtype=vec), a: wp.array2d(dtype=vec),
        bar_err: wp.array(dtype=real), iters: wp.array(dtype=int),
        status: wp.array(dtype=int), fail_step: wp.array(dtype=int),
        twist: wp.array2d(dtype=real), twist_max: wp.array2d(dtype=real), twist_min: wp.array2d(dtype=real),
        height_min: wp.array2d(dtype=real), left_slot: wp.array3d(dtype=int),
        below_node: int, end_node: int,
        # Data out:
        strain: wp.array3d(dtype=real), kinetic: wp.array2d(dtype=real), elastic: wp.array2d(dtype=real),
        below: wp.array2d(dtype=real), end: wp.array2d(dtype=real),
        # Data in/out (mixed): refinement passes per column, velocity projection's and Newton's (-1: not yet probed)
        passes: wp.array2d(dtype=int),
    ):
        """n_sub RATTLE steps of size h (init = 1: make v admissible and compute a(u) instead), with
        the output records of every step that is a multiple of ``every`` (:func:`record`)."""
        tid = wp.tid()
        g = wp.static(G)
        w = tid // g
        lane = tid - w * g
        wl = tid % wp.static(max(G, WARP))  # the lane's index in its warp (k warps: in its block)
        n = hz.shape[0]
        wc = wp.min(w, n_columns - 1)  # a safe column index for the padding threads' reads
        alive = int(0)
        if w < n_columns:
            if status[w] == STATUS_OK:
                alive = 1
        if vote(alive, wl) == 0:
            return
        start = alive
        wE = wc % cab_EA.shape[1]
        wC = wc % cab_EAc.shape[1]
        wM = wc % minv_self.shape[1]
        nb = 3 * n  # first base member (cross cables come first)
        # the lane's levels P lane + j, j = 0..P (j = 0: the level below, owned by lane - 1)
        U = Nodes()
        V = Nodes()
        A = Nodes()
        xyl = XY()
        minv = Lv()
        hzl = Pv()
        hnd = Pv()
        ex = Pv()
        for j in range(wp.static(P + 1)):
            L = wp.static(P) * lane + j
            if L <= n:
                for k in range(3):
                    node = 3 * L + k
                    xyl[3 * j + k] = xy[node]
                    minv[j] = minv_self[node, wM]
                    if j > 0:
                        rr = wp.max(3 * j - 3 + k, 0)
                        U[rr] = u[node, wc]
                        V[rr] = v[node, wc]
                        if wp.static(not a_mem):
                            A[rr] = a[node, wc]
                if j > 0:
                    q = wp.max(j - 1, 0)
                    hzl[q] = hz[L - 1]
                    hnd[q] = real(hand[L - 1])
                    ex[q] = real(1.0)
            elif j > 0:
                q = wp.max(j - 1, 0)
                hzl[q] = real(1.0)  # padding prisms: finite, inert geometry
        Fx = Nodes()  # the dead load on the lane's nodes
        if wp.static(loaded):
            for j in range(1, wp.static(P + 1)):
                L = wp.static(P) * lane + j
                if L <= n:
                    for k in range(3):
                        Fx[3 * j - 3 + k] = ext_force[3 * L + k, wc % ext_force.shape[1]]
        rig = con_active[wp.min(3, con_active.shape[0] - 1), wc % con_active.shape[1]]  # the column's links
        if wp.static(not rigid):
            rig = zero
        cross = vec(cab_EA[0, wE], cab_EAc[0, wC], zero)
        base_ea = vec(cab_EA[nb, wE], cab_EAc[nb, wC], zero)
        s0 = step[0]
        worst = zero
        most = int(0)
        half = real(0.5) * h
        kick = half  # the second half kick; init: none (v is only made admissible)
        n_it = n_sub
        if init != 0:
            kick = zero
            n_it = 1
        Bm = f.bars(U, xyl, hzl, lane, g, wl)
        Cm = Nodes()
        if wp.static(rigid):
            Cm = fr.links(U, xyl, lane, g, wl)
        pass_v = int(0)  # (mixed) refinement passes of the velocity projection's solve, of Newton's:
        pass_n = int(0)  # the column's own, and the warp's most (the loops' counts)
        most_v = int(0)
        most_n = int(0)
        # iteration i: the factor of A(U) at the state after step i and the end of step i (velocity
        # projection), then step i + 1 up to its forces and second half kick; each piece once in code
        for i in range(n_it + 1):
            if vote(alive, wl) == 0:
                break
            Fr = RFac()
            Fm = f.Fac()
            Fq = FacQ()
            okl = int(1)
            if wp.static(mixed):
                Fq, okl = mx.factor(Bm, Cm, minv, ex, rig, n, lane, g, wl)
                if i == 0:  # the column's passes from its first factor of the run, kept in memory: its
                    # results then depend neither on the launches' ends nor on the warp's other columns
                    need = int(0)
                    if alive == 1:
                        pass_v = passes[w, 0]
                        pass_n = passes[w, 1]
                        if pass_v < 0:
                            need = 1
                    if vote(need, wl) == 1:
                        eta = mx.probe(Fq, Bm, Cm, minv, ex, rig, alive, lane, g, wl)
                        if need == 1:
                            pass_v = mx.refinements(eta, target_v, most_passes)
                            pass_n = mx.refinements(eta, target_n, most_passes)
                            if lane == 0:
                                passes[w, 0] = pass_v
                                passes[w, 1] = pass_n
                    most_v = int(ops.segment_max(real(pass_v), 32, wl))
                    most_n = int(ops.segment_max(real(pass_n), 32, wl))
            elif wp.static(rigid):
                Fr, okl = fr.factor(Bm, Cm, minv, ex, rig, n, lane, g, wl)
            else:
                d, e, l, bnext = f.gram(Bm, minv, ex, n, lane, g, wl)
                Fm, okl = f.factor(d, e, l, lane, g, wl)
            fok = seg_ok(okl, g, wl)
            vok = bool(True)
            if i > 0:
                rb = f.velocity_rows(Bm, V, ex, lane, g, wl)
                dv = Nodes()
                if wp.static(mixed):
                    rm = Rows()
                    if wp.static(rigid):
                        rm = fr.link_velocity_rows(Cm, V, ex, rig)
                    beta, mu = mx.solve(Fq, rb, rm, Bm, Cm, minv, ex, rig, most_v, pass_v, lane, g, wl)
                    dv = f.impulse(Bm, beta, minv, lane, g, wl)
                    if wp.static(rigid):
                        dv = fr.link_impulse(dv, Cm, mu, minv)
                elif wp.static(rigid):
                    beta, mu = fr.solve(Fr, rb, fr.link_velocity_rows(Cm, V, ex, rig), lane, g, wl)
                    dv = fr.link_impulse(f.impulse(Bm, beta, minv, lane, g, wl), Cm, mu, minv)
                else:
                    dv = f.impulse(Bm, f.solve(Fm, rb, lane, g, wl), minv, lane, g, wl)
                if fok:
                    V = V - dv
                vok = seg_ok(f.finite_nodes(V), g, wl)
            code = int(STATUS_OK)
            if not fok:
                code = STATUS_CONSTRAINT
            elif not vok:
                code = STATUS_NONFINITE
            if code != STATUS_OK and alive == 1:
                # the column freezes here: its state is stored now, its registers run on unused
                store(U, V, A, u, v, a, lane, n, w)
                if lane == 0:
                    set_failure(status, fail_step, w, code, s0 + wp.max(i, 1))
                alive = 0
            if i > 0:
                slot = output_slot(s0 + i, every, kinetic.shape[0])
                if slot >= 0:  # an output step: warp-uniform (one s0)
                    record(U, V, Fx, xyl, hzl, hnd, ex, cross, base_ea, rest, wc % rest.shape[0], n, lane, g, wl, w,
                           wc % m_self.shape[1],
                           slot, alive, h0, static_dz, level_ref, prism_hand, m_self, strain, kinetic, elastic,
                           twist, twist_max, twist_min, height_min, left_slot, below_node, end_node, below, end)
            if i == n_it:
                break
            if init == 0:
                Bp = Bm  # bars (and links) at the start of the step: the factor's
                Cp = Cm
                if wp.static(a_mem):
                    A = load_a(a, lane, n, wc)
                V = V + A * half
                U = U + V * h
                # simplified Newton onto |b| = L along M^-1 G(P)^T
                err = zero
                prev = zero
                it = int(0)
                going = alive
                while True:
                    Bm = f.bars(U, xyl, hzl, lane, g, wl)
                    r, el = f.residuals(Bm, xyl, hzl, ex, rig, zero)
                    rl = Rows()
                    if wp.static(rigid):
                        Cm = fr.links(U, xyl, lane, g, wl)
                        rl, el = fr.link_residuals(Cm, xyl, hzl, ex, rig, el)
                    es = ops.segment_max(el, g, wl)
                    if going == 1:
                        prev = err
                        err = es
                        if newton_stop(err, prev, tol, it, max_iter):
                            going = 0  # converged, out of iterations or stalled at round-off
                    if vote(going, wl) == 0:
                        break
                    dn = Nodes()
                    if wp.static(mixed):
                        beta, mu = mx.solve(Fq, r, rl, Bp, Cp, minv, ex, rig, most_n, pass_n, lane, g, wl)
                        dn = f.impulse(Bp, beta, minv, lane, g, wl)
                        if wp.static(rigid):
                            dn = fr.link_impulse(dn, Cp, mu, minv)
                    elif wp.static(rigid):
                        beta, mu = fr.solve(Fr, r, rl, lane, g, wl)
                        dn = fr.link_impulse(f.impulse(Bp, beta, minv, lane, g, wl), Cp, mu, minv)
                    else:
                        dn = f.impulse(Bp, f.solve(Fm, r, lane, g, wl), minv, lane, g, wl)
                    if going == 1:  # (other columns of the warp may still iterate)
                        U = U - dn
                        V = V - dn * (real(1.0) / h)
                        it += 1
                if alive == 1:
                    most = wp.max(most, it)
                    if err > worst:
                        worst = err
                    code = projection_status(err, fail_tol)
                    if code != STATUS_OK:
                        store(U, V, A, u, v, a, lane, n, w)
                        if lane == 0:
                            set_failure(status, fail_step, w, code, s0 + i + 1)
                        alive = 0
            Fn = f.forces(U, xyl, hzl, hnd, ex, cross, base_ea, rest, wc % rest.shape[0], n, lane, g, wl)
            if wp.static(loaded):
                Fn = Fn + Fx
            A = f.accelerations(Fn, minv)
            V = V + A * kick
            if wp.static(a_mem):
                if alive == 1:  # (a failed column keeps the a of its failure)
                    store_a(A, a, lane, n, w)
        if alive == 1:
            store(U, V, A, u, v, a, lane, n, w)
        if start == 1 and lane == 0 and init == 0:
            iters[w] = wp.max(iters[w], most)
            if worst > bar_err[w]:
                bar_err[w] = worst

    return LaneKernels(real=real, P=P, G=G, vec=vec, vec2=vec2, lane_steps=lane_steps)


LANE_STEPS = 64  # most RATTLE steps per launch (the kernel writes the output records of the steps it spans)
# CUDA threads per block of the one-warp-per-column kernel: 4 warps (on the CPU: one emulated warp, 32
# fibers). On an H200, B = 16,384, against 64 in the same calls: RB fp32 3.02e7 and 3.02e7 column-steps/s
# against 2.92e7 (twice each; 32: 2.85e7), FB fp32 1.717e8 against 1.713e8, FB fp64 2.204e7 against
# 2.187e7; the same Newton counts (benchmarks/results/issue33_h200_ninth/, calls 18 and 19)
LANE_BLOCK_DIM = 128
LANE_MAX_REGISTERS = {"fp32": None, "fp64": None}  # per CUDA thread (None: the compiler's choice)
# CUDA's approximate fp32 division and square root, for the flexible-base kernel: 2.1x its rate with
# the bars still within 2.4e-7 (H200, 16,384 columns: benchmarks/results/lanes_tuning_h200/). With it
# the bar-length check takes a form that the approximations leave exact (lane_funcs.bar_check): rigid
# bases' bars reached 3.2e-7 with fast math and the plain check, over the fp32 tolerance of 3e-7
LANE_FAST_MATH = {"fp32": True, "fp64": False}
LANE_FAST_MATH_RIGID = {"fp32": True, "fp64": False}  # the same for batches with rigid bases
# k warps per column: blocks per SM the registers must allow. 2 (128 registers at 256 lanes) lost on an
# H200: FB fp32, 500 prisms, 5.7e6 column-steps/s against 9.8e6 (benchmarks/results/issue33_h200_sixth)
LANE_BLOCK_MIN = {"fp32": 1, "fp64": 1}
LANE_SMEM_SPILL = {"fp32": False, "fp64": False}  # register spills to shared memory (CUDA 13+) instead of local
# the accelerations kept in global memory between the forces and the next half kick (registers
# free through the factor and Newton; a failure store leaves them as they were). Off: on an H200
# (B = 16,384) it cost FB fp32 45 % (1.78e8 -> 9.8e7), FB fp64 12 %, RB fp32 6 %: the loads after
# Newton stall 8 resident warps per SM (benchmarks/results/issue33_h200/switches)
LANE_A_MEM = {"fp32": False, "fp64": False}
# the output records (``record``) a function call instead of inlined code, out of the hot loop (called at
# output steps only). Off: on an H200 (B = 16,384) it moved the four 50-prism cases by -2.2 % to +1.1 %,
# though ptxas counts fewer spill bytes (benchmarks/results/issue33_h200_ninth/, call 3)
LANE_RECORD_CALL = {"fp32": False, "fp64": False}
# fp64 columns: an fp32 factor and fp32 solves with fp64 residuals and iterative refinement
LANE_MIXED = {"fp32": False, "fp64": True}
# what refinement reaches (:func:`.lane_funcs.make_mixed_funcs`): the velocity projection's solve
# (a one-shot solve: its relative error e moves v by e |dv|, so 1e-13 keeps v to ~1e-13 of fp64's),
# Newton's (which refines itself: each iteration forms its residual in fp64, and an error eta of its
# solve only slows its convergence by a factor ~ eta). Probed once per column, at its first factor of
# the run (LaneStep.passes), so that launch ends and warp neighbours leave its bits alone. On the CPU
# (benchmarks/lanes_mixed_check.py):
# flexible bases (kappa ~ 3.5) 1 pass and 0, rigid bases (kappa ~ 4e4) 2 and 0
MIXED_TARGET = (1e-13, 1e-3)
MIXED_MOST_PASSES = 6


class LaneStep:
    """Lane arrays and launches of the warp-per-column step for one model on one device."""

    records_inside = True
    """The kernel writes the output records itself (:func:`make_lane_kernel`'s ``record``): a launch
    may span many outputs, and the Integrator launches no record kernels after it."""

    def __init__(self, model: "Model", batch: "NetworkBatch", device, every: int, strain, kinetic, elastic,
                 energy_parts: tuple[int, int] | None = None, below=None, end=None):
        """``every``: steps per output; ``strain`` (or None: not kept), ``kinetic``, ``elastic``: the
        Integrator's record arrays, which the kernel fills; with ``energy_parts`` (below_node, end_node)
        also the energy parts ``below`` and ``end`` (measure.energy)."""
        why = lane_support(batch)
        if why is not None:
            raise ValueError(f"the warp-per-column step does not take this batch: {why}")
        self.model = model
        self.device = device
        n = batch.level_nodes.shape[0] - 1
        self.rigid = batch.constraints.shape[0] == 6 * n
        self.P, self.G = lane_map(n, self.rigid, model.precision)
        real = wp.float64 if model.precision == "fp64" else wp.float32
        npr = np.float64 if real == wp.float64 else np.float32
        self.block_dim = self.G if self.G > WARP else LANE_BLOCK_DIM if device.is_cuda else WARP
        prec = model.precision
        fast = (LANE_FAST_MATH_RIGID if self.rigid else LANE_FAST_MATH)[prec] and device.is_cuda
        self.kernels = make_lane_kernel(real, self.P, self.G, LANE_MAX_REGISTERS[prec], self.rigid, fast,
                                        self.block_dim if LANE_SMEM_SPILL[prec] and device.is_cuda else 0,
                                        batch.external_force is not None and bool(np.any(batch.external_force)),
                                        LANE_A_MEM[prec], LANE_MIXED[prec],
                                        LANE_BLOCK_MIN[prec] if self.G > WARP else 1, LANE_RECORD_CALL[prec])
        X = batch.positions
        z = X[:, 2].reshape(n + 1, 3)[:, 0]
        top = batch.cables[: 3 * n : 3, 1] - 3 * np.arange(1, n + 1)
        d = device
        self.xy = wp.array(X[:, :2].astype(npr), dtype=self.kernels.vec2, device=d)
        self.hz = wp.array(np.diff(z).astype(npr), dtype=real, device=d)
        # rest lengths with the column index first: a column's lanes read adjacent addresses. From the
        # batch (the Model's source), not read back from the device: a read-back waits behind the
        # kernels of the runs stepping beside this one (0.18 s a run on the H200 in phase_large)
        self.rest = wp.array(np.ascontiguousarray(np.asarray(batch.cable_rest_length).astype(npr)), dtype=real,
                             device=d)
        self.hand = wp.array(np.where(top == 2, 1, 0).astype(np.int32), dtype=wp.int32, device=d)
        self.real = real
        self.block_dim = self.G if self.G > WARP else LANE_BLOCK_DIM if device.is_cuda else WARP
        self.steps_per_launch = LANE_STEPS
        B = model.n_columns
        self.threads = -(-B * self.G // WARP) * WARP
        self.every = int(every)
        none = wp.zeros((0, 0), dtype=real, device=d)
        self.parts = [int(x) for x in (energy_parts or (0, 0))]
        self.records = (wp.zeros((0, 0, 0), dtype=real, device=d) if strain is None else strain, kinetic, elastic,
                        none if energy_parts is None else below, none if energy_parts is None else end)
        self.passes = wp.full((B, 2), -1, dtype=wp.int32, device=d)  # (mixed) refinement passes, probed once

    @property
    def description(self) -> str:
        per = WARP // self.G
        if self.G > WARP:
            return (f"lanes ({self.G // WARP} warps per column, one block: {self.P} levels per lane, {self.G} lanes "
                    "per column" + ("; ring links folded into 3 x 3 bar blocks" if self.rigid else "")
                    + "; chains by PCR through shared memory)")
        return (f"lanes (one warp per column: {self.P} levels per lane, {self.G} lanes per column"
                + (f", {per} columns per warp" if per > 1 else "")
                + ("; ring links folded into 3 x 3 bar blocks" if self.rigid else "") + "; chains by PCR over shuffles)")

    def load(self):
        self.kernels.lane_steps.module.load(self.device, self.block_dim)

    def launch(self, data, settings, dt: float, n_sub: int, init: int = 0):
        m, r = self.model, self.real
        wp.launch(self.kernels.lane_steps, dim=self.threads, block_dim=self.block_dim, device=self.device, inputs=[
            self.xy, self.hz, self.hand, m.cab_EA, m.cab_EAc, m.minv_self, self.rest, m.con_active, m.ext_force,
            m.n_columns,
            m.h0, m.static_dz, m.level_ref, m.prism_hand, m.m_self, self.every,
            r(settings.tolerance), int(settings.max_projection_iters), r(settings.failure_bar_error), r(dt),
            int(n_sub), int(init), data.step,
            data.u, data.v, data.a, data.bar_err, data.iters, data.status, data.fail_step,
            data.twist, data.twist_max, data.twist_min, data.height_min, data.left_slot, *self.parts, *self.records,
            self.passes])
