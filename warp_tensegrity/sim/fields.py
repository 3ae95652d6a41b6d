"""The device Model and Data, written out from the declared fields (:data:`warp_tensegrity.types.MODEL_FIELDS`,
:data:`~warp_tensegrity.types.DATA_FIELDS`) by ``python -m warp_tensegrity.sim.fields_gen``. Generated:
do not edit (tests/sim/test_fields.py checks that it is current)."""

from __future__ import annotations

from dataclasses import dataclass

import warp as wp


@dataclass
class Model:
    """Topology and per-column parameters on the device, and the sizes."""

    precision: str
    device: str
    n_columns: int
    n_nodes: int
    n_constraints: int
    n_cables: int
    bandwidth: int
    n_prisms: int
    n_pairs: int
    con_i: wp.array
    """(nc,) int32 [--]: first node of the rigid member."""
    con_j: wp.array
    """(nc,) int32 [--]: second node of the rigid member."""
    con_dref: wp.array
    """(nc,) vec3 [m]: reference bar vector X_j - X_i."""
    con_L: wp.array
    """(nc,) real [m]: bar length (of the rounded con_dref)."""
    con_active: wp.array
    """(nc, Bp) real [1]: 1 if the rigid member exists in the column."""
    cpl_start: wp.array
    """(nc+1,) int32 [--]: CSR row starts of the Gram matrix's coupling terms."""
    cpl_l: wp.array
    """(ncp,) int32 [--]: coupling term's column l <= k of row k."""
    cpl_a: wp.array
    """(ncp,) int32 [--]: coupling term's node a of row k."""
    cpl_cross: wp.array
    """(ncp,) int32 [--]: 1 if the term takes the partner entry of M^-1 (minv_cross)."""
    cpl_sign: wp.array
    """(ncp,) real [1]: coupling term's sign, +-1."""
    ncon_start: wp.array
    """(n+1,) int32 [--]: CSR node -> rigid members."""
    ncon_member: wp.array
    """(2 nc,) int32 [--]: rigid members of the node."""
    cab_i: wp.array
    """(ne,) int32 [--]: first node of the cable."""
    cab_j: wp.array
    """(ne,) int32 [--]: second node of the cable."""
    cab_dref: wp.array
    """(ne,) vec3 [m]: reference cable vector."""
    cab_EA: wp.array
    """(ne, Bp) real [N]: tension stiffness EA."""
    cab_EAc: wp.array
    """(ne, Bp) real [N]: compression stiffness EA_c."""
    cab_L: wp.array
    """(ne, Bp) real [m]: rest length."""
    node_start: wp.array
    """(n+1,) int32 [--]: CSR node -> cables."""
    node_member: wp.array
    """(2 ne,) int32 [--]: cables of the node."""
    node_other: wp.array
    """(2 ne,) int32 [--]: other end of node_member's cable."""
    node_dref: wp.array
    """(2 ne,) vec3 [m]: reference vector from the node to node_other."""
    partner: wp.array
    """(n,) int32 [--]: other end of the node's massive bar if both are free, else -1."""
    mass_blocks: wp.array
    """(nb, 2) int32 [--]: blocks of M: massive bar i < j, or lone node and -1."""
    m_self: wp.array
    """(n, Bp) real [kg]: mass matrix entry of the node."""
    m_cross: wp.array
    """(n, Bp) real [kg]: mass matrix entry of the node and its partner."""
    minv_self: wp.array
    """(n, Bp) real [kg-1]: inverse-mass entry, 0 at fixed nodes."""
    minv_cross: wp.array
    """(n, Bp) real [kg-1]: inverse-mass entry of the node and its partner."""
    ext_force: wp.array
    """(n, Bp) vec3 [N]: dead load on the node (the end preload; 0 without)."""
    level_nodes: wp.array | None
    """(np+1, 3) int32 [--]: nodes of each column base."""
    h0: wp.array | None
    """(np,) real [m]: reference prism heights."""
    static_dz: wp.array | None
    """(np, Bp) real [m]: prism height change in the initial equilibrium (preload; 0 without)."""
    level_ref: wp.array | None
    """(np+1, 3) vec3 [m]: reference position of each base node from its base's centroid."""
    prism_hand: wp.array | None
    """(np,) real [1]: +1 right-handed prism, -1 left-handed."""
    pair_nodes: wp.array | None
    """(nxp, 4) int32 [--]: end nodes i0, i1, j0, j1 of the two members of a checked pair (networks that are not columns; None for columns)."""
    pair_dref: wp.array | None
    """(nxp, 3) vec3 [m]: reference vectors X_i1 - X_i0, X_j1 - X_j0, X_j0 - X_i0 of the pair."""
    pair_kind: wp.array | None
    """(nxp,) int32 [--]: 0: two bars, 1: two cables (read on the host)."""


@dataclass
class Data:
    """Mutable state of a batch on the device; ``rk``: RK4 scratch u0, v0, acc_u, acc_v, us, vs, each
    (n, B) vec3."""

    u: wp.array
    """(n, B) vec3 [m]: displacement from the reference."""
    v: wp.array
    """(n, B) vec3 [m s-1]: velocity."""
    a: wp.array
    """(n, B) vec3 [m s-2]: acceleration."""
    u_prev: wp.array
    """(n, B) vec3 [m]: displacement at the start of the step (staged)."""
    imp: wp.array
    """(n, B) vec3 [--]: scratch: G^T lambda per node (staged)."""
    band: wp.array
    """(nc, bw+1, B) real [--]: banded Cholesky factor of G M^-1 G^T (staged)."""
    lam: wp.array
    """(nc, B) real [--]: multipliers / right-hand sides (staged)."""
    status: wp.array
    """(B,) int32 [--]: :class:`Status`."""
    fail_step: wp.array
    """(B,) int32 [--]: step at which the column froze, -1 if none."""
    iters: wp.array
    """(B,) int32 [--]: largest projection iteration count seen."""
    bar_err: wp.array
    """(B,) real [1]: max relative bar-length error after projection."""
    step: wp.array
    """(1,) int32 [--]: completed steps."""
    twist: wp.array
    """(np, B) real [rad]: prism twist at the last output, unwrapped."""
    twist_max: wp.array
    """(np, B) real [rad]: largest prism twist over the outputs."""
    twist_min: wp.array
    """(np, B) real [rad]: smallest prism twist over the outputs."""
    height_min: wp.array
    """(np, B) real [1]: smallest prism height ratio h/h0 over the outputs."""
    left_slot: wp.array
    """(nr, np, B) int32 [--]: first output slot of each FEASIBILITY_FLAGS reason, -1 never."""
    pair_distance_min: wp.array
    """(nxp, B) real [m]: smallest distance between the pair's member axes."""
    cross_side: wp.array
    """(nxp, B) int32 [--]: side of the pair's oriented axis distance, 0 when not facing."""
    pair_left_slot: wp.array
    """(nxp, B) int32 [--]: first output slot at which the pair crossed, -1 never."""
    rk: dict | None
