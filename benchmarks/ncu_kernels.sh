#!/usr/bin/env bash
# Optional: Nsight Compute "Speed of Light" (+ launch stats, occupancy) of the four kernels of
# a RATTLE step, on a short eager run (no CUDA graph) of B columns of 50 prisms.
#
#   bash benchmarks/ncu_kernels.sh [OUTDIR]        # OUTDIR: default $OUT, else benchmarks/results
#   NCU_BATCH=65536 NCU_CONFIGS="FB:fp32 RB:fp64" bash benchmarks/ncu_kernels.sh /tmp/ncu
#   NCU_PATH=lanes NCU_BATCH=16384 NCU_CONFIGS="FB:fp32 FB:fp64 RB:fp32 RB:fp64" bash benchmarks/ncu_kernels.sh $OUT
#     (the lane kernel: one 64-step launch after initialize, with warp-state, instruction and memory
#     sections, spill traffic and registers; also writes ncu_lanes_raw_<base>_<precision>_B<B>.csv)
#
# Writes OUTDIR/ncu_<base>_<precision>_B<B>.csv (ncu --page details --csv): one row per
# (kernel launch, metric). Each configuration profiles 8 launches: the 4 step kernels of 2
# steps after initialize. Takes ~20-40 s per configuration when the Warp kernel cache is warm
# (run it after benchmarks.throughput in the same session), plus NVRTC compile otherwise.
set -euo pipefail
OUTDIR=${1:-${OUT:-benchmarks/results}}
mkdir -p "$OUTDIR"
NCU=${NCU:-$(command -v ncu || ls /opt/nvidia/nsight-compute/*/ncu /usr/local/cuda/bin/ncu 2>/dev/null | head -n1 || true)}
if [ -z "${NCU}" ] || [ ! -x "${NCU}" ]; then
  echo "ncu (Nsight Compute) not found; set NCU=/path/to/ncu" >&2
  exit 0
fi
PY=${PYTHON:-python3}
B=${NCU_BATCH:-65536}
CONFIGS=${NCU_CONFIGS:-"FB:fp32 RB:fp64"}
PATH_KIND=${NCU_PATH:-staged}  # staged: the 4 step kernels; fused: rattle_columns (one launch = 16 steps)
STEPS=32
RAW=smsp__inst_executed.sum,smsp__issue_active.avg.pct_of_peak_sustained_active,l1tex__t_bytes_pipe_lsu_mem_local_op_ld.sum,l1tex__t_bytes_pipe_lsu_mem_local_op_st.sum,launch__registers_per_thread,sm__warps_active.avg.pct_of_peak_sustained_active,gpu__time_duration.sum
if [ "$PATH_KIND" = fused ]; then
  KERNELS='rattle_columns'; SKIP=1; COUNT=2; EXTRA="--section WarpStateStats --section SchedulerStats"
elif [ "$PATH_KIND" = lanes ]; then
  KERNELS='lane_steps'; SKIP=1; COUNT=1; STEPS=64
  EXTRA="--section WarpStateStats --section SchedulerStats --section InstructionStats --section MemoryWorkloadAnalysis --metrics $RAW,smsp__thread_inst_executed_per_inst_executed.ratio"
else
  KERNELS='kick_drift|project_positions|gather_accel|factor_project_velocities'; SKIP=2; COUNT=8; EXTRA=""
fi
TMP=$(mktemp -d)
for cfg in $CONFIGS; do
  base=${cfg%%:*}
  prec=${cfg##*:}
  rep="$TMP/ncu_${base}_${prec}"
  echo "[ncu] $base $prec B=$B" >&2
  # skip the 2 launches of initialize (factor_project_velocities, gather_accel), then 8 = 2 steps
  "$NCU" --target-processes all --clock-control none \
    --kernel-name regex:"$KERNELS" \
    --launch-skip $SKIP --launch-count $COUNT \
    --section SpeedOfLight --section LaunchStats --section Occupancy $EXTRA \
    --export "$rep" --force-overwrite \
    "$PY" -m benchmarks.throughput --device cuda:0 --ncu-mode --bases "$base" --precisions "$prec" \
    --ncu-batch "$B" --ncu-steps $STEPS --paths "$PATH_KIND" >&2
  tag=""; [ "$PATH_KIND" = staged ] || tag="_$PATH_KIND"
  "$NCU" --import "$rep.ncu-rep" --csv --page details > "$OUTDIR/ncu${tag}_${base}_${prec}_B${B}.csv"
  echo "[ncu] wrote $OUTDIR/ncu${tag}_${base}_${prec}_B${B}.csv" >&2
  if [ "$PATH_KIND" = lanes ]; then
    "$NCU" --import "$rep.ncu-rep" --csv --page raw --metrics "$RAW" > "$OUTDIR/ncu_lanes_raw_${base}_${prec}_B${B}.csv"
  fi
done
rm -rf "$TMP"
