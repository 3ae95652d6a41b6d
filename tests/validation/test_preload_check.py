"""The preload check (issue 34 item 5) passes, and fails when the engine's F0 is 5 % off (must-show 2).

Only the ENGINE side is perturbed, as in test_perturbation.py: ``column_batch`` in the modules that
imported it is wrapped to build the columns with 1.05 F0; the closed form keeps the true F0."""

import sys
from contextlib import contextmanager

import numpy as np

import warp_tensegrity.scene.batch as scene_batch
from warp_tensegrity.validation import report, run_validation

ORIGINAL = scene_batch.column_batch


@contextmanager
def engine_preload_off(factor: float = 1.05):
    def column_batch(config, params):
        p = scene_batch.column_params(config, params)
        return ORIGINAL(config, scene_batch.ColumnParams({**p, "preload": p["preload"] * factor}))

    patched = [m for k, m in list(sys.modules.items())
               if k.startswith("warp_tensegrity.") and not k.startswith("warp_tensegrity.validation")
               and k != "warp_tensegrity.scene.batch" and getattr(m, "column_batch", None) is ORIGINAL]
    assert any(m.__name__ == "warp_tensegrity.engine" for m in patched)
    for m in patched:
        m.column_batch = column_batch
    try:
        yield
    finally:
        for m in patched:
            m.column_batch = ORIGINAL


def test_preload_check_passes_and_fails_with_a_five_percent_error_in_F0():
    (true,) = run_validation(["preload"])
    assert true.passed, report([true])
    with engine_preload_off():
        (off,) = run_validation(["preload"])
    failed = {c.name for c in off.checks if not c.passed}
    # the static state and the wave speed each catch it
    assert {"preload_height", "preload_twist", "preload_speed"} <= failed, report([off])
    assert np.isclose(off.data["F0"], true.data["F0"])  # the closed form kept the true F0
