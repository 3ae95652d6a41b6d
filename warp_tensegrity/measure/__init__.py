"""Pulse measures of a strain history: arrival, leading peak, amplitude, speed, width.

:mod:`.pulse` is the reference NumPy implementation (definitions: ``docs/measurements.md``);
:mod:`.device` computes the same on the Warp device from the engine's record (import it directly:
it loads Warp, this package does not).
"""

from .pulse import *  # noqa: F403
from .pulse import __all__  # noqa: F401
