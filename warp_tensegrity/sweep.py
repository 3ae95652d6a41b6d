"""Run a sweep spec: plan the shards, run each shard through the engine, measure every column,
stream each finished shard into the sweep's Zarr store, export netCDF (see :mod:`.zstore`).

Files for ``OUT.nc``: ``OUT.nc.sweep/`` (store.zarr, manifest.json with per-shard checksums,
spec.toml), ``.OUT.nc.lock`` while a run writes, and the netCDF export ``OUT.nc``.

A shard is reused only when the manifest records it, its data match their checksums, and the
store was made for the same fingerprint (canonical spec + code version), shard size and Warp
version; every other shard is recomputed. The engine is called only through :func:`simulate_batch`.
"""

from __future__ import annotations

import dataclasses
import math
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import dataset as D
from .settings import RunSettings
from .spec import SpecError, SweepSpec, code_version, load_spec



class SweepError(RuntimeError):
    """A sweep cannot run, resume or combine as asked; the message says what to do."""


# ---------------------------------------------------------------------- engine entry points
def simulate_batch(config, params, settings, progress=None, prisms_simulated=None):
    """The one place the engine runs (tests monkeypatch this)."""
    from .simulate import simulate_batch as engine

    return engine(config, params, settings, progress=progress, prisms_simulated=prisms_simulated)


def estimate_batch(config, params, settings) -> dict:
    """The engine's cost/stability estimate (no kernel launch)."""
    from .simulate import estimate_batch as engine_estimate

    return engine_estimate(config, params, settings)


def measure_pulse(strain, time, prism_height, threshold=None) -> dict:
    from .measure import measure_pulse as measure

    return measure(strain, time, prism_height, threshold=threshold)


# ---------------------------------------------------------------------- planning
def shard_dir_for(out) -> Path:
    """The run's work directory (store, manifest, spec copy)."""
    from .zstore import work_dir_for

    return work_dir_for(out)


@dataclass
class SweepPlan:
    """A spec bound to an output, its shards and the resolved run settings."""

    spec: SweepSpec
    out: Path | None
    shard_size: int
    shards: list
    """[(start, stop)] per shard."""
    params: dict
    """Every per-column parameter, shape (N,)."""
    fingerprint: str
    code_version: str
    device: str | None
    """Requested device (None: the GPU if there is one, else the CPU)."""
    settings: RunSettings | None = None
    """Engine settings with dt resolved once for the whole sweep (None until estimated)."""
    estimate: dict = field(default_factory=dict)
    memory_limit: int | None = None
    """Host bytes for the sweep's data (apply_memory_limit); None: no limit."""
    prisms_simulated: int | None = None
    """Prisms every shard simulates (settings.truncate: decided once from all the sweep's columns)."""

    @property
    def n_shards(self) -> int:
        return len(self.shards)

    @property
    def n_columns(self) -> int:
        return self.spec.n_columns

    @property
    def shard_dir(self) -> Path:
        return shard_dir_for(self.out)

    @property
    def dt(self) -> float:
        return float(self.settings.dt)

    @property
    def dt_limit(self) -> float:
        return float(self.estimate.get("dt_limit", float("nan")))


def plan_sweep(
    spec: SweepSpec,
    out=None,
    *,
    device: str | None = None,
    shard_size: int | None = None,
    estimate: bool = True,
) -> SweepPlan:
    """Bind ``spec`` to ``out``; with ``estimate`` also ask the engine for the stability limit,
    refuse an explicit dt above it (SpecError naming the limit) and resolve dt = "auto" once
    for the whole sweep, so every shard steps with the same dt."""
    size = int(shard_size or spec.run["shard_size"])
    if size < 1:
        raise SpecError(f"shard_size = {size!r} must be a positive integer")
    dev = device if device is not None else spec.run["device"]
    plan = SweepPlan(
        spec=spec,
        out=Path(out).absolute() if out is not None else None,
        shard_size=size,
        shards=spec.shards(size),
        params=spec.column_params(),
        fingerprint="",
        code_version=code_version(),
        device=None if dev in (None, "auto") else dev,
    )
    plan.fingerprint = spec.fingerprint(plan.code_version)
    if estimate:
        resolve_dt(plan)
    return plan


def resolve_dt(plan: SweepPlan) -> SweepPlan:
    spec = plan.spec
    probe = dataclasses.replace(spec.run_settings(device=plan.device), allow_unstable_dt=True)
    est = dict(estimate_batch(spec.scene, plan.params, probe))
    plan.estimate = est
    spec.check_dt(float(est["dt_limit"]))
    dt = float(est["dt"]) if isinstance(spec.run["dt"], str) else float(spec.run["dt"])
    plan.settings = spec.run_settings(device=plan.device, dt=dt)
    from .simulate import prisms_to_simulate

    plan.prisms_simulated = prisms_to_simulate(spec.scene, plan.params, plan.settings)
    return plan


# ---------------------------------------------------------------------- one shard
def measure_columns(result, prism_height: float) -> dict:
    """Leading-pulse measurements per column (:func:`warp_tensegrity.measure.measure_pulse`);
    NaN where undefined and for every column whose status is not ok."""
    status = np.asarray(result.status)
    with np.errstate(all="ignore"):
        m = measure_pulse(result.strain, result.time, prism_height)
    bad = status != 0
    out = {
        "amplitude": m["amplitude"],
        "speed": m["speed"],
        "width": m["width_fwhm"],
        "width_10": m["width_10"],
        "prisms_measured": m["prisms_measured"],
        "arrival_time": m["arrival_time"],
    }
    out = {k: np.array(v, dtype=np.float64, copy=True) for k, v in out.items()}
    for v in out.values():
        v[bad] = np.nan
    return out


def compute_shard(plan: SweepPlan, index: int, device: str | None = None, progress=None):
    """Run shard ``index`` and return its case-stacked dataset (not written)."""
    if plan.settings is None:
        resolve_dt(plan)
    spec = plan.spec
    start, stop = plan.shards[index]
    params = {k: np.ascontiguousarray(v[start:stop]) for k, v in plan.params.items()}
    settings = plan.settings if device is None else dataclasses.replace(plan.settings, device=device)
    result = simulate_batch(spec.scene, params, settings, progress=progress, prisms_simulated=plan.prisms_simulated)
    meas = measure_columns(result, spec.scene.height)
    attrs = {
        "Conventions": D.CONVENTIONS,
        "fingerprint": plan.fingerprint,
        "code_version": plan.code_version,
        "package_version": D.package_version(),
        "warp_version": D.warp_version(),
        "git_commit": D.git_commit(),
        "spec_sha256": spec.text_sha256,
        "shard_index": index,
        "n_shards": plan.n_shards,
        "case_start": start,
        "case_stop": stop,
        "device": result.device,
        "device_name": result.device_name,
        "method": result.method,
        "precision": result.precision,
        "dt": float(result.dt),
        "dt_limit": plan.dt_limit,
        "n_steps": int(result.n_steps),
        "output_interval": float(result.time[1] - result.time[0]) if len(result.time) > 1 else float("nan"),
        "wall_time": float(result.wall_time),
        "history": f"{time.strftime('%Y-%m-%dT%H:%M:%S%z')} shard {index} computed by warp_tensegrity",
    }
    if spec.run["output_interval"] is not None:
        attrs["output_interval"] = float(spec.run["output_interval"])
    return D.shard_dataset(spec, plan.params, start, stop, result, meas, attrs)


def load_plan_from_manifest(out, *, device=None, shard_size=None, estimate=True) -> SweepPlan:
    from .zstore import read_run

    m = read_run(out)
    spec = load_spec(m["spec_text"])
    if m.get("spec_file"):
        spec.source = m["spec_file"]
    return plan_sweep(
        spec,
        out,
        device=device if device is not None else m.get("device"),
        shard_size=shard_size or m.get("shard_size"),
        estimate=estimate,
    )


# ---------------------------------------------------------------------- progress
def _fmt_seconds(s: float) -> str:
    if not math.isfinite(s):
        return "?"
    s = int(round(s))
    if s >= 3600:
        return f"{s // 3600}h{(s % 3600) // 60:02d}m"
    if s >= 60:
        return f"{s // 60}m{s % 60:02d}s"
    return f"{s}s"


class ProgressBar:
    """A one-line stderr bar: columns done, columns diverged, ETA."""

    def __init__(self, total: int, done: int = 0, diverged: int = 0, stream=None, enabled: bool = True, width: int = 28):
        self.total = max(int(total), 1)
        self.base_done = done
        self.base_diverged = diverged
        self.done = float(done)
        self.diverged = diverged
        self.stream = stream or sys.stderr
        self.enabled = enabled
        self.width = width
        self.t0 = time.monotonic()
        self.last = 0.0
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self._len = 0
        self._printed = None

    def update(self, done: float, diverged: int, force: bool = False):
        self.done, self.diverged = float(done), int(diverged)
        if not self.enabled:
            return
        now = time.monotonic()
        state = (int(self.done), self.diverged)
        if force and state == self._printed and now - self.last < 1.0:
            return  # nothing new to say
        if not force and now - self.last < (0.2 if self.tty else 10.0):
            return
        self.last = now
        self._printed = state
        frac = min(self.done / self.total, 1.0)
        fill = int(round(frac * self.width))
        elapsed = now - self.t0
        new = self.done - self.base_done
        remaining = self.total - self.done
        eta = elapsed * remaining / new if new > 0 else float("nan")
        line = (
            f"[{'#' * fill}{'.' * (self.width - fill)}] {int(self.done)}/{self.total} columns"
            f"  {self.diverged} diverged  elapsed {_fmt_seconds(elapsed)}  ETA {_fmt_seconds(eta if remaining > 0 else 0)}"
        )
        if self.tty:
            pad = " " * max(self._len - len(line), 0)
            self.stream.write("\r" + line + pad)
            self._len = len(line)
        else:
            self.stream.write(line + "\n")
        self.stream.flush()

    def close(self):
        if self.enabled:
            self.update(self.done, self.diverged, force=True)
            if self.tty:
                self.stream.write("\n")
                self.stream.flush()


# ---------------------------------------------------------------------- whole sweeps
def execute(plan: SweepPlan, *, resume: bool = False, overwrite: bool = False, progress: bool = True,
            dask_workers: int | None = None, scheduler: str | None = None, client=None, stream=None,
            combine_output: bool = True) -> Path | None:
    """Run (or resume) every shard of ``plan`` that is not done, streaming into the store; export plan.out."""
    from . import zstore

    return zstore.execute(plan, resume=resume, overwrite=overwrite, progress=progress, dask_workers=dask_workers,
                          scheduler=scheduler, client=client, stream=stream, export=combine_output)


def apply_memory_limit(plan: SweepPlan, memory_limit) -> SweepPlan:
    """Shrink the shard size so the shards alive on the host fit in ``memory_limit`` (bytes or '64MB')."""
    if memory_limit is None:
        return plan
    from .zstore import limit_shard_size, parse_bytes

    plan.memory_limit = parse_bytes(memory_limit) if isinstance(memory_limit, str) else int(memory_limit)
    n = limit_shard_size(plan, plan.memory_limit)
    if n != plan.shard_size:
        plan.shard_size = n
        plan.shards = plan.spec.shards(n)
    return plan


def run_sweep(spec, out, *, device=None, shard_size=None, resume=False, overwrite=False, progress=True,
              dask_workers=None, scheduler=None, client=None, stream=None, memory_limit=None) -> Path:
    """Run a spec (SweepSpec, path or TOML text) into ``out`` (netCDF, exported from ``out.sweep/``)."""
    if not isinstance(spec, SweepSpec):
        spec = load_spec(spec)
    plan = apply_memory_limit(plan_sweep(spec, out, device=device, shard_size=shard_size), memory_limit)
    return execute(plan, resume=resume, overwrite=overwrite, progress=progress, dask_workers=dask_workers,
                   scheduler=scheduler, client=client, stream=stream)


def resume_sweep(out, spec=None, *, device=None, shard_size=None, progress=True, dask_workers=None,
                 scheduler=None, client=None, stream=None) -> Path:
    """Finish an interrupted run: reuse the shards that check out, recompute the others, export."""
    if spec is None:
        plan = load_plan_from_manifest(out, device=device, shard_size=shard_size)
    else:
        if not isinstance(spec, SweepSpec):
            spec = load_spec(spec)
        plan = plan_sweep(spec, out, device=device, shard_size=shard_size)
    return execute(plan, resume=True, progress=progress, dask_workers=dask_workers, scheduler=scheduler,
                   client=client, stream=stream)


def combine(plan_or_out, spec=None) -> Path:
    """(Re-)export the finished store of a run to its netCDF output. Refuses while shards are not done."""
    from .zstore import export

    if isinstance(plan_or_out, SweepPlan):
        return export(plan_or_out.out, plan_or_out)
    return export(plan_or_out, spec if spec is None or isinstance(spec, SweepSpec) else load_spec(spec))


def sweep_status(out, spec=None) -> dict:
    """Cases done, diverged and remaining, per shard state (shards verified against their checksums)."""
    from .zstore import status

    if spec is None:
        plan = load_plan_from_manifest(out, estimate=True)
    else:
        plan = plan_sweep(spec if isinstance(spec, SweepSpec) else load_spec(spec), out)
    return status(plan)


def dry_run(plan: SweepPlan) -> str:
    """What a run would do: columns, shards, dt, steps, memory and time estimates."""
    spec, est = plan.spec, plan.estimate
    r = spec.run
    n = plan.n_columns
    n_steps = int(est.get("n_steps", 0))
    oi = r["output_interval"]
    n_out = int(math.floor(r["t_end"] / oi + 1e-9)) + 1 if oi else 201
    P = spec.scene.n_prisms
    per_col_out = 8 * (5 + 2 + P) + (8 * 2 * n_out if r["record_energy"] else 0)
    per_col_strain = 8 * n_out * P
    out_bytes = n * (per_col_out + (per_col_strain if r["record_strain"] else 0))
    dev_bytes = int(est.get("bytes_per_column", 0)) * max(b - a for a, b in plan.shards)
    host_shard = (per_col_out + per_col_strain) * max(b - a for a, b in plan.shards)
    spc = float(est.get("seconds_per_column_step_estimate", float("nan")))
    secs = spc * n_steps * n
    dt_txt = f"{plan.dt:.4g} s"
    if isinstance(r["dt"], str):
        dt_txt += f" (auto: {r['dt_safety']} x limit {plan.dt_limit:.4g} s)"
    else:
        dt_txt += f" (explicit; limit {plan.dt_limit:.4g} s)"
    lines = [
        f"spec:        {spec.source or '<text>'} (sha256 {spec.text_sha256[:12]})",
        f"columns:     {spec.describe()}",
        f"shards:      {plan.n_shards} of up to {plan.shard_size} columns -> {plan.shard_dir}/",
        f"method:      {r['method']} {r['precision']}, dt = {dt_txt}",
        f"steps:       {n_steps} to t_end = {r['t_end']} s, {n_out} outputs",
        f"device:      {plan.device or 'auto (the GPU if there is one, else the CPU)'}",
        f"memory:      {_fmt_bytes(dev_bytes)} device memory per shard, {_fmt_bytes(host_shard)} host memory per shard",
        f"output:      {_fmt_bytes(out_bytes)} uncompressed"
        + ("" if r["record_strain"] else " (strain not stored: record_strain = false)"),
        f"time:        ~{_fmt_seconds(secs)} ({n} columns x {n_steps} steps x {spc:.3g} s per column-step)",
    ]
    return "\n".join(lines)


def _fmt_bytes(b: float) -> str:
    for unit in ("B", "kB", "MB", "GB", "TB"):
        if abs(b) < 1000 or unit == "TB":
            return f"{b:.0f} {unit}" if unit == "B" else f"{b:.1f} {unit}"
        b /= 1000.0
    return f"{b:.1f} TB"
