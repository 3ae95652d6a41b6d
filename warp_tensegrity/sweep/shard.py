"""One shard: run its columns through the engine, measure every column, build its dataset; on a
Dask worker also write it into its region of the sweep's store (:mod:`.store`)."""

from __future__ import annotations

import time

import numpy as np

from .. import io as D
from ..scene.base_modes import beta_limit_measures
from ..engine import simulate_batch
from ..measure.feasibility import feasible_record
from ..measure.nan_reasons import measure_columns  # shared with BatchResult.to_xarray
from ..provenance import provenance_attrs
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
    # the run decided once for all the sweep's columns (the plan's)
    result = simulate_batch(spec.scene, params, progress=progress, plan=plan.run.with_device(device))
    meas = measure_columns(result, spec.scene.height)
    meas.update(result.info["beta_limit"](meas["max_compression"]))
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
    }
    if spec.run["output_interval"] is not None:
        attrs["output_interval"] = float(spec.run["output_interval"])
    return D.shard_dataset(spec.layout(), plan.params, start, stop, result, meas, attrs)


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
        info={"output_step": steps}, feasibility=feasible_record(1))
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
