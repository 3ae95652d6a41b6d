"""Whether the energy measures (docs/measurements.md "Energy measures") hold still: five 30-prism
columns (flexible, elastic and rigid bases; weak to strong impacts), t_end = 2.4 s, measured at the
policy's fp64 dt, at dt / 2, in fp32, and at v0 (1 + 1e-6), on the CPU. Writes the shares, the
stability probe's sensitivity and the largest relative change against the fp64 run to
analysis/data/energy_stability.json (~1 min on 2 CPU cores).

    python analysis/energy_stability.py
"""

from __future__ import annotations

import json
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from warp_tensegrity import simulate_batch  # noqa: E402
from warp_tensegrity.options import RunSettings  # noqa: E402
from warp_tensegrity.policy.decide import decide  # noqa: E402
from warp_tensegrity.scene.columns import ColumnConfig  # noqa: E402

OUT = ROOT / "analysis" / "data" / "energy_stability.json"
SCENE = ColumnConfig(n_prisms=30)
PARAMS = {"prestrain": np.array([0.002, 0.01, 0.005, 0.002, 0.004]), "v0": np.array([0.1, 0.05, 0.1, 0.02, 0.15]),
          "base_rigidity": np.array([1.0, 0.0, 0.5, 1.0, 0.0])}
KEYS = ("pulse_energy_share", "end_energy_share")


def main() -> None:
    base = RunSettings(t_end=2.4, device="cpu", precision="fp64", truncate=False, groups=False)
    dt = decide(SCENE, PARAMS, base).dt
    runs = {"fp64": (replace(base, dt=dt), PARAMS), "fp64_half_dt": (replace(base, dt=dt / 2), PARAMS),
            "fp32": (replace(base, dt=dt, precision="fp32"), PARAMS),
            "fp64_v0_plus_1e-6": (replace(base, dt=dt), dict(PARAMS, v0=PARAMS["v0"] * (1 + 1e-6)))}
    out = {"scene": "30 prisms, paper prisms", "t_end": base.t_end, "dt": dt,
           "cases": {k: v.tolist() for k, v in PARAMS.items()}, "runs": {}}
    ref = None
    for name, (settings, params) in runs.items():
        m = simulate_batch(SCENE, params, settings).measurements
        row = {k: m[k].tolist() for k in (*KEYS, "pulse_energy_share_sensitivity")}
        if ref is None:
            ref = m
        else:
            with np.errstate(invalid="ignore"):
                row["relative_change"] = {k: (np.abs(m[k] - ref[k]) / np.abs(ref[k])).tolist() for k in KEYS}
        out["runs"][name] = row
        print(name, {k: np.round(m[k], 6).tolist() for k in KEYS}, row.get("relative_change"), flush=True)
    OUT.write_text(json.dumps(out, indent=1) + "\n")


if __name__ == "__main__":
    main()
