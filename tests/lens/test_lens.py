"""warp_tensegrity.lens: inversion against an analytic speed law, the host superposition
(reciprocity, 1/r and 1/sqrt(r) spreading, flight time), spec errors, and the CLI on CPU."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from warp_tensegrity.lens import (
    LensSpecError,
    column_positions,
    common_arrival,
    design_focus,
    field,
    fit_exit_law,
    focal_map,
    map_grid,
    map_peak,
    parse_lens_spec,
    peak_over_time,
)
from warp_tensegrity.lens.host import sample

# analytic column law: exit time T(p) = t0 + L / c(p), c(p) = c0 sqrt(1 + p / p0)
L, C0, P0, T0 = 0.186, 0.1, 0.02, 0.05


def T_exact(p):
    return T0 + L / (C0 * np.sqrt(1.0 + np.asarray(p) / P0))


def p_exact(t):
    return P0 * ((L / (C0 * (np.asarray(t) - T0))) ** 2 - 1.0)


def gaussian_signals(centres, amps, dt, n, width):
    t = np.arange(n) * dt
    return np.asarray(amps)[:, None] * np.exp(-0.5 * ((t[None, :] - np.asarray(centres)[:, None]) / width) ** 2)


# ---------------------------------------------------------------------- design / inversion
@pytest.mark.parametrize("noise", [0.0, 2e-5])
def test_inversion_recovers_analytic_prestrains(noise):
    p_cal = np.linspace(0.0, 0.1, 1024)
    t_cal = T_exact(p_cal) + noise * np.random.default_rng(0).standard_normal(p_cal.size)
    law = fit_exit_law(p_cal, t_cal)
    assert law.decreasing
    pos = column_positions("line", (16, 1), 0.012)
    F = np.array([0.01, 0.0, 0.12])
    c_h = 0.2
    d = design_focus(law, pos, np.zeros(16), F, c_h)
    assert d.reachable.all()
    # exact prestrains of the analytic law at the design's targets
    p_true = p_exact(d.target_exit_time)
    tol = 1e-6 if noise == 0 else 2e-4  # grid interpolation / jitter of the calibration
    np.testing.assert_allclose(d.prestrain, p_true, atol=tol * 0.1)
    # the analytic law with the designed prestrains focuses: equal arrival at F
    arrival = T_exact(d.prestrain) + np.linalg.norm(pos - F, axis=1) / c_h
    spread = np.ptp(d.target_exit_time)
    assert np.ptp(arrival) < (1e-4 if noise == 0 else 5e-3) * spread
    # the common arrival centres the targets in the calibrated range
    lo, hi = law.t_range
    assert lo <= d.target_exit_time.min() and d.target_exit_time.max() <= hi
    assert abs(0.5 * (d.target_exit_time.min() + d.target_exit_time.max()) - 0.5 * (lo + hi)) < 1e-12


def test_unreachable_columns_are_reported_and_the_most_reach():
    p_cal = np.linspace(0.0, 0.1, 256)
    law = fit_exit_law(p_cal, T_exact(p_cal))
    pos = column_positions("line", (32, 1), 0.012)
    F = np.array([0.1, 0.0, 0.05])  # far off-axis, close: flight times spread more than T's range
    d = design_focus(law, pos, np.zeros(32), F, wave_speed=0.1)
    lo, hi = law.t_range
    assert 0 < d.reachable.sum() < 32
    lag = np.linalg.norm(pos - F, axis=1) / 0.1
    # brute force over C: no common arrival keeps more columns in range
    best = max(np.sum((c - lag >= lo) & (c - lag <= hi)) for c in np.linspace(lo + lag.min() - 1, hi + lag.max() + 1, 20001))
    assert d.reachable.sum() == best
    # unreachable columns get the end of the calibrated range
    assert np.all(np.isin(np.round(d.prestrain[~d.reachable], 12), np.round([p_cal[0], p_cal[-1]], 12)))


def test_common_arrival_feasible_interval_centre():
    assert common_arrival(np.array([0.0, 0.2, 0.1]), 1.0, 2.0) == pytest.approx(0.5 * (1.0 + 2.0 + 0.2 + 0.0))


def test_fit_exit_law_rejects_flat_and_empty():
    from warp_tensegrity.lens import CalibrationError

    with pytest.raises(CalibrationError, match="finite exit time"):
        fit_exit_law(np.linspace(0, 1, 10), np.full(10, np.nan))
    with pytest.raises(CalibrationError, match="does not change"):
        fit_exit_law(np.linspace(0, 1, 10), np.ones(10))


# ---------------------------------------------------------------------- host superposition
def test_sample_interpolates_linearly_zero_before_nan_after():
    dt = 0.01
    s = np.array([[1.0, 3.0, 5.0, 7.0]])
    v = sample(s, dt, np.array([[-0.02, -0.005, 0.0, 0.015, 0.03, 0.031]]))
    np.testing.assert_allclose(v[0, :5], [0.0, 0.5, 1.0, 4.0, 7.0])
    assert np.isnan(v[0, 5])


@pytest.mark.parametrize("dimension, power", [(3, 1.0), (2, 0.5)])
def test_single_source_spreading_and_flight_time(dimension, power):
    dt, c_h = 1e-3, 0.3
    s = gaussian_signals([0.2], [1.0], dt, 1200, 0.02)
    src = np.array([[0.01, -0.02, 0.0]])
    R = np.array([0.05, 0.1, 0.2, 0.4])
    direction = np.array([0.6, 0.0, 0.8])
    rec = src + R[:, None] * direction
    peaks = peak_over_time(s, dt, src, [0.0], rec, c_h, dimension)
    scaled = peaks * R**power
    np.testing.assert_allclose(scaled, scaled[0], rtol=1e-6)  # exactly the spreading law
    np.testing.assert_allclose(scaled, 1.0, rtol=1e-3)  # peak kept through the interpolation
    # the peak arrives R / c_h after the source's
    times = np.arange(2000) * dt
    phi = field(s, dt, src, [0.0], rec, times, c_h, dimension)
    t_peak = times[np.nanargmax(phi, axis=1)]  # NaN: after the record (unknown)
    np.testing.assert_allclose(t_peak, 0.2 + R / c_h, atol=dt)


@pytest.mark.parametrize("dimension", [2, 3])
def test_reciprocity_and_linearity(dimension):
    rng = np.random.default_rng(1)
    dt, c_h = 1e-3, 0.25
    s = gaussian_signals([0.1], [1.0], dt, 600, 0.015)
    times = np.arange(1500) * dt
    for _ in range(5):
        a, b = rng.uniform(-0.2, 0.2, (2, 3))
        ab = field(s, dt, a[None], [0.0], b[None], times, c_h, dimension)
        ba = field(s, dt, b[None], [0.0], a[None], times, c_h, dimension)
        np.testing.assert_array_equal(ab, ba)
    # the field of several sources is the sum of their fields (delays included)
    src = rng.uniform(-0.1, 0.1, (3, 3))
    sig = gaussian_signals([0.1, 0.15, 0.2], [1.0, -0.5, 2.0], dt, 600, 0.015)
    delays = np.array([0.0, 0.03, 0.01])
    rec = rng.uniform(-0.1, 0.1, (4, 3)) + [0, 0, 0.3]
    total = field(sig, dt, src, delays, rec, times, c_h, dimension)
    parts = sum(field(sig[i:i + 1], dt, src[i:i + 1], delays[i:i + 1], rec, times, c_h, dimension) for i in range(3))
    np.testing.assert_allclose(total, parts, rtol=1e-12, atol=1e-14)


def test_designed_delays_focus_synthetic_pulses_at_F():
    """Ideal pulses (Gaussian, one shape) delayed by the design focus where asked, in 2D."""
    dt, c_h, n = 2e-3, 0.15, 32
    pos = column_positions("line", (n, 1), 0.012)
    p_cal = np.linspace(0.0, 0.15, 512)
    law = fit_exit_law(p_cal, 0.8 + 1.1 * (1 - p_cal / 0.15))  # 0.8 .. 1.9 s
    for F in ([0.0, 0.0, 0.12], [0.04, 0.0, 0.14]):
        d = design_focus(law, pos, np.zeros(n), F, c_h)
        s = gaussian_signals(d.target_exit_time, np.ones(n), dt, 1400, 0.025)
        axes = map_grid([F], 0.03, 0.03, 25, False)
        m = focal_map(s, dt, pos, np.zeros(n), axes, c_h, 2)
        peak = map_peak(m, axes)
        assert np.linalg.norm(peak - F) < 0.012  # within one column spacing


# ---------------------------------------------------------------------- spec
BASE = {
    "column": {"scene": {"n_prisms": 6}, "base_rigidity": 1.0},
    "array": {"count": 4, "spacing": 0.012},
    "design": {"focal_points": [[0.0, 0.0, 0.05]]},
    "run": {"t_end": 0.5, "output_interval": 0.002},
}


def _with(path, value):
    import copy

    d = copy.deepcopy(BASE)
    t = d
    keys = path.split(".")
    for k in keys[:-1]:
        t = t.setdefault(k, {})
    t[keys[-1]] = value
    return d


@pytest.mark.parametrize(
    "path, value, words",
    [
        ("array.spacing", -0.01, ["array.spacing", "-0.01"]),
        ("array.spacing", 0.004, ["array.spacing", "0.004", "diameter"]),
        ("host.wave_speed", 0.0, ["host.wave_speed", "0.0"]),
        ("host.dimension", 4, ["host.dimension", "4"]),
        ("calibration.count", 3, ["calibration.count", "3"]),
        ("calibration.prestrain_max", -1.0, ["calibration.prestrain_max", "-1.0"]),
        ("design.focal_points", [[0.0, 0.0, -0.1]], ["design.focal_points", "-0.1"]),
        ("column.scene", {"n_prism": 5}, ["column.scene", "n_prism"]),
        ("column.scene", {"radius": -1.0}, ["column.scene", "radius", "-1.0"]),
        ("column.base_rigidity", 2.0, ["column.base_rigidity", "2.0"]),
        ("run.method", "euler", ["run.method", "euler"]),
        ("run.output_interval", 0.4, ["output_interval", "0.4"]),
        ("incident.v0", "fast", ["incident.v0", "fast"]),
        ("host.speed", 1.0, ["host.speed", "unknown"]),
        ("array.layout", "grid", ["array.count = 4", "[nx, ny]"]),
        ("array.count", [3, 3], ["array.count = [3, 3]", "line"]),
    ],
)
def test_spec_errors_name_key_and_value(path, value, words):
    with pytest.raises(LensSpecError) as e:
        parse_lens_spec(_with(path, value), "t.toml")
    for w in words:
        assert w in str(e.value), (w, str(e.value))


def _sweep_error(table: str) -> str:
    """The message a sweep spec gives for ``table`` (TOML), after its key path."""
    from warp_tensegrity.sweep import SpecError, parse_spec

    text = "[scene]\nn_prisms = 3\n[sweep]\ngrid = { prestrain = [0.0] }\n[run]\nt_end = 0.1\n"
    with pytest.raises(SpecError) as e:
        parse_spec(text.replace("[run]\nt_end = 0.1\n", table) if "[run]" in table else text + table)
    return str(e.value).split(" = ", 1)[1]


@pytest.mark.parametrize("path, value, sweep_table", [
    ("incident.v0", 2e4, "[sweep.fixed]\nv0 = 2e4\n"),  # the lens allowed <= 10, sweeps any v0 >= 0
    ("incident.v0", -1.0, "[sweep.fixed]\nv0 = -1.0\n"),
    ("column.base_rigidity", 2.0, "[sweep.fixed]\nbase_rigidity = 2.0\n"),
    ("run.t_end", 2e9, "[run]\nt_end = 2e9\n"),  # the lens allowed <= 1e3 s, sweeps ~30 years
    ("run.dt", 1e-20, "[run]\nt_end = 0.1\ndt = 1e-20\n"),
])
def test_lens_bounds_are_the_sweeps(path, value, sweep_table):
    """The lens has no option system of its own (issue 26): a key it shares with sweeps has the
    sweeps' bound, from options.py, and the same message after the key path."""
    with pytest.raises(LensSpecError) as e:
        parse_lens_spec(_with(path, value), "t.toml")
    lens = str(e.value).split(f"{path} = ", 1)[1]
    assert lens == _sweep_error(sweep_table), (lens, _sweep_error(sweep_table))


def test_lens_options_are_declared_in_the_options_layer():
    """lens/spec.py declares no option (no pydantic Field, no bound of its own): it reads the
    classes of options_lens, which reuse the sweeps' declarations (issue 26)."""
    from warp_tensegrity import options as O
    from warp_tensegrity import options_lens as OL

    src = (Path(__file__).resolve().parents[2] / "warp_tensegrity" / "lens" / "spec.py").read_text()
    import re

    assert "Field(" not in src and "BaseModel" not in src and not re.search(r"\b(ge|gt|le|lt)=", src)
    assert O.opt_of(OL.LensIncident, "v0") is O.opt_of(O.ColumnParameters, "v0")
    assert O.opt_of(OL.LensRun, "t_end") is O.opt_of(O.RunSettings, "t_end")
    assert O.opt_of(OL.LensCalibration, "prestrain_max") is O.opt_of(O.ColumnParameters, "prestrain")


def test_lens_v0_must_strike():
    with pytest.raises(LensSpecError, match=r"incident.v0 = 0.0: must be > 0 \[m s-1\]"):
        parse_lens_spec(_with("incident.v0", 0.0))


def test_spec_missing_design_and_line_plane():
    d = dict(BASE)
    d.pop("design")
    with pytest.raises(LensSpecError, match="design: required key is missing"):
        parse_lens_spec(d)
    with pytest.raises(LensSpecError, match="y = const"):
        parse_lens_spec(_with("design.focal_points", [[0, 0, 0.1], [0, 0.01, 0.1]]))


def test_shipped_specs_validate():
    from pathlib import Path

    from warp_tensegrity.lens import load_lens_spec

    root = Path(__file__).resolve().parents[2]
    ci = load_lens_spec(root / "sweeps/lens_ci.toml")
    demo = load_lens_spec(root / "sweeps/lens_demo.toml")
    assert ci.array.shape[0] <= 8 and ci.column.config().n_prisms <= 10
    assert demo.calibration.count >= 1024 and len(demo.design.focal_points) == 3


# ---------------------------------------------------------------------- the command, on the CPU
@pytest.mark.slow  # the lens command end to end: calibration and verification batches (~6 s)
def test_lens_command_ci_spec(tmp_path, capsys):
    import xarray as xr

    from warp_tensegrity.cli import main

    out = tmp_path / "x.nc"
    assert main(["lens", "sweeps/lens_ci.toml", "-o", str(out), "--device", "cpu"]) == 0
    ds = xr.open_dataset(out)
    for name in ("prestrain", "exit_time", "target_exit_time", "exit_amplitude"):
        assert ds[name].dims == ("column",)
        assert np.isfinite(ds[name]).all()
    assert ds.focal_map.dims == ("z", "y", "x")
    for name in ("focus_error_m", "focal_gain", "ideal_ratio"):
        assert np.isfinite(ds.attrs[name])
    for name, v in {**ds.data_vars, **ds.coords}.items():
        assert "long_name" in v.attrs or "standard_name" in v.attrs, name
        if v.dtype.kind == "f":
            assert "units" in v.attrs, name
    assert ds.attrs["Conventions"].startswith("CF-")
    # the designed exit times hit their targets; the design beats the uniform array at F
    assert (ds.exit_time_match < 0.05).all()
    assert (ds.focal_gain > 1).all()
    assert ds.sizes["calibration"] == 64 and ds.sizes["focus"] == 3
    # CF-clean as the sweeps' files (issue 23: 'time' in seconds, x/y taken for latitude/longitude)
    pytest.importorskip("compliance_checker.runner")
    from test_cf import cf_messages

    r, msgs = cf_messages(out, tmp_path)
    assert msgs == [], "\n".join(f"{p}: {n}: {m}" for p, n, m in msgs)
    assert r["scored_points"] == r["possible_points"] > 50


def test_lens_command_bad_spec_names_key(tmp_path, capsys):
    from warp_tensegrity.cli import main

    bad = tmp_path / "bad.toml"
    bad.write_text('[array]\nspacing = -1.0\n[design]\nfocal_points = [[0.0, 0.0, 0.1]]\n[run]\nt_end = 1.0\noutput_interval = 0.01\n')
    assert main(["lens", str(bad), "-o", str(tmp_path / "o.nc")]) == 1
    err = capsys.readouterr().err
    assert "array.spacing = -1.0" in err and "Traceback" not in err


def test_plane_wave_delays_enter_the_design():
    """A plane incident wave strikes the columns at d_i; the design still equalises
    d_i + T_i + |F - x_i| / c_h, and the delays are those of the wave's trace speed."""
    from warp_tensegrity.lens import plane_wave_delays

    pos = column_positions("line", (12, 1), 0.012)
    d = plane_wave_delays(pos, angle_deg=30.0, azimuth_deg=0.0, speed=0.5)
    np.testing.assert_allclose(np.diff(d), 0.012 * np.sin(np.radians(30.0)) / 0.5)
    assert d.min() == 0.0
    p_cal = np.linspace(0.0, 0.1, 512)
    law = fit_exit_law(p_cal, T_exact(p_cal))
    F = np.array([0.0, 0.0, 0.1])
    des = design_focus(law, pos, d, F, 0.2)
    total = d + des.target_exit_time + np.linalg.norm(pos - F, axis=1) / 0.2
    np.testing.assert_allclose(total, des.arrival_time, rtol=0, atol=1e-12)
    # the analytic law with the designed prestrains arrives together
    assert np.ptp(d + T_exact(des.prestrain) + np.linalg.norm(pos - F, axis=1) / 0.2) < 1e-4 * np.ptp(des.target_exit_time)


def test_grid_array_focuses_in_3d():
    """A 6 x 6 grid with 1/r spreading and ideal pulses at the designed exit times focuses within a
    spacing of F, off axis in both x and y."""
    dt, c_h = 2e-3, 0.1
    pos = column_positions("grid", (6, 6), 0.012)
    assert pos.shape == (36, 3) and np.ptp(pos[:, 1]) > 0
    p_cal = np.linspace(0.0, 0.15, 256)
    law = fit_exit_law(p_cal, 0.5 + 1.0 * (1 - p_cal / 0.15))
    F = [0.01, -0.008, 0.05]
    d = design_focus(law, pos, np.zeros(36), F, c_h)
    assert d.reachable.all()
    s = gaussian_signals(d.target_exit_time, np.ones(36), dt, 900, 0.02)
    axes = map_grid([F], 0.02, 0.02, 11, True)
    m = focal_map(s, dt, pos, np.zeros(36), axes, c_h, 3)
    assert m.shape == (11, 11, 11)
    assert np.linalg.norm(map_peak(m, axes) - F) < 0.012


def test_reading_a_lens_spec_and_cli_help_do_not_import_warp():
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    code = ("from warp_tensegrity.lens import load_lens_spec; load_lens_spec('sweeps/lens_demo.toml'); "
            "import warp_tensegrity.cli as c; c.build_parser(); import sys; print('warp' in sys.modules)")
    r = subprocess.run([sys.executable, "-c", code], cwd=root, capture_output=True, text=True,
                       env={"PYTHONPATH": str(root), "PATH": ""})
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "False"


def test_calibration_that_never_exits_is_a_clear_error(tmp_path, capsys):
    """t_end too short for any pulse to leave the column: an error naming the cause, no traceback."""
    from pathlib import Path

    from warp_tensegrity.cli import main

    text = (Path(__file__).resolve().parents[2] / "sweeps/lens_ci.toml").read_text()
    text = text.replace("t_end = 0.9 ", "t_end = 0.1 ")
    spec = tmp_path / "short.toml"
    spec.write_text(text.replace("count = 64 ", "count = 8 "))
    assert main(["lens", str(spec), "-o", str(tmp_path / "o.nc"), "--device", "cpu"]) == 1
    err = capsys.readouterr().err
    assert "finite exit time" in err and "t_end" in err and "Traceback" not in err


def test_a_calibration_that_does_not_fit_in_memory_is_refused_up_front(tmp_path, capsys):
    """A lens of long columns (n_prisms = 100,000, legal) recorded the whole column of every
    calibration column: 24 GB and an OOM kill after 90 s here (issue 23); refused at once, with its figures."""
    from warp_tensegrity.cli import main
    from warp_tensegrity.lens.run import check_memory
    from warp_tensegrity.lens.spec import LensSpecError, load_lens_spec

    text = (Path(__file__).resolve().parents[2] / "sweeps/lens_ci.toml").read_text()
    spec = tmp_path / "long.toml"
    spec.write_text(text.replace("n_prisms = 10", "n_prisms = 100000"))
    check_memory(load_lens_spec(Path(__file__).resolve().parents[2] / "sweeps/lens_ci.toml"))  # the CI lens fits
    with pytest.raises(LensSpecError, match=r"64 columns x 451 outputs x 100,000 prisms .* is available"):
        check_memory(load_lens_spec(spec), available=10**9)
    spec.write_text(text.replace("n_prisms = 10", "n_prisms = 100000").replace("count = 64", "count = 1048576"))
    assert main(["lens", str(spec), "-o", str(tmp_path / "o.nc"), "--device", "cpu"]) == 1  # ~1 PB: on any host
    err = capsys.readouterr().err
    assert "1,048,576 columns x 451 outputs x 100,000 prisms" in err and "Traceback" not in err, err


def test_lens_dry_run_and_time_limit_quote_one_estimate(tmp_path, capsys, monkeypatch):
    """The lens job is priced before it runs, by the sweeps' cost model (its two batches decided as
    they will run, one probe): --dry-run prints it and runs nothing; --time-limit refuses a job over it
    with the same figure; a legal but endless job (t_end = 1e6 s) is refused at once."""
    import re

    from warp_tensegrity.cli import main

    from warp_tensegrity.policy import calibrate

    monkeypatch.setenv("WARP_TENSEGRITY_CACHE", str(tmp_path / "cache"))
    # the probe taken as if the host were idle: one taken under load (xdist's other worker) would be
    # taken again between the two calls once the host is idle, with another figure
    monkeypatch.setattr(calibrate, "others_busy", lambda start: 0.0)
    ci = str(Path(__file__).resolve().parents[2] / "sweeps/lens_ci.toml")
    out = tmp_path / "o.nc"
    assert main(["lens", ci, "-o", str(out), "--device", "cpu", "--dry-run"]) == 0
    text = capsys.readouterr().out
    assert "calibration:  64 columns x" in text and "verification: 48 columns x" in text and "fits:        yes" in text
    quoted = re.search(r"time:        ~(\S+) wall", text).group(1)
    assert not out.exists()
    assert main(["lens", ci, "-o", str(out), "--device", "cpu", "--time-limit", "0.5"]) == 1
    err = capsys.readouterr().err
    assert f"the estimate is {quoted} and the time limit is 0.5s" in err and "Traceback" not in err, err
    assert not out.exists()
    endless = tmp_path / "endless.toml"
    endless.write_text(Path(ci).read_text().replace("t_end = 0.9 ", "t_end = 1e6 ").replace(
        "output_interval = 0.002 ", "output_interval = 1e4 ").replace("count = 64 ", "count = 8 "))
    assert main(["lens", str(endless), "-o", str(out), "--device", "cpu"]) == 1
    err = capsys.readouterr().err
    assert re.search(r"the estimate is [\d.]+ days and the time limit is 7 days", err), err
