"""The impact: the column's velocity just after the free end is struck (host, float64 NumPy).

``rigid_members`` (the default, ``docs/impact.md``): the velocity field of least kinetic energy
that gives every impacted node v_z = -v0 and is consistent with every member that can carry an
impulse treated as rigid at the instant of impact: the bars and all the base members (links of
rigid bases, elastic members of the other bases alike). Cross cables are left free.

    minimise  1/2 v^T M v   subject to   v_z(end nodes) = -v0,   J(bars, base members) v = 0,
    v = 0 on the clamped nodes.

This is the mass-weighted projection, with the end nodes' v_z pinned, onto the tangent space
of the constraints of all those members. It does not depend on the base rigidity beta, so the
initial state is the same for every beta; the RB (beta = 1) run starts exactly as the limit of
the stiff elastic bases (beta -> 1), and the FB (beta = 0) run as the limit beta -> 0. It is
linear in v0 and invariant under a uniform scale of the masses.

The paper's own conventions (``end_twist``, ``project``) stay in :mod:`.columns`; they treat
only the members that are rigid in the dynamics as rigid at impact, so their initial velocity
jumps at beta = 1.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np


def member_jacobian(positions: np.ndarray, members: np.ndarray, fixed: np.ndarray) -> np.ndarray:
    """J (n_members x 3 n_nodes) of g_k = |x_j - x_i|^2 / 2, clamped nodes' columns zeroed."""
    n = positions.shape[0]
    J = np.zeros((len(members), 3 * n))
    for k, (i, j) in enumerate(members):
        b = positions[j] - positions[i]
        J[k, 3 * j : 3 * j + 3] += b
        J[k, 3 * i : 3 * i + 3] -= b
    return J * np.repeat(~fixed, 3)[None, :]


def least_energy_impact(
    positions: np.ndarray,
    mass_matrix: np.ndarray,
    fixed: np.ndarray,
    members: np.ndarray,
    end_nodes: Sequence[int],
    v0: float,
) -> np.ndarray:
    """(n_nodes, 3) velocity [m s-1] of least kinetic energy with v_z = -v0 on ``end_nodes``,
    zero on ``fixed`` nodes and J(members) v = 0 (each member's length rate zero).

    ``mass_matrix`` is the (n_nodes, n_nodes) nodal mass matrix [kg] (lumped plus consistent
    bar inertia). Solved as the KKT system of the constrained least-squares problem with a
    pseudo-inverse, so redundant members (a self-stress among them) are allowed.
    """
    n = positions.shape[0]
    v = np.zeros(3 * n)
    pinned = np.zeros(3 * n, dtype=bool)
    pinned[[3 * int(i) + 2 for i in end_nodes]] = True
    v[pinned] = -v0
    if v0 == 0.0:
        return v.reshape(n, 3)
    free = np.repeat(~fixed, 3) & ~pinned
    J = member_jacobian(positions, members, fixed)
    M = np.kron(mass_matrix, np.eye(3))[np.ix_(free, free)]
    Jf = J[:, free]
    rhs = -J[:, pinned] @ v[pinned]
    # KKT: [M Jf^T; Jf 0] [v_f; lam] = [0; rhs]; the null-space solution is the least-energy one
    Minv_JT = np.linalg.solve(M, Jf.T)
    lam = np.linalg.pinv(Jf @ Minv_JT, rcond=1e-12) @ rhs
    v[free] = Minv_JT @ lam
    viol = np.abs(J @ v).max() / (abs(v0) * np.abs(J).max())
    if viol > 1e-9:
        raise ValueError(
            f"impact_admissibility='rigid_members': no velocity with v_z = -v0 on the end nodes keeps "
            f"every bar and base member rigid (residual {viol:.2e})"
        )
    return v.reshape(n, 3)


def kinematic_lock_strain(radius: float, height: float, twist: float) -> float:
    """Prism strain (h - h0)/h [1] at which a prism with rigid bars and rigid bases locks: its bases
    have turned to a relative twist of pi, the three bars meet on the axis, and dh/dphi = 0.

    With bar length l (l^2 = h0^2 + 2 a^2 (1 - cos phi0)), h(phi)^2 = l^2 - 2 a^2 (1 - cos phi) has
    its minimum h_min^2 = l^2 - 4 a^2 at phi = pi: the height is stationary in the twist, so a
    rigid-base pulse saturates at this strain. The constraints of bars and links keep full rank
    there (smallest over largest singular value 0.25, against 0.31 at the reference twist), and
    stiff elastic bases converge to rigid ones at the lock too (docs/impact.md).
    The paper's prism: -0.1005.
    """
    l2 = height**2 + 2.0 * radius**2 * (1.0 - np.cos(twist))
    h_min = np.sqrt(l2 - 4.0 * radius**2)
    return float((h_min - height) / h_min)
