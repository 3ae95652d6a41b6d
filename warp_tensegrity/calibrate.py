"""Calibrated cost estimates: wall time and memory of a batch or a sweep predicted from a short
probe on the target device, not from constants.

The probe (:func:`probe`) runs the real engine path on a few columns of the sweep (the CPU backend
steps columns one after another, so 4 columns give the cost per column-step; on a GPU the probe
takes the shard's width, since the step time there is set by latency up to thousands of columns)
for ``PROBE_STEPS`` steps with the sweep's dt, output interval, method, precision and path
(fused or staged). It times build, stepping (after a first segment that loads kernels and
captures graphs), the device measurement of a record of the sweep's length, the device-to-host
copy and a netCDF write and read of a few MB; a fresh Python process times the imports and the
(warm-cache) kernel loads a run pays once. Results are cached as JSON under the user cache dir
(``platformdirs.user_cache_dir('warp_tensegrity')/calibration``), one file per device, method,
precision, path, scene and code version.

:func:`predict` turns a probe into stage seconds (import, build, compile, stepping, measurement,
transfer, write, finalise) and memory (device bytes per shard, host bytes).
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

PROBE_STEPS = 300
"""Steps timed by the probe (after a first segment of PROBE_WARM_STEPS)."""
PROBE_WARM_STEPS = 60
CPU_PROBE_COLUMNS = 4
CACHE_VERSION = 2


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


def process_age() -> float:
    """Seconds since this process was created (interpreter start included). Linux: /proc (10 ms
    ticks; psutil's create_time rounds the boot time to whole seconds); elsewhere psutil."""
    try:
        with open("/proc/self/stat") as f:
            start = int(f.read().rsplit(")", 1)[1].split()[19])
        with open("/proc/uptime") as f:
            up = float(f.read().split()[0])
        return up - start / os.sysconf("SC_CLK_TCK")
    except OSError:
        import psutil

        return time.time() - psutil.Process().create_time()


def _device(name):
    from .integrate import resolve_device

    return resolve_device(name)


def device_label(name=None) -> str:
    """'cpu (x86_64, 2 cores)' or 'cuda:0 (NVIDIA H100 80GB HBM3)': the device a run will use."""
    import platform

    d = _device(name)
    if d.is_cuda:
        return f"{d.alias} ({d.name})"
    return f"{d.alias} ({platform.machine()}, {os.cpu_count()} cores)"


def _probe_columns(n_columns: int, shard: int, is_cuda: bool) -> np.ndarray:
    if is_cuda:
        return np.arange(min(shard, n_columns))  # the first shard, at its width
    k = min(CPU_PROBE_COLUMNS, n_columns)
    return np.unique(np.round(np.linspace(0, n_columns - 1, k)).astype(int))


def _key(config, params, settings, shard, device) -> tuple[str, dict]:
    from .provenance import code_version

    cols = _probe_columns(len(next(iter(params.values()))) if params else 1, shard, device.is_cuda)
    desc = {
        "device": device_label(device.alias), "method": settings.method, "precision": settings.precision,
        "path": f"fused={settings.fused}", "shard": int(shard), "scene": repr(config), "dt": repr(settings.dt),
        "output_interval": repr(settings.output_interval), "probe_columns": len(cols),
        "params": {k: np.asarray(v, dtype=np.float64)[cols].tolist() for k, v in sorted(params.items())},
        "truncate": settings.truncate, "code": code_version(), "version": CACHE_VERSION,
        # every column's, not only the probe's: a rigid-base column anywhere keeps the lane step away
        "rigid_columns": bool(np.any(np.asarray(params.get("base_rigidity", 0.0), dtype=np.float64) >= 1.0)),
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


def _fresh_process_costs(device: str, config, params, settings, lanes_refused: str | None = None) -> dict:
    """Import and warm kernel-load seconds of a fresh process (what every run pays once), with
    the probe's columns (so the kernels are the ones the probe compiled)."""
    code = (
        "import time, json, sys; from warp_tensegrity.calibrate import process_age; t0 = time.perf_counter() - process_age()\n"
        "import warp as wp; wp.config.quiet = True\n"
        "from warp_tensegrity import cli, io, engine, integrate, sweep\n"
        "from warp_tensegrity.measure import device\n"
        "wp.init(); wp.get_device(sys.argv[1])\n"
        "t1 = time.perf_counter()\n"
        "import pickle, base64\n"
        "cfg, params, s, lanes = pickle.loads(base64.b64decode(sys.argv[2]))\n"
        "r = engine.simulate_batch(cfg, params, s, lanes_refused=lanes)\n"
        "st = r.info['stages']\n"
        "print(json.dumps({'import': t1 - t0, 'compile': st['compile'], 'rss': __import__('resource').getrusage(0).ru_maxrss * 1024}))\n"
    )
    import base64
    import pickle

    s = dataclasses.replace(settings, t_end=2 * float(settings.dt), output_interval=float(settings.dt),
                            record_strain=False)
    arg = base64.b64encode(pickle.dumps((config, params, s, lanes_refused))).decode()
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(Path(__file__).resolve().parents[1]), env.get("PYTHONPATH", "")])
    t0 = time.perf_counter()
    out = subprocess.run([sys.executable, "-c", code, device, arg], capture_output=True, text=True, env=env,
                         timeout=600)
    wall = time.perf_counter() - t0
    if out.returncode != 0:
        raise RuntimeError(f"calibration subprocess failed: {out.stderr[-2000:]}")
    res = json.loads(out.stdout.strip().splitlines()[-1])
    res["process"] = wall  # interpreter start and exit included
    return res


def _io_rates(tmp: Path) -> dict:
    """netCDF write and read seconds per byte (and per file) on this host, from a few-MB file."""
    import xarray as xr

    from . import io as D

    rng = np.random.default_rng(0)
    out = {}
    for n in (1, 400):  # a small and a ~8 MB file: fixed cost and rate
        ds = xr.Dataset({"strain": (("case", "time", "prism"), rng.standard_normal((n, 50, 50)))})
        p = tmp / f"io{n}.nc"
        t0 = time.perf_counter()
        D.write_netcdf(ds, p)
        t1 = time.perf_counter()
        D.open_sweep(p, load=True)
        t2 = time.perf_counter()
        out[n] = (ds.nbytes, t1 - t0, t2 - t1)
    (b0, w0, r0), (b1, w1, r1) = out[1], out[400]
    return {"write_fixed": w0, "write_per_byte": max(w1 - w0, 0.0) / (b1 - b0),
            "read_fixed": r0, "read_per_byte": max(r1 - r0, 0.0) / (b1 - b0)}


def probe(config, params: dict, settings, shard_size: int, use_cache: bool = True) -> dict:
    """Run (or read from the cache) the calibration probe of a batch/sweep on settings.device.
    ``settings`` must carry the resolved dt (seconds). Returns the measured rates (dict)."""
    import warp as wp

    from .engine import (_far_end, apply_accuracy, choose_path, choose_timestep, gram_bandwidth, lane_emulation,
                         lane_refusal, prisms_to_simulate)
    from .integrate import Integrator
    from .measure.device import load_kernels, measure_record
    from .scene.batch import column_batch, omega_max_bound
    from .types import Path as StepPath

    device = _device(settings.device)
    key, desc = _key(config, params, settings, shard_size, device)
    path = cache_dir() / f"{key}.json"
    if use_cache and path.exists():
        try:
            return json.loads(path.read_text())
        except (OSError, ValueError):
            pass
    n_total = len(next(iter(params.values()))) if params else 1
    cols = _probe_columns(n_total, shard_size, device.is_cuda)
    pp = {k: np.ascontiguousarray(np.asarray(v)[cols]) for k, v in params.items()}
    n = config.n_prisms
    n_sim = prisms_to_simulate(config, params, settings)
    s, _ = apply_accuracy(settings, n_sim)
    # as the engine runs it: the record is kept on the device for the measures
    s = dataclasses.replace(s, record_strain=s.record_strain or s.measure != "none")
    sim_cfg = _far_end(config, n_sim) if n_sim < n else config
    # batch assembly (reference states, equilibrium checks) as a + b x columns: medians of three
    # builds at two widths (the probe's and a quarter of it), as a shared 2-core host is noisy
    def build_time(p):
        times = []
        for _ in range(3):
            t0 = time.perf_counter()
            out = column_batch(sim_cfg, p)
            times.append(time.perf_counter() - t0)
        return float(np.median(times)), out

    n_small = max(1, len(cols) // 4)
    t_small, _ = build_time({k: v[:n_small] for k, v in pp.items()})
    t_full, batch = build_time(pp)
    b_col = max(t_full - t_small, 0.0) / (len(cols) - n_small) if len(cols) > n_small else 0.0
    a_batch = max(t_full - b_col * len(cols), 0.0)
    omega = float(omega_max_bound(batch).max())
    dt, _, _, every = choose_timestep(s, omega)
    # whole graph periods (as a run replays them): the fused path captures output periods
    spg = int(s.steps_per_graph)
    # the path a shard of the sweep takes (the key holds settings.fused, the shard width and the scene)
    # (the lane step decided from all the sweep's columns, as the plan decides it for every shard)
    lanes = lane_refusal(config, params, n_sim)
    step_path = choose_path(s, device.is_cuda, shard_size, gram_bandwidth(batch), lanes)
    fused = step_path in (StepPath.FUSED, StepPath.FUSED_SERIAL, StepPath.LANES)
    period = every * max(1, -(-spg // every)) if fused else spg
    seg_steps = period * max(1, -(-(PROBE_STEPS // 3) // period))
    warm_steps = period * max(1, -(-PROBE_WARM_STEPS // period))
    n_out = (warm_steps + 3 * seg_steps) // every + 1
    with lane_emulation(step_path, device):  # the CPU runs the lane step as fibers
        t0 = time.perf_counter()
        integ = Integrator(batch, s, dt, every, n_out, path=step_path)
        t_integ = time.perf_counter() - t0
        B = batch.n_columns
        with wp.ScopedDevice(integ.device):
            t0 = time.perf_counter()
            integ.initialize()
            load_kernels(integ.device)
            wp.synchronize_device(integ.device)
            t_init = time.perf_counter() - t0
            integ.advance(warm_steps)  # loads, graph capture
            wp.synchronize_device(integ.device)
            seg = []  # three segments, median: robust to a neighbour's burst on a shared host
            for _ in range(3):
                t0 = time.perf_counter()
                integ.advance(seg_steps)
                wp.synchronize_device(integ.device)
                seg.append((time.perf_counter() - t0) / seg_steps)
            t_step = float(np.median(seg))
            per_col, fixed = _array_bytes((integ.model, integ.data, integ.kinetic, integ.elastic), B)
            # measurement of a record of the sweep's length (sech^2 pulses crossing the column)
            T_full = int(math.ceil(float(settings.t_end) / float(dt) - 1e-9)) // every + 1
            tt = np.arange(T_full) * every * dt
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
        io = _io_rates(Path(tmp))
    fresh = _fresh_process_costs(integ.device.alias, config, pp, settings, lanes)
    res = {
        "key": key, "describe": desc, "created": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        "device_label": desc["device"], "is_cuda": bool(device.is_cuda), "step_path": str(step_path.value),
        "probe_columns": int(B), "probe_steps": 3 * seg_steps,
        "prisms_simulated": int(n_sim), "dt": float(dt), "output_every": int(every),
        "batch_fixed": a_batch, "batch_per_column": b_col, "integrator_build": t_integ, "initialize": t_init,
        "step_seconds": t_step, "column_step_seconds": t_step / B,
        "measure_seconds": tm["measurement"], "measure_samples": int(T_full),
        "transfer_per_byte": t_copy, "device_bytes_per_column": per_col / B, "device_bytes_fixed": fixed,
        "strain_bytes_per_sample": (4 if s.precision == "fp32" else 8) * n_sim,
        **{f"io_{k}": v for k, v in io.items()},
        "import": fresh["import"], "compile": fresh["compile"], "process": fresh["process"],
        "base_rss": fresh["rss"], "load_avg": os.getloadavg()[0],
    }
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_text(json.dumps(res, indent=1))
    os.replace(tmp, path)
    return res


def host_share(load: float | None = None) -> float:
    """Slow-down of host-bound work on a shared host: max(1, 1-minute load average / cores)."""
    load = os.getloadavg()[0] if load is None else load
    return max(1.0, float(load) / max(os.cpu_count() or 1, 1))


HOST_STAGES = ("import", "build", "compile", "transfer", "write", "finalise")
"""Stages bound by the host CPU wherever the step runs (on the CPU device: every stage)."""


def predict(cal: dict, n_columns: int, shard_sizes: list[int], n_steps: int, n_out: int, n_prisms: int,
            record_strain: bool, record_energy: bool = True, load: float | None = None) -> dict:
    """Stage seconds and memory of a run of ``shard_sizes`` columns from a probe ``cal``. Host-bound
    stages are rescaled from the host load at probe time to ``load`` (default: now; a shared
    host's load average, see :func:`host_share`)."""
    P = n_prisms
    st = dict.fromkeys(("import", "build", "compile", "stepping", "measurement", "transfer", "write", "finalise"), 0.0)
    st["import"] = cal["import"]
    st["compile"] = cal["compile"]
    scale_T = n_out / max(cal["measure_samples"], 1)
    out_bytes_total = 0
    # planning: the stability estimate builds every column once; then each shard builds its own
    st["build"] = cal["batch_fixed"] + cal["batch_per_column"] * n_columns
    for b in shard_sizes:
        st["build"] += cal["batch_fixed"] + cal["batch_per_column"] * b + cal["integrator_build"]
        if cal["is_cuda"]:
            # latency bound up to the probed width, then proportional
            st["stepping"] += n_steps * cal["step_seconds"] * max(1.0, b / cal["probe_columns"])
            st["measurement"] += cal["measure_seconds"] * scale_T * max(1.0, b / cal["probe_columns"])
        else:
            st["stepping"] += n_steps * cal["column_step_seconds"] * b
            st["measurement"] += cal["measure_seconds"] * scale_T * b / cal["probe_columns"]
        host = 8 * b * (10 + 3 * P + 2 * n_out + 2 * 3 * 3 * (P + 1))  # measures, energies, final state
        if record_strain:
            host += 8 * b * n_out * P
        st["transfer"] += cal["transfer_per_byte"] * host
        shard_out = 8 * b * (10 + P + (2 * n_out if record_energy else 0) + (n_out * P if record_strain else 0))
        out_bytes_total += shard_out
        st["write"] += cal["io_write_fixed"] + cal["io_write_per_byte"] * shard_out
        # each shard is read back once to check it, and once more when combined
        st["finalise"] += 2 * (cal["io_read_fixed"] + cal["io_read_per_byte"] * shard_out)
    st["finalise"] += cal["io_write_fixed"] + cal["io_write_per_byte"] * out_bytes_total
    bmax = max(shard_sizes) if shard_sizes else 0
    dev_bytes = cal["device_bytes_fixed"] + bmax * (cal["device_bytes_per_column"]
                                                    + cal["strain_bytes_per_sample"] * n_out
                                                    + 8 * (12 * P + 3 * n_out + 12))
    # imports and kernels, a shard's strain copy when it crosses, and the combine (every shard + the result)
    host_peak = cal["base_rss"] + (8 * bmax * n_out * P if record_strain else 0) + 2 * out_bytes_total
    ratio = host_share(load) / host_share(cal.get("load_avg", 0.0))
    for k in st:
        if k in HOST_STAGES or not cal["is_cuda"]:
            st[k] *= ratio
    return {"stages_s": st, "seconds": float(sum(st.values())), "host_load_ratio": ratio,
            "device_bytes_per_shard": int(dev_bytes),
            "host_peak_bytes": int(host_peak), "output_bytes": int(out_bytes_total), "device": cal["device_label"]}


def estimate_plan(plan, use_cache: bool = True) -> dict:
    """Calibrated prediction of a sweep plan (``sweep.plan.SweepPlan``, planned with its estimate,
    so dt is resolved): stage seconds, memory, the probe used."""
    if plan.settings is None:
        raise ValueError("the plan has no resolved settings: plan it with estimate=True")
    spec = plan.spec
    shard = max(b - a for a, b in plan.shards)
    cal = probe(spec.scene, plan.params, plan.settings, shard, use_cache=use_cache)
    est = plan.estimate
    return predict(cal, plan.n_columns, [b - a for a, b in plan.shards], int(est["n_steps"]), int(est["n_out"]),
                   spec.scene.n_prisms, bool(spec.run["record_strain"]), bool(spec.run["record_energy"])) | {"probe": cal}


def estimate_batch(config, params: dict, settings) -> dict:
    """:func:`warp_tensegrity.engine.estimate_batch` (dt, stability limit, steps) with time and
    device memory from the probe (in-process: no import, kernels taken as loaded):
    ``seconds_estimate``, ``stages_estimate``, ``device_bytes_estimate``, ``device_label``."""
    from dataclasses import replace

    from .engine import check_batch_arguments
    from .engine import estimate_batch as engine_estimate

    params = check_batch_arguments("estimate_batch", config, params, settings)
    out = dict(engine_estimate(config, params, settings))
    n_col = len(next(iter(params.values()))) if params else 1
    cal = probe(config, params, replace(settings, dt=out["dt"]), n_col)
    pred = predict(cal, n_col, [n_col], out["n_steps"], out["n_out"], config.n_prisms, settings.record_strain)
    st = pred["stages_s"]
    seconds = sum(st[k] for k in ("build", "stepping", "measurement", "transfer"))
    return out | {"seconds_estimate": seconds, "seconds_per_column_step_estimate": cal["column_step_seconds"],
                  "stages_estimate": st, "device_bytes_estimate": pred["device_bytes_per_shard"],
                  "device_label": cal["device_label"]}
