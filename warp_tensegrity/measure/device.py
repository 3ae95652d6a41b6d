"""Pulse measurement on the Warp device: every output of :func:`warp_tensegrity.measure.pulse_core.measure_pulse`
computed from the strain record where the engine keeps it, so only the per-column measures cross
to the host.

Definitions: ``docs/measurements.md`` (the NumPy module is the reference the tests compare
against, to <= 1e-12 relative in fp64, with the same NaN pattern). The record is read in the
engine's layout ``strain[k, j, b]`` (sample, prism, column; column fastest), as float32 or float64,
and every measure is computed in float64.

Passes (one launch each; ``(P, B)`` = one thread per prism of each column, ``B`` = per column):

1. ``prism_stats`` (P, B): largest compression and finiteness of each prism's history;
2. ``init_threshold`` (B): first trial threshold, half the record's largest compression (the
   device-side reduction of the two-pass definition), and whether the record is wholly finite;
3. ``track`` (P, B): leading-peak track (and arrival) for a per-column threshold; run for the
   trial thresholds of measure_pulse's refinement (``TRIAL_SCALES``: halved in turn), each followed by
4. ``refine`` (B): prisms reached, trial amplitude, next trial; then ``track`` with the final one;
5. ``column_measures`` (B): the run measured (the longest stretch of the window over which the
   leading peak is continuous, found again past a single captured prism; arrivals outside it NaN
   where a run was cut), amplitude (median), time-of-flight fit, widths at its middle;
6. ``snapshots`` (T, B): spatial peak of every snapshot the time-of-flight fit points at;
7. ``snapshot_fit`` (B): least-squares speed of those peaks.

Passes 2-7 run once with the decision parameters (:class:`~.pulse_core.Decisions`) and, for the
stability probe, twice more with them moved up and down; the host compares the three
(:func:`~.pulse_core._sensitivities`).

Sums are numpy's pairwise summation, reproduced (``pw_sum``), so the fits round as the reference
does; medians are rank selections (no scratch, n <= a few hundred prisms). The shared ``@wp.func``
helpers live in :mod:`.device_funcs`, the kernels in :mod:`.device_kernels`; here the host side.
Columns with ``n_valid < n_time`` (the engine's failed columns, whose record ends at the failure)
count as non-finite, as the NaN-padded host record does; prisms ``j < cut`` (the far end a
truncated run did not simulate) read as zero strain, as the padded host record does.
"""

from __future__ import annotations

import time as _time

import numpy as np
import warp as wp

from .device_funcs import f64
from .energy import end_energy_share, impact_energy, pulse_energy_share
from .device_kernels import (
    column_measures,
    energy_shares,
    init_threshold,
    prism_stats,
    refine,
    snapshot_fit,
    snapshots,
    track,
)
from .pulse_core import (
    DEFAULT_END_FRACTION,
    FALLBACK_SCALE,
    TRIAL_SCALES,
    STABILITY_EPS,
    Decisions,
    _check_fraction,
    _check_history,
    _sensitivities,
    measure_pulse,
    measurement_window,
)

__all__ = ["measure_pulse_device", "measure_record", "TRIAL_SCALES"]



# ---------------------------------------------------------------------- host side
def measure_record(strain: wp.array, time, prism_height, *, n_prisms: int | None = None, cut: int = 0,
                   n_valid=None, threshold=None, skip_impact: int | None = None, skip_clamp: int | None = None,
                   end_fraction: float = DEFAULT_END_FRACTION, stability: float | None = STABILITY_EPS,
                   timings: dict | None = None, energy: dict | None = None) -> dict[str, np.ndarray]:
    """measure_pulse's outputs, computed on ``strain.device`` from a device record
    ``strain[k, j, b]`` (n_time, n_prisms - cut, B), float32 or float64 (the engine's layout).

    ``time`` (n_time,) [s]; ``prism_height`` [m] scalar or (B,); ``n_prisms`` the full column
    (default: the record's), ``cut`` prisms at the clamp that read as zero strain; ``n_valid``
    (B,) samples recorded before a column failed (default: all). ``threshold``, skips,
    ``end_fraction`` and ``stability`` as :func:`warp_tensegrity.measure.measure_pulse` (the
    stability probe measures the record twice more, with the decision parameters moved). Returns the
    same dict of float64 NumPy arrays, (B,) and (B, n_prisms), plus three per-record statistics that
    let the record stay on the device: ``max_compression`` (largest -strain, NaN unless every sample
    is finite), ``max_compression_finite`` (non-finite samples as 0) and ``record_finite`` (bool).
    Only these cross to the host.
    ``timings`` (optional dict) receives ``measurement`` (device work) and ``transfer`` seconds.
    ``energy`` (optional): the energy measures (:mod:`.energy`) too, from the device records
    ``below``, ``end`` and ``kinetic`` (n_time, B), the ``impact`` energy (B,) [J]
    (:func:`~.energy.impact_energy`), the ``station`` prism and the ``end_prisms``: adds
    ``pulse_energy_share``, ``end_energy_share`` (B,) and, with the stability probe,
    ``pulse_energy_share_sensitivity``.
    """
    _check_fraction("end_fraction", end_fraction)
    if stability is not None and not (np.isfinite(stability) and 0.0 < stability < 0.5):
        raise ValueError(f"stability = {stability!r} must be None or lie in (0, 0.5)")
    if strain.ndim != 3:
        raise ValueError(f"strain must be a device array (n_time, n_prisms, B), got shape {strain.shape}")
    T, P_rec, B = strain.shape
    P = int(n_prisms) if n_prisms is not None else P_rec
    cut = int(cut)
    if cut < 0 or P != P_rec + cut:
        raise ValueError(f"n_prisms = {n_prisms!r}, cut = {cut!r} do not fit a record of {P_rec} prisms")
    t = np.asarray(time, dtype=np.float64)
    _check_history(np.empty((0, T, max(P, 1))), t)
    dev = strain.device
    t0 = _time.perf_counter()
    lo, hi = measurement_window(P, skip_impact, skip_clamp)
    min_reached = max(min(5, hi - lo), (hi - lo) // 4)
    h = np.broadcast_to(np.asarray(prism_height, dtype=np.float64), (B,))
    nv = np.full(B, T, dtype=np.int32) if n_valid is None else np.minimum(np.asarray(n_valid, dtype=np.int64), T).astype(np.int32)
    if nv.shape != (B,):
        raise ValueError(f"n_valid must have shape ({B},), got {nv.shape}")
    use_given = threshold is not None
    given = np.broadcast_to(np.asarray(threshold if use_given else np.nan, dtype=np.float64), (B,))
    base = Decisions(end_fraction=end_fraction)
    probes = () if stability is None else (base.perturbed(stability, 1), base.perturbed(stability, -1))
    run = B and P and T

    def arr(a, dtype=f64):
        return wp.array(np.ascontiguousarray(a), dtype=dtype, device=dev)

    def zeros(shape, dtype=f64):
        return wp.empty(shape, dtype=dtype, device=dev)

    with wp.ScopedDevice(dev):
        t_d, h_d, nv_d, given_d = arr(t), arr(h), arr(nv, wp.int32), arr(given)
        qmax, fin = zeros((P, B)), zeros((P, B), wp.int32)
        thr0, whole, trial, a0 = zeros(B), zeros(B, wp.int32), zeros(B), zeros(B)
        tp_time, tp_value, arrival, slope = zeros((P, B)), zeros((P, B)), zeros((P, B)), zeros((P, B))
        jx, jw, fit, lo_eff, hi_eff = zeros((P, B)), zeros((P, B)), zeros((2, B)), zeros(B, wp.int32), zeros(B, wp.int32)
        scal = {k: zeros(B) for k in ("amplitude", "speed", "width_fwhm", "width_10", "prisms_measured",
                                      "speed_snapshot", "pulse_captured")}
        sx, sy, sw = zeros((T, B)), zeros((T, B)), zeros((T, B))
        shares = {} if energy is None else {k: zeros(B) for k in ("pulse_energy_share", "end_energy_share")}
        if run:
            wp.launch(prism_stats, (P, B), [strain, cut, nv_d, qmax, fin])

        def measure(d: Decisions) -> dict:
            """One pass of every measure with the decision parameters d; its outputs on the host."""
            if not run:
                nan_b = np.full(B, np.nan)
                out = {k: nan_b.copy() for k in list(scal) + list(shares) + ["threshold"]}
                out.update({k: np.full((B, P), np.nan) for k in ("arrival_time", "peak_time", "peak_value",
                                                                 "arrival_slope")})
                return out
            given_s = arr(given * d.threshold_scale) if use_given else given_d
            wp.launch(init_threshold, B, [f64(d.threshold_fraction), given_s, int(use_given), qmax, fin,
                                          thr0, whole, trial, a0])
            track_args = [t_d, f64(d.end_fraction), cut, strain, nv_d, whole, trial, tp_time, tp_value, arrival, slope]
            if not use_given:
                for i, _ in enumerate(TRIAL_SCALES):
                    last = i == len(TRIAL_SCALES) - 1
                    nxt = 0.0 if last else TRIAL_SCALES[i + 1]
                    wp.launch(track, (P, B), track_args)
                    wp.launch(refine, B, [lo, hi, min_reached, f64(nxt), int(last), f64(d.refined_fraction),
                                          f64(FALLBACK_SCALE), tp_time, tp_value, thr0, a0, trial])
            wp.launch(track, (P, B), track_args)
            wp.launch(column_measures, B, [t_d, h_d, cut, lo, hi, min_reached, f64(d.continuity_ratio),
                                           f64(d.end_fraction), f64(d.arrival_slack), f64(d.peak_slack),
                                           f64(d.retrack_lead), strain, nv_d, whole, trial, tp_time, tp_value,
                                           arrival, slope, jx, jw, fit, lo_eff, hi_eff, scal["amplitude"],
                                           scal["speed"], scal["width_fwhm"], scal["width_10"], scal["prisms_measured"],
                                           scal["pulse_captured"]])
            if energy is not None:
                wp.launch(energy_shares, B, [t_d, h_d, int(energy["station"]), lo, hi, P, int(energy["end_prisms"]),
                                             energy["below"], energy["end"], energy["kinetic"],
                                             wp.array(np.asarray(energy["impact"], dtype=np.float64), dtype=f64),
                                             nv_d, arrival, tp_time,
                                             scal["width_10"], scal["speed"], shares["pulse_energy_share"],
                                             shares["end_energy_share"]])
            wp.launch(snapshots, (T, B), [t_d, cut, strain, nv_d, whole, fit, lo_eff, hi_eff, P, sx, sy, sw])
            wp.launch(snapshot_fit, B, [h_d, sx, sy, sw, scal["speed_snapshot"]])
            out = {k: v.numpy().copy() for k, v in {**scal, **shares}.items()}  # copies: on the CPU numpy() is a view
            out["threshold"] = trial.numpy().copy()
            out["arrival_time"] = arrival.numpy().T.copy()
            out["peak_time"] = tp_time.numpy().T.copy()
            out["peak_value"] = tp_value.numpy().T.copy()
            out["arrival_slope"] = slope.numpy().T.copy()
            return out

        out = measure(base)
        if probes:
            probed = [measure(d) for d in probes]
            out.update(_sensitivities(out, probed))
            if energy is not None:
                out["pulse_energy_share_sensitivity"] = _share_sensitivity(out["pulse_energy_share"], probed)
        wp.synchronize_device(dev)
        t1 = _time.perf_counter()
        del out["arrival_slope"]
        if run:
            # per-record statistics the NaN reasons need, so the record itself need not cross
            whole_h = whole.numpy().astype(bool)
            qmax_h = qmax.numpy().max(axis=0)
            out["max_compression"] = np.where(whole_h, qmax_h, np.nan)
            out["max_compression_finite"] = qmax_h
            out["record_finite"] = whole_h
        else:
            out["max_compression"] = np.full(B, np.nan)
            out["max_compression_finite"] = np.full(B, np.nan)
            out["record_finite"] = np.ones(B, dtype=bool)
    if timings is not None:
        timings["measurement"] = timings.get("measurement", 0.0) + (t1 - t0)
        timings["transfer"] = timings.get("transfer", 0.0) + (_time.perf_counter() - t1)
    return out


def _share_sensitivity(a: np.ndarray, probed: list[dict]) -> np.ndarray:
    """The stability probe's largest relative change of the pulse energy share (as
    pulse_core._sensitivities: inf where a probe leaves it undefined, NaN where it is undefined)."""
    worst = np.zeros(a.shape)
    with np.errstate(invalid="ignore", divide="ignore"):
        for pr in probed:
            b = pr["pulse_energy_share"]
            worst = np.maximum(worst, np.where(np.isnan(a), 0.0, np.where(np.isnan(b), np.inf, np.abs(b - a) / np.abs(a))))
    return np.where(np.isnan(a), np.nan, worst)


def measure_pulse_device(strain, time, prism_height, threshold=None, skip_impact: int | None = None,
                         skip_clamp: int | None = None, end_fraction: float = DEFAULT_END_FRACTION,
                         device=None, precision: str = "fp64", stability: float | None = STABILITY_EPS) -> dict[str, np.ndarray]:
    """:func:`warp_tensegrity.measure.measure_pulse` for host histories (..., n_time, n_prisms),
    computed by the device kernels on ``device`` (default: Warp's default device): the record is
    uploaded once in the engine's layout (as ``precision``: 'fp64' or 'fp32'). For tests and for
    records not made by the engine."""
    s = np.asarray(strain, dtype=np.float64)
    t = np.asarray(time, dtype=np.float64)
    _check_history(s, t)
    lead, (T, P) = s.shape[:-2], s.shape[-2:]
    B = int(np.prod(lead, dtype=np.int64))
    rec = np.ascontiguousarray(s.reshape(B, T, P).transpose(1, 2, 0))
    dtype = {"fp64": wp.float64, "fp32": wp.float32}[precision]
    dev = wp.get_device(device)
    h = np.broadcast_to(np.asarray(prism_height, dtype=np.float64), lead).reshape(B)
    thr = None if threshold is None else np.broadcast_to(np.asarray(threshold, dtype=np.float64), lead).reshape(B)
    out = measure_record(wp.array(rec, dtype=dtype, device=dev), t, h, threshold=thr, skip_impact=skip_impact,
                         skip_clamp=skip_clamp, end_fraction=end_fraction, stability=stability)
    return {k: v.reshape(lead + v.shape[1:]) for k, v in out.items()}


def energy_shares_host(result, m: dict, station: int, end_prisms: int, prism_height: float) -> dict:
    """The energy shares (:mod:`.energy`) of a host result from its records and pulse measures ``m``."""
    ke, n = np.asarray(result.kinetic_energy, dtype=np.float64), np.shape(m["arrival_time"])[-1]
    n_valid = np.isfinite(ke).sum(axis=1)
    e0 = impact_energy(ke[:, 0], result.info.get("striker"))
    return {"pulse_energy_share": pulse_energy_share(result.station_energy, e0, result.time, m["arrival_time"],
                                                     m["peak_time"], m["width_10"], station,
                                                     measurement_window(n), n_valid),
            "end_energy_share": end_energy_share(result.end_energy, e0, result.time, m["speed"], prism_height, n,
                                                 end_prisms, n_valid)}


def measure_host(result, prism_height, keep_strain: bool = True, station: int | None = None,
                 end_prisms: int | None = None) -> None:
    """The fallback (RunSettings.measure = 'host'): NumPy reference on the host copy of the record;
    sets ``result.measurements`` and the ``measurement`` stage seconds; drops the strain unless kept.
    ``station``, ``end_prisms``: the energy measures' (where the result has the energy-parts record)."""
    t0 = _time.perf_counter()
    if result.strain is not None:
        s = np.asarray(result.strain, dtype=np.float64)
        with np.errstate(all="ignore"):
            m = measure_pulse(s, result.time, prism_height)
            if station is not None and result.station_energy is not None:
                m.update(energy_shares_host(result, m, station, end_prisms, prism_height))
            ok = np.isfinite(s).all(axis=(1, 2))
            q = np.where(np.isfinite(s), -s, 0.0)
            m["max_compression_finite"] = q.max(axis=(1, 2)) if s.size else np.full(s.shape[0], np.nan)
            m["max_compression"] = np.where(ok, m["max_compression_finite"], np.nan)
            m["record_finite"] = ok
        result.measurements = m
    stages = result.info.setdefault("stages", {})
    stages["measurement"] = stages.get("measurement", 0.0) + _time.perf_counter() - t0
    if not keep_strain:
        result.strain = None
