"""The striker (scene impact = 'striker', issue 34 item 2; docs/impact.md): what is refused, the blow, the
records and their dataset variables, and the large mass ratio (must-show 5)."""

import numpy as np
import pytest

from warp_tensegrity import ColumnConfig, RunSettings, simulate_batch
from warp_tensegrity.options import SettingsError
from warp_tensegrity.policy.decide import decide
from warp_tensegrity.policy.paths import STRIKER_PATH
from warp_tensegrity.scene.batch import column_batch
from warp_tensegrity.scene.network import NetworkError
from warp_tensegrity.validation.closed_forms import rb_chain
from warp_tensegrity.validation.striker import striker_chain


@pytest.mark.parametrize("kwargs, message", [
    ({"striker_mass": -1.0}, "striker_mass = -1.0: must lie in [0, 1e+06] [kg]"),
    ({"striker_mass": 0.1, "impact_admissibility": "end_twist"},
     "impact_admissibility = 'end_twist': impact = 'striker' needs impact_admissibility = 'rigid_members'"),
    ({"striker_mass": 0.1, "contact": "bars", "bar_radius": 2e-4}, "contact = 'bars': impact = 'striker' needs"),
    ({"striker_mass": 0.1, "n_prisms": 1, "bar_mass": 0.01}, "bar_mass = 0.01: impact = 'striker' needs massless"),
])
def test_what_the_striker_refuses(kwargs, message):
    """A zero (or negative) striker mass and the combinations the model does not cover: one line naming
    the option and its value."""
    with pytest.raises(NetworkError) as e:
        ColumnConfig(impact="striker", **kwargs)
    assert message in str(e.value) and "\n" not in str(e.value)


@pytest.mark.parametrize("params, message", [
    ({}, "striker_mass = 0.0: impact = 'striker' needs a striker mass > 0 [kg]"),
    ({"striker_mass": [0.1, 0.0]}, "striker_mass[1] = 0.0: impact = 'striker' needs a striker mass > 0 [kg]"),
    ({"striker_mass": [0.1, -2.0]}, "striker_mass[1] = -2.0: must lie in [0, 1e+06] [kg]"),
])
def test_a_striker_without_mass_is_refused(params, message):
    """The mass is per column (the scene's is the default): zero is refused where the batch is built."""
    with pytest.raises(NetworkError) as e:
        column_batch(ColumnConfig(n_prisms=3, impact="striker"), {"v0": 0.01, **params})
    assert str(e.value) == message


def test_the_striker_takes_the_staged_rattle_step():
    cfg = ColumnConfig(n_prisms=6, impact="striker", striker_mass=0.1)
    p = {"prestrain": 0.002, "v0": 0.01, "base_rigidity": 1.0}
    plan = decide(cfg, p, RunSettings(t_end=1.0, device="cpu"))
    assert plan.path.value == "staged" and any(STRIKER_PATH in r for r in plan.reasons)
    assert plan.prisms_simulated == 6  # never truncated: it keeps pushing
    with pytest.raises(SettingsError, match="method = 'rk4': the striker"):
        decide(cfg, p, RunSettings(t_end=1.0, device="cpu", method="rk4"))
    with pytest.raises(SettingsError, match="fused = 'lanes': the striker runs on the staged kernels only"):
        decide(cfg, p, RunSettings(t_end=1.0, device="cpu", fused="lanes"))


@pytest.mark.parametrize("beta", [0.0, 1.0])
def test_the_blow(beta):
    """After the plastic blow the column moves with the rigid_members field at V1 = v0 M / (M + m_end),
    m_end the end's effective mass (for RB the chain's end mass m_eff/2), and so does the striker."""
    M, v0 = np.array([0.07, 0.3]), 0.02  # per column
    cfg = ColumnConfig(n_prisms=5, impact="striker")
    p = {"prestrain": 0.002, "v0": [v0, 2 * v0], "base_rigidity": beta}
    b = column_batch(cfg, {**p, "striker_mass": M})
    ref = column_batch(ColumnConfig(n_prisms=5), p)
    m_end = b.striker_end_mass
    if beta == 1.0:
        np.testing.assert_allclose(m_end, 0.5 * rb_chain(cfg.cable_EA, cfg.radius, cfg.height, cfg.unit_mass, 0.0).m_eff,
                                   rtol=1e-12)
    V1 = np.array([v0, 2 * v0]) * M / (M + m_end)
    np.testing.assert_allclose(-b.striker_velocity, V1, rtol=1e-14)
    np.testing.assert_allclose(b.velocity, ref.velocity * (V1 / np.array([v0, 2 * v0]))[:, None, None], rtol=1e-14,
                               atol=1e-18)
    # the end nodes move down at V1, the striker with them; momentum along the blow is kept
    np.testing.assert_allclose(b.velocity[:, b.striker_nodes, 2], -V1[:, None] * np.ones(3), rtol=1e-12)
    kinetic = 0.5 * np.einsum("bn,bnk->b", np.broadcast_to(b.node_mass, (2, b.node_mass.shape[1])), b.velocity**2)
    np.testing.assert_allclose(kinetic, 0.5 * m_end * V1**2, rtol=1e-12)


def test_records_and_dataset_variables(tmp_path):
    """A short run: energy (column + striker) kept to the integrator's order, the face on the end base's
    mean height to round-off, and the CF variables of the striker in the dataset (CF-clean)."""
    cfg = ColumnConfig(n_prisms=4, impact="striker", striker_mass=0.05)
    r = simulate_batch(cfg, {"prestrain": 0.002, "v0": 0.05, "base_rigidity": 1.0},
                       RunSettings(t_end=0.3, dt=5e-4, output_interval=0.01, device="cpu", precision="fp64"))
    s = r.info["striker"]
    assert int(r.status[0]) == 0 and r.energy_error[0] < 1e-4
    assert s["contact_residual"][0] < 1e-14
    assert 0.0 < s["separation_time"][0] <= s["last_separation_time"][0] < 0.3
    assert s["velocity"][0, -1] > 0  # pushed back: it flies off upward
    assert s["force"][0].min() >= 0.0 and s["force"][0].max() > 0.0
    # the energy shares are of the impact energy, the striker's included (measure.energy.impact_energy)
    from warp_tensegrity.measure.energy import impact_energy

    e0 = impact_energy(r.kinetic_energy[:, 0], s)
    np.testing.assert_allclose(e0, r.kinetic_energy[:, 0] + 0.5 * 0.05 * s["velocity"][:, 0] ** 2, rtol=1e-15)
    ds = r.to_xarray(cfg)
    for name, units, dims in (("striker_velocity", "m s-1", ("case", "t")), ("striker_force", "N", ("case", "t")),
                              ("striker_separation_time", "s", ("case",)), ("striker_mass", "kg", ()),
                              ("striker_last_separation_time", "s", ("case",))):
        assert ds[name].dims == dims and ds[name].attrs["units"] == units and ds[name].attrs["long_name"]
    np.testing.assert_array_equal(ds["striker_velocity"].values, s["velocity"])
    pytest.importorskip("compliance_checker.runner")
    from tests.test_cf import cf_messages

    ds.to_netcdf(tmp_path / "striker.nc")
    scores, messages = cf_messages(tmp_path / "striker.nc", tmp_path)
    assert scores["scored_points"] == scores["possible_points"] and not messages, messages


def test_a_heavy_striker_is_a_piston_not_the_velocity_impact():
    """Must-show 5 (docs/impact.md, "The limit of a heavy striker"). At M = 1e3 x the column's mass the
    state after the blow is the velocity impact's to m_end / (M + m_end) (4.5e-4 here, under the
    accuracy target 1e-3), and the engine's record matches the exact linear response to the same striker to the
    accuracy target. That response is a piston (the striker keeps v0 within 1 %), not the velocity impact:
    their strain records differ by a third of the peak and more."""
    N, p = 8, 0.002
    cfg = ColumnConfig(n_prisms=N)
    ch = rb_chain(cfg.cable_EA, cfg.radius, cfg.height, cfg.unit_mass, p)
    M = 1e3 * N * cfg.unit_mass
    v0 = 0.005 * p * ch.c0 / 0.58
    params = {"prestrain": p, "v0": v0, "base_rigidity": 1.0}
    settings = RunSettings(t_end=1.0, dt=1e-3, output_interval=0.01, device="cpu", precision="fp64", truncate=False)
    striker = ColumnConfig(n_prisms=N, impact="striker", striker_mass=M)
    b0, b1 = column_batch(cfg, params), column_batch(striker, params)
    blow = np.abs(b1.velocity - b0.velocity).max() / np.abs(b0.velocity).max()
    assert blow < 1e-3 and blow == pytest.approx(b1.striker_end_mass[0] / (M + b1.striker_end_mass[0]))
    r = simulate_batch(striker, params, settings)
    ref = striker_chain(ch, N, M, v0, r.time)
    peak = np.abs(ref.strain).max()
    assert np.abs(r.strain[0] - ref.strain).max() / peak < 1e-3
    assert np.abs(r.info["striker"]["velocity"][0] / v0 + 1).max() < 1e-2  # the striker keeps v0 (0.4 % off by 1 s)
    velocity_impact = simulate_batch(cfg, params, settings)
    assert np.abs(velocity_impact.strain[0] - r.strain[0]).max() / peak > 0.3


def test_fp32_keeps_the_contact_that_fp64_keeps():
    """A touching striker is not taken for gone by the round-off of the gap: fp32 leaves where fp64 does
    (within a step), not at the first step (the gap's tolerance, sim.staged.striker.striker_iterate)."""
    cfg = ColumnConfig(n_prisms=6, impact="striker", striker_mass=0.1)
    seps = []
    for precision in ("fp32", "fp64"):
        r = simulate_batch(cfg, {"prestrain": 0.002, "v0": 0.01, "base_rigidity": 1.0},
                           RunSettings(t_end=0.3, dt=5e-4, output_interval=0.01, device="cpu", precision=precision))
        seps.append(float(r.info["striker"]["separation_time"][0]))
    assert seps[1] == pytest.approx(0.167, abs=1e-3) and abs(seps[0] - seps[1]) <= 5e-4 + 1e-12, seps


def test_a_striker_on_a_preloaded_column_is_refused():
    with pytest.raises(NetworkError, match=r"preload\[1\] = 0.01: a striker on a preloaded column is not modelled"):
        column_batch(ColumnConfig(n_prisms=3, impact="striker", striker_mass=0.1),
                     {"v0": 0.01, "prestrain": 0.002, "preload": [0.0, 0.01]})
