"""Issue 31, Must show 1: every fp32 measure is right, flagged, or covered by its error estimate.

The issue's two CPU cases, 24 feasible phase_large cases (FB, 50 prisms, 10 s) whose fp32 and
fp64 measures differed by more than the accuracy target on an H200
(benchmarks/results/error_coverage_phase_large_h200_0f97af1_cases.npz), and 8 phase_large cases at beta
0-1 whose measures differed before issue 31 (benchmarks/measure_stability.py), run here on the CPU
as a sweep runs them (groups, twins, error estimates) in fp32 and in fp64. For each case and each measure the
fp32 answer must agree with fp64 to the target, or be flagged (measurement_flag, error_flag,
feasibility_flag), or carry an estimate of at least half the difference.
"""

from pathlib import Path

import numpy as np
import pytest
import xarray as xr

from warp_tensegrity.measure import errors as E

ROOT = Path(__file__).resolve().parents[2]
TARGET = 1e-3
MEASURES = ("amplitude", "speed", "width", "width_10", "arrival_time")
ISSUE_CASES = [(0.0007, 0.04869, 0.95), (0.0013, 0.09868, 0.0)]
"""(prestrain, v0 [m/s], base_rigidity): the issue's two cases (both leave the feasible set)."""
FB_CASES = [(p, v) for p, vs in (
    (0.0, (0.001, 0.00142, 0.00203, 0.00289, 0.00411, 0.00585, 0.00833, 0.01185, 0.01687, 0.02402)),
    (0.00067, (0.00411, 0.00585, 0.00833, 0.01185, 0.01687, 0.02402)),
    (0.00133, (0.00833, 0.01185, 0.01687, 0.02402)),
    (0.002, (0.01185, 0.01687, 0.02402, 0.0342))) for v in vs]
"""(prestrain, v0) at base_rigidity 0: phase_large's grid cases whose fp32 and fp64 measures differed
by more than the target on an H200 (24 of its 39 such FB cases)."""


def grid_cases() -> list[tuple]:
    """The 8 phase_large cases of benchmarks/measure_stability.py not stored as its fixtures: cases
    whose fp32 and fp64 measures differed by more than the target before issue 31, at beta 0-1."""
    from benchmarks.measure_stability import FIXTURE_CASES, cases

    return [c for i, c in enumerate(cases()) if i not in FIXTURE_CASES]


def spec(precision: str) -> str:
    rows = [f'{{ prestrain = {p}, v0 = {v}, base_rigidity = {b} }}' for p, v, b in ISSUE_CASES + grid_cases()]
    rows += [f'{{ prestrain = {p}, v0 = {v}, base_rigidity = 0.0 }}' for p, v in FB_CASES]
    return ((ROOT / "sweeps" / "phase_large.toml").read_text().split("[sweep]")[0]
            + "[sweep]\ncases = [\n  " + ",\n  ".join(rows) + ",\n]\n[run]\nt_end = 10.0\noutput_interval = 0.002\n"
            + f'precision = "{precision}"\nrecord_strain = false\nshard_size = 64\n')


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    from warp_tensegrity.sweep import run_sweep

    d = tmp_path_factory.mktemp("fp32v")
    return {p: xr.load_dataset(run_sweep(spec(p), d / f"{p}.nc", device="cpu", progress=False)) for p in ("fp32", "fp64")}


def unaccounted(f32, f64, scale_errors=1.0) -> list[str]:
    """The (case, measure) pairs whose fp32 answer is neither within the target of fp64, nor flagged,
    nor covered (estimate x scale_errors >= half the difference)."""
    def scale(x):
        return np.abs(x) if x.ndim == 1 else np.nanmax(np.abs(x), axis=-1, keepdims=True) * np.ones_like(x)

    # error_flag as the estimates (scaled) set it: over_target where one exceeds the target
    over = np.zeros(f32.sizes["case"], bool)
    for k in MEASURES:
        x, e = f32[k].values, f32[f"{k}_error"].values * scale_errors
        with np.errstate(invalid="ignore"):
            over |= np.nan_to_num(e / scale(x), nan=0.0).reshape(len(over), -1).max(axis=1) > TARGET
    flagged = (f32.measurement_flag.values != 0) | (f32.feasibility_flag.values != 0) | over | \
        (f32.error_flag.values == E.FLAG["twin_undefined"])
    bad = []
    for k in MEASURES:
        x, y, e = f32[k].values, f64[k].values, f32[f"{k}_error"].values * scale_errors
        scale_y = scale(y)
        with np.errstate(invalid="ignore"):
            ok = (np.abs(x - y) <= TARGET * scale_y) | (e >= 0.5 * np.abs(x - y)) | (np.isnan(x) & np.isnan(y))
        ok |= flagged.reshape((-1,) + (1,) * (x.ndim - 1))
        bad += [f"case {c} {k}: fp32 {x[c]!r} fp64 {y[c]!r} estimate {e[c]!r}" for c in np.unique(np.where(~ok)[0])]
    return bad


@pytest.mark.slow  # fp32 and fp64, 34 columns in groups of 20,000-110,000 steps, with twins: ~3-4 min on one core
def test_fp32_is_right_flagged_or_covered(runs):
    f32, f64 = runs["fp32"], runs["fp64"]
    # the issue's two cases leave the feasible set: flagged, their measures NaN
    assert np.all(f32.feasibility_flag.values[:2] != 0) and np.isnan(f32.amplitude.values[:2]).all()
    # the others: at least 20 feasible cases where fp32 and fp64 disagree here too (the test has teeth)
    differ = np.zeros(f32.sizes["case"], bool)
    for k in MEASURES[:4]:
        differ |= np.abs(f32[k].values - f64[k].values) > TARGET * np.abs(f64[k].values)
    feasible = f32.feasibility_flag.values == 0
    assert (differ & feasible).sum() >= 20, int((differ & feasible).sum())
    assert not unaccounted(f32, f64), "\n".join(unaccounted(f32, f64))
    # the check fails where it should: fp32 estimates divided by the Richardson factor (the rule
    # before issue 31's H200 study) leave cases neither flagged nor covered
    assert unaccounted(f32, f64, scale_errors=1 / 15), "the check cannot fail"
