"""Names and shapes shared by every layer: enums for the states and choices that were bare ints or
strings, and the shapes and SI units of the device arrays, stated once.

Nothing here imports Warp (specs validate without it).

Device arrays (:class:`~warp_tensegrity.model.Model`, :class:`~warp_tensegrity.model.Data`)
-------------------------------------------------------------------------------------------
``B`` = columns in the batch, ``Bp`` = B or 1 (a per-column parameter shared by all columns),
``n`` = nodes, ``nc`` = rigid members (constraints), ``ne`` = cables, ``bw`` = half-bandwidth of
the constraint Gram matrix G M^-1 G^T, ``np`` = prisms. Batched arrays put the column index last
(fastest), so neighbouring threads read neighbouring columns; the fused step's scratch puts it
first (one thread block per column). Per-column parameters are read as ``param[k, b % Bp]``.

=============  ===============  ========  ============================================
array          shape            unit      meaning
=============  ===============  ========  ============================================
con_dref       (nc,) vec3       m         reference bar vector X_j - X_i
con_L          (nc,)            m         bar length
con_active     (nc, Bp)         1         1 if the rigid member exists in the column
cab_dref       (ne,) vec3       m         reference cable vector
cab_EA         (ne, Bp)         N         tension stiffness EA (EAc: compression)
cab_L          (ne, Bp)         m         rest length
m_self         (n, Bp)          kg        mass matrix entry of the node (m_cross: partner)
minv_self      (n, Bp)          kg-1      inverse-mass entry, 0 at fixed nodes
h0             (np,)            m         reference prism heights
u, v, a        (n, B) vec3      m, m s-1, m s-2  displacement from the reference, velocity, acceleration
band           (nc, bw+1, B)    --        banded Cholesky factor of G M^-1 G^T
lam            (nc, B)          --        multipliers / right-hand sides
status         (B,) int32       --        :class:`Status`
fail_step      (B,) int32       --        step at which the column froze, -1 if none
bar_err        (B,)             1         max relative bar-length error after projection
fused.nodes    (B, 4 n) vec3    --        node rows, slot :class:`Slot` s of node i at 4 i + s
fused.accel    (B, n) vec3      m s-2     accelerations, one global row per column (not in shared memory)
=============  ===============  ========  ============================================
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import Enum, IntEnum, StrEnum
from typing import Any


class Status(IntEnum):
    """Per-column status (``BatchResult.status``, the datasets' ``status`` flag)."""

    OK = 0
    NONFINITE = 1
    """Non-finite state: the column was frozen."""
    CONSTRAINT = 2
    """A bar's relative length error exceeded ``failure_bar_error``: the column was frozen."""

    @property
    def meaning(self) -> str:
        return STATUS_MEANINGS[self]


STATUS_MEANINGS = {Status.OK: "ok", Status.NONFINITE: "non-finite state", Status.CONSTRAINT: "bar constraint failed"}
"""What each :class:`Status` means, the one table of them (``STATUS_MEANINGS[1]`` works too: the keys
are IntEnum members); the datasets' ``status`` flag_meanings are these words."""


TIME = "t"
"""Name of the simulated-time axis of every dataset [s since impact]. Not "time": CF reads a
coordinate named time as calendar time, which needs "seconds since <date>" (io.py)."""


MEASUREMENT_FLAGS = (
    "ok",
    "non_finite",
    "constraint_failure",
    "no_leading_pulse",
    "pulse_not_reached_window_by_t_end",
    "record_too_short_for_width",
    "speed_undefined",
    "measurement_undefined",
    "leading_pulse_captured",
)
"""Values 0.. of the datasets' ``measurement_flag`` (CF flag_values/flag_meanings): why a
column's pulse measures are NaN (:mod:`warp_tensegrity.measure.nan_reasons` tells each case)."""

BETA_LIMIT_FLAGS = ("regular", "slow_convergence_possible", "rigid_bases")
"""Values 0, 1, 2 of the datasets' ``beta_limit_flag`` (:mod:`warp_tensegrity.scene.base_modes`):
how the limit base_rigidity -> 1 converges for a case."""


class Method(StrEnum):
    """Time integrators (see :mod:`warp_tensegrity.integrate`)."""

    RATTLE = "rattle"
    RK4 = "rk4"
    YOSHIDA4 = "yoshida4"
    SYMPLECTIC_EULER = "symplectic_euler"


STABILITY = {Method.RATTLE: 2.0, Method.RK4: 2.0 * math.sqrt(2.0), Method.YOSHIDA4: 1.5734,
             Method.SYMPLECTIC_EULER: 2.0}
"""Stability limit of omega*dt of each method on an undamped oscillator."""
FORCE_EVALS = {Method.RATTLE: 1, Method.RK4: 4, Method.YOSHIDA4: 3, Method.SYMPLECTIC_EULER: 1}
"""Force evaluations (``gather_accel`` launches) per step."""


class Precision(StrEnum):
    FP32 = "fp32"
    FP64 = "fp64"


class Path(StrEnum):
    """How a step is launched: one kernel per stage, or the fused RATTLE step (a block per column)."""

    STAGED = "staged"
    FUSED = "fused"
    """Fused, constraint solve by block cyclic reduction across the block's lanes."""
    FUSED_SERIAL = "fused-serial"
    """Fused, constraint solve by a serial banded Cholesky on lane 0."""
    LANES = "lanes"
    """Fused, one warp per column: state in registers, the bar chains solved by cyclic reduction
    over warp shuffles, no shared memory and no barriers (rigid bases: ring links folded into
    3 x 3 bar blocks first)."""


class Base(float, Enum):
    """Base rigidity beta at the two ends of its range (it is continuous in between)."""

    FLEXIBLE = 0.0
    """FB: base members are tension-only cables."""
    RIGID = 1.0
    """RB: base members are rigid links (constraints)."""


class Slot(IntEnum):
    """Slots of a node's row in the fused step's scratch (``integrate.FusedStep``: rows (n, NQ) per column;
    the accelerations have a row of their own, ``fused.accel``)."""

    U = 0
    """displacement [m]"""
    V = 1
    """velocity [m s-1]"""
    P = 2
    """displacement at the start of the step [m]"""
    I = 3  # noqa: E741
    """G^T lambda (impulse or force of the multipliers)"""


class RKStage(IntEnum):
    """The ``first`` argument of the ``rk_stage`` kernel: which RK4 stage it finishes."""

    MIDDLE = 0
    """stages 2 and 3: accumulate, write the next stage's input"""
    FIRST = 1
    """stage 1: start the accumulators"""
    LAST = 2
    """stage 4: write the new state"""


class ShardState(StrEnum):
    """State of one shard file of a sweep."""

    DONE = "done"
    MISSING = "missing"
    STALE = "stale"
    """written by another spec, code version or case range"""
    CORRUPT = "corrupt"
    """does not open"""


@dataclass(frozen=True)
class Layout:
    """What :mod:`warp_tensegrity.io` reads of a sweep to lay out and annotate its datasets, made by
    :meth:`warp_tensegrity.sweep.SweepSpec.layout`. io takes this value, not the spec, so it imports
    no sweep module (the sweeps import the engine, whose results io writes)."""

    kind: str
    """'grid' (one dimension per swept parameter) or 'cases' (a ``case`` dimension)."""
    swept: tuple[str, ...]
    """Swept per-column parameters: the grid axes in spec order, or those the cases set."""
    grid: dict = field(default_factory=dict)
    """Grid axes in spec order: name -> 1-D float64 values ({} for cases)."""
    scalars: dict = field(default_factory=dict)
    """Every per-column parameter that is not swept -> its value (a scalar coordinate)."""
    labels: tuple | None = None
    """Case labels (cases only), or None."""
    n_columns: int = 0
    scene: Any = None
    """The fixed scene (a :class:`~warp_tensegrity.scene.columns.ColumnConfig`)."""
    run: dict = field(default_factory=dict)
    """Every [run] key, defaults filled in."""
    title: str | None = None
    description: str | None = None
    source: str | None = None
    """Where the spec was read from, or None."""
    text: str = ""
    """The spec's full text."""
    text_sha256: str = ""

    @property
    def shape(self) -> tuple[int, ...]:
        """The grid's shape, or (n_columns,) for cases."""
        return tuple(len(v) for v in self.grid.values()) if self.kind == "grid" else (self.n_columns,)
