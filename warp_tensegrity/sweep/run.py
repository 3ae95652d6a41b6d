"""Drive a sweep: plan the shards (or re-plan them from a run's manifest), run each shard that is
not done (here or on Dask workers), combine them into the sweep's dataset, and report a run's
status (:mod:`.store` describes the files)."""

from __future__ import annotations

import logging
import math
from pathlib import Path

from .. import io as D
from ..provenance import command_line

from ..types import ShardState
from .dask import run_shards_dask
from .errors import SweepError
from .plan import SweepPlan, plan_sweep, resolve_dt
from .progress import ProgressBar
from .shard import run_and_check, run_shard
from .spec import SweepSpec, load_spec
from .store import ShardCheck, check_shard, prepare_dir, read_manifest, shard_dir_for, status_from_output

log = logging.getLogger(__name__)


def execute(
    plan: SweepPlan,
    *,
    resume: bool = False,
    overwrite: bool = False,
    progress: bool | None = None,
    dask_workers: int | None = None,
    scheduler: str | None = None,
    client=None,
    stream=None,
    combine_output: bool = True,
) -> Path | None:
    """Run (or resume) every shard of ``plan`` that is not done, then combine into plan.out.
    ``progress``: None shows the bar only when ``stream`` (stderr) is a terminal; True always; False never."""
    if plan.out is None:
        raise SweepError("no output path")
    if plan.settings is None:
        resolve_dt(plan)
    prepare_dir(plan, overwrite=overwrite, resume=resume)
    states = [check_shard(plan, i) for i in range(plan.n_shards)] if resume else [
        ShardCheck(i, plan.shard_path(i), ShardState.MISSING, n_columns=b - a) for i, (a, b) in enumerate(plan.shards)
    ]
    todo = [s.index for s in states if s.state != ShardState.DONE]
    done_cols = sum(s.n_columns for s in states if s.state == ShardState.DONE)
    done_failed = sum(s.n_failed for s in states if s.state == ShardState.DONE)
    bar = ProgressBar(plan.n_columns, done_cols, done_failed, stream=stream, enabled=progress,
                      estimate_s=_estimated_seconds(plan, todo))
    log.debug("%d of %d shards to run (%d columns done)", len(todo), plan.n_shards, done_cols)
    if todo:
        if dask_workers or scheduler or client is not None:
            run_shards_dask(plan, todo, run_and_check, n_workers=dask_workers, scheduler=scheduler, client=client, bar=bar)
        else:
            for i in todo:
                a, b = plan.shards[i]

                def cb(steps_done, n_steps, n_failed, _a=a, _b=b):
                    frac = steps_done / n_steps if n_steps else 1.0
                    bar.update(done_cols + (_b - _a) * frac, done_failed + n_failed)

                path = run_shard(plan, i, progress=cb)
                st = check_shard(plan, i)
                if st.state != ShardState.DONE:
                    raise SweepError(f"shard {i} was written to {path} but does not check out: {st.reason}")
                done_cols += b - a
                done_failed += st.n_failed
                bar.update(done_cols, done_failed, force=True)
    bar.close()
    if combine_output:
        return combine(plan)
    return None


def _estimated_seconds(plan: SweepPlan, todo) -> float | None:
    """The calibrated cost model's time for the shards still to run (None if unknown)."""
    spc = float(plan.estimate.get("seconds_per_column_step_estimate", float("nan")))
    steps = int(plan.estimate.get("n_steps", 0))
    cols = sum(plan.shards[i][1] - plan.shards[i][0] for i in todo)
    secs = spc * steps * cols
    return secs if math.isfinite(secs) and secs > 0 else None


def run_sweep(spec, out, *, device=None, shard_size=None, resume=False, overwrite=False, progress=None,
              dask_workers=None, scheduler=None, client=None, stream=None) -> Path:
    """Run a spec (SweepSpec, path or TOML text) into ``out`` (netCDF)."""
    if not isinstance(spec, SweepSpec):
        spec = load_spec(spec)
    plan = plan_sweep(spec, out, device=device, shard_size=shard_size)
    return execute(plan, resume=resume, overwrite=overwrite, progress=progress, dask_workers=dask_workers,
                   scheduler=scheduler, client=client, stream=stream)


def resume_sweep(out, spec=None, *, device=None, shard_size=None, progress=None, dask_workers=None,
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


def combine(plan_or_out, spec=None) -> Path:
    """Combine every shard into plan.out (atomically). Refuses while shards are missing or stale."""
    plan = plan_or_out if isinstance(plan_or_out, SweepPlan) else None
    if plan is None:
        if spec is None:
            plan = load_plan_from_manifest(plan_or_out, estimate=False)
        else:
            plan = plan_sweep(spec if isinstance(spec, SweepSpec) else load_spec(spec), plan_or_out, estimate=False)
    bad = [s for s in (check_shard(plan, i) for i in range(plan.n_shards)) if s.state != ShardState.DONE]
    if bad:
        listing = ", ".join(f"{s.index} ({s.state}{': ' + s.reason if s.reason else ''})" for s in bad[:8])
        more = f" and {len(bad) - 8} more" if len(bad) > 8 else ""
        raise SweepError(
            f"{len(bad)} of {plan.n_shards} shards are not done: {listing}{more}; "
            f"run `warp-tensegrity resume {plan.out}`"
        )
    shards = [D.open_sweep(plan.shard_path(i)) for i in range(plan.n_shards)]
    ds = D.combine_shards(plan.spec, shards, extra_attrs={"command_line": command_line()})
    return D.write_netcdf(ds, plan.out)


def sweep_status(out, spec=None) -> dict:
    """Cases done, diverged and remaining, per shard state."""
    if spec is None and not shard_dir_for(out).exists() and Path(out).exists():
        return status_from_output(out)
    if spec is None:
        plan = load_plan_from_manifest(out, estimate=False)
    else:
        plan = plan_sweep(spec if isinstance(spec, SweepSpec) else load_spec(spec), out, estimate=False)
    states = [check_shard(plan, i) for i in range(plan.n_shards)]
    done = [s for s in states if s.state == ShardState.DONE]
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
        "shards_missing": [s.index for s in states if s.state == ShardState.MISSING],
        "shards_stale": [(s.index, s.reason) for s in states if s.state == ShardState.STALE],
        "shards_corrupt": [(s.index, s.reason) for s in states if s.state == ShardState.CORRUPT],
        "combined": combined,
        "fingerprint": plan.fingerprint,
    }
