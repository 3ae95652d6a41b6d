"""Design by computation of a tunable-focus acoustic lens: an array of tensegrity columns, each
under its own prestrain, whose exit pulses meet at a focal point in a host medium
(Fabbrocino & Carpentieri 2017, Sec. 5 and Fig. 8; ``docs/lens.md``).

Modules: :mod:`.spec` (pydantic spec), :mod:`.host` (array geometry, Huygens superposition),
:mod:`.design` (monotone exit-time law and its inversion), :mod:`.run` (calibration and
verification batches), :mod:`.io` (CF netCDF), :mod:`.command` (``warp-tensegrity lens``).
Warp is imported only when a batch runs.
"""

from .design import CalibrationError, Design, ExitLaw, common_arrival, design_focus, fit_exit_law
from .host import column_positions, field, focal_map, map_grid, map_peak, peak_over_time, plane_wave_delays, spreading
from .spec import LensSpec, LensSpecError, load_lens_spec, parse_lens_spec

__all__ = [
    "CalibrationError",
    "Design",
    "ExitLaw",
    "LensSpec",
    "LensSpecError",
    "column_positions",
    "common_arrival",
    "design_focus",
    "field",
    "fit_exit_law",
    "focal_map",
    "load_lens_spec",
    "map_grid",
    "map_peak",
    "parse_lens_spec",
    "peak_over_time",
    "plane_wave_delays",
    "run_lens",
    "spreading",
]


def __getattr__(name):
    if name == "run_lens":
        from .run import run_lens

        return run_lens
    raise AttributeError(name)
