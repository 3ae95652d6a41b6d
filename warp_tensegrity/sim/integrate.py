"""The Integrator: one batch's model, data and kernels on one Warp device, and the step as
kernel launches (staged: one kernel per stage; fused: RATTLE as one kernel, a block per column),
with CUDA graph capture. What to integrate with (method, dt, path) is decided by
:mod:`warp_tensegrity.engine`.

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
import time
from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np
import warp as wp

from .staged.contact import ContactStep
from .block.kernels import FusedStep
from .lanes.lanes import LaneStep
from .staged.kernels import make_kernels
from .staged.solver import make_solver_kernels
from .staged.striker import ITERATIONS as STRIKER_ITERATIONS, StrikerStep
from .model import REAL, Data, Model, build_model, make_data
from ..runtime import resolve_device
from ..options import RunSettings, SettingsError
from ..types import ARGUMENT_GROUPS, Method, Path, Precision, RKStage, group_fields

if TYPE_CHECKING:
    from ..scene.batch import NetworkBatch

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
FUSED_SHARED_ON_CPU = False  # CPU blocks run alone: the global rows are as fast there (tests may switch it on)
MAX_GRAPH_STEPS = 2000  # longest output interval (in steps) captured as one graph by the fused path


class Integrator:
    """Holds the model, data and kernels of one batch and advances it on one Warp device."""

    def __init__(self, batch: NetworkBatch, settings: RunSettings, dt: float, output_every: int, n_out: int, *,
                 path: Path, energy_parts: tuple[int, int] | None = None):
        """``path``: staged or fused launches (:func:`warp_tensegrity.engine.choose_path`); the
        fused path runs RATTLE only. ``energy_parts``: (below_node, end_node) of the energy-parts
        record (:func:`warp_tensegrity.measure.energy.part_nodes`), None: not recorded."""
        if path in (Path.FUSED, Path.FUSED_SERIAL, Path.LANES) and settings.method != Method.RATTLE:
            raise SettingsError(f"the fused path needs method = 'rattle' (got method = {settings.method!r})")
        if settings.precision == Precision.AUTO:  # a batch stepped directly: no twin to verify fp32 (policy.groups)
            settings = replace(settings, precision=Precision.FP64)
        self.settings = settings
        self.path = Path(path)
        self.device = resolve_device(settings.device)
        self.dt = dt
        self.every = output_every
        self.n_out = n_out
        t0 = time.perf_counter()
        with wp.ScopedDevice(self.device):
            self.model: Model = build_model(batch, settings.precision, self.device)
            self.fused = self.path in (Path.FUSED, Path.FUSED_SERIAL, Path.LANES)
            lanes = self.device.is_cuda or wp.config.enable_cpu_blocks  # the CPU emulates lanes only on request
            self.fused_block = (FUSED_BLOCK_DIM if lanes else 1) if self.fused else None
            m = self.model
            self.data: Data = make_data(m, batch.velocity, settings.method, self.fused, batch.initial_displacement)
            real = REAL[settings.precision]
            self.real = real
            self.k = make_kernels(real)
            regs = COLUMN_MAX_REGISTERS if self.device.is_cuda and batch.n_columns >= COLUMN_CAP_FROM else None
            self.ks = make_solver_kernels(real, self.model.bandwidth, regs, COLUMN_BAR_WINDOW)
            m = self.model
            B = m.n_columns
            self.strain = None
            if settings.record_strain and m.n_prisms > 0:
                self.strain = wp.zeros((n_out, m.n_prisms, B), dtype=real)
            self.kinetic = wp.zeros((n_out, B), dtype=real)
            self.elastic = wp.zeros((n_out, B), dtype=real)
            self.energy_parts = energy_parts
            self.energy_below = self.energy_end = None
            if energy_parts is not None:  # the energy measures' record (measure.energy)
                self.energy_below = wp.zeros((n_out, B), dtype=real)
                self.energy_end = wp.zeros((n_out, B), dtype=real)
            self.fk = None
            if self.path == Path.LANES:
                if not (self.device.is_cuda or wp.config.enable_cpu_blocks):  # each lane would be a block of its own
                    raise SettingsError("the lane step on the CPU needs Warp's CPU blocks (wp.config.enable_cpu_blocks; "
                                        "engine runs switch them on: paths.lane_emulation)")
                self.fk = LaneStep(m, batch, self.device, output_every, self.strain, self.kinetic, self.elastic,
                                   energy_parts, self.energy_below, self.energy_end)
            elif self.fused:
                self.fk = FusedStep(m, self.device, self.fused_block, FUSED_STEPS,
                                    self.device.is_cuda or FUSED_SHARED_ON_CPU,
                                    "serial" if self.path == Path.FUSED_SERIAL else "cr")
        self.contact = None
        if batch.contact_pairs is not None:  # bar contact (scene contact = 'bars'): the staged RATTLE step only
            if self.path != Path.STAGED or settings.method != Method.RATTLE:
                raise SettingsError(f"bar contact runs on the staged path with method = 'rattle' (got path "
                                    f"{self.path.value}, method {settings.method!r})")
            self.contact = ContactStep(self.model, batch, self.device, COLUMN_BLOCK_DIM if self.device.is_cuda else 1)
        self.striker = None
        if batch.striker_mass is not None:  # a striker (scene impact = 'striker'): the staged RATTLE step only
            if self.path != Path.STAGED or settings.method != Method.RATTLE:
                raise SettingsError(f"the striker runs on the staged path with method = 'rattle' (got path "
                                    f"{self.path.value}, method {settings.method!r})")
            self.striker = StrikerStep(self.model, batch, self.device, COLUMN_BLOCK_DIM if self.device.is_cuda else 1,
                                       n_out, settings.tolerance)
        self.column_kernels = {
            kern.key for kern in (self.ks.project_positions, self.ks.factor_project_velocities, self.ks.factor_only,
                                  self.ks.constrained_accel, self.k.record_energy, self.k.record_energy_parts)
        }
        self._group_arguments()
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

    def _launch(self, kernel, dim, inputs, model: str | None = None):
        """``model``: the argument group (types.ARGUMENT_GROUPS) whose Model arrays lead the inputs."""
        inputs = (self.args[model] + inputs) if model else inputs
        wp.launch(kernel, dim=dim, inputs=inputs, device=self.device, block_dim=self._block_dim(kernel))

    def _group_arguments(self):
        """The Model arguments of each launch, by argument group (the declared fields naming it, in
        their order: each kernel's signature lists them first, under ``# Model:``), and the
        projection settings as typed scalars."""
        m, s, real = self.model, self.settings, self.real
        self.args = {g: [getattr(m, f.name) for f in group_fields(g)] for g in ARGUMENT_GROUPS}
        self.projection = [real(s.tolerance), int(s.max_projection_iters), real(s.failure_bar_error)]

    def _gather(self, u, v, kick, a, v_out):
        m, d = self.model, self.data
        self._launch(self.k.gather_accel, (m.mass_blocks.shape[0], m.n_columns),
                     [d.status, u, v, self.real(kick), a, v_out], model="gather")

    def _kick_drift(self, kick, drift):
        m, d = self.model, self.data
        self._launch(self.k.kick_drift, (m.n_nodes, m.n_columns),
                     [d.status, d.a, self.real(kick), self.real(drift), d.u, d.v, d.u_prev])

    def _project_positions(self, ug, inv_dt):
        m, d = self.model, self.data
        if m.n_constraints == 0:
            return
        self._launch(self.ks.project_positions, m.n_columns, self.projection + [
            self.real(inv_dt), d.band, ug, d.step, d.u, d.v, d.lam, d.imp, d.bar_err, d.iters, d.status, d.fail_step],
            model="positions")

    def _factor_project_velocities(self, u, v):
        m, d = self.model, self.data
        if m.n_constraints == 0:
            return
        self._launch(self.ks.factor_project_velocities, m.n_columns,
                     [u, d.step, d.band, v, d.lam, d.imp, d.status, d.fail_step], model="velocities")

    def _factor(self, u):
        m, d = self.model, self.data
        if m.n_constraints == 0:
            return
        self._launch(self.ks.factor_only, m.n_columns, [u, d.step, d.band, d.status, d.fail_step], model="factor")

    def _constrained_accel(self, u, v, a):
        m, d = self.model, self.data
        if m.n_constraints == 0:
            return
        self._launch(self.ks.constrained_accel, m.n_columns,
                     [u, v, d.step, d.band, a, d.lam, d.imp, d.status, d.fail_step], model="velocities")

    def _fused(self, n_sub: int, init: int = 0):
        self.fk.launch(self.data, self.settings, self.dt, n_sub, init)

    def _fused_steps(self, n: int):
        """n RATTLE steps as fused launches of at most steps_per_launch, each followed by the counter
        and the (step-gated) records, unless the step writes them itself (``records_inside``)."""
        inside = self.fk.records_inside
        while n > 0:
            k = min(self.fk.steps_per_launch, n)
            self._fused(k)
            self.fk.advance_counter(self.data, k)
            if not inside:
                self._record()
            n -= k

    def _record(self):
        m, d = self.model, self.data
        if self.strain is not None:
            self._launch(self.k.record_strain, (m.n_prisms, m.n_columns),
                         [self.every, d.u, d.step, self.strain], model="strain")
        self._launch(self.k.record_energy, m.n_columns,
                     [self.every, d.u, d.v, d.step, self.kinetic, self.elastic], model="energy")
        if self.energy_parts is not None:
            self._launch(self.k.record_energy_parts, m.n_columns, [self.every, *self.energy_parts, d.u, d.v, d.step,
                                                                  self.energy_below, self.energy_end], model="energy")
        if m.n_prisms > 0:  # the feasibility record (types.FEASIBILITY_FLAGS), whether or not the strain is kept
            self._launch(self.k.record_feasibility, (m.n_prisms, m.n_columns), [self.every, d.u, d.status, d.step,
                         d.twist, d.twist_max, d.twist_min, d.height_min, d.left_slot], model="feasibility")
        elif m.n_pairs > 0:
            self._launch(self.k.record_pairs, (m.n_pairs, m.n_columns), [self.every, d.u, d.status, d.step,
                         d.pair_distance_min, d.cross_side, d.pair_left_slot], model="pairs")
        if self.striker is not None:
            self.striker.record(d, self.every)

    # ------------------------------------------------------------------ steps
    def load_kernels(self):
        """Compile/load the kernels this method uses now, with the block size they launch with,
        so no load happens while stepping or capturing."""
        unused = {"record_pairs" if self.model.n_prisms > 0 else "record_feasibility"}  # the other feasibility record
        if self.energy_parts is None:
            unused.add("record_energy_parts")
        if self.fused:
            self.fk.load()
            for name in ("record_strain", "record_energy", "record_energy_parts", "record_feasibility", "record_pairs"):
                if name not in unused:
                    kern = getattr(self.k, name)
                    kern.module.load(self.device, self._block_dim(kern))
            return
        if self.contact is not None:
            self.contact.load()
        if self.striker is not None:
            self.striker.load()
        if self.settings.method != Method.RK4:
            unused |= {"rk_stage", "constrained_accel", "factor_only"}
        for name, kern in {**vars(self.k), **vars(self.ks)}.items():
            if isinstance(kern, wp.Kernel) and name not in unused:
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
        if self.striker is not None:
            self._rattle_striker(h)
            return
        if self.contact is not None:
            self.contact.save_start(d)
        self._kick_drift(0.5 * h, h)
        self._project_positions(d.u_prev, 1.0 / h)
        if self.contact is not None:  # bar pairs closer than 2 r join the projection (sim.staged.contact)
            self.contact.positions(d, self.settings, d.u_prev, h)
        self._gather(d.u, d.v, 0.5 * h, d.a, d.v)
        self._factor_project_velocities(d.u, d.v)
        if self.contact is not None:
            self.contact.velocities(d)

    def _rattle_striker(self, h):
        """RATTLE with the striker's unilateral row solved jointly with the members (sim.staged.striker):
        the members' position projection once per secant evaluation of the contact multiplier, the
        velocity projection once more for the impulse's direction."""
        d, st = self.data, self.striker
        self._kick_drift(0.5 * h, h)
        st.drift(d, h)
        self._project_positions(d.u_prev, 0.0)
        for k in range(STRIKER_ITERATIONS):
            st.iterate(d, k)
            self._project_positions(d.u_prev, 0.0)
        st.finish(d, h)
        self._gather(d.u, d.v, 0.5 * h, d.a, d.v)
        self._factor_project_velocities(d.u, d.v)
        st.fill(d)
        self._factor_project_velocities(d.u, st.g)
        st.velocities(d, h)

    def _symplectic_euler(self, h):
        d = self.data
        self._kick_drift(h, h)
        self._project_positions(d.u_prev, 1.0 / h)
        self._factor_project_velocities(d.u, d.v)
        self._gather(d.u, d.v, 0.0, d.a, d.v)

    def _yoshida4(self, h):
        for w in YOSHIDA:
            self._rattle(w * h)

    def _rk4(self, h):
        d, r = self.data, self.data.rk
        wp.copy(r["u0"], d.u)
        wp.copy(r["v0"], d.v)
        # stage inputs (us, vs); the first stage reads the current state
        us, vs = d.u, d.v
        coefs = ((1.0, 0.5 * h, RKStage.FIRST), (2.0, 0.5 * h, RKStage.MIDDLE), (2.0, h, RKStage.MIDDLE),
                 (1.0, h / 6.0, RKStage.LAST))
        for c_acc, c_next, stage in coefs:
            self._gather(us, vs, 0.0, d.a, d.imp)  # imp: unused velocity output
            self._constrained_accel(us, vs, d.a)
            u_next, v_next = (d.u, d.v) if stage == RKStage.LAST else (r["us"], r["vs"])
            self._launch(self.k.rk_stage, (self.model.n_nodes, self.model.n_columns), [
                d.status, r["u0"], r["v0"], vs, d.a, self.real(c_acc), self.real(c_next), int(stage),
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
        STEPS[Method(self.settings.method)](self, self.dt)
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
        """Fused launches never straddle an output step, unless the step writes the records itself
        (``records_inside``: then any n steps); whole periods (near steps_per_graph: a multiple of
        ``every``, or of the launch's steps) replay one captured graph."""
        inside = self.fk.records_inside
        every = 1 if inside else self.every  # launches may end anywhere, or on an output step
        unit = self.fk.steps_per_launch if inside else every
        period = self.graph_steps or unit * max(1, -(-int(self.settings.steps_per_graph) // unit))
        graphable = self.device.is_cuda and period <= MAX_GRAPH_STEPS
        while n > 0:
            phase = self.steps_done % every
            if graphable and phase == 0 and n >= period:
                if self.graph is None:
                    gc.collect()
                    with wp.ScopedCapture(device=self.device) as cap:
                        for _ in range(period // unit):
                            self._fused_steps(unit)  # launches end on every output step, or span them
                    self.graph = cap.graph
                    self.graph_steps = period
                wp.capture_launch(self.graph)
                k = period
            else:
                k = n if inside else min(n, every - phase)
                self._fused_steps(k)
            self.steps_done += k
            n -= k

    def run(self, n_steps: int, progress=None) -> tuple[float, float]:
        """Initialize, then advance ``n_steps`` in chunks (on CUDA ~20 per run, whole graphs each),
        calling ``progress(done, n_steps, n_failed)`` at most twice a second. Returns the seconds
        spent stepping and initializing (kernel loads included)."""
        with wp.ScopedDevice(self.device):
            t_compile = time.perf_counter()
            self.initialize()
            wp.synchronize_device(self.device)
            t_compile = time.perf_counter() - t_compile
            t0 = last = time.perf_counter()
            done = 0
            # advance in chunks (on CUDA ~20 per run, whole graphs each); report at most twice a second
            chunk = int(self.settings.steps_per_graph)
            if self.device.is_cuda:
                chunk *= max(1, n_steps // (chunk * 20))
            while done < n_steps:
                n = min(chunk, n_steps - done)
                self.advance(n)
                done += n
                if progress is not None and (time.perf_counter() - last > 0.5 or done == n_steps):
                    wp.synchronize_device(self.device)
                    progress(done, n_steps, self.n_failed())
                    last = time.perf_counter()
            wp.synchronize_device(self.device)
            wall = time.perf_counter() - t0
        return wall, t_compile

    # ------------------------------------------------------------------ results
    def n_failed(self) -> int:
        return int(np.count_nonzero(self.data.status.numpy()))


STEPS = {
    Method.RATTLE: Integrator._rattle,
    Method.YOSHIDA4: Integrator._yoshida4,
    Method.RK4: Integrator._rk4,
    Method.SYMPLECTIC_EULER: Integrator._symplectic_euler,
}
"""One staged step of each method: ``STEPS[method](integrator, dt)``."""
