"""Sweep results as CF-annotated xarray Datasets, written to netCDF4 (one file per shard, one
combined file per sweep).

Layout (see ``docs/sweeps.md``):

* a full grid has one dimension per swept parameter, in spec order (first grid key first);
* an explicit case list has a ``case`` dimension; the swept parameters are auxiliary
  coordinate variables along ``case`` (CF: listed in each variable's ``coordinates``
  attribute, which xarray writes and reads), never a pandas MultiIndex;
* non-swept per-column parameters are scalar coordinates;
* ``prism`` (index from the clamped end) and ``time`` [s] are the other dimensions.

Shards are always case-stacked (a contiguous block of columns ``case_start:case_stop``).
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
import os
import subprocess
import time as _time
import tomllib
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import xarray as xr

from .measure.nan_reasons import FLAG_MEANINGS, FLAG_VALUES
from .scene.columns import ColumnConfig
from .scene.impact import kinematic_lock_strain
from .settings import COLUMN_PARAMETERS, STATUS_NAMES

if TYPE_CHECKING:
    from .sweep.spec import SweepSpec

PACKAGE_DIR = Path(__file__).resolve().parent
SCENE_FIELDS = tuple(f.name for f in dataclasses.fields(ColumnConfig))

CONVENTIONS = "CF-1.10"
REFERENCES = (
    "F. Fabbrocino, G. Carpentieri, Three-dimensional modeling of the wave dynamics of tensegrity "
    "lattices, Composite Structures 173 (2017) 9-16"
)

RUN_DEPENDENT_ATTRS = ("history", "wall_time", "date_created")
"""Global attributes that differ between two runs of the same spec (drop before comparing)."""


MEASUREMENTS = ("amplitude", "speed", "width", "width_10", "prisms_measured", "arrival_time", "max_compression")

STATUS_MEANINGS = " ".join(STATUS_NAMES[k].replace(" ", "_").replace("-", "_") for k in sorted(STATUS_NAMES))

COORD_ATTRS = {
    "prestrain": {"units": "1", "long_name": "cross-cable prestrain p"},
    "v0": {"units": "m s-1", "long_name": "compressive impact speed at the free end"},
    "base_rigidity": {"units": "1", "long_name": "base rigidity (0: flexible bases FB, 1: rigid bases RB)"},
    "cable_EA": {"units": "N", "long_name": "axial stiffness E*A of the cables"},
    "unit_mass": {"units": "kg", "long_name": "mass per unit (prism), lumped on the bases"},
    "case": {"units": "1", "long_name": "column index in the sweep"},
    "case_label": {"long_name": "case label from the spec"},
    "prism": {
        "units": "1",
        "long_name": "prism index from the clamped base (0) to the impacted free end (n_prisms - 1)",
        "axis": "X",
    },
    "time": {"units": "s", "long_name": "time since impact (step * dt, rounded to the output interval's decimals)",
             "axis": "T"},
    "step": {"units": "1", "long_name": "time step count of each output (time = step * dt)"},
}

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
        "comment": "at or above the rigid-base kinematic lock (attribute kinematic_lock_compression) the limit "
                   "base_rigidity -> 1 is singular: rigid bases (1) are then not the limit of stiff ones (docs/impact.md)",
    },
    "arrival_time": {"units": "s", "long_name": "arrival time of the leading pulse at each prism",
                     "comment": "NaN at the prisms the pulse had not reached by t_end"},
    "measurement_flag": {
        "long_name": "why the pulse measures of the column are NaN (ok: all defined; docs/measurements.md)",
        "flag_values": FLAG_VALUES,
        "flag_meanings": FLAG_MEANINGS,
    },
    "status": {
        "long_name": "column status at the end of the run",
        "flag_values": np.array(sorted(STATUS_NAMES), dtype=np.int8),
        "flag_meanings": STATUS_MEANINGS,
    },
    "fail_step": {"units": "1", "long_name": "time step at which a failed column was frozen (-1: never failed)"},
    "energy_error": {
        "units": "1",
        "long_name": "max relative energy drift max_t |E(t) - E(0)| / KE(0) over the outputs",
    },
    "bar_length_error": {"units": "1", "long_name": "max relative bar-length error |l - L| / L over all steps and bars"},
    "kinetic_energy": {"units": "J", "long_name": "kinetic energy of the column"},
    "elastic_energy": {"units": "J", "long_name": "elastic energy of all cables, prestress included"},
    "strain": {
        "units": "1",
        "long_name": "axial prism strain (h - h0) / h, negative in compression",
    },
}

_COMPRESS = {"zlib": True, "complevel": 1, "shuffle": True}


# ---------------------------------------------------------------------- provenance
@functools.lru_cache(maxsize=1)
def package_version() -> str:
    try:
        from importlib.metadata import PackageNotFoundError, version

        try:
            return version("warp_tensegrity")
        except PackageNotFoundError:
            pass
    except ImportError:  # pragma: no cover
        pass
    pyproject = PACKAGE_DIR.parent / "pyproject.toml"
    try:
        return str(tomllib.loads(pyproject.read_text())["project"]["version"])
    except Exception:
        return "unknown"


def source_hash() -> str:
    """sha256 over the package's .py sources (relative path and content, sorted by path)."""
    h = hashlib.sha256()
    for p in sorted(PACKAGE_DIR.rglob("*.py")):
        if "__pycache__" in p.parts:
            continue
        h.update(p.relative_to(PACKAGE_DIR).as_posix().encode() + b"\0")
        h.update(p.read_bytes() + b"\0")
    return h.hexdigest()


def code_version() -> str:
    """Package version + hash of the package's .py sources, e.g. '0.1.0+src.1a2b3c4d5e6f7a8b'."""
    return f"{package_version()}+src.{source_hash()[:16]}"



def git_commit() -> str:
    """The checkout's commit, or $GIT_COMMIT where there is no usable .git (copied trees)."""
    env = os.environ.get("GIT_COMMIT")
    if env:
        return env
    try:
        out = subprocess.run(
            ["git", "rev-parse", "HEAD"],
            cwd=Path(__file__).resolve().parent,
            capture_output=True,
            text=True,
            timeout=10,
        )
        return out.stdout.strip() if out.returncode == 0 and out.stdout.strip() else "unknown"
    except (OSError, subprocess.SubprocessError):
        return "unknown"


@functools.lru_cache(maxsize=1)
def warp_version() -> str:
    try:
        import warp

        return str(warp.config.version)
    except Exception:  # pragma: no cover - warp is a hard dependency
        return "unknown"


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


def spec_attrs(spec: SweepSpec) -> dict:
    """Global attributes that follow from the spec alone."""
    r = spec.run
    a = {
        "Conventions": CONVENTIONS,
        "title": spec.title or f"warp_tensegrity sweep{f' {Path(spec.source).name}' if spec.source else ''}",
        "source": f"warp_tensegrity {package_version()} on NVIDIA Warp",
        "references": REFERENCES,
        "spec": spec.text,
        "spec_sha256": spec.text_sha256,
        "spec_file": Path(spec.source).name if spec.source else "none",
        "sweep_kind": spec.kind,
        "swept_parameters": " ".join(spec.swept),
        "n_columns": spec.n_columns,
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
    }
    if spec.description:
        a["comment"] = spec.description
    for f in SCENE_FIELDS:
        a[f"scene_{f}"] = getattr(spec.scene, f)
    a["scene_cable_EA"] = float(spec.scene.cable_EA)
    sc = spec.scene
    a["kinematic_lock_compression"] = -kinematic_lock_strain(sc.radius, sc.height, sc.twist)
    a["base_rigidity_law"] = ("base members: tension EA/(1-beta), compression beta*EA/(1-beta); beta = 1: rigid links; "
                              "continuous in beta, with the rigid_members impact the same initial state for every beta")
    a["base_rigidity_continuity"] = (
        "outputs converge as beta -> 0 (to FB) and, while max_compression stays below kinematic_lock_compression, as "
        "beta -> 1 (difference ~ 1 - beta); pulses that reach the lock make beta -> 1 singular (stiff base modes "
        "take energy at the locked prisms), so beta = 1 is a separate model there: compare it with beta < 1 only "
        "where max_compression < kinematic_lock_compression (docs/impact.md)")
    return {k: _attr(v) for k, v in a.items()}


# ---------------------------------------------------------------------- building
def _coords(spec: SweepSpec, params: dict, start: int, stop: int, time: np.ndarray, n_prisms: int,
            steps: np.ndarray | None = None) -> dict:
    coords = {
        "case": ("case", np.arange(start, stop, dtype=np.int64), COORD_ATTRS["case"]),
        "prism": ("prism", np.arange(n_prisms, dtype=np.int32), COORD_ATTRS["prism"]),
        "time": ("time", np.asarray(time, dtype=np.float64), COORD_ATTRS["time"]),
    }
    if steps is not None:  # exact: time = step * dt, rounded to the output interval's decimals
        coords["step"] = ("time", np.asarray(steps, dtype=np.int64), COORD_ATTRS["step"])
    swept = spec.swept
    for p in COLUMN_PARAMETERS:
        if p in swept:
            coords[p] = ("case", np.asarray(params[p][start:stop], dtype=np.float64), COORD_ATTRS[p])
        else:
            coords[p] = ((), np.float64(spec.default_param(p)), COORD_ATTRS[p])
    if spec.labels is not None:
        coords["case_label"] = ("case", np.array(spec.labels[start:stop], dtype=object), COORD_ATTRS["case_label"])
    return {k: xr.Variable(d, v, attrs=dict(a)) for k, (d, v, a) in coords.items()}


def shard_dataset(
    spec: SweepSpec,
    params: dict,
    start: int,
    stop: int,
    result,
    measurements: dict,
    attrs: dict,
) -> xr.Dataset:
    """Case-stacked dataset of columns ``start:stop`` from a BatchResult and its measurements."""
    n = stop - start
    if result.n_columns != n:
        raise ValueError(f"batch has {result.n_columns} columns, shard {start}:{stop} needs {n}")
    n_prisms = spec.scene.n_prisms
    C = ("case",)
    dv = {
        "amplitude": (C, measurements["amplitude"]),
        "speed": (C, measurements["speed"]),
        "width": (C, measurements["width"]),
        "width_10": (C, measurements["width_10"]),
        "prisms_measured": (C, measurements["prisms_measured"]),
        "arrival_time": (("case", "prism"), measurements["arrival_time"]),
        "status": (C, np.asarray(result.status, dtype=np.int8)),
        "fail_step": (C, np.asarray(result.fail_step, dtype=np.int64)),
        "energy_error": (C, np.asarray(result.energy_error, dtype=np.float64)),
        "bar_length_error": (C, np.asarray(result.bar_length_error, dtype=np.float64)),
    }
    for k, dtype in (("max_compression", np.float64), ("measurement_flag", np.int8)):  # sweep.measure_columns
        if k in measurements:
            dv[k] = (C, np.asarray(measurements[k], dtype=dtype))
    if spec.run["record_energy"]:
        dv["kinetic_energy"] = (("case", "time"), np.asarray(result.kinetic_energy, dtype=np.float64))
        dv["elastic_energy"] = (("case", "time"), np.asarray(result.elastic_energy, dtype=np.float64))
    if spec.run["record_strain"]:
        if result.strain is None:
            raise ValueError("record_strain is set but the engine returned no strain")
        dv["strain"] = (("case", "time", "prism"), np.asarray(result.strain, dtype=np.float64))
    data_vars = {
        k: xr.Variable(d, np.asarray(v, dtype=np.float64) if k in MEASUREMENTS else v, attrs=dict(VAR_ATTRS[k]))
        for k, (d, v) in dv.items()
    }
    ds = xr.Dataset(data_vars, coords=_coords(spec, params, start, stop, result.time, n_prisms,
                                              result.info.get("output_step")))
    ds.attrs = {k: _attr(v) for k, v in attrs.items()}
    return ds


def _joined(values) -> str:
    seen = []
    for v in values:
        for part in str(v).split(", "):
            if part not in seen:
                seen.append(part)
    return ", ".join(seen)


def combine_shards(spec: SweepSpec, shards: list[xr.Dataset], extra_attrs: dict | None = None) -> xr.Dataset:
    """The sweep's dataset from its loaded shard datasets (in shard order, covering every column)."""
    if not shards:
        raise ValueError("no shards to combine")
    shards = sorted(shards, key=lambda d: int(d.attrs["case_start"]))
    pos = 0
    for d in shards:
        if int(d.attrs["case_start"]) != pos:
            raise ValueError(f"shards do not tile the sweep: expected case_start {pos}, got {d.attrs['case_start']}")
        pos = int(d.attrs["case_stop"])
    if pos != spec.n_columns:
        raise ValueError(f"shards cover {pos} of {spec.n_columns} columns")
    first = shards[0]
    for d in shards[1:]:
        for c in ("time", "prism"):
            if not np.array_equal(d[c].values, first[c].values):
                raise ValueError(f"shard {d.attrs['shard_index']} has a different {c} coordinate")
        for k in ("dt", "n_steps", "fingerprint"):
            if d.attrs.get(k) != first.attrs.get(k):
                raise ValueError(
                    f"shard {d.attrs['shard_index']} has {k} = {d.attrs.get(k)!r}, shard 0 {first.attrs.get(k)!r}"
                )
    case_vars = [k for k in first.variables if "case" in first[k].dims]
    merged = {}
    for k in case_vars:
        v = first.variables[k]
        data = np.concatenate([d.variables[k].values for d in shards], axis=v.dims.index("case"))
        merged[k] = xr.Variable(v.dims, data, attrs=dict(v.attrs))
    for k in first.variables:
        if k not in merged:
            merged[k] = first.variables[k].copy(deep=True)
    coord_names = set(first.coords)
    ds = xr.Dataset(
        {k: merged[k] for k in first.data_vars},
        coords={k: merged[k] for k in first.coords},
    )
    assert set(ds.coords) == coord_names

    attrs = spec_attrs(spec)
    a0 = first.attrs
    for k in ("package_version", "code_version", "fingerprint", "dt", "dt_limit", "n_steps", "output_interval",
              "dt_safety_used", "accuracy_target"):
        if k not in a0:
            continue
        attrs[k] = a0[k]
    for k in ("warp_version", "git_commit", "device", "device_name", "step_path"):
        attrs[k] = _joined(d.attrs.get(k, "unknown") for d in shards)
    attrs["wall_time"] = float(sum(float(d.attrs.get("wall_time", 0.0)) for d in shards))
    attrs["history"] = f"{_time.strftime('%Y-%m-%dT%H:%M:%S%z')} combined {len(shards)} shards by warp_tensegrity {package_version()}"
    if extra_attrs:
        attrs.update(extra_attrs)
    ds.attrs = {k: _attr(v) for k, v in attrs.items()}
    if spec.kind == "grid":
        ds = _to_grid(spec, ds)
    return ds


def _to_grid(spec: SweepSpec, ds: xr.Dataset) -> xr.Dataset:
    """Unstack the case dimension into one dimension per grid axis (C order)."""
    shape = spec.shape
    names = tuple(spec.grid)
    variables = {}
    for k, v in ds.variables.items():
        if k == "case" or k in names:
            continue
        if "case" in v.dims:
            i = v.dims.index("case")
            dims = v.dims[:i] + names + v.dims[i + 1 :]
            data = v.values.reshape(v.shape[:i] + shape + v.shape[i + 1 :])
            variables[k] = xr.Variable(dims, data, attrs=dict(v.attrs))
        else:
            variables[k] = v
    coords = {n: xr.Variable((n,), np.asarray(spec.grid[n], dtype=np.float64), attrs=dict(COORD_ATTRS[n])) for n in names}
    coords.update({k: variables.pop(k) for k in list(variables) if k in ds.coords})
    out = xr.Dataset({k: variables[k] for k in ds.data_vars}, coords=coords, attrs=dict(ds.attrs))
    return out


# ---------------------------------------------------------------------- files
def _encoding(ds: xr.Dataset) -> dict:
    enc = {}
    for k, v in ds.data_vars.items():
        if v.ndim >= 2 and v.size > 1024:
            enc[k] = dict(_COMPRESS)
    for k in ds.coords:  # CF: coordinates have no missing values
        if ds[k].dtype.kind == "f":
            enc[k] = {"_FillValue": None}
    return enc


def write_netcdf(ds: xr.Dataset, path, fsync: bool = True) -> Path:
    """Write ``ds`` to ``path`` atomically: a temporary file in the same directory, then
    os.replace. Always engine='netcdf4'."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        ds.to_netcdf(tmp, engine="netcdf4", format="NETCDF4", encoding=_encoding(ds))
        if fsync:
            fd = os.open(tmp, os.O_RDONLY)
            try:
                os.fsync(fd)
            finally:
                os.close(fd)
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()
    return path


def open_sweep(path, load: bool = True) -> xr.Dataset:
    """Open a sweep or shard file (engine netcdf4; seconds stay floats)."""
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
