"""Per-column pulse measures of a BatchResult, why a measure is NaN (one CF flag per column), and
the end-of-run summary.

Every NaN in ``amplitude``, ``speed``, ``width``, ``width_10`` and ``prisms_measured`` of a column
carries a flag other than ``ok`` in ``measurement_flag`` (the first reason, in the order of the
table below, that explains the first NaN of amplitude, speed, widths):

==  ==================================  =====================================================
 0  ok                                  every measure defined
 1  non_finite                          the state became non-finite (status 1) or the record
                                        holds a non-finite sample: every measure NaN
 2  constraint_failure                  a bar constraint failed (status 2): every measure NaN
 3  no_leading_pulse                    no compression above 1e-9 anywhere (flat
                                        record), or the front crossed the window but no
                                        pulse formed (no peak after which compression fell to
                                        half): every measure NaN
 4  pulse_not_reached_window_by_t_end   the leading pulse had passed fewer than a quarter of
                                        the measurement window's prisms by t_end: run longer
 5  record_too_short_for_width          amplitude and speed are defined, but the mid-column
                                        snapshot has no crossing of half (or 10 %) of the peak
                                        on one side within the column (the pulse had not left
                                        the impacted end or the window by t_end): width NaN
 6  speed_undefined                     amplitude defined, but the leading-peak times do not
                                        move toward the clamp (no positive speed)
 8  leading_pulse_captured              the leading peak breaks off (its value jumps, or the
                                        arrival or peak comes earlier than at the previous
                                        prism, at two prisms in a row or where it cannot be
                                        found again) so often that no continuous run covers a
                                        quarter of the window: something else (a disturbance
                                        from the clamp, a precursor) crossed the threshold
                                        first, so no measure is given (checked before 3 and 4)
 7  measurement_undefined               any other NaN (should not occur; report it)
 9  left_feasible_set                   the column left the model's feasible set (bars
                                        crossed, cables touched, a prism inverted:
                                        ``feasibility_flag``) before its leading pulse had
                                        crossed the measurement window, or at any time where
                                        no pulse was found there: every measure NaN (checked
                                        after 1 and 2, before the others; docs/model.md)
10  measure_unstable                    the measures are defined, but one of amplitude, speed,
                                        widths or arrival times changes by more than the run's
                                        accuracy target when the measure's decisions (threshold,
                                        end of the leading pulse, continuity of the run) move by
                                        that target: a decision sits at its boundary, so round-off
                                        could flip it (checked before 5 and 6; the numbers are kept)
==  ==================================  =====================================================

Where a continuous run of the leading peak covers a quarter of the window or more, the measures
are taken over the longest one (``prisms_measured`` says how long) and the flag stays ``ok``.

``arrival_time`` is per prism: NaN at the prisms the threshold never reached by t_end (that is
what it measures), and at those it reached only after the column left the feasible set, which
needs no flag.
"""

from __future__ import annotations

import math

import numpy as np

from ..types import MEASUREMENT_FLAGS as FLAGS
from ..types import TIME
from .energy import ENERGY_SHARES
from .feasibility import left_before_measured
from .pulse_core import SENSITIVITY_KEYS, STABILITY_FLOOR, measure_pulse, measurement_window

FLAG = {name: i for i, name in enumerate(FLAGS)}
FLAGGED = ("amplitude", "speed", "width", "width_10", "prisms_measured", "max_compression")
"""Per-column measures that are NaN only where measurement_flag is not ok."""

FLAT_STRAIN = 1e-9
"""A record whose largest compression stays below this strain is flat (round-off of the prestressed
reference state is ~1e-14)."""
# prisms beyond the window's far end the front must pass for the last peak to be over
_PEAK_CLEARANCE = 4

FAILED = ("non_finite", "constraint_failure")
"""Flags of a column that did not run to t_end (its state, or a bar constraint, failed)."""
FAR_ABOVE_SOUND = 10.0
"""v0 / c0 from which a run whose every case failed names the impact speed as the likely cause:
the paper's own cases run at up to 5.7 c0 (v0 = 0.15 m s-1, c0 = 0.026 m s-1 at p = 0.002)."""


def measure_columns(result, prism_height: float) -> dict:
    """Leading-pulse measurements per column: the engine's device measures, else
    :func:`~warp_tensegrity.measure.pulse_core.measure_pulse` on the record; NaN where undefined and for
    every column whose status is not ok, with the flag saying why (``measure_unstable`` where a
    measure's sensitivity exceeds the run's accuracy target, ``result.info['choices']['accuracy']``,
    else :data:`~.pulse_core.STABILITY_FLOOR`). ``prism_height`` [m]."""
    status = np.asarray(result.status)
    m = getattr(result, "measurements", None)  # taken by the engine (on the device by default)
    if m is None:
        with np.errstate(all="ignore"):
            m = measure_pulse(result.strain, result.time, prism_height)
    bad = status != 0
    out = {
        "amplitude": m["amplitude"],
        "speed": m["speed"],
        "width": m["width_fwhm"],
        "width_10": m["width_10"],
        "prisms_measured": m["prisms_measured"],
        "arrival_time": m["arrival_time"],
        "pulse_captured": m.get("pulse_captured", np.zeros(status.shape[0])),
        # the energy measures (measure.energy): NaN where the run did not record them
        **{k: m.get(k, np.full(status.shape[0], np.nan)) for k in ENERGY_SHARES},
    }
    out = {k: np.array(v, dtype=np.float64, copy=True) for k, v in out.items()}
    for v in out.values():
        v[bad] = np.nan
    floor = (getattr(result, "info", None) or {}).get("choices", {}).get("accuracy") or STABILITY_FLOOR
    with np.errstate(invalid="ignore"):
        out["unstable"] = np.any([np.asarray(m[k]) > floor for k in SENSITIVITY_KEYS.values() if k in m], axis=0) & ~bad
    stats = None
    if result.strain is not None:
        with np.errstate(invalid="ignore"):
            out["max_compression"] = np.max(-np.asarray(result.strain, dtype=np.float64), axis=(1, 2))
    else:  # the record stayed on the device: its statistics came with the measures
        out["max_compression"] = np.array(m["max_compression"], dtype=np.float64, copy=True)
        stats = {k: m[k] for k in ("record_finite", "max_compression_finite")}
    out["max_compression"][bad | ~np.isfinite(out["max_compression"])] = np.nan
    out["measurement_flag"] = measurement_flags(status, result.strain, result.time, out, stats)
    feas = getattr(result, "feasibility", None)
    if feas is not None:  # measures of a model outside its domain: docs/model.md
        t_left = np.asarray(feas["feasibility_time"], dtype=np.float64)
        left = left_before_measured(t_left, m["peak_time"]) & ~bad
        for k in FLAGGED:
            out[k][left] = np.nan
        out["pulse_energy_share"][left] = np.nan
        out["end_energy_share"][np.isfinite(t_left)] = np.nan  # at t_end: NaN once the column left the set
        out["measurement_flag"][left] = FLAG["left_feasible_set"]
        with np.errstate(invalid="ignore"):
            out["arrival_time"][out["arrival_time"] >= t_left[:, None]] = np.nan
    return out


def measurement_flags(status, strain, time, meas: dict, record_stats: dict | None = None) -> np.ndarray:
    """(B,) int8 flag per column from the engine status, the strain record (B, T, P) (None if not
    recorded) and the measures of :func:`measure_columns`.
    ``record_stats``: when the record stayed on the device, its ``record_finite`` (B,) and
    ``max_compression_finite`` (B,) (:func:`warp_tensegrity.measure.device.measure_record`)."""
    status = np.asarray(status)
    B = status.shape[0]
    flags = np.full(B, FLAG["ok"], dtype=np.int8)
    amp, speed = np.asarray(meas["amplitude"]), np.asarray(meas["speed"])
    captured = np.asarray(meas.get("pulse_captured", np.zeros(B))) == 1
    unstable = np.asarray(meas.get("unstable", np.zeros(B, dtype=bool)), dtype=bool).reshape(B)
    widths = np.isnan(np.asarray(meas["width"])) | np.isnan(np.asarray(meas["width_10"]))
    if strain is None and record_stats is not None:
        finite = np.asarray(record_stats["record_finite"], dtype=bool)
        compressed = np.asarray(record_stats["max_compression_finite"]) > FLAT_STRAIN
        P = np.asarray(meas["arrival_time"]).shape[-1]
        lo, hi = measurement_window(P)
        arrived = np.isfinite(np.asarray(meas["arrival_time"])[:, lo:hi]).sum(axis=1)
    elif strain is None:
        finite = np.ones(B, dtype=bool)
        compressed = np.zeros(B, dtype=bool)
        arrived = np.zeros(B)
        P = None
    else:
        s = np.asarray(strain)
        finite = np.isfinite(s).all(axis=(1, 2))
        P = s.shape[-1]
        with np.errstate(invalid="ignore"):
            compressed = np.nanmax(np.where(np.isfinite(s), -s, 0.0), axis=(1, 2)) > FLAT_STRAIN
        lo, hi = measurement_window(P)
        arrived = np.isfinite(np.asarray(meas["arrival_time"])[:, lo:hi]).sum(axis=1)
    need = None if P is None else max(min(5, hi - lo), (hi - lo) // 4)
    for b in range(B):
        if status[b] == 1 or not finite[b]:
            flags[b] = FLAG["non_finite"]
        elif status[b] == 2:
            flags[b] = FLAG["constraint_failure"]
        elif np.isnan(amp[b]):
            if captured[b]:
                flags[b] = FLAG["leading_pulse_captured"]
            elif not compressed[b]:
                flags[b] = FLAG["no_leading_pulse"]
            elif need is not None and arrived[b] >= need:
                flags[b] = FLAG["no_leading_pulse"]  # the front crossed the window, no pulse over it
            elif need is not None:
                flags[b] = FLAG["pulse_not_reached_window_by_t_end"]
            else:
                flags[b] = FLAG["measurement_undefined"]
        elif unstable[b]:
            flags[b] = FLAG["measure_unstable"]
        elif np.isnan(speed[b]):
            flags[b] = FLAG["speed_undefined"]
        elif widths[b]:
            flags[b] = FLAG["record_too_short_for_width"]
    return flags


def t_end_needed(arrival_time: np.ndarray, time: np.ndarray) -> np.ndarray:
    """(B,) t_end [s] at which the leading front would have passed the far end of the measurement
    window by a few prisms (so that its last peak is over), extrapolated linearly from the
    arrival times so far; NaN where fewer than two prisms were reached."""
    at = np.asarray(arrival_time, dtype=np.float64)
    B, P = at.shape
    lo, _ = measurement_window(P)
    target = lo - _PEAK_CLEARANCE
    out = np.full(B, np.nan)
    j = np.arange(P, dtype=np.float64)
    for b in range(B):
        ok = np.isfinite(at[b])
        if ok.sum() < 2:
            continue
        c1, c0 = np.polyfit(j[ok], at[b, ok], 1)
        if c1 < 0:
            out[b] = c0 + c1 * target
    return out


def _round_up(x: float) -> float:
    """x rounded up to two significant digits."""
    if not (math.isfinite(x) and x > 0):
        return x
    scale = 10.0 ** (math.floor(math.log10(x)) - 1)
    return math.ceil(x / scale - 1e-9) * scale


def summary(flags, n_prisms: int, t_end: float, needed=None) -> list[str]:
    """One line per kind of NaN: how many columns, why, and what would help."""
    flags = np.asarray(flags).reshape(-1)
    n = flags.size
    lines = []
    lo, _ = measurement_window(int(n_prisms))
    counts = {f: int((flags == FLAG[f]).sum()) for f in FLAGS[1:]}
    k = counts["pulse_not_reached_window_by_t_end"]
    if k:
        text = (f"{k} of {n} cases have no speed: the pulse had not reached prism {lo} (far end of the "
                f"measurement window) by t_end = {t_end:g} s")
        if needed is not None:
            nd = np.asarray(needed).reshape(-1)[flags == FLAG["pulse_not_reached_window_by_t_end"]]
            if np.isfinite(nd).all() and nd.size:
                text += f"; t_end >= {_round_up(float(nd.max()) * 1.1):g} s would be enough"
            else:
                text += "; run longer"
        lines.append(text)
    why = {
        "non_finite": "the state became non-finite (try a smaller dt)",
        "constraint_failure": "a bar constraint failed (try a smaller dt)",
        "no_leading_pulse": "no leading pulse formed (flat or front without a pulse)",
        "record_too_short_for_width": "no width: the pulse was not clear of the ends in the mid-column snapshot",
        "speed_undefined": "no speed: the leading peak does not travel toward the clamp",
        "measurement_undefined": "a measure is NaN for no known reason",
        "leading_pulse_captured": "no measure: something else (a disturbance from the clamp, a precursor) crossed the "
                                  "threshold before the leading pulse over most of the window",
        "left_feasible_set": "no measure: the column left the feasible set of the model (feasibility_flag) before its "
                             "pulse had crossed the measurement window",
        "measure_unstable": "a measure sits at a decision's boundary (threshold, end of the pulse, continuity): it "
                            "would change by more than the accuracy target under round-off; numbers kept, not trusted",
    }
    for f, text in why.items():
        if counts[f]:
            lines.append(f"{counts[f]} of {n} cases: {text}")
    return lines


def dataset_summary(ds) -> list[str]:
    """:func:`summary` of a sweep dataset (grid or case list) with ``measurement_flag``."""
    if "measurement_flag" not in ds:
        return []
    flags = ds["measurement_flag"].values.reshape(-1)
    at = ds["arrival_time"].transpose(..., "prism").values
    at = at.reshape(-1, at.shape[-1])
    t_end = float(ds.attrs.get("t_end", float(ds[TIME].values[-1])))
    return summary(flags, ds.sizes["prism"], t_end, t_end_needed(at, ds[TIME].values))


def _span(values, fmt: str, unit: str = "") -> str:
    """'3 m/s' or '3 to 5 m/s' (a unit 'x' after each end: '114x to 190x')."""
    lo, hi = (format(float(f(values)), fmt) for f in (np.min, np.max))
    if lo == hi:
        return lo + unit
    return f"{lo}x to {hi}x" if unit == "x" else f"{lo} to {hi}{unit}"


def all_failed(ds, long_wave_speeds=None) -> str | None:
    """None unless every case of a sweep dataset failed (``measurement_flag`` non_finite or
    constraint_failure: no column ran to t_end); then one line that says so and names the likely
    cause. ``long_wave_speeds(ds)``: the long-wave speed c0 [m s-1] of every column, a DataArray
    over the per-column dimensions (:func:`warp_tensegrity.validation.closed_forms.long_wave_speeds`);
    where v0 is :data:`FAR_ABOVE_SOUND` times c0 or more in every prestressed case, the impact
    speed is named (a v0 given in mm/s); else a dt above its stability limit (attributes ``dt``,
    ``dt_limit`` [s]); else a smaller dt is advised."""
    if "measurement_flag" not in ds or ds["measurement_flag"].size == 0:
        return None
    flag = ds["measurement_flag"]
    failed = np.isin(flag.values, [FLAG[f] for f in FAILED])
    if not failed.all():
        return None
    line = (f"every case failed ({failed.size} of {failed.size}: the state became non-finite or a bar "
            "constraint failed; no column ran to t_end)")
    c0 = long_wave_speeds(ds) if long_wave_speeds is not None else None
    if c0 is not None and "v0" in ds.coords:
        v0, c0 = (np.asarray(a.broadcast_like(flag).transpose(*flag.dims).values, dtype=float).reshape(-1)
                  for a in (ds["v0"], c0))
        stressed = np.isfinite(c0) & (c0 > 0)  # an unstressed column has no long-wave speed
        if stressed.any() and np.all(v0[stressed] / c0[stressed] >= FAR_ABOVE_SOUND):
            ratio = v0[stressed] / c0[stressed]
            return (f"{line}; likely cause: the impact speed v0 = {_span(v0[stressed], 'g', ' m/s')} is "
                    f"{_span(ratio, '.0f', 'x')} the long-wave sound speed c0 = {_span(c0[stressed], '.2g', ' m/s')} "
                    "of the columns (v0 is in m s-1: was it given in mm/s?)")
    dt, limit = (float(ds.attrs.get(k, np.nan)) for k in ("dt", "dt_limit"))
    if dt > limit:  # run.allow_unstable_dt
        return f"{line}; likely cause: dt = {dt:.3g} s is {dt / limit:.1f}x its stability limit {limit:.3g} s"
    return f"{line}: try a smaller dt (run.dt_safety or run.dt)"
