"""Model no more than a scene needs: what each of the engine's cheaper choices saves and costs.

Five choices the engine takes by itself, each measured against the more expensive alternative
(same device, same batch, timings interleaved and repeated, the minimum kept):

1. ``fp32`` instead of ``fp64`` (same method and dt): 50-prism column (``ColumnConfig()``), FB and
   RB at p = 0.002, v0 = 0.1 m/s, t_end = 1.5 s, a batch of identical columns. Cost in error:
   pulse speed and amplitude (:func:`warp_tensegrity.measure.measure_pulse`) of both precisions
   against a float64 RK4 reference at dt = 2e-4 s (10-12x below the engine's dt) and against
   each other.
2. Massless bars (no partner-mass path) when the bar mass is zero: free single T3 prisms
   (as ``tests/validation/test_against_reference.py``), random admissible velocities, 0.1 s. Timed three
   ways: massless bars with the bar mass lumped on the nodes (m/2 per end), the partner-mass
   path with the same lumped masses plus a negligible bar mass (1e-12 kg: the same physics, the
   massive code path; the pure cost of that path), and the consistent-inertia bars
   (bar_mass = m, node mass 0). Cost in error of lumping: final displacement difference
   relative to the motion.
3. ``record_strain=False``: no strain history kept (time, and bytes of the strain arrays).
4. Outputs decimated on the device: ``output_interval = 0.01 s`` against every step
   (``output_interval = dt``), explicit dt = 0.002 s.
5. Truncation to the prisms a front can reach: ``ColumnConfig(n_prisms=200)``, t_end = 0.3 s,
   ``truncate=True`` against ``False`` (FB and RB). Cost in error: max strain difference.

And the accuracy-driven choice (``RunSettings(accuracy=a)``, a in 1e-2 ... 1e-5) on the two
50-prism cases: the chosen method/precision/dt, the cost per simulated second per column, and
the achieved pulse speed and amplitude errors against the reference; then a short scan of the
error against dt (rattle and rk4, fp64, one column) shows what dt each target really needs.

Timings: the minimum over interleaved repeats (3 by default; 7 for the sub-second parts 2-5) of the
stepping time (``BatchResult.wall_time``); end-to-end times add the host-side build (including
the reference-state equilibrium diagnostic, except in part 5) and the result transfer.

Device memory is measured, not estimated: the bytes of every Warp array the Integrator
allocates for that batch and those settings (model, state, outputs).

Usage::

    python -m benchmarks.model_choices --device cpu --out analysis       # ~2 min on 2 cores
    python -m benchmarks.model_choices --plot-only analysis              # figures from the JSON

Writes ``OUT/data/choices_<device>.json`` and ``OUT/figures/choices_{savings,accuracy}_<device>.png``.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from dataclasses import replace
from pathlib import Path

# one BLAS thread (before NumPy loads): the host-side equilibrium diagnostic is a small least-squares
# solve, and OpenBLAS's spinning threads on a loaded 2-core machine made it take 0.07-3.7 s for the
# same call and compete with Warp's stepping thread
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import numpy as np  # noqa: E402

P_CASE = 0.002
V0_CASE = 0.1
CASES = (("FB", 0.0), ("RB", 1.0))
T_END = 1.5
OUT_INTERVAL = 0.01
REF_K = 50  # reference dt = OUT_INTERVAL / REF_K = 2e-4 s (check run at REF_K / 2)
ACCURACIES = (1e-2, 1e-3, 1e-4, 1e-5)
# dt = OUT_INTERVAL / k of the error-vs-dt scan (fp64, one column per case)
SCAN = (("rattle", (2, 4, 8, 16)), ("rk4", (3, 6, 12)))


def _device_tag(device: str) -> str:
    return device.replace(":", "")


# ---------------------------------------------------------------------- helpers
def device_bytes(batch, settings) -> dict:
    """Bytes of every Warp array the Integrator allocates for this batch and these settings."""
    import warp as wp

    from warp_tensegrity.sim.integrate import Integrator
    from warp_tensegrity.policy.decide import decide_batch

    run = decide_batch(batch, settings)
    integ = Integrator(batch, run.settings, run.dt, run.output_every, run.n_out, path=run.path)

    def size(v):
        if isinstance(v, wp.array):
            return int(v.capacity)
        if isinstance(v, dict):
            return sum(size(a) for a in v.values())
        return 0

    model = sum(size(v) for v in vars(integ.model).values())
    state = sum(size(v) for v in vars(integ.data).values())
    strain = size(integ.strain)
    energy = size(integ.kinetic) + size(integ.elastic)
    out = {"model": model, "state": state, "strain": strain, "energy": energy,
           "total": model + state + strain + energy}
    del integ
    return out


def host_result_bytes(r) -> dict:
    """Bytes of the per-column histories a result carries to the host (float64)."""
    strain = 0 if r.strain is None else int(r.strain.nbytes)
    energy = int(r.kinetic_energy.nbytes + r.elastic_energy.nbytes)
    return {"strain": strain, "energy": energy, "total": strain + energy}


def column_params(B: int, base_rigidity: float) -> dict:
    return {"prestrain": np.full(B, P_CASE), "v0": np.full(B, V0_CASE), "base_rigidity": np.full(B, base_rigidity)}


def timed_variants(variants: dict, repeats: int, log) -> dict:
    """Run each variant (name -> callable returning a BatchResult) ``repeats`` times, interleaved.
    Returns name -> {'result': first result, 'wall': [...], 'total': [...]} (stepping seconds and
    end-to-end seconds including the host-side build and result transfer)."""
    out = {k: {"result": None, "wall": [], "total": []} for k in variants}
    for rep in range(repeats):
        for name, fn in variants.items():
            t0 = time.perf_counter()
            r = fn()
            total = time.perf_counter() - t0
            out[name]["wall"].append(float(r.wall_time))
            out[name]["total"].append(total)
            if out[name]["result"] is None:
                out[name]["result"] = r
            log(f"    {name:<28s} rep {rep}: stepping {r.wall_time:7.3f} s, end-to-end {total:7.3f} s")
    return out


def summary(t: dict, column_steps: float) -> dict:
    w, tot = np.array(t["wall"]), np.array(t["total"])
    return {
        "wall_s": w.tolist(),
        "total_s": tot.tolist(),
        "wall_min_s": float(w.min()),
        "wall_median_s": float(np.median(w)),
        "total_min_s": float(tot.min()),
        "wall_spread": float(w.max() / w.min() - 1.0),
        "us_per_column_step": float(w.min() / column_steps * 1e6),
    }


class PulseRef:
    """Reference pulse measures of one case: threshold (measure_pulse's choice on the reference,
    then held fixed) and the reference speed/amplitude; errors of any run sampled at the same times."""

    def __init__(self, strain, time, height):
        from warp_tensegrity.measure import measure_pulse

        self.time = time
        self.height = height
        m = measure_pulse(strain, time, height)
        self.threshold = float(m["threshold"])
        m = measure_pulse(strain, time, height, threshold=self.threshold)
        self.speed = float(m["speed"])
        self.amplitude = float(m["amplitude"])
        self.prisms_measured = float(m["prisms_measured"])
        self.strain = strain

    def measures(self, strain, time) -> dict:
        from warp_tensegrity.measure import measure_pulse

        if time.shape != self.time.shape or np.abs(time - self.time).max() > 1e-9:
            raise ValueError("run and reference sample different times")
        m = measure_pulse(strain, time, self.height, threshold=self.threshold)
        return {"speed": float(m["speed"]), "amplitude": float(m["amplitude"]),
                "prisms_measured": float(m["prisms_measured"])}

    def errors(self, strain, time) -> dict:
        m = self.measures(strain, time)
        return {
            **m,
            "err_speed": abs(m["speed"] / self.speed - 1.0),
            "err_amplitude": abs(m["amplitude"] / self.amplitude - 1.0),
            "err_strain_history": float(np.abs(strain - self.strain).max() / np.abs(self.strain).max()),
        }


# ---------------------------------------------------------------------- parts
def references(device, log) -> dict:
    """float64 RK4 at dt = OUT_INTERVAL/REF_K, one column per case; check at twice that dt."""
    from warp_tensegrity import ColumnConfig, RunSettings, simulate_batch

    cfg = ColumnConfig()
    refs, out = {}, {}
    for name, beta in CASES:
        res = {}
        for k in (REF_K, REF_K // 2):
            s = RunSettings(t_end=T_END, dt=OUT_INTERVAL / k, method="rk4", precision="fp64",
                            output_interval=OUT_INTERVAL, device=device)
            t0 = time.perf_counter()
            res[k] = simulate_batch(cfg, column_params(1, beta), s)
            log(f"  reference {name} rk4 fp64 dt={OUT_INTERVAL / k:.2e}: {time.perf_counter() - t0:.1f} s")
        ref = PulseRef(res[REF_K].strain[0], res[REF_K].time, cfg.height)
        check = ref.errors(res[REF_K // 2].strain[0], res[REF_K // 2].time)
        refs[name] = ref
        out[name] = {
            "dt": OUT_INTERVAL / REF_K,
            "speed": ref.speed,
            "amplitude": ref.amplitude,
            "threshold": ref.threshold,
            "prisms_measured": ref.prisms_measured,
            # difference to the run at 2x the reference dt: bounds the reference's own error
            # (RK4: /15 if 4th order; FB slack/taut dynamics: order ~2, /3)
            "check_dt": OUT_INTERVAL / (REF_K // 2),
            "check_err_speed": check["err_speed"],
            "check_err_amplitude": check["err_amplitude"],
            "check_err_strain_history": check["err_strain_history"],
            "wall_s": float(res[REF_K].wall_time),
        }
    return refs, out


def part_fp32(device, refs, B, repeats, log) -> dict:
    from warp_tensegrity import ColumnConfig, RunSettings, column_batch, simulate_batch

    cfg = ColumnConfig()
    out = {}
    for name, beta in CASES:
        log(f"  fp32 vs fp64, {name}, B={B}")
        params = column_params(B, beta)
        st = {p: RunSettings(t_end=T_END, precision=p, output_interval=OUT_INTERVAL, device=device)
              for p in ("fp64", "fp32")}
        t = timed_variants({p: (lambda s=s: simulate_batch(cfg, params, s)) for p, s in st.items()}, repeats, log)
        r64, r32 = t["fp64"]["result"], t["fp32"]["result"]
        assert r64.dt == r32.dt and r64.n_steps == r32.n_steps
        batch = column_batch(cfg, params)
        entry = {"B": B, "dt": r64.dt, "n_steps": r64.n_steps, "method": r64.method}
        for p, r in (("fp64", r64), ("fp32", r32)):
            same = float(np.nanmax(np.abs(r.strain - r.strain[:1])))
            entry[p] = {
                **summary(t[p], r.n_steps * B),
                **refs[name].errors(r.strain[0], r.time),
                "columns_identical_max_diff": same,
                "bar_length_error": float(r.bar_length_error.max()),
                "energy_error": float(np.nanmax(r.energy_error)),
                "device_bytes": device_bytes(batch, st[p]),
                "host_bytes": host_result_bytes(r),
            }
        m64, m32 = entry["fp64"], entry["fp32"]
        entry["speedup"] = m64["wall_min_s"] / m32["wall_min_s"]
        entry["speedup_median"] = m64["wall_median_s"] / m32["wall_median_s"]
        entry["memory_factor"] = m64["device_bytes"]["total"] / m32["device_bytes"]["total"]
        entry["fp32_vs_fp64"] = {
            "speed": abs(m32["speed"] / m64["speed"] - 1.0),
            "amplitude": abs(m32["amplitude"] / m64["amplitude"] - 1.0),
            "strain_history": float(np.abs(r32.strain[0] - r64.strain[0]).max() / np.abs(r64.strain[0]).max()),
        }
        out[name] = entry
    return out


def free_prisms(B: int, bar_mass: float, seed: int = 1, speed: float = 0.002, prestrain: float = 0.01):
    """Free class-1 T3 prisms, random admissible velocities. Returns the three networks
    (consistent bar inertia; lumped m/2 per end with massless bars; lumped plus a negligible
    bar mass, which takes the partner-mass path) and the velocities (B, 6, 3)."""
    from warp_tensegrity import ColumnConfig, Network, build_column
    from tests.references.reference import ReferenceSystem

    net = build_column(ColumnConfig(n_prisms=1), prestrain=prestrain).network

    def make(node_mass, bm):
        return Network(positions=net.positions, node_mass=node_mass, fixed=False, bars=net.bars, bar_mass=bm,
                       cables=net.cables, cable_EA=net.cable_EA, cable_rest_length=net.cable_rest_length).validate()

    massive = make(0.0, bar_mass)
    lumped = make(bar_mass / 2.0, 0.0)
    lumped_path = make(bar_mass / 2.0, 1e-12)
    ref = ReferenceSystem(massive)
    rng = np.random.default_rng(seed)
    v = np.stack([ref.project_velocities(net.positions, rng.normal(scale=speed, size=(net.positions.shape[0], 3)))
                  for _ in range(B)])
    return massive, lumped, lumped_path, v


def part_massless(device, B, repeats, log) -> dict:
    from warp_tensegrity import RunSettings, network_batch, run_batch

    t_end, dt, bar_mass = 0.1, 2.5e-4, 0.01
    log(f"  massless vs massive bars, free T3 prisms, B={B}")
    massive, lumped, lumped_path, v = free_prisms(B, bar_mass)
    batches = {
        "massless (lumped m/2)": network_batch([lumped] * B, list(v)),
        "partner path (lumped + 1e-12 kg bars)": network_batch([lumped_path] * B, list(v)),
        "massive bars (consistent)": network_batch([massive] * B, list(v)),
    }
    s = RunSettings(t_end=t_end, dt=dt, method="rattle", precision="fp64", output_interval=t_end, device=device)
    t = timed_variants({k: (lambda b=b: run_batch(b, s)) for k, b in batches.items()}, repeats, log)
    res = {k: t[k]["result"] for k in batches}
    u = {k: r.final_displacement for k, r in res.items()}
    motion = float(np.abs(u["massive bars (consistent)"]).max())
    out = {"B": B, "t_end": t_end, "dt": dt, "bar_mass": bar_mass, "n_steps": res["massive bars (consistent)"].n_steps,
           "max_displacement": motion, "variants": {}}
    for k, r in res.items():
        out["variants"][k] = {**summary(t[k], r.n_steps * B), "device_bytes": device_bytes(batches[k], s),
                              "bar_length_error": float(r.bar_length_error.max())}
    ml, pp, mv = ("massless (lumped m/2)", "partner path (lumped + 1e-12 kg bars)", "massive bars (consistent)")
    # same physics, two code paths: the saving of the massless path
    out["speedup_vs_partner_path"] = out["variants"][pp]["wall_min_s"] / out["variants"][ml]["wall_min_s"]
    out["speedup_vs_massive"] = out["variants"][mv]["wall_min_s"] / out["variants"][ml]["wall_min_s"]
    out["speedup_vs_partner_path_median"] = out["variants"][pp]["wall_median_s"] / out["variants"][ml]["wall_median_s"]
    out["speedup_vs_massive_median"] = out["variants"][mv]["wall_median_s"] / out["variants"][ml]["wall_median_s"]
    out["memory_factor"] = out["variants"][mv]["device_bytes"]["total"] / out["variants"][ml]["device_bytes"]["total"]
    out["path_difference"] = float(np.abs(u[pp] - u[ml]).max() / motion)
    # lumping the bar mass on the nodes changes the physics (rotary inertia m L^2/4 vs m L^2/12)
    out["lumping_error"] = float(np.abs(u[mv] - u[ml]).max() / motion)
    return out


def part_strain(device, B, repeats, log) -> dict:
    from warp_tensegrity import ColumnConfig, RunSettings, column_batch, simulate_batch

    cfg, t_end = ColumnConfig(), 0.5
    log(f"  record_strain True vs False, FB, B={B}")
    params = column_params(B, 0.0)
    st = {k: RunSettings(t_end=t_end, output_interval=OUT_INTERVAL, record_strain=k, device=device) for k in (True, False)}
    t = timed_variants({str(k): (lambda s=s: simulate_batch(cfg, params, s)) for k, s in st.items()}, repeats, log)
    batch = column_batch(cfg, params)
    out = {"B": B, "t_end": t_end, "case": "FB"}
    for k, s in st.items():
        r = t[str(k)]["result"]
        out[f"record_strain={k}"] = {**summary(t[str(k)], r.n_steps * B), "device_bytes": device_bytes(batch, s),
                                     "host_bytes": host_result_bytes(r), "n_out": len(r.time)}
    out.update(_savings(out["record_strain=True"], out["record_strain=False"]))
    return out


def _savings(a: dict, b: dict) -> dict:
    """Time and memory of variant a over variant b (each a summary with device/host bytes)."""
    return {
        "speedup": a["wall_min_s"] / b["wall_min_s"],
        "speedup_median": a["wall_median_s"] / b["wall_median_s"],
        "speedup_end_to_end": a["total_min_s"] / b["total_min_s"],
        "memory_factor": a["device_bytes"]["total"] / b["device_bytes"]["total"],
        "host_memory_factor": a["host_bytes"]["total"] / b["host_bytes"]["total"],
    }


def part_outputs(device, B, repeats, log) -> dict:
    from warp_tensegrity import ColumnConfig, RunSettings, column_batch, simulate_batch

    cfg, t_end, dt = ColumnConfig(), 0.5, 0.002
    log(f"  outputs every step vs every 0.01 s, FB, B={B}")
    params = column_params(B, 0.0)
    st = {"every step": RunSettings(t_end=t_end, dt=dt, output_interval=dt, device=device),
          "every 0.01 s": RunSettings(t_end=t_end, dt=dt, output_interval=0.01, device=device)}
    t = timed_variants({k: (lambda s=s: simulate_batch(cfg, params, s)) for k, s in st.items()}, repeats, log)
    batch = column_batch(cfg, params)
    out = {"B": B, "t_end": t_end, "dt": dt, "case": "FB"}
    for k, s in st.items():
        r = t[k]["result"]
        out[k] = {**summary(t[k], r.n_steps * B), "device_bytes": device_bytes(batch, s),
                  "host_bytes": host_result_bytes(r), "n_out": len(r.time)}
    ra, rb = t["every step"]["result"], t["every 0.01 s"]["result"]
    every = rb.info["output_every"]
    out["decimated_equals_every_step_subsampled"] = bool(np.array_equal(ra.strain[:, ::every], rb.strain))
    out.update(_savings(out["every step"], out["every 0.01 s"]))
    return out


def part_truncate(device, B, repeats, log) -> dict:
    from warp_tensegrity import ColumnConfig, RunSettings, column_batch, simulate_batch

    from .common import skip_equilibrium_checks

    cfg, t_end = ColumnConfig(n_prisms=200), 0.3
    out = {}
    for name, beta in CASES:
        log(f"  truncate True vs False, 200 prisms, {name}, B={B}")
        params = column_params(B, beta)
        st = {k: RunSettings(t_end=t_end, output_interval=OUT_INTERVAL, truncate=k, device=device) for k in (True, False)}
        # the reference-state equilibrium diagnostic (a dense least-squares solve, reported and never
        # used by the engine) is skipped: it dominates the host time at 200 prisms and is not a choice
        with skip_equilibrium_checks():
            t = timed_variants({f"truncate={k}": (lambda s=s: simulate_batch(cfg, params, s)) for k, s in st.items()},
                               repeats, log)
            rt, rf = t["truncate=True"]["result"], t["truncate=False"]["result"]
            n_sim = int(rt.info["choices"]["prisms_simulated"])
            mem_t = device_bytes(column_batch(replace(cfg, n_prisms=n_sim), params), st[True])
            mem_f = device_bytes(column_batch(cfg, params), st[False])
        scale = float(np.abs(rf.strain).max())
        e = {"B": B, "t_end": t_end, "prisms": cfg.n_prisms, "prisms_simulated": n_sim,
             "omega_max_bound": float(rf.info["omega_max_bound"]), "dt": rf.dt, "n_steps": rf.n_steps,
             "truncate=True": {**summary(t["truncate=True"], rt.n_steps * B), "device_bytes": mem_t},
             "truncate=False": {**summary(t["truncate=False"], rf.n_steps * B), "device_bytes": mem_f},
             "max_strain_diff": float(np.abs(rt.strain - rf.strain).max()),
             "max_strain": scale,
             "max_strain_far_prisms_full_run": float(np.abs(rf.strain[:, :, : cfg.n_prisms - n_sim]).max()),
             "max_final_displacement_diff": float(np.abs(rt.final_displacement - rf.final_displacement).max()),
             "max_energy_diff_rel": float(np.nanmax(np.abs((rt.kinetic_energy + rt.elastic_energy)
                                                           - (rf.kinetic_energy + rf.elastic_energy)))
                                          / rf.kinetic_energy[:, 0].max())}
        e["speedup"] = e["truncate=False"]["wall_min_s"] / e["truncate=True"]["wall_min_s"]
        e["speedup_median"] = e["truncate=False"]["wall_median_s"] / e["truncate=True"]["wall_median_s"]
        e["speedup_end_to_end"] = e["truncate=False"]["total_min_s"] / e["truncate=True"]["total_min_s"]
        e["memory_factor"] = mem_f["total"] / mem_t["total"]
        out[name] = e
    return out


def part_accuracy(device, refs, B, repeats, log) -> list:
    from warp_tensegrity import ColumnConfig, RunSettings, simulate_batch

    cfg = ColumnConfig()
    rows = []
    for name, beta in CASES:
        params = column_params(B, beta)
        log(f"  accuracy-driven choices, {name}, B={B}")
        st = {a: RunSettings(t_end=T_END, accuracy=a, output_interval=OUT_INTERVAL, device=device) for a in ACCURACIES}
        t = timed_variants({f"accuracy={a:g}": (lambda s=s: simulate_batch(cfg, params, s)) for a, s in st.items()},
                           repeats, log)
        for a in ACCURACIES:
            tt = t[f"accuracy={a:g}"]
            r = tt["result"]
            ch = r.info["choices"]
            err = refs[name].errors(r.strain[0], r.time)
            sm = summary(tt, r.n_steps * B)
            rows.append({
                "case": name, "accuracy": a, "B": B, "method": ch["method"], "precision": ch["precision"],
                "dt": float(ch["dt"]), "dt_safety": float(ch["dt_safety"]), "n_steps": r.n_steps,
                "omega_dt": float(ch["dt"] * r.info["omega_max_bound"]),
                "us_per_sim_s_per_column": sm["wall_min_s"] / (T_END * B) * 1e6,
                **sm, **err,
                "meets": bool(max(err["err_speed"], err["err_amplitude"]) <= a),
                "meets_speed": bool(err["err_speed"] <= a),
                "meets_amplitude": bool(err["err_amplitude"] <= a),
            })
    return rows


def part_dt_scan(device, refs, log) -> list:
    """Pulse errors of rattle and rk4 (fp64) against dt on the 50-prism cases: what dt a target needs."""
    from warp_tensegrity import ColumnConfig, RunSettings, simulate_batch

    cfg = ColumnConfig()
    rows = []
    for name, beta in CASES:
        log(f"  dt scan, {name}, one column")
        for method, ks in SCAN:
            for k in ks:
                s = RunSettings(t_end=T_END, dt=OUT_INTERVAL / k, method=method, output_interval=OUT_INTERVAL,
                                device=device, allow_unstable_dt=True)
                r = simulate_batch(cfg, column_params(1, beta), s)
                m = refs[name].measures(r.strain[0], r.time)
                rows.append({"case": name, "method": method, "precision": "fp64", "dt": OUT_INTERVAL / k,
                             "speed_rel": m["speed"] / refs[name].speed - 1.0,
                             "amplitude_rel": m["amplitude"] / refs[name].amplitude - 1.0})
    return rows


# ---------------------------------------------------------------------- figures
def plot(data: dict, fig_dir: Path, tag: str) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig_dir.mkdir(parents=True, exist_ok=True)
    paths = []
    c = data["choices"]

    # --- savings: speed-up and memory factors per choice, error cost annotated
    def host(e_exp, e_cheap):
        return e_exp["host_bytes"]["total"] / e_cheap["host_bytes"]["total"]

    items = []  # label, stepping speed-up, end-to-end speed-up, device-memory factor, host-memory factor, cost
    for case in ("FB", "RB"):
        f = c["fp32"][case]
        d = f["fp32_vs_fp64"]
        items.append((f"fp32\n({case})", f["speedup"], f["fp64"]["total_min_s"] / f["fp32"]["total_min_s"],
                      f["memory_factor"], host(f["fp64"], f["fp32"]),
                      f"speed {d['speed']:.0e}\namp. {d['amplitude']:.0e}\nhistory {d['strain_history']:.0e}"))
    m = c["massless_bars"]
    v = m["variants"]
    ml, pp = "massless (lumped m/2)", "partner path (lumped + 1e-12 kg bars)"
    items.append(("massless bars\n(free prisms)", m["speedup_vs_partner_path"],
                  v[pp]["total_min_s"] / v[ml]["total_min_s"], m["memory_factor"], 1.0,
                  f"none: {m['path_difference']:.0e}\n(lumping a real\nbar: {m['lumping_error']:.0e})"))
    s = c["record_strain"]
    items.append(("no strain\nhistory", s["speedup"], s["speedup_end_to_end"], s["memory_factor"],
                  s["host_memory_factor"], "none\n(nothing\nmeasurable)"))
    o = c["output_decimation"]
    items.append(("outputs every\n0.01 s, not dt", o["speedup"], o["speedup_end_to_end"], o["memory_factor"],
                  o["host_memory_factor"], "none\n(exact\nsubsample)"))
    for case in ("FB", "RB"):
        tr = c["truncation"][case]
        items.append((f"truncation\n({case}, {tr['prisms_simulated']}/{tr['prisms']})", tr["speedup"],
                      tr["speedup_end_to_end"], tr["memory_factor"], 1.0,
                      f"max |Δε|\n{tr['max_strain_diff']:.0e}\n(ε ~ {tr['max_strain']:.1f})"))
    fig, ax = plt.subplots(figsize=(12, 5.8))
    x = np.arange(len(items))
    w = 0.2
    series = (("speed-up, stepping (min of repeats)", 1, "C0"), ("speed-up, end-to-end (build + transfer)", 2, "C9"),
              ("device-memory factor", 3, "C2"), ("host result-memory factor", 4, "C8"))
    for k, (label, col, color) in enumerate(series):
        bars = ax.bar(x + (k - 1.5) * w, [i[col] for i in items], w, label=label, color=color)
        for rect in bars:
            h = rect.get_height()
            ax.text(rect.get_x() + rect.get_width() / 2, h * 1.03, f"{h:.2f}" if h < 10 else f"{h:.0f}",
                    ha="center", va="bottom", fontsize=6.5, rotation=90)
    ax.axhline(1.0, color="k", lw=0.8)
    ax.set_yscale("log")
    ax.set_xticks(x, [i[0] for i in items], fontsize=9)
    ax.set_ylabel("expensive / cheap (x)")
    top = max(max(i[1:5]) for i in items)
    ax.set_ylim(0.5, top * 9)
    for xi, it in zip(x, items):
        ax.text(xi, top * 3.2, it[5], ha="center", va="center", fontsize=7.5,
                bbox=dict(boxstyle="round", fc="lightyellow", ec="0.6"))
    ax.text(-0.55, top * 6.5, "cost in error (relative to the expensive choice):", fontsize=8, ha="left")
    ax.legend(loc="center right", fontsize=7.5)
    meta, reps = data["meta"], f"{data['repeats']}-{data.get('repeats_small', data['repeats'])}"
    ax.set_title(f"What each cheaper choice saves ({meta['device_name']}, {meta.get('cpu_count')} cores shared with "
                 f"other work; min of {reps} interleaved repeats)", fontsize=10)
    fig.tight_layout()
    p = fig_dir / f"choices_savings_{tag}.png"
    fig.savefig(p, dpi=110)
    plt.close(fig)
    paths.append(p)

    # --- accuracy: requested vs achieved error, and cost
    rows = data["accuracy"]
    scan = data.get("dt_scan")
    if scan:
        fig, (a1, a2, a3) = plt.subplots(1, 3, figsize=(16, 4.8))
    else:
        fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 4.6))
    acc = np.array(ACCURACIES)
    marker = {"FB": "o", "RB": "s"}
    for case in ("FB", "RB"):
        rr = [r for r in rows if r["case"] == case]
        a = np.array([r["accuracy"] for r in rr])
        a1.loglog(a, [max(r["err_speed"], 1e-12) for r in rr], marker[case] + "-", color="C0", label=f"{case} speed")
        a1.loglog(a, [max(r["err_amplitude"], 1e-12) for r in rr], marker[case] + "--", color="C3",
                  label=f"{case} amplitude")
        a2.loglog(a, [r["us_per_sim_s_per_column"] for r in rr], marker[case] + "-", color="k", label=case)
        for r in rr:
            others = [o["us_per_sim_s_per_column"] for o in rows if o["accuracy"] == r["accuracy"] and o is not r]
            upper = all(r["us_per_sim_s_per_column"] >= o for o in others)
            a2.annotate(f"{case} dt={r['dt'] * 1e3:.2f} ms", (r["accuracy"], r["us_per_sim_s_per_column"]),
                        textcoords="offset points", xytext=(-6, 4) if upper else (6, -4), fontsize=7,
                        ha="right" if upper else "left", va="bottom" if upper else "top")
            if case == "RB":
                a2.text(r["accuracy"], 0.97, f"{r['method']}\n{r['precision']}", transform=a2.get_xaxis_transform(),
                        ha="center", va="top", fontsize=7.5, color="C4")
    for case in ("FB", "RB"):
        ref = data["references"][case]
        floor = max(ref["check_err_speed"], ref["check_err_amplitude"])
        a1.axhline(floor, color="0.6", lw=0.8, ls=":" if case == "FB" else "-.")
    a1.loglog(acc, acc, "k-", lw=0.8, label="requested")
    a1.fill_between(acc, acc, 1.0, color="C3", alpha=0.07)
    a1.set_xlabel("requested accuracy (RunSettings.accuracy)")
    a1.set_ylabel("achieved relative error vs reference")
    a1.set_title("requested vs achieved (shaded: not met; grey: ref. check)", fontsize=9)
    a1.invert_xaxis()
    a1.legend(fontsize=7)
    a2.set_xlabel("requested accuracy")
    a2.set_ylabel("µs stepping per simulated s per column")
    a2.set_title(f"cost of the engine's choice (50 prisms, {data['meta']['device_name']})", fontsize=9)
    a2.set_xlim(3e-2, 3.5e-6)
    lo_c = min(r["us_per_sim_s_per_column"] for r in rows)
    hi_c = max(r["us_per_sim_s_per_column"] for r in rows)
    a2.set_ylim(lo_c / 2, hi_c * 4)
    a2.legend(fontsize=8, loc="center right")
    if scan:
        style = {("FB", "rattle"): ("C0", "o-"), ("FB", "rk4"): ("C1", "o-"),
                 ("RB", "rattle"): ("C0", "s--"), ("RB", "rk4"): ("C1", "s--")}
        for (case, method), (color, fmt) in style.items():
            rr = sorted((r for r in scan if r["case"] == case and r["method"] == method), key=lambda r: r["dt"])
            a3.loglog([r["dt"] * 1e3 for r in rr], [max(abs(r["amplitude_rel"]), 1e-12) for r in rr], fmt,
                      color=color, ms=4, label=f"{case} {method} fp64")
        for r in rows:
            a3.plot(r["dt"] * 1e3, max(r["err_amplitude"], 1e-12), "*", color="C3" if r["meets_amplitude"] else "k",
                    ms=10, zorder=5)
            a3.annotate(f"{r['accuracy']:.0e}", (r["dt"] * 1e3, r["err_amplitude"]), textcoords="offset points",
                        xytext=(5, 2), fontsize=6.5)
        ref_floor = data["references"]["FB"]["check_err_amplitude"]
        a3.axhline(ref_floor, color="0.6", lw=0.8, ls=":")
        from matplotlib.ticker import FuncFormatter, LogLocator

        a3.xaxis.set_major_locator(LogLocator(subs=(1.0, 2.0, 5.0)))
        a3.xaxis.set_minor_formatter(FuncFormatter(lambda v, _: ""))
        a3.xaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
        a3.set_xlabel("dt [ms]")
        a3.set_ylabel("amplitude error vs reference")
        a3.set_title("amplitude error vs dt; stars: engine's choice\n(label: accuracy requested; dotted: FB ref. check)",
                     fontsize=9)
        a3.legend(fontsize=7, loc="lower right")
    fig.tight_layout()
    p = fig_dir / f"choices_accuracy_{tag}.png"
    fig.savefig(p, dpi=110)
    plt.close(fig)
    paths.append(p)
    return paths


# ---------------------------------------------------------------------- main
def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--device", default="cpu", help="Warp device (default cpu)")
    ap.add_argument("--out", default="analysis", help="output root: writes OUT/data and OUT/figures")
    ap.add_argument("--repeats", type=int, default=3, help="timing repeats per variant (min kept)")
    ap.add_argument("--repeats-small", type=int, default=7,
                    help="repeats of the sub-second comparisons (parts 2-5), whose noise is largest")
    ap.add_argument("--quick", action="store_true", help="smaller batches, one repeat (a smoke test)")
    ap.add_argument("--plot-only", metavar="DIR", help="only redraw figures from DIR/data/choices_*.json")
    args = ap.parse_args(argv)
    import json

    if args.plot_only:
        root = Path(args.plot_only)
        for f in sorted((root / "data").glob("choices_*.json")):
            data = json.loads(f.read_text())
            for p in plot(data, root / "figures", f.stem.removeprefix("choices_")):
                print(p)
        return 0

    import warp as wp

    wp.config.quiet = True
    wp.init()
    from warp_tensegrity.sim.integrate import resolve_device

    from .common import run_metadata, write_json

    dev = resolve_device(args.device)
    tag = _device_tag(str(dev))
    R = 1 if args.quick else args.repeats
    scale = 4 if args.quick else 1
    t_start = time.perf_counter()

    def log(msg):
        print(f"[{time.perf_counter() - t_start:6.1f} s] {msg}", flush=True)

    data = {"meta": {**run_metadata(dev), "blas_threads": os.environ.get("OPENBLAS_NUM_THREADS")}, "repeats": R,
            "repeats_small": 1 if args.quick else args.repeats_small,
            "setup": {"case_prestrain": P_CASE, "case_v0": V0_CASE, "t_end": T_END, "output_interval": OUT_INTERVAL,
                      "reference": f"rk4 fp64 dt={OUT_INTERVAL / REF_K:g} s, 1 column",
                      "note": "timings: min over interleaved repeats of the stepping time (BatchResult.wall_time); "
                              "end-to-end times include host build and result transfer"}}
    log("references")
    refs, data["references"] = references(str(dev), log)
    ch = {}
    log("1. fp32 vs fp64")
    ch["fp32"] = part_fp32(str(dev), refs, 32 // scale, R, log)
    log("2. massless bars")
    Rs = 1 if args.quick else args.repeats_small
    ch["massless_bars"] = part_massless(str(dev), 512 // scale, Rs, log)
    log("3. record_strain")
    ch["record_strain"] = part_strain(str(dev), 32 // scale, Rs, log)
    log("4. output decimation")
    ch["output_decimation"] = part_outputs(str(dev), 32 // scale, Rs, log)
    log("5. truncation")
    ch["truncation"] = part_truncate(str(dev), 8 // (2 if args.quick else 1), Rs, log)
    data["choices"] = ch
    log("6. accuracy-driven choice")
    data["accuracy"] = part_accuracy(str(dev), refs, 8 // (2 if args.quick else 1), R, log)
    log("6b. error against dt (what a target needs at 50 prisms)")
    data["dt_scan"] = part_dt_scan(str(dev), refs, log)
    data["total_wall_s"] = time.perf_counter() - t_start
    out = Path(args.out)
    suffix = "_quick" if args.quick else ""
    path = write_json(out / "data" / f"choices_{tag}{suffix}.json", data)
    log(f"wrote {path}")
    for p in plot(json.loads(path.read_text()), out / "figures", tag + suffix):
        log(f"wrote {p}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
