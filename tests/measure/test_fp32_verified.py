"""Issue 31, Must show 1: every fp32 measure is right, flagged, or covered by its error estimate.

The cases (benchmarks/fp32_verified.py): the issue's two CPU cases, 24 feasible phase_large cases
whose fp32 and fp64 measures differed by more than the accuracy target on an H200, and 8
phase_large cases at beta 0-1 whose measures differed before issue 31, run here on the CPU in fp32
as sweeps run them (groups, twins, error estimates). Their fp64 answers are read from
tests/data/fp32_verified_fp64.nc (``python -m benchmarks.fp32_verified`` writes it); two of the
cases are re-run in fp64 here, at the dt the file records, and must match it, so a reference that
this code no longer computes fails. For each case and each measure the fp32 answer must agree with
fp64 to the target, or be flagged (measurement_flag, error_flag, feasibility_flag), or carry an
estimate of at least half the difference.
"""

import contextlib

import numpy as np
import pytest
import xarray as xr

from benchmarks.fp32_verified import MEASURES, PARAMS, REFERENCE, VARIABLES, run_cases, spec
from warp_tensegrity.measure import errors as E

TARGET = 1e-3
CURRENT = {"rigid base": lambda ref: int(np.flatnonzero(ref.base_rigidity.values >= 1.0)[0]),
           "flexible base": lambda ref: int(ref.sizes["case"] - 1)}
"""Cases re-run in fp64 to check the stored reference: its one rigid-base case (dt 5e-4 s, 20,000
steps) and its last flexible-base one."""


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """fp32 datasets of the variables the checks read (run here) and the fp64 reference (stored), the
    cases in the order: the issue's two, the 8 grid cases, the 24 flexible-base cases."""
    d = tmp_path_factory.mktemp("fp32v")
    ref = xr.load_dataset(REFERENCE)
    f32 = run_cases("fp32", d)
    for k in PARAMS:  # the same cases, in the same order
        np.testing.assert_array_equal(f32[k].values, ref[k].values, err_msg=k)
    return {"fp32": f32, "fp64": ref}


@pytest.mark.slow  # three fp64 columns of 20,000 and 35,000 steps: ~15 s
@pytest.mark.parametrize("which,perturbed", [("rigid base", None), ("flexible base", None),
                                             ("flexible base", "cross_EA")])
def test_the_fp64_reference_is_what_this_code_computes(which, perturbed, tmp_path):
    """One case of the stored fp64 reference, re-run alone in fp64 at the dt its sweep gave it: the
    measures match the file to 1e-9 (bit-identical on the machine that wrote it; the margin is for
    another machine's BLAS in the base-mode analysis), the flags exactly. The check can fail: an
    engine whose cross cables' EA is 1.05x (``perturbed``) gives measures 3e-2 to 0.23 off (measured)."""
    from tests.validation.test_perturbation import perturbed_engine
    from warp_tensegrity.sweep import run_sweep

    ref = xr.load_dataset(REFERENCE)
    c = CURRENT[which](ref)
    row = tuple(float(ref[k].values[c]) for k in PARAMS)
    text = spec("fp64", [row], dt=float(ref.time_step.values[c]))
    with perturbed_engine(perturbed) if perturbed else contextlib.nullcontext():
        live = xr.load_dataset(run_sweep(text, tmp_path / "one.nc", device="cpu", progress=False))
    assert float(live.time_step.values[0]) == float(ref.time_step.values[c])
    off = {}
    for k in [k for k in VARIABLES if k in ref]:  # fp64 has no twins: no estimates, no error_flag
        a, b = np.asarray(live[k].values[0], float), np.asarray(ref[k].values[c], float)
        if k.endswith("_flag"):
            np.testing.assert_array_equal(a, b, err_msg=k)
        else:
            np.testing.assert_array_equal(np.isnan(a), np.isnan(b), err_msg=f"{k}: where it is NaN")
            with np.errstate(invalid="ignore", divide="ignore"):
                off[k] = float(np.nanmax(np.abs(a - b) / np.abs(b), initial=0.0))
    if perturbed:
        assert max(off.values()) > 1e-2, off
    else:
        assert max(off.values()) <= 1e-9, off


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
    # the two cases leave the feasible set: flagged, their measures NaN
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
