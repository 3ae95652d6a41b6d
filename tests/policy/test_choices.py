"""Model no more than a scene needs: accuracy-driven choices and truncation to the reachable prisms."""

import numpy as np
import pytest

from warp_tensegrity.policy.accuracy import for_accuracy, reachable_prisms
from warp_tensegrity import ColumnConfig, RunSettings, SettingsError, simulate_batch
from warp_tensegrity.sweep import SpecError, load_spec as load_spec_text

CASES = {"prestrain": [0.002, 0.002, 0.0], "v0": [0.1, 0.1, 0.005], "base_rigidity": [0.0, 1.0, 0.0]}


@pytest.mark.parametrize(
    "acc, method, precision",
    [(3e-2, "rattle", "fp32"), (1e-3, "rattle", "fp32"), (3e-4, "rk4", "fp32"), (1e-6, "rk4", "fp64")],
)
def test_accuracy_table(acc, method, precision):
    c = for_accuracy(acc)
    assert (c["method"], c["precision"]) == (method, precision)
    assert 0 < c["dt_safety"] <= 0.5


def test_tighter_accuracy_never_costs_less():
    """Force evaluations per simulated second (in units of omega_max) grow as the accuracy tightens.
    (RK4 may take a larger step than RATTLE: it is the cheaper route below ~1e-3, as measured.)"""
    from warp_tensegrity.types import FORCE_EVALS, STABILITY

    accs = np.logspace(-1.5, -7, 40)
    cost = []
    for a in accs:
        c = for_accuracy(a)
        cost.append(FORCE_EVALS[c["method"]] / (c["dt_safety"] * STABILITY[c["method"]]))
    assert np.all(np.diff(cost) >= -1e-12)


def test_engine_reports_what_it_chose(device):
    r = simulate_batch(ColumnConfig(n_prisms=4), CASES, RunSettings(t_end=0.05, accuracy=3e-5, device=device))
    ch = r.info["choices"]
    want = for_accuracy(3e-5, n_prisms=4)
    assert (ch["accuracy"], ch["method"], ch["precision"]) == (3e-5, want["method"], want["precision"])
    assert (r.method, r.precision) == (want["method"], want["precision"]) == ("rk4", "fp64")
    with pytest.raises(SettingsError, match="give one of them"):
        simulate_batch(ColumnConfig(n_prisms=4), CASES, RunSettings(t_end=0.05, dt=1e-3, accuracy=1e-3, device=device))


def test_reachable_prisms_bound():
    assert reachable_prisms(200.0, 0.1, 400) == 28
    assert reachable_prisms(200.0, 10.0, 50) == 50


ELASTIC_BASES = {"prestrain": [0.002, 0.002, 0.0], "v0": [0.1, 0.1, 0.005], "base_rigidity": [0.0, 0.5, 0.0]}


@pytest.mark.parametrize(
    "handedness, cases",
    [("right", CASES), ("alternating", ELASTIC_BASES), ("RRL" * 15, ELASTIC_BASES)],
)
def test_truncated_column_equals_full_column(handedness, cases, device):
    """The prisms beyond the reach of the front stay at rest: truncation changes nothing measurable."""
    cfg = ColumnConfig(n_prisms=45, handedness=handedness)
    s = dict(t_end=0.08, dt=1e-3, output_interval=0.01, device=device)
    full = simulate_batch(cfg, cases, RunSettings(truncate=False, **s))
    cut = simulate_batch(cfg, cases, RunSettings(truncate=True, **s))
    assert cut.info["choices"]["prisms_simulated"] < 45 == full.info["choices"]["prisms_simulated"]
    assert cut.strain.shape == full.strain.shape
    scale = np.abs(full.strain).max()
    assert np.abs(cut.strain - full.strain).max() < 1e-8 * scale  # round-off, grown by FB dynamics
    E = lambda r: r.kinetic_energy + r.elastic_energy  # noqa: E731
    assert np.abs(E(cut) - E(full)).max() < 1e-12 * full.kinetic_energy[:, 0].max()
    assert np.abs(cut.final_displacement - full.final_displacement).max() < 1e-8 * np.abs(full.final_displacement).max()
    # the far prisms really are at rest in the full run (the premise of truncation)
    n_cut = 45 - cut.info["choices"]["prisms_simulated"]
    assert np.abs(full.strain[:, :, :n_cut]).max() < 1e-8 * scale  # only an exponentially small precursor


SPEC = """
[scene]
n_prisms = 4
[sweep]
grid.v0 = [0.01, 0.02]
[run]
t_end = 0.05
{run}
"""


def test_spec_accuracy_chooses_and_conflicts_are_refused():
    spec = load_spec_text(SPEC.format(run="accuracy = 1e-5"))
    assert (spec.run["method"], spec.run["precision"]) == ("rk4", "fp64")
    with pytest.raises(SpecError, match="run.method .* conflicts with run.accuracy"):
        load_spec_text(SPEC.format(run='accuracy = 1e-3\nmethod = "rattle"'))
    with pytest.raises(SpecError, match="run.accuracy"):
        load_spec_text(SPEC.format(run="accuracy = 2.0"))


@pytest.mark.parametrize("handedness", ["alternating", "RRL" * 15])
def test_mixed_handed_rigid_base_columns_are_never_truncated(handedness, device):
    """Rigid links in a mixed-handed column carry motion far ahead of the front (measured: the full
    run's far prisms move at 1e-8 where truncation would clamp them), so the engine keeps them all."""
    cfg = ColumnConfig(n_prisms=45, handedness=handedness)
    s = dict(t_end=0.08, dt=1e-3, output_interval=0.01, device=device)
    full = simulate_batch(cfg, CASES, RunSettings(truncate=False, **s))
    auto = simulate_batch(cfg, CASES, RunSettings(truncate=True, **s))
    assert auto.info["choices"]["prisms_simulated"] == 45
    np.testing.assert_array_equal(auto.strain, full.strain)


def test_run_batch_with_the_default_settings_decides_dt_as_the_stability_rule_does():
    """run_batch(batch, RunSettings()) (dt 'auto', no dt_safety, no accuracy): the plan takes the
    default accuracy's fraction of the stability limit over the reference column, as the time-step
    rule does on its own, and says so in its reasons (it raised a TypeError formatting them)."""
    from warp_tensegrity import column_batch, run_batch
    from warp_tensegrity.policy.accuracy import choose_timestep, default_dt_safety
    from warp_tensegrity.policy.decide import decide_batch
    from warp_tensegrity.scene.batch import omega_max_bound

    batch = column_batch(ColumnConfig(n_prisms=2), {"v0": [0.01, 0.02]})
    s = RunSettings(t_end=0.01, device="cpu")
    plan = decide_batch(batch, s)
    dt, limit, n_steps, _ = choose_timestep(s, float(omega_max_bound(batch).max()))
    assert (plan.dt, plan.dt_limit, plan.n_steps) == (dt, limit, n_steps)
    assert plan.settings.dt_safety == default_dt_safety("rattle")[0] and "x the stability limit" in plan.reasons[0]
    r = run_batch(batch, s)
    assert r.dt == dt and (r.status == 0).all()
