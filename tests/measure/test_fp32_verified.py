"""Issue 31, Must show 1: every fp32 measure is right, flagged, or covered by its error estimate.

The issue's two CPU cases, 24 feasible phase_large cases (FB, 50 prisms, 10 s) whose fp32 and
fp64 measures differed by more than the accuracy target on an H200
(benchmarks/results/error_coverage_phase_large_h200_0f97af1_cases.npz), and 8 phase_large cases at beta
0-1 whose measures differed before issue 31 (benchmarks/measure_stability.py), run here on the CPU
as sweeps run them (groups, twins, error estimates) in fp32 and, for reference, in fp64: the
flexible-base cases as one sweep, the others as another (:func:`sweeps`). For each case and each measure the
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


VARIABLES = MEASURES + tuple(f"{k}_error" for k in MEASURES) + ("measurement_flag", "feasibility_flag", "error_flag")


def spec(precision: str, rows: list[tuple]) -> str:
    """phase_large's scene over the cases ``rows`` ((prestrain, v0, base_rigidity)) for 10 s; fp64
    without the twins (its measures are the reference; the estimates checked are fp32's)."""
    text = [f'{{ prestrain = {p}, v0 = {v}, base_rigidity = {b} }}' for p, v, b in rows]
    return ((ROOT / "sweeps" / "phase_large.toml").read_text().split("[sweep]")[0]
            + "[sweep]\ncases = [\n  " + ",\n  ".join(text) + ",\n]\n[run]\nt_end = 10.0\noutput_interval = 0.002\n"
            + f'precision = "{precision}"\nrecord_strain = false\nshard_size = 64\n'
            + ("error_estimate = false\n" if precision == "fp64" else ""))


def sweeps() -> tuple[list[tuple], list[tuple]]:
    """The cases as two sweeps: the flexible-base ones (beta = 0: phase_large's grid cases of the H200
    study and the issue's second; omega_max 248.5-248.7 rad/s, their own dt 2.9e-4 s, 35,000 steps;
    phase_large's group stepped them at 1.7e-4 s beside stiffer columns) and the others (the issue's
    first, the grid cases at beta 0-1: dt 9.1e-5 s, and 5e-4 s for the rigid one). As one sweep every
    non-rigid column stepped at 9.1e-5 s (groups of fewer than 64 columns merge into their stiffer
    neighbour): 440 s of CI instead of about 230."""
    flexible = [ISSUE_CASES[1]] + [(p, v, 0.0) for p, v in FB_CASES]
    return flexible, [ISSUE_CASES[0]] + grid_cases()


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """fp32 and fp64 datasets of the variables the checks read, the cases in the order: the issue's
    two, the 8 grid cases, the 24 flexible-base cases."""
    from warp_tensegrity.sweep import run_sweep

    d = tmp_path_factory.mktemp("fp32v")
    out = {}
    for p in ("fp32", "fp64"):
        fb, rest = (xr.load_dataset(run_sweep(spec(p, rows), d / f"{p}_{i}.nc", device="cpu", progress=False))
                    for i, rows in enumerate(sweeps()))
        order = [rest.isel(case=[0]), fb.isel(case=[0]), rest.isel(case=slice(1, None)), fb.isel(case=slice(1, None))]
        out[p] = xr.Dataset({k: xr.concat([o[k] for o in order], dim="case") for k in VARIABLES if k in fb})
    return out


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


@pytest.mark.slow  # fp32 (with twins) and fp64, 34 columns in 4 groups of 20,000-110,000 steps: ~3 min on one core
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
