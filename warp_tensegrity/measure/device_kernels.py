"""The Warp kernels of the device pulse measures (:mod:`.device`, which launches them; the passes
are listed there) and their loading. The shared ``@wp.func`` helpers live in :mod:`.device_funcs`.
"""

from __future__ import annotations

from typing import Any

import warp as wp

from .device_funcs import (
    NAN,
    WIDTH_SEARCH,
    chain,
    f64,
    finite_at,
    median,
    parabola_offset,
    parabola_value,
    peak_time_at,
    pw_sum,
    q_at,
    reached,
    record_at,
    spatial_peak_index,
    transit_width,
)

__all__ = ["column_measures", "energy_shares", "init_threshold", "load_kernels", "prism_stats", "refine", "snapshot_fit", "snapshots",
           "track"]


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
    slope: wp.array2d(dtype=f64),
):
    """Leading peak of prism j (measure._track) and arrival with its dt/dq (measure._arrival_slope) for
    threshold thr[b]."""
    j, b = wp.tid()
    tp_time[j, b] = NAN
    tp_value[j, b] = NAN
    arrival[j, b] = NAN
    slope[j, b] = NAN
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
        slope[j, b] = (time[ka] - time[ka - 1]) / (q1 - q0)
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
    lo: int, hi: int, min_reached: int, next_scale: f64, last: int, refined_fraction: f64, fallback_scale: f64,
    # Data in:
    tp_time: wp.array2d(dtype=f64), tp_value: wp.array2d(dtype=f64), thr0: wp.array(dtype=f64),
    # Data out:
    a0: wp.array(dtype=f64), trial: wp.array(dtype=f64),
):
    """One step of measure_pulse's threshold refinement: the first trial whose leading peaks reach
    min_reached window prisms sets the amplitude a0 (median of those prisms); then the next trial,
    or (last) the final threshold refined_fraction a0 (fallback_scale thr0 where no trial found one)."""
    b = wp.tid()
    a = a0[b]
    if not wp.isfinite(a) and min_reached > 0:
        if reached(tp_time, b, lo, hi) >= min_reached:
            a_new = median(tp_value, b, hi - min_reached, min_reached)
            if a_new > f64(0.0):
                a = a_new
                a0[b] = a
    if last == 1:
        t = thr0[b] * fallback_scale
        if wp.isfinite(a):
            t = refined_fraction * a
        trial[b] = t
    elif wp.isfinite(a):
        trial[b] = NAN
    else:
        trial[b] = thr0[b] * next_scale


@wp.kernel(enable_backward=False)
def column_measures(
    # Model:
    time: wp.array(dtype=f64), prism_height: wp.array(dtype=f64), cut: int, lo: int, hi: int, min_reached: int,
    continuity_ratio: f64, end_fraction: f64, arrival_slack: f64, peak_slack: f64, retrack_lead: f64,
    # Data in:
    strain: Any, n_valid: wp.array(dtype=int), whole: wp.array(dtype=int), thr: wp.array(dtype=f64),
    # Data out:
    tp_time: wp.array2d(dtype=f64), tp_value: wp.array2d(dtype=f64),
    arrival: wp.array2d(dtype=f64), slope: wp.array2d(dtype=f64), jx: wp.array2d(dtype=f64), jw: wp.array2d(dtype=f64),
    fit: wp.array2d(dtype=f64), lo_eff: wp.array(dtype=int), hi_eff: wp.array(dtype=int),
    amplitude: wp.array(dtype=f64), speed: wp.array(dtype=f64), width_fwhm: wp.array(dtype=f64),
    width_10: wp.array(dtype=f64), prisms_measured: wp.array(dtype=f64), pulse_captured: wp.array(dtype=f64),
):
    """The run measured (the longest stretch of the window over which the leading peak is
    continuous, found again past a single captured prism: measure._chain), amplitude,
    time-of-flight speed and widths at its middle for column b (measure_pulse's per-record part);
    fit[:, b] = (c0, c1) of t_peak = c0 + c1 j, for the snapshots. Where a run was cut, arrivals
    outside the run measured (up to the window's impact end) become NaN."""
    b = wp.tid()
    P = tp_time.shape[0]
    amplitude[b] = NAN
    speed[b] = NAN
    width_fwhm[b] = NAN
    width_10[b] = NAN
    prisms_measured[b] = NAN
    pulse_captured[b] = NAN
    fit[0, b] = NAN
    fit[1, b] = NAN
    nv = n_valid[b]
    n_in, run_hi, was_cut = chain(strain, time, cut, nv, thr[b], end_fraction, tp_time, tp_value, arrival, slope, b,
                                  lo, hi, continuity_ratio, arrival_slack, peak_slack, retrack_lead)
    if whole[b] != 0 and (n_in > 0 or was_cut == 1):
        pulse_captured[b] = f64(was_cut)
    if was_cut == 1:
        for jj in range(hi):
            if jj < run_hi - n_in or jj >= run_hi:
                arrival[jj, b] = NAN
    lb = hi
    hb = hi
    if n_in >= min_reached:
        lb = run_hi - n_in
        hb = run_hi
    lo_eff[b] = lb
    hi_eff[b] = hb
    if lb >= hb or whole[b] == 0:
        return
    n = hb - lb
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
    # widths at the leading peak's time at the window's middle (the run's if it does not hold it with the
    # peak search on both sides: measure.width_position), interpolated between the snapshots around it
    j_mid = f64(0.5) * f64(lo + hi - 1)
    if not (lb + WIDTH_SEARCH <= int(wp.floor(j_mid)) and int(wp.ceil(j_mid)) <= hb - 1 - WIDTH_SEARCH):
        j_mid = f64(0.5) * f64(lb + hb - 1)
    # one transit of the leading peak around j_mid: its times at j_mid + 1/2 and j_mid - 1/2 (measure._transit)
    ta = f64(0.5) * (tp_time[wp.clamp(int(wp.floor(j_mid + f64(0.5))), 0, P - 1), b]
                     + tp_time[wp.clamp(int(wp.ceil(j_mid + f64(0.5))), 0, P - 1), b])
    tb = f64(0.5) * (tp_time[wp.clamp(int(wp.floor(j_mid - f64(0.5))), 0, P - 1), b]
                     + tp_time[wp.clamp(int(wp.ceil(j_mid - f64(0.5))), 0, P - 1), b])
    if not (wp.isfinite(ta) and wp.isfinite(tb)):
        return
    t0 = wp.min(ta, tb)
    t1 = wp.max(ta, tb)
    width_fwhm[b] = transit_width(strain, time, b, cut, nv, P, j_mid, t0, t1, f64(0.5))
    width_10[b] = transit_width(strain, time, b, cut, nv, P, j_mid, t0, t1, f64(0.1))


@wp.kernel(enable_backward=False)
def snapshots(
    # Model:
    time: wp.array(dtype=f64), cut: int,
    # Data in:
    strain: Any, n_valid: wp.array(dtype=int), whole: wp.array(dtype=int), fit: wp.array2d(dtype=f64),
    lo_eff: wp.array(dtype=int), hi_eff: wp.array(dtype=int), n_prisms: int,
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
    if not (wp.isfinite(jf) and jf >= f64(lo_eff[b] + 1) and jf <= f64(hi_eff[b] - 2)):
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


@wp.kernel(enable_backward=False)
def energy_shares(
    # Model:
    time: wp.array(dtype=f64), prism_height: wp.array(dtype=f64), station: int, lo: int, hi: int, n_prisms: int,
    end_prisms: int,
    # Data in:
    below: Any, end: Any, kinetic: Any, impact: wp.array(dtype=f64), n_valid: wp.array(dtype=int),
    arrival: wp.array2d(dtype=f64),
    tp_time: wp.array2d(dtype=f64), width_10: wp.array(dtype=f64), speed: wp.array(dtype=f64),
    # Data out:
    pulse_share: wp.array(dtype=f64), end_share: wp.array(dtype=f64),
):
    """Column b's energy shares (measure.energy.pulse_energy_share, end_energy_share): the energy the
    leading pulse carries through the station's section over its passage, and the energy left in the
    end part at t_end (before the leading pulse's reflection at the clamp can be back there), each over
    the impact energy impact[b] (measure.energy.impact_energy; ``kinetic`` gives the record's length)."""
    b = wp.tid()
    T = kinetic.shape[0]
    nv = n_valid[b]
    pulse_share[b] = NAN
    end_share[b] = NAN
    e0 = impact[b]
    if not (wp.isfinite(e0) and e0 > f64(0.0)):
        return
    back = f64(2 * n_prisms - end_prisms) * prism_height[b % prism_height.shape[0]] / speed[b]
    if nv >= T and time[T - 1] < back:  # before the pulse reflected at the clamp can be back
        end_share[b] = f64(end[T - 1, b]) / e0
    d = width_10[b]
    if not (wp.isfinite(d) and d > f64(0.0)):
        return
    ya = f64(station) + f64(1.0) + d
    yb = f64(station) - d
    ja = int(wp.ceil(ya))
    jb = int(wp.floor(yb))
    if jb < lo or ja > hi - 1:
        return
    for j in range(jb, ja + 1):
        if not (wp.isfinite(arrival[j, b]) and wp.isfinite(tp_time[j, b])):
            return
    ta = peak_time_at(tp_time, b, ya)
    tb = peak_time_at(tp_time, b, yb)
    if not ta < tb:
        return
    pulse_share[b] = (record_at(below, time, b, nv, tb) - record_at(below, time, b, nv, ta)) / e0


_STRAIN_KERNELS = (prism_stats, track, column_measures, snapshots)
for _real in (wp.float32, wp.float64):
    for _kern in _STRAIN_KERNELS:
        wp.overload(_kern, {"strain": wp.array3d(dtype=_real)})
    _rec = wp.array2d(dtype=_real)
    wp.overload(energy_shares, {"below": _rec, "end": _rec, "kinetic": _rec})


def load_kernels(device) -> None:
    """Load (compile on first use) the measurement kernels on ``device``, so that their compile time
    is not counted as measurement."""
    wp.load_module(module=__name__, device=wp.get_device(device))
