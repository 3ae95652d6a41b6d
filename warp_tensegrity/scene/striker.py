"""The striker (scene ``impact = 'striker'``, issue 34): a rigid mass M that hits the free end at v0 and
stays in unilateral contact with it until the column pushes it back (host, float64 NumPy).

Model (docs/impact.md, "A striker"). The striker is a frictionless rigid flat face that moves along z
only. It touches the end base on the **mean height of its three nodes**:

    c = s - z_end >= 0,    z_end = (z_1 + z_2 + z_3) / 3,

s the face's height, both as displacements from the reference end base. The contact force F >= 0
pushes the striker up and each end node down by F/3. One scalar row with a constant gradient:
with rigid bars it is well posed for both base classes (the end base always keeps an axial motion,
so the row is independent of the members' rows and the joint system stays regular). A face on each
node would be three unilateral rows whose active set changes with the end base's tilt (one, two or
three nodes touching), and on a rigid end base their forces would be fixed by the tilt alone. Under
the column's threefold symmetry the three nodes stay level, so the face on the mean height is the
flat face there.

The blow at t = 0. The striker arrives at v0 and the column is at rest. During the blow every bar
and base member is rigid (the ``rigid_members`` convention, :mod:`.impact`); the blow is plastic
(the face and the end base leave together). The column's velocity after the blow is then the
``rigid_members`` field at the common speed V1; that field is the response to an impulse spread
equally over the three end nodes, and its kinetic energy at unit end speed is m_end / 2, the end's
effective mass m_end = sum_i m_i |u_i|^2 (u the field at v0 = 1). Momentum along the blow:

    M v0 = (M + m_end) V1,    V1 = v0 M / (M + m_end),

and the blow dissipates (1/2) v0^2 M m_end / (M + m_end). For a rigid-base column m_end is the
chain's end mass m_eff / 2 (:mod:`warp_tensegrity.validation.closed_forms`).
"""

from __future__ import annotations

import numpy as np

IMPACTS = ("velocity", "striker")
"""Values of the scene's ``impact`` option."""


def end_mass(unit_velocity: np.ndarray, node_mass: np.ndarray) -> np.ndarray:
    """(B or 1,) effective mass m_end [kg] of the struck end: sum_i m_i |u_i|^2 of the ``rigid_members``
    field ``unit_velocity`` (n_nodes, 3) at v0 = 1 m/s, for lumped ``node_mass`` (B or 1, n_nodes)."""
    return np.asarray(node_mass, dtype=np.float64) @ (np.asarray(unit_velocity, dtype=np.float64) ** 2).sum(axis=1)


def blow_speed(v0, striker_mass, m_end) -> np.ndarray:
    """Common speed V1 = v0 M / (M + m_end) [m s-1] of striker and end base after the plastic blow."""
    M = np.asarray(striker_mass, dtype=np.float64)
    return np.asarray(v0, dtype=np.float64) * M / (M + np.asarray(m_end, dtype=np.float64))


def attach_striker(batch, striker_mass: np.ndarray, unit_velocity: np.ndarray) -> None:
    """Give a column batch (:func:`~.batch.column_batch`) its striker of mass ``striker_mass`` [kg] per
    column (> 0): the column's velocity after the blow (the ``rigid_members`` field ``unit_velocity`` at
    v0 = 1, taken at V1 instead of v0) and the striker's own V1. (The scene and the batch have refused
    what the model does not cover: ``ColumnConfig._check_striker``, ``column_batch``.)"""
    v0 = batch.params["v0"]
    B = batch.n_columns
    m_end = np.broadcast_to(end_mass(unit_velocity, batch.node_mass), (B,))
    M = np.broadcast_to(np.asarray(striker_mass, dtype=np.float64), (B,)).copy()
    V1 = blow_speed(v0, M, m_end)
    with np.errstate(invalid="ignore", divide="ignore"):
        scale = np.where(v0 > 0, V1 / np.where(v0 > 0, v0, 1.0), 0.0)
    batch.velocity = batch.velocity * scale[:, None, None]
    batch.striker_mass = M
    batch.striker_velocity = -V1  # along -z
    batch.striker_end_mass = m_end.copy()
    batch.striker_nodes = np.asarray(batch.level_nodes[-1], dtype=np.int64).copy()
