"""Cost of the feasibility record (issue 32): stepping a phase_large-like batch (50-prism columns,
output every 2 ms as sweeps/phase_large.toml, the strain record on the device as a sweep keeps it)
with and without the ``record_feasibility`` launch, on the path the engine decides (or the one
named), and the record kernel's own time per output.

    python -m benchmarks.feasibility_cost --device cpu --columns 64 --steps 2000
    python -m benchmarks.feasibility_cost --device cuda:0 --columns 1536 16384 65536 \\
        --out benchmarks/results/feasibility_cost_h100.json

For each base (FB and RB) and column count: two Integrators of the same batch, one whose launches of
``record_feasibility`` are dropped (harness-side, the engine unchanged), stepped ``--steps`` steps
``--reps`` times each, alternating; ``share`` = (median with - median without) / median without
(seconds: wall time on a GPU, this process's CPU time on the CPU).
``kernel_s_per_output``: one launch at an output step (the full kernel), ``gated_launch_s``: one at
another step (it returns at once; the staged path launches it every step, the fused ones after every
fused launch). Writes JSON with the device name and the git commit (benchmarks/common.py).
"""

from __future__ import annotations

import argparse
import statistics
import time

from . import common

OUTPUT_INTERVAL = 0.002  # s, as sweeps/phase_large.toml


def _integrators(batch, settings, path, steps):
    """(with, without): Integrators of ``batch`` with records for ``steps`` steps, the second
    dropping the record_feasibility launches."""
    from warp_tensegrity.sim.integrate import Integrator
    from warp_tensegrity.policy.decide import decide_batch
    from warp_tensegrity.types import Path

    plan = decide_batch(batch, settings)
    path = plan.path if path == "auto" else Path(path)

    class Without(Integrator):
        def _launch(self, kernel, dim, inputs, model=None):
            if kernel is self.k.record_feasibility:
                return
            super()._launch(kernel, dim, inputs, model)

    n_out = steps // plan.output_every + 2
    made = [cls(batch, plan.settings, plan.dt, plan.output_every, n_out, path=path) for cls in (Integrator, Without)]
    return made, plan


def _clock(device):
    """Wall time on a GPU; on the CPU this process's CPU time (Warp's CPU kernels run in the calling
    thread), which other processes on a shared machine do not inflate."""
    return time.perf_counter if device.is_cuda else time.process_time


def _stepping_seconds(integ, steps: int) -> float:
    """Seconds for ``steps`` steps from step 0 (the counter and the record restart; the state goes on)."""
    import warp as wp

    clock = _clock(integ.device)
    integ.data.step.zero_()
    integ.steps_done = 0
    wp.synchronize_device(integ.device)
    t0 = clock()
    integ.advance(steps)
    wp.synchronize_device(integ.device)
    return clock() - t0


def _launch_seconds(integ, at_output: bool, n: int = 50) -> float:
    """Seconds of one record_feasibility launch, at an output step or at another one (gated)."""
    import warp as wp

    m, d = integ.model, integ.data
    integ.data.step.fill_(0 if at_output else 1)
    args = [integ.every, d.u, d.status, d.step, d.twist, d.twist_max, d.twist_min, d.height_min, d.left_slot]
    integ._launch(integ.k.record_feasibility, (m.n_prisms, m.n_columns), args, model="feasibility")
    clock = _clock(integ.device)
    wp.synchronize_device(integ.device)
    t0 = clock()
    for _ in range(n):
        integ._launch(integ.k.record_feasibility, (m.n_prisms, m.n_columns), args, model="feasibility")
    wp.synchronize_device(integ.device)
    return (clock() - t0) / n


def point(device: str, n_prisms: int, beta: float, B: int, steps: int, reps: int, precision: str, path: str) -> dict:
    import warp as wp

    from warp_tensegrity import RunSettings
    from warp_tensegrity.policy.paths import lane_emulation

    batch = common.tile_batch(common.build_base_batch(n_prisms, beta, min(B, common.BASE_COLUMNS)), B)
    settings = RunSettings(device=device, precision=precision, t_end=1.0, output_interval=OUTPUT_INTERVAL)
    (on, off), plan = _integrators(batch, settings, path, steps)
    times = {"with": [], "without": []}
    with lane_emulation(on.path, on.device), wp.ScopedDevice(on.device):
        for integ in (on, off):
            integ.initialize()
            _stepping_seconds(integ, min(steps, 4 * plan.output_every * 50))  # warm-up: loads, graph capture
        for _ in range(reps):
            times["with"].append(_stepping_seconds(on, steps))
            times["without"].append(_stepping_seconds(off, steps))
        kern = _launch_seconds(on, True)
        gated = _launch_seconds(on, False)
    w, wo = statistics.median(times["with"]), statistics.median(times["without"])
    return {"n_prisms": n_prisms, "base_rigidity": beta, "columns": B, "precision": precision, "path": on.path.value,
            "dt": plan.dt, "output_every": plan.output_every, "steps": steps, "outputs_per_run": steps // plan.output_every,
            "stepping_s_with": w, "stepping_s_without": wo, "share": (w - wo) / wo,
            "kernel_s_per_output": kern, "gated_launch_s": gated,
            "kernel_share_estimate": kern * (steps // plan.output_every) / wo,
            "reps_s": times}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--columns", type=int, nargs="+", default=[64])
    ap.add_argument("--prisms", type=int, default=50)
    ap.add_argument("--bases", type=float, nargs="+", default=[0.0, 1.0])
    ap.add_argument("--steps", type=int, default=2000)
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--precision", default="fp64")
    ap.add_argument("--path", default="auto", choices=("auto", "staged", "fused", "fused-serial", "lanes"))
    ap.add_argument("--out", default=None, help="JSON path (default benchmarks/results/feasibility_cost_<device>.json)")
    a = ap.parse_args(argv)
    import warp as wp

    wp.config.quiet = True
    wp.init()
    dev = wp.get_device(a.device)
    doc = {"kind": "feasibility_cost", "meta": common.run_metadata(dev), "args": vars(a),
           "clock": "wall" if dev.is_cuda else "process CPU time", "points": []}
    for B in a.columns:
        for beta in a.bases:
            p = point(a.device, a.prisms, beta, B, a.steps, a.reps, a.precision, a.path)
            doc["points"].append(p)
            print(f"B = {B}, beta = {beta:g}, {p['path']}: with {p['stepping_s_with']:.4g} s, without "
                  f"{p['stepping_s_without']:.4g} s, share {100 * p['share']:+.2f} %; kernel "
                  f"{1e6 * p['kernel_s_per_output']:.1f} us per output ({100 * p['kernel_share_estimate']:.2f} %), "
                  f"gated launch {1e6 * p['gated_launch_s']:.1f} us", flush=True)
    out = a.out or common.RESULTS / f"feasibility_cost_{common.device_tag(a.device)}.json"
    print(common.write_json(out, doc))


if __name__ == "__main__":
    main()
