"""Calibration: the cost of a decided run (:class:`~.decide.RunPlan`) measured by a short probe on
the target device, not taken from constants.

The probe (:func:`probe`) runs the plan's own step (method, precision, dt, output stride, path) on
a few of its columns: the CPU backend steps columns one after another, so 4 columns give the cost
per column-step; on a GPU it takes the shard's width, since the step time there is set by latency
up to thousands of columns. It times the batch build, the stepping (the median of three segments,
after a first one that loads kernels and captures graphs), the device measurement of a record of
the run's length, the device-to-host copy and a netCDF write and read of a few MB; import and
kernel-load seconds are this process's own. :func:`.cost.predict` turns it into stage seconds and
memory.

Probes are cached as JSON under the user cache dir (``platformdirs.user_cache_dir
('warp_tensegrity')/calibration`` or ``$WARP_TENSEGRITY_CACHE``), one file per device, run plan,
scene, probe columns and code version. A probe records how busy the host was with other work
while it ran (:func:`others_busy`); one taken under load (``under_load``) is used with that said,
and taken again as soon as the host is idle. ``recalibrate`` (CLI ``--recalibrate``) renews it.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
import logging
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import psutil

from ..atomic import oserror_line, write_text
from ..measure.energy import end_prisms, part_nodes, station_prism
from ..provenance import code_version
from ..runtime import resolve_device, startup_seconds
from ..scene.batch import ColumnParams, column_batch, column_params, far_end_params, has_profiles, reference_states
from ..types import Path as StepPath
from .cost import predict
from .decide import RunPlan, check_batch_arguments, decide, default_shard_size, far_end
from .paths import lane_emulation

PROBE_STEPS = 300
"""Steps timed by the probe (after a first segment of PROBE_WARM_STEPS)."""
PROBE_WARM_STEPS = 60
PROBE_SAMPLES = 4000
"""Outputs of the synthetic record whose measurement the probe times (at most)."""
CPU_PROBE_COLUMNS = 4
CACHE_VERSION = 7
BUILD_PROBE_COLUMNS = 256
"""Columns of the probe's build-cost measurement (replicas of its first column): 8 measured a
batch's fixed costs, not its per-column one (1.7 ms a column from 8, 0.05 ms from 768 on the
2-core host, issue 33)."""
IO_PROBE_CASES = 1600
"""Cases of the probe's larger netCDF file (2,500 float32 outputs each: 16 MB; a 4 MB one was within
the noise of one fsync on a shared disk)."""
STORE_PROBE_VARIABLES = 48
"""Variables of the probe's store and export datasets: a sweep's output holds 40-50 (io.shard_dataset),
and the store's and the export's fixed costs go by variable (Zarr arrays, netCDF variables)."""
WARM_LOAD_SECONDS = 0.05
"""Kernel loads of a run whose kernels the probe compiled into the cache (measured 0.02-0.04 s on
the 2-core CPU and the H200, benchmarks/results/end_to_end_*.json)."""
BUSY_SHARE = 0.25
"""A probe is taken under load when other processes kept more than this share of the host's cores
busy while it ran (a 2-core host: half a core)."""


def cache_dir() -> Path:
    """Where probes are cached: ``$WARP_TENSEGRITY_CACHE`` or the user cache dir."""
    env = os.environ.get("WARP_TENSEGRITY_CACHE")
    if env:
        return Path(env) / "calibration"
    try:
        import platformdirs

        root = Path(platformdirs.user_cache_dir("warp_tensegrity"))
    except ImportError:  # platformdirs is optional: the XDG default
        root = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "warp_tensegrity"
    return root / "calibration"


def device_label(name=None) -> str:
    """'cpu (x86_64, 2 cores)' or 'cuda:0 (NVIDIA H100 80GB HBM3)': the device a run will use."""
    d = resolve_device(name)
    if d.is_cuda:
        return f"{d.alias} ({d.name})"
    return f"{d.alias} ({platform.machine()}, {os.cpu_count()} cores)"


def _busy_seconds() -> tuple[float, float]:
    """(CPU seconds of the whole host, of this process) so far."""
    t = psutil.cpu_times()
    own = psutil.Process().cpu_times()
    return (t.user + t.nice + t.system + getattr(t, "irq", 0.0) + getattr(t, "softirq", 0.0)
            + getattr(t, "steal", 0.0), own.user + own.system + own.children_user + own.children_system)


def others_busy(start: tuple[float, float, float]) -> float:
    """Share of the host's cores that other processes kept busy since ``start`` = (wall, host CPU
    seconds, own CPU seconds) of :func:`busy_start` (0 idle .. 1 every core busy)."""
    wall0, host0, own0 = start
    host1, own1 = _busy_seconds()
    span = (time.perf_counter() - wall0) * (os.cpu_count() or 1)
    return max(0.0, ((host1 - host0) - (own1 - own0)) / span) if span > 0 else 0.0


def busy_start() -> tuple[float, float, float]:
    return (time.perf_counter(), *_busy_seconds())


def host_idle(window: float = 0.2) -> bool:
    """Whether other processes keep less than BUSY_SHARE of the cores busy (sampled for ``window`` s)."""
    start = busy_start()
    time.sleep(window)
    return others_busy(start) < BUSY_SHARE


def _kernel_cache_entries() -> set:
    """Names in Warp's kernel cache directory (a module the probe compiles adds one)."""
    import warp as wp  # initialised by the probe already

    root = Path(wp.config.kernel_cache_dir or "")
    return set(os.listdir(root)) if root.is_dir() else set()


def _probe_columns(n_columns: int, shard: int, is_cuda: bool) -> np.ndarray:
    if is_cuda:
        return np.arange(min(shard, n_columns))  # the first shard, at its width
    k = min(CPU_PROBE_COLUMNS, n_columns)
    return np.unique(np.round(np.linspace(0, n_columns - 1, k)).astype(int))


def _key(config, params: dict, run: RunPlan, shard: int) -> tuple[str, dict]:
    cols = _probe_columns(params["prestrain"].shape[0], shard, run.on_gpu)
    s = run.settings
    desc = {
        "device": device_label(run.device), "method": run.method, "precision": run.precision, "path": str(run.path.value),
        "shard": int(shard), "scene": repr(config), "dt": repr(run.dt), "output_every": run.output_every,
        "prisms_simulated": run.prisms_simulated, "probe_columns": len(cols), "measure": s.measure,
        "compress_energy": bool(s.compress_energy),
        "params": {k: np.asarray(v, dtype=np.float64)[cols].tolist() for k, v in sorted(params.items())},
        "code": code_version(), "version": CACHE_VERSION,
    }
    h = hashlib.sha256(json.dumps(desc, sort_keys=True, default=str).encode()).hexdigest()[:20]
    return h, desc


@functools.cache
def _tile_columns(real):
    """Kernel: out[k, j, b] = src[k, j] (a synthetic record of the probe's width, built on the device)."""
    import warp as wp

    @wp.kernel(enable_backward=False, module="unique")
    def tile(src: wp.array2d(dtype=wp.float64), out: wp.array3d(dtype=real)):
        k, j, b = wp.tid()
        out[k, j, b] = real(src[k, j])

    return tile


def _array_bytes(obj, B: int) -> tuple[int, int]:
    """(bytes of arrays with a column axis of length B, other bytes) held by obj's attributes."""
    import warp as wp

    per, fixed, seen = 0, 0, set()

    def visit(v):
        nonlocal per, fixed
        if isinstance(v, wp.array):
            if id(v) in seen:
                return
            seen.add(id(v))
            nb = int(np.prod(v.shape)) * wp.types.type_size_in_bytes(v.dtype)
            if v.ndim and v.shape[-1] == B and B > 1:
                per += nb
            else:
                fixed += nb
        elif isinstance(v, dict):
            for x in v.values():
                visit(x)
        elif hasattr(v, "__dict__") and not isinstance(v, type):
            for x in vars(v).values():
                visit(x)

    visit(obj)
    return per, fixed


def _io_rates(tmp: Path, compress_energy: bool = False) -> dict:
    """netCDF write and read seconds per byte (and per file) on this host, from a few-MB file of
    energy histories stored as a sweep stores them (float32 round-off-like data, zlib only with
    ``compress_energy``: compression sets the rate, ~4x slower)."""
    import xarray as xr  # xarray (and pandas) load with a probe, not with the package

    from .. import io as D  # imports xarray: not at package import

    rng = np.random.default_rng(0)
    out = {}
    for n in (1, IO_PROBE_CASES):  # a small and a ~16 MB file: fixed cost and rate; the fastest of three
        ds = xr.Dataset({"kinetic_energy": (("case", "time"), rng.standard_normal((n, 2500)).astype(np.float32))},
                        attrs={"compress_energy": int(compress_energy)})
        p = tmp / f"io{n}.nc"
        w, r = [], []
        for _ in range(3):  # a shared disk's fsync is noisy: the fastest of three
            t0 = time.perf_counter()
            D.write_netcdf(ds, p)
            t1 = time.perf_counter()
            D.open_sweep(p, load=True)
            w.append(t1 - t0)
            r.append(time.perf_counter() - t1)
        out[n] = (ds.nbytes, min(w), min(r))
    (b0, w0, r0), (b1, w1, r1) = out[1], out[IO_PROBE_CASES]
    return {"write_fixed": w0, "write_per_byte": max(w1 - w0, 0.0) / (b1 - b0),
            "read_fixed": r0, "read_per_byte": max(r1 - r0, 0.0) / (b1 - b0)}


@functools.cache
def _store_costs() -> dict:
    """:func:`_measure_store_costs` once a process (they are the host's, whatever the run): 2-4 s."""
    with tempfile.TemporaryDirectory() as tmp:
        return _measure_store_costs(Path(tmp))


def _measure_store_costs(tmp: Path) -> dict:
    """Seconds a sweep's store, export and closing summary pay whatever their size, on this host, the
    fastest of two, on a dataset of :data:`STORE_PROBE_VARIABLES` small variables: ``store_setup``, a
    Zarr store laid out from a lazy template, as the sweep's is (``to_zarr(compute=False)``);
    ``store_write_fixed``, a region of every variable written in two halves and its chunk files
    fsync'd; ``export_fixed``, the store read back whole and written as netCDF (a sweep of one shard);
    ``export_dask_fixed``, the same through dask (the block-by-block export of more shards);
    ``summary_fixed``, the file opened again (the run's closing summary); and the imports a run pays
    first in these stages (:func:`_first_use_seconds`). They are mostly Python work (xarray, Zarr
    metadata), not disk: priced as small-file writes they came to a fifth of what they took on the
    2-core host (ci_small's write 0.22 s against 1.0-1.2 s, its export 4 ms against 0.35-0.48 s)."""
    import dask
    import dask.array as da
    import dask.local
    import xarray as xr

    from .. import io as D  # imports xarray: not at package import

    n, T = 8, 51
    names = [f"v{i}" for i in range(STORE_PROBE_VARIABLES)]
    coords = {"case": np.arange(n), "time": np.linspace(0.0, 1.0, T)}
    full = xr.Dataset({k: (("case", "time"), np.full((n, T), float(i))) for i, k in enumerate(names)}, coords=coords)
    lazy = xr.Dataset({k: (("case", "time"), da.zeros((n, T), chunks=(n, T))) for k in names}, coords=coords)
    enc = {k: {"chunks": (n // 2, T)} for k in names}
    best = dict.fromkeys(("store_setup", "store_write_fixed", "export_fixed", "export_dask_fixed", "summary_fixed"),
                         np.inf)
    for r in range(2):
        store = tmp / f"store{r}.zarr"
        t0 = time.perf_counter()
        lazy.to_zarr(store, mode="w", compute=False, encoding=enc, consolidated=False)
        t1 = time.perf_counter()
        for half in (slice(0, n // 2), slice(n // 2, n)):
            body = full.isel(case=half).drop_vars(["case", "time"])
            for part in (names[: len(names) // 2], names[len(names) // 2:]):
                body[part].to_zarr(store, region={"case": half}, mode="r+", consolidated=False)
        for f in store.rglob("*"):
            if f.is_file():
                with open(f, "rb") as fh:
                    os.fsync(fh.fileno())
        t2 = time.perf_counter()
        with xr.open_zarr(store, consolidated=False, chunks={}) as ds:
            D.write_netcdf(ds.load(), tmp / f"whole{r}.nc")
        t3 = time.perf_counter()
        with xr.open_zarr(store, consolidated=False, chunks={}) as ds, dask.config.set(scheduler=dask.local.get_sync):
            D.write_netcdf(ds, tmp / f"blocks{r}.nc")
        t4 = time.perf_counter()
        with D.open_sweep(tmp / f"whole{r}.nc", load=False) as ds:  # the summary reads per-case flags
            ds["v0"].values  # noqa: B018 - read
        t5 = time.perf_counter()
        for k, v in (("store_setup", t1 - t0), ("store_write_fixed", (t2 - t1) / 2), ("export_fixed", t3 - t2),
                     ("export_dask_fixed", t4 - t3), ("summary_fixed", t5 - t4)):
            best[k] = min(best[k], v)
    return best | _first_use_seconds()


@functools.cache
def _first_use_seconds() -> dict:
    """Seconds a fresh interpreter takes, after xarray, for the imports a run pays on first use:
    ``store_first_use`` dask.array and Zarr, at its store's layout (xarray imports dask.array at its
    first Variable; dask.array imports scipy.fftpack and cupy where they are installed);
    ``export_first_use`` netCDF4, at its export; ``export_dask_first_use`` dask.distributed, which
    xarray imports to look for a client when it writes dask arrays (an export of more than one shard).
    This process may hold them already, so a child measures them; 0 where it cannot."""
    code = """
import time, xarray
t0 = time.perf_counter()
import dask.array, zarr
t1 = time.perf_counter()
import netCDF4
t2 = time.perf_counter()
try:
    import dask.distributed
except ImportError:
    pass
print(t1 - t0, t2 - t1, time.perf_counter() - t2)
"""
    keys = ("store_first_use", "export_first_use", "export_dask_first_use")
    try:
        out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
        vals = [max(float(x), 0.0) for x in out.stdout.split()] if out.returncode == 0 else []
    except (OSError, ValueError, subprocess.SubprocessError):
        vals = []
    return dict(zip(keys, vals)) if len(vals) == 3 else dict.fromkeys(keys, 0.0)


def probe(config, params: dict, run: RunPlan, shard_size: int, use_cache: bool = True) -> dict:
    """Run (or read from the cache) the calibration probe of ``run`` for T3 columns of ``config``
    with the per-column ``params`` (filled, shape (N,); :func:`~.decide.decide`'s), on shards of
    ``shard_size`` columns. ``use_cache`` False renews it. Returns the measured rates (dict)."""
    key, desc = _key(config, params, run, shard_size)
    path = cache_dir() / f"{key}.json"
    cal = _read_cache(path) if use_cache else None
    if cal is not None and (not cal.get("under_load") or not host_idle()):
        return cal
    cal = _measure(config, params, run, shard_size) | {"key": key, "describe": desc, "device_label": desc["device"]}
    _write_cache(path, cal)
    return cal


def _read_cache(path: Path) -> dict | None:
    """A cached probe, or None (none, or one that does not read: it is measured again)."""
    try:
        cal = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return cal if isinstance(cal, dict) else None


_cache_warned: set = set()


def _write_cache(path: Path, cal: dict) -> None:
    """Cache a probe (atomically, never through a link: :func:`warp_tensegrity.atomic.write_text`).
    The cache only saves time: a directory that cannot be written is said once, in one line, and
    the run goes on without it."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        write_text(path, json.dumps(cal, indent=1), fsync=False)
    except OSError as e:
        if path.parent not in _cache_warned:
            _cache_warned.add(path.parent)
            logging.getLogger(__name__).warning(
                "%s; going on without the calibration cache (set WARP_TENSEGRITY_CACHE to a writable directory "
                "to keep probes)", oserror_line(e, path.parent, "calibration cache not written:"))


def _measure(config, params: dict, run: RunPlan, shard_size: int) -> dict:
    import warp as wp  # Warp and the kernels load with a probe, not with the package

    from ..sim.integrate import Integrator  # imports Warp: not at package import
    from ..measure.device import measure_record  # imports Warp: not at package import
    from ..measure.device_kernels import load_kernels  # imports Warp

    busy = busy_start()
    device = resolve_device(run.device)
    cols = _probe_columns(params["prestrain"].shape[0], shard_size, device.is_cuda)
    pp = {k: np.ascontiguousarray(v[cols]) for k, v in params.items()}
    n, n_sim = config.n_prisms, run.prisms_simulated
    # as the engine runs it: the record is kept on the device for the measures
    s = dataclasses.replace(run.settings, record_strain=run.settings.record_strain or run.settings.measure != "none")
    sim_cfg = far_end(config, n_sim) if n_sim < n else config
    pp = far_end_params(ColumnParams(pp), n, n_sim) if has_profiles(pp) else pp

    # batch assembly as a + b x columns + c x distinct reference states (each state's equilibrium
    # is solved once, whatever its columns), plus the scene's first build in a process (its impact
    # solve, cached after): the fastest of three builds of one column, of m copies of it and of m
    # columns with m distinct prestrains (noise on a shared host only adds)
    def build_time(p):
        times = []
        for _ in range(3):
            t0 = time.perf_counter()
            column_batch(sim_cfg, p)
            times.append(time.perf_counter() - t0)
        return min(times), times[0]

    m = BUILD_PROBE_COLUMNS  # replicas: the probe's own columns may be fewer
    t1, first = build_time({k: v[:1] for k, v in pp.items()})
    a_batch, b_col, c_state = t1, 0.0, 0.0
    if m > 1:
        same = {k: np.repeat(v[:1], m, axis=0) for k, v in pp.items()}
        step = 1e-6 * np.arange(m).reshape((m,) + (1,) * (same["prestrain"].ndim - 1))
        distinct = same | {"prestrain": np.minimum(same["prestrain"] + step, 0.5)}
        t_same, t_distinct = build_time(same)[0], build_time(distinct)[0]
        b_col = max(t_same - t1, 0.0) / (m - 1)
        c_state = max(t_distinct - t_same, 0.0) / (m - 1)
        a_batch = max(t1 - b_col - c_state, 0.0)
    batch = column_batch(sim_cfg, pp)
    # outputs every few steps at most: the step's cost, not the output stride's (a run may output every
    # million steps); whole graph periods (as a run replays them), the fused paths capture output periods
    every, spg = min(run.output_every, PROBE_STEPS // 6), int(s.steps_per_graph)
    period = every * max(1, -(-spg // every)) if run.path != StepPath.STAGED else spg
    seg_steps = period * max(1, -(-(PROBE_STEPS // 3) // period))
    warm_steps = period * max(1, -(-PROBE_WARM_STEPS // period))
    n_out = (warm_steps + 3 * seg_steps) // every + 1
    with lane_emulation(run.path, device):  # the CPU runs the lane step as fibers
        t0 = time.perf_counter()
        # the energy-parts record too, as simulate_batch steps it (a station at mid-column)
        integ = Integrator(batch, s, run.dt, every, n_out, path=run.path,
                           energy_parts=part_nodes(n_sim, station_prism(n_sim), end_prisms(n_sim, s.energy_end_prisms)))
        t_integ = time.perf_counter() - t0
        B = batch.n_columns
        with wp.ScopedDevice(integ.device):
            cached = _kernel_cache_entries()
            t0 = time.perf_counter()
            integ.initialize()
            load_kernels(integ.device)
            wp.synchronize_device(integ.device)
            t_init = time.perf_counter() - t0
            # kernels compiled here are loaded from the cache by the run that follows (~0.03 s measured,
            # benchmarks/results/end_to_end_*.json): the compile is the probe's, not the run's
            compiled = _kernel_cache_entries() - cached
            integ.advance(warm_steps)  # loads, graph capture
            wp.synchronize_device(integ.device)
            seg = []  # three segments, their median (a probe under load is marked: others_busy)
            for _ in range(3):
                t0 = time.perf_counter()
                integ.advance(seg_steps)
                wp.synchronize_device(integ.device)
                seg.append((time.perf_counter() - t0) / seg_steps)
            t_step = float(np.median(seg))
            per_col, fixed = _array_bytes((integ.model, integ.data, integ.kinetic, integ.elastic, integ.energy_below,
                                           integ.energy_end), B)
            # measurement of a record of the run's length, up to PROBE_SAMPLES outputs (the cost model
            # scales it to the run's; sech^2 pulses crossing the column)
            T_full = min(run.n_out, PROBE_SAMPLES)
            tt = run.first_output_times(T_full)  # the head only: a run's n_out may be ~1e9
            j = np.arange(n_sim)
            c = max(n_sim, 4) / max(float(tt[-1]), 1e-30) * 0.8
            rec = -1e-3 / np.cosh((j[None, :] - (n_sim - 1 + 4 - c * tt[:, None])) / 2.0) ** 2
            real = wp.float32 if s.precision == "fp32" else wp.float64
            rec_d = wp.empty((T_full, n_sim, B), dtype=real)
            wp.launch(_tile_columns(real), rec_d.shape, [wp.array(rec.astype(np.float64), dtype=wp.float64), rec_d])
            measure_record(rec_d, tt, config.height, n_prisms=n, cut=n - n_sim)  # warm
            tm = {}
            measure_record(rec_d, tt, config.height, n_prisms=n, cut=n - n_sim, timings=tm)
            big = wp.zeros(1 << 21, dtype=wp.float64)
            t0 = time.perf_counter()
            big.numpy()
            t_copy = (time.perf_counter() - t0) / big.size / 8
    with tempfile.TemporaryDirectory() as tmp:
        io = _io_rates(Path(tmp), bool(run.settings.compress_energy))
    store = _store_costs()
    share = others_busy(busy)
    return {
        "created": time.strftime("%Y-%m-%dT%H:%M:%S%z"), "is_cuda": bool(device.is_cuda),
        "step_path": str(run.path.value), "probe_columns": int(B), "probe_steps": 3 * seg_steps,
        "prisms_simulated": int(n_sim), "dt": float(run.dt), "output_every": int(every),
        "batch_fixed": a_batch, "batch_per_column": b_col, "batch_per_state": c_state,
        "batch_first": max(first - t1, 0.0), "integrator_build": t_integ, "initialize": t_init,
        "step_seconds": t_step, "column_step_seconds": t_step / B,
        "measure_seconds": tm["measurement"], "measure_samples": int(T_full),
        "transfer_per_byte": t_copy, "device_bytes_per_column": per_col / B, "device_bytes_fixed": fixed,
        "strain_bytes_per_sample": (4 if s.precision == "fp32" else 8) * n_sim,
        **{f"io_{k}": v for k, v in io.items()}, **store,
        # this process's start-up (interpreter, imports, Warp) and the probe's kernel loads: what a run pays once
        "import": startup_seconds(), "compile": WARM_LOAD_SECONDS if compiled else t_init,
        "probe_compile": t_init if compiled else 0.0, "compiled_modules": len(compiled),
        # what this process holds after imports, kernel loads and the probe: not its lifetime peak
        # (ru_maxrss), which carries whatever it did before and would be cached with the probe
        "base_rss": psutil.Process().memory_info().rss,
        "others_busy": share, "under_load": bool(share > BUSY_SHARE),
    }


def reference_state_count(params: dict) -> int:
    """Distinct reference states (prestrain, base rigidity, EA) among filled per-column parameters."""
    return int(reference_states(params)[0]["prestrain"].shape[0])


def estimate_plan(plan, recalibrate: bool = False, shards: list[int] | None = None) -> dict:
    """The cost of a sweep plan (``sweep.plan.SweepPlan``): :func:`.cost.predict` from the probe of
    its run plan on its widest shard; ``shards``: the indices still to run (a resume; default all);
    ``recalibrate`` renews the probe."""
    spec = plan.spec
    todo = [plan.shards[i] for i in (range(plan.n_shards) if shards is None else shards)]
    width = max(b - a for a, b in plan.shards)
    # with groups, the probe of the run plan is its group's, on that group's columns only: the sweep's
    # columns at the smallest dt priced phase_large's 512 stiffest columns as its 1,536 (24 s, not ~4 s)
    lead = next((g for g in plan.groups if g.plan is plan.run), None) if len(plan.groups) > 1 else None
    if lead is None:
        cal = probe(spec.scene, plan.params, plan.run, width, use_cache=not recalibrate)
    else:
        cal = probe(spec.scene, {k: v[lead.columns] for k, v in plan.params.items()}, plan.run,
                    min(width, lead.n_columns), use_cache=not recalibrate)
    states = [reference_state_count({k: v[a:b] for k, v in plan.params.items()}) for a, b in todo]
    rec = (bool(spec.run["record_strain"]), bool(spec.run["record_energy"]))
    out = predict(cal, plan.run, [b - a for a, b in todo], *rec, shard_states=states,
                  planned=(plan.n_columns, reference_state_count(plan.params)),
                  energy_precision=spec.run["energy_precision"], n_shards=plan.n_shards)
    twins = bool(spec.run.get("error_estimate"))
    if len(plan.groups) > 1 or twins:
        # each group steps its share of every shard at its own dt, priced by its own probe, and its twin
        # (the error estimate) at the twin's; precision 'auto' reruns in fp64 what fp32 does not verify,
        # which no estimate can know beforehand: not priced (the dry run says so)
        group = plan.column_group
        st = out["stages_s"]
        st["stepping"] = st["measurement"] = 0.0
        out["twin_stepping_s"] = 0.0
        runs = [[] for _ in todo]  # per shard: (seconds alone, columns) of each run (group or twin)
        for gi, g in enumerate(plan.groups):
            sizes = [int(np.count_nonzero(group[a:b] == gi)) for a, b in todo]
            if any(sizes):
                params = {k: v[g.columns] for k, v in plan.params.items()}
                cal_g = cal if len(plan.groups) == 1 or g is lead else probe(spec.scene, params, g.plan,
                                                                    min(width, g.n_columns), use_cache=not recalibrate)
                for run, is_twin in ((g.plan, False), (g.twin if twins else None, True)):
                    if run is not None:
                        for si, size in enumerate(sizes):
                            if size:
                                part = predict(cal_g, run, [size], *rec)["stages_s"]
                                runs[si].append((part["stepping"], size))
                                st["measurement"] += part["measurement"]
                                out["twin_stepping_s"] += part["stepping"] if is_twin else 0.0
                                # a twin builds its columns and its Integrator again (the shards' build priced the first)
                                st["build"] += (part["build"] - cal_g.get("batch_first", 0.0)) if is_twin else 0.0
        # a shard's runs step at once on a GPU (engine.run_batches), one after another elsewhere
        capacity = default_shard_size(plan.device) if cal["is_cuda"] else None
        alone = sum(t for shard in runs for t, _ in shard)
        saturation = None if capacity is None else max(1, int(SATURATION_SHARE * capacity))
        st["stepping"] = sum(together_seconds(shard, saturation) for shard in runs)
        out["twin_stepping_s"] *= st["stepping"] / alone if alone > 0 else 0.0
        if capacity is not None:  # the device holds a shard's runs at once: each its arrays, twins a second copy
            per_col = out["device_bytes_per_column"]
            n_runs = max(len(shard) for shard in runs)
            out["device_bytes_per_column"] = per_col * (2 if twins else 1)
            out["device_bytes_per_shard"] = int(cal["device_bytes_fixed"] * n_runs
                                                + per_col * max(sum(b for _, b in shard) for shard in runs))
        out["seconds"] = float(sum(st.values()))
    return out | {"probe": cal}


SATURATION_SHARE = 0.5
"""The share of the resident capacity (:func:`~.decide.default_shard_size`) at which the lane step
fills a GPU: on an H200 (capacity 1,056) 512 columns of 50 prisms step at 80 % (FB fp64) and 82 % (RB
fp64) of their rate at 16,384, 256 at 45 % and 62 %, 1,056 at 95 % and 93 %
(benchmarks/results/issue33_h200_fourth/call3_*/throughput_lanes_new_*_fp64.json). Runs stepped at once
share that, not the resident capacity: priced against 1,056 slots phase_large's runs came to 4.9 s
against 8.4-8.8 s measured."""


def together_seconds(runs: list[tuple[float, int]], capacity: int | None) -> float:
    """Seconds to step runs of (seconds alone, columns) at once on a GPU that ``capacity`` columns fill
    (None: one after another, the sum; :data:`SATURATION_SHARE` of the resident capacity). Each run
    keeps its own pace, so no less than the longest; the device is shared, so no less than the
    slot-seconds (seconds x columns, at most ``capacity`` each) over ``capacity``: the larger of the
    two bounds."""
    if capacity is None or len(runs) < 2:
        return float(sum(t for t, _ in runs))
    return float(max(max(t for t, _ in runs), sum(t * min(b, capacity) for t, b in runs) / capacity))


def estimate_batch(config, params: dict, settings, recalibrate: bool = False) -> dict:
    """What :func:`~warp_tensegrity.simulate_batch` with these arguments would do and cost, before it
    runs: the run plan (dt, stability limit, steps, path, prisms simulated; :func:`~.decide.decide`)
    with time and memory from a probe on the device (:func:`probe`, cached; ``recalibrate`` renews
    it): ``seconds_estimate`` (build, stepping, measurement, transfer), ``stages_estimate``,
    ``device_bytes_estimate``, ``device_label``. ``params`` as ``simulate_batch`` takes them."""
    params = column_params(config, check_batch_arguments("estimate_batch", config, params, settings))
    run = decide(config, params, settings)
    B = int(params["prestrain"].shape[0])
    cal = probe(config, params, run, B, use_cache=not recalibrate)
    states = reference_state_count(params)
    pred = predict(cal, run, [B], run.settings.record_strain, shard_states=[states], planned=(B, states))
    st = pred["stages_s"]
    seconds = sum(st[k] for k in ("build", "stepping", "measurement", "transfer"))
    return {"dt": run.dt, "dt_limit": run.dt_limit, "n_steps": run.n_steps, "output_every": run.output_every,
            "n_out": run.n_out, "omega_max_bound": run.omega_max_bound, "bandwidth": run.bandwidth,
            "step_path": str(run.path.value), "lane_refusal": run.lane_refusal, "on_gpu": run.on_gpu,
            "dt_safety": run.settings.dt_safety, "accuracy_target": run.accuracy, "prisms_simulated": run.prisms_simulated,
            "seconds_estimate": seconds, "seconds_per_column_step_estimate": cal["column_step_seconds"],
            "stages_estimate": st, "device_bytes_estimate": pred["device_bytes_per_shard"],
            "device_label": cal["device_label"], "under_load": pred["under_load"], "run_plan": run}
