"""The sections of a sweep spec, parsed and checked one table at a time ([scene], [sweep], [run]):
the keys each table accepts, and a checker that collects every problem, each message naming the
key path and the bad value. :func:`~warp_tensegrity.sweep.spec.parse_spec` puts the tables
together into a :class:`~warp_tensegrity.sweep.spec.SweepSpec`.

Nothing here imports Warp.
"""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np

from .. import options as O
from ..options import (COLUMN_PARAMETERS, PROFILE_FIELDS, PROFILED, ColumnParameters, OptionError, Profile, RunSettings,
                       suggest)
from ..scene.columns import ColumnConfig, column_topology
from ..scene.network import NetworkError
from ..policy.cost import fmt_bytes
from .budget import host_memory_available, plan_bytes

SWEEP_KEYS = ("grid", "cases", "fixed")
RANGE_KEYS = ("start", "stop", "num", "spacing")
SPACINGS = ("linear", "log")
CASE_EXTRA_KEYS = ("label",)

SCENE_FIELDS = tuple(f.name for f in dataclasses.fields(ColumnConfig))
# per-column parameters that are not ColumnConfig fields and may be given as scene scalars
SCENE_PARAMS = tuple(p for p in COLUMN_PARAMETERS if p not in SCENE_FIELDS)
RUN_KEYS = tuple(f.name for f in dataclasses.fields(RunSettings))
"""Every [run] key: the fields of :class:`~warp_tensegrity.options.RunSettings`."""
PROFILE_AXES = {f"{p}_{f}": (p, f) for p in PROFILED for f in PROFILE_FIELDS}
"""Grid axes over a profile's generating parameters (``prestrain_at``): the profile itself, a grade or
two segments, is given in [sweep.fixed]; the axis sets one of its fields per column."""
GRID_KEYS = tuple(COLUMN_PARAMETERS) + tuple(PROFILE_AXES)


# ---------------------------------------------------------------------- helpers
def _fmt(value) -> str:
    if isinstance(value, (str, float, int)):
        return O.fmt(value)  # repr, long ones cut
    if isinstance(value, (dict, list)):
        s = json.dumps(value, default=str)
        return s if len(s) < 80 else s[:77] + "..."
    return repr(value)


class _Checker:
    """Collects errors; every message starts with the key path."""

    def __init__(self):
        self.errors: list[str] = []

    def error(self, path: str, msg: str):
        self.errors.append(f"{path}: {msg}")

    def bad(self, path: str, value, msg: str):
        self.errors.append(f"{path} = {_fmt(value)}: {msg}")

    def keys(self, table: dict, path: str, allowed, what="key", hint: str = ""):
        ok = True
        for k in table:
            if k not in allowed:
                full = f"{path}.{k}" if path else str(k)
                extra = hint(k) if callable(hint) else hint
                self.errors.append(O.unknown_key(full, k, allowed, what=what, hint=extra))
                ok = False
        return ok

    def number(self, path, value, *, integer=False) -> float | int | None:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            self.bad(path, value, f"must be {'an integer' if integer else 'a number'}")
            return None
        if integer:
            if isinstance(value, float) and not value.is_integer():
                self.bad(path, value, "must be an integer")
                return None
            return int(value)
        try:
            value = float(value)
        except OverflowError:  # an integer beyond float range
            self.bad(path, value, "must be finite (beyond the float range)")
            return None
        if not math.isfinite(value):
            self.bad(path, value, "must be finite")
            return None
        return value

    def boolean(self, path, value) -> bool | None:
        if not isinstance(value, bool):
            self.bad(path, value, "must be true or false")
            return None
        return value

    def choice(self, path, value, choices) -> str | None:
        if not isinstance(value, str) or value not in choices:
            hint = suggest(value, choices) if isinstance(value, str) else ""
            self.bad(path, value, f"choose one of {', '.join(map(repr, choices))}{hint}")
            return None
        return value


def _check_param(ck: _Checker, name: str, path: str, value, profile: bool = False):
    """A per-column parameter checked against its declaration in options.ColumnParameters; with
    ``profile``, a table is a :class:`~warp_tensegrity.options.Profile` along the column."""
    if isinstance(value, dict):
        if not profile or name not in PROFILED:
            why = (f"{name} takes one value per column, not a profile (profiles: {', '.join(PROFILED)})"
                   if name not in PROFILED else "a profile belongs in [sweep.fixed] or a case, not here")
            ck.bad(path, value, why)
            return None
        try:
            return Profile.from_table(name, value, path=path)
        except OptionError as e:
            ck.errors += e.errors
            return None
    v, problem = O.opt_of(ColumnParameters, name).problem(value)
    if problem is not None or v is None:
        ck.bad(path, value, problem or "must be a number")
        return None
    return v


def _param_hint(key) -> str:
    if key in PROFILE_AXES:
        return f" ({key!r} is a grid axis over the {PROFILE_AXES[key][0]} profile: put it in [sweep.grid])"
    if key in SCENE_FIELDS:
        return f" ({key!r} is a scene setting, the same for every column: set it in [scene])"
    return ""


# ---------------------------------------------------------------------- the tables
def _parse_scene(ck: _Checker, t: dict):
    """[scene]: ColumnConfig fields (validated by ColumnConfig itself) and per-column scalars."""
    params: dict = {}
    ck.keys(t, "scene", SCENE_FIELDS + SCENE_PARAMS)
    for k in SCENE_PARAMS:
        if k in t:
            val = _check_param(ck, k, f"scene.{k}", t[k], profile=True)
            if val is not None:
                params[k] = val
    for k in [k for k in t if k in SCENE_FIELDS and isinstance(t[k], dict)]:
        ck.bad(f"scene.{k}", t[k], f"{k} is a scene setting, one value for the whole column" +
               (": give a unit_mass profile in [sweep.fixed]" if k in PROFILED else
                f"; profiles are for {', '.join(PROFILED)}"))
    given = {k: v for k, v in t.items() if k in SCENE_FIELDS and not isinstance(v, dict)}
    try:
        scene = O.build(ColumnConfig, given, prefix="scene.")
        # one prism of the scene: is it prestressable (twist)? cheap, and the engine would refuse later
        column_topology(dataclasses.replace(scene, n_prisms=1, handedness="right"))
    except OptionError as e:
        ck.errors += e.errors
        return None, {}, params
    except NetworkError as e:
        ck.errors.append(f"scene.{e}")
        return None, {}, params
    return scene, {k: getattr(scene, k) for k in given}, params


def _parse_values(ck: _Checker, name: str, path: str, spec) -> np.ndarray | None:
    if isinstance(spec, dict):
        ck.keys(spec, path, RANGE_KEYS)
        missing = [k for k in ("start", "stop", "num") if k not in spec]
        if missing:
            ck.error(path, f"range table needs start, stop and num (missing: {', '.join(missing)})")
            return None
        start = _check_param(ck, name, f"{path}.start", spec["start"])
        stop = _check_param(ck, name, f"{path}.stop", spec["stop"])
        num = ck.number(f"{path}.num", spec["num"], integer=True)
        if num is not None and num < 1:
            ck.bad(f"{path}.num", spec["num"], "must be >= 1")
            num = None
        elif num is not None and (need := plan_bytes(num, 1)) > (have := host_memory_available()):
            # checked before the axis is made: np.linspace would try to allocate it
            count = f"{num:,}" if num < 10**18 else "over 10^18"
            ck.bad(f"{path}.num", spec["num"], f"an axis of {count} values cannot be planned: even one-prism columns "
                   f"need about {fmt_bytes(need)} of host memory and {fmt_bytes(have)} is available")
            num = None
        spacing = spec.get("spacing", "linear")
        spacing = ck.choice(f"{path}.spacing", spacing, SPACINGS)
        if None in (start, stop, num, spacing):
            return None
        if spacing == "log":
            for kk, x in (("start", start), ("stop", stop)):
                if not x > 0:
                    ck.bad(f"{path}.{kk}", x, "must be > 0 for spacing = \"log\"")
                    return None
            vals = np.geomspace(start, stop, num)
            vals[0], vals[-1] = start, stop
        else:
            vals = np.linspace(start, stop, num)
        if np.unique(vals).size != vals.size:  # as for a list: one column per distinct value
            ck.bad(path, spec, f"gives repeated values ({num} values from {start!r} to {stop!r}); grid values must be distinct")
            return None
        return vals.astype(np.float64)
    if isinstance(spec, list):
        if not spec:
            ck.bad(path, spec, "needs at least one value")
            return None
        vals = [_check_param(ck, name, f"{path}[{i}]", v) for i, v in enumerate(spec)]
        if any(v is None for v in vals):
            return None
        arr = np.array(vals, dtype=np.float64)
        uniq, counts = np.unique(arr, return_counts=True)
        if (counts > 1).any():
            ck.bad(path, spec, f"repeats the value {uniq[counts > 1][0]!r}; grid values must be distinct")
            return None
        return arr
    if isinstance(spec, (int, float)) and not isinstance(spec, bool):
        ck.bad(path, spec, "give a list of values or a {start, stop, num} table (a single value belongs in [sweep.fixed])")
        return None
    ck.bad(path, spec, "give a list of values or a {start, stop, num[, spacing]} table")
    return None


def _parse_profile_axis(ck: _Checker, key: str, spec, template) -> np.ndarray | None:
    """A grid axis over a generating parameter of a profile (``prestrain_at``): its values, checked
    as the profile's (``at``: whole prism indices; the column's length is checked with the scene)."""
    name, fld = PROFILE_AXES[key]
    path = f"sweep.grid.{key}"
    if not isinstance(template, Profile) or template.kind == "values" or (fld == "at" and template.kind != "segments"):
        need = "{segments = [first, last], at = k}" if fld == "at" else "{grade = [first, last]} or {segments = [...], at = k}"
        ck.error(path, f"needs the {name} profile it varies in [sweep.fixed]: {name} = {need}")
        return None
    if fld != "at":
        return _parse_values(ck, name, path, spec)
    vals = spec if isinstance(spec, list) else None
    if isinstance(spec, dict) and set(spec) == {"start", "stop", "num"}:  # a range of prism indices
        nums = [ck.number(f"{path}.{k}", spec[k], integer=True) for k in ("start", "stop", "num")]
        if None in nums or not 1 <= nums[2] <= 100_000:
            return None
        vals = np.linspace(nums[0], nums[1], nums[2]).tolist()
    if not isinstance(vals, list) or not vals:
        ck.bad(path, spec, "give a list of prism indices (or a {start, stop, num} table)")
        return None
    for i, v in enumerate(vals):
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not float(v).is_integer() or v < 1:
            ck.bad(f"{path}[{i}]", v, "must be a prism index >= 1 (the first prism of the second segment)")
            return None
    arr = np.array(vals, dtype=np.float64)
    if np.unique(arr).size != arr.size:
        ck.bad(path, spec, "repeats a value; grid values must be distinct")
        return None
    return arr


def _parse_sweep(ck: _Checker, t: dict):
    ck.keys(t, "sweep", SWEEP_KEYS)
    fixed: dict = {}
    if "fixed" in t:
        ft = t["fixed"]
        if not isinstance(ft, dict):
            ck.bad("sweep.fixed", ft, "must be a table of per-column parameters")
        else:
            ck.keys(ft, "sweep.fixed", tuple(COLUMN_PARAMETERS), what="per-column parameter", hint=_param_hint)
            for k, v in ft.items():
                if k in COLUMN_PARAMETERS:
                    x = _check_param(ck, k, f"sweep.fixed.{k}", v, profile=True)
                    if x is not None:
                        fixed[k] = x
    has_grid, has_cases = "grid" in t, "cases" in t
    if has_grid and has_cases:
        ck.error("sweep", "give either grid or cases, not both")
        return "grid", {}, [], None, fixed
    if not (has_grid or has_cases):
        ck.error("sweep", "give grid = {param = [values], ...} or cases = [{param = value, ...}, ...]")
        return "grid", {}, [], None, fixed
    if has_grid:
        g = t["grid"]
        grid: dict = {}
        if not isinstance(g, dict) or not g:
            ck.bad("sweep.grid", g, "must be a non-empty table of swept parameters")
            return "grid", {}, [], None, fixed
        ck.keys(g, "sweep.grid", GRID_KEYS, what="per-column parameter", hint=_param_hint)
        for k, v in g.items():
            if k in COLUMN_PARAMETERS:
                vals = _parse_values(ck, k, f"sweep.grid.{k}", v)
                if vals is not None:
                    grid[k] = vals
            elif k in PROFILE_AXES:
                vals = _parse_profile_axis(ck, k, v, fixed.get(PROFILE_AXES[k][0]))
                if vals is not None:
                    grid[k] = vals
        return "grid", grid, [], None, fixed
    cs = t["cases"]
    if not isinstance(cs, list) or not cs:
        ck.bad("sweep.cases", cs, "must be a non-empty list of tables, e.g. [{v0 = 0.001}, ...]")
        return "cases", {}, [], None, fixed
    cases, labels = [], []
    for i, c in enumerate(cs):
        path = f"sweep.cases[{i}]"
        if not isinstance(c, dict):
            ck.bad(path, c, "must be a table of per-column parameters")
            continue
        ck.keys(c, path, tuple(COLUMN_PARAMETERS) + CASE_EXTRA_KEYS, what="per-column parameter", hint=_param_hint)
        case = {}
        for k, v in c.items():
            if k in COLUMN_PARAMETERS:
                x = _check_param(ck, k, f"{path}.{k}", v, profile=True)
                if x is not None:
                    case[k] = x
        lab = c.get("label")
        if lab is not None and not isinstance(lab, str):
            ck.bad(f"{path}.label", lab, "must be a string")
            lab = None
        labels.append(lab)
        cases.append(case)
    if all(lab is None for lab in labels):
        labels = None
    else:
        labels = [lab or "" for lab in labels]
    return "cases", {}, cases, labels, fixed


def _parse_run(ck: _Checker, t: dict) -> dict:
    """[run]: the fields of RunSettings, validated by RunSettings itself (every [run] key)."""
    ck.keys(t, "run", RUN_KEYS)
    given = {k: v for k, v in t.items() if k in RUN_KEYS}
    try:
        settings = O.build(RunSettings, given, prefix="run.")
    except OptionError as e:
        ck.errors += e.errors
        return {f.name: f.default for f in dataclasses.fields(RunSettings)}
    run = {k: getattr(settings, k) for k in RUN_KEYS}
    if run["accuracy"] is not None:
        # the accuracy chooses method, precision and dt: they may not be given beside it
        for key in ("method", "precision", "dt", "dt_safety"):
            if key in t:
                ck.bad(f"run.{key}", t[key], "conflicts with run.accuracy, which chooses it; give one of them")
        run["accuracy_resolved"] = True  # method, precision, dt_safety set once the scene is known
    return run
