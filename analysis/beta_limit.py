"""The limits beta -> 1 and beta -> 0 of the base rigidity, with the rigid_members impact
(docs/impact.md). Numbers quoted there come from this script.

A. The issue's test: the paper's RB column (50 prisms, p = 0.002, v0 = 0.1 m/s, fp64), beta in
   {0.99, 0.999, 0.9999, 1} in one batch (one dt, set by the stiffest column), t_end = 1.6 s:
   relative differences of amplitude, speed, FWHM to beta = 1, RMS and max strain-history
   difference over the peak.
B. Below and above the kinematic lock: v0 in {0.003, 0.03, 0.1} m/s, beta in {0.999, 0.9999, 1},
   t_end = 0.4 s: max strain difference over the peak against time.
C. RB alone, v0 perturbed by 1e-8..1e-2: the rigid-base motion itself is not chaotic.
D. beta -> 0: beta in {1e-2, 1e-3, 1e-4, 0}, as A.

    python analysis/beta_limit.py      # ~3-5 min on 2 CPU cores
Writes analysis/data/beta_limit.json.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import warp as wp  # noqa: E402

from warp_tensegrity import ColumnConfig, RunSettings, simulate_batch  # noqa: E402
from warp_tensegrity.scene.impact import kinematic_lock_strain  # noqa: E402
from warp_tensegrity.measure import measure_pulse  # noqa: E402

OUT = ROOT / "analysis" / "data" / "beta_limit.json"
CFG = ColumnConfig()


def against_last(betas, v0=0.1, t_end=1.6, dt_safety=0.25, interval=0.002):
    """Columns of one batch compared with its last column."""
    t0 = time.perf_counter()
    r = simulate_batch(CFG, {"prestrain": 0.002, "v0": v0, "base_rigidity": np.array(betas)},
                       RunSettings(t_end=t_end, output_interval=interval, device="cpu", dt_safety=dt_safety))
    m = measure_pulse(r.strain, r.time, CFG.height)
    peak = np.abs(r.strain[-1]).max()
    rows = []
    for b, beta in enumerate(betas[:-1]):
        d = np.abs(r.strain[b] - r.strain[-1])
        rows.append({"beta": beta,
                     **{f"rel_{k}": float(m[k][b] / m[k][-1] - 1) for k in ("amplitude", "speed", "width_fwhm")},
                     "strain_rms_over_peak": float(np.sqrt(np.mean(d**2)) / peak),
                     "strain_max_over_peak": float(d.max() / peak),
                     "max_over_peak_vs_time": {f"{t:g}": float(d[k].max() / peak) for k, t in enumerate(r.time)
                                               if k % max(1, len(r.time) // 8) == 0 or k == len(r.time) - 1}})
    ref = {k: float(m[k][-1]) for k in ("amplitude", "speed", "width_fwhm")}
    return {"reference_beta": betas[-1], "reference": ref, "peak": float(peak), "dt": r.dt, "n_steps": r.n_steps,
            "wall_s": time.perf_counter() - t0, "rows": rows}


def main():
    wp.config.quiet = True
    out = {"kinematic_lock_strain": kinematic_lock_strain(CFG.radius, CFG.height, CFG.twist)}
    out["A_beta_to_1_v0_0.1"] = against_last([0.99, 0.999, 0.9999, 1.0])
    print("A", json.dumps(out["A_beta_to_1_v0_0.1"]["rows"], indent=None)[:2000], flush=True)
    out["B_short_horizon"] = {f"{v0:g}": against_last([0.999, 0.9999, 1.0], v0=v0, t_end=0.4)
                              for v0 in (0.003, 0.03, 0.1)}
    for v0, res in out["B_short_horizon"].items():
        print("B", v0, res["peak"], [(r["beta"], r["strain_max_over_peak"]) for r in res["rows"]], flush=True)
    eps = [1e-8, 1e-6, 1e-4, 1e-2]
    r = simulate_batch(CFG, {"prestrain": 0.002, "v0": 0.1 * (1 + np.array([0.0] + eps)), "base_rigidity": 1.0},
                       RunSettings(t_end=1.6, output_interval=0.002, device="cpu", dt_safety=0.125))
    peak = np.abs(r.strain[0]).max()
    out["C_rb_perturbed_v0"] = {f"{e:g}": float(np.abs(r.strain[i + 1] - r.strain[0]).max() / peak)
                                for i, e in enumerate(eps)}
    print("C", out["C_rb_perturbed_v0"], flush=True)
    out["D_beta_to_0_v0_0.1"] = against_last([1e-2, 1e-3, 1e-4, 0.0], dt_safety=0.1)
    print("D", [(r["beta"], r["rel_amplitude"], r["rel_speed"], r["rel_width_fwhm"], r["strain_rms_over_peak"])
                for r in out["D_beta_to_0_v0_0.1"]["rows"]], flush=True)
    OUT.parent.mkdir(parents=True, exist_ok=True)
    OUT.write_text(json.dumps(out, indent=1))
    print("wrote", OUT)


if __name__ == "__main__":
    main()
