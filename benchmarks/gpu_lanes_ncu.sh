#!/usr/bin/env bash
# Nsight Compute of the lane kernel for the four cases of issue 33 must-show 1 (FB/RB x fp32/fp64,
# 50 prisms, B = 16,384): one 64-step launch after initialize each, the raw counters the issue-bound
# ceiling needs (benchmarks/lanes_bound.py) and the SASS resource use of every compiled lane kernel.
#   bash benchmarks/gpu_lanes_ncu.sh $OUT [TAG]        (after staging the carry, README "Running on a GPU machine")
# Writes $OUT/ncu_lanes_<base>_<prec>_B16384_<TAG>.csv (details page), ..._raw_<TAG>.csv and sass_lanes_<TAG>.txt.
set -uo pipefail
OUT=${1:?give the output folder}
TAG=${2:-new}
B=${NCU_BATCH:-16384}
NCU=${NCU:-$(command -v ncu || ls /opt/nvidia/nsight-compute/*/ncu /usr/local/cuda/bin/ncu 2>/dev/null | head -n1)}
[ -x "$NCU" ] || { echo "ncu not found"; exit 0; }
RAW=smsp__inst_executed.sum,smsp__issue_active.avg.pct_of_peak_sustained_active,l1tex__t_bytes_pipe_lsu_mem_local_op_ld.sum,l1tex__t_bytes_pipe_lsu_mem_local_op_st.sum,launch__registers_per_thread,sm__warps_active.avg.pct_of_peak_sustained_active,gpu__time_duration.sum,smsp__cycles_elapsed.avg.per_second
for cfg in ${NCU_CONFIGS:-FB:fp32 FB:fp64 RB:fp32 RB:fp64}; do
  base=${cfg%%:*}; prec=${cfg##*:}
  rep=/tmp/ncu_lanes_${base}_${prec}_$TAG
  "$NCU" --target-processes all --clock-control none --kernel-name regex:lane_steps --launch-skip 1 --launch-count 1 \
    --section SpeedOfLight --section LaunchStats --section Occupancy --section WarpStateStats \
    --section SchedulerStats --section InstructionStats --metrics "$RAW" \
    --export "$rep" --force-overwrite \
    python3 -m benchmarks.throughput --device cuda:0 --ncu-mode --bases "$base" --precisions "$prec" \
    --ncu-batch "$B" --ncu-steps 64 --paths lanes 2>&1 | grep -E "ncu-mode|rror" | tail -3
  "$NCU" --import "$rep.ncu-rep" --csv --page details > "$OUT/ncu_lanes_${base}_${prec}_B${B}_$TAG.csv"
  "$NCU" --import "$rep.ncu-rep" --csv --page raw --metrics "$RAW" > "$OUT/ncu_lanes_${base}_${prec}_B${B}_raw_$TAG.csv"
done
{
  for f in $(find "${WARP_CACHE_PATH:-/tmp/warp_cache}" -path "*lane_steps*" -name "*.cubin" 2>/dev/null); do
    echo "## $f"
    cuobjdump -res-usage "$f" 2>&1 | grep -A1 lane_steps | head -4
    echo "LDL: $(cuobjdump -sass "$f" | grep -c LDL) STL: $(cuobjdump -sass "$f" | grep -c STL) SHFL: $(cuobjdump -sass "$f" | grep -c SHFL)"
  done
} > "$OUT/sass_lanes_$TAG.txt"
