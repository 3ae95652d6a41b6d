"""The lane step's speed switches against the lane step without them, on any device (issue 33 item 2):
``mixed`` (fp64 columns with an fp32 factor, fp64 residuals and refinement), ``a_mem`` (the
accelerations in memory between the forces and the next half kick) and ``fast`` (fp32: on CUDA fast
math with the bar-length check's fast-math form against IEEE and the plain check; on the CPU, where
fast math does nothing, the check's form alone). Per batch: the largest relative
difference of the strain record and the final state per column, Newton's iteration count per column
(max over the run) and the bar errors; fp64 switches against the staged kernels as well.

Batches: the paper's 12 cases (50 prisms, FB/RB x p x v0), lanes_check's (50 prisms, beta 0 / 0.5 /
0.9 / 1, p 0 / 0.002, v0 0.05 / 0.1 / 0.15, right and alternating) and test_lanes' MIXED / RIGID.

    python -m benchmarks.lanes_mixed_check --device cpu --t-end 0.05 --out /tmp/mixed.json
"""

import argparse
import dataclasses
import time

import numpy as np

from . import common

SWITCHES = {"mixed": "LANE_MIXED", "a_mem": "LANE_A_MEM", "fast": None}


def batches(quick: bool):
    from .paper_cases import PAPER_CASES

    p, v0, beta = np.meshgrid([0.0, 0.002], [0.05, 0.1, 0.15], [0.0, 0.5, 0.9, 1.0], indexing="ij")
    check = {"prestrain": p.ravel(), "v0": v0.ravel(), "base_rigidity": beta.ravel()}
    out = [("paper_12", 50, "right", {k: np.asarray(v) for k, v in PAPER_CASES.items()}),
           ("lanes_check_right", 50, "right", check), ("lanes_check_alternating", 50, "alternating", check),
           ("test_lanes_RIGID_7", 7, "RRLRLLR", {"prestrain": [0.0, 0.002, 0.002, 0.0, 0.002],
                                                 "v0": [0.005, 0.1, 0.05, 0.005, 0.1],
                                                 "base_rigidity": [0.0, 0.5, 0.95, 1.0, 1.0]})]
    return out[:1] + out[3:] if quick else out


def run(device, precision, path, cfg, params, t_end, knobs=None, fast=False):
    """One run with the lane module's switches ``knobs`` ({dict name: value}) set for ``precision``;
    returns (result, per-column Newton iterations)."""
    from warp_tensegrity import RunSettings, decide, simulate_batch
    from warp_tensegrity.sim import integrate
    from warp_tensegrity.sim.lanes import lanes
    from warp_tensegrity.types import Path as LaunchPath

    seen = []

    class Seen(integrate.Integrator):
        def run(self, *a, **k):
            seen.append(self)
            return super().run(*a, **k)

    saved = {name: dict(getattr(lanes, name)) for name in (knobs or {})}
    real_make, integ_class = lanes.make_lane_kernel, integrate.Integrator
    try:
        for name, value in (knobs or {}).items():
            getattr(lanes, name)[precision] = value
        if fast:  # the fast-math form of the bar check (for the CPU, where the approximations do not exist)
            lanes.make_lane_kernel = lambda real, P, G, mr, rigid, fm, *rest: real_make(real, P, G, mr, rigid, True, *rest)
        integrate.Integrator = Seen
        s = RunSettings(t_end=t_end, precision=precision, device=device, truncate=False, output_interval=0.01)
        plan = dataclasses.replace(decide(cfg, params, s), path=LaunchPath(path))
        res = simulate_batch(cfg, params, plan=plan)
    finally:
        for name, d in saved.items():
            getattr(lanes, name).update(d)
        lanes.make_lane_kernel, integrate.Integrator = real_make, integ_class
    return res, seen[0].data.iters.numpy().copy()


def rel(a, b):
    return np.abs(a - b).max(axis=(1, 2)) / np.abs(b).max(axis=(1, 2))


def compare(a, b):
    return {name: float(rel(getattr(a, name), getattr(b, name)).max())
            for name in ("strain", "final_displacement", "final_velocity")}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--device", default="cuda:0")
    ap.add_argument("--out", required=True)
    ap.add_argument("--t-end", dest="t_end", type=float, default=0.2)
    ap.add_argument("--quick", action="store_true", help="the paper's 12 cases and the 7-prism batch only")
    ap.add_argument("--switch", choices=sorted(SWITCHES), nargs="+", default=["mixed", "a_mem", "fast"])
    a = ap.parse_args(argv)
    import warp as wp

    from warp_tensegrity import ColumnConfig
    from warp_tensegrity.sim.lanes import lanes

    wp.config.quiet = True
    wp.init()
    doc = {"kind": "lanes_mixed_check", "meta": common.run_metadata(wp.get_device(a.device)), "t_end": a.t_end,
           "cases": []}
    for name, n, hand, params in batches(a.quick):
        cfg = ColumnConfig(n_prisms=n, handedness=hand)
        for sw in a.switch:
            dict_name = SWITCHES[sw]
            if dict_name is not None and not hasattr(lanes, dict_name):
                continue
            for prec in (("fp64",) if sw == "mixed" else ("fp32",) if sw == "fast" else ("fp64", "fp32")):
                t0 = time.perf_counter()
                if sw == "fast":  # CUDA: fast math and the check's form against neither; CPU: the form only
                    both = {"LANE_FAST_MATH": True, "LANE_FAST_MATH_RIGID": True}
                    on, it_on = run(a.device, prec, "lanes", cfg, params, a.t_end, both, fast=a.device == "cpu")
                    off, it_off = run(a.device, prec, "lanes", cfg, params, a.t_end, dict.fromkeys(both, False))
                else:
                    on, it_on = run(a.device, prec, "lanes", cfg, params, a.t_end, {dict_name: True})
                    off, it_off = run(a.device, prec, "lanes", cfg, params, a.t_end, {dict_name: False})
                case = {"batch": name, "switch": sw, "precision": prec, "columns": len(it_on),
                        "on_vs_off": compare(on, off),
                        "newton_iters_on": it_on.tolist(), "newton_iters_off": it_off.tolist(),
                        "newton_iters_equal": bool(np.array_equal(it_on, it_off)),
                        "bar_error_max_on": float(on.bar_length_error.max()),
                        "bar_error_max_off": float(off.bar_length_error.max()),
                        "status_equal": bool(np.array_equal(on.status, off.status))}
                if prec == "fp64":
                    ref, _ = run(a.device, prec, "staged", cfg, params, a.t_end)
                    case["on_vs_staged"] = compare(on, ref)
                    case["off_vs_staged"] = compare(off, ref)
                case["wall_s"] = time.perf_counter() - t0
                doc["cases"].append(case)
                print({k: v for k, v in case.items() if not k.startswith("newton_iters_o")}, flush=True)
    common.write_json(a.out, doc)


if __name__ == "__main__":
    main()
