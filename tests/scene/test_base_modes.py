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
