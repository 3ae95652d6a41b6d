"""Work-precision of the engine's integrators on the paper's impact problem.

For each method (rattle, rk4, yoshida4, symplectic_euler) and precision (fp32, fp64), sweep
the time step and measure the error against a float64 reference, together with the cost.
The four cases of the paper (FB/RB, p = 0 with v0 = 0.005 m/s and p = 0.002 with v0 = 0.1 m/s)
share ONE batch per (method, precision, dt); on a GPU each case is repeated ``--replicas``
times (default 256) so the batch fills the device, and the cost is divided by the batch size.

* Column: 12 prisms, t_end = 1.44 s (the pulse passes mid-column in all four cases). A GPU
  step of this engine is latency-bound (each column's bars are projected in one thread), so
  the cost grows as n_prisms^2; 12 prisms keep the H100 run under 4 minutes.
* Reference: float64 RK4 at dt = output_interval / k_ref, cross-checked against float64
  yoshida4 at the same dt (their disagreement is stored and plotted as the reference floor).
  Computed on the CPU (``--ref-device``) and kept in ``OUT/data/wp_ref_<mode>.nc`` (or
  ``--ref FILE``), which later runs read instead of recomputing.
* Error measures (relative to the reference unless stated), first copy of each case:
  - pulse speed (time of flight, :func:`warp_tensegrity.measure.measure_pulse`) over a prism
    window clear of the clamp and of the impact end, with the threshold measure_pulse picks on
    the reference held fixed for every run,
  - far-prism peak amplitude: leading-peak strain at the window prism farthest from the impact,
  - final state: max_nodes |u - u_ref| / max_nodes |u_ref| at t_end (and the same for v),
  - maximum bar-length error |l - L| / L over every step (absolute, no reference).
* Cost: device seconds per simulated second per column (wall_time / (t_end * B)) and force
  evaluations per simulated second (n_steps * force_evaluations_per_step / t_end).
  All dt divide the output interval, so every run samples the strain at the same times and
  the pulse measurement is the same function of the samples.

Usage::

    python -m benchmarks.work_precision --reference-only --out analysis       # CPU, ~40 s, once
    python -m benchmarks.work_precision --device cuda:0 --out analysis        # GPU (full)
    python -m benchmarks.work_precision --device cpu --out /tmp/wp --quick    # CPU check
    python -m benchmarks.work_precision --plot-only analysis                  # figures only

Writes ``OUT/data/wp_<device>.nc`` (xarray, netCDF4, CF attributes) and
``OUT/figures/wp_*_<device>.png``.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import sys
import time
from pathlib import Path

import numpy as np

from .common import device_tag, save_study

METHODS = ("rattle", "rk4", "yoshida4", "symplectic_euler")
PRECISIONS = ("fp64", "fp32")
# name, prestrain, v0 [m/s], base_rigidity: the paper's FB/RB columns, weak impact at p = 0
# (sonic vacuum) and strong impact at p = 0.002 (cables slacken and re-tighten)
CASES = (
    ("FB p=0", 0.0, 0.005, 0.0),
    ("RB p=0", 0.0, 0.005, 1.0),
    ("FB p=0.002", 0.002, 0.1, 0.0),
    ("RB p=0.002", 0.002, 0.1, 1.0),
)
# 12 prisms: the engine projects each column's bars serially in one thread, so a step of a
# 12-prism batch takes ~1.5-5 ms on an H100 whatever the batch size (30 prisms: 2.5x that);
# 12 prisms and t_end 1.44 s keep the GPU run under 4 minutes (see analysis/work_precision.md)
FULL = dict(n_prisms=12, t_end=1.44, output_interval=0.012, ks=(1, 2, 4, 6, 8, 16), k_ref=256)
QUICK = dict(n_prisms=12, t_end=1.44, output_interval=0.012, ks=(1, 2, 4, 8, 16), k_ref=96)
MEASURES = ("speed", "amplitude", "state", "velocity", "bar")
MEASURE_LABEL = {
    "speed": "pulse speed, relative error",
    "amplitude": "far-prism peak amplitude, relative error",
    "state": "final displacement, relative max error",
    "velocity": "final velocity, relative max error",
    "bar": "max bar-length error |l-L|/L",
}
COLORS = {"rattle": "C0", "rk4": "C1", "yoshida4": "C2", "symplectic_euler": "C3"}


def log(msg: str):
    print(f"[work_precision {time.strftime('%H:%M:%S')}] {msg}", file=sys.stderr, flush=True)


# ---------------------------------------------------------------------------- running
def _params(replicas=1):
    """The cases, repeated ``replicas`` times (copies are bitwise identical columns)."""
    return {
        "prestrain": np.tile([c[1] for c in CASES], replicas),
        "v0": np.tile([c[2] for c in CASES], replicas),
        "base_rigidity": np.tile([c[3] for c in CASES], replicas),
    }


def _run(cfg, setup, method, precision, dt, device, replicas=1):
    from warp_tensegrity import RunSettings, simulate_batch

    s = RunSettings(t_end=setup["t_end"], dt=dt, method=method, precision=precision,
                    output_interval=setup["output_interval"], device=device, allow_unstable_dt=True)
    r = simulate_batch(cfg, _params(replicas), s)
    if not np.allclose(r.time[-1], setup["t_end"], rtol=1e-9) or r.strain.shape[1] != len(r.time):
        raise RuntimeError(f"{method} {precision} dt={r.dt}: outputs do not end at t_end ({r.time[-1]})")
    return r


def _windows(ref_strain, time, n_prisms, t_end, height):
    """Per case, from the reference: the arrival threshold and the (lo, hi) prism window.

    The threshold is the one measure_pulse picks for the reference record (adaptive); every run
    is then measured with that same fixed threshold, so the measures are one function of the
    strain samples. hi = n - max(2, default_skip(n)) (the pulse has formed); lo = n // 4 (the
    incoming pulse, clear of its reflection at the clamp), raised until the reference's leading
    peaks in [lo, hi) are complete by 0.8 t_end (at least 3 prisms are kept)."""
    from warp_tensegrity.measure import default_skip, measure_pulse, peak_track

    hi = n_prisms - max(2, default_skip(n_prisms))
    out = []
    for c in range(ref_strain.shape[0]):
        thr = float(measure_pulse(ref_strain[c], time, height)["threshold"])
        tp = peak_track(ref_strain[c], time, threshold=thr).time
        lo = max(default_skip(n_prisms), n_prisms // 4)
        while lo < hi - 3 and not (np.all(np.isfinite(tp[lo:hi])) and tp[lo] <= 0.8 * t_end):
            lo += 1
        out.append((lo, hi, thr))
    return out


def _measures(r, windows, height):
    """(4,) pulse speed and far-prism peak amplitude, (4, n, 3) final displacement and velocity
    of the first copy of each case."""
    from warp_tensegrity.measure import measure_pulse

    B = len(CASES)
    speed, amp = np.full(B, np.nan), np.full(B, np.nan)
    n = r.strain.shape[2]
    for c in range(B):
        lo, hi, thr = windows[c]
        m = measure_pulse(r.strain[c], r.time, height, threshold=thr, skip_impact=n - hi, skip_clamp=lo)
        speed[c] = m["speed"]
        amp[c] = m["peak_value"][lo]
    bad = r.status[:B] != 0
    u = r.final_displacement[:B].copy()
    u[bad] = np.nan
    v = r.final_velocity[:B].copy()
    v[bad] = np.nan
    return speed, amp, u, v


def _asymmetry(u):
    """(B,) largest lateral displacement of a base centroid over max |u|: the impact is axially
    symmetric, so this is motion seeded by round-off and amplified (lateral buckling of FB columns)."""
    B = u.shape[0]
    cen = u.reshape(B, -1, 3, 3).mean(axis=2)  # (B, levels, xyz): nodes 3l..3l+2 form level l
    with np.errstate(invalid="ignore"):
        return np.abs(cen[..., :2]).max(axis=(1, 2)) / np.abs(u).max(axis=(1, 2))


def _rel(a, b):
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.abs(a - b) / np.abs(b)


def _state_err(u, uref):
    with np.errstate(invalid="ignore"):
        return np.abs(u - uref).max(axis=(1, 2)) / np.abs(uref).max(axis=(1, 2))


REF_KEYS = ("strain", "final_displacement", "final_velocity", "status", "bar_length_error", "energy_error")


def _setup_attrs(setup):
    return {"n_prisms": setup["n_prisms"], "t_end_s": setup["t_end"], "output_interval_s": setup["output_interval"],
            "k_ref": setup["k_ref"], "cases": repr(CASES)}


def compute_reference(setup, device):
    """float64 RK4 and yoshida4 at dt = output_interval / k_ref: (ref, chk), objects with the
    BatchResult fields the measures use."""
    from warp_tensegrity import ColumnConfig

    cfg = ColumnConfig(n_prisms=setup["n_prisms"])
    dt = setup["output_interval"] / setup["k_ref"]
    ref = _run(cfg, setup, "rk4", "fp64", dt, device)
    chk = _run(cfg, setup, "yoshida4", "fp64", dt, device)
    if np.any(ref.status) or np.any(chk.status):
        raise RuntimeError(f"reference failed: status {ref.status}, check {chk.status}")
    return ref, chk


def save_reference(path: Path, setup, ref, chk):
    import xarray as xr

    data = {}
    for tag, r in (("rk4", ref), ("yoshida4", chk)):
        data[f"{tag}_strain"] = (("case", "time", "prism"), r.strain)
        for k in ("final_displacement", "final_velocity"):
            data[f"{tag}_{k}"] = (("case", "node", "xyz"), getattr(r, k))
        for k in ("status", "bar_length_error", "energy_error"):
            data[f"{tag}_{k}"] = ("case", getattr(r, k))
    ds = xr.Dataset(data, coords={"time": ("time", ref.time, {"units": "s", "long_name": "time"})})
    ds.attrs.update(_setup_attrs(setup) | {"device": ref.device, "device_name": ref.device_name,
                                           "omega_max_bound": ref.info["omega_max_bound"],
                                           "title": "work-precision reference: float64 rk4 and yoshida4"})
    path.parent.mkdir(parents=True, exist_ok=True)
    ds.to_netcdf(path, engine="netcdf4")


def load_reference(path: Path, setup):
    """(ref, chk) from a file written by save_reference for the same setup, else None."""
    import types

    import xarray as xr

    if not path.exists():
        return None
    with xr.open_dataset(path, engine="netcdf4") as ds:
        ds = ds.load()
    want = _setup_attrs(setup)
    if any(ds.attrs.get(k) != v and not (isinstance(v, float) and np.isclose(ds.attrs.get(k, np.nan), v))
           for k, v in want.items()):
        log(f"{path}: made for another setup; recomputing the reference")
        return None
    out = []
    for tag in ("rk4", "yoshida4"):
        fields = {k: ds[f"{tag}_{k}"].values for k in REF_KEYS}
        out.append(types.SimpleNamespace(time=ds.time.values, device=ds.attrs["device"],
                                         device_name=ds.attrs["device_name"], wall_time=0.0,
                                         info={"omega_max_bound": float(ds.attrs["omega_max_bound"])}, **fields))
    return tuple(out)


def run_benchmark(device: str, quick: bool, replicas: int = 1, ref_device: str = "cpu",
                  ref_path: Path | None = None) -> "xarray.Dataset":  # noqa: F821
    """All runs; every (method, precision, dt) is one batch of the 4 cases x ``replicas``.

    The cost is divided by the batch size 4 x replicas (on a GPU a batch of 4 leaves it idle).
    The reference is read from ``ref_path`` if that file holds one for this setup, else computed
    on ``ref_device`` (float64; the CPU is faster than a GPU for 4 columns) and saved there."""
    import warp as wp
    import xarray as xr

    from warp_tensegrity import ColumnConfig
    from warp_tensegrity.types import FORCE_EVALS, STABILITY

    wp.config.quiet = True
    wp.init()
    setup = QUICK if quick else FULL
    cfg = ColumnConfig(n_prisms=setup["n_prisms"])
    T, dout, ks, kref = setup["t_end"], setup["output_interval"], setup["ks"], setup["k_ref"]
    B = len(CASES) * replicas
    t_start = time.perf_counter()

    # ---- reference and its cross-check
    log(f"device {device}, {'quick' if quick else 'full'}: {cfg.n_prisms} prisms, t_end {T} s, reference dt {dout / kref:.3g} s")
    loaded = load_reference(ref_path, setup) if ref_path is not None else None
    if loaded is not None:
        ref, chk = loaded
        log(f"reference read from {ref_path} (computed on {ref.device_name})")
    else:
        try:
            ref, chk = compute_reference(setup, ref_device)
        except Exception as exc:  # e.g. a Warp install without its CPU compiler on a GPU machine
            if ref_device == device:
                raise
            log(f"reference on {ref_device} failed ({exc!r}); computing it on {device} (slow for 4 columns)")
            ref, chk = compute_reference(setup, device)
        if ref_path is not None:
            save_reference(ref_path, setup, ref, chk)
    windows = _windows(ref.strain, ref.time, cfg.n_prisms, T, cfg.height)
    sp_ref, amp_ref, u_ref, v_ref = _measures(ref, windows, cfg.height)
    sp_chk, amp_chk, u_chk, v_chk = _measures(chk, windows, cfg.height)
    log(f"reference done ({ref.wall_time + chk.wall_time:.1f} s stepping): speeds {np.round(sp_ref, 4)} m/s, "
        f"windows {windows}")

    nc = len(CASES)
    shape = (len(METHODS), len(PRECISIONS), len(ks), nc)
    err = {k: np.full(shape, np.nan) for k in MEASURES}
    energy = np.full(shape, np.nan)
    asym = np.full(shape, np.nan)
    status = np.zeros(shape, dtype=np.int32)
    wall = np.full(shape[:3], np.nan)
    nsteps = np.zeros(shape[:3], dtype=np.int64)
    a_shape = (len(METHODS), len(PRECISIONS), nc)
    a_err = {k: np.full(a_shape, np.nan) for k in MEASURES}
    a_energy = np.full(a_shape, np.nan)
    a_status = np.zeros(a_shape, dtype=np.int32)
    a_wall = np.full(a_shape[:2], np.nan)
    a_dt = np.full(a_shape[:2], np.nan)
    a_nsteps = np.zeros(a_shape[:2], dtype=np.int64)
    dt_limit = np.full(len(METHODS), np.nan)
    copies_identical = True
    device_name = None

    def fill(r, e, en, st):
        sp, amp, u, v = _measures(r, windows, cfg.height)
        e["speed"][...] = _rel(sp, sp_ref)
        e["amplitude"][...] = _rel(amp, amp_ref)
        e["state"][...] = _state_err(u, u_ref)
        e["velocity"][...] = _state_err(v, v_ref)
        ok = r.status[:nc] == 0
        e["bar"][...] = np.where(ok, r.bar_length_error[:nc], np.nan)
        en[...] = np.where(ok, r.energy_error[:nc], np.nan)
        st[...] = r.status[:nc]

    for im, method in enumerate(METHODS):
        for ip, prec in enumerate(PRECISIONS):
            for ik, k in enumerate(ks):
                r = _run(cfg, setup, method, prec, dout / k, device, replicas)
                device_name = r.device_name
                if replicas > 1:  # the copies of a case must be the same column
                    copies_identical &= bool(np.array_equal(r.strain[:nc], r.strain[-nc:], equal_nan=True))
                fill(r, {m: err[m][im, ip, ik] for m in MEASURES}, energy[im, ip, ik], status[im, ip, ik])
                asym[im, ip, ik] = np.where(r.status[:nc] == 0, _asymmetry(r.final_displacement[:nc]), np.nan)
                wall[im, ip, ik] = r.wall_time
                nsteps[im, ip, ik] = r.n_steps
                dt_limit[im] = r.dt_limit
            # the engine's own choice: dt = 'auto' (0.25 x the stability limit from the omega bound)
            r = _run(cfg, setup, method, prec, "auto", device, replicas)
            fill(r, {m: a_err[m][im, ip] for m in MEASURES}, a_energy[im, ip], a_status[im, ip])
            a_wall[im, ip], a_dt[im, ip], a_nsteps[im, ip] = r.wall_time, r.dt, r.n_steps
            log(f"{method:>16s} {prec}: stepping {wall[im, ip].sum() + a_wall[im, ip]:.1f} s, "
                f"failed dt {[ks[i] for i in range(len(ks)) if status[im, ip, i].any()]}, "
                f"speed err at k={ks[len(ks) // 2]}: {' '.join(f'{x:.1e}' for x in err['speed'][im, ip, len(ks) // 2])}")

    fe = np.array([FORCE_EVALS[m] for m in METHODS])
    dts = dout / np.array(ks, dtype=float)
    case = [c[0] for c in CASES]
    dims4 = ("method", "precision", "k", "case")
    ds = xr.Dataset(
        coords={
            "method": ("method", list(METHODS), {"long_name": "integrator"}),
            "precision": ("precision", list(PRECISIONS), {"long_name": "floating-point precision"}),
            "k": ("k", np.array(ks, dtype=np.int64), {"long_name": "steps per output interval", "units": "1"}),
            "case": ("case", case, {"long_name": "column case"}),
            "prestrain": ("case", [c[1] for c in CASES], {"long_name": "cross-cable prestrain", "units": "1"}),
            "v0": ("case", [c[2] for c in CASES], {"long_name": "impact speed", "units": "m s-1"}),
            "base_rigidity": ("case", [c[3] for c in CASES], {"long_name": "base rigidity (0 FB, 1 RB)", "units": "1"}),
        }
    )
    ds["dt"] = ("k", dts, {"long_name": "time step", "units": "s"})
    ds["omega_dt_bound"] = (("method", "k"), np.outer(np.full(len(METHODS), ref.info["omega_max_bound"]), dts),
                            {"long_name": "omega_max bound times dt", "units": "1"})
    for m in MEASURES:
        ds[f"err_{m}"] = (dims4, err[m], {"long_name": MEASURE_LABEL[m], "units": "1"})
        ds[f"auto_err_{m}"] = (("method", "precision", "case"), a_err[m],
                               {"long_name": MEASURE_LABEL[m] + " at dt='auto'", "units": "1"})
    ds["energy_error"] = (dims4, energy, {"long_name": "max |E - E0| / KE0 over outputs", "units": "1"})
    ds["auto_energy_error"] = (("method", "precision", "case"), a_energy,
                               {"long_name": "max |E - E0| / KE0 at dt='auto'", "units": "1"})
    ds["asymmetry"] = (dims4, asym, {"long_name": "max lateral base-centroid displacement / max |u| at t_end "
                                            "(symmetry breaking seeded by round-off)", "units": "1"})
    ds["ref_asymmetry"] = ("case", _asymmetry(ref.final_displacement),
                           {"long_name": "reference: max lateral base-centroid displacement / max |u|", "units": "1"})
    ds["status"] = (dims4, status, {"long_name": "column status (0 ok, 1 non-finite, 2 constraint failed)"})
    ds["auto_status"] = (("method", "precision", "case"), a_status, {"long_name": "column status at dt='auto'"})
    ds["wall_time"] = (dims4[:3], wall, {"long_name": "device stepping time of the batch", "units": "s"})
    ds["n_steps"] = (dims4[:3], nsteps, {"long_name": "time steps", "units": "1"})
    ds["cost_device"] = (dims4[:3], wall / (T * B),
                         {"long_name": "device time per simulated second per column", "units": "s s-1"})
    ds["force_evals"] = (dims4[:3], nsteps * fe[:, None, None] / T,
                         {"long_name": "force evaluations per simulated second", "units": "s-1"})
    ds["auto_dt"] = (("method", "precision"), a_dt, {"long_name": "time step chosen by dt='auto'", "units": "s"})
    ds["auto_cost_device"] = (("method", "precision"), a_wall / (T * B),
                              {"long_name": "device time per simulated second per column at dt='auto'", "units": "s s-1"})
    ds["auto_force_evals"] = (("method", "precision"), a_nsteps * fe[:, None] / T,
                              {"long_name": "force evaluations per simulated second at dt='auto'", "units": "s-1"})
    ds["engine_dt_limit"] = ("method", dt_limit, {"long_name": "engine stability limit S/omega_bound", "units": "s"})
    ds["stability_constant"] = ("method", [STABILITY[m] for m in METHODS],
                                {"long_name": "omega dt stability limit S", "units": "1"})
    ds["ref_speed"] = ("case", sp_ref, {"long_name": "reference pulse speed", "units": "m s-1"})
    ds["ref_amplitude"] = ("case", amp_ref, {"long_name": "reference far-prism peak strain", "units": "1"})
    ds["ref_check_speed"] = ("case", _rel(sp_chk, sp_ref),
                             {"long_name": "reference rk4 vs yoshida4: pulse speed relative difference", "units": "1"})
    ds["ref_check_amplitude"] = ("case", _rel(amp_chk, amp_ref),
                                 {"long_name": "reference rk4 vs yoshida4: amplitude relative difference", "units": "1"})
    ds["ref_check_state"] = ("case", _state_err(u_chk, u_ref),
                             {"long_name": "reference rk4 vs yoshida4: final displacement relative difference", "units": "1"})
    ds["ref_check_velocity"] = ("case", _state_err(v_chk, v_ref),
                                {"long_name": "reference rk4 vs yoshida4: final velocity relative difference", "units": "1"})
    ds["ref_bar_error"] = ("case", ref.bar_length_error, {"long_name": "reference max bar-length error", "units": "1"})
    ds["ref_energy_error"] = ("case", ref.energy_error, {"long_name": "reference max |E - E0| / KE0", "units": "1"})
    ds["window_lo"] = ("case", [w[0] for w in windows], {"long_name": "first prism of the measurement window", "units": "1"})
    ds["threshold"] = ("case", [w[2] for w in windows],
                       {"long_name": "arrival threshold (measure_pulse's choice on the reference), used for every run", "units": "1"})
    ds["window_hi"] = ("case", [w[1] for w in windows], {"long_name": "end (exclusive) of the measurement window", "units": "1"})
    ds.attrs.update({
        "title": "warp_tensegrity work-precision",
        "device": device,
        "device_name": device_name,
        "reference_device": ref.device,
        "replicas": replicas,
        "copies_identical": int(copies_identical),
        "mode": "quick" if quick else "full",
        "n_prisms": cfg.n_prisms,
        "columns_per_batch": B,
        "cost_note": "cost = batch wall time / (t_end * columns_per_batch); every case repeated 'replicas' times",
        "t_end_s": T,
        "output_interval_s": dout,
        "k_ref": kref,
        "reference": f"rk4 fp64 at dt = {dout / kref:.6g} s; check: yoshida4 fp64 at the same dt",
        "omega_max_bound": ref.info["omega_max_bound"],
        "warp_version": wp.config.version,
        "created": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        "total_wall_s": time.perf_counter() - t_start,
        "Conventions": "CF-1.8",
    })
    log(f"done in {time.perf_counter() - t_start:.1f} s")
    return ds


# ---------------------------------------------------------------------------- figures
def plot(ds, fig_dir: Path, tag: str) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig_dir.mkdir(parents=True, exist_ok=True)
    paths = []
    cases = list(ds.case.values)
    costs = (("force_evals", "force evaluations per simulated second"),
             ("cost_device", f"device s per simulated s per column ({ds.attrs.get('device_name', '')})"))
    for meas in MEASURES:
        fig, axes = plt.subplots(2, len(cases), figsize=(4.2 * len(cases), 7.5), squeeze=False)
        for row, (cvar, clabel) in enumerate(costs):
            for ic, case in enumerate(cases):
                ax = axes[row, ic]
                # symplectic_euler first and wider: it coincides with rattle in positions here
                for method in sorted(ds.method.values, key=lambda m: m != "symplectic_euler"):
                    for prec in ds.precision.values:
                        sel = {"method": method, "precision": prec}
                        x = ds[cvar].sel(sel).values
                        y = ds[f"err_{meas}"].sel(sel | {"case": case}).values
                        ok = np.isfinite(y) & (y > 0)
                        ls, mk = ("-", "o") if prec == "fp64" else ("--", "^")
                        ax.plot(x[ok], y[ok], ls, marker=mk, ms=3.5 if method != "symplectic_euler" else 6,
                                color=COLORS[method], lw=1.2 if method != "symplectic_euler" else 3.0,
                                alpha=1.0 if method != "symplectic_euler" else 0.5,
                                label=f"{method} {prec}")
                        ya = float(ds[f"auto_err_{meas}"].sel(sel | {"case": case}))
                        xa = float(ds[f"auto_{cvar}"].sel(sel))
                        if np.isfinite(ya) and ya > 0:
                            ax.plot([xa], [ya], marker="*", ms=13 if (method == "rattle" and prec == "fp64") else 8,
                                    color=COLORS[method], mec="k", mew=0.6, ls="none")
                if meas != "bar":
                    floor = float(ds[f"ref_check_{meas}"].sel(case=case))
                    if np.isfinite(floor) and floor > 0:
                        ax.axhline(floor, color="gray", ls=":", lw=1)
                ax.set_xscale("log")
                ax.set_yscale("log")
                ax.grid(True, which="major", alpha=0.3)
                if row == 0:
                    ax.set_title(f"{case}  (v0 = {float(ds.v0.sel(case=case)):g} m/s)")
                ax.set_xlabel(clabel, fontsize=8)
                if ic == 0:
                    ax.set_ylabel(MEASURE_LABEL[meas])
        h, lab = axes[0, 0].get_legend_handles_labels()
        fig.legend(h, lab, loc="lower center", ncol=4, fontsize=8, frameon=False)
        fig.suptitle(f"Work-precision: {MEASURE_LABEL[meas]} ({ds.attrs['n_prisms']} prisms, "
                     f"t_end {ds.attrs['t_end_s']} s, {ds.attrs['mode']}; star = dt='auto', dotted = rk4 vs "
                     f"yoshida4 reference difference)", fontsize=10)
        fig.tight_layout(rect=(0, 0.05, 1, 0.96))
        p = fig_dir / f"wp_{meas}_{tag}.png"
        fig.savefig(p, dpi=110)
        plt.close(fig)
        paths.append(p)

    # error against dt: the observed orders (final displacement and final velocity)
    rows = ("state", "velocity")
    fig, axes = plt.subplots(len(rows), len(cases), figsize=(4.2 * len(cases), 3.6 * len(rows)), squeeze=False)
    dt = ds.dt.values
    for ir, meas in enumerate(rows):
        for ic, case in enumerate(cases):
            ax = axes[ir, ic]
            for method in ds.method.values:
                for prec in ds.precision.values:
                    y = ds[f"err_{meas}"].sel({"method": method, "precision": prec, "case": case}).values
                    ok = np.isfinite(y) & (y > 0)
                    ls, mk = ("-", "o") if prec == "fp64" else ("--", "^")
                    ax.plot(dt[ok], y[ok], ls, marker=mk, ms=3.5, color=COLORS[method], label=f"{method} {prec}")
            for order, st in ((1, "k:"), (2, "k-."), (4, "k--")):
                ax.plot(dt, 0.5 * (dt / dt[0]) ** order, st, lw=0.8,
                        label=f"dt^{order}" if (ic == 0 and ir == 0) else None)
            floor = float(ds[f"ref_check_{meas}"].sel(case=case))
            if np.isfinite(floor) and floor > 0:
                ax.axhline(floor, color="gray", ls=":", lw=1)
            ax.set_xscale("log")
            ax.set_yscale("log")
            if ir == 0:
                ax.set_title(case)
            ax.set_xlabel("dt [s]")
            ax.grid(True, alpha=0.3)
            if ic == 0:
                ax.set_ylabel(MEASURE_LABEL[meas])
    h, lab = axes[0, 0].get_legend_handles_labels()
    fig.legend(h, lab, loc="lower center", ncol=6, fontsize=8, frameon=False)
    fig.tight_layout(rect=(0, 0.07, 1, 1))
    p = fig_dir / f"wp_order_{tag}.png"
    fig.savefig(p, dpi=110)
    plt.close(fig)
    paths.append(p)
    return paths


def summary(ds) -> str:
    """Plain-text table: error of each measure at each dt, fp64 and fp32."""
    lines = [f"device {ds.attrs['device_name']} ({ds.attrs['mode']}), {ds.attrs['n_prisms']} prisms, "
             f"t_end {ds.attrs['t_end_s']} s, total {ds.attrs['total_wall_s']:.1f} s"]
    lines.append("reference check rk4 vs yoshida4 (speed, amplitude, state, velocity): " + "; ".join(
        f"{c}: " + " ".join(f"{float(ds[f'ref_check_{m}'].sel(case=c)):.1e}" for m in MEASURES if m != "bar")
        for c in ds.case.values))
    lines.append("reference speeds [m/s]: " + ", ".join(f"{c}: {float(ds.ref_speed.sel(case=c)):.4f}" for c in ds.case.values))
    for meas in MEASURES:
        lines.append(f"--- {MEASURE_LABEL[meas]} (max over cases); cost = device us per sim s per column")
        for method in ds.method.values:
            for prec in ds.precision.values:
                e = ds[f"err_{meas}"].sel({"method": method, "precision": prec}).max("case", skipna=False).values
                c = ds.cost_device.sel({"method": method, "precision": prec}).values
                ea = float(ds[f"auto_err_{meas}"].sel({"method": method, "precision": prec}).max("case"))
                lines.append(f"{method:>16s} {prec}: " + " ".join(f"{x:8.1e}" for x in e)
                             + f" | auto {ea:8.1e} | cost " + " ".join(f"{x * 1e6:7.0f}" for x in c))
    lines.append("dt [s]: " + " ".join(f"{x:8.1e}" for x in ds.dt.values))
    lines.append("lateral asymmetry at t_end (finest dt, rattle), fp64 / fp32: " + "; ".join(
        f"{c}: {float(ds.asymmetry.isel(k=-1).sel({'method': 'rattle', 'precision': 'fp64', 'case': c})):.1e} / "
        f"{float(ds.asymmetry.isel(k=-1).sel({'method': 'rattle', 'precision': 'fp32', 'case': c})):.1e}"
        for c in ds.case.values))
    return "\n".join(lines)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--device", default=None, help="Warp device, e.g. cpu or cuda:0 (default: GPU if any)")
    ap.add_argument("--out", default="analysis", help="output root: writes OUT/data and OUT/figures")
    ap.add_argument("--quick", action="store_true", help="small column, few dt: a CPU check in < 3 min")
    ap.add_argument("--plot-only", metavar="DIR", help="only redraw figures from DIR/data/wp_*.nc")
    ap.add_argument("--replicas", type=int, default=None,
                    help="copies of the 4 cases per batch, for the cost per column (default: 256 on a GPU, 1 on the CPU)")
    ap.add_argument("--ref-device", default="cpu", help="device of the float64 reference runs (default: cpu)")
    ap.add_argument("--ref", default=None, metavar="FILE",
                    help="reference file to read (or write if absent/stale); default OUT/data/wp_ref_<full|quick>.nc")
    ap.add_argument("--reference-only", action="store_true",
                    help="only compute the reference into OUT/data/wp_ref_<full|quick>.nc (reused by later runs)")
    a = ap.parse_args(argv)
    import xarray as xr

    if a.plot_only:
        root = Path(a.plot_only)
        files = sorted(f for f in (root / "data").glob("wp_*.nc") if not f.name.startswith("wp_ref_"))
        if not files:
            raise SystemExit(f"no wp_*.nc under {root / 'data'}")
        for f in files:
            with xr.open_dataset(f, engine="netcdf4") as ds:
                ds = ds.load()
            tag = f.stem[len("wp_"):]
            for p in plot(ds, root / "figures", tag):
                print(p)
            print(summary(ds))
        return
    if a.device is None:
        import warp as wp

        wp.config.quiet = True
        a.device = "cuda:0" if wp.get_cuda_device_count() > 0 else "cpu"
    root = Path(a.out)
    replicas = a.replicas or (1 if a.device == "cpu" else 256)
    mode = "quick" if a.quick else "full"
    ref_path = Path(a.ref) if a.ref else root / "data" / f"wp_ref_{mode}.nc"
    if a.reference_only:
        import warp as wp

        wp.config.quiet = True
        setup = QUICK if a.quick else FULL
        t0 = time.perf_counter()
        save_reference(ref_path, setup, *compute_reference(setup, a.ref_device))
        print(f"{ref_path} ({time.perf_counter() - t0:.1f} s)")
        return
    ds = run_benchmark(a.device, a.quick, replicas, a.ref_device, ref_path)
    save_study(ds, root, "wp", device_tag(a.device) + ("_quick" if a.quick else ""), plot, summary)


if __name__ == "__main__":
    main()
