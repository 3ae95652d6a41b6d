"""The Warp engine against conservation laws, its own convergence order and batch invariances."""

import numpy as np
import pytest

from warp_tensegrity import ColumnConfig, RunSettings, SettingsError, simulate_batch

SMALL = ColumnConfig(n_prisms=6, impact_admissibility="end_twist")  # the regime these properties are stated for
# integrator-property tests use the impulse-projected impact: a gentler start that keeps the
# dynamics in the regime each property is stated for (the default end_twist impact is 50x stronger)
GENTLE = ColumnConfig(n_prisms=6, impact_admissibility="project", end_base_mass="full")
PAPER_CASES = {  # FB and RB, prestressed, strong impact: cables slacken and re-tighten
    "prestrain": [0.002, 0.002, 0.0, 0.0],
    "v0": [0.1, 0.1, 0.005, 0.005],
    "base_rigidity": [0.0, 1.0, 0.0, 1.0],
}


@pytest.mark.parametrize("method", ["rattle", "rk4", "yoshida4"])
@pytest.mark.parametrize("precision, bound", [("fp64", 1e-12), ("fp32", 1e-6)])
def test_bar_length_error_after_every_step(method, precision, bound, device):
    r = simulate_batch(SMALL, PAPER_CASES, RunSettings(t_end=0.3, method=method, precision=precision, device=device))
    assert np.all(r.status == 0)
    assert r.n_steps > 50
    # bar_length_error is the max over every step and bar of |l - L|/L after the projection
    assert np.all(r.bar_length_error <= bound), r.bar_length_error
    assert np.all(r.bar_length_error > 0)  # measured, not a placeholder


def _final_strain(method, dt, params, t_end=0.2, precision="fp64", device="cpu", cfg=SMALL):
    s = RunSettings(t_end=t_end, dt=dt, method=method, precision=precision, output_interval=t_end, device=device)
    r = simulate_batch(cfg, params, s)
    assert r.time[-1] == pytest.approx(t_end, rel=1e-12)
    return r


SMOOTH = {"prestrain": [0.01], "v0": [0.002], "base_rigidity": [0.0]}  # cables stay taut: smooth dynamics


def test_smooth_case_keeps_cables_taut(device):
    r = _final_strain("rk4", 0.2 / 400, SMOOTH, device=device)
    assert np.abs(r.strain[0, -1]).max() < 0.5 * 0.01  # strain well inside the prestrain


# The observed convergence orders (strain, displacement, velocity) are checked once, in
# tests/test_stability.py::test_observed_order_within_0p2.


def test_rattle_energy_error_scales_as_dt_squared(device):
    params = {"prestrain": [0.002, 0.002], "v0": [0.05, 0.05], "base_rigidity": [0.0, 1.0]}
    e = []
    for dt in (2e-3, 1e-3):
        s = RunSettings(t_end=1.0, dt=dt, method="rattle", output_interval=0.01, device=device)
        e.append(simulate_batch(GENTLE, params, s).energy_error)
    ratio = e[0] / e[1]
    assert np.all((ratio > 3.3) & (ratio < 4.8)), (e, ratio)


def test_rattle_energy_has_no_secular_drift(device):
    """Smooth (taut) dynamics: RATTLE's energy error oscillates at a fixed level over 40 s, ~3,000
    periods of the slowest mode; the late worst case equals the early one to a few percent.
    (Where cables slacken and re-tighten, the cable law's kink breaks the smoothness that backward
    error analysis needs, and the error random-walks instead; see the README.)"""
    params = {"prestrain": [0.01], "v0": [0.002], "base_rigidity": [0.0]}
    s = RunSettings(t_end=40.0, dt=2e-3, output_interval=0.02, device=device)
    cfg = ColumnConfig(n_prisms=4, impact_admissibility="project", end_base_mass="full")
    r = simulate_batch(cfg, params, s)
    E = r.kinetic_energy[0] + r.elastic_energy[0]
    dev = np.abs(E - E[0]) / r.kinetic_energy[0, 0]
    half = len(dev) // 2
    assert 1e-4 < dev[:half].max() < 1e-2  # a real O(dt^2) error, resolved
    assert dev[half:].max() < 1.05 * dev[:half].max()
    params = {"prestrain": [0.002], "v0": [0.1], "base_rigidity": [0.0]}
    # RK4 by contrast dissipates: its energy decays monotonically at coarse dt
    r4 = simulate_batch(cfg, params, RunSettings(t_end=40.0, dt=8e-3, method="rk4", output_interval=0.02, device=device))
    E4 = r4.kinetic_energy[0] + r4.elastic_energy[0]
    assert E4[-1] < E4[0]


def test_column_alone_equals_column_in_batch_of_1000(device):
    rng = np.random.default_rng(0)
    B = 1000
    params = {
        "prestrain": rng.uniform(0, 0.01, B),
        "v0": rng.uniform(0.001, 0.1, B),
        "base_rigidity": rng.choice([0.0, 0.5, 1.0], B),
        "unit_mass": rng.uniform(0.01, 0.03, B),
    }
    cfg = ColumnConfig(n_prisms=3)
    s = RunSettings(t_end=0.05, dt=1e-3, output_interval=0.01, device=device)
    big = simulate_batch(cfg, params, s)
    for b in (0, 417, 999):
        one = simulate_batch(cfg, {k: v[b : b + 1] for k, v in params.items()}, s)
        np.testing.assert_array_equal(one.strain[0], big.strain[b])
        np.testing.assert_array_equal(one.kinetic_energy[0], big.kinetic_energy[b])
        assert one.bar_length_error[0] == big.bar_length_error[b]


def test_diverging_column_is_frozen_and_flagged_others_unharmed(device):
    cfg = ColumnConfig(n_prisms=4)
    good = {"prestrain": [0.002, 0.0, 0.002], "v0": [0.1, 0.002, 0.1], "base_rigidity": [0.0, 1.0, 1.0]}
    bad = {"prestrain": [0.002, 0.0, 0.0, 0.002], "v0": [0.1, 1e4, 0.002, 0.1], "base_rigidity": [0.0, 0.0, 1.0, 1.0]}
    s = RunSettings(t_end=0.2, dt=2e-3, output_interval=0.01, device=device, allow_unstable_dt=True)
    rb = simulate_batch(cfg, bad, s)
    rg = simulate_batch(cfg, good, s)
    assert rb.status[1] != 0 and rb.fail_step[1] >= 1
    assert np.all(rb.status[[0, 2, 3]] == 0) and np.all(rb.fail_step[[0, 2, 3]] == -1)
    np.testing.assert_array_equal(rb.strain[[0, 2, 3]], rg.strain)
    np.testing.assert_array_equal(rb.bar_length_error[[0, 2, 3]], rg.bar_length_error)
    # the frozen column's history stops at its failure, marked NaN after
    assert np.isnan(rb.strain[1, -1]).all()


def test_unstable_explicit_dt_is_refused_with_the_limit():
    with pytest.raises(SettingsError, match=r"exceeds the stability limit .* of method 'rattle'"):
        simulate_batch(SMALL, {"v0": [0.01]}, RunSettings(t_end=1.0, dt=0.05, device="cpu"))


@pytest.mark.parametrize(
    "kw, match",
    [
        (dict(method="euler"), "method = 'euler'"),
        (dict(precision="fp16"), "precision = 'fp16'"),
        (dict(t_end=-1.0), "t_end = -1.0"),
        (dict(dt="fast"), "dt = 'fast'"),
        (dict(dt=0.0), "dt = 0.0"),
    ],
)
def test_bad_settings_are_named(kw, match):
    with pytest.raises(SettingsError, match=match):
        RunSettings(**kw)


def test_unknown_device_is_a_clear_error():
    with pytest.raises(SettingsError, match="device = 'cuda:7'"):
        simulate_batch(SMALL, {"v0": [0.01]}, RunSettings(t_end=0.01, device="cuda:7"))
