"""The staged Step: one kernel per stage (:mod:`.kernels`), the constraint solves one thread per column
(:mod:`.solver`); every method, and the staged-only bar contact (:mod:`.contact`) and striker
(:mod:`.striker`). Also the launcher of the staged kernels with their Model arguments by group, which
the Integrator's record kernels use too.

Methods (one force evaluation = one ``gather_accel`` launch):

* ``rattle`` (default): velocity Verlet with SHAKE position projection and velocity
  projection every step (Andersen 1983). 2nd order, symplectic; stable for omega*dt < 2.
* ``rk4``: the paper's scheme, classic RK4 on the index-1 constrained equations, then
  projection of positions and velocities every step. 4th order; stable for omega*dt < 2*sqrt(2).
* ``yoshida4``: RATTLE composed by Yoshida's triple jump. 4th order, symmetric; omega*dt < 1.573.
* ``symplectic_euler``: kick with the full dt, drift, project. 1st order (negative control).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import warp as wp

from ...types import ARGUMENT_GROUPS, Method, Path, RKStage, group_fields
from ..step import Step, register
from .contact import ContactStep
from .kernels import make_kernels
from .solver import make_gram_struct, make_solver_kernels
from .striker import ITERATIONS as STRIKER_ITERATIONS, StrikerStep

if TYPE_CHECKING:
    from ...scene.batch import NetworkBatch

_W1 = 1.0 / (2.0 - 2.0 ** (1.0 / 3.0))
YOSHIDA = (_W1, 1.0 - 2.0 * _W1, _W1)
COLUMN_BLOCK_DIM = 64  # CUDA threads per block for the one-thread-per-column kernels
# Registers per CUDA thread of the column-solver kernels from COLUMN_CAP_FROM columns up: more
# columns in flight at once, for a few spills (benchmarks/results/staged_tuning_h200.json: +5-18 %
# at 131,072 and 262,144 columns, -6-10 % at 65,536, where every column is in flight already).
COLUMN_MAX_REGISTERS = 64
COLUMN_CAP_FROM = 131072
# Bar vectors of the last bw + 1 rows in registers while assembling the Gram matrix
# (solver.make_solver_kernels): None = fp32 only (fp64 would spill them under the cap).
COLUMN_BAR_WINDOW = None


class Launcher:
    """Launches of staged kernels on one device: the Model arrays of a launch's argument groups first
    (:data:`warp_tensegrity.types.ARGUMENT_GROUPS`; "gram" as its struct), small blocks for the
    per-column kernels."""

    def __init__(self, model, device, real, settings):
        self.device, self.real = device, real
        self.args = {g: [getattr(model, f.name) for f in group_fields(g)] for g in ARGUMENT_GROUPS}
        gram = make_gram_struct(real)()
        for f in group_fields("gram"):
            setattr(gram, f.name, getattr(model, f.name))
        self.args["gram"] = [gram]
        self.projection = [real(settings.tolerance), int(settings.max_projection_iters), real(settings.failure_bar_error)]
        self.column_kernels: set[str] = set()
        """Keys of the one-thread-per-column kernels (their block size: :meth:`block_dim`)."""

    def block_dim(self, kernel) -> int:
        """1 on the CPU; on CUDA small blocks for the per-column kernels (one thread per column), so a
        few thousand columns still spread over every SM."""
        if not self.device.is_cuda:
            return 1
        return COLUMN_BLOCK_DIM if kernel.key in self.column_kernels else 256

    def load(self, kernel):
        kernel.module.load(self.device, self.block_dim(kernel))

    def launch(self, kernel, dim, inputs, model: str | tuple[str, ...] | None = None):
        """``model``: the argument group (or groups, in order) whose Model arrays lead the inputs."""
        for group in reversed((model,) if isinstance(model, str) else model or ()):
            inputs = self.args[group] + inputs
        wp.launch(kernel, dim=dim, inputs=inputs, device=self.device, block_dim=self.block_dim(kernel))


@register
class StagedStep(Step):
    """One kernel per stage; one step per launch (the record kernels after each see every step)."""

    path = Path.STAGED
    staged_scratch = True

    @classmethod
    def refusal(cls, settings, batch, device) -> str | None:
        if batch.contact_pairs is not None and settings.method != Method.RATTLE:
            return f"bar contact runs on the staged path with method = 'rattle' (got path staged, method {settings.method!r})"
        if batch.striker_mass is not None and settings.method != Method.RATTLE:
            return (f"the striker runs on the staged path with method = 'rattle' (got path staged, "
                    f"method {settings.method!r})")
        return None

    @classmethod
    def create(cls, integ, batch: NetworkBatch) -> StagedStep:
        return cls(integ.model, integ.data, batch, integ.device, integ.settings, integ.launcher, integ.n_out)

    def __init__(self, model, data, batch: NetworkBatch, device, settings, launcher: Launcher, n_out: int):
        self.model, self.data, self.device, self.settings, self.L = model, data, device, settings, launcher
        real = launcher.real
        self.real = real
        self.k = make_kernels(real)
        regs = COLUMN_MAX_REGISTERS if device.is_cuda and batch.n_columns >= COLUMN_CAP_FROM else None
        self.ks = make_solver_kernels(real, model.bandwidth, regs, COLUMN_BAR_WINDOW)
        launcher.column_kernels |= {kern.key for kern in (self.ks.project_positions, self.ks.factor_project,
                                                          self.ks.factor_only)}
        block = COLUMN_BLOCK_DIM if device.is_cuda else 1
        self.contact = None
        if batch.contact_pairs is not None:  # bar contact (scene contact = 'bars')
            self.contact = ContactStep(model, batch, device, block)
        self.striker = None
        if batch.striker_mass is not None:  # a striker (scene impact = 'striker')
            self.striker = StrikerStep(model, batch, device, block, n_out, settings.tolerance)

    @property
    def description(self) -> str:
        return "staged (one kernel per stage)"

    def load(self):
        if self.contact is not None:
            self.contact.load()
        if self.striker is not None:
            self.striker.load()
        names = ["gather_accel", "kick_drift", "project_positions", "factor_project"]
        if self.settings.method == Method.RK4:
            names += ["rk_stage", "factor_only"]
        for name in names:
            self.L.load(getattr(self.k, name) if hasattr(self.k, name) else getattr(self.ks, name))

    def initialize(self, data, settings, dt):
        self.data = data
        self.factor_project_velocities(data.u, data.v)
        self.gather(data.u, data.v, 0.0, data.a, data.v)

    def launch(self, data, settings, dt, n_sub):
        self.data = data
        for _ in range(n_sub):
            STEPS[Method(settings.method)](self, dt)

    # ------------------------------------------------------------------ stages
    def gather(self, u, v, kick, a, v_out):
        m, d = self.model, self.data
        self.L.launch(self.k.gather_accel, (m.mass_blocks.shape[0], m.n_columns),
                      [d.status, u, v, self.real(kick), a, v_out], model="gather")

    def kick_drift(self, kick, drift):
        m, d = self.model, self.data
        self.L.launch(self.k.kick_drift, (m.n_nodes, m.n_columns),
                      [d.status, d.a, self.real(kick), self.real(drift), d.u, d.v, d.u_prev])

    def _solve(self, kernel, group: str | tuple[str, ...], inputs):
        """A per-column constraint-solver launch (none without constraints)."""
        if self.model.n_constraints:
            self.L.launch(kernel, self.model.n_columns, inputs, model=group)

    def project_positions(self, ug, inv_dt):
        d = self.data
        self._solve(self.ks.project_positions, "positions", self.L.projection + [
            self.real(inv_dt), d.band, ug, d.step, d.u, d.v, d.lam, d.imp, d.bar_err, d.iters, d.status, d.fail_step])

    def factor_project(self, u, v, rates: int, out):
        """Factor A(u), then project the velocities ``out`` (``rates`` 0) or the accelerations ``out``
        at velocities v (1: the index-1 right-hand side)."""
        d = self.data
        self._solve(self.ks.factor_project, ("gram", "velocities"), [u, v, d.step, rates, d.band, out, d.lam, d.imp,
                                                                     d.status, d.fail_step])

    def factor_project_velocities(self, u, v):
        self.factor_project(u, v, 0, v)

    def constrained_accel(self, u, v, a):
        self.factor_project(u, v, 1, a)

    def factor(self, u):
        d = self.data
        self._solve(self.ks.factor_only, "gram", [u, d.step, d.band, d.status, d.fail_step])

    # ------------------------------------------------------------------ methods
    def rattle(self, h):
        d = self.data
        if self.striker is not None:
            self.rattle_striker(h)
            return
        if self.contact is not None:
            self.contact.save_start(d)
        self.kick_drift(0.5 * h, h)
        self.project_positions(d.u_prev, 1.0 / h)
        if self.contact is not None:  # bar pairs closer than 2 r join the projection (.contact)
            self.contact.positions(d, self.settings, d.u_prev, h)
        self.gather(d.u, d.v, 0.5 * h, d.a, d.v)
        self.factor_project_velocities(d.u, d.v)
        if self.contact is not None:
            self.contact.velocities(d)

    def rattle_striker(self, h):
        """RATTLE with the striker's unilateral row solved jointly with the members (.striker): the
        members' position projection once per secant evaluation of the contact multiplier, the
        velocity projection once more for the impulse's direction."""
        d, st = self.data, self.striker
        self.kick_drift(0.5 * h, h)
        st.drift(d, h)
        self.project_positions(d.u_prev, 0.0)
        for k in range(STRIKER_ITERATIONS):
            st.iterate(d, k)
            self.project_positions(d.u_prev, 0.0)
        st.finish(d, h)
        self.gather(d.u, d.v, 0.5 * h, d.a, d.v)
        self.factor_project_velocities(d.u, d.v)
        st.fill(d)
        self.factor_project_velocities(d.u, st.g)
        st.velocities(d, h)

    def symplectic_euler(self, h):
        d = self.data
        self.kick_drift(h, h)
        self.project_positions(d.u_prev, 1.0 / h)
        self.factor_project_velocities(d.u, d.v)
        self.gather(d.u, d.v, 0.0, d.a, d.v)

    def yoshida4(self, h):
        for w in YOSHIDA:
            self.rattle(w * h)

    def rk4(self, h):
        d, r = self.data, self.data.rk
        wp.copy(r["u0"], d.u)
        wp.copy(r["v0"], d.v)
        # stage inputs (us, vs); the first stage reads the current state
        us, vs = d.u, d.v
        coefs = ((1.0, 0.5 * h, RKStage.FIRST), (2.0, 0.5 * h, RKStage.MIDDLE), (2.0, h, RKStage.MIDDLE),
                 (1.0, h / 6.0, RKStage.LAST))
        for c_acc, c_next, stage in coefs:
            self.gather(us, vs, 0.0, d.a, d.imp)  # imp: unused velocity output
            self.constrained_accel(us, vs, d.a)
            u_next, v_next = (d.u, d.v) if stage == RKStage.LAST else (r["us"], r["vs"])
            self.L.launch(self.k.rk_stage, (self.model.n_nodes, self.model.n_columns), [
                d.status, r["u0"], r["v0"], vs, d.a, self.real(c_acc), self.real(c_next), int(stage),
                r["acc_u"], r["acc_v"], u_next, v_next])
            us, vs = r["us"], r["vs"]
        # project the new state: positions along G(u_new), then velocities
        wp.copy(d.u_prev, d.u)
        self.factor(d.u)
        self.project_positions(d.u_prev, 0.0)
        self.factor_project_velocities(d.u, d.v)


STEPS = {
    Method.RATTLE: StagedStep.rattle,
    Method.YOSHIDA4: StagedStep.yoshida4,
    Method.RK4: StagedStep.rk4,
    Method.SYMPLECTIC_EULER: StagedStep.symplectic_euler,
}
"""One staged step of each method: ``STEPS[method](staged_step, dt)``."""
