#!/usr/bin/env bash
# Issue 33 item 1 (records inside the lane step) on one GPU, against the baseline in the same call
# (after staging the carry, README "Running on a GPU machine"). PART selects what one device call
# (at most 10 min) runs:
#   PART=check       the lane tests on CUDA (records inside against the record kernels, lanes against staged)
#   PART=throughput  lanes column-steps/s, 50 prisms: FB fp32 at B = 1,536 and 16,384, FB fp64, RB fp32 and RB fp64
#                    at 16,384 (CASES="FB fp32 1536 16384;RB fp64 16384" picks some: two calls if one runs out of time;
#                    VERSIONS="new" leaves the baseline out, e.g. for a saturation curve "FB fp64 256 512 1024 16384")
#   PART=switches    new only: each of the lane step's speed switches (issue 33 item 2) off against on, in the
#                    case it is for (LANE_A_MEM, LANE_MIXED, LANE_FAST_MATH_RIGID: sim/lanes/lanes.py); SWITCHES picks
#   PART=phase       phase_large end to end (benchmarks/end_to_end.py) in precision PRECISION (fp64, fp32 or auto)
#   PART=same_physics every registered Step against the staged path, fp64, to t = 1 s: the paper's 12 cases
#                    and lanes_check's (50, 7, 100 prisms) (benchmarks/same_physics.py; exit 1 over 1e-11)
#   PART=ncu         Nsight Compute of the lane kernel in the four cases (benchmarks/gpu_lanes_ncu.sh)
#   PART=e2e         issue 33 must-show 3: end to end (benchmarks/end_to_end.py, every stage and "other"),
#                    REPEAT runs each (default 2), of phase_large at its defaults (fp64), phase_large with
#                    precision auto and paper_2017; VERSIONS="new base" also runs BASE (default: new only);
#                    TRACE=1: the new code's runs with --trace (each chunk's device interval, end_to_end.py);
#                    SPECS="phase_large paper_2017" picks some (default all three); PROFILE=1: the new code's
#                    runs under cProfile (end_to_end.py --profile, in $OUT/profile); the bytecode is compiled
#                    first (compileall over PYTHONPATH, both trees and site-packages; PYC=0: not)
#   PART=long        issue 33 item 3: the fallback table at 128, 300, 500 and 1,000 prisms, B = 4,096: lanes (k warps
#                    per column past a warp), block (fused, fused-serial) and staged, new only; BASES (FB RB) and
#                    PRECISIONS (fp32 fp64) pick a part of it (one call each: FB fp32, RB fp32, then fp64), and
#                    the long-column lane tests on CUDA (tests/kernels/test_lanes_long.py) first (TESTS=0: not);
#                    BASE_DIR is not used (give .)
#   PART=levels      new only: FB lanes at PRISMS (default "500 1000", B = 4,096) with each of LEVELS ("2 3 4")
#                    levels per lane on k warps (policy.lane_fit.MAX_BLOCK_LEVELS_PER_LANE)
#   PART=pytest      the tests PYTESTS (paths) on CUDA (--device cuda:0)
#   PART=bits        the lane step's results here and in BASE compared to the bit (benchmarks/lanes_bits.py)
#   PART=lanemap     new only: lane maps and switches (MAPS, below) against the defaults; every kernel
#                    compiled first, in parallel (KEEP_CACHE=1: the kernel cache tarred into $OUT)
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
case "${PART:?PART=check, throughput, switches, phase, e2e, long, same_physics, ncu, pytest or interface}" in
check)
    python -m pytest -q -p no:cacheprovider tests/kernels/test_lanes.py --device cuda:0 \
        -k "records_inside or match_staged or diverging or hold_the_bars or mixed_precision or accelerations_in_memory" 2>&1 | tail -4 | tee "$OUT/pytest_lanes_cuda.log" ;;
throughput)
    IFS=';' read -r -a specs <<< "${CASES:-FB fp32 1536 16384;FB fp64 16384;RB fp32 16384;RB fp64 16384}"
    for v in ${VERSIONS:-new base}; do
        for spec in "${specs[@]}"; do
            set -- $spec
            run_in $v python -m benchmarks.throughput --device cuda:0 --paths lanes --bases "$1" --precisions "$2" \
                --batches "${@:3}" --prisms 50 --prism-batch "$3" --target-s 0.3 --reps 3 \
                --out "$OUT/throughput_lanes_${v}_$1_$2.json" 2>&1 | grep -E "column-steps|B=|error" | tail -4
        done
    done ;;
switches)
    # NAME:KEY:BASE:PRECISION: the lane module's dict NAME[KEY] set to 0 and to 1, the case run at B = 16,384
    for sw in ${SWITCHES:-LANE_MIXED:fp64:FB:fp64 LANE_MIXED:fp64:RB:fp64 LANE_A_MEM:fp64:RB:fp64 LANE_A_MEM:fp32:FB:fp32 LANE_FAST_MATH_RIGID:fp32:RB:fp32}; do
        IFS=: read -r name key base prec <<< "$sw"
        for val in 0 1; do
            python -c "import runpy, sys; from warp_tensegrity.sim.lanes import lanes
getattr(lanes, '$name')['$key'] = bool($val)
sys.argv = ['throughput', '--device', 'cuda:0', '--paths', 'lanes', '--bases', '$base', '--precisions', '$prec',
            '--batches', '16384', '--prisms', '50', '--prism-batch', '16384', '--target-s', '0.3', '--reps', '3',
            '--out', '$OUT/throughput_switch_${name}_${key}_${base}_${prec}_$val.json']
runpy.run_module('benchmarks.throughput', run_name='__main__')" 2>&1 | grep -E "column-steps|B=|error" | tail -2 | sed "s/^/$name[$key]=$val $base $prec: /"
        done
    done ;;
phase)
    P=${PRECISION:-fp64}
    sed "s/^precision = .*/precision = \"$P\"/" sweeps/phase_large.toml > "$OUT/phase_large_$P.toml"
    for v in new base; do
        run_in $v python -m benchmarks.end_to_end "$OUT/phase_large_$P.toml" --device cuda:0 \
            --out "$OUT/end_to_end_phase_large_${P}_$v.json" 2>&1 | tail -3
    done ;;
same_physics)
    python -m benchmarks.same_physics --device cuda:0 --out "$OUT/same_physics_h200.json" 2>&1 | tail -3 ;;
ncu)  # Nsight Compute of the lane kernel, the four cases (NCU_CONFIGS), for benchmarks/lanes_bound.py
    bash benchmarks/gpu_lanes_ncu.sh "$OUT" new ;;
e2e)  # threadpoolctl (gpu_carry.sh carries it) sets the host's small solves to one BLAS thread: say if it is there
    python -c "import threadpoolctl; print('threadpoolctl', threadpoolctl.__version__)" 2>&1 | tail -1 | tee -a "$OUT/gpu.txt"
    # the bytecode an installed environment has (a host with PYTHONDONTWRITEBYTECODE=1 compiles every module
    # in every process otherwise); PYC=0: not
    if [ "${PYC:-1}" = 1 ]; then
        IFS=: read -r -a dirs <<< "$SITE"
        python -m compileall -q -j 8 "${dirs[@]}" "$HERE/warp_tensegrity" "$BASE/warp_tensegrity" \
            $(python -c "import site; print(' '.join(site.getsitepackages()))") > /dev/null 2>&1
        echo "bytecode compiled (PYTHONDONTWRITEBYTECODE=${PYTHONDONTWRITEBYTECODE:-unset})" | tee -a "$OUT/gpu.txt"
    fi
    sed "s/^precision = .*/precision = \"auto\"/" sweeps/phase_large.toml > "$OUT/phase_large_auto.toml"
    for v in ${VERSIONS:-new}; do
        for spec in "$HERE/sweeps/phase_large.toml" "$OUT/phase_large_auto.toml" "$HERE/sweeps/paper_2017.toml"; do
            name=$(basename "$spec" .toml)
            case " ${SPECS:-phase_large phase_large_auto paper_2017} " in *" $name "*) ;; *) continue ;; esac
            trace=(); [ "${TRACE:-0}" = 1 ] && [ "$v" = new ] && trace=(--trace)
            [ "${PROFILE:-0}" = 1 ] && [ "$v" = new ] && trace+=(--profile "$OUT/profile")
            run_in $v python -m benchmarks.end_to_end "$spec" --device cuda:0 --repeat "${REPEAT:-2}" "${trace[@]}" \
                --out "$OUT/end_to_end_${name}_$v.json" 2>&1 | grep -E "wall|error" | tail -4
        done
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
levels)  # new only: FB lanes at PRISMS (500 1000) with each of LEVELS (2 3 4) levels per lane on k warps
    for lv in ${LEVELS:-2 3 4}; do
        for prec in ${PRECISIONS:-fp32}; do
            python -c "
import runpy, sys
import warp_tensegrity.policy.lane_fit as lf
lf.MAX_BLOCK_LEVELS_PER_LANE = $lv
print('lane map', {n: lf.lane_map(n) for n in [${PRISMS_LIST:-500, 1000}]})
sys.argv = ['throughput', '--device', 'cuda:0', '--bases', 'FB', '--precisions', '$prec', '--batches',
            '--prisms', *'${PRISMS:-500 1000}'.split(), '--prism-batch', '4096', '--paths', 'lanes',
            '--prism-paths', 'lanes', '--target-s', '0.3', '--reps', '3', '--budget-s', '200',
            '--out', '$OUT/throughput_levels_${lv}_$prec.json']
runpy.run_module('benchmarks.throughput', run_name='__main__')" 2>&1 | grep -E "lane map|col-steps|ERROR|skip" | sed "s/^/levels $lv $prec: /"
        done
    done ;;
lanemap)  # lane maps and switches against the defaults (BASE_MAPS: the code in BASE too), compiled first, in parallel
    maps=(${MAPS:?set MAPS})
    # MAP = BASE:PREC:PRISMS:B[:key=value...]; keys: ml (MAX_LEVELS_PER_LANE, the rigid one at most 2), mb
    # (MAX_BLOCK_LEVELS_PER_LANE), wide (WIDE_BLOCK_LANES), r64 (RIGID_FP64_ONE_LEVEL_LANES) of
    # policy.lane_fit; regs (the lane module's LANE_MAX_REGISTERS[PREC], 0: None), bd (LANE_BLOCK_DIM),
    # minb (LANE_BLOCK_MIN[PREC]), rc (LANE_RECORD_CALL[PREC], 0 or 1)
    patch='import sys
import warp_tensegrity.policy.lane_fit as lf
from warp_tensegrity.sim.lanes import lanes as L
def _set(prec, kv):
    for item in filter(None, kv.split(":")):
        k, v = item.split("=")
        v = int(v)
        if k == "ml": lf.MAX_LEVELS_PER_LANE = v; lf.MAX_RIGID_LEVELS_PER_LANE = min(2, v)
        elif k == "mb": lf.MAX_BLOCK_LEVELS_PER_LANE = v
        elif k == "wide": lf.WIDE_BLOCK_LANES = v
        elif k == "r64": lf.RIGID_FP64_ONE_LEVEL_LANES = v
        elif k == "regs": L.LANE_MAX_REGISTERS[prec] = v or None
        elif k == "bd": L.LANE_BLOCK_DIM = v
        elif k == "minb": L.LANE_BLOCK_MIN[prec] = v
        elif k == "rc": L.LANE_RECORD_CALL[prec] = bool(v)
        else: sys.exit(f"unknown key {k}")
'
    # BASE_MAPS: the same for the code in BASE ("base"), its kernels compiled beside the others
    jobs=(); for m in "${maps[@]}"; do jobs+=("new:$m"); done
    for m in ${BASE_MAPS:-}; do jobs+=("base:$m"); done
    declare -A seen=()
    for job in "${jobs[@]}"; do
        v=${job%%:*}; m=${job#*:}
        IFS=: read -r base prec n b kv <<< "$m"
        key="$v:$base:$prec:$n:$kv"  # (one compile per kernel, whatever B)
        [ -n "${seen[$key]:-}" ] && continue
        seen[$key]=1
        run_in "$v" python -c "$patch
_set('$prec', '$kv')
import warp as wp
wp.config.quiet = True
from benchmarks.lanes_ptxas import kernel_for
k, facts = kernel_for('$base', '$prec', $n)
k.module.load(wp.get_device('cuda:0'), facts['G'] if facts['G'] > 32 else L.LANE_BLOCK_DIM)
print('compiled $v $m', facts)" 2>&1 | grep -E "compiled|Error" &
    done
    wait
    for job in "${jobs[@]}"; do
        v=${job%%:*}; m=${job#*:}
        IFS=: read -r base prec n b kv <<< "$m"
        tag=$(echo "${base}_${prec}_${n}_${b}_${kv}" | tr ':=' '_-')
        [ "$v" = base ] && tag="base_$tag"
        run_in "$v" python -c "$patch
_set('$prec', '$kv')
import runpy
print('lane map', lf.lane_map($n, '$base' == 'RB', '$prec'))
sys.argv = ['throughput', '--device', 'cuda:0', '--bases', '$base', '--precisions', '$prec', '--batches',
            '--prisms', '$n', '--prism-batch', '$b', '--paths', 'lanes', '--prism-paths', 'lanes',
            '--target-s', '0.3', '--reps', '3', '--budget-s', '200', '--out', '$OUT/throughput_lanemap_$tag.json']
runpy.run_module('benchmarks.throughput', run_name='__main__')" 2>&1 | grep -E "lane map|col-steps|ERROR|skip" | sed "s/^/$v $m: /"
    done
    if [ "${KEEP_CACHE:-0}" = 1 ]; then
        tar -czf "$OUT/kernel_cache.tgz" -C "$(dirname "$WARP_CACHE_PATH")" "$(basename "$WARP_CACHE_PATH")"
        split -b 15M "$OUT/kernel_cache.tgz" "$OUT/kernel_cache.tgz.part" && rm "$OUT/kernel_cache.tgz"
        ls -la "$OUT"/kernel_cache.tgz.part*
    fi ;;
bits)  # the lane step's results here and in BASE to the bit (benchmarks/lanes_bits.py, its harness copied there)
    cp "$HERE/benchmarks/lanes_bits.py" "$BASE/benchmarks/"
    for v in new base; do
        run_in $v python -m benchmarks.lanes_bits --device cuda:0 --out "$OUT/lanes_bits_$v.npz" 2>&1 | grep -E "lanes|Error" | cut -c1-90
    done
    python -m benchmarks.lanes_bits --device cuda:0 --compare "$OUT/lanes_bits_new.npz" "$OUT/lanes_bits_base.npz" \
        --out "$OUT/lanes_bits_h200.json" 2>&1 | tail -1 ;;
pytest)
    python -m pytest -q -p no:cacheprovider ${PYTESTS:?} --device cuda:0 2>&1 | tail -6 | tee "$OUT/pytest_cuda.log" ;;
interface)
    python -m benchmarks.end_to_end sweeps/interface.toml --device cuda:0 --keep "$OUT" \
        --out "$OUT/end_to_end_interface.json" 2>&1 | tail -3
    WT_INTERFACE_NC="$OUT/interface.nc" WT_FIG_DIR="$OUT" python analysis/interface.py 2>&1 | tail -5 ;;
esac
