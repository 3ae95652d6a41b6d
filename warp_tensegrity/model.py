"""Device model and data: the arrays the kernels read, with each shape stated once.

``B`` = columns in the batch; ``Bp`` = B or 1 for per-column parameters (1 when shared).
Batched arrays put the column index last (fastest) - see :mod:`warp_tensegrity.kernels`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import warp as wp

from .scene.coupling import constraint_coupling, mass_entries  # noqa: F401 (the device model is built from them)

if TYPE_CHECKING:
    from .scene.batch import NetworkBatch


REAL = {"fp32": wp.float32, "fp64": wp.float64}
NP_REAL = {"fp32": np.float32, "fp64": np.float64}


def mass_blocks(partner: np.ndarray) -> np.ndarray:
    """(nb, 2) blocks of M: a massive bar's two nodes (i < j), or a lone node and -1."""
    return np.array([(a, int(p) if p > a else -1) for a, p in enumerate(partner) if p < 0 or p > a],
                    dtype=np.int32).reshape(-1, 2)


def node_incidence(start: np.ndarray, member: np.ndarray, members: np.ndarray, dref: np.ndarray):
    """For each CSR entry t of node n: the member's other end, and its reference vector from n."""
    node = np.repeat(np.arange(len(start) - 1), np.diff(start))
    first = members[member, 0] == node
    other = np.where(first, members[member, 1], members[member, 0]).astype(np.int32)
    return other, np.where(first[:, None], dref[member], -dref[member])


def node_member_csr(n_nodes: int, members: np.ndarray):
    order = np.argsort(np.concatenate([members[:, 0], members[:, 1]]), kind="stable")
    mid = np.concatenate([np.arange(len(members)), np.arange(len(members))])[order]
    counts = np.bincount(members.ravel(), minlength=n_nodes)
    start = np.concatenate([[0], np.cumsum(counts)]).astype(np.int32)
    return start, mid.astype(np.int32)


@dataclass
class Model:
    """Topology and per-column parameters on the device. n = nodes, nc = constraints, ne = cables."""

    precision: str
    device: str
    n_columns: int
    n_nodes: int
    n_constraints: int
    n_cables: int
    bandwidth: int
    """Half-bandwidth of the constraint Gram matrix in the chosen ordering."""
    con_i: wp.array  # (nc,) int32
    con_j: wp.array  # (nc,) int32
    con_dref: wp.array  # (nc,) vec3: reference bar vector X_j - X_i [m]
    con_L: wp.array  # (nc,) bar length [m]
    con_active: wp.array  # (nc, Bp) 1 if the rigid member exists in the column
    cpl_start: wp.array  # (nc+1,) CSR of Gram-matrix coupling terms
    cpl_l: wp.array
    cpl_a: wp.array
    cpl_cross: wp.array
    cpl_sign: wp.array
    cab_i: wp.array  # (ne,) int32
    cab_j: wp.array
    cab_dref: wp.array  # (ne,) vec3 [m]
    cab_EA: wp.array  # (ne, Bp) [N]
    cab_EAc: wp.array  # (ne, Bp) [N]
    cab_L: wp.array  # (ne, Bp) rest length [m]
    node_start: wp.array  # (n+1,) CSR node -> cables
    node_member: wp.array
    node_other: wp.array  # (2 ne,) other end of node_member's cable
    node_dref: wp.array  # (2 ne,) vec3: reference vector from the node to node_other [m]
    ncon_start: wp.array  # (n+1,) CSR node -> rigid members
    ncon_member: wp.array
    partner: wp.array  # (n,) other end of the node's massive bar if both are free, else -1
    mass_blocks: wp.array  # (nb, 2) int32: blocks of M (massive bar i < j, or lone node and -1)
    m_self: wp.array  # (n, Bp) [kg]
    m_cross: wp.array  # (n, Bp) [kg]
    minv_self: wp.array  # (n, Bp) [kg-1], 0 at fixed nodes
    minv_cross: wp.array  # (n, Bp) [kg-1]
    level_nodes: wp.array | None  # (n_prisms+1, 3) column bases
    h0: wp.array | None  # (n_prisms,) reference prism heights [m]
    n_prisms: int


def _dev2(a: np.ndarray, dtype, device) -> wp.array:
    """(Bp, k) host -> (k, Bp) device (column index fastest)."""
    return wp.array(np.ascontiguousarray(np.asarray(a).T), dtype=dtype, device=device)


def build_model(batch: NetworkBatch, precision: str, device) -> Model:
    real = REAL[precision]
    npr = NP_REAL[precision]
    vec = wp.types.vector(3, real)
    X = batch.positions
    cons, cab = batch.constraints, batch.cables
    partner_full, partner, m_self, m_cross, minv_self, minv_cross = mass_entries(batch)
    cpl_start, cpl_l, cpl_a, cpl_cross, cpl_sign, bw = constraint_coupling(batch, partner_full)
    dref_c = (X[cons[:, 1]] - X[cons[:, 0]]).astype(npr) if len(cons) else np.zeros((0, 3), npr)
    # bar lengths consistent with the rounded reference vectors of this precision
    L_c = np.linalg.norm(dref_c.astype(np.float64), axis=1)
    dref_e = (X[cab[:, 1]] - X[cab[:, 0]]).astype(npr)
    node_start, node_member = node_member_csr(X.shape[0], cab)
    node_other, node_dref = node_incidence(node_start, node_member, cab, dref_e)
    ncon_start, ncon_member = node_member_csr(X.shape[0], cons.reshape(-1, 2))
    arr = lambda a, dt: wp.array(np.asarray(a), dtype=dt, device=device)  # noqa: E731
    level_nodes = h0 = None
    n_prisms = 0
    if batch.level_nodes is not None:
        level_nodes = arr(batch.level_nodes.astype(np.int32), wp.int32)
        zl = X[batch.level_nodes, 2].mean(axis=1)
        h0 = arr(np.diff(zl), real)
        n_prisms = len(zl) - 1
    return Model(
        precision=precision,
        device=str(device),
        n_columns=batch.n_columns,
        n_nodes=X.shape[0],
        n_constraints=len(cons),
        n_cables=len(cab),
        bandwidth=int(bw),
        con_i=arr(cons[:, 0].astype(np.int32), wp.int32),
        con_j=arr(cons[:, 1].astype(np.int32), wp.int32),
        con_dref=arr(dref_c, vec),
        con_L=arr(L_c, real),
        con_active=_dev2(batch.constraint_active, real, device),
        cpl_start=arr(cpl_start, wp.int32),
        cpl_l=arr(cpl_l, wp.int32),
        cpl_a=arr(cpl_a, wp.int32),
        cpl_cross=arr(cpl_cross, wp.int32),
        cpl_sign=arr(cpl_sign, real),
        cab_i=arr(cab[:, 0].astype(np.int32), wp.int32),
        cab_j=arr(cab[:, 1].astype(np.int32), wp.int32),
        cab_dref=arr(dref_e, vec),
        cab_EA=_dev2(batch.cable_EA, real, device),
        cab_EAc=_dev2(batch.cable_EA_compression, real, device),
        cab_L=_dev2(batch.cable_rest_length, real, device),
        node_start=arr(node_start, wp.int32),
        node_member=arr(node_member, wp.int32),
        node_other=arr(node_other, wp.int32),
        node_dref=arr(node_dref, vec),
        ncon_start=arr(ncon_start, wp.int32),
        ncon_member=arr(ncon_member, wp.int32),
        partner=arr(partner, wp.int32),
        mass_blocks=arr(mass_blocks(partner_full), wp.int32),
        m_self=_dev2(m_self, real, device),
        m_cross=_dev2(m_cross, real, device),
        minv_self=_dev2(minv_self, real, device),
        minv_cross=_dev2(minv_cross, real, device),
        level_nodes=level_nodes,
        h0=h0,
        n_prisms=n_prisms,
    )


@dataclass
class Data:
    """Mutable state of a batch on the device; shapes with n nodes, nc constraints, B columns."""

    u: wp.array  # (n, B) vec3 displacement from the reference [m]
    v: wp.array  # (n, B) vec3 velocity [m s-1]
    a: wp.array  # (n, B) vec3 acceleration [m s-2]
    u_prev: wp.array  # (n, B) vec3 displacement at the start of the step [m]
    imp: wp.array  # (n, B) vec3 scratch: G^T lambda per node
    band: wp.array  # (nc, bw+1, B) Cholesky factor of G M^-1 G^T
    lam: wp.array  # (nc, B) multipliers / right-hand sides
    status: wp.array  # (B,) int32 0 ok, 1 non-finite, 2 constraint failure
    fail_step: wp.array  # (B,) int32 step of failure, -1 if none
    iters: wp.array  # (B,) int32 largest projection iteration count seen
    bar_err: wp.array  # (B,) max relative bar-length error after projection
    step: wp.array  # (1,) int32 completed steps
    rk: dict | None  # RK4 scratch: u0, v0, acc_u, acc_v, us, vs, each (n, B) vec3


def make_data(model: Model, velocity: np.ndarray, method: str, fused: bool = False) -> Data:
    """velocity: (B, n, 3) initial velocity [m s-1]. With ``fused`` the staged kernels' scratch
    (u_prev, imp, band, lam) is not allocated (size-1 placeholders; the fused step keeps its own
    rows, :class:`warp_tensegrity.integrate.FusedStep`)."""
    real = REAL[model.precision]
    vec = wp.types.vector(3, real)
    d = model.device
    n, B = model.n_nodes, model.n_columns
    nc = max(model.n_constraints, 1)
    z = lambda: wp.zeros((n, B), dtype=vec, device=d)  # noqa: E731
    common = dict(
        u=z(), v=_device_velocity(velocity, model, vec), a=z(),
        status=wp.zeros(B, dtype=wp.int32, device=d),
        fail_step=wp.full(B, -1, dtype=wp.int32, device=d),
        iters=wp.zeros(B, dtype=wp.int32, device=d),
        bar_err=wp.zeros(B, dtype=real, device=d),
        step=wp.zeros(1, dtype=wp.int32, device=d),
    )
    if fused:
        one = wp.zeros((1, 1), dtype=vec, device=d)
        return Data(**common, u_prev=one, imp=one, band=wp.zeros((1, 1, 1), dtype=real, device=d),
                    lam=wp.zeros((1, 1), dtype=real, device=d), rk=None)
    rk = None
    if method == "rk4":
        rk = {k: z() for k in ("u0", "v0", "acc_u", "acc_v", "us", "vs")}
    return Data(**common, u_prev=z(), imp=z(), band=wp.zeros((nc, model.bandwidth + 1, B), dtype=real, device=d),
                lam=wp.zeros((nc, B), dtype=real, device=d), rk=rk)


def _device_velocity(velocity: np.ndarray, model: Model, vec) -> wp.array:
    """(B, n, 3) host -> (n, B) vec3 device."""
    host = np.ascontiguousarray(np.transpose(velocity, (1, 0, 2))).astype(NP_REAL[model.precision])
    return wp.array(host, dtype=vec, device=model.device)
