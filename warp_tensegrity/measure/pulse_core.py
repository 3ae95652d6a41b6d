"""Pulse measurement core: every measure of the impact wave in one call (:func:`measure_pulse`),
the measurement window, the default threshold and the stages the single-measure functions of
:mod:`.pulse` share (input checks, arrival, leading-peak track, amplitude, speeds, widths).

Conventions as in :mod:`.pulse` (``strain[..., k, j]`` at ``time[k]``, prism 0 clamped, the wave
running toward ``j = 0``, compressive magnitude ``q = -eps`` reported positive); exact definitions:
``docs/measurements.md``. Pure NumPy, float64, and imports nothing from the package (a leaf), so
:mod:`.nan_reasons` and :mod:`.device` import it directly and their import chains stay short.
"""

from __future__ import annotations

import warnings
from typing import NamedTuple

import numpy as np

DEFAULT_THRESHOLD_FRACTION = 0.05
"""Default arrival threshold of the single measures (:mod:`.pulse`), as a fraction of the largest
compression of the record."""
TRIAL_FRACTION = 0.5
"""measure_pulse's first trial threshold, as a fraction of the record's largest compression."""
TRIAL_SCALES = tuple(0.5**k for k in range(11))
"""measure_pulse's trial thresholds, as fractions of the first: halved in turn, down to 1/1024 (the
first of them at which the leading peaks reach the window's impact end sets the threshold)."""
FALLBACK_SCALE = DEFAULT_THRESHOLD_FRACTION / TRIAL_FRACTION
"""Where no trial finds the leading peaks, the threshold is the first trial times this: 5 % of the
record's largest compression (the measures are NaN; the arrivals show how far the front got)."""
REFINED_THRESHOLD_FRACTION = 0.25
"""measure_pulse's second pass: threshold as a fraction of the first pass's leading amplitude."""
DEFAULT_END_FRACTION = 0.5
"""The leading pulse ends where compression falls to this fraction of its running maximum."""
DEFAULT_SKIP_FRACTION = 0.1
"""Default fraction of prisms left out of the measurement window at each end."""
MIN_WINDOW = 3
"""Smallest window (prisms) the default skips leave."""
CONTINUITY_RATIO = 2.0
"""measure_pulse follows the leading peak from the impacted end while its value changes by less
than this factor from one prism to the next (with arrivals not earlier, see :func:`_chain`)."""
PEAK_SLACK = 0.5
"""The chain's peak-time test: a prism's leading peak may come earlier than the previous prism's by
at most this fraction of the mean arrival step (rigid-base pulses peak in pairs of prisms)."""
WIDTH_SEARCH = 2
"""The widths' peak is searched within this many prisms of where they are taken."""
STABILITY_EPS = 1e-3
"""measure_pulse's stability probe: every decision parameter (:class:`Decisions`) moved by this
relative amount (the slacks by this many mean arrival steps), up and down."""
STABILITY_FLOOR = 1e-3
"""A measure whose sensitivity exceeds this is flagged ``measure_unstable`` when the run states no
accuracy target (the engine's default target, ``policy.accuracy.DEFAULT_ACCURACY``)."""

__all__ = [
    "CONTINUITY_RATIO",
    "Decisions",
    "PEAK_SLACK",
    "SENSITIVITY_KEYS",
    "STABILITY_EPS",
    "STABILITY_FLOOR",
    "TRIAL_FRACTION",
    "TRIAL_SCALES",
    "WIDTH_SEARCH",
    "DEFAULT_END_FRACTION",
    "DEFAULT_SKIP_FRACTION",
    "DEFAULT_THRESHOLD_FRACTION",
    "MIN_WINDOW",
    "REFINED_THRESHOLD_FRACTION",
    "PeakTrack",
    "default_skip",
    "default_threshold",
    "measure_pulse",
    "measurement_window",
    "width_position",
]


class Decisions(NamedTuple):
    """The parameters of measure_pulse's discrete decisions: which threshold, where a leading pulse
    ends, whether a prism's peak continues its neighbour's. The measures (amplitude, speeds, widths)
    do not depend on them continuously: they change only where a decision flips, which the
    stability probe (:meth:`perturbed`) detects."""

    threshold_fraction: float = TRIAL_FRACTION
    """First trial threshold, as a fraction of the record's largest compression (then halved in turn)."""
    refined_fraction: float = REFINED_THRESHOLD_FRACTION
    """Final threshold, as a fraction of the leading amplitude at the window's impact end."""
    end_fraction: float = DEFAULT_END_FRACTION
    """The leading pulse ends where compression falls to this fraction of its running maximum."""
    continuity_ratio: float = CONTINUITY_RATIO
    """Largest change of the leading peak's value from one prism to the next in a run."""
    arrival_slack: float = 0.0
    """Arrival-order test: at(j) >= at(j + 1) - arrival_slack x the run's mean arrival step."""
    peak_slack: float = PEAK_SLACK
    """Peak-time test: tp(j) >= tp(j + 1) - peak_slack x the run's mean arrival step."""
    retrack_lead: float = 0.5
    """A captured prism is tracked again from this many mean arrival steps before the previous prism's arrival."""
    threshold_scale: float = 1.0
    """Factor on a threshold given by the caller."""

    def perturbed(self, eps: float, sign: int) -> "Decisions":
        """Every parameter moved by ``sign * eps`` (fractions relatively, slacks in mean arrival steps)."""
        f = 1.0 + sign * eps
        return Decisions(self.threshold_fraction * f, self.refined_fraction * f, self.end_fraction * f,
                         self.continuity_ratio * f, self.arrival_slack + sign * eps, self.peak_slack + sign * eps,
                         self.retrack_lead + sign * eps, self.threshold_scale * f)


SENSITIVITY_KEYS = {"amplitude": "amplitude_sensitivity", "speed": "speed_sensitivity",
                    "width_fwhm": "width_fwhm_sensitivity", "width_10": "width_10_sensitivity",
                    "arrival_time": "arrival_time_sensitivity"}
"""measure_pulse's stability outputs: the largest relative change of each measure under the
decision perturbations (:class:`Decisions`)."""


class PeakTrack(NamedTuple):
    """Leading peak at each prism; arrays of shape (..., n_prisms), NaN / -1 where undefined."""

    time: np.ndarray
    """Time of the leading peak [s] (parabolic over 3 samples)."""
    value: np.ndarray
    """Compressive strain magnitude at the leading peak [-] (parabolic over 3 samples)."""
    sample: np.ndarray
    """Index of the sample holding the largest value of the leading pulse (-1 if undefined)."""


# ---------------------------------------------------------------------- input handling


def _check_history(s, t):
    if s.ndim < 2:
        raise ValueError(f"strain must have shape (..., n_time, n_prisms), got {s.shape}")
    if s.shape[-2] < 1 or s.shape[-1] < 1:
        raise ValueError(f"strain needs at least one sample and one prism, got {s.shape}")
    if t.ndim != 1 or t.shape[0] != s.shape[-2]:
        raise ValueError(f"time must have shape ({s.shape[-2]},), got {t.shape}")
    if not np.all(np.isfinite(t)) or np.any(np.diff(t) <= 0):
        raise ValueError("time must be finite and strictly increasing")


def _float_array(name: str, value) -> np.ndarray:
    """``value`` as a float64 array, or ValueError naming ``name`` (a masked array is refused)."""
    if isinstance(value, np.ma.MaskedArray) and np.ma.is_masked(value):
        raise ValueError(f"{name} is a masked array with masked samples; fill them (NaN marks a bad sample)")
    try:
        return np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{name} = {type(value).__name__} {str(value)[:40]!r}: give an array of numbers") from None


def _as_history(strain, time):
    """Validate; return (q, t, finite): q = -strain with non-finite samples zeroed,
    finite[..., j] = prism j's whole history is finite."""
    s = np.asarray(strain, dtype=np.float64)
    t = np.asarray(time, dtype=np.float64)
    _check_history(s, t)
    ok = np.isfinite(s)
    return np.where(ok, -s, 0.0), t, ok.all(axis=-2)


def _as_snapshot(strain_snapshot):
    """Validate; return (q, finite) for a snapshot (..., n_prisms)."""
    s = np.asarray(strain_snapshot, dtype=np.float64)
    if s.ndim < 1 or s.shape[-1] < 1:
        raise ValueError(f"strain_snapshot must have shape (..., n_prisms), got {s.shape}")
    ok = np.isfinite(s)
    return np.where(ok, -s, 0.0), ok.all(axis=-1)


def _check_fraction(name, value):
    if not (np.isfinite(value) and 0.0 < value < 1.0):
        raise ValueError(f"{name} = {value!r} must lie in (0, 1)")


def _take(a, idx, axis):
    """a[..., idx, ...] with one index per remaining position (idx lacks `axis`)."""
    return np.take_along_axis(a, np.expand_dims(idx, axis), axis=axis).squeeze(axis)


def _threshold(q, threshold):
    """Threshold broadcast to (..., n_prisms) and the mask where it is usable (finite, > 0)."""
    if threshold is None:
        thr = DEFAULT_THRESHOLD_FRACTION * q.max(axis=(-2, -1))[..., None]
    else:
        thr = np.asarray(threshold, dtype=np.float64)
    thr = np.broadcast_to(thr, q.shape[:-2] + q.shape[-1:])
    with np.errstate(invalid="ignore"):
        return thr, np.isfinite(thr) & (thr > 0)


def default_threshold(strain) -> np.ndarray:
    """Default arrival threshold, shape (...): ``DEFAULT_THRESHOLD_FRACTION`` (5 %) of the
    largest compressive strain magnitude of each record (..., n_time, n_prisms) [-];
    non-finite samples ignored. 0 for a record with no compression (then every result is NaN)."""
    s = np.asarray(strain, dtype=np.float64)
    q = np.where(np.isfinite(s), -s, 0.0)
    return DEFAULT_THRESHOLD_FRACTION * q.max(axis=(-2, -1))


def default_skip(n_prisms: int) -> int:
    """Prisms left out at each end by default: ``round(0.1 * n_prisms)``, at least 1, reduced
    (down to 0) so that at least ``MIN_WINDOW`` = 3 prisms remain. 50 -> 5, 20 -> 2, 10 -> 1,
    5 -> 1, 4 -> 0."""
    n = int(n_prisms)
    skip = max(1, int(round(DEFAULT_SKIP_FRACTION * n)))
    return max(0, min(skip, (n - MIN_WINDOW) // 2))


def measurement_window(n_prisms: int, skip_impact: int | None = None, skip_clamp: int | None = None) -> tuple[int, int]:
    """Prism window ``lo <= j < hi`` used for amplitude and speed: ``lo = skip_clamp``,
    ``hi = n_prisms - skip_impact``; ``None`` -> :func:`default_skip`. May be empty."""
    d = default_skip(n_prisms)
    si = d if skip_impact is None else int(skip_impact)
    sc = d if skip_clamp is None else int(skip_clamp)
    if si < 0 or sc < 0:
        raise ValueError(f"skip_impact = {skip_impact!r}, skip_clamp = {skip_clamp!r} must be >= 0")
    return sc, max(sc, int(n_prisms) - si)


# ---------------------------------------------------------------------- small numerics


def _parabola_peak(y0, y1, y2, h1, h2):
    """Vertex of the parabola through (-h1, y0), (0, y1), (h2, y2): (offset, value).
    Valid for a strict maximum (y0 < y1 >= y2, so curvature < 0); NaN otherwise."""
    with np.errstate(divide="ignore", invalid="ignore"):
        d0 = (y0 - y1) / h1
        d2 = (y2 - y1) / h2
        a = (d0 + d2) / (h1 + h2)
        b = (d2 * h1 - d0 * h2) / (h1 + h2)
        ok = a < 0
        a = np.where(ok, a, -1.0)
        off = np.where(ok, -b / (2.0 * a), np.nan)
        val = np.where(ok, y1 - b * b / (4.0 * a), np.nan)
    return off, val


def _linfit(x, y, w):
    """Weighted (0/1) least-squares line y = c0 + c1 x along the last axis: (c1, c0, n)."""
    w = w.astype(np.float64)
    n = w.sum(axis=-1)
    x = np.where(w > 0, x, 0.0)
    y = np.where(w > 0, y, 0.0)
    ns = np.where(n > 0, n, 1.0)
    xm = (w * x).sum(axis=-1) / ns
    ym = (w * y).sum(axis=-1) / ns
    dx = x - xm[..., None]
    sxx = (w * dx * dx).sum(axis=-1)
    sxy = (w * dx * (y - ym[..., None])).sum(axis=-1)
    ok = (n >= 2) & (sxx > 0)
    c1 = np.where(ok, sxy / np.where(ok, sxx, 1.0), np.nan)
    c0 = np.where(ok, ym - c1 * xm, np.nan)
    return c1, c0, n


def _spatial_peak(q, near=None, search=1):
    """Largest compression of snapshots q (..., P) - over all prisms, or over the prisms within
    ``search`` of ``round(near)`` - refined by a parabola over 3 prisms.
    Returns (fractional index, value, sample index i); NaN unless the chosen prism is a strict interior local
    maximum (q[i-1] < q[i] >= q[i+1], q[i] > 0)."""
    P = q.shape[-1]
    j = np.arange(P)
    if near is None:
        qm, has = q, np.ones(q.shape[:-1], dtype=bool)
    else:
        near = np.asarray(near, dtype=np.float64)
        c = np.round(np.where(np.isfinite(near), near, -10.0 * (P + search + 1)))
        mask = np.abs(j - c[..., None]) <= search
        qm, has = np.where(mask, q, -np.inf), mask.any(axis=-1)
    i = qm.argmax(axis=-1)
    i0, i2 = np.clip(i - 1, 0, P - 1), np.clip(i + 1, 0, P - 1)
    y0, y1, y2 = _take(q, i0, -1), _take(q, i, -1), _take(q, i2, -1)
    ok = has & (i >= 1) & (i <= P - 2) & (y0 < y1) & (y2 <= y1) & (y1 > 0)
    off, val = _parabola_peak(y0, y1, y2, 1.0, 1.0)
    return np.where(ok, i + off, np.nan), np.where(ok, val, np.nan), i


# ---------------------------------------------------------------------- core stages


def _arrival(q, t, finite, thr, thr_ok):
    return _arrival_slope(q, t, finite, thr, thr_ok)[0]


def _arrival_slope(q, t, finite, thr, thr_ok):
    """Arrival times [s] and dt/dq at the crossing [s] (its response to the threshold), NaN where undefined."""
    above = q >= thr[..., None, :]
    hit = above.any(axis=-2)
    k = above.argmax(axis=-2)
    ok = finite & thr_ok & hit & (k >= 1)  # k = 0: already above at the first sample
    km = np.maximum(k - 1, 0)
    q0, q1 = _take(q, km, -2), _take(q, k, -2)
    dq = np.where(ok, q1 - q0, 1.0)
    frac = (thr - q0) / dq  # q0 < thr <= q1
    return np.where(ok, t[km] + frac * (t[k] - t[km]), np.nan), np.where(ok, (t[k] - t[km]) / dq, np.nan)


def _track(q, t, finite, thr, thr_ok, end_fraction):
    T = q.shape[-2]
    tk = np.arange(T)[:, None]
    above = q >= thr[..., None, :]
    hit = above.any(axis=-2)
    ka = above.argmax(axis=-2)  # first sample at or above threshold
    runmax = np.maximum.accumulate(q, axis=-2)
    ended = (tk > ka[..., None, :]) & (q <= end_fraction * runmax)
    has_end = ended.any(axis=-2)
    ke = ended.argmax(axis=-2)  # first sample after which the leading pulse is over
    kp = np.where(tk < ke[..., None, :], q, -np.inf).argmax(axis=-2)  # its largest sample
    ok = finite & thr_ok & hit & has_end & (kp >= 1)
    km, kq = np.clip(kp - 1, 0, T - 1), np.clip(kp + 1, 0, T - 1)
    t0, t1, t2 = t[km], t[kp], t[kq]
    off, val = _parabola_peak(_take(q, km, -2), _take(q, kp, -2), _take(q, kq, -2),
                              np.where(ok, t1 - t0, 1.0), np.where(ok, t2 - t1, 1.0))
    ok &= np.isfinite(val)
    return PeakTrack(np.where(ok, t1 + off, np.nan), np.where(ok, val, np.nan), np.where(ok, kp, -1))


def _reached(track, lo, hi):
    """Number of window prisms, contiguous from the impact side (hi - 1 downward), with a leading peak."""
    defined = np.isfinite(track.time[..., lo:hi])[..., ::-1]
    return np.where(defined.all(axis=-1), hi - lo, np.argmin(defined, axis=-1))


def _retrack(q, t, thr, thr_r, end_fraction, t_start):
    """The leading peak of histories q (m, T) that starts with the first upward crossing of
    ``thr_r`` (m,) after the first sample at or after ``t_start`` (m,) [s], ended and refined as in
    :func:`_track`; its arrival is the crossing of ``thr`` (m,) on the same rise (not before that
    start sample). Returns (t_peak, q_peak, arrival, dt/dq at the arrival), NaN where undefined."""
    m, T = q.shape
    k = np.arange(T)[None, :]
    rows = np.arange(m)
    k0 = np.searchsorted(t, t_start, side="left")[:, None]
    up = np.zeros((m, T), dtype=bool)
    up[:, 1:] = (q[:, :-1] < thr_r[:, None]) & (q[:, 1:] >= thr_r[:, None])
    up &= k > k0
    hit = up.any(axis=-1)
    ka = up.argmax(axis=-1)
    from_a = k >= ka[:, None]
    runmax = np.maximum.accumulate(np.where(from_a, q, -np.inf), axis=-1)
    ended = (k > ka[:, None]) & (q <= end_fraction * runmax)
    has_end = ended.any(axis=-1)
    ke = ended.argmax(axis=-1)
    kp = np.where(from_a & (k < ke[:, None]), q, -np.inf).argmax(axis=-1)
    below = np.where((k > k0) & (k < ka[:, None]) & (q < thr[:, None]), k, -1).max(axis=-1)
    kb = np.where(below >= 0, below + 1, k0[:, 0] + 1).clip(1, T - 1)
    qb0, qb1 = q[rows, kb - 1], q[rows, kb]
    ok_a = hit & (qb0 < thr) & (thr <= qb1)
    dq = np.where(ok_a, qb1 - qb0, 1.0)
    arrival = np.where(ok_a, t[kb - 1] + (thr - qb0) / dq * (t[kb] - t[kb - 1]), np.nan)
    slope = np.where(ok_a, (t[kb] - t[kb - 1]) / dq, np.nan)
    ok = hit & has_end & (kp + 1 < T)
    km, kq = np.clip(kp - 1, 0, T - 1), np.clip(kp + 1, 0, T - 1)
    off, val = _parabola_peak(q[rows, km], q[rows, kp], q[rows, kq],
                              np.where(ok, t[kp] - t[km], 1.0), np.where(ok, t[kq] - t[kp], 1.0))
    ok &= np.isfinite(val)
    return np.where(ok, t[kp] + off, np.nan), np.where(ok, val, np.nan), arrival, slope


def _continuous(tp, vp, at, tp1, vp1, at1, at_hi, steps, d: Decisions):
    """Prism j's leading peak (tp, vp, at) continues prism j + 1's (tp1, vp1, at1): arrival not
    earlier (by more than ``d.arrival_slack`` mean arrival steps), value within ``d.continuity_ratio``,
    peak not earlier by more than ``d.peak_slack`` mean arrival steps, the mean arrival step being
    (at - at_hi) / steps from the run's first prism."""
    with np.errstate(invalid="ignore"):
        step = (at - at_hi) / steps
        fin = np.isfinite(step)
        ok = np.isfinite(tp) & ~(at < at1 - np.where(fin, d.arrival_slack * step, 0.0))  # NaN arrivals pass
        ok &= (vp * d.continuity_ratio > vp1) & (vp < d.continuity_ratio * vp1)
        return ok & (tp >= tp1 - np.where(fin, d.peak_slack * step, 0.0))


def _chain(q, t, thr, d: Decisions, track, arrival, slope, lo, hi):
    """The leading pulse followed through the window: (n, run_hi, cut, t_peak, q_peak, arrival, slope).

    A run starts at prism ``hi - 1`` and goes toward the clamp: prism j joins it while its leading
    peak is continuous with prism j + 1's (:func:`_continuous`, the mean arrival step taken from
    the run's first prism; arrivals compared with the run's last defined one). A defined peak that is not (something else - a disturbance from the
    clamp, a precursor - crossed the threshold there first) is tracked again (:func:`_retrack`):
    from the first rise above ``q_peak(j + 1) / continuity_ratio`` after the run's last defined
    arrival (prism j + 1's peak time if there is none) less ``retrack_lead`` mean arrival steps of the run. If that peak
    is continuous it replaces the first one and the run goes on. Two such prisms in a row, or a
    peak that stays discontinuous, end the run there (a cut), and a new run starts at that prism.
    An undefined peak ends a run; before any cut it ends the search (the pulse had not reached
    further), after one the search goes on to the next defined prism.
    Returns the longest run (the first of equal ones): ``n`` prisms ending at ``run_hi - 1``;
    ``cut``: some run was cut. The returned track and arrivals (and their dt/dq) hold the replacements."""
    tp, vp, at, sl = track.time.copy(), track.value.copy(), arrival.copy(), slope.copy()
    B = tp.shape[0]
    rows = np.arange(B)
    n = np.zeros(B, dtype=np.int64)  # current run
    cs = np.full(B, hi, dtype=np.int64)  # current run's hi (it starts at cs - 1)
    best_n = np.zeros(B, dtype=np.int64)
    best_hi = np.full(B, hi, dtype=np.int64)
    cut = np.zeros(B, dtype=bool)
    done = np.zeros(B, dtype=bool)
    bridged = np.zeros(B, dtype=bool)

    def close(mask):  # the current run ends: keep it if longer
        better = mask & (n > best_n)
        best_n[better], best_hi[better] = n[better], cs[better]

    at_last = np.full(B, np.nan)  # the last defined arrival of the current run, at prism j_last
    j_last = np.full(B, hi, dtype=np.int64)
    for j in range(hi - 1, lo - 1, -1):
        ok = np.isfinite(tp[:, j])
        start = ~done & (n == 0)
        go = ~done & (n > 0)
        a_hi = at[rows, np.maximum(cs - 1, 0)]
        steps = np.maximum(cs - 1 - j, 1)
        j1 = min(j + 1, tp.shape[1] - 1)
        cont = go & _continuous(tp[:, j], vp[:, j], at[:, j], tp[:, j1], vp[:, j1], at_last, a_hi, steps, d)
        need = go & ok & ~cont
        redo = np.flatnonzero(need & ~bridged)
        good = np.zeros(B, dtype=bool)
        if redo.size:
            with np.errstate(invalid="ignore"):
                k2 = cs[redo] - 1 - j_last[redo]
                s_ = np.where(k2 > 0, (at_last[redo] - a_hi[redo]) / np.maximum(k2, 1), np.nan)
            tol = np.where(np.isfinite(s_), d.retrack_lead * s_, 0.0)
            thr_r = np.maximum(thr[redo, j], vp[redo, j + 1] / d.continuity_ratio)
            t0 = np.where(np.isfinite(at_last[redo]), at_last[redo], tp[redo, j + 1]) - tol
            rt, rv, ra, rs = _retrack(q[redo, :, j], t, thr[redo, j], thr_r, d.end_fraction, t0)
            g = _continuous(rt, rv, ra, tp[redo, j + 1], vp[redo, j + 1], at_last[redo], a_hi[redo], steps[redo], d)
            keep = redo[g]
            tp[keep, j], vp[keep, j], at[keep, j], sl[keep, j] = rt[g], rv[g], ra[g], rs[g]
            good[keep] = True
        grow = cont | good
        n[grow] += 1
        bridged = good
        broken = need & ~good  # a cut: the run ends, a new one starts at j
        ended = go & ~ok  # an undefined peak ends the run
        close(broken | ended)
        cut |= broken
        n[broken], cs[broken] = 1, j + 1
        n[ended] = 0
        done |= ended & ~cut
        new = start & ok & ~done  # the first prism of a run (the first run, or a search after a cut)
        n[new], cs[new] = 1, j + 1
        done |= start & ~ok & ~cut  # before any cut, an undefined peak at the run's start ends the search
        upd = ((grow & np.isfinite(at[:, j])) | broken | new)
        at_last[upd], j_last[upd] = at[upd, j], j
    close(~done | (n > 0))
    return best_n, best_hi, cut, tp, vp, at, sl


def _amplitude(track, lo, hi):
    v = track.value[..., lo:hi]
    if hi - lo < 1:
        return np.full(v.shape[:-1], np.nan)
    ok = np.isfinite(v).all(axis=-1)
    return np.where(ok, np.median(np.where(np.isfinite(v), v, 0.0), axis=-1), np.nan)


def _tof_fit(track, lo, hi):
    """t_peak = c0 + c1 * j over the window; (c1 [s per prism], c0 [s]), NaN unless all defined."""
    tp = track.time[..., lo:hi]
    j = np.arange(lo, hi, dtype=np.float64)
    ok = np.isfinite(tp).all(axis=-1) & (hi - lo >= 2)
    c1, c0, _ = _linfit(np.broadcast_to(j, tp.shape), tp, np.broadcast_to(ok[..., None], tp.shape))
    ok &= np.isfinite(c1) & (c1 < 0)  # the wave runs toward j = 0: t_peak decreases with j
    return np.where(ok, c1, np.nan), np.where(ok, c0, np.nan)


def _speeds(q, t, finite, track, lo, hi, h):
    c1, c0 = _tof_fit(track, lo, hi)
    h = np.asarray(h, dtype=np.float64)
    v_tof = -h / c1
    # snapshots: leading peak predicted by the fit at round(jf) in [lo+1, hi-2], searched +-1
    jf = (t - c0[..., None]) / c1[..., None]  # (..., T) [prisms]
    sel = np.isfinite(jf) & (jf >= lo + 1) & (jf <= hi - 2)
    loc, _, _ = _spatial_peak(q, near=np.where(sel, jf, np.nan), search=1)
    w = sel & np.isfinite(loc) & finite.all(axis=-1)[..., None]
    w &= w.sum(axis=-1, keepdims=True) >= 3
    slope, _, _ = _linfit(np.broadcast_to(t, loc.shape), loc, w)  # [prisms s-1]
    return v_tof, -h * slope


def _width(q, finite, level, near=None, search=1):
    P = q.shape[-1]
    j = np.arange(P)
    loc, val, i = _spatial_peak(q, near, search)
    ok = finite & np.isfinite(loc)
    L = level * np.where(ok, val, 0.0)
    ok &= _take(q, i, -1) >= L
    below = q < L[..., None]
    left = below & (j < i[..., None])
    right = below & (j > i[..., None])
    il = np.clip(np.where(left, j, -1).max(axis=-1), 0, P - 2)  # last sample below, left
    ir = np.clip(np.where(right, j, P).min(axis=-1), 1, P - 1)  # first sample below, right
    ok &= left.any(axis=-1) & right.any(axis=-1)
    a0, a1 = _take(q, il, -1), _take(q, il + 1, -1)
    b0, b1 = _take(q, ir - 1, -1), _take(q, ir, -1)
    xl = il + (L - a0) / np.where(ok, a1 - a0, 1.0)
    xr = ir - 1 + (b0 - L) / np.where(ok, b0 - b1, 1.0)
    return np.where(ok, xr - xl, np.nan)


def width_position(lo: int, hi: int, run_lo: int, run_hi: int) -> float:
    """Where the widths are taken [prisms]: the window's middle ``(lo + hi - 1) / 2`` if the run
    measured (prisms ``run_lo <= j < run_hi``) holds it with the width's peak search
    (``WIDTH_SEARCH`` prisms) on both sides, else the run's middle. So a run whose end moves by a
    prism (a decision near its boundary) leaves the widths where they were."""
    mid = 0.5 * (lo + hi - 1)
    if run_lo + WIDTH_SEARCH <= int(np.floor(mid)) and int(np.ceil(mid)) <= run_hi - 1 - WIDTH_SEARCH:
        return mid
    return 0.5 * (run_lo + run_hi - 1)


def _transit(track, x):
    """(t_a, t_b): the leading peak's times at positions x + 1/2 and x - 1/2 [s] (a position between two
    prisms takes the mean of their peak times), in increasing order: one prism transit around x."""
    P = track.time.shape[-1]

    def at(y):
        a, b = (int(np.clip(f(y), 0, P - 1)) for f in (np.floor, np.ceil))
        return 0.5 * (track.time[..., a] + track.time[..., b])

    ta, tb = at(x + 0.5), at(x - 0.5)
    return np.minimum(ta, tb), np.maximum(ta, tb)


def _mid_width(q, t, finite, track, level, j_mid=None):
    """Width at position ``j_mid`` (default: the column middle) averaged over one transit of the
    leading peak (:func:`_transit`): the mean over [t_a, t_b] of the piecewise-linear interpolant of
    the snapshot widths (peak searched within ``WIDTH_SEARCH`` of ``j_mid``); the value at t_a where
    t_a = t_b. NaN where a snapshot it uses has no width. Averaging over the transit takes out the
    discreteness modulation and sample-to-sample noise, and the result moves continuously with t_a, t_b."""
    P, T = q.shape[-1], q.shape[-2]
    x = 0.5 * (P - 1) if j_mid is None else j_mid
    t0, t1 = _transit(track, x)
    ok = np.isfinite(t0) & np.isfinite(t1) & finite.all(axis=-1) & (T >= 2)
    if T < 2:
        return np.full(q.shape[:-2], np.nan)
    t0, t1 = np.where(ok, t0, t[0]), np.where(ok, t1, t[0])
    ka = np.clip(np.searchsorted(t, t0, side="left"), 1, T - 1)  # bracket of t0: samples ka - 1, ka
    kb = np.clip(np.searchsorted(t, t1, side="right"), 1, T - 1)  # bracket of t1: kb - 1, kb
    kb = np.maximum(kb, ka)
    L = int((kb - ka).max(initial=0)) + 2
    idx = (ka - 1)[..., None] + np.arange(L)  # samples ka - 1 .. kb
    used = idx <= kb[..., None]
    idx = np.minimum(idx, T - 1)
    snap = np.take_along_axis(q, idx[..., None], axis=-2)  # (..., L, P)
    near = np.full(snap.shape[:-1], float(x))
    w = _width(snap, np.broadcast_to(ok[..., None], near.shape), level, near=near, search=WIDTH_SEARCH)
    ok &= ~np.any(used & np.isnan(w), axis=-1)
    w = np.where(used, w, 0.0)
    tk = t[idx]
    with np.errstate(invalid="ignore", divide="ignore"):
        # segments [t_l, t_l+1] of the samples used, cut to [t0, t1]; trapezoids of the interpolant
        u0 = np.maximum(tk[..., :-1], t0[..., None])
        u1 = np.minimum(tk[..., 1:], t1[..., None])
        dt = tk[..., 1:] - tk[..., :-1]
        dw = (w[..., 1:] - w[..., :-1]) / np.where(dt > 0, dt, 1.0)
        seg = used[..., 1:] & (u1 > u0)
        area = np.where(seg, 0.5 * ((w[..., :-1] + dw * (u0 - tk[..., :-1])) + (w[..., :-1] + dw * (u1 - tk[..., :-1])))
                        * (u1 - u0), 0.0).sum(axis=-1)
        span = t1 - t0
        a0 = np.clip((t0 - tk[..., 0]) / np.where(dt[..., 0] > 0, dt[..., 0], 1.0), 0.0, 1.0)
        point = w[..., 0] + a0 * (w[..., 1] - w[..., 0])  # t0 = t1: the interpolant at t0
        mean = np.where(span > 0, area / np.where(span > 0, span, 1.0), point)
    return np.where(ok, mean, np.nan)


# ---------------------------------------------------------------------- all measures in one call


def measure_pulse(strain, time, prism_height, threshold=None, skip_impact: int | None = None,
                  skip_clamp: int | None = None, end_fraction: float = DEFAULT_END_FRACTION,
                  max_chunk_elements: int = 1 << 23, stability: float | None = STABILITY_EPS) -> dict[str, np.ndarray]:
    """All pulse measurements of strain histories (..., n_time, n_prisms) in one call.

    Returns a dict of float64 arrays (leading shape ``...``):

    * ``amplitude`` (...) [-]: :func:`leading_pulse_amplitude`;
    * ``speed`` (...) [m s-1]: time-of-flight speed, :func:`pulse_speed`;
    * ``speed_snapshot`` (...) [m s-1]: snapshot speed, :func:`pulse_speed`;
    * ``width_fwhm``, ``width_10`` (...) [prisms]: :func:`width_at_mid_column` at 0.5, 0.1 (the
      mean over one transit of the leading peak), at :func:`width_position`;
    * ``arrival_time`` (..., n_prisms) [s]: :func:`arrival_times`;
    * ``peak_time``, ``peak_value`` (..., n_prisms) [s], [-]: :func:`peak_track`;
    * ``threshold`` (...) [-]: the arrival threshold used;
    * ``prisms_measured`` (...): prisms of the run measured: the longest stretch of the window over
      which the leading peak is continuous (:func:`_chain`); every per-record measure is taken
      over it, and it must hold at least a quarter of the window, else NaN everywhere;
    * ``pulse_captured`` (...): 1 where a run was cut by a discontinuity (something else crossed
      the threshold first at two prisms in a row, or the pulse could not be found again), 0 where
      not, NaN where there is no run; where 1, ``arrival_time`` is NaN at every prism up to the
      window's impact end outside the run measured; ``arrival_time``, ``peak_time`` and
      ``peak_value`` of a prism where the pulse was found again are the pulse's;
    * with ``stability`` (default :data:`STABILITY_EPS`): ``amplitude_sensitivity``,
      ``speed_sensitivity``, ``width_fwhm_sensitivity``, ``width_10_sensitivity``,
      ``arrival_time_sensitivity`` (...) [-]: the largest relative change of that measure when every
      decision parameter (:class:`Decisions`) moves by ``stability`` up or down (arrival times with
      their first-order response to the threshold removed, largest over the prisms); 0 where no
      decision is that close, inf where the measure becomes undefined, NaN where it is undefined.

    ``threshold`` None -> a quarter of the leading amplitude at the window's impact end, found at
    the highest of the trial thresholds (half the record's largest compression, halved in turn
    down to 1/2048 of it) at which the leading peaks reach there (5 % of that maximum where none does):
    the threshold follows the leading pulse, not the late record; else a
    float or an array broadcastable to (...). A record with any non-finite sample gets NaN
    everywhere; so does a flat one. Nothing raises on signal values. Leading dims are processed in
    chunks of about ``max_chunk_elements`` samples to bound memory.
    """
    _check_fraction("end_fraction", end_fraction)
    if stability is not None and not (np.isfinite(stability) and 0.0 < stability < 0.5):
        raise ValueError(f"stability = {stability!r} must be None or lie in (0, 0.5)")
    s, t = _float_array("strain", strain), _float_array("time", time)
    _check_history(s, t)
    h = _float_array("prism_height", prism_height)  # a number, or an array broadcastable to (...)
    if isinstance(prism_height, (bool, np.bool_)) or not (h.size and np.all(np.isfinite(h) & (h > 0))):
        raise ValueError(f"prism_height = {' '.join(repr(prism_height).split())[:60]}: give the reference prism "
                         "height h0 > 0 [m] (a number, or one per record)")
    lead, (T, P) = s.shape[:-2], s.shape[-2:]
    B = int(np.prod(lead, dtype=np.int64))
    s = s.reshape(B, T, P)
    h = np.broadcast_to(np.asarray(prism_height, dtype=np.float64), lead).reshape(B)
    given = None if threshold is None else np.broadcast_to(np.asarray(threshold, dtype=np.float64), lead).reshape(B)
    lo, hi = measurement_window(P, skip_impact, skip_clamp)
    base = Decisions(end_fraction=end_fraction)
    probes = () if stability is None else (base.perturbed(stability, 1), base.perturbed(stability, -1))
    keys_b = ("amplitude", "speed", "speed_snapshot", "width_fwhm", "width_10", "threshold", "prisms_measured",
              "pulse_captured")
    keys_p = ("arrival_time", "peak_time", "peak_value")
    out = {k: np.full(B, np.nan) for k in keys_b} | {k: np.full((B, P), np.nan) for k in keys_p}
    if probes:
        out |= {k: np.full(B, np.nan) for k in SENSITIVITY_KEYS.values()}
    step = max(1, int(max_chunk_elements) // max(1, T * P))
    for b0 in range(0, B, step):
        sl = slice(b0, min(B, b0 + step))
        q, _, finite = _as_history(s[sl], t)
        whole = finite.all(axis=-1)  # strict: any non-finite sample spoils the record
        finite = finite & whole[:, None]
        g = None if given is None else given[sl]
        res = _measure_block(q, t, finite, whole, g, h[sl], lo, hi, base)
        for k in keys_b + keys_p:
            out[k][sl] = res[k]
        if probes:
            sens = _sensitivities(res, [_measure_block(q, t, finite, whole, g, h[sl], lo, hi, d) for d in probes])
            for k, v in sens.items():
                out[k][sl] = v
    return {k: v.reshape(lead + v.shape[1:]) for k, v in out.items()}


def _sensitivities(res: dict, probes: list[dict]) -> dict:
    """Largest relative change of each measure of ``res`` over the probes' (SENSITIVITY_KEYS); inf
    where a probe leaves it undefined, NaN where it is undefined. Arrival times: first-order
    response to the probe's threshold removed (slope dt/dq at the base crossing), largest over prisms."""
    out = {}
    with np.errstate(invalid="ignore", divide="ignore"):
        for k, name in SENSITIVITY_KEYS.items():
            a = res[k]
            worst = np.zeros(a.shape)
            for pr in probes:
                b = pr[k]
                if k == "arrival_time":
                    b = b - (pr["threshold"] - res["threshold"])[:, None] * res["arrival_slope"]
                d = np.where(np.isnan(b), np.inf, np.abs(b - a) / np.abs(a))
                worst = np.maximum(worst, np.where(np.isnan(a), 0.0, d))
            if k == "arrival_time":
                defined = np.isfinite(a).any(axis=-1)
                worst = np.where(defined, worst.max(axis=-1, initial=0.0), np.nan)
            else:
                worst = np.where(np.isnan(a), np.nan, worst)
            out[name] = worst
    return out


def _measure_block(q, t, finite, whole, given, h, lo, hi, d: Decisions) -> dict:
    """measure_pulse's outputs (and ``arrival_slope``, dt/dq at each arrival) for histories q (m, T, P)
    with the decision parameters ``d``; ``given``: thresholds (m,) or None (the default)."""
    B, T, P = q.shape
    min_reached = max(min(5, hi - lo), (hi - lo) // 4)
    if given is None:
        thr_b = d.threshold_fraction * q.max(axis=(-2, -1)) if T * P else np.zeros(B)
    else:
        thr_b = given * d.threshold_scale
    if given is None:
        # the highest of the trials (the record's largest compression halved in turn) at which the leading peaks
        # reach the window's impact end finds the leading pulse there, above any precursor, whatever made the
        # record's maximum (a late reflection, the struck end's chaotic motion: round-off moves it by per cent);
        # the threshold is then a fraction of that pulse's amplitude
        a0 = np.full(B, np.nan)
        for scale in TRIAL_SCALES:
            trial = np.where(np.isfinite(a0), np.nan, thr_b * scale)
            thr, thr_ok = _threshold(q, trial[:, None])
            tr = _track(q, t, finite, thr, thr_ok, d.end_fraction)
            n_in = _reached(tr, lo, hi)
            ok = n_in >= min_reached
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN rows: flat or diverged records
                a_new = np.nanmedian(tr.value[:, hi - min_reached : hi], axis=-1) if min_reached else np.full(B, np.nan)
            a0 = np.where(np.isfinite(a0), a0, np.where(ok & (a_new > 0), a_new, np.nan))
            if np.isfinite(a0).all():
                break
        thr_b = np.where(np.isfinite(a0), d.refined_fraction * a0, thr_b * FALLBACK_SCALE)
    thr, thr_ok = _threshold(q, thr_b[:, None])
    track = _track(q, t, finite, thr, thr_ok, d.end_fraction)
    out = {k: np.full(B, np.nan) for k in ("amplitude", "speed", "speed_snapshot", "width_fwhm", "width_10",
                                            "prisms_measured")}
    out["threshold"] = thr_b
    # the prisms reached: the leading peak followed from the impact side of the window while continuous
    arrival, slope = _arrival_slope(q, t, finite, thr, thr_ok)
    reached, run_hi, cut, tp_f, vp_f, arrival, slope = _chain(q, t, thr, d, track, arrival, slope, lo, hi)
    track = PeakTrack(tp_f, vp_f, track.sample)
    measured = reached >= min_reached
    lo_eff = np.where(measured, run_hi - reached, hi)
    hi_eff = np.where(measured, run_hi, hi)
    jj = np.arange(P)
    outside = (jj < (run_hi - reached)[:, None]) | ((jj >= run_hi[:, None]) & (jj < hi))
    arrival = np.where(cut[:, None] & outside, np.nan, arrival)  # up to the window's impact end: the run's only
    out["pulse_captured"] = np.where(whole & ((reached > 0) | cut), cut.astype(np.float64), np.nan)
    for k, v in {"arrival_time": arrival, "peak_time": track.time, "peak_value": track.value,
                 "arrival_slope": slope}.items():
        out[k] = np.where(whole[:, None], v, np.nan)
    for lo_b, hi_b in {(int(a), int(b)) for a, b in zip(lo_eff, hi_eff)}:
        m = (lo_eff == lo_b) & (hi_eff == hi_b)
        if lo_b >= hi_b:
            continue  # too few prisms reached: NaN
        sub = PeakTrack(track.time[m], track.value[m], track.sample[m])
        v_tof, v_snap = _speeds(q[m], t, finite[m], sub, lo_b, hi_b, h[m])
        part = {
            "amplitude": _amplitude(sub, lo_b, hi_b),
            "speed": v_tof,
            "speed_snapshot": v_snap,
            "width_fwhm": _mid_width(q[m], t, finite[m], sub, 0.5, width_position(lo, hi, lo_b, hi_b)),
            "width_10": _mid_width(q[m], t, finite[m], sub, 0.1, width_position(lo, hi, lo_b, hi_b)),
            "prisms_measured": np.full(m.sum(), float(hi_b - lo_b)),
        }
        for k, v in part.items():
            out[k][m] = np.where(whole[m], v, np.nan)
    return out
