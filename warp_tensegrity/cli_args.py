"""Command-line options shared by ``warp-tensegrity run``/``resume`` and ``warp-tensegrity lens``,
each declared once: the Warp device and the estimate's options (``--dry-run``, ``--time-limit``,
``--ignore-estimate``, ``--recalibrate``), with their argparse types (a bad value is a usage error
naming the option, never a traceback)."""

from __future__ import annotations

import argparse
import math
import re
from pathlib import Path

from .policy.cost import DEFAULT_TIME_LIMIT, fmt_seconds


def device(value: str) -> str:
    """``--device``: cpu, cuda, cuda:N or auto."""
    if not re.match(r"^(cpu|cuda|cuda:\d+|auto)$", value):
        raise argparse.ArgumentTypeError(f"--device {value!r}: give cpu, cuda, cuda:N or auto")
    return value


def positive_int(value: str) -> int:
    try:
        n = int(value)
    except ValueError:
        n = 0
    if n < 1:
        raise argparse.ArgumentTypeError(f"{value!r} is not a positive integer")
    return n


def positive_seconds(value: str) -> float:
    """``--time-limit``: a positive, finite number of seconds."""
    try:
        x = float(value)
    except ValueError:
        x = -1.0
    if not (math.isfinite(x) and x > 0):
        raise argparse.ArgumentTypeError(f"{value!r} is not a positive number of seconds")
    return x


def file_name(value: str) -> str:
    """A file name: not empty, not a bare directory such as '.'."""
    if not value.strip() or Path(value).name in ("", ".", ".."):
        raise argparse.ArgumentTypeError(f"{value!r} is not a file name")
    return value


def add_device(p: argparse.ArgumentParser, default: str | None = None,
               default_text: str = "the spec's run.device, else the GPU if there is one, else the CPU") -> None:
    p.add_argument("--device", type=device, default=default,
                   help=f"Warp device: cpu, cuda:N or auto (default: {default_text})")


def add_estimate_options(p: argparse.ArgumentParser, dry_run: str) -> None:
    """The estimate's options; ``dry_run``: what ``--dry-run`` prints."""
    if dry_run:
        p.add_argument("--dry-run", action="store_true", help=f"print {dry_run}; run nothing")
    p.add_argument("--time-limit", type=positive_seconds, default=None, metavar="SECONDS",
                   help=f"refuse a run estimated to take longer (default: {fmt_seconds(DEFAULT_TIME_LIMIT)})")
    p.add_argument("--ignore-estimate", action="store_true",
                   help="run even when the estimate says the run exceeds this machine's memory, disk or time limit "
                        "(no calibration probe is taken)")
    p.add_argument("--recalibrate", action="store_true",
                   help="take the calibration probe again instead of the cached one (the estimate of --dry-run "
                        "and --time-limit)")
