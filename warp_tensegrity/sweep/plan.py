"""Planning a sweep: bind a spec to an output, split its columns into shards and decide the run once
for all of them (:func:`~warp_tensegrity.policy.decide.decide`: dt, truncation, path; so every
shard steps alike and no shard's results depend on which columns it holds), and describe it (dry
run) from the one cost model (:mod:`warp_tensegrity.policy.cost`)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..policy.cost import fmt_bytes, fmt_seconds, host_bytes_per_column
from ..policy.decide import RunPlan, default_shard_size
from ..policy.groups import RunGroup, decide_groups
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
    """The run of the stiffest group (the most steps; with one group, of every column), decided once
    (None until decided: :func:`decide_sweep`)."""
    groups: tuple[RunGroup, ...] = ()
    """The columns in groups of like stiffness, each with its run decided once
    (:func:`warp_tensegrity.policy.groups.decide_groups`); a shard runs its columns group by group."""
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
        """The smallest dt of the groups [s]."""
        return float(self.run.dt)

    @property
    def column_group(self) -> np.ndarray:
        """(N,) the group of every column (index into ``groups``)."""
        out = np.empty(self.n_columns, dtype=np.int32)
        for i, g in enumerate(self.groups):
            out[g.columns] = i
        return out

    def column_steps(self, shards=None) -> int:
        """Column-steps of the shards (default: all): what the groups save."""
        cg = self.column_group
        steps = np.array([g.plan.n_steps for g in self.groups])
        return int(sum(steps[cg[a:b]].sum() for a, b in (self.shards if shards is None else shards)))

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
    dev = device if device is not None else spec.run["device"]
    size = shard_size or spec.run["shard_size"]  # given, else from the device ('auto')
    size = int(size) if size is not None else default_shard_size(None if dev in (None, "auto") else dev)
    if size < 1:
        raise SpecError(f"shard_size = {size!r} must be a positive integer")
    check_plan(spec)  # refuse, with the figures, a sweep whose planning would not fit in memory
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
    groups = decide_groups(spec.scene, plan.params, settings, n_columns=max(b - a for a, b in plan.shards),
                           grouping=bool(spec.run["groups"]), twins=bool(spec.run["error_estimate"]))
    spec.check_dt(min(g.plan.dt_limit for g in groups))
    allow = spec.run["allow_unstable_dt"]
    plan.groups = tuple(dataclasses.replace(g, plan=dataclasses.replace(g.plan, settings=dataclasses.replace(
        g.plan.settings, allow_unstable_dt=allow))) for g in groups)
    plan.run = max((g.plan for g in plan.groups), key=lambda r: (r.n_steps, -r.dt))
    if plan.memory_limit is not None:
        per = host_bytes_per_column(plan.run, bool(spec.run["record_strain"]), bool(spec.run["record_energy"]))
        n = limit_shard_size(plan.shard_size, per, plan.memory_limit, plan.n_columns)
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
        *_group_lines(plan),
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
    if "twin_stepping_s" in cost:
        share = cost["twin_stepping_s"] / max(cost["stages_s"]["stepping"] - cost["twin_stepping_s"], 1e-30)
        lines.insert(-1, f"errors:      every measure's error estimated from a twin at ~4x dt (run.error_estimate): "
                         f"+{100 * share:.0f} % of the stepping, {cost['twin_stepping_s']:.3g} s, in the time above")
    if any(g.fallback is not None for g in plan.groups):
        lines.insert(-1, "precision:   auto: fp32, verified case by case by the twins; the cases it does not verify "
                         "are rerun in fp64 (not in the time above: how many is known only after)")
    if p.get("compiled_modules"):
        lines.append(f"             the probe compiled {p['compiled_modules']} kernel modules ({p['probe_compile']:.3g} s) into "
                     "Warp's cache: the run loads them from there")
    if p.get("under_load"):
        lines.append(f"             taken while other work kept {100 * p['others_busy']:.0f} % of the cores busy: "
                     "the time may be high; it is re-measured once the host is idle")
    return "\n".join(lines)


def _group_lines(plan: SweepPlan) -> list[str]:
    """The dry run's lines on the groups: one per group (columns, dt, steps, path) and the saving."""
    if len(plan.groups) < 2:
        return []
    lines = [f"groups:      {len(plan.groups)} of like stiffness, each at its own dt (run.groups; "
             f"{plan.column_steps() / (plan.n_columns * plan.run.n_steps):.2f} x the column-steps of one dt):"]
    for i, g in enumerate(plan.groups):
        p = g.plan
        lines.append(f"  group {i}:   {g.n_columns} columns ({g.label}): dt = {p.dt:.4g} s "
                     f"({p.settings.dt_safety:.3g} x limit {p.dt_limit:.4g} s), {p.n_steps} steps, "
                     f"{p.prisms_simulated} prisms, path {p.path.value}")
    return lines
