#!/usr/bin/env bash
# Nsight Compute source counters of the fused kernel: where its instructions and stalls go, per
# line of the Warp-generated CUDA source (Warp compiles with lineinfo here), for issue 13.
#
#   NCU_BASE=FB NCU_PREC=fp32 NCU_BATCH=16384 bash benchmarks/ncu_source.sh OUTDIR
#
# Writes OUTDIR/ncu_source_<base>_<prec>_B<B>.csv (--page source, CUDA lines with their metrics),
# OUTDIR/ncu_source_<base>_<prec>_B<B>_details.csv (--page details) and the kernel's .cu source.
set -euo pipefail
OUTDIR=${1:-${OUT:-benchmarks/results}}
mkdir -p "$OUTDIR"
NCU=${NCU:-$(command -v ncu || ls /opt/nvidia/nsight-compute/*/ncu /usr/local/cuda/bin/ncu 2>/dev/null | head -n1 || true)}
[ -n "$NCU" ] && [ -x "$NCU" ] || { echo "ncu not found; set NCU=/path/to/ncu" >&2; exit 0; }
B=${NCU_BATCH:-16384}; BASE=${NCU_BASE:-FB}; PREC=${NCU_PREC:-fp32}
export WARP_CACHE_PATH=${WARP_CACHE_PATH:-$(mktemp -d)}
TMP=$(mktemp -d)
tag="${BASE}_${PREC}_B${B}"
"$NCU" --target-processes all --clock-control none --kernel-name regex:rattle_columns \
  --launch-skip 1 --launch-count 1 --import-source yes \
  --section SourceCounters --section WarpStateStats --section SpeedOfLight --section Occupancy \
  --export "$TMP/src" --force-overwrite \
  python3 -c "import warp as wp, runpy, sys; wp.config.lineinfo = True; sys.argv = ['throughput', '--device', 'cuda:0', '--ncu-mode', '--bases', '$BASE', '--precisions', '$PREC', '--ncu-batch', '$B', '--ncu-steps', '32', '--paths', 'fused']; runpy.run_module('benchmarks.throughput', run_name='__main__')" >&2
"$NCU" --import "$TMP/src.ncu-rep" --csv --page details > "$OUTDIR/ncu_source_${tag}_details.csv"
"$NCU" --import "$TMP/src.ncu-rep" --csv --page source --print-source cuda > "$OUTDIR/ncu_source_${tag}.csv" \
  || "$NCU" --import "$TMP/src.ncu-rep" --csv --page source > "$OUTDIR/ncu_source_${tag}.csv" || true
find "$WARP_CACHE_PATH" -name "*rattle_columns*.cu" -exec cp {} "$OUTDIR/" \; 2>/dev/null || true
gzip -f "$OUTDIR"/*.cu 2>/dev/null || true
ls -la "$OUTDIR" >&2
