#!/usr/bin/env bash
# Issue 33 on one GPU, seventh session: what one device call measures, by JOBS (after staging, README
# "Running on a GPU machine"; PYTHONPATH=/tmp/site:$PWD, GIT_COMMIT and BASE_COMMIT set, BASE_DIR holds
# the baseline's warp_tensegrity/ benchmarks/ sweeps/):
#   warm    the kernels of must1 (and with WARM_LONG=1 of long) compiled at once, in parallel processes (one
#           short run each) after the staged and fused modules (common.precompile, both precisions)
#   must1   must-show 1: lanes column-steps/s at 50 prisms (FB fp32 at B = 1,536 and 16,384; FB fp64, RB fp32,
#           RB fp64 at 16,384), this code and the baseline's one after the other, 0.3 s a rep, best of 3
#   ncu     Nsight Compute of the four 50-prism lane kernels (benchmarks/gpu_lanes_ncu.sh)
#   long    the fallback table: lanes, fused, fused-serial, staged at LONG_PRISMS (128 300 1000), B = 4,096
#   e2e     paper_2017 end to end, REPEAT runs, the last under cProfile; the CLI's import profile
#   cache   the kernel cache tarred into $OUT (15 MB parts) for the next call
#   bash benchmarks/gpu_issue33_call.sh $OUT BASE_DIR "warm must1 ncu cache"
# LIMIT_S (default 560): a job that needs more than is left (LEFT_<job>, seconds) is skipped, "cache" always runs.
set -uo pipefail
OUT=${1:?}; BASE=$(cd "${2:?}" && pwd); JOBS=${3:?}
END=$(( $(date +%s) + ${LIMIT_S:-560} ))
HERE=$PWD; SITE=${PYTHONPATH:-}
export PYTHONUNBUFFERED=1 MPLBACKEND=Agg WARP_CACHE_PATH=${WARP_CACHE_PATH:-/tmp/warp_cache_0}
has() {  # has JOB [NEED_S]: JOB asked for and NEED_S seconds left
    [[ " $JOBS " == *" $1 "* ]] || return 1
    local left=$(( END - $(date +%s) ))
    [ "$left" -ge "${2:-0}" ] || { echo "== $1 skipped: $left s left, needs ${2:-0}"; return 1; }
    echo "== $1 ($(date +%T), $left s left)"
}
run_in() {
    if [ "$1" = base ]; then shift; (cd "$BASE" && GIT_COMMIT=${BASE_COMMIT:?} PYTHONPATH=$SITE:$BASE "$@")
    else shift; (cd "$HERE" && PYTHONPATH=$SITE:$HERE "$@"); fi
}
nvidia-smi --query-gpu=name,driver_version,clocks.max.sm --format=csv,noheader | tee "$OUT/gpu.txt"
MUST=("FB fp32 1536 16384" "FB fp64 16384" "RB fp32 16384" "RB fp64 16384")
LONG=${LONG_PRISMS:-128 300 1000}
tp() {  # tp VERSION OUTFILE ARGS...: benchmarks.throughput, its summary lines
    local v=$1 out=$2; shift 2
    run_in "$v" python -m benchmarks.throughput --device cuda:0 --out "$out" "$@" 2>&1 | grep -E "col-steps|ERROR|rror|skip" | tail -12
}
if has warm; then
    t0=$(date +%s)
    pre='from benchmarks import common; import warp as wp; wp.config.quiet = True; wp.init(); print(common.precompile(wp.get_device("cuda:0"), ["fp32", "fp64"]))'
    for v in new ${WARM_BASE:-base}; do run_in "$v" python -c "$pre" 2>&1 | tail -1 | sed "s/^/precompile $v: /" & done
    wait
    for v in new ${WARM_BASE:-base}; do
        for c in FB:fp32 FB:fp64 RB:fp32 RB:fp64; do
            tp "$v" "/tmp/warm_${v}_${c/:/_}.json" --paths lanes --bases "${c%%:*}" --precisions "${c##*:}" --batches 64 \
                --prisms 50 --prism-batch 64 --target-s 0.01 --reps 1 | grep -iE "rror" &
        done
    done
    if [ "${WARM_LONG:-0}" = 1 ]; then
        for n in $LONG; do for c in FB:fp32 FB:fp64 RB:fp32 RB:fp64; do
            tp new "/tmp/warm_long_${n}_${c/:/_}.json" --paths lanes fused fused-serial staged --bases "${c%%:*}" \
                --precisions "${c##*:}" --batches --prisms "$n" --prism-batch 64 --prism-paths lanes fused fused-serial staged \
                --target-s 0.01 --reps 1 | grep -iE "rror" &
        done; done
    fi
    wait
    echo "== warm: $(( $(date +%s) - t0 )) s"
fi
if has must1 60; then
    for v in new base; do
        for spec in "${MUST[@]}"; do
            set -- $spec
            tp "$v" "$OUT/throughput_must1_${v}_$1_$2.json" --paths lanes --bases "$1" --precisions "$2" --batches "${@:3}" \
                --prisms 50 --prism-batch "$3" --target-s 0.3 --reps 3 | sed "s/^/$v /"
        done
    done
fi
if has e2e 60; then
    IFS=: read -r -a dirs <<< "$SITE"
    python -m compileall -q -j 8 "${dirs[@]}" "$HERE/warp_tensegrity" > /dev/null 2>&1
    run_in new python -X importtime -c "import warp_tensegrity.cli, warp; wp=warp; wp.init()" 2> "$OUT/importtime_cli.txt" > /dev/null
    run_in new python -m benchmarks.end_to_end sweeps/paper_2017.toml --device cuda:0 --repeat "${REPEAT:-2}" \
        --out "$OUT/end_to_end_paper_2017_new.json" 2>&1 | grep -E "wall|rror" | tail -4
    run_in new python -m benchmarks.end_to_end sweeps/paper_2017.toml --device cuda:0 --repeat 1 --profile "$OUT/profile" \
        --out "$OUT/end_to_end_paper_2017_profiled.json" 2>&1 | grep -E "wall|rror" | tail -2
fi
if has ncu 200; then
    bash benchmarks/gpu_lanes_ncu.sh "$OUT" new
fi
if has long 150; then
    for c in ${LONG_CASES:-FB:fp32 RB:fp32 FB:fp64 RB:fp64}; do
        tp new "$OUT/throughput_long_${c/:/_}.json" --paths lanes fused fused-serial staged --bases "${c%%:*}" \
            --precisions "${c##*:}" --batches --prisms $LONG --prism-batch 4096 --prism-paths lanes fused fused-serial staged \
            --target-s 0.2 --reps 2 --budget-s 150
        [ $(( END - $(date +%s) )) -gt 120 ] || { echo "== long: stops after $c"; break; }
    done
fi
if [[ " $JOBS " == *" cache "* ]]; then
    tar -czf "$OUT/kernel_cache.tgz" -C "$(dirname "$WARP_CACHE_PATH")" "$(basename "$WARP_CACHE_PATH")"
    split -b 15M "$OUT/kernel_cache.tgz" "$OUT/kernel_cache.tgz.part" && rm "$OUT/kernel_cache.tgz"
    ls -la "$OUT"/kernel_cache.tgz.part*
fi
