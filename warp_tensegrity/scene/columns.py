"""Scene builder: columns of regular minimal T3 prisms (paper Sec. 3 and 4).

Layout (paper Fig. 2, 1-based labels in the paper, 0-based here):
level ``l = 0..n_prisms`` holds nodes ``3l, 3l+1, 3l+2`` on a circle of radius ``a`` at
height ``z = l*h0``; level 0 is clamped, level ``n_prisms`` is the free (impacted) end.
Prism ``m`` joins level ``m`` (bottom, paper nodes 1-3) to level ``m+1`` (top, nodes 4-6):

* bars ``1-4, 2-5, 3-6``: bottom ``k`` -> top ``k``;
* cross cables ``1-6, 2-4, 3-5``: bottom ``k`` -> top ``(k+2) % 3`` (right-handed) or
  ``(k+1) % 3`` (left-handed, the mirror image);
* base members ``1-2, 2-3, 3-1`` per level, shared by the two prisms that meet there.

A right-handed prism's top base is twisted clockwise (seen from +z, the free end) by the
twist angle (5*pi/6, the prestressable configuration) with respect to its bottom base;
nodes are numbered clockwise too, so the labels above match the paper's.

Base rigidity ``beta`` in [0, 1] sets the base members (see :func:`base_member_law`):
``beta = 0`` flexible bases (FB, tension-only cables as the other cables), ``beta = 1``
rigid bases (RB, rigid links that also work in tension), and in between elastic members
that stiffen continuously toward RB.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from functools import lru_cache
from typing import Annotated, Sequence

import numpy as np

from ..options import MASS, Opt, check_column_param, fmt, options_class
from . import sparse
from .contact import CONTACT_MODELS, regular_gap
from .impact import least_energy_impact
from .striker import IMPACTS
from .network import Network, NetworkError

PAPER_CABLE_MODULUS = 5.48e6  # N m-2
PAPER_CABLE_RADIUS = 0.14e-3  # m
PAPER_RADIUS = 5.0e-3  # m
PAPER_HEIGHT = 6.2e-3  # m
PAPER_UNIT_MASS = 0.0249  # kg
PAPER_N_PRISMS = 50
MINIMAL_TWIST = 5.0 * np.pi / 6.0  # rad

END_BASE_MASS = ("full", "half")
IMPACT_ADMISSIBILITY = ("rigid_members", "end_twist", "project")
PAPER_IMPACT = "end_twist"  # the convention of the paper reproduction (analysis/paper_2017.md)

# Physical ranges of the scene (SI). Wide enough for any laboratory or built tensegrity column
# (micro-fabricated to building scale), narrow enough that every derived quantity (cable_EA,
# squared lengths, omega_max) stays a normal float64: values outside them are refused, not run.
LENGTH = (1e-6, 1e3)  # m: prism radius and height
CABLE_RADIUS = (1e-9, 1.0)  # m
MODULUS = (1.0, 1e13)  # N m-2: soft gels (~1e3) .. above diamond (1.2e12)
ASPECT = (1e-2, 1e2)  # prism height / radius: flatter or more slender is no tensegrity column (and the
# rigid-member impact solve loses its accuracy beyond ~300)
MAX_PRISMS = 100_000  # a 600 m column of the paper's prisms; the paper's has 50
SELF_STRESS_EACH_MAX = 100  # prisms up to which each prism's self-stress is solved (longer: one per handedness)


# ---------------------------------------------------------------------- the scene's options
@options_class(NetworkError, frozen=True, section="scene")
class ColumnConfig:
    """The fixed scene: geometry, material, masses, boundary and impact conventions (SI units)."""

    n_prisms: Annotated[int, Opt("int", "1", ge=1, le=MAX_PRISMS,
                                 why="planning builds every prism of every column (~720 B and ~33 us each)")] = PAPER_N_PRISMS
    """Number of stacked T3 prisms."""
    handedness: Annotated[str, Opt("str", rule_text="'right', 'left', 'alternating' or one letter R/L per prism")] = "right"
    """'right', 'left', 'alternating', or one letter R/L per prism (e.g. 'RRL...')."""
    radius: Annotated[float, Opt("real", "m", ge=LENGTH[0], le=LENGTH[1])] = PAPER_RADIUS
    """Radius a of the circle through each base triangle's vertices [m]."""
    height: Annotated[float, Opt("real", "m", ge=LENGTH[0], le=LENGTH[1])] = PAPER_HEIGHT
    """Reference prism height h0 [m] (also the length unit of pulse speed); height/radius must lie
    in [1e-2, 1e2]."""
    twist: Annotated[float, Opt("real", "rad", gt=math.pi / 3, lt=math.pi, rule_text="in (pi/3, pi)",
                                why="5*pi/6 is the prestressable twist", default_text="5*pi/6")] = MINIMAL_TWIST
    """Twist angle between bottom and top base [rad]; a regular minimal prism has a self-stress only
    at 5*pi/6, so a spec with another twist is refused when it is read."""
    cable_modulus: Annotated[float, Opt("real", "N m-2", ge=MODULUS[0], le=MODULUS[1])] = PAPER_CABLE_MODULUS
    """Young modulus of the cables E_s [N m-2]."""
    cable_radius: Annotated[float, Opt("real", "m", ge=CABLE_RADIUS[0], le=CABLE_RADIUS[1])] = PAPER_CABLE_RADIUS
    """Cable cross-section radius r_s [m], <= radius (cable_EA = E_s pi r_s^2)."""
    unit_mass: Annotated[float, Opt("real", "kg", ge=MASS[0], le=MASS[1])] = PAPER_UNIT_MASS
    """Mass per unit (prism) lumped on the bases [kg]; each base's mass is split over its 3 nodes."""
    end_base_mass: Annotated[str, Opt("choice", choices=END_BASE_MASS)] = "half"
    """Mass on the end bases: 'half' (default: each unit's mass split between its two bases, so the
    end bases carry half a unit) or 'full' (every base carries a whole unit)."""
    bar_mass: Annotated[float, Opt("real", "kg", ge=0, le=MASS[1])] = 0.0
    """Mass of each bar [kg], > 0 only for a single prism; the paper's columns carry their mass on
    the bases (0)."""
    impact_admissibility: Annotated[str, Opt("choice", choices=IMPACT_ADMISSIBILITY)] = "rigid_members"
    """How the axial impact velocity is made compatible with the members (docs/impact.md):
    'rigid_members' (default) - the least-kinetic-energy velocity with v_z = -v0 on the free-end
    nodes that keeps every bar and every base member rigid at the instant of impact, whatever the
    base rigidity: the same initial state for every beta, so outputs are continuous in beta;
    the paper's conventions, which treat only the members rigid in the dynamics as rigid at
    impact (their initial velocity jumps at beta = 1; 'end_twist' is the best fit to the
    paper's Section 4, see analysis/paper_2017.md):
    'project' - the impulse view: the axial velocity -v0 on the free-end nodes is projected onto
    the constraint tangent space in the mass metric (a momentum-consistent impulsive load);
    'end_twist' - the free-end nodes keep exactly v_z = -v0 and get the smallest horizontal
    (twisting) velocity that satisfies the bars; no other node moves."""
    impact: Annotated[str, Opt("choice", choices=IMPACTS)] = "velocity"
    """'velocity' (default): the free end starts at v0 (impact_admissibility says how); 'striker': a
    rigid mass striker_mass hits the free end at v0 and stays in unilateral contact until the column
    pushes it back (a frictionless face on the end base's mean height; docs/impact.md). Needs method
    'rattle' and the 'rigid_members' blow; runs on the staged path, untruncated."""
    striker_mass: Annotated[float, Opt("real", "kg", ge=0, le=MASS[1])] = 0.0
    """Mass M of the striker [kg] (impact = 'striker', where every column's must be > 0; a sweep may vary
    it per column); 0: not given."""
    contact: Annotated[str, Opt("choice", choices=CONTACT_MODELS)] = "none"
    """Bar contact: 'none' (default, the paper's model: bars are axes and pass through each other)
    or 'bars': the bars of each prism stay at least 2 bar_radius apart (axis to axis), a unilateral
    constraint of the RATTLE projection on positions and velocities (docs/contact.md). Needs
    method 'rattle'; runs on the staged path."""
    bar_radius: Annotated[float, Opt("real", "m", ge=0, le=LENGTH[1])] = 0.0
    """Radius r of the bars' cross-section [m] (contact = 'bars'): the bar axes of a prism keep 2 r
    apart. Must be > 0 with contact, and 2 r below the axis distance of the reference prism (1.77 mm
    for the paper's); 0: not given (the paper gives none)."""
    restitution: Annotated[float, Opt("real", "1", ge=0, le=1)] = 1.0
    """Restitution coefficient e of a bar impact (contact = 'bars'): the normal relative velocity
    after an impact is -e times the one before. Default 1 (elastic): the model has rigid bars,
    elastic cables and no damping, so contact keeps it conservative and energy_error still measures
    the integration alone; e < 1 dissipates at each impact, 0 keeps touching bars together."""

    def __post_init__(self):
        h = self.handedness  # checked without building the per-prism array (n_prisms may be large)
        if h not in ("right", "left", "alternating") and not (len(h) == self.n_prisms and set(h.upper()) <= {"R", "L"}):
            raise NetworkError(f"handedness = {fmt(h)}: use 'right', 'left', 'alternating' or {self.n_prisms} letters R/L")
        if not ASPECT[0] <= self.height / self.radius <= ASPECT[1]:
            raise NetworkError(f"height = {self.height!r}, radius = {self.radius!r}: the prism aspect ratio height/radius "
                               f"= {self.height / self.radius:.3g} must lie in [{ASPECT[0]:g}, {ASPECT[1]:g}]")
        if self.cable_radius > self.radius:
            raise NetworkError(f"cable_radius = {self.cable_radius!r}: must be <= radius = {self.radius!r} m "
                               "(a cable thicker than the prism)")
        if self.contact == "bars":
            self._check_bar_radius()
        if self.impact == "striker":
            self._check_striker()
        if self.bar_mass > 0 and self.n_prisms > 1:
            # the consistent bar inertia needs class-1 networks; a column's inner nodes carry two bars
            raise NetworkError(f"bar_mass = {self.bar_mass!r}: massive bars need n_prisms = 1 (the inner nodes of a "
                               f"column carry two bars; n_prisms = {self.n_prisms}): put the mass in unit_mass")

    def _check_striker(self):  # its mass is per column (scene.batch refuses 0 there)
        for key, value, need in (("impact_admissibility", self.impact_admissibility, "rigid_members"),
                                 ("contact", self.contact, "none")):
            if value != need:
                raise NetworkError(f"{key} = {value!r}: impact = 'striker' needs {key} = {need!r}")
        if self.bar_mass > 0:
            raise NetworkError(f"bar_mass = {self.bar_mass!r}: impact = 'striker' needs massless bars (0)")

    def reference_gap(self) -> float:
        """Distance [m] between two bar axes of a prism at the reference (the scene's twist)."""
        L = math.sqrt(self.height**2 + 2.0 * self.radius**2 * (1.0 - math.cos(self.twist)))
        return regular_gap(self.radius, L, self.twist)

    def _check_bar_radius(self):
        gap = self.reference_gap()
        if not 0.0 < 2.0 * self.bar_radius < gap:
            raise NetworkError(f"bar_radius = {self.bar_radius!r}: contact = 'bars' needs 0 < bar_radius < "
                               f"{0.5 * gap:.6g} m (the bar axes of the reference prism are {gap:.6g} m apart)")

    @property
    def cable_EA(self) -> float:
        """E_s * pi * r_s^2 [N]."""
        return self.cable_modulus * np.pi * self.cable_radius**2

    def prism_handedness(self) -> np.ndarray:
        """+1 (right) or -1 (left) per prism."""
        h = self.handedness
        n = self.n_prisms
        if h == "right":
            return np.ones(n, dtype=np.int64)
        if h == "left":
            return -np.ones(n, dtype=np.int64)
        if h == "alternating":
            return np.where(np.arange(n) % 2 == 0, 1, -1).astype(np.int64)
        if isinstance(h, str) and len(h) == n and set(h.upper()) <= {"R", "L"}:
            return np.array([1 if c == "R" else -1 for c in h.upper()], dtype=np.int64)
        raise NetworkError(f"handedness = {h!r}: use 'right', 'left', 'alternating' or {n} letters R/L")



# ---------------------------------------------------------------------- topology
@dataclass
class ColumnTopology:
    """Node positions and member lists of a column, shared by every column of a batch."""

    config: ColumnConfig
    positions: np.ndarray
    """(n_nodes, 3) reference positions [m]."""
    fixed: np.ndarray
    """(n_nodes,) clamped nodes: level 0."""
    level_nodes: np.ndarray
    """(n_prisms+1, 3) node indices of each base, level 0 clamped."""
    bars: np.ndarray
    """(3 n_prisms, 2) the struts, prism by prism."""
    cross: np.ndarray
    """(3 n_prisms, 2) cross cables, prism by prism."""
    base: np.ndarray
    """(3 (n_prisms+1), 2) base members, level by level."""
    base_level: np.ndarray
    """(3 (n_prisms+1),) level of each base member."""
    unit_bar_force: np.ndarray = field(repr=False)
    """(3 n_prisms,) self-stress axial force of bars per unit cross-cable tension (negative: compression)."""
    unit_base_force: np.ndarray = field(repr=False)
    """(3 (n_prisms+1),) self-stress force of base members per unit cross-cable tension."""
    unit_base_bottom: np.ndarray | None = field(repr=False, default=None)
    """(3 n_prisms,) each prism's share of unit_base_force on its bottom base (prism m: level m)."""
    unit_base_top: np.ndarray | None = field(repr=False, default=None)
    """(3 n_prisms,) each prism's share on its top base (prism m: level m + 1)."""

    @property
    def n_nodes(self) -> int:
        return self.positions.shape[0]


def prism_self_stress(positions: np.ndarray, bars, cross, bottom, top) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Self-stress of one free prism (null vector of its equilibrium matrix), normalised so the
    cross cables carry unit tension. Returns axial forces (bars, cross, bottom base, top base),
    positive in tension."""
    members = np.concatenate([bars, cross, bottom, top])
    nodes = np.unique(members)
    index = {int(n): r for r, n in enumerate(nodes)}
    A = np.zeros((3 * len(nodes), len(members)))
    for c, (i, j) in enumerate(members):
        e = positions[j] - positions[i]
        e = e / np.linalg.norm(e)
        A[3 * index[int(i)] : 3 * index[int(i)] + 3, c] += e  # tension pulls i toward j
        A[3 * index[int(j)] : 3 * index[int(j)] + 3, c] -= e
    _, sv, vt = np.linalg.svd(A)
    t = vt[-1]
    if sv[-1] > 1e-9 * sv[0]:
        raise NetworkError(
            f"prism is not prestressable: smallest singular value {sv[-1]:.3e} of its equilibrium matrix "
            f"(twist must be 5*pi/6 for a regular minimal prism)"
        )
    t = t / t[3:6].mean()
    nb = len(bars)
    return t[:nb], t[nb : 2 * nb], t[2 * nb : 3 * nb], t[3 * nb :]


def _expect_config(func: str, config) -> None:
    if not isinstance(config, ColumnConfig):
        raise TypeError(f"{func}: config = {' '.join(fmt(config).split())} ({type(config).__name__}): give a ColumnConfig")


def column_topology(config: ColumnConfig) -> ColumnTopology:
    """The column's nodes, members and unit self-stress (shared by every column of a scene): the
    scene's topology, computed once per process (planning and the build ask for it once per batch:
    52 times in phase_large's plan, 1 s of SVDs), the caller's own copy of its arrays."""
    _expect_config("column_topology", config)
    topo = _column_topology(config)
    return dataclasses.replace(topo, **{f.name: getattr(topo, f.name).copy() for f in dataclasses.fields(topo)
                                        if isinstance(getattr(topo, f.name), np.ndarray)})


@lru_cache(maxsize=16)
def _column_topology(config: ColumnConfig) -> ColumnTopology:
    n = config.n_prisms
    hand = config.prism_handedness()
    a, h0, phi = config.radius, config.height, config.twist
    # clockwise numbering and clockwise twist for right-handed prisms (seen from +z)
    angle = np.zeros((n + 1, 3))
    angle[0] = -2.0 * np.pi * np.arange(3) / 3.0
    steps = np.concatenate([angle[:1], -np.repeat((np.asarray(hand, dtype=np.float64) * phi)[:, None], 3, axis=1)])
    angle = np.cumsum(steps, axis=0)  # angle[m + 1] = angle[m] - hand[m] * phi, in that order
    z = np.arange(n + 1)[:, None] * h0 * np.ones((1, 3))
    pos = np.stack([a * np.cos(angle), a * np.sin(angle), z], axis=-1).reshape(-1, 3)
    level_nodes = np.arange(3 * (n + 1)).reshape(n + 1, 3)

    m, k = np.divmod(np.arange(3 * n, dtype=np.int64), 3)  # prism and corner of each bar / cross cable
    bars = np.stack([3 * m + k, 3 * (m + 1) + k], axis=1)
    kk = np.where(np.asarray(hand)[m] > 0, (k + 2) % 3, (k + 1) % 3)
    cross = np.stack([3 * m + k, 3 * (m + 1) + kk], axis=1)
    lvl, k = np.divmod(np.arange(3 * (n + 1), dtype=np.int64), 3)
    base = np.stack([3 * lvl + k, 3 * lvl + (k + 1) % 3], axis=1)
    base_level = lvl

    unit_bar = np.zeros(3 * n)
    unit_base = np.zeros(3 * (n + 1))
    unit_bottom, unit_top = np.zeros(3 * n), np.zeros(3 * n)  # each prism's shares (graded columns)
    # every prism of one handedness is the same prism turned and raised: a long column solves the
    # first of each (a short one solves each, so its numbers stay those of earlier releases bit for bit)
    each = n <= SELF_STRESS_EACH_MAX
    solved = {}
    for m in (range(n) if each else [int(np.argmax(hand == h)) for h in np.unique(hand)]):
        sl, up = slice(3 * m, 3 * m + 3), slice(3 * m + 3, 3 * m + 6)
        try:
            sb, sc, sbot, stop = prism_self_stress(pos, bars[sl], cross[sl], base[sl], base[up])
        except NetworkError as e:  # name the option that decides it
            raise NetworkError(f"twist = {config.twist!r} rad: {e}") from None
        if np.any(np.abs(sc - 1) > 1e-9):
            raise NetworkError(f"prism {m}: cross cables do not share one self-stress level: {sc}")
        if each:
            unit_bar[sl] = sb
            unit_base[sl] += sbot  # superposition: interior bases carry both prisms' share
            unit_base[up] += stop
            unit_bottom[sl], unit_top[sl] = sbot, stop
        solved[int(hand[m])] = (sb, sbot, stop)
    if not each:
        keys = np.array(sorted(solved))
        row = np.searchsorted(keys, hand)  # each prism's handedness in keys
        sb, sbot, stop = (np.stack([solved[int(h)][i] for h in keys])[row] for i in range(3))  # (n, 3) each
        unit_bar[:] = sb.ravel()
        unit_base[:-3] += sbot.ravel()
        unit_base[3:] += stop.ravel()
        unit_bottom[:], unit_top[:] = sbot.ravel(), stop.ravel()
    if np.any(unit_bar >= 0) or np.any(unit_base <= 0):
        raise NetworkError(f"twist = {config.twist!r} rad, handedness = {config.handedness!r}: self-stress has "
                           "compressed cables or stretched bars")
    fixed = np.zeros(3 * (n + 1), dtype=bool)
    fixed[level_nodes[0]] = True
    return ColumnTopology(config, pos, fixed, level_nodes, bars, cross, base, base_level, unit_bar, unit_base,
                          unit_bottom, unit_top)


# ---------------------------------------------------------------------- per-column laws
def base_member_law(EA: np.ndarray, base_rigidity: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Axial law of the base members for base rigidity beta in [0, 1].

    Returns (EA_tension, EA_compression, rigid): tension stiffness EA/(1-beta), compression
    stiffness beta*EA/(1-beta), and a flag for beta == 1 where the member is a rigid link.
    beta = 0 gives the FB tension-only cable; beta -> 1 tends continuously to the RB link.
    """
    beta = np.asarray(base_rigidity, dtype=np.float64)
    rigid = beta >= 1.0
    soft = np.where(rigid, 0.0, 1.0 - beta)
    with np.errstate(divide="ignore", invalid="ignore"):
        ea_t = np.where(rigid, 0.0, EA / np.where(rigid, 1.0, soft))
    ea_c = np.where(rigid, 0.0, beta * ea_t)
    return ea_t, ea_c, rigid


def check_column_params(prestrain, v0, base_rigidity, cable_EA, unit_mass) -> None:
    """Raise NetworkError naming the parameter and value for any physically impossible input."""
    for name, val in zip(("prestrain", "v0", "base_rigidity", "cable_EA", "unit_mass"),
                         (prestrain, v0, base_rigidity, cable_EA, unit_mass)):
        check_column_param(name, val, NetworkError)  # bounds declared once, in options.ColumnParameters


def level_cable_EA(prism_EA: np.ndarray) -> np.ndarray:
    """(B, n_prisms + 1) EA [N] the base members of each level derive from, from the cross cables'
    (B, n_prisms): an interior level is shared by two prisms and takes the mean of theirs; an end
    level takes its one prism's (a uniform column: every level the cables' EA, exactly)."""
    ea = np.asarray(prism_EA, dtype=np.float64)
    return np.concatenate([ea[:, :1], 0.5 * (ea[:, :-1] + ea[:, 1:]), ea[:, -1:]], axis=1)


def level_node_masses(config: ColumnConfig, level_mass: np.ndarray) -> np.ndarray:
    """(B, n_nodes) lumped node masses [kg] from (B, n_prisms + 1) masses per level: each level's
    over its 3 nodes, the end levels' halved under end_base_mass = 'half' (as :func:`node_masses`)."""
    base_mass = np.array(level_mass, dtype=np.float64)
    if config.end_base_mass == "half":
        base_mass[:, 0] *= 0.5
        base_mass[:, -1] *= 0.5
    return np.repeat(base_mass / 3.0, 3, axis=1)


def impact_of_level_masses(config: ColumnConfig, level_mass: np.ndarray, rigid: bool) -> np.ndarray:
    """(n_nodes, 3) admissible impact velocity at v0 = 1 m/s [m s-1] of a column with masses per level
    ``level_mass`` (n_prisms + 1) [kg], flexible-like (``rigid`` False) or rigid bases: the scene's
    impact_admissibility weighs the masses ('rigid_members', 'project')."""
    scene = build_column(config, base_rigidity=1.0 if rigid else 0.0)
    net = scene.network
    net.node_mass = level_node_masses(config, np.asarray(level_mass, dtype=np.float64)[None, :])[0]
    return _impact(config, scene.topology, net, 1.0)


def node_masses(topo: ColumnTopology, unit_mass: float) -> np.ndarray:
    """Lumped node masses [kg]: each base carries unit_mass (free end: per end_base_mass), over 3 nodes."""
    n = topo.config.n_prisms
    base_mass = np.full(n + 1, unit_mass)
    if topo.config.end_base_mass == "half":
        base_mass[n] = 0.5 * unit_mass
        base_mass[0] = 0.5 * unit_mass
    return np.repeat(base_mass / 3.0, 3)


@dataclass
class ColumnScene:
    """One column ready to simulate: its network, initial velocity and the builder's report."""

    topology: ColumnTopology
    network: Network
    velocity: np.ndarray
    """(n_nodes, 3) admissible initial velocity [m s-1]."""
    prestrain: float
    v0: float
    base_rigidity: float
    cross_tension: float
    """Cross-cable tension EA*p in the reference state [N]."""
    equilibrium_residual: float
    """Largest nodal force imbalance at free nodes in the reference state [N] (bars at best-fit forces)."""

    @property
    def relative_equilibrium_residual(self) -> float:
        """Residual over the cross-cable tension (0 when unstressed and exactly balanced)."""
        if self.equilibrium_residual == 0.0:
            return 0.0
        return self.equilibrium_residual / max(self.cross_tension, np.finfo(float).tiny)


def build_column(
    config: ColumnConfig | None = None,
    prestrain: float = 0.0,
    v0: float = 0.0,
    base_rigidity: float = 0.0,
    cable_EA: float | None = None,
    unit_mass: float | None = None,
    topology: ColumnTopology | None = None,
    check_equilibrium: bool = True,
) -> ColumnScene:
    """Build one column: rest lengths from the self-stress at cross prestrain ``p``, masses,
    the impact velocity ``v0`` (compressive, along -z at the free end) and the equilibrium check
    (``check_equilibrium`` False: skipped, ``equilibrium_residual`` NaN; a least-squares solve of the
    whole column, most of the build's time, which the base-mode analysis does not need)."""
    config = ColumnConfig() if config is None else config
    _expect_config("build_column", config)
    for name, val in (("prestrain", prestrain), ("v0", v0), ("base_rigidity", base_rigidity), ("cable_EA", cable_EA),
                      ("unit_mass", unit_mass)):
        if val is not None and (isinstance(val, (bool, np.bool_)) or not isinstance(val, (int, float, np.number))):
            raise TypeError(f"build_column: {name} = {' '.join(fmt(val).split())}: give one number (one column; "
                            "column_batch takes arrays)")
    topo = topology or column_topology(config)
    EA = config.cable_EA if cable_EA is None else float(cable_EA)
    mu = config.unit_mass if unit_mass is None else float(unit_mass)
    check_column_params(prestrain, v0, base_rigidity, EA, mu)

    X = topo.positions
    T = EA * prestrain  # cross-cable tension: EA/L*(s-L) = EA*p
    ea_t, ea_c, rigid = base_member_law(np.array(EA), np.array(base_rigidity))
    rigid = bool(rigid)
    ell_cross = np.linalg.norm(X[topo.cross[:, 1]] - X[topo.cross[:, 0]], axis=1)
    ell_base = np.linalg.norm(X[topo.base[:, 1]] - X[topo.base[:, 0]], axis=1)
    cables = [topo.cross]
    EAs = [np.full(len(topo.cross), EA)]
    EAc = [np.zeros(len(topo.cross))]
    rest = [ell_cross / (1.0 + prestrain)]
    names = [f"cross cable {k}" for k in range(len(topo.cross))]
    bars = [topo.bars]
    bar_names = [f"bar {k}" for k in range(len(topo.bars))]
    if rigid:
        movable = topo.base_level > 0  # links between two clamped nodes carry nothing
        bars.append(topo.base[movable])
        bar_names += [f"base link {k} (level {l})" for k, l in enumerate(topo.base_level) if l > 0]
    else:
        F = T * topo.unit_base_force
        cables.append(topo.base)
        EAs.append(np.full(len(topo.base), float(ea_t)))
        EAc.append(np.full(len(topo.base), float(ea_c)))
        rest.append(ell_base / (1.0 + F / float(ea_t)))
        names += [f"base member {k} (level {l})" for k, l in enumerate(topo.base_level)]
    bars = np.concatenate(bars)
    net = Network(
        positions=X,
        node_mass=node_masses(topo, mu),
        fixed=topo.fixed,
        bars=bars,
        bar_mass=np.where(np.arange(len(bars)) < len(topo.bars), config.bar_mass, 0.0),
        cables=np.concatenate(cables),
        cable_EA=np.concatenate(EAs),
        cable_rest_length=np.concatenate(rest),
        cable_EA_compression=np.concatenate(EAc),
        bar_names=bar_names,
        cable_names=names,
    ).validate()
    residual = equilibrium_residual(net) if check_equilibrium else float("nan")
    vel = _impact(config, topo, net, v0)
    return ColumnScene(topo, net, vel, float(prestrain), float(v0), float(base_rigidity), T, residual)


def _impact(config: ColumnConfig, topo: ColumnTopology, net: Network, v0: float) -> np.ndarray:
    """The admissible impact velocity [m s-1] of the column ``net`` per the scene's impact_admissibility."""
    X = topo.positions
    if config.impact_admissibility == "rigid_members":
        members, dense = np.concatenate([topo.bars, topo.base]), sparse.use_dense(9 * config.n_prisms)
        try:
            if dense or np.any(net.bar_mass):
                return least_energy_impact(X, net.mass_matrix(), topo.fixed, members, topo.level_nodes[-1], v0)
            # a long column: lumped masses, O(n)
            return sparse.least_energy_impact(X, net.node_mass, topo.fixed, members, topo.level_nodes[-1], v0)
        except ValueError as e:  # the scene's error class, so callers see one kind of bad-input error
            raise NetworkError(f"{e} (height = {config.height!r} m, radius = {config.radius!r} m)") from None
    return impact_velocity(net, topo.level_nodes[-1], v0, config.impact_admissibility)


# ---------------------------------------------------------------------- checks and impact
def constraint_jacobian(net: Network, positions: np.ndarray | None = None) -> np.ndarray:
    """J (n_bars x 3 n_nodes) of g_k = |b_k|^2 / 2 with fixed nodes' columns dropped to zero."""
    x = net.positions if positions is None else positions
    J = np.zeros((net.n_bars, 3 * net.n_nodes))
    for k, (i, j) in enumerate(net.bars):
        b = x[j] - x[i]
        J[k, 3 * j : 3 * j + 3] += b
        J[k, 3 * i : 3 * i + 3] -= b
    free = np.repeat(~net.fixed, 3)
    return J * free[None, :]


def equilibrium_residual(net: Network) -> float:
    """Max nodal force imbalance [N] at free nodes with cables at their tension and bars at the
    least-squares forces that balance them (the bars can carry any axial force)."""
    x = net.positions
    f = np.zeros((net.n_nodes, 3))
    t = net.cable_tensions()
    e = x[net.cables[:, 1]] - x[net.cables[:, 0]]
    e /= np.linalg.norm(e, axis=1, keepdims=True)
    np.add.at(f, net.cables[:, 0], t[:, None] * e)
    np.add.at(f, net.cables[:, 1], -t[:, None] * e)
    free = np.repeat(~net.fixed, 3)
    rhs = f.reshape(-1)[free]
    if not rhs.size:
        return 0.0
    if not sparse.use_dense(rhs.size):  # a long column: O(n) (scene/sparse.py)
        return float(sparse.lsq_residual(sparse.jacobian(x, net.bars, net.fixed)[:, np.flatnonzero(free)], rhs))
    J = constraint_jacobian(net)[:, free]
    lam, *_ = np.linalg.lstsq(J.T, rhs, rcond=None)
    r = rhs - J.T @ lam
    return float(np.abs(r).max())


def impact_velocity(net: Network, end_nodes: Sequence[int], v0: float, mode: str) -> np.ndarray:
    """Admissible initial velocity [m s-1] for an axial compressive impact -v0 on ``end_nodes``."""
    n = net.n_nodes
    target = np.zeros((n, 3))
    target[list(end_nodes), 2] = -v0
    if v0 == 0.0:
        return target
    free = np.repeat(~net.fixed, 3)
    long = not sparse.use_dense(int(free.sum()))
    J = sparse.jacobian(net.positions, net.bars, net.fixed) if long or mode == "end_twist" else constraint_jacobian(net)
    if mode == "project" and long and not np.any(net.bar_mass):  # O(n): lumped masses, sparse solve
        return sparse.project_velocity(J, net.node_mass, free, target.reshape(-1)).reshape(n, 3)
    if mode == "project":
        J = J.toarray() if long else J  # massive bars (a single prism): dense
        M = np.kron(net.mass_matrix(), np.eye(3))[np.ix_(free, free)]
        Jf = J[:, free]
        Minv_JT = np.linalg.solve(M, Jf.T)
        lam = np.linalg.solve(Jf @ Minv_JT, Jf @ target.reshape(-1)[free])
        v = target.reshape(-1).copy()
        v[free] -= Minv_JT @ lam
        return v.reshape(n, 3)
    if mode == "end_twist":
        cols = np.array([3 * i + c for i in end_nodes for c in (0, 1)])
        # J sparse (the same entries as the dense one, so the same numbers): O(n) at any length
        rows = np.flatnonzero(np.asarray(abs(J[:, cols]).sum(axis=1)).ravel() > 0)
        rhs = -(J[rows] @ target.reshape(-1))
        u, *_ = np.linalg.lstsq(J[rows][:, cols].toarray(), rhs, rcond=None)
        v = target.reshape(-1).copy()
        v[cols] = u
        viol = np.abs(J @ v).max() / (abs(v0) * abs(J).max())
        if viol > 1e-10:
            raise NetworkError(
                f"impact_admissibility='end_twist': no horizontal end velocity satisfies the bars "
                f"(residual {viol:.2e}); use 'project'"
            )
        return v.reshape(n, 3)
    raise NetworkError(f"impact_admissibility = {mode!r}; choose one of {IMPACT_ADMISSIBILITY}")


def prism_heights(topo: ColumnTopology, positions: np.ndarray) -> np.ndarray:
    """Height of each prism [m]: mean z of its top base minus mean z of its bottom base.
    ``positions`` has shape (..., n_nodes, 3)."""
    zl = positions[..., topo.level_nodes, 2].mean(axis=-1)
    return zl[..., 1:] - zl[..., :-1]
