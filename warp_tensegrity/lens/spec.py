"""Lens specs: one TOML file for the whole design-by-computation job (``docs/lens.md``).

Validated with pydantic v2 models. Each option is defined once, with its unit and bounds in the
field description; an error names the key path and the value (``array.spacing = -0.01: ...``).
Nothing here imports Warp.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from ..options import fmt
from ..scene.columns import ColumnConfig
from ..scene.network import NetworkError
from ..settings import METHODS, PRECISIONS
from ..tomlread import TomlError, read_toml

COLUMN_FIELDS = tuple(f.name for f in dataclasses.fields(ColumnConfig))


class LensSpecError(ValueError):
    """Invalid lens spec; the message lists each problem with its key path and value."""


class _Section(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class Column(_Section):
    """The one column design shared by every column of the array."""

    scene: dict[str, Any] = Field(
        default_factory=dict,
        description="ColumnConfig fields (n_prisms, radius [m], height [m], cable_modulus [N m-2], "
        "cable_radius [m], unit_mass [kg], handedness, ...); unset ones take the paper's values",
    )
    base_rigidity: float = Field(1.0, ge=0.0, le=1.0, description="base rigidity beta [1] in [0, 1] (0: FB, 1: RB)")

    @field_validator("scene")
    @classmethod
    def _scene(cls, v: dict) -> dict:
        unknown = [k for k in v if k not in COLUMN_FIELDS]
        if unknown:
            raise ValueError(f"unknown key {unknown[0]!r} (allowed: {', '.join(COLUMN_FIELDS)})")
        try:
            ColumnConfig(**v)
        except (NetworkError, TypeError) as e:
            raise ValueError(str(e)) from None
        return v

    def config(self) -> ColumnConfig:
        return ColumnConfig(**self.scene)


class Incident(_Section):
    """The shared incident impact: every column is struck with v0, at a delay d_i set by a plane
    incident wave (d_i = (x_i cos(azimuth) + y_i sin(azimuth)) sin(angle) / speed, shifted to
    start at 0); angle = 0 strikes every column at t = 0."""

    v0: float = Field(0.02, gt=0.0, le=10.0, description="compressive impact speed at the free end [m s-1], in (0, 10]")
    angle_deg: float = Field(0.0, ge=0.0, lt=90.0, description="incidence angle of the incident plane wave from the column axis [deg], in [0, 90)")
    azimuth_deg: float = Field(0.0, ge=-360.0, le=360.0, description="azimuth of the incidence plane from the x axis [deg]")
    speed: float = Field(math.inf, gt=0.0, description="speed of the incident wave along its direction [m s-1], > 0 (inf: normal incidence)")


class Array(_Section):
    """Column positions: exit faces in the plane z = 0, the host in z > 0."""

    layout: Literal["line", "grid"] = Field("line", description="'line' (columns along x) or 'grid' (nx x ny, for 3D focusing)")
    count: int | tuple[int, int] = Field(8, description="columns: n (line) or [nx, ny] (grid), each >= 2 and <= 4096")
    spacing: float = Field(0.012, gt=0.0, le=10.0, description="centre-to-centre distance of neighbouring columns [m], > 0 and >= the column diameter 2 * radius")

    @field_validator("count")
    @classmethod
    def _count(cls, v):
        for n in (v,) if isinstance(v, int) else v:
            if not 2 <= n <= 4096:
                raise ValueError("each count must lie in [2, 4096]")
        return v

    @model_validator(mode="after")
    def _layout(self):
        if self.layout == "grid" and isinstance(self.count, int):
            raise ValueError(f"array.count = {self.count!r}: a grid needs [nx, ny]")
        if self.layout == "line" and not isinstance(self.count, int):
            raise ValueError(f"array.count = {list(self.count)!r}: a line needs one number")
        return self

    @property
    def shape(self) -> tuple[int, int]:
        if isinstance(self.count, int):
            return (self.count, 1)
        return tuple(self.count)


class Host(_Section):
    """Homogeneous linear host behind the exit faces (coupling model: docs/lens.md)."""

    wave_speed: float = Field(0.1, gt=0.0, le=1e4, description="host wave speed c_h [m s-1], in (0, 1e4]")
    dimension: Literal[2, 3] = Field(2, description="2: cylindrical spreading 1/sqrt(r) (line array of line sources); 3: spherical 1/r")
    name: str = Field("", description="what physical host c_h represents (free text, copied to the output)")


class Calibration(_Section):
    """One batched run over the prestrain: exit time T(p), amplitude A(p), width W(p)."""

    prestrain_min: float = Field(0.0, ge=0.0, lt=1.0, description="smallest calibrated cross-cable prestrain p [1], in [0, 1)")
    prestrain_max: float = Field(0.15, gt=0.0, lt=1.0, description="largest calibrated prestrain [1], > prestrain_min and < 1")
    count: int = Field(1024, ge=8, le=1_048_576, description="calibration columns (prestrain values, evenly spaced) [1], in [8, 2^20]")

    @model_validator(mode="after")
    def _range(self):
        if self.prestrain_max <= self.prestrain_min:
            raise ValueError(f"prestrain_max = {self.prestrain_max!r} must exceed prestrain_min = {self.prestrain_min!r}")
        return self


class Design(_Section):
    """Focal points, in the order they are designed (the first is the primary one)."""

    focal_points: list[tuple[float, float, float]] = Field(
        ..., min_length=1, max_length=16,
        description="focal points [x, y, z] [m] in the host, z > 0; 1 to 16 of them; the first is the primary")

    @field_validator("focal_points")
    @classmethod
    def _points(cls, v):
        for i, (x, y, z) in enumerate(v):
            if not all(math.isfinite(c) for c in (x, y, z)) or z <= 0:
                raise ValueError(f"focal_points[{i}] = {[x, y, z]}: coordinates must be finite with z > 0 (in the host)")
        return v


class FocalMap(_Section):
    """The grid on which the host field's peak over time is mapped, centred on each focal point."""

    half_width: float = Field(0.05, gt=0.0, description="half extent of the map across the array (x, and y for a grid) [m], > 0")
    half_depth: float = Field(0.05, gt=0.0, description="half extent of the map along z [m], > 0 (clipped to z > 0)")
    points: int = Field(41, ge=5, le=401, description="grid points per map axis [1], in [5, 401]")


class Run(_Section):
    """How the columns are integrated (both the calibration and the verification batch)."""

    t_end: float = Field(..., gt=0.0, le=1e3, description="simulated time of the calibration run [s]: the slowest exit pulse must have passed")
    output_interval: float = Field(..., gt=0.0, description="time between recorded strain samples [s]; ~20 per exit-pulse duration or more")
    method: str = Field("rattle", description=f"integrator, one of {METHODS}")
    precision: str = Field("fp64", description=f"one of {PRECISIONS}")
    dt: float | Literal["auto"] = Field("auto", description="time step [s] or 'auto'; the verification reuses the calibration's dt")
    device: str | None = Field(None, description="Warp device ('cpu', 'cuda:0'); unset: the GPU if there is one")

    @field_validator("method")
    @classmethod
    def _method(cls, v):
        if v not in METHODS:
            raise ValueError(f"choose one of {METHODS}")
        return v

    @field_validator("precision")
    @classmethod
    def _precision(cls, v):
        if v not in PRECISIONS:
            raise ValueError(f"choose one of {PRECISIONS}")
        return v

    @field_validator("dt")
    @classmethod
    def _dt(cls, v):
        if v != "auto" and not (math.isfinite(v) and v > 0):
            raise ValueError("give a positive time step [s] or 'auto'")
        return v

    @model_validator(mode="after")
    def _interval(self):
        if self.output_interval > self.t_end / 10:
            raise ValueError(f"output_interval = {self.output_interval!r} s must be <= t_end / 10 = {self.t_end / 10!r} s")
        return self


class LensSpec(_Section):
    """A whole lens job: calibrate, design, verify, re-target."""

    title: str = Field("", description="short title (copied to the output)")
    description: str = Field("", description="free text (copied to the output)")
    column: Column = Field(default_factory=Column)
    incident: Incident = Field(default_factory=Incident)
    array: Array = Field(default_factory=Array)
    host: Host = Field(default_factory=Host)
    calibration: Calibration = Field(default_factory=Calibration)
    design: Design
    map: FocalMap = Field(default_factory=FocalMap)
    run: Run

    @model_validator(mode="after")
    def _fits(self):
        d = 2 * self.column.config().radius
        if self.array.spacing < d:
            raise ValueError(f"array.spacing = {self.array.spacing!r} m is below the column diameter 2 * radius = {d!r} m")
        if self.host.dimension == 2 and self.array.layout != "line":
            raise ValueError("host.dimension = 2 (line sources along y) needs array.layout = 'line'")
        ys = {p[1] for p in self.design.focal_points}
        if self.array.layout == "line" and len(ys) > 1:
            raise ValueError(f"design.focal_points: a line array focuses in one plane y = const; got y = {sorted(ys)} m")
        return self


def _format_error(err: dict, data: dict) -> str:
    loc = ".".join(str(p) for p in err["loc"] if p not in ("function-after",))
    msg = err["msg"].removeprefix("Value error, ")
    if err["type"] == "missing":
        return f"{loc}: required key is missing"
    if err["type"] == "extra_forbidden":
        return f"{loc}: unknown key"
    if not loc or msg.startswith(loc.split(".")[0] + "."):  # model-level check: its message names the keys
        return msg
    return f"{loc} = {fmt(err.get('input'))}: {msg}"


def parse_lens_spec(data: dict, source: str = "<spec>") -> LensSpec:
    try:
        return LensSpec.model_validate(data)
    except ValidationError as e:
        lines = [_format_error(err, data) for err in e.errors()]
        raise LensSpecError(f"invalid lens spec {source}:\n  - " + "\n  - ".join(lines)) from None


def load_lens_spec(path) -> LensSpec:
    """Read and validate a lens spec (TOML)."""
    path = Path(path)
    try:
        data = read_toml(path.read_bytes())
    except FileNotFoundError:
        raise LensSpecError(f"lens spec {str(path)!r} does not exist") from None
    except OSError as e:
        raise LensSpecError(f"lens spec {str(path)!r} cannot be read: {e.strerror or e}") from None
    except TomlError as e:
        raise LensSpecError(f"lens spec {str(path)!r}: {e.reason}") from None
    return parse_lens_spec(data, str(path))
