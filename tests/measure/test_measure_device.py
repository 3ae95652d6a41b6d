"""Pulse measurement on the Warp device (warp_tensegrity.measure.device) against the NumPy
reference (warp_tensegrity.measure.pulse_core): equal to <= 1e-12 relative (fp64), NaN in exactly the same
places, on engine records (the 12 paper cases, ci_small) and on adversarial synthetic records."""

from pathlib import Path

import numpy as np
import xarray as xr
import pytest
import warp as wp
from hypothesis import HealthCheck, given, settings, strategies as st

from warp_tensegrity.measure import pulse_core as M
from warp_tensegrity.engine import simulate_batch
from warp_tensegrity.measure.device import measure_pulse_device, measure_record
from warp_tensegrity.options import RunSettings, SettingsError
from warp_tensegrity.sweep.spec import load_spec
from warp_tensegrity.types import MEASUREMENT_FLAGS

ROOT = Path(__file__).resolve().parents[2]
H = 6.2e-3
RTOL = 1e-12


RECORD_STATS = ("max_compression", "max_compression_finite", "record_finite")
ENERGY = ("pulse_energy_share", "end_energy_share", "pulse_energy_share_sensitivity")
"""The engine's energy measures (measure.energy; tests/measure/test_energy.py), beside the pulse measures."""


def record_stats(s) -> dict:
    """The per-record statistics measure_record returns beside measure_pulse's keys, in NumPy."""
    s = np.asarray(s, dtype=np.float64)
    ok = np.isfinite(s).all(axis=(-2, -1))
    with np.errstate(invalid="ignore"):
        qf = np.where(np.isfinite(s), -s, 0.0).max(axis=(-2, -1))
    return {"max_compression": np.where(ok, qf, np.nan), "max_compression_finite": qf, "record_finite": ok}


def assert_stats(s, dev: dict):
    for k, a in record_stats(s).items():
        np.testing.assert_array_equal(np.asarray(dev[k], dtype=np.float64), a.astype(np.float64), err_msg=k)


SENS_ATOL = 1e-9
"""The sensitivities are relative differences of nearly equal measures (arrival times after their
first-order response to the threshold is removed): where no decision flips they are round-off or a
second-order residue, and their round-off on the device is that of the measures (1e-12 relative);
compared absolutely, far below any flag floor (1e-3)."""


def assert_same(ref: dict, dev: dict, rtol: float = RTOL):
    assert set(ref) <= set(dev) <= set(ref) | set(RECORD_STATS) | set(ENERGY)
    for k, a in ref.items():
        a, b = np.asarray(a, dtype=np.float64), np.asarray(dev[k], dtype=np.float64)
        assert a.shape == b.shape, k
        np.testing.assert_array_equal(np.isnan(b), np.isnan(a), err_msg=f"NaN pattern of {k}")
        ok = ~np.isnan(a)
        atol = SENS_ATOL if k in M.SENSITIVITY_KEYS.values() else 0.0
        np.testing.assert_allclose(b[ok], a[ok], rtol=rtol, atol=atol, err_msg=k)


DEVICE = "cpu"  # set from pytest --device by the autouse fixture below


@pytest.fixture(autouse=True)
def _device(device):
    global DEVICE
    DEVICE = device


def both(s, t, h=H, **kw):
    with np.errstate(all="ignore"):
        ref = M.measure_pulse(s, t, h, **kw)
    return ref, measure_pulse_device(s, t, h, device=DEVICE, **kw)


# ---------------------------------------------------------------------- synthetic records
def sech2_history(n=50, c=40.0, A=1e-3, w=2.0, t_end=1.0, nt=2001):
    """Compression pulse entering at the free end, running toward prism 0 at c prisms/s."""
    t = np.linspace(0.0, t_end, nt)
    j = np.arange(n)
    x0 = (n - 1) + 3 * w - c * t[:, None]
    return t, -A / np.cosh((j[None, :] - x0) / w) ** 2


def adversarial_records():
    """(strain (R, T, P), time) of one shape: real pulses and every NaN case of the reference."""
    t, base = sech2_history(n=30, c=60.0, t_end=0.8, nt=801)
    R = []
    R.append(base)  # a clean pulse
    R.append(sech2_history(n=30, c=60.0, w=3.5, A=2e-2, t_end=0.8, nt=801)[1])  # wide, strong
    R.append(np.zeros_like(base))  # flat
    R.append(np.full_like(base, 1e-3))  # uniform tension
    s = base.copy(); s[400, 11] = np.nan; R.append(s)  # one NaN sample
    s = base.copy(); s[5, 3] = np.inf; R.append(s)  # one inf sample
    R.append(np.full_like(base, np.nan))  # all NaN
    R.append(sech2_history(n=30, c=60.0, t_end=0.2, nt=801)[1])  # pulse reaches part of the column
    R.append(sech2_history(n=30, c=60.0, t_end=0.05, nt=801)[1])  # hardly entered: too few prisms
    s = base.copy(); s[:, :] += -2e-4; R.append(s)  # compressed from the first sample (arrival at k = 0)
    s = base.copy(); late = t > 0.6; s[late, :8] -= 2e-2 * np.sin(40 * t[late, None]); R.append(s)  # late large motion
    q = 1e-4
    R.append(np.round(base / q) * q)  # coarse levels: ties in time and space everywhere
    R.append(np.round(base / 2.5e-4) * 2.5e-4)
    s = base.copy(); s[:, 12:15] = s[:, 12:15].min(axis=0); R.append(s)  # constant prisms
    R.append(np.where(base < -0.8e-3, -0.8e-3, base))  # flat tops: ties at the peak
    s = base.copy(); s[:, 15] = 0.0; R.append(s)  # a dead prism mid-window
    s = base.copy(); s[:, 16] *= 1.5; R.append(s)  # a stray prism
    rng = np.random.default_rng(7)
    R.append(base + 2e-5 * rng.standard_normal(base.shape))  # noisy
    R.append(base[::-1].copy())  # time-reversed: the pulse leaves
    R.append(-base)  # tension pulse only
    s = base + 0.5 * np.roll(base, 200, axis=0); R.append(s)  # a second, weaker pulse behind
    R.append(base + 1.2 * np.roll(base, 93, axis=0))  # a stronger one behind a dip to 45-50 %: ends the pulse at f = 0.5 only
    s = base.copy()  # a brief strong bump at prism 17 as the pulse passes mid-window (j_mid = 14.5):
    s[:, 17] -= 2e-3 * np.exp(-(((t - 20.5 / 60.0) / 0.004) ** 2))  # the width search must centre on rint(14.5) = 14
    R.append(s)
    j = np.arange(30)
    for c2 in (20.0, 150.0):  # a bump from the clamp captures the threshold: part of the window, most of it
        R.append(base - 3e-4 / np.cosh((j[None, :] - (-3.0 + c2 * t[:, None])) / 1.5) ** 2)
    s = base.copy()  # strong early bumps at the window's impact end: the run measured starts below them
    s[:, 24:27] -= 3e-3 * np.exp(-(((t[:, None] - 0.03) / 0.005) ** 2))
    R.append(s)
    return np.stack(R), t


@pytest.fixture(scope="module")
def adversarial():
    return adversarial_records()


def test_adversarial_records(adversarial):
    s, t = adversarial
    ref, dev = both(s, t)
    assert_same(ref, dev)
    assert_stats(s, dev)
    # the set covers defined and undefined outcomes of every measure
    for k in ("amplitude", "speed", "speed_snapshot", "width_fwhm", "width_10", "prisms_measured"):
        assert np.isnan(ref[k]).any() and np.isfinite(ref[k]).any(), k
    assert set(np.unique(ref["pulse_captured"][np.isfinite(ref["pulse_captured"])])) == {0.0, 1.0}
    captured = ref["pulse_captured"] == 1
    assert np.isfinite(ref["speed"][captured]).any() and np.isnan(ref["speed"][captured]).any()


def test_engine_record_with_a_captured_threshold():
    """The stored 50-prism record (beta = 0.9999 and 1, tests/measure/test_measure.py::captured_record):
    the device follows the pulse as the host does, and its speed at 0.9999 is within 5 % of 1's."""
    from test_measure import captured_record

    s, t, _ = captured_record()
    ref, dev = both(s, t)
    assert_same(ref, dev)
    assert dev["pulse_captured"].tolist() == [1.0, 0.0]
    assert dev["speed"][0] == pytest.approx(dev["speed"][1], rel=0.05)


def test_stability_probe_on_the_device():
    """The probe's three passes run on the device as on the host: a decision at its boundary
    (tests/measure/test_measure.py::double_hump, 2e-4 from it) gives the same sensitivities, one
    5 % from it none."""
    from test_measure import double_hump

    t, near = double_hump(2e-4)
    clear = double_hump(0.05)[1]
    ref, dev = both(np.stack([near, clear]), t)
    assert_same(ref, dev)
    assert dev["amplitude_sensitivity"][0] > 0.2 and dev["amplitude_sensitivity"][1] == 0.0
    off = measure_pulse_device(np.stack([near, clear]), t, H, device=DEVICE, stability=None)
    assert not set(M.SENSITIVITY_KEYS.values()) & set(off)
    assert_same({k: v for k, v in ref.items() if k not in M.SENSITIVITY_KEYS.values()},
                {k: v for k, v in off.items() if k not in RECORD_STATS})


def test_records_discriminate_the_definitions(adversarial):
    """The comparison is not vacuous: changing a definition's parameter changes the reference on
    these records, so a device kernel with that definition broken would fail the test above."""
    s, t = adversarial
    with np.errstate(all="ignore"):
        ref = M.measure_pulse(s, t, H)
        for kw, keys in (({"end_fraction": 0.45}, ("peak_time", "amplitude", "speed")),
                         ({"skip_impact": 4}, ("speed", "width_fwhm", "prisms_measured")),
                         ({"skip_clamp": 2}, ("speed_snapshot", "width_10", "prisms_measured")),
                         ({"threshold": 0.5 * ref["threshold"]}, ("arrival_time", "peak_time"))):
            other = M.measure_pulse(s, t, H, **kw)
            for k in keys:
                a, b = ref[k], other[k]
                differ = ~np.isclose(a, b, rtol=1e-9, atol=0.0, equal_nan=True)
                assert differ.any(), (kw, k)
        assert_same(ref, M.measure_pulse(s, t, H, threshold=ref["threshold"]))  # control: same definition


@pytest.mark.parametrize("kw", [
    {"end_fraction": 0.3},
    {"end_fraction": 0.8},
    {"skip_impact": 0, "skip_clamp": 0},
    {"skip_impact": 7, "skip_clamp": 3},
    {"skip_impact": 13, "skip_clamp": 14},  # a window of 3 prisms
    {"threshold": 2e-4},
    {"threshold": "per-record"},  # with NaN, 0 and negative entries
])
def test_options(adversarial, kw):
    s, t = adversarial
    if kw.get("threshold") == "per-record":
        thr = np.linspace(-1e-4, 5e-4, s.shape[0])
        thr[[0, 3]] = [np.nan, 0.0]
        kw = {"threshold": thr}
    ref, dev = both(s, t, **kw)
    assert_same(ref, dev)


@pytest.mark.parametrize("P", [1, 2, 3, 4, 5, 8])
@pytest.mark.parametrize("T", [1, 2, 3, 40])
def test_short_records_and_small_columns(T, P):
    t, s = sech2_history(n=P, c=80.0, w=1.0, A=1e-3, t_end=0.1, nt=T)
    s = np.stack([s, np.zeros_like(s), s * 0.5])
    ref, dev = both(s, t)
    assert_same(ref, dev)


def test_nonuniform_time_and_batch_dims():
    t, s = sech2_history(n=20, c=50.0, t_end=0.6, nt=500)
    rng = np.random.default_rng(3)
    tt = np.sort(rng.uniform(0.0, 0.6, 500))
    tt[0] = 0.0
    j = np.arange(20)
    s = -1e-3 / np.cosh((j[None, :] - (19 + 6 - 50 * tt[:, None])) / 2.0) ** 2
    batch = np.stack([s, 1.3 * s, np.round(s / 2e-4) * 2e-4, s[:, ::-1]]).reshape(2, 2, 500, 20)
    ref, dev = both(batch, tt, h=np.array([[H, 2 * H], [0.5 * H, H]]))
    assert_same(ref, dev)
    assert dev["amplitude"].shape == (2, 2) and dev["arrival_time"].shape == (2, 2, 20)


def test_empty_window_is_nan(adversarial):
    """docs/measurements.md: NaN if the window is empty (the NumPy reference raises there instead)."""
    s, t = adversarial
    dev = measure_pulse_device(s, t, H, device=DEVICE, skip_impact=20, skip_clamp=20)
    for k in ("amplitude", "speed", "speed_snapshot", "width_fwhm", "width_10", "prisms_measured"):
        assert np.isnan(dev[k]).all(), k
    assert np.isfinite(dev["peak_time"]).any()  # the per-prism track needs no window


def test_fp32_record(adversarial):
    """A float32 device record is measured in float64: the reference on the same float32 values."""
    s, t = adversarial
    s32 = s.astype(np.float32).astype(np.float64)
    with np.errstate(all="ignore"):
        ref = M.measure_pulse(s32, t, H)
    assert_same(ref, measure_pulse_device(s, t, H, device=DEVICE, precision="fp32"))


def test_failed_columns_and_truncated_columns(adversarial):
    """n_valid (samples recorded before a column failed) reads as the NaN-padded host record;
    cut prisms at the clamp read as the zero-padded one."""
    s, t = adversarial
    R, T, P = s.shape
    n_valid = np.full(R, T)
    n_valid[[0, 1, 10]] = [T - 1, 300, 1]
    cut = 6
    host = s.copy()
    host[:, :, :cut] = 0.0
    for b in range(R):
        host[b, n_valid[b]:] = np.nan
    with np.errstate(all="ignore"):
        ref = M.measure_pulse(host, t, H)
    rec = wp.array(np.ascontiguousarray(s[:, :, cut:].transpose(1, 2, 0)), dtype=wp.float64, device=DEVICE)
    dev = measure_record(rec, t, H, n_prisms=P, cut=cut, n_valid=n_valid)
    assert_same(ref, dev)
    assert_stats(host, dev)
    assert np.isfinite(ref["threshold"][[0, 1]]).all() and np.isnan(ref["amplitude"][[0, 1]]).all()


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**31 - 1), P=st.integers(3, 24), T=st.integers(2, 300),
       levels=st.sampled_from([0.0, 1e-4, 3e-4]), noise=st.sampled_from([0.0, 1e-5, 1e-4]))
def test_random_records(seed, P, T, levels, noise):
    """Random pulse trains (several speeds, widths, signs), noise and quantisation (ties)."""
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.uniform(0.5, 1.5, T)) * 1e-3
    t -= t[0]
    j = np.arange(P)
    s = np.zeros((4, T, P))
    for r in range(4):
        for _ in range(rng.integers(1, 4)):
            c = rng.uniform(5.0, 200.0)
            x0 = P - 1 + rng.uniform(-2, 6) - c * t[:, None]
            s[r] -= rng.uniform(-0.3, 1.0) * 1e-3 / np.cosh((j[None, :] - x0) / rng.uniform(0.6, 4.0)) ** 2
    s += noise * rng.standard_normal(s.shape)
    if levels:
        s = np.round(s / levels) * levels
    ref, dev = both(s, t)
    assert_same(ref, dev)


def test_bad_inputs_raise():
    with pytest.raises(ValueError, match="time"):
        measure_pulse_device(np.zeros((10, 5)), np.arange(9.0), H, device="cpu")
    with pytest.raises(ValueError, match="end_fraction"):
        measure_pulse_device(np.zeros((10, 5)), np.arange(10.0), H, device="cpu", end_fraction=1.0)
    rec = wp.zeros((10, 4, 2), dtype=wp.float64, device="cpu")
    with pytest.raises(ValueError, match="cut"):
        measure_record(rec, np.arange(10.0), H, n_prisms=5, cut=2)
    with pytest.raises(SettingsError, match="measure"):
        RunSettings(measure="gpu")


# ---------------------------------------------------------------------- engine records
def _engine(spec_name: str, **over):
    spec = load_spec(ROOT / "sweeps" / spec_name)
    settings = spec.run_settings(device=DEVICE)
    settings = RunSettings(**{**settings.__dict__, "record_strain": True, **over})
    return spec, simulate_batch(spec.scene, spec.column_params(), settings)




@pytest.mark.parametrize("spec_name", ["ci_small.toml"])
def test_engine_ci_small(spec_name):
    spec, r = _engine(spec_name)
    with np.errstate(all="ignore"):
        ref = M.measure_pulse(r.strain, r.time, spec.scene.height)
    assert_same(ref, r.measurements)
    assert r.info["stages"]["measurement"] > 0


@pytest.mark.slow  # needs the README's main job (conftest paper_2017_nc, ~15 s)
def test_engine_paper_cases(paper_2017_nc):
    """The 12 cases of Fabbrocino & Carpentieri (2017) as the README's main job writes them (CLI, CPU,
    fp64, strain recorded): the measures the run stored (taken on the device during the run) and the
    device measures of the stored record, every key, against the NumPy reference."""
    ds = xr.open_dataset(paper_2017_nc)
    s, t = ds["strain"].values, ds["t"].values
    assert ds.sizes["case"] == 12 and np.all(ds["status"].values == 0)
    with np.errstate(all="ignore"):
        ref = M.measure_pulse(s, t, H)
    dev = measure_pulse_device(s, t, H, device=DEVICE)
    assert_same(ref, dev)
    assert_stats(s, dev)
    stored = {"width_fwhm" if k == "width" else k: ds[k].values for k in
              ("amplitude", "speed", "width", "width_10", "prisms_measured", "arrival_time")}
    # the cases that left the feasible set before their pulse crossed the window: NaN (docs/model.md)
    left = ds["measurement_flag"].values == MEASUREMENT_FLAGS.index("left_feasible_set")
    assert left.tolist() == (ds["feasibility_flag"].values != 0).tolist() and left.sum() == 5
    want = {k: np.where(left, np.nan, ref[k]) for k in stored if k != "arrival_time"}
    want["arrival_time"] = ref["arrival_time"].copy()  # NaN where reached at or after the case left
    with np.errstate(invalid="ignore"):
        want["arrival_time"][want["arrival_time"] >= ds["feasibility_time"].values[:, None]] = np.nan
    assert_same(want, stored)
    np.testing.assert_array_equal(ds["max_compression"].values,
                                  np.where(left, np.nan, record_stats(s)["max_compression"]))
    assert np.isfinite(stored["speed"][~left]).all()


def test_engine_truncated_run_and_host_fallback():
    """A truncated run (the far prisms never simulated) measures the zero-padded column; the host
    fallback gives the same measures; record_strain = False keeps the record off the host."""
    spec = load_spec(ROOT / "sweeps" / "paper_2017.toml")
    cfg = spec.scene
    params = {k: v[[6, 8, 9]] for k, v in spec.column_params().items()}  # the fast p = 0.002 cases
    base = RunSettings(t_end=0.1, output_interval=0.001, device=DEVICE, truncate=True)
    dev = simulate_batch(cfg, params, base)
    assert dev.info["choices"]["prisms_simulated"] < cfg.n_prisms
    assert np.isfinite(dev.measurements["peak_time"]).any()
    host = simulate_batch(cfg, params, RunSettings(**{**base.__dict__, "measure": "host"}))
    assert_same({k: v for k, v in host.measurements.items() if k not in RECORD_STATS}, dev.measurements)
    assert_stats(dev.strain, host.measurements)
    assert_stats(dev.strain, dev.measurements)
    with np.errstate(all="ignore"):
        assert_same(M.measure_pulse(dev.strain, dev.time, cfg.height), dev.measurements)
    off = simulate_batch(cfg, params, RunSettings(**{**base.__dict__, "record_strain": False}))
    assert off.strain is None
    assert_same({k: v for k, v in dev.measurements.items() if k not in RECORD_STATS}, off.measurements)


def test_shard_measures_without_the_record_on_the_host():
    """A sweep shard whose strain stays on the device (record_strain = false) gets the same
    measures, max_compression and measurement_flag as one whose record crosses to the host."""
    from warp_tensegrity.sweep.shard import measure_columns

    flags = set()
    for name, over in (("ci_small.toml", {}), ("paper_2017.toml", {"t_end": 0.1, "output_interval": 0.001})):
        spec = load_spec(ROOT / "sweeps" / name)
        s_on = RunSettings(**{**spec.run_settings(device=DEVICE).__dict__, "record_strain": True, **over})
        on = simulate_batch(spec.scene, spec.column_params(), s_on)
        off = simulate_batch(spec.scene, spec.column_params(), RunSettings(**{**s_on.__dict__, "record_strain": False}))
        assert on.strain is not None and off.strain is None
        a, b = measure_columns(on, spec.scene.height), measure_columns(off, spec.scene.height)
        assert set(a) == set(b)
        for k in a:
            np.testing.assert_array_equal(b[k], a[k], err_msg=k)
        flags |= set(a["measurement_flag"].tolist())
    assert len(flags) > 1  # ok and not-ok columns both compared
