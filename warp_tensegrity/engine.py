"""Policy: what to integrate and how, decided in one place from the scene and the settings.

* accuracy -> method, precision and dt (:func:`for_accuracy`, :func:`apply_accuracy`);
* dt and output stride from the stability limit (:func:`choose_timestep`);
* truncation: which prisms to simulate (:func:`prisms_to_simulate`, :func:`reachable_prisms`);
* launch path, staged, fused or lanes (:func:`choose_path`, from :mod:`warp_tensegrity.paths`);
* the cost and memory model (:func:`estimate_batch`);
* and the entry points that apply them: :func:`simulate_batch` (columns), :func:`run_batch`
  (any prepared batch).

Nothing here imports Warp at module level, so a spec validates (it checks ``run.accuracy``
through :func:`for_accuracy`) without loading Warp; the integrator is imported when a batch runs.
Model no more than a scene needs: choices taken from the requested accuracy and the scene.

* :func:`for_accuracy` maps a target relative error of the pulse measures (speed, amplitude) to
  method, precision and the fraction of the stability limit used as dt. Errors accumulate as
  the pulse travels, so the rule depends on the prisms it crosses. Measured on the paper's
  50-prism column (``analysis/work_precision.md``, "Model no more than a scene needs"), the
  worse of speed and amplitude error is bounded by

      RATTLE:  0.59 (dt / dt_limit)^2 (n / 50)        RK4:  8 (dt / dt_limit)^4 (n / 50)

  with dt_limit = 2/omega_max (RATTLE) or 2*sqrt(2)/omega_max (RK4). The engine takes the
  cheaper method (force evaluations per simulated second) that meets the target, with dt at most
  half the limit, and fp32 unless the target is below 1e-4 (fp32 pulse errors equal fp64's
  down to ~1e-5). The final state of flexible-base columns after reflections is another matter:
  fp64 only (see the verdict). Flexible-base amplitudes below ~1e-4 are not promised: slack/taut
  cable switches cut RK4 to about second order there.

* :func:`reachable_prisms`: prisms a disturbance can reach within ``t_end``. A chain whose
  levels couple only to their neighbours has group velocities at most ``h0 * omega_max / 2``;
  with a factor 2 for stiffening under strong compression the front covers at most
  ``omega_max * t_end`` prisms. Prisms beyond that (plus a margin) stay at rest to round-off and
  need not be simulated: the column is clamped at the last level the front can reach.
  Not for mixed-handed columns with rigid bases: their rigid links and bars form a kinematic
  chain that moves prisms far ahead of the front (the disturbance decays only ~2x per prism
  there, against ~1000x per prism in a uniform rigid-base column), so those are never truncated.
"""

from __future__ import annotations

import math
import time
from dataclasses import replace
from functools import partial

import numpy as np

from .scene.batch import (
    NetworkBatch,
    column_batch,
    column_params,
    omega_max_bound,
    reference_elastic_energy,
    reference_states,
)
from .arguments import expect, expect_callable, expect_count, expect_params
from .scene.base_modes import beta_limit_measures
from .scene.columns import ColumnConfig
from .runtime import init_warp
from .result import BatchResult
from .paths import (FUSED_MAX_BANDWIDTH, MEASURED_H100, MEASURED_PATHS, NOT_CHECKED, choose_path,  # noqa: F401
                    gram_bandwidth, lane_emulation, lane_refusal, measured_rates)
from .settings import RunSettings, SettingsError
from .types import FORCE_EVALS, STABILITY, Base, Method

REACH_MARGIN_PRISMS = 8


DEFAULT_ACCURACY = 1e-3
"""Relative error of the pulse measures targeted when neither dt nor accuracy nor dt_safety is
given: the default run's dt fraction comes from the same error model as ``accuracy`` (measured on
the paper's FB and RB columns: amplitude and speed within 4.3e-4, strain history RMS within 8.5e-4
of the peak; README, benchmarks/default_accuracy.py)."""
LEGACY_DT_SAFETY = 0.25
"""dt fraction for methods without a measured error model (yoshida4, symplectic_euler)."""

ERROR_MODEL = {"rattle": (0.59, 2), "rk4": (8.0, 4)}
"""Measured error constant C and order p: error <= C (dt/dt_limit)^p (n_prisms/50)."""
REFERENCE_PRISMS = 50
MAX_FRACTION = 0.5


def for_accuracy(accuracy: float, n_prisms: int = REFERENCE_PRISMS) -> dict:
    """Method, precision and dt_safety for a target relative error of the pulse measures over a
    pulse that crosses ``n_prisms`` prisms."""
    if not (math.isfinite(accuracy) and 0 < accuracy < 1):
        raise SettingsError(f"accuracy = {accuracy!r} must lie in (0, 1) (relative error of pulse speed/amplitude)")
    best = None
    for method in ERROR_MODEL:
        frac = dt_fraction(method, accuracy, n_prisms)
        cost = FORCE_EVALS[method] / (frac * STABILITY[method])  # evaluations per unit of omega_max * t
        if best is None or cost < best[0]:
            best = (cost, method, frac)
    _, method, frac = best
    return {"method": method, "precision": "fp32" if accuracy >= 1e-4 else "fp64", "dt_safety": frac}


def dt_fraction(method: str, accuracy: float, n_prisms: int = REFERENCE_PRISMS) -> float:
    """The one accuracy -> dt decision: the fraction of the stability limit at which ``method``
    meets a relative error ``accuracy`` of the pulse measures over ``n_prisms`` prisms
    (``ERROR_MODEL``), at most ``MAX_FRACTION``."""
    C, p = ERROR_MODEL[method]
    travel = max(int(n_prisms), 1) / REFERENCE_PRISMS
    return min(MAX_FRACTION, (accuracy / (C * travel)) ** (1.0 / p))


def default_dt_safety(method: str, n_prisms: int = REFERENCE_PRISMS) -> tuple[float, float | None]:
    """(dt_safety, accuracy targeted) of a run given neither dt nor accuracy nor dt_safety."""
    if method in ERROR_MODEL:
        return dt_fraction(method, DEFAULT_ACCURACY, n_prisms), DEFAULT_ACCURACY
    return LEGACY_DT_SAFETY, None


def apply_accuracy(settings: RunSettings, n_prisms: int = REFERENCE_PRISMS) -> tuple[RunSettings, dict]:
    """Settings with method/precision/dt_safety chosen from ``settings.accuracy`` (if given) for a
    pulse crossing ``n_prisms`` prisms. Without accuracy, dt = 'auto' and no dt_safety, the dt
    fraction targets :data:`DEFAULT_ACCURACY` with the given method and precision."""
    if settings.accuracy is None:
        if settings.dt != "auto" or settings.dt_safety is not None:
            return settings, {}
        frac, target = default_dt_safety(settings.method, n_prisms)
        fields = dict(vars(settings), dt_safety=frac)
        return RunSettings(**fields), {"accuracy": target, "accuracy_source": "default", "dt_safety": frac}
    if settings.dt != "auto":
        raise SettingsError(
            f"accuracy = {settings.accuracy!r} and dt = {settings.dt!r}: give one of them; accuracy chooses dt"
        )
    choice = for_accuracy(settings.accuracy, n_prisms)
    fields = {k: v for k, v in vars(settings).items()}
    fields.update(choice)
    return RunSettings(**fields), {"accuracy": settings.accuracy, "accuracy_source": "run.accuracy", **choice}


def reachable_prisms(omega_max: float, t_end: float, n_prisms: int) -> int:
    """Prisms from the impacted end that a disturbance can reach within t_end, plus a margin."""
    reach = math.ceil(omega_max * t_end) + REACH_MARGIN_PRISMS
    return int(min(n_prisms, max(reach, 2)))

def choose_timestep(settings: RunSettings, omega_max: float):
    """Returns (dt, dt_limit, n_steps, output_every) with dt dividing the output interval."""
    limit = STABILITY[settings.method] / omega_max if omega_max > 0 else math.inf
    interval = settings.output_interval or settings.t_end / 200.0
    if settings.dt == "auto":
        safety = settings.dt_safety
        if safety is None:  # a batch run directly: the default accuracy over the reference column
            safety = default_dt_safety(settings.method)[0]
        target = safety * limit
        every = max(1, math.ceil(interval / target))
        dt = interval / every
        dt = min(dt, settings.t_end)
    else:
        dt = float(settings.dt)
        if dt > limit and not settings.allow_unstable_dt:
            raise SettingsError(
                f"dt = {dt:.4g} s exceeds the stability limit {limit:.4g} s of method {settings.method!r} "
                f"(omega_max = {omega_max:.4g} rad/s with all cables taut); use dt <= {limit:.4g}, dt = 'auto', "
                "or allow_unstable_dt"
            )
        every = max(1, round(interval / dt))
    n_steps = max(1, math.ceil(settings.t_end / dt - 1e-9))
    return dt, limit, n_steps, every


def output_times(steps: np.ndarray, dt: float) -> np.ndarray:
    """Output times [s] = step * dt, rounded to the decimals of the output interval (the step
    between outputs times dt), so printed times select exactly: 4975 * 0.002 gives 9.95, not
    9.950000000000001. Intervals with no decimal form of up to 12 decimals are not rounded."""
    steps = np.asarray(steps, dtype=np.int64)
    t = steps * dt
    if steps.size < 2:
        return t
    interval = float(steps[1] - steps[0]) * dt
    for d in range(13):
        if abs(round(interval, d) - interval) <= 1e-14 * interval:  # round-off only
            return np.round(t, d)
    return t


def _to_host(a):
    return None if a is None else a.numpy().astype(np.float64)


def run_batch(batch: NetworkBatch, settings: RunSettings, progress=None, pulse: dict | None = None,
              lanes_refused: str | None = None) -> BatchResult:
    """Integrate a prepared batch; see :func:`simulate_batch` for columns. ``pulse``: keywords of
    :func:`~warp_tensegrity.measure.device.measure_record` (prism_height, n_prisms, cut) to measure
    the record on the device (settings.measure = 'device'). ``lanes_refused``: a reason, decided
    for more columns than this batch's (a sweep's), not to take the lane step (:func:`choose_path`)."""
    expect("run_batch", "batch", batch, NetworkBatch), expect("run_batch", "settings", settings, RunSettings)
    expect_callable("run_batch", "progress", progress), expect("run_batch", "pulse", pulse, dict, optional=True)
    init_warp()  # quietly: no CUDA-driver warning on a CPU-only machine
    from .integrate import Integrator, resolve_device  # Warp loads here, not when a spec is read
    from .kernels.lanes import lane_support

    omega = float(omega_max_bound(batch).max())
    dt, limit, n_steps, every = choose_timestep(settings, omega)
    n_out = n_steps // every + 1
    device = resolve_device(settings.device)
    path = choose_path(settings, device.is_cuda, batch.n_columns, gram_bandwidth(batch),
                       lane_support(batch) or lanes_refused)
    # the measures need the record on the device, whether or not it crosses to the host
    record = settings.record_strain or settings.measure == "host" or (pulse is not None and settings.measure == "device")
    with lane_emulation(path, device):  # the CPU runs the lane step as fibers
        integ = Integrator(batch, replace(settings, record_strain=record), dt, every, n_out, path=path)
        wall, t_compile = integ.run(n_steps, progress)
    stages = {"build": integ.build_time, "compile": t_compile, "stepping": wall}
    measure_here = pulse is not None and integ.strain is not None and settings.measure == "device"
    if measure_here:
        from .measure.device import load_kernels, measure_record

        t0 = time.perf_counter()
        load_kernels(integ.device)
        stages["compile"] += time.perf_counter() - t0
    t_host = time.perf_counter()
    d = integ.data
    ke = _to_host(integ.kinetic).T  # (B, n_out)
    ee = _to_host(integ.elastic).T
    status = d.status.numpy().astype(np.int32)
    fail_step = d.fail_step.numpy().astype(np.int64)
    E = ke + ee
    # only outputs written before a failure are meaningful
    valid = np.ones_like(E, dtype=bool)
    for b in np.flatnonzero(status):
        last_slot = max(int(fail_step[b]) - 1, 0) // every
        valid[b, last_slot + 1 :] = False
        ke[b, last_slot + 1 :] = np.nan
        ee[b, last_slot + 1 :] = np.nan
    scale = np.where(ke[:, 0] > 0, ke[:, 0], np.nan)
    with np.errstate(invalid="ignore"):
        dev = np.where(valid, np.abs(E - E[:, :1]), 0.0)
        energy_error = dev.max(axis=1) / scale
    measurements = None
    if measure_here:
        n_valid = np.where(status != 0, np.maximum(fail_step - 1, 0) // every + 1, n_out)
        measurements = measure_record(integ.strain, output_times(np.arange(n_out) * every, dt), n_valid=n_valid, timings=stages,
                                      **pulse)
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
        time=output_times(np.arange(n_out) * every, dt),
        strain=strain,
        kinetic_energy=ke,
        elastic_energy=ee,
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
        dt_limit=limit,
        info={
            "omega_max_bound": omega,
            "output_every": every,
            "output_step": np.arange(n_out, dtype=np.int64) * every,
            "max_projection_iterations": int(d.iters.numpy().max()) if batch.n_columns else 0,
            "bandwidth": integ.model.bandwidth,
            "n_constraints": integ.model.n_constraints,
            "build_time": integ.build_time,
            "initialize_time": t_compile,
            "graph_steps": integ.graph_steps,
            "force_evaluations_per_step": FORCE_EVALS[settings.method],
            "step_path": integ.fk.description if integ.fused else "staged (one kernel per stage)",
            "equilibrium_residual": None if batch.equilibrium_residual is None else batch.equilibrium_residual.copy(),
            "stages": stages,
        },
    )


def simulate_batch(config: ColumnConfig, params: dict, settings: RunSettings, progress=None,
                   prisms_simulated: int | None = None, lanes_refused: str | None = None) -> BatchResult:
    """Simulate B T3 columns of one topology, each with its own parameters.

    ``params`` maps names in :data:`~warp_tensegrity.settings.COLUMN_PARAMETERS` to arrays of
    shape (B,) (or scalars); missing ones take the config's defaults.
    ``progress(steps_done, n_steps, n_failed)`` is called about twice a second.
    With ``settings.accuracy`` the method, precision and dt are chosen from it; with
    ``settings.truncate`` only the prisms a wave can reach within t_end are simulated. Both are
    reported in ``result.info['choices']``. ``prisms_simulated`` fixes that count instead (a sweep
    decides it once for all its columns, so no shard depends on which columns it holds), as
    ``lanes_refused`` does the lane step (a sweep's :func:`lane_refusal`; :func:`run_batch`).
    """
    params = check_batch_arguments("simulate_batch", config, params, settings, progress)
    n = config.n_prisms
    if prisms_simulated is not None:
        prisms_simulated = expect_count("simulate_batch", "prisms_simulated", prisms_simulated, 1, n, " (prisms)")
    n_sim = prisms_to_simulate(config, params, settings) if prisms_simulated is None else prisms_simulated
    settings, choices = apply_accuracy(settings, n_sim)  # errors grow with the prisms a pulse crosses
    sim_config = _far_end(config, n_sim) if n_sim < n else config
    t_build = time.perf_counter()
    batch = column_batch(sim_config, params)
    t_build = time.perf_counter() - t_build
    pulse = {"prism_height": config.height, "n_prisms": n, "cut": n - n_sim}
    result = run_batch(batch, settings, progress, pulse=pulse, lanes_refused=lanes_refused)
    result.info["stages"]["build"] += t_build
    if n_sim < n:
        _pad_to_full_column(result, config, sim_config, params, n, n_sim)
    if settings.measure == "host":
        from .measure.device import measure_host

        measure_host(result, config.height, keep_strain=settings.record_strain)
    choices.update({"dt_safety": settings.dt_safety, "prisms_simulated": n_sim, "prisms": n, "method": settings.method,
                    "precision": settings.precision, "dt": result.dt,
                    "record_strain": settings.record_strain})
    result.info["choices"] = choices
    result.info["prism_height"] = float(config.height)  # for BatchResult.to_xarray's measurements
    # the per-case flag of the limit beta -> 1, evaluated when a dataset is built (it needs max_compression)
    result.info["beta_limit"] = partial(beta_limit_measures, config, column_params(config, params), result.n_columns)
    return result


def check_batch_arguments(func: str, config, params, settings, progress=None) -> dict:
    """The arguments of a batch of columns checked (ArgumentError naming the parameter); the
    per-column parameters as a plain dict (masked arrays refused)."""
    expect(func, "config", config, ColumnConfig), expect(func, "settings", settings, RunSettings)
    expect_callable(func, "progress", progress)
    return expect_params(func, params)


def prisms_to_simulate(config: ColumnConfig, params: dict, settings: RunSettings) -> int:
    """The whole column, or with ``settings.truncate`` the prisms a front can reach within t_end."""
    n = config.n_prisms
    if not settings.truncate or n <= 4:
        return n
    hand = config.prism_handedness()
    if np.any(hand != hand[0]) and np.any(column_params(config, params)["base_rigidity"] >= Base.RIGID):
        # rigid links in a mixed-handed column form a kinematic chain that carries motion ahead of
        # any elastic front, decaying only ~2x per prism (measured): no prism is safely at rest
        return n
    omega = _omega_bound(_far_end(config, 4), params)  # the omega bound is a local property
    return reachable_prisms(omega, settings.t_end, n)


ESTIMATE_CHUNK_BYTES = 4_000_000
"""Host bytes of the column batches built at a time where all of a sweep's columns are only bounded
(omega_max), at ~400 B per prism and column (measured: 2,048 50-prism columns took ~39 MB): a plan
or an estimate does not grow with the sweep's size."""


def _omega_bound(config: ColumnConfig, params: dict) -> float:
    """Largest omega_max bound [rad s-1] over the columns of ``params``, a few MB of columns at a time
    (each column's bound depends on its own parameters only)."""
    p = column_params(config, params)
    B, chunk = p["prestrain"].size, max(16, ESTIMATE_CHUNK_BYTES // (400 * config.n_prisms))
    return max(float(omega_max_bound(column_batch(config, {k: v[i:i + chunk] for k, v in p.items()})).max())
               for i in range(0, B, chunk))


def _topology_batch(config: ColumnConfig, params: dict):
    """A batch with the members of the whole one (rigid links only when some column has them),
    from its first column and its first rigid-base column; and the whole batch's column count."""
    p = column_params(config, params)
    rigid = np.flatnonzero(p["base_rigidity"] >= Base.RIGID)
    rows = [0] + ([int(rigid[0])] if rigid.size and rigid[0] != 0 else [])
    return column_batch(config, {k: v[rows] for k, v in p.items()}), int(p["prestrain"].size)


def _far_end(config: ColumnConfig, n_sim: int) -> ColumnConfig:
    """The last n_sim prisms of the column (the impacted end), as a column of their own."""
    hand = config.prism_handedness()[-n_sim:]
    return replace(config, n_prisms=n_sim, handedness="".join("R" if h > 0 else "L" for h in hand))


def _pad_to_full_column(result: BatchResult, config, sim_config, params, n: int, n_sim: int):
    """Give a truncated run the shapes and constants of the full column: the far prisms at rest."""
    cut = n - n_sim  # prisms (and levels) removed at the clamped end
    if result.strain is not None:
        B, T, _ = result.strain.shape
        result.strain = np.concatenate([np.zeros((B, T, cut)), result.strain], axis=2)
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
    offset = reference_elastic_energy(column_batch(config, states)) - reference_elastic_energy(
        column_batch(sim_config, states))
    result.elastic_energy = result.elastic_energy + offset[index][:, None]


def estimate_batch(config: ColumnConfig, params: dict, settings: RunSettings) -> dict:
    """Time step, stability limit, step count and memory of a batch, without launching kernels
    (its seconds are a rough flop count; :func:`warp_tensegrity.calibrate.estimate_batch`, the
    public ``warp_tensegrity.estimate_batch``, adds time and memory from a probe on the device)."""
    params = check_batch_arguments("estimate_batch", config, params, settings)
    init_warp()
    from .integrate import resolve_device
    from .model import constraint_coupling, mass_entries

    n_sim = prisms_to_simulate(config, params, settings)
    settings, choices = apply_accuracy(settings, n_sim)
    batch, B = _topology_batch(config, params)
    omega = _omega_bound(config, params)
    lanes = lane_refusal(config, params, n_sim)  # as a sweep decides it for all its shards
    dt, limit, n_steps, every = choose_timestep(settings, omega)
    n_out = n_steps // every + 1
    r = 4 if settings.precision == "fp32" else 8
    n, nc, ne, npr = batch.positions.shape[0], len(batch.constraints), len(batch.cables), config.n_prisms
    partner, *_ = mass_entries(batch)
    bw = constraint_coupling(batch, partner)[-1]
    state_vecs = 5 + (6 if settings.method == Method.RK4 else 0)
    per_col = r * (3 * n * state_vecs + nc * (bw + 2) + 3 * ne + 2 * n_out + (n_out * npr if settings.record_strain else 0))
    flops = FORCE_EVALS[settings.method] * (ne * 60 + n * 10) + nc * (bw + 1) ** 2 * (5 if settings.method == Method.RK4 else 2)
    # measured (benchmarks/results): the 2-core CPU backend runs ~1 ns per flop serially; on an H200 the
    # fused step takes >= ~0.1 ms (FB) .. 0.7 ms (RB, 50 prisms) per step (lane 0's serial Cholesky) and
    # sustains ~6e11 (fp32) / 3e11 (fp64) useful flop/s once the GPU is full
    device = resolve_device(settings.device)
    if device.is_cuda:
        step_latency = 1e-4 * (nc / 150.0) * ((bw + 1) / 4.0) ** 2
        rate = 6e11 if settings.precision == "fp32" else 3e11
        seconds = n_steps * max(step_latency, flops * B / rate)
    else:
        seconds = n_steps * B * flops * 1e-9
    return {
        "dt": dt,
        "dt_limit": limit,
        "n_steps": n_steps,
        "output_every": every,
        "n_out": n_out,
        "bytes_per_column": int(per_col),
        "flops_per_column_step": int(flops),
        "omega_max_bound": omega,
        "bandwidth": int(bw),
        "step_path": str(choose_path(settings, device.is_cuda, B, int(bw), lanes).value),
        "lane_refusal": lanes,
        "on_gpu": bool(device.is_cuda),
        "seconds_per_column_step_estimate": seconds / max(n_steps * B, 1),
        "seconds_estimate": seconds,
        "dt_safety": settings.dt_safety,
        "accuracy_target": choices.get("accuracy"),
        "prisms_simulated": n_sim,
    }
