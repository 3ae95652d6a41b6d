"""Shared ``@wp.func`` helpers of the device pulse measures (:mod:`.device`): reads of the strain
record, the parabola vertex, numpy's pairwise summation, rank medians, the window reached, and the
spatial peak and width of a snapshot. Every value is float64; strain is dimensionless, times in s,
positions in prisms (definitions: ``docs/measurements.md``; NumPy reference: :mod:`.pulse`).
"""

from __future__ import annotations

import math
from typing import Any

import warp as wp

from .pulse_core import WIDTH_SEARCH as _WIDTH_SEARCH

f64 = wp.float64
NAN = wp.constant(f64(math.nan))
INF = wp.constant(f64(math.inf))
PW_BLOCK = wp.constant(128)  # numpy's PW_BLOCKSIZE
WIDTH_SEARCH = wp.constant(_WIDTH_SEARCH)
_vec32i = wp.types.vector(32, wp.int32)
_vec32d = wp.types.vector(32, wp.float64)


@wp.func
def q_at(strain: Any, k: int, j: int, b: int, cut: int, n_valid: int) -> f64:
    """Compressive magnitude -strain[k, j] of column b [-]; 0 where non-finite (and for samples
    k >= n_valid, NaN in the host record) as measure._as_history; prisms j < cut read 0 strain."""
    s = f64(0.0)
    if j >= cut:
        if k >= n_valid:
            return f64(0.0)
        s = f64(strain[k, j - cut, b])
        if not wp.isfinite(s):
            return f64(0.0)
    return -s


@wp.func
def finite_at(strain: Any, k: int, j: int, b: int, cut: int, n_valid: int) -> int:
    if j < cut:
        return 1
    if k >= n_valid:
        return 0
    if wp.isfinite(f64(strain[k, j - cut, b])):
        return 1
    return 0


@wp.func
def parabola_coeffs(y0: f64, y1: f64, y2: f64, h1: f64, h2: f64):
    """(a, b) of y = a x^2 + b x + y1 through (-h1, y0), (0, y1), (h2, y2) (measure._parabola_peak)."""
    d0 = (y0 - y1) / h1
    d2 = (y2 - y1) / h2
    return (d0 + d2) / (h1 + h2), (d2 * h1 - d0 * h2) / (h1 + h2)


@wp.func
def parabola_offset(y0: f64, y1: f64, y2: f64, h1: f64, h2: f64) -> f64:
    """Vertex offset of that parabola; NaN unless a < 0."""
    a, bb = parabola_coeffs(y0, y1, y2, h1, h2)
    if a < f64(0.0):
        return -bb / (f64(2.0) * a)
    return NAN


@wp.func
def parabola_value(y0: f64, y1: f64, y2: f64, h1: f64, h2: f64) -> f64:
    """Vertex value of that parabola; NaN unless a < 0."""
    a, bb = parabola_coeffs(y0, y1, y2, h1, h2)
    if a < f64(0.0):
        return y1 - bb * bb / (f64(4.0) * a)
    return NAN


@wp.func
def pw_term(mode: int, x: wp.array2d(dtype=f64), y: wp.array2d(dtype=f64), w: wp.array2d(dtype=f64),
            e: int, b: int, xm: f64, ym: f64) -> f64:
    """Terms of measure._linfit's sums (0/1 weights): w x, w y, w dx dx, w dx (y - ym)."""
    if w[e, b] == f64(0.0):
        return f64(0.0)
    if mode == 0:
        return x[e, b]
    if mode == 1:
        return y[e, b]
    dx = x[e, b] - xm
    if mode == 2:
        return dx * dx
    return dx * (y[e, b] - ym)


@wp.func
def pw_block(mode: int, x: wp.array2d(dtype=f64), y: wp.array2d(dtype=f64), w: wp.array2d(dtype=f64),
             b: int, s: int, n: int, xm: f64, ym: f64) -> f64:
    """numpy's pairwise_sum for n <= 128: eight running sums, then the rest in order."""
    if n < 8:
        res = f64(-0.0)
        for i in range(n):
            res += pw_term(mode, x, y, w, s + i, b, xm, ym)
        return res
    r0 = pw_term(mode, x, y, w, s + 0, b, xm, ym)
    r1 = pw_term(mode, x, y, w, s + 1, b, xm, ym)
    r2 = pw_term(mode, x, y, w, s + 2, b, xm, ym)
    r3 = pw_term(mode, x, y, w, s + 3, b, xm, ym)
    r4 = pw_term(mode, x, y, w, s + 4, b, xm, ym)
    r5 = pw_term(mode, x, y, w, s + 5, b, xm, ym)
    r6 = pw_term(mode, x, y, w, s + 6, b, xm, ym)
    r7 = pw_term(mode, x, y, w, s + 7, b, xm, ym)
    i = int(8)
    while i < n - n % 8:
        r0 += pw_term(mode, x, y, w, s + i + 0, b, xm, ym)
        r1 += pw_term(mode, x, y, w, s + i + 1, b, xm, ym)
        r2 += pw_term(mode, x, y, w, s + i + 2, b, xm, ym)
        r3 += pw_term(mode, x, y, w, s + i + 3, b, xm, ym)
        r4 += pw_term(mode, x, y, w, s + i + 4, b, xm, ym)
        r5 += pw_term(mode, x, y, w, s + i + 5, b, xm, ym)
        r6 += pw_term(mode, x, y, w, s + i + 6, b, xm, ym)
        r7 += pw_term(mode, x, y, w, s + i + 7, b, xm, ym)
        i += 8
    res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    while i < n:
        res += pw_term(mode, x, y, w, s + i, b, xm, ym)
        i += 1
    return res


@wp.func
def pw_half(n: int) -> int:
    h = n / 2
    return h - h % 8


@wp.func
def pw_sum(mode: int, x: wp.array2d(dtype=f64), y: wp.array2d(dtype=f64), w: wp.array2d(dtype=f64),
           b: int, start: int, n: int, xm: f64, ym: f64) -> f64:
    """Sum of pw_term over rows start..start+n-1 of column b, in numpy's pairwise order
    (pw(a, n) = pw(a, n2) + pw(a + n2, n - n2) above 128 terms), so the fits round as the
    reference's. Hand-written: the recursion, which Warp functions cannot do, kept on an explicit stack."""
    if n <= PW_BLOCK:
        return pw_block(mode, x, y, w, b, start, n, xm, ym)
    ss = _vec32i()
    ms = _vec32i()
    st = _vec32i()
    acc = _vec32d()
    sp = int(0)
    ss[0] = wp.int32(start)
    ms[0] = wp.int32(n)
    st[0] = wp.int32(0)
    ret = f64(0.0)
    up = int(0)  # 1: a child has just returned its sum in ret
    while sp >= 0:
        if up == 1:
            if st[sp] == 1:  # left half done: keep it, descend into the right half
                acc[sp] = ret
                st[sp] = wp.int32(2)
                m2 = pw_half(int(ms[sp]))
                ss[sp + 1] = wp.int32(int(ss[sp]) + m2)
                ms[sp + 1] = wp.int32(int(ms[sp]) - m2)
                st[sp + 1] = wp.int32(0)
                sp += 1
                up = 0
            else:
                ret = acc[sp] + ret
                sp -= 1
        else:
            m = int(ms[sp])
            if m <= PW_BLOCK:
                ret = pw_block(mode, x, y, w, b, int(ss[sp]), m, xm, ym)
                sp -= 1
                up = 1
            else:
                st[sp] = wp.int32(1)
                ss[sp + 1] = ss[sp]
                ms[sp + 1] = wp.int32(pw_half(m))
                st[sp + 1] = wp.int32(0)
                sp += 1
    return ret


@wp.func
def kth_smallest(v: wp.array2d(dtype=f64), b: int, start: int, n: int, kk: int) -> f64:
    """The kk-th smallest (0-based) of v[start:start+n, b], by ranks (n small: no scratch, no sort)."""
    for i in range(n):
        x = v[start + i, b]
        less = int(0)
        eq = int(0)
        for m in range(n):
            u = v[start + m, b]
            if u < x:
                less += 1
            elif u == x:
                eq += 1
        if less <= kk and kk < less + eq:
            return x
    return NAN


@wp.func
def median(v: wp.array2d(dtype=f64), b: int, start: int, n: int) -> f64:
    """np.median of v[start:start+n, b] (mean of the two middle values for even n)."""
    if n < 1:
        return NAN
    if n % 2 == 1:
        return kth_smallest(v, b, start, n, n / 2)
    return (kth_smallest(v, b, start, n, n / 2 - 1) + kth_smallest(v, b, start, n, n / 2)) / f64(2.0)


@wp.func
def reached(tp_time: wp.array2d(dtype=f64), b: int, lo: int, hi: int) -> int:
    """measure._reached: window prisms with a leading peak, contiguous from hi - 1 downward."""
    n = int(0)
    j = hi - 1
    while j >= lo:
        if not wp.isfinite(tp_time[j, b]):
            return n
        n += 1
        j -= 1
    return n


@wp.func
def retrack(strain: Any, time: wp.array(dtype=f64), j: int, b: int, cut: int, n_valid: int, th: f64, thr_r: f64,
            end_fraction: f64, t_start: f64):
    """measure._retrack for prism j of column b: (t_peak, q_peak, arrival, dt/dq at the arrival) of
    the pulse that starts with the first upward crossing of thr_r after the first sample at or after t_start."""
    T = time.shape[0]
    k0 = int(T)
    for k in range(T):
        if time[k] >= t_start:
            k0 = k
            break
    ka = int(-1)
    for k in range(k0 + 1, T):
        if q_at(strain, k - 1, j, b, cut, n_valid) < thr_r and q_at(strain, k, j, b, cut, n_valid) >= thr_r:
            ka = k
            break
    if ka < 0:
        return NAN, NAN, NAN, NAN
    m = q_at(strain, ka, j, b, cut, n_valid)
    best = m
    kp = ka
    ke = int(-1)
    for k in range(ka + 1, T):
        qk = q_at(strain, k, j, b, cut, n_valid)
        if qk > m:
            m = qk
        if qk <= end_fraction * m:
            ke = k
            break
        if qk > best:
            best = qk
            kp = k
    kb = k0 + 1
    i = ka - 1
    while i > k0:
        if q_at(strain, i, j, b, cut, n_valid) < th:
            kb = i + 1
            break
        i -= 1
    at = NAN
    sl = NAN
    q0 = q_at(strain, kb - 1, j, b, cut, n_valid)
    q1 = q_at(strain, kb, j, b, cut, n_valid)
    if q0 < th and th <= q1:
        at = time[kb - 1] + (th - q0) / (q1 - q0) * (time[kb] - time[kb - 1])
        sl = (time[kb] - time[kb - 1]) / (q1 - q0)
    if ke < 0 or kp + 1 >= T:
        return NAN, NAN, at, sl
    y0 = q_at(strain, kp - 1, j, b, cut, n_valid)
    y1 = q_at(strain, kp, j, b, cut, n_valid)
    y2 = q_at(strain, kp + 1, j, b, cut, n_valid)
    h1 = time[kp] - time[kp - 1]
    h2 = time[kp + 1] - time[kp]
    val = parabola_value(y0, y1, y2, h1, h2)
    if not wp.isfinite(val):
        return NAN, NAN, at, sl
    return time[kp] + parabola_offset(y0, y1, y2, h1, h2), val, at, sl


@wp.func
def continuous(tp: f64, vp: f64, at: f64, tp1: f64, vp1: f64, at1: f64, at_hi: f64, steps: int, ratio: f64,
               arrival_slack: f64, peak_slack: f64) -> int:
    """measure._continuous: prism j's leading peak continues prism j + 1's."""
    step = (at - at_hi) / f64(steps)
    tol_a = f64(0.0)
    tol_p = f64(0.0)
    if wp.isfinite(step):
        tol_a = arrival_slack * step
        tol_p = peak_slack * step
    if not wp.isfinite(tp):
        return 0
    if at < at1 - tol_a:
        return 0
    if not (vp * ratio > vp1 and vp < ratio * vp1):
        return 0
    if not (tp >= tp1 - tol_p):
        return 0
    return 1


@wp.func
def chain(strain: Any, time: wp.array(dtype=f64), cut: int, n_valid: int, th: f64, end_fraction: f64,
          tp_time: wp.array2d(dtype=f64), tp_value: wp.array2d(dtype=f64), arrival: wp.array2d(dtype=f64),
          slope: wp.array2d(dtype=f64), b: int, lo: int, hi: int, ratio: f64, arrival_slack: f64, peak_slack: f64,
          retrack_lead: f64):
    """measure._chain for column b: (n, run_hi, was_cut) of the longest run of the leading peak
    through the window; the peaks and arrivals (and their dt/dq) of prisms where the pulse was found
    again are written in place."""
    n = int(0)
    cs = hi
    best_n = int(0)
    best_hi = hi
    was_cut = int(0)
    bridged = int(0)
    at_last = NAN  # the last defined arrival of the current run, at prism j_last
    j_last = hi
    j = hi - 1
    while j >= lo:
        ok = wp.isfinite(tp_time[j, b])
        if n == 0:  # the first prism of a run
            if ok:
                n = 1
                cs = j + 1
                bridged = 0
                at_last = arrival[j, b]
                j_last = j
            elif was_cut == 0:
                return best_n, best_hi, was_cut  # before any cut an undefined peak ends the search
            j -= 1
            continue
        a_hi = arrival[cs - 1, b]
        steps = cs - 1 - j
        if continuous(tp_time[j, b], tp_value[j, b], arrival[j, b], tp_time[j + 1, b], tp_value[j + 1, b],
                      at_last, a_hi, steps, ratio, arrival_slack, peak_slack) == 1:
            n += 1
            bridged = 0
            if wp.isfinite(arrival[j, b]):
                at_last = arrival[j, b]
                j_last = j
        elif not ok:  # an undefined peak ends the run
            if n > best_n:
                best_n = n
                best_hi = cs
            n = 0
            bridged = 0
            if was_cut == 0:
                return best_n, best_hi, was_cut
        else:
            good = int(0)
            if bridged == 0:
                s = NAN
                if cs - 1 - j_last > 0:
                    s = (at_last - a_hi) / f64(cs - 1 - j_last)
                tol = f64(0.0)
                if wp.isfinite(s):
                    tol = retrack_lead * s
                thr_r = th
                r = tp_value[j + 1, b] / ratio
                if r > thr_r:
                    thr_r = r
                start = at_last
                if not wp.isfinite(start):
                    start = tp_time[j + 1, b]
                rt, rv, ra, rs = retrack(strain, time, j, b, cut, n_valid, th, thr_r, end_fraction, start - tol)
                if continuous(rt, rv, ra, tp_time[j + 1, b], tp_value[j + 1, b], at_last, a_hi, steps,
                              ratio, arrival_slack, peak_slack) == 1:
                    tp_time[j, b] = rt
                    tp_value[j, b] = rv
                    arrival[j, b] = ra
                    slope[j, b] = rs
                    good = 1
            if good == 1:
                n += 1
                bridged = 1
                if wp.isfinite(arrival[j, b]):
                    at_last = arrival[j, b]
                    j_last = j
            else:  # a cut: the run ends, a new one starts at j
                if n > best_n:
                    best_n = n
                    best_hi = cs
                was_cut = 1
                n = 1
                cs = j + 1
                bridged = 0
                at_last = arrival[j, b]
                j_last = j
        j -= 1
    if n > best_n:
        best_n = n
        best_hi = cs
    return best_n, best_hi, was_cut


@wp.func
def spatial_peak_index(strain: Any, k: int, b: int, cut: int, n_valid: int, P: int, c: int, search: int) -> int:
    """First argmax of q[k, j] over |j - c| <= search, 0 <= j < P (measure._spatial_peak); -1 if none."""
    i = int(-1)
    best = -INF
    for j in range(wp.max(c - search, 0), wp.min(c + search + 1, P)):
        qj = q_at(strain, k, j, b, cut, n_valid)
        if qj > best or i < 0:
            best = qj
            i = j
    return i


@wp.func
def width_at(strain: Any, k: int, b: int, cut: int, n_valid: int, P: int, near: f64, search: int, level: f64) -> f64:
    """measure._width of snapshot k of column b with the peak searched within `search` of rint(near)."""
    i = spatial_peak_index(strain, k, b, cut, n_valid, P, int(wp.rint(near)), search)
    if i < 1 or i > P - 2:
        return NAN
    y0 = q_at(strain, k, i - 1, b, cut, n_valid)
    y1 = q_at(strain, k, i, b, cut, n_valid)
    y2 = q_at(strain, k, i + 1, b, cut, n_valid)
    if not (y0 < y1 and y2 <= y1 and y1 > f64(0.0)):
        return NAN
    off = parabola_offset(y0, y1, y2, f64(1.0), f64(1.0))
    val = parabola_value(y0, y1, y2, f64(1.0), f64(1.0))
    if not wp.isfinite(f64(i) + off):
        return NAN
    L = level * val
    if not (y1 >= L):
        return NAN
    il = int(-1)
    for j in range(i):
        if q_at(strain, k, j, b, cut, n_valid) < L:
            il = j
    ir = int(-1)
    j = i + 1
    while j < P and ir < 0:
        if q_at(strain, k, j, b, cut, n_valid) < L:
            ir = j
        j += 1
    if il < 0 or ir < 0:
        return NAN
    a0 = q_at(strain, k, il, b, cut, n_valid)
    a1 = q_at(strain, k, il + 1, b, cut, n_valid)
    b0 = q_at(strain, k, ir - 1, b, cut, n_valid)
    b1 = q_at(strain, k, ir, b, cut, n_valid)
    xl = f64(il) + (L - a0) / (a1 - a0)
    xr = f64(ir - 1) + (b0 - L) / (b0 - b1)
    return xr - xl



@wp.func
def transit_width(strain: Any, time: wp.array(dtype=f64), b: int, cut: int, n_valid: int, P: int, x: f64,
                  t0: f64, t1: f64, level: f64) -> f64:
    """measure._mid_width's mean over [t0, t1] (t0 <= t1, finite) of the piecewise-linear interpolant
    of the snapshot widths at position x; the interpolant at t0 where t0 = t1; NaN where a snapshot
    used has no width."""
    T = time.shape[0]
    if T < 2:
        return NAN
    ka = int(T - 1)
    for k in range(T):  # np.searchsorted(t, t0, 'left'), clipped to [1, T - 1]
        if time[k] >= t0:
            ka = k
            break
    ka = wp.max(ka, 1)
    kb = int(T - 1)
    for k in range(T):  # np.searchsorted(t, t1, 'right'), clipped
        if time[k] > t1:
            kb = k
            break
    kb = wp.max(wp.max(kb, 1), ka)
    w_prev = width_at(strain, ka - 1, b, cut, n_valid, P, x, WIDTH_SEARCH, level)
    if not wp.isfinite(w_prev):
        return NAN
    w_first = w_prev
    w_second = NAN
    area = f64(0.0)
    for k in range(ka, kb + 1):
        w = width_at(strain, k, b, cut, n_valid, P, x, WIDTH_SEARCH, level)
        if not wp.isfinite(w):
            return NAN
        if k == ka:
            w_second = w
        tk = time[k - 1]
        u0 = wp.max(tk, t0)
        u1 = wp.min(time[k], t1)
        if u1 > u0:
            dw = (w - w_prev) / (time[k] - tk)
            area += f64(0.5) * ((w_prev + dw * (u0 - tk)) + (w_prev + dw * (u1 - tk))) * (u1 - u0)
        w_prev = w
    span = t1 - t0
    if span > f64(0.0):
        return area / span
    a0 = wp.clamp((t0 - time[ka - 1]) / (time[ka] - time[ka - 1]), f64(0.0), f64(1.0))
    return w_first + a0 * (w_second - w_first)


# ---------------------------------------------------------------------- energy measures (measure.energy)
@wp.func
def peak_time_at(tp_time: wp.array2d(dtype=f64), b: int, y: f64) -> f64:
    """The leading peak's time at position y [prisms], linear between the prisms around it
    (energy._interp_peak_time)."""
    i = int(wp.floor(y))
    f = y - f64(i)
    if f == f64(0.0):
        return tp_time[i, b]
    return (f64(1.0) - f) * tp_time[i, b] + f * tp_time[i + 1, b]


@wp.func
def record_at(e: Any, time: wp.array(dtype=f64), b: int, n_valid: int, t: f64) -> f64:
    """Record e[:, b] at time t [s], linear between the output samples; NaN past the last valid
    one (energy._interp_record)."""
    if not (wp.isfinite(t) and time[0] <= t and t <= time[n_valid - 1]):
        return NAN
    k = int(0)
    while k + 1 < n_valid and time[k + 1] <= t:
        k += 1
    ek = f64(e[k, b])
    if time[k] == t:
        return ek
    return ek + (t - time[k]) / (time[k + 1] - time[k]) * (f64(e[k + 1, b]) - ek)
