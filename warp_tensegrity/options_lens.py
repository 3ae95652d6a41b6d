"""Every option of a lens spec (``warp-tensegrity lens``, ``docs/lens.md``), declared once with the
:class:`~warp_tensegrity.options.Opt` of :mod:`warp_tensegrity.options`: name, type, default, unit,
bounds and doc, one options class per table.

What a lens shares with a sweep is not declared again: the impact speed, the base rigidity and the
prestrain take the :class:`~warp_tensegrity.options.ColumnParameters` declarations, the run keys
the :class:`~warp_tensegrity.options.RunSettings` ones, and ``[column.scene]`` holds the [scene]
options (:class:`~warp_tensegrity.scene.columns.ColumnConfig`). So a bound and its error are the
same in both (``v0 = 20000.0: must lie in [0, 10000] [m s-1]: ...``). :mod:`warp_tensegrity.lens.spec`
reads the tables through these classes; the docs table of ``docs/lens.md`` and ``init --example
lens`` are generated from them (:mod:`warp_tensegrity.options_docs`).

Of the package, this imports only :mod:`warp_tensegrity.options` (nor Warp).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Annotated

from .options import ColumnParameters, Opt, OptionError, RunSettings, SettingsError, opt_of, options_class

_V0, _BETA, _P = (opt_of(ColumnParameters, k) for k in ("v0", "base_rigidity", "prestrain"))
SHAPE_FACTOR = Opt("real", "1", gt=0, le=1e3)
"""Bounds of a lens's prestrain_shape factors."""


def _run(name: str, **change) -> Opt:
    return dataclasses.replace(opt_of(RunSettings, name), **change)


@options_class(OptionError, frozen=True)
class LensText:
    """The spec's top-level keys (besides its tables)."""

    title: Annotated[str, Opt("str")] = ""
    """Short title (copied to the output)."""
    description: Annotated[str, Opt("str")] = ""
    """Free text (copied to the output)."""


@options_class(OptionError, frozen=True)
class LensColumn:
    """The one column design shared by every column of the array."""

    scene: Annotated[dict, Opt("table", rule_text="a table of [scene] options", default_text="{}")] = \
        dataclasses.field(default_factory=dict)
    """The column's scene: ColumnConfig options (n_prisms, radius [m], height [m], cable_modulus
    [N m-2], cable_radius [m], unit_mass [kg], handedness, ...; see docs/options.md); unset ones take
    the paper's values."""
    base_rigidity: Annotated[float, _BETA] = 1.0
    """Base rigidity beta [1] of every column: 0 flexible bases (FB), 1 rigid bases (RB)."""
    prestrain_shape: Annotated[dict | None, Opt("table", optional=True, default_text="none (uniform columns)",
                                                rule_text="a profile table of factors in (0, 1000]")] = None
    """A grade along every column: factors, one per prism, that multiply the column's prestrain p
    along its length, as a profile table ({grade = [first, last]}, {segments = [first, last], at = k}
    or {values = [...]}, prism 0 at the clamped end). The calibration sweeps p with this shape and
    the design sets p per column: the array is graded across, the columns along. p x factor < 1."""


@options_class(OptionError, frozen=True)
class LensIncident:
    """The shared incident impact: every column is struck with v0, at a delay d_i set by a plane
    incident wave (d_i = (x_i cos(azimuth) + y_i sin(azimuth)) sin(angle) / speed, shifted to
    start at 0); angle = 0 strikes every column at t = 0."""

    v0: Annotated[float, _V0] = 0.02
    """Compressive impact speed at the free end [m s-1], > 0 (a lens needs an impact)."""
    angle_deg: Annotated[float, Opt("real", "degree", ge=0, lt=90)] = 0.0
    """Incidence angle of the incident plane wave from the column axis [degree]."""
    azimuth_deg: Annotated[float, Opt("real", "degree", ge=-360, le=360)] = 0.0
    """Azimuth of the incidence plane from the x axis [degree]."""
    speed: Annotated[float, Opt("real", "m s-1", gt=0, infinite=True)] = math.inf
    """Speed of the incident wave along its direction [m s-1] (inf: normal incidence)."""

    def __post_init__(self):
        if self.v0 == 0:
            raise OptionError(f"v0 = {self.v0!r}: must be > 0 [m s-1]: a lens needs an impact")


@options_class(OptionError, frozen=True)
class LensArray:
    """Column positions: exit faces in the plane z = 0, the host in z > 0."""

    layout: Annotated[str, Opt("choice", choices=("line", "grid"))] = "line"
    """'line' (columns along x) or 'grid' (nx x ny, x fastest, for 3D focusing)."""
    count: Annotated[int | tuple[int, int], Opt("int", "1", ge=2, le=4096, items=(2, 2), single=True,
                                                rule_text="n (line) or [nx, ny] (grid), each an integer in [2, 4096]")] = 8
    """Columns: n (line) or [nx, ny] (grid)."""
    spacing: Annotated[float, Opt("real", "m", gt=0, le=10)] = 0.012
    """Centre-to-centre distance of neighbouring columns [m], >= the column diameter 2 * radius."""

    def __post_init__(self):
        if self.layout == "grid" and isinstance(self.count, int):
            raise OptionError(f"count = {self.count!r}: a grid needs [nx, ny]")
        if self.layout == "line" and not isinstance(self.count, int):
            raise OptionError(f"count = {list(self.count)!r}: a line needs one number")

    @property
    def shape(self) -> tuple[int, int]:
        return (self.count, 1) if isinstance(self.count, int) else tuple(self.count)


@options_class(OptionError, frozen=True)
class LensHost:
    """Homogeneous linear host behind the exit faces (coupling model: docs/lens.md)."""

    wave_speed: Annotated[float, Opt("real", "m s-1", gt=0, le=1e4)] = 0.1
    """Host wave speed c_h [m s-1]."""
    dimension: Annotated[int, Opt("int", "1", ge=2, le=3)] = 2
    """2: cylindrical spreading 1/sqrt(r) (a line array of line sources; needs layout 'line'); 3: spherical 1/r."""
    name: Annotated[str, Opt("str")] = ""
    """What physical host c_h represents (free text, copied to the output)."""


@options_class(OptionError, frozen=True)
class LensCalibration:
    """One batched run over the prestrain: exit time T(p), amplitude A(p), width W(p)."""

    prestrain_min: Annotated[float, _P] = 0.0
    """Smallest calibrated cross-cable prestrain p [1]."""
    prestrain_max: Annotated[float, _P] = 0.15
    """Largest calibrated prestrain [1], > prestrain_min."""
    count: Annotated[int, Opt("int", "1", ge=8, le=1_048_576)] = 1024
    """Calibration columns (prestrain values, evenly spaced)."""

    def __post_init__(self):
        if self.prestrain_max <= self.prestrain_min:
            raise OptionError(f"prestrain_max = {self.prestrain_max!r}: must exceed prestrain_min = "
                              f"{self.prestrain_min!r}")


@options_class(OptionError, frozen=True)
class LensDesign:
    """Focal points, in the order they are designed (the first is the primary one)."""

    focal_points: Annotated[tuple, Opt("point", "m", items=(1, 16),
                                       rule_text="1 to 16 points [x, y, z] of finite numbers, z > 0")]
    """Focal points [x, y, z] in the host, z > 0 [m]; the first is the primary; a line array needs one y."""

    def __post_init__(self):
        for i, (x, y, z) in enumerate(self.focal_points):
            if z <= 0:
                raise OptionError(f"focal_points[{i}] = {[x, y, z]}: z must be > 0 (in the host)")


@options_class(OptionError, frozen=True)
class LensMap:
    """The grid on which the host field's peak over time is mapped, centred on each focal point."""

    half_width: Annotated[float, Opt("real", "m", gt=0)] = 0.05
    """Half extent of the map across the array (x, and y for a grid) [m]."""
    half_depth: Annotated[float, Opt("real", "m", gt=0)] = 0.05
    """Half extent of the map along z [m] (clipped to z > 0)."""
    points: Annotated[int, Opt("int", "1", ge=5, le=401)] = 41
    """Grid points per map axis."""


@options_class(OptionError, frozen=True)
class LensRun:
    """How the columns are integrated (the calibration and the verification batch); the keys and
    their bounds are the sweeps' [run] ones."""

    t_end: Annotated[float, opt_of(RunSettings, "t_end")]
    """Simulated time of the calibration run [s]: the slowest exit pulse must have passed."""
    output_interval: Annotated[float, _run("output_interval", optional=False, special=(), default_text=None)]
    """Time between recorded strain samples [s], <= t_end / 10; ~20 per exit-pulse duration or more."""
    method: Annotated[str, opt_of(RunSettings, "method")] = "rattle"
    """Integrator (as in sweeps)."""
    precision: Annotated[str, opt_of(RunSettings, "precision")] = "fp64"
    """Floating point of the state (as in sweeps)."""
    dt: Annotated[float | str, opt_of(RunSettings, "dt")] = "auto"
    """Time step [s] or 'auto'; the verification reuses the calibration's dt."""
    device: Annotated[str | None, opt_of(RunSettings, "device")] = None
    """Warp device ('cpu', 'cuda:0'); None ('auto'): the GPU if there is one."""

    def __post_init__(self):
        errors = []
        if self.output_interval > self.t_end / 10:
            errors.append(f"output_interval = {self.output_interval!r}: must be <= t_end / 10 = "
                          f"{self.t_end / 10!r} s")
        try:  # the sweeps' cross-key rules of [run] (dt <= t_end, ...)
            RunSettings(t_end=self.t_end, output_interval=self.output_interval, method=self.method,
                        precision=self.precision, dt=self.dt, device=self.device)
        except SettingsError as e:
            errors += [m for m in e.errors if not (errors and m.startswith("output_interval"))]
        if errors:
            raise OptionError(errors)


LENS_SECTIONS = {"": LensText, "column": LensColumn, "incident": LensIncident, "array": LensArray, "host": LensHost,
                 "calibration": LensCalibration, "design": LensDesign, "map": LensMap, "run": LensRun}
"""The lens spec's options classes by table ('' for the top-level keys), in the order of the docs."""
