"""The block Step ("fused" path): RATTLE as one kernel (:mod:`.kernels`), a thread block per column,
several steps per launch; the constraint solve by block cyclic reduction (``fused``) or serially on
lane 0 (``fused-serial``)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import warp as wp

from ... import types
from ...types import Method, Path
from ..common import NQ
from ..step import Step, register
from .coop import band_reals, solver_reals
from .kernels import make_fused_kernels, shared_plan

FUSED_BLOCK_DIM = 32  # CUDA threads per column block in the fused step (one warp)
FUSED_STEPS = 16  # most RATTLE steps per fused launch
FUSED_SHARED_ON_CPU = False  # CPU blocks run alone: the global rows are as fast there (tests may switch it on)


@register
@dataclass
class FusedStep(Step):
    """Scratch (:data:`warp_tensegrity.types.SCRATCH_FIELDS`) and launches of the fused step for one
    model on one device: :meth:`launch` (n_sub steps), :meth:`initialize`. Its launches end on output
    steps (``records_inside`` False), and the Integrator's record kernels run after them."""

    path = Path.FUSED

    model: object  # warp_tensegrity.sim.model.Model
    device: object  # wp.context.Device
    block_dim: int  # lanes per column block (1 on the CPU unless lanes are emulated)
    steps_per_launch: int  # most RATTLE steps per launch
    shared: bool = True  # solver / node rows in block shared memory where they fit
    solver: str = "cr"  # constraint solver: "cr" (lanes in parallel) or "serial" (lane 0)

    def __post_init__(self):
        m, sv = self.model, self.solver
        real = self.real = wp.float64 if m.precision == "fp64" else wp.float32
        rb = 8 if real == wp.float64 else 4
        self.x_cap, self.q_cap = (shared_plan(m.n_nodes, m.n_constraints, m.bandwidth, self.block_dim, rb, solver=sv)
                                  if self.shared else (0, 0))
        nbr = band_reals(m.n_constraints, m.bandwidth, sv)
        k = self.kernels = make_fused_kernels(real, m.bandwidth, self.x_cap, self.q_cap, sv,
                                              max(m.n_constraints, 1) if nbr else 0)
        B, d = m.n_columns, m.device
        nx = solver_reals(m.n_constraints, m.bandwidth, self.block_dim, sv) - nbr
        self.sx = wp.zeros((1, 1, 1) if self.x_cap else (B, nx, 1), dtype=real, device=d)
        self.sb = wp.zeros((B, max(m.n_constraints, 1), m.bandwidth + 1, 1) if nbr and not self.x_cap else (1, 1, 1, 1),
                           dtype=real, device=d)
        self.sq = wp.zeros((1, 1, 1) if self.q_cap else (B, m.n_nodes, NQ), dtype=k.vec, device=d)
        self.sa = wp.zeros((B, m.n_nodes), dtype=k.vec, device=d)
        self.cm = k.ColumnModel()
        self._column_major = []  # the copies the struct's views point into (kept alive here)
        for f in types.group_fields("fused"):
            a = getattr(m, f.name)
            setattr(self.cm, f.name, self._column_view(a) if a.ndim == 2 and a.shape[1] > 1 else a)

    def _column_view(self, a):
        """The (n, B) parameter ``a`` as an (n, B) view of a (B, n) copy: a block's lanes read a column's
        values from adjacent addresses (coalesced), where the model's layout puts them B apart."""
        t = wp.array(np.ascontiguousarray(np.swapaxes(a.numpy(), 0, 1)), dtype=a.dtype, device=a.device)  # vec3 too
        self._column_major.append(t)
        return t.transpose()

    @property
    def description(self) -> str:
        where = ("shared" if self.x_cap else "global") + "/" + ("shared" if self.q_cap else "global")
        how = "block cyclic reduction" if self.solver == "cr" else "serial banded Cholesky on lane 0"
        name = "fused" if self.solver == "cr" else "fused-serial"
        return f"{name} ({how}, {self.block_dim} lanes per column; solver/node rows {where})"

    @classmethod
    def refusal(cls, settings, batch, device) -> str | None:
        if settings.method != Method.RATTLE:
            return f"the fused path needs method = 'rattle' (got method = {settings.method!r})"
        return super().refusal(settings, batch, device)

    @classmethod
    def create(cls, integ, batch) -> FusedStep:
        lanes = integ.device.is_cuda or wp.config.enable_cpu_blocks  # the CPU emulates lanes only on request
        return cls(integ.model, integ.device, FUSED_BLOCK_DIM if lanes else 1, FUSED_STEPS,
                   integ.device.is_cuda or FUSED_SHARED_ON_CPU, cls.solver)

    def load(self):
        self.kernels.rattle_columns.module.load(self.device, self.block_dim)

    def initialize(self, data, settings, dt: float):
        self.launch(data, settings, dt, 0, init=1)

    def launch(self, data, settings, dt: float, n_sub: int, init: int = 0):
        r, d = self.real, data
        wp.launch_tiled(self.kernels.rattle_columns, dim=[self.model.n_columns], block_dim=self.block_dim,
                        device=self.device, inputs=[
                            self.cm, r(settings.tolerance), int(settings.max_projection_iters),
                            r(settings.failure_bar_error), r(dt), int(n_sub), int(init), d.step,
                            d.u, d.v, d.a, d.bar_err, d.iters, d.status, d.fail_step,
                            self.sq, self.sx, self.sb, self.sa])


@register
@dataclass
class FusedSerialStep(FusedStep):
    """The fused step with the constraint solve serially on lane 0 (the staged threads' banded Cholesky)."""

    path = Path.FUSED_SERIAL
    solver: str = "serial"
