"""The warp-per-column step (sim/lanes/lanes.py) on one GPU: agreement with the staged kernels (an
independent implementation of the same RATTLE) and the kernel's resources from the CUDA driver.

* fp64, 50 prisms, flexible and elastic bases (beta 0, 0.5, 0.9), right and alternating handedness,
  the paper's prestrains and impact speeds, to t = 1 s: max |strain difference| / peak per column;
* fp32: the largest relative bar-length error over every step;
* registers, local (spill) bytes and resident warps per SM of each compiled variant.

    python -m benchmarks.lanes_check --device cuda:0 --out $OUT/lanes_check_h100.json
"""

import argparse
import time

import numpy as np

from . import common


def lane_resources(integ) -> dict:
    """Registers, local bytes and resident warps per SM of the loaded lane kernel (CUDA driver)."""
    fk = integ.stepper
    out = common.kernel_resources(fk.kernels.lane_steps, integ.device, fk.block_dim)
    out["levels_per_lane"], out["lanes_per_column"] = fk.P, fk.G
    return out


def run(device: str, precision: str, path: str, cfg, params, t_end: float):
    import dataclasses

    from warp_tensegrity import RunSettings, decide, simulate_batch
    from warp_tensegrity.types import Path as LaunchPath

    s = RunSettings(t_end=t_end, precision=precision, device=device, truncate=False, output_interval=0.01)
    plan = dataclasses.replace(decide(cfg, params, s), path=LaunchPath(path))  # the path forced
    return simulate_batch(cfg, params, plan=plan)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--device", default="cuda:0")
    ap.add_argument("--out", required=True)
    ap.add_argument("--t-end", dest="t_end", type=float, default=1.0)
    ap.add_argument("--prisms", type=int, nargs="+", default=[50, 7, 100])
    a = ap.parse_args(argv)
    import warp as wp

    from warp_tensegrity import ColumnConfig
    from warp_tensegrity.sim.integrate import Integrator
    from warp_tensegrity.scene.batch import column_batch

    wp.config.quiet = True
    wp.init()
    if a.device == "cpu":
        wp.config.enable_cpu_blocks = True  # lane emulation (a check of the script; no resources there)
    doc = {"kind": "lanes_check", "meta": common.run_metadata(wp.get_device(a.device)), "cases": [], "resources": []}
    p, v0, beta = np.meshgrid([0.0, 0.002], [0.05, 0.1, 0.15], [0.0, 0.5, 0.9, 1.0], indexing="ij")
    from warp_tensegrity.sim.lanes.lane_rigid import MAX_RIGID_LEVELS_PER_LANE

    for n in a.prisms:
        keep = np.ones(p.size, bool) if n <= 32 * MAX_RIGID_LEVELS_PER_LANE else beta.ravel() < 1.0
        params = {"prestrain": p.ravel()[keep], "v0": v0.ravel()[keep], "base_rigidity": beta.ravel()[keep]}
        for hand in ("right", "alternating"):
            cfg = ColumnConfig(n_prisms=n, handedness=hand)
            t0 = time.perf_counter()
            ref = run(a.device, "fp64", "staged", cfg, params, a.t_end)
            lan = run(a.device, "fp64", "lanes", cfg, params, a.t_end)
            l32 = run(a.device, "fp32", "lanes", cfg, params, a.t_end)
            f32 = run(a.device, "fp32", "fused", cfg, params, a.t_end)  # the fp32 yardstick: another fp32 path
            f64 = run(a.device, "fp64", "fused", cfg, params, a.t_end)  # the fp64 one: block per column
            peak = np.abs(ref.strain).max(axis=(1, 2))
            rel = np.abs(lan.strain - ref.strain).max(axis=(1, 2)) / peak
            rel32 = np.abs(l32.strain - ref.strain).max(axis=(1, 2)) / peak
            relf32 = np.abs(f32.strain - ref.strain).max(axis=(1, 2)) / peak
            case = {"n_prisms": n, "handedness": hand, "t_end": a.t_end, "columns": int(keep.sum()),
                    "rigid_columns": int((params["base_rigidity"] >= 1).sum()),
                    "fp64_max_rel_strain_vs_staged": float(rel.max()),
                    "fp64_bar_error_max": float(lan.bar_length_error.max()),
                    "fp64_fused_max_rel_strain_vs_staged": float((np.abs(f64.strain - ref.strain).max(axis=(1, 2))
                                                                  / peak).max()),
                    "fp32_max_rel_strain_vs_staged_fp64": float(rel32.max()),
                    "fp32_bar_error_max": float(l32.bar_length_error.max()),
                    "fp32_fused_max_rel_strain_vs_staged_fp64": float(relf32.max()),
                    "status_ok": bool(np.all(ref.status == 0) and np.all(lan.status == 0) and np.all(l32.status == 0)),
                    "wall_s": time.perf_counter() - t0}
            doc["cases"].append(case)
            print(case, flush=True)
        for prec in ("fp32", "fp64") if a.device != "cpu" else ():
            batch = column_batch(ColumnConfig(n_prisms=n), {"prestrain": [0.002] * 64, "v0": [0.1] * 64})
            from warp_tensegrity import RunSettings
            from warp_tensegrity.types import Path as LaunchPath

            s = RunSettings(t_end=0.01, dt=1e-4, precision=prec, device=a.device, record_strain=False)
            integ = Integrator(batch, s, 1e-4, 100, 2, path=LaunchPath.LANES)
            integ.load_kernels()
            res = {"n_prisms": n, "precision": prec, **lane_resources(integ)}
            doc["resources"].append(res)
            print(res, flush=True)
    common.write_json(a.out, doc)


if __name__ == "__main__":
    main()
