"""The run decided once and the one cost model (warp_tensegrity.policy): a sweep calls decide()
once and nothing recomputes its bound, band or path; --time-limit and --dry-run quote the same
estimate; the probe is cached, renewed by --recalibrate, and one taken under load is not kept as if
it were not; the exported estimate_batch takes every parameter form simulate_batch takes; the cost
model scales as stated. (No timing assertions: the accuracy of the estimates is measured by
benchmarks/end_to_end.py.)"""

import dataclasses
import json
import re
import sys
from pathlib import Path

import numpy as np
import pytest

from warp_tensegrity import ColumnConfig, RunSettings, estimate_batch, simulate_batch
from warp_tensegrity.cli import main
from warp_tensegrity.policy import calibrate as C
from warp_tensegrity.policy import decide as D
from warp_tensegrity.policy.cost import fmt_seconds, predict
from warp_tensegrity.sweep import plan as sweep
from warp_tensegrity.sweep.spec import load_spec

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture
def cache(tmp_path, monkeypatch):
    monkeypatch.setenv("WARP_TENSEGRITY_CACHE", str(tmp_path / "cache"))
    return tmp_path / "cache" / "calibration"


def test_probe_is_cached_and_feeds_the_dry_run(cache, tmp_path, monkeypatch):
    spec = load_spec(ROOT / "sweeps" / "ci_small.toml")
    plan = sweep.plan_sweep(spec, tmp_path / "out.nc", device="cpu")
    est = C.estimate_plan(plan)
    files = list(cache.glob("*.json"))
    assert len(plan.groups) == 2 and len(files) == 2  # a probe per group: ci_small's rigid bases run apart
    cal = est["probe"]
    assert cal["describe"]["device"].startswith("cpu (") and cal["step_path"] == "fused"
    # the store's fixed costs measured, not assumed (calibrate._store_costs)
    assert all(cal[k] > 0 for k in ("store_setup", "store_write_fixed", "export_fixed", "export_dask_fixed",
                                    "summary_fixed", "store_first_use", "export_first_use"))
    assert cal["probe_columns"] == 4 and cal["column_step_seconds"] > 0 and cal["import"] > 0
    assert set(est["stages_s"]) == {"import", "build", "compile", "stepping", "measurement", "transfer", "write",
                                    "finalise"}
    assert est["seconds"] == pytest.approx(sum(est["stages_s"].values()))
    assert est["device_bytes_per_shard"] > 0 and est["host_peak_bytes"] > 0

    def no_probe(*a, **k):
        raise AssertionError("the probe ran again instead of reading the cache")

    # every group's probe is read from the cache. One taken under load (xdist's other worker) is taken
    # again on an idle host (test below): here the host counts as busy, so none is renewed
    monkeypatch.setattr(C, "host_idle", lambda: False)
    monkeypatch.setattr(C, "_measure", no_probe)
    assert C.estimate_plan(plan)["stages_s"] == est["stages_s"]
    text = sweep.dry_run(plan, est)
    assert "device:      cpu (" in text and "calibration: 4 columns x" in text
    assert f"~{fmt_seconds(est['seconds'])} wall" in text


def test_cache_key_separates_precision_method_and_path():
    spec = load_spec(ROOT / "sweeps" / "ci_small.toml")
    params = D.column_params(spec.scene, spec.column_params())
    base = spec.run_settings(device="cpu", dt=1e-3)
    runs = [D.decide(spec.scene, params, s) for s in (
        base, dataclasses.replace(base, precision="fp32"), dataclasses.replace(base, fused=False),
        dataclasses.replace(base, method="rk4", fused=False))]
    keys = {C._key(spec.scene, params, r, 4)[0] for r in runs}
    assert len(keys) == 4
    assert C._key(spec.scene, params, runs[0], 4)[0] == C._key(spec.scene, params, runs[0], 4)[0]


def _cal(is_cuda):
    return {"import": 1.0, "compile": 0.5, "batch_fixed": 0.1, "batch_per_column": 0.01, "batch_per_state": 0.05, "batch_first": 0.5,
            "integrator_build": 0.2,
            "is_cuda": is_cuda, "probe_columns": 4 if not is_cuda else 512, "step_seconds": 1e-3,
            "column_step_seconds": 2.5e-4 if not is_cuda else 1e-3 / 512, "measure_seconds": 0.04,
            "measure_samples": 1001, "transfer_per_byte": 1e-9, "io_write_fixed": 0.05, "io_write_per_byte": 1e-9,
            "io_read_fixed": 0.01, "io_read_per_byte": 1e-9, "store_setup": 0.3, "store_write_fixed": 0.1,
            "export_fixed": 0.2, "export_dask_fixed": 0.25, "summary_fixed": 0.05, "store_first_use": 0.5,
            "export_first_use": 0.01, "export_dask_first_use": 0.3, "device_bytes_fixed": 1000,
            "device_bytes_per_column": 5000, "strain_bytes_per_sample": 400, "base_rss": 3e8, "device_label": "x"}


def _run(on_gpu, record_strain=False):
    """A run plan of 50-prism columns, 1000 steps, 1001 outputs."""
    return D.RunPlan(settings=RunSettings(record_strain=record_strain), dt=1e-3, dt_limit=1e-2, n_steps=1000,
                     output_every=1, omega_max_bound=100.0, bandwidth=3, n_nodes=153, n_constraints=150, n_cables=303,
                     path=D.Path.FUSED, lane_refusal=None, device="cuda:0" if on_gpu else "cpu", on_gpu=on_gpu,
                     n_columns=512, prisms=50, prisms_simulated=50)


def test_cost_model_scaling():
    """CPU: stepping and measurement proportional to columns; GPU: flat up to the probed width
    (latency), proportional beyond; fixed costs once per run, per-shard costs per shard; the same
    figures whatever the host's load now (no rescaling by the load average)."""
    cpu = predict(_cal(False), _run(False), [4, 4], False, shard_states=[1, 2], planned=(8, 3))["stages_s"]
    assert cpu["stepping"] == pytest.approx(1000 * 2.5e-4 * 8)
    assert cpu["measurement"] == pytest.approx(0.04 * 2)
    assert cpu["import"] == 1.0 and cpu["compile"] == 0.5
    # a + b x columns + c x distinct reference states, for the plan and for each shard
    assert cpu["build"] == pytest.approx(0.5 + 0.1 + 0.01 * 8 + 0.05 * 3 + 2 * (0.1 + 0.01 * 4 + 0.2) + 0.05 * (1 + 2))
    gpu = predict(_cal(True), _run(True), [512, 512, 512], False)
    assert gpu["stages_s"]["stepping"] == pytest.approx(3 * 1000 * 1e-3)
    big = predict(_cal(True), _run(True), [1024], False)
    assert big["stages_s"]["stepping"] == pytest.approx(2 * 1000 * 1e-3)
    with_strain = predict(_cal(True), _run(True), [1024], True)
    assert with_strain["output_bytes"] - big["output_bytes"] == 8 * 1024 * 1001 * 50
    assert with_strain["host_bytes_per_column"] > big["host_bytes_per_column"]
    # the store's fixed costs as the probe measured them: its layout and first imports once, a write per
    # shard; the export whole for one shard, through dask (and its first import) for more
    one = predict(_cal(False), _run(False), [4], False)["stages_s"]
    shard_bytes = one_shard_bytes(4)
    assert cpu["write"] - one["write"] == pytest.approx(0.1 + 3.0 * 1e-9 * shard_bytes, rel=1e-6)
    assert one["write"] == pytest.approx(0.5 + 0.3 + 0.1 + 3.0 * 1e-9 * shard_bytes, rel=1e-6)
    assert one["finalise"] == pytest.approx(0.01 + 0.05 + 0.2 + 6.0 * 1e-9 * shard_bytes, rel=1e-6)
    resumed = predict(_cal(False), _run(False), [4], False, n_shards=2)["stages_s"]  # the last of two shards
    assert resumed["finalise"] - one["finalise"] == pytest.approx(0.25 + 0.3 - 0.2)


def one_shard_bytes(b):
    """Output bytes of a shard of ``b`` columns of :func:`_run` (no strain), as the cost model counts them."""
    from warp_tensegrity.policy.cost import output_bytes_per_column

    return b * output_bytes_per_column(1001, 50, False, True, "fp64")


TINY = """[scene]
n_prisms = 4
[sweep]
grid = { v0 = [0.002, 0.004], base_rigidity = [0.0, 0.5, 1.0] }
[run]
t_end = 0.05
output_interval = 0.01
precision = "fp64"
shard_size = 2
groups = false
"""
"""A tiny sweep with one plan for all its columns: the probe, cache and estimate tests (one probe
each); TINY_GROUPED runs its rigid-base columns as a group of their own."""
TINY_GROUPED = TINY.replace("groups = false\n", "")


def _wrap_everywhere(monkeypatch, name, log, inside=None):
    """Count calls of the package function ``name`` wherever a module holds it (by name)."""
    mods = [m for k, m in list(sys.modules.items()) if k.startswith("warp_tensegrity") and hasattr(m, name)]
    orig = getattr(mods[0], name)
    mods = [m for m in mods if getattr(m, name) is orig]

    def counted(*a, **k):
        log.append((name, bool(inside and inside[0])))
        return orig(*a, **k)

    for m in mods:
        monkeypatch.setattr(m, name, counted)


@pytest.mark.parametrize("text, n_groups", [(TINY, 1), (TINY_GROUPED, 2)], ids=["one plan", "two groups"])
def test_a_sweep_decides_once(tmp_path, cache, monkeypatch, text, n_groups):
    """A 3-shard CLI sweep: one decide() per group (its rigid-base columns a group of their own unless
    run.groups = false) and per group's twin, all in one decide_groups(); the omega bound, the Gram band and the path are
    computed inside them only (the estimate, the probe, the store template and every shard read the
    plans)."""
    import warp_tensegrity.engine  # noqa: F401 (every module that could hold the functions is loaded)
    import warp_tensegrity.policy.calibrate  # noqa: F401
    import warp_tensegrity.sweep.run  # noqa: F401
    from warp_tensegrity.policy import groups as G

    spec = tmp_path / "tiny.toml"
    spec.write_text(text)
    log, inside = [], [0]
    for name in ("omega_max_bound", "gram_bandwidth", "choose_path"):
        _wrap_everywhere(monkeypatch, name, log, inside)

    def scope(name, real):
        def wrapped(*a, **k):
            log.append((name, True))
            inside[0] += 1
            try:
                return real(*a, **k)
            finally:
                inside[0] -= 1
        return wrapped

    for name, real in (("decide", D.decide), ("decide_groups", G.decide_groups)):
        for m in [m for k, m in list(sys.modules.items())
                  if k.startswith("warp_tensegrity") and getattr(m, name, None) is real]:
            monkeypatch.setattr(m, name, scope(name, real))
    assert main(["run", str(spec), "-o", str(tmp_path / "o.nc"), "--device", "cpu", "--no-progress"]) == 0
    names = [n for n, _ in log]
    n = 2 * n_groups  # each group's plan and its error estimate's twin
    assert names.count("decide_groups") == 1 and names.count("decide") == n, names
    assert names.count("gram_bandwidth") == n and names.count("choose_path") == n, names
    assert names.count("omega_max_bound") >= 1 and all(ins for _, ins in log), log
    import xarray as xr

    from warp_tensegrity.sweep.store import SweepStore

    assert json.loads(SweepStore(tmp_path / "o.nc").manifest_path.read_text())["n_shards"] == 3
    with xr.open_dataset(tmp_path / "o.nc") as ds:
        assert int((ds.status == 0).sum()) == 6
        assert len(set(ds.time_step.values.ravel().tolist())) == n_groups


def _estimate_line(text):
    return re.search(r"time:        ~(\S+) wall", text).group(1)


def test_time_limit_and_dry_run_quote_the_same_estimate(tmp_path, cache, capsys, monkeypatch):
    monkeypatch.setattr(C, "others_busy", lambda start: 0.0)  # no re-probe between the calls (see the test below)
    spec = tmp_path / "tiny.toml"
    spec.write_text(TINY)
    out = str(tmp_path / "o.nc")
    assert main(["run", str(spec), "-o", out, "--device", "cpu", "--dry-run"]) == 0
    quoted = _estimate_line(capsys.readouterr().out)
    assert main(["run", str(spec), "-o", out, "--device", "cpu", "--time-limit", "0.001"]) == 1
    err = capsys.readouterr().err
    assert f"the estimate is {quoted} " in err, (quoted, err)
    assert not Path(out).exists()


def test_recalibrate_renews_the_probe_and_a_loaded_probe_is_marked(tmp_path, cache, capsys, monkeypatch):
    spec = tmp_path / "tiny.toml"
    spec.write_text(TINY)
    args = ["run", str(spec), "-o", str(tmp_path / "o.nc"), "--device", "cpu", "--dry-run"]
    monkeypatch.setattr(C, "others_busy", lambda start: 0.9)  # the host busy while the probe runs
    real, taken = C._measure, []
    monkeypatch.setattr(C, "_measure", lambda *a, **k: taken.append(1) or real(*a, **k))
    assert main(args) == 0
    text = capsys.readouterr().out
    assert "taken while other work kept 90 % of the cores busy" in text
    files = list(cache.glob("*.json"))
    assert len(files) == 1 and json.loads(files[0].read_text())["under_load"] is True
    monkeypatch.setattr(C, "host_idle", lambda: False)  # still busy: the marked probe is used, and said so
    assert main(args) == 0 and len(taken) == 1
    assert "taken while other work kept" in capsys.readouterr().out
    monkeypatch.setattr(C, "others_busy", lambda start: 0.0)
    monkeypatch.setattr(C, "host_idle", lambda: True)  # idle now: the marked probe is taken again
    assert main(args) == 0 and len(taken) == 2
    assert "taken while other work" not in capsys.readouterr().out
    assert json.loads(files[0].read_text())["under_load"] is False
    assert main(args) == 0 and len(taken) == 2  # an idle probe is kept ...
    assert main(args + ["--recalibrate"]) == 0 and len(taken) == 3  # ... until --recalibrate


@pytest.mark.parametrize("form", ["scalar", "list", "array", "0-d", "int"])
def test_exported_estimate_batch_takes_every_parameter_form(form, cache):
    """``"base_rigidity": 1.0`` crashed the exported estimate_batch while simulate_batch took it."""
    cfg = ColumnConfig(n_prisms=3)
    s = RunSettings(t_end=0.01, device="cpu", truncate=False)
    value = {"scalar": 1.0, "list": [1.0, 1.0], "array": np.ones(2), "0-d": np.array(1.0), "int": 1}[form]
    params = {"base_rigidity": value, "v0": 0.01}
    est = estimate_batch(cfg, params, s)
    r = simulate_batch(cfg, params, s)
    assert est["dt"] == r.dt and est["n_steps"] == r.n_steps and est["step_path"] in r.info["step_path"]
    assert est["seconds_estimate"] > 0 and est["device_bytes_estimate"] > 0


def test_a_resume_is_priced_for_the_shards_left(tmp_path, cache, capsys, monkeypatch):
    """The estimate of a resume (its dry run and its time limit) covers the shards its manifest does
    not record as done: none after a finished run, one of three after one is forgotten."""
    monkeypatch.setattr(C, "others_busy", lambda start: 0.0)  # one probe for all the calls
    spec = tmp_path / "tiny.toml"
    spec.write_text(TINY)
    out = tmp_path / "o.nc"
    assert main(["run", str(spec), "-o", str(out), "--device", "cpu", "--no-progress"]) == 0

    def stepping(args):
        capsys.readouterr()
        assert main(args) == 0
        return float(re.search(r"stepping ([\d.e+-]+) s", capsys.readouterr().out).group(1))

    full = stepping(["run", str(spec), "-o", str(tmp_path / "other.nc"), "--device", "cpu", "--dry-run"])
    assert full > 0 and stepping(["resume", str(out), "--device", "cpu", "--dry-run"]) == 0
    from warp_tensegrity.sweep.manifest import Manifest
    from warp_tensegrity.sweep.store import SweepStore

    path = SweepStore(out).manifest_path
    content, _ = Manifest.read(path)
    del content["shards"]["1"]  # shard 1 forgotten, as after a kill while it ran
    Manifest(path, content).save()
    left = stepping(["resume", str(out), "--device", "cpu", "--dry-run"])
    assert left == pytest.approx(full / 3, rel=1e-2), (left, full)


def test_default_shard_size_fills_the_device_and_a_given_one_wins(monkeypatch):
    """shard_size 'auto': one lane-step warp per column for every warp slot of the GPU (SM count x 8 at
    255 registers a thread: 1,056 on an H200), 256 on the CPU; the spec's or --shard-size's wins."""
    from types import SimpleNamespace

    text = "[scene]\nn_prisms = 3\n[sweep]\ngrid = { v0 = [0.001, 0.002, 0.003] }\n[run]\nt_end = 0.01\n"
    monkeypatch.setattr(D, "resolve_device", lambda device=None: SimpleNamespace(is_cuda=True, sm_count=132))
    assert D.default_shard_size("cuda:0") == 1056
    assert sweep.plan_sweep(load_spec(text), estimate=False).shard_size == 1056
    assert sweep.plan_sweep(load_spec(text + "shard_size = 2\n"), estimate=False).shards == [(0, 2), (2, 3)]
    assert sweep.plan_sweep(load_spec(text), shard_size=1, estimate=False).n_shards == 3
    monkeypatch.setattr(D, "resolve_device", lambda device=None: SimpleNamespace(is_cuda=False, sm_count=0))
    assert sweep.plan_sweep(load_spec(text), estimate=False).shard_size == D.CPU_SHARD_SIZE == 256
