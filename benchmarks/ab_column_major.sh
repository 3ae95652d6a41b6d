#!/usr/bin/env bash
# A/B on one GPU: the fused step with per-column parameters in the model layout (n, B) against
# the column-major views FusedStep makes (integrate.FusedStep._column_view). Writes $OUT/before.json, after.json.
export PYTHONPATH=/tmp/site:$PWD GIT_COMMIT=${GIT_COMMIT:-unknown}
ARGS="--device cuda:0 --batches 16384 65536 --prisms 50 --prism-batch 1024 --paths fused fused-serial --target-s 0.2 --no-diagnostics"
python3 -c "import sys, runpy; import warp_tensegrity.sim.integrate as I; I.FusedStep._column_view = lambda self, a: a; sys.argv=['t'] + '$ARGS'.split() + ['--out', '$OUT/before.json']; runpy.run_module('benchmarks.throughput', run_name='__main__')" > $OUT/before.log 2>&1
python3 -m benchmarks.throughput $ARGS --out $OUT/after.json > $OUT/after.log 2>&1
python3 - <<'PY'
import json, os
o = os.environ["OUT"]
def pts(f):
    d = json.load(open(f)); return {(p["base"], p["precision"], p["B"], p.get("path")): p["column_steps_per_s"] for p in d["points"] if p.get("n_prisms") == 50}
b, a = pts(f"{o}/before.json"), pts(f"{o}/after.json")
for k in sorted(a):
    print(k, f"{b.get(k, float('nan')):.3e} -> {a[k]:.3e}  x{a[k]/b.get(k, float('nan')):.2f}")
PY
tail -3 $OUT/after.log
