"""The interface check (issue 34 item 5) and the graded columns it runs (validation.hetero)."""

from __future__ import annotations

import numpy as np
import pytest

from warp_tensegrity import ColumnConfig
from warp_tensegrity.scene.batch import column_batch, equilibrium_residuals
from warp_tensegrity.validation import report
from warp_tensegrity.validation.checks import chain_of
from warp_tensegrity.validation.hetero import graded_batch
from warp_tensegrity.validation.interface import check_interface, discrete_coefficients, interface_theory


def _half_ends(n, m=0.0249):
    mass = np.full(n + 1, m)
    mass[[0, n]] = 0.5 * m
    return mass


@pytest.mark.parametrize("beta", [0.0, 0.5, 1.0])
def test_a_uniform_graded_column_is_the_scene_builders(beta):
    """Uniform profiles give column_batch's column: rest lengths and masses equal, the RB impact's velocity
    to round-off (its level velocity: the struck level at -v0)."""
    cfg = ColumnConfig(n_prisms=5)
    ref = column_batch(cfg, {"prestrain": 0.003, "v0": 1e-3, "base_rigidity": beta})
    w = np.zeros(6)
    w[-1] = -1e-3
    b = graded_batch(cfg, np.full(5, 0.003), _half_ends(5), w if beta == 1.0 else None, base_rigidity=beta)
    np.testing.assert_allclose(np.broadcast_to(b.cable_rest_length, ref.cable_rest_length.shape),
                               ref.cable_rest_length, rtol=1e-14, atol=0)
    np.testing.assert_array_equal(np.broadcast_to(b.node_mass, ref.node_mass.shape), ref.node_mass)
    if beta == 1.0:
        np.testing.assert_allclose(b.velocity, ref.velocity, rtol=0, atol=1e-15)


@pytest.mark.parametrize("beta", [0.0, 1.0])
@pytest.mark.parametrize("hand", ["right", "RLLRRL"])
def test_graded_column_is_in_equilibrium_and_its_velocity_admissible(beta, hand):
    """Per-prism prestrain: the superposed self-stress balances every free node (FB: the base members carry
    it), and the level velocities keep every bar and link at its length."""
    cfg = ColumnConfig(n_prisms=6, handedness=hand)
    p = np.array([0.001, 0.002, 0.004, 0.004, 0.0005, 0.003])
    w = None if beta < 1 else -np.linspace(0.0, 1.0, 7) ** 2
    b = graded_batch(cfg, p, _half_ends(6), w, base_rigidity=beta)
    assert equilibrium_residuals(b)[0] < 1e-12 * 0.337 * p.max()
    x = b.positions
    T = np.broadcast_to(b.cable_EA, (1, len(b.cables)))[0, :18:3] * (
        np.linalg.norm(x[b.cables[:18:3, 1]] - x[b.cables[:18:3, 0]], axis=1) / b.cable_rest_length[0, :18:3] - 1)
    np.testing.assert_allclose(T, 0.33743 * p, rtol=1e-3)  # each prism's cross-cable tension EA p_m
    if w is not None:
        v = b.velocity[0]
        assert max(abs(np.dot(x[j] - x[i], v[j] - v[i])) for i, j in b.constraints) < 1e-15
        np.testing.assert_allclose(v[b.level_nodes, 2], np.repeat(w[:, None], 3, axis=1))
    # a flexible base of the uniform scene builder would be off balance under graded prestrain
    if beta == 0.0:
        naive = column_batch(cfg, {"prestrain": 0.002, "base_rigidity": 0.0})
        naive.cable_rest_length = b.cable_rest_length.copy()
        naive.cable_rest_length[0, 18:] = np.broadcast_to(column_batch(cfg, {"prestrain": 0.002, "base_rigidity": 0.0})
                                                          .cable_rest_length, (1, len(b.cables)))[0, 18:]
        assert equilibrium_residuals(naive)[0] > 1e-6 * 0.337 * p.max()


def test_graded_batch_refuses_bad_profiles():
    cfg = ColumnConfig(n_prisms=3)
    with pytest.raises(ValueError, match="prestrain_per_prism"):
        graded_batch(cfg, [0.002, 0.002], _half_ends(3))
    with pytest.raises(ValueError, match="level_mass"):
        graded_batch(cfg, [0.002] * 3, np.r_[0.0, -1.0, 1.0, 1.0])
    with pytest.raises(ValueError, match="level_velocity"):
        graded_batch(cfg, [0.002] * 3, _half_ends(3), np.ones(4), base_rigidity=0.0)


def test_discrete_joint_conserves_energy_and_tends_to_the_impedance_formula():
    """The exact joint of the discrete chain: the energy flux K_j sin(k_j) |u|^2 is conserved at every frequency
    below both cut-offs, and R_eps, T_eps tend to the long-wave formulas."""
    cfg = ColumnConfig()
    c1, c2 = chain_of(cfg, 0.002), chain_of(cfg, 0.0005)
    th = interface_theory(cfg, 0.002, 0.0005)
    w = np.linspace(1e-4, 0.95, 30) * c2.omega_c
    R, T = discrete_coefficients(c1.K, c2.K, c1.m_eff, w)
    k1, k2 = (2 * np.arcsin(w / c.omega_c) for c in (c1, c2))
    # back to displacement amplitudes: |R_u| = |R_eps|, |T_u| = |T_eps| |e^(ik1) - 1| / |e^(ik2) - 1|
    T_u = np.abs(T) * np.sin(k1 / 2) / np.sin(k2 / 2)
    np.testing.assert_allclose(np.abs(R) ** 2 + c2.K * np.sin(k2) / (c1.K * np.sin(k1)) * T_u**2, 1.0, rtol=1e-12)
    np.testing.assert_allclose([R[0].real, T[0].real], [th.reflected_strain, th.transmitted_strain], rtol=1e-6)
    # Z2/Z1 = sqrt(p2/p1) with equal level masses (the Bloch cells' speeds against the closed form)
    assert th.Z2 / th.Z1 == pytest.approx(0.5, rel=1e-6)
    assert th.c1 == pytest.approx(c1.c0, rel=1e-6)


def test_interface_check():
    g = check_interface()
    assert g.passed, report([g])
    assert [c.name for c in g.checks] == ["interface_reflected", "interface_transmitted", "interface_delay"]


@pytest.mark.parametrize("beta", [0.0, 0.5, 1.0])
def test_the_profile_api_builds_the_columns_graded_batch_builds(beta):
    """Two constructions of one graded column, written apart: the scene builder's profiles
    (scene.batch.column_batch with per-prism prestrain and per-level unit_mass) and this gallery's
    graded_batch. Rest lengths and node masses agree to round-off (unit_mass counts an end level as
    an interior one, halved by end_base_mass = 'half': graded_batch's masses are what each level
    carries)."""
    from warp_tensegrity import Profile

    cfg = ColumnConfig(n_prisms=9, handedness="RRLRLLRRL")
    rng = np.random.default_rng(7)
    p = rng.uniform(0.001, 0.01, cfg.n_prisms)
    level_mass = rng.uniform(0.5, 2.0, cfg.n_prisms + 1) * cfg.unit_mass
    unit_mass = level_mass.copy()
    unit_mass[[0, -1]] *= 2.0  # 'half' at the end levels
    ref = graded_batch(cfg, p, level_mass, base_rigidity=beta)
    api = column_batch(cfg, {"prestrain": Profile.explicit(p), "unit_mass": Profile.explicit(unit_mass),
                             "base_rigidity": beta})
    np.testing.assert_array_equal(api.cables, ref.cables)
    np.testing.assert_allclose(api.cable_rest_length, ref.cable_rest_length, rtol=1e-14, atol=0)
    free = ~api.fixed
    np.testing.assert_allclose(api.node_mass[:, free], ref.node_mass[:, free], rtol=1e-15, atol=0)
    np.testing.assert_allclose(api.cable_EA, ref.cable_EA, rtol=1e-15, atol=0)
