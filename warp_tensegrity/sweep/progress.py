"""Sweep progress on stderr with tqdm: columns done, columns diverged, elapsed, ETA.

tqdm draws the bar, limits the refresh rate and finds out whether the stream is a terminal; by
default (``enabled=None``) the bar shows only on a terminal, so logs and pipes stay clean.

The ETA starts from the calibrated cost model (``estimate_s``, from
:func:`warp_tensegrity.policy.calibrate.estimate_plan`) and moves to the measured rate as columns
finish: with a fraction f of the outstanding work done, ETA = (1 - f) * estimate_left + f * rate_left.
tqdm's own ETA knows only the rate, hence the postfix.
"""

from __future__ import annotations

import math
import sys
import time

from tqdm import tqdm

from ..policy.cost import fmt_seconds


class ProgressBar:
    """Progress of a sweep in columns. ``update(done, diverged)`` takes totals, not increments."""

    def __init__(self, total: int, done: int = 0, diverged: int = 0, stream=None, enabled: bool | None = None,
                 estimate_s: float | None = None):
        self.total = max(int(total), 1)
        self.base_done = float(done)
        self.done = float(done)
        self.diverged = int(diverged)
        self.estimate_s = estimate_s
        self.t0 = time.monotonic()
        stream = stream or sys.stderr
        self._bar = tqdm(total=self.total, initial=done, file=stream, disable=None if enabled is None else not enabled,
                         unit="col", dynamic_ncols=True, mininterval=0.2, leave=True,
                         bar_format="{l_bar}{bar}| {postfix}")
        self._set_postfix()

    def eta(self) -> float:
        """Seconds left: the calibrated estimate blended with the measured rate."""
        remaining = self.total - self.done
        if remaining <= 0:
            return 0.0
        elapsed = time.monotonic() - self.t0
        todo = self.total - self.base_done
        f = (self.done - self.base_done) / todo if todo > 0 else 1.0
        rate_left = elapsed * (1 - f) / f if f > 0 else math.inf
        if self.estimate_s is None:
            return rate_left
        est_left = max(self.estimate_s - elapsed, 0.0) if f == 0 else self.estimate_s * (1 - f)
        return est_left if f == 0 else (1 - f) * est_left + f * rate_left

    def _set_postfix(self) -> None:
        elapsed = time.monotonic() - self.t0
        self._bar.set_postfix_str(
            f"{int(self.done)}/{self.total} columns, {self.diverged} diverged, elapsed {fmt_seconds(elapsed)}, "
            f"ETA {fmt_seconds(self.eta())}", refresh=False)

    def update(self, done: float, diverged: int, force: bool = False) -> None:
        self.done, self.diverged = float(done), int(diverged)
        if self._bar.disable:
            return
        self._bar.n = min(self.done, self.total)
        self._set_postfix()
        if force:
            self._bar.refresh()
        else:
            self._bar.update(0)  # tqdm redraws at most every mininterval

    def close(self) -> None:
        if not self._bar.disable:
            self.update(self.done, self.diverged, force=True)
        self._bar.close()
