"""One shard: run its columns through the engine, measure every column, build its dataset and
write it atomically."""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from .. import io as D
from ..engine import simulate_batch
from ..provenance import provenance_attrs
from ..runtime import warp_facts
from ..types import ShardState
from .store import check_shard

if TYPE_CHECKING:
    from .plan import SweepPlan


measure_columns = D.measure_columns  # leading-pulse measures of a BatchResult (io.py, shared with to_xarray)


def _num(x):
    """A float attribute, or 'none'."""
    return "none" if x is None else float(x)


def compute_shard(plan: SweepPlan, index: int, device: str | None = None, progress=None):
    """Run shard ``index`` and return its case-stacked dataset (not written)."""
    if plan.settings is None:
        plan.resolve()
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
        "dt_safety_used": _num(plan.estimate.get("dt_safety") if isinstance(spec.run["dt"], str) else None),
        "accuracy_target": _num(plan.estimate.get("accuracy_target") if isinstance(spec.run["dt"], str) else None),
        "history": f"{time.strftime('%Y-%m-%dT%H:%M:%S%z')} shard {index} computed by warp_tensegrity",
    }
    if spec.run["output_interval"] is not None:
        attrs["output_interval"] = float(spec.run["output_interval"])
    return D.shard_dataset(spec, plan.params, start, stop, result, meas, attrs)


def run_shard(plan: SweepPlan, index: int, device: str | None = None, progress=None) -> Path:
    """Compute shard ``index`` and write it atomically; returns its path."""
    ds = compute_shard(plan, index, device=device, progress=progress)
    return D.write_netcdf(ds, plan.shard_path(index))


def run_and_check(plan: SweepPlan, index: int, device: str | None = None) -> tuple[int, str, int]:
    """Run shard ``index``, write it and check the file (a Dask task's body): (index, path, n_failed)."""
    path = run_shard(plan, index, device=device)
    st = check_shard(plan, index)
    if st.state != ShardState.DONE:
        raise RuntimeError(f"shard {index} written to {path} does not check out: {st.reason}")
    return index, str(path), st.n_failed
