"""Integrator orders, stability limits and long-time energy behaviour (CPU, small columns).

* observed orders within +-0.2 of 2 (RATTLE) and 4 (RK4, Yoshida) on a smooth case (taut cables);
* the measured stability limit of RATTLE and RK4 (largest dt without divergence) within 10 % of
  S / omega_max, with omega_max from the linear modal analysis of the reference network, for
  flexible and rigid bases;
* negative control: symplectic Euler is first order (velocities, energy), so the order-2 check
  rejects it;
* RATTLE's energy error has no secular trend over 1e5 steps, while the same trend check flags
  RK4's dissipation.
"""

import numpy as np
import pytest

from warp_tensegrity.scene.batch import column_batch, omega_max_bound
from warp_tensegrity import ColumnConfig, RunSettings, build_column, simulate_batch
from warp_tensegrity.validation.linear import omega_max
from warp_tensegrity.types import STABILITY

# the engine's default conventions at the time of writing, pinned so the regimes below hold
TINY = ColumnConfig(n_prisms=3, impact_admissibility="end_twist", end_base_mass="half")
# v0 = 0.002 keeps every cable taut (prism strain within +-0.005 at p = 0.01); with the end_twist
# impact v0 = 0.005 already compresses prisms past the prestrain (-0.0125), so cables go slack
SMOOTH = {"prestrain": [0.01], "v0": [0.002], "base_rigidity": [0.0]}
T_ORDER = 0.2  # s; omega_max dt = 0.31 .. 0.04 for n = 100 .. 800 steps (omega_max = 153 rad/s)


def _final_state(method, n, device, params=SMOOTH, t_end=T_ORDER):
    s = RunSettings(t_end=t_end, dt=t_end / n, method=method, output_interval=t_end / 100, device=device,
                    allow_unstable_dt=True)
    r = simulate_batch(TINY, params, s)
    assert r.n_steps == n and np.all(r.status == 0)
    assert r.time[-1] == pytest.approx(t_end, rel=1e-12)
    return r


@pytest.fixture(scope="module")
def reference(device):
    """RK4 at 3200 steps: its error (~1e-12) is far below the smallest error measured here."""
    r = _final_state("rk4", 3200, device)
    assert np.abs(r.strain).max() < 0.6 * SMOOTH["prestrain"][0]  # cables stay taut: smooth dynamics
    return r.final_displacement[0], r.final_velocity[0], r.strain[0, -1]


def _orders(method, ns, reference, device):
    """Observed orders of the final displacement, velocity and prism strain, and their errors."""
    ur, vr, sr = reference
    eu, ev, es = [], [], []
    for n in ns:
        r = _final_state(method, n, device)
        eu.append(np.abs(r.final_displacement[0] - ur).max() / np.abs(ur).max())
        ev.append(np.abs(r.final_velocity[0] - vr).max() / np.abs(vr).max())
        es.append(np.abs(r.strain[0, -1] - sr).max())
    eu, ev, es = np.array(eu), np.array(ev), np.array(es)
    return np.log2(eu[:-1] / eu[1:]), np.log2(ev[:-1] / ev[1:]), eu, ev, np.log2(es[:-1] / es[1:]), es


@pytest.mark.parametrize("method, order, ns", [
    ("rattle", 2, (100, 200, 400)),
    ("rk4", 4, (200, 400, 800)),  # the end_twist impulse excites the top modes: RK4 is asymptotic later
    ("yoshida4", 4, (100, 200, 400)),
])
def test_observed_order_within_0p2(method, order, ns, reference, device):
    """Displacement, velocity and the recorded prism strain (what the sweeps measure) converge at
    the method's order. (Formerly also tests/test_engine.py's strain-order check, within 0.3, on a
    6-prism column: merged here, on the same runs, with the tighter 0.2.)"""
    pu, pv, eu, ev, ps, es = _orders(method, ns, reference, device)
    assert ev[-1] > 1e-9, "errors must stay far above round-off for the order to mean anything"
    assert np.all(np.abs(pu - order) < 0.2), (pu, eu)
    assert np.all(np.abs(pv - order) < 0.2), (pv, ev)
    assert np.all(np.abs(ps - order) < 0.2), (ps, es)


def test_negative_control_symplectic_euler_is_first_order(reference, device):
    """Kick(dt)-drift is first order in the velocities, so the order-2 check must reject it.
    (Its positions coincide with RATTLE's here: the column starts at equilibrium, a(u0) = 0,
    so the half-step velocity offset that makes it first order vanishes from the positions.)"""
    pu, pv, eu, ev, _, _ = _orders("symplectic_euler", (800, 1600, 3200), reference, device)
    assert np.all(np.abs(pv - 1.0) < 0.2), (pv, ev)
    assert np.all(np.abs(pv - 2.0) > 0.5)  # fails the order-2 check
    # energy error O(dt) (RATTLE: O(dt^2)): halving dt halves it
    e = [_final_state("symplectic_euler", n, device, t_end=0.5).energy_error[0] for n in (500, 1000)]
    assert 1.7 < e[0] / e[1] < 2.3, e


# ---------------------------------------------------------------------------- stability limit
DIVERGED = 100.0  # energy_error above this (or a flagged column) counts as divergence


def _stable_at_ratios(method, omega, ratios, device, base, n_steps=300, dt0=1e-3):
    """One batch: copies of a column, copy c run at omega dt = ratios[c] * S.

    A column with masses scaled by s, impact speed by 1/sqrt(s) and step dt0 is the original
    column at step dt0 / sqrt(s) (time rescaled), so s = (omega dt0 / (r S))^2 puts copy c at r_c."""
    m0 = TINY.unit_mass
    mass = m0 * (omega * dt0 / (np.asarray(ratios) * STABILITY[method])) ** 2
    params = {k: np.full(len(ratios), v) for k, v in base.items()}
    params["unit_mass"] = mass
    params["v0"] = params["v0"] * np.sqrt(m0 / mass)
    s = RunSettings(t_end=n_steps * dt0, dt=dt0, method=method, output_interval=10 * dt0, device=device,
                    allow_unstable_dt=True, record_strain=False)
    r = simulate_batch(TINY, params, s)
    return (r.status == 0) & (r.energy_error < DIVERGED), r


@pytest.mark.parametrize("beta", [0.0, 1.0])
@pytest.mark.parametrize("method", ["rattle", "rk4"])
def test_measured_stability_limit_matches_prediction(method, beta, device):
    base = {"prestrain": 0.01, "v0": 1e-4, "base_rigidity": beta}  # linear regime, all cables taut
    w = omega_max(build_column(TINY, **base).network)  # exact, all cables taut
    ratios = np.geomspace(0.8, 1.25, 41)  # steps of 1.1 %
    stable, r = _stable_at_ratios(method, w, ratios, device, base)
    assert stable[0] and not stable[-1], stable
    first_bad = int(np.argmin(stable))
    assert not stable[first_bad:].any(), f"stability is not monotone in dt: {stable}"
    measured = np.sqrt(ratios[first_bad - 1] * ratios[first_bad])  # limit / predicted
    assert abs(measured - 1.0) < 0.10, measured
    # below the limit the energy error stays bounded well under the divergence threshold
    assert np.all(r.energy_error[: max(first_bad - 3, 1)] < 10.0), r.energy_error[:first_bad]
    # direct check without the mass scaling: the physical column at 0.95 and 1.05 x S / omega_max
    pred = STABILITY[method] / w
    verdict = []
    for f in (0.95, 1.05):
        s = RunSettings(t_end=300 * f * pred, dt=f * pred, method=method, output_interval=10 * f * pred,
                        device=device, allow_unstable_dt=True, record_strain=False)
        d = simulate_batch(TINY, {k: [v] for k, v in base.items()}, s)
        verdict.append(bool(d.status[0] == 0 and d.energy_error[0] < DIVERGED))
    assert verdict == [True, False], verdict
    # the engine's own limit uses an upper bound on omega_max, so it is on the safe side
    wb = omega_max_bound(column_batch(TINY, {k: [v] for k, v in base.items()}))[0]
    assert wb >= w


# ---------------------------------------------------------------------------- energy over 1e5 steps
def _envelope_trend(t, dev, n_win=20):
    """(slope * duration, max) of the windowed maximum of dev over time."""
    n = len(dev) // n_win * n_win
    env = dev[:n].reshape(n_win, -1).max(axis=1)
    tc = t[:n].reshape(n_win, -1).mean(axis=1)
    slope = np.polyfit(tc, env, 1)[0]
    return slope * (t[-1] - t[0]), dev.max()


def _energy_deviation(method, n_steps, frac, device):
    params = {"prestrain": [0.01, 0.01], "v0": [0.002, 0.002], "base_rigidity": [0.0, 1.0]}  # taut
    cfg = ColumnConfig(n_prisms=2, impact_admissibility="end_twist", end_base_mass="half")
    w = omega_max_bound(column_batch(cfg, params)).max()
    dt = frac * STABILITY[method] / w
    s = RunSettings(t_end=n_steps * dt, dt=dt, method=method, output_interval=100 * dt, device=device,
                    record_strain=False)
    r = simulate_batch(cfg, params, s)
    assert r.n_steps == n_steps and np.all(r.status == 0)
    E = r.kinetic_energy + r.elastic_energy
    return r.time[1:], (np.abs(E - E[:, :1]) / r.kinetic_energy[:, :1])[:, 1:]


@pytest.mark.slow  # 1e5 steps (~4 s)
def test_rattle_energy_has_no_secular_trend_over_1e5_steps(device):
    t, dev = _energy_deviation("rattle", 100_000, 0.5, device)  # large dt: error far above round-off
    for d in dev:  # FB and RB, taut cables
        assert d.max() > 1e-5
        trend, peak = _envelope_trend(t, d)
        assert abs(trend) < 0.1 * peak, (trend, peak)
        q = len(d) // 4
        assert d[-q:].max() < 1.1 * d[:q].max(), (d[:q].max(), d[-q:].max())
    # the same check flags a secular trend where there is one: RK4 dissipates energy
    t4, dev4 = _energy_deviation("rk4", 4000, 0.8, device)
    trend4, peak4 = _envelope_trend(t4, dev4[0])
    assert trend4 > 0.15 * peak4, (trend4, peak4)
