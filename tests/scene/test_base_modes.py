"""The per-case flag of the limit base_rigidity -> 1 (issue 25, part 1; docs/impact.md): the
lowest base-member mode against the top of the rigid-base band, checked against the convergence
table measured on the engine (analysis/beta_limit.py part E, analysis/data/beta_limit.json)."""

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from warp_tensegrity import ColumnConfig
from warp_tensegrity.scene import base_modes as BM
from warp_tensegrity.scene.impact import kinematic_lock_strain

ROOT = Path(__file__).resolve().parents[2]
PAPER = ColumnConfig()
LOCK = -kinematic_lock_strain(PAPER.radius, PAPER.height, PAPER.twist)


def test_lowest_base_mode_follows_the_long_wave_law():
    """The lowest base-member mode sits at ~0.5/n of the top of the base band (n prisms), and both
    scale as (1 - beta)^-1/2; the RB band top (127 rad/s) barely depends on n or p."""
    for n in (15, 20, 50):
        cfg = ColumnConfig(n_prisms=n)
        for one_minus in (1e-3, 1e-4):
            w_min, w_top = BM._omegas(cfg, 0.002, 1.0 - one_minus)
            assert n * w_min / w_top == pytest.approx(0.5, abs=0.015), (n, one_minus)
        w3 = BM.lowest_base_mode(cfg, 0.002, 1 - 1e-3)
        w4 = BM.lowest_base_mode(cfg, 0.002, 1 - 1e-4)
        assert w4 / w3 == pytest.approx(np.sqrt(10), rel=2e-3)
        assert BM.rb_band_top(cfg, 0.002) == pytest.approx(127.0, abs=0.5)
    assert BM.rb_band_top(ColumnConfig(n_prisms=20), 0.0) == pytest.approx(126.6, abs=0.5)


def test_ratio_depends_on_geometry_n_p_and_beta_only():
    cfg = ColumnConfig(n_prisms=12)
    r0 = BM.base_mode_ratio(cfg, 0.002, 0.9999)
    for other in (dataclasses.replace(cfg, cable_modulus=3 * cfg.cable_modulus),
                  dataclasses.replace(cfg, unit_mass=0.1)):
        assert BM.base_mode_ratio(other, 0.002, 0.9999) == pytest.approx(r0, rel=1e-9)
    assert BM.base_mode_ratio(cfg, 0.002, 1.0) == np.inf


def test_long_columns_take_the_one_over_n_law():
    """Beyond MAX_EXACT_PRISMS the lowest base mode is scaled from a 60-prism column: within 1 % of
    the full eigenproblem at 80 prisms."""
    cfg = ColumnConfig(n_prisms=80)
    exact, _ = BM._omegas.__wrapped__(cfg, 0.002, 0.9999)
    assert BM.lowest_base_mode(cfg, 0.002, 0.9999) == pytest.approx(exact, rel=0.01)


def _table():
    data = json.loads((ROOT / "analysis" / "data" / "beta_limit.json").read_text())
    return data["E_convergence_t_0.3"]


def test_flag_against_the_measured_convergence_table():
    """Every decade of 1 - beta that gained less than 5x (a stall) ends at a flagged case, and no
    unflagged case gained less than 9x. The flag is recomputed here; the table is the engine's."""
    stalls = []
    for name, row in _table().items():
        cfg = ColumnConfig(n_prisms=row["n_prisms"])
        for r in row["rows"]:
            beta = 1.0 - r["one_minus_beta"]
            flag = BM.beta_limit_measures(cfg, {"prestrain": 0.002, "base_rigidity": beta}, 1,
                                          row["peak_compression"])["beta_limit_flag"][0]
            assert flag == r["beta_limit_flag"], (name, r)
            gain = r.get("gain_over_the_decade")
            if gain is None:
                continue
            if gain < 5:
                stalls.append((name, r["one_minus_beta"]))
                assert BM.BETA_LIMIT_FLAGS[flag] == "slow_convergence_possible", (name, r)
            elif BM.BETA_LIMIT_FLAGS[flag] == "regular":
                assert gain >= 9, (name, r)
    # the 50-prism stall at the lock is among them, and 15-20 prisms converge unflagged from 1e-4 on
    assert ("50_prisms_v0_0.1", 1e-4) in [(n, pytest.approx(b)) for n, b in stalls]
    for name in ("15_prisms_v0_0.1", "20_prisms_v0_0.1"):
        assert all(r["beta_limit_flag"] == 0 for r in _table()[name]["rows"] if r["one_minus_beta"] <= 1e-4)


def test_the_amplitude_gate():
    """Base modes within reach but a pulse below half the lock: regular (50 prisms, v0 = 0.003
    converged 10x per decade); at or above it, or unknown (NaN), slow_convergence_possible."""
    f = BM.beta_limit_measures(PAPER, {"prestrain": 0.002, "base_rigidity": np.array([0.9999] * 3 + [1.0])}, 4,
                               np.array([0.49 * LOCK, 0.5 * LOCK, np.nan, 0.2]))
    assert [BM.BETA_LIMIT_FLAGS[k] for k in f["beta_limit_flag"]] == [
        "regular", "slow_convergence_possible", "slow_convergence_possible", "rigid_bases"]
    assert np.isnan(f["base_mode_ratio"][3]) and f["base_mode_ratio"][0] == pytest.approx(1.062, abs=2e-3)


def test_sweep_datasets_carry_the_flag(ci_small_nc):
    """ci_small through the CLI (conftest's session run): both variables per case, CF attributes,
    NaN/rigid at beta = 1."""
    from warp_tensegrity.io import open_sweep

    ds = open_sweep(ci_small_nc)
    r, f = ds["base_mode_ratio"], ds["beta_limit_flag"]
    assert r.attrs["units"] == "1" and "long_name" in r.attrs
    assert f.attrs["flag_meanings"].split() == list(BM.BETA_LIMIT_FLAGS)
    np.testing.assert_array_equal(f.attrs["flag_values"], [0, 1, 2])
    rb = ds.base_rigidity.values == 1.0
    assert np.isnan(r.sel(base_rigidity=1.0).values).all() and (f.sel(base_rigidity=1.0).values == 2).all()
    assert np.isfinite(r.sel(base_rigidity=0.0).values).all() and rb.any()
    from warp_tensegrity.sweep.spec import load_spec

    cfg = load_spec(ROOT / "sweeps" / "ci_small.toml").scene
    for p in ds.prestrain.values:
        expect = BM.base_mode_ratio(cfg, float(p), 0.0)
        np.testing.assert_allclose(r.sel(prestrain=p, base_rigidity=0.0).values, expect, rtol=1e-12)


@pytest.mark.parametrize("beta", [0.0, 0.9999, 1.0])
def test_modes_agree_with_the_independent_linear_check(beta):
    """scene.base_modes computes its own modes (sweeps must not depend on the validation references): they agree with
    validation.linear.modal_analysis to round-off."""
    from warp_tensegrity.validation.linear import modal_analysis
    from warp_tensegrity.scene.columns import build_column

    net = build_column(ColumnConfig(n_prisms=6), prestrain=0.002, base_rigidity=beta).network
    mine, share = BM.modes(net)
    ref = modal_analysis(net).omega
    np.testing.assert_allclose(mine, ref, rtol=1e-9, atol=1e-9 * ref.max())
    if 0 < beta < 1:  # stiff bases: three in-plane base modes per free level, cleanly separated
        assert (share > 0.5).sum() == 3 * 6 and (share[share > 0.5] > 0.99).all()


# ---------------------------------------------------------------- bit-identity of the fast assembly
def _reference_modes(net):
    """modes() as first written (issue 25): a Python loop over the members, everything recomputed
    per call. The fast modes() must return the same bits (issue 33 item 5)."""
    x = np.asarray(net.positions, dtype=np.float64)
    free_nodes = np.flatnonzero(~np.asarray(net.fixed, dtype=bool))
    slot = -np.ones(len(x), dtype=np.int64)
    slot[free_nodes] = np.arange(len(free_nodes))
    nd = 3 * len(free_nodes)
    bars, cables = np.asarray(net.bars).reshape(-1, 2), np.asarray(net.cables).reshape(-1, 2)

    def pairs(i, j):
        return [(slot[i], 1.0), (slot[j], -1.0)]

    G = np.zeros((len(bars), nd))
    for k, (i, j) in enumerate(bars):
        b = x[j] - x[i]
        for s_, g in pairs(i, j):
            if s_ >= 0:
                G[k, 3 * s_ : 3 * s_ + 3] -= g * b
    d = x[cables[:, 1]] - x[cables[:, 0]]
    length = np.linalg.norm(d, axis=1)
    rest = np.asarray(net.cable_rest_length, dtype=np.float64)
    at_rest = np.abs(length - rest) <= 1e-12 * rest
    k_br = np.where(at_rest | (length > rest), np.asarray(net.cable_EA, float),
                    np.asarray(net.cable_EA_compression, float)) / rest
    tension = np.where(at_rest, 0.0, k_br * (length - rest))
    e = d / length[:, None]
    f = np.zeros(nd)
    K = np.zeros((nd, nd))
    eye = np.eye(3)

    def add(i, j, blk):
        for sa, ga in pairs(i, j):
            for sb, gb in pairs(i, j):
                if sa >= 0 and sb >= 0:
                    K[3 * sa : 3 * sa + 3, 3 * sb : 3 * sb + 3] += ga * gb * blk

    for c, (i, j) in enumerate(cables):
        for s_, g in pairs(i, j):
            if s_ >= 0:
                f[3 * s_ : 3 * s_ + 3] += g * tension[c] * e[c]
        ee = np.outer(e[c], e[c])
        add(i, j, k_br[c] * ee + tension[c] / length[c] * (eye - ee))
    lam = np.linalg.lstsq(G.T, f, rcond=None)[0] if len(bars) else np.zeros(0)
    for k, (i, j) in enumerate(bars):
        add(i, j, lam[k] * eye)
    K = 0.5 * (K + K.T)
    if len(bars):
        _, sv, vt = np.linalg.svd(G)
        Z = vt[int(np.sum(sv > 1e-10 * sv[0])):].T
    else:
        Z = np.eye(nd)
    M = np.kron(np.asarray(net.mass_matrix())[np.ix_(free_nodes, free_nodes)], eye)
    mu, U = np.linalg.eigh(Z.T @ M @ Z)
    Mih = (U / np.sqrt(mu)) @ U.T
    H = Mih @ (Z.T @ K @ Z) @ Mih
    w2, Y = np.linalg.eigh(0.5 * (H + H.T))
    shapes = (Z @ (Mih @ Y)).T.reshape(len(w2), -1, 3)
    base = np.abs(d[:, 2]) <= 1e-12 * np.abs(d).max()
    u = np.zeros((len(w2), len(x), 3))
    u[:, free_nodes] = shapes
    ext = np.einsum("mci,ci->mc", u[:, cables[base, 1]] - u[:, cables[base, 0]], e[base])
    e_base = 0.5 * (k_br[base] * ext**2).sum(axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        share = np.where(w2 > 0, e_base / (0.5 * w2), 0.0)
    return np.sign(w2) * np.sqrt(np.abs(w2)), share


def _phase_large():
    from warp_tensegrity.sweep.spec import load_spec

    spec = load_spec(ROOT / "sweeps" / "phase_large.toml")
    return spec.scene, spec.column_params()


def _assert_same_bits_as_the_loop(cfg, params):
    """modes() against _reference_modes() per distinct (prestrain, beta), and beta_limit_measures'
    ratio and flag against the ratio recomputed from the reference modes: equal to the last bit."""
    from warp_tensegrity.scene.blas import one_blas_thread
    from warp_tensegrity.scene.columns import build_column

    with one_blas_thread():  # as the sweep computes them: the last bits of an eigensolve may depend on the threads
        _same_bits(cfg, params, build_column)


def _same_bits(cfg, params, build_column):
    BM._omegas.cache_clear()
    BM._constraint_basis.cache_clear()
    p, b = params["prestrain"], params["base_rigidity"]
    q = np.linspace(0.0, LOCK, len(p))  # both sides of the amplitude gate
    got = BM.beta_limit_measures(cfg, params, len(p), q)
    ref_min, ref_top = {}, {}
    for pi, bi in sorted({(float(x), float(y)) for x, y in zip(p, b)}):
        net = build_column(cfg, prestrain=pi, v0=0.0, base_rigidity=bi).network
        w, s = BM.modes(net)
        w_ref, s_ref = _reference_modes(net)
        assert w.tobytes() == w_ref.tobytes() and s.tobytes() == s_ref.tobytes(), (pi, bi)
        if bi >= 1.0:
            ref_top[pi] = float(w_ref.max())
        else:
            ref_min[pi, bi] = float(w_ref[s_ref > 0.5].min())
    ratio = np.array([ref_min[x, y] / ref_top[x] if y < 1.0 else np.nan for x, y in zip(p, b)])
    assert got["base_mode_ratio"].tobytes() == ratio.tobytes()
    flag = np.where(b >= 1.0, 2, np.where((ratio < BM.BAND_FACTOR) & ~(q < BM.LOCK_FRACTION * LOCK), 1, 0))
    np.testing.assert_array_equal(got["beta_limit_flag"], flag)
    assert got["beta_limit_flag"].dtype == np.int8 and set(flag.tolist()) == {0, 1, 2}


def test_fast_modes_match_the_loop_bit_for_bit():
    """A few of phase_large's pairs (both base classes, p = 0 and the largest p) and a 6-prism
    column (another geometry through the shared-basis cache)."""
    cfg, params = _phase_large()
    keep = np.isin(params["prestrain"], params["prestrain"][[0, -1]]) & np.isin(params["base_rigidity"], [0.0, 0.95, 1.0])
    _assert_same_bits_as_the_loop(cfg, {k: v[keep] for k, v in params.items()})
    _assert_same_bits_as_the_loop(ColumnConfig(n_prisms=6), {"prestrain": np.array([0.002, 0.002, 0.0, 0.0]),
                                                             "base_rigidity": np.array([0.5, 1.0, 0.5, 1.0])})


@pytest.mark.slow  # 96 pairs, each twice (~10 s on 2 cores)
def test_fast_modes_match_the_loop_bit_for_bit_on_phase_large():
    """All of phase_large's 96 distinct (prestrain, base_rigidity) pairs."""
    _assert_same_bits_as_the_loop(*_phase_large())
