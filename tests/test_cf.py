"""The CLI's netCDF passes the IOOS compliance checker, CF 1.10, with no error and no warning.

Three layouts: ``sweeps/ci_small.toml`` (a grid: one dimension per swept parameter),
``sweeps/paper_2017.toml`` (a labelled case list: parameters as auxiliary coordinates along
``case``) and ``sweeps/interface.toml`` (a profile along the column over the grid and ``prism``,
its generating parameters as the grid's axes). paper_2017 runs with t_end = 0.2 s here to keep CI fast: t_end changes the lengths
of the axes, not the variables or their attributes. The full run was checked by hand with
``compliance-checker --test cf:1.10`` (no corrective actions).
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from warp_tensegrity import sweep
from warp_tensegrity.sweep import load_spec

cc_runner = pytest.importorskip("compliance_checker.runner")

ROOT = Path(__file__).resolve().parent.parent


def cf_messages(path: Path, tmp_path: Path) -> tuple[dict, list]:
    """(scores, every message of every priority) of ``compliance-checker --test cf:1.10 PATH``."""
    cc_runner.CheckSuite.load_all_available_checkers()
    report = tmp_path / "cf.json"
    cc_runner.ComplianceChecker.run_checker(str(path), ["cf:1.10"], 0, "normal",
                                            output_filename=str(report), output_format="json")
    r = json.loads(report.read_text())["cf:1.10"]
    msgs = [(p, c["name"], m) for p in ("high_priorities", "medium_priorities", "low_priorities")
            for c in r[p] for m in c["msgs"]]
    return r, msgs


INTERFACE_SMALL = {"scene": {"n_prisms": 12}, "sweep": {"grid": {"prestrain_at": [4, 8], "prestrain_to": [0.005, 0.02]}},
                   "run": {"t_end": 0.2}}
"""sweeps/interface.toml cut for CI: profiles along the column, a grid over their generating parameters."""


@pytest.mark.parametrize("name, overrides", [("ci_small", None), ("paper_2017", {"run": {"t_end": 0.2}}),
                                             ("interface", INTERFACE_SMALL)])
def test_cli_output_is_cf_clean(name, overrides, tmp_path, request):
    if name == "ci_small":  # the CLI's own run of sweeps/ci_small.toml, made once a session (conftest ci_small_nc)
        out = request.getfixturevalue("ci_small_nc")
    else:
        spec = load_spec(ROOT / "sweeps" / f"{name}.toml", overrides=overrides)
        out = sweep.run_sweep(spec, tmp_path / f"{name}.nc", device="cpu", progress=False)
    r, msgs = cf_messages(out, tmp_path)
    assert msgs == [], "\n".join(f"{p}: {n}: {m}" for p, n, m in msgs)  # errors (high) and warnings (medium, low)
    assert r["scored_points"] == r["possible_points"] > 100


def test_checker_sees_a_calendar_time_without_epoch(tmp_path):
    """The check can fail: a 'time' axis in seconds with no reference date is a CF error (why ours is 't')."""
    import numpy as np
    import xarray as xr

    ds = xr.Dataset({"x": (("time",), np.zeros(3), {"long_name": "x", "units": "1"})},
                    coords={"time": ("time", np.arange(3.0), {"units": "s", "long_name": "time", "axis": "T"})},
                    attrs={"Conventions": "CF-1.10"})
    ds.to_netcdf(tmp_path / "bad.nc", encoding={"time": {"_FillValue": None}})
    _, msgs = cf_messages(tmp_path / "bad.nc", tmp_path)
    assert any("time" in m for _, _, m in msgs)


def test_combine_and_resume_outputs_are_cf_clean(tmp_path):
    """The exports of `combine` and of a `resume` that recomputed a shard (every file the project writes)."""
    from warp_tensegrity.sweep.manifest import Manifest
    from warp_tensegrity.sweep.store import SweepStore

    spec = load_spec(ROOT / "sweeps" / "ci_small.toml", overrides={"run": {"t_end": 0.5}})
    out = sweep.run_sweep(spec, tmp_path / "ci.nc", device="cpu", progress=False)
    store = SweepStore(out)
    content, _ = Manifest.read(store.manifest_path)
    content["shards"].pop("1")  # as if the run had been killed before shard 1 was recorded
    Manifest(store.manifest_path, content).save()
    out.unlink()
    for path in (sweep.resume_sweep(out, device="cpu", progress=False), sweep.combine(out)):
        r, msgs = cf_messages(path, tmp_path)
        assert msgs == [], "\n".join(f"{p}: {n}: {m}" for p, n, m in msgs)


@pytest.mark.parametrize("record_strain", [True, False])
def test_to_xarray_written_by_xarray_is_cf_clean(record_strain, tmp_path):
    """Issue 30 item 17: ``simulate_batch(...).to_xarray().to_netcdf()`` (xarray's own writer, not
    the CLI's) gave the float coordinate ``t`` a ``_FillValue``, a CF error; the dataset now
    carries the CLI's coordinate encoding."""
    import numpy as np

    from warp_tensegrity import ColumnConfig, RunSettings, simulate_batch

    params = {"v0": np.array([0.002, 0.004]), "prestrain": 0.002}
    r = simulate_batch(ColumnConfig(n_prisms=6), params,
                       RunSettings(t_end=0.05, output_interval=0.005, device="cpu", record_strain=record_strain))
    path = tmp_path / "batch.nc"
    r.to_xarray().to_netcdf(path)
    r, msgs = cf_messages(path, tmp_path)
    assert msgs == [], "\n".join(f"{p}: {n}: {m}" for p, n, m in msgs)


@pytest.mark.slow
def test_init_lens_example_output_is_cf_clean(tmp_path):
    """Issue 30 item 17: the lens spec `init --example lens` writes has no description, and its
    output carried an empty global ``comment`` (a CF warning); a comment is written only where there is one."""
    from warp_tensegrity.cli import main

    spec, out = tmp_path / "lens.toml", tmp_path / "lens.nc"
    assert main(["init", "--example", "lens", "-o", str(spec)]) == 0
    assert main(["lens", str(spec), "-o", str(out), "--device", "cpu"]) == 0
    r, msgs = cf_messages(out, tmp_path)
    assert msgs == [], "\n".join(f"{p}: {n}: {m}" for p, n, m in msgs)
