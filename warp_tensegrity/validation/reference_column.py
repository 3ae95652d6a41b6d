"""The paper's column rebuilt from its geometry and closed-form member laws, for the references.

The validation references (the FB modal sum of :mod:`.checks`, the Bloch cell of :mod:`.dispersion`)
build their network here, not with :mod:`warp_tensegrity.scene.columns`, so that an error in the
engine's scene builder (a member law, a rest length, a mass) shows up as a difference between the
engine and the reference instead of being shared by both. Float64 NumPy; SI units. Nothing here
calls the scene builder: only the :class:`~warp_tensegrity.scene.network.Network` container is shared.

The column (paper Sec. 3): level l = 0..N holds three nodes on a circle of radius a at z = l h0, node k
at the angle -2 pi k/3 - l hand phi (phi = 5 pi/6, hand = +1 right-handed); level 0 is clamped. Prism m
joins level m to m+1 with bars k -> k, cross cables k -> k+2 (right) or k+1 (left, the mirror image)
mod 3, and every level has the three base members k -> k+1.

**Self-stress in closed form.** At a bottom node of a regular minimal prism, with force densities
q_c (cross cable), q_b (bar) and q_l (each base member), the axial balance gives q_b = -q_c and the
horizontal one -3 q_l + q_b (cos phi - 1) + q_c (cos(2 pi/3 - phi) - 1) = 0; at phi = 5 pi/6 this is
q_l = q_c/sqrt 3. A base member of length sqrt3 a then carries F = T a/s0 per prism it belongs to
(T the cross-cable tension, s0 the cross-cable length): once on the end levels, twice in between.

**Member laws.** Cross cables: EA, tension-only, rest length s0/(1 + p) (so T = EA p). Base members
at base rigidity beta < 1: tension stiffness EA/(1 - beta), compression beta EA/(1 - beta) (the
paper's continuous FB -> RB law), rest length sqrt3 a/(1 + F (1 - beta)/EA); at beta = 1 rigid links.
Masses: m/3 on each node, the end levels m/6 (``end_base_mass = 'half'``) or m/3 ('full').
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..scene.network import Network

__all__ = ["ReferenceColumn", "reference_column", "base_member_force", "rigid_members_velocity", "end_twist_velocity"]

TWIST = 5.0 * math.pi / 6.0
"""The twist of the regular minimal prism [rad] (the only one with a self-stress)."""


def base_member_force(radius: float, height: float, tension: float) -> float:
    """Force [N] that one prism's self-stress puts in each of its base members, for cross-cable
    tension ``tension`` [N]: T a / s0 (module docstring)."""
    s0 = math.sqrt(height**2 + radius**2 * (2.0 - math.sqrt(3.0)))
    return tension * radius / s0


@dataclass
class ReferenceColumn:
    """A column of regular minimal T3 prisms built from the closed forms (module docstring)."""

    network: Network
    level_nodes: np.ndarray
    """(N + 1, 3) node indices of each level, level 0 clamped."""
    height: float
    """h0 [m]."""
    velocity: np.ndarray
    """(n_nodes, 3) initial velocity [m s-1] of the impact (zeros without one)."""


def reference_column(n_prisms: int, radius: float, height: float, cable_EA: float, unit_mass: float,
                     prestrain: float, base_rigidity: float, v0: float = 0.0, handedness: str = "right",
                     end_base_mass: str = "half", impact: str = "rigid_members") -> ReferenceColumn:
    """The column of ``n_prisms`` prisms of radius a = ``radius`` [m] and height h0 = ``height`` [m], cable
    EA = ``cable_EA`` [N], level mass m = ``unit_mass`` [kg], cross prestrain p, base rigidity beta, struck at
    ``v0`` [m s-1] with the ``impact`` convention ('rigid_members' or 'end_twist', see
    :func:`rigid_members_velocity` and :func:`end_twist_velocity`). One ``handedness``: 'right' or 'left'."""
    if handedness not in ("right", "left"):
        raise ValueError(f"handedness = {handedness!r}: the reference column takes 'right' or 'left'")
    if end_base_mass not in ("half", "full"):
        raise ValueError(f"end_base_mass = {end_base_mass!r}: choose 'half' or 'full'")
    n, a, h0 = int(n_prisms), float(radius), float(height)
    hand = 1 if handedness == "right" else -1
    lvl, k = np.divmod(np.arange(3 * (n + 1)), 3)
    ang = -2.0 * np.pi * k / 3.0 - lvl * hand * TWIST
    x = np.stack([a * np.cos(ang), a * np.sin(ang), lvl * h0], axis=1)
    level_nodes = np.arange(3 * (n + 1)).reshape(n + 1, 3)
    m, kk = np.divmod(np.arange(3 * n), 3)
    bars = np.stack([3 * m + kk, 3 * (m + 1) + kk], axis=1)
    cross = np.stack([3 * m + kk, 3 * (m + 1) + (kk + (2 if hand > 0 else 1)) % 3], axis=1)
    base = np.stack([3 * lvl + k, 3 * lvl + (k + 1) % 3], axis=1)
    s0 = math.sqrt(h0**2 + a**2 * (2.0 - math.sqrt(3.0)))
    T = cable_EA * prestrain
    cables, EA_t, EA_c, rest = [cross], [np.full(3 * n, cable_EA)], [np.zeros(3 * n)], [np.full(3 * n, s0 / (1 + prestrain))]
    links = np.zeros((0, 2), dtype=np.int64)
    if base_rigidity >= 1.0:
        links = base[lvl >= 1]  # the clamped level's links join clamped nodes
    else:
        ea = cable_EA / (1.0 - base_rigidity)
        share = np.where((lvl == 0) | (lvl == n), 1.0, 2.0)  # end levels belong to one prism
        F = share * base_member_force(a, h0, T)
        cables.append(base)
        EA_t.append(np.full(len(base), ea))
        EA_c.append(np.full(len(base), base_rigidity * ea))
        rest.append(math.sqrt(3.0) * a / (1.0 + F / ea))
    mass = np.full(n + 1, unit_mass / 3.0)
    if end_base_mass == "half":
        mass[[0, n]] /= 2.0
    net = Network(positions=x, node_mass=np.repeat(mass, 3), fixed=lvl == 0, bars=np.concatenate([bars, links]),
                  bar_mass=0.0, cables=np.concatenate(cables), cable_EA=np.concatenate(EA_t),
                  cable_rest_length=np.concatenate(rest), cable_EA_compression=np.concatenate(EA_c))
    if impact == "rigid_members":
        v = rigid_members_velocity(net, np.concatenate([bars, base[lvl >= 1]]), level_nodes[-1], v0)
    elif impact == "end_twist" and base_rigidity < 1.0:
        v = end_twist_velocity(x, bars[-3:], v0)
    else:
        raise ValueError(f"impact = {impact!r} at base_rigidity = {base_rigidity!r}: choose 'rigid_members', or "
                         "'end_twist' with base_rigidity < 1")
    return ReferenceColumn(net, level_nodes, h0, v)


def rigid_members_velocity(net: Network, rigid, struck, v0: float) -> np.ndarray:
    """The least-kinetic-energy velocity [m s-1] with v_z = -v0 on the ``struck`` nodes that keeps every
    member of ``rigid`` (node pairs) at its length: min v^T M v / 2 subject to (x_j - x_i).(v_j - v_i) = 0
    and the struck v_z, by its KKT system (dense, lumped masses)."""
    x, free = net.positions, ~net.fixed
    n = len(x)
    rows = []
    for i, j in rigid:
        r = np.zeros((n, 3))
        r[j] += x[j] - x[i]
        r[i] -= x[j] - x[i]
        rows.append(r.reshape(-1))
    for i in struck:
        r = np.zeros((n, 3))
        r[i, 2] = 1.0
        rows.append(r.reshape(-1))
    dof = np.flatnonzero(np.repeat(free, 3))
    A = np.array(rows)[:, dof]
    c = np.r_[np.zeros(len(rigid)), np.full(len(struck), -float(v0))]
    M = np.repeat(net.node_mass, 3)[dof]
    # KKT of a least-norm problem in the mass metric: v = M^-1 A^T lam, A M^-1 A^T lam = c (least squares:
    # A has dependent rows where rigid members close a triangle)
    lam = np.linalg.lstsq((A / M) @ A.T, c, rcond=None)[0]
    v = np.zeros(3 * n)
    v[dof] = (A.T @ lam) / M
    return v.reshape(n, 3)


def end_twist_velocity(x: np.ndarray, end_bars, v0: float) -> np.ndarray:
    """The paper's 'end_twist' impact [m s-1]: each struck node (the top end of one of ``end_bars``)
    moves with v_z = -v0 and the least horizontal velocity that keeps its bar's length, b_h b_z v0/|b_h|^2
    (b the bar vector, its lower node at rest); every other node at rest."""
    v = np.zeros_like(x)
    for i, j in end_bars:
        b = x[j] - x[i]
        v[j, :2] = b[:2] * b[2] * v0 / float(b[:2] @ b[:2])
        v[j, 2] = -v0
    return v
