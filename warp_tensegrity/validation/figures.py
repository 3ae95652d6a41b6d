"""One figure per validation check (:mod:`.checks`), drawn with matplotlib.

Each ``figure_*`` takes the :class:`~warp_tensegrity.validation.checks.CheckGroup` its check
returned and returns a Figure (``figure_fb_modal``: a list, one per impact); :data:`FIGURES` maps a
group's name to its function.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..atomic import replacing
from ..plot import PRISM_LABEL, dispersion

__all__ = ["FIGURES", "write_figures", "figure_bessel", "figure_soliton", "figure_dispersion", "figure_fb_modal",
           "figure_interface", "figure_diatomic", "figure_preload"]


def _figure(ncols: int, width: float = 10.0, height: float = 4.0, nrows: int = 1):
    import matplotlib.pyplot as plt

    return plt.subplots(nrows, ncols, figsize=(width, height), layout="constrained", squeeze=False)


def _stamp(ax, check, x: float = 0.02, y: float = 0.98):
    ax.text(x, y, f"{check.name}: {check.error:.2e} (tolerance {check.tolerance:g})", transform=ax.transAxes,
            va="top" if y > 0.5 else "bottom", ha="left" if x < 0.5 else "right", fontsize=8,
            bbox={"fc": "w", "ec": "0.8", "alpha": 0.9})


def _record_vs_reference(g, ref_key: str, ref_label: str, prisms):
    """Histories of a few prisms (engine solid, reference dashed) and the error map."""
    from matplotlib import colors

    t, eng, ref = g.data["time"], g.data["engine"], g.data[ref_key]
    peak = float(np.abs(ref).max())
    fig, axes = _figure(2)
    ax0, ax1 = axes[0]
    n = eng.shape[1]
    for i, j in enumerate(prisms):
        ax0.plot(t, -eng[:, j] / peak, color=f"C{i}", lw=1.4, label=f"engine, prism {n - 1 - j} from the struck end")
        ax0.plot(t, -ref[:, j] / peak, "k--", lw=0.8, label=ref_label if i == 0 else None)
    ax0.set_xlabel("time t [s]")
    ax0.set_ylabel("compression / reference peak [-]")
    ax0.legend(fontsize=7, loc="lower right")
    _stamp(ax0, g.checks[0])
    err = (eng - ref) / peak
    v = max(float(np.abs(err).max()), 1e-12)
    mesh = ax1.pcolormesh(np.arange(n), t, err, cmap="RdBu_r", shading="nearest", rasterized=True,
                          norm=colors.TwoSlopeNorm(vcenter=0.0, vmin=-v, vmax=v))
    cb = fig.colorbar(mesh, ax=ax1, pad=0.01)
    cb.set_label("(engine - reference) / reference peak [-]")
    cb.formatter.set_powerlimits((-2, 2))
    ax1.set_xlabel(PRISM_LABEL)
    ax1.set_ylabel("time t [s]")
    return fig


def figure_bessel(g):
    n = g.data["engine"].shape[1]
    fig = _record_vs_reference(g, "bessel", "Bessel form (v0/c0) J_2n+1(omega_c t), images", [n - 1, n - 4, n - 7, n - 10])
    fig.suptitle("RB, p = 0.002: the engine's strain against the linear chain's Bessel form", fontsize=10)
    return fig


def figure_fb_modal(g):
    n = g.data["engine"].shape[1]
    fig = _record_vs_reference(g, "modal", "modal sum (validation.linear)", [n - 1, n // 2, 0])
    fig.suptitle("FB, p = 0.002, 'rigid_members' impact: the engine's strain against the modal sum", fontsize=10)
    if "engine_end_twist" not in g.data:
        return [fig]
    twist = _SecondRecord(g, "_end_twist", 1)
    fig2 = _record_vs_reference(twist, "modal", "modal sum (validation.linear)", [n - 1, n - 2, n // 2])
    fig2.suptitle("FB, p = 0.002, 'end_twist' impact (the bases breathe): the engine's strain against the modal sum",
                  fontsize=10)
    return [fig, fig2]


class _SecondRecord:
    """A group's second record (``data`` keys ending in ``suffix``) and its check, as _record_vs_reference reads them."""

    def __init__(self, g, suffix: str, check: int):
        self.data = {k: g.data[k + suffix] for k in ("time", "engine", "modal")}
        self.checks = [g.checks[check]]


def figure_soliton(g):
    sol, runs = g.data["soliton"], g.data["runs"]
    fig, axes = _figure(2)
    ax0, ax1 = axes[0]
    xi, y = sol.profile
    ax0.plot(xi, y, "k-", lw=1.2, label="cubic chain (own integration)")
    for i, r in enumerate(runs):
        d, t = r["delta"], r["time"]
        j = d.shape[1] // 2
        k = int(np.argmax(d[:, j]))
        x = (t - t[k]) * r["speed_sites"]
        keep = np.flatnonzero(np.abs(x) <= 4)
        keep = keep[:: max(1, len(keep) // 40)]  # about 40 markers a pulse
        ax0.plot(x[keep], d[keep, j] / d[k, j], "o" if i == 0 else "x", ms=4, mfc="none", color=f"C{i}",
                 label=f"engine, A = {r['A']:.4f}")
    ax0.set_xlabel(r"$(t - t_{peak})\,V$ [prisms] at a middle prism")
    ax0.set_ylabel(r"$\delta / \delta_{max}$ [-]")
    ax0.legend(fontsize=7)
    A = np.array([r["A"] for r in runs])
    refs = {"c": sol.speed_constant, "a": sol.amplitude_constant, "w": sol.width_fwhm}
    labels = {"c": "speed constant c/c*", "a": "amplitude law a/a*", "w": "width w/w*"}
    for i, (key, c) in enumerate(zip(("c", "a", "w"), g.checks)):
        ratios = np.array([r[key] for r in runs]) / refs[key]
        x0 = c.value / c.reference
        ax1.plot(A, ratios, "o", color=f"C{i}", label=f"{labels[key]}: {x0:.4f} at A = 0 (tolerance {c.tolerance:.0%})")
        ax1.plot(np.r_[0.0, A], np.r_[x0, ratios], "-", color=f"C{i}", lw=0.8)
        ax1.plot([0.0], [x0], "*", ms=9, color=f"C{i}")
    ax1.axhspan(0.99, 1.01, color="0.9", zorder=0, label="+-1 %")
    ax1.axhline(1.0, color="k", lw=0.6)
    ax1.set_xlim(left=0.0)
    from matplotlib.ticker import MaxNLocator

    ax1.xaxis.set_major_locator(MaxNLocator(5))
    ax1.set_xlabel(r"amplitude $A = \delta_{max}/h_0$ [-]")
    ax1.set_ylabel("engine / cubic chain [-]")
    ax1.legend(fontsize=7)
    fig.suptitle("RB, p = 0: the solitary wave against the cubic chain's (extrapolated linearly to A = 0)", fontsize=10)
    return fig


def figure_dispersion(g):
    d = g.data
    fig, axes = _figure(2, height=7.0, nrows=2)
    for col, (key, name) in enumerate((("rb", "RB (beta = 1)"), ("fb", "FB (beta = 0)"))):
        dispersion(d[key], ax=axes[0, col], speed=d["speed"][col], cutoff=d["cutoff"][col])
        axes[0, col].set_title(f"{name}, p = 0.002: every branch", fontsize=9)
        ax = dispersion(d[key], ax=axes[1, col], speed=d["speed"][col], cutoff=d["cutoff"][col],
                        omega_max=1.6 * d["omega_c"])
        ax.set_title(f"{name}: acoustic branch, simulated speed and ringing", fontsize=9)
    x = np.linspace(0.0, np.pi, 200)
    axes[1, 0].plot(x, d["omega_c"] * np.abs(np.sin(x / 2)), "w:", lw=1.0, label=r"$\omega_c |\sin(k h_0/2)|$")
    axes[1, 0].plot(x, d["c0"] / d["rb"].height * x, "C3-.", lw=0.8, label=f"closed-form c0 = {d['c0']:.5g} m/s")
    for col, key in enumerate(("rb", "fb")):  # the simulated short column's modes at their k_j
        w_sim, _ = d["modes"][key]
        axes[1, col].plot(d["k_modes"] * d[key].height, w_sim, "kx", ms=6, label="simulated modes (8 prisms)")
        axes[1, col].legend(fontsize=7)
    by_name = {c.name: c for c in g.checks}
    _stamp(axes[1, 0], by_name["dispersion_rb_modes"], 0.98, 0.03)
    _stamp(axes[1, 0], by_name["dispersion_speed_measure"], 0.98, 0.12)
    _stamp(axes[1, 1], by_name["dispersion_fb_modes"], 0.98, 0.03)
    return fig


def figure_interface(g):
    """The space-time strain map with the long-wave arrivals, and the three pulses at their stations scaled by
    the formulas (incident, reflected / R_eps, transmitted / T_eps) and shifted by the long-wave times."""
    from matplotlib import colors

    d = g.data
    t, q, (s1, s2), th = d["time"], d["strain"], d["stations"], d["theory"]
    t_inc, t_ref, t_tra = d["arrivals"]
    fig, axes = _figure(2)
    ax0, ax1 = axes[0]
    peak = float(np.abs(q).max())
    n = q.shape[1]
    mesh = ax0.pcolormesh(np.arange(n), t, q / peak, cmap="RdBu_r", shading="nearest", rasterized=True,
                          norm=colors.TwoSlopeNorm(vcenter=0.0, vmin=-1.0, vmax=1.0))
    fig.colorbar(mesh, ax=ax0, pad=0.01).set_label("strain / its largest magnitude [-]")
    J, N, h0 = d["joint"], n, th.height
    lvl = np.linspace(J, N, 50)
    ax0.plot(lvl, (N - lvl) * h0 / th.c1, "k--", lw=0.8, label="long-wave arrivals (c1, c2)")
    ax0.plot(lvl, ((N - J) + (lvl - J)) * h0 / th.c1, "k--", lw=0.8)
    low = np.linspace(0, J, 30)
    ax0.plot(low, (N - J) * h0 / th.c1 + (J - low) * h0 / th.c2, "k--", lw=0.8)
    ax0.axvline(J, color="0.4", lw=0.8)
    for s in (s1, s2):
        ax0.axvline(s + 0.5, color="C2", lw=0.8, ls=":")
    ax0.set_xlabel("prism (0 at the clamp; the joint grey, the stations green)")
    ax0.set_ylabel("time t [s]")
    ax0.set_ylim(t[0], t[-1])
    ax0.legend(fontsize=7, loc="upper right")
    half = d["half"]
    peak = float(np.abs(q[:, s1]).max())  # the incident pulse's
    for y, tc, scale, label, style in (
            (q[:, s1], t_inc, 1.0, "incident (station before the joint)", "k-"),
            (q[:, s1], t_ref, th.reflected_strain, "reflected / R_eps", "C0--"),
            (q[:, s2], t_tra, th.transmitted_strain, "transmitted / T_eps", "C3:")):  # noqa: E127
        sel = (t >= tc - half) & (t <= tc + half)
        ax1.plot(t[sel] - tc, y[sel] / scale / peak, style, lw=1.3, label=label)
    ax1.set_xlabel("time from the long-wave arrival [s]")
    ax1.set_ylabel("strain / scale / incident peak [-]")
    ax1.legend(fontsize=7, loc="lower right")
    for i, c in enumerate(g.checks):
        ax1.text(0.02, 0.72 - 0.1 * i, f"{c.name}:\n{c.error:.2e} (tolerance {c.tolerance:g})", transform=ax1.transAxes,
                 va="top", fontsize=7, bbox={"fc": "w", "ec": "0.8", "alpha": 0.9})
    p1, p2 = d["prestrain"]
    fig.suptitle(f"RB column, prestrain {p1:g} | {p2:g} (Z2/Z1 = {th.Z2 / th.Z1:.3g}): a Gaussian pulse across the joint "
                 "against the chain's impedance formula", fontsize=10)
    return fig


def figure_diatomic(g):
    """The two-level cell's branches with the gap's decay rate, the peaks per cell (engine, prediction,
    kappa(w0)) and the rms per cell outside the gap, and the records at a few cells inside."""
    d = g.data
    fig, axes = _figure(3, width=13.0)
    ax0, ax1, ax2 = axes[0]
    q, br, (lo, hi) = d["q"], d["branches"], d["edges"]
    for i in range(br.shape[1]):
        ax0.plot(q / np.pi, br[:, i], "C0-", lw=1.4, label="two-level Bloch cell (RB, symmetric)" if i == 0 else None)
    ax0.plot(1.0 + d["gap_kappa"] / np.pi, d["gap_omega"], "C3-", lw=1.2, label="gap: 1 + kappa/pi (q = pi + i kappa)")
    ax0.axhspan(lo, hi, color="0.92", zorder=0)
    for key, style in (("gap", "C3"), ("band", "C2")):
        ax0.axhline(d["runs"][key]["omega0"], color=style, ls="--", lw=0.8, label=f"{key} packet's w0")
    ax0.set_xlabel("q / pi (cell of two levels); right of 1: kappa / pi")
    ax0.set_ylabel("angular frequency [rad/s]")
    ax0.legend(fontsize=7, loc="lower right")
    gap, band = d["runs"]["gap"], d["runs"]["band"]
    pe, pt = gap["peaks"]
    c = np.arange(pe.size)
    ax1.semilogy(c, pe / pe[0], "C3o", mfc="none", label="gap: engine's peaks")
    ax1.semilogy(c, pt / pt[0], "k-", lw=0.8, label="gap: lambda(w)^c on the joint's record")
    ax1.semilogy(c, np.exp(-d["kappa_w0"] * c), "C3:", lw=0.8, label="gap: exp(-kappa(w0) c)")
    ax1.semilogy(c, band["peaks"] / band["peaks"][0], "C2s", mfc="none", label="band: engine's rms, first passage")
    ax1.set_xlabel("cells from the joint")
    ax1.set_ylabel("amplitude / the joint's [-]")
    ax1.legend(fontsize=7, loc="lower left")
    for i, ch in enumerate(g.checks[:2]):
        ax1.text(0.98, 0.84 - 0.08 * i, f"{ch.name}: {ch.error:.2e} (tolerance {ch.tolerance:g})",
                 transform=ax1.transAxes, va="top", ha="right", fontsize=7, bbox={"fc": "w", "ec": "0.8", "alpha": 0.9})
    t, y, pred = gap["time"], gap["strain"][:, gap["prisms"]], gap["predicted"]
    scale = float(np.abs(y[:, 0]).max())
    for i, cc in enumerate((0, 1, 3)):
        ax2.plot(t, y[:, cc] / scale, color=f"C{i}", lw=1.0, label=f"engine, cell {cc}")
        ax2.plot(t, pred[:, cc] / scale, "k--", lw=0.6, label="prediction" if i == 0 else None)
    ax2.set_xlim(gap["t_joint"] - 3.0 * gap["sigma"] * 0.25, t[-1])
    ax2.set_xlabel("time t [s]")
    ax2.set_ylabel("strain / the joint prism's peak [-]")
    ax2.legend(fontsize=7, loc="upper left")
    fig.suptitle("RB column, level masses m | 2m: a packet inside the gap dies at the complex Bloch wavenumber's rate, "
                 "one in the acoustic band passes", fontsize=10)


def figure_striker(g):
    """The striker's velocity and contact force, and the column's energy, engine against the chain."""
    d = g.data
    fig, axes = _figure(3, 13.0, 3.8)
    axes = axes[0]
    t = d["time"]
    for ax, (key, label, scale) in zip(axes, (("velocity", "striker velocity / v0", 1.0 / d["v0"]),
                                              ("force", "contact force [nN]", 1e9),
                                              ("energy", "energy in the column [fJ]", 1e15))):
        ax.plot(t, d[f"chain_{key}"] * scale, "k-", lw=2.5, alpha=0.35, label="linear chain (exact)")
        ax.plot(t, d[f"engine_{key}"] * scale, "C3.", ms=2.5, label="engine")
        for ts in d["separations"]:
            ax.axvline(ts, color="0.6", lw=0.8, ls="--")
        ax.set_xlabel("t [s]")
        ax.set_ylabel(label)
    axes[0].legend(loc="lower right", fontsize=8)
    c = {k.name: k for k in g.checks}
    fig.suptitle(f"{g.title}: velocity error {c['striker_velocity'].error:.1e} v0, energy error "
                 f"{c['striker_energy'].error:.1e} (dashed: separations)", fontsize=10)
    return fig


def figure_preload(g):
    """Two figures: the force-displacement law along the mechanism path with the engine's static
    state, and the small impact on the loaded column against the chain of its tangent stiffness."""
    d = g.data
    by_name = {c.name: c for c in g.checks}
    fig, axes = _figure(1, 5.5, 4.0)
    ax = axes[0][0]
    ax.plot(1.0 - d["height"] / d["h0"], d["force"], "k-", lw=1.2, label="F0(delta), closed form (mechanism path)")
    ax.plot([1.0 - d["engine_height"] / d["h0"]], [d["F0"]], "o", color="C3", ms=6, label="engine: static state under F0")
    ax.set_ylim(0.0, 4.0 * d["F0"])
    ax.set_xlabel("static shortening delta/h0 = 1 - h/h0 [-]")
    ax.set_ylabel("end preload F0 [N]")
    ax.legend(fontsize=7, loc="lower right")
    _stamp(ax, by_name["preload_height"], 0.02, 0.98)
    _stamp(ax, by_name["preload_twist"], 0.02, 0.90)
    record = _record_vs_reference(g, "bessel", "Bessel form of the chain (K_t, m_eff)",
                                  [d["engine"].shape[1] - 1 - k for k in (0, 2, 4)])
    _stamp(record.axes[0], by_name["preload_speed"], 0.02, 0.90)
    return [fig, record]


FIGURES = {"bessel": figure_bessel, "soliton": figure_soliton, "dispersion": figure_dispersion,
           "fb_modal": figure_fb_modal, "interface": figure_interface,
           "diatomic": figure_diatomic, "striker": figure_striker, "preload": figure_preload}


def write_figures(groups, directory) -> list[Path]:
    """The PNGs of each check group, ``validation_<name>.png`` (a second figure ``validation_<name>_2.png``) in
    ``directory`` (made if missing)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = Path(directory)
    out.mkdir(parents=True, exist_ok=True)
    paths = []
    for g in groups:
        figs = FIGURES[g.name](g)
        for i, fig in enumerate(figs if isinstance(figs, list) else [figs]):
            paths.append(out / f"validation_{g.name}{'' if i == 0 else f'_{i + 1}'}.png")
            with replacing(paths[-1]) as tmp:  # atomically, never through a link
                fig.savefig(tmp, dpi=110)
            plt.close(fig)
    return paths
