"""Same physics (issue 33, must show 4), CPU side: every registered Step against the staged
reference within 1e-11 in fp64 on the paper's 12 cases and on lanes_check's cases of 50 prisms, a few
steps each (benchmarks/same_physics.py runs them, 7 and 100 prisms too, to t = 1 s on a GPU: each other
length is another fused-serial variant to compile, several seconds of CI each)."""

from benchmarks.same_physics import TOL, cases, compare, worst
from warp_tensegrity.sim.step import STEPS


def test_every_step_path_matches_staged_on_the_paper_and_lanes_check_cases():
    rows = list(compare("cpu", 0.001, cases(prisms=(50,))))
    names = {"paper_12"} | {f"lanes_check_50_{h}" for h in ("right", "alternating")}
    assert {r["case"] for r in rows} == names
    assert {(r["case"], r["path"]) for r in rows} == {(c, p.value) for c in names for p in STEPS}
    assert all(r["status_ok"] and r["n_steps"] >= 3 for r in rows), rows
    assert worst(rows) <= TOL, [r for r in rows if max(r["rel_strain"], r["rel_displacement"], r["rel_velocity"]) > TOL]
