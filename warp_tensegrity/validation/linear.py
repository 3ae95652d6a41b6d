"""Linearised (small-amplitude) analysis of a tensegrity network about its reference state.

Job: natural frequencies and mode shapes of the constrained system (rigid bars), the largest
frequency (explicit step limits), zero-stiffness mechanisms, the axial stiffness of the prisms
of a column and the long-wave sound speeds of a column. Float64 NumPy on the host; the bar
kinematics and mass matrix come from :class:`.constrained.ConstrainedNetwork`.
SI units: omega [rad s-1], stiffness [N m-1], torsional stiffness [N m rad-1], speeds [m s-1].

Theory. With bar constraints ``g_k = (|b_k|^2 - L_k^2)/2`` and multipliers ``lam_k`` (force
densities, tension positive: ``M a = f - G^T lam``), small motions about an equilibrium
``f = G^T lam`` obey, in the tangent space ``u = Z y`` (``G Z = 0``)::

    Z^T M Z y'' + Z^T K_t Z y = 0,   K_t = Hess(V) + sum_k lam_k Hess(g_k).

* cable (or base member) of branch stiffness k and axial force T at length s, unit vector e:
  Hess(V) block ``k e e^T + (T/s)(I - e e^T)`` on ``[[+,-],[-,+]]``;
* bar k: ``Hess(g_k) = [[I, -I], [-I, I]]``, so it adds ``lam_k [[I, -I], [-I, I]]``. On the
  tangent space only its transverse part acts: ``(F/l)(I - e e^T)`` with bar tension
  ``F = lam_k l`` (compressed bars soften, F < 0).

The bar multipliers are the least-squares solution of ``G^T lam = f`` at the reference state.
The reduced problem is solved as the symmetric eigenproblem of ``M_r^-1/2 K_r M_r^-1/2``.

At zero prestrain every cable sits exactly at its rest length, where the tension-only law has a
kink: the linear model is then one-sided. ``rest_branch="tension"`` (default) uses the loading
(taut) stiffness EA/L there, ``"compression"`` the unloading one (0 for true cables).

Columns (T3 prisms, right-handed) couple axial and twist motion. In the long-wave limit each
unit is a 2-DOF (height change, twist) cell with a 2x2 stiffness and mass diag(m, I), I the
polar inertia of a base; the column carries two axial-torsional acoustic branches. With rigid
bases (RB) the bars lock twist to height, leaving one. The branch that an axial impact mostly
excites at low amplitude is the soft one (prestress-stiffened mechanism); its speed is far below
``h0 sqrt(K_axial/m)`` because most of its kinetic energy is base rotation.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..scene.network import Network
from .constrained import ConstrainedNetwork

__all__ = [
    "equilibrium_multipliers",
    "tangent_stiffness",
    "constraint_basis",
    "ModalResult",
    "modal_analysis",
    "modes",
    "omega_max",
    "count_zero_modes",
    "column_cell_compliance",
    "axial_stiffness_per_prism",
    "LongWaveSpeed",
    "long_wave_speed",
]


def _positions(net: Network, positions):
    return np.array(net.positions if positions is None else positions, float)


# ====================================================================== general networks
def equilibrium_multipliers(network: Network, positions: np.ndarray | None = None,
                            _rs: ConstrainedNetwork | None = None):
    """Bar force densities lam [N m-1] (tension positive; bar force = lam * length) balancing the
    cable forces at the free nodes in the least-squares sense, and the max residual force [N]."""
    rs = _rs or ConstrainedNetwork(network)
    x = _positions(network, positions)
    f = rs.to_q(rs.nodal_forces(x))
    G = rs.jacobian(x)
    if G.shape[0] == 0:
        return np.zeros(0), float(np.abs(f).max(initial=0.0))
    lam, *_ = np.linalg.lstsq(G.T, f, rcond=None)
    return lam, float(np.abs(f - G.T @ lam).max(initial=0.0))


def tangent_stiffness(network: Network, positions: np.ndarray | None = None,
                      rest_branch: str = "tension", _rs: ConstrainedNetwork | None = None) -> np.ndarray:
    """K_t [N m-1] on the free coordinates (3 n_free x 3 n_free): cables plus bar geometric terms."""
    if rest_branch not in ("tension", "compression"):
        raise ValueError(f"rest_branch = {rest_branch!r}; choose 'tension' or 'compression'")
    rs = _rs or ConstrainedNetwork(network)
    x = _positions(network, positions)
    K = np.zeros((rs.ndof, rs.ndof))
    I3 = np.eye(3)

    def add(i, j, blk):  # blk on [[+, -], [-, +]] for the free ends of member (i, j)
        ends = [(rs._slot[i], 1.0), (rs._slot[j], -1.0)]
        for sa, ga in ends:
            for sb, gb in ends:
                if sa >= 0 and sb >= 0:
                    K[3 * sa : 3 * sa + 3, 3 * sb : 3 * sb + 3] += ga * gb * blk

    # cables: branch stiffness; a cable exactly at rest length goes on the chosen branch
    d = x[rs.cables[:, 1]] - x[rs.cables[:, 0]]
    s = np.linalg.norm(d, axis=1)
    L = rs.L_cable
    at_rest = np.abs(s - L) <= 1e-12 * L
    taut = np.where(at_rest, rest_branch == "tension", s > L)
    k = np.where(taut, rs.k_t, rs.k_c)
    T = np.where(at_rest, 0.0, k * (s - L))
    for c, (i, j) in enumerate(rs.cables):
        e = d[c] / s[c]
        ee = np.outer(e, e)
        add(i, j, k[c] * ee + T[c] / s[c] * (I3 - ee))
    # bars: lam_k * Hess(g_k)
    lam, _ = equilibrium_multipliers(network, x, rs)
    for b, (i, j) in enumerate(rs.bars):
        add(i, j, lam[b] * I3)
    return 0.5 * (K + K.T)


def constraint_basis(network: Network, positions: np.ndarray | None = None, rtol: float = 1e-10,
                     _rs: ConstrainedNetwork | None = None) -> np.ndarray:
    """Orthonormal basis Z (3 n_free x n_modes) of null(G): the admissible displacements."""
    rs = _rs or ConstrainedNetwork(network)
    G = rs.jacobian(_positions(network, positions))
    if G.shape[0] == 0:
        return np.eye(rs.ndof)
    _, sv, vt = np.linalg.svd(G)
    rank = int(np.sum(sv > rtol * sv[0]))
    return vt[rank:].T


@dataclass
class ModalResult:
    """Small-oscillation modes about the reference state."""

    omega2: np.ndarray
    """(n_modes,) eigenvalues omega^2 [rad2 s-2], ascending; negative = unstable."""
    shapes: np.ndarray
    """(n_modes, n_nodes, 3) mode shapes [m kg^-1/2], mass-normalised (u^T M u = 1)."""
    n_free_dof: int
    """3 x number of free nodes."""
    n_constraints: int
    """Rank of the bar Jacobian G."""
    equilibrium_residual: float
    """Max unbalanced nodal force at the reference state [N] (bars at least-squares forces)."""

    @property
    def omega(self) -> np.ndarray:
        """Signed frequencies [rad s-1]: sqrt(omega^2), or -sqrt(-omega^2) for unstable modes."""
        return np.sign(self.omega2) * np.sqrt(np.abs(self.omega2))


def modal_analysis(network: Network, positions: np.ndarray | None = None,
                   rest_branch: str = "tension") -> ModalResult:
    """Generalised eigenproblem K_r y = omega^2 M_r y on the constraint tangent space."""
    rs = ConstrainedNetwork(network)
    x = _positions(network, positions)
    Z = constraint_basis(network, x, _rs=rs)
    K = tangent_stiffness(network, x, rest_branch, _rs=rs)
    Kr = Z.T @ K @ Z
    Mr = Z.T @ rs.M @ Z
    mu, U = np.linalg.eigh(0.5 * (Mr + Mr.T))
    Mih = (U / np.sqrt(mu)) @ U.T  # M_r^-1/2
    H = Mih @ Kr @ Mih
    w2, Y = np.linalg.eigh(0.5 * (H + H.T))
    U_full = Z @ (Mih @ Y)  # (3 n_free, n_modes), u^T M u = 1
    shapes = np.zeros((len(w2), rs.n_nodes, 3))
    shapes[:, rs.free_nodes, :] = U_full.T.reshape(len(w2), rs.n_free, 3)
    _, res = equilibrium_multipliers(network, x, rs)
    return ModalResult(w2, shapes, rs.ndof, rs.ndof - Z.shape[1], res)


def modes(network: Network, positions: np.ndarray | None = None, rest_branch: str = "tension"):
    """(omega [rad s-1] ascending and signed as :attr:`ModalResult.omega`, shapes (n_modes, n_nodes, 3))."""
    r = modal_analysis(network, positions, rest_branch)
    return r.omega, r.shapes


def omega_max(network: Network, positions: np.ndarray | None = None, rest_branch: str = "tension") -> float:
    """Largest natural frequency [rad s-1] (explicit RK4 is stable for omega_max dt < 2 sqrt 2)."""
    return float(modal_analysis(network, positions, rest_branch).omega.max())


def count_zero_modes(network: Network, rtol: float = 1e-8, positions: np.ndarray | None = None,
                     rest_branch: str = "tension") -> int:
    """Number of modes with |omega^2| <= rtol * max |omega^2| (mechanisms and rigid-body modes).

    Round-off puts true zero modes near 1e-16 relative; the first bending mode of a long column
    is genuinely small (about 1e-7 relative for 50 paper prisms), so keep rtol well below it."""
    w2 = modal_analysis(network, positions, rest_branch).omega2
    return int(np.sum(np.abs(w2) <= rtol * np.abs(w2).max()))


# ====================================================================== columns
def _level_motion(topo, x: np.ndarray, u: np.ndarray):
    """Per level: mean axial displacement [m] and mean small rotation about the level axis [rad]."""
    ln = topo.level_nodes
    uz = u[ln, 2].mean(axis=1)
    c = x[ln, :2] - x[ln, :2].mean(axis=1, keepdims=True)
    cross = c[..., 0] * u[ln, 1] - c[..., 1] * u[ln, 0]
    th = (cross / np.sum(c**2, axis=2)).mean(axis=1)
    return uz, th


def _column_static(scene, axial_force: float, torque: float, rest_branch: str = "tension"):
    """Linear static response of a clamped column to an axial force [N] (+z, tension positive)
    and a torque about +z [N m] on its free-end base, equal shares on its three nodes (the torque
    as tangential forces, so the work-conjugate rotation is the mean node rotation).

    Returns (dh, dtheta, singular): per-prism height changes [m] and relative twists [rad], and
    True where the load drives a zero-stiffness mechanism (then dh, dtheta are meaningless).
    """
    net, topo = scene.network, scene.topology
    rs = ConstrainedNetwork(net)
    x = np.array(net.positions, float)
    Z = constraint_basis(net, x, _rs=rs)
    Kr = Z.T @ tangent_stiffness(net, x, rest_branch, _rs=rs) @ Z
    f = np.zeros((rs.n_nodes, 3))
    top = topo.level_nodes[-1]
    f[top, 2] = axial_force / 3.0
    r = x[top, :2] - x[top, :2].mean(axis=0)
    rad2 = np.sum(r**2, axis=1)
    f[top, 0] += -torque / 3.0 * r[:, 1] / rad2
    f[top, 1] += torque / 3.0 * r[:, 0] / rad2
    rhs = Z.T @ rs.to_q(f)
    y, *_ = np.linalg.lstsq(Kr, rhs, rcond=1e-12)
    singular = np.linalg.norm(Kr @ y - rhs) > 1e-8 * np.linalg.norm(rhs)
    uz, th = _level_motion(topo, x, rs._to_v(Z @ y))
    return np.diff(uz), np.diff(th), bool(singular)


def column_cell_compliance(scene, prism: int | None = None, rest_branch: str = "tension"):
    """2x2 compliance C of one prism in the column, (dh, dtheta) per (axial force, torque):
    units [[m/N, m/(N m)], [rad/N, rad/(N m)]]. Every prism carries the end load, so C is read
    from prism ``prism`` (default: the middle one, away from the clamped base). Returns None when
    the end loads drive a zero-stiffness mechanism (unstressed prisms)."""
    dhF, dtF, sF = _column_static(scene, 1.0, 0.0, rest_branch)
    dhQ, dtQ, sQ = _column_static(scene, 0.0, 1.0, rest_branch)
    if sF or sQ:
        return None
    m = len(dhF) // 2 if prism is None else prism
    C = np.array([[dhF[m], dhQ[m]], [dtF[m], dtQ[m]]])
    return 0.5 * (C + C.T)  # Maxwell-Betti symmetric; average out round-off


def axial_stiffness_per_prism(scene, prism: int | None = None, rest_branch: str = "tension") -> float:
    """Linear axial stiffness of one prism [N m-1] inside the column, at zero torque (free twist).

    Equal and opposite axial forces on the end bases (the clamp reacts) load every prism with F
    and no torque; the stiffness is F / |dh| of prism ``prism`` (default: the middle one).
    Returns 0.0 when the load drives a zero-stiffness mechanism (the 'sonic vacuum')."""
    dh, _, singular = _column_static(scene, -1.0, 0.0, rest_branch)
    if singular:
        return 0.0
    m = len(dh) // 2 if prism is None else prism
    return float(1.0 / abs(dh[m]))


@dataclass
class LongWaveSpeed:
    """Long axial-torsional wave speeds of a column [m s-1] and what they come from."""

    c0: float
    """Headline: speed of the lowest axial(-torsional) branch from the column's modes (0 if that
    branch is a zero-stiffness mechanism)."""
    c_branches_modal: np.ndarray
    """(n_branches,) omega_1 / k_1 of each branch's lowest mode, soft first (discrete chain k_1)."""
    c_branches_homogenised: np.ndarray
    """(n_branches,) branch speeds of the homogenised 2-DOF cell, h0 sqrt(eig(M^-1 K_cell)), soft
    first; a rigid direction (RB: twist locked to height) is dropped. Empty if unstressed."""
    c0_continuum_k: float
    """omega_1 / k_1 of the soft branch with the continuum k_1 = pi / (2 L_col)."""
    c0_point_mass: float
    """h0 sqrt(K_axial / m_unit): ignores the rotary inertia of the twisting bases."""
    c0_zero_torque: float
    """h0 sqrt(K_axial / (m_unit + I_unit kappa^2)), kappa = dtheta/dh at zero torque."""
    k_axial: float
    """Axial stiffness per prism at zero torque [N m-1]."""
    kappa: float
    """Twist per height change at zero torque [rad m-1]."""
    m_unit: float
    """Mass of one level [kg]."""
    I_unit: float
    """Polar moment of inertia of one level about the axis [kg m2]."""
    branch_omegas: list
    """Per branch (soft first), the lowest few mode frequencies found [rad s-1]."""
    branch_speeds: list
    """Per branch, omega_n h0 / (2 sin(k_n h0 / 2)) with the discrete fixed-free k_n [m s-1]:
    roughly constant when the branch is acoustic (non-dispersive after the lattice correction)."""


def long_wave_speed(scene, n_per_branch: int = 3, at_fraction: float = 0.5,
                    rest_branch: str = "tension") -> LongWaveSpeed:
    """Long-wave speeds of a clamped-free column, from its modes and from statics.

    Modes are called axial-torsional when at least ``at_fraction`` of their kinetic energy is in
    rigid axial and twist motion of the levels. They are split into the cell's branches by their
    (dh, dtheta) direction (M-orthogonal eigenvectors of the 2x2 cell problem); without prestress
    the soft branch is the mechanism (speed 0) and every found mode belongs to the stiff branch.
    A fixed-free chain of N cells with a full end mass has k_n h0 = (2n-1) pi / (2N+1) (2N for a
    half end mass); the lattice correction omega = 2 sqrt(K/m) sin(k h0/2) is divided out.
    """
    net, topo = scene.network, scene.topology
    cfg = topo.config
    N, h0 = cfg.n_prisms, cfg.height
    x = np.array(net.positions, float)
    lvl = topo.level_nodes[1]  # an interior level
    m_unit = float(net.node_mass[lvl].sum())
    c = x[lvl, :2] - x[lvl, :2].mean(axis=0)
    I_unit = float(np.sum(net.node_mass[lvl] * np.sum(c**2, axis=1)))
    Mc = np.diag([m_unit, I_unit])
    Mh = np.sqrt(Mc)

    # --- homogenised cell from statics
    C = column_cell_compliance(scene, rest_branch=rest_branch)
    if C is not None:
        mu, Wv = np.linalg.eigh(Mh @ C @ Mh)  # mu = (k/omega)^2 / h0^2 per branch
        keep = mu > 1e-9 * mu.max()  # mu ~ 0: rigid direction (RB)
        order = np.argsort(-mu[keep])  # soft (largest compliance) first
        mu, Wv = mu[keep][order], Wv[:, keep][:, order]
        c_hom = h0 / np.sqrt(mu)
        k_ax = 1.0 / abs(C[0, 0])
        kappa = C[1, 0] / C[0, 0]
        c_zt = h0 * np.sqrt(k_ax / (m_unit + I_unit * kappa**2))
    else:
        mu, Wv, c_hom = np.zeros(0), np.zeros((2, 0)), np.zeros(0)
        k_ax, kappa, c_zt = 0.0, np.nan, 0.0

    # --- modes: axial-torsional ones, sorted into branches
    r = modal_analysis(net, rest_branch=rest_branch)
    n_br = max(len(c_hom), 1)
    found = [[] for _ in range(n_br)]
    scale = np.max(np.abs(r.omega2))
    for w2, u in zip(r.omega2, r.shapes):
        if w2 <= 1e-8 * scale:
            continue
        uz, th = _level_motion(topo, x, u)
        q = np.stack([uz[1:], th[1:]])  # (2, levels), clamped level dropped
        if float(np.sum(q * (Mc @ q))) < at_fraction:  # u^T M u = 1
            continue
        br = 0 if len(c_hom) == 0 else int(np.argmax(np.sum((Wv.T @ Mh @ q) ** 2, axis=1)))
        if len(found[br]) < n_per_branch:
            found[br].append(np.sqrt(w2))
        if all(len(f) >= n_per_branch for f in found):
            break
    denom = 2 * N + 1 if cfg.end_base_mass == "full" else 2 * N
    speeds = []
    for f in found:
        n = np.arange(1, len(f) + 1)
        kh = (2 * n - 1) * np.pi / denom
        speeds.append(np.array(f) * h0 / (2.0 * np.sin(kh / 2.0)))
    c_modal = np.array([s[0] if len(s) else np.nan for s in speeds])
    if C is None:  # the soft branch is the zero-stiffness mechanism
        c_modal = np.concatenate([[0.0], c_modal]) if len(found[0]) else np.array([0.0])
        speeds = [np.zeros(0)] + speeds if len(found[0]) else [np.zeros(0)]
        found = [[]] + found if len(found[0]) else [[]]
    c0 = float(c_modal[0])
    w_soft = found[0][0] if found[0] else 0.0
    return LongWaveSpeed(
        c0=c0,
        c_branches_modal=c_modal,
        c_branches_homogenised=c_hom,
        c0_continuum_k=float(w_soft / (np.pi / (2.0 * N * h0))),
        c0_point_mass=float(h0 * np.sqrt(k_ax / m_unit)),
        c0_zero_torque=float(c_zt),
        k_axial=float(k_ax),
        kappa=float(kappa),
        m_unit=m_unit,
        I_unit=I_unit,
        branch_omegas=[np.array(f) for f in found],
        branch_speeds=speeds,
    )
