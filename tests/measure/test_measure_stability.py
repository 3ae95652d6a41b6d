"""Measures that hold still (issue 31): on phase_large-like engine records (50 prisms, 10 s, dt =
10/110,000 s, RATTLE, CPU), the fp32 answer of every measure (amplitude, speed, widths, arrival
times) agrees with fp64 to the accuracy target (1e-3), or is flagged (measurement_flag), or the two
records themselves differ by more than the target before the last time that measure used (the
dynamics differ, not the measure: such cases need a twin run to be told, issue 31's error
estimate); and for those, the two records cut where they still agree to 1e-4 measure alike.
Likewise fp64 at dt against dt/2 and v0 against v0 (1 +- 1e-6).

The records: ``benchmarks/measure_stability.py`` (``fixtures`` writes tests/data/measure_stability.npz;
the slow test simulates three of its ``cases()`` again). The fp32 runs of its other cases, with
their error estimates, are in test_fp32_verified.py.
"""

import numpy as np
import pytest

from benchmarks.measure_stability import DT, FIXTURE_CASES, MEASURES, TARGET, cases, load_fixtures, simulate, verdicts


def check(v: dict, where: str) -> list[str]:
    """The measures of one verdict row that are 'wrong', or diverged but wrong once cut."""
    bad = [f"{where}: {n} {v[n][0]} ({v[n][1]:.2e}, flag {v['flag']})" for n in MEASURES if v[n][0] == "wrong"]
    if "cut" in v:
        bad += [f"{where} cut at {v['cut']['t_cut']:.3f} s: {n} ({v['cut'][n][1]:.2e})" for n in MEASURES
                if v["cut"][n][0] == "wrong"]
    return bad


@pytest.fixture(scope="module")
def stored():
    return load_fixtures()


def test_fp32_agrees_with_fp64_or_is_flagged_on_stored_records(stored):
    """The issue's two cases, an FB case near its example p = 0.004, v0 = 0.0487 m/s (records that
    diverge) and a weak slow pulse. The first case's measures agree (with the whole record the
    measure before issue 31 gave amplitude 0.0065 against 0.1192: its 5 % threshold followed the
    late, chaotic maximum, which the stored records, cut where the measures no longer change,
    leave out), and so do the weak pulse's widths (before: 2.3e-2 apart, the snapshot nearest a time)."""
    t, cs, recs = stored
    assert [tuple(c) for c in cs] == [cases()[i] for i in FIXTURE_CASES]
    bad, rows = [], []
    for c, r in enumerate(recs):
        n = r["fp32"].shape[0]
        v = verdicts(r["fp64"][None], r["fp32"][None], t[:n])[0]
        rows.append(v)
        bad += check(v, f"case {tuple(cs[c])}")
    assert not bad, "\n".join(bad)
    for n in ("amplitude", "speed", "width", "width_10"):
        assert rows[0][n][0] == "agree", (n, rows[0][n])  # the first case
        assert rows[3][n][0] == "agree", (n, rows[3][n])  # the weak pulse
    assert rows[1]["amplitude"][0] == "diverged" and rows[2]["amplitude"][0] == "diverged"  # records differ


@pytest.mark.parametrize("kind", ["dt2", "v0p", "v0m"])
def test_dt_half_and_v0_perturbations_hold_still_on_stored_records(stored, kind):
    """fp64 at the policy's dt against dt/2, and v0 against v0 (1 +- 1e-6), on the issue's first case."""
    t, cs, recs = stored
    r = recs[0]
    n = r["fp64"].shape[0]
    v = verdicts(r["fp64"][None], r[kind][None], t[:n])[0]
    assert not check(v, kind), check(v, kind)
    for m in ("amplitude", "speed", "width", "width_10"):
        assert v[m][0] == "agree", (m, v[m])


@pytest.mark.slow  # 3 columns x (2 x 110,000 + 3 x 110,000 steps)
def test_dt_half_and_v0_perturbations_hold_still_on_grid_cases():
    c = np.array(cases())[[2, 7, 9]]
    t, s, _ = simulate(c, "fp64")
    bad = []
    for kind, kw in (("dt/2", {"dt": DT / 2}), ("v0+", {"v0_scale": 1 + 1e-6}), ("v0-", {"v0_scale": 1 - 1e-6})):
        _, sp, _ = simulate(c, "fp64", **kw)
        for b, v in enumerate(verdicts(s, sp, t)):
            bad += check(v, f"{kind} case {tuple(c[b])}")
    assert not bad, "\n".join(bad)


def test_the_target_is_the_default_accuracy():
    from warp_tensegrity.measure.pulse_core import STABILITY_EPS, STABILITY_FLOOR
    from warp_tensegrity.policy.accuracy import DEFAULT_ACCURACY

    assert TARGET == STABILITY_FLOOR == STABILITY_EPS == DEFAULT_ACCURACY
