"""Pulse measurement: arrival, leading peak, amplitude, speed and width of the impact wave.

Input is the axial strain history of a column of prisms, ``strain[..., k, j]`` at time
``time[k]`` [s] in prism ``j`` (any leading batch dims). Prism 0 is the clamped end, prism
``n_prisms - 1`` the impacted free end; the wave runs from high ``j`` toward ``j = 0``.
Strain is ``eps = (h - h0)/h`` [-], negative in compression. Everything here works on the
compressive magnitude ``q = -eps`` and reports amplitudes as positive numbers (as the paper,
Fabbrocino & Carpentieri 2017, does). Exact definitions: ``docs/measurements.md``.

Pure NumPy, float64. Undefined or unmeasurable quantities (no arrival, flat signal,
non-finite samples, too short a record) come back as NaN; nothing raises on signal values,
only on malformed inputs (shapes, time axis, out-of-range options).

The single-measure functions live here; :func:`~.pulse_core.measure_pulse` (all of them in one
call), the measurement window, the default threshold, the constants and the shared stages live in
:mod:`.pulse_core` (import them from there; the package :mod:`warp_tensegrity.measure` offers both).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .pulse_core import (
    DEFAULT_END_FRACTION,
    PeakTrack,
    _amplitude,
    _arrival,
    _as_history,
    _as_snapshot,
    _check_fraction,
    _mid_width,
    _spatial_peak,
    _speeds,
    _threshold,
    _track,
    _width,
    measurement_window,
)

__all__ = [
    "PulseSpeed",
    "arrival_times",
    "peak_track",
    "leading_pulse_amplitude",
    "pulse_speed",
    "peak_location",
    "pulse_width",
    "width_at_mid_column",
]


class PulseSpeed(NamedTuple):
    """Speed of the leading peak toward the clamp [m s-1], shape (...)."""

    time_of_flight: np.ndarray
    """Primary: least-squares fit of leading-peak time vs prism position over the window."""
    snapshot: np.ndarray
    """Check: least-squares fit of the spatial peak location (snapshots) vs time."""


# ---------------------------------------------------------------------- public API


def arrival_times(strain, time, threshold=None) -> np.ndarray:
    """Arrival time [s] of the wave at each prism, shape (..., n_prisms).

    The first time the compressive magnitude ``-strain`` reaches ``threshold`` [-], linearly
    interpolated between the last sample below and the first sample at or above it.
    ``threshold``: float or array broadcastable to (..., n_prisms); ``None`` ->
    :func:`default_threshold` (5 % of the record's largest compression).
    NaN where the threshold is never reached, is reached at the first sample already, the
    prism's history has a non-finite sample, or the threshold is not finite and > 0.
    """
    q, t, finite = _as_history(strain, time)
    thr, thr_ok = _threshold(q, threshold)
    return _arrival(q, t, finite, thr, thr_ok)


def peak_track(strain, time, threshold=None, end_fraction: float = DEFAULT_END_FRACTION) -> PeakTrack:
    """Leading compression peak at each prism: time [s], value [-], sample index.

    At prism j, with q = -strain and running maximum M(k) = max(q[0..k]):
    ``ka`` is the first sample with q >= threshold (arrival), ``ke`` the first sample after
    ``ka`` with q <= end_fraction * M (the leading pulse is over), and the leading peak is the
    largest q in samples [0, ke) (first one on ties), refined by the parabola through it and
    its two time neighbours (non-uniform time steps allowed). Equivalently: the first local
    maximum above threshold after which q falls to ``end_fraction`` of it before exceeding it,
    so rising-front wiggles and the oscillatory tail are both skipped.
    NaN (sample -1) where there is no arrival, the pulse is not over before the record ends,
    the peak is at the first sample, the history has a non-finite sample, or the threshold
    is unusable. ``threshold`` as in :func:`arrival_times`; ``end_fraction`` in (0, 1).
    """
    _check_fraction("end_fraction", end_fraction)
    q, t, finite = _as_history(strain, time)
    thr, thr_ok = _threshold(q, threshold)
    return _track(q, t, finite, thr, thr_ok, end_fraction)


def leading_pulse_amplitude(strain, time, skip_impact: int | None = None, skip_clamp: int | None = None,
                            threshold=None, end_fraction: float = DEFAULT_END_FRACTION) -> np.ndarray:
    """Amplitude of the leading compression pulse [-] (positive), shape (...).

    Median over the window prisms ``skip_clamp <= j < n_prisms - skip_impact`` (see
    :func:`measurement_window`; default skip :func:`default_skip`, 5 per end for 50 prisms)
    of the leading-peak values of :func:`peak_track`. The median ignores a stray prism
    (discreteness, a misread peak) while equalling the mean for a steady pulse.
    NaN if the window is empty or any window prism has no leading peak.
    """
    _check_fraction("end_fraction", end_fraction)
    q, t, finite = _as_history(strain, time)
    thr, thr_ok = _threshold(q, threshold)
    lo, hi = measurement_window(q.shape[-1], skip_impact, skip_clamp)
    return _amplitude(_track(q, t, finite, thr, thr_ok, end_fraction), lo, hi)


def pulse_speed(strain, time, prism_height, skip_impact: int | None = None, skip_clamp: int | None = None,
                threshold=None, end_fraction: float = DEFAULT_END_FRACTION) -> PulseSpeed:
    """Speed [m s-1] (positive, toward the clamp) of the leading peak, shape (...).

    ``time_of_flight`` (primary): least-squares line ``t_peak(j) = c0 + c1 j`` over the window
    prisms (:func:`peak_track`, :func:`measurement_window`); speed ``= -prism_height / c1``,
    prism position ``x_j = j * prism_height`` [m]. NaN unless every window prism has a peak,
    the window holds >= 2 prisms and c1 < 0.
    ``snapshot`` (check): at every time sample where the fitted track puts the leading peak at
    fractional index ``jf`` in [lo + 1, hi - 2], its location from :func:`peak_location`
    (searched within 1 prism of round(jf)); speed ``= -prism_height *`` slope of the
    least-squares line location vs time (>= 3 snapshots, else NaN).
    ``prism_height`` [m]: float or array broadcastable to (...).
    """
    _check_fraction("end_fraction", end_fraction)
    q, t, finite = _as_history(strain, time)
    thr, thr_ok = _threshold(q, threshold)
    lo, hi = measurement_window(q.shape[-1], skip_impact, skip_clamp)
    track = _track(q, t, finite, thr, thr_ok, end_fraction)
    return PulseSpeed(*_speeds(q, t, finite, track, lo, hi, prism_height))


def peak_location(strain_snapshot, near=None, search: int = 1) -> np.ndarray:
    """Fractional prism index of the compression peak of a snapshot (..., n_prisms).

    The prism with the largest ``-strain`` (over all prisms, or within ``search`` prisms of
    ``round(near)`` if ``near`` is given, broadcastable to (...)), plus the vertex offset of the
    parabola through it and its two neighbours, ``(q[i-1] - q[i+1]) / (2 (q[i-1] - 2 q[i] + q[i+1]))``.
    NaN unless that prism is a strict interior local maximum of positive compression, or if the
    snapshot has a non-finite value.
    """
    q, finite = _as_snapshot(strain_snapshot)
    loc, _, _ = _spatial_peak(q, near, search)
    return np.where(finite, loc, np.nan)


def pulse_width(strain_snapshot, level: float = 0.5, near=None, search: int = 1) -> np.ndarray:
    """Width [prisms] of the compression pulse of a snapshot (..., n_prisms) at ``level`` of its
    peak (0.5: FWHM; 0.1: width at 10 %). Multiply by the prism height for metres.

    Peak as in :func:`peak_location` (value from the same parabola, ``Q``); from the peak prism
    go left and right to the first prism with ``-strain < level * Q``; each crossing is
    linearly interpolated between that prism and its neighbour toward the peak; width = right
    crossing - left crossing. NaN if a side has no crossing inside the column, no valid peak,
    or a non-finite value. Leading dims are vectorised, so a history (..., n_time, n_prisms)
    gives the width history (..., n_time) of the largest pulse.
    """
    _check_fraction("level", level)
    q, finite = _as_snapshot(strain_snapshot)
    return _width(q, finite, level, near, search)


def width_at_mid_column(strain, time, level: float = 0.5, threshold=None,
                        end_fraction: float = DEFAULT_END_FRACTION) -> np.ndarray:
    """Width [prisms] of the leading pulse as its peak crosses the middle of the column, shape (...).

    With x = ``(n-1)/2`` and the leading-peak times (:func:`peak_track`) at x + 1/2 and x - 1/2 (a
    position between two prisms takes the mean of their times): the mean over that transit of the
    widths of the snapshots (:func:`pulse_width`, peak searched within 2 prisms of x), linear in
    time between samples. Averaging over a transit takes out the discreteness modulation and the
    samples' round-off. NaN where the transit is undefined or a snapshot in it has no width.
    """
    _check_fraction("level", level)
    _check_fraction("end_fraction", end_fraction)
    q, t, finite = _as_history(strain, time)
    thr, thr_ok = _threshold(q, threshold)
    return _mid_width(q, t, finite, _track(q, t, finite, thr, thr_ok, end_fraction), level)
