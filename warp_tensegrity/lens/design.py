"""Design: invert the calibrated exit-time law T(p) so that every column's pulse meets at F.

For focal point F, columns at x_i struck at delays d_i, host speed c_h:

    d_i + T(p_i) + |F - x_i| / c_h = C   for all i.

The common arrival C is the centre of the interval that keeps every target T_i = C - d_i -
|F - x_i| / c_h inside the calibrated range [T_lo, T_hi]; if the targets' spread exceeds the
range, C maximises the number of columns that reach it and the others are reported (and get the
nearest calibrated prestrain).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import isotonic_regression


class CalibrationError(ValueError):
    """The calibration cannot be inverted (too few finite samples, no monotone trend)."""


@dataclass(frozen=True)
class ExitLaw:
    """Monotone fit of the calibrated exit time T(p) (pool-adjacent-violators, SciPy), inverted
    piecewise linearly between its knots."""

    prestrain: np.ndarray
    """(K,) knot prestrains [1], increasing."""
    exit_time: np.ndarray
    """(K,) knot exit times [s], strictly monotone."""
    decreasing: bool
    """True when a larger prestrain gives an earlier exit."""
    rms_residual: float
    """RMS of the raw samples about the monotone fit [s] (measurement jitter)."""
    dropped: int
    """Calibration samples left out (non-finite exit time)."""

    @property
    def t_range(self) -> tuple[float, float]:
        return float(self.exit_time.min()), float(self.exit_time.max())

    def time(self, p) -> np.ndarray:
        """T(p) [s], piecewise linear between knots (p clipped to the calibrated range)."""
        return np.interp(p, self.prestrain, self.exit_time)

    def invert(self, t) -> np.ndarray:
        """p with T(p) = t [1]; t outside the calibrated range gives the nearest end."""
        if self.decreasing:
            return np.interp(t, self.exit_time[::-1], self.prestrain[::-1])
        return np.interp(t, self.exit_time, self.prestrain)


def fit_exit_law(prestrain, exit_time) -> ExitLaw:
    """Monotone exit-time law from calibration samples (NaN samples are dropped)."""
    p = np.asarray(prestrain, float)
    t = np.asarray(exit_time, float)
    ok = np.isfinite(p) & np.isfinite(t)
    if ok.sum() < 4:
        raise CalibrationError(f"only {int(ok.sum())} calibration columns have a finite exit time; need >= 4 "
                               "(is t_end long enough for the slowest pulse to leave the column?)")
    order = np.argsort(p[ok])
    p, t = p[ok][order], t[ok][order]
    decreasing = bool(np.polyfit(p - p.mean(), t, 1)[0] < 0)
    fit = isotonic_regression(t, increasing=not decreasing).x
    # pool equal fitted values into strictly monotone knots at their mean prestrain
    edges = np.flatnonzero(np.diff(fit) != 0) + 1
    blocks = np.split(np.arange(len(p)), edges)
    kp = np.array([p[b].mean() for b in blocks])
    kt = np.array([fit[b[0]] for b in blocks])
    if len(kp) < 2:
        raise CalibrationError("the calibrated exit time does not change with the prestrain: nothing to design with")
    return ExitLaw(kp, kt, decreasing, float(np.sqrt(np.mean((t - fit) ** 2))), int((~ok).sum()))


@dataclass(frozen=True)
class Design:
    """Prestrains for one focal point."""

    focal_point: np.ndarray
    """(3,) [m]."""
    prestrain: np.ndarray
    """(N,) designed prestrain per column [1]."""
    target_exit_time: np.ndarray
    """(N,) exit time each column must have, after its own strike [s]."""
    arrival_time: float
    """Common arrival time C at the focal point [s]."""
    reachable: np.ndarray
    """(N,) bool: the target lies in the calibrated range."""
    flight_time: np.ndarray
    """(N,) d_i + |F - x_i| / c_h [s]."""


def common_arrival(lag: np.ndarray, t_lo: float, t_hi: float) -> float:
    """C for targets C - lag_i: the centre of the feasible interval [t_lo + max lag, t_hi + min lag],
    else the C that keeps the most targets in [t_lo, t_hi] (ties: nearest that centre)."""
    lag = np.asarray(lag, float)
    centre = 0.5 * (t_lo + t_hi + lag.max() + lag.min())
    if t_lo + lag.max() <= t_hi + lag.min():
        return float(centre)
    cand = np.concatenate([t_lo + lag, t_hi + lag])
    count = np.array([np.sum((c - lag >= t_lo - 1e-15) & (c - lag <= t_hi + 1e-15)) for c in cand])
    best = cand[count == count.max()]
    return float(best[np.argmin(np.abs(best - centre))])


def design_focus(law: ExitLaw, positions, delays, focal_point, wave_speed: float) -> Design:
    """Prestrain per column so that all exit pulses arrive at ``focal_point`` together."""
    F = np.asarray(focal_point, float)
    lag = np.asarray(delays, float) + np.linalg.norm(np.asarray(positions, float) - F, axis=1) / wave_speed
    t_lo, t_hi = law.t_range
    C = common_arrival(lag, t_lo, t_hi)
    target = C - lag
    span = t_hi - t_lo
    reachable = (target >= t_lo - 1e-9 * span) & (target <= t_hi + 1e-9 * span)
    return Design(F, law.invert(target), target, C, reachable, lag)
