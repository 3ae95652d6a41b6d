"""Running a decided plan: :func:`run_batch` (any prepared batch) and :func:`simulate_batch` (T3
columns) take a :class:`~warp_tensegrity.policy.decide.RunPlan` (or decide one from the settings,
once), build the columns, step them with the Integrator, measure the records and return a
:class:`~warp_tensegrity.result.BatchResult` (a truncated run padded back to the whole column).
Nothing here decides: method, dt, truncation and path are the plan's (:mod:`warp_tensegrity.policy`).
Warp is imported when a batch runs, not with this module (the package imports it).
"""

from __future__ import annotations

import contextlib
import time
from dataclasses import replace
from functools import partial

import numpy as np

from .measure.energy import end_prisms, impact_energy, part_nodes, station_prism
from .measure.feasibility import pair_record, prism_record
from .policy.decide import RunPlan, check_batch_arguments, decide, decide_batch, far_end
from .policy.paths import lane_emulation
from .arguments import expect, expect_callable
from .result import BatchResult
from .runtime import drive, init_warp, resolve_device
from .scene.base_modes import beta_limit_measures
from .scene.batch import (NetworkBatch, column_batch, column_params, far_end_params, reference_elastic_energy,
                          reference_states)
from .scene.columns import ColumnConfig
from .options import RunSettings
from .types import FORCE_EVALS


def _to_host(a):
    return None if a is None else a.numpy().astype(np.float64)



def _feasibility(integ, time) -> dict | None:
    """The per-case feasibility record (:mod:`warp_tensegrity.measure.feasibility`) of a run."""
    m, d = integ.model, integ.data
    if m.n_prisms > 0:
        return prism_record(d.left_slot.numpy(), d.twist_max.numpy(), d.twist_min.numpy(), d.height_min.numpy(),
                            d.twist.numpy(), time)
    if m.n_pairs > 0:
        return pair_record(d.pair_left_slot.numpy(), m.pair_kind.numpy(), d.pair_distance_min.numpy(),
                           m.pair_nodes.numpy(), time)
    return None


def _levels_in_order(batch: NetworkBatch) -> bool:
    """Whether level l holds nodes 3l..3l+2 (columns): the energy-parts record cuts by node index."""
    ln = batch.level_nodes
    return ln is not None and np.array_equal(ln, np.arange(ln.size).reshape(ln.shape))


def run_batch(batch: NetworkBatch, settings: RunSettings | None = None, progress=None, pulse: dict | None = None,
              plan: RunPlan | None = None) -> BatchResult:
    """Integrate a prepared batch; see :func:`simulate_batch` for columns. ``plan``: the run decided
    already (:func:`~warp_tensegrity.policy.decide.decide_batch` from ``settings`` otherwise).
    ``pulse``: keywords of :func:`~warp_tensegrity.measure.device.measure_record` (prism_height,
    n_prisms, cut) to measure the record on the device (settings.measure = 'device'); with the
    energy measures (:mod:`~warp_tensegrity.measure.energy`) of T3 columns also ``station`` and
    ``end_prisms``."""
    return drive(run_batch_steps(batch, settings, progress, pulse, plan))


def run_batch_steps(batch: NetworkBatch, settings: RunSettings | None = None, progress=None,
                    pulse: dict | None = None, plan: RunPlan | None = None):
    """:func:`run_batch` as a generator that yields while it steps and returns the BatchResult, so
    that several runs can step at once (:func:`run_batches`)."""
    expect("run_batch", "batch", batch, NetworkBatch), expect("run_batch", "plan", plan, RunPlan, optional=True)
    expect_callable("run_batch", "progress", progress), expect("run_batch", "pulse", pulse, dict, optional=True)
    if plan is None:
        expect("run_batch", "settings", settings, RunSettings)
        plan = decide_batch(batch, settings)
    init_warp()  # quietly: no CUDA-driver warning on a CPU-only machine
    from .sim.integrate import Integrator  # imports Warp: not at package import, loads with the first run

    settings, dt, every, n_steps, n_out, path = plan.settings, plan.dt, plan.output_every, plan.n_steps, plan.n_out, plan.path
    device = resolve_device(plan.device)
    # the measures need the record on the device, whether or not it crosses to the host
    record = settings.record_strain or settings.measure == "host" or (pulse is not None and settings.measure == "device")
    pulse = None if pulse is None else dict(pulse)
    station, k = (None, None) if pulse is None else (pulse.pop("station", None), pulse.pop("end_prisms", None))
    parts = None
    if station is not None and _levels_in_order(batch):
        parts = part_nodes(pulse["n_prisms"], station, k, pulse.get("cut", 0))
    with lane_emulation(path, device):  # the CPU runs the lane step as fibers
        integ = Integrator(batch, replace(settings, record_strain=record), dt, every, n_out, path=path,
                           energy_parts=parts)
        wall, t_compile = yield from integ.run_steps(n_steps, progress)
    stages = {"build": integ.build_time, "compile": t_compile, "stepping": wall}
    measure_here = pulse is not None and integ.strain is not None and settings.measure == "device"
    if measure_here:
        from .measure.device import measure_record  # imports Warp: not at package import
        from .measure.device_kernels import load_kernels  # imports Warp

        t0 = time.perf_counter()
        load_kernels(integ.device)
        stages["compile"] += time.perf_counter() - t0
    t_host = time.perf_counter()
    d = integ.data
    ke = _to_host(integ.kinetic).T  # (B, n_out)
    ee = _to_host(integ.elastic).T
    status = d.status.numpy().astype(np.int32)
    fail_step = d.fail_step.numpy().astype(np.int64)
    striker = integ.striker.summary(dt) if integ.striker is not None else None
    E = ke + ee
    if striker is not None:  # the striker's kinetic energy belongs to the conserved total
        E = E + 0.5 * striker["mass"][:, None] * striker["velocity"] ** 2
    # only outputs written before a failure are meaningful
    valid = np.ones_like(E, dtype=bool)
    for b in np.flatnonzero(status):
        last_slot = max(int(fail_step[b]) - 1, 0) // every
        valid[b, last_slot + 1 :] = False
        ke[b, last_slot + 1 :] = np.nan
        ee[b, last_slot + 1 :] = np.nan
    records = {name: _to_host(a) for name, a in (("station_energy", integ.energy_below), ("end_energy", integ.energy_end))}
    for a in records.values():  # (n_out, B)
        if a is not None:
            a[~valid.T] = np.nan
    records = {name: None if a is None else np.ascontiguousarray(a.T) for name, a in records.items()}
    k0 = impact_energy(ke[:, 0], striker)  # the striker's kinetic energy belongs to it
    scale = np.where(k0 > 0, k0, np.nan)
    with np.errstate(invalid="ignore"):
        dev = np.where(valid, np.abs(E - E[:, :1]), 0.0)
        energy_error = dev.max(axis=1) / scale
    measurements = None
    if measure_here:
        n_valid = np.where(status != 0, np.maximum(fail_step - 1, 0) // every + 1, n_out)
        energy = None if integ.energy_parts is None else {"below": integ.energy_below, "end": integ.energy_end,
                                                          "kinetic": integ.kinetic, "impact": k0, "station": station,
                                                          "end_prisms": k}
        measurements = measure_record(integ.strain, plan.output_times, n_valid=n_valid, timings=stages,
                                      energy=energy, **pulse)
    strain = None
    if integ.strain is not None and (settings.record_strain or settings.measure == "host"):
        strain = _to_host(integ.strain).transpose(2, 0, 1)  # (B, n_out, n_prisms)
        for b in np.flatnonzero(status):
            last_slot = max(int(fail_step[b]) - 1, 0) // every
            strain[b, last_slot + 1 :] = np.nan
    stages["transfer"] = stages.get("transfer", 0.0) + time.perf_counter() - t_host - stages.get("measurement", 0.0)
    return BatchResult(
        measurements=measurements,
        params=dict(batch.params),
        time=plan.output_times,
        strain=strain,
        kinetic_energy=ke,
        elastic_energy=ee,
        **records,
        energy_error=energy_error,
        bar_length_error=d.bar_err.numpy().astype(np.float64),
        status=status,
        fail_step=fail_step,
        dt=dt,
        n_steps=n_steps,
        method=settings.method,
        precision=settings.precision,
        device=str(integ.device),
        device_name=integ.device.name,
        wall_time=wall,
        final_displacement=d.u.numpy().astype(np.float64).transpose(1, 0, 2),
        final_velocity=d.v.numpy().astype(np.float64).transpose(1, 0, 2),
        feasibility=_feasibility(integ, plan.output_times),
        dt_limit=plan.dt_limit,
        info={
            "omega_max_bound": plan.omega_max_bound,
            "output_every": every,
            "output_step": plan.output_steps,
            "column_dt": np.full(batch.n_columns, dt),
            "column_group": np.zeros(batch.n_columns, dtype=np.int32),
            "column_bits": np.full(batch.n_columns, 32 if settings.precision == "fp32" else 64, dtype=np.int8),
            "max_projection_iterations": int(d.iters.numpy().max()) if batch.n_columns else 0,
            "bandwidth": integ.model.bandwidth,
            "n_constraints": integ.model.n_constraints,
            "build_time": integ.build_time,
            "initialize_time": t_compile,
            "graph_steps": integ.graph_steps,
            "force_evaluations_per_step": FORCE_EVALS[settings.method],
            "step_path": integ.stepper.description,
            "equilibrium_residual": None if batch.equilibrium_residual is None else batch.equilibrium_residual.copy(),
            "stages": stages,
            **({"contact": integ.contact.summary()} if integ.contact is not None else {}),
            **({"energy_station": station, "energy_end_prisms": k} if integ.energy_parts is not None else {}),
            **({"striker": striker} if striker is not None else {}),
        },
    )


def simulate_batch(config: ColumnConfig, params: dict, settings: RunSettings | None = None, progress=None,
                   prisms_simulated: int | None = None, *, plan: RunPlan | None = None) -> BatchResult:
    """Simulate B T3 columns of one topology, each with its own parameters.

    ``params`` maps names in :data:`~warp_tensegrity.options.COLUMN_PARAMETERS` to arrays of
    shape (B,) (or scalars); missing ones take the config's defaults.
    ``progress(steps_done, n_steps, n_failed)`` is called about twice a second.
    The run is decided once (:func:`~warp_tensegrity.policy.decide.decide`): with
    ``settings.accuracy`` the method, precision and dt are chosen from it; with ``settings.truncate``
    only the prisms a wave can reach within t_end are simulated. Both are reported in
    ``result.info['choices']``. ``prisms_simulated`` fixes that count instead. ``plan``: a run
    decided already, for more columns than these (a sweep decides once for all its shards);
    ``settings`` and ``prisms_simulated`` are then the plan's.
    """
    return drive(simulate_batch_steps(config, params, settings, progress, prisms_simulated, plan=plan))


def simulate_batch_steps(config: ColumnConfig, params: dict, settings: RunSettings | None = None, progress=None,
                         prisms_simulated: int | None = None, *, plan: RunPlan | None = None):
    """:func:`simulate_batch` as a generator that yields while it steps and returns the BatchResult
    (:func:`run_batches` steps several at once)."""
    if plan is None:
        expect("simulate_batch", "settings", settings, RunSettings)
        plan = decide(config, params, settings, prisms_simulated=prisms_simulated)
    else:
        expect("simulate_batch", "plan", plan, RunPlan)
    params = column_params(config, check_batch_arguments("simulate_batch", config, params, plan.settings, progress))
    n, n_sim = config.n_prisms, plan.prisms_simulated
    sim_config = far_end(config, n_sim) if n_sim < n else config
    t_build = time.perf_counter()
    batch = column_batch(sim_config, far_end_params(params, n, n_sim))
    t_build = time.perf_counter() - t_build
    pulse = {"prism_height": config.height, "n_prisms": n, "cut": n - n_sim,
             "station": station_prism(n, plan.settings.energy_station),
             "end_prisms": end_prisms(n, plan.settings.energy_end_prisms)}
    result = yield from run_batch_steps(batch, progress=progress, pulse=pulse, plan=plan)
    result.params = dict(params)  # profiles of the whole column, not of the part simulated
    result.info["stages"]["build"] += t_build
    if n_sim < n:
        _pad_to_full_column(result, config, sim_config, params, n, n_sim)
    if plan.settings.measure == "host":
        from .measure.device import measure_host  # imports Warp (the record helpers): not at package import

        measure_host(result, config.height, keep_strain=plan.settings.record_strain, station=pulse["station"],
                     end_prisms=pulse["end_prisms"])
    result.info["choices"] = plan.choices()
    result.info["prism_height"] = float(config.height)  # for BatchResult.to_xarray's measurements
    # the per-case flag of the limit beta -> 1, evaluated when a dataset is built (it needs max_compression)
    result.info["beta_limit"] = partial(beta_limit_measures, config, column_params(config, params), result.n_columns)
    return result


class HostWork:
    """Host-side work that steps with the runs of :func:`run_batches`: a generator that yields between
    pieces (each under ``context``, e.g. :func:`~warp_tensegrity.scene.blas.one_blas_thread`) and
    returns ``value``; its seconds count as the ``stage`` it names."""

    def __init__(self, gen, stage: str = "measurement", context=None):
        self.gen, self.stage, self.context, self.value, self.seconds = gen, stage, context, None, 0.0

    def steps(self):
        while True:
            t0 = time.perf_counter()
            try:
                with self.context() if self.context is not None else contextlib.nullcontext():
                    next(self.gen)
            except StopIteration as stop:
                self.value = stop.value
                return
            finally:
                self.seconds += time.perf_counter() - t0
            yield


def run_batches(runs: list[tuple[ColumnConfig, dict, RunPlan]], device=None,
                progress: list | None = None, interleave: bool | None = None,
                host: list[HostWork] = ()) -> tuple[list[BatchResult], dict]:
    """Simulate several batches of T3 columns, each ``(config, params, plan)`` as
    :func:`simulate_batch` takes them, all on ``device`` (default: the first plan's). On a GPU they
    step at once, each on its own CUDA stream (:func:`~warp_tensegrity.sim.integrate.run_together`):
    a sweep's groups and their twins are each too narrow to fill it. Each batch's numbers are those
    it gets alone. ``progress``: one callback per run, or None; ``interleave``: as
    :func:`~warp_tensegrity.sim.integrate.run_together` takes it; ``host``: host work resumed in
    turn with the runs (after them, off a GPU), each its ``value`` when done. Returns the results in
    order and the stage seconds of the whole set (build, compile, measurement and transfer as the
    runs report them, the host work's in its stage; stepping: the rest of the set's wall time, the
    host feeding and waiting on the device)."""
    init_warp()  # quietly: no CUDA-driver warning on a CPU-only machine
    from .sim.integrate import run_together  # imports Warp: not at package import

    progress = progress or [None] * len(runs)
    device = resolve_device(device if device is not None or not runs else runs[0][2].device)
    t0 = time.perf_counter()
    results = run_together([simulate_batch_steps(c, p, progress=cb, plan=rp.with_device(device))
                            for (c, p, rp), cb in zip(runs, progress)] + [h.steps() for h in host],
                           device, interleave)[:len(runs)]
    wall = time.perf_counter() - t0
    stages = dict.fromkeys(("build", "compile", "stepping", "measurement", "transfer"), 0.0)
    for r in results:
        for k in ("build", "compile", "measurement", "transfer"):
            stages[k] += float(r.info["stages"].get(k, 0.0))
    for h in host:
        stages[h.stage] = stages.get(h.stage, 0.0) + h.seconds
    stages["stepping"] = max(wall - sum(stages.values()), 0.0)
    return results, stages


def _pad_to_full_column(result: BatchResult, config, sim_config, params, n: int, n_sim: int):
    """Give a truncated run the shapes and constants of the full column: the far prisms at rest."""
    cut = n - n_sim  # prisms (and levels) removed at the clamped end
    if result.strain is not None:
        B, T, _ = result.strain.shape
        result.strain = np.concatenate([np.zeros((B, T, cut)), result.strain], axis=2)
    f = result.feasibility  # prisms numbered in the full column; the far ones at their reference
    f["feasibility_prism"] = np.where(f["feasibility_prism"] >= 0, f["feasibility_prism"] + cut, -1).astype(np.int32)
    for k, ref in (("prism_twist_max", config.twist), ("prism_twist_min", config.twist),
                   ("prism_height_ratio_min", 1.0), ("prism_twist_last", config.twist)):
        f[k] = np.concatenate([np.full((f[k].shape[0], cut), ref), f[k]], axis=1)
    # the short column starts untwisted: rotate its vectors into the full column's frame
    theta = -config.twist * float(config.prism_handedness()[:cut].sum())
    c, sn = np.cos(theta), np.sin(theta)
    rot = np.array([[c, -sn, 0.0], [sn, c, 0.0], [0.0, 0.0, 1.0]])
    for name in ("final_displacement", "final_velocity"):
        a = getattr(result, name)
        if a is not None:
            setattr(result, name, np.concatenate([np.zeros((a.shape[0], 3 * cut, 3)), a @ rot.T], axis=1))
    # the removed prisms keep their prestress energy: add it so energies mean the whole column
    states, index = reference_states(column_params(config, params))
    sim_states = states if not any(np.ndim(v) == 2 for v in states.values()) else {
        k: v[:, cut:] if np.ndim(v) == 2 else v for k, v in states.items()}
    offset = reference_elastic_energy(column_batch(config, states)) - reference_elastic_energy(
        column_batch(sim_config, sim_states))
    result.elastic_energy = result.elastic_energy + offset[index][:, None]
