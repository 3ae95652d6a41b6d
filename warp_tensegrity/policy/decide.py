"""A run decided once: :func:`decide` (T3 columns of a scene) and :func:`decide_batch` (any prepared
batch) turn the settings into a frozen :class:`RunPlan`: method, precision and dt from the accuracy
(:mod:`.accuracy`), the prisms simulated (truncation), the stability bound, the output stride, the
Gram band and the launch path (:mod:`.paths`, :mod:`.lane_fit`), each with the reason it was taken.
A plan whose step count or one column's records no machine setting can hold is refused as it is
decided (:func:`.cost.size_problems`, a SettingsError with the figures): the output times and steps
(O(n_out)) are built only by the run itself; a head of them needs only its head
(:meth:`RunPlan.first_output_times`).

Everything downstream reads the plan and recomputes nothing: the engine steps it, the cost model
prices it (:mod:`.cost`), the calibration probe times it (:mod:`.calibrate`), a sweep stores it
once for all its shards (:mod:`warp_tensegrity.sweep.plan`), and the shards, the store template and
the dry run read it. No Warp at module level: the device is resolved inside :func:`decide`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from ..arguments import expect, expect_callable, expect_count, expect_params
from ..options import RunSettings, SettingsError
from ..runtime import cuda_memory, resolve_device
from ..scene.batch import NetworkBatch, column_batch, column_params, far_end_params, has_profiles, omega_max_bound
from ..scene.columns import ColumnConfig
from ..scene.contact import contact_strain
from ..types import Base, Path, Precision
from .accuracy import (
    REACH_MARGIN_PRISMS,
    apply_accuracy,
    choose_timestep,
    default_dt_safety,
    output_times,
    reachable_prisms,
)
from .cost import size_problems
from .lane_fit import lane_refusal, lane_support
from .paths import CONTACT_PATH, STRIKER_PATH, choose_path, gram_bandwidth

ESTIMATE_CHUNK_BYTES = 4_000_000
"""Host bytes of the column batches built at a time where all of a run's columns are only bounded
(omega_max), at ~400 B per prism and column (measured: 2,048 50-prism columns took ~39 MB): a plan
does not grow with the sweep's size."""


REGISTERS_PER_SM = 65536
"""32-bit registers of one streaming multiprocessor (every CUDA architecture from Kepler to Blackwell)."""
LANE_REGISTERS = 255
"""Registers per thread of the lane step: the compiler's cap, which its FB fp64 and RB kernels reach
(issue 33's profiles), so 8 warps per SM: 1,056 on an H200's 132 SMs."""
CPU_SHARD_SIZE = 256
"""Default shard size on the CPU, whose backend steps the columns one after another: a shard only
bounds the host memory and the work lost to a crash."""


def default_shard_size(device: str | None = None) -> int:
    """Columns per shard when the spec gives none (run.shard_size = 'auto'): on a GPU one warp per
    column for every warp slot its SMs hold at the lane step's registers (SM count x
    REGISTERS_PER_SM // (32 x LANE_REGISTERS)), so one launch fills the device; CPU_SHARD_SIZE on
    the CPU."""
    d = resolve_device(device)
    if not d.is_cuda:
        return CPU_SHARD_SIZE
    return max(1, int(d.sm_count) * (REGISTERS_PER_SM // (32 * LANE_REGISTERS)))


@dataclass(frozen=True)
class RunPlan:
    """What a run of T3 columns (or of a prepared batch) will do, decided once (:func:`decide`)."""

    settings: RunSettings
    """The settings stepped: method, precision and dt_safety resolved from the accuracy, ``dt`` the
    step below [s]."""
    dt: float
    """Time step [s]; it divides the output interval."""
    dt_limit: float
    """The method's stability limit for the stiffest column [s]."""
    n_steps: int
    """Steps to ``t_end``."""
    output_every: int
    """Steps between outputs."""
    omega_max_bound: float
    """Upper bound of the highest natural frequency over the columns, all cables taut [rad s-1]."""
    bandwidth: int
    """Half-bandwidth of the constraint Gram matrix G M^-1 G^T."""
    n_nodes: int
    n_constraints: int
    """Rigid members (bars, and rigid base links where a column has them)."""
    n_cables: int
    path: Path
    """The launch path (:func:`.paths.choose_path`)."""
    lane_refusal: str | None
    """Why the lane step does not take the columns; None if it does."""
    device: str
    """Warp device alias the run steps on."""
    on_gpu: bool
    n_columns: int
    """Columns per launch the path was chosen for (a sweep: its widest shard)."""
    prisms: int
    """Prisms of the scene's column (0 for a batch that is not a column)."""
    prisms_simulated: int
    """Prisms stepped from the impacted end (truncation; the rest stay at rest)."""
    accuracy: float | None = None
    """Relative error of the pulse measures targeted [1] (None: dt or dt_safety given)."""
    accuracy_source: str | None = None
    """'run.accuracy' or 'default'."""
    reasons: tuple[str, ...] = ()
    """Why each choice was taken, one sentence each."""

    @property
    def n_out(self) -> int:
        """Outputs, t = 0 included."""
        return self.n_steps // self.output_every + 1

    @property
    def method(self) -> str:
        return str(self.settings.method)

    @property
    def precision(self) -> str:
        return str(self.settings.precision)

    @property
    def output_steps(self) -> np.ndarray:
        """Steps of every output (n_out,): for the run itself; a count or a head needs none of it."""
        return self.first_output_steps(self.n_out)

    @property
    def output_times(self) -> np.ndarray:
        """Output times [s] (:func:`.accuracy.output_times`) of every output (n_out,)."""
        return self.first_output_times(self.n_out)

    def first_output_steps(self, n: int) -> np.ndarray:
        """Steps of the first ``n`` outputs (at most n_out), without building the others."""
        return np.arange(min(int(n), self.n_out), dtype=np.int64) * self.output_every

    def first_output_times(self, n: int) -> np.ndarray:
        """Times [s] of the first ``n`` outputs, equal to the head of :attr:`output_times` (the
        rounding reads the interval only)."""
        return output_times(self.first_output_steps(n), self.dt)

    def choices(self) -> dict:
        """The choices a result reports (``BatchResult.info['choices']``)."""
        out = {} if self.accuracy_source is None else {"accuracy": self.accuracy, "accuracy_source": self.accuracy_source}
        return out | {"dt_safety": self.settings.dt_safety, "prisms_simulated": self.prisms_simulated,
                      "prisms": self.prisms, "method": self.method, "precision": self.precision, "dt": self.dt,
                      "record_strain": self.settings.record_strain}

    def with_device(self, device: str | None) -> RunPlan:
        """The same plan on another device of the same kind (a Dask worker's GPU); None: unchanged."""
        if device is None or device == self.device:
            return self
        return replace(self, device=device, settings=replace(self.settings, device=device))


def check_batch_arguments(func: str, config, params, settings, progress=None) -> dict:
    """The arguments of a batch of columns checked (ArgumentError naming the parameter); the
    per-column parameters as a plain dict (masked arrays refused)."""
    expect(func, "config", config, ColumnConfig), expect(func, "settings", settings, RunSettings)
    expect_callable(func, "progress", progress)
    if settings.energy_station is not None and settings.energy_station >= config.n_prisms:
        raise SettingsError(f"energy_station = {settings.energy_station!r}: must be < the scene's n_prisms = "
                            f"{config.n_prisms}")
    return expect_params(func, params)


def far_end(config: ColumnConfig, n_sim: int) -> ColumnConfig:
    """The last n_sim prisms of the column (the impacted end), as a column of their own."""
    hand = config.prism_handedness()[-n_sim:]
    return replace(config, n_prisms=n_sim, handedness="".join("R" if h > 0 else "L" for h in hand))


def omega_bound(config: ColumnConfig, params: dict) -> float:
    """Largest omega_max bound [rad s-1] over the columns of ``params``, a few MB of columns at a time
    (each column's bound depends on its own parameters only)."""
    p = column_params(config, params)
    B, chunk = p["prestrain"].shape[0], max(16, ESTIMATE_CHUNK_BYTES // (400 * config.n_prisms))
    return max(float(omega_max_bound(column_batch(config, p.take(slice(i, i + chunk)))).max())
               for i in range(0, B, chunk))


def prisms_to_simulate(config: ColumnConfig, params: dict, settings: RunSettings) -> int:
    """The whole column, or with ``settings.truncate`` the prisms a front can reach within t_end
    (with bar contact, also a compaction front's reach)."""
    n = config.n_prisms
    if not settings.truncate or n <= 4 or config.impact == "striker":  # a striker keeps pushing: no front bound
        return n
    hand = config.prism_handedness()
    if np.any(hand != hand[0]) and np.any(column_params(config, params)["base_rigidity"] >= Base.RIGID):
        # rigid links in a mixed-handed column form a kinematic chain that carries motion ahead of
        # any elastic front, decaying only ~2x per prism (measured): no prism is safely at rest
        return n
    if np.any(column_params(config, params)["preload"] > 0):
        return n  # a preload stresses the whole column: the far prisms are not at their reference
    # a local bound: the last prisms of a uniform column; the whole column where a profile varies along it
    local = omega_bound(config, params) if has_profiles(params) else omega_bound(far_end(config, 4), params)
    reach = reachable_prisms(local, settings.t_end, n)
    if config.contact == "bars":
        # prisms locked at the contact compression eps_c pass the impact on rigidly: a compaction
        # front at ~v0/eps_c (0.5 of it measured, docs/contact.md), which strong impacts drive past
        # the elastic bound; twice that, with the margin
        eps = abs(contact_strain(config.radius, config.height, config.twist, config.bar_radius))
        v0 = float(np.max(column_params(config, params)["v0"]))
        front = math.ceil(2.0 * v0 * settings.t_end / (eps * config.height)) + REACH_MARGIN_PRISMS
        reach = max(reach, min(n, front))
    return reach


def _topology_batch(config: ColumnConfig, params: dict) -> NetworkBatch:
    """A batch with the members of the whole one (rigid links only when some column has them),
    from its first column and its first rigid-base column."""
    rigid = np.flatnonzero(params["base_rigidity"] >= Base.RIGID)
    rows = [0] + ([int(rigid[0])] if rigid.size and rigid[0] != 0 else [])
    return column_batch(config, params.take(rows))


def decide(config: ColumnConfig, params: dict, settings: RunSettings, *, n_columns: int | None = None,
           prisms_simulated: int | None = None) -> RunPlan:
    """The run of T3 columns of scene ``config`` with the per-column ``params`` (arrays (B,) or
    scalars, as :func:`~warp_tensegrity.simulate_batch` takes them), decided once.
    ``n_columns``: columns per launch (default: all of them; a sweep gives its widest shard).
    ``prisms_simulated``: fix the truncation instead of deriving it from ``settings``."""
    params = column_params(config, check_batch_arguments("decide", config, params, settings))
    n = config.n_prisms
    if prisms_simulated is None:
        n_sim = prisms_to_simulate(config, params, settings)
    else:
        n_sim = expect_count("decide", "prisms_simulated", prisms_simulated, 1, n, " (prisms)")
    settings, acc = apply_accuracy(settings, n_sim)  # errors grow with the prisms a pulse crosses
    sim = far_end(config, n_sim) if n_sim < n else config
    sim_params = far_end_params(params, n, n_sim)
    omega = omega_bound(sim, sim_params)
    lanes = lane_refusal(config, params, n_sim)
    reasons = [f"{n_sim} of {n} prisms simulated: " + ("the whole column" if n_sim == n else
                                                       f"a front reaches at most {n_sim} prisms by t_end")]
    return _finish(settings, acc, omega, _topology_batch(sim, sim_params), lanes,
                   int(params["prestrain"].shape[0]) if n_columns is None else int(n_columns), n, n_sim, reasons)


def decide_batch(batch: NetworkBatch, settings: RunSettings, lanes_refused: str | None = None) -> RunPlan:
    """The run of a prepared batch (any network), decided once. ``lanes_refused``: a reason, decided
    for more columns than this batch's, not to take the lane step."""
    expect("run_batch", "batch", batch, NetworkBatch), expect("run_batch", "settings", settings, RunSettings)
    settings, acc = apply_accuracy(settings) if settings.accuracy is not None else (settings, {})
    if settings.dt == "auto" and settings.dt_safety is None:  # the default accuracy over the reference column
        settings = replace(settings, dt_safety=default_dt_safety(settings.method)[0])
    n = 0 if batch.level_nodes is None else batch.level_nodes.shape[0] - 1
    return _finish(settings, acc, float(omega_max_bound(batch).max()), batch, lane_support(batch) or lanes_refused,
                   batch.n_columns, n, n, [])


def _finish(settings, acc: dict, omega: float, topology: NetworkBatch, lanes: str | None, n_columns: int, n: int,
            n_sim: int, reasons: list) -> RunPlan:
    """The plan from the bound, a batch with every member of the run's (``topology``) and the rest."""
    auto = settings.precision == Precision.AUTO
    if auto:  # a run alone has no twin to verify fp32 (policy.groups does)
        settings = replace(settings, precision=Precision.FP64)
    bandwidth = gram_bandwidth(topology)
    dt, limit, n_steps, every = choose_timestep(settings, omega)
    contact = topology.contact_pairs is not None
    if contact and settings.method != "rattle":
        raise SettingsError(f"method = {settings.method!r}: bar contact (scene contact = 'bars') is a RATTLE projection; "
                            "use method = 'rattle'" + (" (run.accuracy chose it: give dt or dt_safety instead)"
                                                       if settings.accuracy is not None else ""))
    striker = topology.striker_mass is not None
    if striker and settings.method != "rattle":
        raise SettingsError(f"method = {settings.method!r}: the striker (scene impact = 'striker') is a RATTLE "
                            "constraint; use method = 'rattle'" + (" (run.accuracy chose it: give dt or dt_safety "
                                                                   "instead)" if settings.accuracy is not None else ""))
    device = resolve_device(settings.device)  # initialises Warp (quietly)
    path = choose_path(settings, device.is_cuda, n_columns, bandwidth, lanes, contact, striker)
    reasons.append(f"dt = {dt:.4g} s: " + (f"{settings.dt_safety:.3g} x the stability limit {limit:.4g} s"
                                          if settings.dt == "auto" else "given"))
    reasons.append(f"path {path.value}: " + (CONTACT_PATH if contact else STRIKER_PATH if striker else
                                               f"fused = {settings.fused!r} on {device.alias}, {n_columns} columns per launch"
                                               + ("" if lanes is None else f"; not the lane step: {lanes}")))
    run = RunPlan(settings=replace(settings, device=device.alias), dt=dt, dt_limit=limit, n_steps=n_steps,
                  output_every=every, omega_max_bound=omega, bandwidth=int(bandwidth), n_nodes=int(topology.positions.shape[0]),
                  n_constraints=len(topology.constraints), n_cables=len(topology.cables), path=path, lane_refusal=lanes,
                  device=device.alias, on_gpu=bool(device.is_cuda), n_columns=n_columns, prisms=n,
                  prisms_simulated=n_sim, accuracy=acc.get("accuracy"), accuracy_source=acc.get("accuracy_source"),
                  reasons=tuple(reasons))
    if auto:
        run = replace(run, reasons=run.reasons + ("precision fp64: 'auto' without a twin run to verify fp32 case by case",))
    # every size that follows from the plan, checked before anything of the run's size is built
    # (its output times included): a run no shard size can fit is refused here, with its figures
    found = size_problems(run, device_bytes=cuda_memory(device)[1] if device.is_cuda else None)
    if found:
        raise SettingsError("the run cannot be done: " + "; ".join(found))
    return run
