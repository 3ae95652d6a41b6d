"""The lens job's CF netCDF: designed array (primary focal point), re-targeted focal points,
calibration curves, focal maps (``docs/lens.md`` lists every variable)."""

from __future__ import annotations

import json
import time as _time

import numpy as np
import xarray as xr

from .. import io as D
from ..provenance import provenance_attrs
from ..types import TIME
from .spec import LensSpec

CONVENTIONS = "CF-1.10"


def _v(dims, data, units, long_name, **extra):
    attrs = {"long_name": long_name, **extra}
    if units is not None:
        attrs["units"] = units
    return xr.Variable(dims, np.asarray(data), attrs)


def lens_dataset(spec: LensSpec, positions, delays, p_cal, m_cal, law, r_cal, r_ver, axes, foci, wall) -> xr.Dataset:
    x, y, z = axes
    f0 = foci[0]
    d0 = f0["design"]
    n_f = len(foci)
    stack = lambda key: np.stack([f[key] for f in foci])  # noqa: E731
    dstack = lambda key: np.stack([getattr(f["design"], key) for f in foci])  # noqa: E731
    impedance = spec.column.config().unit_mass * np.interp(
        dstack("prestrain"), p_cal[np.isfinite(m_cal["speed"])], m_cal["speed"][np.isfinite(m_cal["speed"])]
    ) / spec.column.config().height
    coords = {
        "column": _v("column", np.arange(len(positions)), "1", "column index in the array (x fastest)"),
        "focus": _v("focus", np.arange(n_f), "1", "focal point index (0: primary; others re-targeted by prestrain only)"),
        "calibration": _v("calibration", np.arange(len(p_cal)), "1", "calibration column index"),
        # the time since the strike in seconds, not a calendar time: named as the sweeps' ('t', no
        # standard_name 'time' nor axis T, which CF reserves for '<unit> since <epoch>')
        TIME: _v(TIME, r_ver.time, "s", "time since the column was struck"),
        # map axes in metres of the host, not latitude/longitude nor a vertical: no axis X/Y/Z, no positive
        # (CF 4.1, 4.2, 5.6; and 2.4, since a Z axis would ask y and x to be Y and X)
        "x": _v("x", x, "m", "focal map x (across the array)"),
        "y": _v("y", y, "m", "focal map y"),
        "z": _v("z", z, "m", "focal map z (depth into the host, from the exit faces)"),  # no `positive`: not a vertical
        "xyz": _v("xyz", np.arange(3), "1", "Cartesian component (0: x, 1: y, 2: z)"),
        "column_x": _v("column", positions[:, 0], "m", "x of the column's exit-face centre"),
        "column_y": _v("column", positions[:, 1], "m", "y of the column's exit-face centre"),
        "calibration_prestrain": _v("calibration", p_cal, "1", "cross-cable prestrain p of the calibration column"),
    }
    v = {
        # primary focal point, per column (the named variables)
        "prestrain": _v("column", d0.prestrain, "1", "designed cross-cable prestrain p (primary focal point)"),
        "exit_time": _v("column", f0["exit_time"], "s",
                        "simulated exit time: leading-peak time of the exit prism (parabola vertex), primary focal point"),
        "target_exit_time": _v("column", d0.target_exit_time, "s", "exit time that makes every pulse meet at the primary focal point"),
        "exit_amplitude": _v("column", f0["exit_amplitude"], "1", "peak compressive strain of the exit prism (leading pulse)"),
        "strike_delay": _v("column", delays, "s", "time at which the incident wave strikes the column"),
        "reachable": _v("column", d0.reachable.astype(np.int8), None, "1 if the target exit time lies in the calibrated range",
                        flag_values=np.array([0, 1], np.int8), flag_meanings="unreachable reachable"),
        "exit_signal": _v(("column", TIME), f0["signal"], "1", "compressive strain of the exit prism (host source signal), primary design"),
        "focal_map": _v(("z", "y", "x"), f0["map"], "1",
                        "peak over time of the host field (superposed exit signals, spreading included), primary design"),
        # every focal point
        "focal_point": _v(("focus", "xyz"), dstack("focal_point"), "m", "target focal point"),
        "peak_point": _v(("focus", "xyz"), stack("peak_point"), "m", "location of the focal map's maximum (sub-grid)"),
        "focus_error": _v("focus", stack("focus_error"), "m", "distance from the target focal point to the map's maximum"),
        "focal_gain": _v("focus", stack("focal_gain"), "1", "field peak at the focal point, designed / uniform prestrain array"),
        "ideal_ratio": _v("focus", stack("ideal_ratio"), "1", "field peak at the focal point, designed / exact target delays (own pulses)"),
        "exit_time_match": _v("focus", stack("exit_time_match"), "1",
                              "max |exit time - target| over reachable columns / spread of the targets"),
        "arrival_time": _v("focus", [f["design"].arrival_time for f in foci], "s", "common arrival time C at the focal point"),
        "uniform_prestrain": _v("focus", stack("uniform_prestrain"), "1", "prestrain of the uniform reference array (mean of the design)"),
        "focal_value": _v("focus", stack("focal_value"), "1", "field peak at the focal point, designed array"),
        "uniform_focal_value": _v("focus", stack("uniform_value"), "1", "field peak at the focal point, uniform array"),
        "ideal_focal_value": _v("focus", stack("ideal_value"), "1", "field peak at the focal point, exact target delays"),
        "prestrain_by_focus": _v(("focus", "column"), dstack("prestrain"), "1", "designed prestrain per focal point"),
        "target_exit_time_by_focus": _v(("focus", "column"), dstack("target_exit_time"), "s", "target exit time per focal point"),
        "exit_time_by_focus": _v(("focus", "column"), stack("exit_time"), "s", "simulated exit time per focal point"),
        "exit_amplitude_by_focus": _v(("focus", "column"), stack("exit_amplitude"), "1", "exit-prism peak strain per focal point"),
        "reachable_by_focus": _v(("focus", "column"), dstack("reachable").astype(np.int8), None, "1 if the target is in the calibrated range",
                                 flag_values=np.array([0, 1], np.int8), flag_meanings="unreachable reachable"),
        "column_impedance": _v(("focus", "column"), impedance, "N s m-1",
                               "column impedance unit_mass * speed / height (bounds the one-way coupling error, docs/lens.md)"),
        "status_by_focus": _v(("focus", "column"), stack("status").astype(np.int8), None, "engine status of the designed column",
                              flag_values=D.VAR_ATTRS["status"]["flag_values"],
                              flag_meanings=D.VAR_ATTRS["status"]["flag_meanings"]),
        "focal_map_by_focus": _v(("focus", "z", "y", "x"), stack("map"), "1", "peak over time of the host field, designed array"),
        "uniform_focal_map": _v(("focus", "z", "y", "x"), stack("uniform_map"), "1", "peak over time of the host field, uniform array"),
        "exit_signal_by_focus": _v(("focus", "column", TIME), stack("signal").astype(np.float32), "1",
                                   "compressive strain of the exit prism, designed array"),
        "uniform_exit_signal": _v(("focus", "column", TIME), stack("uniform_signal").astype(np.float32), "1",
                                  "compressive strain of the exit prism, uniform array"),
        # calibration curves
        "calibration_exit_time": _v("calibration", m_cal["exit_time"], "s", "calibrated exit time T(p)"),
        "calibration_exit_time_fit": _v("calibration", law.time(p_cal), "s", "monotone fit of T(p) used for the inversion"),
        "calibration_exit_amplitude": _v("calibration", m_cal["exit_amplitude"], "1", "calibrated exit-prism peak strain"),
        "calibration_amplitude": _v("calibration", m_cal["amplitude"], "1", "calibrated leading-pulse amplitude A(p) (sweeps' measure)"),
        "calibration_width": _v("calibration", m_cal["width"], "1", "calibrated leading-pulse FWHM W(p), in prisms (sweeps' measure)"),
        "calibration_speed": _v("calibration", m_cal["speed"], "m s-1", "calibrated time-of-flight pulse speed (sweeps' measure)"),
    }
    s0 = spec
    attrs = {
        "Conventions": CONVENTIONS,
        "title": s0.title or "tensegrity acoustic lens",
        "institution": "warp_tensegrity",
        "source": "warp_tensegrity.lens: batched column simulation (NVIDIA Warp) + one-way Huygens host superposition",
        "references": D.REFERENCES,
        "history": f"{_time.strftime('%Y-%m-%dT%H:%M:%S%z')} warp-tensegrity lens",
        "focus_error_m": float(f0["focus_error"]),
        "focal_gain": float(f0["focal_gain"]),
        "ideal_ratio": float(f0["ideal_ratio"]),
        "exit_time_match": float(f0["exit_time_match"]),
        "column_spacing_m": float(s0.array.spacing),
        "host_wave_speed_m_s": float(s0.host.wave_speed),
        "host_dimension": int(s0.host.dimension),
        "host_name": s0.host.name,
        "calibration_exit_time_range_s": [float(t) for t in law.t_range],
        "calibration_fit_rms_s": float(law.rms_residual),
        "calibration_undefined": int(law.dropped),
        "incident_v0_m_s": float(s0.incident.v0),
        "base_rigidity": float(s0.column.base_rigidity),
        "spec_json": json.dumps(s0.as_dict(), sort_keys=True, default=str),
        "device": r_ver.device,
        "device_name": r_ver.device_name,
        "method": r_ver.method,
        "precision": r_ver.precision,
        "dt": float(r_ver.dt),
        "calibration_wall_time": float(r_cal.wall_time),
        "verification_wall_time": float(r_ver.wall_time),
        "wall_time": float(wall),
        **provenance_attrs(),  # package version, commit, dirty flag, Warp version, command line
    }
    if s0.description:  # CF: a comment, where there is one, is a non-empty string
        attrs["comment"] = s0.description
    shape = spec.column.shape_factors()
    if shape is not None:  # graded along the columns: prism i's prestrain is p x its factor
        coords["prism"] = _v("prism", np.arange(shape.size), "1", D.COORD_ATTRS["prism"]["long_name"])
        v["prestrain_shape"] = _v("prism", shape, "1", "factor multiplying each column's prestrain p along its "
                                                       "length (column.prestrain_shape)")
    return xr.Dataset(v, coords=coords, attrs=attrs)


def write_lens(ds: xr.Dataset, path):
    """Write atomically (netCDF4, compressed; :func:`warp_tensegrity.io.write_netcdf`: never through a
    link, a full disk raised as an OSError naming the path with ENOSPC)."""
    return D.write_netcdf(ds, path)
