"""A tensegrity network on the host: nodes, rigid bars and elastic cables (float64 NumPy).

This is the scene-level description every other stage starts from. It knows nothing of
Warp or batching; :mod:`warp_tensegrity.sim.model` turns a batch of networks of one topology
into device arrays.

Conventions (paper, Sec. 2.1): bar ``k`` joining nodes ``(i, j)`` has vector
``b_k = n_j - n_i``; a cable of axial stiffness ``EA`` and rest length ``L`` at stretched
length ``s`` carries the tension ``EA/L * max(s - L, 0)`` (Eq. 10). A cable may also be
given a compressive stiffness ``EA_compression`` (0 for a true cable); the base members of
a column between the flexible and rigid limits use it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


class NetworkError(ValueError):
    """Invalid network or scene input. The message names the member, node or field and the bad
    value; ``errors`` lists one message per problem."""

    def __init__(self, errors):
        self.errors = [errors] if isinstance(errors, str) else list(errors)
        super().__init__(self.errors[0] if len(self.errors) == 1 else "; ".join(self.errors))


@dataclass
class Network:
    """Nodes, bars and cables of one tensegrity network. All arrays are float64/int64, SI units."""

    positions: np.ndarray
    """Reference node positions, shape (n_nodes, 3) [m]."""
    node_mass: np.ndarray
    """Lumped node masses, shape (n_nodes,) [kg]. Fixed nodes may have any mass."""
    fixed: np.ndarray
    """True for clamped nodes, shape (n_nodes,)."""
    bars: np.ndarray
    """Rigid members as node pairs (i, j), shape (n_bars, 2); b = n_j - n_i."""
    bar_mass: np.ndarray
    """Bar masses, shape (n_bars,) [kg]; thin-rod consistent inertia (paper's M). 0 = massless."""
    cables: np.ndarray
    """Elastic members as node pairs (i, j), shape (n_cables, 2)."""
    cable_EA: np.ndarray
    """Axial stiffness in tension E*A, shape (n_cables,) [N]."""
    cable_rest_length: np.ndarray
    """Rest lengths L, shape (n_cables,) [m]."""
    cable_EA_compression: np.ndarray | None = None
    """Axial stiffness in compression, shape (n_cables,) [N]; None or 0 = tension-only."""
    bar_names: list[str] | None = field(default=None, repr=False)
    """Optional labels used in error messages, one per bar."""
    cable_names: list[str] | None = field(default=None, repr=False)
    """Optional labels used in error messages, one per cable."""

    def __post_init__(self):
        self.positions = np.asarray(self.positions, dtype=np.float64).reshape(-1, 3)
        n = self.positions.shape[0]
        self.node_mass = np.broadcast_to(np.asarray(self.node_mass, dtype=np.float64), (n,)).copy()
        self.fixed = np.broadcast_to(np.asarray(self.fixed, dtype=bool), (n,)).copy()
        self.bars = np.asarray(self.bars, dtype=np.int64).reshape(-1, 2)
        self.cables = np.asarray(self.cables, dtype=np.int64).reshape(-1, 2)
        nb, ns = len(self.bars), len(self.cables)
        self.bar_mass = np.broadcast_to(np.asarray(self.bar_mass, dtype=np.float64), (nb,)).copy()
        self.cable_EA = np.broadcast_to(np.asarray(self.cable_EA, dtype=np.float64), (ns,)).copy()
        self.cable_rest_length = np.broadcast_to(
            np.asarray(self.cable_rest_length, dtype=np.float64), (ns,)
        ).copy()
        if self.cable_EA_compression is None:
            self.cable_EA_compression = np.zeros(ns)
        self.cable_EA_compression = np.broadcast_to(
            np.asarray(self.cable_EA_compression, dtype=np.float64), (ns,)
        ).copy()

    # ------------------------------------------------------------------ sizes
    @property
    def n_nodes(self) -> int:
        return self.positions.shape[0]

    @property
    def n_bars(self) -> int:
        return self.bars.shape[0]

    @property
    def n_cables(self) -> int:
        return self.cables.shape[0]

    def bar_name(self, k: int) -> str:
        i, j = self.bars[k]
        label = self.bar_names[k] if self.bar_names else f"bar {k}"
        return f"{label} (nodes {i}-{j})"

    def cable_name(self, k: int) -> str:
        i, j = self.cables[k]
        label = self.cable_names[k] if self.cable_names else f"cable {k}"
        return f"{label} (nodes {i}-{j})"

    # ------------------------------------------------------------------ geometry
    def bar_lengths(self, positions: np.ndarray | None = None) -> np.ndarray:
        x = self.positions if positions is None else positions
        return np.linalg.norm(x[self.bars[:, 1]] - x[self.bars[:, 0]], axis=-1)

    def cable_lengths(self, positions: np.ndarray | None = None) -> np.ndarray:
        x = self.positions if positions is None else positions
        return np.linalg.norm(x[self.cables[:, 1]] - x[self.cables[:, 0]], axis=-1)

    def cable_tensions(self, positions: np.ndarray | None = None) -> np.ndarray:
        """Axial force in each cable [N], positive in tension (Eq. 10, plus the compressive branch)."""
        s = self.cable_lengths(positions)
        L = self.cable_rest_length
        stretch = s - L
        return np.where(stretch > 0, self.cable_EA, self.cable_EA_compression) / L * stretch

    def class_k(self) -> int:
        """Largest number of bars meeting at one node (the paper's 'class')."""
        if self.n_bars == 0:
            return 0
        return int(np.bincount(self.bars.ravel(), minlength=self.n_nodes).max())

    def mass_matrix(self) -> np.ndarray:
        """The paper's nodal mass matrix M (n_nodes x n_nodes), Eq. (13) for bars plus lumped masses.

        A thin rod of mass m between nodes i, j contributes (m/6)[[2, 1], [1, 2]].
        """
        M = np.diag(self.node_mass.copy())
        for (i, j), m in zip(self.bars, self.bar_mass):
            M[i, i] += m / 3.0
            M[j, j] += m / 3.0
            M[i, j] += m / 6.0
            M[j, i] += m / 6.0
        return M

    # ------------------------------------------------------------------ validation
    def validate(self) -> "Network":
        """Check the input; raise :class:`NetworkError` naming the offending member and value."""
        n = self.n_nodes
        if n == 0:
            raise NetworkError("network has no nodes")
        bad = ~np.isfinite(self.positions)
        if bad.any():
            i = int(np.argwhere(bad)[0, 0])
            raise NetworkError(f"node {i}: position {self.positions[i].tolist()} is not finite")
        for name, arr in (("mass", self.node_mass),):
            bad = ~np.isfinite(arr) | (arr < 0)
            if bad.any():
                i = int(np.argmax(bad))
                raise NetworkError(f"node {i}: {name} = {arr[i]} kg must be finite and >= 0")
        # vectorised checks (a long column has 10^5 members); each message names the first offender
        for kind, pairs, namer in (("bar", self.bars, self.bar_name), ("cable", self.cables, self.cable_name)):
            pairs = np.asarray(pairs).reshape(-1, 2)
            out = np.flatnonzero(~((pairs >= 0) & (pairs < n)).all(axis=1))
            if out.size:
                i, j = pairs[out[0]]
                raise NetworkError(f"{kind} {int(out[0])}: node index {(int(i), int(j))} out of range 0..{n - 1}")
            same = np.flatnonzero(pairs[:, 0] == pairs[:, 1])
            if same.size:
                raise NetworkError(f"{namer(int(same[0]))}: joins node {pairs[same[0], 0]} to itself")
        # bars
        L = self.bar_lengths()
        m = self.bar_mass
        both = self.fixed[self.bars[:, 0]] & self.fixed[self.bars[:, 1]] if self.n_bars else np.zeros(0, bool)
        for k in np.flatnonzero(~(L > 0) | ~np.isfinite(m) | (m < 0) | both)[:1]:
            if not (L[k] > 0):
                raise NetworkError(f"{self.bar_name(k)}: length {L[k]} m must be > 0")
            if not np.isfinite(m[k]) or m[k] < 0:
                raise NetworkError(f"{self.bar_name(k)}: mass {m[k]} kg must be finite and >= 0")
            raise NetworkError(f"{self.bar_name(k)}: both ends are fixed; remove the bar")
        # cables
        for label, vals, unit in (("EA", self.cable_EA, "N"), ("rest length", self.cable_rest_length, "m")):
            for k in np.flatnonzero(~np.isfinite(vals) | ~(vals > 0))[:1]:
                raise NetworkError(f"{self.cable_name(k)}: {label} = {vals[k]} {unit} must be finite and > 0")
        c = self.cable_EA_compression
        for k in np.flatnonzero(~np.isfinite(c) | (c < 0))[:1]:
            raise NetworkError(f"{self.cable_name(k)}: EA_compression = {c[k]} N must be finite and >= 0")
        sl = self.cable_lengths()
        for k in np.flatnonzero(~(sl > 0))[:1]:
            raise NetworkError(f"{self.cable_name(k)}: current length {sl[k]} m must be > 0")
        # every free node needs inertia
        inertia = self.node_mass.copy()
        np.add.at(inertia, self.bars[:, 0], self.bar_mass)
        np.add.at(inertia, self.bars[:, 1], self.bar_mass)
        free_no_mass = (~self.fixed) & (inertia <= 0)
        if free_no_mass.any():
            i = int(np.argmax(free_no_mass))
            raise NetworkError(
                f"node {i}: free node has no mass (node mass {self.node_mass[i]} kg and no massive bar); "
                "give it mass or fix it"
            )
        # massive bars: the paper's consistent M is used only where massive bars do not share nodes
        massive = self.bar_mass > 0
        if massive.any():
            counts = np.bincount(self.bars[massive].ravel(), minlength=n)
            if counts.max() > 1:
                i = int(np.argmax(counts))
                raise NetworkError(
                    f"node {i}: {int(counts[i])} massive bars meet here; the consistent bar inertia "
                    "is supported where each node carries at most one massive bar (class-1 in massive "
                    "bars). For class-k networks put the mass on the nodes (bar_mass=0); note that lumping "
                    "m/2 on each end triples the bar's rotary inertia."
                )
        return self
