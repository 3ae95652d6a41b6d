"""Planning a sweep: bind a spec to an output, split its columns into shards, resolve dt once for
the whole sweep (so every shard steps alike), and describe the run (dry run)."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from ..engine import NOT_CHECKED, choose_path, estimate_batch
from ..provenance import code_version
from ..settings import RunSettings
from .progress import fmt_seconds
from .budget import check_plan
from .errors import SpecError
from .manifest import shard_dir_for
from .store import limit_shard_size, parse_bytes

if TYPE_CHECKING:
    from .spec import SweepSpec


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
    """Host bytes for the sweep's data (:func:`apply_memory_limit`); None: no limit."""
    prisms_simulated: int | None = None
    """Prisms every shard simulates (settings.truncate: decided once from all the sweep's columns,
    so no shard's results depend on which columns it holds)."""

    @property
    def n_shards(self) -> int:
        return len(self.shards)

    @property
    def n_columns(self) -> int:
        return self.spec.n_columns

    @property
    def shard_dir(self) -> Path:
        return shard_dir_for(self.out)

    def resolve(self) -> SweepPlan:
        """Resolve dt once for the whole sweep (:func:`resolve_dt`)."""
        return resolve_dt(self)

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
    plan.prisms_simulated = int(est["prisms_simulated"])  # depends on t_end and truncate only, as the probe's
    return plan


def apply_memory_limit(plan: SweepPlan, memory_limit) -> SweepPlan:
    """Shrink the shard size so the shards alive on the host fit in ``memory_limit`` (bytes or
    '64MB'; :func:`~warp_tensegrity.sweep.store.limit_shard_size`)."""
    if memory_limit is None:
        return plan
    plan.memory_limit = parse_bytes(memory_limit) if isinstance(memory_limit, str) else int(memory_limit)
    n = limit_shard_size(plan, plan.memory_limit)
    if n != plan.shard_size:
        plan.shard_size = n
        plan.shards = plan.spec.shards(n)
    return plan


def dry_run(plan: SweepPlan, costs: dict | None = None) -> str:
    """What a run would do: columns, shards, dt, steps, memory and time estimates. ``costs``: the
    calibrated prediction (:func:`warp_tensegrity.calibrate.estimate_plan`, which the CLI passes);
    without it, memory and time are the engine's uncalibrated figures."""
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
    dt_txt = f"{plan.dt:.4g} s"
    if isinstance(r["dt"], str):
        dt_txt += f" (auto: {plan.estimate.get('dt_safety', r['dt_safety']):.4g} x limit {plan.dt_limit:.4g} s)"
    else:
        dt_txt += f" (explicit; limit {plan.dt_limit:.4g} s)"
    lines = [
        f"spec:        {spec.source or '<text>'} (sha256 {spec.text_sha256[:12]})",
        f"columns:     {spec.describe()}",
        f"shards:      {plan.n_shards} of up to {plan.shard_size} columns -> {plan.shard_dir}/ (Zarr store)",
        f"method:      {r['method']} {r['precision']}, dt = {dt_txt}",
        f"steps:       {n_steps} to t_end = {r['t_end']} s, {n_out} outputs",
    ]
    auto = "" if plan.device else " (auto: the GPU if there is one, else the CPU)"
    step_path = f"step path:   {_step_path(plan)} (per shard of {max(b - a for a, b in plan.shards)} columns)"
    if costs is not None:
        p = costs["probe"]
        lines += [
            f"device:      {costs['device']}{auto}",
            step_path,
            f"memory:      {_fmt_bytes(costs['device_bytes_per_shard'])} device memory per shard, "
            f"{_fmt_bytes(costs['host_peak_bytes'])} peak host memory",
        ]
    else:
        dev_bytes = int(est.get("bytes_per_column", 0)) * max(b - a for a, b in plan.shards)
        lines += [f"device:      {plan.device or 'auto'}{auto}", step_path,
                  f"memory:      {_fmt_bytes(dev_bytes)} device memory per shard (uncalibrated)"]
    lines.append(f"output:      {_fmt_bytes(out_bytes)} uncompressed"
                 + ("" if r["record_strain"] else " (strain not stored: record_strain = false)"))
    if costs is not None:
        lines += [
            f"time:        ~{fmt_seconds(costs['seconds'])} wall ("
            + ", ".join(f"{k} {v:.3g} s" for k, v in costs["stages_s"].items()) + ")",
            f"calibration: {p['probe_columns']} columns x {p['probe_steps']} steps on this device "
            f"({p['column_step_seconds']:.3g} s per column-step; cached {p['created']})",
        ]
    else:
        spc = float(est.get("seconds_per_column_step_estimate", float("nan")))
        lines.append(f"time:        ~{fmt_seconds(spc * n_steps * n)} stepping (uncalibrated flop count)")
    return "\n".join(lines)


def _step_path(plan: SweepPlan) -> str:
    """The launch path (engine.choose_path) a shard takes: 'lanes', 'fused', 'fused-serial' or
    'staged' (whether the lane step takes the columns is decided once for the whole sweep)."""
    est = plan.estimate
    shard = max(b - a for a, b in plan.shards)
    return str(choose_path(plan.settings, bool(est.get("on_gpu")), shard, int(est.get("bandwidth", 0)),
                           est.get("lane_refusal", NOT_CHECKED)).value)


def _fmt_bytes(b: float) -> str:
    for unit in ("B", "kB", "MB", "GB", "TB"):
        if abs(b) < 1000 or unit == "TB":
            return f"{b:.0f} {unit}" if unit == "B" else f"{b:.1f} {unit}"
        b /= 1000.0
    return f"{b:.1f} TB"
