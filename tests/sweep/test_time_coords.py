"""Output times are exact: time = step * dt rounded to the output interval's decimals, so every
printed time selects (issue 16, part 4)."""

import numpy as np
import pytest

from warp_tensegrity import ColumnConfig, RunSettings, simulate_batch
from warp_tensegrity.io import open_sweep
from warp_tensegrity.policy.accuracy import output_times


def test_output_times_round_to_the_interval():
    steps = np.arange(1001) * 5
    t = output_times(steps, 0.002)  # the paper run: dt = 2 ms, outputs every 10 ms
    assert 9.95 in t and t[-1] == 10.0
    assert (9.950000000000001 != t).all()
    np.testing.assert_allclose(t, steps * 0.002, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(np.round(t, 2), t)
    # dt = 1/600 s, three steps per output: exact multiples of 5 ms
    t = output_times(np.arange(201) * 3, 1.0 / 600.0)
    np.testing.assert_array_equal(t, np.round(np.arange(201) * 0.005, 3))
    # an interval with no short decimal form is left alone
    t = output_times(np.arange(4) * 1, 1.0 / 3.0)
    np.testing.assert_array_equal(t, np.arange(4) * (1.0 / 3.0))


def test_engine_times_select_exactly():
    r = simulate_batch(ColumnConfig(n_prisms=4), {"prestrain": 0.002, "v0": 0.01},
                       RunSettings(t_end=1.0, dt=0.002, output_interval=0.01, device="cpu"))
    np.testing.assert_array_equal(r.info["output_step"], np.arange(101) * 5)
    assert r.time[-6] == 0.95 and r.time[-1] == 1.0


@pytest.fixture(scope="module")
def ci_small(ci_small_nc):
    return open_sweep(ci_small_nc)  # conftest's session run of sweeps/ci_small.toml through the CLI


def test_every_printed_time_selects(ci_small):
    ds = ci_small
    interval = float(ds.attrs["output_interval"])
    decimals = len(repr(interval).split(".")[1])
    for t in ds.t.values:
        printed = round(float(t), decimals)
        ds.strain.sel(t=printed)  # KeyError if the stored time were 0.30000000000000004
        assert float(repr(printed)) == printed
    # the stored times are whole output intervals, rounded to the interval's decimals; each run group's dt
    # divides the interval (ci_small's rigid-base columns step at their own dt: no one step count)
    np.testing.assert_array_equal(ds.t.values, np.round(np.arange(ds.t.size) * interval, decimals))
    every = interval / ds.time_step.values
    np.testing.assert_allclose(every, np.round(every), rtol=1e-12)
    assert len(set(ds.time_step.values.ravel().tolist())) == 2 and "step" not in ds.coords
