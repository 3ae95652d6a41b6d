"""The fused RATTLE step against the staged one on one device: agreement, then launch shape.

1. Agreement: the paper's 12 cases on 50-prism columns (FB and RB, p = 0 and 0.002) for 1 s,
   fused and staged, fp64 and fp32. Reports the largest strain difference relative to the
   largest strain (before the pulse reflects, so chaos after reflection does not enter), the
   bar-length errors and energy errors of both.
2. Launch shape: column-steps/s of the fused step at B = 4,096 and 65,536 for threads per
   column block (32, 64, 128) and steps per launch (1, 4, 16).

Usage::

    python -m benchmarks.fused_tuning --device cuda:0 --out-dir benchmarks/results
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from . import common

CASES = {  # sweeps/paper_2017.toml
    "prestrain": [0.0] * 6 + [0.002] * 6,
    "v0": [0.001, 0.002, 0.005] * 2 + [0.1, 0.125, 0.15] * 2,
    "base_rigidity": ([0.0] * 3 + [1.0] * 3) * 2,
}


def agreement(device: str) -> list[dict]:
    from warp_tensegrity import ColumnConfig, RunSettings, simulate_batch

    cfg = ColumnConfig(n_prisms=50)
    rows = []
    for prec in ("fp64", "fp32"):
        runs = {}
        for path in ("staged", "fused"):
            s = RunSettings(t_end=1.0, precision=prec, device=device, fused=path == "fused", truncate=False,
                            output_interval=0.01)
            t = time.perf_counter()
            runs[path] = simulate_batch(cfg, CASES, s)
            runs[path].info["total_s"] = time.perf_counter() - t
        a, b = runs["staged"], runs["fused"]
        scale = np.nanmax(np.abs(a.strain), axis=(1, 2))
        diff = np.nanmax(np.abs(a.strain - b.strain), axis=(1, 2)) / scale
        rows.append({
            "precision": prec, "t_end": 1.0, "dt": a.dt, "n_steps": a.n_steps,
            "max_rel_strain_difference": float(diff.max()), "per_case_rel_strain_difference": diff.tolist(),
            "bar_error_staged": float(a.bar_length_error.max()), "bar_error_fused": float(b.bar_length_error.max()),
            "energy_error_staged": float(np.nanmax(a.energy_error)), "energy_error_fused": float(np.nanmax(b.energy_error)),
            "status_staged": a.status.tolist(), "status_fused": b.status.tolist(),
            "wall_s_staged": a.wall_time, "wall_s_fused": b.wall_time,
        })
        print(f"[agreement] {prec}: max rel strain diff {diff.max():.3g}; bar err staged "
              f"{a.bar_length_error.max():.3g} fused {b.bar_length_error.max():.3g}; energy err "
              f"{np.nanmax(a.energy_error):.3g} / {np.nanmax(b.energy_error):.3g}; wall {a.wall_time:.2f} / "
              f"{b.wall_time:.2f} s", flush=True)
    return rows


def shapes(device, batches, blocks, subs, target_s: float) -> list[dict]:
    from warp_tensegrity.sim.block import step as integrate  # the block step's launch constants

    rows = []
    defaults = (integrate.FUSED_BLOCK_DIM, integrate.FUSED_STEPS)
    for base, beta in (("FB", 0.0), ("RB", 1.0)):
        small = common.build_base_batch(50, beta, common.BASE_COLUMNS)
        dt = common.rattle_dt(small)
        for prec in ("fp32", "fp64"):
            for B in batches:
                batch = common.tile_batch(small, B)
                combos = [(bd, 16) for bd in blocks] + [(blocks[0], k) for k in subs if k != 16]
                for bd, k in combos:
                    integrate.FUSED_BLOCK_DIM, integrate.FUSED_STEPS = bd, k
                    try:
                        p = common.time_batch(batch, base, 50, prec, device, target_s=target_s, reps=3,
                                              diag_steps=0, dt=dt, path="fused").as_dict()
                        p.update(block_dim=bd, steps_per_launch=k)
                        print(f"[shape] {base} {prec} B={B} block {bd} steps/launch {k}: "
                              f"{p['column_steps_per_s']:.4g} col-steps/s", flush=True)
                    except Exception as exc:  # noqa: BLE001
                        p = {"base": base, "precision": prec, "B": B, "block_dim": bd, "steps_per_launch": k,
                             "error": repr(exc)}
                        print(f"[shape] ERROR {p}", flush=True)
                    rows.append(p)
    integrate.FUSED_BLOCK_DIM, integrate.FUSED_STEPS = defaults
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--device", default="cuda:0")
    ap.add_argument("--out-dir", dest="out_dir", default=str(common.RESULTS))
    ap.add_argument("--batches", type=int, nargs="+", default=[4096, 65536])
    ap.add_argument("--blocks", type=int, nargs="+", default=[32, 64, 128])
    ap.add_argument("--subs", type=int, nargs="+", default=[1, 4, 16])
    ap.add_argument("--target-s", dest="target_s", type=float, default=0.3)
    ap.add_argument("--skip-agreement", action="store_true")
    a = ap.parse_args(argv)
    import warp as wp

    wp.config.quiet = True
    wp.config.log_level = wp.LOG_WARNING
    wp.init()
    device = wp.get_device(a.device)
    tag = "cpu" if device.is_cpu else common.device_kind(device.name)
    out = Path(a.out_dir) / f"fused_tuning_{tag}.json"
    doc = {"kind": "fused_tuning", "meta": common.run_metadata(device), "agreement": [], "shapes": []}
    if not a.skip_agreement:
        doc["agreement"] = agreement(a.device)
        common.write_json(out, doc)
    doc["shapes"] = shapes(device, a.batches, a.blocks, a.subs, a.target_s)
    common.write_json(out, doc)
    print(f"[fused_tuning] wrote {out}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
