"""Run a sweep spec: plan the shards, run each shard through the engine, measure every column,
write one netCDF file per shard atomically, combine them into the sweep's dataset.

Files for ``OUT.nc``::

    OUT.nc.shards/manifest.json     what the shards belong to (fingerprint, shard size, device)
    OUT.nc.shards/spec.toml         the spec text (so ``resume OUT.nc`` needs nothing else)
    OUT.nc.shards/shard-00000.nc    columns [0, shard_size), ...
    OUT.nc                          the combined dataset

A shard is reused only when it opens cleanly, covers the same columns, carries the same
fingerprint (canonical spec + code version) and was made with the same Warp version;
every other shard is recomputed. The engine is called only through :func:`simulate_batch`.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import dataset as D
from .budget import check_plan
from .settings import RunSettings
from .spec import SpecError, SweepSpec, code_version, load_spec

MANIFEST = "manifest.json"
SPEC_COPY = "spec.toml"


class SweepError(RuntimeError):
    """A sweep cannot run, resume or combine as asked; the message says what to do."""


# ---------------------------------------------------------------------- engine entry points
def simulate_batch(config, params, settings, progress=None):
    """The one place the engine runs (tests monkeypatch this)."""
    from .simulate import simulate_batch as engine

    return engine(config, params, settings, progress=progress)


def estimate_batch(config, params, settings) -> dict:
    """The engine's cost/stability estimate (no kernel launch)."""
    from .simulate import estimate_batch as engine_estimate

    return engine_estimate(config, params, settings)


def measure_pulse(strain, time, prism_height, threshold=None) -> dict:
    from .measure import measure_pulse as measure

    return measure(strain, time, prism_height, threshold=threshold)


# ---------------------------------------------------------------------- planning
def shard_dir_for(out) -> Path:
    out = Path(out)
    return out.with_name(out.name + ".shards")


def shard_name(index: int) -> str:
    return f"shard-{index:05d}.nc"


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

    @property
    def n_shards(self) -> int:
        return len(self.shards)

    @property
    def n_columns(self) -> int:
        return self.spec.n_columns

    @property
    def shard_dir(self) -> Path:
        return shard_dir_for(self.out)

    def shard_path(self, index: int) -> Path:
        return self.shard_dir / shard_name(index)

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
    check_plan(spec)  # refuse, with the figures, a sweep whose planning would not fit in memory
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
    result = simulate_batch(spec.scene, params, settings, progress=progress)
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


def run_shard(plan: SweepPlan, index: int, device: str | None = None, progress=None) -> Path:
    """Compute shard ``index`` and write it atomically; returns its path."""
    ds = compute_shard(plan, index, device=device, progress=progress)
    return D.write_netcdf(ds, plan.shard_path(index))


# ---------------------------------------------------------------------- shard bookkeeping
@dataclass
class ShardState:
    index: int
    path: Path
    state: str
    """'done', 'missing', 'stale' (other spec/code/range) or 'corrupt' (does not open)."""
    reason: str = ""
    n_failed: int = 0
    n_columns: int = 0


def check_shard(plan: SweepPlan, index: int) -> ShardState:
    path = plan.shard_path(index)
    start, stop = plan.shards[index]
    if not path.exists():
        return ShardState(index, path, "missing", n_columns=stop - start)
    try:
        ds = D.open_sweep(path, load=True)
    except Exception as e:  # truncated or not netCDF at all
        return ShardState(index, path, "corrupt", f"{type(e).__name__}: {e}", n_columns=stop - start)
    a = ds.attrs
    reason = ""
    if a.get("fingerprint") != plan.fingerprint:
        reason = "fingerprint differs (spec or code changed)"
    elif (int(a.get("case_start", -1)), int(a.get("case_stop", -1))) != (start, stop):
        reason = f"covers columns {a.get('case_start')}:{a.get('case_stop')}, expected {start}:{stop}"
    elif a.get("warp_version") != D.warp_version():
        reason = f"made with Warp {a.get('warp_version')}, this is Warp {D.warp_version()}"
    elif ds.sizes.get("case") != stop - start or "status" not in ds:
        reason = "incomplete contents"
    if reason:
        return ShardState(index, path, "stale", reason, n_columns=stop - start)
    return ShardState(index, path, "done", n_failed=int((ds["status"].values != 0).sum()), n_columns=stop - start)


def _clean_tmp(shard_dir: Path) -> None:
    for p in shard_dir.glob(".*.tmp"):
        try:
            p.unlink()
        except OSError:
            pass


def _write_manifest(plan: SweepPlan) -> None:
    d = plan.shard_dir
    d.mkdir(parents=True, exist_ok=True)
    (d / f".{SPEC_COPY}.tmp").write_text(plan.spec.text)
    os.replace(d / f".{SPEC_COPY}.tmp", d / SPEC_COPY)
    manifest = {
        "spec_file": str(plan.spec.source) if plan.spec.source else None,
        "spec_sha256": plan.spec.text_sha256,
        "fingerprint": plan.fingerprint,
        "code_version": plan.code_version,
        "n_columns": plan.n_columns,
        "shard_size": plan.shard_size,
        "n_shards": plan.n_shards,
        "device": plan.device,
        "output": plan.out.name,
    }
    tmp = d / f".{MANIFEST}.tmp"
    tmp.write_text(json.dumps(manifest, indent=2) + "\n")
    os.replace(tmp, d / MANIFEST)


def read_manifest(out) -> dict:
    d = shard_dir_for(out)
    if not d.is_dir():
        raise SweepError(f"no run found for {out}: {d}/ does not exist (start one with `warp-tensegrity run SPEC -o {out}`)")
    try:
        manifest = json.loads((d / MANIFEST).read_text())
        text = (d / SPEC_COPY).read_text()
    except (OSError, ValueError) as e:
        raise SweepError(
            f"{d} has no readable {MANIFEST}/{SPEC_COPY} ({e}); give the spec: resume SPEC -o {out}"
        ) from None
    manifest["spec_text"] = text
    return manifest


def load_plan_from_manifest(out, *, device=None, shard_size=None, estimate=True) -> SweepPlan:
    m = read_manifest(out)
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
def _prepare_dir(plan: SweepPlan, overwrite: bool, resume: bool) -> None:
    d = plan.shard_dir
    if d.exists() and not resume:
        existing = sorted(d.glob("shard-*.nc"))
        if existing or (d / MANIFEST).exists():
            if not overwrite:
                raise SweepError(
                    f"{d} already holds a run ({len(existing)} shard files); continue it with "
                    f"`warp-tensegrity resume {plan.out}` or start over with --overwrite"
                )
            for p in existing + [d / MANIFEST, d / SPEC_COPY]:
                if p.exists():
                    p.unlink()
    if not resume and plan.out.exists():
        if not overwrite:
            raise SweepError(f"{plan.out} exists; give another output, or --overwrite to replace it")
        plan.out.unlink()
    d.mkdir(parents=True, exist_ok=True)
    _clean_tmp(d)
    _write_manifest(plan)


def execute(
    plan: SweepPlan,
    *,
    resume: bool = False,
    overwrite: bool = False,
    progress: bool = True,
    dask_workers: int | None = None,
    scheduler: str | None = None,
    client=None,
    stream=None,
    combine_output: bool = True,
) -> Path | None:
    """Run (or resume) every shard of ``plan`` that is not done, then combine into plan.out."""
    if plan.out is None:
        raise SweepError("no output path")
    if plan.settings is None:
        resolve_dt(plan)
    _prepare_dir(plan, overwrite=overwrite, resume=resume)
    states = [check_shard(plan, i) for i in range(plan.n_shards)] if resume else [
        ShardState(i, plan.shard_path(i), "missing", n_columns=b - a) for i, (a, b) in enumerate(plan.shards)
    ]
    todo = [s.index for s in states if s.state != "done"]
    done_cols = sum(s.n_columns for s in states if s.state == "done")
    done_failed = sum(s.n_failed for s in states if s.state == "done")
    bar = ProgressBar(plan.n_columns, done_cols, done_failed, stream=stream, enabled=progress)
    if todo:
        if dask_workers or scheduler or client is not None:
            from .scaleout import run_shards_dask

            run_shards_dask(plan, todo, n_workers=dask_workers, scheduler=scheduler, client=client, bar=bar)
        else:
            for i in todo:
                a, b = plan.shards[i]

                def cb(steps_done, n_steps, n_failed, _a=a, _b=b):
                    frac = steps_done / n_steps if n_steps else 1.0
                    bar.update(done_cols + (_b - _a) * frac, done_failed + n_failed)

                path = run_shard(plan, i, progress=cb)
                st = check_shard(plan, i)
                if st.state != "done":
                    raise SweepError(f"shard {i} was written to {path} but does not check out: {st.reason}")
                done_cols += b - a
                done_failed += st.n_failed
                bar.update(done_cols, done_failed, force=True)
    bar.close()
    if combine_output:
        return combine(plan)
    return None


def run_sweep(spec, out, *, device=None, shard_size=None, resume=False, overwrite=False, progress=True,
              dask_workers=None, scheduler=None, client=None, stream=None) -> Path:
    """Run a spec (SweepSpec, path or TOML text) into ``out`` (netCDF)."""
    if not isinstance(spec, SweepSpec):
        spec = load_spec(spec)
    plan = plan_sweep(spec, out, device=device, shard_size=shard_size)
    return execute(plan, resume=resume, overwrite=overwrite, progress=progress, dask_workers=dask_workers,
                   scheduler=scheduler, client=client, stream=stream)


def resume_sweep(out, spec=None, *, device=None, shard_size=None, progress=True, dask_workers=None,
                 scheduler=None, client=None, stream=None) -> Path:
    """Finish an interrupted run: reuse the shards that check out, recompute the others, combine."""
    if spec is None:
        plan = load_plan_from_manifest(out, device=device, shard_size=shard_size)
    else:
        if not isinstance(spec, SweepSpec):
            spec = load_spec(spec)
        plan = plan_sweep(spec, out, device=device, shard_size=shard_size)
    return execute(plan, resume=True, progress=progress, dask_workers=dask_workers, scheduler=scheduler,
                   client=client, stream=stream)


def combine(plan_or_out, spec=None) -> Path:
    """Combine every shard into plan.out (atomically). Refuses while shards are missing or stale."""
    plan = plan_or_out if isinstance(plan_or_out, SweepPlan) else None
    if plan is None:
        if spec is None:
            plan = load_plan_from_manifest(plan_or_out, estimate=False)
        else:
            plan = plan_sweep(spec if isinstance(spec, SweepSpec) else load_spec(spec), plan_or_out, estimate=False)
    bad = [s for s in (check_shard(plan, i) for i in range(plan.n_shards)) if s.state != "done"]
    if bad:
        listing = ", ".join(f"{s.index} ({s.state}{': ' + s.reason if s.reason else ''})" for s in bad[:8])
        more = f" and {len(bad) - 8} more" if len(bad) > 8 else ""
        raise SweepError(
            f"{len(bad)} of {plan.n_shards} shards are not done: {listing}{more}; "
            f"run `warp-tensegrity resume {plan.out}`"
        )
    shards = [D.open_sweep(plan.shard_path(i)) for i in range(plan.n_shards)]
    ds = D.combine_shards(plan.spec, shards)
    return D.write_netcdf(ds, plan.out)


def sweep_status(out, spec=None) -> dict:
    """Cases done, diverged and remaining, per shard state."""
    if spec is None and not shard_dir_for(out).exists() and Path(out).exists():
        return _status_from_output(out)
    if spec is None:
        plan = load_plan_from_manifest(out, estimate=False)
    else:
        plan = plan_sweep(spec if isinstance(spec, SweepSpec) else load_spec(spec), out, estimate=False)
    states = [check_shard(plan, i) for i in range(plan.n_shards)]
    done = [s for s in states if s.state == "done"]
    out = Path(out)
    combined = False
    if out.exists():
        try:
            with D.open_sweep(out, load=False) as ds:
                combined = ds.attrs.get("fingerprint") == plan.fingerprint
        except Exception:
            combined = False
    return {
        "output": str(out),
        "spec": plan.spec.source,
        "columns": plan.n_columns,
        "shards": plan.n_shards,
        "shard_size": plan.shard_size,
        "shards_done": len(done),
        "cases_done": sum(s.n_columns for s in done),
        "cases_diverged": sum(s.n_failed for s in done),
        "cases_remaining": plan.n_columns - sum(s.n_columns for s in done),
        "shards_missing": [s.index for s in states if s.state == "missing"],
        "shards_stale": [(s.index, s.reason) for s in states if s.state == "stale"],
        "shards_corrupt": [(s.index, s.reason) for s in states if s.state == "corrupt"],
        "combined": combined,
        "fingerprint": plan.fingerprint,
    }


def _status_from_output(out) -> dict:
    """Status of a combined output whose shard directory is gone."""
    try:
        ds = D.open_sweep(out)
    except Exception as e:
        raise SweepError(f"{out} does not open ({type(e).__name__}: {e}) and has no shard directory") from None
    n = int(ds.attrs.get("n_columns", ds["status"].size))
    return {
        "output": str(out),
        "spec": ds.attrs.get("spec_file"),
        "columns": n,
        "shards": 0,
        "shard_size": 0,
        "shards_done": 0,
        "cases_done": n,
        "cases_diverged": int((ds["status"].values != 0).sum()),
        "cases_remaining": 0,
        "shards_missing": [],
        "shards_stale": [],
        "shards_corrupt": [],
        "combined": True,
        "fingerprint": ds.attrs.get("fingerprint"),
    }


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
