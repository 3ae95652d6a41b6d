"""``@wp.func`` bodies shared by the staged and the fused step, each written once.

The functions are generic over precision (``typing.Any``: Warp specialises them for the fp32 or
fp64 arrays a kernel passes). Node state and multipliers are 2-D arrays read as ``u[n, c]``,
``lam[k, c]``: the staged kernels pass the batch arrays ``(n, B)`` with c = the column w; the
fused kernel passes its column's own rows ``(n, NQ)`` with c = the state slot (U, V, ...), and
its multipliers ``(rows, 1)`` with c = 0. (Overloading one function on the array's ndim instead
resolved to the wrong overload depending on compile order: do not.)
"""

import functools
import math
from typing import Any, NamedTuple

import warp as wp

wp.set_module_options({"enable_backward": False})

STATUS_OK = wp.constant(0)
STATUS_NONFINITE = wp.constant(1)
STATUS_CONSTRAINT = wp.constant(2)
# angles as fp64 constants, cast to the run's precision where used (Warp folds arithmetic on
# literals, e.g. 2.0 * math.pi, in fp32: 1.7e-7 off in fp64)
PI = wp.constant(wp.float64(math.pi))
TWO_PI = wp.constant(wp.float64(2.0 * math.pi))
THIRD_PI = wp.constant(wp.float64(math.pi / 3.0))

# slots of a node's row in the fused step (the values of types.Slot; not imported, to keep the
# import chains short: tests/test_layout.py, test_parallel_solve.py checks they agree)
NQ = 4
U, V, P, I = (wp.constant(i) for i in range(NQ))


def array_type(dtype: str, ndim: int, real):
    """The Warp array type of a declared device array (``types.Field``: dtype "int32", "real" or
    "vec3", ``real`` the run's scalar type)."""
    scalar = {"int32": wp.int32, "real": real, "vec3": wp.types.vector(3, real)}[dtype]
    return wp.array(dtype=scalar, ndim=ndim)


@wp.func
def pget(p: wp.array2d(dtype=Any), k: int, w: int):
    """Per-column parameter ``p[k, w % Bp]`` (Bp = 1: shared by all columns)."""
    return p[k, w % p.shape[1]]


@wp.func
def member_vec(dref: wp.array(dtype=Any), ni: wp.array(dtype=int), nj: wp.array(dtype=int),
               u: wp.array2d(dtype=Any), k: int, c: int):
    """Member k's vector x_j - x_i [m] at the displacement ``u[:, c]``."""
    return dref[k] + u[nj[k], c] - u[ni[k], c]


@wp.func
def cable_force(b: Any, EA: Any, EAc: Any, L: Any):
    """Force [N] on the member's first node (toward the second) for the bilinear axial law:
    tension k/L (s - L) along b/s, k = EA in tension, EA_c in compression; one division."""
    s = wp.length(b)
    stretch = s - L
    k = EA
    if stretch < type(L)(0.0):
        k = EAc
    return b * (k * stretch / (L * s))


@wp.func
def node_force(
    node_start: wp.array(dtype=int), node_member: wp.array(dtype=int), node_other: wp.array(dtype=int),
    node_dref: wp.array(dtype=Any), cab_EA: wp.array2d(dtype=Any), cab_EAc: wp.array2d(dtype=Any),
    cab_L: wp.array2d(dtype=Any), ext_force: wp.array2d(dtype=Any), u: wp.array2d(dtype=Any), n: int, c: int,
    wE: int, wC: int, wL: int, wF: int,
):
    """Sum of the external (dead) load ``ext_force[n, wF]`` and the cable forces [N] on node n at the
    displacement ``u[:, c]``, each along its vector from n to the cable's other end; wE, wC, wL, wF:
    the column's index into EA, EA_c, L and the load. The sum starts from the load, so a zero load
    (+0) gives the cable sum bit for bit."""
    un = u[n, c]
    f = ext_force[n, wF]
    for t in range(node_start[n], node_start[n + 1]):
        e = node_member[t]
        f += cable_force(node_dref[t] + u[node_other[t], c] - un, cab_EA[e, wE], cab_EAc[e, wC], cab_L[e, wL])
    return f


@wp.func
def force_columns(EA: wp.array2d(dtype=Any), EAc: wp.array2d(dtype=Any), L: wp.array2d(dtype=Any),
                  ext: wp.array2d(dtype=Any), minv_self: wp.array2d(dtype=Any), minv_cross: wp.array2d(dtype=Any),
                  w: int):
    """Column w's index (w modulo the parameter's Bp) into each per-column parameter of the forces and
    the inverse masses: (EA, EA_c, rest length, dead load, self, cross)."""
    return (w % EA.shape[1], w % EAc.shape[1], w % L.shape[1], w % ext.shape[1], w % minv_self.shape[1],
            w % minv_cross.shape[1])


@wp.func
def bar_residual(b: Any, L: Any):
    """(r, e): the Newton residual r = (|b|^2 - L^2)/2 [m2] and the relative length error e."""
    bb = wp.dot(b, b)
    return type(L)(0.5) * (bb - L * L), wp.abs(wp.sqrt(bb) - L) / L


@wp.func
def bar_row(dref: wp.array(dtype=Any), ni: wp.array(dtype=int), nj: wp.array(dtype=int), L: wp.array(dtype=Any),
            u: wp.array2d(dtype=Any), k: int, c: int, err: Any):
    """Bar k's residual at ``u[:, c]`` (:func:`bar_residual`), its relative error, and the running
    largest error ``err`` after it (a NaN kept: ``not (e <= err)`` also catches it)."""
    r, e = bar_residual(member_vec(dref, ni, nj, u, k, c), L[k])
    if not (e <= err):
        err = e
    return r, e, err


@wp.func
def node_impulse(
    con_i: wp.array(dtype=int), con_j: wp.array(dtype=int), con_dref: wp.array(dtype=Any),
    ncon_start: wp.array(dtype=int), ncon_member: wp.array(dtype=int),
    ug: wp.array2d(dtype=Any), cu: int, lam: wp.array2d(dtype=Any), cl: int, n: int,
):
    """(G(ug[:, cu])^T lam[:, cl])_n: node n gathers its own members (no read-modify-write chains)."""
    g = type(con_dref[0])()
    for t in range(ncon_start[n], ncon_start[n + 1]):
        k = ncon_member[t]
        gk = member_vec(con_dref, con_i, con_j, ug, k, cu) * lam[k, cl]
        if con_j[k] == n:
            g += gk
        else:
            g -= gk
    return g


@wp.func
def finite3(v: Any):
    return wp.isfinite(v[0]) and wp.isfinite(v[1]) and wp.isfinite(v[2])


@wp.func
def projection_status(err: Any, fail_tol: Any):
    """The column's status after a position projection whose largest relative bar error is err:
    non-finite, over ``fail_tol`` (constraint failure), or ok."""
    code = int(STATUS_OK)
    if not wp.isfinite(err):
        code = STATUS_NONFINITE
    elif err > fail_tol:
        code = STATUS_CONSTRAINT
    return code


@wp.func
def newton_stop(err: Any, prev: Any, tol: Any, it: int, max_iter: int):
    """Whether a projection's Newton iteration stops at the largest relative bar error ``err``
    (``prev``: the last iteration's) after ``it`` iterations: converged (err <= tol), out of
    iterations, or stalled at round-off just above tol (less than halved, under 10 tol), where more
    iterations cannot help. Every step family's stall rule (a NaN err never stops it here)."""
    return (err <= tol or it >= max_iter) or (it > 0 and err > type(err)(0.5) * prev and err < type(err)(10.0) * tol)


@wp.func
def output_slot(s: int, every: int, n_out: int):
    """The output slot of step s: s / every where s is a multiple of ``every`` (and the slot is below
    ``n_out``, the record's length; n_out < 0: a record of running values, no bound), else -1: no
    record at this step. Every record kernel gates on it."""
    slot = int(-1)
    if s % every == 0:
        if n_out < 0 or s / every < n_out:
            slot = s / every
    return slot


@wp.func
def set_failure(status: wp.array(dtype=int), fail_step: wp.array(dtype=int), w: int, code: int, at_step: int):
    """Flag column w (first failure only) with ``code`` at step ``at_step``."""
    if status[w] == STATUS_OK:
        status[w] = code
        fail_step[w] = at_step


@wp.func
def axial_angle(rb: Any, rt: Any, axis: Any):
    """Signed angle [rad] in (-pi, pi] from rb to rt about the unit vector ``axis`` (right-hand
    rule), between their projections on the plane normal to it."""
    return wp.atan2(wp.dot(axis, wp.cross(rb, rt)), wp.dot(rb, rt) - wp.dot(axis, rb) * wp.dot(axis, rt))


@wp.func
def prism_twist_of(Db: Any, Dt: Any, Rb: Any, Rt: Any, h0j: Any, hand: Any, near: Any):
    """(twist [rad], height h [m]) of a prism from the displacements of its bottom and top nodes
    (rows c = 0..2 of Db, Dt) and their reference positions about their base's centroid (Rb, Rt).
    The twist is the mean over the three bars (bottom k -> top k) of the angle about the prism axis
    (bottom centroid -> top centroid; the reference axis is z, of length h0j) from the bar's bottom
    node to its top node, both from their base's centroid, counted clockwise seen from the top for a
    right-handed prism (``hand`` +1; -1 mirrors it), each bar's angle taken within pi of ``near``
    (unwrapped: 183 deg reads 183, not -177). h is the strain record's: h0j plus the mean z motion
    of the top base over the bottom's."""
    three = type(h0j)(3.0)
    ub = Db[0]
    ut = Dt[0]
    zb = Db[0][2]
    zt = Dt[0][2]
    for c in range(1, 3):  # the strain record's sums, in its order
        ub += Db[c]
        ut += Dt[c]
        zb += Db[c][2]
        zt += Dt[c][2]
    h = h0j + (zt - zb) / three
    ub = ub / three
    ut = ut / three
    axis = ut - ub
    axis = wp.normalize(type(axis)(axis[0], axis[1], axis[2] + h0j))
    two_pi = type(h0j)(TWO_PI)
    phi = type(h0j)(0.0)
    for c in range(3):
        rb = Rb[c] + Db[c] - ub
        rt = Rt[c] + Dt[c] - ut
        a = -hand * axial_angle(rb, rt, axis)
        phi += a + two_pi * wp.floor((near - a) / two_pi + type(h0j)(0.5))
    return phi / three, h


@wp.func
def prism_twist(level_nodes: wp.array2d(dtype=int), h0: wp.array(dtype=Any), level_ref: wp.array2d(dtype=Any),
                hand: Any, u: wp.array2d(dtype=Any), j: int, w: int, near: Any):
    """:func:`prism_twist_of` for prism j of column w at the displacement ``u[:, w]``."""
    Db = wp.matrix_from_rows(u[level_nodes[j, 0], w], u[level_nodes[j, 1], w], u[level_nodes[j, 2], w])
    Dt = wp.matrix_from_rows(u[level_nodes[j + 1, 0], w], u[level_nodes[j + 1, 1], w], u[level_nodes[j + 1, 2], w])
    Rb = wp.matrix_from_rows(level_ref[j, 0], level_ref[j, 1], level_ref[j, 2])
    Rt = wp.matrix_from_rows(level_ref[j + 1, 0], level_ref[j + 1, 1], level_ref[j + 1, 2])
    return prism_twist_of(Db, Dt, Rb, Rt, h0[j], hand, near)


@wp.func
def feasibility_record(phi: Any, h: Any, h0j: Any, near: Any, slot: int, j: int, w: int,
                       twist: wp.array2d(dtype=Any), twist_max: wp.array2d(dtype=Any),
                       twist_min: wp.array2d(dtype=Any), height_min: wp.array2d(dtype=Any),
                       left_slot: wp.array3d(dtype=int)):
    """Record prism j of column w at output ``slot``: its twist phi (kept at ``near``, the last
    output's, where the prism inverted: its axis has flipped), the running extremes of the twist
    and of h/h0, and the first slot at which each reason of types.FEASIBILITY_FLAGS occurred."""
    ratio = h / h0j
    if h <= type(h)(0.0):
        phi = near
    if slot == 0:
        twist_max[j, w] = phi
        twist_min[j, w] = phi
        height_min[j, w] = ratio
        for r in range(3):
            left_slot[r, j, w] = -1
    else:
        if phi > twist_max[j, w]:
            twist_max[j, w] = phi
        if phi < twist_min[j, w]:
            twist_min[j, w] = phi
        if ratio < height_min[j, w]:
            height_min[j, w] = ratio
    twist[j, w] = phi
    if phi >= type(h)(PI) and left_slot[0, j, w] < 0:
        left_slot[0, j, w] = slot
    if phi <= type(h)(THIRD_PI) and left_slot[1, j, w] < 0:
        left_slot[1, j, w] = slot
    if h <= type(h)(0.0) and left_slot[2, j, w] < 0:
        left_slot[2, j, w] = slot


@wp.func
def member_excess2(b0: Any, du: Any, EA: Any, EAc: Any, L: Any):
    """Twice the elastic energy [J] of a member of reference vector b0 displaced by du above its value
    at u = 0, under the bilinear law of :func:`cable_force`: k/L dl (dl + 2 (l0 - L)), dl = l - l0 =
    du.(2 b0 + du)/(l + l0), with no cancellation of the prestress energy (the two laws' difference
    where the member went slack or taut)."""
    l0 = wp.length(b0)
    l = wp.length(b0 + du)
    dl = wp.dot(du, b0 + b0 + du) / (l + l0)
    st = l - L
    st0 = l0 - L
    k = EA
    if st < type(L)(0.0):
        k = EAc
    k0 = EA
    if st0 < type(L)(0.0):
        k0 = EAc
    de = type(L)(0.0)
    if k == k0:
        de = k / L * dl * (dl + st0 + st0)
    else:  # the member went slack or taut: its two laws differ
        de = (k * st * st - k0 * st0 * st0) / L
    return de


@wp.func
def cable_energy2(b: Any, EA: Any, EAc: Any, L: Any):
    """Twice the elastic energy [J] of a member of vector b under the bilinear law of
    :func:`cable_force`: k/L (s - L)^2."""
    st = wp.length(b) - L
    k = EA
    if st < type(L)(0.0):
        k = EAc
    return k / L * st * st


@wp.func
def axis_pair(bi: Any, bj: Any, w0: Any):
    """(distance [m], side) of two members x_i0 + s bi and x_j0 + t bj (s, t in [0, 1]), with
    w0 = x_j0 - x_i0: the distance between the two segments (Ericson, Real-Time Collision Detection,
    5.1.9), and the sign of their oriented distance w0 . (bi x bj) where the closest points of the
    two lines lie inside both segments (0 elsewhere, and for parallel members): it changes only when
    one member passes through the other."""
    a = wp.dot(bi, bi)
    e = wp.dot(bj, bj)
    b = wp.dot(bi, bj)
    c = -wp.dot(bi, w0)
    f = -wp.dot(bj, w0)
    den = a * e - b * b
    # parallel below ~1e-3 rad; 1e-30: no division by 0 at a slack cable's zero length
    tiny = type(a)(1e-6) * a * e + type(a)(1e-30)
    s_line = type(a)(0.0)
    t_line = type(a)(-1.0)
    if den > tiny:
        s_line = (b * f - c * e) / den
        t_line = (a * f - b * c) / den
    s = wp.clamp(s_line, type(a)(0.0), type(a)(1.0))
    t = (b * s + f) / wp.max(e, tiny)
    if t < type(a)(0.0):
        t = type(a)(0.0)
        s = wp.clamp(-c / wp.max(a, tiny), type(a)(0.0), type(a)(1.0))
    elif t > type(a)(1.0):
        t = type(a)(1.0)
        s = wp.clamp((b - c) / wp.max(a, tiny), type(a)(0.0), type(a)(1.0))
    dist = wp.length(bi * s - bj * t - w0)
    side = int(0)
    if s_line > type(a)(0.0) and s_line < type(a)(1.0) and t_line > type(a)(0.0) and t_line < type(a)(1.0):
        side = 1
        if wp.dot(w0, wp.cross(bi, bj)) < type(a)(0.0):
            side = -1
    return dist, side


@functools.cache
def make_gram_row(real, bandwidth: int):
    """``gram_row``: row k of A = G M^-1 G^T at u, lower band only, as a vector r with
    r[d] = A[k, k-d], d = 0..bandwidth (r = e_0 for an inactive member). Both paths assemble
    their rows with it; the half-bandwidth is compiled in so the row stays in registers."""
    LD = int(bandwidth) + 1
    rowvec = wp.types.vector(LD, real)

    @wp.func
    def gram_row(
        con_i: wp.array(dtype=int), con_j: wp.array(dtype=int), con_dref: wp.array(dtype=Any),
        con_active: wp.array2d(dtype=Any), cpl_start: wp.array(dtype=int), cpl_l: wp.array(dtype=int),
        cpl_a: wp.array(dtype=int), cpl_cross: wp.array(dtype=int), cpl_sign: wp.array(dtype=Any),
        minv_self: wp.array2d(dtype=Any), minv_cross: wp.array2d(dtype=Any),
        u: wp.array2d(dtype=Any), c: int, k: int, wa: int, ws: int, wx: int,
    ):
        r = rowvec()
        if con_active[k, wa] > real(0.0):
            bk = member_vec(con_dref, con_i, con_j, u, k, c)
            for t in range(cpl_start[k], cpl_start[k + 1]):
                l = cpl_l[t]
                if con_active[l, wa] > real(0.0):
                    na = cpl_a[t]
                    m = minv_self[na, ws]
                    if cpl_cross[t] != 0:
                        m = minv_cross[na, wx]
                    val = cpl_sign[t] * m * wp.dot(bk, member_vec(con_dref, con_i, con_j, u, l, c))
                    for e in range(LD):
                        if k - l == e:
                            r[e] += val
        else:
            r[0] = real(1.0)
        return r

    return gram_row, rowvec


class BandFuncs(NamedTuple):
    """The serial banded Cholesky's bodies for one precision and half-bandwidth."""

    band_row: wp.Function
    factor_store_row: wp.Function
    band_solve: wp.Function
    rowvec: type


@functools.cache
def make_band_funcs(real, bandwidth: int):
    """The sequential banded Cholesky of one thread (a staged solver thread per column, or lane 0
    of the fused step's serial variant), the bandwidth compiled in:
    the row being factored and the last ``bandwidth`` unknowns of a sweep sit in registers, and
    each sweep loads the next row while it works on the current one.

    The band ``(nc, bw+1, B)`` holds row k of L at ``band[k, d, w] = L[k, k-d]`` (zero for k-d < 0),
    except the diagonal slot, which holds 1/L[k, k]."""
    BW = int(bandwidth)
    LD = BW + 1
    rowvec = make_gram_row(real, BW)[1]
    winvec = wp.types.vector(max(BW, 1), real)

    @wp.func
    def band_row(band: wp.array3d(dtype=real), k: int, w: int):
        r = rowvec()
        for e in range(LD):
            r[e] = band[k, e, w]
        return r

    @wp.func
    def band_col(band: wp.array3d(dtype=real), k: int, nc: int, w: int):
        """(1/L[k,k], L[k+1,k], ..., L[k+BW,k]): what the backward sweep needs at row k."""
        c = rowvec()
        c[0] = band[k, 0, w]
        for e in range(BW):
            if k + e + 1 < nc:
                c[e + 1] = band[k + e + 1, e + 1, w]
        return c

    @wp.func
    def factor_store_row(band: wp.array3d(dtype=real), r: rowvec, k: int, w: int):
        """Factor assembled row k of A against the rows above (A = L L^T) and store it. Returns
        False if the pivot is not positive (singular constraints)."""
        for dd in range(BW):
            d = BW - dd  # l = k - d ascending
            l = k - d
            if l >= 0:
                s = r[d]
                for e in range(d + 1, LD):
                    s -= r[e] * band[l, e - d, w]
                r[d] = s * band[l, 0, w]
        s = r[0]
        for e in range(1, LD):
            s -= r[e] * r[e]
        ok = bool(True)
        if s > real(0.0):
            r[0] = real(1.0) / wp.sqrt(s)
        else:
            r[0] = real(1.0)
            ok = False
        for e in range(LD):
            band[k, e, w] = r[e]
        return ok

    @wp.func
    def sweep_row(cur: rowvec, rhs: real, win: winvec):
        """One row of a triangular sweep: x_k = (rhs - sum_e cur[e+1] win[e]) cur[0], and the
        window shifted to take x_k; returns (x_k, new window)."""
        s = rhs
        for e in range(BW):
            s -= cur[e + 1] * win[e]
        xk = s * cur[0]
        out = winvec()
        for e in range(BW - 1):
            out[BW - 1 - e] = win[BW - 2 - e]
        out[0] = xk
        return xk, out

    @wp.func
    def band_solve(band: wp.array3d(dtype=real), x: wp.array2d(dtype=real), nc: int, w: int):
        """Solve L L^T x = rhs in place (rhs given in x[0:nc, w])."""
        xw = winvec()  # xw[e] = x[k - 1 - e] (forward), x[k + 1 + e] (backward)
        nxt = band_row(band, 0, w)
        nrhs = x[0, w]
        for k in range(nc):
            cur = nxt
            s = nrhs
            if k + 1 < nc:  # issue the next row's loads before this row's dependent chain
                nxt = band_row(band, k + 1, w)
                nrhs = x[k + 1, w]
            xk, xw = sweep_row(cur, s, xw)
            x[k, w] = xk
        xw = winvec()
        nxt = band_col(band, nc - 1, nc, w)
        nrhs = x[nc - 1, w]
        for kk in range(nc):
            k = nc - 1 - kk
            cur = nxt
            s = nrhs
            if k > 0:
                nxt = band_col(band, k - 1, nc, w)
                nrhs = x[k - 1, w]
            xk, xw = sweep_row(cur, s, xw)
            x[k, w] = xk

    return BandFuncs(band_row=band_row, factor_store_row=factor_store_row, band_solve=band_solve, rowvec=rowvec)
