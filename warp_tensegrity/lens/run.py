"""The lens job: calibrate (one batch), design, verify and re-target (one batch), map the focus.

Every simulation goes through :func:`warp_tensegrity.simulate_batch`; pulses are measured with
:mod:`warp_tensegrity.measure` (the sweeps' measures), the exit time being the leading-peak
time of the exit prism (prism 0, on the base that faces the host), a parabola vertex between
samples.
"""

from __future__ import annotations

import math
import time as _time

import numpy as np

from ..engine import simulate_batch
from ..measure.pulse import peak_track
from ..measure.pulse_core import measure_pulse
from ..policy.cost import fmt_bytes
from ..sweep.budget import host_memory_available
from . import host as H
from .design import design_focus, fit_exit_law
from .io import lens_dataset
from .spec import LensSpec, LensSpecError, lens_settings


def exit_signals(strain: np.ndarray) -> np.ndarray:
    """(B, n_out) compressive strain of the exit prism [1] (positive in compression)."""
    return -np.asarray(strain[:, :, 0], dtype=np.float64)


def measure_exit(result, prism_height: float) -> dict:
    """Exit time [s] and exit amplitude [1] (exit prism's leading peak), and the sweeps' pulse
    measures (amplitude, speed, FWHM width), NaN for failed columns."""
    with np.errstate(all="ignore"):
        m = measure_pulse(result.strain, result.time, prism_height)
        track = peak_track(result.strain, result.time)
    out = {
        "exit_time": track.time[:, 0],
        "exit_amplitude": track.value[:, 0],
        "amplitude": m["amplitude"],
        "speed": m["speed"],
        "width": m["width_fwhm"],
    }
    out = {k: np.array(v, dtype=np.float64, copy=True) for k, v in out.items()}
    for v in out.values():
        v[np.asarray(result.status) != 0] = np.nan
    return out


def _simulate(spec: LensSpec, prestrain: np.ndarray, settings, progress=None):
    params = {"prestrain": spec.column.prestrain(prestrain), "v0": spec.incident.v0,  # graded along: (B, n)
              "base_rigidity": spec.column.base_rigidity}
    return simulate_batch(spec.column.config(), params, settings, progress=progress)


RECORD_COPIES = 3
"""Host bytes of a batch's strain record, in units of the record (the engine's record on the CPU
device, its float64 copy, the measures' temporaries)."""


def check_memory(spec: LensSpec, available: int | None = None) -> None:
    """Refuse up front (LensSpecError, with the figures) a calibration whose strain record would not
    fit in host memory: the whole column is recorded at every output, count x n_out x n_prisms."""
    n_out = int(spec.run.t_end / spec.run.output_interval) + 1
    n_prisms, count = spec.column.config().n_prisms, spec.calibration.count
    need = RECORD_COPIES * 8 * count * n_out * n_prisms
    have = host_memory_available() if available is None else int(available)
    if need > have:
        raise LensSpecError(
            f"the calibration records {count:,} columns x {n_out:,} outputs x {n_prisms:,} prisms of strain: about "
            f"{fmt_bytes(need)} of host memory with its working copies, and {fmt_bytes(have)} is available; lower "
            "calibration.count or column.scene.n_prisms, or raise run.output_interval")


def calibrate(spec: LensSpec, device: str | None = None, progress=None):
    """One batch over ``calibration.count`` prestrains: (prestrain, measures, law, result)."""
    check_memory(spec)
    c = spec.calibration
    p = np.linspace(c.prestrain_min, c.prestrain_max, c.count)
    result = _simulate(spec, p, lens_settings(spec, device), progress)
    meas = measure_exit(result, spec.column.config().height)
    return p, meas, fit_exit_law(p, meas["exit_time"]), result


def _maps_spread(spec, positions, delays, axes, chunk: int = 4096) -> float:
    """Largest spread max_i - min_i of d_i + R_i / c_h over the map's points [s]."""
    x, y, z = axes
    Z, Y, X = np.meshgrid(z, y, x, indexing="ij")
    pts = np.stack([X.ravel(), Y.ravel(), Z.ravel()], axis=1)
    spread = 0.0
    for a in range(0, len(pts), chunk):
        lag = delays[None, :] + H.distances(pts[a:a + chunk], positions) / spec.host.wave_speed
        spread = max(spread, float((lag.max(axis=1) - lag.min(axis=1)).max()))
    return spread


def run_lens(spec: LensSpec, device: str | None = None, progress=None, log=print):
    """Run the whole job; returns the CF dataset (see :func:`warp_tensegrity.lens.io.lens_dataset`)."""

    t0 = _time.perf_counter()
    cfg = spec.column.config()
    positions = H.column_positions(spec.array.layout, spec.array.shape, spec.array.spacing)
    delays = H.plane_wave_delays(positions, spec.incident.angle_deg, spec.incident.azimuth_deg, spec.incident.speed)
    N = len(positions)
    c_h, dim = spec.host.wave_speed, spec.host.dimension

    # 1. calibration: one batch
    p_cal, m_cal, law, r_cal = calibrate(spec, device, progress)
    t_lo, t_hi = law.t_range
    log(f"calibration: {len(p_cal)} columns on {r_cal.device_name} in {r_cal.wall_time:.1f} s; exit time "
        f"{t_lo:.4f}..{t_hi:.4f} s over p = {p_cal[0]:g}..{p_cal[-1]:g} (jitter {law.rms_residual:.2e} s, "
        f"{law.dropped} undefined)")

    # 2. design: one prestrain set per focal point, by inversion
    designs = [design_focus(law, positions, delays, F, c_h) for F in spec.design.focal_points]
    uniform = [float(np.mean(d.prestrain)) for d in designs]
    axes = H.map_grid(spec.design.focal_points, spec.map.half_width, spec.map.half_depth, spec.map.points,
                      spec.array.layout == "grid")

    # 3. verification: designed and uniform arrays of every focal point in one batch
    interval = float(r_cal.time[1] - r_cal.time[0])
    extra = _maps_spread(spec, positions, delays, axes) + max(
        float(np.ptp(d.target_exit_time)) for d in designs)
    t_end_v = math.ceil((spec.run.t_end + extra) / interval) * interval
    p_ver = np.concatenate([d.prestrain for d in designs] + [np.full(N, u) for u in uniform])
    r_ver = _simulate(spec, p_ver, lens_settings(spec, device, t_end=t_end_v, dt=float(r_cal.dt)), progress)
    m_ver = measure_exit(r_ver, cfg.height)
    sig = exit_signals(r_ver.strain)
    failed = np.flatnonzero(np.asarray(r_ver.status) != 0)
    if len(failed):  # a frozen column radiates nothing after its failure: it is left out, and reported
        log(f"warning: {len(failed)} verification columns failed (status_by_focus); their signals are set to 0")
        sig[failed] = 0.0
    dt_out = float(r_ver.time[1] - r_ver.time[0])
    log(f"verification: {len(p_ver)} columns, t_end {t_end_v:.3f} s, in {r_ver.wall_time:.1f} s")

    foci = []
    for k, d in enumerate(designs):
        sl, su = slice(k * N, (k + 1) * N), slice((len(designs) + k) * N, (len(designs) + k + 1) * N)
        s_des, s_uni = sig[sl], sig[su]
        T = m_ver["exit_time"][sl]
        F = d.focal_point[None, :]
        fmap = H.focal_map(s_des, dt_out, positions, delays, axes, c_h, dim)
        umap = H.focal_map(s_uni, dt_out, positions, delays, axes, c_h, dim)
        at_F = H.peak_over_time(s_des, dt_out, positions, delays, F, c_h, dim)[0]
        uni_F = H.peak_over_time(s_uni, dt_out, positions, delays, F, c_h, dim)[0]
        # ideal: each column's own pulse, shifted to exit exactly at its target
        ideal_F = H.peak_over_time(s_des, dt_out, positions, delays + (d.target_exit_time - T), F, c_h, dim)[0]
        peak = H.map_peak(fmap, axes)
        ok = d.reachable & np.isfinite(T)
        spread = float(np.ptp(d.target_exit_time[ok])) if ok.any() else float("nan")
        mismatch = float(np.max(np.abs(T[ok] - d.target_exit_time[ok]))) if ok.any() else float("nan")
        foci.append({
            "design": d, "uniform_prestrain": uniform[k], "map": fmap, "uniform_map": umap,
            "exit_time": T, "exit_amplitude": m_ver["exit_amplitude"][sl], "signal": s_des,
            "uniform_signal": s_uni, "uniform_exit_time": m_ver["exit_time"][su],
            "peak_point": peak, "focus_error": float(np.linalg.norm(peak - d.focal_point)),
            "focal_value": float(at_F), "uniform_value": float(uni_F), "ideal_value": float(ideal_F),
            "focal_gain": float(at_F / uni_F), "ideal_ratio": float(at_F / ideal_F),
            "target_spread": spread, "exit_time_mismatch": mismatch,
            "exit_time_match": mismatch / spread if spread > 0 else float("nan"),
            "unreachable": np.flatnonzero(~d.reachable),
            "status": np.asarray(r_ver.status[sl]),
        })
        f = foci[-1]
        log(f"focus {k} at {np.round(d.focal_point, 4).tolist()} m: peak at {np.round(peak, 4).tolist()} m "
            f"(error {f['focus_error']:.4g} m = {f['focus_error'] / spec.array.spacing:.2f} spacings), "
            f"gain {f['focal_gain']:.3f}, ideal ratio {f['ideal_ratio']:.3f}, exit times within "
            f"{100 * f['exit_time_match']:.3f} % of the target spread {spread:.4g} s"
            + (f", unreachable columns {f['unreachable'].tolist()}" if len(f["unreachable"]) else ""))
    wall = _time.perf_counter() - t0
    return lens_dataset(spec, positions, delays, p_cal, m_cal, law, r_cal, r_ver, axes, foci, wall)
