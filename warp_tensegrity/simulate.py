"""Integrator orchestration: time step choice, the step as kernel launches, graph capture, outputs.

Methods (one force evaluation = one ``gather_accel`` launch):

* ``rattle`` (default): velocity Verlet with SHAKE position projection and velocity
  projection every step (Andersen 1983). 2nd order, symplectic; stable for omega*dt < 2.
* ``rk4``: the paper's scheme, classic RK4 on the index-1 constrained equations, then
  projection of positions and velocities every step. 4th order; stable for omega*dt < 2*sqrt(2).
* ``yoshida4``: RATTLE composed by Yoshida's triple jump. 4th order, symmetric; omega*dt < 1.573.
* ``symplectic_euler``: kick with the full dt, drift, project. 1st order (negative control).
"""

from __future__ import annotations

import gc
import math
import time
from dataclasses import replace

import numpy as np
import warp as wp

from .batch import (
    NetworkBatch,
    column_batch,
    column_params,
    omega_max_bound,
    reference_elastic_energy,
    reference_states,
)
from .choose import apply_accuracy, reachable_prisms
from .columns import ColumnConfig
from .fused import make_fused_kernels, shared_capacity
from .kernels import make_kernels, make_solver_kernels
from .model import REAL, Data, Model, build_model, constraint_coupling, make_data, mass_entries
from .settings import BatchResult, RunSettings, SettingsError

# stability limit of omega*dt for each method on an undamped oscillator
STABILITY = {"rattle": 2.0, "rk4": 2.0 * math.sqrt(2.0), "yoshida4": 1.5734, "symplectic_euler": 2.0}
FORCE_EVALS = {"rattle": 1, "rk4": 4, "yoshida4": 3, "symplectic_euler": 1}
_W1 = 1.0 / (2.0 - 2.0 ** (1.0 / 3.0))
YOSHIDA = (_W1, 1.0 - 2.0 * _W1, _W1)
COLUMN_BLOCK_DIM = 64  # CUDA threads per block for the one-thread-per-column kernels
# Registers per CUDA thread of the column-solver kernels from COLUMN_CAP_FROM columns up: more
# columns in flight at once, for a few spills (benchmarks/results/staged_tuning_h200.json: +5-18 %
# at 131,072 and 262,144 columns, -6-10 % at 65,536, where every column is in flight already).
COLUMN_MAX_REGISTERS = 64
COLUMN_CAP_FROM = 131072
# Bar vectors of the last bw + 1 rows in registers while assembling the Gram matrix
# (kernels.make_solver_kernels): None = fp32 only (fp64 would spill them under the cap).
COLUMN_BAR_WINDOW = None
FUSED_BLOCK_DIM = 32  # CUDA threads per column block in the fused step (one warp)
FUSED_STEPS = 16  # most RATTLE steps per fused launch
# fused='auto' on a GPU: above this many columns the staged kernels stream faster (H200: the fused
# step is 1.25-1.55x faster at 16,384 columns, RB fp64 0.87x; 0.5-0.93x at 32,768; benchmarks/README.md)
FUSED_MAX_COLUMNS = 16384
FUSED_SHARED_ON_CPU = False  # CPU blocks run alone: the global rows are as fast there (tests may switch it on)
MAX_GRAPH_STEPS = 2000  # longest output interval (in steps) captured as one graph by the fused path


def default_device() -> str:
    """The first CUDA device if there is one, else the CPU."""
    return "cuda:0" if wp.get_cuda_device_count() > 0 else "cpu"


def resolve_device(name: str | None) -> wp.context.Device:
    name = name or default_device()
    try:
        return wp.get_device(name)
    except Exception as exc:  # warp raises RuntimeError/ValueError for unknown aliases
        raise SettingsError(f"device = {name!r} is not available ({exc}); use 'cpu' or 'cuda:N'") from None


def choose_timestep(settings: RunSettings, omega_max: float):
    """Returns (dt, dt_limit, n_steps, output_every) with dt dividing the output interval."""
    limit = STABILITY[settings.method] / omega_max if omega_max > 0 else math.inf
    interval = settings.output_interval or settings.t_end / 200.0
    if settings.dt == "auto":
        target = settings.dt_safety * limit
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


class Integrator:
    """Holds the model, data and kernels of one batch and advances it on one Warp device."""

    def __init__(self, batch: NetworkBatch, settings: RunSettings, dt: float, output_every: int, n_out: int):
        self.settings = settings
        self.device = resolve_device(settings.device)
        self.dt = dt
        self.every = output_every
        self.n_out = n_out
        t0 = time.perf_counter()
        with wp.ScopedDevice(self.device):
            self.model: Model = build_model(batch, settings.precision, self.device)
            self.fused = settings.fused is True or (
                settings.fused == "auto" and settings.method == "rattle"
                and (not self.device.is_cuda or batch.n_columns <= FUSED_MAX_COLUMNS))
            lanes = self.device.is_cuda or wp.config.enable_cpu_blocks  # the CPU emulates lanes only on request
            self.fused_block = (FUSED_BLOCK_DIM if lanes else 1) if self.fused else None
            m = self.model
            cap = 0  # reals of shared memory for the band and multipliers (0: global rows)
            if self.fused and (self.device.is_cuda or FUSED_SHARED_ON_CPU):
                cap = shared_capacity(m.n_constraints, m.bandwidth, 4 if settings.precision == "fp32" else 8)
            self.data: Data = make_data(m, batch.velocity, settings.method, self.fused_block, cap > 0)
            real = REAL[settings.precision]
            self.real = real
            self.k = make_kernels(real)
            regs = COLUMN_MAX_REGISTERS if self.device.is_cuda and batch.n_columns >= COLUMN_CAP_FROM else None
            self.ks = make_solver_kernels(real, self.model.bandwidth, regs, COLUMN_BAR_WINDOW)
            m = self.model
            B = m.n_columns
            self.strain = None
            if (settings.record_strain or settings.measure != "none") and m.n_prisms > 0:
                self.strain = wp.zeros((n_out, m.n_prisms, B), dtype=real)
            self.kinetic = wp.zeros((n_out, B), dtype=real)
            self.elastic = wp.zeros((n_out, B), dtype=real)
            self.fk = make_fused_kernels(real, cap, m.bandwidth) if self.fused else None
        self.column_kernels = {
            kern.key for kern in (self.ks.project_positions, self.ks.factor_project_velocities, self.ks.factor_only,
                                  self.ks.constrained_accel, self.k.record_energy)
        }
        self.build_time = time.perf_counter() - t0
        self.graph = None
        self.graph_steps = 0
        self.steps_done = 0

    # ------------------------------------------------------------------ launch helpers
    def _block_dim(self, kernel) -> int:
        """1 on the CPU; on CUDA small blocks for the per-column solver kernels (one thread per
        column), so a few thousand columns still spread over every SM."""
        if not self.device.is_cuda:
            return 1
        return COLUMN_BLOCK_DIM if kernel.key in self.column_kernels else 256

    def _launch(self, kernel, dim, inputs):
        wp.launch(kernel, dim=dim, inputs=inputs, device=self.device, block_dim=self._block_dim(kernel))

    def _gather(self, u, v, kick, a, v_out):
        m, d = self.model, self.data
        self._launch(self.k.gather_accel, (m.mass_blocks.shape[0], m.n_columns), [
            m.cab_EA, m.cab_EAc, m.cab_L, m.node_start, m.node_member, m.node_other, m.node_dref,
            m.mass_blocks, m.minv_self, m.minv_cross, d.status, u, v, self.real(kick), a, v_out])

    def _kick_drift(self, kick, drift):
        m, d = self.model, self.data
        self._launch(self.k.kick_drift, (m.n_nodes, m.n_columns),
                     [d.status, d.a, self.real(kick), self.real(drift), d.u, d.v, d.u_prev])

    def _project_positions(self, ug, inv_dt):
        m, d, s = self.model, self.data, self.settings
        if m.n_constraints == 0:
            return
        self._launch(self.ks.project_positions, m.n_columns, [
            m.con_i, m.con_j, m.con_dref, m.con_L, m.con_active, m.ncon_start, m.ncon_member, m.partner,
            m.minv_self, m.minv_cross, self.real(s.tolerance), int(s.max_projection_iters), self.real(s.failure_bar_error),
            self.real(inv_dt), d.band, ug, d.step, d.u, d.v, d.lam, d.imp, d.bar_err, d.iters, d.status, d.fail_step])

    def _cpl(self):
        m = self.model
        return [m.con_i, m.con_j, m.con_dref, m.con_active, m.cpl_start, m.cpl_l, m.cpl_a, m.cpl_cross, m.cpl_sign]

    def _factor_project_velocities(self, u, v):
        m, d = self.model, self.data
        if m.n_constraints == 0:
            return
        self._launch(self.ks.factor_project_velocities, m.n_columns, self._cpl() + [
            m.ncon_start, m.ncon_member, m.partner, m.minv_self, m.minv_cross, u, d.step, d.band, v, d.lam, d.imp,
            d.status, d.fail_step])

    def _factor(self, u):
        m, d = self.model, self.data
        if m.n_constraints == 0:
            return
        self._launch(self.ks.factor_only, m.n_columns, self._cpl() + [
            m.minv_self, m.minv_cross, u, d.step, d.band, d.status, d.fail_step])

    def _constrained_accel(self, u, v, a):
        m, d = self.model, self.data
        if m.n_constraints == 0:
            return
        self._launch(self.ks.constrained_accel, m.n_columns, self._cpl() + [
            m.ncon_start, m.ncon_member, m.partner, m.minv_self, m.minv_cross, u, v, d.step, d.band, a, d.lam, d.imp,
            d.status, d.fail_step])

    def _fused(self, n_sub: int, init: int = 0):
        m, d, s, f = self.model, self.data, self.settings, self.data.fused
        wp.launch_tiled(self.fk.rattle_columns, dim=[m.n_columns], block_dim=self.fused_block, device=self.device,
                        inputs=[
            m.con_i, m.con_j, m.con_dref, m.con_L, m.con_active, m.cpl_start, m.cpl_l, m.cpl_a, m.cpl_cross,
            m.cpl_sign, m.ncon_start, m.ncon_member, m.cab_i, m.cab_j, m.cab_dref, m.cab_EA, m.cab_EAc, m.cab_L,
            m.node_start, m.node_member, m.partner, m.minv_self, m.minv_cross, self.real(s.tolerance), int(s.max_projection_iters), self.real(s.failure_bar_error),
            self.real(self.dt), int(n_sub), int(init), d.step, d.u, d.v, d.a, d.bar_err, d.iters, d.status,
            d.fail_step, f.nodes, f.solve, f.red])

    def _fused_steps(self, n: int):
        """n RATTLE steps as fused launches of at most FUSED_STEPS, each followed by the counter and
        the (step-gated) records."""
        while n > 0:
            k = min(FUSED_STEPS, n)
            self._fused(k)
            self._launch(self.fk.advance_counter_by, 1, [self.data.step, k])
            self._record()
            n -= k

    def _record(self):
        m, d = self.model, self.data
        if self.strain is not None:
            self._launch(self.k.record_strain, (m.n_prisms, m.n_columns),
                         [m.level_nodes, m.h0, self.every, d.u, d.step, self.strain])
        self._launch(self.k.record_energy, m.n_columns, [
            m.cab_i, m.cab_j, m.cab_dref, m.cab_EA, m.cab_EAc, m.cab_L, m.partner, m.m_self, m.m_cross,
            self.every, d.u, d.v, d.step, self.kinetic, self.elastic])

    # ------------------------------------------------------------------ steps
    def load_kernels(self):
        """Compile/load the kernels this method uses now, with the block size they launch with,
        so no load happens while stepping or capturing."""
        if self.fused:
            self.fk.rattle_columns.module.load(self.device, self.fused_block)
            for kern in (self.fk.advance_counter_by, self.k.record_strain, self.k.record_energy):
                kern.module.load(self.device, self._block_dim(kern))
            return
        rk_only = {"rk_stage", "constrained_accel", "factor_only"}
        for name, kern in {**vars(self.k), **vars(self.ks)}.items():
            if isinstance(kern, wp.Kernel) and (self.settings.method == "rk4" or name not in rk_only):
                kern.module.load(self.device, self._block_dim(kern))

    def initialize(self):
        """Make the initial velocity exactly admissible, factor A(u0), compute a(u0), record step 0."""
        self.load_kernels()
        d = self.data
        if self.fused:
            self._fused(0, init=1)
        else:
            self._factor_project_velocities(d.u, d.v)
            self._gather(d.u, d.v, 0.0, d.a, d.v)
        self._record()

    def _rattle(self, h):
        d = self.data
        self._kick_drift(0.5 * h, h)
        self._project_positions(d.u_prev, 1.0 / h)
        self._gather(d.u, d.v, 0.5 * h, d.a, d.v)
        self._factor_project_velocities(d.u, d.v)

    def _symplectic_euler(self, h):
        d = self.data
        self._kick_drift(h, h)
        self._project_positions(d.u_prev, 1.0 / h)
        self._factor_project_velocities(d.u, d.v)
        self._gather(d.u, d.v, 0.0, d.a, d.v)

    def _rk4(self, h):
        d, r = self.data, self.data.rk
        wp.copy(r["u0"], d.u)
        wp.copy(r["v0"], d.v)
        # stage inputs (us, vs); the first stage reads the current state
        us, vs = d.u, d.v
        coefs = ((1.0, 0.5 * h, 1), (2.0, 0.5 * h, 0), (2.0, h, 0), (1.0, h / 6.0, 2))
        for c_acc, c_next, first in coefs:
            self._gather(us, vs, 0.0, d.a, d.imp)  # imp: unused velocity output
            self._constrained_accel(us, vs, d.a)
            u_next, v_next = (d.u, d.v) if first == 2 else (r["us"], r["vs"])
            self._launch(self.k.rk_stage, (self.model.n_nodes, self.model.n_columns), [
                d.status, r["u0"], r["v0"], vs, d.a, self.real(c_acc), self.real(c_next), first,
                r["acc_u"], r["acc_v"], u_next, v_next])
            us, vs = r["us"], r["vs"]
        # project the new state: positions along G(u_new), then velocities
        wp.copy(d.u_prev, d.u)
        self._factor(d.u)
        self._project_positions(d.u_prev, 0.0)
        self._factor_project_velocities(d.u, d.v)

    def step(self):
        """One step (eager launches)."""
        self.steps_done += 1
        self._step_launches()

    def _step_launches(self):
        if self.fused:
            self._fused_steps(1)
            return
        h = self.dt
        method = self.settings.method
        if method == "rattle":
            self._rattle(h)
        elif method == "yoshida4":
            for w in YOSHIDA:
                self._rattle(w * h)
        elif method == "rk4":
            self._rk4(h)
        elif method == "symplectic_euler":
            self._symplectic_euler(h)
        self._launch(self.k.advance_counter, 1, [self.data.step])
        self._record()

    def advance(self, n: int):
        """Advance n steps: through a captured CUDA graph of steps_per_graph steps when possible."""
        if self.fused:
            self._advance_fused(n)
            return
        spg = self.graph_steps or int(self.settings.steps_per_graph)  # a captured graph fixes it
        if self.device.is_cuda and n >= spg:
            if self.graph is None:
                gc.collect()
                with wp.ScopedCapture(device=self.device) as cap:
                    for _ in range(spg):
                        self._step_launches()
                self.graph = cap.graph
                self.graph_steps = spg
            while n >= spg:
                wp.capture_launch(self.graph)
                self.steps_done += spg
                n -= spg
        for _ in range(n):
            self.step()

    def _advance_fused(self, n: int):
        """Fused launches never straddle an output step; whole output periods (a multiple of
        ``every`` near steps_per_graph) replay one captured graph."""
        every = self.every
        period = self.graph_steps or every * max(1, -(-int(self.settings.steps_per_graph) // every))
        graphable = self.device.is_cuda and period <= MAX_GRAPH_STEPS
        while n > 0:
            phase = self.steps_done % every
            if graphable and phase == 0 and n >= period:
                if self.graph is None:
                    gc.collect()
                    with wp.ScopedCapture(device=self.device) as cap:
                        for _ in range(period // every):
                            self._fused_steps(every)  # launches end on every output step
                    self.graph = cap.graph
                    self.graph_steps = period
                wp.capture_launch(self.graph)
                k = period
            else:
                k = min(n, every - phase)
                self._fused_steps(k)
            self.steps_done += k
            n -= k

    # ------------------------------------------------------------------ results
    def n_failed(self) -> int:
        return int(np.count_nonzero(self.data.status.numpy()))


def _to_host(a: wp.array | None):
    return None if a is None else a.numpy().astype(np.float64)


def run_batch(batch: NetworkBatch, settings: RunSettings, progress=None, pulse: dict | None = None) -> BatchResult:
    """Integrate a prepared batch; see :func:`simulate_batch` for columns. ``pulse``: keywords of
    :func:`~warp_tensegrity.measure_device.measure_record` (prism_height, n_prisms, cut) to measure
    the record on the device (settings.measure = 'device')."""
    omega = float(omega_max_bound(batch).max())
    dt, limit, n_steps, every = choose_timestep(settings, omega)
    n_out = n_steps // every + 1
    integ = Integrator(batch, settings, dt, every, n_out)
    with wp.ScopedDevice(integ.device):
        t_compile = time.perf_counter()
        integ.initialize()
        if pulse is not None and settings.measure == "device":
            from .measure_device import load_kernels

            load_kernels(integ.device)
        wp.synchronize_device(integ.device)
        t_compile = time.perf_counter() - t_compile
        t0 = last = time.perf_counter()
        done = 0
        # advance in chunks (on CUDA ~20 per run, whole graphs each); report at most twice a second
        chunk = int(settings.steps_per_graph)
        if integ.device.is_cuda:
            chunk *= max(1, n_steps // (chunk * 20))
        while done < n_steps:
            n = min(chunk, n_steps - done)
            integ.advance(n)
            done += n
            if progress is not None and (time.perf_counter() - last > 0.5 or done == n_steps):
                wp.synchronize_device(integ.device)
                progress(done, n_steps, integ.n_failed())
                last = time.perf_counter()
        wp.synchronize_device(integ.device)
        wall = time.perf_counter() - t0
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
    stages = {"build": integ.build_time, "compile": t_compile, "stepping": wall}
    t_host = time.perf_counter()
    measurements = None
    if pulse is not None and integ.strain is not None and settings.measure == "device":
        from .measure_device import measure_record

        n_valid = np.where(status != 0, np.maximum(fail_step - 1, 0) // every + 1, n_out)
        measurements = measure_record(integ.strain, np.arange(n_out) * every * dt, n_valid=n_valid, timings=stages,
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
        time=np.arange(n_out) * every * dt,
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
            "max_projection_iterations": int(d.iters.numpy().max()) if batch.n_columns else 0,
            "bandwidth": integ.model.bandwidth,
            "n_constraints": integ.model.n_constraints,
            "build_time": integ.build_time,
            "initialize_time": t_compile,
            "graph_steps": integ.graph_steps,
            "force_evaluations_per_step": FORCE_EVALS[settings.method],
            "equilibrium_residual": None if batch.equilibrium_residual is None else batch.equilibrium_residual.copy(),
            "stages": stages,
        },
    )


def simulate_batch(config: ColumnConfig, params: dict, settings: RunSettings, progress=None) -> BatchResult:
    """Simulate B T3 columns of one topology, each with its own parameters.

    ``params`` maps names in :data:`~warp_tensegrity.settings.COLUMN_PARAMETERS` to arrays of
    shape (B,) (or scalars); missing ones take the config's defaults.
    ``progress(steps_done, n_steps, n_failed)`` is called about twice a second.
    With ``settings.accuracy`` the method, precision and dt are chosen from it; with
    ``settings.truncate`` only the prisms a wave can reach within t_end are simulated. Both are
    reported in ``result.info['choices']``.
    """
    n = config.n_prisms
    n_sim = prisms_to_simulate(config, params, settings)
    settings, choices = apply_accuracy(settings, n_sim)  # errors grow with the prisms a pulse crosses
    sim_config = _far_end(config, n_sim) if n_sim < n else config
    t_build = time.perf_counter()
    batch = column_batch(sim_config, params)
    t_build = time.perf_counter() - t_build
    pulse = {"prism_height": config.height, "n_prisms": n, "cut": n - n_sim}
    result = run_batch(batch, settings, progress, pulse=pulse)
    result.info["stages"]["build"] += t_build
    if n_sim < n:
        _pad_to_full_column(result, config, sim_config, params, n, n_sim)
    if settings.measure == "host":
        from .measure_device import measure_host

        measure_host(result, config.height, keep_strain=settings.record_strain)
    choices.update({"prisms_simulated": n_sim, "prisms": n, "method": settings.method,
                    "precision": settings.precision, "dt": result.dt,
                    "record_strain": settings.record_strain})
    result.info["choices"] = choices
    return result


def prisms_to_simulate(config: ColumnConfig, params: dict, settings: RunSettings) -> int:
    """The whole column, or with ``settings.truncate`` the prisms a front can reach within t_end."""
    n = config.n_prisms
    if not settings.truncate or n <= 4:
        return n
    hand = config.prism_handedness()
    if np.any(hand != hand[0]) and np.any(column_params(config, params)["base_rigidity"] >= 1.0):
        # rigid links in a mixed-handed column form a kinematic chain that carries motion ahead of
        # any elastic front, decaying only ~2x per prism (measured): no prism is safely at rest
        return n
    probe = column_batch(_far_end(config, 4), params)  # the omega bound is a local property
    return reachable_prisms(float(omega_max_bound(probe).max()), settings.t_end, n)


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


def estimate_batch(config: ColumnConfig, params: dict, settings: RunSettings, calibrated: bool = True) -> dict:
    """Time step, stability limit, step count, memory and time of a batch. With ``calibrated``
    (default) time and device memory come from a short probe of a few of its columns on the
    target device (:mod:`warp_tensegrity.calibrate`, cached); without, no kernel is launched and
    the time is a rough flop count."""
    settings, _ = apply_accuracy(settings, prisms_to_simulate(config, params, settings))
    batch = column_batch(config, params)
    omega = float(omega_max_bound(batch).max())
    dt, limit, n_steps, every = choose_timestep(settings, omega)
    n_out = n_steps // every + 1
    r = 4 if settings.precision == "fp32" else 8
    n, nc, ne, npr = batch.positions.shape[0], len(batch.constraints), len(batch.cables), config.n_prisms
    partner, *_ = mass_entries(batch)
    bw = constraint_coupling(batch, partner)[-1]
    state_vecs = 5 + (6 if settings.method == "rk4" else 0)
    per_col = r * (3 * n * state_vecs + nc * (bw + 2) + 3 * ne + 2 * n_out + (n_out * npr if settings.record_strain else 0))
    flops = FORCE_EVALS[settings.method] * (ne * 60 + n * 10) + nc * (bw + 1) ** 2 * (5 if settings.method == "rk4" else 2)
    # measured (benchmarks/results): the 2-core CPU backend runs ~1 ns per flop serially; on an H200 the
    # fused step takes >= ~0.1 ms (FB) .. 0.7 ms (RB, 50 prisms) per step (lane 0's serial Cholesky) and
    # sustains ~6e11 (fp32) / 3e11 (fp64) useful flop/s once the GPU is full
    device = resolve_device(settings.device)
    if device.is_cuda:
        step_latency = 1e-4 * (nc / 150.0) * ((bw + 1) / 4.0) ** 2
        rate = 6e11 if settings.precision == "fp32" else 3e11
        seconds = n_steps * max(step_latency, flops * batch.n_columns / rate)
    else:
        seconds = n_steps * batch.n_columns * flops * 1e-9
    out = {}
    if calibrated:
        from .calibrate import predict, probe

        cal = probe(config, params, replace(settings, dt=dt), batch.n_columns)
        pred = predict(cal, batch.n_columns, [batch.n_columns], n_steps, n_out, npr, settings.record_strain)
        st = pred["stages_s"]
        seconds = sum(st[k] for k in ("build", "stepping", "measurement", "transfer"))  # in-process, kernels loaded
        out = {"stages_estimate": st, "device_bytes_estimate": pred["device_bytes_per_shard"],
               "device_label": cal["device_label"]}
    return out | {
        "dt": dt,
        "dt_limit": limit,
        "n_steps": n_steps,
        "output_every": every,
        "n_out": n_out,
        "bytes_per_column": int(per_col),
        "flops_per_column_step": int(flops),
        "omega_max_bound": omega,
        "bandwidth": int(bw),
        "seconds_per_column_step_estimate": seconds / max(n_steps * batch.n_columns, 1),
        "seconds_estimate": seconds,
    }
