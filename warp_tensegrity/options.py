"""Every option of a scene and a run, declared once: name, type, default, unit, bounds and doc.

Three pydantic (v2) dataclasses hold them; everything else is generated from them:

* :class:`~warp_tensegrity.scene.columns.ColumnConfig` - ``[scene]``: the fixed scene (geometry,
  material, masses, conventions), declared in the scene package with the :class:`Opt` below;
* :class:`ColumnParameters` - the per-column parameters a sweep varies (``[sweep]``);
* :class:`RunSettings` - ``[run]``: how a batch or a sweep is integrated and stored.

Each field is ``name: Annotated[type, Opt(...)] = default`` followed by its docstring: the
:class:`Opt` carries the unit, the bounds and the accepted special strings, and validates.
The sweep spec parser (:mod:`warp_tensegrity.sweep.parse`), the command line's ``--set
section.key=value`` (:func:`warp_tensegrity.overrides.parse_set`), the Python constructors and the docs tables
(:func:`~warp_tensegrity.options_docs.options_table`) all read these declarations; there is no
other list of options.

Errors name the key, the value and what was expected (``t_end = -1.0: must be > 0 [s]``),
with a did-you-mean for unknown keys. Nothing here imports Warp, nor any module of the package
(a leaf of the import graph).
"""

from __future__ import annotations

import dataclasses
import difflib
import functools
import math
import numbers
import re
from dataclasses import dataclass as _std_dataclass
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import ConfigDict, ValidationError
from pydantic.dataclasses import dataclass as _pydantic_dataclass
from pydantic_core import PydanticCustomError, core_schema

METHODS = ("rattle", "rk4", "yoshida4", "symplectic_euler")
"""The values of :class:`warp_tensegrity.types.Method` (a leaf cannot import it; a test checks)."""
PRECISIONS = ("fp32", "fp64", "auto")
"""The values of :class:`warp_tensegrity.types.Precision`."""
# Physical ranges of the per-column parameters (the scene's are in scene.columns): wide enough for
# any laboratory or built tensegrity column, narrow enough that derived quantities stay normal floats.
MASS = (1e-15, 1e6)  # kg: unit and bar masses
MAX_EA = 1e20  # N
# Impact speed: 10 km/s, the hypervelocity regime of light-gas guns, far beyond what an elastic column
# with rigid bars models; bounded so the impact's energies stay normal floats. Sweeps and lenses alike.
MAX_SPEED = 1e4  # m s-1
# Times (s): a femtosecond to ~30 years. Outside, step and output counts overflow float64 in the
# estimate; inside, the estimate refuses what will not finish (sweep.budget).
MIN_TIME, MAX_TIME = 1e-15, 1e9


# ---------------------------------------------------------------------- errors
class OptionError(ValueError):
    """An option outside its type or bounds. ``errors`` lists one message per problem, each
    starting with the key (``t_end = -1.0: must be > 0 [s]``)."""

    def __init__(self, errors):
        self.errors = [errors] if isinstance(errors, str) else list(errors)
        super().__init__(self.errors[0] if len(self.errors) == 1 else "; ".join(self.errors))


class SettingsError(OptionError):
    """Invalid run setting; the message names the field and the value."""


def fmt(value) -> str:
    """A value as the messages quote it (repr, long containers cut)."""
    s = repr(value)
    return s if len(s) < 80 else s[:77] + "..."


def suggest(key, allowed) -> str:
    """'; did you mean 'x'?' for the closest allowed name, or ''."""
    names = [str(a) for a in allowed]
    key = str(key)
    match = difflib.get_close_matches(key, names, n=1, cutoff=0.6)
    if not match and len(key) <= 4:  # short keys: one wrong character is half the key
        match = difflib.get_close_matches(key, [n for n in names if len(n) <= 4], n=1, cutoff=0.5)
    if not match:
        low = {n.lower(): n for n in names}
        match = [low[m] for m in difflib.get_close_matches(key.lower(), list(low), n=1, cutoff=0.6)]
    return f"; did you mean {match[0]!r}?" if match else ""


def unknown_key(path: str, key, allowed, what: str = "key", hint: str = "") -> str:
    return f"{path}: unknown {what}{suggest(key, allowed)}{hint} (allowed: {', '.join(map(str, allowed))})"


# ---------------------------------------------------------------------- one option
def _num(x) -> str:
    return format(x, "g") if isinstance(x, float) else str(x)


@_std_dataclass(frozen=True)
class Opt:
    """How one option is typed, bounded and documented (pydantic field metadata).

    kind: 'real' (finite float), 'int', 'bool', 'choice' (one of ``choices``), 'str', 'table' (a
    TOML table, checked by its owner) or 'point' (finite [x, y, z]). Bounds ``gt/ge/lt/le`` apply
    to reals and ints. ``special`` maps accepted strings to the value they stand for
    (``{"auto": None}``); ``optional``: None is accepted; ``items = (lo, hi)``: a list of lo..hi such
    values (a tuple), or also one value when ``single``.
    """

    kind: str
    unit: str = ""
    gt: float | None = None
    ge: float | None = None
    lt: float | None = None
    le: float | None = None
    choices: tuple = ()
    special: tuple = ()
    """(string, value) pairs accepted in place of a value."""
    optional: bool = False
    pattern: str | None = None
    rule_text: str | None = None
    """The rule as written in docs and errors, when the bounds alone would read badly."""
    why: str = ""
    """Appended to the error when the bounds are broken."""
    default_text: str | None = None
    """The default as the docs show it, when it is not a plain value (e.g. the scene's EA)."""
    long_name: str = ""
    """CF ``long_name`` of the coordinate a per-column parameter becomes in the datasets (io)."""
    infinite: bool = False
    """+inf accepted besides the bounds (a wave speed: normal incidence)."""
    items: tuple | None = None
    single: bool = False

    # -- the rule in words, shared by errors and the docs table
    def bounds(self) -> str:
        lo = ("(" if self.gt is not None else "[") if (self.gt, self.ge) != (None, None) else None
        hi = (")" if self.lt is not None else "]") if (self.lt, self.le) != (None, None) else None
        a = self.gt if self.gt is not None else self.ge
        b = self.lt if self.lt is not None else self.le
        if lo and hi:
            return f"in {lo}{_num(a)}, {_num(b)}{hi}"
        if lo:
            return f"{'>' if lo == '(' else '>='} {_num(a)}"
        if hi:
            return f"{'<' if hi == ')' else '<='} {_num(b)}"
        return ""

    def rule(self) -> str:
        if self.rule_text:
            base = self.rule_text
        elif self.kind == "bool":
            base = "true or false"
        elif self.kind == "choice":
            base = ", ".join(f'"{c}"' for c in self.choices)
        elif self.kind == "int":
            base = "integer >= 1" if (self.ge == 1 and self.le is None) else f"integer {self.bounds()}".strip()
        elif self.kind == "real":
            base = self.bounds() or "finite"
        else:
            base = "string"
        extra = [f'"{s}"' for s, _ in self.special] + (["inf"] if self.infinite else [])
        return base + (f", or {' or '.join(extra)}" if extra else "")

    def _expected(self, x=None) -> str:
        unit = f" [{self.unit}]" if self.unit and self.unit != "1" else ""
        sp = f" (or {' or '.join(repr(s) for s, _ in self.special)})" if self.special else ""
        if self.kind == "int" and self.ge == 1 and (self.le is None or (x is not None and x < 1)):
            return f"must be a positive integer{sp}"
        b = self.rule_text or self.bounds()
        verb = "must lie " if b.startswith("in ") else "must be "
        return f"{verb}{b}{unit}{sp}{': ' + self.why if self.why else ''}"

    # -- validation
    def check(self, x):
        if x is None and self.optional:
            return None
        if isinstance(x, Profile):  # a per-column parameter along the column, given where one value belongs
            raise _err(f"takes one value, not a profile (profiles: {', '.join(PROFILED)}, per column)")
        if self.items is not None and (isinstance(x, (list, tuple)) or not self.single):
            lo, hi = self.items
            if not isinstance(x, (list, tuple)) or not lo <= len(x) <= hi:
                raise _err(f"give {self.rule()}")
            one = dataclasses.replace(self, items=None, single=False)
            return tuple(one.check(v) for v in x)
        if self.kind == "table":
            if not isinstance(x, dict):
                raise _err("must be a table")
            return x
        if self.kind == "point":
            if not (isinstance(x, (list, tuple)) and len(x) == 3 and all(
                    isinstance(c, numbers.Real) and not isinstance(c, bool) and math.isfinite(c) for c in x)):
                raise _err("must be a point [x, y, z] of finite numbers")
            return tuple(float(c) for c in x)
        if isinstance(x, str):
            for s, v in self.special:
                if x == s:
                    return v
        sp = f" or {' or '.join(repr(s) for s, _ in self.special)}" if self.special else ""
        if self.kind == "bool":
            if isinstance(x, (bool, np.bool_)):
                return bool(x)
            raise _err(f"must be true or false{sp}")
        if self.kind == "choice":
            if isinstance(x, str) and x in self.choices:
                return x
            hint = suggest(x, self.choices) if isinstance(x, str) else ""
            raise _err(f"choose one of {', '.join(map(repr, self.choices))}{sp}{hint}")
        if self.kind == "str":
            if not isinstance(x, str) or (self.pattern and not re.fullmatch(self.pattern, x)):
                raise _err(f"give {self.rule_text}{sp}" if self.rule_text else f"must be a string{sp}")
            return x
        if isinstance(x, (bool, np.bool_)) or not isinstance(x, numbers.Real):
            raise _err(f"must be {'an integer' if self.kind == 'int' else 'a number'}{sp}")
        if self.kind == "int":
            if isinstance(x, numbers.Integral):
                x = int(x)
            else:
                f = float(x)  # a Real that is not Integral: a float-like, never an overflow
                if not f.is_integer():  # NaN and inf are not integers either
                    raise _err(f"must be an integer{sp}")
                x = int(f)
        else:
            try:
                x = float(x)
            except OverflowError:  # an integer beyond float range (TOML has them)
                x = math.inf
            if x == math.inf and self.infinite:
                return x
            if not math.isfinite(x):
                raise _err(f"must be finite{sp}")
        ok = (
            (self.gt is None or x > self.gt)
            and (self.ge is None or x >= self.ge)
            and (self.lt is None or x < self.lt)
            and (self.le is None or x <= self.le)
        )
        if not ok:
            raise _err(self._expected(x))
        return x

    def problem(self, x) -> tuple[Any, str | None]:
        """(validated value, None), or (None, what was expected)."""
        try:
            return self.check(x), None
        except PydanticCustomError as e:
            return None, e.message()

    def check_array(self, name: str, values, error: type[ValueError] = OptionError) -> None:
        """Vectorised bounds check of a real option over many columns; ``error`` names the first
        bad entry (``prestrain[3] = -0.1: ...``)."""
        try:
            arr = np.asarray(values)
        except (TypeError, ValueError):  # ragged nesting
            arr = np.asarray(None)
        if arr.dtype.kind not in "iuf" or arr.size == 0:  # strings, bools, None, ragged or empty lists
            raise error(f"{name} = {fmt(values)}: must be a number or an array of numbers [{self.unit}]")
        arr = arr.astype(np.float64).ravel()
        good = np.isfinite(arr)
        for bound, op in ((self.gt, np.greater), (self.ge, np.greater_equal), (self.lt, np.less), (self.le, np.less_equal)):
            if bound is not None:
                good &= op(arr, bound)
        if not good.all():
            i = int(np.argmin(good))
            where = f"[{i}]" if arr.size > 1 else ""
            why = "must be finite" if not np.isfinite(arr[i]) else self._expected()
            raise error(f"{name}{where} = {float(arr[i])!r}: {why}")

    def __get_pydantic_core_schema__(self, source, handler):
        return core_schema.no_info_plain_validator_function(self.check)


def _err(msg: str) -> PydanticCustomError:
    return PydanticCustomError("option", msg)


def opt_of(cls, name: str) -> Opt:
    """The :class:`Opt` of field ``name`` of an options class."""
    return next(m for m in cls.__pydantic_fields__[name].metadata if isinstance(m, Opt))


# ---------------------------------------------------------------------- error translation
def messages(exc: ValidationError, cls, prefix: str = "") -> list[str]:
    """One line per problem: ``{prefix}{key} = {value}: {what was expected}``."""
    out = []
    fields = list(cls.__pydantic_fields__)
    for e in exc.errors():
        loc = [str(x) for x in e["loc"]]
        key = ".".join(loc)
        if e["type"] == "option":
            out.append(f"{prefix}{key} = {fmt(e['input'])}: {e['msg']}")
        elif e["type"] in ("missing", "missing_argument"):
            out.append(f"{prefix}{key}: required key is missing")
        elif e["type"] == "unexpected_keyword_argument":
            out.append(unknown_key(f"{prefix}{key}", key, fields))
        elif e["type"] == "unexpected_positional_argument":
            out.append(f"{prefix}{key}: too many positional arguments (fields: {', '.join(fields)})")
        elif e["type"] == "value_error" and isinstance(e.get("ctx", {}).get("error"), ValueError):
            err = e["ctx"]["error"]  # a cross-field check of __post_init__
            out += [f"{prefix}{m}" for m in getattr(err, "errors", [str(err)])]
        else:  # pragma: no cover - every field is an Opt; kept so nothing is ever swallowed
            out.append(f"{prefix}{key or cls.__name__}: {e['msg']}")
    return out


SECTIONS: dict = {}
"""The options classes by the spec table their options live in ('scene', 'sweep', 'run'); each
class registers itself here when it is defined (:func:`options_class`), so this leaf module
imports nothing of the package and the docs and --set still see every option."""
SECTION_ORDER = ("scene", "sweep", "run")


def options_class(error: type[ValueError], *, frozen: bool = False, section: str | None = None):
    """A pydantic dataclass whose constructor raises ``error`` (which takes a list of messages)
    with :func:`messages`; registered in :data:`SECTIONS` under ``section`` (None: not a sweep
    spec's table, e.g. the lens's, :mod:`warp_tensegrity.options_lens`)."""

    def wrap(cls):
        cls = _pydantic_dataclass(
            cls, frozen=frozen, config=ConfigDict(extra="forbid", use_attribute_docstrings=True)
        )
        init = cls.__init__

        @functools.wraps(init)
        def __init__(self, *args, **kwargs):
            try:
                init(self, *args, **kwargs)
            except ValidationError as exc:
                raise error(messages(exc, cls)) from None

        cls.__init__ = __init__
        if section is not None:
            SECTIONS[section] = cls
        return cls

    return wrap


def build(cls, values: dict, prefix: str = ""):
    """``cls(**values)``, or raise OptionError whose messages start with ``prefix`` (e.g.
    ``"run."``). Every problem of the table is reported."""
    try:
        return cls(**values)
    except ValueError as e:
        if not hasattr(e, "errors"):
            raise
        raise OptionError([f"{prefix}{m}" for m in e.errors]) from None


# ---------------------------------------------------------------------- per-column parameters
@options_class(OptionError, frozen=True, section="sweep")
class ColumnParameters:
    """The per-column parameters of a batch or a sweep (each column may have its own)."""

    prestrain: Annotated[float, Opt("real", "1", ge=0, lt=1, why="the cross-cable prestrain p; 1 would put the cables' rest length at zero",
                                    long_name="cross-cable prestrain p")] = 0.0
    """Cross-cable prestrain p [1]; or a profile along the column, one value per prism (docs/sweeps.md, Profiles)."""
    v0: Annotated[float, Opt("real", "m s-1", ge=0, le=MAX_SPEED, why="v0 is the compressive impact speed of the free end",
                             long_name="compressive impact speed at the free end")] = 0.0
    """Compressive impact speed of the free end [m s-1]."""
    base_rigidity: Annotated[float, Opt("real", "1", ge=0, le=1, why="0 flexible bases (FB), 1 rigid bases (RB)",
                                        long_name="base rigidity (0: flexible bases FB, 1: rigid bases RB)")] = 0.0
    """Base rigidity beta [1]: 0 flexible bases (FB), 1 rigid bases (RB), elastic in between."""
    cable_EA: Annotated[float | None, Opt("real", "N", gt=0, le=MAX_EA, optional=True,
                                          default_text="scene's E_s pi r_s^2",
                                          long_name="axial stiffness E*A of the cables")] = None
    """Cable axial stiffness E_s A [N]; None: the scene's E_s pi r_s^2; or a profile, one value per prism
    (an interior base member takes the mean of its two prisms')."""
    unit_mass: Annotated[float | None, Opt("real", "kg", ge=MASS[0], le=MASS[1], optional=True,
                                           default_text="scene's unit_mass",
                                           long_name="mass per unit (prism), lumped on the bases")] = None
    """Mass per unit (prism) [kg]; None: the scene's unit_mass; or a profile, one value per level
    (n_prisms + 1: the mass each base carries, the end bases half of theirs with end_base_mass = 'half')."""
    striker_mass: Annotated[float | None, Opt("real", "kg", ge=0, le=MASS[1], optional=True,
                                              default_text="scene's striker_mass", long_name="mass of the striker")] = None
    """Striker mass M [kg] (scene impact = 'striker', where it must be > 0); None: the scene's striker_mass."""
    preload: Annotated[float, Opt("real", "N", ge=0, le=MAX_EA, why="F0 is the static compressive force on the free end",
                                  long_name="static axial compressive force on the free end (preload F0)")] = 0.0
    """Static axial compressive force F0 on the free end [N], a dead load in equilibrium before the
    impact (scene.preload); 0: none (the column as without it, bit for bit)."""


COLUMN_PARAMETERS = {name: opt_of(ColumnParameters, name).unit for name in ColumnParameters.__pydantic_fields__}
"""Swept per-column parameters and their units."""


def check_column_param(name: str, values, error: type[ValueError] = OptionError) -> None:
    """``error`` naming the first entry of ``values`` outside the bounds of parameter ``name``."""
    opt_of(ColumnParameters, name).check_array(name, values, error)


# ---------------------------------------------------------------------- profiles along the column
PROFILED = {"prestrain": "prism", "cable_EA": "prism", "unit_mass": "level"}
"""Per-column parameters that may vary along the column, and what they hold one value for: prestrain
and cable_EA one per prism (n_prisms values, prism 0 at the clamped base), unit_mass one per level
(n_prisms + 1 values, level 0 the clamped base): the mass a level carries as an interior base (the end
bases carry half of theirs under the scene's end_base_mass = 'half', as a uniform column's do).
Handedness varies along the column already, as the scene's letters R/L."""
PROFILE_KINDS = ("values", "grade", "segments")
PROFILE_FIELDS = ("from", "to", "at")
"""The generating parameters of a grade or two segments, which a sweep grid can vary (``prestrain_at``)."""


def profile_length(name: str, n_prisms: int) -> int:
    """Entries of a profile of ``name`` in a column of ``n_prisms``."""
    return int(n_prisms) + (PROFILED[name] == "level")


@_std_dataclass(frozen=True)
class Profile:
    """A per-column parameter along the column (:data:`PROFILED`): explicit ``values``; a linear
    ``grade`` from ``first`` (prism or level 0, at the clamped base) to ``last`` (at the free end); or
    two ``segments``, ``first`` before prism (level) ``at`` and ``last`` from it on. The same profile
    fits columns of any length (except explicit values); :meth:`array` gives its entries. TOML:
    ``{values = [...]}``, ``{grade = [first, last]}``, ``{segments = [first, last], at = k}``."""

    kind: str
    values: tuple
    """The explicit values, or (first, last)."""
    at: int | None = None

    @classmethod
    def grade(cls, first: float, last: float) -> Profile:
        """From ``first`` at the clamped base to ``last`` at the free end, linearly."""
        return cls("grade", (first, last))

    @classmethod
    def segments(cls, first: float, last: float, at: int) -> Profile:
        """``first`` on prisms 0..at-1 (levels 0..at-1), ``last`` on prisms at..n-1 (levels at..n)."""
        return cls("segments", (first, last), at)

    @classmethod
    def explicit(cls, values) -> Profile:
        """One value per prism (or level: unit_mass)."""
        return cls("values", tuple(np.asarray(values, dtype=np.float64).ravel().tolist()))

    @property
    def first(self) -> float:
        return self.values[0]

    @property
    def last(self) -> float:
        return self.values[-1]

    def fields(self) -> dict:
        """The generating parameters ('from', 'to' and, for segments, 'at'); {} for explicit values."""
        if self.kind == "values":
            return {}
        return {"from": self.first, "to": self.last} | ({"at": self.at} if self.kind == "segments" else {})

    def replace(self, field: str, value) -> Profile:
        """This profile with one generating parameter ('from', 'to', 'at') set to ``value``."""
        if field == "at":
            return Profile(self.kind, self.values, value)
        first, last = (value, self.last) if field == "from" else (self.first, value)
        return Profile(self.kind, (first, last), self.at)

    def table(self) -> dict:
        """The TOML table of this profile."""
        if self.kind == "values":
            return {"values": list(self.values)}
        return {self.kind: list(self.values)} | ({"at": self.at} if self.kind == "segments" else {})

    def check(self, name: str, n_prisms: int, error: type[ValueError] = OptionError, path: str | None = None,
              bounds: Opt | None = None) -> np.ndarray:
        """The profile's entries for parameter ``name`` in a column of ``n_prisms``, checked: ``error``
        names the parameter (``path``: as the spec writes it) and the bad value (wrong length, an entry
        out of bounds, a bad ``at``); ``bounds``: the entries' Opt, if not the parameter's."""
        key, name = name, (path or name)
        bounds = bounds or opt_of(ColumnParameters, key)
        if key not in PROFILED:
            raise error(f"{name} = {fmt(self)}: {key} takes one value per column, not a profile "
                        f"(profiles: {', '.join(PROFILED)})")
        n = profile_length(key, n_prisms)
        if self.kind == "values" and len(self.values) != n:
            raise error(f"{name} = {fmt(self.table())}: give {n} values, one per {PROFILED[key]} "
                        f"(n_prisms = {n_prisms}), not {len(self.values)}")
        if self.kind == "segments":
            at = self.at
            if isinstance(at, (bool, np.bool_)) or not isinstance(at, numbers.Integral) or not 1 <= at <= n_prisms - 1:
                raise error(f"{name}.at = {fmt(at)}: the interface must be a prism index in [1, {n_prisms - 1}] "
                            f"(n_prisms = {n_prisms}), so both segments have a prism")
        if self.kind not in PROFILE_KINDS:
            raise error(f"{name} = {fmt(self)}: profile kind must be one of {', '.join(PROFILE_KINDS)}")
        bounds.check_array(f"{name}.{self.kind}", list(self.values), error)
        vals = np.asarray(self.values, dtype=np.float64)
        if self.kind == "values":
            return vals
        if self.kind == "grade":
            return np.linspace(vals[0], vals[1], n)
        return np.where(np.arange(n) < self.at, vals[0], vals[1])

    @classmethod
    def from_table(cls, name: str, table, error: type[ValueError] = OptionError, path: str | None = None,
                   bounds: Opt | None = None) -> Profile:
        """A profile from its TOML table; ``error`` names ``name`` (``path``: as the spec writes it) and
        the bad key or value; ``bounds``: the entries' Opt, if not the parameter's."""
        key, name = name, (path or name)
        bounds = bounds or opt_of(ColumnParameters, key)
        if not isinstance(table, dict):
            raise error(f"{name} = {fmt(table)}: a profile is a table: {{values = [...]}}, {{grade = [first, last]}} "
                        "or {segments = [first, last], at = k}")
        kinds = [k for k in PROFILE_KINDS if k in table]
        allowed = PROFILE_KINDS + ("at",)
        bad = [k for k in table if k not in allowed]
        if bad:
            raise error(unknown_key(f"{name}.{bad[0]}", bad[0], allowed, what="profile key"))
        if len(kinds) != 1:
            raise error(f"{name} = {fmt(table)}: give exactly one of {', '.join(PROFILE_KINDS)}")
        kind = kinds[0]
        vals = table[kind]
        if not isinstance(vals, (list, tuple)) or (kind != "values" and len(vals) != 2):
            want = "a list of values" if kind == "values" else "[first, last]"
            raise error(f"{name}.{kind} = {fmt(vals)}: give {want}")
        if not vals:
            raise error(f"{name}.{kind} = []: give at least one value")
        for i, v in enumerate(vals):
            if isinstance(v, (bool, np.bool_)) or not isinstance(v, numbers.Real):
                raise error(f"{name}.{kind}[{i}] = {fmt(v)}: must be a number")
        if ("at" in table) != (kind == "segments"):
            raise error(f"{name} = {fmt(table)}: " + ("segments need at = k, the first prism of the second segment"
                                                        if kind == "segments" else f"at belongs to segments, not {kind}"))
        at = table.get("at")
        if kind == "segments" and (isinstance(at, bool) or not isinstance(at, int)):
            raise error(f"{name}.at = {fmt(at)}: must be an integer prism index")
        bounds.check_array(f"{name}.{kind}", list(vals), error)  # bounds, by position
        return cls(kind, tuple(float(v) for v in vals), at)


# ---------------------------------------------------------------------- [run]
@options_class(SettingsError, section="run")
class RunSettings:
    """How to integrate a batch, and (sweeps) how to store it (SI units)."""

    t_end: Annotated[float, Opt("real", "s", gt=0, le=MAX_TIME, why="about 30 years of simulated time")] = 1.0
    """Simulated time [s]."""
    dt: Annotated[float | Literal["auto"], Opt("real", "s", ge=MIN_TIME, special=(("auto", "auto"),))] = "auto"
    """Time step [s], <= t_end; 'auto': the largest step <= dt_safety x the method's stability limit
    that divides the output interval."""
    method: Annotated[str, Opt("choice", choices=METHODS)] = "rattle"
    """'rattle' (default: velocity Verlet + position/velocity projection), 'rk4' (the paper's
    RK4 with projection), 'yoshida4' (RATTLE triple-jump composition), 'symplectic_euler'."""
    precision: Annotated[str, Opt("choice", choices=PRECISIONS)] = "auto"
    """Floating point of the state: 'fp32', 'fp64' or 'auto' (default): a sweep on a GPU runs fp32,
    verifies every case by its error estimate (``error_estimate``) and reruns in fp64 the cases it does
    not verify (the dataset's ``precision_used`` says which answered); fp64 everywhere else (the CPU,
    where fp32 buys little, and single runs, which have no twin to verify them)."""
    output_interval: Annotated[float | None, Opt("real", "s", ge=MIN_TIME, optional=True, special=(("auto", None),))] = None
    """Time between recorded outputs [s], <= t_end; None ('auto'): t_end / 200."""
    record_strain: Annotated[bool, Opt("bool")] = True
    """Keep the prism strain history (n_out x n_prisms per column) in the result and the dataset
    (sweeps compute it either way: the measurements need it)."""
    record_energy: Annotated[bool, Opt("bool")] = True
    """Store the kinetic and elastic energy histories in a sweep's dataset."""
    energy_precision: Annotated[str, Opt("choice", choices=("auto", "fp32", "fp64"))] = "auto"
    """Sweeps: the floating point a dataset stores its energy histories in (``kinetic_energy``,
    ``elastic_energy``, ``station_energy``, ``end_energy``; they are computed in fp64 either way, and
    every measure is taken before they are stored). 'auto': float32 for the kinetic, station and
    end energies, whose values start from 0 (a relative round-off of 6e-8 of each value, far below
    the run's accuracy target, 1e-3 by default), float64 for the elastic energy, which carries the
    prestress energy (up to ~1,400x the impact energy in phase_large: float32 would resolve its
    change only to ~1e-4 of the impact energy); 'fp32' all float32 (half the bytes); 'fp64' all
    float64 (to study energy conservation from the histories)."""
    compress_energy: Annotated[bool, Opt("bool")] = False
    """Sweeps: zlib-compress the energy histories in the netCDF export. Off by default: their low
    bits are round-off, so compression saves 19 % (float64) to 28 % (float32) of their bytes for
    3-4x the export time (docs/sweeps.md, measured at phase_large's size)."""
    device: Annotated[str | None, Opt("str", pattern=r"cpu|cuda|cuda:\d+", optional=True, special=(("auto", None),),
                                      rule_text='"cpu", "cuda", "cuda:N"', default_text='"auto"')] = None
    """Warp device ('cpu', 'cuda:0'); None ('auto'): the GPU if there is one, else the CPU."""
    shard_size: Annotated[int | None, Opt("int", "1", ge=1, optional=True, special=(("auto", None),),
                                          default_text='"auto"')] = None
    """Columns per shard of a sweep (one engine batch, one chunk of the run's Zarr store); not part of
    the fingerprint. None ('auto'): on a GPU the columns its resident warps of the lane step hold
    (one warp per column: SM count x the warps an SM holds at the lane step's registers;
    :func:`warp_tensegrity.policy.decide.default_shard_size`), 256 on the CPU."""
    dt_safety: Annotated[float | None, Opt("real", "1", ge=1e-6, le=0.5, optional=True, default_text="from the default accuracy",
                                           why="strong impacts lower the stability limit to ~0.45 of the prediction")] = None
    """Fraction of the predicted stability limit used when dt = 'auto'; None (not given, and no
    accuracy): the fraction the error model gives for :data:`~warp_tensegrity.engine.DEFAULT_ACCURACY`
    (1e-3) on the pulse measures (:func:`~warp_tensegrity.engine.default_dt_safety`), recorded as
    ``dt_safety_used`` and ``accuracy_target``."""
    # dt_safety, measured (analysis/work_precision.md): strong impacts stiffen the prisms and lower
    # the real limit to ~0.45 of 2/omega_max; the default 0.25 keeps a margin of >= 2.5x
    allow_unstable_dt: Annotated[bool, Opt("bool")] = False
    """Accept an explicit dt above the stability limit (for stability studies)."""
    projection_tol: Annotated[float | None, Opt("real", "1", gt=0, lt=1e-2, optional=True,
                                                default_text="1e-13 (fp64), 3e-7 (fp32)")] = None
    """Relative bar-length tolerance of the projection; None: 1e-13 (fp64) or 3e-7 (fp32, just above
    the ~2.4e-7 round-off floor of a fp32 bar length: a tighter one only buys stalled iterations)."""
    max_projection_iters: Annotated[int, Opt("int", "1", ge=1)] = 25
    """Newton iterations allowed per projection before a column is flagged."""
    failure_bar_error: Annotated[float, Opt("real", "1", gt=0)] = 1e-3
    """Relative bar-length error above which a column is frozen and flagged."""
    steps_per_graph: Annotated[int, Opt("int", "1", ge=1)] = 50
    """Steps captured in one CUDA graph."""
    fused: Annotated[bool | Literal["auto", "lanes"], Opt("bool", special=(("auto", "auto"), ("lanes", "lanes")))] = "auto"
    """RATTLE as one fused kernel with several steps per launch; False: one kernel per stage (the only
    path of the other methods). 'auto' and True on a GPU: the lane step (one warp per column,
    :mod:`warp_tensegrity.sim.lanes.lanes`) wherever it takes the columns (massless bars, up to 2,048 prisms
    simulated, 1,024 with rigid bases; past 128 (64) prisms k warps per column;
    :func:`~warp_tensegrity.engine.choose_path`).
    Otherwise 'auto': for RATTLE on a GPU the fastest measured of the fused step (a thread block per
    column, :mod:`warp_tensegrity.sim.block.kernels`; constraint solve by block cyclic reduction or
    serially on lane 0) and the staged kernels for the band, precision and batch; the fused step
    on the CPU; staged for Gram bands wider than ``FUSED_MAX_BANDWIDTH`` (generic networks); True:
    the faster fused variant. 'lanes': the lane step on any device (the CPU emulates its warps:
    slow, for tests), an error where it does not take the columns. The paths give the same numbers
    to round-off (not part of the fingerprint)."""
    accuracy: Annotated[float | None, Opt("real", "1", ge=1e-15, lt=1, optional=True,
                                          why="the relative error wanted on pulse speed and amplitude, "
                                              "not below fp64 round-off")] = None
    """Target relative error of the pulse measures (speed, amplitude). When given, the engine
    chooses method, precision and dt from the measured work-precision curves
    (:mod:`warp_tensegrity.engine`) and says what it chose in ``BatchResult.info['choices']``."""
    truncate: Annotated[bool, Opt("bool")] = True
    """Simulate only the prisms a disturbance can reach within t_end (plus a margin), clamping the
    column there; results are padded back to the full column (the far prisms stay at rest).
    Mixed-handed columns with rigid bases are never truncated (see :mod:`warp_tensegrity.engine`)."""
    groups: Annotated[bool, Opt("bool")] = True
    """Sweeps: run the columns in groups of like stiffness, each with its own plan (dt, steps, path;
    :mod:`warp_tensegrity.policy.groups`: rigid bases apart, omega_max within 2x), so no column steps
    at the stiffest column's dt; False: one plan, one dt, for every column. Only with dt = 'auto'."""
    error_estimate: Annotated[bool, Opt("bool")] = True
    """Sweeps: step every group's columns a second time at about 4x its dt (a twin on the same output
    times, about a quarter of the steps) and give each measure an error estimate from the two
    (``<measure>_error``, docs/measurements.md); False: no twin, no estimate."""
    measure: Annotated[str, Opt("choice", choices=("device", "host", "none"))] = "device"
    """Pulse measures (``BatchResult.measurements``) of :func:`~warp_tensegrity.engine.simulate_batch`:
    'device' (Warp kernels on the device record; only the measures cross to the host), 'host'
    (NumPy reference on a host copy) or 'none'. Except with 'none', the strain record is kept on
    the device (n_out x n_prisms per column) even when record_strain is False."""
    energy_station: Annotated[int | None, Opt("int", "1", ge=0, optional=True, special=(("auto", None),),
                                              default_text='"auto"', rule_text=">= 0 and < the scene's n_prisms")] = None
    """Station prism (index from the clamp) whose section the leading pulse's energy is measured through
    (``pulse_energy_share``, docs/measurements.md "Energy measures"); None ('auto'): the prism at
    mid-column, (n_prisms - 1) // 2. Must be < the scene's n_prisms."""
    energy_end_prisms: Annotated[int, Opt("int", "1", ge=1)] = 5
    """Prisms k at the impacted end whose energy at t_end is ``end_energy_share`` (the whole column
    where it has fewer)."""

    def __post_init__(self):
        errors = []
        if self.dt != "auto" and self.dt > self.t_end:
            errors.append(f"dt = {self.dt!r}: must be <= t_end = {self.t_end!r} s")
        if self.output_interval is not None and self.output_interval > self.t_end:
            errors.append(f"output_interval = {self.output_interval!r}: must be <= t_end = {self.t_end!r} s")
        if self.fused in (True, "lanes") and self.method != "rattle":
            errors.append(f"fused = {self.fused!r}: the fused step is RATTLE's; needs method = 'rattle' (got {self.method!r})")
        if errors:
            raise SettingsError(errors)

    @property
    def tolerance(self) -> float:
        if self.projection_tol is not None:
            return self.projection_tol
        return 3e-7 if self.precision == "fp32" else 1e-13


EXECUTION_KEYS = ("device", "shard_size", "fused")
"""[run] keys that say where/how a sweep runs, not what it computes: left out of the fingerprint."""


def sections() -> dict:
    """{'scene': ColumnConfig, 'sweep': ColumnParameters, 'run': RunSettings}, in that order
    (ColumnConfig registers when :mod:`warp_tensegrity.scene.columns` is imported, which importing
    the package does)."""
    missing = [s for s in SECTION_ORDER if s not in SECTIONS]
    if missing:
        raise RuntimeError(f"options sections {missing} not registered: import warp_tensegrity first")
    return {s: SECTIONS[s] for s in SECTION_ORDER}
