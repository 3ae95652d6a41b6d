"""The striker on the staged RATTLE step (scene ``impact = 'striker'``, issue 34; model and blow:
:mod:`warp_tensegrity.scene.striker`, docs/impact.md).

The striker is one more body of the column: its face height s and velocity V, mass M, no force but
the contact. The contact is the unilateral constraint c = s - z_end >= 0 (z_end the mean height of
the end base's three nodes), a RATTLE constraint like the bars, solved jointly with them:

* **Positions.** After the drift (the striker drifts s += h V), the members' projection runs as
  usual. If then c < 0, the joint projection has a multiplier nu > 0 along M^-1 grad c: the striker
  moves up by nu / M, each end node down by nu / (3 m_i), and the members are projected again. c is
  linear in the positions, so c(nu) is a smooth scalar function of the scalar nu; it is solved by a
  secant on nu (:data:`ITERATIONS` updates, the first from the slope of the last velocity stage),
  each evaluation one pass of the staged members' projection (the same kernel, so the joint
  projection is the members' own SHAKE along M^-1 G(u_start)^T plus the striker's row; the secant is
  written here because each evaluation is a launch of that device kernel). A gap within the members'
  projection tolerance times the prism height still touches. The velocities take the whole position
  correction / h (RATTLE). The largest |c| left over the run is recorded (``contact_residual``).
* **Velocities.** After the members' velocity projection P, a column in contact (it touched in the
  position stage) whose
  relative velocity c' = V - z_end' is negative gets the impulse mu along P M^-1 grad c: the
  velocity constraint is linear, so one more projection of M^-1 grad c (a scratch field) makes
  c' = 0 exactly (mu = -c' / (1/M + |grad c|^2_P)). c' >= 0: the striker leaves (no impulse).
  A column apart (a gap after the members' projection) gets nothing: the striker flies on.

No penalty stiffness enters, so the striker does not lower the stable time step. The contact force
recorded is the striker's momentum change over the step / h (its only force), positive when it
pushes the column. A first contact after a separation is a plastic impact (the position stage kills
the approach), like the blow.
"""

import functools
from typing import NamedTuple

import numpy as np
import warp as wp

from ..common import STATUS_OK, output_slot

wp.set_module_options({"enable_backward": False})

ITERATIONS = 4
"""Secant updates of the contact multiplier per step (each one pass of the members' projection)."""


class StrikerKernels(NamedTuple):
    """The striker's kernels."""

    striker_drift: wp.Kernel
    striker_iterate: wp.Kernel
    striker_finish: wp.Kernel
    striker_fill: wp.Kernel
    striker_velocity: wp.Kernel
    striker_record: wp.Kernel


@functools.cache
def make_striker_kernels(real):
    """The striker kernels for scalar type ``real`` (one thread per column)."""
    vec = wp.types.vector(3, real)
    third = real(1.0 / 3.0)

    @wp.func
    def mean_z(x: wp.array2d(dtype=vec), nodes: wp.array(dtype=int), w: int):
        return (x[nodes[0], w][2] + x[nodes[1], w][2] + x[nodes[2], w][2]) * third

    @wp.kernel(enable_backward=False, module="unique")
    def striker_drift(status: wp.array(dtype=int), h: real, u: wp.array2d(dtype=vec), s: wp.array(dtype=real),
                      V: wp.array(dtype=real), v_start: wp.array(dtype=real), nu: wp.array(dtype=real),
                      ut: wp.array2d(dtype=vec)):
        """The striker drifts; the column's drifted positions are kept (the secant restarts from them)."""
        w = wp.tid()
        if status[w] != STATUS_OK:
            return
        v_start[w] = V[w]
        s[w] = s[w] + h * V[w]
        nu[w] = real(0.0)
        for n in range(u.shape[0]):
            ut[n, w] = u[n, w]

    @wp.kernel(enable_backward=False, module="unique")
    def striker_iterate(k: int, touch: real, nodes: wp.array(dtype=int), minv_self: wp.array2d(dtype=real),
                        mass: wp.array(dtype=real), status: wp.array(dtype=int), s: wp.array(dtype=real),
                        ut: wp.array2d(dtype=vec), slope: wp.array(dtype=real), u: wp.array2d(dtype=vec),
                        nu: wp.array(dtype=real), nu_prev: wp.array(dtype=real), c_prev: wp.array(dtype=real),
                        active: wp.array(dtype=int)):
        """c at the projected positions of the current nu; the next nu (k = 0: from the slope, then a
        secant); the column restarts from its drifted positions moved by the next nu. A gap up to
        ``touch`` [m] (what the members' projection leaves of the positions: its tolerance times the
        prism height) still touches, so a striker that touches is not taken for gone; no force unless
        c < 0 there."""
        w = wp.tid()
        if status[w] != STATUS_OK:
            return
        M = mass[w % mass.shape[0]]
        c = s[w] + nu[w] / M - mean_z(u, nodes, w)
        nxt = nu[w]
        if k == 0:
            if c > touch:  # apart: no contact force this step
                active[w] = 0
                return
            active[w] = 1
            nxt = wp.max(-c / slope[w], real(0.0))
        else:
            if active[w] == 0:
                return
            dc = c - c_prev[w]
            if dc != real(0.0):
                nxt = nu[w] - c * (nu[w] - nu_prev[w]) / dc
            if nxt < real(0.0):
                nxt = real(0.0)
        c_prev[w] = c
        nu_prev[w] = nu[w]
        nu[w] = nxt
        for n in range(u.shape[0]):
            u[n, w] = ut[n, w]
        ws = w % minv_self.shape[1]
        for i in range(3):
            a = nodes[i]
            u[a, w] = ut[a, w] - vec(real(0.0), real(0.0), nxt * third * minv_self[a, ws])

    @wp.kernel(enable_backward=False, module="unique")
    def striker_finish(inv_h: real, nodes: wp.array(dtype=int), mass: wp.array(dtype=real),
                       status: wp.array(dtype=int), ut: wp.array2d(dtype=vec), u: wp.array2d(dtype=vec),
                       nu: wp.array(dtype=real), active: wp.array(dtype=int), v: wp.array2d(dtype=vec),
                       s: wp.array(dtype=real), V: wp.array(dtype=real), residual: wp.array(dtype=real)):
        """The position stage's velocity update (the whole correction / h, the members' and the
        striker's) and the striker's move by nu / M; records |c| left in contact."""
        w = wp.tid()
        if status[w] != STATUS_OK:
            return
        for n in range(u.shape[0]):
            v[n, w] = v[n, w] + (u[n, w] - ut[n, w]) * inv_h
        if active[w] == 1:
            M = mass[w % mass.shape[0]]
            s[w] = s[w] + nu[w] / M
            V[w] = V[w] + nu[w] / M * inv_h
            residual[w] = wp.max(residual[w], wp.abs(s[w] - mean_z(u, nodes, w)))

    @wp.kernel(enable_backward=False, module="unique")
    def striker_fill(nodes: wp.array(dtype=int), minv_self: wp.array2d(dtype=real), status: wp.array(dtype=int),
                     active: wp.array(dtype=int), g: wp.array2d(dtype=vec)):
        """g = M^-1 grad_x c (the end nodes' part: -1/(3 m_i) e_z) in a column in contact, else 0."""
        w = wp.tid()
        if status[w] != STATUS_OK:
            return
        for n in range(g.shape[0]):
            g[n, w] = vec()
        if active[w] == 1:
            ws = w % minv_self.shape[1]
            for i in range(3):
                a = nodes[i]
                g[a, w] = vec(real(0.0), real(0.0), -third * minv_self[a, ws])

    @wp.kernel(enable_backward=False, module="unique")
    def striker_velocity(inv_h: real, nodes: wp.array(dtype=int), mass: wp.array(dtype=real),
                         status: wp.array(dtype=int), step: wp.array(dtype=int), g: wp.array2d(dtype=vec),
                         active: wp.array(dtype=int), v_start: wp.array(dtype=real), v: wp.array2d(dtype=vec),
                         V: wp.array(dtype=real), slope: wp.array(dtype=real), force: wp.array(dtype=real),
                         sep_step: wp.array(dtype=int), contacts: wp.array(dtype=int), last_sep: wp.array(dtype=int)):
        """In contact: c' = V - z_end' made >= 0 by the impulse mu along P M^-1 grad c (g, projected).
        The step's contact force (the striker's momentum change / h), the first separation (the start
        of the first step without a contact force), the last one and the contacts after the first."""
        w = wp.tid()
        if status[w] != STATUS_OK:
            return
        M = mass[w % mass.shape[0]]
        if active[w] == 1:
            sl = real(1.0) / M - mean_z(g, nodes, w)
            slope[w] = sl
            cdot = V[w] - mean_z(v, nodes, w)
            if cdot < real(0.0):
                mu = -cdot / sl
                for n in range(v.shape[0]):
                    v[n, w] = v[n, w] + g[n, w] * mu
                V[w] = V[w] + mu / M
            if sep_step[w] >= 0 and contacts[w] % 2 == 1:  # touching again after the separation
                contacts[w] = contacts[w] + 1
        else:
            if sep_step[w] < 0:
                sep_step[w] = step[0]
            if contacts[w] % 2 == 0:  # it leaves now
                contacts[w] = contacts[w] + 1
                last_sep[w] = step[0]
        force[w] = M * (V[w] - v_start[w]) * inv_h

    @wp.kernel(enable_backward=False, module="unique")
    def striker_record(every: int, step: wp.array(dtype=int), V: wp.array(dtype=real), force: wp.array(dtype=real),
                       v_rec: wp.array2d(dtype=real), f_rec: wp.array2d(dtype=real)):
        """The striker's velocity and the last step's contact force when step % every == 0."""
        w = wp.tid()
        slot = output_slot(step[0], every, v_rec.shape[0])
        if slot < 0:
            return
        v_rec[slot, w] = V[w]
        f_rec[slot, w] = force[w]

    return StrikerKernels(striker_drift=striker_drift, striker_iterate=striker_iterate, striker_finish=striker_finish,
                          striker_fill=striker_fill, striker_velocity=striker_velocity, striker_record=striker_record)


class StrikerStep:
    """The striker's device arrays and launches for one model on one device (the staged RATTLE step)."""

    def __init__(self, model, batch, device, block_dim: int, n_out: int, tolerance: float):
        """``tolerance``: the projection's relative bar-length tolerance; a gap within it times the prism
        height still touches (the positions are no more accurate than that)."""
        real = wp.float64 if model.precision == "fp64" else wp.float32
        npr = np.float64 if model.precision == "fp64" else np.float32
        self.real, self.device, self.block_dim = real, device, block_dim
        self.k = make_striker_kernels(real)
        B, n = model.n_columns, model.n_nodes
        self.n_columns = B
        self.model = model
        z = batch.positions[np.asarray(batch.level_nodes), 2].mean(axis=1)
        self.touch = float(tolerance) * float(np.abs(np.diff(z)).max())
        arr = lambda x: wp.array(np.ascontiguousarray(x, dtype=npr), dtype=real, device=device)  # noqa: E731
        self.mass_host = np.asarray(batch.striker_mass, dtype=np.float64)
        self.mass = arr(self.mass_host)
        self.nodes = wp.array(np.asarray(batch.striker_nodes, dtype=np.int32), dtype=int, device=device)
        self.s = wp.zeros(B, dtype=real, device=device)
        self.V = arr(batch.striker_velocity)
        self.v_start = arr(batch.striker_velocity)
        self.slope = arr(1.0 / self.mass_host + 1.0 / np.asarray(batch.striker_end_mass, dtype=np.float64))
        self.nu, self.nu_prev, self.c_prev, self.force, self.residual = (wp.zeros(B, dtype=real, device=device)
                                                                          for _ in range(5))
        self.active = wp.zeros(B, dtype=int, device=device)
        self.contacts = wp.zeros(B, dtype=int, device=device)
        self.sep_step = wp.full(B, -1, dtype=int, device=device)
        self.last_sep = wp.full(B, -1, dtype=int, device=device)
        vec = wp.types.vector(3, real)
        self.ut = wp.zeros((n, B), dtype=vec, device=device)
        self.g = wp.zeros((n, B), dtype=vec, device=device)
        self.v_rec = wp.zeros((n_out, B), dtype=real, device=device)
        self.f_rec = wp.zeros((n_out, B), dtype=real, device=device)

    def _launch(self, kernel, inputs):
        wp.launch(kernel, dim=self.n_columns, inputs=inputs, device=self.device, block_dim=self.block_dim)

    def load(self):
        for kern in self.k:
            kern.module.load(self.device, self.block_dim)

    def drift(self, data, h: float):
        self._launch(self.k.striker_drift, [data.status, self.real(h), data.u, self.s, self.V, self.v_start, self.nu,
                                            self.ut])

    def iterate(self, data, k: int):
        self._launch(self.k.striker_iterate, [int(k), self.real(self.touch), self.nodes, self.model.minv_self, self.mass, data.status, self.s,
                                              self.ut, self.slope, data.u, self.nu, self.nu_prev, self.c_prev,
                                              self.active])

    def finish(self, data, h: float):
        self._launch(self.k.striker_finish, [self.real(1.0 / h), self.nodes, self.mass, data.status, self.ut, data.u,
                                             self.nu, self.active, data.v, self.s, self.V, self.residual])

    def fill(self, data):
        self._launch(self.k.striker_fill, [self.nodes, self.model.minv_self, data.status, self.active, self.g])

    def velocities(self, data, h: float):
        self._launch(self.k.striker_velocity, [self.real(1.0 / h), self.nodes, self.mass, data.status, data.step,
                                               self.g, self.active, self.v_start, data.v, self.V, self.slope,
                                               self.force, self.sep_step, self.contacts, self.last_sep])

    def record(self, data, every: int):
        self._launch(self.k.striker_record, [int(every), data.step, self.V, self.force, self.v_rec, self.f_rec])

    def summary(self, dt: float) -> dict:
        """Per column: the striker's velocity [m s-1] and contact force [N] at the output times (n_out, B
        -> (B, n_out)), its mass [kg], the time it first separated [s] (NaN: it never did), the start of
        its last free flight [s] (NaN: touching at the end), the contacts after the first separation, and
        the largest |c| [m] left by the position stage."""
        sep = self.sep_step.numpy().astype(np.int64)
        contacts = self.contacts.numpy().astype(np.int64)
        last = np.where(contacts % 2 == 1, self.last_sep.numpy().astype(np.int64), -1)  # odd: apart at the end
        return {"velocity": self.v_rec.numpy().astype(np.float64).T,
                "force": self.f_rec.numpy().astype(np.float64).T,
                "mass": self.mass_host.copy(),
                "separation_time": np.where(sep >= 0, sep * float(dt), np.nan),
                "last_separation_time": np.where(last >= 0, last * float(dt), np.nan),
                "recontacts": contacts // 2,
                "contact_residual": self.residual.numpy().astype(np.float64)}
