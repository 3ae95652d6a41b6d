"""Run a sweep spec: plan the shards, run each shard that is not done (here or on Dask workers),
then combine them into the sweep's dataset (:mod:`.store` describes the files)."""

from __future__ import annotations

from pathlib import Path

from ..types import ShardState
from .dask import run_shards_dask
from .plan import SweepError, SweepPlan, plan_sweep, resolve_dt
from .progress import ProgressBar
from .shard import run_shard
from .spec import SweepSpec, load_spec
from .store import ShardCheck, check_shard, combine, load_plan_from_manifest, prepare_dir


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
    prepare_dir(plan, overwrite=overwrite, resume=resume)
    states = [check_shard(plan, i) for i in range(plan.n_shards)] if resume else [
        ShardCheck(i, plan.shard_path(i), ShardState.MISSING, n_columns=b - a) for i, (a, b) in enumerate(plan.shards)
    ]
    todo = [s.index for s in states if s.state != ShardState.DONE]
    done_cols = sum(s.n_columns for s in states if s.state == ShardState.DONE)
    done_failed = sum(s.n_failed for s in states if s.state == ShardState.DONE)
    bar = ProgressBar(plan.n_columns, done_cols, done_failed, stream=stream, enabled=progress)
    if todo:
        if dask_workers or scheduler or client is not None:
            run_shards_dask(plan, todo, n_workers=dask_workers, scheduler=scheduler, client=client, bar=bar)
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
