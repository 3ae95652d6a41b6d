#!/usr/bin/env bash
# Issue 33's GPU measurements in one device call on a host of several GPUs: each stream of
# benchmarks/gpu_issue33.sh PARTs runs on its own GPU (CUDA_VISIBLE_DEVICES) with its own kernel
# cache, the streams at once, every job cut at the call's deadline (LIMIT_S from the start), logs
# in $OUT/stream<i>.log, results in $OUT/s<i>/ (the probes the estimates used in $OUT/s<i>/calibration/).
#   GIT_COMMIT=<commit> BASE_COMMIT=<baseline> STREAMS='PART=throughput CASES="FB fp64 16384"|PART=check#PART=e2e' \
#       bash benchmarks/gpu_issue33_all.sh $OUT BASE_DIR [LIMIT_S]
# STREAMS: the GPUs' streams separated by '#', a stream's jobs by '|', a job = VAR=value ... (shell words).
set -uo pipefail
OUT=${1:?give the output folder}
BASE=${2:?give the baseline folder}
LIMIT=${3:-540}
END=$(( $(date +%s) + LIMIT ))
IFS='#' read -r -a streams <<< "${STREAMS:?set STREAMS}"
i=0
for s in "${streams[@]}"; do
    (
        export CUDA_VISIBLE_DEVICES=$i WARP_CACHE_PATH=/tmp/warp_cache_$i WARP_TENSEGRITY_CACHE=$OUT/s$i/calibration
        mkdir -p "$OUT/s$i"
        IFS='|' read -r -a jobs <<< "$s"
        for job in "${jobs[@]}"; do
            left=$(( END - $(date +%s) ))
            [ "$left" -gt 5 ] || { echo "== GPU $i: no time left for $job"; continue; }
            echo "== GPU $i: $job  ($(date +%T), ${left} s left)"
            eval "env $job timeout -k 5 $left bash benchmarks/gpu_issue33.sh \"$OUT/s$i\" \"$BASE\"" 2>&1
        done
        echo "== GPU $i done ($(date +%T))"
    ) > "$OUT/stream$i.log" 2>&1 &
    i=$((i + 1))
done
wait
for f in "$OUT"/stream*.log; do echo "#### $f"; tail -20 "$f"; done
