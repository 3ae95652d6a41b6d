"""Bar contact on the staged path (scene ``contact = 'bars'``, issue 32): the bars of a prism keep
their axes at least 2 r apart, a unilateral constraint of RATTLE. Geometry, the pairs and the
layout of the constraint system: :mod:`warp_tensegrity.scene.contact`.

Two per-column kernels (one thread per column) follow the staged step's own projections:

* :func:`contact_positions`, after the position projection. A detection pass computes each pair's
  signed axis distance D at the projected positions. With every D >= 2 r it writes nothing but the
  column's smallest D: a run that never touches executes the same floating-point operations as one
  without contact. Otherwise the thread redoes the step from its start (positions, the velocity
  kept by :meth:`ContactStep.save_start`, accelerations) as RATTLE substeps that end at each impact:
  the first crossing of D = 2 r is predicted on the velocity Verlet path x + s v + s^2/2 a (regula
  falsi) and landed on by a substep, shortened while it overshoots; there the impact law acts
  (:func:`rate_solve`): the pairs touching within 1e-6 of a step of each other (one impact, so a
  symmetric prism stays symmetric) leave with -e times their approaching normal velocity, jointly
  with the members' G v = 0, an impulse along M^-1 J^T. Each substep is a whole RATTLE step (kick,
  drift, projection onto the members and onto D = 2 r for pairs pressed together, forces, kick,
  velocity projection), so the energy error of an elastic impact is the integrator's own O(dt^2):
  the step's impact is resolved at its instant, not by a projection after the fact. The step ends
  with v less dt/2 a(u), which the staged force gather adds back.
* :func:`contact_velocities`, after the velocity projection: a pair that still touches after the
  step (lasting contact, pressed together) may not approach; a negative normal velocity becomes 0
  with the members' G v = 0 (RATTLE's velocity projection with the pair as an equality). Nothing
  runs unless a pair touched in the position stage.

The constraint system (members and bar pairs) is factored as a banded Cholesky of J M^-1 J^T with
each pair's row right after its later bar (inactive pairs: identity rows). Active sets: a pair
whose multiplier would pull the bars together leaves (the solve restarts without it), a pair the
correction pushes below 2 r joins.

Cost: the detection pass (3 signed distances per prism and step) and a copy of v per step until
a pair touches; a contact step then costs a few in-thread RATTLE substeps with the wider band
(half-bandwidth 11 for flexible bases, 14 for rigid ones, against 3 and 6 of the members alone).
"""

import functools
from typing import NamedTuple

import numpy as np
import warp as wp

from ... import types
from ...scene.contact import contact_arrays
from ...scene.coupling import mass_entries
from ..common import STATUS_CONSTRAINT, STATUS_NONFINITE, STATUS_OK, array_type, bar_row, force_columns, \
    make_band_funcs, member_vec, newton_stop, node_force, projection_status, set_failure

wp.set_module_options({"enable_backward": False})

MODEL_PART = ("con_i", "con_j", "con_dref", "con_L", "con_active", "partner", "minv_self", "minv_cross", "cab_EA",
              "cab_EAc", "cab_L", "node_start", "node_member", "node_other", "node_dref", "ext_force")
"""The :data:`~warp_tensegrity.types.MODEL_FIELDS` the contact kernels read (besides CONTACT_FIELDS)."""
MAX_PASSES = 8
"""Most active-set passes of one contact solve."""
SIMULTANEOUS = 1e-6
"""Impacts within this fraction of the step are one impact (a symmetric prism's three pairs touch
together; round-off would otherwise order them, and sequential impacts break the symmetry)."""
LANDING = 1e-7
"""A landing on a contact is accepted within this fraction of 2 r (5e-11 m for r = 0.25 mm): the
impact then acts there (closer costs more secant substeps and changes nothing measurable)."""
MAX_EVENTS = 16
"""Most impact instants of one contact step (then the rest of the step is one substep)."""
SIN_MIN = 0.1
"""Pairs whose axes are closer to parallel (sin of their angle below this) have no contact geometry."""
TOUCH = 1e-6
"""Pairs within 2 r (1 + TOUCH) count as touching in the velocity stage."""


class ContactKernels(NamedTuple):
    """The contact step's structs and kernels."""

    ContactModel: type
    ContactState: type
    vec: type
    contact_positions: wp.Kernel
    contact_velocities: wp.Kernel
    pair_geometry: wp.Function


@functools.cache
def make_contact_kernels(real, bandwidth: int):
    """The contact kernels for scalar type ``real`` and the contact Gram half-bandwidth ``bandwidth``."""
    vec = wp.types.vector(3, real)
    decl = {f.name: f for f in types.MODEL_FIELDS + types.CONTACT_FIELDS}
    ContactModel = wp.struct(type("ContactModel", (), {"__module__": __name__, "__annotations__": {
        name: array_type(decl[name].dtype, decl[name].ndim, real)
        for name in MODEL_PART + tuple(f.name for f in types.CONTACT_FIELDS)}}))
    ContactState = wp.struct(type("ContactState", (), {"__module__": __name__, "__annotations__": {
        f.name: array_type(f.dtype, f.ndim, real) for f in types.CONTACT_STATE_FIELDS}}))
    bf = make_band_funcs(real, bandwidth)
    rowvec, factor_store_row, band_solve = bf.rowvec, bf.factor_store_row, bf.band_solve
    LD = int(bandwidth) + 1
    NPASS = int(MAX_PASSES)
    NEVENT = int(MAX_EVENTS)
    SIM = float(SIMULTANEOUS)
    LAND = float(LANDING)
    ONE_TOUCH = float(1.0 + TOUCH)
    SIN2_MIN = float(SIN_MIN**2)

    @wp.func
    def axis_parts(ei: vec, ej: vec, wv: vec, sign: real):
        """(D, n, s, t) of the axes e_i, e_j whose first nodes are wv apart (P_j - P_i): the signed
        distance D [m], the unit normal n = dD/dc_j, the closest points' parameters s, t (s = -1
        for axes within asin(0.1) of parallel, where D is undefined)."""
        c = wp.cross(ei, ej)
        nrm = c * (sign / wp.length(c))
        A = wp.dot(ei, ei)
        Bd = wp.dot(ei, ej)
        C = wp.dot(ej, ej)
        wi = wp.dot(ei, wv)
        wj = wp.dot(ej, wv)
        den = A * C - Bd * Bd
        s = (C * wi - Bd * wj) / den
        if den < real(SIN2_MIN) * A * C:  # axes within asin(0.1) of parallel: D flips sign there, no contact
            s = real(-1.0)
        return wp.dot(nrm, wv), nrm, s, (Bd * wi - A * wj) / den

    @wp.func
    def pair_geometry(m: ContactModel, st: ContactState, u: wp.array2d(dtype=vec), p: int, w: int):
        """(D, n, s, t) of pair p at u (:func:`axis_parts`), D signed by the pair's side."""
        bi = m.pair_bi[p]
        bj = m.pair_bj[p]
        ei = member_vec(m.con_dref, m.con_i, m.con_j, u, bi, w)
        ej = member_vec(m.con_dref, m.con_i, m.con_j, u, bj, w)
        wv = m.pair_wref[p] + u[m.con_i[bj], w] - u[m.con_i[bi], w]
        return axis_parts(ei, ej, wv, st.pair_side[p, w])

    @wp.func
    def inside(s: real, t: real):
        """Both closest points inside their bars (the axes' distance is the bars'), axes not near
        parallel: where contact is defined."""
        return s >= real(0.0) and s <= real(1.0) and t >= real(0.0) and t <= real(1.0)

    @wp.func
    def slot_node(m: ContactModel, k: int, slot: int):
        idx = m.row_index[k]
        b = idx
        if m.row_kind[k] != 0:
            b = m.pair_bi[idx]
            if slot >= 2:
                b = m.pair_bj[idx]
        n = m.con_i[b]
        if slot % 2 == 1:
            n = m.con_j[b]
        return n

    @wp.func
    def row_grad(m: ContactModel, st: ContactState, ug: wp.array2d(dtype=vec), k: int, slot: int, w: int):
        """Row k's gradient on its slot: a member's -b, +b at ug, or a pair's stored normal times
        -(1 - s), -s, 1 - t, t."""
        idx = m.row_index[k]
        g = vec()
        if m.row_kind[k] == 0:
            g = member_vec(m.con_dref, m.con_i, m.con_j, ug, idx, w)
            if slot == 0:
                g = -g
        else:
            s = st.pair_s[idx, w]
            t = st.pair_t[idx, w]
            c = -s
            if slot == 0:
                c = s - real(1.0)
            elif slot == 2:
                c = real(1.0) - t
            elif slot == 3:
                c = t
            g = st.pair_m[idx, w] * c
        return g

    @wp.func
    def row_active(m: ContactModel, st: ContactState, k: int, w: int, wa: int):
        idx = m.row_index[k]
        on = bool(False)
        if m.row_kind[k] == 0:
            on = m.con_active[idx, wa] > real(0.0)
        else:
            on = st.pair_act[idx, w] == 1
        return on

    @wp.func
    def row_rate(m: ContactModel, st: ContactState, ug: wp.array2d(dtype=vec), y: wp.array2d(dtype=vec), k: int,
                 w: int):
        """(J(ug) y)_k: a member's b . (y_j - y_i), a pair's normal relative velocity."""
        ns = 2
        if m.row_kind[k] != 0:
            ns = 4
        r = real(0.0)
        for slot in range(ns):
            r += wp.dot(row_grad(m, st, ug, k, slot, w), y[slot_node(m, k, slot), w])
        return r

    @wp.func
    def assemble_factor(m: ContactModel, st: ContactState, ug: wp.array2d(dtype=vec), w: int):
        """Factor J M^-1 J^T of the members and the active pairs at ug into cband (inactive rows:
        identity). False on a non-positive pivot."""
        wa = w % m.con_active.shape[1]
        ws = w % m.minv_self.shape[1]
        wx = w % m.minv_cross.shape[1]
        ok = bool(True)
        for k in range(m.row_kind.shape[0]):
            r = rowvec()
            if row_active(m, st, k, w, wa):
                for t in range(m.acpl_start[k], m.acpl_start[k + 1]):
                    l = m.acpl_l[t]
                    if row_active(m, st, l, w, wa):
                        a = m.acpl_a[t]
                        mi = m.minv_self[a, ws]
                        if m.acpl_cross[t] != 0:
                            mi = m.minv_cross[a, wx]
                        val = mi * wp.dot(row_grad(m, st, ug, k, m.acpl_sk[t], w), row_grad(m, st, ug, l, m.acpl_sl[t], w))
                        for e in range(LD):
                            if k - l == e:
                                r[e] += val
            else:
                r[0] = real(1.0)
            if not factor_store_row(st.cband, r, k, w):
                ok = False
        return ok

    @wp.func
    def apply_impulse(m: ContactModel, st: ContactState, ug: wp.array2d(dtype=vec), y: wp.array2d(dtype=vec), w: int):
        """y -= M^-1 J(ug)^T lam, lam in clam: each node gathers its own rows; a massive bar's two
        free nodes go through cimp, then M^-1 couples them."""
        wa = w % m.con_active.shape[1]
        ws = w % m.minv_self.shape[1]
        wx = w % m.minv_cross.shape[1]
        n_coupled = int(0)
        for n in range(y.shape[0]):
            g = vec()
            for t in range(m.anode_start[n], m.anode_start[n + 1]):
                k = m.anode_row[t]
                if row_active(m, st, k, w, wa):
                    g += row_grad(m, st, ug, k, m.anode_slot[t], w) * st.clam[k, w]
            if m.partner[n] < 0:
                y[n, w] = y[n, w] - g * m.minv_self[n, ws]
            else:
                st.cimp[n, w] = g
                n_coupled += 1
        if n_coupled > 0:
            for n in range(y.shape[0]):
                p = m.partner[n]
                if p >= 0:
                    y[n, w] = y[n, w] - (st.cimp[n, w] * m.minv_self[n, ws] + st.cimp[p, w] * m.minv_cross[n, wx])
    @wp.func
    def accelerations(m: ContactModel, u: wp.array2d(dtype=vec), a: wp.array2d(dtype=vec), w: int):
        """a = M^-1 f(u), as the staged gather_accel computes it."""
        wE, wC, wL, wF, ws, wx = force_columns(m.cab_EA, m.cab_EAc, m.cab_L, m.ext_force, m.minv_self, m.minv_cross, w)
        for n in range(u.shape[0]):
            f = node_force(m.node_start, m.node_member, m.node_other, m.node_dref, m.cab_EA, m.cab_EAc, m.cab_L,
                           m.ext_force, u, n, w, wE, wC, wL, wF)
            acc = f * m.minv_self[n, ws]
            p = m.partner[n]
            if p >= 0:
                fp = node_force(m.node_start, m.node_member, m.node_other, m.node_dref, m.cab_EA, m.cab_EAc, m.cab_L,
                                m.ext_force, u, p, w, wE, wC, wL, wF)
                acc = acc + fp * m.minv_cross[n, wx]
            a[n, w] = acc

    @wp.func
    def take_row(m: ContactModel, st: ContactState, x: wp.array2d(dtype=vec), p: int, w: int):
        """Pair p becomes a row of the next solve, its gradient taken at x."""
        D, nrm, s, t = pair_geometry(m, st, x, p, w)
        st.pair_m[p, w] = nrm
        st.pair_s[p, w] = s
        st.pair_t[p, w] = t
        st.pair_act[p, w] = 1
        st.pair_acc[p, w] = real(0.0)

    @wp.func
    def rate_solve(m: ContactModel, st: ContactState, x: wp.array2d(dtype=vec), v: wp.array2d(dtype=vec),
                   restitution: real, w: int):
        """The impact law at x: v -= M^-1 J(x)^T lam with the members' rates G(x) v = 0 and each row
        pair's normal relative velocity (pair_vn, < 0) turned into -e pair_vn (no pair rows: the
        velocity projection). A pair the impulse would pull leaves the rows (act -1) and the solve
        restarts from cv0. False on a singular system."""
        nn = v.shape[0]
        wa = w % m.con_active.shape[1]
        nr = m.row_kind.shape[0]
        npr = m.pair_bi.shape[0]
        for n in range(nn):
            st.cv0[n, w] = v[n, w]
        ok = bool(True)
        passes = int(0)
        more = bool(True)
        while more and passes < NPASS:
            more = bool(False)
            if not assemble_factor(m, st, x, w):
                ok = False
                break
            for k in range(nr):
                r = real(0.0)
                if row_active(m, st, k, w, wa):
                    r = row_rate(m, st, x, v, k, w)
                    if m.row_kind[k] != 0:
                        r += restitution * st.pair_vn[m.row_index[k], w]
                st.clam[k, w] = r
            band_solve(st.cband, st.clam, nr, w)
            apply_impulse(m, st, x, v, w)
            for p in range(npr):
                if st.pair_act[p, w] == 1 and st.clam[m.pair_row[p], w] > real(0.0):
                    st.pair_act[p, w] = -1
                    more = True
            if more:
                for n in range(nn):
                    v[n, w] = st.cv0[n, w]
            passes += 1
        return ok

    @wp.func
    def newton(m: ContactModel, st: ContactState, ug: wp.array2d(dtype=vec), u: wp.array2d(dtype=vec), gap: real,
               tol: real, max_iter: int, w: int):
        """Simplified Newton onto the members' lengths and the row pairs' D = gap along
        M^-1 J^T (members at ug, pairs at their stored gradients; cband holds the factor); the pairs'
        multipliers summed into pair_acc. Returns (largest relative error, the members' own)."""
        wa = w % m.con_active.shape[1]
        nr = m.row_kind.shape[0]
        npr = m.pair_bi.shape[0]
        err = real(0.0)
        errb = real(0.0)
        prev = real(0.0)
        it = int(0)
        while True:
            prev = err
            err = real(0.0)
            errb = real(0.0)
            for k in range(nr):
                r = real(0.0)
                if row_active(m, st, k, w, wa):
                    idx = m.row_index[k]
                    if m.row_kind[k] == 0:
                        r, e, err = bar_row(m.con_dref, m.con_i, m.con_j, m.con_L, u, idx, w, err)
                        if not (e <= errb):
                            errb = e
                    else:
                        D, nrm, s, t = pair_geometry(m, st, u, idx, w)
                        r = D - gap
                        ec = wp.abs(r) / gap
                        if not (ec <= err):
                            err = ec
                st.clam[k, w] = r
            if newton_stop(err, prev, tol, it, max_iter):
                break
            band_solve(st.cband, st.clam, nr, w)
            for p in range(npr):
                if st.pair_act[p, w] == 1:
                    st.pair_acc[p, w] = st.pair_acc[p, w] + st.clam[m.pair_row[p], w]
            apply_impulse(m, st, ug, u, w)
            it += 1
        return err, errb

    @wp.func
    def project_positions(m: ContactModel, st: ContactState, x0: wp.array2d(dtype=vec), u: wp.array2d(dtype=vec),
                          gap: real, tol: real, max_iter: int, w: int):
        """u onto the members' lengths and onto D >= gap for every pair (the pairs below gap as
        equalities, an active set) but those being landed on (pair_state 3), along M^-1 J(x0)^T;
        cv0 keeps the start. Returns (largest relative error, the members' own, ok)."""
        npr = m.pair_bi.shape[0]
        nn = u.shape[0]
        for n in range(nn):
            st.cv0[n, w] = u[n, w]
        for p in range(npr):
            st.pair_act[p, w] = 0
        err = real(0.0)
        errb = real(0.0)
        ok = bool(True)
        passes = int(0)
        more = bool(True)
        while more and passes < NPASS:
            thr = gap
            if passes > 0:
                thr = gap * (real(1.0) - tol)
            for p in range(npr):
                if st.pair_act[p, w] == 0 and st.pair_state[p, w] != 3:
                    D, nrm, s, t = pair_geometry(m, st, u, p, w)
                    if inside(s, t) and D < thr:
                        take_row(m, st, x0, p, w)
            if not assemble_factor(m, st, x0, w):
                ok = False
                break
            err, errb = newton(m, st, x0, u, gap, tol, max_iter, w)
            more = bool(False)
            dropped = int(0)
            for p in range(npr):
                if st.pair_act[p, w] == 1 and st.pair_acc[p, w] > real(0.0):
                    st.pair_act[p, w] = -1  # adhesive: out of this projection
                    dropped += 1
            if dropped > 0:
                more = True
                for n in range(nn):
                    u[n, w] = st.cv0[n, w]
                for p in range(npr):
                    st.pair_acc[p, w] = real(0.0)
            else:
                for p in range(npr):
                    if st.pair_act[p, w] == 0 and st.pair_state[p, w] != 3:
                        D, nrm, s, t = pair_geometry(m, st, u, p, w)
                        if inside(s, t) and D < gap * (real(1.0) - tol):
                            more = True
            passes += 1
        return err, errb, ok

    @wp.func
    def substep(m: ContactModel, st: ContactState, h: real, u: wp.array2d(dtype=vec), v: wp.array2d(dtype=vec),
                a: wp.array2d(dtype=vec), gap: real, tol: real, max_iter: int, w: int):
        """One RATTLE step of length h of column w in this thread, (u, v, a) in place: kick, drift,
        project positions (members and pairs below gap) with v -= du/h, forces, kick, project
        velocities onto the members. Returns (errors of :func:`project_positions`, ok)."""
        nn = u.shape[0]
        half = real(0.5) * h
        st.contact_substeps[w] = st.contact_substeps[w] + 1
        for n in range(nn):
            st.cu0[n, w] = u[n, w]
            vn = v[n, w] + a[n, w] * half
            v[n, w] = vn
            u[n, w] = u[n, w] + vn * h
        err, errb, ok = project_positions(m, st, st.cu0, u, gap, tol, max_iter, w)
        inv_h = real(1.0) / h
        for n in range(nn):
            v[n, w] = v[n, w] + (u[n, w] - st.cv0[n, w]) * inv_h  # RATTLE: v = (u_end - u_start)/h
        accelerations(m, u, a, w)
        for n in range(nn):
            v[n, w] = v[n, w] + a[n, w] * half
        npr = m.pair_bi.shape[0]
        for p in range(npr):
            st.pair_act[p, w] = 0
        if ok:
            ok = rate_solve(m, st, u, v, real(0.0), w)  # no pair rows: v onto G(u) v = 0
        return err, errb, ok

    @wp.kernel(enable_backward=False, module="unique")
    def contact_positions(
        m: ContactModel, st: ContactState, gap: real, restitution: real, tol: real, max_iter: int, fail_tol: real,
        dt: real, kick: real,
        # Data in:
        ug: wp.array2d(dtype=vec), step: wp.array(dtype=int),
        # Data out:
        u: wp.array2d(dtype=vec), v: wp.array2d(dtype=vec), a: wp.array2d(dtype=vec), bar_err: wp.array(dtype=real),
        status: wp.array(dtype=int), fail_step: wp.array(dtype=int),
    ):
        """After the staged position projection of the step from (ug, st.vstart, a): if a pair is
        closer than gap = 2 r, redo the step in this thread as RATTLE substeps that end at each
        impact, where the impact law acts (restitution e). Ends with v less kick * a(u), which the
        staged force gather adds back. Records the smallest D."""
        w = wp.tid()
        if status[w] != STATUS_OK:
            return
        npr = m.pair_bi.shape[0]
        nn = u.shape[0]
        dmin = real(1.0e30)
        hit = int(0)
        for p in range(npr):
            D, nrm, s, t = pair_geometry(m, st, u, p, w)
            if inside(s, t) and D < real(0.0):
                # on the other side: through the other bar (the normal kept, on the bars at the step's
                # start: a contact), or around it (past an end of a bar, or through parallel axes,
                # where D is undefined): then the pair's side changes, written only here, and D's sign
                Dg, ng, sg, tg = pair_geometry(m, st, ug, p, w)
                if not (inside(sg, tg) and wp.dot(ng, nrm) > real(0.0)):
                    st.pair_side[p, w] = -st.pair_side[p, w]
                    D = -D
            if inside(s, t):
                dmin = wp.min(dmin, D)
                if D < gap:
                    hit = 1
        if hit == 0:  # below contact: nothing of the state is written (a pair's side aside)
            st.contact_min[w] = wp.min(st.contact_min[w], dmin)
            return
        win = gap * (real(1.0) + real(100.0) * tol)  # pairs this close touch
        sim = real(SIM) * dt  # impacts this close in time are one
        land = real(LAND) * gap  # a landing this close to contact is on it
        # unless a pair touched at the start (lasting contact), the staged step itself is the first
        # trial: its earliest crossing, interpolated linearly in D, is where the first landing aims
        target0 = int(-1)
        guess = dt
        Ds0 = real(0.0)
        touching = int(0)
        for p in range(npr):
            Dg, ng, sg, tg = pair_geometry(m, st, ug, p, w)
            if inside(sg, tg) and Dg <= win:
                touching = 1
        if touching == 0:
            for p in range(npr):
                D1, n1, s1, t1 = pair_geometry(m, st, u, p, w)
                if inside(s1, t1) and D1 < gap:
                    Dg, ng, sg, tg = pair_geometry(m, st, ug, p, w)
                    sp = dt * (Dg - gap) / (Dg - D1)
                    if sp < guess:
                        guess = sp
                        target0 = p
                        Ds0 = Dg
        for n in range(nn):  # the step again from its start (a holds a(ug) still)
            u[n, w] = ug[n, w]
            v[n, w] = st.vstart[n, w]
        rem = dt
        impacts = int(0)
        err = real(0.0)
        errb = real(0.0)
        ok = bool(True)
        passes = int(0)
        while rem > real(0.0) and passes < NEVENT:
            # pairs touching now and approaching: an impact now; pairs apart are watched (pair_state 3:
            # no row of a projection) while a trial substep over the rest of the step shows whether
            # and where they cross 2 r
            n_now = int(0)
            for p in range(npr):
                st.pair_state[p, w] = 0
                D0, n0, s0, t0 = pair_geometry(m, st, u, p, w)
                if inside(s0, t0):
                    if D0 > win:
                        st.pair_state[p, w] = 3
                    else:
                        take_row(m, st, u, p, w)
                        if row_rate(m, st, u, v, m.pair_row[p], w) < real(0.0):
                            n_now += 1
            first = real(0.0)
            if n_now == 0:
                for n in range(nn):
                    st.vsub[n, w] = v[n, w]
                    st.asub[n, w] = a[n, w]
                first = rem
                target = int(-1)
                Ds = real(0.0)
                if passes == 0 and target0 >= 0:  # the staged step was the trial
                    first = guess
                    target = target0
                    Ds = Ds0
                else:
                    e1, e2, ok1 = substep(m, st, rem, u, v, a, gap, tol, max_iter, w)
                    err = wp.max(err, e1)
                    errb = wp.max(errb, e2)
                    if not ok1:
                        ok = False
                        break
                    for p in range(npr):  # the earliest crossing, interpolated linearly in D
                        if st.pair_state[p, w] == 3:
                            D1, n1, s1, t1 = pair_geometry(m, st, u, p, w)
                            if inside(s1, t1) and D1 < gap:
                                D0, n0, s0, t0 = pair_geometry(m, st, st.cu0, p, w)
                                sp = rem * (D0 - gap) / (D0 - D1)
                                if sp < first:
                                    first = sp
                                    target = p
                                    Ds = D0
                    if target < 0:  # no crossing: the trial is the rest of the step
                        rem = real(0.0)
                        break
                    for n in range(nn):  # back to the start of the trial
                        u[n, w] = st.cu0[n, w]
                        v[n, w] = st.vsub[n, w]
                        a[n, w] = st.asub[n, w]
                if first <= sim:
                    first = real(0.0)
                if first > real(0.0):  # land on the crossing: substeps, secant in the target's D
                    attempt = int(0)
                    while True:
                        e1, e2, ok1 = substep(m, st, first, u, v, a, gap, tol, max_iter, w)
                        err = wp.max(err, e1)
                        errb = wp.max(errb, e2)
                        Dt, nt, st_, tt = pair_geometry(m, st, u, target, w)
                        if wp.abs(Dt - gap) <= land or attempt >= 4 or not ok1:
                            break
                        for n in range(nn):
                            u[n, w] = st.cu0[n, w]
                            v[n, w] = st.vsub[n, w]
                            a[n, w] = st.asub[n, w]
                        first = first * (Ds - gap) / (Ds - Dt)
                        attempt += 1
                    if not ok1:
                        ok = False
                        break
                rem = rem - first
            for p in range(npr):
                st.pair_state[p, w] = 0
            n_s = int(0)
            for p in range(npr):  # the pairs that touch within sim of now take part in the impact
                st.pair_act[p, w] = 0
                D, nrm, s, t = pair_geometry(m, st, u, p, w)
                if inside(s, t) and D <= gap * real(1.001):
                    take_row(m, st, u, p, w)
                    rate = row_rate(m, st, u, v, m.pair_row[p], w)
                    if rate < real(0.0) and D <= win + land - rate * sim:
                        st.pair_vn[p, w] = rate
                        n_s += 1
                    else:
                        st.pair_act[p, w] = 0
            if n_s > 0:
                for p in range(npr):
                    if st.pair_act[p, w] == 1:
                        impacts += 1
                if not rate_solve(m, st, u, v, restitution, w):
                    ok = False
                    break
            passes += 1
        if ok and rem > real(0.0):  # out of passes: the rest in one substep
            e1, e2, ok1 = substep(m, st, rem, u, v, a, gap, tol, max_iter, w)
            err = wp.max(err, e1)
            errb = wp.max(errb, e2)
            ok = ok1
        if not ok:
            set_failure(status, fail_step, w, STATUS_CONSTRAINT, step[0] + 1)
            return
        for n in range(nn):
            v[n, w] = v[n, w] - a[n, w] * kick
        dmin = real(1.0e30)
        for p in range(npr):
            D, nrm, s, t = pair_geometry(m, st, u, p, w)
            on = int(0)
            if inside(s, t):
                dmin = wp.min(dmin, D)
                if D <= gap * real(ONE_TOUCH):
                    on = 1
            st.pair_state[p, w] = on  # touching: the velocity stage looks at it
        st.contact_min[w] = wp.min(st.contact_min[w], dmin)
        st.contact_impacts[w] = st.contact_impacts[w] + impacts
        if st.contact_first[w] < 0:
            st.contact_first[w] = step[0] + 1
        code = projection_status(err, fail_tol)
        if code != STATUS_OK:
            set_failure(status, fail_step, w, code, step[0] + 1)
        if errb > bar_err[w]:
            bar_err[w] = errb

    @wp.kernel(enable_backward=False, module="unique")
    def contact_velocities(
        m: ContactModel, st: ContactState, gap: real,
        # Data in:
        u: wp.array2d(dtype=vec), step: wp.array(dtype=int),
        # Data out:
        v: wp.array2d(dtype=vec), status: wp.array(dtype=int), fail_step: wp.array(dtype=int),
    ):
        """After the velocity projection: a pair touching after the position stage (lasting contact)
        may not approach: its normal relative velocity, if negative, becomes 0, jointly with the
        members' G v = 0 (RATTLE's velocity projection with the pair as an equality)."""
        w = wp.tid()
        if status[w] != STATUS_OK:
            return
        npr = m.pair_bi.shape[0]
        on = int(0)
        for p in range(npr):
            if st.pair_state[p, w] != 0:
                on += 1
        if on == 0:
            return
        n_s = int(0)
        for p in range(npr):
            st.pair_act[p, w] = 0
            if st.pair_state[p, w] != 0:
                D, nrm, s, t = pair_geometry(m, st, u, p, w)
                if inside(s, t) and D <= gap * real(ONE_TOUCH):
                    take_row(m, st, u, p, w)
                    rate = row_rate(m, st, u, v, m.pair_row[p], w)
                    if rate < real(0.0):
                        st.pair_vn[p, w] = rate
                        n_s += 1
                    else:
                        st.pair_act[p, w] = 0
                else:
                    st.pair_state[p, w] = 0  # apart again
        if n_s == 0:
            return
        if not rate_solve(m, st, u, v, real(0.0), w):
            set_failure(status, fail_step, w, STATUS_CONSTRAINT, step[0] + 1)
            return
        for n in range(v.shape[0]):
            vn = v[n, w]
            if not (wp.isfinite(vn[0]) and wp.isfinite(vn[1]) and wp.isfinite(vn[2])):
                set_failure(status, fail_step, w, STATUS_NONFINITE, step[0] + 1)
                return

    return ContactKernels(ContactModel=ContactModel, ContactState=ContactState, vec=vec,
                          contact_positions=contact_positions, contact_velocities=contact_velocities,
                          pair_geometry=pair_geometry)


class ContactStep:
    """The contact system's arrays (:data:`~warp_tensegrity.types.CONTACT_FIELDS`,
    :data:`~warp_tensegrity.types.CONTACT_STATE_FIELDS`) and launches for one model on one device."""

    def __init__(self, model, batch, device, block_dim: int):
        real = wp.float64 if model.precision == "fp64" else wp.float32
        npr_real = np.float64 if model.precision == "fp64" else np.float32
        self.real, self.device, self.block_dim = real, device, block_dim
        host = contact_arrays(batch, mass_entries(batch)[0])
        self.bandwidth = int(host.pop("bandwidth"))
        k = self.kernels = make_contact_kernels(real, self.bandwidth)
        self.gap = float(batch.contact_gap)
        self.restitution = float(batch.restitution)
        self.cm = k.ContactModel()
        for name in MODEL_PART:
            setattr(self.cm, name, getattr(model, name))
        for f in types.CONTACT_FIELDS:
            a = np.ascontiguousarray(host[f.name], dtype=np.int32 if f.dtype == "int32" else npr_real)
            setattr(self.cm, f.name, wp.array(a, dtype=array_type(f.dtype, f.ndim, real).dtype, device=device))
        B, n, npr = model.n_columns, model.n_nodes, len(host["pair_bi"])
        R = len(host["row_kind"])
        sizes = {"R": R, "cbw+1": self.bandwidth + 1, "B": B, "n": n, "npr": npr}
        self.cs = k.ContactState()
        for f in types.CONTACT_STATE_FIELDS:
            shape = tuple(sizes[d.strip()] for d in f.shape.strip("()").split(",") if d.strip())
            dtype = array_type(f.dtype, f.ndim, real).dtype
            if f.name == "contact_min":
                arr = wp.full(shape, np.inf, dtype=dtype, device=device)
            elif f.name == "pair_side":
                arr = wp.array(np.repeat(host["pair_sign"][:, None], B, axis=1).astype(npr_real), dtype=dtype,
                               device=device)
            elif f.name == "contact_first":
                arr = wp.full(shape, -1, dtype=dtype, device=device)
            else:
                arr = wp.zeros(shape, dtype=dtype, device=device)
            setattr(self.cs, f.name, arr)
        self.n_columns = B

    def load(self):
        for kern in (self.kernels.contact_positions, self.kernels.contact_velocities):
            kern.module.load(self.device, self.block_dim)

    def save_start(self, data):
        """Keep the velocity at the start of the step (a contact step is redone from it)."""
        wp.copy(self.cs.vstart, data.v)

    def positions(self, data, settings, ug, dt: float):
        """After the staged position projection of a step of ``dt`` [s] from the positions ``ug``."""
        r = self.real
        wp.launch(self.kernels.contact_positions, dim=self.n_columns, device=self.device, block_dim=self.block_dim,
                  inputs=[self.cm, self.cs, r(self.gap), r(self.restitution), r(settings.tolerance),
                          int(settings.max_projection_iters), r(settings.failure_bar_error), r(dt), r(0.5 * dt), ug,
                          data.step, data.u, data.v, data.a, data.bar_err, data.status, data.fail_step])

    def velocities(self, data):
        """After the staged velocity projection."""
        r = self.real
        wp.launch(self.kernels.contact_velocities, dim=self.n_columns, device=self.device, block_dim=self.block_dim,
                  inputs=[self.cm, self.cs, r(self.gap), data.u, data.step, data.v, data.status, data.fail_step])

    def summary(self) -> dict:
        """Per column: the smallest signed axis distance of any pair over the run [m] (inf if none had
        its closest points inside both bars), the impacts, the step of the first contact (-1: none),
        the in-thread RATTLE substeps taken (the contact steps' cost); and the contact distance
        2 r [m], the restitution and the contact system's half-bandwidth."""
        return {"min_distance": self.cs.contact_min.numpy().astype(np.float64),
                "impacts": self.cs.contact_impacts.numpy().astype(np.int64),
                "first_step": self.cs.contact_first.numpy().astype(np.int64),
                "substeps": self.cs.contact_substeps.numpy().astype(np.int64),
                "gap": self.gap, "restitution": self.restitution, "bandwidth": self.bandwidth}
