"""Warp kernels of the integrator step.

* :mod:`.common`: the ``@wp.func`` bodies both paths share (cable law, per-column reads, Gram
  rows, impulses, status codes, the serial banded Cholesky), each written once;
* :mod:`.staged`: one kernel per stage (per-node kernels and one thread per column for the
  constraint solves, the latter in :mod:`.staged_solver`); every method;
* :mod:`.fused`: RATTLE as one kernel, a thread block per column, several steps per launch,
  the constraint solve by block cyclic reduction across the block's lanes or (``solver="serial"``)
  by lane 0 with the staged threads' banded Cholesky (:func:`.common.make_band_funcs`);
* :mod:`.coop`: the fused step's in-block pieces: barrier, shared buffers, lane reduction, the
  block cyclic reduction and the size of a column's solver rows;
* :mod:`.lanes`: RATTLE with one warp per column (state in registers, no shared memory, no
  barriers), its host launcher and which batches it takes; its pieces in :mod:`.lane_funcs` (the
  bar chains: in-lane Thomas and cyclic reduction over shuffles), :mod:`.lane_rigid` (rigid bases:
  the ring links folded into 3 x 3 bar blocks) and :mod:`.lane_ops` (shuffles, segment max, vote,
  with their CPU emulation).
"""

from .common import STATUS_CONSTRAINT, STATUS_NONFINITE, STATUS_OK
from .coop import solver_reals
from .fused import make_fused_kernels, shared_plan
from .staged import make_kernels
from .staged_solver import make_solver_kernels

__all__ = [
    "STATUS_CONSTRAINT", "STATUS_NONFINITE", "STATUS_OK", "make_fused_kernels",
    "shared_plan", "solver_reals", "make_kernels", "make_solver_kernels",
]
