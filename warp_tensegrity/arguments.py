"""Argument checks of the public functions (``simulate_batch``, ``run_batch``, ``estimate_batch``,
``column_batch``, ``network_batch``, ...): a wrong type, a missing value, a masked array or a
count out of range is an :class:`ArgumentError` naming the function, the parameter and the value,
raised before any work starts (never an AttributeError from deep inside, nor a run that fails
after stepping).

A leaf of the import graph: of the package, only :mod:`warp_tensegrity.options` (for ``fmt``).
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Mapping

import numpy as np

from .options import fmt


class ArgumentError(TypeError, ValueError):
    """A public function's argument of the wrong type or value; the message names the function,
    the parameter and the value. Both a TypeError and a ValueError, so either ``except`` catches it."""


def _what(value) -> str:
    return f"{' '.join(fmt(value).split())} ({type(value).__name__})"  # one line, long ones cut


def expect(func: str, name: str, value, cls, optional: bool = False):
    """``value`` when it is an instance of ``cls`` (or None and ``optional``), else ArgumentError."""
    if (value is None and optional) or isinstance(value, cls):
        return value
    want = " or ".join(c.__name__ for c in (cls if isinstance(cls, tuple) else (cls,)))
    raise ArgumentError(f"{func}: {name} = {_what(value)}: give a {want}{' or None' if optional else ''}")


def expect_callable(func: str, name: str, value):
    """``value`` when it is None or callable, else ArgumentError."""
    if value is None or callable(value):
        return value
    raise ArgumentError(f"{func}: {name} = {_what(value)}: give a function or None")


def expect_count(func: str, name: str, value, lo: int, hi: int, unit: str = "") -> int:
    """``value`` as an int in [lo, hi] (an integral number, not a bool, not NaN), else ArgumentError."""
    ok = isinstance(value, numbers.Real) and not isinstance(value, (bool, np.bool_))
    if ok and not isinstance(value, numbers.Integral):
        ok = math.isfinite(float(value)) and float(value).is_integer()
    if not ok or not lo <= int(value) <= hi:
        raise ArgumentError(f"{func}: {name} = {_what(value)}: give an integer in [{lo}, {hi}]{unit}")
    return int(value)


def expect_params(func: str, params) -> dict:
    """The per-column parameters: a mapping of names to scalars or 1-D arrays [SI units]. A NumPy
    masked array is refused when anything is masked (a masked column would be simulated with the
    value under its mask); unmasked ones are taken as plain arrays."""
    if not isinstance(params, Mapping):
        raise ArgumentError(f"{func}: params = {_what(params)}: give a dict of per-column parameters, "
                            "e.g. {'prestrain': [0.0, 0.002], 'v0': 0.1}")
    out = {}
    for k, v in params.items():
        if not isinstance(k, str):
            raise ArgumentError(f"{func}: params key {_what(k)}: parameter names are strings")
        if isinstance(v, np.ma.MaskedArray):
            n = int(np.ma.count_masked(v))
            if n:
                raise ArgumentError(f"{func}: params[{k!r}] is a masked array with {n} masked entries; drop the "
                                    f"masked columns (or fill them, v.filled(...)) first")
            v = np.asarray(v.data)
        out[k] = v
    return out
