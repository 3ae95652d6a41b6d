"""Same physics (issue 33, must show 4): every registered Step (``sim.step.STEPS``: staged, fused,
fused-serial, lanes) against the staged reference in fp64, on the paper's 12 cases
(:mod:`benchmarks.paper_cases`) and on lanes_check's cases (:mod:`benchmarks.lanes_check`: 50, 7 and
100 prisms, right and alternating, prestrain x v0 x base rigidity). Per case and path: the largest
relative difference (per column, over the column's peak) of the strain record and of the final
displacement and velocity.

Over a whole run the Steps' different (and equally valid) floating-point orders leave differences that
the dynamics amplify: a 1-ulp change of v0 alone grows to ~1e-9 of the velocity over 7,700 steps of
lanes_check's 50-prism columns (CPU, staged). So every case also runs a round-off twin: the staged path
with v0 x (1 + 2^-52), whose difference from the reference is the scale round-off reaches by t_end.
A Step passes where its strain record up to T_EARLY = 0.1 s is within TOL = 1e-11 of the reference and
its differences at t_end are within ROUNDOFF_FACTOR = 10 times the round-off twin's (or TOL). A
change of the physics (a constant x 1.05) moves them by ~1e-2, seven decades above either bound.
The run fails (exit 1) where a Step does not pass or a column failed.

    python -m benchmarks.same_physics --device cuda:0 --out $OUT/same_physics_h200.json
    python -m benchmarks.same_physics --device cpu --t-end 0.01 --prisms 7 --out /tmp/same_physics_cpu.json
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time

import numpy as np

from . import common
from .paper_cases import PAPER_CASES

TOL = 1e-11
"""The largest relative difference any Step may have from the staged reference (fp64) up to T_EARLY."""
T_EARLY = 0.1
"""Seconds of the strain record held to TOL [s]."""
ROUNDOFF_FACTOR = 10.0
"""At t_end a Step's differences may reach this many times the round-off twin's."""
ROUNDOFF = "roundoff_twin"
"""The path name of the round-off twin's row (staged, v0 x (1 + 2^-52))."""


def lanes_check_params(n_prisms: int) -> dict:
    """lanes_check's batch for ``n_prisms``: prestrain x v0 x base rigidity, the rigid bases left out
    where the lane step takes none (over 32 x MAX_RIGID_LEVELS_PER_LANE prisms)."""
    from warp_tensegrity.policy.lane_fit import MAX_RIGID_LEVELS_PER_LANE

    p, v0, beta = np.meshgrid([0.0, 0.002], [0.05, 0.1, 0.15], [0.0, 0.5, 0.9, 1.0], indexing="ij")
    keep = np.ones(p.size, bool) if n_prisms <= 32 * MAX_RIGID_LEVELS_PER_LANE else beta.ravel() < 1.0
    return {"prestrain": p.ravel()[keep], "v0": v0.ravel()[keep], "base_rigidity": beta.ravel()[keep]}


def cases(prisms=(50, 7, 100), paper: bool = True):
    """(name, ColumnConfig, params) of the paper's 12 cases and of lanes_check's."""
    from warp_tensegrity import ColumnConfig

    if paper:
        yield "paper_12", ColumnConfig(), PAPER_CASES
    for n in prisms:
        for hand in ("right", "alternating"):
            yield f"lanes_check_{n}_{hand}", ColumnConfig(n_prisms=n, handedness=hand), lanes_check_params(n)


def _rel(a: np.ndarray, b: np.ndarray) -> float:
    """Largest per-column |a - b| over the column's peak |b| (column first)."""
    ax = tuple(range(1, b.ndim))
    return float((np.abs(a - b).max(axis=ax) / np.maximum(np.abs(b).max(axis=ax), 1e-300)).max())


def compare(device: str, t_end: float, case_list, paths=None):
    """Yields one row per (case, path): the relative differences from the staged path and whether
    every column of both runs stayed ok."""
    from warp_tensegrity import RunSettings, decide, simulate_batch
    from warp_tensegrity.sim.integrate import Integrator  # noqa: F401 (fills the Step registry)
    from warp_tensegrity.sim.step import STEPS
    from warp_tensegrity.types import Path

    paths = [Path(p) for p in (paths or STEPS)]
    for name, cfg, params in case_list:
        s = RunSettings(t_end=t_end, precision="fp64", device=device, truncate=False,
                        output_interval=min(0.01, t_end))
        plan = decide(cfg, params, s)
        runs = {}
        for p in [Path.STAGED] + [p for p in paths if p != Path.STAGED]:
            t0 = time.perf_counter()
            runs[p] = (simulate_batch(cfg, params, plan=dataclasses.replace(plan, path=p)), time.perf_counter() - t0)
        twin_params = dict(params, v0=np.asarray(params["v0"], dtype=np.float64) * (1.0 + 2.0**-52))
        t0 = time.perf_counter()
        runs[ROUNDOFF] = (simulate_batch(cfg, twin_params, plan=dataclasses.replace(plan, path=Path.STAGED)),
                          time.perf_counter() - t0)
        ref = runs[Path.STAGED][0]
        early = np.asarray(ref.time) <= T_EARLY + 1e-12
        rows = []
        for p, (r, wall) in runs.items():
            rows.append({
                "case": name, "path": getattr(p, "value", p), "n_prisms": cfg.n_prisms, "columns": int(r.n_columns),
                "n_steps": int(r.n_steps), "step_path": r.info.get("step_path"),
                "rel_strain_early": _rel(r.strain[:, early], ref.strain[:, early]),
                "rel_strain": _rel(r.strain, ref.strain),
                "rel_displacement": _rel(r.final_displacement, ref.final_displacement),
                "rel_velocity": _rel(r.final_velocity, ref.final_velocity),
                "status_ok": bool(np.all(r.status == 0) and np.all(ref.status == 0)), "wall_s": wall})
        twin = next(r for r in rows if r["path"] == ROUNDOFF)
        for row in rows:
            row["over_twin"] = max(row[k] / max(twin[k], TOL / ROUNDOFF_FACTOR) for k in KEYS)
            row["passes"] = passes(row, twin)
            yield row


KEYS = ("rel_strain", "rel_displacement", "rel_velocity")


def passes(row: dict, twin: dict) -> bool:
    """A Step's row against its case's round-off twin (see the module's docstring)."""
    return bool(row["status_ok"] and row["rel_strain_early"] <= TOL
                and all(row[k] <= max(TOL, ROUNDOFF_FACTOR * twin[k]) for k in KEYS))


def worst(rows) -> float:
    """The largest difference of any Step (the round-off twin left out)."""
    return max(max(r[k] for k in KEYS) for r in rows if r["path"] != ROUNDOFF)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--device", default="cuda:0")
    ap.add_argument("--out", required=True)
    ap.add_argument("--t-end", dest="t_end", type=float, default=1.0)
    ap.add_argument("--prisms", type=int, nargs="*", default=[50, 7, 100], help="lanes_check's column lengths")
    ap.add_argument("--no-paper", dest="paper", action="store_false", help="leave the paper's 12 cases out")
    a = ap.parse_args(argv)
    import warp as wp

    wp.config.quiet = True
    wp.init()
    doc = {"kind": "same_physics", "meta": common.run_metadata(wp.get_device(a.device)), "t_end": a.t_end,
           "tolerance": TOL, "t_early": T_EARLY, "roundoff_factor": ROUNDOFF_FACTOR, "rows": []}
    for row in compare(a.device, a.t_end, cases(a.prisms, a.paper)):
        doc["rows"].append(row)
        print(row, flush=True)
    doc["worst"] = worst(doc["rows"])
    doc["worst_early"] = max(r["rel_strain_early"] for r in doc["rows"])
    doc["worst_over_twin"] = max(r["over_twin"] for r in doc["rows"] if r["path"] != ROUNDOFF)
    doc["pass"] = all(r["passes"] for r in doc["rows"])
    common.write_json(a.out, doc)
    print(f"worst relative difference from staged: {doc['worst']:.3e} at t_end, {doc['worst_early']:.3e} up to "
          f"{T_EARLY} s; at most {doc['worst_over_twin']:.2f}x the round-off twin's ({'pass' if doc['pass'] else 'FAIL'})")
    return 0 if doc["pass"] else 1


if __name__ == "__main__":
    sys.exit(main())
