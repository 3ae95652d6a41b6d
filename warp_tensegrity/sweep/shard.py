"""One shard: run its columns through the engine, measure every column, build its dataset; on a
Dask worker also write it into its region of the sweep's store (:mod:`.store`)."""

from __future__ import annotations

import time

import numpy as np

from .. import io as D
from ..scene.base_modes import base_mode_ratios_one_thread, base_mode_ratios_steps, beta_limit_measures
from ..scene.blas import one_blas_thread
from ..engine import HostWork, run_batches
from ..measure.errors import FLAG as ERROR_FLAG
from ..measure.errors import VERIFY_MARGIN, error_estimates, largest_share, with_perturbation
from ..measure.feasibility import feasible_record
from ..measure.nan_reasons import measure_columns  # shared with BatchResult.to_xarray
from ..policy.accuracy import DEFAULT_ACCURACY
from ..policy.groups import twin_ratio
from ..provenance import provenance_attrs
from ..result import merge_results, overwrite_columns
from ..runtime import warp_facts
from . import beside
from .plan import SweepPlan, decide_sweep
from .store import SweepStore, time_coord



def _num(x):
    """A float attribute, or 'none'."""
    return "none" if x is None else float(x)


def compute_shard(plan: SweepPlan, index: int, device: str | None = None, progress=None, host: list[HostWork] = ()):
    """Run shard ``index`` and return its case-stacked dataset (not written). ``host``: host work
    stepped with its runs (:func:`warp_tensegrity.engine.run_batches`; on a GPU, in turns between
    their launches: the run's template and store layout while the first shard steps, :mod:`.run`)."""
    if plan.run is None:
        decide_sweep(plan)
    spec = plan.spec
    start, stop = plan.shards[index]
    params = {k: np.ascontiguousarray(v[start:stop]) for k, v in plan.params.items()}
    twins = bool(spec.run["error_estimate"])
    # the base-mode analysis (~3 s for phase_large's 96 pairs) on one BLAS thread (scene.blas: a
    # multi-threaded OpenBLAS is slower on these small solves). On a GPU it runs while the shard steps,
    # in a process beside this one (sweep.beside: a thread or turns in the host loop stall the
    # launches), or, where none can be started, one pair per turn of the host between the launches.
    # The CPU computes it after the stepping with the default threads (an eigensolve's last bits
    # follow the thread count, and the reference outputs were made so; beside a CPU run it would
    # share the cores with the stepping).
    modes = beside.submit(base_mode_ratios_one_thread, spec.scene, params, stop - start) if modes_beside(plan) else None
    turns = (HostWork(base_mode_ratios_steps(spec.scene, params, stop - start), "measurement", one_blas_thread)
             if modes_beside(plan) and modes is None else None)
    result = run_groups(plan, start, stop, device, progress, twins=twins, host=[*host, *([turns] if turns else [])])
    result, errors = result if twins else (result, {})
    meas = measure_columns(result, spec.scene.height)
    ratio = None  # the CPU's: computed in beta_limit_measures, after the stepping
    if modes is not None:
        ratio = beside.result(modes, lambda: base_mode_ratios_one_thread(spec.scene, params, stop - start))
    elif turns is not None:
        ratio = turns.value
    meas.update(beta_limit_measures(spec.scene, params, stop - start, meas["max_compression"], ratio))
    meas.update(errors)
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


def modes_beside(plan: SweepPlan) -> bool:
    """Whether a shard's base-mode analysis runs in the process beside (:mod:`.beside`): on a GPU."""
    return bool(plan.run.on_gpu)


def run_groups_attr(plan: SweepPlan) -> str:
    """The dataset attribute ``run_groups``: one line per group (its index in ``run_group``, columns,
    what they hold, dt, steps, path)."""
    return "; ".join(f"{i}: {g.n_columns} columns ({g.label}), dt {g.plan.dt:.6g} s, {g.plan.n_steps} steps, "
                     f"path {g.plan.path.value}" for i, g in enumerate(plan.groups))


VERIFY_FAILS = (ERROR_FLAG["over_target"], ERROR_FLAG["twin_undefined"])
"""error_flag values a precision 'auto' fp32 case is rerun in fp64 for."""


def run_groups(plan: SweepPlan, start: int, stop: int, device: str | None = None, progress=None,
               twins: bool = False, host: list[HostWork] = ()):
    """Columns ``start:stop`` of the sweep run group by group, each with its group's plan (decided once
    for the sweep, :attr:`SweepPlan.groups`), merged back in column order (one BatchResult).

    ``twins``: each group's error-estimate twin too (:attr:`RunGroup.twin`); a group that verifies
    fp32 (precision 'auto', :attr:`RunGroup.fallback`) reruns in fp64 the columns whose error_flag
    is over_target or twin_undefined (and that stay in the feasible set). Then returns (result, errors): every measure's error estimate
    and ``error_flag`` (:func:`warp_tensegrity.measure.errors.error_estimates`), in column order.
    ``progress(done, total, n_failed)`` sees the shard's column-steps (twins included) as one run.
    ``host``: host work stepped with the groups (:func:`warp_tensegrity.engine.run_batches`)."""
    group = plan.column_group[start:stop]
    n = stop - start
    jobs = [(gi, cols) for gi in range(len(plan.groups)) if (cols := np.flatnonzero(group == gi)).size]
    total = float(sum(cols.size * (plan.groups[gi].plan.n_steps + (plan.groups[gi].twin.n_steps
                                   if twins and plan.groups[gi].twin is not None else 0)) for gi, cols in jobs))
    state = {"done": 0.0, "failed": 0, "stages": {}}

    def run(runs, host=()):
        """Run each (cols, plan) (None: no run), on a GPU all at once (engine.run_batches: each group
        and twin alone is too narrow to fill it); progress sees their column-steps summed."""
        todo = [i for i, (_, rp) in enumerate(runs) if rp is not None]
        now = {i: (0.0, 0) for i in todo}  # each run's column-steps done and columns failed so far

        def callback(i, w):
            def cb(steps_done, n_steps, n_failed):
                now[i] = (w * steps_done / max(n_steps, 1), n_failed)
                progress(min(state["done"] + sum(d for d, _ in now.values()), total),
                         total, state["failed"] + sum(f for _, f in now.values()))
            return cb

        cbs = [callback(i, runs[i][0].size * runs[i][1].n_steps) if progress is not None else None for i in todo]
        batches = [(plan.spec.scene, {k: np.ascontiguousarray(v[start:stop][runs[i][0]]) for k, v in plan.params.items()},
                    runs[i][1]) for i in todo]
        results, stages = run_batches(batches, device, cbs, host=host) if todo or host else ([], {})
        state["done"] += sum(runs[i][0].size * runs[i][1].n_steps for i in todo)
        state["failed"] += sum(int(np.count_nonzero(r.status)) for r in results)
        for k, v in stages.items():
            state["stages"][k] = state["stages"].get(k, 0.0) + v
        out = [None] * len(runs)
        for i, r in zip(todo, results):
            out[i] = r
        return out

    def estimate(r, rp, twin_r, twin):
        height = plan.spec.scene.height
        meas = measure_columns(r, height)
        return meas, error_estimates(meas, None if twin_r is None else measure_columns(twin_r, height),
                                     1.0 if twin is None else twin_ratio(rp, twin), rp.precision, rp.accuracy)

    # every group and its twin at once (on a GPU; one after another elsewhere)
    firsts = run([(cols, plan.groups[gi].plan) for gi, cols in jobs]
                 + [(cols, plan.groups[gi].twin if twins else None) for gi, cols in jobs], host)
    done_runs, twin_runs = firsts[:len(jobs)], firsts[len(jobs):]
    errors = {}
    redos = []  # (job index, columns of the group to rerun, meas, err)
    for k, (gi, cols) in enumerate(jobs):
        g, r = plan.groups[gi], done_runs[k]
        if twins:
            meas, err = estimate(r, g.plan, twin_runs[k], g.twin)
            bad = np.isin(err["error_flag"], VERIFY_FAILS)
            if g.fallback is not None:  # auto's fp32: verified with a margin (errors.VERIFY_MARGIN)
                bad |= largest_share(meas, err) > VERIFY_MARGIN * (g.plan.accuracy or DEFAULT_ACCURACY)
            if r.feasibility is not None:  # a case outside the model's feasible set is flagged, not rerun
                bad &= np.asarray(r.feasibility["feasibility_flag"]) == 0
            redo = np.flatnonzero(bad) if g.fallback is not None else []
            if len(redo):
                redos.append((k, redo, meas, err))
            else:
                _keep_errors(errors, err, cols, n)
    if redos:  # fp32 not verified: fp64, with its own twin and estimate, every group's at once
        backs = run([(jobs[k][1][redo], plan.groups[jobs[k][0]].fallback) for k, redo, _, _ in redos]
                    + [(jobs[k][1][redo], plan.groups[jobs[k][0]].fallback_twin) for k, redo, _, _ in redos])
        for j, (k, redo, meas, err) in enumerate(redos):
            gi, cols = jobs[k]
            g, r, rb, rbt = plan.groups[gi], done_runs[k], backs[j], backs[len(redos) + j]
            meas_b, err_b = estimate(rb, g.fallback, rbt, g.fallback_twin)
            # fp32 and fp64 at one dt differ by round-off only: what that moves, the estimate covers
            err_b = with_perturbation(err_b, meas_b, {key: np.asarray(v)[redo] for key, v in meas.items()},
                                      g.fallback.accuracy or DEFAULT_ACCURACY)
            overwrite_columns(r, redo, rb)
            for key, v in err_b.items():
                err[key][redo] = v
            _keep_errors(errors, err, cols, n)
    merged = merge_results([(cols, r) for (_, cols), r in zip(jobs, done_runs)], n, [gi for gi, _ in jobs])
    merged.wall_time = state["stages"].get("stepping", 0.0)  # every run's: the groups', twins' and fp64 reruns'
    merged.info["stages"] = state["stages"]  # the runs' stages, stepping as the wall of runs stepped at once
    return (merged, errors) if twins else merged


def _keep_errors(errors: dict, err: dict, cols, n: int) -> None:
    """Put one group's error estimates (its columns ``cols``) into the shard's arrays of ``n``."""
    for k, v in err.items():
        errors.setdefault(k, np.empty((n,) + v.shape[1:], dtype=v.dtype))[cols] = v


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
        station_energy=z(1, T), end_energy=z(1, T),
        info={"output_step": steps if len(plan.groups) < 2 else None, "column_dt": np.full(1, plan.dt),
              "column_group": np.zeros(1, np.int32), "column_bits": np.full(1, 64, np.int8)}, feasibility=feasible_record(1))
    if spec.scene.impact == "striker":  # the striker's records (sim.staged.striker)
        result.info["striker"] = {"velocity": z(1, T), "force": z(1, T), "mass": z(1), "separation_time": z(1),
                                  "last_separation_time": z(1), "recontacts": np.zeros(1, np.int64),
                                  "contact_residual": z(1)}
    with np.errstate(all="ignore"):
        meas = measure_columns(result, spec.scene.height)
    # the flag's layout only: no modes solved (a ratio of NaN, as at beta = 1)
    meas.update(beta_limit_measures(spec.scene, {k: v[:1] for k, v in plan.params.items()}, 1, meas["max_compression"],
                                    ratio=np.full(1, np.nan)))
    if spec.run["error_estimate"]:
        meas.update(error_estimates(meas, meas, 1.0))
    return D.shard_dataset(spec.layout(), plan.params, 0, 1, result, meas, {})


def compute_and_write(plan: SweepPlan, index: int, device: str | None = None) -> tuple[int, dict]:
    """A Dask task's body: compute shard ``index``, write its region of the store (created by the
    client), return (index, its manifest record). Only the client marks shards done."""
    import xarray as xr

    store = SweepStore(plan.out)
    ds = compute_shard(plan, index, device=device)
    time = time_coord(xr.open_zarr(store.zarr, consolidated=False, decode_timedelta=False))
    return index, store.write_shard(plan, index, ds, time)
