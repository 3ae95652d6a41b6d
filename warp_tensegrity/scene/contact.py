"""Bar contact (issue 32), host side, NumPy: the bar pairs of each prism, the signed distance of their
axes, the contact twist of a regular prism, and the augmented constraint system (rigid members and
contact rows) whose Gram matrix the contact projection factors (:mod:`warp_tensegrity.sim.staged.contact`).

Geometry. Bars i and j of a prism are segments P_i -> Q_i and P_j -> Q_j (bottom -> top node). The
signed axis distance is

    D = sigma * (P_j - P_i) . (e_i x e_j) / |e_i x e_j|,    e = Q - P,

the distance of the two infinite axes, sigma = +-1 chosen so that D > 0 in the reference
configuration. D is smooth through zero: when bars cross, D changes sign (the bars of a T3 prism
touch on the axis at twist pi, Sec. 3 of the paper). Its gradient is that of the distance of the
closest points c_i = P_i + s e_i and c_j = P_j + t e_j (envelope theorem) with m = dD/dc_j:

    dD/dP_i = -(1 - s) m,   dD/dQ_i = -s m,   dD/dP_j = (1 - t) m,   dD/dQ_j = t m.

Bars of radius r touch when D = 2 r with both closest points inside the bars (0 <= s, t <= 1); a
pair whose axes meet beyond an end of a bar is not a contact (the bars of a prism pass each other
only through their interiors: their ends sit on the base triangles).
"""

from __future__ import annotations

import math

import numpy as np

CONTACT_MODELS = ("none", "bars")
"""Values of the scene's ``contact`` option."""


def axis_geometry(P_i, Q_i, P_j, Q_j):
    """(D_unsigned_normal_distance, s, t) of the infinite axes through the segments (arrays (..., 3)):
    the distance ``(P_j - P_i) . n`` along n = e_i x e_j / |e_i x e_j| (its sign depends on the
    orientation) and the parameters of the closest points."""
    ei, ej, w = Q_i - P_i, Q_j - P_j, P_j - P_i
    c = np.cross(ei, ej)
    d = np.einsum("...k,...k", w, c) / np.linalg.norm(c, axis=-1)
    A, Bd, C = (ei * ei).sum(-1), (ei * ej).sum(-1), (ej * ej).sum(-1)
    ew_i, ew_j = (ei * w).sum(-1), (ej * w).sum(-1)
    den = A * C - Bd * Bd
    return d, (C * ew_i - Bd * ew_j) / den, (Bd * ew_i - A * ew_j) / den


def segment_distance(P_i, Q_i, P_j, Q_j) -> np.ndarray:
    """Unsigned closest distance [m] of two segments (arrays (..., 3)), clamped to the segments: an
    independent check of the device's signed axis distance (Ericson, Real-Time Collision Detection
    5.1.9; non-parallel segments)."""
    d1, d2, r = Q_i - P_i, Q_j - P_j, P_i - P_j
    a, e, f = (d1 * d1).sum(-1), (d2 * d2).sum(-1), (d2 * r).sum(-1)
    c, b = (d1 * r).sum(-1), (d1 * d2).sum(-1)
    den = a * e - b * b
    s = np.clip((b * f - c * e) / den, 0.0, 1.0)
    t = (b * s + f) / e
    s = np.where(t < 0, np.clip(-c / a, 0, 1), np.where(t > 1, np.clip((b - c) / a, 0, 1), s))
    t = np.clip(t, 0.0, 1.0)
    return np.linalg.norm(P_i + s[..., None] * d1 - P_j - t[..., None] * d2, axis=-1)


def prism_pairs(bars: np.ndarray) -> np.ndarray:
    """(3 n_prisms, 2) indices into ``bars`` (3 per prism, prism by prism) of the three bar pairs of
    each prism: (0, 1), (1, 2), (0, 2)."""
    n = len(bars) // 3
    base = 3 * np.arange(n)[:, None, None]
    return (base + np.array([[0, 1], [1, 2], [0, 2]])[None]).reshape(-1, 2)


def reference_sign(positions: np.ndarray, bars: np.ndarray, pairs: np.ndarray) -> np.ndarray:
    """(n_pairs,) sigma = +-1: the sign that makes each pair's axis distance positive at the reference."""
    P, Q = positions[bars[:, 0]], positions[bars[:, 1]]
    d, _, _ = axis_geometry(P[pairs[:, 0]], Q[pairs[:, 0]], P[pairs[:, 1]], Q[pairs[:, 1]])
    return np.where(d >= 0, 1.0, -1.0)


def regular_prism(radius: float, bar_length: float, twist: float):
    """Bottom and top nodes (3, 3) each of a regular prism of base circumradius ``radius`` [m] whose
    bars of length ``bar_length`` [m] give it the twist ``twist`` [rad]: height
    h = sqrt(L^2 - 2 a^2 (1 - cos phi)) (clockwise twist, as :func:`~.columns.column_topology`)."""
    h = math.sqrt(bar_length**2 - 2.0 * radius**2 * (1.0 - math.cos(twist)))
    ang = -2.0 * np.pi * np.arange(3) / 3.0
    bottom = np.stack([radius * np.cos(ang), radius * np.sin(ang), np.zeros(3)], axis=1)
    top = np.stack([radius * np.cos(ang - twist), radius * np.sin(ang - twist), np.full(3, h)], axis=1)
    return bottom, top


def regular_gap(radius: float, bar_length: float, twist: float) -> float:
    """Distance [m] between two bar axes of a regular prism at ``twist`` (all three pairs alike;
    zero at pi, where the bars meet on the axis)."""
    P, Q = regular_prism(radius, bar_length, twist)
    d, _, _ = axis_geometry(P[0], Q[0], P[1], Q[1])
    return abs(float(d))


def contact_twist(radius: float, height: float, twist: float, bar_radius: float) -> float:
    """The twist phi_c [rad] in (twist, pi) at which the bars of a regular prism of reference height
    ``height`` and ``twist`` (which fix the bar length) touch: axis distance 2 r. The height is
    then fixed by the twist through the bar length (rigid bases: the RB hard stop)."""
    from scipy.optimize import brentq

    L = math.sqrt(height**2 + 2.0 * radius**2 * (1.0 - math.cos(twist)))
    g = lambda phi: regular_gap(radius, L, phi) - 2.0 * bar_radius  # noqa: E731
    if g(twist) <= 0:
        raise ValueError(f"bar_radius = {bar_radius!r}: the bars touch in the reference configuration")
    return float(brentq(g, twist, math.pi, xtol=1e-15, rtol=4 * np.finfo(float).eps))


# ---------------------------------------------------------------------- the augmented system
ROW_BAR, ROW_CONTACT = 0, 1


def augmented_system(constraints: np.ndarray, pairs: np.ndarray, fixed: np.ndarray, partner: np.ndarray) -> dict:
    """The rows of the contact projection: every rigid member and every bar pair, each pair placed
    right after the later of its two bars (the rigid members keep their order), so the Gram matrix
    stays banded. A row's gradient sits on its slots: a member's nodes (i: -b, j: +b) or a pair's
    four nodes (P_i, Q_i, P_j, Q_j).

    Returns host arrays: ``row_kind`` (ROW_BAR or ROW_CONTACT), ``row_index`` (member or pair),
    ``pair_row`` (each pair's row); the Gram matrix's lower coupling terms as CSR over rows
    (``acpl_start``, and per term ``acpl_l`` the column l <= k, ``acpl_sk``/``acpl_sl`` the slots of
    rows k and l, ``acpl_a`` the node of row k whose M^-1 entry (``acpl_cross``: self 0 or partner 1)
    couples them); each node's (row, slot) incidences (``anode_start``, ``anode_row``,
    ``anode_slot``); and ``bandwidth``. Vectorised (a long column has 10^5 rows)."""
    cons = np.asarray(constraints, dtype=np.int64).reshape(-1, 2)
    pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    nc, npair, n = len(cons), len(pairs), len(fixed)
    # ordering: members by index, each pair after its later bar
    key = np.concatenate([np.arange(nc) * 2.0, pairs.max(axis=1) * 2.0 + 1.0]) if npair else np.arange(nc) * 2.0
    order = np.lexsort((np.arange(nc + npair), key))
    kind = np.concatenate([np.full(nc, ROW_BAR), np.full(npair, ROW_CONTACT)])[order].astype(np.int32)
    index = np.concatenate([np.arange(nc), np.arange(npair)])[order].astype(np.int32)
    R = nc + npair
    row_of = np.empty(R, dtype=np.int64)
    row_of[order] = np.arange(R)
    pair_row = row_of[nc:].astype(np.int32)
    # slots: (row, slot, node)
    slot_nodes = -np.ones((R, 4), dtype=np.int64)
    bar_rows = row_of[:nc]
    slot_nodes[bar_rows, 0], slot_nodes[bar_rows, 1] = cons[:, 0], cons[:, 1]
    if npair:
        pr = row_of[nc:]
        slot_nodes[pr, 0], slot_nodes[pr, 1] = cons[pairs[:, 0], 0], cons[pairs[:, 0], 1]
        slot_nodes[pr, 2], slot_nodes[pr, 3] = cons[pairs[:, 1], 0], cons[pairs[:, 1], 1]
    r_all = np.repeat(np.arange(R), 4)
    s_all = np.tile(np.arange(4), R)
    nd_all = slot_nodes.ravel()
    ok = nd_all >= 0
    r_all, s_all, nd_all = r_all[ok], s_all[ok], nd_all[ok]
    o = np.lexsort((s_all, r_all, nd_all))  # by node, then row, then slot
    inc_node, inc_row, inc_slot = nd_all[o], r_all[o], s_all[o]
    anode_start = np.searchsorted(inc_node, np.arange(n + 1)).astype(np.int32)
    # coupling terms: every (row k, slot p, node a free, cross) joined with the incidences of a or partner(a)
    p = np.asarray(partner, dtype=np.int64)
    k = np.repeat(r_all, 2)
    sk = np.repeat(s_all, 2)
    a = np.repeat(nd_all, 2)
    cr = np.tile(np.array([0, 1]), len(r_all))
    b = np.where(cr == 0, a, p[a])
    keep = ~np.asarray(fixed, bool)[a] & (b >= 0)
    k, sk, a, cr, b = k[keep], sk[keep], a[keep], cr[keep], b[keep]
    cnt = anode_start[b + 1] - anode_start[b]
    src = np.repeat(np.arange(len(k)), cnt)
    pos = np.repeat(anode_start[b], cnt) + (np.arange(cnt.sum()) - np.repeat(np.cumsum(cnt) - cnt, cnt))
    K, L, SK, SL, A, C = k[src], inc_row[pos], sk[src], inc_slot[pos], a[src], cr[src]
    m = L <= K
    K, L, SK, SL, A, C = K[m], L[m], SK[m], SL[m], A[m], C[m]
    o = np.lexsort((SL, SK, C, A, L, K))
    K, L, SK, SL, A, C = K[o], L[o], SK[o], SL[o], A[o], C[o]
    i32 = lambda x: np.ascontiguousarray(x, dtype=np.int32)  # noqa: E731
    return dict(row_kind=kind, row_index=index, pair_row=pair_row,
                acpl_start=i32(np.searchsorted(K, np.arange(R + 1))), acpl_l=i32(L), acpl_sk=i32(SK),
                acpl_sl=i32(SL), acpl_a=i32(A), acpl_cross=i32(C),
                anode_start=anode_start, anode_row=i32(inc_row), anode_slot=i32(inc_slot),
                bandwidth=int((K - L).max()) if K.size else 0)


def contact_arrays(batch, partner: np.ndarray) -> dict:
    """The host values of :data:`warp_tensegrity.types.CONTACT_FIELDS` for a batch with contact pairs
    (float64; ``partner``: each node's massive-bar partner or -1, as
    :func:`~.coupling.mass_entries` gives it), and ``bandwidth``, the contact Gram half-bandwidth."""
    cons = np.asarray(batch.constraints, dtype=np.int64).reshape(-1, 2)
    pairs = np.asarray(batch.contact_pairs, dtype=np.int64).reshape(-1, 2)
    X = batch.positions
    out = augmented_system(cons, pairs, batch.fixed, partner)
    out.update(pair_bi=pairs[:, 0].astype(np.int32), pair_bj=pairs[:, 1].astype(np.int32),
               pair_wref=X[cons[pairs[:, 1], 0]] - X[cons[pairs[:, 0], 0]],
               pair_sign=reference_sign(X, cons, pairs))
    return out


def contact_strain(radius: float, height: float, twist: float, bar_radius: float) -> float:
    """Prism strain (h - h0)/h [1] at the contact twist of a regular prism (:func:`contact_twist`):
    where a rigid-base prism stops compressing with bar contact (without it, at the kinematic lock
    of twist pi, :func:`~.impact.kinematic_lock_strain`)."""
    L2 = height**2 + 2.0 * radius**2 * (1.0 - math.cos(twist))
    h = math.sqrt(L2 - 2.0 * radius**2 * (1.0 - math.cos(contact_twist(radius, height, twist, bar_radius))))
    return (h - height) / h
