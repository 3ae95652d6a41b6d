"""Peer: the same T3 column in MuJoCo (CPU, one column), pulse speed and amplitude first, then cost.

MJCF model (built from :func:`warp_tensegrity.scene.columns.build_column`'s network):

* each free node: a body at its reference position with three slide joints (x, y, z) and a
  point mass (``inertial`` with the node mass, negligible rotational inertia); clamped nodes are
  world sites;
* each cable: a spatial tendon between the two node sites, ``stiffness`` = EA/L0 and
  ``springlength="0 L0"`` (dead band: no force while shorter than L0, so tension-only);
  cables between two clamped nodes are left out;
* each bar (and each RB rigid link): a spatial tendon held at its reference length by a
  ``<tendon>`` equality constraint. MuJoCo's equality constraints are soft: ``solref``
  (time constant, damping ratio) makes them stiff damped springs, and the time constant
  cannot go below 2 x timestep (MuJoCo's safety clamp), so bar lengths drift by O(force *
  timeconst^2 / mass) and the constraint damping dissipates energy;
* no gravity, no damping elsewhere; initial velocity = the engine's admissible impact velocity.

Needs ``mujoco`` (pip; 4.0.0 = ``mujoco`` + ``mujoco-core`` wheels, ~10 MB; physics only, the
viewer dependencies glfw/pyopengl/mujoco-studio are not needed: ``pip install --no-deps
mujoco mujoco-core`` works). Without it the script says so and exits 0.

Usage::

    python -m benchmarks.peer_mujoco [--n-prisms 50] [--base FB] [--out benchmarks/results/peer_mujoco_cpu.json]
"""

from __future__ import annotations

import argparse
import math
import sys
import time

import numpy as np

from . import common

CASES = {  # base: (prestrain, v0 [m/s], t_end [s]) -- the pulse leaves the window before t_end
    "FB": (0.01, 0.05, 1.0),
    "RB": (0.002, 0.1, 3.5),
}


def _g(x) -> str:
    return f"{float(x):.17g}"


def mjcf(scene, timestep: float, timeconst: float, integrator: str = "Euler") -> str:
    net = scene.network
    X = net.positions
    fixed = net.fixed
    out = ['<mujoco model="t3_column">',
           f'  <option timestep="{_g(timestep)}" gravity="0 0 0" integrator="{integrator}" '
           'solver="Newton" iterations="200" tolerance="1e-12"/>',
           '  <size memory="256M"/>',
           "  <worldbody>"]
    for i, x in enumerate(X):
        pos = f"{_g(x[0])} {_g(x[1])} {_g(x[2])}"
        if fixed[i]:
            out.append(f'    <site name="n{i}" pos="{pos}" size="0.0002"/>')
            continue
        m = float(net.node_mass[i])
        out += [f'    <body name="b{i}" pos="{pos}">',
                f'      <joint name="x{i}" type="slide" axis="1 0 0" limited="false"/>',
                f'      <joint name="y{i}" type="slide" axis="0 1 0" limited="false"/>',
                f'      <joint name="z{i}" type="slide" axis="0 0 1" limited="false"/>',
                f'      <inertial pos="0 0 0" mass="{_g(m)}" diaginertia="1e-12 1e-12 1e-12"/>',
                f'      <site name="n{i}" size="0.0002"/>',
                "    </body>"]
    out += ["  </worldbody>", "  <tendon>"]
    if np.any(net.cable_EA_compression != 0):
        raise ValueError("cables with compression stiffness (0 < base_rigidity < 1) are not modelled here")
    n_cab = 0
    for c, (i, j) in enumerate(net.cables):
        if fixed[i] and fixed[j]:
            continue
        L0 = float(net.cable_rest_length[c])
        k = float(net.cable_EA[c]) / L0
        out.append(f'    <spatial name="c{c}" stiffness="{_g(k)}" springlength="0 {_g(L0)}" damping="0">'
                   f'<site site="n{i}"/><site site="n{j}"/></spatial>')
        n_cab += 1
    for k, (i, j) in enumerate(net.bars):
        out.append(f'    <spatial name="bar{k}"><site site="n{i}"/><site site="n{j}"/></spatial>')
    out += ["  </tendon>", "  <equality>"]
    for k in range(len(net.bars)):
        out.append(f'    <tendon tendon1="bar{k}" solref="{_g(timeconst)} 1" solimp="0.99 0.999 0.001 0.5 2"/>')
    out += ["  </equality>", "</mujoco>"]
    return "\n".join(out)


def run_mujoco(scene, topo, t_end, timestep, output_interval, timeconst_factor=2.0, integrator="Euler"):
    import mujoco

    xml = mjcf(scene, timestep, timeconst_factor * timestep, integrator)
    model = mujoco.MjModel.from_xml_string(xml)
    data = mujoco.MjData(model)
    net = scene.network
    free = np.flatnonzero(~net.fixed)
    # joints in body order: x, y, z per free node
    data.qvel[:] = scene.velocity[free].reshape(-1)
    mujoco.mj_forward(model, data)
    every = max(1, round(output_interval / timestep))
    n_out = int(math.floor(t_end / (every * timestep) + 1e-9))
    X = net.positions
    levels = topo.level_nodes

    def positions():
        x = X.copy()
        x[free] += data.qpos.reshape(-1, 3)
        return x

    def strain_and_bars():
        x = positions()
        zl = x[levels, 2].mean(axis=1)
        h = np.diff(zl)
        h0 = np.diff(X[levels, 2].mean(axis=1))
        b = x[net.bars[:, 1]] - x[net.bars[:, 0]]
        L = np.linalg.norm(X[net.bars[:, 1]] - X[net.bars[:, 0]], axis=1)
        return (h - h0) / h, float(np.max(np.abs(np.linalg.norm(b, axis=1) - L) / L))

    def energy():
        ke = 0.5 * float(np.sum(net.node_mass[free][:, None] * data.qvel.reshape(-1, 3) ** 2))
        x = positions()
        s = np.linalg.norm(x[net.cables[:, 1]] - x[net.cables[:, 0]], axis=1)
        st = np.maximum(s - net.cable_rest_length, 0.0)
        return ke + 0.5 * float(np.sum(net.cable_EA / net.cable_rest_length * st * st)), ke

    strain = [strain_and_bars()[0]]
    times = [0.0]
    E0, KE0 = energy()
    bar_err = 0.0
    e_dev = 0.0
    t0 = time.perf_counter()
    wall_steps = 0.0
    for k in range(1, n_out + 1):
        ts = time.perf_counter()
        mujoco.mj_step(model, data, nstep=every)
        wall_steps += time.perf_counter() - ts
        s, be = strain_and_bars()
        strain.append(s)
        times.append(k * every * timestep)
        bar_err = max(bar_err, be)
        e_dev = max(e_dev, abs(energy()[0] - E0))
        if not np.all(np.isfinite(s)):
            break
    wall = time.perf_counter() - t0
    return {
        "time": np.array(times), "strain": np.array(strain), "wall_s": wall, "wall_stepping_s": wall_steps,
        "steps": (len(times) - 1) * every, "bar_err": bar_err, "energy_error": e_dev / KE0,
        "nv": int(model.nv), "neq": int(model.neq), "ntendon": int(model.ntendon),
        "mujoco_version": mujoco.__version__,
    }


def run_mjwarp(scene, topo, timestep, nworld, device, t_end=None, output_interval=0.005, target_s=0.3,
               timeconst_factor=2.0, integrator="Euler"):
    """MuJoCo Warp (batched, GPU): ``nworld`` copies of the column. Returns throughput (graph
    replay of a block of steps, timed like benchmarks.throughput) and, if ``t_end`` is given,
    the strain history of world 0 (for the pulse)."""
    import mujoco
    import mujoco_warp as mjw
    import warp as wp

    model = mujoco.MjModel.from_xml_string(mjcf(scene, timestep, timeconst_factor * timestep, integrator))
    data = mujoco.MjData(model)
    net = scene.network
    free = np.flatnonzero(~net.fixed)
    data.qvel[:] = scene.velocity[free].reshape(-1)
    mujoco.mj_forward(model, data)
    out = {"nworld": int(nworld), "timestep": timestep, "device": str(device)}
    with wp.ScopedDevice(device):
        t0 = time.perf_counter()
        m = mjw.put_model(model)
        d = mjw.put_data(model, data, nworld=nworld)
        mjw.step(m, d)  # compile + first step
        wp.synchronize_device(device)
        out["compile_s"] = time.perf_counter() - t0
        every = max(1, round(output_interval / timestep))
        dev = wp.get_device(device)
        graph = None
        if dev.is_cuda:
            with wp.ScopedCapture(device=dev) as cap:
                for _ in range(every):
                    mjw.step(m, d)
            graph = cap.graph

        def block():
            if graph is not None:
                wp.capture_launch(graph)
            else:
                for _ in range(every):
                    mjw.step(m, d)

        if t_end is not None:
            # pulse run from the initial state (world 0)
            d = mjw.put_data(model, data, nworld=nworld)
            if dev.is_cuda:
                with wp.ScopedCapture(device=dev) as cap:
                    for _ in range(every):
                        mjw.step(m, d)
                graph = cap.graph
            X = net.positions
            levels = topo.level_nodes
            h0 = np.diff(X[levels, 2].mean(axis=1))
            strain, times = [], []
            n_out = int(math.floor(t_end / (every * timestep) + 1e-9))
            for k in range(n_out + 1):
                if k:
                    block()
                q = d.qpos.numpy()[0]
                x = X.copy()
                x[free] += q.reshape(-1, 3)
                h = np.diff(x[levels, 2].mean(axis=1))
                strain.append((h - h0) / h)
                times.append(k * every * timestep)
            out["time"] = np.array(times)
            out["strain"] = np.array(strain)
        # throughput
        block()
        wp.synchronize_device(device)
        tp = time.perf_counter()
        block()
        wp.synchronize_device(device)
        per_block = time.perf_counter() - tp
        n_blocks = max(1, int(round(target_s / max(per_block, 1e-9))))
        tp = time.perf_counter()
        for _ in range(n_blocks):
            block()
        wp.synchronize_device(device)
        wall = time.perf_counter() - tp
        out["steps"] = n_blocks * every
        out["wall_s"] = wall
        out["world_steps_per_s"] = nworld * n_blocks * every / wall
    return out


def mjwarp_main(a, cfg, topo, doc):
    """--mjwarp-device: batched MuJoCo Warp, pulse (world 0) and world-steps/s against nworld."""
    import warp as wp

    from warp_tensegrity import RunSettings, build_column, simulate_batch
    from warp_tensegrity.measure import measure_pulse

    doc["mjwarp"] = []
    for base in a.bases:
        p, v0, t_end = CASES[base]
        beta = 0.0 if base == "FB" else 1.0
        scene = build_column(cfg, prestrain=p, v0=v0, base_rigidity=beta, topology=topo)
        s = RunSettings(t_end=t_end, output_interval=a.output_interval, precision="fp64", device=a.mjwarp_device)  # the reference pulse from our engine, on the same device
        r = simulate_batch(cfg, {"prestrain": [p], "v0": [v0], "base_rigidity": [beta]}, s)
        me = measure_pulse(r.strain[0], r.time, cfg.height)
        for hs in a.timesteps:
            h = r.dt if hs == "engine" else float(hs)
            for i, nw in enumerate(a.mjwarp_batches):
                t0 = time.perf_counter()
                try:
                    o = run_mjwarp(scene, topo, h, nw, a.mjwarp_device, t_end=t_end if i == 0 else None,
                                   output_interval=a.output_interval, timeconst_factor=a.tcf,
                                   integrator=a.integrator)
                except Exception as exc:  # noqa: BLE001
                    doc["mjwarp"].append({"base": base, "timestep": h, "nworld": nw, "error": repr(exc)})
                    print(f"  mjwarp {base} dt={h:g} nworld={nw}: ERROR {exc!r}", flush=True)
                    continue
                row = {"base": base, "prestrain": p, "v0": v0, "timestep": h, "nworld": nw,
                       "compile_s": o["compile_s"], "steps": o["steps"], "wall_s": o["wall_s"],
                       "world_steps_per_s": o["world_steps_per_s"],
                       "engine_column_steps_per_s_equiv": o["world_steps_per_s"] * h / r.dt,
                       "engine_dt": r.dt, "total_s": time.perf_counter() - t0}
                if "strain" in o:
                    k = min(len(o["time"]), len(r.time))
                    mm = measure_pulse(o["strain"][:k], o["time"][:k], cfg.height)
                    row.update(speed=float(mm["speed"]), amplitude=float(mm["amplitude"]),
                               speed_rel_diff=float(mm["speed"]) / float(me["speed"]) - 1.0,
                               amplitude_rel_diff=float(mm["amplitude"]) / float(me["amplitude"]) - 1.0)
                doc["mjwarp"].append(row)
                extra = ""
                if "speed" in row:
                    extra = (f" speed {row['speed']:.4g} ({100 * row['speed_rel_diff']:+.1f}%), amplitude "
                             f"{row['amplitude']:.4g} ({100 * row['amplitude_rel_diff']:+.1f}%);")
                print(f"  mjwarp {base} dt={h:g} nworld={nw}:{extra} {row['world_steps_per_s']:.3g} world-steps/s = "
                      f"{row['engine_column_steps_per_s_equiv']:.3g} column-steps/s equivalent "
                      f"(compile {o['compile_s']:.1f} s)", flush=True)
                common.write_json(a.out, doc)
    wp.synchronize()


def summary_markdown(doc) -> str:
    lines = [f"MuJoCo {next((m.get('mujoco_version') for c in doc['cases'] for m in c['mujoco'] if m.get('mujoco_version')), '?')}"
             f" ({doc['integrator']} integrator, bar constraint time constant = {doc['timeconst_factor']:g} x timestep), "
             f"{doc['n_prisms']}-prism column, one column on the CPU; engine = RATTLE fp64 on the CPU (B = 1). "
             "Column-steps/s equivalent = simulated time / engine dt per wall second.", "",
             "| case | run | dt [s] | speed [m/s] | amplitude | bar err | energy err | wall [s] | col-steps/s equiv |",
             "|---|---|---:|---:|---:|---:|---:|---:|---:|"]
    for c in doc["cases"]:
        e = c["engine"]
        tag = f"{c['base']} p={c['prestrain']} v0={c['v0']}"
        lines.append(f"| {tag} | engine | {e['dt']:.3g} | {e['speed']:.4g} | {e['amplitude']:.4g} | {e['bar_err']:.1e} | "
                     f"{e['energy_error']:.1e} | {e['wall_stepping_s']:.2f} | {e['steps'] / e['wall_stepping_s']:.3g} |")
        for m in c["mujoco"]:
            if m.get("error"):
                lines.append(f"| {tag} | MuJoCo | {m['timestep']:.3g} | error: {m['error']} | | | | | |")
                continue
            lines.append(f"| {tag} | MuJoCo | {m['timestep']:.3g} | {m['speed']:.4g} ({100 * m['speed_rel_diff']:+.1f}%) | "
                         f"{m['amplitude']:.4g} ({100 * m['amplitude_rel_diff']:+.1f}%) | {m['bar_err']:.1e} | "
                         f"{m['energy_error']:.1e} | {m['wall_stepping_s']:.2f} | {m['engine_column_steps_per_s_equiv']:.3g} |")
    if doc.get("mjwarp"):
        lines += ["", f"MuJoCo Warp {doc.get('mujoco_warp_version') or ''} on {doc.get('mjwarp_meta', {}).get('device_name')}"
                  " (fp32, batched worlds, graph replay):", "",
                  "| case | dt [s] | nworld | speed (world 0) | amplitude | world-steps/s | col-steps/s equiv |",
                  "|---|---:|---:|---:|---:|---:|---:|"]
        for m in doc["mjwarp"]:
            if m.get("error"):
                lines.append(f"| {m['base']} | {m['timestep']:.3g} | {m['nworld']} | error: {m['error']} | | | |")
                continue
            sp = f"{m['speed']:.4g} ({100 * m['speed_rel_diff']:+.1f}%)" if "speed" in m else "-"
            am = f"{m['amplitude']:.4g} ({100 * m['amplitude_rel_diff']:+.1f}%)" if "amplitude" in m else "-"
            lines.append(f"| {m['base']} | {m['timestep']:.3g} | {m['nworld']} | {sp} | {am} | "
                         f"{m['world_steps_per_s']:.3g} | {m['engine_column_steps_per_s_equiv']:.3g} |")
    return "\n".join(lines)


def main(argv=None):
    ap = argparse.ArgumentParser(description="MuJoCo peer: same column, pulse speed/amplitude and cost")
    ap.add_argument("--n-prisms", dest="n_prisms", type=int, default=50)
    ap.add_argument("--bases", nargs="+", default=["FB", "RB"], choices=["FB", "RB"])
    ap.add_argument("--timesteps", nargs="+", default=["engine", "5e-4", "1e-4"],
                    help="MuJoCo timesteps [s]; 'engine' = the engine's default dt of the case")
    ap.add_argument("--timeconst-factor", dest="tcf", type=float, default=2.0,
                    help="bar constraint time constant / timestep (MuJoCo's minimum is 2)")
    ap.add_argument("--integrator", default="Euler", choices=["Euler", "RK4", "implicit", "implicitfast"])
    ap.add_argument("--output-interval", dest="output_interval", type=float, default=0.005)
    ap.add_argument("--out", default=str(common.RESULTS / "peer_mujoco_cpu.json"))
    ap.add_argument("--mjwarp-device", dest="mjwarp_device", default=None,
                    help="also (or with --mjwarp-only, only) run MuJoCo Warp batched on this Warp device")
    ap.add_argument("--mjwarp-batches", dest="mjwarp_batches", type=int, nargs="+", default=[1, 1024, 8192])
    ap.add_argument("--mjwarp-only", dest="mjwarp_only", action="store_true")
    a = ap.parse_args(argv)
    try:
        import mujoco  # noqa: F401
    except ImportError:
        print("[peer_mujoco] mujoco is not installed (pip install --no-deps mujoco mujoco-core); nothing to do")
        return 0
    import warp as wp

    wp.config.quiet = True
    wp.config.log_level = wp.LOG_WARNING
    wp.init()
    from warp_tensegrity import ColumnConfig, RunSettings, build_column, column_topology, simulate_batch
    from warp_tensegrity.measure import measure_pulse

    cfg = ColumnConfig(n_prisms=a.n_prisms)
    topo = column_topology(cfg)
    doc = {"kind": "peer_mujoco", "meta": common.run_metadata(wp.get_device("cpu")), "n_prisms": a.n_prisms,
           "integrator": a.integrator, "timeconst_factor": a.tcf, "cases": []}
    if a.mjwarp_device:
        doc["mjwarp_meta"] = common.run_metadata(wp.get_device(a.mjwarp_device))
        try:
            import mujoco_warp

            doc["mujoco_warp_version"] = getattr(mujoco_warp, "__version__", None)
        except ImportError:
            print("[peer_mujoco] mujoco_warp is not installed; skipping the batched run")
            a.mjwarp_device = None
    for base in ([] if a.mjwarp_only else a.bases):
        p, v0, t_end = CASES[base]
        beta = 0.0 if base == "FB" else 1.0
        scene = build_column(cfg, prestrain=p, v0=v0, base_rigidity=beta, topology=topo)
        s = RunSettings(t_end=t_end, output_interval=a.output_interval, precision="fp64", device="cpu")
        r = simulate_batch(cfg, {"prestrain": [p], "v0": [v0], "base_rigidity": [beta]}, s)
        me = measure_pulse(r.strain[0], r.time, cfg.height)
        case = {"base": base, "prestrain": p, "v0": v0, "t_end": t_end,
                "engine": {"dt": r.dt, "steps": r.n_steps, "wall_stepping_s": r.wall_time,
                           "speed": float(me["speed"]), "amplitude": float(me["amplitude"]),
                           "energy_error": float(r.energy_error[0]), "bar_err": float(r.bar_length_error[0])},
                "mujoco": []}
        print(f"[peer_mujoco] {a.n_prisms} prisms {base} p={p} v0={v0}: engine RATTLE fp64 dt={r.dt:.3g} s: speed "
              f"{case['engine']['speed']:.4g} m/s, amplitude {case['engine']['amplitude']:.4g}, "
              f"{r.wall_time:.2f} s for {r.n_steps} steps (CPU, B=1)", flush=True)
        for hs in a.timesteps:
            h = r.dt if hs == "engine" else float(hs)
            try:
                mj = run_mujoco(scene, topo, t_end, h, a.output_interval, a.tcf, a.integrator)
            except Exception as exc:  # noqa: BLE001
                case["mujoco"].append({"timestep": h, "error": repr(exc)})
                print(f"  mujoco dt={h:g}: ERROR {exc!r}", flush=True)
                continue
            k = min(len(mj["time"]), len(r.time))
            mm = measure_pulse(mj["strain"][:k], mj["time"][:k], cfg.height)
            sim = mj["time"][-1]
            row = {"timestep": h, "timeconst": a.tcf * h, "steps": mj["steps"], "wall_s": mj["wall_s"],
                   "wall_stepping_s": mj["wall_stepping_s"], "speed": float(mm["speed"]),
                   "amplitude": float(mm["amplitude"]), "bar_err": mj["bar_err"], "energy_error": mj["energy_error"],
                   "nv": mj["nv"], "neq": mj["neq"], "ntendon": mj["ntendon"],
                   "sim_seconds_per_wall_second": sim / mj["wall_stepping_s"],
                   "engine_column_steps_per_s_equiv": sim / r.dt / mj["wall_stepping_s"],
                   "speed_rel_diff": float(mm["speed"]) / case["engine"]["speed"] - 1.0,
                   "amplitude_rel_diff": float(mm["amplitude"]) / case["engine"]["amplitude"] - 1.0,
                   "mujoco_version": mj["mujoco_version"]}
            case["mujoco"].append(row)
            print(f"  mujoco {a.integrator} dt={h:g} (bar timeconst {a.tcf * h:g} s): speed {row['speed']:.4g} m/s "
                  f"({100 * row['speed_rel_diff']:+.1f}%), amplitude {row['amplitude']:.4g} "
                  f"({100 * row['amplitude_rel_diff']:+.1f}%), bar err {row['bar_err']:.1e}, energy err "
                  f"{row['energy_error']:.1e}; {mj['wall_stepping_s']:.2f} s for {mj['steps']} steps = "
                  f"{row['engine_column_steps_per_s_equiv']:.3g} column-steps/s equivalent", flush=True)
        doc["cases"].append(case)
        doc["summary_markdown"] = summary_markdown(doc)
        common.write_json(a.out, doc)
    if a.mjwarp_device:
        mjwarp_main(a, cfg, topo, doc)
        doc["summary_markdown"] = summary_markdown(doc)
        common.write_json(a.out, doc)
    print(f"[peer_mujoco] wrote {a.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
