"""Long columns on the lane step (k warps per column, one block of 32 k lanes joined through shared
memory: kernels/lane_ops.make_block_ops; on the CPU a block of 32 k fibers) against the staged
kernels at 300 (rigid and elastic bases) and 1,000 prisms (flexible and elastic), fp64; and the
map that sends a column to one warp, k warps or nowhere (policy/lane_fit.lane_map).

Every node starts moving (a smooth velocity field along the whole column, made admissible by the
initial projection of both paths), so each warp boundary carries the solve and the forces from the
first step: a few steps check every join. Two kernels are compiled (CI budget: issue 33)."""

import numpy as np
import pytest

from benchmarks.lanes_bits import moving_batch as _batch
from warp_tensegrity import RunSettings
from warp_tensegrity.engine import run_batch
from warp_tensegrity.policy.lane_fit import MAX_COLUMN_LANES, lane_map, lane_support

STEPS = 12
DT = 5e-4


def _run(batch, fused, device):
    s = RunSettings(precision="fp64", device=device, truncate=False, fused=fused, t_end=STEPS * DT, dt=DT,
                    output_interval=STEPS * DT / 2)
    return run_batch(batch, s)


def _rel(a, b):
    axis = tuple(range(1, a.ndim))
    return np.abs(a - b).max(axis=axis) / np.abs(b).max(axis=axis)


# 300 prisms with rigid and elastic bases: in fp64 1 level per lane, 512 lanes (16 warps), the ring
# links folded into 3 x 3 blocks; 1,000 prisms flexible and elastic: 4 levels per lane, 256 lanes
CASES = [(300, [1.0, 0.5], (1, 512)), (1000, [0.0, 0.5], (4, 256))]


@pytest.fixture(scope="module")
def staged_runs(device):
    return {n: _run(_batch(n, br), False, device) for n, br, _ in CASES}


@pytest.mark.parametrize("n, base_rigidity, shape", CASES)
def test_long_columns_match_staged_fp64(n, base_rigidity, shape, staged_runs, device):
    b = _batch(n, base_rigidity)
    assert lane_support(b) is None
    assert lane_map(n, 1.0 in base_rigidity, "fp64") == shape
    lanes, staged = _run(b, "lanes", device), staged_runs[n]
    P, G = shape
    assert lanes.info["step_path"].startswith(f"lanes ({G // 32} warps per column, one block: {P} levels per lane")
    assert np.all(lanes.status == 0) and np.all(staged.status == 0)
    # every level moves: the joins of all warps are exercised
    assert np.all(np.abs(staged.final_velocity).reshape(2, n + 1, 9)[:, 1:].max(axis=2) > 1e-3)
    for name in ("strain", "final_displacement", "final_velocity"):
        rel = _rel(getattr(lanes, name), getattr(staged, name))
        assert np.all(rel <= 1e-11), (name, rel)
    assert np.all(lanes.bar_length_error <= 1e-12), lanes.bar_length_error


def test_a_perturbed_constant_fails_the_comparison(staged_runs, device):
    """The comparison above sees a 5 % stiffer cable set (the same kernel, compiled already)."""
    n, br, _ = CASES[1]
    lanes = _run(_batch(n, br, ea_scale=1.05), "lanes", device)
    assert np.all(_rel(lanes.final_displacement, staged_runs[n].final_displacement) > 1e-6)


def test_lane_map_one_warp_k_warps_or_none():
    assert lane_map(100) == (4, 32) and lane_map(64, rigid=True) == (2, 32)  # one warp, as before
    assert lane_map(129) == (3, 64) and lane_map(65, rigid=True) == (2, 64)
    assert lane_map(300) == (3, 128) and lane_map(1000) == (4, 256)
    assert lane_map(500) == (2, 256) and lane_map(200) == (2, 128)  # 4 levels on <= 128 lanes spill: twice the lanes
    assert lane_map(1000, rigid=True) == (2, 512) and lane_map(1024, rigid=True) == (2, 512)
    # rigid bases in fp64: one level per lane from 33 prisms to RIGID_FP64_ONE_LEVEL_LANES, on k warps
    assert lane_map(32, True, "fp64") == (1, 32) and lane_map(64, True, "fp32") == (2, 32)
    assert lane_map(33, True, "fp64") == (1, 64) and lane_map(64, True, "fp64") == (1, 64)
    assert lane_map(65, True, "fp64") == (1, 128) and lane_map(65, True) == (2, 64)
    assert lane_map(300, True, "fp64") == (1, 512) and lane_map(300, True) == (2, 256)
    assert lane_map(513, True, "fp64") == lane_map(513, True) == (2, 512) and lane_map(50, False, "fp64") == (2, 32)
    assert lane_map(4 * MAX_COLUMN_LANES) == (4, MAX_COLUMN_LANES)
    assert lane_map(4 * MAX_COLUMN_LANES + 1) is None and lane_map(1025, rigid=True) is None
    for n in (1, 31, 33, 50, 64, 127, 128, 129, 300, 999, 1000, 2048):
        for rigid, prec in ((False, None), (True, None), (True, "fp64")):
            m = lane_map(n, rigid, prec)
            if m is not None:
                P, G = m
                assert P * G >= n and P * (G // 2) < n or G == 32, (n, rigid, m)  # no spare half


def test_k_warp_kernels_state_one_block_per_sm():
    """A k-warp kernel's launch bounds name the blocks per SM (1): given only the block size, ptxas
    held blocks of 256 and 512 threads to 32-128 registers and spilled (FB fp64, 1,000 prisms: 32
    registers, 30 KB of spill stores a thread; 2.5x slower on an H200: benchmarks/results/
    issue33_h200_sixth). One warp per column states no bounds (255 registers)."""
    import warp as wp

    from warp_tensegrity.sim.lanes import lanes as L

    assert L.make_lane_kernel(wp.float64, 4, 256).lane_steps.options["launch_bounds"] == (256, 1)
    assert L.make_lane_kernel(wp.float64, 1, 512, rigid=True).lane_steps.options["launch_bounds"] == (512, 1)
    assert L.make_lane_kernel(wp.float32, 2, 256, block_min=2).lane_steps.options["launch_bounds"] == (256, 2)
    assert "launch_bounds" not in L.make_lane_kernel(wp.float32, 2, 32).lane_steps.options
