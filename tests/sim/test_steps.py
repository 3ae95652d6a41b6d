"""The one Step interface (issue 33 item 4): every registered Step (sim.step.STEPS) runs the same
small batch on Warp's CPU device in fp64 and lands on the staged reference within 1e-11 (relative,
positions and velocities); a Step registered but not run fails the test."""

from __future__ import annotations

from unittest import mock

import numpy as np
import pytest
import warp as wp

from warp_tensegrity import ColumnConfig, RunSettings
from warp_tensegrity.policy.paths import lane_emulation
from warp_tensegrity.scene.batch import column_batch
from warp_tensegrity.sim.integrate import Integrator
from warp_tensegrity.sim.step import STEPS, Step
from warp_tensegrity.types import Path

# flexible and rigid bases (FB + RB) in one T3 batch, slack and prestressed
PARAMS = {"prestrain": [0.0, 0.002, 0.002], "v0": [0.05, 0.1, 0.08], "base_rigidity": [0.0, 0.5, 1.0]}
DT, EVERY, N_OUT = 5e-4, 7, 4  # 21 steps: launches of the block step end between outputs
TOL = 1e-11
N_PRISMS = 50  # the kernel variants of the paper's cases (tests/sim/test_same_physics.py): no compile of its own


def _final(path: Path, step: type[Step], n_prisms: int = N_PRISMS) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The state after 21 steps of the Integrator driving ``step`` (registered for ``path`` meanwhile)."""
    batch = column_batch(ColumnConfig(n_prisms=n_prisms), PARAMS)
    settings = RunSettings(device="cpu", precision="fp64")
    dev = wp.get_device("cpu")
    with lane_emulation(path, dev), mock.patch.dict(STEPS, {path: step}):
        integ = Integrator(batch, settings, DT, EVERY, N_OUT, path=path)
        assert type(integ.stepper) is step
        integ.run(EVERY * (N_OUT - 1))
        return integ.data.u.numpy(), integ.data.v.numpy(), integ.data.status.numpy()


def _rel(a, b):
    return float(np.abs(a - b).max() / np.abs(b).max())


def run_every_step(steps: dict[Path, type[Step]], n_prisms: int = N_PRISMS) -> dict[Path, tuple[float, float]]:
    """{path: (rel. error of u, of v)} against the staged Step, for every Step in ``steps``."""
    u0, v0, s0 = _final(Path.STAGED, STEPS[Path.STAGED], n_prisms)
    assert np.all(s0 == 0) and np.abs(v0).max() > 0
    out = {}
    for path, step in steps.items():
        u, v, s = _final(path, step, n_prisms)
        assert np.all(s == 0), (path, s)
        out[path] = (_rel(u, u0), _rel(v, v0))
    return out


def check_every_step(steps: dict[Path, type[Step]], run=run_every_step):
    assert set(steps) == set(Path), "a launch path without a Step, or a Step for no path"
    errors = run(steps)
    assert set(errors) == set(steps), f"registered but not run: {set(steps) - set(errors)}"
    bad = {p.value: e for p, e in errors.items() if max(e) > TOL}
    assert not bad, bad


def test_every_registered_step_matches_the_staged_reference():
    check_every_step(STEPS)


def test_the_check_fails_on_a_step_off_by_a_constant():
    """Controls: a Step whose dt is 1.05 x the batch's, registered as the fused path's, fails the
    check; so does a registered Step that the run leaves out."""
    from warp_tensegrity.sim.block.step import FusedStep

    class Scaled(FusedStep):
        path = Path.FUSED

        def launch(self, data, settings, dt, n_sub, init=0):
            super().launch(data, settings, 1.05 * dt, n_sub, init)

    steps = {**STEPS, Path.FUSED: Scaled}
    with pytest.raises(AssertionError, match="'fused':"):
        check_every_step(steps, run=lambda s: run_every_step({Path.FUSED: Scaled}) | {
            p: (0.0, 0.0) for p in s if p != Path.FUSED})
    with pytest.raises(AssertionError, match="registered but not run"):
        check_every_step(STEPS, run=lambda s: {p: (0.0, 0.0) for p in s if p != Path.LANES})
