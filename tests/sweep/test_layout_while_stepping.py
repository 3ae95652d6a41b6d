"""A fresh run on a GPU builds its template and lays out its store while the first shard steps
(sweep.run.layout_with_first_shard: two turns of the host between the launches). Forced here on the
CPU, where the runs step first and the layout follows: the output is the one a run that lays out
first writes, bit for bit, and a layout that fails (a full disk) fails the run with the store's own
error and no shard recorded done."""

from __future__ import annotations

import errno

import numpy as np
import pytest
import xarray as xr

from warp_tensegrity import sweep
from warp_tensegrity.sweep import run as sweep_run
from warp_tensegrity.sweep import shard as sweep_shard
from warp_tensegrity.sweep.manifest import StoreError
from warp_tensegrity.sweep.store import SweepStore

SPEC = ("[scene]\nn_prisms = 6\n\n[sweep]\ngrid = { prestrain = [0.0, 0.002], v0 = [0.003, 0.006] }\n\n"
        "[run]\nt_end = 0.05\noutput_interval = 0.01\nshard_size = 2\n")


def _run(tmp_path, name, monkeypatch, deferred: bool):
    monkeypatch.setattr(sweep_run, "layout_with_first_shard", lambda plan, serial: deferred and serial)
    order = []
    real_init, real_compute = SweepStore.initialise, sweep_run.compute_shard

    def init(self, *a, **k):
        order.append("layout")
        return real_init(self, *a, **k)

    def compute(plan, i, *a, **k):
        order.append(f"shard {i} with {len(k.get('host', ()))} host work")
        return real_compute(plan, i, *a, **k)

    monkeypatch.setattr(SweepStore, "initialise", init)
    monkeypatch.setattr(sweep_run, "compute_shard", compute)
    out = sweep.run_sweep(SPEC, tmp_path / name, device="cpu", progress=False)
    monkeypatch.undo()
    return out, order


def test_the_layout_with_the_first_shard_writes_the_same_output(tmp_path, monkeypatch):
    first, order_first = _run(tmp_path, "first.nc", monkeypatch, deferred=False)
    with_shard, order = _run(tmp_path, "with.nc", monkeypatch, deferred=True)
    assert order_first == ["layout", "shard 0 with 0 host work", "shard 1 with 0 host work"]
    assert order == ["shard 0 with 1 host work", "layout", "shard 1 with 0 host work"]
    a, b = xr.open_dataset(first), xr.open_dataset(with_shard)
    assert set(a.data_vars) == set(b.data_vars)
    for k in a.data_vars:
        if np.issubdtype(a[k].dtype, np.number):
            assert a[k].values.tobytes() == b[k].values.tobytes(), k


def test_the_store_is_checked_against_the_plans_times_before_the_template_is_built(tmp_path):
    """The deferred run checks its shards against the plan's output times, bit for bit the template's."""
    from warp_tensegrity.sweep.store import time_coord

    for text in (SPEC, SPEC.replace("output_interval = 0.01", "output_interval = 0.007")):
        plan = sweep.plan_sweep(sweep.load_spec(text), tmp_path / "t.nc", device="cpu")
        got = time_coord(sweep_shard.template_dataset(plan))
        assert got.dtype == plan.run.output_times.dtype and got.tobytes() == plan.run.output_times.tobytes()


def test_a_layout_that_fails_fails_the_run_with_nothing_done(tmp_path, monkeypatch):
    monkeypatch.setattr(sweep_run, "layout_with_first_shard", lambda plan, serial: serial)

    def full(self, plan, tpl):
        raise OSError(errno.ENOSPC, "No space left on device", str(self.zarr))

    monkeypatch.setattr(SweepStore, "_initialise", full)
    calls = []
    real = sweep_shard.compute_shard

    def compute(*a, **k):
        calls.append(1)
        return real(*a, **k)

    monkeypatch.setattr(sweep_run, "compute_shard", compute)
    with pytest.raises(StoreError, match="No space left"):
        sweep.run_sweep(SPEC, tmp_path / "full.nc", device="cpu", progress=False)
    assert calls == [1]  # the first shard stepped; the layout failed with it
    assert not (tmp_path / "full.nc").exists()
    store = SweepStore(tmp_path / "full.nc")
    assert not store.manifest_path.exists()  # no shard recorded done
