"""analysis/interface.py: the transmitted amplitude across a prestrain interface, on a record made
by hand (no run): the numbers its definitions give, and the reflected wave it must leave out."""

import sys
from pathlib import Path

import numpy as np
import xarray as xr

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "analysis"))

import interface as I  # noqa: E402


def _record(reflected: float = 0.0) -> xr.Dataset:
    """Two interfaces x two prestrains, 12 prisms: peak compression 0.03 before the interface
    (prisms >= at), 0.05 past it, the front at prism 0 at t = 2 and, after it, ``reflected``."""
    at, to, t, n = np.array([4.0, 8.0]), np.array([0.01, 0.02]), np.arange(4.0), 12
    s = np.zeros((2, 2, 4, n))
    for i, a in enumerate(at.astype(int)):
        s[i, :, 1, a:] = -0.03
        s[i, :, 1, :a] = -0.05 * np.array([1.0, 1.0])[:, None]
        s[i, 1, 1, :a] *= 2.0  # the second prestrain transmits twice as much
    s[:, :, 1, 0] = 0.0
    s[:, :, 2, 0] = -0.01  # the front reaches the clamped base
    s[:, :, 3, :] = -reflected  # what comes back from it: not counted
    return xr.Dataset({"strain": (("prestrain_at", "prestrain_to", "t", "prism"), s)},
                      coords={"prestrain_at": at, "prestrain_to": to, "t": t, "prism": np.arange(n)})


def test_transmitted_amplitude_and_ratio():
    tr = I.transmission(_record())
    assert np.allclose(tr["A_T"].sel(prestrain_to=0.01), 0.05) and np.allclose(tr["A_T"].sel(prestrain_to=0.02), 0.1)
    assert np.allclose(tr["A_I"], 0.03)
    assert np.allclose(tr["ratio"].sel(prestrain_to=0.02), 0.1 / 0.03)
    assert tr["A_T"].attrs["units"] == "1" and "transmitted amplitude" in tr["A_T"].attrs["long_name"]


def test_waves_after_the_front_reaches_the_base_are_left_out():
    assert np.allclose(I.transmission(_record(reflected=0.5))["A_T"], I.transmission(_record())["A_T"])


def test_the_phase_diagram_is_drawn(tmp_path):
    assert I.phase_diagram(I.transmission(_record()), tmp_path / "t.png", far=0.01).stat().st_size > 1000
