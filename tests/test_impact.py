"""The rigid_members impact (docs/impact.md) and the limits of the base rigidity (issue 16, part 1)."""

import numpy as np
import pytest

from warp_tensegrity import ColumnConfig, RunSettings, simulate_batch
from warp_tensegrity.scene.batch import column_batch
from warp_tensegrity.scene.columns import build_column, column_topology
from warp_tensegrity.scene.impact import kinematic_lock_strain, least_energy_impact, member_jacobian
from warp_tensegrity.measure import measure_pulse

PAPER = ColumnConfig()


def _ke(scene):
    return 0.5 * float((scene.network.node_mass[:, None] * scene.velocity**2).sum())


def test_rigid_member_impact_is_admissible_and_least_energy():
    cfg = ColumnConfig(n_prisms=5)
    s = build_column(cfg, prestrain=0.002, v0=0.1, base_rigidity=0.3)
    topo = s.topology
    v = s.velocity.reshape(-1)
    J = member_jacobian(topo.positions, np.concatenate([topo.bars, topo.base]), topo.fixed)
    assert np.abs(J @ v).max() < 1e-12 * 0.1 * np.abs(J).max()
    np.testing.assert_array_equal(s.velocity[topo.level_nodes[-1], 2], -0.1)
    assert np.all(s.velocity[topo.fixed] == 0)
    # least energy: every admissible variation (null space of the constraints and the pins) is
    # M-orthogonal to v, so none lowers the kinetic energy
    pinned = np.zeros(v.size, bool)
    pinned[[3 * i + 2 for i in topo.level_nodes[-1]]] = True
    fixed = np.repeat(topo.fixed, 3)
    A = np.vstack([J, np.eye(v.size)[pinned | fixed]])
    _, sv, vt = np.linalg.svd(A)
    null = vt[np.sum(sv > 1e-12 * sv[0]):]
    assert null.shape[0] > 0
    M = np.kron(s.network.mass_matrix(), np.eye(3))
    assert np.abs(null @ M @ v).max() < 1e-12 * np.abs(M @ v).max()


def test_rigid_member_impact_is_the_paper_rb_impact_and_independent_of_beta():
    rb_paper = build_column(ColumnConfig(impact_admissibility="end_twist"), v0=0.1, base_rigidity=1.0)
    fb_paper = build_column(ColumnConfig(impact_admissibility="end_twist"), v0=0.1, base_rigidity=0.0)
    for beta in (0.0, 0.5, 0.9999, 1.0):
        s = build_column(PAPER, prestrain=0.002, v0=0.1, base_rigidity=beta)
        np.testing.assert_allclose(s.velocity, rb_paper.velocity, rtol=0, atol=1e-12 * 0.1)  # round-off
    assert _ke(build_column(PAPER, v0=0.1)) / _ke(fb_paper) == pytest.approx(5.06, rel=0.01)
    b = column_batch(ColumnConfig(n_prisms=6), {"v0": [0.05, 0.05, 0.05], "base_rigidity": [0.0, 0.7, 1.0]})
    np.testing.assert_array_equal(b.velocity[0], b.velocity[1])
    np.testing.assert_array_equal(b.velocity[0], b.velocity[2])
    # the direct solver agrees with the builder
    topo = column_topology(ColumnConfig(n_prisms=6))
    v = least_energy_impact(topo.positions, np.diag(np.full(topo.n_nodes, 1.0)), topo.fixed,
                            np.concatenate([topo.bars, topo.base]), topo.level_nodes[-1], 0.05)
    np.testing.assert_allclose(v, b.velocity[0], rtol=0, atol=1e-12 * 0.05)  # round-off


def test_kinematic_lock_of_the_paper_prism():
    # a rigid-base prism twisted to phi = pi: h_min^2 = l^2 - 4 a^2 (independent arithmetic)
    a, h0 = 5e-3, 6.2e-3
    l2 = h0**2 + 2 * a**2 * (1 + np.sqrt(3) / 2)
    h = np.sqrt(l2 - 4 * a**2)
    assert kinematic_lock_strain(a, h0, 5 * np.pi / 6) == pytest.approx((h - h0) / h, rel=1e-12)
    assert kinematic_lock_strain(a, h0, 5 * np.pi / 6) == pytest.approx(-0.1005, abs=1e-4)


def _against_last(betas, v0, t_end, n_prisms=50, dt_safety=0.25):
    r = simulate_batch(ColumnConfig(n_prisms=n_prisms), {"prestrain": 0.002, "v0": v0, "base_rigidity": np.array(betas)},
                       RunSettings(t_end=t_end, output_interval=0.002, device="cpu", dt_safety=dt_safety))
    assert (r.status == 0).all()
    return r


@pytest.mark.slow
def test_beta_to_zero_converges_to_flexible_bases():
    """The issue's test from beta = 1e-4 toward FB: paper column, p = 0.002, v0 = 0.1 m/s, fp64."""
    betas = [1e-2, 1e-3, 1e-4, 0.0]
    r = _against_last(betas, 0.1, 1.6, dt_safety=0.1)  # one batch: one dt for all
    m = measure_pulse(r.strain, r.time, PAPER.height)
    peak = np.abs(r.strain[-1]).max()
    for key in ("amplitude", "speed", "width_fwhm"):
        d = np.abs(m[key][:-1] / m[key][-1] - 1)
        assert np.all(np.diff(d) < 0), (key, d)  # shrinks with beta
        assert d[-1] <= 0.01, (key, d)
    rms = [np.sqrt(np.mean((r.strain[b] - r.strain[-1]) ** 2)) / peak for b in range(3)]
    assert np.all(np.diff(rms) < 0) and rms[-1] <= 0.02, rms


@pytest.mark.slow
def test_beta_to_one_regular_below_the_lock_singular_at_it():
    """Below the kinematic lock the difference to rigid bases is ~ (1 - beta) at every time; a pulse
    that reaches the lock keeps an O(1) difference however stiff the bases (docs/impact.md). The
    issue-16 criterion as first stated (paper RB column, v0 = 0.1 m/s, beta = 0.9999 within 1 %), which
    this singularity rules out, is evidence rather than a test: analysis/beta_limit.py part A,
    analysis/data/beta_limit.json (speed +69 % at beta = 0.9999)."""
    betas = np.array([0.999, 0.9999, 1.0] * 2)
    v0 = np.repeat([0.003, 0.1], 3)
    lock = -kinematic_lock_strain(PAPER.radius, PAPER.height, PAPER.twist)
    r = simulate_batch(PAPER, {"prestrain": 0.002, "v0": v0, "base_rigidity": betas},
                       RunSettings(t_end=0.3, output_interval=0.002, device="cpu", dt_safety=0.25))
    assert (r.status == 0).all()
    for g, regular in ((0, True), (1, False)):
        ref = r.strain[3 * g + 2]
        peak = np.abs(ref).max()
        d = [np.abs(r.strain[3 * g + b] - ref).max() / peak for b in range(2)]
        if regular:
            assert peak < 0.5 * lock
            assert 5 < d[0] / d[1] < 20 and d[1] < 1e-3, d  # ~ 1 - beta
        else:
            assert peak > lock
            assert d[0] / d[1] < 3 and d[1] > 0.05, d  # no convergence
