"""A batch of networks of one topology, with per-column parameters (host, float64 NumPy).

This is the step between the scene builders and the device model: every per-column array
has a leading dimension of either B (varies across the batch) or 1 (shared), as MuJoCo Warp's
batched model fields. :func:`column_batch` builds one for T3 columns without a Python loop
over columns; :func:`network_batch` wraps arbitrary networks of identical topology.
"""

from __future__ import annotations

import dataclasses
import functools
from dataclasses import dataclass, field

import numpy as np

from ..arguments import expect, expect_params
from ..options import COLUMN_PARAMETERS, PROFILED, ColumnParameters, Profile, check_column_param, fmt, profile_length
from . import columns as col
from . import sparse
from .blas import single_blas_thread
from .contact import prism_pairs
from .network import Network, NetworkError
from .striker import attach_striker
from .preload import apply_preload


@dataclass
class NetworkBatch:
    """B networks sharing nodes, member lists and reference geometry."""

    positions: np.ndarray
    """(n_nodes, 3) reference positions shared by the batch [m]."""
    fixed: np.ndarray
    """(n_nodes,) clamped nodes."""
    constraints: np.ndarray
    """(n_constraints, 2) rigid members (bars, and rigid base links when any column has them)."""
    cables: np.ndarray
    """(n_cables, 2) elastic members."""
    node_mass: np.ndarray
    """(B or 1, n_nodes) lumped node masses [kg]."""
    constraint_mass: np.ndarray
    """(B or 1, n_constraints) bar masses [kg] (consistent thin-rod inertia)."""
    constraint_active: np.ndarray
    """(B or 1, n_constraints) 1 where the rigid member exists in that column, else 0."""
    cable_EA: np.ndarray
    """(B or 1, n_cables) tension stiffness EA [N]; 0 disables the member."""
    cable_EA_compression: np.ndarray
    """(B or 1, n_cables) compression stiffness [N]; 0 for tension-only cables."""
    cable_rest_length: np.ndarray
    """(B or 1, n_cables) rest lengths [m]."""
    velocity: np.ndarray
    """(B, n_nodes, 3) admissible initial velocities [m s-1]."""
    n_columns: int
    params: dict = field(default_factory=dict)
    """Per-column scene parameters, each (B,), for the record."""
    level_nodes: np.ndarray | None = None
    """(n_levels, 3) node indices of each column base (T3 columns), for strain output."""
    constraint_names: list[str] | None = None
    cable_names: list[str] | None = None
    equilibrium_residual: np.ndarray | None = None
    """(B,) relative equilibrium residual of the reference state (columns)."""
    contact_pairs: np.ndarray | None = None
    """(n_pairs, 2) constraint indices of the bar pairs kept apart (scene contact = 'bars'), or None."""
    contact_gap: float = 0.0
    """Smallest distance 2 r allowed between the axes of a contact pair [m]."""
    restitution: float = 1.0
    """Restitution coefficient of a bar impact [1]."""
    striker_mass: np.ndarray | None = None
    """(B,) striker mass [kg] (scene impact = 'striker', :mod:`.striker`), or None: no striker."""
    striker_velocity: np.ndarray | None = None
    """(B,) striker velocity after the blow [m s-1] (along z: negative, downward)."""
    striker_end_mass: np.ndarray | None = None
    """(B,) effective mass of the struck end in the blow [kg]."""
    striker_nodes: np.ndarray | None = None
    """(3,) the end base's nodes, which the striker's face touches."""
    initial_displacement: np.ndarray | None = None
    """(B, n_nodes, 3) initial displacement from ``positions`` [m]: a preloaded column starts from its
    static equilibrium (scene.preload); None: every column starts at the reference."""
    external_force: np.ndarray | None = None
    """(B or 1, n_nodes, 3) dead load on the nodes [N] (the end preload); None: none."""
    static_dz: np.ndarray | None = None
    """(B or 1, n_prisms) prism height change of the initial equilibrium [m]; the strain is recorded
    from it (from the preloaded state, not from ``positions``); None: 0."""


def _shrink(a: np.ndarray) -> np.ndarray:
    """(B, ...) -> (1, ...) when every column holds the same values."""
    a = np.asarray(a, dtype=np.float64)
    if a.shape[0] > 1 and np.all(a == a[:1]):
        return a[:1].copy()
    return a


def network_batch(networks: list[Network], velocities: list[np.ndarray] | None = None) -> NetworkBatch:
    """Batch arbitrary networks with identical topology and reference positions."""
    expect("network_batch", "networks", networks, (list, tuple))
    for b, net in enumerate(networks):
        expect("network_batch", f"networks[{b}]", net, Network)
    if not networks:
        raise NetworkError("network_batch: empty list of networks")
    first = networks[0].validate()
    for b, net in enumerate(networks[1:], start=1):
        net.validate()
        for name in ("bars", "cables", "fixed"):
            if not np.array_equal(getattr(net, name), getattr(first, name)):
                raise NetworkError(f"network {b}: {name} differ from network 0; a batch shares one topology")
        if not np.allclose(net.positions, first.positions, rtol=0, atol=1e-15):
            raise NetworkError(f"network {b}: reference positions differ from network 0")
    B = len(networks)
    vel = np.zeros((B, first.n_nodes, 3)) if velocities is None else np.asarray(velocities, dtype=np.float64)
    if vel.shape != (B, first.n_nodes, 3):
        raise NetworkError(f"velocities: shape {vel.shape}, expected {(B, first.n_nodes, 3)}")
    stack = lambda name: _shrink(np.stack([getattr(n, name) for n in networks]))  # noqa: E731
    return NetworkBatch(
        positions=first.positions.copy(),
        fixed=first.fixed.copy(),
        constraints=first.bars.copy(),
        cables=first.cables.copy(),
        node_mass=stack("node_mass"),
        constraint_mass=stack("bar_mass"),
        constraint_active=np.ones((1, first.n_bars)),
        cable_EA=stack("cable_EA"),
        cable_EA_compression=stack("cable_EA_compression"),
        cable_rest_length=stack("cable_rest_length"),
        velocity=vel,
        n_columns=B,
        constraint_names=[first.bar_name(k) for k in range(first.n_bars)],
        cable_names=[first.cable_name(k) for k in range(first.n_cables)],
    )


class ColumnParams(dict):
    """Per-column parameters filled, broadcast to (B,) and validated once, at entry
    (:func:`column_params`), which passes them through unchanged afterwards; :meth:`take` keeps the
    mark on a subset of the columns. A profile along the column (:data:`~warp_tensegrity.options.PROFILED`)
    is (B, n_prisms) or (B, n_prisms + 1) (unit_mass, per level)."""

    @property
    def n_columns(self) -> int:
        return int(self["prestrain"].shape[0])

    def take(self, index) -> ColumnParams:
        """The parameters of the columns ``index`` (a slice, or an integer array)."""
        return ColumnParams({k: v[index] for k, v in self.items()})


def has_profiles(params: dict) -> bool:
    """Whether some parameter varies along the column (a 2-D array in filled parameters)."""
    return any(np.ndim(v) == 2 for v in params.values())


def far_end_params(params: ColumnParams, n_prisms: int, n_sim: int) -> ColumnParams:
    """The parameters of the last ``n_sim`` prisms of ``n_prisms`` (a truncated run's column,
    :func:`~warp_tensegrity.policy.decide.far_end`): profiles cut at the clamped end."""
    if n_sim >= n_prisms or not has_profiles(params):
        return params
    cut = n_prisms - n_sim
    return ColumnParams({k: v[:, cut:] if np.ndim(v) == 2 else v for k, v in params.items()})


def _profile_array(config: col.ColumnConfig, name: str, value) -> np.ndarray | None:
    """(B or 1, n) entries of a profile given as a Profile or a 2-D array; None for a per-column
    value (a scalar or a 1-D array). NetworkError names the parameter and the value."""
    if isinstance(value, Profile):
        return value.check(name, config.n_prisms, NetworkError)[None, :]
    if isinstance(value, dict) and name in PROFILED:  # the TOML form, from Python
        return Profile.from_table(name, value, NetworkError).check(name, config.n_prisms, NetworkError)[None, :]
    try:
        arr = np.asarray(value)
    except (TypeError, ValueError):  # ragged nesting: the per-column check names it
        return None
    if arr.ndim != 2 or arr.dtype.kind not in "iuf":  # not numbers: the per-column check names it too
        return None
    if name not in PROFILED:
        raise NetworkError(f"{name} = {fmt(value)}: {name} takes one value per column, not a profile "
                           f"(profiles: {', '.join(PROFILED)})")
    n = profile_length(name, config.n_prisms)
    shape = np.shape(value)
    if shape[1] != n or shape[0] < 1:
        raise NetworkError(f"{name}: shape {shape}, expected (B, {n}): one value per {PROFILED[name]} "
                           f"(n_prisms = {config.n_prisms})")
    check_column_param(name, value, NetworkError)
    return np.asarray(value, dtype=np.float64)


def column_params(config: col.ColumnConfig, params: dict) -> ColumnParams:
    """Fill defaults and broadcast the per-column parameters to a common length B; validate. Parameters
    this function returned already come back as they are (validated once)."""
    expect("column_batch", "config", config, col.ColumnConfig)
    if isinstance(params, ColumnParams):
        return params
    params = expect_params("column_batch", params)
    unknown = sorted(set(params) - set(COLUMN_PARAMETERS))
    if unknown:
        raise NetworkError(f"unknown column parameter(s) {unknown}; known: {sorted(COLUMN_PARAMETERS)}")
    # defaults declared in options.ColumnParameters; None there means "the scene's value"
    defaults = {f.name: getattr(config, f.name) if f.default is None else f.default
                for f in dataclasses.fields(ColumnParameters)}
    profiles = {}
    for k in params:
        prof = _profile_array(config, k, params[k])
        if prof is not None:
            profiles[k] = prof
        else:
            check_column_param(k, params[k], NetworkError)  # type and bounds, before any conversion
    arrays = {k: np.atleast_1d(np.asarray(params.get(k, d), dtype=np.float64)) if k not in profiles else profiles[k]
              for k, d in defaults.items()}
    B = max(a.shape[0] if k in profiles else a.size for k, a in arrays.items())
    for k, a in arrays.items():
        if k in profiles:
            if a.shape[0] not in (1, B):
                raise NetworkError(f"parameter {k}: shape {a.shape} does not broadcast to ({B}, {a.shape[1]})")
            a = np.broadcast_to(a, (B, a.shape[1])).copy()
            # a profile that is the same along every column is that column's value (exactly as a scalar)
            arrays[k] = a[:, 0].copy() if np.all(a == a[:, :1]) else a
            continue
        if a.ndim != 1 or a.size not in (1, B):
            raise NetworkError(f"parameter {k}: shape {a.shape} does not broadcast to ({B},)")
        arrays[k] = np.broadcast_to(a, (B,)).copy()
    col.check_column_params(*(arrays[k] for k in ("prestrain", "v0", "base_rigidity", "cable_EA", "unit_mass")))
    return ColumnParams(arrays)


@functools.lru_cache(maxsize=32)
def _unit_impact(config: col.ColumnConfig, rigid: bool) -> np.ndarray:
    """(n_nodes, 3) initial velocity [m s-1] of the column at v0 = 1 m/s, FB-like or RB, read-only.
    Cached per scene: a 'rigid_members' impact is a least-energy solve (an SVD) per build, and a
    sweep builds the same column for every shard (and again to pad truncated runs)."""
    v = col.build_column(config, prestrain=0.0, v0=1.0, base_rigidity=1.0 if rigid else 0.0).velocity
    v.flags.writeable = False
    return v


@functools.lru_cache(maxsize=32)
def _graded_unit_impact(config: col.ColumnConfig, rigid: bool, mass_shape: bytes) -> np.ndarray:
    """:func:`_unit_impact` of a column whose level masses are ``mass_shape`` (float64 bytes, any
    scale: the impact is invariant to a uniform one), read-only."""
    v = col.impact_of_level_masses(config, np.frombuffer(mass_shape), rigid)
    v.flags.writeable = False
    return v


@single_blas_thread
def column_batch(config: col.ColumnConfig, params: dict) -> NetworkBatch:
    """Vectorised batch of T3 columns: one topology, per-column prestrain, v0, base rigidity, EA, mass.

    Rigid base links are included as constraints only if some column has base_rigidity == 1
    (model no more than the scene needs); they are inactive in the other columns, whose base
    members are elastic instead.
    """
    topo = col.column_topology(config)
    p = column_params(config, params)
    B = p.n_columns
    X = topo.positions
    n_cross, n_base = len(topo.cross), len(topo.base)
    graded = p["prestrain"].ndim == 2 or p["cable_EA"].ndim == 2  # a mass profile keeps the uniform stress
    if graded:  # per prism: prestrain and EA (B, n); per level: the base members' EA (B, n + 1)
        n = config.n_prisms
        prism_p = np.broadcast_to(p["prestrain"][:, None], (B, n)) if p["prestrain"].ndim == 1 else p["prestrain"]
        prism_ea = np.broadcast_to(p["cable_EA"][:, None], (B, n)) if p["cable_EA"].ndim == 1 else p["cable_EA"]
        level_ea = col.level_cable_EA(prism_ea)
        ea_t, ea_c, rigid = col.base_member_law(level_ea, p["base_rigidity"][:, None])
        ea_t, ea_c = np.repeat(ea_t, 3, axis=1), np.repeat(ea_c, 3, axis=1)
    else:
        ea_t, ea_c, rigid = col.base_member_law(p["cable_EA"][:, None], p["base_rigidity"][:, None])
    rigid = rigid[:, 0]
    any_rigid = bool(rigid.any())
    movable = topo.base_level > 0
    links = topo.base[movable]

    # constraints ordered level by level so the Gram matrix is banded: bars of prism m, then links of level m+1
    cons, names, is_link = [], [], []
    for m in range(config.n_prisms):
        for k in range(3):
            cons.append(topo.bars[3 * m + k])
            names.append(f"bar {3 * m + k} (prism {m})")
            is_link.append(False)
        if any_rigid:
            for k in range(3):
                cons.append(topo.base[3 * (m + 1) + k])
                names.append(f"base link {3 * (m + 1) + k} (level {m + 1})")
                is_link.append(True)
    cons = np.array(cons, dtype=np.int64)
    is_link = np.array(is_link)
    active = np.ones((B, len(cons)))
    active[:, is_link] = rigid[:, None].astype(float)

    # cables: cross cables then base members; rest lengths from the self-stress at prestrain p
    ell_cross = np.linalg.norm(X[topo.cross[:, 1]] - X[topo.cross[:, 0]], axis=1)
    ell_base = np.linalg.norm(X[topo.base[:, 1]] - X[topo.base[:, 0]], axis=1)
    if graded:
        # each prism's self-stress scaled by its own cross tension T_m = EA_m p_m; a base member shared
        # by prisms m - 1 and m carries both shares (superposition keeps every node in equilibrium)
        T = prism_ea * prism_p  # (B, n) [N]
        T3 = np.repeat(T, 3, axis=1)
        F_base = np.zeros((B, n_base))
        F_base[:, :-3] += T3 * topo.unit_base_bottom[None, :]
        F_base[:, 3:] += T3 * topo.unit_base_top[None, :]
        cross_p, cross_ea = np.repeat(prism_p, 3, axis=1), np.repeat(prism_ea, 3, axis=1)
    else:
        T = p["cable_EA"] * p["prestrain"]  # (B,) cross-cable tension [N]
        F_base = T[:, None] * topo.unit_base_force[None, :]
        cross_p, cross_ea = p["prestrain"][:, None], np.repeat(p["cable_EA"][:, None], n_cross, 1)
    safe_ea = np.where(ea_t > 0, ea_t, 1.0)
    rest_base = np.where(rigid[:, None], ell_base[None, :], ell_base[None, :] / (1.0 + F_base / safe_ea))
    rest = np.concatenate([ell_cross[None, :] / (1.0 + cross_p), rest_base], axis=1)
    EA = np.concatenate([cross_ea, np.broadcast_to(ea_t, (B, n_base))], axis=1)
    EAc = np.concatenate([np.zeros((B, n_cross)), np.broadcast_to(ea_c, (B, n_base))], axis=1)
    cables = np.concatenate([topo.cross, topo.base])
    cable_names = [f"cross cable {k}" for k in range(n_cross)] + [
        f"base member {k} (level {lvl})" for k, lvl in enumerate(topo.base_level)
    ]

    if p["unit_mass"].ndim == 2:  # per level
        node_mass = col.level_node_masses(config, p["unit_mass"])
    else:
        masses = np.stack([col.node_masses(topo, mu) for mu in np.unique(p["unit_mass"])])
        mass_index = np.searchsorted(np.unique(p["unit_mass"]), p["unit_mass"])
        node_mass = masses[mass_index]
    bar_mass = np.where(is_link, 0.0, config.bar_mass)[None, :]

    # the admissible initial velocity is linear in v0 and invariant to a uniform mass scale:
    # one exact build per base class (FB-like or RB)
    velocity = np.zeros((B, topo.n_nodes, 3))
    # ('rigid_members' does not depend on beta: one build for all)
    classes = (False,) if config.impact_admissibility == "rigid_members" else (False, True)
    mass_shape = np.zeros((B, 1)) if p["unit_mass"].ndim == 1 else p["unit_mass"] / p["unit_mass"][:, -1:]
    for r in classes:
        cols_r = np.arange(B) if len(classes) == 1 else np.flatnonzero(rigid == r)
        if cols_r.size == 0:
            continue
        if p["unit_mass"].ndim == 1 or config.impact_admissibility == "end_twist":  # no mass profile, or blind to it
            velocity[cols_r] = p["v0"][cols_r, None, None] * _unit_impact(config, r)[None]
            continue
        # the least-energy and projected impacts weigh the masses: one build per distinct mass profile
        shapes, which = np.unique(mass_shape[cols_r], axis=0, return_inverse=True)
        for i, shape in enumerate(shapes):
            sel = cols_r[which.reshape(-1) == i]
            velocity[sel] = p["v0"][sel, None, None] * _graded_unit_impact(config, r, shape.tobytes())[None]
    batch = NetworkBatch(
        positions=X.copy(),
        fixed=topo.fixed.copy(),
        constraints=cons,
        cables=cables,
        node_mass=_shrink(node_mass),
        constraint_mass=_shrink(np.broadcast_to(bar_mass, (1, len(cons)))),
        constraint_active=_shrink(active),
        cable_EA=_shrink(EA),
        cable_EA_compression=_shrink(EAc),
        cable_rest_length=_shrink(rest),
        velocity=velocity,
        n_columns=B,
        params=p,
        level_nodes=topo.level_nodes.copy(),
        constraint_names=names,
        cable_names=cable_names,
    )
    if config.contact == "bars":  # each prism's bar pairs, as rows of the constraint list
        bar_row = np.flatnonzero(~is_link)
        batch.contact_pairs = bar_row[prism_pairs(topo.bars)].astype(np.int64)
        batch.contact_gap = 2.0 * float(config.bar_radius)
        batch.restitution = float(config.restitution)
    if config.impact == "striker":  # the blow: the rigid_members field at the common speed (scene.striker)
        M = p["striker_mass"]
        bad = np.flatnonzero(~(M > 0.0))
        if bad.size:
            where = f"[{int(bad[0])}]" if B > 1 else ""
            raise NetworkError(f"striker_mass{where} = {float(M[bad[0]])!r}: impact = 'striker' needs a striker mass "
                               "> 0 [kg]")
        loaded = np.flatnonzero(p["preload"] > 0)
        if loaded.size:  # the blow is solved at the unloaded reference (scene.striker)
            where = f"[{int(loaded[0])}]" if B > 1 else ""
            raise NetworkError(f"preload{where} = {float(p['preload'][loaded[0]])!r}: a striker on a preloaded column "
                               "is not modelled; give impact = 'velocity' or preload = 0")
        attach_striker(batch, M, _unit_impact(config, False))
    # the reference state depends on (prestrain, base rigidity, EA) only: check each distinct one once
    states, inverse = reference_states(p)
    if len(inverse) > len(states["prestrain"]):
        still = dataclasses.replace(config, impact="velocity") if config.impact == "striker" else config  # statics
        batch.equilibrium_residual = column_batch(still, states).equilibrium_residual[inverse]
    else:  # over the largest cross-cable tension of the column
        batch.equilibrium_residual = equilibrium_residuals(batch) / np.maximum(
            T.max(axis=1) if T.ndim == 2 else T, np.finfo(float).tiny)
    if np.any(p["preload"] > 0):  # the loaded columns start from their static equilibrium
        apply_preload(batch, config, p, col.impact_velocity)
    return batch


def reference_states(p: dict[str, np.ndarray]) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """The distinct reference states among filled per-column parameters (see :func:`column_params`):
    (prestrain, base_rigidity, cable_EA) of each (profiles as they are), and the index of each column's state."""
    names = ("prestrain", "base_rigidity", "cable_EA")
    if not any(np.ndim(p[k]) == 2 for k in names):
        key = np.stack([p["prestrain"], p["base_rigidity"], p["cable_EA"]], axis=1)
        uniq, inverse = np.unique(key, axis=0, return_inverse=True)
        return {"prestrain": uniq[:, 0], "base_rigidity": uniq[:, 1], "cable_EA": uniq[:, 2]}, inverse.reshape(-1)
    parts = [p[k].reshape(p[k].shape[0], -1) for k in names]
    uniq, inverse = np.unique(np.concatenate(parts, axis=1), axis=0, return_inverse=True)
    edges = np.cumsum([0] + [a.shape[1] for a in parts])
    out = {k: uniq[:, a:b] if np.ndim(p[k]) == 2 else uniq[:, a] for k, a, b in zip(names, edges[:-1], edges[1:])}
    return out, inverse.reshape(-1)


def _reference_tensions(batch: NetworkBatch):
    """Unit vectors e (n_cables, 3), stretch s - L and tension (Bc, n_cables) of the reference state."""
    X = batch.positions
    c = batch.cables
    e = X[c[:, 1]] - X[c[:, 0]]
    ell = np.linalg.norm(e, axis=1)
    stretch = ell[None, :] - batch.cable_rest_length
    k = np.where(stretch > 0, batch.cable_EA, batch.cable_EA_compression) / batch.cable_rest_length
    return e / ell[:, None], stretch, k * stretch


def equilibrium_residuals(batch: NetworkBatch) -> np.ndarray:
    """(B,) largest nodal force imbalance [N] at free nodes of the reference state, with the
    rigid members at the least-squares forces that balance the cables (vectorised over columns)."""
    X = batch.positions
    c = batch.cables
    B = batch.n_columns
    e, _, T = _reference_tensions(batch)
    T = np.broadcast_to(T, (B, c.shape[0]))
    n = X.shape[0]
    f = np.zeros((B, n, 3))
    np.add.at(f, (slice(None), c[:, 0]), T[:, :, None] * e[None])
    np.add.at(f, (slice(None), c[:, 1]), -T[:, :, None] * e[None])
    free = np.repeat(~batch.fixed, 3)
    f = f.reshape(B, -1)[:, free]
    active = np.broadcast_to(batch.constraint_active, (B, batch.constraints.shape[0]))
    out = np.zeros(B)
    groups: dict = {}  # columns by their pattern of active constraints (np.unique(axis=0) is slow on long rows)
    if batch.constraint_active.shape[0] == 1:
        groups[b""] = list(range(B))
    for b in range(B if batch.constraint_active.shape[0] > 1 else 0):
        groups.setdefault(active[b].tobytes(), []).append(b)
    for cols in groups.values():
        pattern, sel = active[cols[0]], np.array(cols)
        rows = batch.constraints[pattern > 0]
        if not sparse.use_dense(int(free.sum())):  # a long column: O(n) (scene/sparse.py)
            J = sparse.jacobian(X, rows, batch.fixed)[:, np.flatnonzero(free)]
            out[sel] = sparse.lsq_residual(J, f[sel].T)
            continue
        Q = _constraint_range(np.ascontiguousarray(X, dtype=np.float64).tobytes(), X.shape,
                              np.ascontiguousarray(rows, dtype=np.int64).tobytes(), free.tobytes())
        r = f[sel].T
        out[sel] = np.abs(r - Q @ (Q.T @ r)).max(axis=0)  # what no rigid-member force balances
    return out


@functools.lru_cache(maxsize=16)
def _constraint_range(x: bytes, shape: tuple, rows: bytes, free: bytes) -> np.ndarray:
    """Orthonormal basis of the forces the rigid members ``rows`` can exert on the free coordinates of
    nodes ``x``: the range of J^T, from its SVD (numpy.linalg.lstsq's rank rule). The least-squares
    residual of a load f is f - Q Q^T f; the basis is the same for every prestrain, impact and
    column of one topology, so a sweep computes it once per constraint pattern (each column
    batch and group used to solve its own least squares: 52 ms a call, ~3.6 s for phase_large's)."""
    X = np.frombuffer(x).reshape(shape)
    rows = np.frombuffer(rows, dtype=np.int64).reshape(-1, 2)
    free = np.frombuffer(free, dtype=bool)
    J = np.zeros((len(rows), X.size))
    for k, (i, j) in enumerate(rows):
        b = X[j] - X[i]
        J[k, 3 * j : 3 * j + 3] += b
        J[k, 3 * i : 3 * i + 3] -= b
    u, sv, _ = np.linalg.svd(J[:, free].T, full_matrices=False)
    rank = int(np.sum(sv > np.finfo(float).eps * max(u.shape[0], len(rows)) * sv[0])) if sv.size else 0
    q = np.ascontiguousarray(u[:, :rank])
    q.flags.writeable = False
    return q


def reference_elastic_energy(batch: NetworkBatch) -> np.ndarray:
    """(B,) elastic energy of the reference (prestressed) state [J]."""
    _, stretch, T = _reference_tensions(batch)
    return np.broadcast_to(0.5 * (T * stretch).sum(axis=1), (batch.n_columns,)).copy()


def omega_max_bound(batch: NetworkBatch) -> np.ndarray:
    """(B,) upper bound on the highest natural frequency [rad s-1] with all cables taut.

    Gershgorin on the unconstrained tangent stiffness (notes: omega^2 <= max_i 2/m_i sum max(k, T/l));
    rigid bars only remove degrees of freedom, so the bound holds for the constrained system.
    The inertia of a node includes a third of each massive bar on it.
    """
    X = batch.positions
    c = batch.cables
    ell = np.linalg.norm(X[c[:, 1]] - X[c[:, 0]], axis=1)
    L = batch.cable_rest_length
    k = np.maximum(batch.cable_EA, batch.cable_EA_compression) / L
    T = batch.cable_EA / L * np.maximum(ell - L, 0.0)
    stiff = np.maximum(k, T / ell)  # (Bc, n_cables)
    n = X.shape[0]
    Bc = stiff.shape[0]
    node_k = np.zeros((Bc, n))
    for end in (0, 1):
        np.add.at(node_k, (slice(None), c[:, end]), stiff)
    inertia = np.broadcast_to(batch.node_mass, (max(Bc, batch.node_mass.shape[0]), n)).copy()
    bm = np.broadcast_to(batch.constraint_mass, (inertia.shape[0], batch.constraints.shape[0]))
    for end in (0, 1):
        np.add.at(inertia, (slice(None), batch.constraints[:, end]), bm / 3.0)
    free = ~batch.fixed
    with np.errstate(divide="ignore"):
        ratio = np.where(free[None, :], 2.0 * node_k / np.maximum(inertia, 1e-300), 0.0)
    w = np.sqrt(ratio.max(axis=1))
    return np.broadcast_to(w, (batch.n_columns,)).copy()
