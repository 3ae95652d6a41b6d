"""Launch shape of the staged step's column solvers (one thread per column) at large batch.

Column-steps/s of the staged RATTLE step for 50-prism columns (FB and RB, fp32 and fp64) against
the batch size, for CUDA threads per block of the column-solver kernels and a cap on their
registers per thread (``__maxnreg__``; fewer registers let more columns run at once, at the price
of spills), and with or without the bar vectors of the last bw + 1 rows in registers during the
Gram-matrix assembly. The engine's choice: ``sim.staged.step.COLUMN_BLOCK_DIM`` threads per block,
``COLUMN_MAX_REGISTERS`` registers from ``COLUMN_CAP_FROM`` columns up, and
``COLUMN_BAR_WINDOW`` (None: the window for fp32 only).

Usage::

    python -m benchmarks.staged_tuning --device cuda:0 --out-dir benchmarks/results --label h200
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from . import common


WINDOWS = {"auto": None, "on": True, "off": False}


def shapes(device, batches, blocks, regs, target_s: float, bases, precisions, windows=("auto",)) -> list[dict]:
    from warp_tensegrity.sim.staged import step as integrate  # the staged step's launch constants

    rows = []
    defaults = (integrate.COLUMN_BLOCK_DIM, integrate.COLUMN_MAX_REGISTERS, integrate.COLUMN_CAP_FROM,
                integrate.COLUMN_BAR_WINDOW)
    integrate.COLUMN_CAP_FROM = 0  # the cap (or none) at every batch size
    for base in bases:
        small = common.build_base_batch(50, 1.0 if base == "RB" else 0.0, common.BASE_COLUMNS)
        dt = common.rattle_dt(small)
        for prec in precisions:
            for B in batches:
                batch = common.tile_batch(small, B)
                for bd, r, win in ((bd, r, win) for bd in blocks for r in regs for win in windows):
                    integrate.COLUMN_BLOCK_DIM, integrate.COLUMN_MAX_REGISTERS = bd, r
                    integrate.COLUMN_BAR_WINDOW = WINDOWS[win]
                    try:
                        p = common.time_batch(batch, base, 50, prec, device, target_s=target_s, reps=3,
                                              diag_steps=0, dt=dt, path="staged").as_dict()
                        p.update(block_dim=bd, max_registers=r, bar_window=win)
                        print(f"[staged] {base} {prec} B={B} block {bd} regs {r} bar window {win}: "
                              f"{p['column_steps_per_s']:.4g} col-steps/s", flush=True)
                    except Exception as exc:  # noqa: BLE001 - out of memory at the largest B
                        p = {"base": base, "precision": prec, "B": B, "block_dim": bd, "max_registers": r,
                             "bar_window": win, "error": repr(exc)}
                        print(f"[staged] ERROR {p}", flush=True)
                    rows.append(p)
                del batch
    (integrate.COLUMN_BLOCK_DIM, integrate.COLUMN_MAX_REGISTERS, integrate.COLUMN_CAP_FROM,
     integrate.COLUMN_BAR_WINDOW) = defaults
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--device", default="cuda:0")
    ap.add_argument("--out-dir", dest="out_dir", default=str(common.RESULTS))
    ap.add_argument("--label", default=None, help="file suffix (default: the device kind)")
    ap.add_argument("--batches", type=int, nargs="+", default=[16384, 65536, 131072, 262144])
    ap.add_argument("--blocks", type=int, nargs="+", default=[64])
    ap.add_argument("--regs", type=int, nargs="+", default=[0], help="register caps; 0: none")
    ap.add_argument("--windows", nargs="+", default=["auto"], choices=sorted(WINDOWS),
                    help="bar vectors in registers during the Gram assembly (auto: fp32 only)")
    ap.add_argument("--bases", nargs="+", default=["FB", "RB"])
    ap.add_argument("--precisions", nargs="+", default=["fp32", "fp64"])
    ap.add_argument("--target-s", dest="target_s", type=float, default=0.3)
    a = ap.parse_args(argv)
    import warp as wp

    wp.config.quiet = True
    wp.config.log_level = wp.LOG_WARNING
    wp.init()
    device = wp.get_device(a.device)
    tag = a.label or ("cpu" if device.is_cpu else common.device_kind(device.name))
    out = Path(a.out_dir) / f"staged_tuning_{tag}.json"
    doc = {"kind": "staged_tuning", "meta": common.run_metadata(device)}
    doc["shapes"] = shapes(device, a.batches, a.blocks, [r or None for r in a.regs], a.target_s, a.bases,
                           a.precisions, a.windows)
    common.write_json(out, doc)
    print(f"[staged_tuning] wrote {out}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
