"""Do the error estimates cover the real error? (issue 31, Must show 2 and 3.)

Runs a sweep the way the CLI does (groups, twins, precision as asked) and a reference of every case
in fp64 at a quarter of its group's dt, then reports per measure how many feasible cases have

* a number within the accuracy target of the reference (unflagged ones: all of them should);
* an error estimate at least as large as the real difference (the coverage), and at least half of it;
* which flag took the others (measurement_flag, error_flag) and which precision answered.

    python -m benchmarks.error_coverage                         # the built-in 200-case CPU set
    python -m benchmarks.error_coverage --spec sweeps/phase_large.toml --device cuda:0 \\
        --precision auto fp32 fp64 --reference-cache /tmp/ref.npz

Feasible: max_compression < 1 and, where base_rigidity >= 0.9, v0 < 0.045 m/s (the issue's filter:
past that the twist passes pi; docs/measurements.md), and a feasibility flag of 0 where the dataset
has one. JSON under benchmarks/results/ with the device and the commit.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from benchmarks.common import run_metadata, write_json

ROOT = Path(__file__).resolve().parents[1]
MEASURES = ("amplitude", "speed", "width", "width_10", "arrival_time")
CPU_SET = """title = "error-estimate coverage set"
[scene]
n_prisms = 16
[sweep]
grid.prestrain = { start = 0.0, stop = 0.01, num = 5 }
grid.v0 = { start = 3.0e-3, stop = 0.04, num = 8, spacing = "log" }
grid.base_rigidity = [0.0, 0.5, 0.9, 0.95, 1.0]
[run]
t_end = 1.5
output_interval = 0.002
record_strain = false
shard_size = 100
"""


CASE_KEYS = MEASURES + ("prestrain", "v0", "base_rigidity", "max_compression", "measurement_flag", "error_flag",
                        "precision_used", "feasibility_flag", "run_group", "time_step")


def _stack(ds):
    dims = [d for d in ds.dims if d not in ("prism", "t")]
    return ds.stack(case_=dims).transpose("case_", ...) if dims != ["case"] else ds


def run_sweep(text: str, device: str, mode: str) -> tuple:
    """(stacked dataset, seconds, stepping seconds, plan) of the spec run as the CLI runs it. ``mode``:
    a precision (fp32, fp64, auto), with ':onedt' one dt for every column (no groups)."""
    import xarray as xr

    from warp_tensegrity.sweep import compute_shard, load_spec, plan_sweep

    precision, _, one = mode.partition(":")
    spec = load_spec(text, overrides={"run": {"precision": precision, "error_estimate": True, "record_strain": False,
                                              "groups": one != "onedt"}})
    plan = plan_sweep(spec, device=device)
    t0 = time.perf_counter()
    parts = [compute_shard(plan, i) for i in range(plan.n_shards)]
    wall = time.perf_counter() - t0
    stepping = sum(float(p.attrs.get("wall_time", 0.0)) for p in parts)  # every group's runs, twins and reruns
    return xr.concat(parts, "case"), wall, stepping, plan


def reference(plan, device: str) -> dict:
    """Every case of ``plan`` in fp64 at a quarter of its group's dt: the measures, in case order."""
    from dataclasses import replace

    from warp_tensegrity import simulate_batch
    from warp_tensegrity.measure.nan_reasons import measure_columns
    from warp_tensegrity.policy.decide import decide

    spec, out = plan.spec, {}
    settings = replace(spec.run_settings(device=device), precision="fp64", record_strain=False)
    for g in plan.groups:
        params = {k: v[g.columns] for k, v in plan.params.items()}
        s = replace(settings, dt=g.plan.dt / 4, dt_safety=None, output_interval=g.plan.dt * g.plan.output_every)
        run = decide(spec.scene, params, s, n_columns=min(plan.shard_size, g.n_columns),
                     prisms_simulated=g.plan.prisms_simulated)
        for a in range(0, g.n_columns, plan.shard_size):
            sl = slice(a, a + plan.shard_size)
            r = simulate_batch(spec.scene, {k: v[sl] for k, v in params.items()}, plan=run)
            m = measure_columns(r, spec.scene.height)
            for k in MEASURES + ("max_compression",):
                v = np.asarray(m[k])
                out.setdefault(k, np.full((plan.n_columns,) + v.shape[1:], np.nan))[g.columns[sl]] = v
    return out


def feasible(ds) -> np.ndarray:
    ok = (ds.max_compression.values < 1) & ~((ds.base_rigidity.values >= 0.9) & (ds.v0.values >= 0.045))
    if "feasibility_flag" in ds:
        ok &= ds.feasibility_flag.values == 0
    return ok


def evaluate(ds, ref: dict, target: float) -> dict:
    """Per measure: cases compared, within target, covered by the estimate (and by twice it), by flag."""
    ok = feasible(ds)
    flag = ds.measurement_flag.values
    eflag = ds.error_flag.values
    feas = ds["feasibility_flag"].values if "feasibility_flag" in ds else np.zeros(ds.sizes["case"], np.int8)
    from warp_tensegrity.types import FEASIBILITY_FLAGS

    res = {"cases": int(ds.sizes["case"]), "feasible": int(ok.sum()),
           "left_feasible_set": {name: int(((feas & (1 << i)) != 0).sum()) for i, name in enumerate(FEASIBILITY_FLAGS)}
           | {"any": int((feas != 0).sum())},
           "measurement_flag": {int(f): int(((flag == f) & ok).sum()) for f in np.unique(flag)},
           "error_flag": {int(f): int(((eflag == f) & ok).sum()) for f in np.unique(eflag)},
           "precision_used": {int(p): int((ds.precision_used.values == p).sum()) for p in np.unique(ds.precision_used)}}
    for k in MEASURES:
        x, e, y = ds[k].values, ds[f"{k}_error"].values, ref[k]
        use = ok.reshape(ok.shape + (1,) * (x.ndim - 1)) & np.isfinite(x) & np.isfinite(y) & np.isfinite(e)
        real = np.abs(x - y)
        scale = np.abs(y)
        if k == "arrival_time":  # an arrival's error relative to the time the pulse took to cross the column
            scale = np.broadcast_to(np.nanmax(np.where(np.isfinite(y), y, np.nan), axis=-1, keepdims=True), y.shape)
        rel = real / scale
        unflagged = use & (flag == 0).reshape(use.shape[:1] + (1,) * (x.ndim - 1)) & \
            (eflag == 0).reshape(use.shape[:1] + (1,) * (x.ndim - 1))
        res[k] = {
            "compared": int(use.sum()),
            "unflagged": int(unflagged.sum()),
            "unflagged_within_target": int((unflagged & (rel <= target)).sum()),
            "unflagged_worst_relative_error": float(np.nanmax(np.where(unflagged, rel, np.nan), initial=0.0)),
            "unflagged_p95_relative_error": float(np.percentile(rel[unflagged], 95)) if unflagged.any() else None,
            "unflagged_median_relative_error": float(np.median(rel[unflagged])) if unflagged.any() else None,
            "covered": float((e[use] >= real[use]).mean()) if use.any() else None,
            "covered_half": float((e[use] >= 0.5 * real[use]).mean()) if use.any() else None,
            "median_estimate_over_real": float(np.median(e[use] / np.maximum(real[use], 1e-300))) if use.any() else None,
        }
    return res


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--spec", default=None, help="a sweep spec (default: the built-in 200-case CPU set)")
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--precision", nargs="+", default=["fp64"], help="modes to run: fp32, fp64, auto")
    ap.add_argument("--reference-cache", default=None, help="npz of the reference (made if missing)")
    ap.add_argument("--auto-fp32-on-cpu", action="store_true", help="precision auto verifies fp32 on the CPU too")
    ap.add_argument("--out", default=None, help="JSON (default benchmarks/results/error_coverage_<set>_<device>.json)")
    ap.add_argument("--modes-from", default=None,
                    help="an earlier JSON of this set whose modes (and reference time) are kept: a long study split "
                         "over device calls, the reference passed on with --reference-cache")
    ap.add_argument("--rechart", default=None, metavar="JSON",
                    help="evaluate again from the per-case file beside JSON (no run) and redraw its chart")
    args = ap.parse_args(argv)
    if args.rechart:
        return rechart(Path(args.rechart))
    import warp as wp

    wp.config.quiet = True
    if args.auto_fp32_on_cpu:
        from warp_tensegrity.policy import groups

        groups.AUTO_FP32_ON_CPU = True
    text = Path(args.spec).read_text() if args.spec else CPU_SET
    name = Path(args.spec).stem if args.spec else "cpu_set"
    out = {"meta": run_metadata(wp.get_device(args.device)), "set": name, "modes": {}}
    path = Path(args.out) if args.out else ROOT / "benchmarks" / "results" / f"error_coverage_{name}_{args.device.split(':')[0]}.json"
    if args.modes_from:
        import json

        old = json.loads(Path(args.modes_from).read_text())
        if old.get("set") != name or old["meta"].get("git_commit") != out["meta"].get("git_commit"):
            raise SystemExit(f"--modes-from {args.modes_from}: another set or commit ({old.get('set')}, "
                             f"{old['meta'].get('git_commit')})")
        out["modes"] = old["modes"]
        out.update({k: v for k, v in old.items() if k == "reference_seconds"})
    ref, cases = None, {}
    for prec in args.precision:
        ds, wall, stepping, plan = run_sweep(text, args.device, prec)
        if ref is None and len(plan.groups) == 1 and plan.groups[0].n_columns > 1 and ":onedt" in prec:
            raise SystemExit("give a grouped mode first: the reference is each case at its group's dt / 4")
        ds = _stack(ds)
        if ref is None:
            cache = Path(args.reference_cache) if args.reference_cache else None
            if cache is not None and cache.exists():
                with np.load(cache) as z:
                    ref = {k: z[k] for k in z.files}
            else:
                t0 = time.perf_counter()
                ref = reference(plan, args.device)
                out["reference_seconds"] = time.perf_counter() - t0
                print(f"reference: {out['reference_seconds']:.1f} s", flush=True)
                if cache is not None:
                    np.savez_compressed(cache, **ref)
        target = float(plan.run.accuracy or 1e-3)
        res = evaluate(ds, ref, target) | {"wall_seconds": wall, "stepping_seconds": stepping, "target": target,
                                           "groups": [[g.n_columns, g.plan.dt, g.plan.n_steps, g.twin.dt if g.twin else None]
                                                      for g in plan.groups]}
        out["modes"][prec] = res
        cases.update({f"{prec}/{k}": np.asarray(ds[k].values) for k in CASE_KEYS if k in ds}
                     | {f"{prec}/{k}_error": np.asarray(ds[f"{k}_error"].values) for k in MEASURES}
                     | {f"reference/{k}": np.asarray(v) for k, v in ref.items()})
        np.savez_compressed(path.with_name(path.stem + "_cases.npz"), **cases)  # per case, for a later look
        print(prec, {k: (v["covered"], v["unflagged_within_target"], v["unflagged"]) for k, v in res.items()
                     if isinstance(v, dict) and "covered" in v}, f"{wall:.1f} s", flush=True)
        write_json(path, out)  # after every mode: a run cut short keeps what it measured
    print(f"wrote {path}")
    chart(out, path.with_suffix(".png"))
    return 0


def rechart(path: Path) -> int:
    """Each mode of ``path`` evaluated again from its ``_cases.npz`` (the same rules as a run), the
    JSON rewritten with the new fields and the chart redrawn."""
    import json

    import xarray as xr

    out = json.loads(path.read_text())
    with np.load(path.with_name(path.stem + "_cases.npz")) as z:
        arrays = {k: z[k] for k in z.files}
    ref = {k.split("/", 1)[1]: v for k, v in arrays.items() if k.startswith("reference/")}
    for mode, res in out["modes"].items():
        data = {k.split("/", 1)[1]: v for k, v in arrays.items() if k.startswith(mode + "/")}
        ds = xr.Dataset({k: (("case",) if v.ndim == 1 else ("case", "prism"), v) for k, v in data.items()})
        res.update(evaluate(ds, ref, res["target"]))
    out["reevaluated_from_cases"] = True
    write_json(path, out)
    chart(out, path.with_suffix(".png"))
    return 0


def chart(out: dict, path: Path) -> None:
    """Work against precision: each mode's stepping seconds against the largest (filled), the 95th
    percentile (open) and the median (small) relative error of its unflagged measures (against the
    fp64 dt/4 reference), over amplitude, speed, width and width_10."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    for i, (mode, r) in enumerate(out["modes"].items()):
        c, x = f"C{i}", r["stepping_seconds"]
        worst = max(r[k]["unflagged_worst_relative_error"] for k in MEASURES[:4])
        ax.scatter(x, worst, marker="o", color=c)
        ax.annotate(mode, (x, worst), textcoords="offset points", xytext=(5, 3))
        if r["amplitude"].get("unflagged_p95_relative_error") is not None:
            p95 = max(r[k]["unflagged_p95_relative_error"] for k in MEASURES[:4])
            med = max(r[k]["unflagged_median_relative_error"] for k in MEASURES[:4])
            ax.scatter(x, p95, marker="o", facecolors="none", edgecolors=c)
            ax.scatter(x, med, marker=".", color=c)
            ax.plot([x, x], [med, worst], color=c, lw=0.8)
    ax.axhline(out["modes"][next(iter(out["modes"]))]["target"], color="k", lw=0.8, ls="--", label="accuracy target")
    ax.set(xscale="log", yscale="log", xlabel="stepping [s] (runs, twins and fp64 reruns)",
           ylabel="relative error of unflagged measures\n(largest, 95th percentile, median)",
           title=f"{out['set']} on {out['meta']['device_name']}")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    print(f"wrote {path}")


if __name__ == "__main__":
    raise SystemExit(main())
