"""``@wp.func`` bodies shared by the staged and the fused step, each written once.

The functions are generic over precision (``typing.Any``: Warp specialises them for the fp32 or
fp64 arrays a kernel passes). Node state and multipliers are 2-D arrays read as ``u[n, c]``,
``lam[k, c]``: the staged kernels pass the batch arrays ``(n, B)`` with c = the column w; the
fused kernel passes its column's own rows ``(n, NQ)`` with c = the state slot (U, V, ...), and
its multipliers ``(rows, 1)`` with c = 0. (Overloading one function on the array's ndim instead
resolved to the wrong overload depending on compile order: do not.)
"""

import functools
from typing import Any

import warp as wp

wp.set_module_options({"enable_backward": False})

STATUS_OK = wp.constant(0)
STATUS_NONFINITE = wp.constant(1)
STATUS_CONSTRAINT = wp.constant(2)

# slots of a node's row in the fused step (the values of types.Slot; not imported, to keep the
# import chains short: tests/test_layout.py, test_parallel_solve.py checks they agree)
NQ = 5
U, V, A, P, I = (wp.constant(i) for i in range(NQ))


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
    cab_L: wp.array2d(dtype=Any), u: wp.array2d(dtype=Any), n: int, c: int, wE: int, wC: int, wL: int,
):
    """Sum of the cable forces [N] on node n at the displacement ``u[:, c]``, each along its
    vector from n to the cable's other end; wE, wC, wL: the column's index into EA, EA_c, L."""
    un = u[n, c]
    f = type(un)()
    for t in range(node_start[n], node_start[n + 1]):
        e = node_member[t]
        f += cable_force(node_dref[t] + u[node_other[t], c] - un, cab_EA[e, wE], cab_EAc[e, wC], cab_L[e, wL])
    return f


@wp.func
def bar_residual(b: Any, L: Any):
    """(r, e): the Newton residual r = (|b|^2 - L^2)/2 [m2] and the relative length error e."""
    bb = wp.dot(b, b)
    return type(L)(0.5) * (bb - L * L), wp.abs(wp.sqrt(bb) - L) / L


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
def set_failure(status: wp.array(dtype=int), fail_step: wp.array(dtype=int), w: int, code: int, at_step: int):
    """Flag column w (first failure only) with ``code`` at step ``at_step``."""
    if status[w] == STATUS_OK:
        status[w] = code
        fail_step[w] = at_step


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
