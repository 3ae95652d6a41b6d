"""Which T3 columns the warp-per-column step (:mod:`warp_tensegrity.sim.lanes.lanes`) takes, in
NumPy alone, so the policy decides without loading Warp: the lane map's shape (:func:`lane_shape`
on one warp, :func:`lane_map` also k warps per column for long columns),
a built batch (:func:`lane_support`) and a scene before any batch is built (:func:`lane_refusal`);
the two agree on column batches (tests/kernels/test_lanes.py)."""

from __future__ import annotations

import numpy as np

from ..options import ColumnParameters
from ..types import Base

WARP = 32
"""Lanes of a warp."""


def lane_shape(n_prisms: int, max_levels: int = 4) -> tuple[int, int] | None:
    """(P levels per lane, G lanes per column) for a column of ``n_prisms``; None if it needs more
    than ``max_levels`` levels per lane (a warp holds at most 32 P levels)."""
    n = max(int(n_prisms), 1)
    P = -(-n // WARP)
    if P > max_levels:
        return None
    lanes = -(-n // P)
    G = 1
    while G < lanes:
        G *= 2
    return P, G


MAX_LEVELS_PER_LANE = 4
"""Most levels (prisms) a lane holds in registers: 128 prisms a warp."""
MAX_RIGID_LEVELS_PER_LANE = 2
"""Most levels per lane once a column has rigid base links (their 3 x 3 blocks): 64 prisms a warp."""
MAX_BLOCK_LEVELS_PER_LANE = 4
"""Most levels per lane of a flexible-base column on k warps (:func:`lane_map`; benchmarks/gpu_issue33.sh
PART=levels measures other values)."""
WIDE_BLOCK_LANES = 256
"""A flexible-base block that would hold the most levels per lane doubles its lanes up to this many
(8 warps). On an H200, FB fp32, B = 4,096 (benchmarks/results/issue33_h200_third, call 3): 500
prisms on 256 lanes of 2 levels step 8.55e6 column-steps/s, against 4.10e6 on 128 lanes of 4. At
1,000 prisms, 512 lanes of 2 levels (128 registers a thread) lose to 256 of 4: 2.38e6 against 2.84e6
(issue33_h200_sixth, call 6)."""
MAX_COLUMN_LANES = 512
"""Most lanes (CUDA threads) of a column longer than a warp holds: one block of 32 k threads per
column, k <= 16. 512 threads fill an SM's 65,536 registers at 128 each (the rigid-base kernel then
spills more); 1,024 would leave 64. Flexible bases up to 2,048 prisms, rigid up to 1,024."""


RIGID_FP64_ONE_LEVEL_LANES = MAX_COLUMN_LANES
"""A rigid-base fp64 column of more than 32 prisms and at most this many takes 1 level per lane on k
warps (one block: pure fp64, no mixed factor) instead of 2 levels; longer ones keep 2 levels on
:data:`MAX_COLUMN_LANES` lanes. On an H200 (benchmarks/results/issue33_h200_sixth), column-steps/s,
1 level against 2: 50 prisms 6.33e6 against 4.99e6 (B = 16,384; one warp of 2 levels runs the mixed
kernel, which spills 17.6 KB of loads a thread: lanes_ptxas_sm90.json); 100 prisms 2.84e6 against
1.91e6 (B = 16,384); 200 prisms 7.83e5 against 5.45e5 and 300 prisms 2.09e5 against 1.44e5 (B =
4,096). The flexible-base fp64 kernel gains nothing (2.15e7 both, 50 prisms) and the fp32 kernels
lose (FB 5.9e7 against 1.71e8, RB 1.94e7 against 2.93e7)."""


def lane_map(n_prisms: int, rigid: bool = False, precision: str | None = None) -> tuple[int, int] | None:
    """(P levels per lane, G lanes per column) of the lane step for a column of ``n_prisms``
    (``rigid``: rigid base links, at most :data:`MAX_RIGID_LEVELS_PER_LANE` levels per lane;
    ``precision``: 'fp32' or 'fp64', None: either, where the map is the same): one
    warp's :func:`lane_shape` where it fits, else k warps per column (G = 32 k, a power of two): the
    fewest lanes at the most levels, then the fewest levels that fill them; a flexible-base block at
    the most levels doubles its lanes up to :data:`WIDE_BLOCK_LANES`; rigid bases in fp64 take one
    level per lane up to :data:`RIGID_FP64_ONE_LEVEL_LANES` lanes. None above
    :data:`MAX_COLUMN_LANES` lanes."""
    most = MAX_RIGID_LEVELS_PER_LANE if rigid else MAX_LEVELS_PER_LANE
    one = lane_shape(n_prisms, most)
    if rigid and precision == "fp64" and WARP < n_prisms <= RIGID_FP64_ONE_LEVEL_LANES:
        G = 2 * WARP
        while G < n_prisms:
            G *= 2
        return 1, G
    if one is not None:
        return one
    n = int(n_prisms)
    most = MAX_RIGID_LEVELS_PER_LANE if rigid else MAX_BLOCK_LEVELS_PER_LANE
    G = WARP
    while G * most < n:
        G *= 2
    if G > MAX_COLUMN_LANES:
        return None
    if not rigid and -(-n // G) == most and 2 * G <= WIDE_BLOCK_LANES:
        G *= 2  # the registers of 4 levels spill: twice the lanes at half the levels
    return -(-n // G), G


def _too_long(n: int, rigid: bool) -> str:
    most = MAX_RIGID_LEVELS_PER_LANE if rigid else MAX_LEVELS_PER_LANE
    return (f"{'rigid bases with ' if rigid else ''}{n} prisms need more than {most} levels per lane of "
            f"{MAX_COLUMN_LANES} lanes (a block of {MAX_COLUMN_LANES // WARP} warps holds "
            f"{most * MAX_COLUMN_LANES} prisms)")


def _column_members(n: int, hand: np.ndarray):
    """Bars, cross cables and base members of an n-prism column in column_batch's order."""
    m = np.repeat(np.arange(n), 3)
    k = np.tile(np.arange(3), n)
    bars = np.stack([3 * m + k, 3 * m + 3 + k], axis=1)
    kk = np.where(np.repeat(hand, 3) > 0, (k + 2) % 3, (k + 1) % 3)
    cross = np.stack([3 * m + k, 3 * m + 3 + kk], axis=1)
    lv = np.repeat(np.arange(n + 1), 3)
    kb = np.tile(np.arange(3), n + 1)
    base = np.stack([3 * lv + kb, 3 * lv + (kb + 1) % 3], axis=1)
    return bars, cross, base


def _uniform(a: np.ndarray) -> bool:
    """Every member of a kind holds the same value in each column ((Bp, k) arrays)."""
    return a.shape[1] == 0 or bool(np.all(a == a[:, :1]))


def lane_support(batch) -> str | None:
    """None if the lane step takes this batch, else why not (one sentence)."""
    ln = batch.level_nodes
    if ln is None:
        return "not a T3 column (no levels)"
    n = ln.shape[0] - 1
    if n < 1 or not np.array_equal(ln, np.arange(3 * (n + 1)).reshape(n + 1, 3)):
        return "the column's nodes are not numbered level by level"
    if lane_map(n) is None:
        return _too_long(n, False)
    if batch.positions.shape[0] != 3 * (n + 1):
        return "nodes other than the column's"
    if np.any(batch.constraint_mass != 0):
        return "massive bars (consistent bar inertia couples node pairs)"
    fixed = np.zeros(3 * (n + 1), dtype=bool)
    fixed[:3] = True
    if not np.array_equal(batch.fixed, fixed):
        return "a boundary other than the clamped level 0"
    # handedness from the cross cables; then every member list must be column_batch's
    if batch.cables.shape[0] != 6 * n + 3:
        return "a member layout other than column_batch's"
    top = batch.cables[: 3 * n : 3, 1] - 3 * np.arange(1, n + 1)
    hand = np.where(top == 2, 1, -1)
    bars, cross, base = _column_members(n, hand)
    if not np.array_equal(batch.cables, np.concatenate([cross, base])):
        return "a member layout other than column_batch's"
    active = batch.constraint_active
    if np.array_equal(batch.constraints, bars):
        if np.any(active != 1):
            return "inactive bars"
    else:
        # rigid base links: prism m's bars, then the links of level m + 1 (column_batch's order)
        links = base[3:].reshape(n, 3, 2)
        if not np.array_equal(batch.constraints, np.concatenate([bars.reshape(n, 3, 2), links], axis=1).reshape(-1, 2)):
            return "a constraint layout other than column_batch's"
        if lane_map(n, True) is None:
            return _too_long(n, True)
        a = active.reshape(active.shape[0], n, 6)
        if np.any(a[:, :, :3] != 1):
            return "inactive bars"
        if np.any(a[:, :, 3:] != a[:, :1, 3:4]) or np.any((a[:, 0, 3] != 0) & (a[:, 0, 3] != 1)):
            return "a column whose base links are partly rigid"
    m = batch.node_mass.reshape(batch.node_mass.shape[0], n + 1, 3)
    if np.any(m != m[:, :, :1]):
        return "nodes of one level with different masses"
    z = batch.positions[:, 2].reshape(n + 1, 3)
    if np.any(z != z[:, :1]):
        return "a base that is not horizontal"
    c, b = slice(0, 3 * n), slice(3 * n, None)
    for name in ("cable_EA", "cable_EA_compression"):
        if not _uniform(getattr(batch, name)[:, c]):
            return f"cross cables of one column with different {name}"
    for name in ("cable_EA", "cable_EA_compression"):
        if not _uniform(getattr(batch, name)[:, b]):
            return f"base members of one column with different {name}"
    return None


def lane_refusal(config, params: dict, n_prisms: int | None = None) -> str | None:
    """Why the lane step would not take T3 columns of scene ``config`` with the per-column ``params``
    when ``n_prisms`` of their prisms are simulated (default: all); None if it takes them. The
    scene-level form of :func:`lane_support`: massless bars, at most ``MAX_LEVELS_PER_LANE`` levels
    per lane of :data:`MAX_COLUMN_LANES` lanes, and at most ``MAX_RIGID_LEVELS_PER_LANE`` once a column has rigid
    bases (base_rigidity = 1) (:func:`lane_map`)."""
    n = config.n_prisms if n_prisms is None else int(n_prisms)
    rigid = np.any(np.asarray(params.get("base_rigidity", ColumnParameters.base_rigidity), dtype=np.float64) >= Base.RIGID)
    if rigid and lane_map(n, True) is None:
        return _too_long(n, True)
    if config.bar_mass > 0:
        return "massive bars (consistent bar inertia couples node pairs)"
    if np.ndim(params.get("cable_EA", 0.0)) == 2:
        # the lane step holds one cross-cable and one base-member EA per column (sim/lanes/lanes.py)
        return "a cable_EA profile along the column (the lane step takes one EA per column)"
    if lane_map(n) is None:
        return _too_long(n, False)
    return None
