"""Calibrated estimates (warp_tensegrity.calibrate): the probe runs once per key and is cached;
the dry-run names the device; the cost model scales as stated. (No timing assertions: the
accuracy of the estimates is measured by benchmarks/end_to_end.py.)"""

import dataclasses
import json
from pathlib import Path

import pytest

from warp_tensegrity import calibrate as C
from warp_tensegrity.sweep import plan as sweep
from warp_tensegrity.sweep.progress import fmt_seconds
from warp_tensegrity.sweep.spec import load_spec

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture
def cache(tmp_path, monkeypatch):
    monkeypatch.setenv("WARP_TENSEGRITY_CACHE", str(tmp_path / "cache"))
    return tmp_path / "cache" / "calibration"


def test_probe_is_cached_and_feeds_the_dry_run(cache, tmp_path, monkeypatch):
    spec = load_spec(ROOT / "sweeps" / "ci_small.toml")
    plan = sweep.plan_sweep(spec, tmp_path / "out.nc", device="cpu")
    est = C.estimate_plan(plan)
    files = list(cache.glob("*.json"))
    assert len(files) == 1
    cal = json.loads(files[0].read_text())
    assert cal["describe"]["device"].startswith("cpu (") and cal["step_path"] == "fused"
    assert cal["probe_columns"] == 4 and cal["column_step_seconds"] > 0 and cal["import"] > 0
    assert set(est["stages_s"]) == {"import", "build", "compile", "stepping", "measurement", "transfer", "write",
                                    "finalise"}
    assert est["seconds"] == pytest.approx(sum(est["stages_s"].values()))
    assert est["device_bytes_per_shard"] > 0 and est["host_peak_bytes"] > 0

    def no_probe(*a, **k):
        raise AssertionError("the probe ran again instead of reading the cache")

    monkeypatch.setattr(C, "_fresh_process_costs", no_probe)
    assert C.estimate_plan(plan)["stages_s"] == est["stages_s"]
    text = sweep.dry_run(plan, C.estimate_plan(plan))
    assert "device:      cpu (" in text and "calibration: 4 columns x" in text
    assert f"~{fmt_seconds(est['seconds'])} wall" in text


def test_cache_key_separates_precision_method_and_path():
    import warp as wp

    spec = load_spec(ROOT / "sweeps" / "ci_small.toml")
    params = spec.column_params()
    base = spec.run_settings(device="cpu", dt=1e-3)
    dev = wp.get_device("cpu")
    keys = {C._key(spec.scene, params, s, 4, dev)[0] for s in (
        base, dataclasses.replace(base, precision="fp32"), dataclasses.replace(base, fused=False),
        dataclasses.replace(base, method="rk4", fused=False))}
    assert len(keys) == 4
    assert C._key(spec.scene, params, base, 4, dev)[0] == C._key(spec.scene, params, base, 4, dev)[0]


def _cal(is_cuda):
    return {"import": 1.0, "compile": 0.5, "batch_fixed": 0.1, "batch_per_column": 0.01, "integrator_build": 0.2,
            "is_cuda": is_cuda, "probe_columns": 4 if not is_cuda else 512, "step_seconds": 1e-3,
            "column_step_seconds": 2.5e-4 if not is_cuda else 1e-3 / 512, "measure_seconds": 0.04,
            "measure_samples": 1001, "transfer_per_byte": 1e-9, "io_write_fixed": 0.05, "io_write_per_byte": 1e-9,
            "io_read_fixed": 0.01, "io_read_per_byte": 1e-9, "device_bytes_fixed": 1000,
            "device_bytes_per_column": 5000, "strain_bytes_per_sample": 400, "base_rss": 3e8, "device_label": "x",
            "load_avg": 0.0}


def test_cost_model_scaling():
    """CPU: stepping and measurement proportional to columns; GPU: flat up to the probed width
    (latency), proportional beyond; fixed costs once per run, per-shard costs per shard."""
    cpu = C.predict(_cal(False), 8, [4, 4], 1000, 1001, 50, False, load=0.0)["stages_s"]
    assert cpu["stepping"] == pytest.approx(1000 * 2.5e-4 * 8)
    assert cpu["measurement"] == pytest.approx(0.04 * 2)
    assert cpu["import"] == 1.0 and cpu["compile"] == 0.5
    assert cpu["build"] == pytest.approx(0.1 + 0.01 * 8 + 2 * (0.1 + 0.01 * 4 + 0.2))
    gpu = C.predict(_cal(True), 1536, [512, 512, 512], 1000, 1001, 50, False, load=0.0)
    assert gpu["stages_s"]["stepping"] == pytest.approx(3 * 1000 * 1e-3)
    big = C.predict(_cal(True), 1024, [1024], 1000, 1001, 50, False, load=0.0)
    assert big["stages_s"]["stepping"] == pytest.approx(2 * 1000 * 1e-3)
    with_strain = C.predict(_cal(True), 1024, [1024], 1000, 1001, 50, True, load=0.0)
    # a host twice as loaded (per core) as at probe time: host stages double, GPU stepping does not
    cores = __import__("os").cpu_count()
    busy = C.predict(_cal(True), 1024, [1024], 1000, 1001, 50, False, load=2.0 * cores)["stages_s"]
    assert busy["stepping"] == big["stages_s"]["stepping"] and busy["write"] == pytest.approx(2 * big["stages_s"]["write"])
    cpu_busy = C.predict(_cal(False), 8, [4, 4], 1000, 1001, 50, False, load=2.0 * cores)["stages_s"]
    assert cpu_busy["stepping"] == pytest.approx(2 * cpu["stepping"])
    assert with_strain["output_bytes"] - big["output_bytes"] == 8 * 1024 * 1001 * 50
