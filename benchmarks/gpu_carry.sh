#!/usr/bin/env bash
# Packs Warp and the wheels the GPU machine lacks into device calls that fit beside the checkout.
#
# A device call carries the working tree plus its `carry` paths, 64 MiB in all. The tracked tree is
# ~38 MB (committed results), so ../shared/gpu/prepare-carry.sh's two parts (67 + 37 MB) do not fit.
# This script runs it with the project's runtime wheels, then re-cuts both parts into .carry/s1..sN
# (git-ignored) of at most 64 MiB minus the tree each. Then, back to back (the machine is kept ~30 s):
#   for N in 1..N-1:  run(carry=[".carry/sN"], command="bash .carry/sN/stage.sh")
#   last:             run(carry=[".carry/sN"], command="source .carry/sN/stage.sh && <command>")
# and later calls on the warm machine start with: export PYTHONPATH=/tmp/site:$PWD
#
# usage: bash benchmarks/gpu_carry.sh     (the versions are those CI installs today; edit to move)
set -euo pipefail
root=$(git rev-parse --show-toplevel)
cd "$root"
WHEELS=(netCDF4==1.7.5.1.post1 cftime==1.6.6.1 pydantic==2.14.4 pydantic-core==2.50.5 annotated-types==0.8.0
        typing-inspection==0.4.5 typing_extensions==4.16.0 zarr==3.1.6 numcodecs==0.16.6 donfig==0.8.1.post1
        google-crc32c==1.9.0 dask==2026.8.0 distributed==2026.8.0 partd==1.4.2 locket==1.0.0 filelock==4.3.1
        platformdirs==4.14.8 tomli-w==1.2.0 tqdm==4.70.1 psutil==7.2.2
        threadpoolctl==3.8.0)
bash ../shared/gpu/prepare-carry.sh "${WHEELS[@]}"

# what travels with every call: tracked files and untracked files git does not ignore
# (files moved out of the tree for the call are skipped: du fails on them, the total counts the rest)
tree=$( ( (git ls-files -z; git ls-files -z --others --exclude-standard) | du -cb --files0-from=- 2>/dev/null || true) | tail -1 | cut -f1)
limit=$((64 * 1024 * 1024 - tree - 2 * 1024 * 1024))  # 2 MiB margin
(( limit > 4 * 1024 * 1024 )) || { echo "the checkout ($tree B) leaves no room for a carry part" >&2; exit 1; }
work=$(mktemp -d)
tar -C .carry -cf "$work/all.tar" gpu0 gpu1
total=$(stat -c %s "$work/all.tar")
n=$(( (total + limit - 1) / limit ))
size=$(( (total + n - 1) / n ))
(cd "$work" && split -b "$size" -d -a 2 all.tar chunk)
rm -rf .carry/s[0-9]*
i=0
for c in "$work"/chunk*; do
  i=$((i + 1))
  mkdir -p ".carry/s$i"
  mv "$c" ".carry/s$i/"
  cat > ".carry/s$i/stage.sh" <<'STAGE'
#!/usr/bin/env bash
# one part of the carry: parked in /opt/gs until the last part joins them
set -e
mkdir -p /opt/gs && cp "$(dirname "${BASH_SOURCE[0]}")"/chunk* /opt/gs/ && ls /opt/gs
STAGE
done
sed -i 's|^mkdir -p /opt/gs|rm -rf /opt/gs \&\& mkdir -p /opt/gs|' .carry/s1/stage.sh  # the first part starts afresh
cat > ".carry/s$i/stage.sh" <<'STAGE'
#!/usr/bin/env bash
# last part (source this): join the parts, unpack gpu0/gpu1, install Warp and the wheels into /tmp/site
here=$(dirname "${BASH_SOURCE[0]}")
mkdir -p /opt/gs && cp "$here"/chunk* /opt/gs/
rm -rf /opt/gu && mkdir -p /opt/gu && cat /opt/gs/chunk* | tar -C /opt/gu -xf -
rm -rf /opt/gpu-carry && mkdir -p /opt/gpu-carry && cp -r /opt/gu/gpu0/* /opt/gpu-carry/
source /opt/gu/gpu1/stage.sh
STAGE
rm -rf "$work"
echo "tree $tree B; $i parts of <= $size B in .carry/s1..s$i (stage s1..s$((i - 1)), then source s$i)"
