"""The lane step's results to the bit, for comparing two versions of the code on one device: each
case (prisms, base rigidities, precision) runs ``--steps`` RATTLE steps on the lane step from a
perturbed state that moves every level (:func:`moving_batch`, tests/kernels/test_lanes_long.py's), and its strain
record, final displacement and velocity are saved. ``--compare`` reads two such files and says,
array by array, whether they are bit-identical and by how much they differ.

    python -m benchmarks.lanes_bits --device cuda:0 --out new.npz
    python -m benchmarks.lanes_bits --compare new.npz base.npz --out same.json
"""

from __future__ import annotations

import argparse
import dataclasses
import sys

import numpy as np

CASES = [(300, (0.0, 0.5), "fp64"), (300, (1.0, 0.5), "fp64"), (50, (1.0, 0.0), "fp64"), (500, (0.0, 0.5), "fp32"),
         (1000, (0.0, 0.5), "fp64")]
"""(prisms, base rigidities of the 2 columns, precision): k warps per column (300 flexible: 3 levels on
128 lanes; rigid fp64 300: 1 level on 512; 50 rigid fp64: 1 level on 64; 500 fp32: 2 on 256; 1,000:
4 on 256)."""


def moving_batch(n, base_rigidity, ea_scale=1.0):
    """Two n-prism columns (alternating hands, p = 0.002 and 0, v0 = 0.1 and 0.05 m/s, ``base_rigidity``
    one per column) whose every node starts moving: a smooth velocity field along the column (seeded
    by n), level 0 clamped; cable EA scaled by ``ea_scale`` (tests/kernels/test_lanes_long.py)."""
    from warp_tensegrity import ColumnConfig
    from warp_tensegrity.scene.batch import column_batch

    cfg = ColumnConfig(n_prisms=n, handedness="alternating", impact_admissibility="end_twist")
    b = column_batch(cfg, {"prestrain": [0.002, 0.0], "v0": [0.1, 0.05], "base_rigidity": list(base_rigidity)})
    z = b.positions[:, 2]
    rng = np.random.default_rng(n)
    k = rng.uniform(1.0, 4.0, size=(b.n_columns, 1, 3))
    phase = rng.uniform(0.0, 2 * np.pi, size=(b.n_columns, 1, 3))
    v = b.velocity + 0.05 * np.sin(2 * np.pi * k * z[None, :, None] / z.max() + phase)
    v[:, :3] = 0.0  # the clamped level 0
    return dataclasses.replace(b, velocity=v, cable_EA=b.cable_EA * ea_scale)


def run(device: str, steps: int, dt: float) -> dict:
    from warp_tensegrity import RunSettings
    from warp_tensegrity.engine import run_batch

    out = {}
    for n, br, prec in CASES:
        s = RunSettings(precision=prec, device=device, truncate=False, fused="lanes", t_end=steps * dt, dt=dt,
                        output_interval=steps * dt / 4)
        r = run_batch(moving_batch(n, br), s)
        tag = f"{n}_{'_'.join(str(b) for b in br)}_{prec}"
        print(f"{tag}: {r.info['step_path']}", flush=True)
        for name in ("strain", "final_displacement", "final_velocity", "status"):
            out[f"{tag}/{name}"] = np.asarray(getattr(r, name))
    return out


def compare(a: dict, b: dict) -> dict:
    rows = {}
    for k in sorted(set(a) | set(b)):
        if k not in a or k not in b:
            rows[k] = {"present": [k in a, k in b]}
            continue
        x, y = a[k], b[k]
        same = x.shape == y.shape and x.tobytes() == y.tobytes()
        d = float(np.max(np.abs(x.astype(np.float64) - y.astype(np.float64)))) if x.shape == y.shape else None
        rows[k] = {"bit_identical": bool(same), "max_abs_difference": d}
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--device", default="cuda:0")
    ap.add_argument("--steps", type=int, default=40)
    ap.add_argument("--dt", type=float, default=5e-4)
    ap.add_argument("--compare", nargs=2, metavar=("NEW", "BASE"))
    ap.add_argument("--out", required=True)
    a = ap.parse_args(argv)
    if a.compare:
        import warp as wp

        from . import common

        with np.load(a.compare[0]) as x, np.load(a.compare[1]) as y:
            rows = compare(dict(x), dict(y))
        same = all(r.get("bit_identical", False) for r in rows.values())
        print(f"{sum(r.get('bit_identical', False) for r in rows.values())} of {len(rows)} arrays bit-identical")
        doc = {"kind": "lanes_bits", "meta": common.run_metadata(wp.get_device(a.device)), "new": a.compare[0], "base": a.compare[1],
               "all_bit_identical": same, "arrays": rows}
        common.write_json(a.out, doc)
        return 0 if same else 1
    np.savez(a.out, **run(a.device, a.steps, a.dt))
    return 0


if __name__ == "__main__":
    sys.exit(main())
