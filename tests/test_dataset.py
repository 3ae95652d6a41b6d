"""Sweep datasets: CF attributes, provenance, the CF encoding of explicit case lists, netCDF
round trips and atomic writes."""

from __future__ import annotations

import hashlib
from pathlib import Path

import netCDF4
import numpy as np
import pytest
import xarray as xr

from warp_tensegrity import io as D
from warp_tensegrity import sweep
from warp_tensegrity import BatchResult
from warp_tensegrity.types import STATUS_MEANINGS
from warp_tensegrity.sweep import parse_spec
from warp_tensegrity.sweep import store as zstore

CASES = """
title = "dataset test"
[scene]
n_prisms = 5

[sweep]
cases = [
  { label = "FB soft", prestrain = 0.0,   v0 = 0.004, base_rigidity = 0.0 },
  { label = "RB",      prestrain = 0.002, v0 = 0.008, base_rigidity = 1.0 },
  { label = "mid",     prestrain = 0.001, v0 = 0.006, base_rigidity = 0.5 },
]
fixed = { cable_EA = 0.3 }

[run]
t_end = 0.1
output_interval = 0.01
device = "cpu"
shard_size = 2
record_strain = true
"""

GRID = """
[scene]
n_prisms = 5
[sweep]
grid = { v0 = [0.004, 0.008], base_rigidity = [0.0, 0.5, 1.0] }
[run]
t_end = 0.1
output_interval = 0.01
device = "cpu"
shard_size = 4
record_strain = false
"""


@pytest.fixture(scope="module")
def case_run(tmp_path_factory):
    d = tmp_path_factory.mktemp("cases")
    (d / "cases.toml").write_text(CASES)
    out = sweep.run_sweep(d / "cases.toml", d / "cases.nc", progress=False)
    return d, out


@pytest.fixture(scope="module")
def grid_run(tmp_path_factory):
    d = tmp_path_factory.mktemp("grid")
    (d / "grid.toml").write_text(GRID)
    return sweep.run_sweep(d / "grid.toml", d / "grid.nc", progress=False)


def test_every_variable_has_cf_attributes(case_run):
    _, out = case_run
    ds = D.open_sweep(out)
    for name, v in ds.variables.items():
        assert "long_name" in v.attrs, name
        if v.dtype.kind in "fiu" and not {"flag_values", "flag_masks"} & set(v.attrs):  # CF flags: no units
            assert "units" in v.attrs, name
    assert ds["v0"].attrs["units"] == "m s-1" and ds["t"].attrs["units"] == "s"
    assert ds["speed"].attrs["units"] == "m s-1" and ds["arrival_time"].attrs["units"] == "s"
    st = ds["status"]
    assert list(st.attrs["flag_values"]) == sorted(STATUS_MEANINGS)
    assert len(st.attrs["flag_meanings"].split()) == len(STATUS_MEANINGS)
    assert st.attrs["flag_meanings"].split()[0] == "ok"


def test_global_provenance(case_run):
    d, out = case_run
    ds = D.open_sweep(out)
    a = ds.attrs
    text = (d / "cases.toml").read_text()
    assert a["Conventions"] == "CF-1.10"
    assert a["spec"] == text and a["spec_sha256"] == hashlib.sha256(text.encode()).hexdigest()
    import warp

    assert a["warp_version"] == warp.config.version
    from warp_tensegrity import provenance

    assert a["package_version"] == provenance.package_version()
    assert a["code_version"] == f"{provenance.release_version()}+src.{provenance.source_hash()[:16]}"
    assert provenance.release_version() in a["package_version"]
    assert a["git_commit"] == provenance.git_commit() and a["git_dirty"] in (0, 1)
    assert a["device"] == "cpu" and a["device_name"] and a["cuda_driver"] == "none" or a["cuda_driver"][0].isdigit()
    assert a["command_line"] == provenance.command_line()  # the combining process (pytest here)
    assert a["precision"] == "auto" and a["method"] == "rattle"  # as asked; on the CPU 'auto' runs fp64:
    assert set(ds.precision_used.values.ravel()) == {64}
    assert 0 < a["dt"] <= a["dt_limit"] and a["n_steps"] >= 1
    assert a["scene_n_prisms"] == 5 and a["swept_parameters"] == "prestrain v0 base_rigidity"
    assert a["title"] == "dataset test" and a["wall_time"] > 0


def test_case_list_is_cf_encoded_not_multiindex(case_run):
    _, out = case_run
    with netCDF4.Dataset(out) as nc:
        assert nc.variables["v0"].dimensions == ("case",)
        assert nc.variables["cable_EA"].dimensions == ()  # fixed: scalar coordinate
        coords = nc.variables["amplitude"].coordinates.split()
        assert {"prestrain", "v0", "base_rigidity", "case_label", "cable_EA", "unit_mass"} <= set(coords)
        assert list(nc.variables["case_label"][:]) == ["FB soft", "RB", "mid"]
        assert "_FillValue" not in nc.variables["v0"].ncattrs()
    ds = D.open_sweep(out)
    assert not any(isinstance(ix, __import__("pandas").MultiIndex) for ix in ds.indexes.values())
    assert ds["v0"].dims == ("case",) and list(ds["v0"].values) == [0.004, 0.008, 0.006]
    assert float(ds["cable_EA"]) == 0.3
    # per-case selection by the auxiliary coordinates works
    rb = ds.where(ds.base_rigidity == 1.0, drop=True)
    assert rb.sizes["case"] == 1 and rb.prestrain.values.tolist() == [0.002]


def test_grid_layout_and_selection(grid_run):
    ds = D.open_sweep(grid_run)
    assert ds["amplitude"].dims == ("v0", "base_rigidity")
    assert "strain" not in ds  # record_strain = false: not stored
    assert ds["kinetic_energy"].dims == ("v0", "base_rigidity", "t")
    assert float(ds["prestrain"]) == 0.0 and ds["prestrain"].dims == ()
    assert ds.sel(v0=0.008, base_rigidity=0.5)["status"] == 0
    assert ds.attrs["sweep_kind"] == "grid"


def test_netcdf_round_trip_identical(case_run, tmp_path):
    _, out = case_run
    ds = D.open_sweep(out)
    again = D.write_netcdf(ds, tmp_path / "again.nc")
    back = D.open_sweep(again)
    xr.testing.assert_identical(back, ds)
    assert back.attrs == ds.attrs
    for k in ds.variables:
        assert back[k].attrs.keys() == ds[k].attrs.keys(), k
    assert back["t"].dtype == np.float64  # seconds stay floats (no timedelta decoding)


def test_shards_tile_the_sweep(case_run):
    """Each shard's region of the store (chunk along case) is the matching slice of the export."""
    _, out = case_run
    lazy = sweep.open_sweep(out)
    raw = xr.open_zarr(zstore.SweepStore(out).zarr, consolidated=False, decode_timedelta=False)
    assert raw["strain"].chunks[0] == (2, 1)  # the store: one chunk per shard
    c = lazy["strain"].chunks[0]  # the lazy view: blocks of whole shards (sweep/store.py, block_columns)
    assert sum(c) == 3 and all(w % 2 == 0 for w in c[:-1]), c
    xr.testing.assert_identical(lazy.load(), D.open_sweep(out))


def _fake_result(B, T=11, P=5, dt=0.01) -> BatchResult:
    rng = np.random.default_rng(0)
    return BatchResult(
        params={}, time=np.arange(T) * dt, strain=-rng.random((B, T, P)) * 1e-3,
        kinetic_energy=rng.random((B, T)), elastic_energy=rng.random((B, T)),
        energy_error=rng.random(B), bar_length_error=rng.random(B) * 1e-14,
        status=np.zeros(B, dtype=np.int32), fail_step=-np.ones(B, dtype=np.int64),
        dt=dt, n_steps=T - 1, method="rattle", precision="fp64", device="cpu", device_name="CPU", wall_time=0.1,
    )


def test_write_is_atomic(tmp_path, monkeypatch):
    spec = parse_spec(CASES)
    res = _fake_result(2)
    meas = {k: np.ones(2) for k in ("amplitude", "speed", "width", "width_10", "prisms_measured")} | {"arrival_time": np.ones((2, 5))}
    ds = D.shard_dataset(spec.layout(), spec.column_params(), 0, 2, res, meas, {"case_start": 0, "case_stop": 2})
    path = tmp_path / "s.nc"
    D.write_netcdf(ds, path)
    before = path.read_bytes()

    def boom(self, *a, **k):
        Path(a[0]).write_bytes(b"partial")
        raise OSError("disk full")

    monkeypatch.setattr(xr.Dataset, "to_netcdf", boom)
    with pytest.raises(OSError, match="disk full"):
        D.write_netcdf(ds, path)
    assert path.read_bytes() == before  # the old file is untouched
    assert [p.name for p in tmp_path.iterdir()] == ["s.nc"]  # no temporary left behind


def test_drop_run_dependent():
    ds = xr.Dataset(attrs={"wall_time": 1.0, "history": "x", "dt": 0.1})
    assert D.drop_run_dependent(ds).attrs == {"dt": 0.1}


def test_to_xarray_is_the_cli_layout(case_run):
    """BatchResult.to_xarray() and a case-list sweep file: same variables, dims, attributes of
    every variable and the same numbers (the same builder)."""
    from warp_tensegrity import simulate_batch

    d, out = case_run
    spec = parse_spec(CASES)
    params = spec.column_params()
    from warp_tensegrity.sweep import plan_sweep
    from warp_tensegrity.sweep.shard import run_groups

    plan = plan_sweep(spec, device="cpu")
    assert len(plan.groups) == 2  # the rigid-base case apart: each group at its own dt, merged back in order
    res = run_groups(plan, 0, plan.n_columns)
    mine = res.to_xarray()
    one = simulate_batch(spec.scene, params, spec.run_settings(device="cpu", dt=float(D.open_sweep(out).attrs["dt"])))
    assert set(one.to_xarray().data_vars) == set(mine.data_vars)  # one plan: the same layout
    cli = D.open_sweep(out)
    from warp_tensegrity.types import ERROR_ESTIMATED

    errors = {f"{k}_error" for k in ERROR_ESTIMATED} | {"error_flag"}  # a sweep's twin gives them; a batch has none
    assert set(mine.data_vars) == set(cli.data_vars) - errors and errors <= set(cli.data_vars)
    for k in mine.variables:
        if k == "case_label":
            continue
        assert mine[k].dims == cli[k].dims, k
        stored = ("ancillary_variables", "comment") if cli[k].dtype == np.float32 else ("ancillary_variables",)
        assert {a: str(v) for a, v in mine[k].attrs.items()} == {a: str(v) for a, v in cli[k].attrs.items()
                                                                 if a not in stored}, k
    for k in ("strain", "amplitude", "speed", "status"):
        np.testing.assert_allclose(mine[k].values, cli[k].values, rtol=1e-12, atol=0, equal_nan=True)
    # a sweep stores it as float32 (run.energy_precision 'auto'), to_xarray keeps the result's float64
    assert mine["kinetic_energy"].dtype == np.float64 and cli["kinetic_energy"].dtype == np.float32
    np.testing.assert_allclose(mine["kinetic_energy"].values, cli["kinetic_energy"].values, rtol=2**-23, atol=0,
                               equal_nan=True)
    np.testing.assert_array_equal(mine["time_step"].values, cli["time_step"].values)
    assert len(set(cli["time_step"].values.tolist())) == 2 and set(cli["run_group"].values.tolist()) == {0, 1}
    for k in ("git_commit", "warp_version", "device", "method", "dt", "n_steps"):
        assert mine.attrs[k] == cli.attrs[k], k


def test_parameter_coordinates_take_their_units_from_the_options():
    """The per-column parameters' coordinate attributes come from their one declaration
    (options.ColumnParameters: unit and long_name), not from a second table in io (issue 26)."""
    from warp_tensegrity.options import COLUMN_PARAMETERS, ColumnParameters, opt_of

    for p, unit in COLUMN_PARAMETERS.items():
        o = opt_of(ColumnParameters, p)
        assert o.long_name, p
        assert D.COORD_ATTRS[p] == {"units": unit, "long_name": o.long_name}, p


@pytest.mark.parametrize("measure", ["device", "host"])
def test_to_xarray_without_the_strain_record(measure):
    """Issue 30 item 17: with record_strain = false the record stays on the device, and to_xarray()
    raised "conflicting sizes for dimension 'prism'" (a prism axis of length 0 against arrival_time's).
    Now the prism axis has the column's prisms and the measures are those of the run that keeps the record."""
    from warp_tensegrity import ColumnConfig, RunSettings, simulate_batch

    cfg = ColumnConfig(n_prisms=6)
    params = {"v0": np.array([0.002, 0.004]), "prestrain": 0.002, "base_rigidity": 1.0}
    run = dict(t_end=0.1, output_interval=0.005, device="cpu", measure=measure)
    bare = simulate_batch(cfg, params, RunSettings(record_strain=False, **run)).to_xarray()
    full = simulate_batch(cfg, params, RunSettings(record_strain=True, **run)).to_xarray()
    assert "strain" not in bare and "strain" in full
    assert bare.sizes["prism"] == 6 and bare["arrival_time"].dims == ("case", "prism")
    for k in ("amplitude", "speed", "arrival_time", "measurement_flag", "max_compression"):
        np.testing.assert_array_equal(bare[k].values, full[k].values, err_msg=k)
    nothing_per_prism = _fake_result(2)
    nothing_per_prism.strain = None
    assert "prism" not in nothing_per_prism.to_xarray(measure=False).dims  # no config: the count is unknown
