"""End-to-end cost of a sweep through the CLI's code path, by stage, beside the dry-run estimate.

    python benchmarks/end_to_end.py sweeps/ci_small.toml sweeps/paper_2017.toml --device cpu \
        --out benchmarks/results/end_to_end_cpu.json

For every spec: the dry-run's calibrated prediction is taken first
(:func:`warp_tensegrity.policy.calibrate.estimate_plan`, the function ``--dry-run`` prints; its probe
also warms the kernel cache), then a fresh Python process runs ``warp-tensegrity run SPEC -o OUT
--device D --overwrite --no-progress`` through :func:`warp_tensegrity.cli.main`, timed from
process creation to the closed output file. Stages are read off the engine
(``BatchResult.info['stages']``: build, compile, stepping, measurement, transfer) and from thin
timing wrappers around the sweep's own functions (planning -> build, shard dataset and netCDF
write -> write, shard checks and the combine -> finalise); imports are everything before the
CLI is entered (interpreter start, warp_tensegrity, Warp, xarray, ``wp.init``). The rest of the run
is timed too: the pricing of the plan (``estimate_plan``, the budget check) -> build; the store's
layout (template dataset, store initialise) -> write; the per-case measures and error estimates
(the base-mode flag, the twins' estimates) -> measurement; merging the groups' results ->
transfer; the run's closing report (``_log_nan_summary``, which reads the output) -> finalise.
Seconds not in any stage are reported as ``other_s``. Peak host RSS is the run process's ``ru_maxrss``.

``--stub-outputs K`` (a machine that cannot step the run, e.g. ``phase_large`` on the CPU): every
engine call steps only K outputs of its plan and its records are then padded to the run's outputs
(energies a smooth synthetic trace, times and steps the plan's), so everything around the step --
build, measures, the store, the export -- runs at the run's real size; stepping is K outputs' worth.

``--trace`` (CUDA): every chunk a run launches (``Integrator.advance``) and every run's initialisation
is bracketed by timing events on its stream, and the host's seconds around it are kept: the record
gets ``trace``, per run its chunks' device intervals and host launch seconds, and the union of the
device's busy intervals (how far the runs of a shard overlap, and where the device waits on the host),
also as intervals on the process clock (``busy_intervals_s``); and ``timeline``: every timed host call
(the stage wrappers, each Integrator's build and kernel load, ``run_groups``, ``compute_shard``) as
(what, start s since process creation, seconds, thread), off a GPU too. A run's record ``runs`` are keyed by the
Integrator's ``id``, which Python may reuse once a run has ended: two runs can merge into one entry.

Writes a JSON list of records (one per run) with keys ``spec``, ``device_name``, ``git_commit``,
``wall_s``, ``stages_s``, ``estimate_s``, ``peak_rss_bytes`` and some context.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
STAGES = ("import", "build", "compile", "stepping", "measurement", "transfer", "write", "finalise")


def _stub(orig, k: int, spent: dict):
    """engine.run_batches stepping only ``k`` outputs of each plan, the records padded to the plan's outputs."""
    import dataclasses

    import numpy as np

    def pad(r, plan):
        n_out, t0 = plan.n_out, r.time.size
        rng = np.random.default_rng(t0)
        tt = plan.output_times
        for name in ("kinetic_energy", "elastic_energy", "station_energy", "end_energy"):
            a0 = getattr(r, name)
            if a0 is not None:  # smooth, with round-off-like low bits, scaled as the short record
                B = a0.shape[0]
                w, ph = rng.uniform(5, 50, (B, 1)), rng.uniform(0, 6, (B, 1))
                pad = np.abs(a0[:, :1]) * (1.2 + np.sin(w * tt[t0:] + ph)) * (1 + 1e-9 * rng.standard_normal((B, n_out - t0)))
                setattr(r, name, np.concatenate([a0, pad], axis=1))
        if r.strain is not None:  # (B, T, P): the last record held
            r.strain = np.concatenate([r.strain, np.repeat(r.strain[:, -1:], n_out - t0, axis=1)], axis=1)
        r.time = tt
        if r.info.get("output_step") is not None:
            r.info["output_step"] = plan.output_steps
        r.n_steps = plan.n_steps

    def run(runs, *a, **kw):
        short = [(c, p, dataclasses.replace(plan, n_steps=min(plan.n_steps, k * plan.output_every)))
                 for c, p, plan in runs]
        results, stages = orig(short, *a, **kw)
        t_pad = time.perf_counter()
        for r, (_, _, plan) in zip(results, runs):
            pad(r, plan)
        spent["s"] += time.perf_counter() - t_pad
        return results, stages

    return run


def _trace_runs(t_ref: float = 0.0):
    """Patch Integrator.advance and .initialize to bracket each call with timing events (``--trace``);
    returns a function that makes the record's ``trace`` once the run has ended."""
    import warp as wp

    from warp_tensegrity.sim import integrate

    calls, t_host0 = [], time.perf_counter()

    def bracket(name):
        orig = getattr(integrate.Integrator, name)

        def wrapped(self, *a, **k):
            if not self.device.is_cuda:
                return orig(self, *a, **k)
            e0 = wp.Event(self.device, enable_timing=True)
            wp.record_event(e0)
            h0 = time.perf_counter()
            out = orig(self, *a, **k)
            h1 = time.perf_counter()
            e1 = wp.Event(self.device, enable_timing=True)
            wp.record_event(e1)
            calls.append((id(self), name, a[0] if a else 0, self.model.n_columns, h0 - t_host0, h1 - h0, e0, e1,
                          str(getattr(self.settings.precision, "value", self.settings.precision))))
            return out

        setattr(integrate.Integrator, name, wrapped)

    bracket("advance")
    bracket("initialize")

    def report():
        if not calls:
            return None
        wp.synchronize()
        ref = calls[0][6]
        runs = {}
        spans = []
        for rid, name, n, B, h0, dh, e0, e1, prec in calls:
            a, b = wp.get_event_elapsed_time(ref, e0) / 1e3, wp.get_event_elapsed_time(ref, e1) / 1e3
            r = runs.setdefault(rid, {"columns": B, "precision": prec, "steps": 0, "chunks": 0, "host_s": 0.0, "first_s": a, "last_s": b,
                                      "device_s": 0.0, "host_first_s": h0})
            r["steps"] += int(n) if name == "advance" else 0
            r["chunks"] += 1
            r["host_s"] += dh
            r["first_s"], r["last_s"] = min(r["first_s"], a), max(r["last_s"], b)
            r["device_s"] += b - a
            spans.append((a, b))
        spans.sort()
        # the device's busy intervals on the process clock (the first event was recorded at its call's host start)
        off = t_host0 - t_ref + calls[0][4]
        merged = []
        for a, b in spans:
            if merged and a <= merged[-1][1]:
                merged[-1][1] = max(merged[-1][1], b)
            else:
                merged.append([a, b])
        busy_on_clock = [[round(a + off, 4), round(b + off, 4)] for a, b in merged]
        busy, cur = 0.0, None
        for a, b in spans:
            if cur is None or a > cur[1]:
                busy += 0.0 if cur is None else cur[1] - cur[0]
                cur = [a, b]
            else:
                cur[1] = max(cur[1], b)
        busy += cur[1] - cur[0]
        span = max(b for _, b in spans) - min(a for a, _ in spans)
        return {"runs": list(runs.values()), "device_busy_s": busy, "device_span_s": span,
                "busy_intervals_s": busy_on_clock,
                "note": "seconds from the first traced event; a run's device_s sums its chunks' event intervals "
                        "(queued chunks overlap in it); busy: the union of all chunks' intervals"}

    return report


def _child(spec: str, device: str, out: str, record: str, stub: int = 0, trace: bool = False,
           profile: str | None = None) -> None:
    """Run one spec through cli.main and write its stage record (the run process); with ``profile``, the
    run's main thread under cProfile (pstats dump at that path, its top functions beside it as .txt)."""
    from warp_tensegrity.runtime import process_age

    t_ref = time.perf_counter() - process_age()  # process creation on the perf_counter clock
    import warp as wp

    wp.config.quiet = True
    from warp_tensegrity import cli, engine  # noqa: F401 - the modules a run imports
    from warp_tensegrity.sim import integrate  # noqa: F401 - the modules a run imports
    from warp_tensegrity import io as D
    from warp_tensegrity.measure import device as _measure_device  # noqa: F401
    from warp_tensegrity.sweep import beside, budget, plan as sweep_plan, run as sweep_run, shard as sweep_shard, store as sweep_store

    wp.init()
    wp.get_device(device)
    st = dict.fromkeys(STAGES, 0.0)
    st["import"] = time.perf_counter() - t_ref
    info = {"shards": 0}
    phase = {"finalise": False}

    depth = threading.local()  # a timed call inside another counts once, in the outer one's stage
    timeline = []  # --trace: (what, start s since process creation, seconds, thread) of every outer timed call

    def mark(what, t0, dt):
        if trace:
            timeline.append((what, round(t0 - t_ref, 4), round(dt, 4), threading.current_thread().name))

    def timed(owner, name, stage, fn=None):
        orig = getattr(owner, name)

        def wrapper(*a, **k):
            outer = getattr(depth, "n", 0) == 0
            depth.n = getattr(depth, "n", 0) + 1
            t0 = time.perf_counter()
            try:
                return (fn or orig)(*a, **k)
            finally:
                dt = time.perf_counter() - t0
                depth.n -= 1
                s = stage() if callable(stage) else stage
                if s and outer:
                    st[s] += dt
                    mark(f"{s}:{name}", t0, dt)

        setattr(owner, name, wrapper)
        return orig

    stubbed = {"s": 0.0}  # the stub's synthetic padding: no stage of a real run, left out of the wall
    orig_runs = sweep_shard.run_batches if not stub else _stub(sweep_shard.run_batches, stub, stubbed)

    def runs(*a, **k):  # a shard's runs (its groups and twins, at once on a GPU): the engine's stages
        t0, stub0 = time.perf_counter(), stubbed["s"]
        results, es = orig_runs(*a, **k)
        total = time.perf_counter() - t0
        total -= stubbed["s"] - stub0
        mark("runs", t0, time.perf_counter() - t0)
        keys = ("build", "compile", "stepping", "measurement", "transfer")
        for key in keys:
            st[key] += float(es.get(key, 0.0))
        # host-side preparation around the engine's own stages (batch assembly, padding); host work stepped
        # with the runs (the store's layout: timed in its own stage by its wrapper) is not preparation
        st["build"] += max(0.0, total - sum(float(v) for v in es.values()))
        info["shards"] += len(results)
        for r in results:
            info["n_steps"] = max(info.get("n_steps", 0), int(r.n_steps))
            info["device"] = r.device
            info["device_name"] = r.device_name
        return results, es

    sweep_shard.run_batches = runs
    traced = _trace_runs(t_ref) if trace else None
    if trace:  # host intervals on the timeline only (their seconds are in the engine's stages)
        for owner, name in ((integrate.Integrator, "__init__"), (integrate.Integrator, "load_kernels"),
                            (sweep_shard, "run_groups"), (sweep_run, "compute_shard")):
            def marked(*a, _orig=getattr(owner, name), _name=name, **k):
                t0 = time.perf_counter()
                try:
                    return _orig(*a, **k)
                finally:
                    mark(f"host:{_name}", t0, time.perf_counter() - t0)

            setattr(owner, name, marked)
    syncs = {"calls": 0, "seconds": 0.0}  # every fsync of the run (its files' durability), on any thread
    real_fsync = os.fsync

    def fsync(fd):
        t0 = time.perf_counter()
        try:
            return real_fsync(fd)
        finally:
            syncs["calls"] += 1
            syncs["seconds"] += time.perf_counter() - t0

    os.fsync = fsync
    timed(sweep_plan, "plan_sweep", "build")
    timed(cli, "estimate_plan", "build")  # the run's pricing (the probe cached by the dry run)
    timed(budget, "check_run", "build")
    timed(sweep_run, "template_dataset", "write")  # the store's layout
    timed(sweep_store.SweepStore, "initialise", "write")
    timed(sweep_shard, "beta_limit_measures", "measurement")
    timed(beside, "result", "measurement")  # waits for the base-mode analysis beside, if it still runs
    timed(sweep_shard, "error_estimates", "measurement")
    timed(sweep_shard, "merge_results", "transfer")
    timed(cli, "_log_nan_summary", "finalise")  # the closing report reads the output
    timed(sweep_shard, "measure_columns", "measurement")
    timed(D, "shard_dataset", "write")
    timed(D, "write_netcdf", lambda: None if phase["finalise"] else "write")
    # the streaming store: a shard's chunk write (writer thread, overlapping the next shard's
    # stepping) is "write"; the export of OUT.nc from the store is "finalise"
    timed(sweep_store.SweepStore, "write_shard", "write")
    orig_export = sweep_run.export_netcdf

    def export(*a, **k):
        phase["finalise"] = True
        t0 = time.perf_counter()
        try:
            return orig_export(*a, **k)
        finally:
            st["finalise"] += time.perf_counter() - t0
            mark("finalise:export_netcdf", t0, time.perf_counter() - t0)
            phase["finalise"] = False

    sweep_run.export_netcdf = export
    prof = None
    if profile:
        import cProfile

        prof = cProfile.Profile()
        prof.enable()
    rc = cli.main(["run", spec, "-o", out, "--device", device, "--overwrite", "--no-progress"])
    if prof is not None:
        prof.disable()
        import io as _io
        import pstats

        prof.dump_stats(profile)
        buf = _io.StringIO()
        stats = pstats.Stats(prof, stream=buf)
        stats.sort_stats("cumulative").print_stats(120)
        stats.sort_stats("tottime").print_stats(60)
        Path(profile).with_suffix(".txt").write_text(buf.getvalue())
    wall = time.perf_counter() - t_ref - stubbed["s"]
    if rc != 0:
        raise SystemExit(f"run of {spec} failed with exit code {rc}")
    import resource

    rec = {"wall_s": wall, "stages_s": st, "other_s": wall - sum(st.values()),
           "peak_rss_bytes": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024, "fsync": syncs, **info}
    if traced is not None:
        rec["trace"] = traced()
        rec["timeline"] = timeline
    Path(record).write_text(json.dumps(rec))


def _estimate(spec: str, device: str, out: str) -> dict:
    from warp_tensegrity.policy.calibrate import estimate_plan
    from warp_tensegrity.sweep.plan import plan_sweep
    from warp_tensegrity.sweep.spec import load_spec

    t0 = time.perf_counter()
    plan = plan_sweep(load_spec(Path(spec)), out, device=device)
    est = estimate_plan(plan)
    est["dry_run_s"] = time.perf_counter() - t0
    return est


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("specs", nargs="*", help="sweep specs (TOML)")
    p.add_argument("--device", default="cpu")
    p.add_argument("--out", default=None, help="JSON output (default benchmarks/results/end_to_end_<device>.json)")
    p.add_argument("--repeat", type=int, default=1, help="runs per spec (each a record)")
    p.add_argument("--append", action="store_true", help="keep the records already in the output file")
    p.add_argument("--keep", default=None, help="copy each spec's output netCDF into this folder")
    p.add_argument("--stub-outputs", type=int, default=0, metavar="K",
                   help="step only K outputs per engine call, records padded to the run's (see above)")
    p.add_argument("--trace", action="store_true", help="bracket every chunk with CUDA timing events (see above)")
    p.add_argument("--profile", default=None, metavar="DIR",
                   help="each run's main thread under cProfile: DIR/<spec>_<run>.prof and .txt (adds overhead)")
    p.add_argument("--child", nargs=3, metavar=("SPEC", "OUT_NC", "RECORD"), help=argparse.SUPPRESS)
    a = p.parse_args(argv)
    if a.child:
        _child(a.child[0], a.device, a.child[1], a.child[2], a.stub_outputs, a.trace, a.profile)
        return 0
    sys.path.insert(0, str(REPO))
    sys.path.insert(0, str(REPO / "benchmarks"))
    import warp as wp

    wp.config.quiet = True
    from common import git_commit, run_metadata

    meta = run_metadata(wp.get_device(a.device))
    commit = git_commit()
    out_path = Path(a.out) if a.out else REPO / "benchmarks" / "results" / f"end_to_end_{a.device.replace(':', '')}.json"
    out_path.parent.mkdir(parents=True, exist_ok=True)
    records = json.loads(out_path.read_text()) if a.append and out_path.exists() else []
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(REPO), env.get("PYTHONPATH", "")])
    with tempfile.TemporaryDirectory(prefix="e2e_") as tmp:
        for spec in a.specs:
            out = str(Path(tmp) / (Path(spec).stem + ".nc"))
            est = _estimate(spec, a.device, out)
            for r in range(a.repeat):
                rec_path = Path(tmp) / "record.json"
                cmd = [sys.executable, str(Path(__file__).resolve()), "--device", a.device, "--child", spec, out,
                       str(rec_path), "--stub-outputs", str(a.stub_outputs)] + (["--trace"] if a.trace else [])
                if a.profile:
                    Path(a.profile).mkdir(parents=True, exist_ok=True)
                    cmd += ["--profile", str(Path(a.profile).resolve() / f"{Path(spec).stem}_{r}.prof")]
                load0 = os.getloadavg()[0]
                subprocess.run(cmd, check=True, env=env)
                rec = json.loads(rec_path.read_text())
                record = {
                    "spec": spec,
                    "device_name": rec.get("device_name", meta.get("device_name")),
                    "device": rec.get("device", a.device),
                    "git_commit": commit,
                    "code_sha256": meta["code_sha256"],
                    "wall_s": rec["wall_s"],
                    "stages_s": rec["stages_s"],
                    "other_s": rec["other_s"],
                    "estimate_s": est["seconds"],
                    "estimate_stages_s": est["stages_s"],
                    "estimate_error": est["seconds"] / rec["wall_s"] - 1.0,
                    "dry_run_s": est["dry_run_s"],
                    "estimate_device_bytes_per_shard": est["device_bytes_per_shard"],
                    "estimate_host_peak_bytes": est["host_peak_bytes"],
                    "peak_rss_bytes": rec["peak_rss_bytes"],
                    "fsync": rec.get("fsync"),
                    "shards": rec["shards"],
                    "n_steps": rec.get("n_steps"),
                    "repeat": r,
                    **({"stub_outputs": a.stub_outputs} if a.stub_outputs else {}),
                    **({"trace": rec["trace"]} if rec.get("trace") else {}),
                    **({"timeline": rec["timeline"]} if rec.get("timeline") else {}),
                    "load_avg_1min": [load0, os.getloadavg()[0]],
                    "probe_load_avg_1min": est["probe"].get("load_avg"),
                    "kernel_cache": "warm (the estimate's probe compiled what the run loads)",
                    "measurement_on": "device",
                    "host": {k: meta.get(k) for k in ("host", "cpu", "cpu_count", "driver", "sm_count")},
                    "warp_version": wp.config.version,
                    "time": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
                }
                st = rec["stages_s"]
                tail = st["measurement"] + st["transfer"] + st["write"] + st["finalise"]
                record["tail_s"] = tail
                record["tail_over_stepping"] = tail / st["stepping"] if st["stepping"] else None
                records.append(record)
                out_path.write_text(json.dumps(records, indent=1, default=str) + "\n")  # after every run
                if a.keep:
                    Path(a.keep).mkdir(parents=True, exist_ok=True)
                    shutil.copyfile(out, Path(a.keep) / Path(out).name)
                print(f"{spec}: wall {rec['wall_s']:.2f} s (estimate {est['seconds']:.2f} s, "
                      f"{100 * record['estimate_error']:+.0f} %); " + ", ".join(f"{k} {v:.3g}" for k, v in st.items())
                      + f"; other {rec['other_s']:.3g}; peak RSS {rec['peak_rss_bytes'] / 1e6:.0f} MB", flush=True)
    print(out_path)
    return 0


if __name__ == "__main__":
    sys.exit(main())
