"""The constraint Gram matrix's coupling pattern and the mass entries of a network batch, in NumPy:
what the device model is built from (:mod:`warp_tensegrity.sim.model`) and what the policy reads the
Gram half-bandwidth from (:func:`warp_tensegrity.policy.paths.gram_bandwidth`) without Warp."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from .batch import NetworkBatch


def constraint_coupling(batch: NetworkBatch, partner: np.ndarray):
    """Lower-triangle coupling terms of A = G M^-1 G^T: for row k, the (l <= k, node a of k,
    cross?, sign) whose M^-1 entry is non-zero, sorted by (l, a, cross, sign). Returns CSR arrays
    and the bandwidth. Vectorised (a long column has 10^5 constraints): every (row, end, node)
    source joined with the node's incidences, then one lexsort."""
    cons = np.asarray(batch.constraints, dtype=np.int64).reshape(-1, 2)
    nc = len(cons)
    n = batch.positions.shape[0]
    # incidence of every node: (constraint l, sign: -1 first node, +1 second), ordered by l, first before second
    inc_node = cons.ravel()
    inc_l = np.repeat(np.arange(nc), 2)
    inc_s = np.tile(np.array([-1.0, 1.0]), nc)
    order = np.lexsort((inc_l, inc_node))  # by node, then l (stable: within one l the ends keep order)
    inc_node, inc_l, inc_s = inc_node[order], inc_l[order], inc_s[order]
    start = np.searchsorted(inc_node, np.arange(n + 1))
    # every (row k, end a, sign sa, node b, cross) source
    k = np.repeat(np.arange(nc), 4)
    a = np.repeat(cons, 2, axis=1).ravel()
    sa = np.tile(np.array([-1.0, -1.0, 1.0, 1.0]), nc)
    cr = np.tile(np.array([0, 1, 0, 1]), nc)
    p = np.asarray(partner, dtype=np.int64)
    b = np.where(cr == 0, a, p[a])
    keep = ~np.asarray(batch.fixed, bool)[a] & (b >= 0)
    k, a, sa, cr, b = k[keep], a[keep], sa[keep], cr[keep], b[keep]
    cnt = start[b + 1] - start[b]
    src = np.repeat(np.arange(len(k)), cnt)
    pos = np.repeat(start[b], cnt) + (np.arange(cnt.sum()) - np.repeat(np.cumsum(cnt) - cnt, cnt))
    K, L, A, C, S = k[src], inc_l[pos], a[src], cr[src], sa[src] * inc_s[pos]
    m = L <= K
    K, L, A, C, S = K[m], L[m], A[m], C[m], S[m]
    o = np.lexsort((S, C, A, L, K))
    K, L, A, C, S = K[o], L[o], A[o], C[o], S[o]
    rowstart = np.searchsorted(K, np.arange(nc + 1))
    bw = int((K - L).max()) if K.size else 0
    return (rowstart.astype(np.int32), L.astype(np.int32), A.astype(np.int32), C.astype(np.int32),
            S.astype(np.float64), bw)


def mass_entries(batch: NetworkBatch):
    """Per-node M and M^-1 entries (self and partner) for lumped masses plus the paper's
    consistent bar inertia (each node in at most one massive bar). Shapes (Bp, n_nodes)."""
    n = batch.positions.shape[0]
    Bp = max(batch.node_mass.shape[0], batch.constraint_mass.shape[0])
    m_node = np.broadcast_to(batch.node_mass, (Bp, n)).astype(np.float64)
    m_bar = np.broadcast_to(batch.constraint_mass, (Bp, len(batch.constraints)))
    partner = -np.ones(n, dtype=np.int32)
    m_self = m_node.copy()
    m_cross = np.zeros((Bp, n))
    for k in np.flatnonzero(np.any(m_bar > 0, axis=0)):  # massive bars only (none in a long column)
        i, j = batch.constraints[k]
        partner[i], partner[j] = j, i
        m_self[:, i] += m_bar[:, k] / 3.0
        m_self[:, j] += m_bar[:, k] / 3.0
        m_cross[:, i] = m_bar[:, k] / 6.0
        m_cross[:, j] = m_bar[:, k] / 6.0
    minv_self = np.zeros_like(m_self)
    minv_cross = np.zeros_like(m_self)
    free = ~batch.fixed
    paired = free & (partner >= 0) & free[np.maximum(partner, 0)]
    lone = free & ~paired
    minv_self[:, lone] = 1.0 / m_self[:, lone]
    a = np.flatnonzero(paired)
    p = partner[a]
    det = m_self[:, a] * m_self[:, p] - m_cross[:, a] ** 2
    minv_self[:, a] = m_self[:, p] / det
    minv_cross[:, a] = -m_cross[:, a] / det
    both_free = (partner >= 0) & free & free[np.maximum(partner, 0)]
    partner_dev = np.where(both_free, partner, -1).astype(np.int32)
    return partner, partner_dev, m_self, m_cross, minv_self, minv_cross
