"""Checks of the float64 reference dynamics (tests.references.reference).

The class-1 matrix form (paper Eqs. 12-14) and the Lagrange-multiplier form are independent
derivations; on a free T3 prism with massive bars they must give the same motion. Both must
conserve bar lengths and energy to integration accuracy, and RK4 must converge at order 4.
"""

from dataclasses import replace

import numpy as np
import pytest

from warp_tensegrity import ColumnConfig, Network, build_column
from tests.references.reference import (
    ClassOneMatrixForm,
    ReferenceSystem,
    integrate_matrix_form,
    matrix_form_accel,
)

BAR_MASS = 0.0249 / 3.0  # kg


@pytest.fixture(scope="module")
def free_prism():
    """Free FB T3 prism, massive bars, no node masses, cross prestrain 0.01, small admissible velocity."""
    scene = build_column(ColumnConfig(n_prisms=1, bar_mass=BAR_MASS), prestrain=0.01)
    net = replace(scene.network, fixed=np.zeros(6, bool), node_mass=np.zeros(6))
    net.validate()
    rs = ReferenceSystem(net)
    rng = np.random.default_rng(42)
    v0 = rs.project_velocities(net.positions, 1e-3 * rng.standard_normal((6, 3)))
    return net, rs, ClassOneMatrixForm.from_network(net), v0


def _rel(a, b, ref):
    return np.abs(a - b).max() / np.abs(ref).max()


def test_prism_is_class_one_and_velocity_admissible(free_prism):
    net, rs, _, v0 = free_prism
    assert net.class_k() == 1
    bd = v0[net.bars[:, 1]] - v0[net.bars[:, 0]]
    b = net.positions[net.bars[:, 1]] - net.positions[net.bars[:, 0]]
    assert np.abs(np.einsum("ij,ij->i", b, bd)).max() < 1e-14 * np.abs(b).max() * np.abs(v0).max()


def test_mass_matrix_is_thin_rod(free_prism):
    net, rs, form, _ = free_prism
    # Eq. (13) with C_R = |C_B|/2 equals the consistent thin-rod inertia (m/6)[[2, 1], [1, 2]]
    np.testing.assert_allclose(form.M, net.mass_matrix(), rtol=0, atol=1e-18)
    np.testing.assert_allclose(rs.M, np.kron(net.mass_matrix(), np.eye(3)), rtol=0, atol=1e-18)


def test_matrix_form_rejects_non_class_one():
    scene = build_column(ColumnConfig(n_prisms=1, bar_mass=BAR_MASS), prestrain=0.01)
    with pytest.raises(ValueError, match="clamped"):
        ClassOneMatrixForm.from_network(scene.network)
    free = replace(scene.network, fixed=np.zeros(6, bool), node_mass=np.zeros(6))
    with pytest.raises(ValueError, match="mass"):
        ClassOneMatrixForm.from_network(replace(free, bar_mass=np.zeros(3)))
    with pytest.raises(ValueError, match="node_mass"):
        ClassOneMatrixForm.from_network(replace(free, node_mass=np.full(6, 1e-3)))
    rb = build_column(ColumnConfig(n_prisms=1, bar_mass=BAR_MASS), prestrain=0.01, base_rigidity=1.0)
    rb_free = replace(rb.network, fixed=np.zeros(6, bool), node_mass=np.zeros(6),
                      bar_mass=np.full(rb.network.n_bars, BAR_MASS))
    with pytest.raises(ValueError, match="class-1"):
        ClassOneMatrixForm.from_network(rb_free)


def test_spinning_bar_multiplier_sign():
    """A free bar spinning at omega about its centre is in tension m omega^2 l / 12 at its ends."""
    m, l, w = 0.3, 0.2, 5.0
    x = np.array([[-l / 2, 0, 0], [l / 2, 0, 0]])
    v = np.array([[0, -w * l / 2, 0], [0, w * l / 2, 0]])
    net = Network(positions=x, node_mass=0.0, fixed=False, bars=[[0, 1]], bar_mass=m,
                  cables=np.zeros((0, 2)), cable_EA=[], cable_rest_length=[])
    rs = ReferenceSystem(net)
    form = ClassOneMatrixForm.from_network(net)
    np.testing.assert_allclose(rs.multipliers(x, v), [m * w**2 / 12], rtol=1e-13)  # tension +
    np.testing.assert_allclose(form.bar_force_densities(x.T, v.T), [-m * w**2 / 12], rtol=1e-13)  # compression +
    np.testing.assert_allclose(rs.accel(x, v), -w**2 * x, atol=1e-13)
    np.testing.assert_allclose(matrix_form_accel(x.T, v.T, form).T, -w**2 * x, atol=1e-13)


def test_accelerations_agree(free_prism):
    net, rs, form, v0 = free_prism
    rng = np.random.default_rng(1)
    for _ in range(5):
        x = rs.project_positions(net.positions + 2e-4 * rng.standard_normal((6, 3)))
        v = rs.project_velocities(x, 0.05 * rng.standard_normal((6, 3)))
        a_lag = rs.accel(x, v)
        a_mat = matrix_form_accel(x.T, v.T, form).T
        assert _rel(a_lag, a_mat, a_lag) < 1e-11
        # the state-dependent multipliers: lam (tension +) = -lambda (compression +)
        np.testing.assert_allclose(rs.multipliers(x, v), -form.bar_force_densities(x.T, v.T),
                                   rtol=1e-10, atol=1e-12 * np.abs(rs.multipliers(x, v)).max())
        # second time derivative of |b|^2 vanishes: b.b'' + |b'|^2 = 0
        b = x[net.bars[:, 1]] - x[net.bars[:, 0]]
        bd = v[net.bars[:, 1]] - v[net.bars[:, 0]]
        bdd = a_mat[net.bars[:, 1]] - a_mat[net.bars[:, 0]]
        res = np.einsum("ij,ij->i", b, bdd) + np.einsum("ij,ij->i", bd, bd)
        assert np.abs(res).max() < 1e-12 * np.einsum("ij,ij->i", bd, bd).max()


def test_trajectories_agree_and_conserve(free_prism):
    net, rs, form, v0 = free_prism
    x0 = net.positions
    t1, X, V = rs.integrate(x0, v0, 0.05, 1e-4, stride=50)
    t2, N, Nd = integrate_matrix_form(form, x0.T, v0.T, 0.05, 1e-4, stride=50)
    np.testing.assert_allclose(t1, t2)
    Xm = N.transpose(0, 2, 1)
    assert _rel(X, Xm, X - x0) < 1e-9
    assert _rel(V, Nd.transpose(0, 2, 1), V) < 1e-9
    # bar lengths: projected exactly; unprojected matrix form to integration accuracy
    L = net.bar_lengths()
    assert max(np.abs(net.bar_lengths(x) / L - 1).max() for x in X) < 1e-14
    assert max(np.abs(net.bar_lengths(x) / L - 1).max() for x in Xm) < 1e-12
    # energy
    E = np.array([rs.energy(x, v) for x, v in zip(X, V)])
    Em = np.array([form.energy(n, nd) for n, nd in zip(N, Nd)])
    np.testing.assert_allclose(Em, E, rtol=1e-9)
    assert np.ptp(E) / E[0] < 1e-9
    assert np.ptp(Em) / Em[0] < 1e-9
    # kinetic energy is a real share of E (the test is not trivial)
    ke = 0.5 * rs.to_q(V[-1]) @ rs.M @ rs.to_q(V[-1])
    assert ke > 1e-3 * E[0]


def test_dop853_agrees_with_rk4(free_prism):
    net, rs, form, v0 = free_prism
    x0 = net.positions
    _, X, V = rs.integrate(x0, v0, 0.02, 5e-5, stride=100)
    _, Xd, Vd = rs.integrate(x0, v0, 0.02, 5e-5, stride=100, method="dop853")
    assert _rel(X, Xd, X - x0) < 1e-9
    assert _rel(V, Vd, V) < 1e-9
    # unprojected index-1 DAE: tiny drift-off only
    assert np.abs(net.bar_lengths(Xd[-1]) / net.bar_lengths() - 1).max() < 1e-10


@pytest.mark.parametrize("form_name", ["lagrange", "matrix"])
def test_rk4_fourth_order(free_prism, form_name):
    """Successive differences of the final state shrink by 2^4 per dt halving (Richardson).
    omega_max ~ 246 rad/s, so omega*dt <= 0.5: the asymptotic regime; cables stay taut."""
    net, rs, form, v0 = free_prism
    x0 = net.positions
    v = 2.0 * v0
    finals = []
    for dt in (2e-3, 1e-3, 5e-4, 2.5e-4):
        if form_name == "lagrange":
            _, X, _ = rs.integrate(x0, v, 0.1, dt, stride=10**6)
            finals.append(X[-1])
        else:
            _, N, _ = integrate_matrix_form(form, x0.T, v.T, 0.1, dt, stride=10**6)
            finals.append(N[-1].T)
    d = np.array([np.abs(finals[i] - finals[i + 1]).max() for i in range(3)])
    orders = np.log2(d[:-1] / d[1:])
    assert np.all((orders > 3.8) & (orders < 4.2)), orders


def _column_setup(beta, n_prisms=3, p=0.002, v0=0.05):
    scene = build_column(ColumnConfig(n_prisms=n_prisms), prestrain=p, v0=v0, base_rigidity=beta)
    return scene, ReferenceSystem(scene.network)


@pytest.mark.parametrize("beta", [0.0, 0.5, 1.0])
def test_clamped_column_conserves(beta):
    """Class-k networks (RB: bars and base links share nodes), massless bars, clamped base.
    v0 = 1 mm/s keeps every cable taut, so the force law is smooth along the motion."""
    scene, rs = _column_setup(beta, v0=0.001)
    net = scene.network
    t, X, V = rs.integrate(net.positions, scene.velocity, 0.05, 1e-4, stride=100)
    assert min((net.cable_lengths(x) / net.cable_rest_length).min() for x in X) > 1.0
    E = np.array([rs.energy(x, v) for x, v in zip(X, V)])
    assert np.ptp(E) / E[0] < 1e-10
    L = net.bar_lengths()
    assert max(np.abs(net.bar_lengths(x) / L - 1).max() for x in X) < 1e-14
    assert np.all(X[:, net.fixed] == net.positions[net.fixed])
    assert np.all(V[:, net.fixed] == 0.0)
    # the impact has compressed the column: the end moved down
    top = scene.topology.level_nodes[-1]
    assert X[-1, top, 2].mean() < net.positions[top, 2].mean()


def test_slack_cables_energy():
    """A harder impact slackens FB cables: the force law has kinks, RK4 loses its order there,
    but energy stays conserved to a small error at a modest step."""
    scene, rs = _column_setup(0.0, v0=0.05)
    net = scene.network
    _, X, V = rs.integrate(net.positions, scene.velocity, 0.05, 5e-5, stride=100)
    assert min((net.cable_lengths(x) / net.cable_rest_length).min() for x in X) < 1.0  # went slack
    E = np.array([rs.energy(x, v) for x, v in zip(X, V)])
    assert np.ptp(E) / E[0] < 1e-6


def test_projections_reach_tolerance():
    scene, rs = _column_setup(1.0, n_prisms=4)
    net = scene.network
    rng = np.random.default_rng(3)
    x = net.positions + 1e-4 * rng.standard_normal(net.positions.shape)
    x[net.fixed] = net.positions[net.fixed]
    xp = rs.project_positions(x)
    assert np.max(np.abs(rs.constraints(xp)) / rs.L_bar**2) <= 1e-14
    vp = rs.project_velocities(xp, rng.standard_normal(x.shape))
    G = rs.jacobian(xp)
    assert np.abs(G @ rs.to_q(vp)).max() <= 1e-14 * np.abs(G).max() * np.abs(vp).max()
    # an admissible velocity is left alone
    np.testing.assert_allclose(rs.project_velocities(xp, vp), vp, atol=1e-15 * np.abs(vp).max())


def test_equilibrium_is_at_rest():
    scene, rs = _column_setup(0.0, p=0.002, v0=0.0)
    a = rs.accel(scene.network.positions, np.zeros_like(scene.network.positions))
    # accelerations from round-off only: compare with a typical cable force over node mass
    scale = scene.cross_tension / scene.network.node_mass.max()
    assert np.abs(a).max() < 1e-12 * scale


def test_bad_step_count():
    scene, rs = _column_setup(0.0)
    with pytest.raises(ValueError, match="multiple"):
        rs.integrate(scene.network.positions, scene.velocity, 0.01, 3e-3)
    with pytest.raises(ValueError, match="method"):
        rs.integrate(scene.network.positions, scene.velocity, 0.01, 1e-3, method="euler")
