"""The lane step's measured throughput beside its issue-bound ceiling (issue 33 must-show 1).

The ceiling: the SMs' warp schedulers (4 per SM) issue one warp-instruction per cycle each, so a
kernel that executes ``I`` warp-instructions per column-step cannot exceed
``n_SM * 4 * f_clock / I`` column-steps/s (``roofline.issue_bound``). ``I`` is measured by Nsight
Compute (``smsp__inst_executed.sum`` of one 64-step launch / (64 B), benchmarks/gpu_lanes_ncu.sh);
the clock is the one ncu saw (``smsp__cycles_elapsed.avg.per_second``), else the card's maximum SM clock.

    python -m benchmarks.lanes_bound --throughput DIR --ncu DIR [--tag new] --out FILE.json
"""

import argparse
import csv
import glob
import json
import os
import re

from .roofline import DEVICES

STEPS_PER_LAUNCH = 64
"""Steps of the profiled launch (gpu_lanes_ncu.sh: --ncu-steps 64)."""


def ncu_raw(path: str) -> dict:
    """The first kernel row of an ncu ``--page raw --csv`` export: metric -> float (units row skipped)."""
    with open(path) as f:
        rows = list(csv.reader(f))
    head, data = rows[0], [r for r in rows[2:] if len(r) == len(rows[0])]
    row = dict(zip(head, data[0]))
    out = {}
    for k, v in row.items():
        try:
            out[k] = float(v.replace(",", ""))
        except ValueError:
            out[k] = v
    units = dict(zip(head, rows[1]))
    return out | {"_units": units}


def _clock_hz(raw: dict, gpu_txt: str | None) -> float:
    v = raw.get("smsp__cycles_elapsed.avg.per_second")
    if isinstance(v, float) and v > 0:
        unit = raw["_units"].get("smsp__cycles_elapsed.avg.per_second", "")
        return v * {"cycle/second": 1.0, "cycle/nsecond": 1e9, "cycle/usecond": 1e6, "Ghz": 1e9, "Mhz": 1e6}.get(unit, 1.0)
    if gpu_txt and os.path.exists(gpu_txt):  # "NVIDIA H200, 580.xx, 1980 MHz"
        m = re.search(r"(\d+)\s*MHz", open(gpu_txt).read())
        if m:
            return float(m.group(1)) * 1e6
    return 1.98e9


def best_point(doc: dict, base: str, prec: str, B: int):
    pts = [p for p in doc.get("points", []) if not p.get("error") and p.get("base") == base
           and p.get("precision") == prec and p.get("B") == B and p.get("path", "lanes") == "lanes"]
    return max(pts, key=lambda p: p["column_steps_per_s"]) if pts else None


def rows(throughput_dir: str, ncu_dir: str, tag: str, device_kind: str = "h200", B: int = 16384,
         prefix: str = "throughput_lanes"):
    n_sm = DEVICES[device_kind]["sm"]
    gpu_txt = os.path.join(ncu_dir, "gpu.txt")
    out = []
    for base in ("FB", "RB"):
        for prec in ("fp32", "fp64"):
            raw_path = os.path.join(ncu_dir, f"ncu_lanes_{base}_{prec}_B{B}_raw_{tag}.csv")
            rec = {"base": base, "precision": prec, "B": B}
            for f in glob.glob(os.path.join(throughput_dir, f"{prefix}_{tag}_{base}_{prec}*.json")):
                p = best_point(json.load(open(f)), base, prec, B)
                if p is not None:
                    rec["column_steps_per_s"] = p["column_steps_per_s"]
                    rec["commit"] = json.load(open(f)).get("meta", {}).get("git_commit")
            if os.path.exists(raw_path):
                raw = ncu_raw(raw_path)
                ins = raw["smsp__inst_executed.sum"] / (STEPS_PER_LAUNCH * B)
                clk = _clock_hz(raw, gpu_txt)
                rec |= {"warp_instructions_per_column_step": ins, "clock_hz": clk,
                        "registers_per_thread": raw.get("launch__registers_per_thread"),
                        "issue_active_pct": raw.get("smsp__issue_active.avg.pct_of_peak_sustained_active"),
                        "issue_bound_column_steps_per_s": n_sm * 4 * clk / ins}
                if "column_steps_per_s" in rec:
                    rec["fraction_of_issue_bound"] = rec["column_steps_per_s"] / rec["issue_bound_column_steps_per_s"]
            out.append(rec)
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--throughput", required=True, help="folder of <prefix>_<tag>_<base>_<prec>*.json")
    ap.add_argument("--ncu", required=True, help="folder of ncu_lanes_*_raw_<tag>.csv (and gpu.txt)")
    ap.add_argument("--tag", default="new")
    ap.add_argument("--prefix", default="throughput_lanes", help="the throughput JSONs' name before _<tag>")
    ap.add_argument("--device-kind", default="h200", choices=sorted(DEVICES))
    ap.add_argument("--out", default=None)
    a = ap.parse_args(argv)
    r = rows(a.throughput, a.ncu, a.tag, a.device_kind, prefix=a.prefix)
    print("| case | column-steps/s | warp-instr/col-step | issue bound | fraction | registers |")
    print("|---|---:|---:|---:|---:|---:|")
    for x in r:
        g = lambda k, f: (f.format(x[k]) if x.get(k) is not None else "")
        print(f"| {x['base']} {x['precision']} | {g('column_steps_per_s', '{:.3g}')} | "
              f"{g('warp_instructions_per_column_step', '{:.0f}')} | {g('issue_bound_column_steps_per_s', '{:.3g}')} | "
              f"{g('fraction_of_issue_bound', '{:.0%}')} | {g('registers_per_thread', '{:.0f}')} |")
    if a.out:
        with open(a.out, "w") as f:
            json.dump({"tag": a.tag, "rows": r}, f, indent=1)


if __name__ == "__main__":
    main()
