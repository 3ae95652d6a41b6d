"""Sweep specs: a TOML file that names the fixed scene, the swept per-column parameters and the
run settings, validated with errors that name the key path and the bad value.

A spec has three parts (see ``docs/sweeps.md`` for every key)::

    [scene]                 # ColumnConfig fields (+ non-swept per-column scalars)
    n_prisms = 50
    [sweep]
    grid = {prestrain = [0.0, 0.002], v0 = {start = 1e-3, stop = 0.2, num = 16, spacing = "log"}}
    # or: cases = [{prestrain = 0.0, v0 = 0.001, base_rigidity = 0.0}, ...]
    fixed = {base_rigidity = 1.0}
    [run]
    t_end = 1.0
    dt = "auto"

The tables are parsed and checked in :mod:`.parse`. Nothing here imports Warp: loading and
validating a spec is instant. The dt stability check needs the engine's estimate
(:func:`warp_tensegrity.sweep.plan_sweep` calls :meth:`SweepSpec.check_dt`).
"""

from __future__ import annotations

import copy
import dataclasses
import hashlib
import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..policy.accuracy import for_accuracy
from ..options import (COLUMN_PARAMETERS, EXECUTION_KEYS, PROFILED, ColumnParameters, OptionError, Profile, RunSettings,
                       profile_length)
from ..provenance import code_version
from ..scene.columns import ColumnConfig
from ..tomlread import TomlError, decode, read_file, read_toml
from ..types import Layout
from .errors import SpecError
from .parse import PROFILE_AXES, SCENE_FIELDS, _Checker, _parse_run, _parse_scene, _parse_sweep


TOP_KEYS = ("title", "description", "scene", "sweep", "run")

PARAM_DEFAULTS = {f.name: f.default for f in dataclasses.fields(ColumnParameters) if f.default is not None}
"""Defaults of the per-column parameters that are not scene-derived (cable_EA and unit_mass
default to the scene's values)."""

KEY_DOCS = {
    "title": "dataset `title` attribute (default: from the file name)",
    "description": "dataset `comment` attribute",
    "scene": "table: the fixed scene, the same for every column",
    "sweep": "table: the swept per-column parameters",
    "run": "table: run settings",
    "sweep.grid": "a full grid, one axis per per-column parameter, in the order written (C order: the first varies slowest); "
                  "each axis a list of distinct values or a range table",
    "sweep.cases": "an explicit list of tables, one column each, setting any per-column parameters (and `label`)",
    "sweep.fixed": "non-swept per-column parameters (a parameter is either swept or fixed)",
    "sweep.grid.<param>.start": "first value of a range axis (included)",
    "sweep.grid.<param>.stop": "last value of a range axis (included)",
    "sweep.grid.<param>.num": "number of values of a range axis (integer >= 1)",
    "sweep.grid.<param>.spacing": '`"linear"` (default) or `"log"` (geometric; start, stop > 0)',
    "sweep.cases[i].label": "case label, stored as the `case_label` coordinate",
    "<param>.values": "a profile along the column (prestrain, cable_EA: one value per prism; unit_mass: one per level, "
                      "n_prisms + 1), in [sweep.fixed], a case, or [scene] (prestrain, cable_EA): the values, "
                      "prism 0 at the clamped base",
    "<param>.grade": "a profile: [first, last], linear from the clamped base to the free end",
    "<param>.segments": "a profile: [first, last], two segments joined at prism `at`",
    "<param>.at": "the first prism (level) of a profile's second segment, in [1, n_prisms - 1]",
    "sweep.grid.<param>_from": "a grid axis over the first value of the [sweep.fixed] profile of `<param>`",
    "sweep.grid.<param>_to": "a grid axis over the last value of the [sweep.fixed] profile of `<param>`",
    "sweep.grid.<param>_at": "a grid axis over the interface prism of the [sweep.fixed] two-segment profile of `<param>`",
}
"""What each structural spec key means (the options themselves are documented where they are
declared: :func:`warp_tensegrity.options_docs.options_table`; the docs' hook reads both)."""


# ---------------------------------------------------------------------- the spec
@dataclass
class SweepSpec:
    """A validated sweep spec. Columns are numbered in C order over the grid (first grid key
    slowest), or in list order for explicit cases."""

    text: str
    """The spec file's full text."""
    source: str | None
    """Where it was read from (for messages)."""
    title: str | None
    description: str | None
    scene: ColumnConfig
    scene_keys: dict
    """The [scene] ColumnConfig keys as written (validated)."""
    fixed: dict
    """Non-swept per-column parameters given as scalars ([scene] or [sweep.fixed])."""
    kind: str
    """'grid' or 'cases'."""
    grid: dict = field(default_factory=dict)
    """Grid axes in spec order: name -> 1-D float64 array."""
    cases: list = field(default_factory=list)
    """Explicit cases: one dict of swept values per case."""
    labels: list | None = None
    """Optional case labels (explicit cases only)."""
    run: dict = field(default_factory=dict)
    """Every [run] key, defaults filled in."""
    data: dict = field(default_factory=dict, repr=False)
    """The parsed TOML (after overrides)."""

    # ------------------------------------------------------------------ shape
    @property
    def swept(self) -> tuple[str, ...]:
        """Swept parameters: grid axes in spec order, or (cases) in COLUMN_PARAMETERS order."""
        if self.kind == "grid":
            return tuple(self.grid)
        present = {k for c in self.cases for k in c}
        return tuple(p for p in COLUMN_PARAMETERS if p in present)

    @property
    def shape(self) -> tuple[int, ...]:
        if self.kind == "grid":
            return tuple(len(v) for v in self.grid.values())
        return (len(self.cases),)

    @property
    def n_columns(self) -> int:
        return int(np.prod(self.shape))

    def default_param(self, name: str) -> float | Profile:
        """Value of a per-column parameter that is not swept: fixed (a number or a profile), or its default."""
        if name in self.fixed:
            v = self.fixed[name]
            return v if isinstance(v, Profile) else float(v)
        if name == "cable_EA":
            return float(self.scene.cable_EA)
        if name == "unit_mass":
            return float(self.scene.unit_mass)
        if name == "striker_mass":
            return float(self.scene.striker_mass)
        return float(PARAM_DEFAULTS[name])

    def column_params(self) -> dict[str, np.ndarray]:
        """Every per-column parameter (all of COLUMN_PARAMETERS) for every column, shape (N,), or
        (N, its length) for a profile along the column (:data:`~warp_tensegrity.options.PROFILED`)."""
        n, n_prisms = self.n_columns, self.scene.n_prisms
        out = {}
        for p in COLUMN_PARAMETERS:
            d = self.default_param(p)
            if isinstance(d, Profile) and any(f"{p}_{f}" in self.grid for f in ("from", "to", "at")):
                continue  # a template the grid sets per column, below
            out[p] = (np.broadcast_to(d.check(p, n_prisms), (n, profile_length(p, n_prisms))).copy()
                      if isinstance(d, Profile) else np.full(n, d, dtype=np.float64))
        if self.kind == "grid":
            mesh = np.meshgrid(*self.grid.values(), indexing="ij")
            fields: dict = {}
            for name, m in zip(self.grid, mesh):
                if name in PROFILE_AXES:  # a field of a profile, set per column below
                    p, fld = PROFILE_AXES[name]
                    fields.setdefault(p, {})[fld] = m.reshape(-1)
                else:
                    out[name] = np.ascontiguousarray(m.reshape(-1), dtype=np.float64)
            for p, f in fields.items():
                out[p] = profile_rows(self.fixed[p], f, profile_length(p, n_prisms))
            out = {p: out[p] for p in COLUMN_PARAMETERS}  # in the declared order
        else:
            for i, case in enumerate(self.cases):
                for name, v in case.items():
                    if isinstance(v, Profile) and out[name].ndim == 1:
                        out[name] = np.repeat(out[name][:, None], profile_length(name, n_prisms), axis=1)
                    out[name][i] = v.check(name, n_prisms) if isinstance(v, Profile) else v
        return out

    def layout(self) -> Layout:
        """What :mod:`warp_tensegrity.io` needs of this spec to lay out and annotate its datasets."""
        swept = self.swept
        return Layout(
            kind=self.kind, swept=swept, grid=dict(self.grid),
            scalars={p: self.default_param(p) for p in COLUMN_PARAMETERS if p not in swept},
            labels=None if self.labels is None else tuple(self.labels), n_columns=self.n_columns,
            scene=self.scene, run=dict(self.run), title=self.title, description=self.description,
            source=self.source, text=self.text, text_sha256=self.text_sha256,
        )

    def shards(self, shard_size: int | None = None) -> list[tuple[int, int]]:
        """Contiguous blocks of columns: [(start, stop), ...] (the spec's shard_size if none is given;
        'auto' is the device's: :func:`warp_tensegrity.policy.decide.default_shard_size`)."""
        size = shard_size or self.run["shard_size"]
        if size is None:
            from ..policy.decide import default_shard_size  # initialises Warp: only for 'auto'

            size = default_shard_size(self.run["device"] if self.run["device"] not in (None, "auto") else None)
        size = int(size)
        n = self.n_columns
        return [(s, min(s + size, n)) for s in range(0, n, size)]

    # ------------------------------------------------------------------ settings
    def run_settings(self, device: str | None = None, dt: float | str | None = None) -> RunSettings:
        """RunSettings for the engine. The engine keeps the strain record on the device (the
        measurements are taken there); record_strain decides whether it crosses to the host and is
        stored. The accuracy was resolved into method, precision and dt_safety for the whole column
        when the spec was read."""
        r = dict(self.run)
        r.update(accuracy=None)
        if device is not None:
            r["device"] = device
        if dt is not None:
            r["dt"] = dt
        return RunSettings(**r)

    def check_dt(self, dt_limit: float) -> None:
        """Refuse an explicit dt above the stability limit unless run.allow_unstable_dt."""
        dt = self.run["dt"]
        if isinstance(dt, str) or self.run["allow_unstable_dt"]:
            return
        if math.isfinite(dt_limit) and dt > dt_limit:
            raise SpecError(
                f"run.dt = {dt!r} s is above the stability limit dt_limit = {dt_limit:.6g} s of method "
                f"{self.run['method']!r} ({self.run['precision']}) for the stiffest column of the sweep; "
                f"use run.dt <= {dt_limit:.6g}, run.dt = \"auto\" "
                f"({self.run['dt_safety'] or 'a fraction of'} x the limit), or set run.allow_unstable_dt = true",
                self.source,
            )

    # ------------------------------------------------------------------ identity
    def canonical(self, include_execution: bool = False) -> str:
        """Canonical JSON of everything that decides the results (sorted keys, exact floats).
        Execution choices (device, shard_size) are left out unless asked for."""
        run = {k: v for k, v in self.run.items() if include_execution or k not in EXECUTION_KEYS}
        doc = {
            "title": self.title,
            "description": self.description,
            "scene": {f: getattr(self.scene, f) for f in SCENE_FIELDS},
            "fixed": {k: _canonical_value(v) for k, v in sorted(self.fixed.items())},
            "sweep": (
                {"grid": [[k, [float(x) for x in v]] for k, v in self.grid.items()]}
                if self.kind == "grid"
                else {"cases": [{k: _canonical_value(v) for k, v in sorted(c.items())} for c in self.cases],
                      "labels": self.labels}
            ),
            "run": run,
        }
        return json.dumps(_plain(doc), sort_keys=True, separators=(",", ":"))

    @property
    def text_sha256(self) -> str:
        return hashlib.sha256(self.text.encode()).hexdigest()

    def fingerprint(self, code: str | None = None) -> str:
        """sha256 of the canonical spec and the code version string."""
        code = code_version() if code is None else code
        return hashlib.sha256((self.canonical() + "\n" + code).encode()).hexdigest()

    def describe(self) -> str:
        if self.kind == "grid":
            axes = " x ".join(f"{k} {len(v)}" for k, v in self.grid.items())
            return f"{self.n_columns} columns (grid {axes})"
        return f"{self.n_columns} columns (explicit cases over {', '.join(self.swept) or 'nothing'})"


def _canonical_value(v):
    """A number as a float; a profile as its table (a spec without profiles keeps its fingerprint)."""
    return v.table() if isinstance(v, Profile) else float(v)


def profile_rows(template: Profile, fields: dict, n: int) -> np.ndarray:
    """(N, n) entries of ``template`` (a grade or two segments) with the generating parameters
    ``fields`` ('from', 'to', 'at': arrays of N) set per column, as :meth:`Profile.check` makes them."""
    N = len(next(iter(fields.values())))
    first = np.broadcast_to(np.asarray(fields.get("from", template.first), dtype=np.float64), (N,))
    last = np.broadcast_to(np.asarray(fields.get("to", template.last), dtype=np.float64), (N,))
    if template.kind == "grade":
        return np.ascontiguousarray(np.linspace(first, last, n, axis=1))
    at = np.broadcast_to(np.asarray(fields.get("at", template.at), dtype=np.float64), (N,))
    return np.where(np.arange(n)[None, :] < at[:, None], first[:, None], last[:, None])


def _plain(x):
    if isinstance(x, dict):
        return {str(k): _plain(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_plain(v) for v in x]
    if isinstance(x, np.generic):
        return x.item()
    return x


# ---------------------------------------------------------------------- loading
def load_spec(source, overrides: dict | None = None) -> SweepSpec:
    """Read and validate a spec from a path (str/Path to an existing file) or TOML text.

    ``overrides`` is a nested dict merged over the parsed TOML before validation
    (e.g. ``{"run": {"t_end": 0.1}}``). Raises SpecError listing every problem found.
    """
    path = None
    if isinstance(source, (bytes, bytearray)):
        try:
            source = decode(source)
        except TomlError as e:
            raise SpecError(e.reason) from None
    elif not isinstance(source, (str, Path)):
        raise SpecError(f"give a spec file's path or its TOML text, not {type(source).__name__} {source!r:.60}")
    if isinstance(source, Path) or ("\n" not in source and (source.endswith(".toml") or _is_file(source))):
        path = Path(source)
        try:
            raw = read_file(path)
        except OSError as e:
            raise SpecError(f"cannot read spec: {e}", str(path)) from None
        except TomlError as e:  # a FIFO, a device, a directory, a file larger than a spec may be
            raise SpecError(e.reason, str(path)) from None
        try:
            text = decode(raw)
        except TomlError as e:
            raise SpecError(e.reason, str(path)) from None
    else:
        text = str(source)
    return parse_spec(text, source=str(path) if path else None, overrides=overrides)


def _is_file(name: str) -> bool:
    try:
        return Path(name).is_file()
    except (OSError, ValueError):  # a name too long, or with a NUL byte: TOML text, not a path
        return False


def _merge(base: dict, over: dict) -> dict:
    out = copy.deepcopy(base)
    for k, v in over.items():
        if isinstance(v, dict) and isinstance(out.get(k), dict):
            out[k] = _merge(out[k], v)
        else:
            out[k] = copy.deepcopy(v)
    return out


def _overridden_text(text: str, data: dict, overrides: dict) -> str:
    """The spec as run: the merged tables written back as TOML (a resumed run reads this text,
    so it must hold the overrides), headed by the overrides as a comment."""
    import tomli_w  # only needed with overrides

    flat = [f"{s}.{k} = {v!r}" for s, t in overrides.items() if isinstance(t, dict) for k, v in t.items()]
    head = "# spec with command-line overrides: " + ", ".join(flat) + "\n"
    try:
        return head + tomli_w.dumps(data)
    except (TypeError, ValueError):  # not writable as TOML: validation below names the bad value
        return text


def _check_profiles(ck, n_prisms: int, fixed: dict, grid: dict, cases: list) -> None:
    """Profiles against the scene's column: lengths and interface positions (each named by its path)."""
    swept = {}  # a template's fields a grid sets: checked with the grid's values, not the template's
    for key, vals in grid.items():
        if key in PROFILE_AXES and isinstance(fixed.get(PROFILE_AXES[key][0]), Profile):
            name, fld = PROFILE_AXES[key]
            swept[name] = swept.get(name, fixed[name]).replace(fld, int(vals[0]) if fld == "at" else float(vals[0]))
    where = [(f"sweep.fixed.{k}", k, swept.get(k, v)) for k, v in fixed.items()]
    where += [(f"sweep.cases[{i}].{k}", k, v) for i, c in enumerate(cases) for k, v in c.items()]
    for path, k, v in where:
        if isinstance(v, Profile):
            try:
                v.check(k, n_prisms, path=path)
            except OptionError as e:
                ck.errors += e.errors
    for key, vals in grid.items():
        name, fld = PROFILE_AXES.get(key, (None, None))
        if name in grid:
            ck.error(f"sweep.grid.{key}", f"conflicts with sweep.grid.{name}: sweep the profile's fields or the whole "
                                          "parameter, not both")
        if fld == "at" and vals.max() > n_prisms - 1:
            ck.bad(f"sweep.grid.{key}", float(vals.max()), f"the interface must be a prism index in [1, {n_prisms - 1}] "
                   f"(n_prisms = {n_prisms}), so both segments have a prism")


def parse_spec(text: str, source: str | None = None, overrides: dict | None = None) -> SweepSpec:
    try:
        data = read_toml(text)
    except TomlError as e:
        raise SpecError(e.reason, source) from None
    if overrides:
        data = _merge(data, overrides)
        text = _overridden_text(text, data, overrides)
    ck = _Checker()
    ck.keys(data, "", TOP_KEYS, what="top-level table")
    title = data.get("title")
    description = data.get("description")
    for k, v in (("title", title), ("description", description)):
        if v is not None and not isinstance(v, str):
            ck.bad(k, v, "must be a string")

    for k in ("scene", "sweep", "run"):
        if k in data and not isinstance(data[k], dict):
            ck.bad(k, data[k], f"must be a table ([{k}])")
    scene_t = data.get("scene", {}) if isinstance(data.get("scene", {}), dict) else {}
    sweep_t = data.get("sweep") if isinstance(data.get("sweep"), dict) else None
    run_t = data.get("run", {}) if isinstance(data.get("run", {}), dict) else {}

    scene, scene_keys, scene_params = _parse_scene(ck, scene_t)
    fixed = dict(scene_params)
    kind, grid, cases, labels = "cases", {}, [], None
    if sweep_t is None:
        if "sweep" not in data:
            ck.error("sweep", "missing: give [sweep] with grid = {...} or cases = [...]")
    else:
        kind, grid, cases, labels, sweep_fixed = _parse_sweep(ck, sweep_t)
        for k, v in sweep_fixed.items():
            if k in fixed:
                ck.error(f"sweep.fixed.{k}", f"also set as scene.{k}; give it once")
            fixed[k] = v
        swept = set(grid) | {k for c in cases for k in c}
        for k in sorted(swept):
            where = f"sweep.grid.{k}" if kind == "grid" else f"sweep.cases[*].{k}"
            if k in scene_params:
                ck.error(f"scene.{k}", f"conflicts with {where}: a parameter is either swept or fixed")
            elif k in sweep_fixed:
                ck.error(f"sweep.fixed.{k}", f"conflicts with {where}: a parameter is either swept or fixed")
            elif k in scene_keys:  # unit_mass: a scene field and a per-column parameter
                ck.error(f"scene.{k}", f"conflicts with {where}: a parameter is either swept or fixed")
        for k in fixed:
            if k in scene_keys:
                ck.error(f"sweep.fixed.{k}", f"also set as scene.{k}; give it once")

    if scene is not None:
        _check_profiles(ck, scene.n_prisms, fixed, grid, cases)
    run = _parse_run(ck, run_t)
    if ck.errors:
        raise SpecError(ck.errors, source)
    scene_obj = scene
    if run.pop("accuracy_resolved", False):
        # conservative: the pulse may cross the whole column
        run.update(for_accuracy(run["accuracy"], scene_obj.n_prisms))
    spec = SweepSpec(
        text=text,
        source=source,
        title=title,
        description=description,
        scene=scene_obj,
        scene_keys=scene_keys,
        fixed=fixed,
        kind=kind,
        grid=grid,
        cases=cases,
        labels=labels,
        run=run,
        data=data,
    )
    try:
        spec.run_settings()
    except OptionError as e:
        raise SpecError([f"run.{m}" for m in e.errors], source) from None
    return spec
