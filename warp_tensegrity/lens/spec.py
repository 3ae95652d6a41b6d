"""Lens specs: one TOML file for the whole design-by-computation job (``docs/lens.md``).

The lens has no options of its own here: every key is declared once, with its unit, bounds and doc,
in :mod:`warp_tensegrity.options_lens` (which takes the sweeps' declarations for what a lens shares
with them: v0, base rigidity, prestrain and the [run] keys), and ``[column.scene]`` holds the
[scene] options (:class:`~warp_tensegrity.scene.columns.ColumnConfig`). This module reads the tables
through those classes and checks what spans tables (the spacing against the column diameter, the
host's dimension against the layout, one plane of focal points for a line). An error names the key
path and the value (``array.spacing = -0.01: ...``), worded as a sweep's. Nothing here imports Warp.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..options import OptionError, Profile, RunSettings, build, unknown_key
from ..options_lens import (
    LENS_SECTIONS, SHAPE_FACTOR, LensArray, LensCalibration, LensDesign, LensHost, LensIncident, LensMap, LensRun,
)
from ..scene.columns import ColumnConfig
from ..scene.network import NetworkError
from ..tomlread import TomlError, read_file, read_toml

COLUMN_FIELDS = tuple(f.name for f in dataclasses.fields(ColumnConfig))


class LensSpecError(ValueError):
    """Invalid lens spec; the message lists each problem with its key path and value."""


@dataclass(frozen=True)
class Column:
    """``[column]`` as :class:`~warp_tensegrity.options_lens.LensColumn` validated it, and its scene."""

    scene: dict
    base_rigidity: float
    prestrain_shape: dict | None = None

    def config(self) -> ColumnConfig:
        return ColumnConfig(**self.scene)

    def shape_factors(self) -> np.ndarray | None:
        """(n_prisms,) factors of ``prestrain_shape`` along the column [1], or None (uniform columns)."""
        if self.prestrain_shape is None:
            return None
        prof = Profile.from_table("prestrain", self.prestrain_shape, OptionError, "column.prestrain_shape", SHAPE_FACTOR)
        return prof.check("prestrain", self.config().n_prisms, OptionError, "column.prestrain_shape", SHAPE_FACTOR)

    def prestrain(self, p) -> np.ndarray:
        """The columns' prestrain for levels ``p`` (B,): (B,), or (B, n_prisms) with a shape [1]."""
        f = self.shape_factors()
        p = np.asarray(p, dtype=np.float64)
        return p if f is None else p[:, None] * f[None, :]


@dataclass(frozen=True)
class LensSpec:
    """A whole lens job: calibrate, design, verify, re-target (its tables:
    :data:`~warp_tensegrity.options_lens.LENS_SECTIONS`)."""

    title: str
    description: str
    column: Column
    incident: LensIncident
    array: LensArray
    host: LensHost
    calibration: LensCalibration
    design: LensDesign
    map: LensMap
    run: LensRun

    def as_dict(self) -> dict:
        """Every key's validated value, by table (the output's ``spec_json``)."""
        out = {"title": self.title, "description": self.description}
        out.update({sec: dataclasses.asdict(getattr(self, sec)) for sec in LENS_SECTIONS if sec})
        return out


def _read(data: dict) -> tuple[dict, list[str]]:
    """The validated tables of ``data`` by section, and every problem found."""
    errors, tables = [], {}
    for key in data:
        if key not in LENS_SECTIONS and key not in LENS_SECTIONS[""].__pydantic_fields__:
            errors.append(unknown_key(str(key), key, [*LENS_SECTIONS[""].__pydantic_fields__, *list(LENS_SECTIONS)[1:]]))
    for sec, cls in LENS_SECTIONS.items():
        if sec == "":
            values = {k: data[k] for k in cls.__pydantic_fields__ if k in data}
        elif sec not in data:
            required = [f.name for f in dataclasses.fields(cls)
                        if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING]
            if required:
                errors.append(f"{sec}: required key is missing")
                continue
            values = {}
        elif not isinstance(data[sec], dict):
            errors.append(f"{sec}: must be a table ([{sec}])")
            continue
        else:
            values = data[sec]
        try:
            tables[sec] = build(cls, values, prefix=f"{sec}." if sec else "")
        except OptionError as e:
            errors += e.errors
    column = tables.get("column")
    if column is not None:
        unknown = [k for k in column.scene if k not in COLUMN_FIELDS]
        if unknown:
            errors.append(unknown_key(f"column.scene.{unknown[0]}", unknown[0], COLUMN_FIELDS))
        else:
            try:
                ColumnConfig(**column.scene)
            except (NetworkError, TypeError) as e:
                errors += [f"column.scene.{m}" for m in getattr(e, "errors", [str(e)])]
    return tables, errors


def _across(spec: LensSpec) -> list[str]:
    """The rules that span tables."""
    errors = []
    d = 2 * spec.column.config().radius
    if spec.array.spacing < d:
        errors.append(f"array.spacing = {spec.array.spacing!r}: must be >= the column diameter 2 * radius = {d!r} m")
    if spec.host.dimension == 2 and spec.array.layout != "line":
        errors.append("host.dimension = 2 (line sources along y) needs array.layout = 'line'")
    try:  # a grade along the columns: its factors, and the largest prestrain they make
        f = spec.column.shape_factors()
    except OptionError as e:
        errors += e.errors
        f = None
    if f is not None and spec.calibration.prestrain_max * f.max() >= 1.0:
        errors.append(f"column.prestrain_shape: the largest factor {f.max():g} x calibration.prestrain_max = "
                      f"{spec.calibration.prestrain_max!r} reaches a prestrain of {spec.calibration.prestrain_max * f.max():g}; "
                      "must stay < 1")
    ys = {p[1] for p in spec.design.focal_points}
    if spec.array.layout == "line" and len(ys) > 1:
        errors.append(f"design.focal_points: a line array focuses in one plane y = const; got y = {sorted(ys)} m")
    return errors


def parse_lens_spec(data: dict, source: str = "<spec>") -> LensSpec:
    """Validate the parsed TOML of a lens spec; LensSpecError lists every problem."""
    tables, errors = _read(data) if isinstance(data, dict) else ({}, ["the spec must be a table"])
    spec = None
    if not errors:
        text = tables[""]
        c = tables["column"]
        spec = LensSpec(title=text.title, description=text.description,
                        column=Column(scene=dict(c.scene), base_rigidity=c.base_rigidity,
                                      prestrain_shape=None if c.prestrain_shape is None else dict(c.prestrain_shape)),
                        **{k: v for k, v in tables.items() if k not in ("", "column")})
        errors = _across(spec)
    if errors:
        raise LensSpecError(f"invalid lens spec {source}:\n  - " + "\n  - ".join(errors))
    return spec


def load_lens_spec(path) -> LensSpec:
    """Read and validate a lens spec (TOML)."""
    path = Path(path)
    try:
        data = read_toml(read_file(path))
    except FileNotFoundError:
        raise LensSpecError(f"lens spec {str(path)!r} does not exist") from None
    except OSError as e:
        raise LensSpecError(f"lens spec {str(path)!r} cannot be read: {e.strerror or e}") from None
    except TomlError as e:
        raise LensSpecError(f"lens spec {str(path)!r}: {e.reason}") from None
    return parse_lens_spec(data, str(path))


def lens_settings(spec: LensSpec, device: str | None, **over):
    """The run settings of the lens's batches (the whole column recorded, never truncated)."""
    r = spec.run
    kw = dict(t_end=r.t_end, output_interval=r.output_interval, method=r.method, precision=r.precision,
              dt=r.dt, device=device or r.device, record_strain=True, truncate=False)
    kw.update(over)
    return RunSettings(**kw)
