"""How far the base-member modes of a column sit above the band of its rigid-base motion: the
per-case diagnostic of the limit beta -> 1 that sweeps record (``base_mode_ratio``,
``beta_limit_flag``; ``docs/impact.md``).

With elastic bases (0 <= beta < 1) each level's base triangle adds three in-plane modes whose
stiffness is the base members' EA/((1-beta) L). They form a band whose top grows as
(1-beta)^-1/2 and whose lowest mode, a long-wave mode pinned at the clamp, sits at about
0.5/n of that top (n prisms). The rigid-base column (beta = 1) has no such modes; the
frequencies its motion fills reach the top of its own band, omega_RB (127 rad/s for the
paper's prism at p = 0.002, nearly independent of p).

The limit beta -> 1 is the stiff-spring limit of Rubin and Ungar: the elastic column follows
the rigid-base motion, with a difference ~ (1 - beta), when the stiff modes are far above the
frequencies that drive them. The base members are driven by the constraint forces of the rigid
motion, which hold terms quadratic in the velocities (the bars' and links' |b'|^2), so by
frequencies up to 2 omega_RB. Hence the criterion

    base_mode_ratio = omega_base_min / omega_RB,   scale-separated  <=>  ratio >= BAND_FACTOR = 2.

Below it the limit is pre-asymptotic: the difference to beta = 1 need not fall ~ (1 - beta)
and can stall over a decade (measured in analysis/beta_limit.py, part E). The transfer into the
base modes is nonlinear, and it was seen only where the pulse's compression reached at least
``LOCK_FRACTION`` = 1/2 of the rigid-base kinematic lock (50 prisms, p = 0.002: compression 0.037
converged 9-10.5x per decade from 1 - beta = 1e-2 to 1e-5 with the base modes within reach;
0.068 slowed to 6x over one decade, 0.0999 and 0.199 stalled at 1.7-1.8x). The per-case flag is
therefore

    beta_limit_flag = slow_convergence_possible  <=>  ratio < BAND_FACTOR  and
                                                      max_compression >= LOCK_FRACTION x lock.

All frequencies scale with sqrt(EA / m) at fixed prestrain, geometry and beta, so the ratio
depends on the geometry, n, prestrain and beta only (not on cable_EA or unit_mass). Columns
longer than ``MAX_EXACT_PRISMS`` are evaluated on a column of that length, the lowest base mode
scaled by n_exact / n (its 1/n law) and the RB band top taken as is (it converges with n).

Float64 NumPy on the host. The modes are those of the linearised constrained system about the
reference state (:func:`modes`: tangent stiffness of the cables and of the bars' prestress on the
tangent space of the bar constraints). This module computes them itself, so the sweeps that
record the flag do not depend on the validation gallery (:mod:`warp_tensegrity.validation`); ``tests/scene/test_base_modes.py``
checks them against :func:`warp_tensegrity.validation.linear.modal_analysis`.
"""

from __future__ import annotations

import dataclasses
from functools import lru_cache

import numpy as np

from ..runtime import drive
from ..types import BETA_LIMIT_FLAGS
from .blas import one_blas_thread
from .columns import build_column, column_topology
from .impact import kinematic_lock_strain

__all__ = ["BAND_FACTOR", "BETA_LIMIT_FLAGS", "LOCK_FRACTION", "MAX_EXACT_PRISMS", "base_mode_ratio", "base_mode_ratios",
           "base_mode_ratios_one_thread", "beta_limit_measures", "lowest_base_mode", "modes", "rb_band_top"]

BAND_FACTOR = 2.0
"""Scale separation the regular limit needs: lowest base mode >= BAND_FACTOR x RB band top."""
MAX_EXACT_PRISMS = 60
"""Longer columns are evaluated on this many prisms, with the lowest base mode scaled as 1/n."""
LOCK_FRACTION = 0.5
"""... and the pulse's compression reaches this fraction of the kinematic lock."""


class _Geometry:
    """A network's nodes, clamps, bars and masses, hashed and compared by their bytes: the key of
    :func:`_constraint_basis`, which only they determine (not the cables, prestrain or beta)."""

    __slots__ = ("net", "key")

    def __init__(self, net):
        self.net = net
        parts = (np.asarray(net.positions, dtype=np.float64), np.asarray(net.fixed, dtype=bool),
                 np.asarray(net.bars, dtype=np.int64), np.asarray(net.node_mass, dtype=np.float64),
                 np.asarray(net.bar_mass, dtype=np.float64))
        self.key = tuple((a.shape, a.tobytes()) for a in parts)

    def __hash__(self):
        return hash(self.key)

    def __eq__(self, other):
        return isinstance(other, _Geometry) and self.key == other.key


@lru_cache(maxsize=8)
def _constraint_basis(geom: _Geometry):
    """(free nodes, node -> free slot, bar matrix G, tangent basis Z, M^-1/2 on it) of a network:
    the same for every prestrain and base rigidity of a column with elastic bases (and for every
    prestrain with rigid ones), so a sweep computes them once per base class. Read-only arrays."""
    net = geom.net
    x = np.asarray(net.positions, dtype=np.float64)
    free_nodes = np.flatnonzero(~np.asarray(net.fixed, dtype=bool))
    slot = -np.ones(len(x), dtype=np.int64)
    slot[free_nodes] = np.arange(len(free_nodes))
    nd = 3 * len(free_nodes)
    bars = np.asarray(net.bars).reshape(-1, 2)
    G = np.zeros((len(bars), nd))
    for k, (i, j) in enumerate(bars):
        b = x[j] - x[i]
        for s_, g in ((slot[i], 1.0), (slot[j], -1.0)):
            if s_ >= 0:
                G[k, 3 * s_ : 3 * s_ + 3] -= g * b
    if len(bars):
        _, sv, vt = np.linalg.svd(G)
        Z = vt[int(np.sum(sv > 1e-10 * sv[0])):].T
    else:
        Z = np.eye(nd)
    M = np.kron(np.asarray(net.mass_matrix())[np.ix_(free_nodes, free_nodes)], np.eye(3))
    mu, U = np.linalg.eigh(Z.T @ M @ Z)
    Mih = (U / np.sqrt(mu)) @ U.T
    for a in (free_nodes, slot, G, Z, Mih):
        a.flags.writeable = False
    return free_nodes, slot, G, Z, Mih


def _pair_blocks(members: np.ndarray, slot: np.ndarray, nd: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Flat indices into an (nd x nd) matrix of the four 3x3 blocks (ii, ij, ji, jj) of each member
    (i, j), members in order, and each block's sign (+1, -1, -1, +1); True where both ends are free.
    Shapes (n, 4, 3, 3), (4,), (n, 4)."""
    si, sj = slot[members[:, 0]], slot[members[:, 1]]
    sa = np.stack([si, si, sj, sj], axis=1)  # rows, in the order of a double loop over (i, j)
    sb = np.stack([si, sj, si, sj], axis=1)
    r = np.arange(3)
    flat = (3 * sa[:, :, None, None] + r[:, None]) * nd + 3 * sb[:, :, None, None] + r
    return flat, np.array([1.0, -1.0, -1.0, 1.0]), (sa >= 0) & (sb >= 0)


def modes(net) -> tuple[np.ndarray, np.ndarray]:
    """(omega [rad s-1] ascending, base share) of a network's linearised constrained modes about its
    positions. ``base share``: the part of each mode's stiffness energy in the axial stretch of the
    members with both ends on one level (the base members). Cables exactly at their rest length
    take their tension branch; bars add their prestress lam (I, -I; -I, I), lam from the least-
    squares balance of the cable forces."""
    free_nodes, slot, G, Z, Mih = _constraint_basis(_Geometry(net))
    x = np.asarray(net.positions, dtype=np.float64)
    nd = 3 * len(free_nodes)
    bars, cables = np.asarray(net.bars).reshape(-1, 2), np.asarray(net.cables).reshape(-1, 2)
    d = x[cables[:, 1]] - x[cables[:, 0]]
    length = np.linalg.norm(d, axis=1)
    rest = np.asarray(net.cable_rest_length, dtype=np.float64)
    at_rest = np.abs(length - rest) <= 1e-12 * rest
    k_br = np.where(at_rest | (length > rest), np.asarray(net.cable_EA, float), np.asarray(net.cable_EA_compression, float)) / rest
    tension = np.where(at_rest, 0.0, k_br * (length - rest))
    e = d / length[:, None]
    # K and f are scattered with np.add.at, which adds its entries one after another in the order
    # given: members in order, as a loop over them would, so every sum is rounded the same way
    # (bit-identical to the per-member loop; tests/scene/test_base_modes.py keeps that loop).
    f = np.zeros(nd)
    ends = slot[cables]  # (n, 2): +1 at i, -1 at j
    fv = (np.array([1.0, -1.0]) * tension[:, None])[:, :, None] * e[:, None, :]
    fi = 3 * ends[:, :, None] + np.arange(3)
    np.add.at(f, fi[ends >= 0], fv[ends >= 0])
    eye = np.eye(3)
    ee = e[:, :, None] * e[:, None, :]
    blk = k_br[:, None, None] * ee + (tension / length)[:, None, None] * (eye - ee)
    flat, sign, ok = _pair_blocks(cables, slot, nd)
    idx, val = [flat[ok]], [(sign[:, None, None] * blk[:, None])[ok]]
    lam = np.linalg.lstsq(G.T, f, rcond=None)[0] if len(bars) else np.zeros(0)
    flat, sign, ok = _pair_blocks(bars, slot, nd)
    idx.append(flat[ok])
    val.append((sign[:, None, None] * (lam[:, None, None] * eye)[:, None])[ok])
    K = np.zeros((nd, nd))
    np.add.at(K.reshape(-1), np.concatenate(idx).reshape(-1), np.concatenate(val).reshape(-1))
    K = 0.5 * (K + K.T)
    H = Mih @ (Z.T @ K @ Z) @ Mih
    w2, Y = np.linalg.eigh(0.5 * (H + H.T))
    shapes = (Z @ (Mih @ Y)).T.reshape(len(w2), -1, 3)  # u^T M u = 1, free nodes
    base = np.abs(d[:, 2]) <= 1e-12 * np.abs(d).max()
    u = np.zeros((len(w2), len(x), 3))
    u[:, free_nodes] = shapes
    ext = np.einsum("mci,ci->mc", u[:, cables[base, 1]] - u[:, cables[base, 0]], e[base])
    e_base = 0.5 * (k_br[base] * ext**2).sum(axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        share = np.where(w2 > 0, e_base / (0.5 * w2), 0.0)
    return np.sign(w2) * np.sqrt(np.abs(w2)), share


@lru_cache(maxsize=8)
def _topology(config):
    """The column's topology and reference positions: shared by every prestrain and base rigidity."""
    return column_topology(config)


@lru_cache(maxsize=256)
def _omegas(config, prestrain: float, base_rigidity: float) -> tuple[float, float]:
    """(lowest base-member mode, largest mode) [rad s-1] of the column ``config``."""
    net = build_column(config, prestrain=prestrain, v0=0.0, base_rigidity=base_rigidity, topology=_topology(config),
                       check_equilibrium=False)  # the reference state's residual: not needed here
    omega, share = modes(net.network)
    if base_rigidity >= 1.0:
        return float("inf"), float(omega.max())
    wb = omega[share > 0.5]
    return (float(wb.min()) if wb.size else float("nan")), float(omega.max())


def _exact_config(config):
    n = int(config.n_prisms)
    m = min(n, MAX_EXACT_PRISMS)
    return dataclasses.replace(config, n_prisms=m), m / n


def lowest_base_mode(config, prestrain: float, base_rigidity: float) -> float:
    """Lowest base-member mode omega [rad s-1] of the column (inf at beta = 1: no base modes).
    A mode is a base-member mode when the base members' stretch holds over half its energy."""
    cfg, scale = _exact_config(config)
    w, _ = _omegas(cfg, float(prestrain), float(base_rigidity))
    return w * scale


def rb_band_top(config, prestrain: float) -> float:
    """Largest mode omega [rad s-1] of the rigid-base (beta = 1) column: the top of the RB band."""
    cfg, _ = _exact_config(config)
    return _omegas(cfg, float(prestrain), 1.0)[1]


def base_mode_ratio(config, prestrain: float, base_rigidity: float) -> float:
    """omega_base_min / omega_RB [1]: inf at beta = 1."""
    if base_rigidity >= 1.0:
        return float("inf")
    return lowest_base_mode(config, prestrain, base_rigidity) / rb_band_top(config, prestrain)


def base_mode_ratios(config, params: dict, n_columns: int) -> np.ndarray:
    """(n_columns,) :func:`base_mode_ratio` of every column from its ``prestrain`` and ``base_rigidity``
    (arrays or scalars; defaults 0), NaN at beta = 1; a prestrain profile takes the smaller ratio of
    its two extremes (the flag errs toward caution). Modes are computed once per distinct pair. It
    reads the parameters only, so a sweep on a GPU computes it while its shard steps
    (:func:`base_mode_ratios_steps`, :mod:`warp_tensegrity.sweep.shard`)."""
    return drive(base_mode_ratios_steps(config, params, n_columns))


def base_mode_ratios_one_thread(config, params: dict, n_columns: int) -> np.ndarray:
    """:func:`base_mode_ratios` on one BLAS thread (:mod:`.blas`), as a GPU sweep computes them: in a
    process beside the stepping (:mod:`warp_tensegrity.sweep.beside`), or in turns with it."""
    with one_blas_thread():
        return base_mode_ratios(config, params, n_columns)


def base_mode_ratios_steps(config, params: dict, n_columns: int):
    """:func:`base_mode_ratios` as a generator that yields after each distinct pair and returns the
    ratios: a driver interleaves it with the stepping (:func:`warp_tensegrity.engine.run_batches`)."""
    p = np.asarray(params.get("prestrain", 0.0), dtype=np.float64)
    b = np.broadcast_to(np.asarray(params.get("base_rigidity", 0.0), dtype=np.float64), (n_columns,))
    ratio = np.full(n_columns, np.nan)
    ends = (p.min(axis=1), p.max(axis=1)) if p.ndim == 2 else (np.broadcast_to(p, (n_columns,)),)
    for p in ends:
        r = np.full(n_columns, np.nan)
        for pi, bi in {(float(x), float(y)) for x, y in zip(p, b) if y < 1.0}:
            r[(p == pi) & (b == bi)] = base_mode_ratio(config, pi, bi)
            yield
        ratio = r if p is ends[0] else np.fmin(ratio, r)
    return ratio


def beta_limit_measures(config, params: dict, n_columns: int, max_compression,
                        ratio: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """Per column: ``base_mode_ratio`` (float64, NaN at beta = 1, where there are no base modes)
    and ``beta_limit_flag`` (int8, :data:`BETA_LIMIT_FLAGS`) from the columns' ``prestrain`` and
    ``base_rigidity`` (arrays or scalars; defaults 0) and their ``max_compression`` (NaN: the
    flag assumes the lock was reached). ``ratio``: :func:`base_mode_ratios` of these columns,
    computed already; None: computed here."""
    b = np.broadcast_to(np.asarray(params.get("base_rigidity", 0.0), dtype=np.float64), (n_columns,))
    qmax = np.broadcast_to(np.asarray(max_compression, dtype=np.float64), (n_columns,))
    lock = -kinematic_lock_strain(config.radius, config.height, config.twist)
    if ratio is None:
        ratio = base_mode_ratios(config, params, n_columns)
    driven = ~(qmax < LOCK_FRACTION * lock)  # NaN counts as driven
    flag = np.where(b >= 1.0, BETA_LIMIT_FLAGS.index("rigid_bases"),
                    np.where((ratio < BAND_FACTOR) & driven, BETA_LIMIT_FLAGS.index("slow_convergence_possible"),
                             BETA_LIMIT_FLAGS.index("regular")))
    return {"base_mode_ratio": ratio, "beta_limit_flag": flag.astype(np.int8)}
