"""Reference outputs for refactors: runs ``ci_small``, ``paper_2017`` (truncated in time) and the
holdout scenes of ``tests/validation/test_against_reference.py`` in fp64 on Warp's CPU device and writes every
output array (strain histories, energies, errors, status, final state, pulse measures) to one
compressed npz. A refactor that must not change results re-runs this and compares bit for bit
(``tests/test_reference_outputs.py``).

    python -m benchmarks.reference_outputs            # rewrite tests/data/reference_outputs.npz
    python -m benchmarks.reference_outputs --check    # compare (see below), exit 1 on a change
    python -m benchmarks.reference_outputs --check --exact   # exit 1 on any bit that differs
    python -m benchmarks.reference_outputs --remeasure  # only the sweeps' measures, from the stored strain
    python -m benchmarks.reference_outputs --add-new    # add new outputs; every existing entry kept

``--remeasure`` (for a change of the measures alone, issue 25) recomputes each stored sweep shard's
per-case measures (device measure on the CPU, measure_columns, the beta_limit variables) from its
stored strain record and parameters, and rewrites only the entries that differ or are new; every
simulation output stays as committed. It reads the stored ``feasibility_time`` where the file has
it (the measures of a case that left the feasible set are NaN, docs/model.md).

``--add-new`` (for a new output array, issue 32's feasibility record) runs everything and adds the
arrays the file does not hold yet; every array it holds stays as committed (run ``--check`` first:
it lists them as "missing in reference").

**The BLAS.** The scene build (the impact's least-energy solve, the self-stress null vector, the
base-mode eigensolve) goes through NumPy's and SciPy's OpenBLAS, which picks its kernels by CPU:
on a CPU with AVX-512 it takes SkylakeX kernels, on others Haswell, Sandybridge, ... Their results
differ in the last bits, and the dynamics carry that to the outputs (measured over five kernel sets
on one machine: strain histories within 4.0e-12 of their peak, measures within 2.6e-13). So:

* the file records the BLAS it was made with (``meta/blas``: each library's OpenBLAS version, its
  kernel set and thread count), and :func:`pinned_blas_env` gives the environment that makes
  OpenBLAS take the same kernels and threads (``OPENBLAS_CORETYPE``, ``OPENBLAS_NUM_THREADS``);
* a run under the recorded BLAS must be bit-identical (the test checks this whenever the pin
  takes, which is any x86-64 CPU with AVX2 and the same OpenBLAS versions);
* under any other BLAS every array must stay within its round-off tolerance (:data:`TOLERANCES`,
  each with its reason, 25x or more above the spread measured across kernel sets and far below what
  a real change makes: a cable stiffness changed by 1e-8 moves the strain by ~1e-8 of its peak).
"""

from __future__ import annotations

import argparse
import json
import os
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


META_BLAS = "meta/blas"
"""The npz entry recording the BLAS the file was made with (JSON: :func:`blas_signature`)."""

ROUND_OFF = {"strain", "kinetic_energy", "elastic_energy", "station_energy", "end_energy", "final_displacement",
             "final_velocity", "twist_max", "twist_min", "height_ratio_min"}  # the last three: extremes of a state history
MEASURES = {"amplitude", "speed", "width", "width_10", "arrival_time", "max_compression", "base_mode_ratio",
            "pulse_energy_share", "end_energy_share"}
ESTIMATES = {f"{k}_error" for k in ("amplitude", "speed", "width", "width_10", "arrival_time")}
TOLERANCES = {
    **{k: ("peak", 2e-9, "an error estimate: the difference of two runs' measures, each at round-off (spread across "
                         "kernel sets 5.7e-11 of its largest value)") for k in ESTIMATES},
    **{k: ("peak", 1e-10, "a state history: round-off of the BLAS-built initial state carried by the dynamics "
                          "(spread across kernel sets 4.0e-12 of the peak)") for k in ROUND_OFF},
    **{k: ("peak", 1e-11, "a measure of a history (spread across kernel sets 2.6e-13 of its largest value)")
       for k in MEASURES},
    "energy_error": ("abs", 1e-11, "a relative energy error, itself round-off and truncation (spread 3.0e-13)"),
    "bar_length_error": ("abs", 1e-14, "a relative bar-length error at round-off (spread 3.0e-16)"),
}
"""Per-array tolerance under a BLAS other than the recorded one, by the array's last name:
('peak', x): |new - ref| <= x * max|ref|; ('abs', x): |new - ref| <= x. Every other array (time axes,
parameters, dt, status, fail steps, flags, counts) must be equal."""


def blas_signature() -> list[dict]:
    """The BLAS libraries loaded by NumPy and SciPy: OpenBLAS version, kernel set, threads
    (threadpoolctl, a test dependency)."""
    import scipy.linalg  # noqa: F401  (loads SciPy's own OpenBLAS)
    from threadpoolctl import threadpool_info

    return sorted(({"library": os.path.basename(d["filepath"]).split("-")[0], "version": d.get("version"),
                    "architecture": d.get("architecture"), "num_threads": d.get("num_threads")}
                   for d in threadpool_info() if d.get("user_api") == "blas"), key=lambda d: d["library"])


def recorded_blas(path: Path = REFERENCE_FILE) -> list[dict] | None:
    with np.load(path) as ref:
        return json.loads(str(ref[META_BLAS])) if META_BLAS in ref.files else None


def pinned_blas_env(env: dict | None = None, path: Path = REFERENCE_FILE) -> dict:
    """``env`` (default: this process's) with OpenBLAS told to take the recorded kernel set and
    thread count, so a run reproduces the reference bit for bit where the CPU allows it."""
    env = dict(os.environ if env is None else env)
    rec = recorded_blas(path) or []
    archs = {d["architecture"] for d in rec if d.get("architecture")}
    threads = {d["num_threads"] for d in rec if d.get("num_threads")}
    if len(archs) == 1:
        env["OPENBLAS_CORETYPE"] = archs.pop()
    if len(threads) == 1:
        env["OPENBLAS_NUM_THREADS"] = str(threads.pop())
    return env


def compare_report(new: dict, path: Path = REFERENCE_FILE) -> tuple[list[str], list[str], dict]:
    """(changed, bit-identical, within tolerance): names over their tolerance (:data:`TOLERANCES`) or
    missing on either side; names equal bit for bit (NaN equal to NaN); names that differ within their
    tolerance, each with its largest difference as a fraction of the tolerance.
    The reference's ``time`` arrays are compared under the axis's current name ``t`` (renamed for
    CF, issue 17: simulated time is no calendar time)."""
    with np.load(path) as ref:
        ref_name = {_renamed(k): k for k in ref.files if not k.startswith("meta/")}
        names = set(ref_name) | {k for k in new if not k.startswith("meta/")}
        bad, same, within = [], [], {}
        for k in sorted(names):
            if k not in ref_name or k not in new:
                bad.append(f"{k}: missing {'in reference' if k not in ref_name else 'in new run'}")
                continue
            r, x = ref[ref_name[k]], np.asarray(new[k])
            if np.array_equal(r, x, equal_nan=r.dtype.kind == "f"):
                same.append(k)
                continue
            rule = TOLERANCES.get(k.rsplit("/", 1)[-1])
            if rule is None or r.shape != x.shape or r.dtype.kind != "f":
                bad.append(f"{k}: differs (no tolerance: must be equal)")
                continue
            kind, tol, _ = rule
            if kind == "peak":
                tol = tol * float(np.nanmax(np.abs(r), initial=0.0))
            if not np.array_equal(np.isnan(r), np.isnan(x)):
                bad.append(f"{k}: differs (NaN in other places)")
                continue
            diff = float(np.nanmax(np.abs(x - r), initial=0.0))
            if not diff <= tol:
                bad.append(f"{k}: differs by {diff:.3g}, over its tolerance {tol:.3g}")
            else:
                within[k] = diff / tol if tol else 0.0
        return bad, same, within


def compare(new: dict, path: Path = REFERENCE_FILE, exact: bool = False) -> list[str]:
    """Names whose arrays changed (over their tolerance, or with ``exact`` in any bit) or are
    missing on either side (:func:`compare_report`)."""
    bad, _, within = compare_report(new, path)
    return bad + ([f"{k}: differs within round-off ({f:.2g} of its tolerance)" for k, f in within.items()]
                  if exact else [])


def summary(new: dict, path: Path = REFERENCE_FILE) -> str:
    """One line: bit-identical, or within round-off (with the largest fraction of a tolerance used)."""
    bad, same, within = compare_report(new, path)
    if bad:
        return "\n".join(bad)
    if not within:
        return f"bit-identical: {len(same)} arrays"
    worst = max(within, key=within.get)
    return (f"within round-off: {len(same)} arrays bit-identical, {len(within)} within their tolerance "
            f"(largest: {worst} at {within[worst]:.2g} of it); BLAS here {json.dumps(blas_signature())}, "
            f"the reference's {json.dumps(recorded_blas(path))}")


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
    shards = sorted({k.rsplit("/", 1)[0] for k in out if "/shard" in k and not k.startswith("meta/")})
    for sh in shards:
        name = sh.split("/")[0]
        spec = load_spec(ROOT / "sweeps" / f"{name}.toml")
        strain = out[f"{sh}/strain"]
        time = out[f"{sh}/t"] if f"{sh}/t" in out else out[f"{sh}/time"]  # the axis is "t" since the CF rename
        B = strain.shape[0]
        with np.errstate(all="ignore"):
            dev = measure_pulse_device(strain, time, spec.scene.height, device="cpu")
        feas = {"feasibility_time": out[f"{sh}/feasibility_time"]} if f"{sh}/feasibility_time" in out else None
        res = SimpleNamespace(status=out[f"{sh}/status"], strain=strain, time=time, measurements=dev, feasibility=feas)
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
    ap.add_argument("--exact", action="store_true", help="with --check: fail on any bit that differs")
    ap.add_argument("--add-new", action="store_true",
                    help="add the arrays a run has and the file lacks (new outputs); every existing entry kept")
    args = ap.parse_args(argv)
    import warp as wp

    wp.config.quiet = True
    if args.add_new:
        with np.load(REFERENCE_FILE) as ref:
            before = {k: ref[k] for k in ref.files}
        held = {_renamed(k) for k in before}
        new = {k: v for k, v in compute().items() if k not in held and not k.startswith("meta/")}
        print("\n".join(f"{k}: new" for k in sorted(new)))
        np.savez_compressed(REFERENCE_FILE, **before, **new)
        print(f"wrote {REFERENCE_FILE} ({len(new)} entries added)")
        return 0
    if args.remeasure:
        with np.load(REFERENCE_FILE) as ref:
            before = {k: ref[k] for k in ref.files}
        out = remeasure()
        changed = [k for k in out if not k.startswith("meta/") and (
            k not in before or not np.array_equal(out[k], before[k], equal_nan=out[k].dtype.kind == "f"))]
        print("\n".join(f"{k}: {'new' if k not in before else 'changed'}" for k in changed))
        np.savez_compressed(REFERENCE_FILE, **out)
        print(f"wrote {REFERENCE_FILE} ({len(changed)} entries rewritten)")
        return 0
    out = compute()
    if args.check:
        print(summary(out))
        return 1 if compare(out, exact=args.exact) else 0
    out[META_BLAS] = np.asarray(json.dumps(blas_signature()))
    REFERENCE_FILE.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(REFERENCE_FILE, **out)
    print(f"wrote {REFERENCE_FILE} ({len(out)} arrays, {REFERENCE_FILE.stat().st_size / 1e6:.2f} MB)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
