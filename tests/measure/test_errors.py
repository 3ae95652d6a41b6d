"""Error estimates from a twin run (measure/errors.py) and precision 'auto' (fp32 verified case by
case, fp64 reruns: sweep/shard.run_groups)."""

import numpy as np
import pytest
import xarray as xr

from warp_tensegrity.measure import errors as E
from warp_tensegrity.types import ERROR_ESTIMATED


def _meas(B=4, P=6, scale=1.0):
    rng = np.random.default_rng(0)
    m = {k: scale * (1.0 + rng.random(B)) for k in ERROR_ESTIMATED if k != "arrival_time"}
    m["arrival_time"] = scale * np.cumsum(1.0 + rng.random((B, P)), axis=1)
    return m


def test_richardson_estimate_with_safety_and_floor():
    a = _meas()
    b = {k: v * (1 + 5e-4) for k, v in a.items()}  # the twin off by 5e-4, inside the target
    out = E.error_estimates(a, b, factor=15.0, precision="fp64", target=1e-3)
    for k in ERROR_ESTIMATED:
        scale = np.abs(a[k]) if a[k].ndim == 1 else np.max(np.abs(a[k]), axis=-1, keepdims=True)
        np.testing.assert_allclose(out[f"{k}_error"], E.SAFETY * 5e-4 * np.abs(a[k]) / 15 + E.FLOOR["fp64"] * scale)
    assert np.all(out["error_flag"] == E.FLAG["ok"])
    # an estimate over the target is flagged; a measure only one run defines cannot be estimated
    b2 = {k: v.copy() for k, v in b.items()}
    b2["speed"][1] = np.nan
    b2["amplitude"][2] *= 1.1
    out = E.error_estimates(a, b2, factor=15.0, precision="fp64", target=1e-3)
    assert list(out["error_flag"]) == [0, E.FLAG["twin_undefined"], E.FLAG["over_target"], 0]
    assert np.isnan(out["speed_error"][1]) and np.isfinite(out["amplitude_error"][1])
    a3 = {k: v.copy() for k, v in a.items()}
    a3["width"][3] = np.nan  # the run has no width, its twin has one: the estimate cannot say
    assert E.error_estimates(a3, b, 15.0)["error_flag"][3] == E.FLAG["twin_undefined"]
    # a lost arrival at one prism (the last reached by t_end) is NaN, not a flag
    b4 = {k: v.copy() for k, v in b.items()}
    b4["arrival_time"][0, -1] = np.nan
    out = E.error_estimates(a, b4, 15.0)
    assert np.isnan(out["arrival_time_error"][0, -1]) and out["error_flag"][0] == 0
    out = E.error_estimates(a, None, 15.0)
    assert np.all(out["error_flag"] == E.FLAG["no_twin"]) and np.isnan(out["amplitude_error"]).all()


def test_outside_the_asymptotic_range_and_fp32_the_difference_is_not_divided():
    """fp64: a twin that differs by more than the target is not in the Richardson range (phase_large on
    an H200: such pairs missed the fp64 dt/4 reference by up to 2 %); its estimate is the difference
    itself. fp32: the difference is round-off's, which dt does not scale: SAFETY x the difference."""
    a = _meas()
    b = {k: v * (1 + 5e-3) for k, v in a.items()}
    out = E.error_estimates(a, b, factor=15.0, precision="fp64", target=1e-3)
    np.testing.assert_allclose(out["amplitude_error"], 5e-3 * a["amplitude"] + E.FLOOR["fp64"] * a["amplitude"])
    assert np.all(out["error_flag"] == E.FLAG["over_target"])
    small = {k: v * (1 + 2e-4) for k, v in a.items()}
    out = E.error_estimates(a, small, factor=15.0, precision="fp32", target=1e-3)
    np.testing.assert_allclose(out["speed_error"], (E.SAFETY * 2e-4 + E.FLOOR["fp32"]) * a["speed"])
    assert np.all(out["error_flag"] == E.FLAG["ok"])  # 5e-4 of the measure: within the target
    out = E.error_estimates(a, {k: v * (1 + 6e-4) for k, v in a.items()}, factor=15.0, precision="fp32", target=1e-3)
    assert np.all(out["error_flag"] == E.FLAG["over_target"])  # 1.3e-3: fp64 reruns it under 'auto'


def test_a_perturbed_run_raises_the_estimate_and_flags_what_it_moves_past_the_target():
    """with_perturbation: fp32 and fp64 at one dt differ by round-off only; what that moves a measure,
    the fp64 estimate covers (SAFETY x the difference, plus the floor), and past the target it flags."""
    a = _meas()
    err = E.error_estimates(a, {k: v * (1 + 1e-8) for k, v in a.items()}, 15.0, "fp64", target=1e-3)
    assert np.all(err["error_flag"] == E.FLAG["ok"])
    moved = {k: v.copy() for k, v in a.items()}
    moved["amplitude"][1] *= 1 + 3e-4  # 2 x 3e-4 + 1e-5 = 6.1e-4: raised, within the target
    moved["amplitude"][2] *= 1 + 6e-4  # 1.21e-3: over it
    out = E.with_perturbation(err, a, moved, 1e-3)
    rel = out["amplitude_error"] / a["amplitude"]
    np.testing.assert_allclose(rel[1:3], [6.1e-4, 1.21e-3], rtol=1e-6)
    np.testing.assert_array_equal(out["amplitude_error"][[0, 3]], err["amplitude_error"][[0, 3]])  # nothing moved
    np.testing.assert_array_equal(out["error_flag"], [0, 0, E.FLAG["over_target"], 0])
    assert E.largest_share(a, out)[2] == pytest.approx(1.21e-3, rel=1e-6)
    # a twin_undefined case keeps its flag
    err["error_flag"][2] = E.FLAG["twin_undefined"]
    assert E.with_perturbation(err, a, moved, 1e-3)["error_flag"][2] == E.FLAG["twin_undefined"]


SPEC = """[scene]
n_prisms = 10
[sweep]
grid = { prestrain = [0.002, 0.006], v0 = [0.005, 0.02], base_rigidity = [0.0, 1.0] }
[run]
t_end = 0.8
output_interval = 0.002
record_strain = false
shard_size = 4
"""


def _sweep(tmp_path, monkeypatch, name, **run):
    from warp_tensegrity.policy import groups as G
    from warp_tensegrity.sweep import run_sweep

    monkeypatch.setattr(G, "AUTO_FP32_ON_CPU", True)  # 'auto' verifies fp32 on a GPU; here on the CPU
    text = SPEC + "".join(f"{k} = {v!r}\n".replace("'", '"') for k, v in run.items())
    return xr.open_dataset(run_sweep(text, tmp_path / f"{name}.nc", device="cpu", progress=False))


@pytest.mark.slow
def test_auto_keeps_verified_fp32_and_reruns_the_rest_in_fp64(tmp_path, monkeypatch):
    auto = _sweep(tmp_path, monkeypatch, "auto", precision="auto")
    fp32 = _sweep(tmp_path, monkeypatch, "fp32", precision="fp32")
    fp64 = _sweep(tmp_path, monkeypatch, "fp64", precision="fp64")
    bits = auto.precision_used.values
    # cases whose fp32 estimates miss the target, or come within VERIFY_MARGIN of it, are rerun in
    # fp64; the others verify
    assert (bits == 32).sum() >= 2 and (bits == 64).sum() >= 1
    n = bits.size
    flat = lambda x: x.reshape(n, -1) if x.ndim > bits.ndim else x.reshape(n)  # noqa: E731  (grid -> cases)
    share = E.largest_share({k: flat(fp32[k].values) for k in ERROR_ESTIMATED},
                            {f"{k}_error": flat(fp32[f"{k}_error"].values) for k in ERROR_ESTIMATED})
    unverified = np.isin(fp32.error_flag.values, (E.FLAG["over_target"], E.FLAG["twin_undefined"])) | \
        (share > E.VERIFY_MARGIN * 1e-3).reshape(bits.shape)
    np.testing.assert_array_equal(bits == 64, unverified)
    for k in ("amplitude", "speed", "width", "arrival_time", "kinetic_energy", "status", "amplitude_error"):
        np.testing.assert_array_equal(auto[k].values[bits == 32], fp32[k].values[bits == 32])  # fp32's own numbers
    for k in ("amplitude", "speed", "width", "arrival_time", "kinetic_energy", "status"):
        np.testing.assert_array_equal(auto[k].values[bits == 64], fp64[k].values[bits == 64])  # bit for bit fp64's
    # a rerun case's estimate also covers what round-off moved (fp32 and fp64 at one dt)
    for k in ERROR_ESTIMATED:
        a, b, e = (x[k].values[bits == 64] for x in (fp64, fp32, auto[[f"{k}_error"]].rename({f"{k}_error": k})))
        floor = E.FLOOR["fp64"] * (np.abs(a) if a.ndim == 1 else np.nanmax(np.abs(a), axis=-1, keepdims=True))
        expect = np.fmax(fp64[f"{k}_error"].values[bits == 64], E.SAFETY * np.abs(a - b) + floor)
        np.testing.assert_allclose(e, expect, rtol=1e-15, err_msg=k)
    for k in ERROR_ESTIMATED:
        assert auto[k].attrs["ancillary_variables"] == f"{k}_error error_flag"
        ok = np.isfinite(auto[k].values)
        assert np.all(auto[f"{k}_error"].values[ok] > 0)
    # an estimate that verifies nothing (every estimate over the target): every case rerun in fp64
    monkeypatch.setattr(E, "SAFETY", 1e9)
    redo = _sweep(tmp_path, monkeypatch, "redo", precision="auto")
    assert set(redo.precision_used.values.ravel()) == {64}
    for k in ("amplitude", "speed", "width", "arrival_time", "kinetic_energy", "status"):
        np.testing.assert_array_equal(redo[k].values, fp64[k].values)
    assert np.all(redo.error_flag.values[np.isfinite(redo.amplitude.values)] == E.FLAG["over_target"])
