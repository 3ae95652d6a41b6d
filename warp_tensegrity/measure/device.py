"""Pulse measurement on the Warp device: every output of :func:`warp_tensegrity.measure.pulse.measure_pulse`
computed from the strain record where the engine keeps it, so only the per-column measures cross
to the host.

Definitions: ``docs/measurements.md`` (the NumPy module is the reference the tests compare
against, to <= 1e-12 relative in fp64, with the same NaN pattern). The record is read in the
engine's layout ``strain[k, j, b]`` (sample, prism, column; column fastest), as float32 or float64,
and every measure is computed in float64.

Passes (one launch each; ``(P, B)`` = one thread per prism of each column, ``B`` = per column):

1. ``prism_stats`` (P, B): largest compression and finiteness of each prism's history;
2. ``init_threshold`` (B): default threshold, 5 % of the record's largest compression (the
   device-side reduction of the two-pass definition), and whether the record is wholly finite;
3. ``track`` (P, B): leading-peak track (and arrival) for a per-column threshold; run for the
   three trial thresholds of measure_pulse's refinement (1, 0.1, 0.01 x default), each followed by
4. ``refine`` (B): prisms reached, trial amplitude, next trial; then ``track`` with the final one;
5. ``column_measures`` (B): window reached, amplitude (median), time-of-flight fit, widths at
   mid-column;
6. ``snapshots`` (T, B): spatial peak of every snapshot the time-of-flight fit points at;
7. ``snapshot_fit`` (B): least-squares speed of those peaks.

Sums are numpy's pairwise summation, reproduced (``pw_sum``), so the fits round as the reference
does; medians are rank selections (no scratch, n <= a few hundred prisms). The shared ``@wp.func``
helpers live in :mod:`.device_funcs`; here the kernels and the host side.
Columns with ``n_valid < n_time`` (the engine's failed columns, whose record ends at the failure)
count as non-finite, as the NaN-padded host record does; prisms ``j < cut`` (the far end a
truncated run did not simulate) read as zero strain, as the padded host record does.
"""

from __future__ import annotations

import time as _time
from typing import Any

import numpy as np
import warp as wp

from .device_funcs import (
    NAN,
    f64,
    finite_at,
    median,
    parabola_offset,
    parabola_value,
    pw_sum,
    q_at,
    reached,
    spatial_peak_index,
    width_at,
)
from .pulse import (
    DEFAULT_END_FRACTION,
    DEFAULT_THRESHOLD_FRACTION,
    REFINED_THRESHOLD_FRACTION,
    _check_fraction,
    _check_history,
    measurement_window,
)

__all__ = ["measure_pulse_device", "measure_record", "TRIAL_SCALES"]

TRIAL_SCALES = (1.0, 0.1, 0.01)
"""measure_pulse's threshold trials, as fractions of the default threshold."""


# ---------------------------------------------------------------------- kernels
@wp.kernel(enable_backward=False)
def prism_stats(
    # Data in:
    strain: Any, cut: int, n_valid: wp.array(dtype=int),
    # Data out:
    qmax: wp.array2d(dtype=f64), finite: wp.array2d(dtype=int),
):
    """qmax[j, b] = largest -strain of prism j's history (non-finite as 0); finite[j, b] = all finite."""
    j, b = wp.tid()
    T = strain.shape[0]
    nv = n_valid[b]
    m = q_at(strain, 0, j, b, cut, nv)
    ok = int(1)
    if nv < T:
        ok = 0
    for k in range(T):
        q = q_at(strain, k, j, b, cut, nv)
        if q > m:
            m = q
        if ok == 1 and k < nv:
            ok = finite_at(strain, k, j, b, cut, nv)
    qmax[j, b] = m
    finite[j, b] = ok


@wp.kernel(enable_backward=False)
def init_threshold(
    # Model:
    fraction: f64, given: wp.array(dtype=f64), use_given: int,
    # Data in:
    qmax: wp.array2d(dtype=f64), finite: wp.array2d(dtype=int),
    # Data out:
    thr0: wp.array(dtype=f64), whole: wp.array(dtype=int), trial: wp.array(dtype=f64), a0: wp.array(dtype=f64),
):
    """thr0 = fraction x the record's largest compression (or the given threshold); whole = every sample finite."""
    b = wp.tid()
    m = qmax[0, b]
    ok = int(1)
    for j in range(qmax.shape[0]):
        if qmax[j, b] > m:
            m = qmax[j, b]
        if finite[j, b] == 0:
            ok = 0
    thr = fraction * m
    if use_given == 1:
        thr = given[b % given.shape[0]]
    thr0[b] = thr
    whole[b] = ok
    trial[b] = thr
    a0[b] = NAN


@wp.kernel(enable_backward=False)
def track(
    # Model:
    time: wp.array(dtype=f64), end_fraction: f64, cut: int,
    # Data in:
    strain: Any, n_valid: wp.array(dtype=int), whole: wp.array(dtype=int), thr: wp.array(dtype=f64),
    # Data out:
    tp_time: wp.array2d(dtype=f64), tp_value: wp.array2d(dtype=f64), arrival: wp.array2d(dtype=f64),
):
    """Leading peak of prism j (measure._track) and arrival (measure._arrival) for threshold thr[b]."""
    j, b = wp.tid()
    tp_time[j, b] = NAN
    tp_value[j, b] = NAN
    arrival[j, b] = NAN
    th = thr[b]
    if whole[b] == 0 or not (wp.isfinite(th) and th > f64(0.0)):
        return
    T = time.shape[0]
    nv = n_valid[b]
    ka = int(-1)
    ke = int(-1)
    kp = int(0)
    runmax = f64(0.0)
    best = f64(0.0)
    for k in range(T):
        q = q_at(strain, k, j, b, cut, nv)
        if k == 0 or q > runmax:
            runmax = q
        if ka >= 0 and q <= end_fraction * runmax:  # k > ka: the leading pulse is over
            ke = k
            break
        if ka < 0 and q >= th:
            ka = k
        if k == 0 or q > best:  # first argmax over [0, ke)
            best = q
            kp = k
    if ka >= 1:
        q0 = q_at(strain, ka - 1, j, b, cut, nv)
        q1 = q_at(strain, ka, j, b, cut, nv)
        frac = (th - q0) / (q1 - q0)
        arrival[j, b] = time[ka - 1] + frac * (time[ka] - time[ka - 1])
    if ka < 0 or ke < 0 or kp < 1:
        return
    t0 = time[kp - 1]
    t1 = time[kp]
    t2 = time[kp + 1]
    y0 = q_at(strain, kp - 1, j, b, cut, nv)
    y1 = q_at(strain, kp, j, b, cut, nv)
    y2 = q_at(strain, kp + 1, j, b, cut, nv)
    off = parabola_offset(y0, y1, y2, t1 - t0, t2 - t1)
    val = parabola_value(y0, y1, y2, t1 - t0, t2 - t1)
    if wp.isfinite(val):
        tp_time[j, b] = t1 + off
        tp_value[j, b] = val


@wp.kernel(enable_backward=False)
def refine(
    # Model:
    lo: int, hi: int, min_reached: int, next_scale: f64, last: int, refined_fraction: f64,
    # Data in:
    tp_time: wp.array2d(dtype=f64), tp_value: wp.array2d(dtype=f64), thr0: wp.array(dtype=f64),
    # Data out:
    a0: wp.array(dtype=f64), trial: wp.array(dtype=f64),
):
    """One step of measure_pulse's threshold refinement: the first trial whose leading peaks reach
    min_reached window prisms sets the amplitude a0 (median of those prisms); then the next trial,
    or (last) the final threshold min(thr0, refined_fraction a0)."""
    b = wp.tid()
    a = a0[b]
    if not wp.isfinite(a) and min_reached > 0:
        if reached(tp_time, b, lo, hi) >= min_reached:
            a_new = median(tp_value, b, hi - min_reached, min_reached)
            if a_new > f64(0.0):
                a = a_new
                a0[b] = a
    if last == 1:
        t = thr0[b]
        if wp.isfinite(a):
            r = refined_fraction * a
            if r < t:
                t = r
        trial[b] = t
    elif wp.isfinite(a):
        trial[b] = NAN
    else:
        trial[b] = thr0[b] * next_scale


@wp.kernel(enable_backward=False)
def column_measures(
    # Model:
    time: wp.array(dtype=f64), prism_height: wp.array(dtype=f64), cut: int, lo: int, hi: int, min_reached: int,
    # Data in:
    strain: Any, n_valid: wp.array(dtype=int), whole: wp.array(dtype=int),
    tp_time: wp.array2d(dtype=f64), tp_value: wp.array2d(dtype=f64),
    # Data out:
    jx: wp.array2d(dtype=f64), jw: wp.array2d(dtype=f64),
    fit: wp.array2d(dtype=f64), lo_eff: wp.array(dtype=int),
    amplitude: wp.array(dtype=f64), speed: wp.array(dtype=f64), width_fwhm: wp.array(dtype=f64),
    width_10: wp.array(dtype=f64), prisms_measured: wp.array(dtype=f64),
):
    """Window reached, amplitude, time-of-flight speed and widths at mid-column of column b
    (measure_pulse's per-record part); fit[:, b] = (c0, c1) of t_peak = c0 + c1 j, for the snapshots."""
    b = wp.tid()
    P = tp_time.shape[0]
    amplitude[b] = NAN
    speed[b] = NAN
    width_fwhm[b] = NAN
    width_10[b] = NAN
    prisms_measured[b] = NAN
    fit[0, b] = NAN
    fit[1, b] = NAN
    n_in = reached(tp_time, b, lo, hi)
    lb = hi
    if n_in >= min_reached:
        lb = hi - n_in
    lo_eff[b] = lb
    if lb >= hi or whole[b] == 0:
        return
    n = hi - lb
    prisms_measured[b] = f64(n)
    amplitude[b] = median(tp_value, b, lb, n)
    # time of flight: least squares t_peak(j) = c0 + c1 j over the prisms reached (all defined)
    for j in range(P):
        jx[j, b] = f64(j)
        jw[j, b] = f64(1.0)
    if n >= 2:
        cnt = f64(n)
        xm = pw_sum(0, jx, tp_time, jw, b, lb, n, f64(0.0), f64(0.0)) / cnt
        ym = pw_sum(1, jx, tp_time, jw, b, lb, n, f64(0.0), f64(0.0)) / cnt
        sxx = pw_sum(2, jx, tp_time, jw, b, lb, n, xm, ym)
        sxy = pw_sum(3, jx, tp_time, jw, b, lb, n, xm, ym)
        if sxx > f64(0.0):
            c1 = sxy / sxx
            c0 = ym - c1 * xm
            if wp.isfinite(c1) and c1 < f64(0.0):
                h = prism_height[b % prism_height.shape[0]]
                speed[b] = -h / c1
                fit[0, b] = c0
                fit[1, b] = c1
    # widths at the sample nearest to the leading peak's time at mid-window
    j_mid = f64(0.5) * f64(lb + hi - 1)
    j0 = int(wp.floor(j_mid))
    j1 = int(wp.ceil(j_mid))
    t_mid = f64(0.5) * (tp_time[j0, b] + tp_time[j1, b])
    if not wp.isfinite(t_mid):
        return
    k = int(0)
    dbest = wp.abs(time[0] - t_mid)
    for kk in range(1, time.shape[0]):
        d = wp.abs(time[kk] - t_mid)
        if d < dbest:
            dbest = d
            k = kk
    nv = n_valid[b]
    width_fwhm[b] = width_at(strain, k, b, cut, nv, P, j_mid, 2, f64(0.5))
    width_10[b] = width_at(strain, k, b, cut, nv, P, j_mid, 2, f64(0.1))


@wp.kernel(enable_backward=False)
def snapshots(
    # Model:
    time: wp.array(dtype=f64), cut: int, hi: int,
    # Data in:
    strain: Any, n_valid: wp.array(dtype=int), whole: wp.array(dtype=int), fit: wp.array2d(dtype=f64),
    lo_eff: wp.array(dtype=int), n_prisms: int,
    # Data out:
    sx: wp.array2d(dtype=f64), sy: wp.array2d(dtype=f64), sw: wp.array2d(dtype=f64),
):
    """Snapshot k of column b: where the fit t = c0 + c1 j puts the peak at jf in [lo + 1, hi - 2],
    the parabolic peak location searched within 1 prism of rint(jf) (measure._speeds)."""
    k, b = wp.tid()
    sx[k, b] = f64(0.0)
    sy[k, b] = f64(0.0)
    sw[k, b] = f64(0.0)
    c1 = fit[1, b]
    if whole[b] == 0 or not wp.isfinite(c1):
        return
    P = n_prisms
    nv = n_valid[b]
    tk = time[k]
    jf = (tk - fit[0, b]) / c1
    if not (wp.isfinite(jf) and jf >= f64(lo_eff[b] + 1) and jf <= f64(hi - 2)):
        return
    i = spatial_peak_index(strain, k, b, cut, nv, P, int(wp.rint(jf)), 1)
    if i < 1 or i > P - 2:
        return
    y0 = q_at(strain, k, i - 1, b, cut, nv)
    y1 = q_at(strain, k, i, b, cut, nv)
    y2 = q_at(strain, k, i + 1, b, cut, nv)
    if not (y0 < y1 and y2 <= y1 and y1 > f64(0.0)):
        return
    loc = f64(i) + parabola_offset(y0, y1, y2, f64(1.0), f64(1.0))
    if not wp.isfinite(loc):
        return
    sx[k, b] = tk
    sy[k, b] = loc
    sw[k, b] = f64(1.0)


@wp.kernel(enable_backward=False)
def snapshot_fit(
    # Model:
    prism_height: wp.array(dtype=f64),
    # Data in:
    sx: wp.array2d(dtype=f64), sy: wp.array2d(dtype=f64), sw: wp.array2d(dtype=f64),
    # Data out:
    speed_snapshot: wp.array(dtype=f64),
):
    """Least squares location = a + s t over the snapshots taken (>= 3); speed = -h s."""
    b = wp.tid()
    T = sx.shape[0]
    speed_snapshot[b] = NAN
    cnt = int(0)
    for k in range(T):
        if sw[k, b] != f64(0.0):
            cnt += 1
    if cnt < 3:
        return
    n = f64(cnt)
    xm = pw_sum(0, sx, sy, sw, b, 0, T, f64(0.0), f64(0.0)) / n
    ym = pw_sum(1, sx, sy, sw, b, 0, T, f64(0.0), f64(0.0)) / n
    sxx = pw_sum(2, sx, sy, sw, b, 0, T, xm, ym)
    sxy = pw_sum(3, sx, sy, sw, b, 0, T, xm, ym)
    if sxx > f64(0.0):
        h = prism_height[b % prism_height.shape[0]]
        speed_snapshot[b] = -h * (sxy / sxx)


_STRAIN_KERNELS = (prism_stats, track, column_measures, snapshots)
for _real in (wp.float32, wp.float64):
    for _kern in _STRAIN_KERNELS:
        wp.overload(_kern, {"strain": wp.array3d(dtype=_real)})


# ---------------------------------------------------------------------- host side
def measure_record(strain: wp.array, time, prism_height, *, n_prisms: int | None = None, cut: int = 0,
                   n_valid=None, threshold=None, skip_impact: int | None = None, skip_clamp: int | None = None,
                   end_fraction: float = DEFAULT_END_FRACTION, timings: dict | None = None) -> dict[str, np.ndarray]:
    """measure_pulse's outputs, computed on ``strain.device`` from a device record
    ``strain[k, j, b]`` (n_time, n_prisms - cut, B), float32 or float64 (the engine's layout).

    ``time`` (n_time,) [s]; ``prism_height`` [m] scalar or (B,); ``n_prisms`` the full column
    (default: the record's), ``cut`` prisms at the clamp that read as zero strain; ``n_valid``
    (B,) samples recorded before a column failed (default: all). ``threshold``, skips and
    ``end_fraction`` as :func:`warp_tensegrity.measure.measure_pulse`. Returns the same dict of
    float64 NumPy arrays, (B,) and (B, n_prisms), plus three per-record statistics that let the
    record stay on the device: ``max_compression`` (largest -strain, NaN unless every sample is
    finite), ``max_compression_finite`` (non-finite samples as 0) and ``record_finite`` (bool).
    Only these cross to the host.
    ``timings`` (optional dict) receives ``measurement`` (device work) and ``transfer`` seconds.
    """
    _check_fraction("end_fraction", end_fraction)
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

    def arr(a, dtype=f64):
        return wp.array(np.ascontiguousarray(a), dtype=dtype, device=dev)

    def zeros(shape, dtype=f64):
        return wp.empty(shape, dtype=dtype, device=dev)

    with wp.ScopedDevice(dev):
        t_d, h_d, nv_d, given_d = arr(t), arr(h), arr(nv, wp.int32), arr(given)
        qmax, fin = zeros((P, B)), zeros((P, B), wp.int32)
        thr0, whole, trial, a0 = zeros(B), zeros(B, wp.int32), zeros(B), zeros(B)
        tp_time, tp_value, arrival = zeros((P, B)), zeros((P, B)), zeros((P, B))
        if B and P and T:
            wp.launch(prism_stats, (P, B), [strain, cut, nv_d, qmax, fin])
            wp.launch(init_threshold, B, [f64(DEFAULT_THRESHOLD_FRACTION), given_d, int(use_given), qmax, fin,
                                          thr0, whole, trial, a0])
            if not use_given:
                for i, _ in enumerate(TRIAL_SCALES):
                    last = i == len(TRIAL_SCALES) - 1
                    nxt = 0.0 if last else TRIAL_SCALES[i + 1]
                    wp.launch(track, (P, B), [t_d, f64(end_fraction), cut, strain, nv_d, whole, trial,
                                              tp_time, tp_value, arrival])
                    wp.launch(refine, B, [lo, hi, min_reached, f64(nxt), int(last), f64(REFINED_THRESHOLD_FRACTION),
                                          tp_time, tp_value, thr0, a0, trial])
            wp.launch(track, (P, B), [t_d, f64(end_fraction), cut, strain, nv_d, whole, trial,
                                      tp_time, tp_value, arrival])
        jx, jw, fit, lo_eff = zeros((P, B)), zeros((P, B)), zeros((2, B)), zeros(B, wp.int32)
        scal = {k: zeros(B) for k in ("amplitude", "speed", "width_fwhm", "width_10", "prisms_measured",
                                      "speed_snapshot")}
        sx, sy, sw = zeros((T, B)), zeros((T, B)), zeros((T, B))
        if B and P and T:
            wp.launch(column_measures, B, [t_d, h_d, cut, lo, hi, min_reached, strain, nv_d, whole, tp_time, tp_value,
                                           jx, jw, fit, lo_eff, scal["amplitude"], scal["speed"], scal["width_fwhm"],
                                           scal["width_10"], scal["prisms_measured"]])
            wp.launch(snapshots, (T, B), [t_d, cut, hi, strain, nv_d, whole, fit, lo_eff, P, sx, sy, sw])
            wp.launch(snapshot_fit, B, [h_d, sx, sy, sw, scal["speed_snapshot"]])
        wp.synchronize_device(dev)
        t1 = _time.perf_counter()
        if B and P and T:
            out = {k: v.numpy() for k, v in scal.items()}
            out["threshold"] = trial.numpy()
            # per-record statistics the NaN reasons need, so the record itself need not cross
            whole_h = whole.numpy().astype(bool)
            qmax_h = qmax.numpy().max(axis=0)
            out["max_compression"] = np.where(whole_h, qmax_h, np.nan)
            out["max_compression_finite"] = qmax_h
            out["record_finite"] = whole_h
            out["arrival_time"] = arrival.numpy().T.copy()
            out["peak_time"] = tp_time.numpy().T.copy()
            out["peak_value"] = tp_value.numpy().T.copy()
        else:
            nan_b = np.full(B, np.nan)
            out = {k: nan_b.copy() for k in list(scal) + ["threshold", "max_compression", "max_compression_finite"]}
            out["record_finite"] = np.ones(B, dtype=bool)
            out.update({k: np.full((B, P), np.nan) for k in ("arrival_time", "peak_time", "peak_value")})
    if timings is not None:
        timings["measurement"] = timings.get("measurement", 0.0) + (t1 - t0)
        timings["transfer"] = timings.get("transfer", 0.0) + (_time.perf_counter() - t1)
    return out


def measure_pulse_device(strain, time, prism_height, threshold=None, skip_impact: int | None = None,
                         skip_clamp: int | None = None, end_fraction: float = DEFAULT_END_FRACTION,
                         device=None, precision: str = "fp64") -> dict[str, np.ndarray]:
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
                         skip_clamp=skip_clamp, end_fraction=end_fraction)
    return {k: v.reshape(lead + v.shape[1:]) for k, v in out.items()}


def load_kernels(device) -> None:
    """Load (compile on first use) the measurement kernels on ``device``, so that their compile time
    is not counted as measurement."""
    wp.load_module(module=__name__, device=wp.get_device(device))


def measure_host(result, prism_height, keep_strain: bool = True) -> None:
    """The fallback (RunSettings.measure = 'host'): NumPy reference on the host copy of the record;
    sets ``result.measurements`` and the ``measurement`` stage seconds; drops the strain unless kept."""
    from .pulse import measure_pulse

    t0 = _time.perf_counter()
    if result.strain is not None:
        s = np.asarray(result.strain, dtype=np.float64)
        with np.errstate(all="ignore"):
            m = measure_pulse(s, result.time, prism_height)
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
