"""Throughput of the RATTLE engine: column-steps/s and node-steps/s against batch size and
against prisms per column, FB and RB, fp32 and fp64.

Usage::

    python -m benchmarks.throughput --device cuda:0 --out benchmarks/results/throughput_cuda.json
    python -m benchmarks.throughput --device cpu --quick       # -> benchmarks/results/throughput_cpu_quick.json
    python -m benchmarks.throughput --device cuda:0 --ncu-mode # a few eager steps, for Nsight Compute

Method (per point): build the batch on the host (tiled from 64 distinct columns), build the
Integrator, initialize (kernels were compiled up front), probe 2 eager steps, capture a CUDA
graph of up to 50 steps and replay it once, then time ``reps`` segments of n steps with a
device synchronisation around each; n is chosen so the segments take about ``--target-s``.
Reported rate = B * steps / wall. JSON is rewritten after every point, so a run that is cut
short keeps what it measured.
"""

from __future__ import annotations

import argparse
import sys
import time
import traceback
from pathlib import Path

from . import common

FULL = {
    "cuda": {"batches": [1, 4, 16, 64, 256, 1024, 4096, 16384, 65536], "prisms": [10, 25, 50, 100, 200, 400],
             "prism_batch": 4096, "target_s": 0.3, "budget_s": 330.0},
    "cpu": {"batches": [1, 4, 16, 64], "prisms": [10, 25, 50, 100], "prism_batch": 4,
            "target_s": 0.25, "budget_s": 90.0},
}
QUICK = {
    "cuda": {"batches": [1, 16, 256, 4096, 65536], "prisms": [10, 50, 200], "prism_batch": 4096,
             "target_s": 0.12, "budget_s": 90.0},
    "cpu": {"batches": [1, 4, 16], "prisms": [10, 50, 100], "prism_batch": 4, "target_s": 0.12,
            "budget_s": 45.0},
}
BASES = {"FB": 0.0, "RB": 1.0}
DIAG_STEPS = 10


def _log(msg):
    print(msg, flush=True)


def default_out(device, quick: bool) -> Path:
    tag = "cpu" if device.is_cpu else common.device_kind(device.name)
    if tag == "other":
        tag = str(device).replace(":", "")
    return common.RESULTS / f"throughput_{tag}{'_quick' if quick else ''}.json"


def run(args) -> dict:
    import warp as wp

    wp.config.quiet = not args.verbose
    if not args.verbose:
        wp.config.log_level = wp.LOG_WARNING  # no per-module load lines
    wp.init()
    device = wp.get_device(args.device)
    kind = "cuda" if device.is_cuda else "cpu"
    plan = dict((QUICK if args.quick else FULL)[kind])
    for key in ("batches", "prisms", "prism_batch", "target_s", "budget_s"):
        v = getattr(args, key)
        if v is not None:
            plan[key] = v
    out = Path(args.out) if args.out else default_out(device, args.quick)
    if args.out_dir and not args.out:
        out = Path(args.out_dir) / default_out(device, args.quick).name
    t_start = time.perf_counter()
    meta = common.run_metadata(device)
    _log(f"[throughput] device {device} ({device.name}), Warp {wp.__version__}, driver {meta.get('driver')}, "
         f"commit {meta['git_commit']}; out {out}")
    _log(f"[throughput] plan: batches {plan['batches']} at 50 prisms; prisms {plan['prisms']} at B={plan['prism_batch']}; "
         f"precisions {args.precisions}; bases {args.bases}; target {plan['target_s']} s/point; budget {plan['budget_s']} s")
    t = time.perf_counter()
    compile_s = common.precompile(device, args.precisions)
    _log(f"[throughput] compiled/loaded RATTLE kernels for {args.precisions} in {compile_s:.1f} s")
    doc = {
        "kind": "throughput", "method": "rattle", "meta": meta, "plan": plan, "quick": bool(args.quick),
        "precisions": args.precisions, "bases": args.bases, "paths": args.paths,
        "harness": {
            "base_columns": common.BASE_COLUMNS, "prestrain_range": common.PRESTRAIN_RANGE,
            "v0_range": common.V0_RANGE, "dt": "0.25 * 2 / omega_max_bound (RATTLE dt='auto' before rounding)",
            "output_every": 100, "record_strain": False, "reps": args.reps,
            "timing": "B * steps / wall over reps segments, each synchronised; graph replay on CUDA",
        },
        "compile_s": compile_s, "points": [], "skipped": [],
    }
    sweep_t0 = time.perf_counter()
    done = {}
    dts = {}

    def over_budget():
        return time.perf_counter() - sweep_t0 > plan["budget_s"]

    def measure(batch_small, n_prisms, base, prec, B, sweep):
        for path in args.paths:
            if sweep == "prisms" and path not in args.prism_paths:
                continue
            measure_path(batch_small, n_prisms, base, prec, B, sweep, path)

    def measure_path(batch_small, n_prisms, base, prec, B, sweep, path):
        key = (n_prisms, base, prec, B, path)
        if key in done:
            p = dict(done[key])
            p["sweep"] = sweep
            p["reused"] = True
            doc["points"].append(p)
            return
        if over_budget():
            doc["skipped"].append({"n_prisms": n_prisms, "base": base, "precision": prec, "B": B, "sweep": sweep,
                                   "path": path, "reason": "time budget"})
            _log(f"  skip {sweep} B={B} prisms={n_prisms} {base} {prec} (budget)")
            return
        try:
            tb = time.perf_counter()
            if (n_prisms, base) not in dts:
                dts[(n_prisms, base)] = common.rattle_dt(batch_small)  # tiled copies share omega_max
            batch = common.tile_batch(batch_small, B)
            tile_s = time.perf_counter() - tb
            pt = common.time_batch(batch, base, n_prisms, prec, device, target_s=plan["target_s"], reps=args.reps,
                                   max_steps=args.max_steps, diag_steps=DIAG_STEPS if args.diagnostics else 0,
                                   dt=dts[(n_prisms, base)], path=path)
            p = pt.as_dict()
            p["tile_s"] = tile_s
            p["sweep"] = sweep
            try:
                from . import roofline

                dk = common.device_kind(device.name)
                if dk in roofline.DEVICES:
                    it = p.get("mean_iters")
                    rb = roofline.bound(n_prisms, base, prec, dk, it=it, B=B, path=path)
                    p["roofline_bound_column_steps_per_s"] = rb["bound_column_steps_per_s"]
                    p["roofline_bytes_per_column_step"] = rb["bytes_per_column_step"]
                    p["roofline_fraction"] = p["column_steps_per_s"] / rb["bound_column_steps_per_s"]
                    p["sm_fill_per_column_kernels"] = rb["sm_fill_per_column_kernels"]
            except Exception as exc:  # noqa: BLE001
                p["roofline_error"] = repr(exc)
            done[key] = p
            doc["points"].append(p)
            extra = ""
            if p.get("mean_iters") is not None:
                extra = f" iters {p['mean_iters']:.2f} (warp max {p['warp32_max_iters_mean']:.2f})"
            if "roofline_fraction" in p:
                extra += f" {100 * p['roofline_fraction']:.1f}% of roofline"
            _log(f"  {sweep:7s} {path:12s} B={B:6d} prisms={n_prisms:4d} {base} {prec}: {p['column_steps_per_s']:.4g} col-steps/s "
                 f"{p['node_steps_per_s']:.4g} node-steps/s ({p['steps']} steps, {p['wall_s']:.3f} s, "
                 f"graph {p['steps_per_graph']}) {p['bytes_per_column'] / 1e3:.1f} KB/col, build {p['build_s']:.2f} s,"
                 f" failed {p['n_failed']}{extra}")
        except Exception as exc:  # noqa: BLE001
            doc["points"].append({"n_prisms": n_prisms, "base": base, "precision": prec, "B": B, "sweep": sweep,
                                  "path": path, "error": repr(exc), "traceback": traceback.format_exc()})
            _log(f"  ERROR {sweep} B={B} prisms={n_prisms} {base} {prec}: {exc!r}")
        doc["elapsed_s"] = time.perf_counter() - t_start
        common.write_json(out, doc)

    # 1. against batch size, 50 prisms
    for base in args.bases if plan["batches"] else ():
        tb = time.perf_counter()
        small = common.build_base_batch(50, BASES[base], min(common.BASE_COLUMNS, max(plan["batches"])))
        _log(f"[batch sweep] 50 prisms {base}: base batch built in {time.perf_counter() - tb:.2f} s")
        for prec in args.precisions:
            for B in plan["batches"]:
                measure(small, 50, base, prec, B, "batch")
    # 2. against prisms per column, fixed B
    Bp = plan["prism_batch"]
    for npr in plan["prisms"]:
        for base in args.bases:
            if all((npr, base, prec, Bp, path) in done for prec in args.precisions for path in args.prism_paths):
                for prec in args.precisions:
                    measure(None, npr, base, prec, Bp, "prisms")
                continue
            if over_budget():
                for prec in args.precisions:
                    measure(None, npr, base, prec, Bp, "prisms")
                continue
            tb = time.perf_counter()
            small = common.build_base_batch(npr, BASES[base], min(common.BASE_COLUMNS if npr <= 100 else 16, Bp))
            _log(f"[prism sweep] {npr} prisms {base}: base batch built in {time.perf_counter() - tb:.2f} s")
            for prec in args.precisions:
                measure(small, npr, base, prec, Bp, "prisms")
    doc["elapsed_s"] = time.perf_counter() - t_start
    doc["sweep_s"] = time.perf_counter() - sweep_t0
    common.write_json(out, doc)
    n_err = sum(1 for p in doc["points"] if p.get("error"))
    _log(f"[throughput] {len(doc['points'])} points ({n_err} errors, {len(doc['skipped'])} skipped) in "
         f"{doc['elapsed_s']:.1f} s total (compile {compile_s:.1f} s); wrote {out}")
    return doc


def ncu_mode(args):
    """A short eager run (no graph) of B columns for Nsight Compute: initialize + a few steps."""
    import warp as wp

    wp.config.quiet = True
    wp.config.log_level = wp.LOG_WARNING
    wp.init()
    device = wp.get_device(args.device)
    prec = args.precisions[0]
    base = args.bases[0]
    npr = args.ncu_prisms
    B = args.ncu_batch
    common.precompile(device, [prec])
    from warp_tensegrity import RunSettings
    from warp_tensegrity.sim.integrate import Integrator
    from warp_tensegrity.types import Path as LaunchPath

    batch = common.tile_batch(common.build_base_batch(npr, BASES[base], min(common.BASE_COLUMNS, B)), B)
    dt = common.rattle_dt(batch)
    fused = args.paths[0] != "staged"
    s = RunSettings(t_end=dt * 1000, dt=dt, precision=prec, device=str(device), record_strain=False,
                    steps_per_graph=1 << 30, fused=fused)
    integ = Integrator(batch, s, dt, 100, 16, path=LaunchPath(args.paths[0]))
    if not fused:
        integ.load_kernels = lambda: None
    integ.initialize()
    integ.advance(args.ncu_steps)
    wp.synchronize_device(device)
    print(f"[ncu-mode] {npr} prisms {base} {prec} B={B}: {args.ncu_steps} eager steps done; "
          f"failed {integ.n_failed()}", flush=True)


def main(argv=None):
    ap = argparse.ArgumentParser(description="RATTLE throughput against batch size and prisms per column")
    ap.add_argument("--device", default="cuda:0" if _has_cuda() else "cpu")
    ap.add_argument("--out", default=None, help="JSON path (default benchmarks/results/throughput_<device>.json)")
    ap.add_argument("--out-dir", dest="out_dir", default=None,
                    help="write throughput_<h100|h200|cpu|...>[_quick].json into this folder instead")
    ap.add_argument("--quick", action="store_true", help="fewer points, shorter timings")
    ap.add_argument("--precisions", nargs="+", default=["fp32", "fp64"], choices=["fp32", "fp64"])
    ap.add_argument("--bases", nargs="+", default=["FB", "RB"], choices=["FB", "RB"])
    ap.add_argument("--batches", type=int, nargs="*", default=None,
                    help="batch sizes at 50 prisms (none given: no batch sweep, the prism sweep only)")
    ap.add_argument("--prisms", type=int, nargs="+", default=None, help="prisms per column for the second sweep")
    ap.add_argument("--prism-batch", dest="prism_batch", type=int, default=None, help="B of the prism sweep")
    ap.add_argument("--target-s", dest="target_s", type=float, default=None, help="timed seconds per point")
    ap.add_argument("--budget-s", dest="budget_s", type=float, default=None,
                    help="stop starting new points after this many seconds of sweeping (compile excluded)")
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--paths", nargs="+", default=["fused", "staged"], choices=["lanes", "fused", "fused-serial", "staged"],
                    help="step implementations: fused (block per column; its solve by block cyclic reduction), "
                         "fused-serial (the same, lane 0's serial banded Cholesky) and/or staged (kernel per stage)")
    ap.add_argument("--prism-paths", dest="prism_paths", nargs="+", default=["fused"],
                    choices=["lanes", "fused", "fused-serial", "staged"],
                    help="paths measured in the prism sweep")
    ap.add_argument("--max-steps", dest="max_steps", type=int, default=200_000)
    ap.add_argument("--no-diagnostics", dest="diagnostics", action="store_false",
                    help="skip the 10-step Newton-iteration diagnostic after each point")
    ap.add_argument("--verbose", action="store_true", help="Warp's own messages (module loads)")
    ap.add_argument("--ncu-mode", dest="ncu_mode", action="store_true",
                    help="run a few eager steps (for ncu) instead of the sweep")
    ap.add_argument("--ncu-batch", dest="ncu_batch", type=int, default=4096)
    ap.add_argument("--ncu-prisms", dest="ncu_prisms", type=int, default=50)
    ap.add_argument("--ncu-steps", dest="ncu_steps", type=int, default=3)
    args = ap.parse_args(argv)
    if args.ncu_mode:
        ncu_mode(args)
        return 0
    doc = run(args)
    return 1 if any(p.get("error") for p in doc["points"]) else 0


def _has_cuda() -> bool:
    try:
        import warp as wp

        wp.config.quiet = True
        return wp.get_cuda_device_count() > 0
    except Exception:  # noqa: BLE001
        return False


if __name__ == "__main__":
    sys.exit(main())
