"""Host time of the base-mode analysis a sweep runs (issue 33 item 5): ``beta_limit_measures`` for
``sweeps/phase_large.toml``'s 1,536 columns (96 distinct (prestrain, base_rigidity) pairs) from a
cold cache, on the CPU. The machine may be shared, so the run is repeated and the minimum kept.

usage: python -m benchmarks.base_modes_time [--spec sweeps/phase_large.toml] [--repeats 5] [--out PATH]
"""

from __future__ import annotations

import argparse
import hashlib
import os
import time
from functools import _lru_cache_wrapper

import numpy as np

from benchmarks.common import REPO, RESULTS, run_metadata, write_json


def clear_caches(module) -> None:
    """Empty every lru_cache of ``module`` (a cold start, as in a fresh sweep process)."""
    for obj in vars(module).values():
        if isinstance(obj, _lru_cache_wrapper):
            obj.cache_clear()


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--spec", default=str(REPO / "sweeps" / "phase_large.toml"))
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--out", default=str(RESULTS / "base_modes_time_cpu.json"))
    args = ap.parse_args(argv)

    import warp as wp

    from warp_tensegrity.scene import base_modes as BM
    from warp_tensegrity.sweep.spec import load_spec

    spec = load_spec(args.spec)
    params = spec.column_params()
    n = len(params["prestrain"])
    pairs = {(float(p), float(b)) for p, b in zip(params["prestrain"], params["base_rigidity"])}
    qmax = np.full(n, np.nan)
    times, first = [], None
    for _ in range(args.repeats):
        clear_caches(BM)
        t0 = time.perf_counter()
        out = BM.beta_limit_measures(spec.scene, params, n, qmax)
        times.append(time.perf_counter() - t0)
        first = out if first is None else first
        assert np.array_equal(out["base_mode_ratio"], first["base_mode_ratio"], equal_nan=True)
        print(f"{times[-1]:.3f} s", flush=True)
    result = {
        "meta": run_metadata(wp.get_device("cpu")),
        "spec": str(args.spec),
        "openblas_env": {k: v for k, v in os.environ.items() if k.startswith(("OPENBLAS", "OMP"))},
        "columns": n,
        "distinct_pairs": len(pairs),
        "pairs_below_rigid": sum(b < 1.0 for _, b in pairs),
        "seconds": times,
        "seconds_min": min(times),
        "seconds_median": float(np.median(times)),
        "ratio_sha": hashlib.sha256(np.ascontiguousarray(first["base_mode_ratio"]).tobytes()).hexdigest(),
    }
    print(f"beta_limit_measures, {n} columns, {len(pairs)} pairs: min {min(times):.3f} s over {len(times)}")
    print(write_json(args.out, result))


if __name__ == "__main__":
    main()
