#!/usr/bin/env bash
# Optional: Nsight Compute "Speed of Light" (+ launch stats, occupancy) of the four kernels of
# a RATTLE step, on a short eager run (no CUDA graph) of B columns of 50 prisms.
#
#   bash benchmarks/ncu_kernels.sh [OUTDIR]        # OUTDIR: default $OUT, else benchmarks/results
#   NCU_BATCH=65536 NCU_CONFIGS="FB:fp32 RB:fp64" bash benchmarks/ncu_kernels.sh /tmp/ncu
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
if [ "$PATH_KIND" = fused ]; then
  KERNELS='rattle_columns'; SKIP=1; COUNT=2; EXTRA="--section WarpStateStats --section SchedulerStats"
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
    --ncu-batch "$B" --ncu-steps 32 --paths "$PATH_KIND" >&2
  tag=""; [ "$PATH_KIND" = fused ] && tag="_fused"
  "$NCU" --import "$rep.ncu-rep" --csv --page details > "$OUTDIR/ncu${tag}_${base}_${prec}_B${B}.csv"
  echo "[ncu] wrote $OUTDIR/ncu${tag}_${base}_${prec}_B${B}.csv" >&2
done
rm -rf "$TMP"
