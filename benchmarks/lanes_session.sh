#!/usr/bin/env bash
# GPU calls for the warp-per-column step (issue 24). Run from the repo root after staging Warp
# (README "GPU"):  LANES_SECTIONS="check throughput ncu paper phase prisms" bash benchmarks/lanes_session.sh $OUT
#   check       agreement with the staged kernels and the kernel's resources (benchmarks/lanes_check.py)
#   throughput  every path at B = 1,536 and 16,384, FB and RB, fp32 and fp64 (the pre-lanes paths' kernels
#               are 3e92af8's: the baseline rerun in the same call)
#   ncu         Nsight Compute of the lane kernel (FB fp32, B = 16,384, one 64-step launch) and the SASS
#               resource usage of every compiled lane variant
#   paper       the paper's 12 cases in fp64 to t = 1 s: lanes against staged
#   phase       sweeps/phase_large.toml end to end through the CLI (its own shards), with the dry-run estimate
#   prisms      lanes against the block-per-column step from 10 to 128 prisms (where the lane step ends)
set -u
OUT=${1:?output dir}
export PYTHONPATH=/tmp/site:$PWD PYTHONUNBUFFERED=1 WARP_CACHE_PATH=${WARP_CACHE_PATH:-/tmp/wcache}
nvidia-smi --query-gpu=name,driver_version --format=csv,noheader | tee "$OUT/gpu.txt"
tag=$(nvidia-smi --query-gpu=name --format=csv,noheader | grep -q H200 && echo h200 || echo h100)
SECTIONS=${LANES_SECTIONS:-check throughput ncu}
has() { [[ " $SECTIONS " == *" $1 "* ]]; }
if has check; then
  echo "== agreement with the staged kernels, resources"
  python3 -m benchmarks.lanes_check --device cuda:0 --out "$OUT/lanes_check_$tag.json" 2>&1 | grep -v "^Module"
fi
if has throughput; then
  echo "== throughput"
  python3 -m benchmarks.throughput --device cuda:0 --paths lanes fused fused-serial staged --bases FB RB \
    --precisions fp32 fp64 --batches 1536 16384 --prisms 50 --prism-batch 16384 --prism-paths lanes \
    --target-s 1.0 --no-diagnostics --out "$OUT/throughput_lanes_$tag.json" 2>&1 | grep -E "col-steps|ERROR|skip"
fi
if has ncu; then
  echo "== Nsight Compute, lane kernel, FB fp32 B=16384 (one 64-step launch after initialize)"
  NCU=$(command -v ncu || ls /opt/nvidia/nsight-compute/*/ncu /usr/local/cuda/bin/ncu 2>/dev/null | head -n1)
  rep=/tmp/ncu_lanes
  "$NCU" --target-processes all --clock-control none --kernel-name regex:lane_steps --launch-skip 1 --launch-count 1 \
    --section SpeedOfLight --section LaunchStats --section Occupancy --section WarpStateStats \
    --section SchedulerStats --section InstructionStats --section MemoryWorkloadAnalysis \
    --metrics smsp__inst_executed.sum,smsp__issue_active.avg.pct_of_peak_sustained_active,l1tex__t_bytes_pipe_lsu_mem_local_op_ld.sum,l1tex__t_bytes_pipe_lsu_mem_local_op_st.sum,smsp__thread_inst_executed_per_inst_executed.ratio \
    --export "$rep" --force-overwrite \
    python3 -m benchmarks.throughput --device cuda:0 --ncu-mode --bases FB --precisions fp32 \
    --ncu-batch 16384 --ncu-steps 64 --paths lanes 2>&1 | grep -v "^Module" | tail -8
  "$NCU" --import "$rep.ncu-rep" --csv --page details > "$OUT/ncu_lanes_FB_fp32_B16384_$tag.csv"
  "$NCU" --import "$rep.ncu-rep" --csv --page raw --metrics smsp__inst_executed.sum,smsp__issue_active.avg.pct_of_peak_sustained_active,l1tex__t_bytes_pipe_lsu_mem_local_op_ld.sum,launch__registers_per_thread,sm__warps_active.avg.pct_of_peak_sustained_active,gpu__time_duration.sum > "$OUT/ncu_lanes_raw_$tag.csv"
  echo "== SASS of the lane kernels (barriers, local memory)"
  {
    for f in $(find "$WARP_CACHE_PATH" -path "*lane_steps*" -name "*.cubin" 2>/dev/null); do
      echo "## $f"
      cuobjdump -res-usage "$f" 2>&1 | grep -A1 lane_steps | head -4
      echo "BAR: $(cuobjdump -sass "$f" | grep -cE '\bBAR\b|BAR\.') LDL: $(cuobjdump -sass "$f" | grep -c LDL) STL: $(cuobjdump -sass "$f" | grep -c STL) SHFL: $(cuobjdump -sass "$f" | grep -c SHFL) instructions: $(cuobjdump -sass "$f" | grep -cE '^\s+/\*[0-9a-f]+\*/')"
    done
  } | tee "$OUT/sass_lanes_$tag.txt"
fi
if has paper; then
  echo "== the paper's 12 cases, fp64 to t = 1 s: lanes against staged"
  mkdir -p /tmp/pc
  for f in lanes false; do
    python3 -m benchmarks.paper_cases --device cuda:0 --precision fp64 --t-end 1.0 --fused $f --out /tmp/pc 2>&1 | tail -1
  done
  python3 -m benchmarks.paper_cases --compare /tmp/pc/paper_cases_cuda0_fp64_rattle_lanes.npz \
    /tmp/pc/paper_cases_cuda0_fp64_rattle_staged.npz --compare-out "$OUT/paper_cases_lanes_vs_staged_$tag.json" | tail -4
fi
if has phase; then
  echo "== sweeps/phase_large.toml end to end (the spec's own shards)"
  python3 -m warp_tensegrity run sweeps/phase_large.toml -o /tmp/phase_large.nc --dry-run 2>&1 | tail -4
  start=$(date +%s.%N)
  (cd /tmp && python3 -m warp_tensegrity run "$OLDPWD/sweeps/phase_large.toml" -o /tmp/phase_large.nc \
     --no-progress --overwrite 2>&1 | tail -3)
  end=$(date +%s.%N)
  python3 - "$OUT" "$start" "$end" "$tag" <<'PY'
import json, sys, xarray as xr
out, t0, t1, tag = sys.argv[1], float(sys.argv[2]), float(sys.argv[3]), sys.argv[4]
ds = xr.open_dataset("/tmp/phase_large.nc")
rec = {"spec": "sweeps/phase_large.toml", "columns": int(ds.status.size), "wall_s_total": t1 - t0,
       "step_path": ds.attrs.get("step_path"), "diverged": int((ds.status != 0).sum()),
       "attrs": {k: str(v) for k, v in ds.attrs.items() if "time" in k or "estimate" in k or "wall" in k}}
json.dump(rec, open(f"{out}/phase_large_lanes_{tag}.json", "w"), indent=1)
print(json.dumps(rec, indent=1))
PY
fi
if has prisms; then
  echo "== lanes against fused, 10..128 prisms, B = 16,384"
  python3 -m benchmarks.throughput --device cuda:0 --paths lanes fused --bases FB RB --precisions fp32 \
    --batches 16384 --prisms 25 64 100 128 --prism-batch 16384 --prism-paths lanes fused --target-s 0.5 \
    --no-diagnostics --budget-s 300 --out "$OUT/throughput_lanes_prisms_$tag.json" 2>&1 | grep -E "col-steps|ERROR|skip"
fi
