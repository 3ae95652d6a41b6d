"""The dense float64 Lagrange model of a network: what the linearised checks need, no dynamics.

:class:`ConstrainedNetwork` holds the free-node coordinates ``q``, the bar constraints
``g_k = (|b_k|^2 - L_k^2)/2`` and their Jacobian ``G = dg/dq``, the cable forces (Eq. 10 plus the
compressive branch of the column's base members: ``EA/L (s - L)`` for ``s >= L``,
``EA_compression/L (s - L)`` for ``s < L``) and the paper's consistent mass matrix (thin rods,
(m/6)[[2, 1], [1, 2]] per bar, plus lumped node masses), built here from the thin-rod kinetic
energy rather than taken from :meth:`Network.mass_matrix`. NumPy only, no Warp; SI units.

:mod:`.linear` (modes, stiffness, long-wave speeds) and :mod:`.dispersion` (Bloch bands) build on
it. The tests' independent fp64 simulator (``tests/references/reference.py``, ``ReferenceSystem``)
subclasses it with the accelerations, multipliers, projections and integrators; that simulator is
a test and benchmark reference and is not part of the package.
"""

from __future__ import annotations

import numpy as np

from ..scene.network import Network

__all__ = ["ConstrainedNetwork"]


class ConstrainedNetwork:
    """Bar constraints, cable forces and the consistent mass matrix of any :class:`Network`.

    Public methods take full node arrays of shape (n_nodes, 3); clamped nodes stay at their
    reference positions. Bar lengths L_k are those of ``network.positions``; ``external_force``
    (n_nodes, 3) [N] is added to the nodal forces.
    """

    def __init__(self, network: Network, external_force: np.ndarray | None = None):
        net = network
        self.network = net
        self.n_nodes = net.n_nodes
        self.free = ~np.asarray(net.fixed, bool)
        self.free_nodes = np.flatnonzero(self.free)
        self.n_free = len(self.free_nodes)
        self.ndof = 3 * self.n_free
        self.x_ref = np.array(net.positions, float)
        self.bars = np.asarray(net.bars)
        self.cables = np.asarray(net.cables)
        self.L_bar = np.linalg.norm(self.x_ref[self.bars[:, 1]] - self.x_ref[self.bars[:, 0]], axis=1)
        self.L_cable = np.asarray(net.cable_rest_length, float)
        self.k_t = np.asarray(net.cable_EA, float) / self.L_cable
        self.k_c = np.asarray(net.cable_EA_compression, float) / self.L_cable
        self.W = np.zeros((self.n_nodes, 3)) if external_force is None else np.asarray(external_force, float)
        # consistent mass matrix, built here from the thin-rod kinetic energy (not Network.mass_matrix)
        Mn = np.diag(np.asarray(net.node_mass, float))
        for (i, j), m in zip(self.bars, net.bar_mass):
            Mn[np.ix_([i, j], [i, j])] += m / 6.0 * np.array([[2.0, 1.0], [1.0, 2.0]])
        Mf = Mn[np.ix_(self.free_nodes, self.free_nodes)]
        self.M = np.kron(Mf, np.eye(3))
        self.Minv = np.linalg.inv(self.M)
        # map node -> free index (or -1)
        self._slot = -np.ones(self.n_nodes, dtype=np.int64)
        self._slot[self.free_nodes] = np.arange(self.n_free)

    # ---------------------------------------------------------------- coordinates
    def to_q(self, x: np.ndarray) -> np.ndarray:
        return np.asarray(x, float)[self.free_nodes].reshape(-1)

    def to_x(self, q: np.ndarray, fill: np.ndarray | None = None) -> np.ndarray:
        x = (self.x_ref if fill is None else fill).copy()
        x[self.free_nodes] = q.reshape(-1, 3)
        return x

    def _to_v(self, vq: np.ndarray) -> np.ndarray:
        v = np.zeros((self.n_nodes, 3))
        v[self.free_nodes] = vq.reshape(-1, 3)
        return v

    # ---------------------------------------------------------------- model pieces
    def constraints(self, x: np.ndarray) -> np.ndarray:
        """g_k = (|b_k|^2 - L_k^2)/2 [m^2]."""
        b = x[self.bars[:, 1]] - x[self.bars[:, 0]]
        return 0.5 * (np.einsum("ij,ij->i", b, b) - self.L_bar**2)

    def jacobian(self, x: np.ndarray) -> np.ndarray:
        """G = dg/dq, shape (n_bars, 3 n_free) [m]."""
        G = np.zeros((len(self.bars), self.ndof))
        for k, (i, j) in enumerate(self.bars):
            b = x[j] - x[i]
            if self._slot[j] >= 0:
                G[k, 3 * self._slot[j] : 3 * self._slot[j] + 3] += b
            if self._slot[i] >= 0:
                G[k, 3 * self._slot[i] : 3 * self._slot[i] + 3] -= b
        return G

    def cable_forces(self, x: np.ndarray) -> np.ndarray:
        """Axial force of every cable [N], positive in tension."""
        d = x[self.cables[:, 1]] - x[self.cables[:, 0]]
        s = np.linalg.norm(d, axis=1)
        k = np.where(s >= self.L_cable, self.k_t, self.k_c)
        return k * (s - self.L_cable)

    def nodal_forces(self, x: np.ndarray) -> np.ndarray:
        """Cable plus external forces on each node [N], shape (n_nodes, 3)."""
        d = x[self.cables[:, 1]] - x[self.cables[:, 0]]
        s = np.linalg.norm(d, axis=1)
        T = self.cable_forces(x)
        fe = (T / s)[:, None] * d  # tension pulls i toward j
        f = self.W.copy()
        np.add.at(f, self.cables[:, 0], fe)
        np.add.at(f, self.cables[:, 1], -fe)
        return f
