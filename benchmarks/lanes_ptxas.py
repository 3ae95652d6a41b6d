"""The lane kernel's register budget without a GPU: each case's kernel compiled ahead of time for a
CUDA architecture (Warp's NVRTC, ``wp.compile_aot_module``) and assembled by the local ``ptxas -v``,
which reports its registers per thread, stack frame and spill bytes. The issue-33 profiles put the
lane step at 255 registers and spill-latency bound; this measures that budget in a CPU-only session
(it times nothing: speed comes from the GPU benchmarks).

    python -m benchmarks.lanes_ptxas --cases FB:fp64 RB:fp64 FB:fp32 RB:fp32 --prisms 50 \
        --out benchmarks/results/lanes_ptxas_sm90.json

The kernel of each case is the one the lane Step builds for a column of ``--prisms`` prisms on a
GPU (:class:`warp_tensegrity.sim.lanes.lanes.LaneStep`: lane map, fast math, mixed precision and the
other switches as they are set). The PTX of a newer NVRTC than the local ptxas is assembled with its
``.version`` line lowered to ptxas's (``--ptx-version``); ptxas refuses the file if it needs more.
"""

from __future__ import annotations

import argparse
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from . import common

INFO = re.compile(r"(\d+) bytes stack frame, (\d+) bytes spill stores, (\d+) bytes spill loads")
USED = re.compile(r"Used (\d+) registers.*?(\d+) bytes smem")


def kernel_for(base: str, prec: str, n_prisms: int):
    """The lane kernel the GPU Step builds for ``base`` ('FB' or 'RB') columns of ``n_prisms`` in ``prec``."""
    import warp as wp

    from warp_tensegrity.policy.lane_fit import lane_map
    from warp_tensegrity.sim.lanes import lanes as L

    rigid = base == "RB"
    P, G = lane_map(n_prisms, rigid, prec)
    real = wp.float64 if prec == "fp64" else wp.float32
    block = G if G > L.WARP else L.LANE_BLOCK_DIM
    fast = (L.LANE_FAST_MATH_RIGID if rigid else L.LANE_FAST_MATH)[prec]
    k = L.make_lane_kernel(real, P, G, L.LANE_MAX_REGISTERS[prec], rigid, fast,
                           block if L.LANE_SMEM_SPILL[prec] else 0, False, L.LANE_A_MEM[prec], L.LANE_MIXED[prec],
                           L.LANE_BLOCK_MIN[prec] if G > L.WARP else 1, L.LANE_RECORD_CALL[prec])
    return k.lane_steps, {"P": P, "G": G, "fast_math": bool(fast), "mixed": bool(L.LANE_MIXED[prec]),
                          "a_mem": bool(L.LANE_A_MEM[prec]), "max_registers": L.LANE_MAX_REGISTERS[prec],
                          "block_min": L.LANE_BLOCK_MIN[prec] if G > L.WARP else 1,
                          "record_call": bool(L.LANE_RECORD_CALL[prec])}


def ptxas_budget(ptx: Path, arch: int, ptx_version: str | None) -> dict:
    """ptxas -v of ``ptx`` for sm_<arch>: registers, stack frame, spill stores and loads, shared memory."""
    text = ptx.read_bytes().replace(b"\0", b"").decode()  # NVRTC's PTX ends in a NUL, which ptxas reads as text
    if ptx_version:
        text = re.sub(r"^\.version \S+", f".version {ptx_version}", text, count=1, flags=re.M)
    with tempfile.TemporaryDirectory() as tmp:
        src = Path(tmp) / "k.ptx"
        src.write_text(text)
        out = subprocess.run(["ptxas", f"-arch=sm_{arch}", "-v", "-o", str(Path(tmp) / "k.cubin"), str(src)],
                             capture_output=True, text=True)
    log = out.stdout + out.stderr
    if out.returncode != 0:
        raise RuntimeError(f"ptxas failed: {log.strip()[-400:]}")
    info, used = INFO.search(log), USED.search(log)
    return {"registers": int(used.group(1)), "smem_bytes": int(used.group(2)), "stack_frame_bytes": int(info.group(1)),
            "spill_store_bytes": int(info.group(2)), "spill_load_bytes": int(info.group(3)), "ptxas_log": log.strip()}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--cases", nargs="+", default=["FB:fp64", "RB:fp64", "FB:fp32", "RB:fp32"])
    ap.add_argument("--prisms", type=int, default=50)
    ap.add_argument("--arch", type=int, default=90)
    ap.add_argument("--ptx-version", default="9.0", help="the .version ptxas takes (CUDA 13.0: 9.0; '' keeps NVRTC's)")
    ap.add_argument("--out", required=True)
    a = ap.parse_args(argv)
    import warp as wp

    wp.config.quiet = True
    wp.init()
    ptxas = subprocess.run(["ptxas", "--version"], capture_output=True, text=True).stdout.strip().splitlines()[-1]
    doc = {"kind": "lanes_ptxas", "meta": common.run_metadata(wp.get_device("cpu")), "arch": a.arch,
           "ptxas": ptxas, "ptx_version": a.ptx_version or None, "n_prisms": a.prisms, "rows": []}
    for case in a.cases:
        base, prec = case.split(":")
        kernel, facts = kernel_for(base, prec, a.prisms)
        with tempfile.TemporaryDirectory() as tmp:
            t0 = time.perf_counter()
            paths = wp.compile_aot_module(kernel.module, arch=a.arch, module_dir=tmp, use_ptx=True)
            t_nvrtc = time.perf_counter() - t0
            row = {"base": base, "precision": prec, **facts, "nvrtc_s": t_nvrtc,
                   **ptxas_budget(Path(paths[0]), a.arch, a.ptx_version or None)}
        doc["rows"].append(row)
        print(f"{base} {prec} ({a.prisms} prisms, P={facts['P']} G={facts['G']}): {row['registers']} registers, "
              f"stack {row['stack_frame_bytes']} B, spill stores {row['spill_store_bytes']} B, loads "
              f"{row['spill_load_bytes']} B (NVRTC {t_nvrtc:.0f} s)", flush=True)
    common.write_json(a.out, doc)
    return 0


if __name__ == "__main__":
    sys.exit(main())
