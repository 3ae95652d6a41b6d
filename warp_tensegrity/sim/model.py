"""Device model and data: the arrays the kernels read. Their names, shapes, dtypes and units are
declared once, in :data:`warp_tensegrity.types.MODEL_FIELDS` and :data:`~warp_tensegrity.types.DATA_FIELDS`;
:class:`Model` and :class:`Data` are written out from them (:mod:`.fields`, by :mod:`.fields_gen`),
and :func:`build_model` fills them by name.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import warp as wp

from .. import types
from .common import array_type
from .fields import Data, Model
from ..scene.coupling import constraint_coupling, mass_entries  # noqa: F401 (the device model is built from them)

if TYPE_CHECKING:
    from ..scene.batch import NetworkBatch


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


MAX_PAIRS = 1 << 16
"""Most member pairs a network's feasibility record checks (the nearest, by reference midpoint distance)."""


def member_pairs(X: np.ndarray, bars: np.ndarray, cables: np.ndarray):
    """(pair_nodes (npr, 4), pair_dref (npr, 3, 3), pair_kind (npr,)): every two bars, and every two
    cables, that share no node (those that do cannot pass through each other), at most
    :data:`MAX_PAIRS` (the nearest at the reference)."""
    rows = []
    for kind, mem in enumerate((bars, cables)):
        i, j = np.triu_indices(len(mem), 1)
        a, b = mem[i], mem[j]
        apart = (a[:, :1] != b).all(axis=1) & (a[:, 1:] != b).all(axis=1)
        rows.append((np.concatenate([a[apart], b[apart]], axis=1), np.full(int(apart.sum()), kind)))
    nodes = np.concatenate([r[0] for r in rows]).reshape(-1, 4).astype(np.int32)
    kind = np.concatenate([r[1] for r in rows]).astype(np.int32)
    if len(nodes) > MAX_PAIRS:
        mid = 0.5 * (X[nodes[:, 0]] + X[nodes[:, 1]] - X[nodes[:, 2]] - X[nodes[:, 3]])
        keep = np.sort(np.argpartition(np.linalg.norm(mid, axis=1), MAX_PAIRS)[:MAX_PAIRS])
        nodes, kind = nodes[keep], kind[keep]
    dref = np.stack([X[nodes[:, 1]] - X[nodes[:, 0]], X[nodes[:, 3]] - X[nodes[:, 2]], X[nodes[:, 2]] - X[nodes[:, 0]]],
                    axis=1)
    return nodes, dref, kind


def host_arrays(batch: NetworkBatch, precision: str) -> tuple[dict, dict]:
    """(sizes, arrays): every Model array on the host, by its declared name; per-column parameters
    as the batch holds them, (Bp, k) (:func:`device_array` lays them out as declared, (k, Bp))."""
    npr = NP_REAL[precision]
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
    level_nodes = h0 = level_ref = prism_hand = pair_nodes = pair_dref = pair_kind = static_dz = None
    n_prisms = n_pairs = 0
    if batch.level_nodes is not None:
        level_nodes = batch.level_nodes.astype(np.int32)
        zl = X[batch.level_nodes, 2].mean(axis=1)
        h0 = np.diff(zl)
        n_prisms = len(zl) - 1
        XL = X[batch.level_nodes]  # (np+1, 3, 3)
        level_ref = (XL - XL.mean(axis=1, keepdims=True)).astype(npr)
        # right-handed: the top base turned clockwise seen from +z (scene.columns), a negative z-rotation
        prism_hand = -np.sign(np.cross(level_ref[:-1], level_ref[1:])[..., 2].sum(axis=1))
        static_dz = np.zeros((1, n_prisms)) if batch.static_dz is None else batch.static_dz
    else:
        pairs = member_pairs(X, cons, cab)
        n_pairs = len(pairs[0])
        if n_pairs:  # else None, as the optional fields of a network with no pair
            pair_nodes, pair_dref, pair_kind = pairs[0], pairs[1].astype(npr), pairs[2]
    sizes = dict(precision=precision, n_columns=batch.n_columns, n_nodes=X.shape[0], n_constraints=len(cons),
                 n_cables=len(cab), bandwidth=int(bw), n_prisms=n_prisms, n_pairs=n_pairs)
    arrays = dict(
        con_i=cons[:, 0].astype(np.int32), con_j=cons[:, 1].astype(np.int32), con_dref=dref_c, con_L=L_c,
        cpl_start=cpl_start, cpl_l=cpl_l, cpl_a=cpl_a, cpl_cross=cpl_cross, cpl_sign=cpl_sign,
        ncon_start=ncon_start, ncon_member=ncon_member,
        cab_i=cab[:, 0].astype(np.int32), cab_j=cab[:, 1].astype(np.int32), cab_dref=dref_e,
        node_start=node_start, node_member=node_member, node_other=node_other, node_dref=node_dref,
        partner=partner, mass_blocks=mass_blocks(partner_full),
        m_self=m_self, m_cross=m_cross, minv_self=minv_self, minv_cross=minv_cross,
        level_nodes=level_nodes, h0=h0, level_ref=level_ref, prism_hand=prism_hand,
        pair_nodes=pair_nodes, pair_dref=pair_dref, pair_kind=pair_kind, static_dz=static_dz,
        ext_force=np.zeros((1, X.shape[0], 3)) if batch.external_force is None else batch.external_force,
    )
    # the batch's own arrays, by their declared source (types.Field.source)
    arrays.update({f.name: getattr(batch, f.source) for f in types.MODEL_FIELDS if f.source})
    return sizes, arrays


def device_array(a: np.ndarray | None, field: types.Field, real, device) -> wp.array | None:
    """The declared array ``field`` on the device from its host values (None stays None when optional);
    a per-column parameter's (Bp, k) rows (vec3: (Bp, k, 3)) are transposed to (k, Bp), the column index fastest."""
    if a is None and field.optional:
        return None
    a = np.ascontiguousarray(np.swapaxes(np.asarray(a), 0, 1) if field.per_column else a)
    if a.ndim != field.ndim + (field.dtype == "vec3"):
        raise ValueError(f"{field.name}: host array of shape {a.shape} for the declared {field.shape} {field.dtype}")
    return wp.array(a, dtype=array_type(field.dtype, field.ndim, real).dtype, device=device)


def build_model(batch: NetworkBatch, precision: str, device) -> Model:
    """The Model of a batch: each declared array (:data:`warp_tensegrity.types.MODEL_FIELDS`) from
    its host values (:func:`host_arrays`), by name."""
    fields = types.MODEL_FIELDS
    sizes, host = host_arrays(batch, precision)
    if set(host) != {f.name for f in fields}:
        raise KeyError(f"host arrays {sorted(set(host) ^ {f.name for f in fields})} undeclared or not computed")
    real = REAL[precision]
    return Model(device=str(device), **sizes, **{f.name: device_array(host[f.name], f, real, device) for f in fields})


def make_data(model: Model, velocity: np.ndarray, method: str, fused: bool = False,
              displacement: np.ndarray | None = None) -> Data:
    """velocity: (B, n, 3) initial velocity [m s-1]; displacement: (B, n, 3) initial displacement from
    the reference [m] (a preloaded column's equilibrium), None: 0. With ``fused`` the staged kernels' scratch
    (u_prev, imp, band, lam) is not allocated (size-1 placeholders; the fused step keeps its own
    rows, :class:`warp_tensegrity.sim.block.step.FusedStep`)."""
    real = REAL[model.precision]
    vec = wp.types.vector(3, real)
    d = model.device
    n, B = model.n_nodes, model.n_columns
    nc = max(model.n_constraints, 1)
    z = lambda: wp.zeros((n, B), dtype=vec, device=d)  # noqa: E731
    common = dict(
        u=z() if displacement is None else _device_velocity(displacement, model, vec),
        v=_device_velocity(velocity, model, vec), a=z(),
        status=wp.zeros(B, dtype=wp.int32, device=d),
        fail_step=wp.full(B, -1, dtype=wp.int32, device=d),
        iters=wp.zeros(B, dtype=wp.int32, device=d),
        bar_err=wp.zeros(B, dtype=real, device=d),
        step=wp.zeros(1, dtype=wp.int32, device=d),
        **_feasibility_data(model, real),
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


def _feasibility_data(model: Model, real) -> dict:
    """The feasibility record's running extremes (types.DATA_FIELDS), each (items, B); (1, 1)
    placeholders where the batch has no prisms (or no member pairs). The kernels write them at step 0."""
    d, B, P, Q = model.device, model.n_columns, model.n_prisms, model.n_pairs
    arr = lambda k, dtype, fill, lead=(): wp.full((*lead, k, B) if k else (*lead, 1, 1), fill, dtype=dtype,  # noqa: E731
                                                 device=d)
    return dict(twist=arr(P, real, 0.0), twist_max=arr(P, real, 0.0), twist_min=arr(P, real, 0.0),
                height_min=arr(P, real, 0.0), left_slot=arr(P, wp.int32, -1, (len(types.FEASIBILITY_FLAGS),)),
                pair_distance_min=arr(Q, real, 0.0), cross_side=arr(Q, wp.int32, 0), pair_left_slot=arr(Q, wp.int32, -1))


def _device_velocity(velocity: np.ndarray, model: Model, vec) -> wp.array:
    """(B, n, 3) host -> (n, B) vec3 device (velocities and displacements)."""
    host = np.ascontiguousarray(np.transpose(velocity, (1, 0, 2))).astype(NP_REAL[model.precision])
    return wp.array(host, dtype=vec, device=model.device)
