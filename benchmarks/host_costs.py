"""The host's share of a sweep's run on this machine, with nothing stepped and no kernel compiled:
the imports a run makes, Warp's initialisation, the plan (`plan_sweep`), the template dataset and the
store's layout, and a full garbage collection at the heap those leave (the collection the graph
capture used to run once per run, before daaf375). It tells a slow host from slow code: the same
script on the CPU host and on a GPU host.

    python -m benchmarks.host_costs sweeps/phase_large.toml --device cuda:0 --out OUT.json
"""

from __future__ import annotations

import argparse
import gc
import sys
import tempfile
import time
from pathlib import Path


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("spec")
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--out", required=True)
    a = ap.parse_args(argv)
    t = {}
    t0 = time.perf_counter()
    import warp as wp

    wp.config.quiet = True
    t["import_warp"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    wp.init()
    wp.get_device(a.device)
    t["warp_init"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    from warp_tensegrity import cli  # noqa: F401 - what `warp-tensegrity run` imports
    from warp_tensegrity.sim import integrate  # noqa: F401
    from warp_tensegrity.sweep.plan import plan_sweep
    from warp_tensegrity.sweep.shard import template_dataset
    from warp_tensegrity.sweep.spec import load_spec
    from warp_tensegrity.sweep.store import SweepStore

    t["import_package"] = time.perf_counter() - t0
    from . import common

    spec = load_spec(Path(a.spec))
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "out.nc"
        t0 = time.perf_counter()
        plan = plan_sweep(spec, out, device=a.device)
        t["plan_sweep"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        tpl = template_dataset(plan)
        t["template_dataset"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        SweepStore(out).initialise(plan, tpl)
        t["store_layout"] = time.perf_counter() - t0
        collections = []
        for _ in range(3):
            t0 = time.perf_counter()
            gc.collect()
            collections.append(time.perf_counter() - t0)
        t["gc_collect"] = collections
        t["gc_objects"] = len(gc.get_objects())
    doc = {"kind": "host_costs", "meta": common.run_metadata(wp.get_device(a.device)), "spec": a.spec,
           "seconds": t}
    common.write_json(a.out, doc)
    print({k: (round(v, 3) if isinstance(v, float) else v) for k, v in t.items()})
    return 0


if __name__ == "__main__":
    sys.exit(main())
