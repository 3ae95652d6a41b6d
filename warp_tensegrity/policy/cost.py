"""The one cost model: time, memory and output size of a decided run (:class:`~.decide.RunPlan`),
and the one formatter of each unit.

* bytes: :func:`output_bytes_per_column` (what a column leaves in the output),
  :func:`disk_bytes` (the disk a sweep's store and netCDF export take, at most),
  :func:`state_bytes_per_column` (the engine's arrays), :func:`host_bytes_per_column` (what a
  shard holds on the host while it steps, is measured and written);
* the sizes no machine setting can shrink (:func:`size_problems`): the step count against the
  device's int32 step counter (:data:`MAX_STEPS`), and the records of ONE column (the output
  count times the energies and the strain record, :func:`column_bytes`) against the memory of
  this machine: a run that breaks either is refused when it is decided, before any array of its
  size exists (:func:`warp_tensegrity.policy.decide.decide`), whatever the shard size or
  ``--ignore-estimate``;
* seconds and memory from a calibration probe (:func:`predict`; the probe is
  :func:`warp_tensegrity.policy.calibrate.probe`): every figure the dry run prints, the time
  limit and the memory checks read (:mod:`warp_tensegrity.sweep.budget`) and the progress bar's
  first ETA start from the same prediction.

No figure here is rescaled by the host's load at the time of the estimate: a probe taken under
load says so (``under_load``) and is taken again once the host is idle (:mod:`.calibrate`).
"""

from __future__ import annotations

import math
import os

from ..types import Method

DEFAULT_TIME_LIMIT = 7 * 86400.0
"""Seconds a run may be estimated to take before it is refused (``--time-limit`` of ``run``,
``resume`` and ``lens``)."""
HOST_COPIES = 4
"""Host bytes a shard needs while stepping and measuring, in units of its output bytes
(engine arrays, their float64 copies, measurement temporaries); calibrated by
tests/sweep/test_store.py::test_peak_rss_stays_under_the_memory_limit."""
MEASURE_VALUES = 12
"""Per-column scalars of the output (pulse and energy measures, flags, errors)."""
MAX_STEPS = 2**31 - 1
"""The device's step counter is a Warp ``int`` (int32), and so is every dimension of a Warp array:
the output axis (at most one output per step) is bounded with it."""
TIME_AXIS_BYTES = 16
"""Host bytes per output of a run's time axis: the output times (float64) and steps (int64) of
:class:`~.decide.RunPlan`, built once per run and held by every result and the store's template."""


def fmt_bytes(b: float) -> str:
    """'144.6 kB', '2.3 GB' (decimal units)."""
    try:
        b = float(b)
    except OverflowError:  # an integer count beyond float range
        b = math.inf
    for unit in ("B", "kB", "MB", "GB", "TB", "PB"):
        if abs(b) < 1000 or unit == "PB":
            return f"{b:.0f} {unit}" if unit == "B" else f"{b:.3g} {unit}"
        b /= 1000.0
    return f"{b:.3g} PB"  # pragma: no cover


def fmt_seconds(s: float) -> str:
    """A duration: '0.5s', '45s', '2m05s', '9h48m', '7 days', '32.4 days', '?' when unknown."""
    if not math.isfinite(s):
        return "?"
    if s < 9.5:
        return f"{s:.2g}s"
    if s >= 2 * 86400:
        return f"{s / 86400:.3g} days"
    s = int(round(s))
    if s >= 3600:
        return f"{s // 3600}h{(s % 3600) // 60:02d}m"
    if s >= 60:
        return f"{s // 60}m{s % 60:02d}s"
    return f"{s}s"


ENERGY_BYTES = {"fp64": 32, "fp32": 16, "auto": 20}
"""Bytes per output of the four energy histories as run.energy_precision stores them ('auto':
float32 but the elastic energy; :func:`warp_tensegrity.io.energy_dtypes`)."""


def output_bytes_per_column(n_out: int, n_prisms: int, record_strain: bool, record_energy: bool = True,
                            energy_precision: str = "fp64") -> int:
    """Bytes one column leaves in the output: measures and final state scalars, prism heights (float64),
    energy histories (kinetic, elastic and the two energy parts, as ``energy_precision`` stores them)
    and the strain record when kept (float64)."""
    energy = ENERGY_BYTES[energy_precision] * n_out if record_energy else 0
    return 8 * (MEASURE_VALUES + n_prisms + (n_out * n_prisms if record_strain else 0)) + energy


BLOCK = 4096
"""Bytes a file or a directory takes on disk at least (a block of ext4 or XFS, a page of tmpfs)."""
STORE_BLOCKS_PER_SHARD = 32
"""Files and directories a shard adds to the Zarr store, at most: a chunk file per variable (21 with
strain and energies) and the directories of the multi-dimensional ones' chunk keys; 27-28 measured per
shard, 32 for the first (sweeps like tests/test_faults.py's, energy measures included)."""
STORE_BLOCKS_FIXED = 160
"""Files and directories of the store whatever its shards: each variable's and coordinate's
directory, metadata and coordinate chunks, the manifest and the spec copy (130 measured, energy
measures included)."""
MANIFEST_BYTES_PER_SHARD = 4096
"""Bytes a done shard adds to manifest.json (a sha256 per variable and the shard's attributes;
2.8 kB measured), counted twice: the manifest is replaced through a temporary copy."""
COLUMN_EXTRA_BYTES = 256
"""Bytes per column beyond its data in each file: per-column coordinates, labels, the spec text."""
NC_FIXED_BYTES = 65536
"""The netCDF file's own bytes whatever its size: HDF5 superblock, object headers and attributes of
its ~25 variables, the global attributes (16-22 kB measured for sweeps/ci_small.toml)."""
NC_BYTES_PER_SHARD = 2048
"""The netCDF file's chunk index per shard (one chunk per variable and shard; ~360 B measured)."""


def netcdf_bytes(data_bytes: int, n_chunks: int = 1) -> int:
    """Bytes of disk a netCDF file of ``data_bytes`` of data (uncompressed), in ``n_chunks`` chunks
    per variable, takes at most."""
    return int(data_bytes) + NC_FIXED_BYTES + NC_BYTES_PER_SHARD * max(int(n_chunks), 1)


def disk_bytes(run, shard_sizes: list[int], n_columns: int, n_shards: int, record_strain: bool,
               record_energy: bool = True, energy_precision: str = "fp64") -> dict:
    """Bytes of disk a sweep needs at most, its data uncompressed: ``store`` for the Zarr store's
    shards of ``shard_sizes`` columns (their data, files and directories, and their manifest
    records) and ``netcdf`` for the export of all ``n_columns`` columns in ``n_shards`` shards; both
    are on disk when the export ends (``--no-keep-store`` removes the store only after it)."""
    col = output_bytes_per_column(run.n_out, run.prisms, record_strain, record_energy, energy_precision) + COLUMN_EXTRA_BYTES
    time = 16 * run.n_out  # the output times and steps, in each file
    store = (col * sum(shard_sizes) + time
             + BLOCK * (STORE_BLOCKS_PER_SHARD * len(shard_sizes) + STORE_BLOCKS_FIXED)
             + 2 * MANIFEST_BYTES_PER_SHARD * n_shards)
    netcdf = netcdf_bytes(col * n_columns + time, n_shards)
    return {"store": int(store), "netcdf": int(netcdf), "total": int(store + netcdf)}


def state_bytes_per_column(run) -> int:
    """The engine's device arrays per column (state, constraint band, cable rest lengths, energies and
    energy parts;
    the strain record when kept, or when the pulse measures read it on the device)."""
    r = 4 if run.precision == "fp32" else 8
    state_vecs = 5 + (6 if run.method == Method.RK4 else 0)
    kept = run.settings.record_strain or run.settings.measure != "none"  # as engine.run_batch keeps it
    record = run.n_out * run.prisms_simulated if kept else 0
    return int(r * (3 * run.n_nodes * state_vecs + run.n_constraints * (run.bandwidth + 2) + 3 * run.n_cables
                    + 4 * run.n_out + record))


def host_bytes_per_column(run, record_strain: bool, record_energy: bool = True) -> int:
    """Host bytes one column needs while its shard steps, is measured and written (the engine's
    arrays too when the engine runs on the CPU)."""
    out = output_bytes_per_column(run.n_out, run.prisms, record_strain, record_energy)
    return HOST_COPIES * out + (0 if run.on_gpu else state_bytes_per_column(run))


def column_bytes(run) -> tuple[int, int]:
    """(host, device) bytes that one column of ``run`` needs, the least any shard size can give it:
    the time axis, the energy histories and the strain record when kept (float64, on the host,
    where every result crosses), and the engine's arrays (:func:`state_bytes_per_column`: device
    memory on a GPU, host memory on the CPU)."""
    host = TIME_AXIS_BYTES * run.n_out + output_bytes_per_column(run.n_out, run.prisms, run.settings.record_strain)
    state = state_bytes_per_column(run)
    return (host, state) if run.on_gpu else (host + state, 0)


def host_memory_total() -> int:
    """Bytes of physical memory of this host (what no run can exceed, whatever else runs)."""
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):  # pragma: no cover - not POSIX
        return 2**63


def size_problems(run, host_bytes: int | None = None, device_bytes: int | None = None) -> list[str]:
    """What no shard size and no override can run, one line each with its figure and a remedy ([] if
    none): more steps than :data:`MAX_STEPS`, or one column whose records (:func:`column_bytes`)
    exceed this host's physical memory (``host_bytes``; default :func:`host_memory_total`) or, on a
    GPU, the device's (``device_bytes``; default its total memory). Arithmetic on the plan's counts
    only: nothing of the run's size is built."""
    s = run.settings
    span = f"run.t_end = {s.t_end:g} s"
    out = []
    if run.n_steps > MAX_STEPS:
        remedy = ["lower run.t_end"] + (["raise run.dt"] if s.dt != "auto" else
                                        ["raise run.output_interval"] if run.output_every == 1 else [])
        out.append(f"{run.n_steps:.3g} steps ({span} at dt = {run.dt:.3g} s) exceed the device's step counter "
                   f"({MAX_STEPS:,} steps); {' or '.join(remedy)}")
    host, dev = column_bytes(run)
    interval = "auto (t_end / 200)" if s.output_interval is None else f"{s.output_interval:g} s"
    what = "the time axis, energies" + (f", the strain of {run.prisms:,} prisms" if s.record_strain else "")
    remedy = ("raise run.output_interval, lower run.t_end or set run.record_strain = false" if s.record_strain
              else "raise run.output_interval or lower run.t_end")
    for need, have, where in ((host, host_bytes, "host"), (dev, device_bytes, run.device)):
        if not need:
            continue
        if have is None:
            have = host_memory_total() if where == "host" else _device_total(run.device)
        if need > have:
            out.append(f"{run.n_out:,} outputs per column ({span} / run.output_interval = {interval}): one column's "
                       f"records ({what}) need about {fmt_bytes(need)} of {where} memory and this machine has "
                       f"{fmt_bytes(have)}; {remedy}")
    return out


def _device_total(device: str) -> int:
    """Total memory of a CUDA device [bytes] (Warp is initialised: the run was decided on it)."""
    from ..runtime import cuda_memory, resolve_device  # initialises Warp

    return cuda_memory(resolve_device(device))[1]


STORE_WRITE_FACTOR = 3.0
"""A shard's write into the store (its dataset, a sha256 per variable, Zarr, fsync) over the probe's
netCDF write rate per byte, beyond the fixed costs the probe measures (calibrate._store_costs): fit
to phase_large at its size (--stub-outputs) on the 2-core host, write 1.11-1.19 s with 0.81 s fixed."""
EXPORT_FACTOR = 6.0
"""The netCDF export (the store read back, the file written and fsync'd) over the probe's write rate
per byte, beyond its measured fixed costs: fit as STORE_WRITE_FACTOR, export 0.87-0.93 s with 0.17 s
fixed."""

HOST_STAGES = ("import", "build", "compile", "transfer", "write", "finalise")
"""Stages bound by the host CPU wherever the step runs (on the CPU device: every stage)."""


def predict(cal: dict, run, shard_sizes: list[int], record_strain: bool, record_energy: bool = True,
            shard_states: list[int] | None = None, planned: tuple[int, int] | None = None,
            energy_precision: str = "fp64", n_shards: int | None = None) -> dict:
    """Stage seconds and memory of ``run`` over shards of ``shard_sizes`` columns, from a probe ``cal``
    (:func:`~warp_tensegrity.policy.calibrate.probe`). ``shard_states``: distinct reference states
    of each shard (default: as many as columns); ``planned``: (columns, states) whose bound the plan
    built (a sweep's; None: none beyond the shards). Write and finalise are priced on the bytes
    stored (``energy_precision``), at the probe's rates for data stored as the run stores it, plus
    the fixed costs the probe measured (the store's layout, a shard's write, the export: whole for a
    sweep of one shard, through dask for more; ``n_shards``, default ``len(shard_sizes)``)."""
    P, n_out, n_steps = run.prisms, run.n_out, run.n_steps
    st = dict.fromkeys(("import", "build", "compile", "stepping", "measurement", "transfer", "write", "finalise"), 0.0)
    st["import"] = cal["import"]
    st["compile"] = cal["compile"]
    scale_T = n_out / max(cal["measure_samples"], 1)
    out_total = held = 0
    def build(columns, states):
        return cal["batch_fixed"] + cal["batch_per_column"] * columns + cal.get("batch_per_state", 0.0) * states

    st["build"] = cal.get("batch_first", 0.0) + (build(*planned) if planned else 0.0)  # the scene's first build
    out_col = output_bytes_per_column(n_out, P, record_strain, record_energy, energy_precision)
    for b, states in zip(shard_sizes, shard_states or shard_sizes):
        st["build"] += build(b, states) + cal["integrator_build"]
        if cal["is_cuda"]:
            # latency bound up to the probed width, then proportional
            st["stepping"] += n_steps * cal["step_seconds"] * max(1.0, b / cal["probe_columns"])
            st["measurement"] += cal["measure_seconds"] * scale_T * max(1.0, b / cal["probe_columns"])
        else:
            st["stepping"] += n_steps * cal["column_step_seconds"] * b
            st["measurement"] += cal["measure_seconds"] * scale_T * b / cal["probe_columns"]
        st["transfer"] += cal["transfer_per_byte"] * b * (output_bytes_per_column(n_out, P, record_strain) + 8 * 18 * (P + 1))
        out_total += b * out_col
        held += b * output_bytes_per_column(n_out, P, record_strain, record_energy)  # float64 on the host
        st["write"] += cal["store_write_fixed"] + STORE_WRITE_FACTOR * cal["io_write_per_byte"] * b * out_col
    # the store's layout, once: the probe's, and the imports it brings (calibrate._store_costs)
    st["write"] += cal["store_first_use"] + cal["store_setup"]
    # the export reads every shard back from the store and writes the netCDF file; the summary reads it
    whole = (len(shard_sizes) if n_shards is None else n_shards) <= 1
    st["finalise"] += (cal["export_first_use"] + cal["summary_fixed"] + EXPORT_FACTOR * cal["io_write_per_byte"] * out_total
                       + (cal["export_fixed"] if whole else cal["export_dask_fixed"] + cal["export_dask_first_use"]))
    bmax = max(shard_sizes) if shard_sizes else 0
    dev_bytes = cal["device_bytes_fixed"] + bmax * (cal["device_bytes_per_column"] + cal["strain_bytes_per_sample"] * n_out
                                                    + 8 * (12 * P + 3 * n_out + 12))
    # imports and kernels, the shards in flight, and the combine (every shard + the result)
    host_col = host_bytes_per_column(run, record_strain, record_energy)
    host_peak = cal["base_rss"] + bmax * host_col + 2 * held
    n_cols = planned[0] if planned else sum(shard_sizes)
    disk = disk_bytes(run, shard_sizes, n_cols, -(-n_cols // max(bmax, 1)), record_strain, record_energy,
                      energy_precision)
    return {"stages_s": st, "seconds": float(sum(st.values())), "device_bytes_per_shard": int(dev_bytes),
            "host_bytes_per_shard": int(bmax * host_col), "host_bytes_per_column": int(host_col),
            "device_bytes_per_column": int(dev_bytes - cal["device_bytes_fixed"]) // max(bmax, 1),
            "host_peak_bytes": int(host_peak), "output_bytes": int(out_total), "store_bytes": disk["store"],
            "netcdf_bytes": disk["netcdf"], "disk_bytes": disk["total"], "device": cal["device_label"],
            "column_step_seconds": float(cal["column_step_seconds"]), "under_load": bool(cal.get("under_load"))}
