#!/usr/bin/env bash
# Issue 33 item 1 (records inside the lane step) on one GPU, against the baseline in the same call
# (after staging the carry, README "Running on a GPU machine"). PART selects what one device call
# (at most 10 min) runs:
#   PART=check       the lane tests on CUDA (records inside against the record kernels, lanes against staged)
#   PART=throughput  lanes column-steps/s, 50 prisms: FB fp32 at B = 1,536 and 16,384, FB fp64 and RB fp32 at 16,384
#   PART=phase       phase_large end to end (benchmarks/end_to_end.py) in precision PRECISION (fp64, fp32 or auto)
#   PART=long        issue 33 item 3: the fallback table at 128, 300, 500 and 1,000 prisms, B = 4,096: lanes (k warps
#                    per column past a warp), block (fused, fused-serial) and staged, new only; BASES (FB RB) and
#                    PRECISIONS (fp32 fp64) pick a part of it (one call each: FB fp32, RB fp32, then fp64), and
#                    the long-column lane tests on CUDA (tests/kernels/test_lanes_long.py) first (TESTS=0: not);
#                    BASE_DIR is not used (give .)
#   PART=interface   issue 34's interface sweep (sweeps/interface.toml) end to end, new only, and its phase
#                    diagram (analysis/interface.py) from the output
# each for the code here ("new") and in BASE ("base"): the baseline commit's warp_tensegrity/, benchmarks/ and
# sweeps/ (git archive BASE_COMMIT warp_tensegrity benchmarks sweeps | tar -x -C BASE_DIR), run from there.
#   GIT_COMMIT=<commit measured> BASE_COMMIT=<baseline> PART=... bash benchmarks/gpu_issue33.sh $OUT BASE_DIR
set -uo pipefail
OUT=${1:?give the output folder}
BASE=$(cd "${2:?give the baseline folder}" && pwd)
HERE=$PWD
SITE=${PYTHONPATH:-}
run_in() {  # run_in new|base CMD...: in this tree or in BASE, with the commit of the code run
    if [ "$1" = base ]; then shift; (cd "$BASE" && GIT_COMMIT=${BASE_COMMIT:?} PYTHONPATH=$SITE:$BASE "$@")
    else shift; (cd "$HERE" && PYTHONPATH=$SITE:$HERE "$@"); fi
}
export PYTHONUNBUFFERED=1 MPLBACKEND=Agg WARP_CACHE_PATH=${WARP_CACHE_PATH:-/tmp/warp_cache}
nvidia-smi --query-gpu=name,driver_version,clocks.max.sm --format=csv,noheader | tee "$OUT/gpu.txt"
case "${PART:?PART=check, throughput, phase, long or interface}" in
check)
    python -m pytest -q -p no:cacheprovider tests/kernels/test_lanes.py --device cuda:0 \
        -k "records_inside or match_staged or diverging" 2>&1 | tail -4 | tee "$OUT/pytest_lanes_cuda.log" ;;
throughput)
    for v in new base; do
        for spec in "FB fp32 1536 16384" "FB fp64 16384" "RB fp32 16384"; do
            set -- $spec
            run_in $v python -m benchmarks.throughput --device cuda:0 --paths lanes --bases "$1" --precisions "$2" \
                --batches "${@:3}" --prisms 50 --prism-batch "$3" --target-s 0.3 --reps 3 \
                --out "$OUT/throughput_lanes_${v}_$1_$2.json" 2>&1 | grep -E "column-steps|B=|error" | tail -4
        done
    done ;;
phase)
    P=${PRECISION:-fp64}
    sed "s/^precision = .*/precision = \"$P\"/" sweeps/phase_large.toml > "$OUT/phase_large_$P.toml"
    for v in new base; do
        run_in $v python -m benchmarks.end_to_end "$OUT/phase_large_$P.toml" --device cuda:0 \
            --out "$OUT/end_to_end_phase_large_${P}_$v.json" 2>&1 | tail -3
    done ;;
long)
    if [ "${TESTS:-1}" = 1 ]; then
        python -m pytest -q -p no:cacheprovider tests/kernels/test_lanes_long.py --device cuda:0 2>&1 | tail -4 \
            | tee "$OUT/pytest_lanes_long_cuda.log"
    fi
    for b in ${BASES:-FB RB}; do
        for p in ${PRECISIONS:-fp32 fp64}; do
            run_in new python -m benchmarks.throughput --device cuda:0 --bases "$b" --precisions "$p" --batches \
                --prisms 128 300 500 1000 --prism-batch 4096 --paths lanes fused fused-serial staged \
                --prism-paths lanes fused fused-serial staged --target-s 0.3 --reps 3 --budget-s 420 \
                --out "$OUT/throughput_long_${b}_$p.json" 2>&1 | grep -E "col-steps|ERROR|skip" | tail -16
        done
    done ;;
interface)
    python -m benchmarks.end_to_end sweeps/interface.toml --device cuda:0 --keep "$OUT" \
        --out "$OUT/end_to_end_interface.json" 2>&1 | tail -3
    WT_INTERFACE_NC="$OUT/interface.nc" WT_FIG_DIR="$OUT" python analysis/interface.py 2>&1 | tail -5 ;;
esac
