"""Pulse measures of a strain history: arrival, leading peak, amplitude, speed, width.

:mod:`.pulse_core` (:func:`measure_pulse`, the window, the threshold, the constants) and :mod:`.pulse`
(the single measures) are the reference NumPy implementation (definitions: ``docs/measurements.md``);
this package's namespace offers the public names of both. :mod:`.device` computes the same on the Warp
device from the engine's record (import it directly: it loads Warp, this package does not).
"""

from . import pulse
from .pulse import *  # noqa: F403 (pulse.__all__: the single measures)
from .pulse_core import (
    DEFAULT_END_FRACTION,
    DEFAULT_SKIP_FRACTION,
    DEFAULT_THRESHOLD_FRACTION,
    PeakTrack,
    default_skip,
    default_threshold,
    measure_pulse,
    measurement_window,
)

__all__ = [*pulse.__all__, "DEFAULT_THRESHOLD_FRACTION", "DEFAULT_END_FRACTION", "DEFAULT_SKIP_FRACTION", "PeakTrack",
           "default_skip", "default_threshold", "measurement_window", "measure_pulse"]
