"""The end preload (issue 34 item 3): the static solve, its refusals, the dead load on every step path,
and F0 = 0 as today's column bit for bit."""

import re

import numpy as np
import pytest

from warp_tensegrity import ColumnConfig
from warp_tensegrity.engine import simulate_batch
from warp_tensegrity.options import RunSettings
from warp_tensegrity.scene import columns as col
from warp_tensegrity.scene.batch import column_batch
from warp_tensegrity.scene.network import NetworkError
from warp_tensegrity.scene.preload import solve_preload

P = 0.01
T = ColumnConfig().cable_EA * P  # cross-cable tension [N]


def test_zero_preload_given_is_the_default_bit_for_bit():
    cfg = ColumnConfig(n_prisms=4)
    p = {"prestrain": P, "v0": 1e-3, "base_rigidity": np.array([0.0, 1.0])}
    a, b = column_batch(cfg, p), column_batch(cfg, {**p, "preload": 0.0})
    for name, x in vars(a).items():
        y = getattr(b, name)
        if isinstance(x, np.ndarray):
            assert np.array_equal(x, y), name
    assert b.initial_displacement is None and b.external_force is None
    s = RunSettings(t_end=0.05, output_interval=0.01, device="cpu", precision="fp64", fused=False, measure="none")
    ra, rb = simulate_batch(cfg, p, s), simulate_batch(cfg, {**p, "preload": [0.0, 0.0]}, s)
    for name in ("strain", "kinetic_energy", "elastic_energy", "final_displacement", "final_velocity"):
        assert np.array_equal(getattr(ra, name), getattr(rb, name)), name


@pytest.mark.parametrize("beta", [1.0, 0.0])
def test_static_state_is_in_equilibrium_and_shortened(beta):
    sc = col.build_column(ColumnConfig(n_prisms=3), prestrain=P, base_rigidity=beta)
    st = solve_preload(sc.network, sc.topology.level_nodes[-1], T, sc.topology.level_nodes)
    assert st.residual < 1e-12 * T
    assert np.allclose(sc.network.bar_lengths(st.positions), sc.network.bar_lengths(), rtol=1e-12, atol=0)
    h = col.prism_heights(sc.topology, st.positions)
    assert np.all(h < 0.99 * sc.topology.config.height)  # every prism carries F0: each shortens
    assert np.all(st.tensions[: 3 * 3] > 0)


def test_beyond_capacity_and_bad_values_are_refused():
    cfg = ColumnConfig(n_prisms=2)
    with pytest.raises(NetworkError, match=r"preload = 0\.1.* N: beyond the column's capacity.*goes slack"):
        column_batch(cfg, {"prestrain": P, "base_rigidity": 0.0, "preload": 30 * T})
    for bad, why in ((-1.0, "must lie in [0, 1e+20] [N]"), (float("nan"), "must be finite"), (float("inf"), "must be finite")):
        with pytest.raises(NetworkError, match=re.escape(f"preload = {bad!r}: {why}")):
            column_batch(cfg, {"prestrain": P, "preload": bad})


@pytest.mark.parametrize("fused", [False, True, "lanes"])
def test_the_dead_load_holds_the_column_on_every_path(fused):
    """Left at rest, a preloaded column stays in its static state (the load persists in the dynamics); a
    struck one conserves kinetic + elastic energy, the latter with the load's potential."""
    cfg = ColumnConfig(n_prisms=4)
    r = simulate_batch(cfg, {"prestrain": P, "base_rigidity": [1.0, 0.0, 0.0], "preload": [T, T, T],
                             "v0": [0.0, 0.0, 1e-3]},
                       RunSettings(t_end=0.3, output_interval=0.05, device="cpu", precision="fp64", fused=fused,
                                   measure="none"))
    assert np.all(r.status == 0)
    assert np.abs(r.strain[:2]).max() < 1e-12  # strain from the preloaded state: 0 at rest
    assert np.abs(r.final_velocity[:2]).max() < 1e-12
    assert r.energy_error[2] < 1e-4
    assert np.abs(r.strain[2]).max() > 1e-4  # the struck column moves
