"""Error and cost of the default run (no dt, no accuracy) and of ``accuracy = 1e-3`` against a
converged solution, on the paper's FB and RB columns (50 prisms, p = 0.002, v0 = 0.1 m/s), CPU.

Reference: RATTLE fp64 at dt_safety = 0.01 (error model 0.59 * 0.01^2 = 6e-5), checked against
dt_safety = 0.02 (its error must be ~4x the reference's).
Errors: relative amplitude and time-of-flight speed; strain history: max and RMS over
(time, prism) of |eps - eps_ref| divided by max |eps_ref|, on the common output times.

    python -m benchmarks.default_accuracy          # ~3-5 min on 2 CPU cores
Writes benchmarks/results/default_accuracy_cpu.json.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import warp as wp

from benchmarks.common import run_metadata, write_json
from warp_tensegrity import ColumnConfig, RunSettings, simulate_batch
from warp_tensegrity.measure import measure_pulse

OUT = Path(__file__).resolve().parent / "results" / "default_accuracy_cpu.json"
CASES = {"FB": (0.0, "rigid_members"), "RB": (1.0, "rigid_members"), "FB end_twist": (0.0, "end_twist")}
"""name: (base rigidity, impact); the paper's own FB impact too (RB: the two impacts are the same)."""
T_END = 1.6  # s: both pulses cross the measurement window (prisms 44 -> 5)
INTERVAL = 0.002  # s


def run(case: tuple, **kw) -> dict:
    beta, impact = case
    cfg = ColumnConfig(impact_admissibility=impact)
    s = RunSettings(t_end=T_END, output_interval=INTERVAL, device="cpu", **kw)
    t0 = time.perf_counter()
    r = simulate_batch(cfg, {"prestrain": 0.002, "v0": 0.1, "base_rigidity": beta}, s)
    wall = time.perf_counter() - t0
    m = measure_pulse(r.strain, r.time, cfg.height)
    return {"settings": {k: v for k, v in kw.items()}, "choices": r.info["choices"], "dt": r.dt,
            "n_steps": r.n_steps, "force_evaluations": r.n_steps * r.info["force_evaluations_per_step"],
            "wall_s": wall, "amplitude": float(m["amplitude"][0]), "speed": float(m["speed"][0]),
            "width": float(m["width_fwhm"][0]), "strain": r.strain[0]}


def errors(run_: dict, ref: dict) -> dict:
    d = np.abs(run_["strain"] - ref["strain"])
    peak = np.abs(ref["strain"]).max()
    return {"amplitude": run_["amplitude"] / ref["amplitude"] - 1, "speed": run_["speed"] / ref["speed"] - 1,
            "width": run_["width"] / ref["width"] - 1, "strain_max": float(d.max() / peak),
            "strain_rms": float(np.sqrt(np.mean(d**2)) / peak)}


def main():
    wp.config.quiet = True
    wp.init()
    out = {"meta": run_metadata(wp.get_device("cpu")), "t_end": T_END, "output_interval": INTERVAL,
           "scene": "paper column, 50 prisms, p = 0.002, v0 = 0.1 m/s", "cases": {}}
    for name, beta in CASES.items():
        ref = run(beta, dt_safety=0.01)
        half = run(beta, dt_safety=0.02)
        rows = {"dt_safety=0.02 (reference check)": half, "default": run(beta),
                "accuracy=1e-3": run(beta, accuracy=1e-3), "dt_safety=0.25 (old default)": run(beta, dt_safety=0.25)}
        case = {"reference": {k: v for k, v in ref.items() if k != "strain"}}
        for label, r in rows.items():
            case[label] = {k: v for k, v in r.items() if k != "strain"} | {"error": errors(r, ref)}
            e = case[label]["error"]
            print(f"{name} {label:34s} dt={r['dt']:.3e} steps={r['n_steps']:6d} wall={r['wall_s']:6.1f}s "
                  f"amp {e['amplitude']:+.2e} speed {e['speed']:+.2e} width {e['width']:+.2e} "
                  f"strain max {e['strain_max']:.2e} rms {e['strain_rms']:.2e}", flush=True)
        out["cases"][name] = case
    write_json(OUT, out)
    print("wrote", OUT)


if __name__ == "__main__":
    main()
