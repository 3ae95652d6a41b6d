"""Where the integrators go unstable, against the linear prediction S / omega_max.

Part 1 - largest stable time step. For every method and for a grid of columns (prestrain,
base rigidity, impact speed), bisect (log scale) the largest stable dt, where stable means:
status 0 (no non-finite state, every bar within failure_bar_error after its projection) and
energy_error < 1 (|E - E0| < KE0 at every output) over ``n_steps`` steps. The prediction is
S / omega_max with S = 2 (rattle, symplectic_euler), 2 sqrt 2 (rk4), 1.5734 (yoshida4) and
omega_max from :func:`warp_tensegrity.validation.linear.omega_max` on the reference network (all cables
taut).

Batch trick (dt is one per batch, the cases are many): the dynamics of a column with masses
scaled by s, impact speed scaled by 1/sqrt(s) and time step dt * sqrt(s) is the same as the
original one in the time variable t * sqrt(s) - same positions after the same number of steps,
same strains, same energy error relative to KE0, same bar errors. So one batch at a fixed dt0
holds every case, each with its own ``unit_mass = m0 (omega_c dt0 / (r_c S))**2`` and
``v0 = v0_c sqrt(m0 / unit_mass)``, which runs case c at omega_c dt = r_c S. Every bisection
iteration is then one batch per method. The equivalence is re-checked directly (unscaled
columns at the physical dt on both sides of the measured limit) for a few cases.

Part 2 - energy error against time over a long run, every method at the engine's default
dt = 'auto' (0.25 x its stability limit from the omega bound), on a smooth case (taut cables)
and on strong impacts where cables go slack and taut again and again; the number of slack
cables of the strong FB impact is counted with the independent NumPy reference integrator.

Usage::

    python -m benchmarks.stability --device cuda:0 --out analysis
    python -m benchmarks.stability --device cpu --out /tmp/stab --quick
    python -m benchmarks.stability --plot-only analysis

Writes ``OUT/data/stab_<device>.nc`` and ``OUT/figures/stab_*_<device>.png``.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import itertools
import sys
import time
from pathlib import Path

import numpy as np

from .common import device_tag, save_study

METHODS = ("rattle", "rk4", "yoshida4", "symplectic_euler")
COLORS = {"rattle": "C0", "rk4": "C1", "yoshida4": "C2", "symplectic_euler": "C3"}
N_PRISMS = 6
V0_SMALL = 1e-4
PRESTRAINS = (0.0, 0.0005, 0.001, 0.002, 0.005, 0.01, 0.02)
RIGIDITIES = (0.0, 0.5, 1.0)
V0S = (1e-4, 1e-3, 3e-3, 0.01, 0.03, 0.1)
V0_PRESTRAINS = (0.0, 0.002, 0.01)
V0_RIGIDITIES = (0.0, 1.0)
R_LO, R_HI = 0.3, 3.0  # bracket of r = dt omega_max / S
FULL = dict(n_steps=2000, n_bisect=8, energy_t_end=400.0, slack_t_end=4.0)
QUICK = dict(n_steps=400, n_bisect=6, energy_t_end=20.0, slack_t_end=1.5)
# long runs: name, prestrain, v0, base_rigidity
# (with the default end_twist impact: FB p=0.002 v0=0.1 reaches prism strain -0.43, RB p=0.002
# v0=0.03 swings between -0.10 and +0.16, both far past the prestrain; FB p=0.01 v0=0.002 stays
# within +-0.005 of a 0.01 prestrain)
ENERGY_CASES = (
    ("FB p=0.002 v0=0.1 (slack/taut)", 0.002, 0.1, 0.0),
    ("RB p=0.002 v0=0.03 (slack/taut)", 0.002, 0.03, 1.0),
    ("FB p=0.01 v0=0.002 (taut)", 0.01, 0.002, 0.0),
)
ENERGY_RUNS = tuple((m, "fp64") for m in METHODS) + (("rattle", "fp32"),)


def log(msg: str):
    print(f"[stability {time.strftime('%H:%M:%S')}] {msg}", file=sys.stderr, flush=True)


def stability_cases():
    """(prestrain, v0, base_rigidity) arrays of the grid: prestrain x rigidity at small v0, and
    v0 sweeps at three prestrains, FB and RB (duplicates removed, order kept)."""
    rows = [(p, V0_SMALL, b) for b, p in itertools.product(RIGIDITIES, PRESTRAINS)]
    rows += [(p, v, b) for b, p, v in itertools.product(V0_RIGIDITIES, V0_PRESTRAINS, V0S)]
    seen, out = set(), []
    for r in rows:
        if r not in seen:
            seen.add(r)
            out.append(r)
    a = np.array(out)
    return {"prestrain": a[:, 0], "v0": a[:, 1], "base_rigidity": a[:, 2]}


def omega_exact(cfg, cases) -> np.ndarray:
    """omega_max [rad/s] of each case's reference network (all cables taut), by modal analysis."""
    from warp_tensegrity import build_column
    from warp_tensegrity.validation.linear import omega_max

    return np.array([omega_max(build_column(cfg, p, v, b).network)
                     for p, v, b in zip(cases["prestrain"], cases["v0"], cases["base_rigidity"])])


def omega_bound(cfg, cases) -> np.ndarray:
    from warp_tensegrity.scene.batch import column_batch, omega_max_bound

    return omega_max_bound(column_batch(cfg, cases))


BLOWUP_ENERGY = 100.0


def is_stable(res, criterion="energy"):
    """'energy' (the definition used here): status 0 and energy_error < 1;
    'blowup': status 0 and energy_error < BLOWUP_ENERGY (the run did not diverge)."""
    bound = 1.0 if criterion == "energy" else BLOWUP_ENERGY
    return (res.status == 0) & np.isfinite(res.energy_error) & (res.energy_error < bound)


def run_at_ratio(cfg, cases, omega, r, method, n_steps, device, precision="fp64", dt0=1e-3,
                 criterion="energy", **kw):
    """Run every case c for n_steps at omega_c dt = r_c * S (one batch, masses scaled).

    Returns (stable (B,) bool, BatchResult)."""
    from warp_tensegrity import RunSettings, simulate_batch
    from warp_tensegrity.types import STABILITY

    m0 = cfg.unit_mass
    S = STABILITY[method]
    mass = m0 * (omega * dt0 / (np.asarray(r) * S)) ** 2
    params = dict(cases)
    params["unit_mass"] = mass
    params["v0"] = np.asarray(cases["v0"]) * np.sqrt(m0 / mass)
    s = RunSettings(t_end=n_steps * dt0, dt=dt0, method=method, precision=precision, output_interval=10 * dt0,
                    device=device, allow_unstable_dt=True, record_strain=False, **kw)
    res = simulate_batch(cfg, params, s)
    if res.n_steps != n_steps:
        raise RuntimeError(f"expected {n_steps} steps, got {res.n_steps}")
    return is_stable(res, criterion), res


def bisect_limits(cfg, cases, omega, method, n_steps, n_bisect, device, r_lo=R_LO, r_hi=R_HI, **kw):
    """Largest stable r = dt omega / S per case, by bisection on log r (all cases in each batch).

    Returns dict with r_stable (largest stable r found), r_unstable (smallest unstable r),
    bracket flag (0 inside; -1 unstable already at r_lo; +1 stable at r_hi), and the status and
    energy error at r_unstable."""
    B = len(omega)
    ok_lo, _ = run_at_ratio(cfg, cases, omega, np.full(B, r_lo), method, n_steps, device, **kw)
    ok_hi, res_hi = run_at_ratio(cfg, cases, omega, np.full(B, r_hi), method, n_steps, device, **kw)
    lo, hi = np.full(B, r_lo), np.full(B, r_hi)
    flag = np.where(~ok_lo, -1, np.where(ok_hi, 1, 0))
    fail_status = res_hi.status.copy()
    fail_energy = res_hi.energy_error.copy()
    fail_step = res_hi.fail_step.copy()
    for _ in range(n_bisect):
        mid = np.sqrt(lo * hi)
        ok, res = run_at_ratio(cfg, cases, omega, mid, method, n_steps, device, **kw)
        lo = np.where(ok, mid, lo)
        hi = np.where(ok, hi, mid)
        bad = ~ok
        fail_status[bad] = res.status[bad]
        fail_energy[bad] = res.energy_error[bad]
        fail_step[bad] = res.fail_step[bad]
    lo = np.where(flag == -1, np.nan, lo)
    hi = np.where(flag == 1, np.nan, hi)
    return dict(r_stable=lo, r_unstable=hi, flag=flag, fail_status=fail_status, fail_energy=fail_energy,
                fail_step=fail_step)


def verify_scaling(cfg, cases, omega, method, r_stable, r_unstable, n_steps, device, idx, criterion="energy"):
    """Unscaled columns (paper mass and v0) at the physical dt = r S / omega_c for
    r = 0.99 r_stable and 1.01 r_unstable: returns (B_idx, 2) stable flags (expected True, False)."""
    from warp_tensegrity import RunSettings, simulate_batch
    from warp_tensegrity.types import STABILITY

    out = np.zeros((len(idx), 2), dtype=bool)
    for a, c in enumerate(idx):
        if not (np.isfinite(r_stable[c]) and np.isfinite(r_unstable[c])):
            out[a] = (True, False)
            continue
        for b, r in enumerate((0.99 * r_stable[c], 1.01 * r_unstable[c])):
            dt = r * STABILITY[method] / omega[c]
            one = {k: v[c : c + 1] for k, v in cases.items()}
            s = RunSettings(t_end=n_steps * dt, dt=dt, method=method, output_interval=10 * dt, device=device,
                            allow_unstable_dt=True, record_strain=False)
            r = simulate_batch(cfg, one, s)
            out[a, b] = bool(is_stable(r, criterion)[0])
    return out


def energy_runs(device, t_end):
    """Energy error (E - E0)/KE0 against time for ENERGY_CASES, every run of ENERGY_RUNS at dt='auto'."""
    from warp_tensegrity import ColumnConfig, RunSettings, simulate_batch

    cfg = ColumnConfig(n_prisms=N_PRISMS)
    params = {k: np.array([c[i] for c in ENERGY_CASES]) for i, k in
              ((1, "prestrain"), (2, "v0"), (3, "base_rigidity"))}
    dev, dts, walls, steps, bars, stats, mins = [], [], [], [], [], [], []
    time_axis = None
    for method, prec in ENERGY_RUNS:
        s = RunSettings(t_end=t_end, dt="auto", method=method, precision=prec, output_interval=t_end / 2000,
                        device=device, record_strain=True)
        r = simulate_batch(cfg, params, s)
        E = r.kinetic_energy + r.elastic_energy
        dev.append((E - E[:, :1]) / r.kinetic_energy[:, :1])
        dts.append(r.dt)
        walls.append(r.wall_time)
        steps.append(r.n_steps)
        bars.append(r.bar_length_error)
        stats.append(r.status)
        mins.append(np.nanmin(r.strain, axis=(1, 2)))
        time_axis = r.time
        log(f"energy run {method} {prec}: dt {r.dt:.3g} s, {r.n_steps} steps, {r.wall_time:.1f} s, "
            f"max |dE|/KE0 {np.nanmax(np.abs(dev[-1]), axis=1)}")
    return dict(time=time_axis, dev=np.array(dev), dt=np.array(dts), wall=np.array(walls), steps=np.array(steps),
                bar=np.array(bars), status=np.array(stats), min_strain=np.array(mins))


def slack_history(t_end, dt=1e-3, stride=5):
    """Slack cross/base cables of ENERGY_CASES[0] (6 prisms) over time, by the NumPy reference (RK4 +
    projection, fp64): (time, n_slack, n_cables, transitions)."""
    from warp_tensegrity import ColumnConfig, build_column
    from tests.references.reference import ReferenceSystem

    _, p, v0, b = ENERGY_CASES[0]
    scene = build_column(ColumnConfig(n_prisms=N_PRISMS), p, v0, b)
    rs = ReferenceSystem(scene.network)
    t, x, _ = rs.integrate(scene.network.positions, scene.velocity, t_end, dt, stride=stride)
    tension_only = np.asarray(scene.network.cable_EA_compression) == 0
    slack = np.array([(rs.cable_forces(xi) <= 0) & tension_only for xi in x])
    transitions = int(np.abs(np.diff(slack.astype(int), axis=0)).sum())
    return t, slack.sum(axis=1), int(tension_only.sum()), transitions


def run_benchmark(device: str, quick: bool):
    import warp as wp
    import xarray as xr

    from warp_tensegrity import ColumnConfig
    from warp_tensegrity.types import STABILITY

    wp.config.quiet = True
    wp.init()
    setup = QUICK if quick else FULL
    t0 = time.perf_counter()
    cfg = ColumnConfig(n_prisms=N_PRISMS)
    cases = stability_cases()
    B = len(cases["v0"])
    w = omega_exact(cfg, cases)
    wb = omega_bound(cfg, cases)
    log(f"{B} cases, {N_PRISMS} prisms, omega_max {w.min():.1f}..{w.max():.1f} rad/s (bound {wb.min():.1f}..{wb.max():.1f})")

    M = len(METHODS)
    r_st, r_un = np.full((M, B), np.nan), np.full((M, B), np.nan)
    b_st, b_un, b_flag = np.full((M, B), np.nan), np.full((M, B), np.nan), np.zeros((M, B), dtype=np.int32)
    flag, fstat, fen, fstep = (np.zeros((M, B), dtype=np.int32), np.zeros((M, B), dtype=np.int32),
                               np.full((M, B), np.nan), np.zeros((M, B), dtype=np.int64))
    vidx = np.array([0, len(PRESTRAINS) - 1, B - 1])  # FB p=0 v0 small, FB p=0.02, RB p=0.01 v0=0.1
    verify = np.zeros((M, len(vidx), 2), dtype=bool)
    for im, method in enumerate(METHODS):
        res = bisect_limits(cfg, cases, w, method, setup["n_steps"], setup["n_bisect"], device)
        r_st[im], r_un[im], flag[im] = res["r_stable"], res["r_unstable"], res["flag"]
        fstat[im], fen[im], fstep[im] = res["fail_status"], res["fail_energy"], res["fail_step"]
        verify[im] = verify_scaling(cfg, cases, w, method, r_st[im], r_un[im], setup["n_steps"], device, vidx)
        rb = bisect_limits(cfg, cases, w, method, setup["n_steps"], setup["n_bisect"], device, criterion="blowup")
        b_st[im], b_un[im], b_flag[im] = rb["r_stable"], rb["r_unstable"], rb["flag"]
        ratio = r_st[im]
        log(f"{method:>16s}: measured/predicted limit min {np.nanmin(ratio):.3f} median {np.nanmedian(ratio):.3f} "
            f"max {np.nanmax(ratio):.3f}; out of bracket {np.count_nonzero(flag[im])}; "
            f"direct check ok {verify[im, :, 0].all() and not verify[im, :, 1].any()}")

    en = energy_runs(device, setup["energy_t_end"])
    ts, n_slack, n_tension_only, transitions = slack_history(setup["slack_t_end"])
    log(f"slack cables (FB p=0.002 v0=0.1, first {setup['slack_t_end']} s): up to {n_slack.max()} of "
        f"{n_tension_only}, {transitions} slack/taut transitions")

    S = np.array([STABILITY[m] for m in METHODS])
    ds = xr.Dataset(coords={
        "method": ("method", list(METHODS), {"long_name": "integrator"}),
        "case": ("case", np.arange(B), {"long_name": "stability case index"}),
        "prestrain": ("case", cases["prestrain"], {"long_name": "cross-cable prestrain", "units": "1"}),
        "v0": ("case", cases["v0"], {"long_name": "impact speed", "units": "m s-1"}),
        "base_rigidity": ("case", cases["base_rigidity"], {"long_name": "base rigidity (0 FB, 1 RB)", "units": "1"}),
        "verify_case": ("verify_case", vidx, {"long_name": "cases re-checked without mass scaling"}),
        "side": ("side", ["0.99 x largest stable", "1.01 x smallest unstable"], {"long_name": "dt of the direct check"}),
        "energy_case": ("energy_case", [c[0] for c in ENERGY_CASES], {"long_name": "long-run case"}),
        "run": ("run", [f"{m} {p}" for m, p in ENERGY_RUNS], {"long_name": "method and precision"}),
        "time": ("time", en["time"], {"long_name": "time", "units": "s"}),
        "slack_time": ("slack_time", ts, {"long_name": "time (NumPy reference)", "units": "s"}),
    })
    ds["omega_max"] = ("case", w, {"long_name": "omega_max of the reference network (all cables taut)", "units": "rad s-1"})
    ds["omega_bound"] = ("case", wb, {"long_name": "engine omega_max bound (Gershgorin)", "units": "rad s-1"})
    ds["stability_constant"] = ("method", S, {"long_name": "predicted omega dt limit S", "units": "1"})
    ds["dt_predicted"] = (("method", "case"), S[:, None] / w[None, :],
                          {"long_name": "predicted stability limit S / omega_max", "units": "s"})
    ds["dt_engine_limit"] = (("method", "case"), S[:, None] / wb[None, :],
                             {"long_name": "engine stability limit S / omega_bound", "units": "s"})
    ds["ratio_stable"] = (("method", "case"), r_st,
                          {"long_name": "largest stable dt found / predicted limit", "units": "1"})
    ds["ratio_unstable"] = (("method", "case"), r_un,
                            {"long_name": "smallest unstable dt found / predicted limit", "units": "1"})
    ds["dt_limit_measured"] = (("method", "case"), np.sqrt(r_st * r_un) * S[:, None] / w[None, :],
                               {"long_name": "measured stability limit (geometric mid of the bracket)", "units": "s"})
    ds["ratio_stable_blowup"] = (("method", "case"), b_st,
                                 {"long_name": f"largest dt without blow-up (status 0, energy error < {BLOWUP_ENERGY:g}) / predicted", "units": "1"})
    ds["ratio_unstable_blowup"] = (("method", "case"), b_un,
                                   {"long_name": "smallest dt with blow-up / predicted", "units": "1"})
    ds["bracket_flag_blowup"] = (("method", "case"), b_flag, {"long_name": "as bracket_flag, blow-up criterion"})
    ds["bracket_flag"] = (("method", "case"), flag,
                          {"long_name": "0 limit inside the bracket, -1 unstable at its low end, +1 stable at its high end"})
    ds["fail_status"] = (("method", "case"), fstat, {"long_name": "status at the smallest unstable dt (0: energy criterion only)"})
    ds["fail_energy_error"] = (("method", "case"), fen, {"long_name": "energy error at the smallest unstable dt", "units": "1"})
    ds["fail_step"] = (("method", "case"), fstep, {"long_name": "step at which the unstable run was frozen (-1: not frozen)"})
    ds["verify_stable"] = (("method", "verify_case", "side"), verify.astype(np.int8),
                           {"long_name": "unscaled run at the physical dt is stable (expect 1, 0)"})
    ds["energy_deviation"] = (("run", "energy_case", "time"), en["dev"],
                              {"long_name": "(E - E0) / KE0", "units": "1"})
    ds["energy_dt"] = ("run", en["dt"], {"long_name": "time step (dt='auto')", "units": "s"})
    ds["energy_steps"] = ("run", en["steps"], {"long_name": "steps of the long run", "units": "1"})
    ds["energy_wall"] = ("run", en["wall"], {"long_name": "device stepping time of the long run", "units": "s"})
    ds["energy_bar_error"] = (("run", "energy_case"), en["bar"], {"long_name": "max bar-length error", "units": "1"})
    ds["energy_status"] = (("run", "energy_case"), en["status"], {"long_name": "column status"})
    ds["energy_min_strain"] = (("run", "energy_case"), en["min_strain"],
                               {"long_name": "most compressive prism strain of the run", "units": "1"})
    ds["n_slack"] = ("slack_time", n_slack, {"long_name": "slack tension-only cables, FB p=0.002 v0=0.1", "units": "1"})
    ds.attrs.update({
        "title": "warp_tensegrity integrator stability",
        "device": device,
        "mode": "quick" if quick else "full",
        "n_prisms": N_PRISMS,
        "n_steps": setup["n_steps"],
        "n_bisect": setup["n_bisect"],
        "bracket": f"r in [{R_LO}, {R_HI}] x predicted",
        "stability_criterion": "status 0 and energy_error < 1 over n_steps steps",
        "blowup_criterion": f"status 0 and energy_error < {BLOWUP_ENERGY:g} over n_steps steps",
        "energy_t_end_s": setup["energy_t_end"],
        "n_tension_only_cables": n_tension_only,
        "slack_transitions": transitions,
        "warp_version": wp.config.version,
        "created": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        "total_wall_s": time.perf_counter() - t0,
        "Conventions": "CF-1.8",
    })
    log(f"done in {time.perf_counter() - t0:.1f} s")
    return ds


# ---------------------------------------------------------------------------- figures
def _envelope(t, y, n_win=100):
    """Max of y over n_win consecutive windows, at the window centres."""
    n = len(y) // n_win * n_win
    if n == 0:
        return t, y
    return t[:n].reshape(n_win, -1).mean(axis=1), np.nanmax(y[:n].reshape(n_win, -1), axis=1)


def plot(ds, fig_dir: Path, tag: str):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig_dir.mkdir(parents=True, exist_ok=True)
    paths = []
    methods = list(ds.method.values)
    v0 = ds.v0.values
    p = ds.prestrain.values
    b = ds.base_rigidity.values
    small = np.isclose(v0, V0_SMALL)

    fig, axes = plt.subplots(3, len(methods), figsize=(4.0 * len(methods), 10.5), squeeze=False)
    for im, m in enumerate(methods):
        rs = ds.ratio_stable.sel({"method": m}).values
        ru = ds.ratio_unstable.sel({"method": m}).values
        mid = np.sqrt(rs * ru)
        eng = (ds.dt_engine_limit / ds.dt_predicted).sel({"method": m}).values
        blow = np.sqrt(ds.ratio_stable_blowup.sel({"method": m}).values * ds.ratio_unstable_blowup.sel({"method": m}).values)
        # row 0: parity, measured vs predicted dt
        ax = axes[0, im]
        dp = ds.dt_predicted.sel({"method": m}).values
        dm = ds.dt_limit_measured.sel({"method": m}).values
        sc = ax.scatter(dp * 1e3, dm * 1e3, c=np.log10(v0), cmap="viridis", s=14)
        lim = np.array([np.nanmin(dp), np.nanmax(dp)]) * 1e3
        ax.plot(lim, lim, "k-", lw=0.8, label="measured = S/omega_max")
        ax.plot(lim, lim * 1.1, "k:", lw=0.8, label="+-10 %")
        ax.plot(lim, lim / 1.1, "k:", lw=0.8)
        ax.set_xlabel("predicted S/omega_max [ms]")
        ax.set_ylabel("measured largest stable dt [ms]")
        ax.set_title(f"{m} (S = {float(ds.stability_constant.sel({'method': m})):.4g})")
        ax.legend(fontsize=7)
        if im == len(methods) - 1:
            fig.colorbar(sc, ax=ax, label="log10 v0 [m/s]")
        # row 1: ratio against prestrain at small v0
        ax = axes[1, im]
        for beta, mk in zip(RIGIDITIES, ("o", "s", "^")):
            sel = small & np.isclose(b, beta)
            o = np.argsort(p[sel])
            ln, = ax.plot(np.maximum(p[sel][o], 1e-4), mid[sel][o], marker=mk, label=f"beta={beta:g}")
            ax.plot(np.maximum(p[sel][o], 1e-4), blow[sel][o], marker=mk, mfc="none", ls=":", color=ln.get_color())
            ax.plot(np.maximum(p[sel][o], 1e-4), eng[sel][o], ls="--", color="gray", lw=0.8)
        ax.axhline(1.0, color="k", lw=0.8)
        ax.set_xscale("log")
        ax.set_xlabel("prestrain (0 plotted at 1e-4)")
        ax.set_ylabel("measured / predicted limit")
        ax.set_title(f"v0 = {V0_SMALL:g} m/s; dotted/hollow: no blow-up; dashed: engine", fontsize=9)
        ax.legend(fontsize=7)
        # row 2: ratio against v0
        ax = axes[2, im]
        for (pp, beta), (ls, mk) in zip(itertools.product(V0_PRESTRAINS, V0_RIGIDITIES),
                                        itertools.cycle([("-", "o"), ("--", "s")])):
            sel = np.isclose(p, pp) & np.isclose(b, beta) & np.isin(v0, V0S)
            o = np.argsort(v0[sel])
            ln, = ax.plot(v0[sel][o], mid[sel][o], ls=ls, marker=mk, label=f"p={pp:g} {'RB' if beta == 1 else 'FB'}")
            ax.plot(v0[sel][o], blow[sel][o], ls=":", marker=mk, mfc="none", color=ln.get_color(), lw=0.8)
        ax.axhline(1.0, color="k", lw=0.8)
        ax.set_xscale("log")
        ax.set_xlabel("v0 [m/s]")
        ax.set_ylabel("measured / predicted limit")
        ax.set_title("solid: |E-E0| < KE0; dotted/hollow: no blow-up", fontsize=9)
        ax.legend(fontsize=7)
    fig.suptitle(f"Largest stable dt ({ds.attrs['n_prisms']} prisms, {ds.attrs['n_steps']} steps, "
                 f"stable = status 0 and |E-E0| < KE0), {ds.attrs['device']}", fontsize=10)
    fig.tight_layout(rect=(0, 0, 1, 0.97))
    path = fig_dir / f"stab_limit_{tag}.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    paths.append(path)

    # energy against time
    ec = list(ds.energy_case.values)
    fig, axes = plt.subplots(1, len(ec) + 1, figsize=(4.6 * (len(ec) + 1), 4.2), squeeze=False)
    t = ds.time.values
    for ic, case in enumerate(ec):
        ax = axes[0, ic]
        for run in ds.run.values:
            y = np.abs(ds.energy_deviation.sel(run=run, energy_case=case).values)
            m, prec = run.split()
            tw, yw = _envelope(t, y)
            ok = np.isfinite(yw) & (yw > 0)
            ax.plot(tw[ok], yw[ok], color=COLORS[m], ls="-" if prec == "fp64" else ":", lw=1.0,
                    label=f"{run} (dt {float(ds.energy_dt.sel(run=run)) * 1e3:.2f} ms)")
        ax.set_yscale("log")
        ax.set_xlabel("time [s]")
        ax.set_ylabel("|E - E0| / KE0 (max over 1/100 of the run)")
        ax.set_title(case, fontsize=9)
        ax.grid(True, alpha=0.3)
        if ic == 0:
            ax.legend(fontsize=7)
    ax = axes[0, -1]
    ax.plot(ds.slack_time.values, ds.n_slack.values, "k-", lw=0.8)
    ax.set_xlabel("time [s]")
    ax.set_ylabel(f"slack cables (of {ds.attrs['n_tension_only_cables']})")
    ax.set_title(f"{ec[0]}: {ds.attrs['slack_transitions']} slack/taut switches", fontsize=9)
    fig.suptitle(f"Energy error over long runs at dt='auto' ({ds.attrs['n_prisms']} prisms)", fontsize=10)
    fig.tight_layout(rect=(0, 0, 1, 0.94))
    path = fig_dir / f"stab_energy_{tag}.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    paths.append(path)
    return paths


def summary(ds) -> str:
    lines = [f"stability ({ds.attrs['mode']}, {ds.attrs['device']}), {ds.sizes['case']} cases, "
             f"{ds.attrs['n_steps']} steps, total {ds.attrs['total_wall_s']:.1f} s"]
    v0, p, b = ds.v0.values, ds.prestrain.values, ds.base_rigidity.values
    for m in ds.method.values:
        rs = ds.ratio_stable.sel({"method": m}).values
        ru = ds.ratio_unstable.sel({"method": m}).values
        mid = np.sqrt(rs * ru)
        small = np.isclose(v0, V0_SMALL)
        taut = small & (p > 0)
        lines.append(
            f"{m:>16s}: measured/predicted, v0 small & p>0: {np.nanmin(mid[taut]):.3f}..{np.nanmax(mid[taut]):.3f}; "
            f"p=0: {np.nanmin(mid[small & (p == 0)]):.3f}..{np.nanmax(mid[small & (p == 0)]):.3f}; "
            f"all: {np.nanmin(mid):.3f}..{np.nanmax(mid):.3f}; out of bracket {int(np.count_nonzero(ds.bracket_flag.sel({'method': m}).values))}; "
            f"engine limit / predicted {float((ds.dt_engine_limit / ds.dt_predicted).sel({'method': m}).min()):.3f}.."
            f"{float((ds.dt_engine_limit / ds.dt_predicted).sel({'method': m}).max()):.3f}; "
            f"direct check {ds.verify_stable.sel({'method': m}).values.tolist()}")
        bm = np.sqrt(ds.ratio_stable_blowup.sel({"method": m}).values * ds.ratio_unstable_blowup.sel({"method": m}).values)
        lines.append(f"{'':>16s}  blow-up criterion: v0 small & p>0: {np.nanmin(bm[taut]):.3f}..{np.nanmax(bm[taut]):.3f}; "
                     f"p=0: {np.nanmin(bm[small & (p == 0)]):.3f}..{np.nanmax(bm[small & (p == 0)]):.3f}; "
                     f"all: {np.nanmin(bm):.3f}..{np.nanmax(bm):.3f}; out of bracket "
                     f"{int(np.count_nonzero(ds.bracket_flag_blowup.sel({'method': m}).values))}")
    lines.append("v0 sweep (measured/predicted), rows p,beta; columns v0 = " + " ".join(f"{x:g}" for x in V0S))
    for m in ds.method.values:
        mid = np.sqrt(ds.ratio_stable.sel({"method": m}).values * ds.ratio_unstable.sel({"method": m}).values)
        for pp, bb in itertools.product(V0_PRESTRAINS, V0_RIGIDITIES):
            row = []
            for vv in V0S:
                sel = np.flatnonzero(np.isclose(p, pp) & np.isclose(b, bb) & np.isclose(v0, vv))
                row.append(mid[sel[0]] if len(sel) else np.nan)
            lines.append(f"  {m:>16s} p={pp:<6g} beta={bb:g}: " + " ".join(f"{x:6.3f}" for x in row))
    for run in ds.run.values:
        d = np.abs(ds.energy_deviation.sel(run=run).values)
        n = d.shape[1]
        q = n // 4
        lines.append(f"energy {run:>22s}: dt {float(ds.energy_dt.sel(run=run)):.3g} s, "
                     + "; ".join(f"{c}: max {np.nanmax(d[i]):.1e} (1st quarter {np.nanmax(d[i, :q]):.1e}, "
                                 f"last {np.nanmax(d[i, -q:]):.1e})" for i, c in enumerate(ds.energy_case.values)))
    return "\n".join(lines)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--device", default=None)
    ap.add_argument("--out", default="analysis")
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--plot-only", metavar="DIR")
    a = ap.parse_args(argv)
    import xarray as xr

    if a.plot_only:
        root = Path(a.plot_only)
        files = sorted((root / "data").glob("stab_*.nc"))
        if not files:
            raise SystemExit(f"no stab_*.nc under {root / 'data'}")
        for f in files:
            with xr.open_dataset(f, engine="netcdf4") as ds:
                ds = ds.load()
            for path in plot(ds, root / "figures", f.stem[len("stab_"):]):
                print(path)
            print(summary(ds))
        return
    if a.device is None:
        import warp as wp

        wp.config.quiet = True
        a.device = "cuda:0" if wp.get_cuda_device_count() > 0 else "cpu"
    root = Path(a.out)
    ds = run_benchmark(a.device, a.quick)
    save_study(ds, root, "stab", device_tag(a.device) + ("_quick" if a.quick else ""), plot, summary)


if __name__ == "__main__":
    main()
