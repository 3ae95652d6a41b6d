#!/usr/bin/env bash
# Scale-out on one host: sweeps/scaling_2gpu.toml with one Dask worker per GPU against one worker.
# Run from the repo root on a multi-GPU machine with Warp staged in /tmp/site; writes $1/scaling_dask.json.
set -u
OUT=${1:?output dir}; REPO=$PWD; N=${2:-2}
export PYTHONPATH=/tmp/site:$REPO PYTHONUNBUFFERED=1 NCCL_NVLS_ENABLE=0
cd /tmp
python3 -m warp_tensegrity run "$REPO/sweeps/ci_small.toml" -o /tmp/warm.nc --no-progress --overwrite > /dev/null 2>&1  # fill the kernel cache
t0=$(date +%s.%N); python3 -m warp_tensegrity run "$REPO/sweeps/scaling_2gpu.toml" -o /tmp/s1.nc --dask 1 --no-progress --overwrite 2>&1 | tail -2; t1=$(date +%s.%N)
python3 -m warp_tensegrity run "$REPO/sweeps/scaling_2gpu.toml" -o /tmp/sN.nc --dask "$N" --no-progress --overwrite 2>&1 | tail -2; t2=$(date +%s.%N)
python3 - "$OUT" "$t0" "$t1" "$t2" "$N" <<'PY'
import json, sys, xarray as xr
from warp_tensegrity.io import drop_run_dependent
out, t0, t1, t2, n = sys.argv[1], *map(float, sys.argv[2:5]), int(sys.argv[5])
a, b = xr.open_dataset("/tmp/s1.nc"), xr.open_dataset("/tmp/sN.nc")
try:
    xr.testing.assert_identical(drop_run_dependent(a).drop_attrs(), drop_run_dependent(b).drop_attrs()); same = True
except AssertionError as e:
    same = str(e)[:500]
cols = int(a.status.size)
r = {"spec": "sweeps/scaling_2gpu.toml", "columns": cols, "n_gpus": n, "device_name": a.attrs.get("device_name"),
     "wall_s_1gpu": t1 - t0, "wall_s_ngpu": t2 - t1, "speedup": (t1 - t0) / (t2 - t1),
     "scaling_efficiency": (t1 - t0) / (t2 - t1) / n, "columns_per_s_per_gpu_1": cols / (t1 - t0),
     "columns_per_s_per_gpu_n": cols / (t2 - t1) / n, "datasets_identical": same}
json.dump(r, open(f"{out}/scaling_dask.json", "w"), indent=1); print(json.dumps(r, indent=1))
PY
