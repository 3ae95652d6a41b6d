"""Dask scale-out: shards as tasks on a LocalCluster of CPU worker processes give exactly the
dataset of a single-process run."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
import xarray as xr

from warp_tensegrity import sweep
from warp_tensegrity.io import drop_run_dependent, open_sweep

pytestmark = pytest.mark.slow  # Dask LocalClusters of worker processes, each importing Warp

distributed = pytest.importorskip("distributed")

REPO = Path(__file__).resolve().parents[2]

SPEC = """
[scene]
n_prisms = 5

[sweep]
grid = { prestrain = [0.0, 0.002], v0 = [0.003, 0.006], base_rigidity = [0.0, 1.0] }

[run]
t_end = 0.1
output_interval = 0.005
device = "cpu"
shard_size = 2
record_strain = true
"""


@pytest.fixture(scope="module")
def client():
    # worker processes must import this checkout of warp_tensegrity
    old = os.environ.get("PYTHONPATH")
    os.environ["PYTHONPATH"] = str(REPO) + (os.pathsep + old if old else "")
    try:
        cluster = distributed.LocalCluster(
            n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0"
        )
        c = distributed.Client(cluster)
        yield c
        c.close()
        cluster.close()
    finally:
        if old is None:
            os.environ.pop("PYTHONPATH", None)
        else:
            os.environ["PYTHONPATH"] = old


def test_dask_run_equals_single_process(tmp_path, client):
    spec = tmp_path / "spec.toml"
    spec.write_text(SPEC)
    single = sweep.run_sweep(spec, tmp_path / "single.nc", progress=False)
    dask_out = sweep.run_sweep(spec, tmp_path / "dask.nc", progress=False, client=client)
    st = sweep.sweep_status(dask_out)
    assert st["shards"] == st["shards_done"] == 4
    a, b = open_sweep(single), open_sweep(dask_out)
    xr.testing.assert_identical(drop_run_dependent(b), drop_run_dependent(a))
    # both workers took part
    workers = client.scheduler_info()["workers"]
    assert len(workers) == 2


def test_dask_resume_runs_only_missing_shards(tmp_path, client):
    """A shard whose manifest record is gone (as after a kill) is recomputed on the workers; the
    others keep their chunk files untouched; the result is identical."""
    import json

    spec = tmp_path / "spec.toml"
    spec.write_text(SPEC)
    out = sweep.run_sweep(spec, tmp_path / "r.nc", progress=False)
    d = tmp_path / "r.nc.sweep"
    chunks = lambda: {p.parts[-3]: p.stat().st_mtime_ns for p in (d / "store.zarr" / "strain" / "c").glob("*/*/*")}  # noqa: E731
    keep = chunks()
    m = json.loads((d / "manifest.json").read_text())
    m.pop("sha256")
    del m["shards"]["2"]
    store = sweep.SweepStore(out)
    from warp_tensegrity.sweep.manifest import Manifest

    Manifest(store.manifest_path, m).save()
    ref = open_sweep(out)
    out.unlink()
    sweep.resume_sweep(out, progress=False, scheduler=client.scheduler.address)
    after = chunks()
    assert after.keys() == keep.keys() == {"0", "1", "2", "3"}
    assert all(after[k] == keep[k] for k in keep if k != "2") and after["2"] != keep["2"]
    xr.testing.assert_identical(drop_run_dependent(open_sweep(out)), drop_run_dependent(ref))


def test_cli_dask_flag_local_cluster(tmp_path, monkeypatch):
    """`run --dask 2` starts its own LocalCluster; device auto resolves per worker (CPU here)."""
    from warp_tensegrity import cli

    monkeypatch.setenv("PYTHONPATH", str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    spec = tmp_path / "spec.toml"
    spec.write_text(SPEC.replace('device = "cpu"\n', "").replace("shard_size = 2", "shard_size = 3"))
    ref = sweep.run_sweep(spec, tmp_path / "ref.nc", progress=False, device="cpu")
    assert cli.main(["run", str(spec), "-o", str(tmp_path / "d.nc"), "--dask", "2", "--no-progress"]) == 0
    a = drop_run_dependent(open_sweep(tmp_path / "d.nc"))
    b = drop_run_dependent(open_sweep(ref))
    if a.attrs["device"] != "cpu":  # a GPU machine: workers picked cuda:N; only the layout is comparable
        assert a.sizes == b.sizes
    else:
        xr.testing.assert_identical(a, b)
