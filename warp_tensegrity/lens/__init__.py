"""Design by computation of a tunable-focus acoustic lens: an array of tensegrity columns, each
under its own prestrain, whose exit pulses meet at a focal point in a host medium
(Fabbrocino & Carpentieri 2017, Sec. 5 and Fig. 8; ``docs/lens.md``).

Modules: :mod:`.spec` (pydantic spec), :mod:`.host` (array geometry, Huygens superposition),
:mod:`.design` (monotone exit-time law and its inversion), :mod:`.run` (calibration and
verification batches), :mod:`.io` (CF netCDF), :mod:`.command` (``warp-tensegrity lens``).
Warp is imported only when a batch runs.
"""

from .host import (
    column_positions,
    field,
    focal_map,
    map_grid,
    map_peak,
    peak_over_time,
    plane_wave_delays,
    spreading,
)
from .spec import LensSpec, LensSpecError, load_lens_spec, parse_lens_spec

_DESIGN = ("CalibrationError", "Design", "ExitLaw", "common_arrival", "design_focus", "fit_exit_law")

__all__ = sorted(_DESIGN + ("column_positions", "field", "focal_map", "map_grid", "map_peak", "peak_over_time",
                            "plane_wave_delays", "spreading", "LensSpec", "LensSpecError", "load_lens_spec",
                            "parse_lens_spec", "run_lens"))


def __getattr__(name):
    # lazy: the CLI imports lens.command at start-up; design and run load SciPy (run: xarray, Warp at a batch)
    if name in _DESIGN:
        from . import design as mod  # imports SciPy: not at `--help`
    elif name == "run_lens":
        from . import run as mod  # imports SciPy and xarray: not at `--help`
    else:
        raise AttributeError(name)
    return getattr(mod, name)
