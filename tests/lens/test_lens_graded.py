"""A lens of graded columns (issue 34 item 6): ``column.prestrain_shape`` multiplies each column's
prestrain along its length, in the calibration and the verification alike."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from warp_tensegrity.lens import run as lens_run
from warp_tensegrity.lens.spec import LensSpecError, parse_lens_spec
from warp_tensegrity.tomlread import read_toml

CI = (Path(__file__).resolve().parents[2] / "sweeps" / "lens_ci.toml").read_text()


def _spec(shape: str | None, **column):
    data = read_toml(CI)
    if shape is not None:
        data["column"]["prestrain_shape"] = read_toml(f"x = {shape}")["x"]
    data["column"]["scene"].update(column)
    return parse_lens_spec(data)


def test_shape_factors_and_prestrain():
    spec = _spec("{ segments = [0.5, 1.0], at = 4 }")
    assert spec.column.shape_factors().tolist() == [0.5] * 4 + [1.0] * 6
    p = spec.column.prestrain([0.1, 0.02])
    assert p.shape == (2, 10) and np.allclose(p[0], 0.1 * spec.column.shape_factors())
    assert _spec(None).column.prestrain([0.1]).shape == (1,)  # uniform columns, as before


@pytest.mark.parametrize("shape, match", [
    ("{ grade = [0.5, -1.0] }", r"column.prestrain_shape.grade\[1\] = -1.0: must lie in \(0, 1000\]"),
    ("{ values = [1.0, 1.0] }", r"column.prestrain_shape = .*give 10 values, one per prism"),
    ("{ segments = [1.0, 0.5], at = 10 }", r"column.prestrain_shape.at = 10: the interface must be a prism index"),
    ("{ grade = [1.0, 7.0] }", r"column.prestrain_shape: the largest factor 7 x calibration.prestrain_max = 0.15 "
                               r"reaches a prestrain of 1.05; must stay < 1"),
    ("0.5", r"column.prestrain_shape = 0.5: must be a table"),
])
def test_bad_shapes_name_the_key_and_value(shape, match):
    with pytest.raises(LensSpecError, match=match):
        _spec(shape)


def test_calibration_and_verification_columns_are_graded(monkeypatch):
    """Every batch the lens runs gets (B, n_prisms) prestrains: p per column times the shape."""
    seen = []

    def fake(config, params, settings, progress=None):
        seen.append(np.asarray(params["prestrain"]))
        raise RuntimeError("stop")

    monkeypatch.setattr(lens_run, "simulate_batch", fake)
    spec = _spec("{ grade = [0.5, 1.0] }")
    with pytest.raises(RuntimeError, match="stop"):
        lens_run.calibrate(spec, device="cpu")
    p = np.linspace(0.0, 0.15, 64)
    assert np.allclose(seen[0], p[:, None] * np.linspace(0.5, 1.0, 10)[None, :])
