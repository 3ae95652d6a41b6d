"""Planning a sweep: bind a spec to an output, split its columns into shards and decide the run once
for all of them (:func:`~warp_tensegrity.policy.decide.decide`: dt, truncation, path; so every
shard steps alike and no shard's results depend on which columns it holds), and describe it (dry
run) from the one cost model (:mod:`warp_tensegrity.policy.cost`)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path

from ..policy.cost import fmt_bytes, fmt_seconds, host_bytes_per_column
from ..policy.decide import RunPlan, decide
from ..provenance import code_version
from .budget import check_plan
from .errors import SpecError
from .manifest import shard_dir_for
from .spec import SweepSpec
from .store import limit_shard_size, parse_bytes


@dataclass
class SweepPlan:
    """A spec bound to an output, its shards and the run decided for them."""

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
    run: RunPlan | None = None
    """The run of every shard, decided once (None until decided: :func:`decide_sweep`)."""
    memory_limit: int | None = None
    """Host bytes for the sweep's data (``memory_limit`` of :func:`plan_sweep`); None: no limit."""

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
    def settings(self):
        """The settings every shard steps with (the run plan's)."""
        return self.run.settings

    @property
    def dt(self) -> float:
        return float(self.run.dt)

    @property
    def dt_limit(self) -> float:
        return float(self.run.dt_limit)


def plan_sweep(
    spec: SweepSpec,
    out=None,
    *,
    device: str | None = None,
    shard_size: int | None = None,
    estimate: bool = True,
    memory_limit=None,
) -> SweepPlan:
    """Bind ``spec`` to ``out``; with ``estimate`` also decide the run (:func:`decide_sweep`): an
    explicit dt above the stability limit is refused (SpecError naming the limit), dt = "auto" is
    resolved once for the whole sweep. ``memory_limit`` (bytes or '64MB') lowers the shard size so
    the shards alive on the host fit (:func:`~warp_tensegrity.sweep.store.limit_shard_size`)."""
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
        memory_limit=None if memory_limit is None else (
            parse_bytes(memory_limit) if isinstance(memory_limit, str) else int(memory_limit)),
    )
    plan.fingerprint = spec.fingerprint(plan.code_version)
    if estimate:
        decide_sweep(plan)
    return plan


def decide_sweep(plan: SweepPlan) -> SweepPlan:
    """Decide the run of every shard once (its path for the widest shard), then fit the shards to
    the memory limit."""
    spec = plan.spec
    settings = dataclasses.replace(spec.run_settings(device=plan.device), allow_unstable_dt=True)
    run = decide(spec.scene, plan.params, settings, n_columns=max(b - a for a, b in plan.shards))
    spec.check_dt(run.dt_limit)
    plan.run = dataclasses.replace(run, settings=dataclasses.replace(
        run.settings, allow_unstable_dt=spec.run["allow_unstable_dt"]))
    if plan.memory_limit is not None:
        per = host_bytes_per_column(plan.run, bool(spec.run["record_strain"]), bool(spec.run["record_energy"]))
        n = limit_shard_size(plan.shard_size, per, plan.memory_limit)
        if n != plan.shard_size:
            plan.shard_size, plan.shards = n, spec.shards(n)
    return plan


def dry_run(plan: SweepPlan, cost: dict) -> str:
    """What a run would do: columns, shards, dt, steps, path, memory, output and time, from the run
    plan and its cost (:func:`warp_tensegrity.policy.calibrate.estimate_plan`)."""
    spec, run = plan.spec, plan.run
    r = spec.run
    dt_txt = f"{plan.dt:.4g} s"
    if isinstance(r["dt"], str):
        dt_txt += f" (auto: {run.settings.dt_safety:.4g} x limit {plan.dt_limit:.4g} s)"
    else:
        dt_txt += f" (explicit; limit {plan.dt_limit:.4g} s)"
    p = cost["probe"]
    auto = "" if plan.device else " (auto: the GPU if there is one, else the CPU)"
    lines = [
        f"spec:        {spec.source or '<text>'} (sha256 {spec.text_sha256[:12]})",
        f"columns:     {spec.describe()}",
        f"shards:      {plan.n_shards} of up to {plan.shard_size} columns -> {plan.shard_dir}/ (Zarr store)",
        f"method:      {run.method} {run.precision}, dt = {dt_txt}",
        f"steps:       {run.n_steps} to t_end = {r['t_end']} s, {run.n_out} outputs",
        f"prisms:      {run.prisms_simulated} of {run.prisms} simulated",
        f"device:      {cost['device']}{auto}",
        f"step path:   {run.path.value} (decided for shards of {run.n_columns} columns)",
        f"memory:      {fmt_bytes(cost['device_bytes_per_shard'])} device memory per shard, "
        f"{fmt_bytes(cost['host_peak_bytes'])} peak host memory",
        f"output:      {fmt_bytes(cost['output_bytes'])} uncompressed"
        + ("" if r["record_strain"] else " (strain not stored: record_strain = false)")
        + f"; disk up to {fmt_bytes(cost['disk_bytes'])} (store {fmt_bytes(cost['store_bytes'])} + "
          f"{plan.out.name if plan.out else 'netCDF'} {fmt_bytes(cost['netcdf_bytes'])})",
        f"time:        ~{fmt_seconds(cost['seconds'])} wall ("
        + ", ".join(f"{k} {v:.3g} s" for k, v in cost["stages_s"].items()) + ")",
        f"calibration: {p['probe_columns']} columns x {p['probe_steps']} steps on this device "
        f"({p['column_step_seconds']:.3g} s per column-step; cached {p['created']}; --recalibrate renews it)",
    ]
    if p.get("compiled_modules"):
        lines.append(f"             the probe compiled {p['compiled_modules']} kernel modules ({p['probe_compile']:.3g} s) into "
                     "Warp's cache: the run loads them from there")
    if p.get("under_load"):
        lines.append(f"             taken while other work kept {100 * p['others_busy']:.0f} % of the cores busy: "
                     "the time may be high; it is re-measured once the host is idle")
    return "\n".join(lines)
