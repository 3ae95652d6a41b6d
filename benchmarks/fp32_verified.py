"""The cases of tests/measure/test_fp32_verified.py (issue 31, must show 1) and their fp64 reference.

The issue's two CPU cases, 24 feasible phase_large cases (FB, 50 prisms, 10 s) whose fp32 and fp64
measures differed by more than the accuracy target on an H200
(benchmarks/results/error_coverage_phase_large_h200_0f97af1_cases.npz), and 8 phase_large cases at
beta 0-1 whose measures differed before issue 31 (benchmarks/measure_stability.py), run on the CPU
as sweeps run them (groups, twins, error estimates): the flexible-base cases as one sweep, the
others as another (:func:`sweeps`).

The test runs fp32 and reads the fp64 answers from ``REFERENCE``, which this module writes
(about 80 s of one core: the half of the test's time it no longer spends); the test re-runs two of
the cases in fp64 at the stored dt and checks they match the file, so a stale reference fails.

    python -m benchmarks.fp32_verified     # rewrite tests/data/fp32_verified_fp64.nc
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
REFERENCE = ROOT / "tests" / "data" / "fp32_verified_fp64.nc"
MEASURES = ("amplitude", "speed", "width", "width_10", "arrival_time")
VARIABLES = MEASURES + tuple(f"{k}_error" for k in MEASURES) + (
    "measurement_flag", "feasibility_flag", "error_flag", "time_step")
PARAMS = ("prestrain", "v0", "base_rigidity")
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


def spec(precision: str, rows: list[tuple], dt=None) -> str:
    """phase_large's scene over the cases ``rows`` ((prestrain, v0, base_rigidity)) for 10 s; fp64
    without the twins (its measures are the reference; the estimates checked are fp32's). ``dt``
    [s]: set, instead of the sweep's policy (to re-run a case at the dt its sweep gave it)."""
    text = [f'{{ prestrain = {float(p)!r}, v0 = {float(v)!r}, base_rigidity = {float(b)!r} }}' for p, v, b in rows]
    return ((ROOT / "sweeps" / "phase_large.toml").read_text().split("[sweep]")[0]
            + "[sweep]\ncases = [\n  " + ",\n  ".join(text) + ",\n]\n[run]\nt_end = 10.0\noutput_interval = 0.002\n"
            + f'precision = "{precision}"\nrecord_strain = false\nshard_size = 64\n'
            + ("error_estimate = false\n" if precision == "fp64" else "")
            + (f"dt = {float(dt)!r}\n" if dt is not None else ""))


def sweeps() -> tuple[list[tuple], list[tuple]]:
    """The cases as two sweeps: the flexible-base ones (beta = 0: phase_large's grid cases of the H200
    study and the issue's second; omega_max 248.5-248.7 rad/s, their own dt 2.9e-4 s, 35,000 steps;
    phase_large's group stepped them at 1.7e-4 s beside stiffer columns) and the others (the issue's
    first, the grid cases at beta 0-1: dt 9.1e-5 s, and 5e-4 s for the rigid one). As one sweep every
    non-rigid column stepped at 9.1e-5 s (groups of fewer than 64 columns merge into their stiffer
    neighbour): 440 s of CI instead of about 230."""
    flexible = [ISSUE_CASES[1]] + [(p, v, 0.0) for p, v in FB_CASES]
    return flexible, [ISSUE_CASES[0]] + grid_cases()


def run_cases(precision: str, d) -> "xr.Dataset":
    """VARIABLES and the case parameters of every case in ``precision``, in the order: the issue's
    two, the 8 grid cases, the 24 flexible-base cases (run into folder ``d``)."""
    import xarray as xr

    from warp_tensegrity.sweep import run_sweep

    fb, rest = (xr.load_dataset(run_sweep(spec(precision, rows), Path(d) / f"{precision}_{i}.nc", device="cpu",
                                          progress=False))
                for i, rows in enumerate(sweeps()))
    order = [rest.isel(case=[0]), fb.isel(case=[0]), rest.isel(case=slice(1, None)), fb.isel(case=slice(1, None))]
    keep = [k for k in VARIABLES + PARAMS if k in fb.variables]
    out = xr.concat([o[keep] for o in order], dim="case")
    return out.drop_vars([k for k in out.coords if k not in PARAMS])


def main() -> int:
    from warp_tensegrity.provenance import code_version

    from .common import git_commit

    with tempfile.TemporaryDirectory(prefix="fp32v_") as d:
        ref = run_cases("fp64", d)
    ref.attrs = {"title": "fp64 reference of tests/measure/test_fp32_verified.py",
                 "source": "python -m benchmarks.fp32_verified", "git_commit": git_commit(),
                 "code_version": code_version()}
    ref.to_netcdf(REFERENCE)
    print(f"wrote {REFERENCE.relative_to(ROOT)}: {ref.sizes['case']} cases")
    return 0


if __name__ == "__main__":
    sys.exit(main())
