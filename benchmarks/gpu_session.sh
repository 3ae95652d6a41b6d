#!/usr/bin/env bash
# One GPU call for the committed GPU results. Run from the repo root on the device machine after
# Warp is staged (.carry/gpu0 then .carry/gpu1, see README "GPU"); writes everything under $1.
set -u
OUT=${1:?output dir}
REPO=$PWD
export PYTHONPATH=/tmp/site:$REPO PYTHONUNBUFFERED=1
[ -d /tmp/site/warp ] || { echo "warp is not staged in /tmp/site"; exit 3; }
[ -d .whl ] && python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --target /tmp/site .whl/*.whl
nvidia-smi --query-gpu=name,driver_version --format=csv,noheader | tee "$OUT/gpu.txt"

echo "== paper cases (default conventions), fp64 and fp32"
for p in fp64 fp32; do
  python3 -m benchmarks.paper_cases --device cuda:0 --precision $p --out "$OUT" 2>&1 | grep -v "^Module" | tail -3
done

echo "== large sweep: sweeps/phase_large.toml as one shard"
start=$(date +%s.%N)
(cd /tmp && python3 -m warp_tensegrity run "$REPO/sweeps/phase_large.toml" -o /tmp/phase_large.nc \
   --shard-size 1536 --no-progress --overwrite 2>&1 | tail -3)
end=$(date +%s.%N)
python3 - "$OUT" "$start" "$end" <<'PY'
import json, sys, xarray as xr
out, t0, t1 = sys.argv[1], float(sys.argv[2]), float(sys.argv[3])
ds = xr.open_dataset("/tmp/phase_large.nc")
small = ds.drop_vars([v for v in ("strain", "kinetic_energy", "elastic_energy") if v in ds])
enc = {v: {"zlib": True, "complevel": 4} for v in small.data_vars}
small.to_netcdf(f"{out}/phase_large.nc", engine="netcdf4", encoding=enc)
n = int(ds.status.size)
json.dump({"spec": "sweeps/phase_large.toml", "columns": n, "wall_s_total": t1 - t0,
           "wall_s_stepping": float(ds.attrs.get("wall_time", "nan")), "dt": float(ds.attrs.get("dt", "nan")),
           "device_name": ds.attrs.get("device_name"), "git_commit": ds.attrs.get("git_commit"),
           "diverged": int((ds.status != 0).sum())}, open(f"{out}/phase_large_timing.json", "w"), indent=1)
print(open(f"{out}/phase_large_timing.json").read())
PY

echo "== throughput"
python3 -m benchmarks.throughput --device cuda:0 --out-dir "$OUT" 2>&1 | grep -v "^Module" | tail -25
for f in "$OUT"/throughput_h*.json; do python3 -m benchmarks.roofline --results "$f" --kernels > "$OUT/roofline.md" 2>&1; done

echo "== fused step: agreement with the staged kernels and launch shape"
python3 -m benchmarks.fused_tuning --device cuda:0 --out-dir "$OUT" --batches 4096 65536 --blocks 32 64 --subs 1 16 \
  2>&1 | grep -v "^Module" | tail -8
