#!/usr/bin/env bash
# Issues 31 and 32 on one GPU (after staging the carry, README "Running on a GPU machine"), in two
# device calls of < 10 min on the warm machine:
#   part a: the feasibility record's cost as a share of stepping; phase_large in precision auto (groups
#           of like stiffness, error estimates from twins, fp32 verified, fp64 reruns) against every
#           case in fp64 at a quarter of its group's dt (benchmarks/error_coverage.py), the reference
#           kept in $OUT/reference_phase_large.npz
#   part b: fp64, fp64 with one dt (no groups: the last release's run, with its twin) and fp32
#           against that reference, appended to part a's JSON
#   bash benchmarks/gpu_issue31.sh $OUT a
#   bash benchmarks/gpu_issue31.sh $OUT b REFERENCE.npz PART_A.json
# (GIT_COMMIT=<the commit measured> in the environment)
set -uo pipefail
OUT=${1:?give the output folder}
PART=${2:-a}
export PYTHONUNBUFFERED=1 MPLBACKEND=Agg WARP_CACHE_PATH=${WARP_CACHE_PATH:-/tmp/warp_cache}
nvidia-smi --query-gpu=name,driver_version,clocks.max.sm --format=csv | tee "$OUT/gpu_$PART.txt"
json="$OUT/error_coverage_phase_large_gpu.json"
if [ "$PART" = a ]; then
  python -m benchmarks.feasibility_cost --device cuda:0 --columns 16384 --steps 1100 --reps 3 \
      --out "$OUT/feasibility_cost_gpu.json" 2>&1 | tail -20 | tee "$OUT/feasibility_cost.log"
  python -m benchmarks.error_coverage --spec sweeps/phase_large.toml --device cuda:0 --precision auto \
      --reference-cache "$OUT/reference_phase_large.npz" --out "$json" 2>&1 \
      | grep -v "^Warp\|^   \|Kernel cache" | tee "$OUT/error_coverage_a.log"
else
  python -m benchmarks.error_coverage --spec sweeps/phase_large.toml --device cuda:0 \
      --precision fp64 fp64:onedt fp32 --reference-cache "${3:?reference npz}" --modes-from "${4:?part a json}" \
      --out "$json" 2>&1 | grep -v "^Warp\|^   \|Kernel cache" | tee "$OUT/error_coverage_b.log"
fi
