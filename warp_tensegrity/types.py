"""Names and shapes shared by every layer: enums for the states and choices that were bare ints or
strings, and the shapes and SI units of the device arrays, stated once.

Nothing here imports Warp (specs validate without it).

Device arrays
-------------
Every device array is declared once, as a :class:`Field` of :data:`MODEL_FIELDS`,
:data:`DATA_FIELDS` or :data:`SCRATCH_FIELDS` below: :class:`~warp_tensegrity.sim.model.Model` and
:class:`~warp_tensegrity.sim.model.Data`, the fused step's struct and the launch argument groups
(:data:`ARGUMENT_GROUPS`) are made from them, and so is this table.

``B`` = columns in the batch, ``Bp`` = B or 1 (a per-column parameter shared by all columns),
``n`` = nodes, ``nc`` = rigid members (constraints), ``ne`` = cables, ``bw`` = half-bandwidth of
the constraint Gram matrix G M^-1 G^T, ``np`` = prisms, ``nb`` = blocks of M, ``ncp`` = coupling
terms of the Gram matrix, ``nx`` = a column's solver reals, ``nr`` = feasibility reasons
(:data:`FEASIBILITY_FLAGS`), ``nxp`` = member pairs checked for crossing; with bar contact ``npr`` =
bar pairs, ``R`` = nc + npr rows of the contact system, ``cbw`` its Gram half-bandwidth, ``ncq`` its
coupling terms, ``nin`` its node incidences. Batched arrays put the column index last (fastest), so
neighbouring threads read neighbouring columns; the fused step's scratch puts it first (one thread
block per column). Per-column parameters are read as ``param[k, b % Bp]``.
``real`` is fp32 or fp64 (the run's precision), ``vec3`` three reals.

{field_table}
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import Enum, IntEnum, StrEnum
from typing import Any, NamedTuple


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
    "left_feasible_set",
    "measure_unstable",
)
"""Values 0.. of the datasets' ``measurement_flag`` (CF flag_values/flag_meanings): why a
column's pulse measures are NaN (:mod:`warp_tensegrity.measure.nan_reasons` tells each case)."""

ERROR_ESTIMATED = ("amplitude", "speed", "width", "width_10", "arrival_time")
"""The pulse measures that carry an error estimate ``<measure>_error`` (same units and dims) in a
sweep's dataset (:mod:`warp_tensegrity.measure.errors`)."""
ERROR_FLAGS = ("ok", "no_twin", "twin_undefined", "over_target")
"""Values 0.. of the datasets' ``error_flag`` (:mod:`warp_tensegrity.measure.errors`): whether each
measure's error estimate can be trusted: ok; no_twin (no coarser dt on the same outputs: no
estimate); twin_undefined (a measure is defined but its twin's is not: the estimate cannot say);
over_target (an estimate exceeds the run's accuracy target)."""

FEASIBILITY_FLAGS = ("bars_crossed", "strings_touched", "prism_inverted")
"""Bit i (value 2**i) of the datasets' ``feasibility_flag`` (CF flag_masks/flag_meanings): how a
column left the feasible set of the paper's Sec. 3 (:mod:`warp_tensegrity.measure.feasibility`):
a prism's twist reached pi (its bars touch), or the paper's lower bound pi/3 ("strings touching";
docs/model.md), or its height reached 0 (the bases passed through each other); in a network that is not a column, two bar
(cable) axes passed through each other. Several bits may be set."""


BETA_LIMIT_FLAGS = ("regular", "slow_convergence_possible", "rigid_bases")
"""Values 0, 1, 2 of the datasets' ``beta_limit_flag`` (:mod:`warp_tensegrity.scene.base_modes`):
how the limit base_rigidity -> 1 converges for a case."""


class Method(StrEnum):
    """Time integrators (see :mod:`warp_tensegrity.sim.integrate`)."""

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
    AUTO = "auto"
    """fp32 verified case by case where a sweep's twin can verify it and fp32 is worth it (a GPU),
    with fp64 reruns of the cases it does not verify; fp64 elsewhere (:mod:`warp_tensegrity.policy.groups`)."""


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
    """Slots of a node's row in the fused step's scratch (``sim.block.step.FusedStep.sq``: rows (n, NQ)
    per column; the accelerations have a row of their own, ``sa``)."""

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
    """State of one shard of a sweep (its block of columns in the run's store)."""

    DONE = "done"
    MISSING = "missing"
    STALE = "stale"
    """written by another spec, code version or case range"""
    CORRUPT = "corrupt"
    """does not open"""


# ---------------------------------------------------------------------------- device arrays
class Field(NamedTuple):
    """One device array, declared once (the module docstring's table lists them all)."""

    name: str
    dtype: str
    """"int32", "real" (the run's precision) or "vec3" (3 reals)."""
    shape: str
    """e.g. "(nc, Bp)"; one entry per dimension."""
    unit: str
    """SI; "1" dimensionless, "--" for indices and codes."""
    doc: str
    groups: tuple[str, ...] = ()
    """The :data:`ARGUMENT_GROUPS` that take it."""
    optional: bool = False
    """None when the batch has no prism levels (the pair fields: when it has)."""
    source: str | None = None
    """The :class:`~warp_tensegrity.scene.batch.NetworkBatch` attribute holding its host values, as
    the batch holds them ((Bp, k) for a per-column parameter); None: computed by
    :func:`warp_tensegrity.sim.model.host_arrays`. With a source, declaring a field is its only edit."""

    @property
    def ndim(self) -> int:
        return len([d for d in self.shape.strip("()").split(",") if d.strip()])

    @property
    def per_column(self) -> bool:
        """A per-column parameter (k, Bp): host rows (Bp, k) are transposed onto the device."""
        return self.shape.endswith(", Bp)")


ARGUMENT_GROUPS = {
    "fused": "the fused step's struct ``ColumnModel`` (:mod:`warp_tensegrity.sim.block.kernels`)",
    "positions": "``project_positions``",
    "gram": "the staged solver's struct ``GramModel`` of the Gram matrix's arrays "
            "(:mod:`warp_tensegrity.sim.staged.solver`): ``factor_only``'s one, ``factor_project``'s first",
    "velocities": "``factor_project`` after ``GramModel`` (velocities and the index-1 accelerations)",
    "gather": "``gather_accel``",
    "energy": "``record_energy``",
    "strain": "``record_strain``",
    "feasibility": "``record_feasibility``",
    "pairs": "``record_pairs``",
}
"""Model arguments of each launch: the :data:`MODEL_FIELDS` naming the group, in their order (a
hand-written kernel lists them first, under ``# Model:``; a struct group is one argument of its name)."""

_BAR = ("fused", "positions", "gram")
_CPL = ("fused", "gram")
_NCON = ("fused", "positions", "velocities")
_CAB = ("fused", "gather", "energy")
_NODE = ("fused", "gather")
_MINV = ("fused", "gather", "positions", "gram")

MODEL_FIELDS = (
    Field("con_i", "int32", "(nc,)", "--", "first node of the rigid member", _BAR),
    Field("con_j", "int32", "(nc,)", "--", "second node of the rigid member", _BAR),
    Field("con_dref", "vec3", "(nc,)", "m", "reference bar vector X_j - X_i", _BAR),
    Field("con_L", "real", "(nc,)", "m", "bar length (of the rounded con_dref)", ("fused", "positions")),
    Field("con_active", "real", "(nc, Bp)", "1", "1 if the rigid member exists in the column", _BAR,
          source="constraint_active"),
    Field("cpl_start", "int32", "(nc+1,)", "--", "CSR row starts of the Gram matrix's coupling terms", _CPL),
    Field("cpl_l", "int32", "(ncp,)", "--", "coupling term's column l <= k of row k", _CPL),
    Field("cpl_a", "int32", "(ncp,)", "--", "coupling term's node a of row k", _CPL),
    Field("cpl_cross", "int32", "(ncp,)", "--", "1 if the term takes the partner entry of M^-1 (minv_cross)", _CPL),
    Field("cpl_sign", "real", "(ncp,)", "1", "coupling term's sign, +-1", _CPL),
    Field("ncon_start", "int32", "(n+1,)", "--", "CSR node -> rigid members", _NCON),
    Field("ncon_member", "int32", "(2 nc,)", "--", "rigid members of the node", _NCON),
    Field("cab_i", "int32", "(ne,)", "--", "first node of the cable", ("energy",)),
    Field("cab_j", "int32", "(ne,)", "--", "second node of the cable", ("energy",)),
    Field("cab_dref", "vec3", "(ne,)", "m", "reference cable vector", ("energy",)),
    Field("cab_EA", "real", "(ne, Bp)", "N", "tension stiffness EA", _CAB, source="cable_EA"),
    Field("cab_EAc", "real", "(ne, Bp)", "N", "compression stiffness EA_c", _CAB, source="cable_EA_compression"),
    Field("cab_L", "real", "(ne, Bp)", "m", "rest length", _CAB, source="cable_rest_length"),
    Field("node_start", "int32", "(n+1,)", "--", "CSR node -> cables", _NODE),
    Field("node_member", "int32", "(2 ne,)", "--", "cables of the node", _NODE),
    Field("node_other", "int32", "(2 ne,)", "--", "other end of node_member's cable", _NODE),
    Field("node_dref", "vec3", "(2 ne,)", "m", "reference vector from the node to node_other", _NODE),
    Field("partner", "int32", "(n,)", "--", "other end of the node's massive bar if both are free, else -1",
          ("fused", "positions", "velocities", "energy")),
    Field("mass_blocks", "int32", "(nb, 2)", "--", "blocks of M: massive bar i < j, or lone node and -1", ("gather",)),
    Field("m_self", "real", "(n, Bp)", "kg", "mass matrix entry of the node", ("energy",)),
    Field("m_cross", "real", "(n, Bp)", "kg", "mass matrix entry of the node and its partner", ("energy",)),
    Field("minv_self", "real", "(n, Bp)", "kg-1", "inverse-mass entry, 0 at fixed nodes", _MINV),
    Field("minv_cross", "real", "(n, Bp)", "kg-1", "inverse-mass entry of the node and its partner", _MINV),
    Field("ext_force", "vec3", "(n, Bp)", "N", "dead load on the node (the end preload; 0 without)", ("fused", "gather", "energy")),
    Field("level_nodes", "int32", "(np+1, 3)", "--", "nodes of each column base", ("strain", "feasibility"),
          optional=True),
    Field("h0", "real", "(np,)", "m", "reference prism heights", ("strain", "feasibility"), optional=True),
    Field("static_dz", "real", "(np, Bp)", "m", "prism height change in the initial equilibrium (preload; 0 without)",
          ("strain",), optional=True),
    Field("level_ref", "vec3", "(np+1, 3)", "m", "reference position of each base node from its base's centroid",
          ("feasibility",), optional=True),
    Field("prism_hand", "real", "(np,)", "1", "+1 right-handed prism, -1 left-handed", ("feasibility",), optional=True),
    Field("pair_nodes", "int32", "(nxp, 4)", "--", "end nodes i0, i1, j0, j1 of the two members of a checked pair "
          "(networks that are not columns; None for columns)", ("pairs",), optional=True),
    Field("pair_dref", "vec3", "(nxp, 3)", "m", "reference vectors X_i1 - X_i0, X_j1 - X_j0, X_j0 - X_i0 of the pair",
          ("pairs",), optional=True),
    Field("pair_kind", "int32", "(nxp,)", "--", "0: two bars, 1: two cables (read on the host)", optional=True),
)
"""Topology and per-column parameters (:class:`~warp_tensegrity.sim.model.Model`)."""

DATA_FIELDS = (
    Field("u", "vec3", "(n, B)", "m", "displacement from the reference"),
    Field("v", "vec3", "(n, B)", "m s-1", "velocity"),
    Field("a", "vec3", "(n, B)", "m s-2", "acceleration"),
    Field("u_prev", "vec3", "(n, B)", "m", "displacement at the start of the step (staged)"),
    Field("imp", "vec3", "(n, B)", "--", "scratch: G^T lambda per node (staged)"),
    Field("band", "real", "(nc, bw+1, B)", "--", "banded Cholesky factor of G M^-1 G^T (staged)"),
    Field("lam", "real", "(nc, B)", "--", "multipliers / right-hand sides (staged)"),
    Field("status", "int32", "(B,)", "--", ":class:`Status`"),
    Field("fail_step", "int32", "(B,)", "--", "step at which the column froze, -1 if none"),
    Field("iters", "int32", "(B,)", "--", "largest projection iteration count seen"),
    Field("bar_err", "real", "(B,)", "1", "max relative bar-length error after projection"),
    Field("step", "int32", "(1,)", "--", "completed steps"),
    # the feasibility record (sim.staged.kernels.record_feasibility, at output steps; (1, 1) placeholders
    # where the batch has no prisms, or no pairs)
    Field("twist", "real", "(np, B)", "rad", "prism twist at the last output, unwrapped"),
    Field("twist_max", "real", "(np, B)", "rad", "largest prism twist over the outputs"),
    Field("twist_min", "real", "(np, B)", "rad", "smallest prism twist over the outputs"),
    Field("height_min", "real", "(np, B)", "1", "smallest prism height ratio h/h0 over the outputs"),
    Field("left_slot", "int32", "(nr, np, B)", "--", "first output slot of each FEASIBILITY_FLAGS reason, -1 never"),
    Field("pair_distance_min", "real", "(nxp, B)", "m", "smallest distance between the pair's member axes"),
    Field("cross_side", "int32", "(nxp, B)", "--", "side of the pair's oriented axis distance, 0 when not facing"),
    Field("pair_left_slot", "int32", "(nxp, B)", "--", "first output slot at which the pair crossed, -1 never"),
)
"""Mutable state (:class:`~warp_tensegrity.sim.model.Data`; staged-only arrays are size-1 placeholders
on the fused paths)."""

SCRATCH_FIELDS = (
    Field("sq", "vec3", "(B, n, NQ)", "--", "node rows, slot :class:`Slot` s of node i at [i, s]"),
    Field("sa", "vec3", "(B, n)", "m s-2", "accelerations, one global row per column (not in shared memory)"),
    Field("sx", "real", "(B, nx, 1)", "--", "solver rows: CR storage or the serial right-hand side; lane reduction"),
    Field("sb", "real", "(B, nc, bw+1, 1)", "--", "the serial solver's band"),
)
"""The fused step's own rows (``sim.block.step.FusedStep``; size-1 where they live in shared memory)."""


CONTACT_FIELDS = (
    Field("pair_bi", "int32", "(npr,)", "--", "rigid member of the bar pair's first bar"),
    Field("pair_bj", "int32", "(npr,)", "--", "rigid member of the bar pair's second bar"),
    Field("pair_wref", "vec3", "(npr,)", "m", "reference vector from the first bar's first node to the second's"),
    Field("pair_sign", "real", "(npr,)", "1", "sign that makes the pair's axis distance positive at the reference"),
    Field("pair_row", "int32", "(npr,)", "--", "the pair's row in the contact system"),
    Field("row_kind", "int32", "(R,)", "--", "row of the contact system: 0 rigid member, 1 bar pair"),
    Field("row_index", "int32", "(R,)", "--", "the row's rigid member or bar pair"),
    Field("acpl_start", "int32", "(R+1,)", "--", "CSR row starts of the contact Gram matrix's coupling terms"),
    Field("acpl_l", "int32", "(ncq,)", "--", "coupling term's column l <= k"),
    Field("acpl_sk", "int32", "(ncq,)", "--", "coupling term's slot of row k"),
    Field("acpl_sl", "int32", "(ncq,)", "--", "coupling term's slot of row l"),
    Field("acpl_a", "int32", "(ncq,)", "--", "coupling term's node a of row k"),
    Field("acpl_cross", "int32", "(ncq,)", "--", "1 if the term takes the partner entry of M^-1"),
    Field("anode_start", "int32", "(n+1,)", "--", "CSR node -> (row, slot) of the contact system"),
    Field("anode_row", "int32", "(nin,)", "--", "row of the node's incidence"),
    Field("anode_slot", "int32", "(nin,)", "--", "slot of the node's incidence"),
)
"""The contact system's topology (scene contact = 'bars', :mod:`warp_tensegrity.sim.staged.contact`):
rows of rigid members and bar pairs, each pair right after its later bar; a row's slots are its nodes
(a member's i, j; a pair's P_i, Q_i, P_j, Q_j)."""

CONTACT_STATE_FIELDS = (
    Field("cband", "real", "(R, cbw+1, B)", "--", "banded Cholesky factor of the contact system's Gram matrix"),
    Field("clam", "real", "(R, B)", "--", "multipliers / right-hand sides of the contact system"),
    Field("cu0", "vec3", "(n, B)", "m", "positions at the start of a substep"),
    Field("vsub", "vec3", "(n, B)", "m s-1", "velocities at the start of a landing substep (its retry point)"),
    Field("asub", "vec3", "(n, B)", "m s-2", "accelerations at the start of a landing substep"),
    Field("vstart", "vec3", "(n, B)", "m s-1", "velocities at the start of the step"),
    Field("cv0", "vec3", "(n, B)", "--", "velocities before an impact, positions before a projection (restart points)"),
    Field("cimp", "vec3", "(n, B)", "--", "scratch: J^T lambda per node (massive bars)"),
    Field("pair_side", "real", "(npr, B)", "1", "the pair's side (+-1): the sign of its axis distance (pair_sign at the start; "
          "it changes where the axes pass through parallel, never through contact)"),
    Field("pair_m", "vec3", "(npr, B)", "1", "unit normal dD/dc_j of the pair at the linearisation point"),
    Field("pair_s", "real", "(npr, B)", "1", "closest point's parameter on the first bar"),
    Field("pair_t", "real", "(npr, B)", "1", "closest point's parameter on the second bar"),
    Field("pair_act", "int32", "(npr, B)", "--", "1 while the pair is a row of the current solve (2: its impact done, -1: left out)"),
    Field("pair_acc", "real", "(npr, B)", "--", "the pair's multiplier summed over the position solve (> 0: adhesive)"),
    Field("pair_vn", "real", "(npr, B)", "m s-1", "normal relative velocity of the pair before its impact"),
    Field("pair_state", "int32", "(npr, B)", "--", "1 if the pair touched after the last position stage, else 0"),
    Field("contact_min", "real", "(B,)", "m", "smallest signed axis distance of any pair over the run"),
    Field("contact_impacts", "int32", "(B,)", "--", "bar impacts so far"),
    Field("contact_first", "int32", "(B,)", "--", "step of the first contact, -1 if none"),
    Field("contact_substeps", "int32", "(B,)", "--", "RATTLE substeps the column's contact steps took"),
)
"""State of the contact projection (:class:`warp_tensegrity.sim.staged.contact.ContactStep`)."""


def group_fields(group: str, fields: tuple[Field, ...] | None = None) -> tuple[Field, ...]:
    """The fields (default :data:`MODEL_FIELDS`) in argument group ``group``, in their order."""
    return tuple(f for f in (MODEL_FIELDS if fields is None else fields) if group in f.groups)


def field_table() -> str:
    """The declared arrays as a reStructuredText table (the module docstring's)."""
    rows = [(f"{owner}.{f.name}", f"{f.shape} {f.dtype}", f.unit, f.doc + (" (optional)" if f.optional else ""))
            for owner, fields in (("Model", MODEL_FIELDS), ("Data", DATA_FIELDS), ("FusedStep", SCRATCH_FIELDS),
                                  ("ContactStep", CONTACT_FIELDS + CONTACT_STATE_FIELDS))
            for f in fields]
    head = ("array", "shape dtype", "unit", "meaning")
    widths = [max(len(r[i]) for r in rows + [head]) for i in range(4)]
    rule = "  ".join("=" * w for w in widths)
    line = lambda r: "  ".join(c.ljust(w) for c, w in zip(r, widths)).rstrip()  # noqa: E731
    return "\n".join([rule, line(head), rule, *map(line, rows), rule])


__doc__ = __doc__.replace("{field_table}", field_table())
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
