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
E. The convergence table of issue 25: RMS over the strain record (t <= 0.3 s) of the difference to
   beta = 1, over the peak, at 1 - beta = 1e-2 .. 1e-5 (one batch per row: one dt), for 15, 20, 50
   prisms at v0 = 0.1 m/s, 50 prisms at v0 = 0.003, 0.01, 0.03 and 20 prisms at 0.01; 50 prisms
   at 1 - beta = 1e-5 and 1e-6. Beside each: the lowest base-member mode over the top of the RB
   band (scene.base_modes.base_mode_ratio) and the per-case flag the datasets record.
F. The lock is not a rank loss: singular values of the Jacobian of the bar and link constraints
   of one rigid-base prism (bottom base clamped) at the reference twist and at the lock (pi).
G. The speed measure against the main pulse (issue 25, part 2): 50 prisms, p = 0.002, t_end = 1.6 s,
   v0 in {0.05, 0.075, 0.1, 0.125, 0.15}, beta in {0.999, 0.9999, 1} (one batch): measured speed
   against beta = 1's, the run it used, and the main pulse of the same column tracked snapshot by
   snapshot over that run's time span.

    python analysis/beta_limit.py            # all parts, ~15 min on 2 CPU cores
    python analysis/beta_limit.py E F G      # only these parts (merged into the JSON)
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


BETAS_E = [0.99, 0.999, 0.9999, 0.99999, 1.0]
ROWS_E = [(15, 0.1), (20, 0.1), (50, 0.1), (50, 0.003), (50, 0.01), (50, 0.03), (20, 0.01)]


def convergence_row(n, v0, betas=BETAS_E, t_end=0.3):
    """RMS/peak and max/peak of the strain difference to the last column (beta = 1) over t <= t_end."""
    from warp_tensegrity.scene.base_modes import beta_limit_measures

    cfg = ColumnConfig(n_prisms=n)
    t0 = time.perf_counter()
    r = simulate_batch(cfg, {"prestrain": 0.002, "v0": v0, "base_rigidity": np.array(betas)},
                       RunSettings(t_end=t_end, output_interval=0.002, device="cpu", dt_safety=0.25))
    assert (r.status == 0).all()
    ref = r.strain[-1]
    peak = float(np.abs(ref).max())
    qmax = -r.strain.min(axis=(1, 2))
    fl = beta_limit_measures(cfg, {"prestrain": 0.002, "base_rigidity": np.array(betas)}, len(betas), qmax)
    rows = [{"one_minus_beta": float(1 - b), "rms_over_peak": float(np.sqrt(np.mean((r.strain[i] - ref) ** 2)) / peak),
             "max_over_peak": float(np.abs(r.strain[i] - ref).max() / peak),
             "base_mode_ratio": float(fl["base_mode_ratio"][i]), "beta_limit_flag": int(fl["beta_limit_flag"][i])}
            for i, b in enumerate(betas[:-1])]
    for a, b in zip(rows[:-1], rows[1:]):
        b["gain_over_the_decade"] = a["rms_over_peak"] / b["rms_over_peak"]
    return {"n_prisms": n, "v0": v0, "t_end": t_end, "peak_compression": peak, "dt": r.dt, "n_steps": r.n_steps,
            "wall_s": time.perf_counter() - t0, "rows": rows}


def part_e():
    out = {f"{n}_prisms_v0_{v0:g}": convergence_row(n, v0) for n, v0 in ROWS_E}
    out["50_prisms_v0_0.1_to_1e-6"] = convergence_row(50, 0.1, [0.99999, 0.999999, 1.0])
    for k, v in out.items():
        print("E", k, [(r["one_minus_beta"], f"{r['rms_over_peak']:.3g}", f"{r['base_mode_ratio']:.3g}", r["beta_limit_flag"])
                       for r in v["rows"]], flush=True)
    return out


def part_f():
    """Singular values of J (rows: 3 bars, 3 top links; g = |b|^2/2; bottom base clamped)."""
    from warp_tensegrity.scene.columns import column_topology
    from warp_tensegrity.scene.impact import member_jacobian

    topo = column_topology(ColumnConfig(n_prisms=1))
    x0 = np.array(topo.positions, float)
    a, h0, phi0 = CFG.radius, CFG.height, CFG.twist
    bars, top = topo.bars, topo.level_nodes[-1]
    l2 = float(np.sum((x0[bars[0, 1]] - x0[bars[0, 0]]) ** 2))
    ang0 = np.arctan2(x0[top, 1], x0[top, 0])
    sense = np.sign(np.angle(np.exp(1j * (ang0 - np.arctan2(x0[bars[:, 0], 1], x0[bars[:, 0], 0]))))[0])
    links = np.array([m for m in topo.base if m[0] in top and m[1] in top])
    out = {}
    for name, phi in (("reference", phi0), ("lock", np.pi)):
        x = x0.copy()
        h = np.sqrt(l2 - 2 * a**2 * (1 - np.cos(phi)))
        ang = ang0 + sense * (phi - phi0)
        x[top, 0], x[top, 1], x[top, 2] = a * np.cos(ang), a * np.sin(ang), h
        J = member_jacobian(x, np.concatenate([bars, links]), topo.fixed)[:, np.repeat(~topo.fixed, 3)]
        sv = np.linalg.svd(J, compute_uv=False)
        svn = np.linalg.svd(J / np.linalg.norm(J, axis=1, keepdims=True), compute_uv=False)
        out[name] = {"twist": float(phi), "strain": float((h - h0) / h), "rank": int(np.linalg.matrix_rank(J)),
                     "n_constraints": int(J.shape[0]), "singular_values": sv.tolist(),
                     "min_over_max": float(sv[-1] / sv[0]), "min_over_max_unit_rows": float(svn[-1] / svn[0])}
    print("F", {k: (v["rank"], round(v["min_over_max"], 4)) for k, v in out.items()}, flush=True)
    return out


def main_pulse_speed(q, t, h, t0=0.2, t1=1.0, start=(30, 45)):
    """Independent of the measure (as tests/measure/test_measure.py): the largest compression of the main
    pulse tracked snapshot by snapshot (searched from 2 prisms behind to 1 ahead of the last
    location, parabolic), its location fitted linearly in time over [t0, t1]."""
    k0, k1 = np.searchsorted(t, [t0, t1])
    i = start[0] + int(q[k0, start[0]:start[1]].argmax())
    locs = []
    for k in range(k0, k1 + 1):
        lo = max(i - 2, 1)
        i = lo + int(q[k, lo:i + 2].argmax())
        y0, y1, y2 = q[k, i - 1], q[k, i], q[k, i + 1]
        locs.append(i + 0.5 * (y0 - y2) / (y0 - 2 * y1 + y2))
    return float(-h * np.polyfit(t[k0:k1 + 1], locs, 1)[0])


def part_g():
    """Speed vs beta, and against the main pulse of the same column tracked over the time span of
    the run the measure used (the window prisms whose arrival it kept where a run was cut)."""
    v0s, betas = [0.05, 0.075, 0.1, 0.125, 0.15], [0.999, 0.9999, 1.0]
    V, B = (a.ravel() for a in np.meshgrid(v0s, betas, indexing="ij"))
    r = simulate_batch(CFG, {"prestrain": 0.002, "v0": V, "base_rigidity": B},
                       RunSettings(t_end=1.6, output_interval=0.002, device="cpu", dt_safety=0.25))
    m = measure_pulse(r.strain, r.time, CFG.height)
    lo, hi = 5, 45
    rows = []
    for i in range(len(V)):
        ref = int(np.flatnonzero((V == V[i]) & (B == 1.0))[0])
        n = int(m["prisms_measured"][i])
        if m["pulse_captured"][i] == 1:
            top = int((np.flatnonzero(np.isfinite(m["arrival_time"][i][lo:hi])) + lo).max())
        else:
            top = hi - 1
        js = np.arange(top, top - n, -1)
        pt = m["peak_time"][i]
        t0, t1 = float(np.nanmin(pt[js])), float(np.nanmax(pt[js]))
        mp = main_pulse_speed(-r.strain[i], r.time, CFG.height, t0=t0, t1=t1,
                              start=(int(js[np.nanargmin(pt[js])]), int(js[np.nanargmin(pt[js])]) + 1))
        rows.append({"v0": float(V[i]), "beta": float(B[i]), "speed": float(m["speed"][i]),
                     "rel_to_beta_1": float(m["speed"][i] / m["speed"][ref] - 1), "prisms_measured": float(n),
                     "run": [int(js.min()), int(js.max())], "run_time": [t0, t1],
                     "pulse_captured": float(m["pulse_captured"][i]), "amplitude": float(m["amplitude"][i]),
                     "main_pulse_speed_same_span": mp, "measured_over_main_pulse": float(m["speed"][i]) / mp - 1})
        x = rows[-1]
        print("G", x["v0"], x["beta"], f"{x['speed']:.4f} ({x['rel_to_beta_1']:+.1%}) run {x['run']} t {t0:.2f}..{t1:.2f} "
              f"main {mp:.4f} (measured {x['measured_over_main_pulse']:+.1%})", flush=True)
    return {"dt": r.dt, "rows": rows}


def main(parts=("A", "B", "C", "D", "E", "F", "G")):
    wp.config.quiet = True
    out = json.loads(OUT.read_text()) if OUT.exists() else {}
    out["kinematic_lock_strain"] = kinematic_lock_strain(CFG.radius, CFG.height, CFG.twist)
    if "E" in parts:
        out["E_convergence_t_0.3"] = part_e()
    if "F" in parts:
        out["F_lock_jacobian"] = part_f()
    if "G" in parts:
        out["G_speed_vs_main_pulse"] = part_g()
    if set(parts) <= {"E", "F", "G"}:
        OUT.write_text(json.dumps(out, indent=1))
        print("wrote", OUT)
        return
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
    main(tuple(sys.argv[1:]) or ("A", "B", "C", "D", "E", "F", "G"))
