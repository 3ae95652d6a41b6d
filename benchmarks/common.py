"""Shared pieces of the benchmark scripts: run metadata, batch preparation, timing, memory.

Nothing here changes the engine: the Integrator of :mod:`warp_tensegrity.sim.integrate` is used
as it is, with two harness-side choices (both stated in benchmarks/README.md):

* the batch of B columns is built once at a small size (``BASE_COLUMNS`` distinct columns with
  prestrain and impact speed spread over a range) and tiled to B on the host: the engine's
  cost does not depend on how the batch was assembled, and ``column_batch`` itself costs
  ~30 s on the host at B = 65,536 (equilibrium check with B right-hand sides);
* only the kernels the RATTLE step launches are compiled, in parallel threads
  (``wp.force_load``), with the block size the launches use.
"""

from __future__ import annotations

import contextlib
import dataclasses
import datetime
import gc
import hashlib
import json
import math
import os
import platform
import subprocess
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "benchmarks" / "results"

# spread of the per-column parameters of the benchmark batches (a sweep-like batch: every
# column has its own rest lengths; EA, masses and the base law are shared)
BASE_COLUMNS = 64
PRESTRAIN_RANGE = (0.005, 0.02)
V0_RANGE = (0.01, 0.05)  # m/s

# kernels of one RATTLE step (StagedStep.rattle + record_energy; the step counter: kernel_modules)
RATTLE_KERNELS = ("kick_drift", "project_positions", "gather_accel", "factor_project", "record_energy")


# ---------------------------------------------------------------------- metadata
DIRTY_OK = "WT_BENCH_ALLOW_DIRTY"
"""Set to 1 for a trial run from a checkout with uncommitted changes: its results say '-dirty' and
are not to be committed (tests/test_benchmark_provenance.py refuses them)."""


def code_hash(commit: str | None = None) -> str:
    """sha256 over the .py files of warp_tensegrity/ and benchmarks/ (path and content, sorted by
    path): the code a benchmark measures. ``commit``: the same hash of that commit's files, read
    from git (to check a result's claimed commit against the code it recorded)."""
    h = hashlib.sha256()
    if commit is None:
        files = sorted(p.relative_to(REPO).as_posix() for d in ("warp_tensegrity", "benchmarks")
                       for p in (REPO / d).rglob("*.py") if "__pycache__" not in p.parts and p.name != "_version.py")
        read = lambda f: (REPO / f).read_bytes()  # noqa: E731
    else:
        out = subprocess.run(["git", "ls-tree", "-r", "--name-only", commit, "--", "warp_tensegrity", "benchmarks"],
                             cwd=REPO, capture_output=True, text=True, check=True).stdout.split()
        files = sorted(f for f in out if f.endswith(".py") and not f.endswith("/_version.py"))
        read = lambda f: subprocess.run(["git", "show", f"{commit}:{f}"], cwd=REPO, capture_output=True,  # noqa: E731
                                        check=True).stdout
    for f in files:
        h.update(f.encode() + b"\0" + read(f) + b"\0")
    return h.hexdigest()


def git_commit() -> str:
    """The commit of the code measured. From git where the checkout has one (refused when tracked
    files differ from it, unless WT_BENCH_ALLOW_DIRTY=1, which records '-dirty'); else from the
    GIT_COMMIT environment variable (the GPU machine's copy has no .git), which
    :func:`run_metadata`'s ``code_sha256`` lets a test check against git afterwards."""
    env = os.environ.get("GIT_COMMIT")
    if env:
        return env
    try:
        out = subprocess.run(["git", "rev-parse", "HEAD"], cwd=REPO, capture_output=True, text=True, timeout=10)
        if out.returncode == 0:
            commit = out.stdout.strip()
            dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=REPO,
                                   capture_output=True, text=True, timeout=10).stdout.strip()
            if dirty and os.environ.get(DIRTY_OK) != "1":
                raise SystemExit(f"benchmarks: tracked files differ from commit {commit[:12]} ({len(dirty.splitlines())} "
                                 f"changed): commit first, so the result records the code it measured, or set "
                                 f"{DIRTY_OK}=1 for a trial run (recorded '-dirty', not to be committed)")
            return commit + ("-dirty" if dirty else "")
    except (OSError, subprocess.SubprocessError):
        pass
    return "unknown"


def _nvidia_smi_driver() -> str | None:
    try:
        out = subprocess.run(["nvidia-smi", "--query-gpu=driver_version", "--format=csv,noheader"],
                             capture_output=True, text=True, timeout=20)
        if out.returncode == 0 and out.stdout.strip():
            return out.stdout.strip().splitlines()[0]
    except (OSError, subprocess.SubprocessError):
        pass
    return None


def run_metadata(device) -> dict:
    """Device name, driver, Warp version, commit, date, host."""
    import warp as wp

    meta = {
        "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "git_commit": git_commit(),
        "code_sha256": code_hash(),
        "warp_version": wp.__version__,
        "numpy_version": np.__version__,
        "python": platform.python_version(),
        "host": platform.node(),
        "cpu": platform.processor() or platform.machine(),
        "cpu_count": os.cpu_count(),
        "device": str(device),
        "device_name": device.name,
    }
    if device.is_cuda:
        drv = None
        try:
            v = wp._src.context.runtime.driver_version  # CUDA driver API version, e.g. (13, 0)
            drv = ".".join(str(x) for x in v) if isinstance(v, (tuple, list)) else str(v)
        except Exception:  # noqa: BLE001 - best effort
            pass
        meta["cuda_driver_api"] = drv
        meta["driver"] = _nvidia_smi_driver() or drv
        try:
            tk = wp._src.context.runtime.toolkit_version
            meta["cuda_toolkit"] = ".".join(str(x) for x in tk) if isinstance(tk, (tuple, list)) else str(tk)
        except Exception:  # noqa: BLE001
            pass
        meta["sm_count"] = device.sm_count
        meta["arch"] = device.arch
        meta["total_memory"] = int(device.total_memory)
    else:
        meta["driver"] = None
    return meta


def device_kind(name: str) -> str:
    """'h100', 'h200' or 'cpu'/'other' from a device name."""
    n = name.lower()
    if "h200" in n:
        return "h200"
    if "h100" in n:
        return "h100"
    if n in ("cpu",) or "cpu" in n:
        return "cpu"
    return "other"


def device_tag(device: str) -> str:
    """A device name fit for a file name: 'cuda:0' -> 'cuda0'."""
    return device.replace(":", "")


def save_study(ds, root: Path, stem: str, tag: str, plot, summary) -> Path:
    """Write a study's dataset to root/data/<stem>_<tag>.nc, draw its figures under root/figures
    with ``plot(ds, fig_dir, tag)``, and print the paths and ``summary(ds)``."""
    (root / "data").mkdir(parents=True, exist_ok=True)
    path = root / "data" / f"{stem}_{tag}.nc"
    ds.to_netcdf(path, engine="netcdf4")
    print(path)
    for p in plot(ds, root / "figures", tag):
        print(p)
    print(summary(ds))
    return path


def write_json(path: str | Path, obj) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(path.suffix + ".tmp")
    with open(tmp, "w") as f:
        json.dump(obj, f, indent=1, default=_json_default)
    os.replace(tmp, path)
    return path


def _json_default(o):
    if isinstance(o, (np.integer,)):
        return int(o)
    if isinstance(o, (np.floating,)):
        return float(o)
    if isinstance(o, np.ndarray):
        return o.tolist()
    return str(o)


# ---------------------------------------------------------------------- batches
def base_params(n: int, base_rigidity: float) -> dict:
    """n distinct columns: prestrain and v0 spread over their ranges (one column: the middle)."""
    if n == 1:
        p = np.array([np.mean(PRESTRAIN_RANGE)])
        v = np.array([np.mean(V0_RANGE)])
    else:
        p = np.linspace(*PRESTRAIN_RANGE, n)
        v = np.linspace(*V0_RANGE, n)[::-1].copy()
    return {"prestrain": p, "v0": v, "base_rigidity": np.full(n, float(base_rigidity))}


@contextlib.contextmanager
def skip_equilibrium_checks():
    """Skip the reference-state equilibrium diagnostics of the scene builders (their results are
    reported, never used by the engine): each is a dense least-squares solve of the (3n x nc)
    equilibrium matrix, ~97% of column_batch's host time at 200+ prisms (e.g. 31 s of 32 s for
    200 RB prisms on the 2-core dev machine)."""
    from warp_tensegrity.scene import batch as _batch
    from warp_tensegrity.scene import columns as _col

    saved = (_col.equilibrium_residual, _batch.equilibrium_residuals)
    _col.equilibrium_residual = lambda net: float("nan")
    _batch.equilibrium_residuals = lambda b: np.full(b.n_columns, np.nan)
    try:
        yield
    finally:
        _col.equilibrium_residual, _batch.equilibrium_residuals = saved


def build_base_batch(n_prisms: int, base_rigidity: float, n_columns: int = BASE_COLUMNS,
                     check_equilibrium: bool = False):
    """column_batch of ``n_columns`` distinct columns (see base_params)."""
    from warp_tensegrity import ColumnConfig, column_batch

    params = base_params(n_columns, base_rigidity)
    if check_equilibrium:
        return column_batch(ColumnConfig(n_prisms=n_prisms), params)
    with skip_equilibrium_checks():
        return column_batch(ColumnConfig(n_prisms=n_prisms), params)


def tile_batch(batch, B: int):
    """The first B columns of ``batch`` repeated cyclically (per-column arrays only)."""
    b0 = batch.n_columns
    if B == b0:
        return batch
    idx = np.arange(B) % b0

    def take(a):
        if a is None:
            return None
        a = np.asarray(a)
        if a.ndim >= 1 and a.shape[0] == b0 and b0 > 1:
            return np.ascontiguousarray(a[idx])
        return a

    changes = {}
    for f in dataclasses.fields(batch):
        if f.name in ("positions", "fixed", "constraints", "cables", "level_nodes", "constraint_names",
                      "cable_names", "n_columns", "params"):
            continue
        changes[f.name] = take(getattr(batch, f.name))
    changes["velocity"] = np.ascontiguousarray(np.asarray(batch.velocity)[idx])
    changes["params"] = {k: np.asarray(v)[idx] for k, v in batch.params.items()}
    changes["n_columns"] = B
    return dataclasses.replace(batch, **changes)


def rattle_dt(batch, safety: float = 0.25) -> float:
    """The step RunSettings(dt='auto') would choose before rounding to the output interval:
    dt_safety * 2 / omega_max (RATTLE's stability limit on the Gershgorin bound)."""
    from warp_tensegrity.scene.batch import omega_max_bound
    from warp_tensegrity.types import STABILITY

    omega = float(omega_max_bound(batch).max())
    return safety * STABILITY["rattle"] / omega


# ---------------------------------------------------------------------- kernels
def kernel_modules(spaces) -> list:
    """Modules of the RATTLE step's kernels found in the given kernel namespaces, and the step counter's."""
    import warp as wp

    from warp_tensegrity.sim.step import advance_counter_by

    return [getattr(ns, n).module for ns in spaces for n in RATTLE_KERNELS
            if isinstance(getattr(ns, n, None), wp.Kernel)] + [advance_counter_by.module]


def rattle_modules(precision: str, bandwidths=(3, 6), register_caps=(None,)):
    """Modules of the staged RATTLE kernels for the Gram-matrix half-bandwidths of FB (3) and RB (6)
    columns and the given register caps (the solver kernels are compiled per bandwidth and cap)."""
    from warp_tensegrity.sim.staged.kernels import make_kernels
    from warp_tensegrity.sim.staged.solver import make_solver_kernels
    from warp_tensegrity.sim.model import REAL

    real = REAL[precision]
    return kernel_modules([make_kernels(real)] + [make_solver_kernels(real, bw, regs) for bw in bandwidths
                                                   for regs in register_caps])


def precompile(device, precisions, max_workers: int | None = None) -> float:
    """Compile (or load from the kernel cache) the RATTLE kernels of each precision, in parallel
    threads. Returns the seconds taken."""
    import warp as wp

    from warp_tensegrity.sim.staged import step as integrate  # the staged step's launch constants

    caps = (None, integrate.COLUMN_MAX_REGISTERS) if device.is_cuda else (None,)  # capped from COLUMN_CAP_FROM
    mods = []
    for p in precisions:
        mods += rattle_modules(p, register_caps=caps)
    workers = max_workers if max_workers is not None else max(1, min(len(mods), os.cpu_count() or 1, 16))
    t0 = time.perf_counter()
    # block_dim=None: the variant an ordinary launch uses (1 on the CPU, the module default on CUDA)
    try:
        wp.force_load(device=device, modules=mods, max_workers=workers)
    except Exception as exc:  # noqa: BLE001 - fall back to serial loading, then to lazy loads
        print(f"[precompile] parallel load failed ({exc!r}); loading serially", flush=True)
        for m in mods:
            try:
                wp.force_load(device=device, modules=[m], max_workers=0)
            except Exception as exc2:  # noqa: BLE001
                print(f"[precompile] {m.name}: {exc2!r} (will load at first launch)", flush=True)
    return time.perf_counter() - t0


def kernel_resources(kernel, device, block_dim: int) -> dict:
    """Registers, local (spill) bytes, static shared bytes, resident blocks and warps per SM of a
    Warp kernel as loaded on a CUDA device with ``block_dim`` threads a block (cuFuncGetAttribute,
    cuOccupancyMaxActiveBlocksPerMultiprocessor)."""
    import ctypes

    cuda = ctypes.CDLL("libcuda.so.1")
    exe = kernel.module.execs[(device.context, block_dim)]
    func = ctypes.c_void_p(exe.get_kernel_hooks(kernel).forward)
    out = {}
    for name, attr in (("registers", 4), ("local_bytes", 3), ("static_shared_bytes", 1)):
        v = ctypes.c_int()
        cuda.cuFuncGetAttribute(ctypes.byref(v), attr, func)
        out[name] = v.value
    n = ctypes.c_int()
    cuda.cuOccupancyMaxActiveBlocksPerMultiprocessor(ctypes.byref(n), func, block_dim, ctypes.c_size_t(0))
    out["blocks_per_sm"] = n.value
    out["warps_per_sm"] = n.value * -(-block_dim // 32)
    return out


# ---------------------------------------------------------------------- memory
def _array_bytes(a) -> int:
    import warp as wp

    if isinstance(a, wp.array):
        return int(a.size) * int(wp.types.type_size_in_bytes(a.dtype))
    return 0


def integrator_bytes(integ) -> dict:
    """Bytes held by the Integrator's device arrays: model (topology + parameters), data (state
    and solver scratch) and outputs."""
    out = {"model": 0, "data": 0, "outputs": 0}
    for f in dataclasses.fields(integ.model):
        out["model"] += _array_bytes(getattr(integ.model, f.name))
    for f in dataclasses.fields(integ.data):
        v = getattr(integ.data, f.name)
        if isinstance(v, dict):
            out["data"] += sum(_array_bytes(x) for x in v.values())
        else:
            out["data"] += _array_bytes(v)
    fk = getattr(integ, "stepper", None)  # the Step's own rows (sim.block.step.FusedStep, sim.lanes.lanes.LaneStep)
    if fk is not None:
        for name in ("sx", "sq", "sa", "sb", "xy", "hz", "hand"):  # FusedStep's rows or LaneStep's lane arrays
            if getattr(fk, name, None) is not None:
                out["data"] += _array_bytes(getattr(fk, name))
    for name in ("strain", "kinetic", "elastic"):
        out["outputs"] += _array_bytes(getattr(integ, name, None))
    out["total"] = out["model"] + out["data"] + out["outputs"]
    return out


def mempool_used(device) -> int | None:
    import warp as wp

    try:
        if device.is_cuda and wp.is_mempool_enabled(device):
            return int(wp.get_mempool_used_mem_current(device))
    except Exception:  # noqa: BLE001
        pass
    return None


# ---------------------------------------------------------------------- timing
def iteration_diagnostics(integ, steps: int) -> dict:
    """Newton iterations of the position projection over ``steps`` eager steps (see time_batch)."""
    import warp as wp

    hist = []
    for _ in range(steps):
        integ.data.iters.zero_()
        integ.step()
        hist.append(integ.data.iters.numpy().astype(np.float64))
    wp.synchronize_device(integ.device)
    h = np.array(hist)  # (steps, B)
    pad = (-h.shape[1]) % 32
    hw = np.pad(h, ((0, 0), (0, pad))).reshape(h.shape[0], -1, 32).max(axis=2)
    return {"mean_iters": float(h.mean()), "warp32_max_iters_mean": float(hw.mean()), "diag_max_iters": int(h.max())}


@dataclasses.dataclass
class TimedPoint:
    B: int
    n_prisms: int
    path: str
    base: str
    precision: str
    n_nodes: int
    n_cables: int
    n_constraints: int
    bandwidth: int
    dt: float
    steps: int
    wall_s: float
    column_steps_per_s: float
    node_steps_per_s: float
    seconds_per_step: float
    rep_seconds_per_step: list
    steps_per_graph: int
    graph: bool
    bytes_per_column: float
    array_bytes: dict
    mempool_bytes: int | None
    mempool_bytes_per_column: float | None
    build_s: float
    warmup_s: float
    max_projection_iters: int
    n_failed: int
    output_every: int
    mean_iters: float | None = None
    warp32_max_iters_mean: float | None = None
    diag_max_iters: int | None = None

    def as_dict(self):
        return dataclasses.asdict(self)


def time_batch(batch, base_label: str, n_prisms: int, precision: str, device, target_s: float,
               reps: int = 3, max_steps: int = 1_000_000, steps_per_graph: int = 50, output_every: int = 100,
               dt: float | None = None, diag_steps: int = 10, path: str = "fused") -> TimedPoint:
    """Build an Integrator for ``batch``, warm it up (kernels, graph capture), then time
    ``reps`` segments of n steps each (n chosen so that all segments take about target_s).

    ``path``: 'fused' (one block per column, :mod:`warp_tensegrity.sim.block.kernels`, block cyclic
    reduction), 'fused-serial' (the same with lane 0's serial banded Cholesky) or 'staged' (one
    kernel per stage, the columns' solves one thread each).

    Per-step rate = total steps / total wall; rep_seconds_per_step gives each segment's rate.
    Then (untimed) ``diag_steps`` eager steps read the Newton iteration count of every column
    after each step: mean_iters (per column-step) and warp32_max_iters_mean (mean over steps of
    the largest count in each group of 32 consecutive columns: what a GPU warp waits for).
    """
    import warp as wp

    from warp_tensegrity import RunSettings
    from warp_tensegrity.sim.integrate import Integrator
    from warp_tensegrity.types import Path as LaunchPath

    B = batch.n_columns
    dt = rattle_dt(batch) if dt is None else dt
    t_build = time.perf_counter()
    gc.collect()
    wp.synchronize_device(device)
    pool0 = mempool_used(device)
    # outputs every `output_every` steps; the record kernels launch every step and return early
    # otherwise. n_out covers at most 64 records (later records are skipped by the kernel's bound).
    settings = RunSettings(t_end=dt * output_every * 64, dt=dt, method="rattle", precision=precision,
                           device=str(device), record_strain=False, steps_per_graph=steps_per_graph,
                           fused=path != "staged")
    integ = Integrator(batch, settings, dt, output_every, 64, path=LaunchPath(path))
    if path == "staged":
        # the needed kernels were force-loaded with the launch block size; Integrator.load_kernels
        # would also compile the RK4-only kernels (and, on the CPU, a second block-size variant)
        mods = kernel_modules([integ.k, integ.stepper.ks])
        integ.load_kernels = lambda: wp.force_load(device=device, modules=mods, max_workers=0)  # cheap when loaded
    wp.synchronize_device(device)
    pool1 = mempool_used(device)
    build_s = time.perf_counter() - t_build

    t0 = time.perf_counter()
    integ.initialize()
    wp.synchronize_device(device)
    # eager probe of 2 steps (CUDA: async launches plus launch overhead, so it over-estimates
    # the step time at small B; it only sizes the graph and the segments)
    integ.settings.steps_per_graph = 1 << 30
    tp = time.perf_counter()
    integ.advance(2)
    wp.synchronize_device(device)
    probe = (time.perf_counter() - tp) / 2.0
    graph = bool(device.is_cuda)
    spg = steps_per_graph
    if graph:
        # at large B keep one graph launch under ~1/3 of a segment
        seg = target_s / reps
        spg = int(max(1, min(steps_per_graph, math.floor(seg / 3.0 / max(probe, 1e-9)))))
        if path != "staged":
            # whole fused launches: each launch factors A(u) once, so short launches would over-count it
            q = integ.stepper.steps_per_launch
            spg = max(q, spg - spg % q)
        integ.settings.steps_per_graph = spg
        integ.advance(spg)  # capture + first replay
        wp.synchronize_device(device)
        tp = time.perf_counter()
        integ.advance(spg)
        wp.synchronize_device(device)
        probe = (time.perf_counter() - tp) / spg
    warmup_s = time.perf_counter() - t0

    def segments(per_step):
        n = max(1, int(round(target_s / reps / max(per_step, 1e-9))))
        if graph:
            n = max(spg, int(round(n / spg)) * spg)
        n = min(n, max(1, max_steps // reps))
        times = []
        for _ in range(reps):
            t = time.perf_counter()
            integ.advance(n)
            wp.synchronize_device(device)
            times.append(time.perf_counter() - t)
        return n, times

    per_rep, rep_times = segments(probe)
    if sum(rep_times) < 0.5 * target_s and per_rep * reps < max_steps:
        # the probe over-estimated the step time (first steps, a busy host): size again
        per_rep, rep_times = segments(sum(rep_times) / (per_rep * reps))
    wall = float(sum(rep_times))
    steps = per_rep * reps
    n_failed = integ.n_failed()
    iters = int(integ.data.iters.numpy().max())
    # diagnostics cost at most ~1/3 of the timed seconds (2..diag_steps steps)
    n_diag = min(diag_steps, max(2, int(target_s / 3.0 / max(wall / steps, 1e-9)))) if diag_steps > 0 else 0
    diag = iteration_diagnostics(integ, n_diag) if n_diag > 0 else {}
    ab = integrator_bytes(integ)
    m = integ.model
    mem_pool = None if (pool0 is None or pool1 is None) else pool1 - pool0
    point = TimedPoint(
        B=B, n_prisms=n_prisms, path=path, base=base_label, precision=precision, n_nodes=m.n_nodes, n_cables=m.n_cables,
        n_constraints=m.n_constraints, bandwidth=m.bandwidth, dt=dt, steps=steps, wall_s=wall,
        column_steps_per_s=B * steps / wall, node_steps_per_s=B * m.n_nodes * steps / wall,
        seconds_per_step=wall / steps, rep_seconds_per_step=[t / per_rep for t in rep_times],
        steps_per_graph=spg if graph else 0, graph=graph, bytes_per_column=ab["total"] / B, array_bytes=ab,
        mempool_bytes=mem_pool, mempool_bytes_per_column=None if mem_pool is None else mem_pool / B,
        build_s=build_s, warmup_s=warmup_s, max_projection_iters=iters, n_failed=n_failed,
        output_every=output_every, **diag,
    )
    del integ
    gc.collect()
    return point
