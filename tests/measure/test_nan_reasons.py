"""Every NaN pulse measure carries a reason (measurement_flag), the end-of-run summary says what
would help, and the README's Python snippets run and show data (issue 16, part 2)."""

import re
from pathlib import Path

import numpy as np
import pytest
import xarray as xr

from warp_tensegrity import ColumnConfig, RunSettings, simulate_batch
from warp_tensegrity.cli import main as cli_main
from warp_tensegrity.io import open_sweep
from warp_tensegrity.measure.nan_reasons import FLAG, FLAGGED, FLAGS, dataset_summary, measurement_flags, t_end_needed
from warp_tensegrity.sweep.shard import measure_columns

ROOT = Path(__file__).resolve().parents[2]


def _check_every_nan_flagged(ds):
    flag = ds["measurement_flag"]
    assert list(flag.attrs["flag_meanings"].split()) == list(FLAGS)
    np.testing.assert_array_equal(flag.attrs["flag_values"], np.arange(len(FLAGS)))
    for name in FLAGGED:
        nan = np.isnan(ds[name].values)
        assert not np.any(nan & (flag.values == FLAG["ok"])), f"{name} NaN with flag ok"


@pytest.fixture(scope="module")
def ci_small(ci_small_nc):
    return ci_small_nc  # conftest's session run of sweeps/ci_small.toml through the CLI


def test_ci_small_every_case_measured_and_flagged(ci_small):
    ds = open_sweep(ci_small)
    _check_every_nan_flagged(ds)
    assert (ds["measurement_flag"].values == FLAG["ok"]).all()
    assert np.isfinite(ds.speed.sel(base_rigidity=1.0).values).all()


def _python_blocks(text):
    return re.findall(r"```python\n(.*?)```", text, flags=re.S)


def test_readme_python_snippets_run_and_show_data(ci_small, monkeypatch, tmp_path):
    import matplotlib

    matplotlib.use("Agg")
    blocks = _python_blocks((ROOT / "README.md").read_text())
    assert len(blocks) >= 2
    (tmp_path / "ci_small.nc").symlink_to(ci_small)
    monkeypatch.chdir(tmp_path)
    for code in blocks:
        code = code.replace("B = 4096", "B = 4")  # small data: the README's batch is a GPU's
        ns = {}
        exec(compile(code, "README.md", "exec"), ns)  # noqa: S102 - the README's own examples
        if "r" in ns:  # the engine example
            r = ns["r"]
            assert (r.status == 0).all()
            assert np.isfinite(r.strain).all() and np.abs(r.strain).max() > 0
            from warp_tensegrity.measure import measure_pulse

            m = measure_pulse(r.strain, r.time, ns["cfg"].height)
            assert np.isfinite(m["speed"]).all() and np.isfinite(m["amplitude"]).all()
        if "ds" in ns:  # the dataset example: the plotted speeds are data
            assert np.isfinite(ns["ds"].speed.sel(base_rigidity=1.0).values).all()


def test_cli_prints_the_nan_summary_and_its_t_end_is_enough(tmp_path, capsys):
    spec = (ROOT / "sweeps" / "ci_small.toml").read_text().replace("t_end = 2.0", "t_end = 0.5")
    (tmp_path / "short.toml").write_text(spec)
    out = tmp_path / "short.nc"
    assert cli_main(["run", str(tmp_path / "short.toml"), "-o", str(out), "--device", "cpu", "--no-progress"]) == 0
    printed = capsys.readouterr().err  # the summary is a log message (stderr; -q hides it)
    ds = open_sweep(out)
    _check_every_nan_flagged(ds)
    n_short = int((ds.measurement_flag.values == FLAG["pulse_not_reached_window_by_t_end"]).sum())
    assert n_short > 0
    m = re.search(rf"{n_short} of 8 cases have no speed: the pulse had not reached prism \d+ .*by t_end = 0.5 s; "
                  r"t_end >= ([0-9.e+-]+) s would be enough", printed)
    assert m, printed
    # independent check of the advice: rerun the flagged RB cases with that t_end
    t_need = float(m.group(1))
    short = ds.measurement_flag.values == FLAG["pulse_not_reached_window_by_t_end"]
    grid = xr.broadcast(ds.prestrain, ds.v0, ds.base_rigidity)
    params = {k: g.transpose(*ds.measurement_flag.dims).values[short] for k, g in zip(("prestrain", "v0", "base_rigidity"), grid)}
    cfg = ColumnConfig(n_prisms=8)
    r = simulate_batch(cfg, params, RunSettings(t_end=t_need, output_interval=0.005, device="cpu"))
    meas = measure_columns(r, cfg.height)
    assert np.isfinite(meas["speed"]).all(), meas["speed"]


def test_flags_for_flat_failed_and_short_records():
    cfg = ColumnConfig(n_prisms=8)
    params = {"prestrain": [0.002, 0.002, 0.002], "v0": [0.0, 0.005, 0.005], "base_rigidity": 1.0}
    r = simulate_batch(cfg, params, RunSettings(t_end=0.3, output_interval=0.005, device="cpu"))
    r.status[2] = 2  # as if a constraint had failed: the measures must be NaN and say so
    meas = measure_columns(r, cfg.height)
    flags = meas["measurement_flag"]
    assert flags[0] == FLAG["no_leading_pulse"]  # v0 = 0: flat record
    assert flags[1] == FLAG["pulse_not_reached_window_by_t_end"]
    assert flags[2] == FLAG["constraint_failure"] and np.isnan(meas["speed"][2])
    strain = r.strain.copy()
    strain[1, -1, 0] = np.nan
    assert measurement_flags(np.zeros(3), strain, r.time, meas)[1] == FLAG["non_finite"]


def test_t_end_needed_extrapolates_the_front():
    P = 20
    at = np.full((1, P), np.nan)
    j = np.arange(12, P)
    at[0, j] = (P - 1 - j) * 0.1  # 10 prisms per second from the impacted end
    need = t_end_needed(at, np.linspace(0, 1, 11))
    lo = 2  # measurement window of 20 prisms starts at prism 2; 4 prisms beyond it
    assert need[0] == pytest.approx((P - 1 - (lo - 4)) * 0.1)


@pytest.mark.slow
def test_paper_2017_nans_are_flagged(paper_2017_nc):
    ds = open_sweep(paper_2017_nc)
    _check_every_nan_flagged(ds)
    assert dataset_summary(ds) == [] or all("of 12 cases" in s for s in dataset_summary(ds))


def test_a_captured_threshold_is_flagged_not_measured():
    """Issue 25: where something else crosses the threshold before the leading pulse over most of
    the window, the case gets leading_pulse_captured and NaN measures; where it does so over a
    smaller part, the measures are taken before the cut and the flag stays ok."""
    from types import SimpleNamespace

    from test_measure import _sech2_history, _with_disturbance

    t, clean = _sech2_history(t_end=1.4)
    s = np.stack([clean, _with_disturbance(20.0)[1], _with_disturbance(150.0)[1]])
    res = SimpleNamespace(status=np.zeros(3, np.int8), strain=s, time=t, measurements=None)
    m = measure_columns(res, 6.2e-3)
    assert m["measurement_flag"].tolist() == [FLAG["ok"], FLAG["ok"], FLAG["leading_pulse_captured"]]
    assert np.isfinite(m["speed"][:2]).all() and np.isnan(m["speed"][2])
    assert m["pulse_captured"].tolist() == [0.0, 1.0, 1.0]
