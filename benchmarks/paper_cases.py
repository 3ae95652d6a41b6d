"""Run the paper's 12 cases (FB/RB x p in {0, 0.002} x three v0) as one batch; save strain histories.

    python -m benchmarks.paper_cases --device cpu --precision fp64 --out benchmarks/results
    python -m benchmarks.paper_cases --compare A.npz B.npz      # e.g. CPU fp64 against CUDA fp64
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import sys

import numpy as np

from benchmarks.common import code_hash, git_commit

PAPER_CASES = {
    "base_rigidity": np.array([0.0] * 6 + [1.0] * 6),
    "prestrain": np.array(([0.0] * 3 + [0.002] * 3) * 2),
    "v0": np.array([0.001, 0.002, 0.005, 0.1, 0.125, 0.15] * 2),
}


def run(device, precision, method, t_end, out, fused="auto"):
    import warp as wp

    from warp_tensegrity import ColumnConfig, RunSettings, simulate_batch
    from warp_tensegrity.measure import measure_pulse

    cfg = ColumnConfig()
    s = RunSettings(t_end=t_end, output_interval=0.01, device=device, precision=precision, method=method,
                    fused=fused)
    r = simulate_batch(cfg, PAPER_CASES, s, progress=lambda d, n, f: print(f"\r{d}/{n} steps, {f} failed", end="", file=sys.stderr))
    print(file=sys.stderr)
    m = measure_pulse(r.strain, r.time, cfg.height)
    tag = f"paper_cases_{r.device.replace(':', '')}_{precision}_{method}" + (
        "" if fused == "auto" else "_lanes" if fused == "lanes" else "_fused" if fused else "_staged")
    np.savez_compressed(os.path.join(out, tag + ".npz"), time=r.time, strain=r.strain.astype(np.float64),
                        kinetic=r.kinetic_energy, elastic=r.elastic_energy, **{k: v for k, v in PAPER_CASES.items()})
    summary = {
        "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "commit": git_commit(), "code_sha256": code_hash(), "warp": wp.config.version, "device": r.device, "device_name": r.device_name,
        "precision": precision, "method": method, "dt": r.dt, "dt_limit": r.dt_limit, "n_steps": r.n_steps,
        "t_end": t_end, "wall_time_s": r.wall_time, "n_columns": r.n_columns,
        "step_path": r.info.get("step_path"),
        "cases": [
            {"base": "FB" if b == 0 else "RB", "prestrain": float(p), "v0": float(v),
             "status": int(r.status[i]), "bar_length_error": float(r.bar_length_error[i]),
             "energy_error": float(r.energy_error[i]), "amplitude": float(m["amplitude"][i]),
             "speed": float(m["speed"][i]), "width_fwhm": float(m["width_fwhm"][i])}
            for i, (b, p, v) in enumerate(zip(PAPER_CASES["base_rigidity"], PAPER_CASES["prestrain"], PAPER_CASES["v0"]))
        ],
    }
    with open(os.path.join(out, tag + ".json"), "w") as f:
        json.dump(summary, f, indent=1)
    print(json.dumps({k: v for k, v in summary.items() if k != "cases"}, indent=1))
    for c in summary["cases"]:
        print(c)


def compare(a_path, b_path, out):
    a, b = np.load(a_path), np.load(b_path)
    d = np.abs(a["strain"] - b["strain"])
    scale = np.abs(a["strain"]).max(axis=(1, 2))
    res = {
        "a": os.path.basename(a_path), "b": os.path.basename(b_path),
        "max_abs_strain_difference_per_case": d.max(axis=(1, 2)).tolist(),
        "max_relative_strain_difference_per_case": (d.max(axis=(1, 2)) / scale).tolist(),
        "max_relative_strain_difference": float((d.max(axis=(1, 2)) / scale).max()),
    }
    print(json.dumps(res, indent=1))
    if out:
        with open(out, "w") as f:
            json.dump(res, f, indent=1)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--device", default=None)
    ap.add_argument("--precision", default="fp64", choices=["fp32", "fp64"])
    ap.add_argument("--method", default="rattle")
    ap.add_argument("--t-end", type=float, default=10.0)
    ap.add_argument("--out", default="benchmarks/results")
    ap.add_argument("--fused", default="auto", choices=["auto", "true", "false", "lanes"],
                    help="step path: auto (the engine's choice), true (fused), false (staged), lanes (warp per column)")
    ap.add_argument("--compare", nargs=2, metavar=("A", "B"))
    ap.add_argument("--compare-out", default=None)
    args = ap.parse_args(argv)
    if args.compare:
        compare(*args.compare, args.compare_out)
        return
    os.makedirs(args.out, exist_ok=True)
    run(args.device, args.precision, args.method, args.t_end, args.out,
        fused={"auto": "auto", "true": True, "false": False, "lanes": "lanes"}[args.fused])


if __name__ == "__main__":
    main()
