#!/usr/bin/env bash
# One GPU call for the warp-per-column step (issue 24): agreement and resources, throughput of
# every path at B = 1,536 and 16,384 (the pre-lanes paths are the 3e92af8 baseline: their kernels
# are unchanged), Nsight Compute of the lane kernel (FB fp32, B = 16,384) and its SASS.
# Run from the repo root after staging Warp (README "GPU"): bash benchmarks/lanes_session.sh $OUT
set -u
OUT=${1:?output dir}
export PYTHONPATH=/tmp/site:$PWD PYTHONUNBUFFERED=1 WARP_CACHE_PATH=/tmp/wcache
nvidia-smi --query-gpu=name,driver_version --format=csv,noheader | tee "$OUT/gpu.txt"
tag=$(nvidia-smi --query-gpu=name --format=csv,noheader | grep -q H200 && echo h200 || echo h100)
SECTIONS=${LANES_SECTIONS:-check throughput ncu}
if [[ " $SECTIONS " == *" check "* ]]; then
  echo "== agreement with the staged kernels, resources"
  python3 -m benchmarks.lanes_check --device cuda:0 --out "$OUT/lanes_check_$tag.json" 2>&1 | grep -v "^Module"
fi
if [[ " $SECTIONS " == *" throughput "* ]]; then
  echo "== throughput"
  python3 -m benchmarks.throughput --device cuda:0 --paths ${LANES_PATHS:-lanes fused fused-serial staged} \
    --bases ${LANES_BASES:-FB} --precisions fp32 fp64 --batches ${LANES_BATCHES:-1536 16384} --prisms 50 \
    --prism-batch 16384 --prism-paths lanes --target-s ${LANES_TARGET_S:-1.0} --no-diagnostics \
    --out "$OUT/throughput_lanes_$tag.json" 2>&1 | grep -v "^Module" | grep -E "col-steps|ERROR|skip|throughput\]"
fi
if [[ " $SECTIONS " == *" ncu "* ]]; then
  echo "== Nsight Compute, lane kernel, FB fp32 B=16384 (one 64-step launch after initialize)"
  NCU=$(command -v ncu || ls /opt/nvidia/nsight-compute/*/ncu /usr/local/cuda/bin/ncu 2>/dev/null | head -n1)
  rep=/tmp/ncu_lanes
  "$NCU" --target-processes all --clock-control none --kernel-name regex:lane_steps --launch-skip 1 --launch-count 1 \
    --section SpeedOfLight --section LaunchStats --section Occupancy --section WarpStateStats \
    --section SchedulerStats --section InstructionStats --section MemoryWorkloadAnalysis \
    --metrics smsp__inst_executed.sum,smsp__issue_active.avg.pct_of_peak_sustained_active,l1tex__t_bytes_pipe_lsu_mem_local_op_ld.sum,l1tex__t_bytes_pipe_lsu_mem_local_op_st.sum,smsp__thread_inst_executed_per_inst_executed.ratio \
    --export "$rep" --force-overwrite \
    python3 -m benchmarks.throughput --device cuda:0 --ncu-mode --bases FB --precisions fp32 \
    --ncu-batch 16384 --ncu-steps 64 --paths lanes 2>&1 | grep -v "^Module" | tail -5
  "$NCU" --import "$rep.ncu-rep" --csv --page details > "$OUT/ncu_lanes_FB_fp32_B16384_$tag.csv"
  "$NCU" --import "$rep.ncu-rep" --csv --page raw --metrics smsp__inst_executed.sum,smsp__issue_active.avg.pct_of_peak_sustained_active,l1tex__t_bytes_pipe_lsu_mem_local_op_ld.sum,launch__registers_per_thread,sm__warps_active.avg.pct_of_peak_sustained_active,gpu__time_duration.sum > "$OUT/ncu_lanes_raw_$tag.csv"
  echo "== SASS of the lane kernels (barriers, local memory)"
  {
    for f in $(find /tmp/wcache -path "*lane_steps*" -name "*.cubin" 2>/dev/null); do
      echo "## $f"
      cuobjdump -res-usage "$f" 2>&1 | grep -A1 lane_steps | head -4
      echo "BAR: $(cuobjdump -sass "$f" | grep -cE '\bBAR\b|BAR\.') LDL: $(cuobjdump -sass "$f" | grep -c LDL) STL: $(cuobjdump -sass "$f" | grep -c STL) SHFL: $(cuobjdump -sass "$f" | grep -c SHFL) instructions: $(cuobjdump -sass "$f" | grep -cE '^\s+/\*[0-9a-f]+\*/')"
    done
  } | tee "$OUT/sass_lanes_$tag.txt"
fi
