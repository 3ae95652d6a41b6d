"""Scene builder: layout as the paper describes, self-stress equilibrium, input validation."""

import numpy as np
import pytest

from warp_tensegrity import Network, NetworkError, column_batch, network_batch
from warp_tensegrity.scene.columns import ColumnConfig, build_column, column_topology, prism_heights


def test_single_prism_members_are_the_papers():
    topo = column_topology(ColumnConfig(n_prisms=1))
    # paper, Sec. 3 (1-based): bars 1-4, 2-5, 3-6; cross cables 1-6, 2-4, 3-5; bases 1-2-3, 4-5-6
    assert sorted(map(tuple, (topo.bars + 1).tolist())) == [(1, 4), (2, 5), (3, 6)]
    assert sorted(map(tuple, (topo.cross + 1).tolist())) == [(1, 6), (2, 4), (3, 5)]
    bases = {tuple(sorted(p)) for p in (topo.base + 1).tolist()}
    assert bases == {(1, 2), (2, 3), (1, 3), (4, 5), (5, 6), (4, 6)}


@pytest.mark.parametrize("n", [1, 3, 50])
def test_member_counts(n):
    s = build_column(ColumnConfig(n_prisms=n), prestrain=0.002)
    net = s.network
    assert net.n_nodes == 3 * (n + 1)
    assert len(s.topology.bars) == 3 * n
    assert len(s.topology.cross) + len(s.topology.base) == 3 * (2 * n + 1)  # paper's n_s
    assert net.class_k() == 2 if n > 1 else 1


def test_geometry_twist_and_heights():
    cfg = ColumnConfig(n_prisms=2)
    topo = column_topology(cfg)
    X = topo.positions
    np.testing.assert_allclose(np.linalg.norm(X[:, :2], axis=1), cfg.radius, rtol=1e-14)
    np.testing.assert_allclose(prism_heights(topo, X), cfg.height, rtol=1e-14)
    # right-handed: clockwise twist seen from +z by 5*pi/6
    a0 = np.arctan2(X[0, 1], X[0, 0])
    a3 = np.arctan2(X[3, 1], X[3, 0])
    assert np.isclose(np.mod(a0 - a3, 2 * np.pi), 5 * np.pi / 6)
    # cross cables are the short vertical cables (bottom node to the top node 30 deg away)
    for i, j in topo.cross:
        d = np.mod(np.arctan2(X[i, 1], X[i, 0]) - np.arctan2(X[j, 1], X[j, 0]), 2 * np.pi)
        assert np.isclose(min(d, 2 * np.pi - d), np.pi / 6)


@pytest.mark.parametrize("handedness", ["right", "left", "alternating", "RRLRL"])
@pytest.mark.parametrize("beta", [0.0, 0.5, 1.0])
def test_reference_state_is_equilibrium(handedness, beta):
    s = build_column(ColumnConfig(n_prisms=5, handedness=handedness), prestrain=0.002, base_rigidity=beta)
    assert s.cross_tension > 0
    assert s.relative_equilibrium_residual < 1e-10
    # cables all taut at the prescribed prestrain; cross cables at exactly p
    t = s.network.cable_tensions()
    assert np.all(t > 0)
    np.testing.assert_allclose(t[: 15], s.cross_tension, rtol=1e-12)


def test_unbalanced_state_is_detected():
    """The residual check is not vacuous: a wrong base rest length is reported."""
    s = build_column(ColumnConfig(n_prisms=3), prestrain=0.01)
    net = s.network
    net.cable_rest_length[-1] *= 0.99
    from warp_tensegrity.scene.columns import equilibrium_residual

    assert equilibrium_residual(net) / s.cross_tension > 1e-3


def test_batch_residual_matches_single_builds():
    cfg = ColumnConfig(n_prisms=4)
    b = column_batch(cfg, {"prestrain": [0.0, 0.002, 0.01], "base_rigidity": [0.0, 1.0, 0.5]})
    assert np.all(b.equilibrium_residual < 1e-10)


@pytest.mark.parametrize("mode", ["project", "end_twist"])
@pytest.mark.parametrize("beta", [0.0, 1.0])
def test_impact_velocity_is_admissible(mode, beta):
    s = build_column(ColumnConfig(n_prisms=4, impact_admissibility=mode), v0=0.1, base_rigidity=beta)
    net, v = s.network, s.velocity
    b = net.positions[net.bars[:, 1]] - net.positions[net.bars[:, 0]]
    bdot = v[net.bars[:, 1]] - v[net.bars[:, 0]]
    assert np.abs((b * bdot).sum(1)).max() < 1e-15
    assert np.all(v[s.topology.level_nodes[0]] == 0)
    if mode == "end_twist":
        np.testing.assert_allclose(v[s.topology.level_nodes[-1], 2], -0.1, rtol=1e-14)
        assert np.all(v[:-3] == 0)
    else:  # momentum-consistent impulse: never more kinetic energy than the axial target
        m = net.node_mass
        assert 0.5 * (m[:, None] * v * v).sum() <= 0.5 * 3 * m[-1] * 0.1**2


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(prestrain=-0.1), r"prestrain = -0.1"),
        (dict(prestrain=float("nan")), r"prestrain = nan"),
        (dict(base_rigidity=1.5), r"base_rigidity = 1.5"),
        (dict(cable_EA=0.0), r"cable_EA = 0.0"),
        (dict(unit_mass=-1.0), r"unit_mass = -1.0"),
        (dict(v0=float("inf")), r"v0 = inf"),
    ],
)
def test_bad_column_parameters_are_named(kwargs, match):
    with pytest.raises(NetworkError, match=match):
        build_column(ColumnConfig(n_prisms=2), **kwargs)


def test_bad_config_is_named():
    with pytest.raises(NetworkError, match="height"):
        ColumnConfig(height=0.0)
    with pytest.raises(NetworkError, match="handedness"):
        ColumnConfig(n_prisms=3, handedness="RX")
    with pytest.raises(NetworkError, match="end_base_mass"):
        ColumnConfig(end_base_mass="some")
    with pytest.raises(NetworkError, match=r"prestrain\[1\] = -1"):
        column_batch(ColumnConfig(n_prisms=2), {"prestrain": [0.0, -1.0]})
    with pytest.raises(NetworkError, match="unknown column parameter"):
        column_batch(ColumnConfig(n_prisms=2), {"prestrian": [0.0]})


def _two_node(**over):
    kw = dict(
        positions=[[0, 0, 0], [1, 0, 0], [0, 1, 0]],
        node_mass=[1.0, 1.0, 1.0],
        fixed=[True, False, False],
        bars=[[0, 1]],
        bar_mass=[0.0],
        cables=[[1, 2]],
        cable_EA=[1.0],
        cable_rest_length=[1.0],
    )
    kw.update(over)
    return Network(**kw)


@pytest.mark.parametrize(
    "over, match",
    [
        (dict(bars=[[0, 7]]), r"bar 0: node index \(0, 7\) out of range"),
        (dict(cables=[[1, 1]]), r"cable 0 \(nodes 1-1\): joins node 1 to itself"),
        (dict(positions=[[0, 0, 0], [0, 0, 0], [0, 1, 0]]), r"bar 0 \(nodes 0-1\): length 0.0 m"),
        (dict(node_mass=[1.0, -2.0, 1.0]), r"node 1: mass = -2.0"),
        (dict(node_mass=[1.0, 0.0, 1.0]), r"node 1: free node has no mass"),
        (dict(cable_EA=[float("nan")]), r"cable 0 \(nodes 1-2\): EA = nan"),
        (dict(cable_rest_length=[-1.0]), r"cable 0 \(nodes 1-2\): rest length = -1.0"),
        (dict(bar_mass=[-1.0]), r"bar 0 \(nodes 0-1\): mass -1.0"),
        (dict(positions=[[0, 0, 0], [np.inf, 0, 0], [0, 1, 0]]), r"node 1: position"),
    ],
)
def test_network_validation_names_member_and_value(over, match):
    with pytest.raises(NetworkError, match=match):
        _two_node(**over).validate()


def test_network_batch_rejects_mixed_topologies():
    a = _two_node()
    b = _two_node(cables=[[0, 2]])
    with pytest.raises(NetworkError, match="network 1: cables differ"):
        network_batch([a, b])


# ---------------------------------------------------------------------- long columns (issue 23, defect 4)
@pytest.mark.parametrize("mode", ["rigid_members", "end_twist", "project"])
def test_sparse_solves_agree_with_the_dense_ones(mode, monkeypatch):
    """Beyond DENSE_MAX_DOF the scene solves sparsely (O(n)); forced on a short column, the sparse
    impact, equilibrium residual and self-stress agree with the dense ones to round-off."""
    from warp_tensegrity.scene import columns as C
    from warp_tensegrity.scene import sparse
    from warp_tensegrity.scene.batch import equilibrium_residuals

    cfg = ColumnConfig(n_prisms=12, impact_admissibility=mode, handedness="alternating")
    params = {"prestrain": [0.002, 0.0], "v0": 0.1, "base_rigidity": [0.0, 1.0]}
    dense = [build_column(cfg, prestrain=0.002, v0=0.1, base_rigidity=b) for b in (0.0, 0.5, 1.0)]
    dense_batch = equilibrium_residuals(column_batch(cfg, params))
    monkeypatch.setattr(sparse, "DENSE_MAX_DOF", 0)
    monkeypatch.setattr(C, "SELF_STRESS_EACH_MAX", 0)
    long = [build_column(cfg, prestrain=0.002, v0=0.1, base_rigidity=b) for b in (0.0, 0.5, 1.0)]
    for d, s in zip(dense, long):
        np.testing.assert_allclose(s.velocity, d.velocity, rtol=0, atol=1e-12 * 0.1)
        np.testing.assert_allclose(s.network.cable_rest_length, d.network.cable_rest_length, rtol=1e-13)
        assert s.relative_equilibrium_residual < 1e-12 and d.relative_equilibrium_residual < 1e-12
    np.testing.assert_allclose(equilibrium_residuals(column_batch(cfg, params)), dense_batch, rtol=0, atol=1e-15)
    # and the sparse residual is no vacuous check either
    net = long[0].network
    net.cable_rest_length[-1] *= 0.99
    assert C.equilibrium_residual(net) / long[0].cross_tension > 1e-3


@pytest.mark.parametrize("mode", ["rigid_members", "end_twist", "project"])
def test_long_column_builds_in_linear_time(mode):
    """20,000 prisms (the dense solves wanted ~86 GB here and O(n^3) time): built in seconds,
    admissible and balanced, in every impact convention."""
    import time

    cfg = ColumnConfig(n_prisms=20_000, impact_admissibility=mode)
    t0 = time.perf_counter()
    b = column_batch(cfg, {"prestrain": [0.002, 0.0], "v0": 0.1, "base_rigidity": [0.0, 1.0]})
    assert time.perf_counter() - t0 < 20.0
    assert np.all(b.equilibrium_residual < 1e-9)
    end = b.velocity[:, -3:, 2]
    assert np.allclose(end, -0.1) if mode != "project" else np.all(end < 0)


def _coupling_by_loops(batch, partner):
    """The members' coupling as model.py built it before it was vectorised (the oracle)."""
    touching = {}
    for k, (i, j) in enumerate(batch.constraints):
        touching.setdefault(int(i), []).append((k, -1.0))
        touching.setdefault(int(j), []).append((k, 1.0))
    start, rows, bw = [0], [], 0
    for k, (i, j) in enumerate(batch.constraints):
        terms = sorted((l, a, c, sa * sb) for a, sa in ((int(i), -1.0), (int(j), 1.0)) if not batch.fixed[a]
                       for b, c in ((a, 0), (int(partner[a]), 1)) if b >= 0 for l, sb in touching.get(b, []) if l <= k)
        rows += terms
        bw = max([bw] + [k - t[0] for t in terms])
        start.append(len(rows))
    cols = list(zip(*rows)) if rows else [[], [], [], []]
    return [np.array(start)] + [np.array(c) for c in cols] + [bw]


@pytest.mark.parametrize("n, mode, hand, massive", [(1, "rigid_members", "right", True), (4, "end_twist", "right", False),
                                                    (7, "project", "alternating", False), (60, "rigid_members", "LRRL" * 15, False)])
def test_vectorised_member_coupling_and_masses_are_the_loops(n, mode, hand, massive):
    """model.constraint_coupling / mass_entries (vectorised for long columns, issue 23) give the
    device exactly what the per-member loops gave, rigid links, mixed handedness and massive bars included."""
    pytest.importorskip("warp")
    from warp_tensegrity.sim.model import constraint_coupling, mass_entries

    cfg = ColumnConfig(n_prisms=n, impact_admissibility=mode, handedness=hand, bar_mass=0.01 if massive else 0.0)
    for beta in ([0.0], [1.0], [0.0, 1.0, 0.5]):
        b = column_batch(cfg, {"base_rigidity": beta, "prestrain": [0.002] * len(beta)})
        partner, partner_dev, m_self, m_cross, minv_self, minv_cross = mass_entries(b)
        assert (partner >= 0).any() == massive
        free = ~b.fixed
        for a in np.flatnonzero(free):  # M^-1 entries, node by node, as the loop computed them
            p = partner[a]
            if p < 0 or not free[p]:
                assert np.array_equal(minv_self[:, a], 1.0 / m_self[:, a])
            else:
                det = m_self[:, a] * m_self[:, p] - m_cross[:, a] ** 2
                assert np.array_equal(minv_self[:, a], m_self[:, p] / det)
                assert np.array_equal(minv_cross[:, a], -m_cross[:, a] / det)
        got, want = constraint_coupling(b, partner), _coupling_by_loops(b, partner)
        for g, w in zip(got[:-1], want[:-1]):
            assert np.array_equal(g, w.astype(g.dtype))
        assert got[-1] == want[-1]
