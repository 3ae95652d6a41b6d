"""Bar contact, host side (issue 32 item 3): the signed axis distance and its gradient, the contact
twist, the contact system's coupling terms, and the scene options that ask for contact."""

import math

import numpy as np
import pytest

from warp_tensegrity import ColumnConfig, RunSettings
from warp_tensegrity.scene.batch import column_batch
from warp_tensegrity.scene.contact import (
    ROW_BAR,
    axis_geometry,
    contact_arrays,
    contact_twist,
    regular_gap,
    regular_prism,
    segment_distance,
)
from warp_tensegrity.scene.coupling import mass_entries
from warp_tensegrity.scene.network import NetworkError

A, H0, PHI0 = 5e-3, 6.2e-3, 5 * np.pi / 6
L = math.sqrt(H0**2 + 2 * A**2 * (1 - math.cos(PHI0)))


def test_signed_axis_distance_is_the_bars_distance_and_changes_sign_through_pi():
    """Where both closest points lie on the bars, |D| equals the clamped segment distance
    (Ericson's algorithm, an independent computation); D shrinks to 0 at twist pi and changes sign
    past it (the bars cross on the axis)."""
    d_prev = np.inf
    for phi in np.linspace(PHI0, np.pi - 1e-3, 25):
        P, Q = regular_prism(A, L, phi)
        for i, j in ((0, 1), (1, 2), (0, 2)):
            d, s, t = axis_geometry(P[i], Q[i], P[j], Q[j])
            assert 0 < s < 1 and 0 < t < 1
            assert abs(d) == pytest.approx(segment_distance(P[i], Q[i], P[j], Q[j]), rel=1e-12)
        gap = regular_gap(A, L, phi)
        assert gap < d_prev
        d_prev = gap
    signs = [np.sign(axis_geometry(*(lambda P, Q: (P[0], Q[0], P[1], Q[1]))(*regular_prism(A, L, phi)))[0])
             for phi in (np.pi - 0.05, np.pi + 0.05)]
    assert signs[0] == -signs[1]
    assert regular_gap(A, L, PHI0) == pytest.approx(1.768e-3, abs=1e-6)  # the docs quote 1.77 mm


def test_axis_distance_gradient_matches_finite_differences():
    """The gradient the contact rows use, -(1-s) n, -s n, (1-t) n, t n on P_i, Q_i, P_j, Q_j,
    against central differences of D on a perturbed prism (a wrong weight fails by O(1))."""
    rng = np.random.default_rng(3)
    P, Q = regular_prism(A, L, 2.9)
    X = np.concatenate([P[:2], Q[:2]]) + rng.normal(scale=3e-4, size=(4, 3))

    def D(x):
        d, _, _ = axis_geometry(x[0], x[2], x[1], x[3])  # bar i: x0 -> x2, bar j: x1 -> x3
        return d

    d0, s, t = axis_geometry(X[0], X[2], X[1], X[3])
    c = np.cross(X[2] - X[0], X[3] - X[1])
    n = c / np.linalg.norm(c)
    grad = {0: -(1 - s) * n, 2: -s * n, 1: (1 - t) * n, 3: t * n}
    eps = 1e-9
    for node in range(4):
        for k in range(3):
            xp, xm = X.copy(), X.copy()
            xp[node, k] += eps
            xm[node, k] -= eps
            fd = (D(xp) - D(xm)) / (2 * eps)
            assert fd == pytest.approx(grad[node][k], abs=1e-6)


@pytest.mark.parametrize("r", [0.1e-3, 0.25e-3, 0.8e-3])
def test_contact_twist_puts_the_axes_2r_apart(r):
    phi_c = contact_twist(A, H0, PHI0, r)
    assert PHI0 < phi_c < np.pi
    assert regular_gap(A, L, phi_c) == pytest.approx(2 * r, rel=1e-12)
    assert contact_twist(A, H0, PHI0, 1.05 * r) < phi_c  # thicker bars touch earlier


def _dense_gram(batch, grads):
    """J M^-1 J^T from per-row dense gradients (rows x nodes x 3) and the batch's M^-1."""
    _, _, m_self, m_cross, _, _ = mass_entries(batch)
    n = batch.positions.shape[0]
    M = np.zeros((n, n))
    partner = mass_entries(batch)[0]
    for a in range(n):
        M[a, a] = m_self[0, a]
        if partner[a] >= 0:
            M[a, partner[a]] = m_cross[0, a]
    free = ~batch.fixed
    Minv = np.zeros((n, n))
    Minv[np.ix_(free, free)] = np.linalg.inv(M[np.ix_(free, free)])
    return np.einsum("kai,ab,lbi->kl", grads, Minv, grads)


@pytest.mark.parametrize("beta, bar_mass, n", [(0.0, 0.0, 3), (1.0, 0.0, 3), (0.0, 0.01, 1)])
def test_contact_system_coupling_terms_assemble_the_dense_gram_matrix(beta, bar_mass, n):
    """The CSR coupling terms (and the bandwidth) give J M^-1 J^T of every row, members and bar
    pairs alike, with random gradients on every slot: as the device assembles it."""
    cfg = ColumnConfig(n_prisms=n, contact="bars", bar_radius=2e-4, bar_mass=bar_mass)
    b = column_batch(cfg, {"base_rigidity": beta})
    partner, _, _, _, minv_self, minv_cross = mass_entries(b)
    sysd = contact_arrays(b, partner)
    R, nn = len(sysd["row_kind"]), b.positions.shape[0]
    rng = np.random.default_rng(0)
    slot_grad = rng.normal(size=(R, 4, 3))
    grads = np.zeros((R, nn, 3))
    nodes = np.zeros((R, 4), dtype=int)
    cons = b.constraints
    for k in range(R):
        idx = sysd["row_index"][k]
        if sysd["row_kind"][k] == ROW_BAR:
            nodes[k, :2] = cons[idx]
            ns = 2
        else:
            bi, bj = b.contact_pairs[idx]
            nodes[k] = (cons[bi, 0], cons[bi, 1], cons[bj, 0], cons[bj, 1])
            ns = 4
        for sl in range(ns):
            grads[k, nodes[k, sl]] += slot_grad[k, sl]
    dense = _dense_gram(b, grads)
    sparse = np.zeros((R, R))
    st = sysd["acpl_start"]
    for k in range(R):
        for t in range(st[k], st[k + 1]):
            l, a = sysd["acpl_l"][t], sysd["acpl_a"][t]
            mi = minv_cross[0, a] if sysd["acpl_cross"][t] else minv_self[0, a]
            sparse[k, l] += mi * slot_grad[k, sysd["acpl_sk"][t]] @ slot_grad[l, sysd["acpl_sl"][t]]
    lower = np.tril(dense)
    assert np.allclose(sparse, lower, rtol=1e-12, atol=1e-12 * np.abs(dense).max())
    assert sysd["bandwidth"] == max(k - l for k, l in zip(*np.nonzero(np.abs(lower) > 0)))
    # each node's incidences are exactly its rows' slots
    inc = {(int(r), int(s)) for a in range(nn) for r, s in zip(
        sysd["anode_row"][sysd["anode_start"][a]:sysd["anode_start"][a + 1]],
        sysd["anode_slot"][sysd["anode_start"][a]:sysd["anode_start"][a + 1]]) if nodes[r, s] == a}
    assert len(inc) == len(sysd["anode_row"])
    # every pair sits right after its later bar
    for p, (bi, bj) in enumerate(b.contact_pairs):
        row = sysd["pair_row"][p]
        assert sysd["row_kind"][row] != ROW_BAR and sysd["row_index"][row] == p
        assert max(np.flatnonzero((sysd["row_kind"] == ROW_BAR) & (sysd["row_index"] == max(bi, bj)))) < row


def test_a_column_batch_carries_its_prisms_pairs():
    cfg = ColumnConfig(n_prisms=4, contact="bars", bar_radius=2e-4, restitution=0.5)
    b = column_batch(cfg, {"base_rigidity": [0.0, 1.0]})
    assert b.contact_pairs.shape == (12, 2) and b.contact_gap == 4e-4 and b.restitution == 0.5
    names = np.array(b.constraint_names)
    assert all(n.startswith("bar") for n in names[b.contact_pairs.ravel()])
    prism = lambda k: int(names[k].split("prism ")[1].rstrip(")"))  # noqa: E731
    assert all(prism(i) == prism(j) for i, j in b.contact_pairs)
    assert column_batch(ColumnConfig(n_prisms=4), {}).contact_pairs is None


@pytest.mark.parametrize("kwargs, words", [
    ({"contact": "bars"}, ["bar_radius = 0.0", "0.000884"]),
    ({"contact": "bars", "bar_radius": 1e-3}, ["bar_radius = 0.001", "0.00176826"]),
    ({"contact": "bar"}, ["contact = 'bar'", "'bars'"]),
    ({"contact": "bars", "bar_radius": 2e-4, "restitution": 1.5}, ["restitution = 1.5", "[0, 1]"]),
])
def test_contact_options_refuse_bad_values_by_name(kwargs, words):
    with pytest.raises(ValueError) as e:
        ColumnConfig(**kwargs)
    assert all(w in str(e.value) for w in words), str(e.value)


def test_run_settings_do_not_carry_contact():
    """Declared once, on the scene (the spec's [scene] table, the Python ColumnConfig)."""
    assert "contact" not in RunSettings.__pydantic_fields__
    assert {"contact", "bar_radius", "restitution"} <= set(ColumnConfig.__pydantic_fields__)
    with pytest.raises(NetworkError):
        ColumnConfig(contact="bars", bar_radius=0.9e-3)


def test_a_spec_and_init_carry_the_contact_options():
    """[scene] of a sweep spec takes them (errors name the key with its table), and the starting
    spec of `warp-tensegrity init` lists them, generated from the declarations."""
    from warp_tensegrity.init_spec import sweep_spec_text
    from warp_tensegrity.sweep import SpecError, load_spec

    text = ('[scene]\nn_prisms = 4\ncontact = "bars"\nbar_radius = 2.5e-4\nrestitution = 0.5\n'
            '[sweep]\ncases = [{ v0 = 0.1, base_rigidity = 1.0 }]\n[run]\nt_end = 0.1\n')
    spec = load_spec(text)
    assert (spec.scene.contact, spec.scene.bar_radius, spec.scene.restitution) == ("bars", 2.5e-4, 0.5)
    with pytest.raises(SpecError, match=r"scene\.bar_radius = 0\.002: contact = 'bars' needs"):
        load_spec(text.replace("2.5e-4", "0.002"))
    starting = sweep_spec_text("paper")
    assert all(f"# {k} = " in starting for k in ("contact", "bar_radius", "restitution"))
