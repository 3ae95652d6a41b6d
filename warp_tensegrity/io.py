"""Sweep results as CF-annotated xarray Datasets, written to netCDF4 (a sweep's shards are blocks
of one Zarr store, :mod:`warp_tensegrity.sweep.store`, exported to one file). The CLI (:mod:`warp_tensegrity.sweep`) and
:meth:`warp_tensegrity.BatchResult.to_xarray` build their datasets here, with one function
(:func:`batch_dataset`), so Python and CLI users share one format.

Layout (see ``docs/sweeps.md``):

* a full grid has one dimension per swept parameter, in spec order (first grid key first);
* an explicit case list has a ``case`` dimension; the swept parameters are auxiliary
  coordinate variables along ``case`` (CF: listed in each variable's ``coordinates``
  attribute, which xarray writes and reads), never a pandas MultiIndex;
* non-swept per-column parameters are scalar coordinates;
* ``prism`` (index from the clamped end) and ``t`` [s], the simulated time since impact, are
  the other dimensions.

CF (checked by ``compliance-checker --test cf:1.10`` in ``tests/test_cf.py``): every variable
has a ``long_name`` (a ``standard_name`` where the CF table has one: only ``status_flag`` does)
and ``units``. Simulated time is not a calendar time, so it is *not* a CF time coordinate
(which needs "seconds since <date>"): the axis is named ``t``, with units "s" and no
``axis``/``standard_name``, and xarray keeps it as plain float seconds.

Shards are always case-stacked (a contiguous block of columns ``case_start:case_stop``).
"""

from __future__ import annotations

import contextlib
import dataclasses
import errno
import json
import os
import time as _time
from pathlib import Path

import numpy as np
import xarray as xr

from . import atomic
from .measure.energy import ENERGY_SHARES, end_prisms, station_prism
from .policy.cost import netcdf_bytes
from .scene.impact import kinematic_lock_strain
from .options import COLUMN_PARAMETERS, PROFILE_FIELDS, PROFILED, ColumnParameters, opt_of
from .types import (BETA_LIMIT_FLAGS, ERROR_ESTIMATED, ERROR_FLAGS, FEASIBILITY_FLAGS, MEASUREMENT_FLAGS,
                    STATUS_MEANINGS, TIME, Layout)

PACKAGE_DIR = Path(__file__).resolve().parent

CONVENTIONS = "CF-1.10"
REFERENCES = (
    "F. Fabbrocino, G. Carpentieri, Three-dimensional modeling of the wave dynamics of tensegrity "
    "lattices, Composite Structures 173 (2017) 9-16"
)

RUN_DEPENDENT_ATTRS = ("history", "wall_time", "date_created", "command_line")
"""Global attributes that differ between two runs of the same spec (drop before comparing)."""


MEASUREMENTS = ("amplitude", "speed", "width", "width_10", "prisms_measured", "arrival_time", "max_compression")

PROVENANCE_ATTRS = ("package_version", "git_commit", "git_dirty", "warp_version", "device", "device_name",
                    "cuda_driver", "command_line")
"""Provenance every output carries (besides the full spec text in ``spec``)."""


def flag_attrs(long_name: str, names: dict, standard_name: str = "status_flag") -> dict:
    """CF flag-variable attributes (``flag_values``/``flag_meanings``) from {code: meaning};
    meanings become blank-free words. For int8 flag variables (status and NaN-reason flags)."""
    codes = sorted(names)
    words = " ".join(str(names[k]).replace(" ", "_").replace("-", "_") for k in codes)
    return {"standard_name": standard_name, "long_name": long_name,
            "flag_values": np.array(codes, dtype=np.int8), "flag_meanings": words}


COORD_ATTRS = {
    # the per-column parameters: units and long_name as declared, once, in options.ColumnParameters
    **{p: {"units": opt_of(ColumnParameters, p).unit, "long_name": opt_of(ColumnParameters, p).long_name}
       for p in COLUMN_PARAMETERS},
    "case": {"units": "1", "long_name": "column index in the sweep"},
    "case_label": {"long_name": "case label from the spec"},
    "prism": {
        "units": "1",
        "long_name": "prism index from the clamped base (0) to the impacted free end (n_prisms - 1)",
    },
    "level": {
        "units": "1",
        "long_name": "level (base) index from the clamped base (0) to the impacted free end (n_prisms)",
    },
    TIME: {"units": "s", "long_name": "simulated time since impact (step * dt, rounded to the output interval's decimals)"},
    "step": {"units": "1", "long_name": "time step count of each output (t = step * dt)"},
}

PROFILE_ATTRS = {
    f"{p}_{f}": {"units": "1" if f == "at" else opt_of(ColumnParameters, p).unit,
                 "long_name": {"from": f"{p} at the clamped base (grade) or of the first segment",
                               "to": f"{p} at the free end (grade) or of the second segment",
                               "at": f"interface of the {p} segments: index of the first {PROFILED[p]} of the second"}[f]}
    for p in PROFILED for f in PROFILE_FIELDS}
"""Grid axes over the generating parameters of a profile (``prestrain_at``)."""
COORD_ATTRS.update(PROFILE_ATTRS)

VAR_ATTRS = {
    "amplitude": {
        "units": "1",
        "long_name": "amplitude of the leading compression pulse (peak axial prism strain magnitude)",
    },
    "speed": {"units": "m s-1", "long_name": "propagation speed of the leading compression pulse"},
    "width": {"units": "1", "long_name": "full width at half maximum of the leading pulse, in prisms"},
    "width_10": {"units": "1", "long_name": "full width at 10% of maximum of the leading pulse, in prisms"},
    "prisms_measured": {
        "units": "1",
        "long_name": "prisms of the measurement window the leading pulse reached within t_end",
    },
    "max_compression": {
        "units": "1",
        "long_name": "largest prism compression -strain over the record",
        "comment": "the rigid-base kinematic lock (attribute kinematic_lock_compression) is where the pulse of "
                   "rigid bases saturates; beta_limit_flag says where the limit base_rigidity -> 1 may converge slowly "
                   "(docs/impact.md)",
    },
    "arrival_time": {"units": "s", "long_name": "arrival time of the leading pulse at each prism",
                     "comment": "NaN at the prisms the pulse had not reached by t_end, and on the clamp side of a "
                                "prism where something else crossed the threshold first (docs/measurements.md)"},
    "base_mode_ratio": {
        "units": "1",
        "long_name": "lowest base-member mode frequency over the top of the rigid-base band (omega_base_min / omega_RB)",
        "comment": "NaN at base_rigidity = 1 (no base modes); below 2 the base modes are within reach of the "
                   "rigid-base motion and the limit base_rigidity -> 1 may converge slowly (docs/impact.md)",
    },
    "beta_limit_flag": flag_attrs("how the limit base_rigidity -> 1 converges for this case: slow_convergence_possible "
                                  "where base_mode_ratio < 2 and max_compression >= half the kinematic lock "
                                  "(docs/impact.md)", dict(enumerate(BETA_LIMIT_FLAGS))),
    "measurement_flag": flag_attrs("why the pulse measures of the column are NaN or not to be trusted (ok: all "
                                   "defined and stable; docs/measurements.md)", dict(enumerate(MEASUREMENT_FLAGS))),
    "status": flag_attrs("column status at the end of the run", STATUS_MEANINGS),
    "error_flag": flag_attrs("whether the error estimates of the case's measures can be trusted: no_twin (no "
                             "estimate), twin_undefined (a measure defined, its twin's not), over_target (an estimate "
                             "above the accuracy target; docs/measurements.md)", dict(enumerate(ERROR_FLAGS))),
    "fail_step": {"units": "1", "long_name": "time step at which a failed column was frozen (-1: never failed)"},
    "time_step": {"units": "s", "long_name": "time step dt the case was stepped with (its run group's)"},
    "precision_used": flag_attrs("floating point the case's results came from: fp32, or fp64 where precision "
                                 "'auto' did not verify fp32 (docs/measurements.md)", {32: "fp32", 64: "fp64"}),
    "run_group": {"units": "1", "long_name": "run group of the case: columns of like stiffness stepped with one plan "
                  "(dt, steps, path; the dataset attribute run_groups describes each)"},
    "energy_error": {
        "units": "1",
        "long_name": "max relative energy drift max_t |E(t) - E(0)| / KE(0) over the outputs (a striker's kinetic "
                     "energy included in E and KE)",
    },
    "bar_length_error": {"units": "1", "long_name": "max relative bar-length error |l - L| / L over all steps and bars"},
    # the striker (scene impact = 'striker'; docs/impact.md)
    "striker_velocity": {"units": "m s-1", "long_name": "axial velocity of the striker (negative: toward the clamp)"},
    "striker_force": {"units": "N", "long_name": "contact force between striker and end base, mean over the time "
                      "step before the output (the striker's momentum change / dt; positive: pushing)"},
    "striker_separation_time": {"units": "s", "long_name": "simulated time at which the striker first left the "
                                "end base (start of the first step without contact force; NaN: never)"},
    "striker_last_separation_time": {"units": "s", "long_name": "simulated time at which the striker's last free "
                                     "flight began (NaN: touching the end base at t_end)"},
    "kinetic_energy": {"units": "J", "long_name": "kinetic energy of the column"},
    "elastic_energy": {"units": "J", "long_name": "elastic energy of all cables, prestress included, and the end "
                       "preload's potential -F0 . u (0 without a preload)"},
    "strain": {
        "units": "1",
        "long_name": "axial prism strain (h - hs) / h, negative in compression (hs: the prism's height at rest, "
                     "h0, or under an end preload its static height)",
    },
    # the energy measures (measure.energy; docs/measurements.md "Energy measures")
    "pulse_energy_share": {"units": "1", "long_name": "share of the impact energy the leading pulse carries through "
                           "the station prism's section over its passage",
                           "comment": "station: the dataset attribute energy_station (prism index from the clamp)"},
    "end_energy_share": {"units": "1", "long_name": "share of the impact energy left at t_end in the energy_end_prisms "
                         "prisms at the impacted end"},
    "station_energy": {"units": "J", "long_name": "energy above the reference state on the clamp side of the station "
                       "prism's section (the time integral of the energy flux through it)"},
    "end_energy": {"units": "J", "long_name": "energy above the reference state of the energy_end_prisms prisms at "
                   "the impacted end"},
    # the feasibility record (measure.feasibility; docs/model.md)
    "feasibility_flag": {
        "standard_name": "status_flag", "long_name": "how the column left the feasible set of the model (0: it stayed "
        "in it; several bits may be set; docs/model.md)",
        "flag_masks": np.array([1 << i for i in range(len(FEASIBILITY_FLAGS))], dtype=np.int8),
        "flag_meanings": " ".join(FEASIBILITY_FLAGS)},
    "feasibility_time": {"units": "s", "long_name": "simulated time of the first output at which the column was "
                         "outside the feasible set (NaN: never)"},
    **{f"feasibility_time_{r}": {"units": "s", "long_name": f"simulated time of the first output with {r} (NaN: never)"}
       for r in FEASIBILITY_FLAGS},
    "feasibility_prism": {"units": "1", "long_name": "prism (index from the clamped base) of the first output outside "
                          "the feasible set (-1: never)"},
    "twist_max": {"units": "rad", "long_name": "largest prism twist over the outputs (bars touch at pi)"},
    "twist_min": {"units": "rad", "long_name": "smallest prism twist over the outputs (the paper's bound: pi/3)"},
    "height_ratio_min": {"units": "1", "long_name": "smallest prism height over its reference h/h0 over the outputs "
                         "(inverted at 0)"},
    "member_distance_min": {"units": "m", "long_name": "smallest distance between two bar axes over the outputs"},
}
for _k in ERROR_ESTIMATED:  # <measure>_error: the measure's units, its estimate's method in docs/measurements.md
    VAR_ATTRS[f"{_k}_error"] = {"units": VAR_ATTRS[_k]["units"],
                                "long_name": f"estimated numerical error of {_k} (from a twin run at ~4x dt; "
                                             "docs/measurements.md)"}
FEASIBILITY_VARS = {"feasibility_flag": np.int8, "feasibility_time": np.float64, "feasibility_prism": np.int32,
                    "twist_max": np.float64, "twist_min": np.float64, "height_ratio_min": np.float64,
                    "member_distance_min": np.float64}
"""The per-case values of BatchResult.feasibility a dataset carries (those the result has), and their dtypes."""

_COMPRESS = {"zlib": True, "complevel": 1, "shuffle": True}

ENERGY_RECORDS = ("kinetic_energy", "elastic_energy", "station_energy", "end_energy")
"""The energy histories (case, t) a dataset stores; their storage is ``run.energy_precision`` and
``run.compress_energy`` (:func:`energy_dtypes`, :func:`_encoding`)."""


def energy_dtypes(energy_precision: str = "fp64") -> dict:
    """{energy history: numpy dtype it is stored in} for ``run.energy_precision`` ('auto': float32
    but the elastic energy, which carries the prestress energy; see options.RunSettings)."""
    if energy_precision == "fp64":
        return dict.fromkeys(ENERGY_RECORDS, np.float64)
    if energy_precision == "fp32":
        return dict.fromkeys(ENERGY_RECORDS, np.float32)
    return {**dict.fromkeys(ENERGY_RECORDS, np.float32), "elastic_energy": np.float64}


def _attr(v):
    """netCDF-storable attribute value."""
    if isinstance(v, (bool, np.bool_)):
        return int(v)
    if v is None:
        return "none"
    if isinstance(v, (dict, list, tuple)):
        return json.dumps(v)
    if isinstance(v, np.generic):
        return v.item()
    return v


def spec_attrs(layout: Layout) -> dict:
    """Global attributes that follow from the sweep's spec alone (its :class:`Layout`)."""
    r = layout.run
    a = {
        "Conventions": CONVENTIONS,
        "title": layout.title or f"warp_tensegrity sweep{f' {Path(layout.source).name}' if layout.source else ''}",
        "references": REFERENCES,
        "spec": layout.text,
        "spec_sha256": layout.text_sha256,
        "spec_file": Path(layout.source).name if layout.source else "none",
        "sweep_kind": layout.kind,
        "swept_parameters": " ".join(layout.swept),
        "n_columns": layout.n_columns,
        "method": r["method"],
        "precision": r["precision"],
        "dt_mode": "auto" if isinstance(r["dt"], str) else "explicit",
        "dt_safety": r["dt_safety"],
        "accuracy": "none" if r.get("accuracy") is None else r["accuracy"],
        "truncate": int(bool(r.get("truncate", True))),
        "allow_unstable_dt": r["allow_unstable_dt"],
        "t_end": r["t_end"],
        "record_strain": r["record_strain"],
        "record_energy": r["record_energy"],
        "energy_precision": r.get("energy_precision", "fp64"),
        "compress_energy": r.get("compress_energy", True),
        "energy_station": station_prism(layout.scene.n_prisms, r.get("energy_station")),
        "energy_end_prisms": end_prisms(layout.scene.n_prisms, r.get("energy_end_prisms", 5)),
    }
    if layout.description:
        a["comment"] = layout.description
    for f in dataclasses.fields(layout.scene):  # the ColumnConfig
        a[f"scene_{f.name}"] = getattr(layout.scene, f.name)
    a["scene_cable_EA"] = float(layout.scene.cable_EA)
    sc = layout.scene
    a["kinematic_lock_compression"] = -kinematic_lock_strain(sc.radius, sc.height, sc.twist)
    a["base_rigidity_law"] = ("base members: tension EA/(1-beta), compression beta*EA/(1-beta); beta = 1: rigid links; "
                              "continuous in beta, with the rigid_members impact the same initial state for every beta")
    a["base_rigidity_continuity"] = (
        "outputs converge as beta -> 0 (to FB) and as beta -> 1 (to RB), at the kinematic lock too: the rigid-base "
        "constraints keep full rank there. The difference to beta = 1 falls ~ (1 - beta) once the lowest base-member "
        "mode is above twice the rigid-base band (base_mode_ratio >= 2); before that it can stall over a decade of "
        "1 - beta for pulses near the lock (beta_limit_flag = slow_convergence_possible; docs/impact.md)")
    return {k: _attr(v) for k, v in a.items()}


# ---------------------------------------------------------------------- building
def _var(name: str, dims, data, attrs: dict) -> xr.Variable:
    return xr.Variable(dims, data, attrs=dict(attrs))


def _coords(layout: Layout, params: dict, start: int, stop: int, time: np.ndarray, n_prisms: int,
            steps: np.ndarray | None = None) -> dict:
    """Coordinates of columns ``start:stop`` of a sweep: swept parameters along ``case``, the others scalar."""
    coords = {
        "case": _var("case", "case", np.arange(start, stop, dtype=np.int64), COORD_ATTRS["case"]),
        "prism": _var("prism", "prism", np.arange(n_prisms, dtype=np.int32), COORD_ATTRS["prism"]),
        TIME: _var(TIME, TIME, np.asarray(time, dtype=np.float64), COORD_ATTRS[TIME]),
    }
    if steps is not None:  # exact: t = step * dt, rounded to the output interval's decimals
        coords["step"] = _var("step", TIME, np.asarray(steps, dtype=np.int64), COORD_ATTRS["step"])
    swept = layout.swept
    for p in COLUMN_PARAMETERS:
        if p == "striker_mass" and getattr(layout.scene, "impact", "velocity") != "striker":
            continue  # no striker, no striker mass
        if np.ndim(params[p]) == 2:  # a profile: per case where swept (itself, or a field of it), else one
            varies = p in swept or any(f"{p}_{f}" in swept for f in PROFILE_FIELDS)
            coords.update(profile_coords(p, np.asarray(params[p][start:stop], dtype=np.float64), per_case=varies))
        elif p in swept:
            coords[p] = _var(p, "case", np.asarray(params[p][start:stop], dtype=np.float64), COORD_ATTRS[p])
        else:
            coords[p] = _var(p, (), np.float64(layout.scalars[p]), COORD_ATTRS[p])
    axes = [k for k in layout.grid if k in PROFILE_ATTRS]
    if axes:  # a profile's generating parameters swept: along case, as the other grid axes
        index = np.unravel_index(np.arange(start, stop), layout.shape)
        for k in axes:
            i = list(layout.grid).index(k)
            coords[k] = _var(k, "case", np.asarray(layout.grid[k], dtype=np.float64)[index[i]], COORD_ATTRS[k])
    if layout.labels is not None:
        coords["case_label"] = _var("case_label", "case", np.array(layout.labels[start:stop], dtype=object),
                                    COORD_ATTRS["case_label"])
    return coords


def params_coords(params: dict, n_columns: int, time: np.ndarray, n_prisms: int | None,
                  steps: np.ndarray | None = None) -> dict:
    """Coordinates from per-column parameter arrays (a BatchResult's ``params``): a parameter
    that varies lies along ``case``, a constant one is a scalar coordinate (as in a sweep).
    ``n_prisms`` None: no ``prism`` coordinate (nothing per prism in the dataset)."""
    coords = {"case": _var("case", "case", np.arange(n_columns, dtype=np.int64), COORD_ATTRS["case"])}
    if n_prisms is not None:
        coords["prism"] = _var("prism", "prism", np.arange(n_prisms, dtype=np.int32), COORD_ATTRS["prism"])
    coords[TIME] = _var(TIME, TIME, np.asarray(time, dtype=np.float64), COORD_ATTRS[TIME])
    if steps is not None:
        coords["step"] = _var("step", TIME, np.asarray(steps, dtype=np.int64), COORD_ATTRS["step"])
    for p in COLUMN_PARAMETERS:
        if p not in params:
            continue
        if np.ndim(params[p]) == 2:  # a profile along the column
            coords.update(profile_coords(p, np.asarray(params[p], dtype=np.float64)))
            continue
        v = np.broadcast_to(np.asarray(params[p], dtype=np.float64), (n_columns,))
        if n_columns > 1 and np.any(v != v[0]):
            coords[p] = _var(p, "case", np.array(v), COORD_ATTRS[p])
        else:
            coords[p] = _var(p, (), np.float64(v[0]), COORD_ATTRS[p])
    return coords


def profile_coords(name: str, values: np.ndarray, per_case: bool | None = None) -> dict:
    """The coordinate of a profile along the column (:data:`~warp_tensegrity.options.PROFILED`):
    ``name`` over (prism) or (level) when every column has the same (``per_case`` None) or
    ``per_case`` is False, else over (case, prism) or (case, level); with the ``level`` coordinate."""
    along = PROFILED[name]
    v = np.atleast_2d(values)
    same = (v.shape[0] == 1 or bool(np.all(v == v[:1]))) if per_case is None else not per_case
    attrs = dict(COORD_ATTRS[name])
    attrs["long_name"] += f", per {along} along the column"
    out = {name: _var(name, (along,) if same else ("case", along), v[0].copy() if same else v, attrs)}
    if along == "level":
        out["level"] = _var("level", "level", np.arange(v.shape[1], dtype=np.int32), COORD_ATTRS["level"])
    return out


def batch_dataset(result, measurements: dict | None, coords: dict, attrs: dict,
                  record_energy: bool = True, record_strain: bool | None = None,
                  energy_precision: str = "fp64") -> xr.Dataset:
    """Case-stacked dataset of a BatchResult: measurements (if given), per-column status and
    errors, energy histories (``record_energy``, stored as ``energy_precision`` says:
    :func:`energy_dtypes`) and the strain history (``record_strain``; None: whenever the result
    has one). The one builder behind the CLI's files and :meth:`BatchResult.to_xarray`."""
    C = ("case",)
    dv = {}
    if measurements is not None:
        dv.update({k: (C, measurements[k]) for k in MEASUREMENTS if k != "arrival_time" and k in measurements})
        dv["arrival_time"] = (("case", "prism"), measurements["arrival_time"])
        for k in ERROR_ESTIMATED:
            if f"{k}_error" in measurements:
                e = np.asarray(measurements[f"{k}_error"], dtype=np.float64)
                dv[f"{k}_error"] = (("case", "prism") if e.ndim == 2 else C, e)
        if "error_flag" in measurements:
            dv["error_flag"] = (C, np.asarray(measurements["error_flag"], dtype=np.int8))
        if "measurement_flag" in measurements:
            dv["measurement_flag"] = (C, np.asarray(measurements["measurement_flag"], dtype=np.int8))
        dv.update({k: (C, np.asarray(measurements[k], dtype=np.float64)) for k in ENERGY_SHARES if k in measurements})
        if "base_mode_ratio" in measurements:
            dv["base_mode_ratio"] = (C, np.asarray(measurements["base_mode_ratio"], dtype=np.float64))
            dv["beta_limit_flag"] = (C, np.asarray(measurements["beta_limit_flag"], dtype=np.int8))
    dv.update({
        "status": (C, np.asarray(result.status, dtype=np.int8)),
        "fail_step": (C, np.asarray(result.fail_step, dtype=np.int64)),
        **({"time_step": (C, np.asarray(result.info["column_dt"], dtype=np.float64))} if "column_dt" in result.info else {}),
        **({"precision_used": (C, np.asarray(result.info["column_bits"], dtype=np.int8))}
           if "column_bits" in result.info else {}),
        **({"run_group": (C, np.asarray(result.info["column_group"], dtype=np.int8))}
           if "column_group" in result.info else {}),
        "energy_error": (C, np.asarray(result.energy_error, dtype=np.float64)),
        "bar_length_error": (C, np.asarray(result.bar_length_error, dtype=np.float64)),
    })
    feas = getattr(result, "feasibility", None)
    if feas is not None:
        dv.update({k: (C, np.asarray(feas[k], dtype=t)) for k, t in FEASIBILITY_VARS.items() if k in feas})
        for i, r in enumerate(FEASIBILITY_FLAGS if "feasibility_times" in feas else ()):
            dv[f"feasibility_time_{r}"] = (C, np.asarray(feas["feasibility_times"][:, i], dtype=np.float64))
    striker = result.info.get("striker") if isinstance(getattr(result, "info", None), dict) else None
    if striker is not None:
        dv["striker_separation_time"] = (C, np.asarray(striker["separation_time"], dtype=np.float64))
        dv["striker_last_separation_time"] = (C, np.asarray(striker["last_separation_time"], dtype=np.float64))
        dv["striker_velocity"] = (("case", TIME), np.asarray(striker["velocity"], dtype=np.float64))
        dv["striker_force"] = (("case", TIME), np.asarray(striker["force"], dtype=np.float64))
    if record_energy:
        dtype = energy_dtypes(energy_precision)
        for k in ENERGY_RECORDS:  # the energy-parts record (station, end) where the run has one
            if getattr(result, k, None) is not None:
                dv[k] = (("case", TIME), np.asarray(getattr(result, k), dtype=dtype[k]))
    if record_strain is None:
        record_strain = result.strain is not None
    if record_strain:
        if result.strain is None:
            raise ValueError("record_strain is set but the engine returned no strain")
        dv["strain"] = (("case", TIME, "prism"), np.asarray(result.strain, dtype=np.float64))
    data_vars = {
        k: xr.Variable(d, np.asarray(v, dtype=np.float64) if k in MEASUREMENTS else v, attrs=dict(VAR_ATTRS[k]))
        for k, (d, v) in dv.items()
    }
    for k in ERROR_ESTIMATED:  # CF: a measure names its error estimate and the estimate's flag
        if f"{k}_error" in data_vars and k in data_vars:
            data_vars[k].attrs["ancillary_variables"] = f"{k}_error error_flag"
    for k in ENERGY_RECORDS:
        if k in data_vars and data_vars[k].dtype == np.float32:
            data_vars[k].attrs["comment"] = ("computed in float64, stored as float32 (relative round-off 6e-8; "
                                             "run.energy_precision); every measure was taken before")
    ds = xr.Dataset(data_vars, coords=coords)
    ds.attrs = {k: _attr(v) for k, v in attrs.items()}
    return ds


def result_attrs(result) -> dict:
    """Run facts of a BatchResult that go into the global attributes."""
    a = {
        "device": result.device,
        "device_name": result.device_name,
        "method": result.method,
        "precision": result.precision,
        "dt": float(result.dt),
        "n_steps": int(result.n_steps),
        "output_interval": float(result.time[1] - result.time[0]) if len(result.time) > 1 else float("nan"),
        "wall_time": float(result.wall_time),
    }
    if "cuda_driver" in result.info:
        a["cuda_driver"] = result.info["cuda_driver"]
    return a


def result_dataset(result, config=None, measurements: dict | None = None, attrs: dict | None = None) -> xr.Dataset:
    """:meth:`BatchResult.to_xarray`: the case-stacked layout the CLI writes for a case list.
    ``config`` (the ColumnConfig) gives the scene attributes; ``measurements``: the per-column
    measures (:func:`warp_tensegrity.measure.nan_reasons.measure_columns`) or None. ``attrs``: the
    caller's provenance (:func:`warp_tensegrity.provenance.provenance_attrs`) and anything else."""
    if result.strain is not None:
        n_prisms = int(result.strain.shape[-1])
    elif measurements is not None:  # the record stayed on the device (record_strain = false)
        n_prisms = int(np.shape(measurements["arrival_time"])[-1])
    else:
        n_prisms = int(config.n_prisms) if config is not None else None
    attrs = dict(attrs or {})
    a = {"Conventions": CONVENTIONS, "title": "warp_tensegrity batch",
         "source": f"warp_tensegrity {attrs.get('package_version', 'unknown')} on NVIDIA Warp",
         "references": REFERENCES, "n_columns": result.n_columns, **result_attrs(result)}
    if config is not None:
        for f in dataclasses.fields(config):
            a[f"scene_{f.name}"] = getattr(config, f.name)
    a.update({k: result.info[k] for k in ("energy_station", "energy_end_prisms") if k in result.info})
    a["history"] = f"{_time.strftime('%Y-%m-%dT%H:%M:%S%z')} made by BatchResult.to_xarray"
    a.update(attrs)
    params = {k: v for k, v in result.params.items() if k != "striker_mass" or "striker" in result.info}
    coords = params_coords(params, result.n_columns, result.time, n_prisms, result.info.get("output_step"))
    ds = batch_dataset(result, measurements, coords, a, record_energy=result.kinetic_energy is not None)
    for k, enc in _coordinate_encoding(ds).items():  # ds.to_netcdf() stays CF-clean, as the CLI's files
        ds[k].encoding.update(enc)
    return ds


def shard_dataset(
    layout: Layout,
    params: dict,
    start: int,
    stop: int,
    result,
    measurements: dict,
    attrs: dict,
) -> xr.Dataset:
    """Case-stacked dataset of columns ``start:stop`` of a sweep (its :class:`Layout`: ``spec.layout()``)
    from a BatchResult and its measurements."""
    n = stop - start
    if result.n_columns != n:
        raise ValueError(f"batch has {result.n_columns} columns, shard {start}:{stop} needs {n}")
    coords = _coords(layout, params, start, stop, result.time, layout.scene.n_prisms, result.info.get("output_step"))
    return batch_dataset(result, measurements, coords, attrs, record_energy=layout.run["record_energy"],
                         record_strain=layout.run["record_strain"],
                         energy_precision=layout.run.get("energy_precision", "fp64"))


def _joined(values) -> str:
    seen = []
    for v in values:
        for part in str(v).split(", "):
            if part not in seen:
                seen.append(part)
    return ", ".join(seen)


def sweep_attrs(layout: Layout, shard_attrs: list[dict], history: str, extra_attrs: dict | None = None) -> dict:
    """Global attributes of a sweep's dataset: the spec's (its :class:`Layout`), the step settings of
    its first shard, the provenance of all its shards (joined), their summed wall time, and ``history`` (where
    ``{package_version}`` is filled in). ``extra_attrs`` (e.g. the exporting ``command_line``) wins."""
    attrs = spec_attrs(layout)
    a0 = shard_attrs[0]
    for k in ("code_version", "fingerprint", "dt", "dt_limit", "n_steps", "output_interval",
              "dt_safety_used", "accuracy_target", "run_groups"):
        if k not in a0:
            continue
        attrs[k] = a0[k]
    for k in ("warp_version", "git_commit", "device", "device_name", "cuda_driver", "package_version", "step_path"):
        attrs[k] = _joined(a.get(k, "unknown") for a in shard_attrs)
    attrs["git_dirty"] = int(any(int(a.get("git_dirty", 0)) for a in shard_attrs))
    attrs["source"] = f"warp_tensegrity {attrs['package_version']} on NVIDIA Warp"
    attrs["command_line"] = _joined(a.get("command_line", "unknown") for a in shard_attrs)
    attrs["wall_time"] = float(sum(float(a.get("wall_time", 0.0)) for a in shard_attrs))
    attrs["history"] = history.format(package_version=attrs["package_version"])
    if extra_attrs:
        attrs.update(extra_attrs)
    return {k: _attr(v) for k, v in attrs.items()}


def to_grid(layout: Layout, ds: xr.Dataset, split=None) -> xr.Dataset:
    """Unstack the case dimension into one dimension per grid axis of ``layout`` (C order). ``split(name,
    variable, grid_shape)`` gives the data of a variable whose first dimension is ``case`` in its
    new shape (default: ``variable.data.reshape``, lazy for dask arrays)."""
    shape = layout.shape
    names = tuple(layout.grid)
    variables = {}
    for k, v in ds.variables.items():
        if k == "case" or k in names:
            continue
        if "case" in v.dims:
            i = v.dims.index("case")
            dims = v.dims[:i] + names + v.dims[i + 1 :]
            if split is not None and i == 0:
                data = split(k, v, shape)
            else:
                data = v.data.reshape(v.shape[:i] + shape + v.shape[i + 1 :])
            variables[k] = xr.Variable(dims, data, attrs=dict(v.attrs))
        else:
            variables[k] = v
    coords = {n: xr.Variable((n,), np.asarray(layout.grid[n], dtype=np.float64), attrs=dict(COORD_ATTRS[n])) for n in names}
    coords.update({k: variables.pop(k) for k in list(variables) if k in ds.coords})
    return xr.Dataset({k: variables[k] for k in ds.data_vars}, coords=coords, attrs=dict(ds.attrs))


# ---------------------------------------------------------------------- files
def _coordinate_encoding(ds: xr.Dataset) -> dict:
    """CF: coordinates have no missing values, so no ``_FillValue`` (xarray gives floats NaN)."""
    return {k: {"_FillValue": None} for k in ds.coords if ds[k].dtype.kind == "f"}


def _encoding(ds: xr.Dataset) -> dict:
    """Compression of the records: zlib, but the energy histories only where the dataset's
    ``compress_energy`` attribute (a sweep's run.compress_energy; absent: 1) asks for it."""
    enc = {}
    energy = bool(int(ds.attrs.get("compress_energy", 1)))
    for k, v in ds.data_vars.items():
        if v.ndim >= 2 and v.size > 1024 and (energy or k not in ENERGY_RECORDS):
            enc[k] = dict(_COMPRESS)
    enc.update(_coordinate_encoding(ds))
    return enc


def write_netcdf(ds: xr.Dataset, path, fsync: bool = True) -> Path:
    """Write ``ds`` to ``path`` atomically (:func:`writing_netcdf`). Always engine='netcdf4'."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with writing_netcdf(path, netcdf_bytes(ds.nbytes), fsync) as tmp:
        ds.to_netcdf(tmp, engine="netcdf4", format="NETCDF4", encoding=_encoding(ds))
    return path


@contextlib.contextmanager
def writing_netcdf(path, need: int, fsync: bool = True):
    """Yields the name to write ``path``'s netCDF under: a file in a private directory beside it
    (:func:`warp_tensegrity.atomic.replacing`: never a name someone could plant a link at), moved
    onto ``path`` once the block ends. A failure is raised as an OSError naming ``path``, with its
    true cause: netCDF-C may report a full disk as 'NetCDF: HDF error' (a RuntimeError), or even
    as a PermissionError (issue 30); when the disk had less room left than the ``need`` bytes
    the file takes at most (:func:`warp_tensegrity.policy.cost.netcdf_bytes`) minus what it had
    written, it is ENOSPC, and the error carries ``need`` and ``free`` (bytes free once the partial
    file is gone: netCDF-C may keep it open until the process ends)."""
    path = Path(path)
    seen: dict = {}
    try:
        with atomic.replacing(path, fsync) as tmp:
            try:
                yield tmp
            except BaseException:
                seen["free"] = atomic.free_bytes(path)[0]  # before the partial file is removed
                seen["written"] = tmp.stat().st_blocks * 512 if tmp.exists() else 0  # on disk, not its length
                raise
    except (OSError, RuntimeError) as e:
        if isinstance(e, RuntimeError) and not str(e).startswith("NetCDF"):
            raise
        free, written = seen.get("free", atomic.free_bytes(path)[0]), seen.get("written", 0)
        why = (e.strerror or str(e)) if isinstance(e, OSError) else str(e)
        # a netCDF error (no errno) or EACCES while netCDF-C wrote: the free space tells a full disk
        unclear = "free" in seen and (isinstance(e, RuntimeError) or e.errno in (None, errno.EACCES))
        if atomic.is_no_space(e) or (unclear and free < need - written):
            err = OSError(errno.ENOSPC, os.strerror(errno.ENOSPC)
                          + ("" if atomic.is_no_space(e) else f" (netCDF said: {why})"), str(path))
            err.need, err.free = int(need), int(free + written)
            raise err from e
        if isinstance(e, OSError):
            raise OSError(e.errno, why, str(path)) from e
        raise OSError(None, why, str(path)) from e  # netCDF-C gave no errno


def open_sweep(path, load: bool = True) -> xr.Dataset:
    """Open a netCDF file this module wrote: a sweep's export, a lens output (engine netcdf4;
    seconds stay floats)."""
    ds = xr.open_dataset(path, engine="netcdf4", decode_timedelta=False)
    if load:
        with ds:
            ds = ds.load()
    return ds


def drop_run_dependent(ds: xr.Dataset, extra=()) -> xr.Dataset:
    """A copy without the attributes that differ between runs of one spec (for comparisons)."""
    out = ds.copy()
    out.attrs = {k: v for k, v in ds.attrs.items() if k not in RUN_DEPENDENT_ATTRS and k not in extra}
    return out
