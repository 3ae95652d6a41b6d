"""Divergence isolation (issue 18): one column that blows up (an absurd impact speed, or a cable so
stiff that the batch's dt is absurd for it alone) is flagged with its step and reason, and every
other column of the batch is bit-identical to a batch without it: staged kernels, the fused step,
and the fused step with Warp's CPU block emulation (lanes, barriers, shared rows) as on the GPU."""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp

from warp_tensegrity.sim.block import step as block_step
from warp_tensegrity.engine import simulate_batch
from warp_tensegrity.policy.decide import prisms_to_simulate
from warp_tensegrity.scene.columns import ColumnConfig
from warp_tensegrity.options import RunSettings
from warp_tensegrity.types import STATUS_MEANINGS
from warp_tensegrity.types import Status

CFG = ColumnConfig(n_prisms=6)
GOOD = {
    "prestrain": [0.0, 0.002, 0.001, 0.0],
    "v0": [0.003, 0.006, 0.004, 0.05],
    "base_rigidity": [0.0, 1.0, 0.5, 0.0],
    "cable_EA": [CFG.cable_EA] * 4,
}
BAD = {
    "v0": {"prestrain": 0.0, "v0": 1000.0, "base_rigidity": 0.0, "cable_EA": CFG.cable_EA},  # 1 km/s impact
    "stiffness": {"prestrain": 0.002, "v0": 0.05, "base_rigidity": 0.0, "cable_EA": CFG.cable_EA * 1e6},
}
AT = 2  # the bad column's place in the batch
FIELDS = ("strain", "kinetic_energy", "elastic_energy", "energy_error", "bar_length_error", "status", "fail_step",
          "final_displacement", "final_velocity")


def _insert(good: dict, bad: dict) -> dict:
    return {k: np.insert(np.asarray(v, dtype=np.float64), AT, bad[k]) for k, v in good.items()}


class _Lanes:
    """The fused step with 4 emulated lanes per block and the band in shared rows (CPU blocks)."""

    names = ("FUSED_BLOCK_DIM", "FUSED_SHARED_ON_CPU")

    def __enter__(self):
        self.old = [wp.config.enable_cpu_blocks] + [getattr(block_step, n) for n in self.names]
        wp.config.enable_cpu_blocks = True
        block_step.FUSED_BLOCK_DIM = 4
        block_step.FUSED_SHARED_ON_CPU = True

    def __exit__(self, *exc):
        wp.config.enable_cpu_blocks = self.old[0]
        for n, v in zip(self.names, self.old[1:]):
            setattr(block_step, n, v)


@pytest.mark.parametrize("absurd", ["v0", "stiffness"])
@pytest.mark.parametrize("path", ["staged", "fused", "fused_lanes"])
def test_one_diverging_column_leaves_the_others_bit_identical(path, absurd, device):
    settings = RunSettings(t_end=0.1, dt=2e-3, output_interval=0.01, device=device, allow_unstable_dt=True,
                           fused=path != "staged")
    params = _insert(GOOD, BAD[absurd])
    # truncation is a batch-level choice from the stiffest column; a sweep fixes it once for all
    # its shards (SweepPlan.prisms_simulated), and so does this test for both batches
    n_sim = prisms_to_simulate(CFG, params, settings)
    if path == "fused_lanes":
        if device != "cpu":
            pytest.skip("CPU block emulation")
        with _Lanes():
            with_bad = simulate_batch(CFG, params, settings, prisms_simulated=n_sim)
            without = simulate_batch(CFG, GOOD, settings, prisms_simulated=n_sim)
    else:
        with_bad = simulate_batch(CFG, params, settings, prisms_simulated=n_sim)
        without = simulate_batch(CFG, GOOD, settings, prisms_simulated=n_sim)

    # the bad column is flagged with the step and the reason
    status, step = int(with_bad.status[AT]), int(with_bad.fail_step[AT])
    assert status != Status.OK and status in STATUS_MEANINGS, status
    assert 0 <= step <= with_bad.n_steps
    t_fail = step * with_bad.dt
    late = with_bad.time > t_fail + with_bad.dt * 1.0001
    if with_bad.strain is not None and late.any():
        assert np.isnan(with_bad.strain[AT][late]).all()  # nothing after the failure is reported as data
    # every other column: bit-identical to the batch without it
    assert without.status.tolist() == [Status.OK] * 4
    others = [i for i in range(5) if i != AT]
    for f in FIELDS:
        a, b = getattr(with_bad, f), getattr(without, f)
        if a is None:
            assert b is None, f
            continue
        a = np.ascontiguousarray(np.asarray(a)[others])
        b = np.ascontiguousarray(np.asarray(b))
        assert a.dtype == b.dtype and a.tobytes() == b.tobytes(), f
    np.testing.assert_array_equal(with_bad.time, without.time)
