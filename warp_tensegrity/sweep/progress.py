"""The sweep's progress bar (stderr)."""

from __future__ import annotations

import math
import sys
import time


def fmt_seconds(s: float) -> str:
    if not math.isfinite(s):
        return "?"
    s = int(round(s))
    if s >= 3600:
        return f"{s // 3600}h{(s % 3600) // 60:02d}m"
    if s >= 60:
        return f"{s // 60}m{s % 60:02d}s"
    return f"{s}s"


class ProgressBar:
    """A one-line stderr bar: columns done, columns diverged, ETA."""

    def __init__(self, total: int, done: int = 0, diverged: int = 0, stream=None, enabled: bool = True, width: int = 28):
        self.total = max(int(total), 1)
        self.base_done = done
        self.base_diverged = diverged
        self.done = float(done)
        self.diverged = diverged
        self.stream = stream or sys.stderr
        self.enabled = enabled
        self.width = width
        self.t0 = time.monotonic()
        self.last = 0.0
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self._len = 0
        self._printed = None

    def update(self, done: float, diverged: int, force: bool = False):
        self.done, self.diverged = float(done), int(diverged)
        if not self.enabled:
            return
        now = time.monotonic()
        state = (int(self.done), self.diverged)
        if force and state == self._printed and now - self.last < 1.0:
            return  # nothing new to say
        if not force and now - self.last < (0.2 if self.tty else 10.0):
            return
        self.last = now
        self._printed = state
        frac = min(self.done / self.total, 1.0)
        fill = int(round(frac * self.width))
        elapsed = now - self.t0
        new = self.done - self.base_done
        remaining = self.total - self.done
        eta = elapsed * remaining / new if new > 0 else float("nan")
        line = (
            f"[{'#' * fill}{'.' * (self.width - fill)}] {int(self.done)}/{self.total} columns"
            f"  {self.diverged} diverged  elapsed {fmt_seconds(elapsed)}  ETA {fmt_seconds(eta if remaining > 0 else 0)}"
        )
        if self.tty:
            pad = " " * max(self._len - len(line), 0)
            self.stream.write("\r" + line + pad)
            self._len = len(line)
        else:
            self.stream.write(line + "\n")
        self.stream.flush()

    def close(self):
        if self.enabled:
            self.update(self.done, self.diverged, force=True)
            if self.tty:
                self.stream.write("\n")
                self.stream.flush()
