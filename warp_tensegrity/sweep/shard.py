"""One shard: run its columns through the engine, measure every column, build its dataset; on a
Dask worker also write it into its region of the sweep's store (:mod:`.store`)."""

from __future__ import annotations

import time

import numpy as np

from .. import io as D
from ..scene.base_modes import beta_limit_measures
from ..engine import simulate_batch
from ..measure.nan_reasons import measure_columns  # shared with BatchResult.to_xarray
from ..provenance import provenance_attrs
from ..result import merge_results
from ..runtime import warp_facts
from .plan import SweepPlan, decide_sweep
from .store import SweepStore, time_coord



def _num(x):
    """A float attribute, or 'none'."""
    return "none" if x is None else float(x)


def compute_shard(plan: SweepPlan, index: int, device: str | None = None, progress=None):
    """Run shard ``index`` and return its case-stacked dataset (not written)."""
    if plan.run is None:
        decide_sweep(plan)
    spec = plan.spec
    start, stop = plan.shards[index]
    params = {k: np.ascontiguousarray(v[start:stop]) for k, v in plan.params.items()}
    result = run_groups(plan, start, stop, device, progress)
    meas = measure_columns(result, spec.scene.height)
    meas.update(beta_limit_measures(spec.scene, params, stop - start, meas["max_compression"]))
    attrs = {
        "Conventions": D.CONVENTIONS,
        "fingerprint": plan.fingerprint,
        "code_version": plan.code_version,
        **provenance_attrs(),
        **warp_facts(result.device),
        "spec_sha256": spec.text_sha256,
        "shard_index": index,
        "n_shards": plan.n_shards,
        "case_start": start,
        "case_stop": stop,
        **D.result_attrs(result),
        "step_path": result.info.get("step_path", "unknown"),
        "dt_limit": plan.dt_limit,
        "dt_safety_used": _num(plan.run.settings.dt_safety if isinstance(spec.run["dt"], str) else None),
        "accuracy_target": _num(plan.run.accuracy if isinstance(spec.run["dt"], str) else None),
        "history": f"{time.strftime('%Y-%m-%dT%H:%M:%S%z')} shard {index} computed by warp_tensegrity",
        "run_groups": run_groups_attr(plan),
    }
    if spec.run["output_interval"] is not None:
        attrs["output_interval"] = float(spec.run["output_interval"])
    return D.shard_dataset(spec.layout(), plan.params, start, stop, result, meas, attrs)


def run_groups_attr(plan: SweepPlan) -> str:
    """The dataset attribute ``run_groups``: one line per group (its index in ``run_group``, columns,
    what they hold, dt, steps, path)."""
    return "; ".join(f"{i}: {g.n_columns} columns ({g.label}), dt {g.plan.dt:.6g} s, {g.plan.n_steps} steps, "
                     f"path {g.plan.path.value}" for i, g in enumerate(plan.groups))


def run_groups(plan: SweepPlan, start: int, stop: int, device: str | None = None, progress=None):
    """Columns ``start:stop`` of the sweep run group by group, each with its group's plan (decided once
    for the sweep, :attr:`SweepPlan.groups`), merged back in column order (one BatchResult).
    ``progress(steps_done, n_steps, n_failed)`` sees the shard's column-steps as one run."""
    group = plan.column_group[start:stop]
    parts, work = [], []
    for gi, g in enumerate(plan.groups):
        cols = np.flatnonzero(group == gi)
        if cols.size:
            parts.append((gi, cols))
            work.append(cols.size * g.plan.n_steps)
    total, done, failed = float(sum(work)), 0.0, 0
    results = []
    for (gi, cols), w in zip(parts, work):
        cb = None
        if progress is not None:
            def cb(steps_done, n_steps, n_failed, _w=w, _done=done, _failed=failed):
                progress(_done + _w * steps_done / max(n_steps, 1), total, _failed + n_failed)
        params = {k: np.ascontiguousarray(v[start:stop][cols]) for k, v in plan.params.items()}
        r = simulate_batch(plan.spec.scene, params, progress=cb, plan=plan.groups[gi].plan.with_device(device))
        results.append((cols, r))
        done += w
        failed += int(np.count_nonzero(r.status))
    return merge_results(results, stop - start, [gi for gi, _ in parts])


def template_dataset(plan: SweepPlan):
    """A one-column shard dataset built by the same code as every shard (engine output times,
    :func:`measure_columns` on an all-zero column, io.shard_dataset): the store is laid out from it
    before any shard runs. Nothing is stepped."""
    from types import SimpleNamespace

    if plan.run is None:
        decide_sweep(plan)
    spec = plan.spec
    steps, time = plan.run.output_steps, plan.run.output_times  # as every shard's
    P, T = spec.scene.n_prisms, len(time)
    z = lambda *shape: np.zeros(shape)  # noqa: E731
    result = SimpleNamespace(
        n_columns=1, status=np.zeros(1, np.int8), fail_step=np.full(1, -1, np.int64), energy_error=z(1),
        bar_length_error=z(1), kinetic_energy=z(1, T), elastic_energy=z(1, T), strain=z(1, T, P), time=time,
        info={"output_step": steps if len(plan.groups) < 2 else None, "column_dt": np.full(1, plan.dt),
              "column_group": np.zeros(1, np.int32)})
    with np.errstate(all="ignore"):
        meas = measure_columns(result, spec.scene.height)
    meas.update(beta_limit_measures(spec.scene, {k: v[:1] for k, v in plan.params.items()}, 1, meas["max_compression"]))
    return D.shard_dataset(spec.layout(), plan.params, 0, 1, result, meas, {})


def compute_and_write(plan: SweepPlan, index: int, device: str | None = None) -> tuple[int, dict]:
    """A Dask task's body: compute shard ``index``, write its region of the store (created by the
    client), return (index, its manifest record). Only the client marks shards done."""
    import xarray as xr

    store = SweepStore(plan.out)
    ds = compute_shard(plan, index, device=device)
    time = time_coord(xr.open_zarr(store.zarr, consolidated=False, decode_timedelta=False))
    return index, store.write_shard(plan, index, ds, time)
