"""The fused RATTLE step (one block per column) against the staged kernels, which are an
independent implementation of the same scheme: same numbers to round-off, same flags."""

import numpy as np
import pytest
import warp as wp

from warp_tensegrity import ColumnConfig, RunSettings, SettingsError, simulate_batch
from warp_tensegrity.sim.block import step as block_step
from warp_tensegrity.sim.staged import step as staged_step
from warp_tensegrity.sim.block.kernels import SHARED_BYTES_MAX, shared_plan, solver_reals
from warp_tensegrity.sweep import SpecError, parse_spec

CASES = {  # FB and RB, slack-cable impacts and a prestressed one
    "prestrain": [0.0, 0.002, 0.0, 0.002],
    "v0": [0.005, 0.1, 0.005, 0.1],
    "base_rigidity": [0.0, 0.0, 1.0, 1.0],
}


def _pair(precision, device, cfg=ColumnConfig(n_prisms=8), params=CASES, **kw):
    out = {}
    for fused in (False, True):
        # 20 steps per output: launches of up to 16 steps must stop at the output steps
        s = RunSettings(t_end=0.2, dt=5e-4, precision=precision, device=device, fused=fused, truncate=False,
                        output_interval=0.01, **kw)
        out[fused] = simulate_batch(cfg, params, s)
    return out[False], out[True]


@pytest.mark.parametrize("precision, tol", [("fp64", 1e-11), ("fp32", 1e-3)])
def test_fused_matches_staged(precision, tol, device):
    staged, fused = _pair(precision, device)
    assert staged.info["output_every"] > block_step.FUSED_STEPS  # records fall between launch ends
    assert np.all(staged.status == 0) and np.all(fused.status == 0)
    scale = np.abs(staged.strain).max(axis=(1, 2))
    assert np.all(scale > 1e-6)
    rel = np.abs(fused.strain - staged.strain).max(axis=(1, 2)) / scale
    assert np.all(rel < tol), rel
    # energies recorded at the same output steps
    e_rel = np.abs(fused.kinetic_energy - staged.kinetic_energy).max() / staged.kinetic_energy.max()
    assert e_rel < tol
    bound = 1e-12 if precision == "fp64" else 1e-6
    assert np.all(fused.bar_length_error <= bound) and np.all(fused.bar_length_error > 0)
    assert fused.info["max_projection_iterations"] == staged.info["max_projection_iterations"] or precision == "fp32"


def test_emulated_lanes_and_shared_rows_match_staged():
    """Four lanes per block on the CPU (Warp's CPU block emulation, real barriers) with the band
    in the shared-memory buffer: the lane split, the barriers and the shared rows the GPU uses."""
    names = ("FUSED_BLOCK_DIM", "FUSED_SHARED_ON_CPU")
    old = [wp.config.enable_cpu_blocks] + [getattr(block_step, n) for n in names]
    try:
        wp.config.enable_cpu_blocks = True
        block_step.FUSED_BLOCK_DIM = 4
        block_step.FUSED_SHARED_ON_CPU = True
        staged, fused = _pair("fp64", "cpu", cfg=ColumnConfig(n_prisms=5))
    finally:
        wp.config.enable_cpu_blocks = old[0]
        for n, v in zip(names, old[1:]):
            setattr(block_step, n, v)
    rel = np.abs(fused.strain - staged.strain).max() / np.abs(staged.strain).max()
    assert rel < 1e-11, rel
    assert np.all(fused.bar_length_error <= 1e-12)


def test_fused_flags_one_diverging_column_and_spares_the_rest(device):
    params = {"prestrain": [0.002, 0.002, 0.002], "v0": [0.05, 0.05, 0.05], "base_rigidity": [0.0, 0.0, 0.0]}
    cfg = ColumnConfig(n_prisms=6)
    base = RunSettings(t_end=0.1, dt=2e-3, device=device, allow_unstable_dt=True, truncate=False, fused=True)
    alone = simulate_batch(cfg, {k: v[:1] for k, v in params.items()}, base)
    # column 1 gets a cable 1e6 times stiffer: dt is then far above its stability limit
    cab = cfg.cable_EA
    bad = dict(params, cable_EA=[cab, cab * 1e6, cab])
    r = simulate_batch(cfg, bad, base)
    assert r.status[1] != 0 and r.fail_step[1] > 0
    assert r.status[0] == 0 and r.status[2] == 0
    np.testing.assert_array_equal(r.strain[0], alone.strain[0])  # untouched, bit for bit


def test_fused_setting_is_checked():
    with pytest.raises(SettingsError, match="fused"):
        RunSettings(fused="yes")
    with pytest.raises(SettingsError, match="rattle"):
        RunSettings(fused=True, method="rk4")
    RunSettings(fused=False, method="rk4")  # the staged path runs every method


def test_spec_fused_key():
    base = '[scene]\nn_prisms = 4\n[sweep]\ngrid = { v0 = [0.01] }\n[run]\nt_end = 0.01\n'
    assert parse_spec(base + "fused = false\n").run["fused"] is False
    with pytest.raises(SpecError, match="run.fused"):
        parse_spec(base + 'fused = "sometimes"\n')
    with pytest.raises(SpecError, match="run.fused"):
        parse_spec(base + 'method = "rk4"\nfused = true\n')


def test_shared_plan_places_whole_rows_within_the_budget():
    # FB, 50 prisms: 153 nodes, 150 bars, band 3 -> 50 blocks of 3x3; 32 lanes
    assert solver_reals(150, 3, 32) == 50 * 3 * 16 + 32
    x, q = shared_plan(153, 150, 3, 32, 4)  # fp32: solver rows and node rows fit
    assert x == solver_reals(150, 3, 32) and q == 153 * 4  # 4 node slots (U, V, P, I); accelerations in a global row
    x, q = shared_plan(153, 300, 6, 32, 8)  # RB fp64: 50 blocks of 6x6 = 60 kB: global rows
    assert x == 0 and q == 153 * 4
    x, q = shared_plan(603, 1200, 6, 32, 8)  # RB fp64, 200 prisms: nothing fits
    assert (x, q) == (0, 0)
    for args in [(153, 150, 3, 32, 8), (153, 300, 6, 32, 4), (33, 30, 3, 64, 8)]:
        x, q = shared_plan(*args)
        assert (x + 3 * q) * args[-1] <= SHARED_BYTES_MAX


@pytest.mark.parametrize("precision, tol", [("fp64", 1e-12), ("fp32", 1e-5)])
def test_gram_assembly_with_bar_window_matches_reload(precision, tol, device, monkeypatch):
    """The staged factorisation with the bar vectors of the last bw + 1 rows in registers against
    the one that reloads them for every coupling term (FB and RB columns, slack and taut)."""
    runs = {}
    for window in (False, True):
        monkeypatch.setattr(staged_step, "COLUMN_BAR_WINDOW", window)
        s = RunSettings(t_end=0.1, dt=5e-4, precision=precision, device=device, fused=False, truncate=False,
                        output_interval=0.01)
        runs[window] = simulate_batch(ColumnConfig(n_prisms=8), CASES, s)
    scale = np.abs(runs[False].strain).max(axis=(1, 2))
    rel = np.abs(runs[True].strain - runs[False].strain).max(axis=(1, 2)) / scale
    assert np.all(scale > 1e-6) and np.all(rel < tol), rel
