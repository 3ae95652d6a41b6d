"""Sweeps end to end on the CPU with tiny columns: grid layout, shard-size invariance, a diverging
column among normal ones, status/dry-run/progress. The store itself (streaming, resume after
SIGKILL, corruption, locks, memory) is tested in test_store.py."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import xarray as xr

from warp_tensegrity import cli, sweep
from warp_tensegrity.io import drop_run_dependent, open_sweep
from warp_tensegrity.sweep import SpecError, parse_spec

REPO = Path(__file__).resolve().parents[2]

GRID_SPEC = """
title = "test grid"
[scene]
n_prisms = 6
impact_admissibility = "end_twist"  # FB p = 0 pulses cross 6 prisms within 0.2 s

[sweep]
grid = { prestrain = [0.0, 0.002], v0 = [0.003, 0.006], base_rigidity = [0.0, 1.0] }

[run]
t_end = 0.2
output_interval = 0.005
device = "cpu"
shard_size = 3
record_strain = true
"""


def write(tmp_path, text, name="spec.toml") -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


def run_cli(*args) -> int:
    extra = ["--no-progress"] if args[0] in ("run", "resume") else []
    return cli.main([*map(str, args), *extra])


def comparable(ds: xr.Dataset) -> xr.Dataset:
    return drop_run_dependent(ds)


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """One uninterrupted run of GRID_SPEC (in-process)."""
    d = tmp_path_factory.mktemp("reference")
    spec = write(d, GRID_SPEC)
    out = d / "ref.nc"
    assert run_cli("run", spec, "-o", out) == 0
    return open_sweep(out)


def test_grid_dataset_layout(reference):
    ds = reference
    assert dict(ds.sizes) == {"prestrain": 2, "v0": 2, "base_rigidity": 2, "prism": 6, "t": 41}
    assert ds["amplitude"].dims == ("prestrain", "v0", "base_rigidity")
    assert ds["arrival_time"].dims == ("prestrain", "v0", "base_rigidity", "prism")
    assert ds["strain"].dims == ("prestrain", "v0", "base_rigidity", "t", "prism")
    assert (ds["status"] == 0).all()
    assert float(ds["bar_length_error"].max()) < 1e-8
    # the stronger impact gives the larger pulse (FB, zero prestrain)
    amp = ds["amplitude"].sel(prestrain=0.0, base_rigidity=0.0)
    assert np.isfinite(amp).all() and amp.sel(v0=0.006) > amp.sel(v0=0.003)
    assert ds.attrs["sweep_kind"] == "grid" and ds.attrs["device"] == "cpu"


def test_shard_size_invariance(tmp_path, reference):
    spec = write(tmp_path, GRID_SPEC)
    out = tmp_path / "one_shard.nc"
    assert run_cli("run", spec, "-o", out, "--shard-size", 8) == 0
    assert sweep.sweep_status(out)["shards"] == 1
    xr.testing.assert_identical(comparable(open_sweep(out)), comparable(reference))


def test_run_refuses_to_clobber_then_overwrites(tmp_path, capsys):
    spec = write(tmp_path, GRID_SPEC.replace("v0 = [0.003, 0.006]", "v0 = [0.003]"))
    out = tmp_path / "o.nc"
    assert run_cli("run", spec, "-o", out) == 0
    assert run_cli("run", spec, "-o", out) == 1
    assert "resume" in capsys.readouterr().err
    assert run_cli("run", spec, "-o", out, "--overwrite") == 0


CASES_SPEC = """
[scene]
n_prisms = 6

[sweep]
cases = [
  { prestrain = 0.0,   v0 = 0.003, base_rigidity = 0.0 },
  { prestrain = 0.002, v0 = 0.006, base_rigidity = 1.0 },
{ABSURD}
  { prestrain = 0.0,   v0 = 0.006, base_rigidity = 0.0 },
]

[run]
t_end = 0.2
dt = 0.012                 # above the stability limit (~0.0096 s) but stable for the normal columns
allow_unstable_dt = true
output_interval = 0.024
device = "cpu"
shard_size = 2
record_strain = true
"""


def test_diverging_column_is_recorded_and_others_unaffected(tmp_path):
    absurd = "  { prestrain = 0.0, v0 = 1000.0, base_rigidity = 0.0 },   # absurd: 1 km/s impact"
    with_bad = write(tmp_path, CASES_SPEC.replace("{ABSURD}", absurd), "with.toml")
    without = write(tmp_path, CASES_SPEC.replace("{ABSURD}", ""), "without.toml")
    assert run_cli("run", with_bad, "-o", tmp_path / "with.nc") == 0
    assert run_cli("run", without, "-o", tmp_path / "without.nc") == 0
    a = open_sweep(tmp_path / "with.nc")
    b = open_sweep(tmp_path / "without.nc")
    assert a.sizes["case"] == 4 and b.sizes["case"] == 3
    assert a["v0"].dims == ("case",)  # CF auxiliary coordinate along case
    bad = a.isel(case=2)
    assert int(bad["status"]) != 0 and int(bad["fail_step"]) >= 0
    assert np.isnan(float(bad["amplitude"])) and np.isnan(float(bad["speed"]))
    assert sweep.sweep_status(tmp_path / "with.nc")["cases_diverged"] == 1
    normal = a.isel(case=[0, 1, 3])
    assert (normal["status"] == 0).all() and (normal["fail_step"] == -1).all()
    keep = [v for v in a.data_vars]
    for k in keep:
        np.testing.assert_array_equal(normal[k].values, b[k].values, err_msg=k)
    for k in ("prestrain", "v0", "base_rigidity"):
        np.testing.assert_array_equal(normal[k].values, b[k].values)


def test_dt_refused_without_allow_unstable(tmp_path, capsys):
    text = CASES_SPEC.replace("{ABSURD}", "").replace("allow_unstable_dt = true", "")
    spec = write(tmp_path, text)
    assert run_cli("run", spec, "-o", tmp_path / "x.nc") == 1
    err = capsys.readouterr().err
    assert "run.dt = 0.012" in err and "stability limit" in err
    assert not (tmp_path / "x.nc.sweep").exists()


def test_dry_run_prints_plan_and_runs_nothing(tmp_path, capsys):
    spec = write(tmp_path, GRID_SPEC)
    out = tmp_path / "d.nc"
    assert run_cli("run", spec, "-o", out, "--dry-run") == 0
    text = capsys.readouterr().out
    assert "8 columns" in text and "3 of up to 3 columns" in text
    assert "memory" in text and "time" in text and "dt =" in text
    assert not out.exists() and not (tmp_path / "d.nc.sweep").exists()


def test_progress_bar(tmp_path):
    import io

    spec = parse_spec(GRID_SPEC.replace("v0 = [0.003, 0.006]", "v0 = [0.003]"))
    buf = io.StringIO()
    sweep.run_sweep(spec, tmp_path / "p.nc", progress=True, stream=buf)
    text = buf.getvalue()
    assert "4/4 columns" in text and "0 diverged" in text and "ETA" in text
    quiet = io.StringIO()  # not a terminal: by default (progress=None) the bar stays quiet
    sweep.run_sweep(spec, tmp_path / "q.nc", progress=None, stream=quiet)
    assert quiet.getvalue() == ""


def test_progress_eta_starts_from_the_estimate():
    from warp_tensegrity.sweep.progress import ProgressBar

    bar = ProgressBar(100, enabled=False, estimate_s=50.0)
    assert 49.0 < bar.eta() <= 50.0  # nothing done yet: the calibrated estimate
    bar.t0 -= 10.0  # 10 s on, half done: blend of estimate (25 s left) and rate (10 s left)
    bar.update(50, 0)
    assert bar.eta() == pytest.approx(0.5 * 25.0 + 0.5 * 10.0, rel=1e-3)
    bar.update(100, 0)
    assert bar.eta() == 0.0


def test_python_api_matches_spec_error_paths(tmp_path):
    spec = parse_spec(GRID_SPEC.replace("t_end = 0.2", "t_end = 0.2\ndt = 0.1"))
    with pytest.raises(SpecError, match="run.dt"):
        sweep.run_sweep(spec, tmp_path / "z.nc", progress=False)
