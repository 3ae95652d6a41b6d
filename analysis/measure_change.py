"""What the pulse measure of issue 25 (the leading peak followed while continuous) changes on
phase_large, against the measure before it (3e92af8), on the same records.

analysis/data/phase_large.nc holds no strain record (a GPU sweep with record_strain = false), so
128 of its 1,536 cases are run again on the CPU (fp64, the spec's run settings, one batch per
group and base rigidity): the 68 whose stored arrival times reverse inside the measurement window
(where a capture shows) and 60 others drawn at random (seed 25). Both measures are applied to
each record, and every changed speed is compared with the largest compression tracked snapshot by
snapshot over the time span of the run the new measure used (independent of both measures).

    python analysis/measure_change.py simulate DIR   # ~15 min on 2 CPU cores; records (~400 MB) in DIR
    python analysis/measure_change.py measure DIR    # -> analysis/data/measure_change_phase_large.json
"""

from __future__ import annotations

import glob
import importlib.util
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

OUT = ROOT / "analysis" / "data" / "measure_change_phase_large.json"
OLD_COMMIT = "3e92af8"


def selection():
    """(case indices, reversed?) into phase_large's flattened grid, and the grid (p, v0, beta)."""
    import xarray as xr

    from warp_tensegrity.measure.pulse_core import measurement_window

    ds = xr.open_dataset(ROOT / "analysis" / "data" / "phase_large.nc")
    at = ds.arrival_time.transpose("prestrain", "v0", "base_rigidity", "prism").values.reshape(-1, ds.sizes["prism"])
    grid = np.stack(np.meshgrid(ds.prestrain.values, ds.v0.values, ds.base_rigidity.values, indexing="ij"),
                    -1).reshape(-1, 3)
    lo, hi = measurement_window(at.shape[1])
    rev = []
    for b in range(at.shape[0]):
        for j in range(hi - 2, lo - 1, -1):
            if not np.isfinite(at[b, j]):
                break
            if at[b, j] < at[b, j + 1]:
                rev.append(b)
                break
    others = np.random.default_rng(25).choice(np.setdiff1d(np.arange(at.shape[0]), rev), 60, replace=False)
    return np.array(rev), others, grid, ds.speed.values.reshape(-1)


def simulate(d: Path):
    import warp as wp

    from warp_tensegrity.engine import simulate_batch
    from warp_tensegrity.sweep import load_spec, plan_sweep

    wp.config.quiet = True
    rev, others, grid, _ = selection()
    spec = load_spec(ROOT / "sweeps" / "phase_large.toml", overrides={"run": {"record_strain": True}})
    plan = plan_sweep(spec, device="cpu")
    d.mkdir(parents=True, exist_ok=True)
    for name, sel in (("rev", rev), ("others", others)):
        for beta in np.unique(grid[sel, 2]):
            m = sel[grid[sel, 2] == beta]
            r = simulate_batch(spec.scene, {"prestrain": grid[m, 0], "v0": grid[m, 1], "base_rigidity": grid[m, 2]},
                               plan.settings)
            np.savez(d / f"pl_rec_{name}_{beta:g}.npz", strain64=np.asarray(r.strain, dtype=np.float64), time=r.time,
                     cases=m, status=r.status)
            print(name, beta, len(m), r.dt, flush=True)


def old_measure():
    """measure_pulse as it was at OLD_COMMIT (from git)."""
    text = subprocess.run(["git", "-C", str(ROOT), "show", f"{OLD_COMMIT}:warp_tensegrity/measure/pulse_core.py"],
                          check=True, capture_output=True, text=True).stdout
    path = Path(tempfile.mkdtemp()) / "old_pulse_core.py"
    path.write_text(text)
    spec = importlib.util.spec_from_file_location("old_pulse_core", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod.measure_pulse


def tracked(q, t, t0, t1, j0, h):
    """Largest compression followed from prism j0 at t0 (searched 2 behind, 1 ahead), fitted over [t0, t1]."""
    k0, k1 = np.searchsorted(t, [t0, t1])
    P = q.shape[1]
    i = int(np.clip(j0, 1, P - 2))
    locs = []
    for k in range(k0, k1 + 1):
        lo = max(i - 2, 1)
        i = lo + int(q[k, lo:min(i + 2, P - 1)].argmax())
        y0, y1, y2 = q[k, i - 1], q[k, i], q[k, i + 1]
        den = y0 - 2 * y1 + y2
        locs.append(i + (0.5 * (y0 - y2) / den if den < 0 else 0.0))
    return float(-h * np.polyfit(t[k0:k1 + 1], locs, 1)[0])


def measure(d: Path):
    from warp_tensegrity.measure import measure_pulse
    from warp_tensegrity.measure.pulse_core import measurement_window

    old = old_measure()
    rev, _, grid, stored = selection()
    h = 6.2e-3
    rows = []
    for f in sorted(glob.glob(str(d / "pl_rec_*.npz"))):
        z = np.load(f)
        s, t, cases = z["strain64"], z["time"], z["cases"]
        with np.errstate(all="ignore"):
            mo, mn = old(s, t, h), measure_pulse(s, t, h)
        lo, hi = measurement_window(s.shape[-1])
        for i, c in enumerate(cases):
            row = {"case": int(c), "reversed": bool(c in rev), "prestrain": float(grid[c, 0]), "v0": float(grid[c, 1]),
                   "base_rigidity": float(grid[c, 2]), "status": int(z["status"][i]), "stored": float(stored[c]),
                   "old": float(mo["speed"][i]), "new": float(mn["speed"][i]), "pulse_captured": float(mn["pulse_captured"][i]),
                   "prisms_old": float(mo["prisms_measured"][i]), "prisms_new": float(mn["prisms_measured"][i]),
                   "tracked": float("nan")}
            n = row["prisms_new"]
            if np.isfinite(row["old"]) and np.isfinite(row["new"]) and row["old"] != row["new"]:
                if row["pulse_captured"] == 1:  # the run measured: the window prisms whose arrival survived
                    fa = np.flatnonzero(np.isfinite(mn["arrival_time"][i][lo:hi])) + lo
                    js = np.arange(fa.max(), fa.max() - int(n), -1)
                else:
                    js = np.arange(hi - 1, hi - 1 - int(n), -1)
                pt = mn["peak_time"][i]
                t0, t1 = np.nanmin(pt[js]), np.nanmax(pt[js])
                if np.isfinite(t0) and np.isfinite(t1) and t1 - t0 > 0.05:
                    row["tracked"] = tracked(-s[i], t, t0, t1, js[np.nanargmin(pt[js])], h)
            rows.append(row)
    summary = {}
    for g, sel in (("reversed", [r for r in rows if r["reversed"]]), ("random", [r for r in rows if not r["reversed"]]),
                   ("all", rows)):
        o, nw = np.array([r["old"] for r in sel]), np.array([r["new"] for r in sel])
        same = (o == nw) | (np.isnan(o) & np.isnan(nw))
        ch = np.isfinite(o) & np.isfinite(nw) & ~same
        rel = np.abs(nw[ch] / o[ch] - 1)
        tr = np.array([r["tracked"] for r in sel])[ch]
        summary[g] = {"cases": len(sel), "unchanged": int(same.sum()), "changed": int(ch.sum()),
                      "changed_by_more_than_5pct": int((rel > 0.05).sum()),
                      "lost": int((np.isfinite(o) & np.isnan(nw)).sum()), "gained": int((np.isnan(o) & np.isfinite(nw)).sum()),
                      "changed_new_within_5pct_of_tracked": int((np.abs(nw[ch] / tr - 1) < 0.05).sum()),
                      "changed_old_within_5pct_of_tracked": int((np.abs(o[ch] / tr - 1) < 0.05).sum())}
    print(json.dumps(summary, indent=1))
    OUT.write_text(json.dumps({"old_commit": OLD_COMMIT, "summary": summary, "rows": rows}, indent=1))
    print("wrote", OUT)


if __name__ == "__main__":
    {"simulate": simulate, "measure": measure}[sys.argv[1]](Path(sys.argv[2]))
