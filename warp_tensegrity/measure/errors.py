"""The numerical error of every pulse measure, estimated from a twin run (:func:`error_estimates`).

A sweep steps each group of columns twice (:func:`warp_tensegrity.policy.groups.twin_plan`): at its
dt and at dt_twin ~ 4 dt, on the same output times. For a method of order p the truncation error of
a measure m scales as dt^p, so (Richardson)

    err(m) ~ |m(dt) - m(dt_twin)| / ((dt_twin / dt)^p - 1)

and the twin costs about a quarter of the steps. The estimate given is :data:`SAFETY` times that plus
a :data:`FLOOR` relative to the measure: the same difference also holds the two runs' round-off,
which the Richardson factor wrongly divides, and a measure that flips between two features in one
run only. Where a measure is
defined and its twin's is not (or the other way round), the estimate cannot say: ``error_flag`` =
twin_undefined; where the
estimate exceeds the accuracy target: over_target (:data:`~warp_tensegrity.types.ERROR_FLAGS`).
A per-prism arrival time the twin lacks (the last prism reached by t_end) has a NaN estimate and
no flag.
"""

from __future__ import annotations

import warnings

import numpy as np

from ..types import ERROR_ESTIMATED as ESTIMATED
from ..types import ERROR_FLAGS
FLAG = {name: i for i, name in enumerate(ERROR_FLAGS)}
SAFETY = 2.0
"""The Richardson difference is an estimate, not a bound: it is taken twice."""
FLOOR = {"fp32": 1e-4, "fp64": 1e-5}
"""Added to every estimate, relative to the measure (to the column's crossing time for an arrival
time): what the twin cannot see. In fp32 the twin's difference holds the round-off of both runs
divided by the Richardson factor (~15), so it underrates round-off; in fp64 it bounds the estimate's
resolution. Both calibrated on a 200-case CPU set (16 prisms; FB, beta 0.5-0.95, RB; p 0-0.01;
v0 3-40 mm/s; reference fp64 at dt/4, ``benchmarks/error_coverage.py``): with SAFETY 2 and these
floors the estimate covered the real error in >= 99 % (fp64) and >= 97.9 % (fp32) of the feasible
cases for every measure, against 76-81 % and 41-65 % with the bare difference."""


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
    for k in ESTIMATED:
        a = np.asarray(meas[k], dtype=np.float64)
        b = np.asarray(twin[k], dtype=np.float64)
        with np.errstate(invalid="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN rows: columns with no arrival
            f = factor.reshape(factor.shape + (1,) * (a.ndim - factor.ndim)) if factor.ndim else factor
            scale = np.abs(a) if a.ndim == 1 else np.nanmax(np.abs(a), axis=-1, keepdims=True)
            e = SAFETY * np.abs(a - b) / f + floor * scale
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
