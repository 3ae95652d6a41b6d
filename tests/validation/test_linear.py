"""Checks of the linearised analysis (warp_tensegrity.validation.linear).

Analytic cases first (spring-mass chains, a bar pendulum in tension and in compression, which
exercise the cable material and geometric terms and the bar geometric term), then T3 columns:
mode count, mechanisms of unstressed prisms, prestress stiffening, long-wave speeds, and the
linear modes against the nonlinear reference dynamics at small amplitude.
"""

import numpy as np
import pytest

from warp_tensegrity import ColumnConfig, build_column
from warp_tensegrity.validation.linear import (
    axial_stiffness_per_prism,
    column_cell_compliance,
    count_zero_modes,
    equilibrium_multipliers,
    long_wave_speed,
    modal_analysis,
    modes,
    omega_max,
    tangent_stiffness,
)
from warp_tensegrity import Network
from tests.references.reference import ReferenceSystem

EA, L, P, MASS = 2.0, 0.1, 0.01, 0.05  # N, m, -, kg


def _chain(n_masses):
    """n_masses equal masses on the x axis between two clamped walls, n+1 cables prestrained P."""
    s = L * (1 + P)
    x = np.zeros((n_masses + 2, 3))
    x[:, 0] = s * np.arange(n_masses + 2)
    fixed = np.zeros(n_masses + 2, bool)
    fixed[[0, -1]] = True
    cables = np.stack([np.arange(n_masses + 1), np.arange(1, n_masses + 2)], axis=1)
    return Network(positions=x, node_mass=MASS, fixed=fixed, bars=np.zeros((0, 2)), bar_mass=[],
                   cables=cables, cable_EA=EA, cable_rest_length=L).validate()


def test_mass_between_two_springs():
    w, shapes = modes(_chain(1))
    k, T, s = EA / L, EA * P, L * (1 + P)
    np.testing.assert_allclose(w, np.sort([np.sqrt(2 * T / (s * MASS))] * 2 + [np.sqrt(2 * k / MASS)]), rtol=1e-12)
    assert abs(shapes[2, 1, 0]) == pytest.approx(1 / np.sqrt(MASS))  # longitudinal, mass-normalised


@pytest.mark.parametrize("n", [1, 5, 12])
def test_linear_chain(n):
    w = modes(_chain(n))[0]
    k, T, s = EA / L, EA * P, L * (1 + P)
    j = np.arange(1, n + 1)
    sines = np.sin(j * np.pi / (2 * (n + 1)))
    expected = np.sort(np.concatenate([2 * np.sqrt(k / MASS) * sines, np.repeat(2 * np.sqrt(T / (s * MASS)) * sines, 2)]))
    np.testing.assert_allclose(w, expected, rtol=1e-11)
    assert omega_max(_chain(n)) < 2 * np.sqrt(k / MASS)  # the infinite-chain bound
    assert count_zero_modes(_chain(n)) == 0


@pytest.mark.parametrize("tension", [True, False])
def test_bar_pendulum_geometric_stiffness(tension):
    """Node 1 on a bar (length l) from clamped node 0; a cable (length s, tension T) to clamped
    node 2 beyond node 1 (bar in tension) or beyond node 0 (bar in compression). Transverse
    omega^2 = T (1/s +- 1/l) / m; the bar removes the axial mode."""
    l, d, m = 0.2, 0.1, 0.02
    x2 = l + d if tension else -d
    s = abs(x2 - l)
    x = np.array([[0, 0, 0], [l, 0, 0], [x2, 0, 0]], float)
    net = Network(positions=x, node_mass=[0, m, 0], fixed=[True, False, True], bars=[[0, 1]], bar_mass=0,
                  cables=[[1, 2]], cable_EA=EA, cable_rest_length=s / (1 + P)).validate()
    T = EA * P
    lam, res = equilibrium_multipliers(net)
    assert res < 1e-15
    np.testing.assert_allclose(lam * l, [T if tension else -T], rtol=1e-12)  # bar force, tension +
    r = modal_analysis(net)
    assert r.n_free_dof == 3 and r.n_constraints == 1 and len(r.omega2) == 2
    expected = T * (1 / s + (1 / l if tension else -1 / l)) / m
    np.testing.assert_allclose(r.omega2, [expected, expected], rtol=1e-12)
    if not tension:
        assert np.all(r.omega2 < 0)  # the compressed bar is an unstable inverted pendulum


def test_tangent_stiffness_is_force_jacobian():
    """K_t equals minus the derivative of the nodal forces (finite differences), with bar
    multipliers frozen, on a prestressed column."""
    scene = build_column(ColumnConfig(n_prisms=2), prestrain=0.002, base_rigidity=0.5)
    net = scene.network
    rs = ReferenceSystem(net)
    K = tangent_stiffness(net)
    lam, _ = equilibrium_multipliers(net)
    x0 = net.positions

    def force(q):
        x = rs.to_x(q)
        return rs.to_q(rs.nodal_forces(x)) - rs.jacobian(x).T @ lam

    q0 = rs.to_q(x0)
    h = 1e-9
    J = np.stack([(force(q0 + h * e) - force(q0 - h * e)) / (2 * h) for e in np.eye(len(q0))], axis=1)
    np.testing.assert_allclose(K, -J, atol=1e-6 * np.abs(K).max())


@pytest.mark.parametrize("beta", [0.0, 1.0])
def test_column_mode_count_and_zero_modes(beta):
    """Modes = free DOF - independent bar constraints. Unstressed T3 prisms each keep one
    zero-stiffness infinitesimal mechanism (FB and RB alike, cables on their loading branch);
    the prestress p = 0.002 stabilises all of them."""
    n = 4
    for p, zeros in ((0.0, n), (0.002, 0)):
        scene = build_column(ColumnConfig(n_prisms=n), prestrain=p, base_rigidity=beta)
        net = scene.network
        r = modal_analysis(net)
        assert r.n_constraints == net.n_bars  # independent constraints
        assert len(r.omega2) == r.n_free_dof - net.n_bars
        assert count_zero_modes(net) == zeros
        assert np.all(r.omega2 > -1e-8 * r.omega2.max())  # nothing unstable
        # the axial load finds the mechanism when unstressed: zero axial stiffness
        assert (axial_stiffness_per_prism(scene) == 0.0) == (p == 0.0)


def test_omega_max_bound():
    """Practical bound of the numerics notes: omega_max^2 <= max_i (2/m_i) sum_c max(k_c, T_c/l_c)."""
    for beta in (0.0, 1.0):
        net = build_column(ColumnConfig(n_prisms=4), prestrain=0.002, base_rigidity=beta).network
        T, ell = net.cable_tensions(), net.cable_lengths()
        k = np.maximum(net.cable_EA / net.cable_rest_length, T / ell)
        acc = np.zeros(net.n_nodes)
        np.add.at(acc, net.cables[:, 0], k)
        np.add.at(acc, net.cables[:, 1], k)
        bound = np.sqrt(np.max(2 / net.node_mass[~net.fixed] * acc[~net.fixed]))
        assert 0.5 * bound < omega_max(net) < bound


def test_rb_axial_stiffness_linear_in_prestrain():
    """RB: the linear axial stiffness comes from prestress alone (the mechanism), so it is
    proportional to p; every prism has the same stiffness (rigid bases: no end effect)."""
    ks = [axial_stiffness_per_prism(build_column(ColumnConfig(n_prisms=4), prestrain=p, base_rigidity=1.0))
          for p in (0.001, 0.002, 0.004)]
    np.testing.assert_allclose(np.array(ks) / [0.001, 0.002, 0.004], ks[0] / 0.001, rtol=1e-9)
    scene = build_column(ColumnConfig(n_prisms=4), prestrain=0.002, base_rigidity=1.0)
    np.testing.assert_allclose([axial_stiffness_per_prism(scene, m) for m in range(4)], ks[1], rtol=1e-9)
    C = column_cell_compliance(scene)
    assert abs(np.linalg.det(C)) < 1e-9 * abs(C[0, 0] * C[1, 1])  # twist locked to height


@pytest.mark.parametrize("beta", [0.0, 1.0])
def test_long_wave_speed(beta):
    scene = build_column(ColumnConfig(n_prisms=20), prestrain=0.002, base_rigidity=beta)
    lw = long_wave_speed(scene)
    # one branch per unlocked cell DOF: FB two (soft mechanism + stiff base stretching), RB one
    assert len(lw.c_branches_homogenised) == (2 if beta == 0.0 else 1)
    # lowest modes of each branch are non-dispersive once the lattice factor is removed
    for s in lw.branch_speeds:
        assert len(s) == 3 and np.ptp(s) < 0.01 * s[0]
    # modal speeds agree with the homogenised cell
    np.testing.assert_allclose(lw.c_branches_modal, lw.c_branches_homogenised, rtol=0.02)
    # rotary inertia of the twisting bases: the point-mass formula overestimates the soft speed
    assert lw.c0_point_mass > 2 * lw.c0
    np.testing.assert_allclose(lw.c0_zero_torque, lw.c0, rtol=1e-6 if beta == 1.0 else 0.02)
    # the soft branch sits below the stiff one
    assert lw.c0 == lw.c_branches_modal[0] == min(lw.c_branches_modal)


def test_long_wave_speed_unstressed():
    lw = long_wave_speed(build_column(ColumnConfig(n_prisms=10), prestrain=0.0, base_rigidity=1.0))
    assert lw.c0 == 0.0 and lw.k_axial == 0.0  # RB: sonic vacuum
    lw = long_wave_speed(build_column(ColumnConfig(n_prisms=10), prestrain=0.0, base_rigidity=0.0))
    assert lw.c0 == 0.0 and lw.c_branches_modal[1] > 0.3  # FB: stiff base-stretching branch survives


def test_small_amplitude_mode_matches_reference_dynamics():
    """Start the nonlinear reference on a mode with tiny amplitude: it oscillates as
    eps * u * cos(omega t) (checked over one period)."""
    scene = build_column(ColumnConfig(n_prisms=2), prestrain=0.002, base_rigidity=0.0)
    net = scene.network
    rs = ReferenceSystem(net)
    w, shapes = modes(net)
    for k in (0, len(w) // 2, len(w) - 1):
        u = shapes[k] / np.abs(shapes[k]).max()
        eps = 1e-8  # m, strain ~1e-6 << p
        x0 = rs.project_positions(net.positions + eps * u)
        period = 2 * np.pi / w[k]
        n_steps = 400
        t, X, _ = rs.integrate(x0, np.zeros_like(x0), period, period / n_steps, stride=50)
        pred = eps * u[None] * np.cos(w[k] * t)[:, None, None]
        assert np.abs((X - net.positions) - pred).max() < 1e-4 * eps  # a 1% frequency error gives 5e-2
