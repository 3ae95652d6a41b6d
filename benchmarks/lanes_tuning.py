"""Launch and compile options of the warp-per-column step (sim/lanes/lanes.py) on one GPU: register
cap per thread, threads per block, steps per launch, CUDA fast math (fp32) and register spills to
shared memory, with the kernel's registers and spills, its rate at B = 1,536 and 16,384, and (fast
math) the largest bar-length error of 16 paper-like columns to t = 0.5 s.

    python -m benchmarks.lanes_tuning --device cuda:0 --out $OUT/lanes_tuning_h200.json
"""

import argparse
import itertools

import numpy as np

from . import common
from .lanes_check import lane_resources


def _variant(lanes, prec, regs, bd, steps, fm, sp):
    lanes.LANE_MAX_REGISTERS[prec] = regs or None
    lanes.LANE_FAST_MATH[prec] = bool(fm)
    lanes.LANE_SMEM_SPILL[prec] = bool(sp)
    lanes.LANE_BLOCK_DIM = bd
    lanes.LANE_STEPS = steps
    return {"precision": prec, "max_registers": regs or None, "block_dim": bd, "steps_per_launch": steps,
            "fast_math": bool(fm), "smem_spill": bool(sp)}


def _bar_error(device: str, prec: str, base: str) -> float:
    """Largest relative bar-length error of 16 columns (p, v0 as the paper's; this base) to t = 0.5 s."""
    from warp_tensegrity import ColumnConfig, RunSettings, simulate_batch

    params = {"prestrain": np.repeat([0.0, 0.002], 8), "v0": np.tile(np.linspace(0.05, 0.15, 8), 2),
              "base_rigidity": 1.0 if base == "RB" else 0.0}
    s = RunSettings(t_end=0.5, precision=prec, device=device, fused="lanes", record_strain=False)
    return float(simulate_batch(ColumnConfig(), params, s).bar_length_error.max())


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--device", default="cuda:0")
    ap.add_argument("--out", required=True)
    ap.add_argument("--regs", type=int, nargs="+", default=[0])
    ap.add_argument("--block-dims", dest="block_dims", type=int, nargs="+", default=[64])
    ap.add_argument("--steps", type=int, nargs="+", default=[64])
    ap.add_argument("--fast-math", dest="fast_math", type=int, nargs="+", default=[0])
    ap.add_argument("--smem-spill", dest="smem_spill", type=int, nargs="+", default=[0])
    ap.add_argument("--bases", nargs="+", default=["FB"])
    ap.add_argument("--batches", type=int, nargs="+", default=[1536, 16384])
    ap.add_argument("--precisions", nargs="+", default=["fp32", "fp64"])
    ap.add_argument("--target-s", dest="target_s", type=float, default=0.5)
    a = ap.parse_args(argv)
    import warp as wp

    from warp_tensegrity import RunSettings
    from warp_tensegrity.sim.integrate import Integrator
    from warp_tensegrity.sim.lanes import lanes
    from warp_tensegrity.types import Path as LaunchPath

    wp.config.quiet = True
    wp.init()
    device = wp.get_device(a.device)
    doc = {"kind": "lanes_tuning", "meta": common.run_metadata(device), "points": []}
    for base in a.bases:
        small = common.build_base_batch(50, {"FB": 0.0, "RB": 1.0}[base], common.BASE_COLUMNS)
        dt = common.rattle_dt(small)
        for prec, regs, bd, steps, fm, sp in itertools.product(a.precisions, a.regs, a.block_dims, a.steps,
                                                               a.fast_math, a.smem_spill):
            var = {"base": base, **_variant(lanes, prec, regs, bd, steps, fm, sp)}
            for B in a.batches:
                try:
                    pt = common.time_batch(common.tile_batch(small, B), base, 50, prec, device, target_s=a.target_s,
                                           reps=2, dt=dt, diag_steps=0, path="lanes")
                    p = {**var, "B": B, "column_steps_per_s": pt.column_steps_per_s}
                except Exception as exc:  # noqa: BLE001
                    p = {**var, "B": B, "error": repr(exc)}
                doc["points"].append(p)
                print(p, flush=True)
            try:
                s = RunSettings(t_end=dt * 10, dt=dt, precision=prec, device=a.device, record_strain=False)
                integ = Integrator(common.tile_batch(small, 64), s, dt, 100, 2, path=LaunchPath.LANES)
                integ.load_kernels()
                res = {**var, "resources": lane_resources(integ)}
                if fm:
                    res["max_bar_error_t0.5"] = _bar_error(a.device, prec, base)
                doc["points"].append(res)
                print(res, flush=True)
            except Exception as exc:  # noqa: BLE001
                print("resources:", repr(exc), flush=True)
            common.write_json(a.out, doc)


if __name__ == "__main__":
    main()
