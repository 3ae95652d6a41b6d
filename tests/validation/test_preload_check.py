"""The preload check (issue 34 item 5) passes, and fails when the engine's F0 is 5 % off (must-show 2).

Only the ENGINE side is perturbed, as in test_perturbation.py: ``column_batch`` in the modules that
imported it is wrapped to build the columns with 1.05 F0; the closed form keeps the true F0."""

from contextlib import contextmanager

import numpy as np

import warp_tensegrity.scene.batch as scene_batch
from warp_tensegrity.validation import report, run_validation

from tests.validation.engine_patch import ORIGINAL, engine_builds_with


@contextmanager
def engine_preload_off(factor: float = 1.05):
    def column_batch(config, params):
        p = scene_batch.column_params(config, params)
        return ORIGINAL(config, scene_batch.ColumnParams({**p, "preload": p["preload"] * factor}))

    with engine_builds_with(column_batch):
        yield


def test_preload_check_passes_and_fails_with_a_five_percent_error_in_F0():
    (true,) = run_validation(["preload"])
    assert true.passed, report([true])
    with engine_preload_off():
        (off,) = run_validation(["preload"])
    failed = {c.name for c in off.checks if not c.passed}
    # the static state and the wave speed each catch it
    assert {"preload_height", "preload_twist", "preload_speed"} <= failed, report([off])
    assert np.isclose(off.data["F0"], true.data["F0"])  # the closed form kept the true F0
