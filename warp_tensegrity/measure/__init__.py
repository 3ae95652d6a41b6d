"""Pulse measures of a strain history: arrival, leading peak, amplitude, speed, width.

:mod:`.pulse` is the reference NumPy implementation (definitions: ``docs/measurements.md``).
"""

from .pulse import *  # noqa: F403
from .pulse import __all__  # noqa: F401
