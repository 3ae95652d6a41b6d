"""Reference outputs for refactors: runs ``ci_small``, ``paper_2017`` (truncated in time) and the
holdout scenes of ``tests/validation/test_against_reference.py`` in fp64 on Warp's CPU device and writes every
output array (strain histories, energies, errors, status, final state, pulse measures) to one
compressed npz. A refactor that must not change results re-runs this and compares bit for bit
(``tests/test_reference_outputs.py``).

    python -m benchmarks.reference_outputs            # rewrite tests/data/reference_outputs.npz
    python -m benchmarks.reference_outputs --check    # compare, exit 1 on any difference
    python -m benchmarks.reference_outputs --remeasure  # only the sweeps' measures, from the stored strain

``--remeasure`` (for a change of the measures alone, issue 25) recomputes each stored sweep shard's
per-case measures (device measure on the CPU, measure_columns, the beta_limit variables) from its
stored strain record and parameters, and rewrites only the entries that differ or are new; every
simulation output stays as committed.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
REFERENCE_FILE = ROOT / "tests" / "data" / "reference_outputs.npz"
PAPER_T_END = 0.4  # s: paper_2017 truncated in time (its full 10 s takes minutes on the CPU)
RESULT_FIELDS = ("time", "strain", "kinetic_energy", "elastic_energy", "energy_error", "bar_length_error",
                 "status", "fail_step", "final_displacement", "final_velocity")


def _result_arrays(prefix: str, r) -> dict:
    out = {f"{prefix}/{k}": np.asarray(getattr(r, k)) for k in RESULT_FIELDS if getattr(r, k) is not None}
    out[f"{prefix}/dt"] = np.asarray(r.dt)
    return out


def _sweep_arrays(name: str, overrides: dict | None = None) -> dict:
    """Every shard of a sweep spec, computed as the CLI does (plan, engine, measures, dataset)."""
    from warp_tensegrity.sweep import compute_shard, load_spec, plan_sweep

    spec = load_spec(ROOT / "sweeps" / f"{name}.toml", overrides=overrides)
    plan = plan_sweep(spec, device="cpu")
    out = {}
    for i in range(plan.n_shards):
        ds = compute_shard(plan, i)
        for k, v in {**ds.data_vars, **ds.coords}.items():
            if v.dtype.kind in "fiub":
                out[f"{name}/shard{i}/{k}"] = v.values
    return out


def _holdout_arrays() -> dict:
    """The scenes of tests/validation/test_against_reference.py, with the settings used there."""
    from warp_tensegrity import (
        ColumnConfig,
        Network,
        RunSettings,
        build_column,
        network_batch,
        run_batch,
        simulate_batch,
    )
    from tests.references.reference import ReferenceSystem

    out = {}
    for speed in (0.002, 0.02):  # free class-1 prism, massive bars, random admissible velocity
        s = build_column(ColumnConfig(n_prisms=1), prestrain=0.01)
        net = s.network
        free = Network(positions=net.positions, node_mass=0.0, fixed=False, bars=net.bars, bar_mass=0.01,
                       cables=net.cables, cable_EA=net.cable_EA, cable_rest_length=net.cable_rest_length).validate()
        rng = np.random.default_rng(1)
        v = ReferenceSystem(free).project_velocities(free.positions, rng.normal(scale=speed, size=(free.n_nodes, 3)))
        for method, dt in (("rk4", 2.5e-4), ("rattle", 2.5e-4), ("rk4", 5e-4)):
            r = run_batch(network_batch([free], [v]), RunSettings(t_end=0.1, dt=dt, method=method, output_interval=0.1,
                                                                  device="cpu"))
            out.update(_result_arrays(f"prism_v{speed}_{method}_dt{dt}", r))
    cfg = ColumnConfig(n_prisms=4)
    for beta in (0.0, 1.0):  # constrained column with slackening cables
        for method in ("rk4", "rattle", "yoshida4", "symplectic_euler"):
            r = simulate_batch(cfg, {"prestrain": [0.002], "v0": [0.05], "base_rigidity": [beta]},
                               RunSettings(t_end=0.2, dt=2e-4, method=method, output_interval=0.01, device="cpu"))
            out.update(_result_arrays(f"column_b{beta}_{method}", r))
    return out


def compute() -> dict:
    out = {}
    out.update(_sweep_arrays("ci_small"))
    out.update(_sweep_arrays("paper_2017", {"run": {"t_end": PAPER_T_END, "output_interval": 0.002}}))
    out.update(_holdout_arrays())
    return out


def compare(new: dict, path: Path = REFERENCE_FILE) -> list[str]:
    """Names whose arrays differ (bitwise, NaN equal to NaN) or are missing on either side.
    The reference's ``time`` arrays are compared under the axis's current name ``t`` (renamed for
    CF, issue 17: simulated time is no calendar time); their values must still match bit for bit."""
    with np.load(path) as ref:
        ref_name = {_renamed(k): k for k in ref.files}
        names = set(ref_name) | set(new)
        bad = []
        for k in sorted(names):
            if k not in ref_name or k not in new:
                bad.append(f"{k}: missing {'in reference' if k not in ref_name else 'in new run'}")
            elif not np.array_equal(r := ref[ref_name[k]], new[k], equal_nan=r.dtype.kind == "f"):
                bad.append(f"{k}: differs")
        return bad


def _renamed(name: str) -> str:
    """A dataset's (shard's) ``time`` variable is ``t`` now; BatchResult.time keeps its name."""
    head, _, last = name.rpartition("/")
    return f"{head}/t" if last == "time" and "/shard" in f"/{head}" else name


MEASURE_KEYS = ("amplitude", "speed", "width", "width_10", "prisms_measured", "arrival_time", "max_compression",
                "measurement_flag", "base_mode_ratio", "beta_limit_flag")


def remeasure(path: Path = REFERENCE_FILE) -> dict:
    """The stored file with the sweep shards' measures recomputed from their stored strain."""
    from types import SimpleNamespace

    from warp_tensegrity.measure.device import measure_pulse_device
    from warp_tensegrity.measure.nan_reasons import measure_columns
    from warp_tensegrity.scene.base_modes import beta_limit_measures
    from warp_tensegrity.sweep import load_spec
    from warp_tensegrity.options import COLUMN_PARAMETERS

    with np.load(path) as ref:
        out = {k: ref[k] for k in ref.files}
    shards = sorted({k.rsplit("/", 1)[0] for k in out if "/shard" in k})
    for sh in shards:
        name = sh.split("/")[0]
        spec = load_spec(ROOT / "sweeps" / f"{name}.toml")
        strain = out[f"{sh}/strain"]
        time = out[f"{sh}/t"] if f"{sh}/t" in out else out[f"{sh}/time"]  # the axis is "t" since the CF rename
        B = strain.shape[0]
        with np.errstate(all="ignore"):
            dev = measure_pulse_device(strain, time, spec.scene.height, device="cpu")
        res = SimpleNamespace(status=out[f"{sh}/status"], strain=strain, time=time, measurements=dev)
        meas = measure_columns(res, spec.scene.height)
        params = {p: np.broadcast_to(out[f"{sh}/{p}"], (B,)) for p in COLUMN_PARAMETERS if f"{sh}/{p}" in out}
        meas.update(beta_limit_measures(spec.scene, params, B, meas["max_compression"]))
        for k in MEASURE_KEYS:
            v = np.asarray(meas[k], dtype=out.get(f"{sh}/{k}", np.asarray(meas[k])).dtype)
            out[f"{sh}/{k}"] = v
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--check", action="store_true", help="compare against the committed file instead of writing it")
    ap.add_argument("--remeasure", action="store_true", help="rewrite only the sweeps' measures from the stored strain")
    args = ap.parse_args(argv)
    import warp as wp

    wp.config.quiet = True
    if args.remeasure:
        with np.load(REFERENCE_FILE) as ref:
            before = {k: ref[k] for k in ref.files}
        out = remeasure()
        changed = [k for k in out if k not in before or not np.array_equal(out[k], before[k], equal_nan=out[k].dtype.kind == "f")]
        print("\n".join(f"{k}: {'new' if k not in before else 'changed'}" for k in changed))
        np.savez_compressed(REFERENCE_FILE, **out)
        print(f"wrote {REFERENCE_FILE} ({len(changed)} entries rewritten)")
        return 0
    out = compute()
    if args.check:
        bad = compare(out)
        print("\n".join(bad) if bad else f"bit-identical: {len(out)} arrays")
        return 1 if bad else 0
    REFERENCE_FILE.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(REFERENCE_FILE, **out)
    print(f"wrote {REFERENCE_FILE} ({len(out)} arrays, {REFERENCE_FILE.stat().st_size / 1e6:.2f} MB)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
