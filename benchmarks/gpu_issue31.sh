#!/usr/bin/env bash
# Issues 31 and 32 on one GPU, one device call (after staging the carry, README "Running on a GPU
# machine"): the feasibility record's cost as a share of stepping, then phase_large in precision
# auto, fp64 and fp32 (groups of like stiffness, error estimates from twins) and fp64 with one dt
# (no groups: the last release's run, with its twin), each against every case in fp64 at a quarter
# of its group's dt (benchmarks/error_coverage.py; the reference is read from REFERENCE.npz where it
# exists, else computed and kept there), with the flags' counts by reason.
#   bash benchmarks/gpu_issue31.sh $OUT [REFERENCE.npz]     (GIT_COMMIT=<the commit measured>)
set -uo pipefail
OUT=${1:?give the output folder}
REF=${2:-$OUT/reference_phase_large.npz}
export PYTHONUNBUFFERED=1 MPLBACKEND=Agg WARP_CACHE_PATH=${WARP_CACHE_PATH:-/tmp/warp_cache}
nvidia-smi --query-gpu=name,driver_version,clocks.max.sm --format=csv | tee "$OUT/gpu.txt"
[ -n "${SKIP_FEASIBILITY_COST:-}" ] || python -m benchmarks.feasibility_cost --device cuda:0 --columns 16384 \
    --steps 1100 --reps 3 --out "$OUT/feasibility_cost_gpu.json" 2>&1 | tail -20 | tee "$OUT/feasibility_cost.log"
python -m benchmarks.error_coverage --spec sweeps/phase_large.toml --device cuda:0 \
    --precision auto fp64 fp32 fp64:onedt --reference-cache "$REF" \
    --out "$OUT/error_coverage_phase_large_gpu.json" 2>&1 | grep -v "^Warp\|^   \|Kernel cache" | tee "$OUT/error_coverage.log"
