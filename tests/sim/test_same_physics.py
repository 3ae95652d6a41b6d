"""Same physics (issue 33, must show 4), CPU side: every registered Step against the staged
reference within 1e-11 in fp64 on the paper's 12 cases and on lanes_check's cases of 50 prisms, a few
steps each (benchmarks/same_physics.py runs them, 7 and 100 prisms too, to t = 1 s on a GPU: each other
length is another fused-serial variant to compile, several seconds of CI each)."""

from benchmarks.same_physics import ROUNDOFF, TOL, cases, compare, passes, worst
from warp_tensegrity.sim.step import STEPS


def test_every_step_path_matches_staged_on_the_paper_and_lanes_check_cases():
    rows = list(compare("cpu", 0.001, cases(prisms=(50,))))
    names = {"paper_12"} | {f"lanes_check_50_{h}" for h in ("right", "alternating")}
    assert {r["case"] for r in rows} == names
    assert {(r["case"], r["path"]) for r in rows} == {(c, p) for c in names for p in [s.value for s in STEPS] + [ROUNDOFF]}
    assert all(r["status_ok"] and r["n_steps"] >= 3 and r["passes"] for r in rows), rows
    assert worst(rows) <= TOL, [r for r in rows if max(r["rel_strain"], r["rel_displacement"], r["rel_velocity"]) > TOL]


def test_the_roundoff_twin_bound_fails_a_changed_step():
    """The t_end bound scales with the twin's round-off growth: a Step off by a 1.05 constant
    (differences ~1e-2) fails it however long the run, and one within round-off passes."""
    twin = {"rel_strain": 1e-10, "rel_displacement": 1e-10, "rel_velocity": 1e-9}
    ok = {"status_ok": True, "rel_strain_early": 1e-13, "rel_strain": 3e-10, "rel_displacement": 2e-10, "rel_velocity": 5e-9}
    assert passes(ok, twin)
    assert not passes(ok | {"rel_velocity": 2e-2}, twin)
    assert not passes(ok | {"rel_strain_early": 2e-11}, twin)  # the early record holds to TOL
    assert not passes(ok | {"status_ok": False}, twin)
