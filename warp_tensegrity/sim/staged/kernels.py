"""Warp kernels of the integrator step, generated once per precision.

Layout (see :mod:`warp_tensegrity.sim.model`): every batched array is ``(n_items, B)`` with the
column index ``w`` fastest, so per-node/per-member launches ``dim=(n_items, B)`` and
per-column solver threads (``dim=B``, looping over items) both read coalesced memory.
Per-column parameters may have a trailing size of 1 (shared) and are read as ``p[k, w % p.shape[1]]``;
the hot kernels compute each array's column index ``w % p.shape[1]`` once per thread.

State is the displacement ``u = x - X`` from the reference configuration, so fp32 keeps
bar vectors ``b = d_ref + u_j - u_i`` to ~1e-7 relative even far from the origin.

Kernel arguments are grouped as ``# Model:`` (topology and parameters), ``# Data in:`` and
``# Data out:``. One thread per node (kick, drift), per block of M (force gather: a massive
bar's two nodes, or a lone node), per prism (strain), or per column (constraint solves: banded
Cholesky of the Gram matrix G M^-1 G^T, which handles bars sharing nodes and rigid-link loops
alike). The per-column solver kernels (``make_solver_kernels``) live in :mod:`.staged_solver`;
import them from there (not re-exported here: that would lengthen the import chains).
"""


import functools
from typing import NamedTuple

import warp as wp

from ..common import (PI, STATUS_OK, axis_pair, cable_energy2, feasibility_record, member_excess2, member_vec,
                     node_force, output_slot, pget, prism_twist)

wp.set_module_options({"enable_backward": False})


class StagedKernels(NamedTuple):
    """The staged step's per-node kernels and the output records, by name (:func:`make_kernels`)."""

    real: type
    vec: type
    gather_accel: wp.Kernel
    kick_drift: wp.Kernel
    rk_stage: wp.Kernel
    record_strain: wp.Kernel
    record_energy: wp.Kernel
    record_energy_parts: wp.Kernel
    record_feasibility: wp.Kernel
    record_pairs: wp.Kernel


@functools.cache
def make_kernels(real) -> StagedKernels:
    """Kernels for scalar type ``real`` (wp.float32 or wp.float64): the per-node step kernels
    and the output records."""
    return StagedKernels(real=real, vec=wp.types.vector(3, real), **_node_kernels(real), **_record_kernels(real))


@functools.cache
def _node_kernels(real):
    vec = wp.types.vector(3, real)

    @wp.kernel(enable_backward=False, module="unique")
    def gather_accel(
        # Model:
        cab_EA: wp.array2d(dtype=real), cab_EAc: wp.array2d(dtype=real), cab_L: wp.array2d(dtype=real),
        node_start: wp.array(dtype=int), node_member: wp.array(dtype=int), node_other: wp.array(dtype=int),
        node_dref: wp.array(dtype=vec), mass_blocks: wp.array2d(dtype=int), minv_self: wp.array2d(dtype=real), minv_cross: wp.array2d(dtype=real),
        ext_force: wp.array2d(dtype=vec),
        status: wp.array(dtype=int),
        # Data in:
        u: wp.array2d(dtype=vec), v: wp.array2d(dtype=vec), kick: real,
        # Data out:
        a: wp.array2d(dtype=vec), v_out: wp.array2d(dtype=vec),
    ):
        """a = M^-1 f(u) (unconstrained); v_out = v + kick * a. One thread per block of M: a massive
        bar's two nodes, which M^-1 couples, or a lone node; each node sums its own members."""
        blk, w = wp.tid()
        if status[w] != STATUS_OK:
            return
        wE = w % cab_EA.shape[1]
        wC = w % cab_EAc.shape[1]
        wL = w % cab_L.shape[1]
        ws = w % minv_self.shape[1]
        wF = w % ext_force.shape[1]
        na = mass_blocks[blk, 0]
        nb = mass_blocks[blk, 1]
        fa = node_force(node_start, node_member, node_other, node_dref, cab_EA, cab_EAc, cab_L, ext_force, u, na, w,
                        wE, wC, wL, wF)
        if nb < 0:
            acc = fa * minv_self[na, ws]
            a[na, w] = acc
            v_out[na, w] = v[na, w] + acc * kick
        else:
            fb = node_force(node_start, node_member, node_other, node_dref, cab_EA, cab_EAc, cab_L, ext_force, u, nb,
                            w, wE, wC, wL, wF)
            wx = w % minv_cross.shape[1]
            acc = fa * minv_self[na, ws] + fb * minv_cross[na, wx]
            a[na, w] = acc
            v_out[na, w] = v[na, w] + acc * kick
            acc = fb * minv_self[nb, ws] + fa * minv_cross[nb, wx]
            a[nb, w] = acc
            v_out[nb, w] = v[nb, w] + acc * kick

    @wp.kernel(enable_backward=False, module="unique")
    def kick_drift(
        # Model:
        status: wp.array(dtype=int),
        # Data in:
        a: wp.array2d(dtype=vec), kick: real, drift: real,
        # Data out:
        u: wp.array2d(dtype=vec), v: wp.array2d(dtype=vec), u_prev: wp.array2d(dtype=vec),
    ):
        """v += kick * a; u_prev = u; u += drift * v."""
        n, w = wp.tid()
        if status[w] != STATUS_OK:
            return
        vn = v[n, w] + a[n, w] * kick
        v[n, w] = vn
        un = u[n, w]
        u_prev[n, w] = un
        u[n, w] = un + vn * drift

    @wp.kernel(enable_backward=False, module="unique")
    def rk_stage(
        # Model:
        status: wp.array(dtype=int),
        # Data in:
        u0: wp.array2d(dtype=vec), v0: wp.array2d(dtype=vec), vs: wp.array2d(dtype=vec), a: wp.array2d(dtype=vec),
        c_acc: real, c_next: real, first: int,
        # Data out:
        acc_u: wp.array2d(dtype=vec), acc_v: wp.array2d(dtype=vec), u_next: wp.array2d(dtype=vec), v_next: wp.array2d(dtype=vec),
    ):
        """One RK4 stage: acc += c_acc * (vs, a); next = y0 + c_next * (vs, a) (or y0 + c_next*acc at the end)."""
        n, w = wp.tid()
        if status[w] != STATUS_OK:
            return
        du = vs[n, w]
        dv = a[n, w]
        au = du * c_acc
        av = dv * c_acc
        if first != 1:  # 1: first stage starts the sum
            au = au + acc_u[n, w]
            av = av + acc_v[n, w]
        acc_u[n, w] = au
        acc_v[n, w] = av
        if first == 2:  # final combination
            u_next[n, w] = u0[n, w] + au * c_next
            v_next[n, w] = v0[n, w] + av * c_next
        else:
            u_next[n, w] = u0[n, w] + du * c_next
            v_next[n, w] = v0[n, w] + dv * c_next

    return {"gather_accel": gather_accel, "kick_drift": kick_drift, "rk_stage": rk_stage}


@functools.cache
def _record_kernels(real):
    vec = wp.types.vector(3, real)

    @wp.kernel(enable_backward=False, module="unique")
    def record_strain(
        # Model:
        level_nodes: wp.array2d(dtype=int), h0: wp.array(dtype=real), static_dz: wp.array2d(dtype=real), every: int,
        # Data in:
        u: wp.array2d(dtype=vec), step: wp.array(dtype=int),
        # Data out:
        strain: wp.array3d(dtype=real),
    ):
        """strain[slot, j, w] = (h - hs)/h of prism j when step % every == 0, hs = h0 + static_dz the
        prism's height in the column's initial equilibrium (h0 without a preload)."""
        j, w = wp.tid()
        slot = output_slot(step[0], every, strain.shape[0])
        if slot < 0:
            return
        zb = real(0.0)
        zt = real(0.0)
        for c in range(3):
            zb += u[level_nodes[j, c], w][2]
            zt += u[level_nodes[j + 1, c], w][2]
        h = h0[j] + (zt - zb) / real(3.0)
        strain[slot, j, w] = (h - (h0[j] + pget(static_dz, j, w))) / h

    @wp.kernel(enable_backward=False, module="unique")
    def record_energy(
        # Model:
        cab_i: wp.array(dtype=int), cab_j: wp.array(dtype=int), cab_dref: wp.array(dtype=vec),
        cab_EA: wp.array2d(dtype=real), cab_EAc: wp.array2d(dtype=real), cab_L: wp.array2d(dtype=real),
        partner: wp.array(dtype=int), m_self: wp.array2d(dtype=real), m_cross: wp.array2d(dtype=real),
        ext_force: wp.array2d(dtype=vec), every: int,
        # Data in:
        u: wp.array2d(dtype=vec), v: wp.array2d(dtype=vec), step: wp.array(dtype=int),
        # Data out:
        kinetic: wp.array2d(dtype=real), elastic: wp.array2d(dtype=real),
    ):
        """Kinetic 1/2 v^T M v and elastic sum 1/2 k (s - L)^2 per column when step % every == 0; the
        elastic energy includes the dead load's potential -f_ext . u (0 without a preload), so their sum
        is conserved."""
        w = wp.tid()
        slot = output_slot(step[0], every, kinetic.shape[0])
        if slot < 0:
            return
        ke = real(0.0)
        work = real(0.0)  # of the dead load: f_ext . u
        for n in range(u.shape[0]):
            vn = v[n, w]
            ke += pget(m_self, n, w) * wp.dot(vn, vn)
            work += wp.dot(ext_force[n, w % ext_force.shape[1]], u[n, w])
            p = partner[n]
            if p >= 0:
                ke += pget(m_cross, n, w) * wp.dot(vn, v[p, w])
        ee = real(0.0)
        for c in range(cab_i.shape[0]):
            b = member_vec(cab_dref, cab_i, cab_j, u, c, w)
            ee += cable_energy2(b, pget(cab_EA, c, w), pget(cab_EAc, c, w), pget(cab_L, c, w))
        kinetic[slot, w] = real(0.5) * ke
        elastic[slot, w] = real(0.5) * ee - work

    @wp.kernel(enable_backward=False, module="unique")
    def record_energy_parts(
        # Model:
        cab_i: wp.array(dtype=int), cab_j: wp.array(dtype=int), cab_dref: wp.array(dtype=vec),
        cab_EA: wp.array2d(dtype=real), cab_EAc: wp.array2d(dtype=real), cab_L: wp.array2d(dtype=real),
        partner: wp.array(dtype=int), m_self: wp.array2d(dtype=real), m_cross: wp.array2d(dtype=real),
        ext_force: wp.array2d(dtype=vec), every: int, below_node: int, end_node: int,
        # Data in:
        u: wp.array2d(dtype=vec), v: wp.array2d(dtype=vec), step: wp.array(dtype=int),
        # Data out:
        below: wp.array2d(dtype=real), end: wp.array2d(dtype=real),
    ):
        """When step % every == 0, the energy above the reference state (kinetic + elastic - reference
        elastic) of two parts of each column (measure.energy, docs/measurements.md "Energy measures"):
        ``below``, nodes n < below_node and members with an end there (the clamp side of the station
        section), and ``end``, nodes n >= end_node and members with both ends there (the k prisms at the
        impacted end). Node n's kinetic term is record_energy's, less the dead load's work f_ext . u on
        it (the preload's potential, as in record_energy; 0 without). A member's excess is
        k/(2L) dl (dl + 2 (l0 - L)), dl = l - l0 = du.(2 b0 + du)/(l + l0): no cancellation of the
        prestress energy. One thread per column."""
        w = wp.tid()
        slot = output_slot(step[0], every, below.shape[0])
        if slot < 0:
            return
        eb = real(0.0)
        et = real(0.0)
        for n in range(u.shape[0]):
            if n >= below_node and n < end_node:
                continue
            vn = v[n, w]
            ke = pget(m_self, n, w) * wp.dot(vn, vn)
            p = partner[n]
            if p >= 0:
                ke += pget(m_cross, n, w) * wp.dot(vn, v[p, w])
            ke -= real(2.0) * wp.dot(ext_force[n, w % ext_force.shape[1]], u[n, w])  # (twice, as ke)
            if n < below_node:
                eb += ke
            if n >= end_node:
                et += ke
        for c in range(cab_i.shape[0]):
            first = wp.min(cab_i[c], cab_j[c])
            if first >= below_node and first < end_node:
                continue
            de = member_excess2(cab_dref[c], u[cab_j[c], w] - u[cab_i[c], w], pget(cab_EA, c, w), pget(cab_EAc, c, w),
                                pget(cab_L, c, w))
            if first < below_node:
                eb += de
            if first >= end_node:
                et += de
        below[slot, w] = real(0.5) * eb
        end[slot, w] = real(0.5) * et

    @wp.kernel(enable_backward=False, module="unique")
    def record_feasibility(
        # Model:
        level_nodes: wp.array2d(dtype=int), h0: wp.array(dtype=real), level_ref: wp.array2d(dtype=vec),
        prism_hand: wp.array(dtype=real), every: int,
        # Data in:
        u: wp.array2d(dtype=vec), status: wp.array(dtype=int), step: wp.array(dtype=int),
        # Data out:
        twist: wp.array2d(dtype=real), twist_max: wp.array2d(dtype=real), twist_min: wp.array2d(dtype=real),
        height_min: wp.array2d(dtype=real), left_slot: wp.array3d(dtype=int),
    ):
        """When step % every == 0: prism j's twist (common.prism_twist, unwrapped against the last
        output's; taken in (0, 2 pi) at step 0) and height ratio h/h0, their running extremes, and the
        first output slot at which each reason of types.FEASIBILITY_FLAGS occurred: twist >= pi (bars
        touch), twist <= pi/3 (cross cables touch), h <= 0 (the prism inverted). An inverted prism's
        twist is not updated (its axis has flipped). One thread per prism and column: no atomics."""
        j, w = wp.tid()
        slot = output_slot(step[0], every, -1)  # running extremes and first slots: no length
        if slot < 0 or status[w] != STATUS_OK:
            return
        near = real(PI)
        if slot > 0:
            near = twist[j, w]
        phi, h = prism_twist(level_nodes, h0, level_ref, prism_hand[j], u, j, w, near)
        feasibility_record(phi, h, h0[j], near, slot, j, w, twist, twist_max, twist_min, height_min, left_slot)

    @wp.kernel(enable_backward=False, module="unique")
    def record_pairs(
        # Model:
        pair_nodes: wp.array2d(dtype=int), pair_dref: wp.array2d(dtype=vec), every: int,
        # Data in:
        u: wp.array2d(dtype=vec), status: wp.array(dtype=int), step: wp.array(dtype=int),
        # Data out:
        pair_distance_min: wp.array2d(dtype=real), cross_side: wp.array2d(dtype=int),
        pair_left_slot: wp.array2d(dtype=int),
    ):
        """When step % every == 0: the distance of pair p's member axes (common.axis_pair), its
        smallest, and the first output slot at which the side of their oriented distance flipped
        while their closest points lay inside both members (one passed through the other) against
        the last output's; a side seen outside the members is forgotten (members may pass around
        each other's ends). One thread per pair and column."""
        p, w = wp.tid()
        slot = output_slot(step[0], every, -1)  # running extremes and first slots: no length
        if slot < 0 or status[w] != STATUS_OK:
            return
        i0 = pair_nodes[p, 0]
        j0 = pair_nodes[p, 2]
        bi = pair_dref[p, 0] + u[pair_nodes[p, 1], w] - u[i0, w]
        bj = pair_dref[p, 1] + u[pair_nodes[p, 3], w] - u[j0, w]
        w0 = pair_dref[p, 2] + u[j0, w] - u[i0, w]
        dist, side = axis_pair(bi, bj, w0)
        if slot == 0:
            pair_distance_min[p, w] = dist
            pair_left_slot[p, w] = -1
        else:
            if dist < pair_distance_min[p, w]:
                pair_distance_min[p, w] = dist
            last = cross_side[p, w]
            if side != 0 and last != 0 and side != last and pair_left_slot[p, w] < 0:
                pair_left_slot[p, w] = slot
        cross_side[p, w] = side

    return {"record_strain": record_strain, "record_energy": record_energy, "record_energy_parts": record_energy_parts,
            "record_feasibility": record_feasibility, "record_pairs": record_pairs}
