"""Heterogeneous T3 columns for the validation checks: per-prism prestrain, per-level mass and a
per-level initial velocity, as one :class:`~warp_tensegrity.scene.batch.NetworkBatch` that the engine
runs (:func:`warp_tensegrity.engine.run_batch`).

This is the engine side of the interface and diatomic checks (:mod:`.interface`, :mod:`.diatomic`);
their references never call it. It starts from ``scene.batch.column_batch``'s uniform column and sets
the per-prism and per-level fields itself (issue 34's profile API is built in parallel: this one
function is what will point at it). SI units.
"""

from __future__ import annotations

import numpy as np

from .closed_forms import rb_chain
from ..options import RunSettings
from ..scene import batch as scene_batch
from ..scene import columns as col

__all__ = ["graded_batch", "chain_at", "graded_settings", "checked", "EQUILIBRIUM_TOLERANCE"]

EQUILIBRIUM_TOLERANCE = 1e-10
"""Largest equilibrium residual of the built reference state, relative to the largest cross-cable tension."""


def _rigid_velocity(topo: col.ColumnTopology, axial: np.ndarray) -> np.ndarray:
    """(n_nodes, 3) velocity [m s-1] of a rigid-base column whose level l moves axially at ``axial[l]``:
    each level turns with it, as its bars require. A prism of height h and twist phi keeps its bar length
    (h^2 + 2 a^2 (1 - cos phi) = l^2), so dphi/dh = -h0/(a^2 sin phi); the top base of a right-handed
    prism sits at -phi from its bottom (scene.columns), so it turns by +h0/(a^2 sin phi) per metre of
    the prism's lengthening (the mirror for a left-handed one)."""
    cfg = topo.config
    rate = cfg.height / (cfg.radius**2 * np.sin(cfg.twist))
    turn = np.concatenate([[0.0], np.cumsum(cfg.prism_handedness() * rate * np.diff(axial))])
    x = topo.positions
    v = np.zeros_like(x)
    for lvl, nodes in enumerate(topo.level_nodes):
        v[nodes, 2] = axial[lvl]
        v[nodes, 0] = -turn[lvl] * x[nodes, 1]
        v[nodes, 1] = turn[lvl] * x[nodes, 0]
    return v


def graded_batch(config: col.ColumnConfig, prestrain_per_prism, level_mass, level_velocity=None,
                 base_rigidity: float = 1.0) -> scene_batch.NetworkBatch:
    """One column (B = 1) of ``config``'s prisms, prism m prestressed at ``prestrain_per_prism[m]`` [-], level
    l carrying ``level_mass[l]`` [kg] (a third on each node; the clamped level 0's mass is never used), and
    level l moving axially at ``level_velocity[l]`` [m s-1] at t = 0 (+z away from the clamp; rigid bases
    only: each level turns as its bars require; default at rest).

    Prism m's cross cables get the rest length s0/(1 + p_m); the base members of level l carry the
    superposed self-stress T_(l-1) f_top + T_l f_bottom (T_m = EA p_m, f the unit base forces of one prism,
    :func:`~warp_tensegrity.scene.columns.prism_self_stress`), so the reference state is in equilibrium;
    its residual is checked and stored in ``equilibrium_residual``."""
    topo = col.column_topology(config)
    n = config.n_prisms
    p = np.asarray(prestrain_per_prism, dtype=np.float64)
    m = np.asarray(level_mass, dtype=np.float64)
    if p.shape != (n,) or not np.all((p > 0) & (p < 1)):
        raise ValueError(f"prestrain_per_prism: shape {p.shape}, expected ({n},) values in (0, 1)")
    if m.shape != (n + 1,) or not np.all(m[1:] > 0):
        raise ValueError(f"level_mass: shape {m.shape}, expected ({n + 1},) positive values")
    if level_velocity is not None and base_rigidity < 1.0:
        raise ValueError(f"level_velocity needs rigid bases (base_rigidity = 1, got {base_rigidity!r})")
    batch = scene_batch.column_batch(config, {"prestrain": float(np.max(p)), "v0": 0.0, "base_rigidity": base_rigidity})
    X = topo.positions
    n_cross = len(topo.cross)
    EA = np.array(np.broadcast_to(batch.cable_EA, (1, len(batch.cables))))
    rest = np.array(np.broadcast_to(batch.cable_rest_length, (1, len(batch.cables))))
    ell = np.linalg.norm(X[batch.cables[:, 1]] - X[batch.cables[:, 0]], axis=1)
    rest[0, :n_cross] = ell[:n_cross] / (1.0 + np.repeat(p, 3))
    T = EA[0, :n_cross:3] * p  # (n,) cross-cable tension of each prism [N]
    F = np.zeros(3 * (n + 1))  # base member forces, level by level
    for k in range(n):
        sl, up = slice(3 * k, 3 * k + 3), slice(3 * k + 3, 3 * k + 6)
        _, _, bottom, top = col.prism_self_stress(X, topo.bars[sl], topo.cross[sl], topo.base[sl], topo.base[up])
        F[sl] += T[k] * bottom
        F[up] += T[k] * top
    base = slice(n_cross, None)
    ea_base = EA[0, base]
    rest[0, base] = np.where(ea_base > 0, ell[base] / (1.0 + F / np.where(ea_base > 0, ea_base, 1.0)), ell[base])
    batch.cable_rest_length = rest
    batch.node_mass = np.repeat(m / 3.0, 3)[None, :]
    if level_velocity is not None:
        w = np.asarray(level_velocity, dtype=np.float64)
        if w.shape != (n + 1,) or w[0] != 0.0:
            raise ValueError(f"level_velocity: shape {w.shape}, expected ({n + 1},) with the clamped level at 0")
        batch.velocity = _rigid_velocity(topo, w)[None]
    batch.params = {k: v[:1].copy() for k, v in batch.params.items()}
    batch.params["prestrain"] = np.array([float(np.mean(p))])
    residual = scene_batch.equilibrium_residuals(batch) / float(T.max())
    if residual.max() > EQUILIBRIUM_TOLERANCE:
        raise RuntimeError(f"graded column out of equilibrium: residual {residual.max():.3g} of the largest tension")
    batch.equilibrium_residual = residual
    return batch


def chain_at(config: col.ColumnConfig, prestrain: float):
    """The RB chain of ``config``'s prism at ``prestrain`` (:func:`.closed_forms.rb_chain`)."""
    return rb_chain(config.cable_EA, config.radius, config.height, config.unit_mass, prestrain)


def graded_settings(t_end: float, dt: float, device: str, output_interval: float | None = None) -> RunSettings:
    """The settings of the engine's fp64 run of a graded column (:func:`~warp_tensegrity.engine.run_batch`),
    its strain recorded. (The checks call run_batch themselves: importing the engine here would make
    the import chains one module longer than tests/test_layout.py allows.)"""
    return RunSettings(t_end=t_end, output_interval=dt if output_interval is None else output_interval, dt=dt,
                       truncate=False, device=device, precision="fp64", measure="none")


def checked(result):
    """``result``, refused where a column failed (a validation run must run clean)."""
    if int(np.max(result.status)) != 0:
        raise RuntimeError(f"validation run failed (status {result.status})")
    return result
