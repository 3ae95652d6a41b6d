"""The numerical error of every pulse measure, estimated from a twin run (:func:`error_estimates`).

A sweep steps each group of columns twice (:func:`warp_tensegrity.policy.groups.twin_plan`): at its
dt and at dt_twin ~ 4 dt, on the same output times. Their difference d = |m(dt) - m(dt_twin)|
gives the estimate:

* fp64, where truncation dominates: for a method of order p the error of m scales as dt^p, so
  (Richardson) err ~ d / ((dt_twin / dt)^p - 1), taken :data:`SAFETY` times. Where d itself exceeds
  the accuracy target the pair is outside the asymptotic range (a measure that the dynamics make
  sensitive to any perturbation: a low-prestrain column's late peaks), the division is not
  trusted and the estimate is d;
* fp32, where round-off dominates: two runs whose round-off differs differ by about the error of
  either, and dt does not scale it, so the estimate is :data:`SAFETY` x d, undivided.

Each adds a :data:`FLOOR` relative to the measure. Where a measure is defined and its twin's is not
(or the other way round), the estimate cannot say: ``error_flag`` = twin_undefined; where the
estimate exceeds the accuracy target: over_target (:data:`~warp_tensegrity.types.ERROR_FLAGS`).
A per-prism arrival time the twin lacks (the last prism reached by t_end) has a NaN estimate and
no flag.

Calibrated on phase_large on an H200 (1,053 feasible cases, reference fp64 at dt / 4,
``benchmarks/error_coverage.py``; benchmarks/results/error_coverage_phase_large_h200_0f97af1.json): the
Richardson estimate alone covered the real error in 89.6-91.3 % (fp32) and 94.9-96.5 % (fp64) of
the cases per measure; these rules cover 95.6-97.2 % (fp32) and 96.4-97.7 % (fp64).
"""

from __future__ import annotations

import warnings

import numpy as np

from ..policy.accuracy import DEFAULT_ACCURACY
from ..types import ERROR_ESTIMATED as ESTIMATED
from ..types import ERROR_FLAGS
FLAG = {name: i for i, name in enumerate(ERROR_FLAGS)}
SAFETY = 2.0
"""The difference is an estimate, not a bound: it is taken twice (fp64: the Richardson quotient;
fp32: the difference)."""
FLOOR = {"fp32": 1e-4, "fp64": 1e-5}
"""Added to every estimate, relative to the measure (to the column's crossing time for an arrival
time): what the twin cannot see, and the estimate's resolution."""
VERIFY_MARGIN = 0.5
"""precision 'auto' keeps a case's fp32 answer only where every estimate is within this share of the
accuracy target: an estimate is itself uncertain (on phase_large, 2-3 % of the real errors exceed
twice their estimate), so one just under the target does not verify."""


def _scale(a: np.ndarray) -> np.ndarray:
    """What an estimate is relative to: |m|, or for a per-prism measure its row's largest |m|."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN rows: columns with no arrival
        return np.abs(a) if a.ndim == 1 else np.nanmax(np.abs(a), axis=-1, keepdims=True)


def largest_share(meas: dict, err: dict) -> np.ndarray:
    """(B,) the largest estimate relative to its measure over :data:`ESTIMATED` (0 where none is
    defined)."""
    B = np.asarray(meas["amplitude"]).shape[0]
    out = np.zeros(B)
    for k in ESTIMATED:
        with np.errstate(invalid="ignore", divide="ignore"):
            rel = (np.asarray(err[f"{k}_error"], dtype=np.float64) / _scale(np.asarray(meas[k], dtype=np.float64)))
        out = np.fmax(out, np.nan_to_num(rel.reshape(B, -1), nan=0.0).max(axis=1))
    return out


def with_perturbation(err: dict, meas: dict, perturbed: dict, target: float, precision: str = "fp64") -> dict:
    """``err`` (of ``meas``, a run's measures) raised where a run of the same cases at the same dt that
    differs by round-off only (``perturbed``: precision 'auto''s fp32 run of the cases it reruns in
    fp64) moved a measure more: to :data:`SAFETY` x that difference plus the floor, the fp32 rule.
    A measure that round-off moves by more than the twin's dt pair does (a low-prestrain column's
    late peaks: on phase_large, fp64 runs at dt and 4 dt that agree to 2e-5 while dt / 4 moves the
    amplitude by 1.4e-3) is sensitive to any perturbation, and the fp64 twin alone cannot see it.
    ``error_flag`` is set over_target again where an estimate now exceeds ``target``."""
    out = dict(err)
    floor = FLOOR.get(str(precision), FLOOR["fp64"])
    for k in ESTIMATED:
        a = np.asarray(meas[k], dtype=np.float64)
        b = np.asarray(perturbed[k], dtype=np.float64)
        with np.errstate(invalid="ignore"):
            e = np.fmax(np.asarray(err[f"{k}_error"], dtype=np.float64), SAFETY * np.abs(a - b) + floor * _scale(a))
        out[f"{k}_error"] = np.where(np.isfinite(err[f"{k}_error"]), e, err[f"{k}_error"])
    flag = np.asarray(err["error_flag"]).copy()
    flag[(flag == FLAG["ok"]) & (largest_share(meas, out) > target)] = FLAG["over_target"]
    out["error_flag"] = flag
    return out


def error_estimates(meas: dict, twin: dict | None, factor: float, precision: str = "fp64",
                    target: float | None = None) -> dict:
    """``<measure>_error`` (same shape and units as each measure of :data:`ESTIMATED`) and
    ``error_flag`` (B,) int8 from the measures of a run (``meas``) and of its twin (``twin``, None:
    no twin), ``factor`` = (dt_twin / dt)^p - 1. ``target``: relative accuracy target above which an
    estimate is flagged over_target (None: not checked)."""
    B = np.asarray(meas["amplitude"]).shape[0]
    flag = np.zeros(B, dtype=np.int8)
    out = {}
    if twin is None:
        for k in ESTIMATED:
            out[f"{k}_error"] = np.full(np.shape(meas[k]), np.nan)
        defined = np.isfinite(np.asarray(meas["amplitude"], dtype=np.float64))
        flag[defined] = FLAG["no_twin"]
        return out | {"error_flag": flag}
    factor = np.asarray(factor, dtype=np.float64)
    undefined = np.zeros(B, dtype=bool)
    over = np.zeros(B, dtype=bool)
    floor = FLOOR.get(str(precision), FLOOR["fp64"])
    threshold = DEFAULT_ACCURACY if target is None else target
    for k in ESTIMATED:
        a = np.asarray(meas[k], dtype=np.float64)
        b = np.asarray(twin[k], dtype=np.float64)
        with np.errstate(invalid="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN rows: columns with no arrival
            f = factor.reshape(factor.shape + (1,) * (a.ndim - factor.ndim)) if factor.ndim else factor
            scale = np.abs(a) if a.ndim == 1 else np.nanmax(np.abs(a), axis=-1, keepdims=True)
            d = np.abs(a - b)
            if str(precision) == "fp32":  # round-off: the twin differs by about the error itself
                e = SAFETY * d + floor * scale
            else:  # truncation: Richardson, unless the pair is outside the asymptotic range
                e = np.where(d > threshold * scale, d, SAFETY * d / f) + floor * scale
        e = np.where(np.isfinite(a), e, np.nan)
        lost = np.isfinite(a) & ~np.isfinite(b)
        e = np.where(lost, np.nan, e)
        out[f"{k}_error"] = e
        if a.ndim == 1:  # a per-prism arrival the twin lacks is the last prism reached by t_end: NaN, no flag
            undefined |= np.isfinite(a) != np.isfinite(b)  # either run alone defines the measure
        if target is not None:
            with np.errstate(invalid="ignore"):
                rel = (e / scale).reshape(B, -1)
            over |= np.nan_to_num(rel, nan=0.0).max(axis=1) > target
    flag[over] = FLAG["over_target"]
    flag[undefined] = FLAG["twin_undefined"]
    return out | {"error_flag": flag}
