"""With neither dt nor accuracy given, a run is within 0.5 % of the converged solution on pulse
amplitude and speed and within 1 % (RMS, of the peak) on the strain history, for the paper's
FB and RB columns (issue 16, part 3). Reference: the same engine at dt_safety = 0.01, whose own
error is checked against dt_safety = 0.02."""

import numpy as np
import pytest

from warp_tensegrity import ColumnConfig, RunSettings, simulate_batch
from warp_tensegrity.policy.accuracy import DEFAULT_ACCURACY, apply_accuracy, default_dt_safety, dt_fraction
from warp_tensegrity.measure import measure_pulse


def test_default_policy_is_the_accuracy_policy():
    s, choices = apply_accuracy(RunSettings(), 50)
    assert choices == {"accuracy": DEFAULT_ACCURACY, "accuracy_source": "default", "dt_safety": s.dt_safety}
    assert s.dt_safety == dt_fraction("rattle", DEFAULT_ACCURACY, 50) == default_dt_safety("rattle", 50)[0]
    assert s.method == "rattle" and s.precision == "auto"  # the default keeps method and precision
    # an explicit dt or dt_safety is kept as given
    assert apply_accuracy(RunSettings(dt=1e-3), 50)[0].dt_safety is None
    assert apply_accuracy(RunSettings(dt_safety=0.25), 50)[0].dt_safety == 0.25


@pytest.mark.slow
@pytest.mark.parametrize("beta", [0.0, 1.0], ids=["FB", "RB"])
def test_default_run_within_half_a_percent(beta):
    cfg = ColumnConfig()
    params = {"prestrain": 0.002, "v0": 0.1, "base_rigidity": [beta]}
    run = lambda **kw: simulate_batch(cfg, params, RunSettings(t_end=1.6, output_interval=0.002,  # noqa: E731
                                                               device="cpu", **kw))
    ref, check, default = run(dt_safety=0.01), run(dt_safety=0.02), run()
    assert default.info["choices"]["accuracy"] == DEFAULT_ACCURACY
    assert default.info["choices"]["accuracy_source"] == "default"
    m = {k: measure_pulse(r.strain, r.time, cfg.height) for k, r in (("ref", ref), ("check", check), ("default", default))}
    peak = np.abs(ref.strain).max()
    for name in ("amplitude", "speed"):
        err = abs(m["default"][name][0] / m["ref"][name][0] - 1)
        ref_err = abs(m["check"][name][0] / m["ref"][name][0] - 1)
        assert ref_err < 0.2 * 5e-3  # the reference is converged well past the claim
        assert err <= 5e-3, (name, err)
    rms = np.sqrt(np.mean((default.strain - ref.strain) ** 2)) / peak
    assert rms <= 1e-2, rms
