"""Pulse amplitude and speed against base rigidity beta through beta = 1 (issue 16, Must show 2).

A reduced CPU version of sweeps/phase_large.toml: the paper's 50-prism column, p = 0.002,
v0 in {0.003, 0.01, 0.03, 0.1} m/s, beta in {0, 0.5, 0.8, 0.9, 0.95, 0.99, 0.999, 1}, default
impact (rigid_members) and default accuracy, one batch per beta (each with its own dt: the stiff
base members of beta -> 1 need dt ~ (1 - beta)^(1/2)). The phase_large grid itself (1,536 columns)
needs a GPU; this is the cut through it that decides continuity.

    python analysis/beta_continuity.py        # ~5-10 min on 2 CPU cores
Writes analysis/data/beta_continuity.csv and analysis/figures/beta_continuity.png.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import warp as wp  # noqa: E402

from warp_tensegrity import ColumnConfig, RunSettings, simulate_batch  # noqa: E402
from warp_tensegrity.measure import measure_pulse  # noqa: E402
from warp_tensegrity.measure.nan_reasons import FLAGS  # noqa: E402
from warp_tensegrity.sweep.shard import measure_columns  # noqa: E402

BETAS = (0.0, 0.5, 0.8, 0.9, 0.95, 0.99, 0.999, 1.0)
V0 = (0.003, 0.01, 0.03, 0.1)
P = 0.002
T_END = 3.0
CSV = ROOT / "analysis" / "data" / "beta_continuity.csv"
PNG = ROOT / "analysis" / "figures" / "beta_continuity.png"


def main():
    import pandas as pd

    wp.config.quiet = True
    cfg = ColumnConfig()
    rows = []
    for beta in BETAS:
        t0 = time.perf_counter()
        r = simulate_batch(cfg, {"prestrain": P, "v0": np.array(V0), "base_rigidity": beta},
                           RunSettings(t_end=T_END, output_interval=0.002, device="cpu"))
        m = measure_columns(r, cfg.height)
        peak = np.abs(np.where(np.isfinite(r.strain), r.strain, 0)).max(axis=(1, 2))
        for i, v0 in enumerate(V0):
            rows.append({"base_rigidity": beta, "v0": v0, "prestrain": P, "amplitude": m["amplitude"][i],
                         "speed": m["speed"][i], "width": m["width"][i], "flag": FLAGS[m["measurement_flag"][i]],
                         "max_compression": peak[i], "dt": r.dt, "n_steps": r.n_steps,
                         "wall_s": time.perf_counter() - t0})
        print(f"beta={beta}: dt={r.dt:.3g} steps={r.n_steps} {time.perf_counter() - t0:.0f}s "
              f"A={np.round(m['amplitude'], 5)} c={np.round(m['speed'], 4)}", flush=True)
    df = pd.DataFrame(rows)
    CSV.parent.mkdir(parents=True, exist_ok=True)
    df.to_csv(CSV, index=False)
    plot(df)


def plot(df):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 4), constrained_layout=True)
    x = lambda b: -np.log10(np.maximum(1.0 - b, 1e-4))  # noqa: E731 - beta = 1 drawn at 1 - beta = 1e-4
    for v0, g in df.groupby("v0"):
        g = g.sort_values("base_rigidity")
        soft = g[g.base_rigidity < 1]
        rb = g[g.base_rigidity == 1]
        for ax, q in zip(axes, ("amplitude", "speed")):
            line, = ax.plot(x(soft.base_rigidity), soft[q], "o-", label=f"v0 = {v0} m/s")
            ax.plot(x(rb.base_rigidity), rb[q], "s", ms=9, mfc="none", color=line.get_color())
    lock = 0.1004733722234424
    axes[0].axhline(lock, color="0.5", ls=":", lw=1)
    axes[0].text(0.05, lock, "kinematic lock of a rigid-base prism", va="bottom", fontsize=8, color="0.4")
    ticks = [0.0, 0.5, 0.9, 0.99, 0.999, 1.0]
    for ax, q, unit in zip(axes, ("amplitude", "speed"), ("-", "m/s")):
        ax.set_xticks([x(np.array(t)) for t in ticks], ["0", "0.5", "0.9", "0.99", "0.999", "1 (RB)"])
        ax.set_xlabel("base rigidity beta (axis: -log10(1 - beta))")
        ax.set_ylabel(f"{q} [{unit}]")
        ax.set_yscale("log")
    axes[0].legend(fontsize=8)
    fig.suptitle("Paper column, p = 0.002, rigid_members impact: squares = rigid bases (beta = 1)")
    PNG.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(PNG, dpi=120)


if __name__ == "__main__":
    main()
