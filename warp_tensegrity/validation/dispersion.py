"""Linear dispersion omega(k) of the prestressed periodic column, from a Bloch unit cell.

Float64 NumPy on the host; SI units (k [rad m-1], omega [rad s-1]). The cell is one level (its
three nodes, 9 coordinates) of an infinite column of equal prisms, one handedness. The column is
screw-periodic: level n+1 is level n turned by -/+ twist (right/left) about the axis and lifted
by h0. In each level's own turned frame, the tangent stiffness of :mod:`.linear` (cables, base
members and the bars' geometric terms) is the same for every level, so a Bloch wave
w_n = w exp(i k n h0) gives the 9 x 9 Hermitian problem

    D(k) = K_00 + K_01 R e^(i k h0) + K_0,-1 R^T e^(-i k h0),    D w = omega^2 M w,

R the level-to-level turn (block diagonal over the nodes). The rigid members of one cell (its
three bars; with rigid bases also its three base links) are constraints G(k) w = 0, handled by
projecting onto the null space of G(k). Where a rigid motion adds a null vector (a rigid turn of
every level does at k = 0), k is moved by 1e-9 pi/h0, so every k has the same branches. Long
axial-torsional waves sit at k -> 0 in these frames (a rigid translation across the axis shows up
at k h0 = twist instead).

The cell is built from :mod:`.reference_column` (the paper's geometry and closed-form member laws),
independently of the engine's scene builder: the bands are a reference the simulated column can be
held against (:func:`mode_frequencies`, ``check_dispersion``).

The axial impact excites only the 3-fold symmetric motion (each node's displacement the turn of
its neighbour's), so the **symmetric sector** (3 coordinates per level) is returned on its own:
with rigid bases it has one branch, omega = omega_c |sin(k h0/2)| exactly (the 1-D chain of
:mod:`.closed_forms`); with flexible bases two.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..scene.columns import ColumnConfig
from .constrained import ConstrainedNetwork
from .linear import tangent_stiffness
from .reference_column import TWIST, reference_column

__all__ = ["BlochCell", "bloch_cell", "Bands", "bands", "ringing_frequency", "mode_frequencies", "chain_wavenumbers"]

_CELL_LEVEL = 2  # an interior level of a 4-prism column: every member it touches is interior


def _rot_z(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


@dataclass
class BlochCell:
    """Blocks of one level of a screw-periodic column (9 coordinates: 3 nodes x xyz)."""

    K0: np.ndarray
    """(9, 9) stiffness of the level on itself [N m-1]."""
    K1: np.ndarray
    """(9, 9) stiffness of the level on the next level up, in the next level's frame [N m-1]."""
    M: np.ndarray
    """(9, 9) mass of the level [kg]."""
    G0: np.ndarray
    """(n_c, 9) Jacobian of the cell's rigid members on this level's coordinates [m]."""
    G1: np.ndarray
    """(n_c, 9) the same on the next level's coordinates, in its frame [m]."""
    sym: np.ndarray
    """(9, 3) basis of the 3-fold symmetric motions (orthonormal)."""
    height: float
    """h0 [m]."""

    def dynamic(self, k: float):
        """(D(k), G(k)): the Bloch stiffness [N m-1] and constraint Jacobian at k [rad m-1]."""
        e = np.exp(1j * k * self.height)
        return self.K0 + self.K1 * e + self.K1.T * np.conj(e), self.G0 + self.G1 * e


def bloch_cell(config: ColumnConfig, prestrain: float, base_rigidity: float, cable_EA: float | None = None,
               unit_mass: float | None = None) -> BlochCell:
    """The Bloch cell of the column ``config`` describes (its n_prisms is ignored; one handedness), built
    from :func:`.reference_column.reference_column` (the paper's geometry and closed-form member laws),
    not from the engine's scene builder."""
    hand_text = config.handedness
    if hand_text not in ("right", "left") and len(set(hand_text.upper())) > 1:
        raise ValueError(f"handedness = {hand_text!r}: a one-level cell needs one handedness")
    if abs(config.twist - TWIST) > 1e-12:
        raise ValueError(f"twist = {config.twist!r}: the Bloch cell is that of the regular minimal prism (5*pi/6)")
    hand = 1.0 if hand_text.upper().startswith("R") else -1.0  # 'right' or 'RR...R'; else left
    col = reference_column(2 * _CELL_LEVEL, config.radius, config.height,
                           config.cable_EA if cable_EA is None else float(cable_EA),
                           config.unit_mass if unit_mass is None else float(unit_mass), prestrain, base_rigidity,
                           handedness="right" if hand > 0 else "left")
    net = col.network
    rs = ConstrainedNetwork(net)
    K = tangent_stiffness(net, _rs=rs)
    G = rs.jacobian(net.positions)
    dof = {lvl: np.concatenate([3 * rs._slot[i] + np.arange(3) for i in col.level_nodes[lvl]])
           for lvl in (_CELL_LEVEL, _CELL_LEVEL + 1)}
    R = np.kron(np.eye(3), _rot_z(-hand * TWIST))  # this level's frame -> the next one's
    here, up = dof[_CELL_LEVEL], dof[_CELL_LEVEL + 1]
    # the cell's rigid members: the bars of the prism above the level, and its own base links
    cell_nodes = set(col.level_nodes[_CELL_LEVEL].tolist())
    rows = [b for b, (i, j) in enumerate(net.bars)
            if (i in cell_nodes and (j in cell_nodes or j in col.level_nodes[_CELL_LEVEL + 1]))]
    angles = -2.0 * np.pi * np.arange(3) / 3.0  # node j sits at angle[0] - 2 pi j / 3
    sym = np.concatenate([_rot_z(a) for a in angles]) / np.sqrt(3.0)
    return BlochCell(K0=K[np.ix_(here, here)], K1=K[np.ix_(here, up)] @ R, M=rs.M[np.ix_(here, here)],
                     G0=G[np.ix_(rows, here)], G1=G[np.ix_(rows, up)] @ R, sym=sym, height=col.height)


def _rank(G: np.ndarray, rtol: float = 1e-9) -> int:
    sv = np.linalg.svd(G, compute_uv=False)
    return int(np.sum(sv > rtol * sv[0])) if sv.size else 0


def _omega(D, G, M, rank: int) -> np.ndarray:
    from scipy.linalg import eigh

    Z = np.linalg.svd(G)[2][rank:].conj().T if G.shape[0] else np.eye(D.shape[0])
    Dr, Mr = Z.conj().T @ D @ Z, Z.conj().T @ M @ Z
    w2 = eigh(0.5 * (Dr + Dr.conj().T), 0.5 * (Mr + Mr.conj().T), eigvals_only=True)
    return np.sign(w2) * np.sqrt(np.abs(w2))


@dataclass
class Bands:
    """Branches omega(k) of the periodic column [rad s-1], ascending at each k."""

    k: np.ndarray
    """(n_k,) Bloch wavenumbers [rad m-1]."""
    omega: np.ndarray
    """(n_k, n_branches) every branch (signed: negative = unstable)."""
    omega_symmetric: np.ndarray
    """(n_k, n_sym) the 3-fold symmetric (axial-torsional) branches: what an axial impact excites."""
    height: float
    """h0 [m]."""

    def long_wave_speed(self) -> float:
        """omega/k of the lowest symmetric branch at the smallest |k| > 0 [m s-1]."""
        i = int(np.argmin(np.where(self.k != 0, np.abs(self.k), np.inf)))
        return float(self.omega_symmetric[i, 0] / abs(self.k[i]))


def bands(config: ColumnConfig, prestrain: float, base_rigidity: float, k=None, n_k: int = 121,
          cable_EA: float | None = None, unit_mass: float | None = None) -> Bands:
    """omega(k) over ``k`` [rad m-1] (default: ``n_k`` points over the Brillouin zone 0 .. pi/h0)."""
    cell = bloch_cell(config, prestrain, base_rigidity, cable_EA, unit_mass)
    k = np.linspace(0.0, np.pi / cell.height, n_k) if k is None else np.atleast_1d(np.asarray(k, dtype=float))
    S = cell.sym
    G_any = cell.dynamic(1.0 / cell.height)[1]  # k h0 = 1: no rigid motion there
    generic = [_rank(G_any), _rank(G_any @ S)]
    full, sym = [], []
    for kk in k:
        D, G = cell.dynamic(kk)
        if [_rank(G), _rank(G @ S)] != generic:  # a rigid motion adds a null vector at this k: step off it
            D, G = cell.dynamic(kk + 1e-9 * np.pi / cell.height)
        full.append(_omega(D, G, cell.M, generic[0]))
        sym.append(_omega(S.T @ D @ S, G @ S, S.T @ cell.M @ S, generic[1]))
    return Bands(k, np.array(full), np.array(sym), cell.height)


def ringing_frequency(strain, time, prism: int = -1, skip: int = 1) -> float:
    """Angular frequency [rad s-1] at which prism ``prism`` (default: the struck one) rings after
    the impact: pi over the mean time between its strain's sign changes, the first ``skip`` left out.
    A chain's struck end rings at its cut-off (J_1(omega_c t) in the RB chain: its zeros tend to a
    spacing of pi, the first ten are 0.3 % wider). NaN with fewer than 3 sign changes.
    ``strain`` (n_time, n_prisms), ``time`` (n_time,) [s]."""
    y = np.asarray(strain, dtype=float)[:, prism]
    t = np.asarray(time, dtype=float)
    i = np.flatnonzero(np.signbit(y[1:]) != np.signbit(y[:-1]))
    tc = t[i] + y[i] / (y[i] - y[i + 1]) * (t[i + 1] - t[i])  # linear interpolation of each crossing
    tc = tc[skip:]
    if tc.size < 3:
        return float("nan")
    return float(np.pi * (tc.size - 1) / (tc[-1] - tc[0]))


def chain_wavenumbers(n_prisms: int, height: float) -> np.ndarray:
    """(n_prisms,) Bloch wavenumbers [rad m-1] of the modes of a clamped column struck at a half-mass end:
    k_j h0 = (2j - 1) pi / (2 N), j = 1..N. The half-mass end is the mirror plane of a column twice as long
    and clamped at both ends, so the RB chain's modes are exactly its branch at these k (omega_c
    sin(k_j h0/2)); a flexible-base column's soft modes are within ~3e-5 of its soft branch there."""
    return (2.0 * np.arange(1, n_prisms + 1) - 1.0) * np.pi / (2.0 * n_prisms * height)


def mode_frequencies(strain, time, n_modes: int) -> np.ndarray:
    """The ``n_modes`` angular frequencies [rad s-1] of the undamped modes in a record, ascending: a
    matrix pencil (Hua & Sarkar 1990) over every prism's record at once. ``strain`` (n_time, n_prisms)
    sampled at the uniform ``time`` (n_time,) [s]; the modes with the largest singular values (the
    2 n_modes dominant exponentials, each mode a pair e^(+-i omega t)) are kept. Hand-written: SciPy has
    no matrix pencil, and ~10 lines of NumPy do it."""
    y = np.asarray(strain, dtype=float)
    dt = float(np.mean(np.diff(time)))
    L = y.shape[0] // 2  # the pencil's window: half the record
    X = np.vstack([np.lib.stride_tricks.sliding_window_view(y[:, c], L + 1) for c in range(y.shape[1])])
    V = np.linalg.svd(X, full_matrices=False)[2][: 2 * n_modes].T  # the signal subspace
    z = np.linalg.eigvals(np.linalg.pinv(V[:-1]) @ V[1:])
    return np.sort(np.abs(np.angle(z)))[::2][:n_modes] / dt
