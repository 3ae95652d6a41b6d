"""Launch shape of the warp-per-column step (kernels/lanes.py) on one GPU: register cap per thread,
threads per block and steps per launch, with registers, spills and rate at B = 1,536 and 16,384.

    python -m benchmarks.lanes_tuning --device cuda:0 --out $OUT/lanes_tuning_h200.json
"""

import argparse
import itertools

from . import common
from .lanes_check import lane_resources


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--device", default="cuda:0")
    ap.add_argument("--out", required=True)
    ap.add_argument("--regs", type=int, nargs="+", default=[0, 128, 168, 200])
    ap.add_argument("--block-dims", dest="block_dims", type=int, nargs="+", default=[64])
    ap.add_argument("--steps", type=int, nargs="+", default=[64])
    ap.add_argument("--batches", type=int, nargs="+", default=[1536, 16384])
    ap.add_argument("--precisions", nargs="+", default=["fp32", "fp64"])
    ap.add_argument("--target-s", dest="target_s", type=float, default=0.5)
    a = ap.parse_args(argv)
    import warp as wp

    from warp_tensegrity.kernels import lanes

    wp.config.quiet = True
    wp.init()
    device = wp.get_device(a.device)
    doc = {"kind": "lanes_tuning", "meta": common.run_metadata(device), "points": []}
    small = common.build_base_batch(50, 0.0, common.BASE_COLUMNS)
    dt = common.rattle_dt(small)
    for prec, regs, bd, steps in itertools.product(a.precisions, a.regs, a.block_dims, a.steps):
        lanes.LANE_MAX_REGISTERS[prec] = regs or None
        lanes.LANE_BLOCK_DIM = bd
        lanes.LANE_STEPS = steps
        for B in a.batches:
            try:
                pt = common.time_batch(common.tile_batch(small, B), "FB", 50, prec, device, target_s=a.target_s,
                                       reps=2, dt=dt, diag_steps=0, path="lanes")
                p = {"precision": prec, "max_registers": regs or None, "block_dim": bd, "steps_per_launch": steps,
                     "B": B, "column_steps_per_s": pt.column_steps_per_s}
            except Exception as exc:  # noqa: BLE001
                p = {"precision": prec, "max_registers": regs or None, "block_dim": bd, "steps_per_launch": steps,
                     "B": B, "error": repr(exc)}
            doc["points"].append(p)
            print(p, flush=True)
        try:
            from warp_tensegrity import RunSettings
            from warp_tensegrity.integrate import Integrator
            from warp_tensegrity.types import Path as LaunchPath

            s = RunSettings(t_end=dt * 10, dt=dt, precision=prec, device=a.device, record_strain=False)
            integ = Integrator(common.tile_batch(small, 64), s, dt, 100, 2, path=LaunchPath.LANES)
            integ.load_kernels()
            doc["points"][-1]["resources"] = lane_resources(integ)
            print(doc["points"][-1]["resources"], flush=True)
        except Exception as exc:  # noqa: BLE001
            print("resources:", repr(exc), flush=True)
        common.write_json(a.out, doc)


if __name__ == "__main__":
    main()
