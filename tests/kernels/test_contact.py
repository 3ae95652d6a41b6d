"""Bar contact on the staged path (issue 32 item 3, Must-show 3), on the CPU: below contact a run is
bit-identical to one without; an elastic contact conserves energy as the integrator does without
contact; no bar pair ever comes closer than 2 r; the engine agrees with an independent reduced
model (the rigid-base twist chain with a hard stop, SciPy); the policy routes contact runs to the
staged path. Each check carries a control that fails it (a constant scaled by 1.05, or contact off)."""

from dataclasses import replace

import numpy as np
import pytest

from warp_tensegrity import ColumnConfig, RunSettings, SettingsError, simulate_batch
from warp_tensegrity.policy.decide import decide
from warp_tensegrity.policy.paths import CONTACT_PATH, choose_path
from warp_tensegrity.scene.columns import column_topology
from warp_tensegrity.scene.contact import prism_pairs, segment_distance
from warp_tensegrity.types import Path
from warp_tensegrity.validation.twist_chain import TwistChain

R = 0.25e-3  # bar radius [m]: axes 0.5 mm apart at contact, twist 171.2 deg (1.77 mm at the reference)
NONE = ColumnConfig(n_prisms=30)
BARS = replace(NONE, contact="bars", bar_radius=R)
DT = 0.002 / 3  # 1.5 x the default step of these runs: the coarse end


def _run(cfg, params, t_end=0.3, dt=DT, **kw):
    s = RunSettings(t_end=t_end, dt=dt, output_interval=0.002, fused=False, device="cpu", truncate=False, **kw)
    return simulate_batch(cfg, params, s)


def _pair_distances(cfg, result):
    """(B,) smallest clamped segment distance [m] of the bar pairs of every prism at the final
    positions (host, an independent computation of the device's signed axis distance)."""
    topo = column_topology(cfg)
    x = topo.positions[None] + result.final_displacement
    P, Q = x[:, topo.bars[:, 0]], x[:, topo.bars[:, 1]]
    pairs = prism_pairs(topo.bars)
    return segment_distance(P[:, pairs[:, 0]], Q[:, pairs[:, 0]], P[:, pairs[:, 1]], Q[:, pairs[:, 1]]).min(axis=1)


def test_below_contact_a_run_is_bit_identical_to_one_without():
    """A weak RB and a weak FB pulse never bring bars within 2 r: every output equals the run
    without contact bit for bit (the staged path, which both take). Control: a pulse that touches
    (RB, v0 = 0.05) differs."""
    params = {"prestrain": 0.002, "v0": [0.01, 0.005, 0.05], "base_rigidity": [1.0, 0.0, 1.0]}
    off, on = _run(NONE, params), _run(BARS, params)
    c = on.info["contact"]
    assert c["impacts"][:2].tolist() == [0, 0] and np.all(c["min_distance"][:2] > 2 * R)
    assert c["impacts"][2] > 0  # the control touched
    for name in ("strain", "kinetic_energy", "elastic_energy", "final_displacement", "final_velocity",
                 "bar_length_error", "energy_error"):
        a, b = getattr(off, name), getattr(on, name)
        assert np.array_equal(a[:2], b[:2]), name
        assert not np.array_equal(a[2], b[2]), name


def test_elastic_contact_conserves_energy_as_the_integrator_does_without():
    """Restitution 1: the energy error of a strong RB pulse that hits the stop ~25 times (v0 = 0.1)
    is that of the same pulse without contact (which twists through pi instead), within 1.5x;
    at v0 = 0.2 (~65 impacts) it is the integrator's O(dt^2) error too: a quarter of it at dt/2.
    Control: restitution 1/1.05 loses more than 10x that error."""
    p = {"prestrain": 0.002, "v0": [0.1, 0.2], "base_rigidity": 1.0}
    off, on = _run(NONE, p), _run(BARS, p)
    assert np.all(on.status == 0) and np.all(on.info["contact"]["impacts"] > 50)
    assert on.energy_error[0] <= 1.5 * off.energy_error[0], (on.energy_error, off.energy_error)
    fine = _run(BARS, p, dt=DT / 2)
    ratio = on.energy_error / fine.energy_error
    assert np.all((ratio > 3.0) & (ratio < 5.5)), ratio
    lossy = _run(replace(BARS, restitution=1 / 1.05), p)
    assert np.all(lossy.energy_error > 10 * on.energy_error[0]), lossy.energy_error


@pytest.mark.parametrize("beta, v0", [(1.0, (0.1, 0.2)), (0.0, (0.15, 0.2))])
def test_no_bar_pair_ever_comes_closer_than_2r(beta, v0):
    """RB pulses that would twist through pi and FB pulses that would invert prisms: with contact,
    the device's smallest signed axis distance over every step, and the host's segment distance
    at the final positions, stay >= 2 r (to 1e-9). Controls: every pulse touches (2 r x 1.05 is
    broken), and without contact each compresses a prism past what contact allows (RB: to the
    crossing at twist pi; FB: through inversion)."""
    p = {"prestrain": 0.002, "v0": list(v0), "base_rigidity": beta}
    on = _run(BARS, p)
    assert np.all(on.status == 0)
    dmin = on.info["contact"]["min_distance"]
    assert np.all(dmin >= 2 * R * (1 - 1e-9)), dmin
    assert np.all(_pair_distances(BARS, on) >= 2 * R * (1 - 1e-9))
    assert np.all(dmin < 1.05 * 2 * R)  # the 1.05 control
    off = _run(NONE, p)
    squeeze_on, squeeze_off = np.nanmin(on.strain, axis=(1, 2)), np.nanmin(off.strain, axis=(1, 2))
    assert np.all(squeeze_off < squeeze_on - 0.005), (squeeze_off, squeeze_on)


@pytest.mark.slow
def test_engine_agrees_with_the_reduced_twist_chain():
    """The RB column (30 prisms, p = 0.002) under v0 = 0.1 and 0.2 m/s, where without contact the
    twist passes pi (199 and 227 deg): the engine with contact (e = 1, dt = 1/6 ms) against the
    symmetric twist chain with a hard stop at the contact twist, integrated by SciPy's DOP853 with
    an impact law at each event: strain histories within 5e-3 of the peak to t = 0.15 s. Control:
    the chain with the bar radius x 1.05 is off by more than 10x that."""
    t_end, v0 = 0.15, (0.1, 0.2)
    r = _run(BARS, {"prestrain": 0.002, "v0": list(v0), "base_rigidity": 1.0}, t_end=t_end, dt=DT / 4)
    chain = TwistChain(NONE, 0.002, bar_radius=R)
    assert np.degrees(chain.phi_c) == pytest.approx(171.19, abs=0.01)
    for b, v in enumerate(v0):
        ref = chain.simulate(v, t_end, times=r.time)
        peak = np.abs(ref.strain).max()
        assert ref.impacts > 5 and ref.twist.max() <= chain.phi_c + 1e-9
        assert np.abs(r.strain[b] - ref.strain).max() < 5e-3 * peak
        wrong = TwistChain(NONE, 0.002, bar_radius=1.05 * R).simulate(v, t_end, times=r.time)
        assert np.abs(r.strain[b] - wrong.strain).max() > 5e-2 * peak
    free = TwistChain(NONE, 0.002).simulate(0.1, 0.3)  # without contact: through the crossing
    assert np.degrees(free.twist.max()) > 195


def test_restitution_below_one_dissipates_and_keeps_2r():
    p = {"prestrain": 0.002, "v0": [0.1, 0.1], "base_rigidity": [1.0, 0.0]}
    for e in (0.0, 0.5):
        r = _run(replace(BARS, restitution=e), p, t_end=0.2)
        E = r.kinetic_energy + r.elastic_energy
        assert np.all(r.status == 0)
        assert E[0, -1] < 0.8 * E[0, 0]  # RB: the stop takes energy at each impact
        assert np.all(r.info["contact"]["min_distance"] >= 2 * R * (1 - 1e-9))


def test_contact_in_fp32_and_with_massive_bars():
    r = _run(BARS, {"prestrain": 0.002, "v0": 0.1, "base_rigidity": 1.0}, t_end=0.2, precision="fp32")
    assert r.status[0] == 0 and r.info["contact"]["impacts"][0] > 0
    assert r.info["contact"]["min_distance"][0] >= 2 * R * (1 - 1e-5)
    one = ColumnConfig(n_prisms=1, bar_mass=0.005)  # M^-1 couples a massive bar's two nodes
    p = {"prestrain": 0.002, "v0": [1.0, 1.0], "base_rigidity": [0.0, 1.0]}
    off = _run(one, p, t_end=0.05, dt=2.5e-4)
    on = _run(replace(one, contact="bars", bar_radius=R), p, t_end=0.05, dt=2.5e-4)
    assert np.all(on.status == 0) and np.all(on.info["contact"]["impacts"] > 0)
    assert np.all(on.energy_error <= 2 * off.energy_error + 1e-4), (on.energy_error, off.energy_error)
    assert np.all(on.info["contact"]["min_distance"] >= 2 * R * (1 - 1e-9))


def test_policy_routes_contact_to_the_staged_path():
    params = {"prestrain": 0.002, "v0": 0.1, "base_rigidity": 1.0}
    plan = decide(BARS, params, RunSettings(t_end=0.1, device="cpu"))
    assert plan.path == Path.STAGED and any(CONTACT_PATH in r for r in plan.reasons)
    assert decide(NONE, params, RunSettings(t_end=0.1, device="cpu")).path == Path.FUSED  # the CPU default
    s = RunSettings(t_end=0.1, device="cpu")
    for on_gpu in (False, True):
        assert choose_path(s, on_gpu, 4096, 6, None, contact=True) == Path.STAGED  # not the lane step
    for fused in (True, "lanes"):
        with pytest.raises(SettingsError, match="bar contact runs on the staged kernels"):
            decide(BARS, params, RunSettings(t_end=0.1, device="cpu", fused=fused))
    with pytest.raises(SettingsError, match="method = 'rk4': bar contact"):
        decide(BARS, params, RunSettings(t_end=0.1, device="cpu", method="rk4"))


def test_truncation_keeps_the_contact_compaction_front():
    """A strong impact with contact drives a compaction front (prisms locked at the contact
    compression pass the impact on rigidly) past the elastic bound that truncation uses: at
    v0 = 0.3 m/s on 120 RB prisms it is 68 prisms deep by t = 0.3 s, beyond that bound (55,
    margin included). prisms_to_simulate keeps it (the control: the bound without the contact term)."""
    from warp_tensegrity.policy.accuracy import reachable_prisms
    from warp_tensegrity.policy.decide import far_end, omega_bound, prisms_to_simulate

    cfg = replace(BARS, n_prisms=120)
    params = {"prestrain": 0.002, "v0": 0.3, "base_rigidity": 1.0}
    r = _run(cfg, params, t_end=0.3)
    reached = np.flatnonzero(np.nanmin(r.strain[0], axis=0) < -0.01)
    depth = cfg.n_prisms - reached.min()  # prisms from the impacted end the front compressed
    elastic = reachable_prisms(omega_bound(far_end(cfg, 4), params), 0.3, cfg.n_prisms)
    assert depth > elastic, (depth, elastic)
    assert prisms_to_simulate(cfg, params, RunSettings(t_end=0.3)) >= depth + 8
