"""Host side of the one-warp-per-column step (:mod:`.lanes`): which batches it takes, its lane
arrays, and its launches. The Integrator drives it like the fused step (same ``launch`` /
``advance_counter`` / ``load`` interface).

It takes T3 columns with flexible or elastic bases (every base member a cable, beta < 1), lumped
masses and a column that fits a warp (at most :data:`MAX_LEVELS_PER_LANE` levels per lane, so
128 prisms). Rigid bases (their ring links couple the three bar chains into a 6 x 6 block chain),
massive bars and other networks run the other paths; :func:`lane_support` says why.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import warp as wp

from .lanes import WARP, lane_shape, make_lane_kernel

if TYPE_CHECKING:
    from ..model import Model
    from ..scene.batch import NetworkBatch

MAX_LEVELS_PER_LANE = 4
LANE_STEPS = 64  # most RATTLE steps per launch (launches also end on every output step)
LANE_BLOCK_DIM = 64  # CUDA threads per block: 2 warps (on the CPU: one emulated warp, 32 fibers)


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


def lane_support(batch: NetworkBatch) -> str | None:
    """None if the lane step takes this batch, else why not (one sentence)."""
    ln = batch.level_nodes
    if ln is None:
        return "not a T3 column (no levels)"
    n = ln.shape[0] - 1
    if n < 1 or not np.array_equal(ln, np.arange(3 * (n + 1)).reshape(n + 1, 3)):
        return "the column's nodes are not numbered level by level"
    if lane_shape(n, MAX_LEVELS_PER_LANE) is None:
        return f"{n} prisms need more than {MAX_LEVELS_PER_LANE} levels per lane of a 32-lane warp"
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
        return "rigid base links or another member layout"
    top = batch.cables[: 3 * n : 3, 1] - 3 * np.arange(1, n + 1)
    hand = np.where(top == 2, 1, -1)
    bars, cross, base = _column_members(n, hand)
    if not (np.array_equal(batch.constraints, bars) and np.array_equal(batch.cables, np.concatenate([cross, base]))):
        return "rigid base links or another member layout"
    if np.any(batch.constraint_active != 1):
        return "inactive bars"
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


class LaneStep:
    """Lane arrays and launches of the warp-per-column step for one model on one device."""

    def __init__(self, model: Model, batch: NetworkBatch, device):
        why = lane_support(batch)
        if why is not None:
            raise ValueError(f"the warp-per-column step does not take this batch: {why}")
        self.model = model
        self.device = device
        n = batch.level_nodes.shape[0] - 1
        self.P, self.G = lane_shape(n, MAX_LEVELS_PER_LANE)
        real = wp.float64 if model.precision == "fp64" else wp.float32
        npr = np.float64 if real == wp.float64 else np.float32
        self.kernels = make_lane_kernel(real, self.P, self.G)
        X = batch.positions
        z = X[:, 2].reshape(n + 1, 3)[:, 0]
        top = batch.cables[: 3 * n : 3, 1] - 3 * np.arange(1, n + 1)
        d = device
        self.xy = wp.array(X[:, :2].astype(npr), dtype=self.kernels.vec2, device=d)
        self.hz = wp.array(np.diff(z).astype(npr), dtype=real, device=d)
        self.hand = wp.array(np.where(top == 2, 1, 0).astype(np.int32), dtype=wp.int32, device=d)
        self.real = real
        self.block_dim = LANE_BLOCK_DIM if device.is_cuda else WARP
        self.steps_per_launch = LANE_STEPS
        B = model.n_columns
        self.threads = -(-B * self.G // WARP) * WARP

    @property
    def description(self) -> str:
        per = WARP // self.G
        return (f"lanes (one warp per column: {self.P} levels per lane, {self.G} lanes per column"
                + (f", {per} columns per warp" if per > 1 else "") + "; chains by PCR over shuffles)")

    def load(self):
        self.kernels.lane_steps.module.load(self.device, self.block_dim)
        self.kernels.advance_counter_by.module.load(self.device, 1)

    def launch(self, data, settings, dt: float, n_sub: int, init: int = 0):
        m, r = self.model, self.real
        wp.launch(self.kernels.lane_steps, dim=self.threads, block_dim=self.block_dim, device=self.device, inputs=[
            self.xy, self.hz, self.hand, m.cab_EA, m.cab_EAc, m.cab_L, m.minv_self, m.n_columns,
            r(settings.tolerance), int(settings.max_projection_iters), r(settings.failure_bar_error), r(dt),
            int(n_sub), int(init), data.step,
            data.u, data.v, data.a, data.bar_err, data.iters, data.status, data.fail_step])

    def advance_counter(self, data, n: int):
        wp.launch(self.kernels.advance_counter_by, dim=1, inputs=[data.step, int(n)], device=self.device, block_dim=1)
