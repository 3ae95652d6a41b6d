"""Bar contact (issue 32 item 3): what it changes, and its checks. Numbers quoted in docs/contact.md
come from this script; it writes analysis/data/contact.json and docs/figures/contact_*.png.

A. The pulse with and without contact: the paper's RB column (50 prisms, p = 0.002, the default
   rigid_members impact, fp64), v0 = 0.05, 0.1, 0.15, 0.2 m/s, bar radius 0.25 mm, restitution 1,
   t_end = 1.2 s: amplitude, speed, FWHM (the engine's measures), the energy the leading pulse
   carries when its peak passes mid-column, impacts. Strain snapshots for the figure.
B. The checks, as tests/kernels/test_contact.py makes them, on a wider range: 30 RB prisms,
   v0 = 0.05..0.2: energy error with and without contact at dt and dt/2; the device's smallest axis
   distance over 2 r for RB and FB pulses; without contact, the reduced chain's smallest signed
   axis distance (the bars cross); engine against the reduced twist chain by dt.
C. The paper's rigid-base cases that leave the feasible set (Fig. 7: RB, p = 0.002, v0 = 0.1,
   0.125, 0.15, its end_twist impact, 50 prisms): the measures with contact at r = 0.1 and 0.25 mm.
D. Flexible bases: the smallest prism height with and without bar contact (50 prisms, v0 = 0.1,
   0.15, 0.2, p = 0, 0.002, 0.01, t_end = 0.4 s), and a single prism at v0 up to 2 m/s.

    python analysis/contact.py          # all parts, ~10 min on 2 CPU cores
    python analysis/contact.py A        # only these parts (merged into the JSON)
"""

from __future__ import annotations

import json
import math
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from warp_tensegrity import ColumnConfig, RunSettings, simulate_batch  # noqa: E402
from warp_tensegrity.scene.batch import column_batch  # noqa: E402
from warp_tensegrity.scene.columns import column_topology  # noqa: E402
from warp_tensegrity.scene.contact import contact_strain, contact_twist, regular_gap  # noqa: E402
from warp_tensegrity.scene.impact import kinematic_lock_strain  # noqa: E402
from warp_tensegrity.validation.twist_chain import TwistChain  # noqa: E402

DATA = ROOT / "analysis" / "data" / "contact.json"
FIGS = ROOT / "docs" / "figures"
R = 0.25e-3
PAPER = ColumnConfig(n_prisms=50)
V0 = [0.05, 0.1, 0.15, 0.2]


def _settings(t_end, **kw):
    kw.setdefault("output_interval", 0.002)
    return RunSettings(t_end=t_end, fused=False, device="cpu", truncate=False, **kw)


def _pulse_energy(cfg, params, result, b, t_index):
    """Energy [J] above the reference in the leading pulse of column b at the final state: the
    prisms whose compression is >= 5 % of the snapshot's largest, contiguous around it, their
    cables' elastic energy and the kinetic energy of their levels."""
    topo = column_topology(cfg)
    one = {k: np.atleast_1d(v)[b:b + 1] if np.ndim(v) else v for k, v in params.items()}
    batch = column_batch(cfg, one)
    x = topo.positions + result.final_displacement[b]
    v = result.final_velocity[b]
    c, L, EA = batch.cables, batch.cable_rest_length[0], batch.cable_EA[0]
    EAc = batch.cable_EA_compression[0]
    s = np.linalg.norm(x[c[:, 1]] - x[c[:, 0]], axis=1)
    s0 = np.linalg.norm(topo.positions[c[:, 1]] - topo.positions[c[:, 0]], axis=1)
    k = lambda st: np.where(st > 0, EA, EAc) / L  # noqa: E731
    pe = 0.5 * k(s - L) * (s - L) ** 2 - 0.5 * k(s0 - L) * (s0 - L) ** 2
    level = topo.positions[:, 2].round(12)
    lvl_of = lambda n: np.searchsorted(np.unique(level), level[n])  # noqa: E731
    pe_prism = np.zeros(cfg.n_prisms + 1)
    np.add.at(pe_prism, np.minimum(lvl_of(c[:, 0]), lvl_of(c[:, 1])).clip(max=cfg.n_prisms), pe)
    m = batch.node_mass[0]
    ke_level = np.zeros(cfg.n_prisms + 1)
    np.add.at(ke_level, lvl_of(np.arange(len(m))), 0.5 * m * (v**2).sum(axis=1))
    strain = result.strain[b, t_index]
    q = -strain
    j = int(np.argmax(q))
    lo = hi = j
    while lo > 0 and q[lo - 1] >= 0.05 * q[j]:
        lo -= 1
    while hi < cfg.n_prisms - 1 and q[hi + 1] >= 0.05 * q[j]:
        hi += 1
    return float(pe_prism[lo:hi + 1].sum() + ke_level[lo:hi + 2].sum()), (lo, hi)


def part_a():
    out, t_end = {"bar_radius": R, "v0": V0, "t_end": 1.2}, 1.2
    params = {"prestrain": 0.002, "v0": np.array(V0), "base_rigidity": 1.0}
    runs = {}
    for name, cfg in (("none", PAPER), ("bars", replace(PAPER, contact="bars", bar_radius=R))):
        t0 = time.perf_counter()
        r = simulate_batch(cfg, params, _settings(t_end))
        runs[name] = r
        m = r.measurements
        row = {k: [float(x) for x in m[k]] for k in ("amplitude", "speed", "width_fwhm")}
        row["energy_error"] = r.energy_error.tolist()
        row["ke0"] = r.kinetic_energy[:, 0].tolist()
        row["largest_compression"] = (-np.nanmin(r.strain, axis=(1, 2))).tolist()
        if "contact" in r.info:
            row["impacts"] = r.info["contact"]["impacts"].tolist()
        # the energy in the leading pulse when its peak passes mid-column (prism 25)
        t_mid = np.asarray(m["peak_time"])[:, 25]
        carried = []
        for b in range(len(V0)):
            if not np.isfinite(t_mid[b]):
                carried.append(float("nan"))
                continue
            rb = simulate_batch(cfg, {k: (v[b:b + 1] if np.ndim(v) else v) for k, v in params.items()},
                                _settings(float(t_mid[b]), output_interval=float(t_mid[b]) / 50))
            e, _ = _pulse_energy(cfg, {k: (v[b:b + 1] if np.ndim(v) else v) for k, v in params.items()}, rb, 0, -1)
            carried.append(e / float(rb.kinetic_energy[0, 0]))
        row["pulse_energy_fraction_mid"] = carried
        row["t_mid"] = t_mid.tolist()
        row["wall_s"] = time.perf_counter() - t0
        out[name] = row
        print(name, {k: np.round(v, 4).tolist() for k, v in row.items() if k not in ("ke0",)}, flush=True)
    out["contact_strain"] = contact_strain(PAPER.radius, PAPER.height, PAPER.twist, R)
    out["lock_strain"] = kinematic_lock_strain(PAPER.radius, PAPER.height, PAPER.twist)
    out["contact_twist_deg"] = math.degrees(contact_twist(PAPER.radius, PAPER.height, PAPER.twist, R))
    _figure_pulse(runs, out)
    return out


def _figure_pulse(runs, out):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 4, figsize=(17, 4), layout="constrained")
    t = runs["none"].time
    b = 1  # v0 = 0.1
    for ax, name, title in ((axes[0], "none", "no contact"), (axes[1], "bars", "contact (r = 0.25 mm, e = 1)")):
        im = ax.imshow(-runs[name].strain[b].T, aspect="auto", origin="lower", cmap="magma_r", vmin=0, vmax=0.1,
                       extent=(t[0], t[-1], -0.5, PAPER.n_prisms - 0.5))
        ax.set_xlabel("t [s]")
        ax.set_ylabel("prism (0: clamped end)")
        ax.set_title(f"RB, v0 = {V0[b]} m/s, {title}", fontsize=9)
        ax.set_xlim(0, 1.0)
    fig.colorbar(im, ax=axes[1], label="compression")
    ax = axes[2]
    for j, col in ((45, "C0"), (30, "C1")):
        ax.plot(t, runs["none"].strain[b, :, j], "--", color=col, lw=1, label=f"prism {j}, no contact")
        ax.plot(t, runs["bars"].strain[b, :, j], "-", color=col, lw=1.2, label=f"prism {j}, contact")
    ax.axhline(out["lock_strain"], color="k", lw=0.6, ls=":")
    ax.axhline(out["contact_strain"], color="r", lw=0.6, ls=":")
    ax.set_xlim(0, 1.0)
    ax.set_xlabel("t [s]")
    ax.set_ylabel("strain (h - h0)/h")
    ax.set_title("strain; dotted: at twist pi and at contact", fontsize=9)
    ax.legend(fontsize=6, loc="lower right")
    # the twist of prism 40 in the reduced chain, with and without the stop
    chain = TwistChain(PAPER, 0.002, bar_radius=R)
    free = TwistChain(PAPER, 0.002)
    times = np.linspace(0, 0.4, 801)
    ax = axes[3]
    for v0, ls in ((0.1, "-"), (0.2, "--")):
        ax.plot(times, np.degrees(chain.simulate(v0, 0.4, times).twist[:, 40]), "r" + ls, lw=1.2,
                label=f"contact, v0 = {v0}")
        ax.plot(times, np.degrees(free.simulate(v0, 0.4, times).twist[:, 40]), "k" + ls, lw=1,
                label=f"no contact, v0 = {v0}")
    ax.axhline(180, color="k", lw=0.5, ls=":")
    ax.axhline(out["contact_twist_deg"], color="r", lw=0.5, ls=":")
    ax.set_xlabel("t [s]")
    ax.set_ylabel("twist of prism 40 [deg]")
    ax.set_title("reduced twist chain: the stop at 171.2 deg", fontsize=9)
    ax.legend(fontsize=6)
    FIGS.mkdir(parents=True, exist_ok=True)
    fig.savefig(FIGS / "contact_pulse.png", dpi=110)
    plt.close(fig)


def part_b():
    cfg0 = ColumnConfig(n_prisms=30)
    cfg1 = replace(cfg0, contact="bars", bar_radius=R)
    v0 = [0.05, 0.1, 0.15, 0.2]
    dt = 0.002 / 3
    out = {"n_prisms": 30, "v0": v0, "dt": dt}
    rb = {"prestrain": 0.002, "v0": v0, "base_rigidity": 1.0}
    for f in (1, 2):
        for name, cfg in (("none", cfg0), ("bars", cfg1)):
            r = simulate_batch(cfg, rb, _settings(0.3, dt=dt / f))
            out[f"energy_error_{name}_dt/{f}"] = r.energy_error.tolist()
            if name == "bars":
                out[f"min_distance_over_2r_RB_dt/{f}"] = (r.info["contact"]["min_distance"] / (2 * R)).tolist()
                out[f"impacts_RB_dt/{f}"] = r.info["contact"]["impacts"].tolist()
    fb = simulate_batch(cfg1, {"prestrain": 0.002, "v0": v0, "base_rigidity": 0.0}, _settings(0.3, dt=dt / 2))
    out["min_distance_over_2r_FB"] = (fb.info["contact"]["min_distance"] / (2 * R)).tolist()
    # without contact: the reduced chain's smallest signed axis distance (the bars cross past pi)
    L = math.sqrt(cfg0.height**2 + 2 * cfg0.radius**2 * (1 - math.cos(cfg0.twist)))
    free = TwistChain(cfg0, 0.002)
    dmin = []
    for v in v0:
        phi = free.simulate(v, 0.3).twist.max()
        dmin.append(math.copysign(regular_gap(cfg0.radius, L, phi), math.pi - phi) / (2 * R))
    out["min_signed_distance_over_2r_no_contact_RB"] = dmin
    # engine against the reduced chain, by dt (t <= 0.15 s)
    chain = TwistChain(cfg0, 0.002, bar_radius=R)
    agree = {}
    for f in (1, 2, 4, 8):
        r = simulate_batch(cfg1, {"prestrain": 0.002, "v0": [0.1, 0.2], "base_rigidity": 1.0},
                           _settings(0.15, dt=dt / f))
        row = []
        for b, v in enumerate((0.1, 0.2)):
            ref = chain.simulate(v, 0.15, times=r.time)
            row.append(float(np.abs(r.strain[b] - ref.strain).max() / np.abs(ref.strain).max()))
        agree[f"dt/{f}"] = row
        print("agreement", f, row, flush=True)
    out["reduced_model_max_diff_over_peak_v0_0.1_0.2"] = agree
    print({k: np.round(v, 6).tolist() if isinstance(v, list) else v for k, v in out.items()}, flush=True)
    _figure_checks(out)
    return out


def _figure_checks(out):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    v0 = out["v0"]
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.6))
    ax = axes[0]
    for f, mk in ((1, "o"), (2, "s")):
        ax.semilogy(v0, out[f"energy_error_none_dt/{f}"], "k" + mk + "--", label=f"no contact, dt/{f}")
        ax.semilogy(v0, out[f"energy_error_bars_dt/{f}"], "r" + mk + "-", label=f"contact e = 1, dt/{f}")
    ax.set_xlabel("v0 [m/s]")
    ax.set_ylabel("energy_error")
    ax.set_title(f"RB, 30 prisms, p = 0.002, t <= 0.3 s (dt = {out['dt'] * 1e3:.3g} ms)", fontsize=8)
    ax.legend(fontsize=7)
    ax = axes[1]
    ax.plot(v0, out["min_distance_over_2r_RB_dt/1"], "ro-", ms=8, label="RB, contact (device record)")
    ax.plot(v0, out["min_distance_over_2r_FB"], "bs--", ms=4, label="FB, contact (device record)")
    ax.plot(v0, out["min_signed_distance_over_2r_no_contact_RB"], "k^--", label="RB, no contact (reduced chain)")
    ax.axhline(1, color="k", lw=0.6, ls=":")
    ax.set_xlabel("v0 [m/s]")
    ax.set_ylabel("smallest axis distance / 2r")
    ax.set_title("bars: smallest distance over the run", fontsize=8)
    ax.legend(fontsize=7)
    ax = axes[2]
    fs = [1, 2, 4, 8]
    a = np.array([out["reduced_model_max_diff_over_peak_v0_0.1_0.2"][f"dt/{f}"] for f in fs])
    dts = [out["dt"] / f * 1e3 for f in fs]
    ax.loglog(dts, a[:, 0], "ro-", label="v0 = 0.1")
    ax.loglog(dts, a[:, 1], "bs-", label="v0 = 0.2")
    ax.loglog(dts, a[0, 1] * (np.array(dts) / dts[0]) ** 2, "k:", lw=0.8, label="dt^2")
    ax.set_xticks(dts, [f"{d:.3g}" for d in dts])
    ax.minorticks_off()
    ax.set_xlabel("dt [ms]")
    ax.set_ylabel("max |strain - chain| / peak")
    ax.set_title("engine vs reduced twist chain, t <= 0.15 s", fontsize=8)
    ax.legend(fontsize=7)
    fig.tight_layout()
    FIGS.mkdir(parents=True, exist_ok=True)
    fig.savefig(FIGS / "contact_checks.png", dpi=110)
    plt.close(fig)


def part_c():
    cfg = replace(PAPER, impact_admissibility="end_twist")
    v0 = [0.1, 0.125, 0.15]
    params = {"prestrain": 0.002, "v0": v0, "base_rigidity": 1.0}
    out = {"v0": v0, "t_end": 1.2}
    for name, c in (("none", cfg), ("r=0.1mm", replace(cfg, contact="bars", bar_radius=0.1e-3)),
                    ("r=0.25mm", replace(cfg, contact="bars", bar_radius=0.25e-3))):
        r = simulate_batch(c, params, _settings(1.2))
        m = r.measurements
        out[name] = {k: [float(x) for x in m[k]] for k in ("amplitude", "speed", "width_fwhm")}
        out[name]["energy_error"] = r.energy_error.tolist()
        if "contact" in r.info:
            out[name]["impacts"] = r.info["contact"]["impacts"].tolist()
            out[name]["contact_strain"] = contact_strain(c.radius, c.height, c.twist, c.bar_radius)
        print(name, out[name], flush=True)
    return out


def part_d():
    out = {}
    cfg0 = PAPER
    cfg1 = replace(PAPER, contact="bars", bar_radius=R)
    rows = []
    for p in (0.0, 0.002, 0.01):
        params = {"prestrain": p, "v0": [0.1, 0.15, 0.2], "base_rigidity": 0.0}
        for name, cfg in (("none", cfg0), ("bars", cfg1)):
            r = simulate_batch(cfg, params, _settings(0.4, output_interval=0.001))
            h = cfg.height / (1.0 - r.strain)  # strain = (h - h0)/h; h <= 0 shows as strain >= 1 or < -h0/eps
            rows.append({"prestrain": p, "contact": name, "v0": [0.1, 0.15, 0.2],
                         "min_height_mm": (np.nanmin(h, axis=(1, 2)) * 1e3).tolist(),
                         "inverted_samples": np.sum(h <= 0, axis=(1, 2)).tolist(),
                         "status": r.status.tolist()})
            print(rows[-1], flush=True)
    out["fb_columns"] = rows
    one = ColumnConfig(n_prisms=1)
    single = []
    for name, cfg in (("none", one), ("bars", replace(one, contact="bars", bar_radius=R))):
        r = simulate_batch(cfg, {"prestrain": 0.002, "v0": [0.2, 0.5, 1.0, 2.0], "base_rigidity": 0.0},
                           _settings(0.05, output_interval=0.00025))
        h = one.height / (1.0 - r.strain)
        single.append({"contact": name, "v0": [0.2, 0.5, 1.0, 2.0], "min_height_mm": (np.nanmin(h, axis=(1, 2)) * 1e3).tolist(),
                       "inverted_samples": np.sum(h <= 0, axis=(1, 2)).tolist()})
        print(single[-1], flush=True)
    out["single_prism_fb"] = single
    return out


PARTS = {"A": part_a, "B": part_b, "C": part_c, "D": part_d}


def main(argv):
    if argv == ["plot"]:  # redraw the checks' figure from the JSON
        _figure_checks(json.loads(DATA.read_text())["B"])
        return
    names = argv or list(PARTS)
    data = json.loads(DATA.read_text()) if DATA.exists() else {}
    for n in names:
        t0 = time.perf_counter()
        data[n] = PARTS[n]()
        data[n]["seconds"] = time.perf_counter() - t0
        DATA.parent.mkdir(parents=True, exist_ok=True)
        tmp = DATA.with_suffix(".tmp")
        tmp.write_text(json.dumps(data, indent=1))
        tmp.replace(DATA)
    print(f"wrote {DATA}")


if __name__ == "__main__":
    main(sys.argv[1:])
