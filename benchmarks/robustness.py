"""Divergence isolation and determinism on a device (issue 18), both step paths, fp64 and fp32.

For each (path, precision):

* run to run: the same batch twice -> every output array compared byte for byte;
* isolation: the batch with one column made to blow up (a 1 km/s impact; a cable 1e6 times
  stiffer, so the shared dt is absurd for that column alone) against the batch without it ->
  the bad column's status and fail step, and the other columns compared byte for byte;
* batch composition (what a shard size changes): the first 64 columns alone against the same
  columns inside the full batch, byte for byte.

Writes ``benchmarks/results/robustness_<device>.json`` (device name, git commit, one record per
check; a record is written as soon as it is measured, so a cut-off run keeps what it did).

    python benchmarks/robustness.py --device cuda:0 [--columns 2048] [--out DIR]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.common import RESULTS, device_tag, run_metadata, write_json  # noqa: E402

FIELDS = ("strain", "kinetic_energy", "elastic_energy", "energy_error", "bar_length_error", "status", "fail_step",
          "final_displacement", "final_velocity")


def _params(B: int, cable_EA: float) -> dict:
    rng = np.random.default_rng(18)
    return {
        "prestrain": rng.uniform(0.0, 0.002, B),
        "v0": rng.uniform(0.003, 0.05, B),
        "base_rigidity": rng.choice([0.0, 1.0], B),
        "cable_EA": np.full(B, cable_EA),
    }


def _compare(a, b, rows_a=None, rows_b=None) -> dict:
    """Per field: identical bytes?, max |difference| where not."""
    out = {}
    for f in FIELDS:
        x, y = getattr(a, f), getattr(b, f)
        if x is None or y is None:
            continue
        x = np.ascontiguousarray(np.asarray(x) if rows_a is None else np.asarray(x)[rows_a])
        y = np.ascontiguousarray(np.asarray(y) if rows_b is None else np.asarray(y)[rows_b])
        same = x.shape == y.shape and x.dtype == y.dtype and x.tobytes() == y.tobytes()
        rec = {"identical": bool(same)}
        if not same and x.shape == y.shape and x.dtype.kind == "f":
            with np.errstate(invalid="ignore"):
                rec["max_abs_diff"] = float(np.nanmax(np.abs(x - y)))
        out[f] = rec
    out["all_identical"] = all(r["identical"] for r in out.values())
    return out


def _sweep_check(spec: str, device: str, scratch: Path) -> dict:
    """The whole sweep path (plan, stepping, writer thread, Zarr store, netCDF export) on the device:
    run to run and across shard sizes, every variable byte for byte."""
    import shutil

    from warp_tensegrity.sweep import open_sweep, run_sweep

    shutil.rmtree(scratch, ignore_errors=True)
    scratch.mkdir(parents=True)
    runs, data = [], []
    for k, size in enumerate((4, 4, 8)):
        t0 = time.perf_counter()
        out = run_sweep(spec, scratch / f"run{k}.nc", device=device, shard_size=size, progress=False)
        ds = open_sweep(out).load()
        runs.append({"shard_size": size, "seconds": time.perf_counter() - t0, "device": ds.attrs.get("device")})
        data.append({k: np.ascontiguousarray(v.values).tobytes() for k, v in ds.data_vars.items()})
    same = lambda a, b: sorted(k for k in a if a[k] != b[k])  # noqa: E731
    return {"spec": spec, "runs": runs, "differing_run_to_run": same(data[0], data[1]),
            "differing_across_shard_sizes": same(data[0], data[2]),
            "identical": not same(data[0], data[1]) and not same(data[0], data[2])}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--device", default=None)
    ap.add_argument("--columns", type=int, default=2048)
    ap.add_argument("--prisms", type=int, default=20)
    ap.add_argument("--t-end", type=float, default=0.2)
    ap.add_argument("--dt", type=float, default=5e-4)
    ap.add_argument("--precisions", default="fp64,fp32")
    ap.add_argument("--paths", default="fused,staged")
    ap.add_argument("--out", default=str(RESULTS))
    ap.add_argument("--sweep", default=None, metavar="SPEC",
                    help="also run SPEC through the CLI path three times (shard sizes 4, 4, 8) on the device "
                         "and compare the stored datasets byte for byte")
    ap.add_argument("--scratch", default="/tmp/robustness_sweeps")
    args = ap.parse_args(argv)

    import warp as wp

    wp.config.quiet = True
    wp.init()
    from warp_tensegrity.engine import simulate_batch
    from warp_tensegrity.policy.decide import prisms_to_simulate
    from warp_tensegrity.runtime import default_device
    from warp_tensegrity.scene.columns import ColumnConfig
    from warp_tensegrity.options import RunSettings
    from warp_tensegrity.types import STATUS_MEANINGS

    device = args.device or default_device()
    cfg = ColumnConfig(n_prisms=args.prisms)
    B = args.columns
    good = _params(B, cfg.cable_EA)
    bad_at = {"v0": 7, "stiffness": B // 2 + 3}
    bad = {}
    for kind, at in bad_at.items():
        p = {k: v.copy() for k, v in good.items()}
        if kind == "v0":
            p["v0"][at] = 1000.0
        else:
            p["cable_EA"][at] *= 1e6
        bad[kind] = p
    # the good columns: the full batch without the bad one (same order)
    out = Path(args.out) / f"robustness_{device_tag(device)}.json"
    doc = {"benchmark": "robustness", **run_metadata(wp.get_device(device)), "device": device, "columns": B, "prisms": args.prisms,
           "t_end_s": args.t_end, "dt_s": args.dt, "bad_columns": bad_at, "records": []}
    try:
        doc["device_name"] = wp.get_device(device).name
    except Exception:
        pass
    write_json(out, doc)
    t_all = time.perf_counter()
    for precision in args.precisions.split(","):
        for path in args.paths.split(","):
            s = RunSettings(t_end=args.t_end, dt=args.dt, output_interval=args.t_end / 20, device=device,
                            precision=precision, allow_unstable_dt=True, fused=path == "fused")
            n_sim = max(prisms_to_simulate(cfg, p, s) for p in bad.values())
            t0 = time.perf_counter()
            r1 = simulate_batch(cfg, good, s, prisms_simulated=n_sim)
            r2 = simulate_batch(cfg, good, s, prisms_simulated=n_sim)
            rec = {"path": path, "precision": precision, "prisms_simulated": n_sim,
                   "run_to_run": _compare(r1, r2), "graph_steps": r1.info.get("graph_steps"),
                   "wall_time_s": r1.wall_time}
            sub = simulate_batch(cfg, {k: v[:64] for k, v in good.items()}, s, prisms_simulated=n_sim)
            rec["first_64_alone_vs_in_batch"] = _compare(sub, r1, rows_b=slice(0, 64))
            rec["isolation"] = {}
            for kind, at in bad_at.items():
                rb = simulate_batch(cfg, bad[kind], s, prisms_simulated=n_sim)
                others = np.array([i for i in range(B) if i != at])
                ref = np.array([i for i in range(B) if i != at])
                iso = _compare(rb, r1, rows_a=others, rows_b=ref)
                # the good columns at the bad one's place differ only in that one column: compare the rest
                iso.update({"bad_status": int(rb.status[at]), "bad_reason": STATUS_MEANINGS.get(int(rb.status[at])),
                            "bad_fail_step": int(rb.fail_step[at]),
                            "other_columns_failed": int(np.count_nonzero(rb.status[others]))})
                rec["isolation"][kind] = iso
            rec["seconds"] = time.perf_counter() - t0
            doc["records"].append(rec)
            doc["seconds"] = time.perf_counter() - t_all
            write_json(out, doc)
            print(f"{path} {precision}: run-to-run identical {rec['run_to_run']['all_identical']}, "
                  f"subset identical {rec['first_64_alone_vs_in_batch']['all_identical']}, isolation "
                  + ", ".join(f"{k}: {v['all_identical']} (bad status {v['bad_status']} at step {v['bad_fail_step']})"
                              for k, v in rec["isolation"].items()), flush=True)
    if args.sweep:
        doc["sweep"] = _sweep_check(args.sweep, device, Path(args.scratch))
        write_json(out, doc)
        print("sweep:", {k: v for k, v in doc["sweep"].items() if k != "runs"}, flush=True)
    doc["run_to_run_identical"] = all(r["run_to_run"]["all_identical"] for r in doc["records"])
    doc["isolation_identical"] = all(v["all_identical"] for r in doc["records"] for v in r["isolation"].values())
    doc["composition_identical"] = all(r["first_64_alone_vs_in_batch"]["all_identical"] for r in doc["records"])
    write_json(out, doc)
    print(out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
