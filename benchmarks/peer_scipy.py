"""Peer: the float64 SciPy route a researcher would write, at the engine's accuracy.

One column at a time on the CPU: ``scipy.integrate.solve_ivp(method="DOP853")`` on the index-1
DAE  M a = f(x) - G^T lam,  G M^-1 G^T lam = G M^-1 f + |b'|^2  (the bar multipliers solved at
every right-hand-side evaluation with ``numpy.linalg.solve`` on the dense Gram matrix; the
right-hand side is :meth:`tests.references.reference.ReferenceSystem.accel`, dense float64).

Accuracy matching: the error of a run is the largest final-state position error over the
nodes, relative to the largest displacement of the tight reference (DOP853 at rtol 1e-11);
the velocity error is reported too. Our engine (RATTLE, fp64, the default dt = 0.25 x the
stability limit, rounded to divide t_end) gives err_ours; the peer uses the loosest rtol in a
decade sweep whose error is <= err_ours ("matched").

Throughput in the engine's unit: a "column-step" is engine dt of simulated time, so the peer
does (t_end / dt) column-steps in its wall time. ratio = ours / peer in simulated seconds
per wall second per column (= ratio of column-steps/s).

Usage::

    python -m benchmarks.peer_scipy [--n-prisms 50] [--t-end 0.1] [--out benchmarks/results/peer_scipy_cpu.json]
"""

from __future__ import annotations

import os

# One BLAS thread (set before NumPy loads): the engine's CPU backend is serial too, and on a
# shared 2-core host a spinning 2-thread OpenBLAS made each RHS evaluation ~50x slower
# (175 ms instead of 3 ms, measured). PEER_BLAS_THREADS overrides.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, os.environ.get("PEER_BLAS_THREADS", "1"))

import argparse  # noqa: E402
import glob  # noqa: E402
import math  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from . import common  # noqa: E402

RTOLS = [1e-2, 1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9]
REF_RTOL = 1e-11


def peer_solve(ref, scene, t_end, rtol, atol_factor=1e-4):
    """DOP853 from the scene's admissible initial state; returns final (x, v), wall, nfev, steps."""
    from scipy.integrate import solve_ivp

    nd = ref.ndof
    free = ref.free_nodes
    fill = scene.network.positions.copy()
    n = ref.n_nodes

    def rhs(_t, y):
        x = ref.to_x(y[:nd], fill)
        v = np.zeros((n, 3))
        v[free] = y[nd:].reshape(-1, 3)
        a = ref.accel(x, v)
        return np.concatenate([y[nd:], a[free].ravel()])

    y0 = np.concatenate([ref.to_q(scene.network.positions), ref.to_q(scene.velocity)])
    t0 = time.perf_counter()
    sol = solve_ivp(rhs, (0.0, t_end), y0, method="DOP853", rtol=rtol, atol=rtol * atol_factor)
    wall = time.perf_counter() - t0
    if not sol.success:
        raise RuntimeError(f"DOP853 rtol={rtol}: {sol.message}")
    y = sol.y[:, -1]
    x = ref.to_x(y[:nd], fill)
    v = np.zeros((n, 3))
    v[free] = y[nd:].reshape(-1, 3)
    return x, v, wall, int(sol.nfev), int(len(sol.t) - 1)


def bar_error(net, x):
    b = x[net.bars[:, 1]] - x[net.bars[:, 0]]
    L = np.linalg.norm(net.positions[net.bars[:, 1]] - net.positions[net.bars[:, 0]], axis=1)
    return float(np.max(np.abs(np.linalg.norm(b, axis=1) - L) / L))


def engine_run(cfg, params, t_end, dt, device="cpu"):
    from warp_tensegrity import RunSettings, simulate_batch

    s = RunSettings(t_end=t_end, dt=dt, method="rattle", precision="fp64", device=device, record_strain=False,
                    output_interval=t_end)
    t0 = time.perf_counter()
    r = simulate_batch(cfg, params, s)
    return r, time.perf_counter() - t0


def main(argv=None):
    ap = argparse.ArgumentParser(description="SciPy DOP853 peer at the engine's accuracy")
    ap.add_argument("--n-prisms", dest="n_prisms", type=int, default=50)
    ap.add_argument("--base", default="FB", choices=["FB", "RB"])
    ap.add_argument("--prestrain", type=float, default=0.01)
    ap.add_argument("--v0", type=float, default=0.05)
    ap.add_argument("--t-end", dest="t_end", type=float, default=0.1, help="simulated seconds")
    ap.add_argument("--rtols", type=float, nargs="+", default=RTOLS)
    ap.add_argument("--out", default=str(common.RESULTS / "peer_scipy_cpu.json"))
    ap.add_argument("--budget-s", dest="budget_s", type=float, default=100.0,
                    help="stop the rtol sweep once this much wall time is spent")
    a = ap.parse_args(argv)

    import warp as wp

    wp.config.quiet = True
    wp.config.log_level = wp.LOG_WARNING
    wp.init()
    from warp_tensegrity import ColumnConfig, build_column
    from tests.references.reference import ReferenceSystem

    t_start = time.perf_counter()
    cfg = ColumnConfig(n_prisms=a.n_prisms)
    beta = 0.0 if a.base == "FB" else 1.0
    scene = build_column(cfg, prestrain=a.prestrain, v0=a.v0, base_rigidity=beta)
    ref = ReferenceSystem(scene.network)
    params = {"prestrain": [a.prestrain], "v0": [a.v0], "base_rigidity": [beta]}
    from warp_tensegrity import column_batch

    dt_default = common.rattle_dt(column_batch(cfg, params))
    n_steps = math.ceil(a.t_end / dt_default - 1e-9)
    dt = a.t_end / n_steps
    print(f"[peer_scipy] {a.n_prisms} prisms {a.base}, p={a.prestrain}, v0={a.v0} m/s, t_end={a.t_end} s; "
          f"engine dt={dt:.4g} s ({n_steps} steps); ndof={ref.ndof}, bars={len(scene.network.bars)}", flush=True)

    # tight reference
    xr, vr, wall_ref, nfev_ref, steps_ref = peer_solve(ref, scene, a.t_end, REF_RTOL)
    X = scene.network.positions
    free = ref.free_nodes
    dscale = float(np.abs(xr - X)[free].max())
    vscale = float(np.abs(vr)[free].max())
    print(f"[peer_scipy] reference DOP853 rtol={REF_RTOL}: {wall_ref:.2f} s, nfev {nfev_ref}, steps {steps_ref}; "
          f"max displacement {dscale:.4g} m, max speed {vscale:.4g} m/s", flush=True)

    def errors(x, v):
        return (float(np.abs(x - xr)[free].max() / dscale), float(np.abs(v - vr)[free].max() / vscale))

    # ours: RATTLE fp64 on the CPU, default dt and refinements (work-precision of the engine)
    ours = []
    for fac in (1, 2, 4, 8, 16):
        r, total = engine_run(cfg, params, a.t_end, dt / fac)
        x = X + r.final_displacement[0]
        v = r.final_velocity[0]
        ex, ev = errors(x, v)
        ours.append({"dt": dt / fac, "steps": r.n_steps, "pos_err": ex, "vel_err": ev, "wall_stepping_s": r.wall_time,
                     "wall_total_s": total, "bar_err": float(r.bar_length_error[0]), "status": int(r.status[0])})
        print(f"  ours RATTLE fp64 dt/{fac:<2d}: pos err {ex:.3e}, vel err {ev:.3e}, {r.n_steps} steps, "
              f"{r.wall_time * 1e3:.1f} ms stepping (CPU, B=1)", flush=True)
    err_ours = ours[0]["pos_err"]

    # peer sweep
    peer = []
    matched = None
    for rtol in a.rtols:
        if time.perf_counter() - t_start > a.budget_s:
            print(f"  (budget reached: rtol sweep stops before {rtol:g})", flush=True)
            break
        x, v, wall, nfev, steps = peer_solve(ref, scene, a.t_end, rtol)
        ex, ev = errors(x, v)
        row = {"rtol": rtol, "atol": rtol * 1e-4, "wall_s": wall, "nfev": nfev, "steps": steps, "pos_err": ex,
               "vel_err": ev, "bar_err": bar_error(scene.network, x), "ms_per_rhs": 1e3 * wall / max(nfev, 1)}
        peer.append(row)
        print(f"  peer DOP853 rtol={rtol:.0e}: pos err {ex:.3e}, vel err {ev:.3e}, {wall:.2f} s, nfev {nfev}, "
              f"steps {steps}, {row['ms_per_rhs']:.2f} ms/rhs, bar err {row['bar_err']:.1e}", flush=True)
        if matched is None and ex <= err_ours:
            matched = row
        if ex < 0.05 * err_ours and matched is not None:
            break  # tighter runs only cost more

    doc = {
        "kind": "peer_scipy", "meta": common.run_metadata(wp.get_device("cpu")),
        "scene": {"n_prisms": a.n_prisms, "base": a.base, "prestrain": a.prestrain, "v0": a.v0, "t_end": a.t_end,
                  "ndof": int(ref.ndof), "n_bars": int(len(scene.network.bars))},
        "engine_dt": dt, "engine_steps": n_steps,
        "reference": {"rtol": REF_RTOL, "wall_s": wall_ref, "nfev": nfev_ref, "steps": steps_ref,
                      "max_displacement": dscale, "max_speed": vscale},
        "blas_threads": os.environ.get("OPENBLAS_NUM_THREADS"),
        "ours_cpu": ours, "peer": peer, "matched": matched, "err_ours_default_dt": err_ours,
    }
    if matched is not None:
        sim_rate = a.t_end / matched["wall_s"]  # simulated seconds per wall second, one column
        doc["peer_seconds_per_simulated_second"] = matched["wall_s"] / a.t_end
        doc["peer_sim_seconds_per_wall_second"] = sim_rate
        doc["peer_column_steps_per_s"] = sim_rate / dt
        cpu1 = ours[0]["steps"] / ours[0]["wall_stepping_s"]
        doc["ours_cpu_b1_column_steps_per_s"] = cpu1
        doc["ratio_ours_cpu_b1"] = cpu1 / doc["peer_column_steps_per_s"]
    doc["comparisons"] = compare_with_throughput(doc, sorted(glob.glob(str(common.RESULTS / "throughput_*.json"))))
    doc["summary_markdown"] = summary_markdown(doc)
    doc["elapsed_s"] = time.perf_counter() - t_start
    common.write_json(a.out, doc)
    print(doc["summary_markdown"])
    print(f"[peer_scipy] wrote {a.out} ({doc['elapsed_s']:.0f} s)")
    return 0


def compare_with_throughput(doc, files) -> list:
    """ours / peer for the best measured FB-or-RB fp64 point of the same prisms in each throughput JSON."""
    import json

    out = []
    if doc.get("peer_sim_seconds_per_wall_second") is None:
        return out
    sc = doc["scene"]
    for f in files:
        try:
            with open(f) as fh:
                t = json.load(fh)
        except (OSError, ValueError):
            continue
        if t.get("kind") != "throughput":
            continue
        pts = [p for p in t.get("points", []) if not p.get("error") and p.get("n_prisms") == sc["n_prisms"]
               and p.get("base") == sc["base"] and p.get("precision") == "fp64"]
        if not pts:
            continue
        best = max(pts, key=lambda p: p["column_steps_per_s"])
        ours_rate = best["column_steps_per_s"] * best["dt"]  # simulated s per wall s per column
        out.append({"file": Path(f).name, "device_name": t.get("meta", {}).get("device_name"), "B": best["B"],
                    "column_steps_per_s": best["column_steps_per_s"], "dt": best["dt"],
                    "ours_sim_seconds_per_wall_second_per_column": ours_rate,
                    "ratio": ours_rate / doc["peer_sim_seconds_per_wall_second"]})
    return out


def summary_markdown(doc) -> str:
    sc = doc["scene"]
    m = doc.get("matched")
    lines = [f"{sc['n_prisms']}-prism {sc['base']} column, prestrain {sc['prestrain']}, v0 {sc['v0']} m/s, "
             f"t_end {sc['t_end']} s; engine dt {doc['engine_dt']:.4g} s ({doc['engine_steps']} steps). "
             f"Errors: final positions vs DOP853 rtol {doc['reference']['rtol']:g}, relative to the largest "
             f"displacement ({doc['reference']['max_displacement']:.3g} m).", "",
             "| run | pos err | vel err | wall [s] | RHS evals | steps |", "|---|---:|---:|---:|---:|---:|"]
    for o in doc["ours_cpu"]:
        k = round(doc["engine_dt"] / o["dt"])
        lines.append(f"| ours RATTLE fp64 dt/{k} (CPU, B=1) | {o['pos_err']:.2e} | {o['vel_err']:.2e} | "
                     f"{o['wall_stepping_s']:.3f} | {o['steps']} | {o['steps']} |")
    for p in doc["peer"]:
        tag = " **matched**" if m is not None and p["rtol"] == m["rtol"] else ""
        lines.append(f"| SciPy DOP853 rtol {p['rtol']:.0e}{tag} | {p['pos_err']:.2e} | {p['vel_err']:.2e} | "
                     f"{p['wall_s']:.2f} | {p['nfev']} | {p['steps']} |")
    lines.append("")
    if m is None:
        lines.append("No rtol of the sweep reached the engine's error at the default dt.")
    else:
        lines.append(f"Matched peer (rtol {m['rtol']:.0e}): {doc['peer_seconds_per_simulated_second']:.3g} wall s per "
                     f"simulated s per column = {doc['peer_column_steps_per_s']:.3g} column-steps/s equivalent "
                     f"({m['ms_per_rhs']:.2f} ms per RHS evaluation). Ours on the same CPU, one column: "
                     f"{doc['ours_cpu_b1_column_steps_per_s']:.3g} column-steps/s (ratio {doc['ratio_ours_cpu_b1']:.3g}).")
        for c in doc.get("comparisons", []):
            lines.append(f"- vs `{c['file']}` ({c['device_name']}, best B = {c['B']}): "
                         f"{c['column_steps_per_s']:.3g} column-steps/s at dt {c['dt']:.3g} s -> ratio ours/peer "
                         f"= {c['ratio']:.3g} (simulated seconds per wall second per column).")
    return "\n".join(lines)


if __name__ == "__main__":
    sys.exit(main())
