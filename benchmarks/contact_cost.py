"""What bar contact costs (issue 32 item 3): stepping rate (column-steps/s) of batches of the paper's
50-prism columns (p = 0.002, fp64 unless told) with and without ``contact = 'bars'``, on one device.

Contact runs on the staged path only, so three runs of each batch are timed:

* ``default``: no contact, the path the policy picks (the lane step on a GPU, the fused step on the CPU);
* ``staged``: no contact, the staged kernels (``fused = false``): the path contact runs take;
* ``contact``: bar radius 0.25 mm, restitution 1 (staged).

and two batches per base: ``weak`` pulses (v0 0.005-0.015 m/s: no bar pair comes within 2 r, so the
cost is the detection pass and the copy of v) and ``strong`` ones (v0 0.1-0.2 m/s: every column
has tens of impacts, each step with one is redone in the column's thread as RATTLE substeps).
The time is ``BatchResult.wall_time`` (stepping only; one CUDA graph capture included).

usage: python -m benchmarks.contact_cost --device cuda:0 [--columns 4096 16384] [--precision fp64]
"""

from __future__ import annotations

import argparse
from dataclasses import replace

import numpy as np

from benchmarks.common import RESULTS, device_tag, run_metadata, write_json

PULSES = {"weak": (0.005, 0.015), "strong": (0.1, 0.2)}
T_END = 0.3  # s: the strong pulses hit the stop throughout


def time_case(base: float, pulse: str, B: int, precision: str, device: str) -> dict:
    from warp_tensegrity import ColumnConfig, RunSettings, simulate_batch

    none = ColumnConfig(n_prisms=50)
    bars = replace(none, contact="bars", bar_radius=0.25e-3)
    params = {"prestrain": 0.002, "v0": np.linspace(*PULSES[pulse], B), "base_rigidity": base}
    out = {"base": "RB" if base == 1 else "FB", "pulse": pulse, "v0_range": PULSES[pulse], "columns": B,
           "precision": precision}
    for name, cfg, fused in (("default", none, "auto"), ("staged", none, False), ("contact", bars, "auto")):
        s = RunSettings(t_end=T_END, precision=precision, device=device, fused=fused, truncate=False,
                        record_strain=False, measure="none")
        r = simulate_batch(cfg, params, s)
        out[name] = {"path": r.info["step_path"], "wall_s": r.wall_time, "steps": r.n_steps, "dt": r.dt,
                     "column_steps_per_s": B * r.n_steps / r.wall_time, "failed": int(np.count_nonzero(r.status))}
        if "contact" in r.info:
            c = r.info["contact"]
            out[name].update(impacts_mean=float(c["impacts"].mean()), touched=int((c["impacts"] > 0).sum()),
                             substeps_mean=float(c["substeps"].mean()),
                             min_distance_over_2r=float(c["min_distance"].min() / c["gap"]))
        print(f"{out['base']} {pulse:6s} B={B:6d} {precision} {name:8s} {out[name]['column_steps_per_s']:.3e} "
              f"column-steps/s ({r.info['step_path']})", flush=True)
    out["contact_over_staged"] = out["contact"]["wall_s"] / out["staged"]["wall_s"]
    out["contact_over_default"] = out["contact"]["wall_s"] / out["default"]["wall_s"]
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--columns", type=int, nargs="+", default=[4096])
    ap.add_argument("--precision", default="fp64")
    ap.add_argument("--out-dir", default=str(RESULTS))
    a = ap.parse_args(argv)
    from warp_tensegrity.runtime import init_warp, resolve_device

    init_warp()
    dev = resolve_device(a.device)
    cases = [time_case(base, pulse, B, a.precision, a.device) for B in a.columns for base in (1.0, 0.0)
             for pulse in PULSES]
    path = write_json(f"{a.out_dir}/contact_cost_{device_tag(a.device)}.json",
                      {"meta": run_metadata(dev), "t_end": T_END, "cases": cases})
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
