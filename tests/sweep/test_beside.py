"""The process beside the run (sweep.beside): a GPU sweep's base-mode analysis runs there while the
shard steps. Its ratios are those computed in the run's own process, bit for bit; where no process
can be started, or the worker dies, the caller computes them itself."""

from __future__ import annotations

import os

import numpy as np
import pytest

from warp_tensegrity import ColumnConfig
from warp_tensegrity.scene.base_modes import base_mode_ratios_one_thread
from warp_tensegrity.sweep import beside

CONFIG = ColumnConfig(n_prisms=6)
PARAMS = {"prestrain": np.array([0.0, 0.002, 0.002, 0.004, 0.0]), "base_rigidity": np.array([0.0, 0.5, 0.5, 0.9, 1.0])}


@pytest.fixture(autouse=True)
def fresh(monkeypatch):
    """Each test starts with no worker and nothing refused, and leaves none behind."""
    monkeypatch.setattr(beside, "_pool", None)
    monkeypatch.setattr(beside, "_refused", None)
    yield
    if beside._pool is not None:
        beside._pool.shutdown()


def test_the_worker_is_another_process_and_gives_the_same_bits():
    assert beside.result(beside.submit(os.getpid), lambda: None) != os.getpid()
    fut = beside.submit(base_mode_ratios_one_thread, CONFIG, PARAMS, 5)
    got = beside.result(fut, lambda: pytest.fail("the worker did not answer"))
    here = base_mode_ratios_one_thread(CONFIG, PARAMS, 5)
    assert got.tobytes() == here.tobytes()
    assert np.isnan(got[4]) and np.all(np.isfinite(got[:4]))  # rigid bases have no base modes


def test_a_daemonic_process_computes_it_itself(monkeypatch):
    class Daemon:
        daemon = True

    monkeypatch.setattr(beside.mp, "current_process", lambda: Daemon())
    assert beside.submit(os.getpid) is None
    assert beside._pool is None and "daemonic" in beside._refused


def test_a_dead_worker_falls_back_to_this_process():
    fut = beside.submit(os._exit, 3)  # the worker dies without an answer
    assert beside.result(fut, lambda: "here") == "here"
    assert "died" in beside._refused and beside.submit(os.getpid) is None


def test_an_error_in_the_work_is_raised_here():
    fut = beside.submit(int, "not a number")
    with pytest.raises(ValueError, match="not a number"):
        beside.result(fut, lambda: pytest.fail("not a dead worker: no fallback"))


def test_a_sweep_with_the_analysis_beside_records_the_same_ratios(tmp_path, monkeypatch):
    """A shard whose analysis runs beside (as on a GPU) records the one-thread ratios of its columns
    (the CPU device's own path computes them in-process after the stepping)."""
    from warp_tensegrity.sweep import load_spec, plan_sweep, shard

    spec = load_spec("[scene]\nn_prisms = 6\n\n[sweep]\ngrid = { prestrain = [0.0, 0.002], base_rigidity = [0.0, 0.5, 1.0] }\n\n"
                     "[run]\nt_end = 0.05\noutput_interval = 0.01\n")
    plan = plan_sweep(spec, tmp_path / "out.nc", device="cpu")
    calls = []
    real = beside.submit

    def counted(fn, *args):
        calls.append(fn)
        return real(fn, *args)

    monkeypatch.setattr(shard, "modes_beside", lambda plan: True)
    monkeypatch.setattr(beside, "submit", counted)
    ds = shard.compute_shard(plan, 0, device="cpu")
    assert calls == [base_mode_ratios_one_thread]
    want = base_mode_ratios_one_thread(spec.scene, plan.params, plan.n_columns)
    assert ds["base_mode_ratio"].dims == ("case",)  # the shard's columns in plan order
    assert ds["base_mode_ratio"].values.tobytes() == want.tobytes()
