"""Launch shape of the fused step (sim/block/kernels.py) on one GPU: lanes per column block and where
the column's rows live (block shared memory or per-column global rows), with the kernel's
registers, spills, static shared memory and resident blocks per SM read from the CUDA driver.

    python -m benchmarks.coop_tuning --device cuda:0 --out benchmarks/results/coop_tuning_h100.json
"""

import argparse
import sys
import time
from pathlib import Path

from . import common

VARIANTS = {  # name: (lanes per block, shared budget [bytes], node rows shared)
    "w32_shared": (32, 46 * 1024, True),
    "w32_solver_shared": (32, 46 * 1024, False),
    "w32_global": (32, 0, False),
    "w64_shared": (64, 46 * 1024, True),
    "w64_global": (64, 0, False),
}


def kernel_resources(integ) -> dict:
    """Resources of the fused kernel as loaded for this Integrator (:func:`common.kernel_resources`)."""
    return common.kernel_resources(integ.stepper.kernels.rattle_columns, integ.device, integ.stepper.block_dim)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--device", default="cuda:0")
    ap.add_argument("--out", default=None)
    ap.add_argument("--batches", type=int, nargs="+", default=[16384, 65536])
    ap.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=list(VARIANTS))
    ap.add_argument("--precisions", nargs="+", default=["fp32", "fp64"])
    ap.add_argument("--bases", nargs="+", default=["FB", "RB"])
    ap.add_argument("--target-s", dest="target_s", type=float, default=0.25)
    a = ap.parse_args(argv)
    import warp as wp

    import warp_tensegrity.sim.block.kernels as F
    from warp_tensegrity import RunSettings
    from warp_tensegrity.sim.block import step as simulate
    from warp_tensegrity.sim.integrate import Integrator
    from warp_tensegrity.types import Path as LaunchPath

    wp.config.quiet = True
    wp.config.log_level = wp.LOG_WARNING
    wp.init()
    device = wp.get_device(a.device)
    tag = common.device_kind(device.name)
    out = Path(a.out) if a.out else common.RESULTS / f"coop_tuning_{tag}.json"
    doc = {"kind": "coop_tuning", "meta": common.run_metadata(device), "variants": VARIANTS, "points": []}
    defaults = (simulate.FUSED_BLOCK_DIM, F.SHARED_BYTES_MAX, F.SHARED_NODES)
    t_all = time.perf_counter()
    for base in a.bases:
        small = common.build_base_batch(50, {"FB": 0.0, "RB": 1.0}[base], common.BASE_COLUMNS)
        dt = common.rattle_dt(small)
        for prec in a.precisions:
            for name in a.variants:
                bd, budget, nodes = VARIANTS[name]
                simulate.FUSED_BLOCK_DIM, F.SHARED_BYTES_MAX, F.SHARED_NODES = bd, budget, nodes
                res = None
                for B in a.batches:
                    batch = common.tile_batch(small, B)
                    try:
                        p = common.time_batch(batch, base, 50, prec, device, target_s=a.target_s, reps=3,
                                              diag_steps=0, dt=dt, path="fused").as_dict()
                        if res is None:
                            s = RunSettings(t_end=dt, dt=dt, precision=prec, device=a.device, fused=True)
                            integ = Integrator(common.tile_batch(small, 64), s, dt, 1, 2, path=LaunchPath.FUSED)
                            integ.load_kernels()
                            res = kernel_resources(integ) if device.is_cuda else {}
                            res["rows"] = integ.stepper.description
                        p.update(variant=name, block_dim=bd, **res)
                        print(f"[coop] {base} {prec} {name} B={B}: {p['column_steps_per_s']:.4g} col-steps/s "
                              f"{res}", flush=True)
                    except Exception as exc:  # noqa: BLE001
                        p = {"base": base, "precision": prec, "B": B, "variant": name, "error": repr(exc)}
                        print(f"[coop] ERROR {p}", flush=True)
                    doc["points"].append(p)
                    common.write_json(out, doc)
    simulate.FUSED_BLOCK_DIM, F.SHARED_BYTES_MAX, F.SHARED_NODES = defaults
    print(f"[coop] wrote {out} in {time.perf_counter() - t_all:.0f} s", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
