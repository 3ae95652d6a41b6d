"""Sparse linear algebra of long columns: the member Jacobian as a SciPy sparse matrix and the
three solves a scene needs (equilibrium residual, mass-weighted velocity projection, least-energy
impact), each O(n) in time and memory for a column (its members are level-ordered chains, so the
Gram matrix J M^-1 J^T is banded and its sparse LU has O(n) fill).

Up to :data:`DENSE_MAX_DOF` free degrees of freedom the scene keeps its dense NumPy solves (the
numbers of every column of up to 100 prisms stay bit for bit those of earlier releases); above,
the dense solves are O(n^3) in time and O(n^2) in memory (1.96 TiB at 100,000 prisms) and these
take over. Both agree to round-off (tests/scene/test_columns.py).

A leaf of the import graph: NumPy and SciPy only.
"""

from __future__ import annotations

import numpy as np

DENSE_MAX_DOF = 900
"""Free degrees of freedom (9 per prism of a column) up to which the dense solves are used."""


def use_dense(n_free_dof: int) -> bool:
    return int(n_free_dof) <= DENSE_MAX_DOF


def jacobian(positions: np.ndarray, members: np.ndarray, fixed: np.ndarray):
    """Sparse J (n_members x 3 n_nodes, CSR) of g_k = |x_j - x_i|^2 / 2, clamped nodes' columns
    zero: the same entries as the dense builders (:func:`~warp_tensegrity.scene.impact.member_jacobian`)."""
    from scipy import sparse

    members = np.asarray(members, dtype=np.int64).reshape(-1, 2)
    n = positions.shape[0]
    m = len(members)
    b = positions[members[:, 1]] - positions[members[:, 0]]  # (m, 3)
    free = ~np.asarray(fixed, dtype=bool)
    rows = np.repeat(np.arange(m), 6)
    cols = np.concatenate([3 * members[:, 1:2] + np.arange(3), 3 * members[:, 0:1] + np.arange(3)], axis=1).ravel()
    vals = np.concatenate([b, -b], axis=1).ravel()
    keep = free[cols // 3] & (vals != 0)
    return sparse.csr_matrix((vals[keep], (rows[keep], cols[keep])), shape=(m, 3 * n))


def _nonzero_rows(J):
    """J without its empty rows (members between clamped nodes carry no force)."""
    nnz = np.diff(J.indptr)
    return J[nnz > 0]


def _gram_solver(J, minv: np.ndarray | None = None):
    """A solve with G = J diag(minv) J^T (sparse LU; G is banded for a level-ordered column)."""
    from scipy.sparse.linalg import splu

    Jw = J if minv is None else J.multiply(minv[None, :]).tocsr()
    G = (Jw @ J.T).tocsc()
    try:
        lu = splu(G)
    except RuntimeError:  # exactly singular: redundant members
        raise ValueError("the members' constraints are redundant (singular Gram matrix)") from None
    return Jw, lu.solve


def lsq_residual(J, rhs: np.ndarray) -> np.ndarray:
    """max |rhs - J^T lam| over the rows of ``rhs`` (k,) or (k, B), lam the least-squares member
    forces (normal equations, one step of iterative refinement); ``J`` (m x k) sparse."""
    J = _nonzero_rows(J.tocsr())
    rhs = np.asarray(rhs, dtype=np.float64)
    if J.shape[0] == 0:
        return np.abs(rhs).max(axis=0) if rhs.size else np.zeros(rhs.shape[1:])
    _, solve = _gram_solver(J)
    lam = solve(J @ rhs)
    r = rhs - J.T @ lam
    lam = lam + solve(J @ r)
    return np.abs(rhs - J.T @ lam).max(axis=0)


def diagonal_mass(mass_rows: np.ndarray, mass_cols: np.ndarray, mass_vals: np.ndarray, n: int) -> np.ndarray | None:
    """The (n,) diagonal of an n x n mass matrix given as triplets, or None when it has
    off-diagonal terms (massive bars: then the dense solves are used)."""
    off = mass_rows != mass_cols
    if np.any(mass_vals[off] != 0):
        return None
    d = np.zeros(n)
    np.add.at(d, mass_rows[~off], mass_vals[~off])
    return d


def project_velocity(J, node_mass: np.ndarray, free: np.ndarray, target: np.ndarray) -> np.ndarray:
    """The velocity closest to ``target`` (3 n,) in the kinetic-energy norm with J v = 0, moving
    only the ``free`` dofs: v_f = t_f - M^-1 J_f^T lam, (J_f M^-1 J_f^T) lam = J_f t_f."""
    minv = 1.0 / np.repeat(node_mass, 3)[free]
    Jf = _nonzero_rows(J.tocsr()[:, np.flatnonzero(free)])
    v = target.copy()
    if Jf.shape[0]:
        Jw, solve = _gram_solver(Jf, minv)
        lam = solve(Jf @ target[free])
        v[free] -= Jw.T @ lam
    return v


def least_energy_impact(positions: np.ndarray, node_mass: np.ndarray, fixed: np.ndarray, members: np.ndarray,
                        end_nodes, v0: float) -> np.ndarray:
    """:func:`~warp_tensegrity.scene.impact.least_energy_impact` for lumped masses ``node_mass``
    (n_nodes,) [kg], by sparse solves: (n_nodes, 3) velocity [m s-1] of least kinetic energy with
    v_z = -v0 [m s-1] on ``end_nodes``, zero on ``fixed`` nodes, every member's length rate zero."""
    n = positions.shape[0]
    v = np.zeros(3 * n)
    pinned = np.zeros(3 * n, dtype=bool)
    pinned[[3 * int(i) + 2 for i in end_nodes]] = True
    v[pinned] = -v0
    if v0 == 0.0:
        return v.reshape(n, 3)
    J = jacobian(positions, members, fixed)
    try:
        v = least_energy_velocity(J, node_mass, np.repeat(~np.asarray(fixed, bool), 3) & ~pinned, v)
        viol = np.abs(J @ v).max() / (abs(v0) * abs(J).max())
    except ValueError:  # singular: redundant members
        viol = np.inf
    if viol > 1e-9:
        raise ValueError(
            f"impact_admissibility='rigid_members': no velocity with v_z = -v0 on the end nodes keeps "
            f"every bar and base member rigid (residual {viol:.2e})"
        )
    return v.reshape(n, 3)


def least_energy_velocity(J, node_mass: np.ndarray, free: np.ndarray, v: np.ndarray) -> np.ndarray:
    """v (3 n,) with its ``free`` dofs set to the least kinetic energy that satisfies J v = 0 given
    the other dofs of ``v`` (pinned or clamped): v_f = M^-1 J_f^T lam, (J_f M^-1 J_f^T) lam = -J_p v_p."""
    J = J.tocsr()
    minv = 1.0 / np.repeat(node_mass, 3)[free]
    rhs = -(J[:, np.flatnonzero(~free)] @ v[~free])
    nz = np.diff(J[:, np.flatnonzero(free)].indptr) > 0
    Jf = J[:, np.flatnonzero(free)][nz]
    out = v.copy()
    if Jf.shape[0]:
        Jw, solve = _gram_solver(Jf, minv)
        out[free] = Jw.T @ solve(rhs[nz])
    return out
