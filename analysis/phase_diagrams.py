# ---
# jupyter:
#   jupytext:
#     formats: ipynb,py:percent
#     text_representation:
#       extension: .py
#       format_name: percent
#       format_version: '1.3'
#       jupytext_version: 1.19.6
#   kernelspec:
#     display_name: Python 3 (ipykernel)
#     language: python
#     name: python3
# ---

# %% [markdown]
# # Phase diagrams of the leading pulse: prestrain x impact speed x base rigidity
#
# Input: a grid sweep over (prestrain, v0, base_rigidity), e.g. `sweeps/phase_large.toml` (1536
# columns, GPU). Output: maps of the leading pulse's width, amplitude and speed, and the places where
# the response changes character (linear / stiffening / softening; compact pulse / dispersive tail).
# The reading of each figure is in `analysis/phase_diagrams.md`. Measures: `docs/measurements.md`.
#
# | variable | default | meaning |
# |---|---|---|
# | `WT_PHASE_NC` | `analysis/data/phase_large.nc` | the grid sweep (relative paths: from the repository root) |
# | `WT_PHASE_FALLBACK_SPEC` | `sweeps/ci_small.toml` | run (CPU, seconds) when `WT_PHASE_NC` does not exist |
# | `WT_PHASE_FALLBACK_NC` | `<tmp>/warp_tensegrity/phase_fallback.nc` | where that fallback run goes |
# | `WT_FIG_DIR` | `analysis/figures` (fallback data: `<tmp>/warp_tensegrity/figures`) | where the PNGs go |
# | `WT_DEVICE` | `cpu` | Warp device of the fallback run |

# %%
import os
import sys
import tempfile
from pathlib import Path

_here = Path(__file__).resolve().parent if "__file__" in globals() else Path.cwd()
sys.path.insert(0, str(_here if (_here / "plotting.py").exists() else _here / "analysis"))

import matplotlib.pyplot as plt
import numpy as np
import xarray as xr
from matplotlib import colors
from matplotlib.patches import Patch

import plotting as P

P.use_style()
NC = P.input_path("WT_PHASE_NC", "analysis/data/phase_large.nc")
FALLBACK = not NC.exists()
if FALLBACK:
    tmp = Path(tempfile.gettempdir()) / "warp_tensegrity"
    NC = P.ensure_sweep(P.input_path("WT_PHASE_FALLBACK_NC", str(tmp / "phase_fallback.nc")),
                        os.environ.get("WT_PHASE_FALLBACK_SPEC", "sweeps/ci_small.toml"))
    os.environ.setdefault("WT_FIG_DIR", str(tmp / "figures"))  # never overwrite the real figures
    print("input missing: using the fallback sweep", NC)
ds = xr.open_dataset(NC).load()
print(NC, "| figures ->", P.figure_dir())
print(ds.attrs.get("title"), "|", {k: ds.attrs.get(k) for k in ("n_columns", "device", "t_end", "output_interval")})
print({d: ds.sizes[d] for d in P.GRID_DIMS}, "| status != 0:", int((ds.status != 0).sum()))
P_, V_, B_ = (ds[d].values for d in P.GRID_DIMS)
H = float(ds.attrs["scene_height"])
N_PRISMS = int(ds.attrs["scene_n_prisms"])


def panel_grid(n, width=3.6, height=2.9):
    ncol = min(3, n)
    nrow = int(np.ceil(n / ncol))
    fig, axes = plt.subplots(nrow, ncol, figsize=(width * ncol + 0.8, height * nrow), squeeze=False)
    for ax in axes.flat[n:]:
        ax.set_visible(False)
    return fig, axes.flat[:n]


def beta_title(b):
    name = {0.0: " (FB)", 1.0: " (RB)"}.get(float(b), "")
    return f"base rigidity $\\beta$ = {b:g}{name}"


def label_axes(ax, first_col, last_row):
    """Axis labels on the left column and on the lowest panel of each column."""
    if last_row:
        ax.set_xlabel("cross-cable prestrain p [-]")
    if first_col:
        ax.set_ylabel(r"impact speed $v_0$ [m/s]")


def maps(var: xr.DataArray, cbar_label, norm, cmap="viridis", name=None, suptitle="", overlay=None):
    """One panel per base rigidity: ``var`` over (prestrain, v0); returns {beta: QuadMesh}."""
    fig, axes = panel_grid(len(B_))
    meshes = {}
    for i, (ax, b) in enumerate(zip(axes, B_)):
        mesh, _ = P.phase_map(ax, var.sel(base_rigidity=b), norm=norm, cmap=cmap, colorbar=False)
        meshes[float(b)] = mesh
        if overlay is not None:
            overlay(ax, b)
        ax.set_title(beta_title(b))
        label_axes(ax, i % 3 == 0, i >= len(B_) - 3)
    cb = fig.colorbar(meshes[float(B_[0])], ax=list(axes), shrink=0.9, pad=0.02)
    cb.set_label(cbar_label)
    fig.suptitle(suptitle)
    if name:
        P.save_figure(fig, name)
    plt.show()
    return meshes


amp = P.grid_variable(ds, "amplitude")
speed = P.grid_variable(ds, "speed")
width = P.grid_variable(ds, "width")
width10 = P.grid_variable(ds, "width_10")


SAMPLES = P.samples_per_passage(ds)
MIN_SAMPLES = 0.8
print(f"output interval {ds.attrs.get('output_interval')} s; cells with < {MIN_SAMPLES} output samples per pulse "
      f"passage (time of flight unreliable): {int((SAMPLES < MIN_SAMPLES).sum())} of {SAMPLES.size}; < 1 sample "
      f"(amplitude biased low): {int((SAMPLES < 1).sum())}")


def unresolved(ax, b):
    """Cross-hatch cells whose leading pulse passes a prism in < MIN_SAMPLES output samples."""
    P.hatch_cells(ax, SAMPLES.sel(base_rigidity=b) < MIN_SAMPLES, hatch="xxx", edgecolor="0.5")


def slack_line(ax, b):
    """Dashed: amplitude = prestrain (a pulse this strong slackens the cross cables of prisms with
    deformable bases; not drawn for rigid bases, whose prisms shorten by twisting and stretch them)."""
    if float(b) >= 1.0:
        return
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = (amp.sel(base_rigidity=b) / amp.prestrain).transpose("v0", "prestrain")
    P.safe_contour(ax, P_, V_, np.where(np.isfinite(ratio.values), ratio.values, np.nan), [1.0],
                   colors="w", linestyles="--", linewidths=1.0)


# %% [markdown]
# ## Amplitude and speed

# %%
amp_meshes = maps(amp, "leading-pulse amplitude [-]", colors.LogNorm(*np.nanpercentile(amp, [0, 100])),
                  name="phase_amplitude", overlay=lambda ax, b: (slack_line(ax, b), unresolved(ax, b)),
                  suptitle="Leading-pulse amplitude (dashed white: amplitude = prestrain; x: pulse not resolved in time)")
speed_meshes = maps(speed, "leading-pulse speed [m/s]", colors.LogNorm(*np.nanpercentile(speed, [0, 100])),
                    cmap="magma", name="phase_speed", overlay=lambda ax, b: (slack_line(ax, b), unresolved(ax, b)),
                    suptitle="Leading-pulse speed (time of flight; dashed white: amplitude = prestrain; x: not resolved)")

# %% [markdown]
# ## Width against prestrain, impact speed and base rigidity

# %%
width_meshes = maps(width, "FWHM at mid-column [prisms]", colors.Normalize(0.8, min(6.0, float(np.nanmax(width)))),
                    cmap="cividis", name="phase_width_maps", overlay=lambda ax, b: (slack_line(ax, b), unresolved(ax, b)),
                    suptitle="Leading-pulse width (FWHM at mid-column; x: pulse not resolved in time)")

# %%
wres = width.where(SAMPLES >= MIN_SAMPLES)  # line cuts: resolved cells only
fig, axes = plt.subplots(1, 3, figsize=(11.5, 3.4))
cm = plt.get_cmap("viridis")
bcol = {float(b): cm(0.9 * i / max(len(B_) - 1, 1)) for i, b in enumerate(B_)}
v_mid = float(V_[len(V_) // 2])
width_lines = {"prestrain": {}, "v0": {}, "base_rigidity": {}}
for b in B_:
    w = wres.sel(base_rigidity=b, v0=v_mid)
    (ln,) = axes[0].plot(P_, w, "o-", color=bcol[float(b)], label=f"$\\beta$ = {b:g}")
    width_lines["prestrain"][float(b)] = ln
axes[0].set_xlabel("cross-cable prestrain p [-]")
axes[0].set_title(f"against prestrain, $v_0$ = {v_mid:.3g} m/s")
for b in B_:
    for p, ls in ((P_[0], "-"), (P_[-1], "--")):
        w = wres.sel(base_rigidity=b, prestrain=p)
        (ln,) = axes[1].plot(V_, w, "o" + ls, color=bcol[float(b)], ms=2.5,
                             label=f"$\\beta$ = {b:g}, p = {p:g}")
        width_lines["v0"][(float(b), float(p))] = ln
axes[1].set_xscale("log")
axes[1].set_xlabel(r"impact speed $v_0$ [m/s]")
axes[1].set_title(f"against $v_0$ (solid: p = {P_[0]:g}, dashed: p = {P_[-1]:g})")
p_mid = float(P_[len(P_) // 2])
vcm = plt.get_cmap("plasma")
for i, v in enumerate(V_[:: max(1, len(V_) // 4)]):
    w = wres.sel(prestrain=p_mid, v0=v)
    (ln,) = axes[2].plot(B_, w, "o-", color=vcm(0.85 * i / 4), label=f"$v_0$ = {v:.2g} m/s")
    width_lines["base_rigidity"][float(v)] = ln
axes[2].set_xlabel(r"base rigidity $\beta$ [-]")
axes[2].set_title(f"against base rigidity, p = {p_mid:.3g}")
for ax in axes:
    ax.set_ylabel("FWHM at mid-column [prisms]")
    ax.legend(fontsize=6, frameon=False, ncol=2 if ax is axes[1] else 1)
fig.suptitle(f"Leading-pulse width (cells with < {MIN_SAMPLES} output samples per pulse passage left out)")
P.save_figure(fig, "phase_width")
plt.show()

# %% [markdown]
# ## Speed against impact speed, with the linearised branch speeds
#
# Lines: our speeds, one per prestrain. Horizontal marks (same colour): the linearised long-wave
# speeds of that prestrain (`plotting.branch_speeds`, a 10-prism column of the same scene): soft
# branch c0 (dotted), stiff branch with all cables taut (dashed) and with the cross cables slack
# (dash-dot). Linear response: speed flat at a branch speed. Stiffening: speed grows with v0.
# Softening: speed falls with v0.

# %%
branches = P.branch_speeds(ds)
fig, axes = panel_grid(len(B_), 3.7, 3.0)
pcm = plt.get_cmap("viridis")
pcol = {float(p): pcm(0.9 * i / max(len(P_) - 1, 1)) for i, p in enumerate(P_)}
step = max(1, len(P_) // 5)
p_show = P_[::step]
for i, (ax, b) in enumerate(zip(axes, B_)):
    for p in p_show:
        sp = speed.sel(base_rigidity=b, prestrain=p)
        ax.plot(V_, sp.where(SAMPLES.sel(base_rigidity=b, prestrain=p) >= MIN_SAMPLES), "o-", ms=2.5,
                color=pcol[float(p)], label=f"p = {p:g}")
        ax.plot(V_, sp.where(SAMPLES.sel(base_rigidity=b, prestrain=p) < MIN_SAMPLES), "x", ms=3,
                color=pcol[float(p)])
        for key, ls in (("c_soft", ":"), ("c_stiff", "--"), ("c_stiff_slack", "-.")):
            c = float(branches[key].sel(base_rigidity=b, prestrain=p))
            if np.isfinite(c) and c > 0:
                ax.axhline(c, color=pcol[float(p)], ls=ls, lw=0.7)
    ax.set_xscale("log")
    ax.set_xlim(V_.min() / 1.3, V_.max() * 1.3)
    if np.isfinite(speed.sel(base_rigidity=b).values).any():
        ax.set_yscale("log")
    else:
        ax.text(0.5, 0.5, "no leading pulse measured\n(run too short for it to cross the window)",
                transform=ax.transAxes, ha="center", va="center", fontsize=7)
    ax.set_title(beta_title(b))
    if i % 3 == 0:
        ax.set_ylabel("leading-pulse speed [m/s]")
    if i >= len(B_) - 3:
        ax.set_xlabel(r"impact speed $v_0$ [m/s]")
axes[0].legend(fontsize=6, frameon=False)
fig.suptitle("Speed against impact speed (dotted: soft branch c0; dashed: stiff branch; dash-dot: stiff branch, "
             f"cross cables slack; x: < {MIN_SAMPLES} output samples per pulse passage)")
P.save_figure(fig, "phase_speed_lines")
plt.show()
branches.to_dataframe().round(4)

# %% [markdown]
# ## Where the response changes character
#
# * **Linear vs nonlinear**: alpha = d log speed / d log v0 (centred differences on the log v0 grid).
#   |alpha| < 0.15: linear(-like), the speed does not depend on the impact; alpha > 0.15: stiffening
#   (a sonic vacuum with a cubic force law has 1/2); alpha < -0.15: softening.
# * Cells where the leading pulse passes a prism in fewer than 0.8 output samples
#   (`plotting.samples_per_passage`) are cross-hatched and left out of alpha: their time of flight is
#   not reliable.
# * **Compact pulse vs dispersive tail**: share of the leading pulse in sum(strain^2) behind the front
#   when the pulse is at mid-column (`plotting.lead_fraction`); < 0.35: the tail (or slower waves)
#   holds most of it.

# %%
reg = P.regimes(ds, linear_tol=0.15, min_samples=MIN_SAMPLES)
alpha_meshes = maps(reg.alpha, r"$\alpha = d\,\log c / d\,\log v_0$ [-]", colors.TwoSlopeNorm(0.0, -1.0, 1.0),
                    cmap="RdBu_r", name="phase_nonlinearity",
                    overlay=lambda ax, b: (P.safe_contour(ax, P_, V_, reg.alpha.sel(base_rigidity=b).transpose("v0", "prestrain").values,
                                                          [-0.15, 0.15], colors="k", linewidths=0.7), slack_line(ax, b)),
                    suptitle=r"Nonlinearity: $\alpha$ = d log speed / d log $v_0$ (black: $\alpha$ = $\pm$0.15; dashed: amplitude = p)")

# %%
COMPACT = 0.35
if "lead_share" not in reg:
    print("no strain record in this dataset: the lead share (compact vs dispersive) needs it; showing "
          "width_10 / FWHM instead, a weaker proxy (about 2 for a bell-shaped pulse)")
    share_meshes = maps(reg.tail_ratio, "10 % width / FWHM at mid-column [-]", colors.Normalize(1.0, 4.0),
                        cmap="YlGnBu_r", name="phase_compactness",
                        suptitle="Pulse shape: 10 % width / FWHM (no strain record: lead share unavailable)")
else:
    share_meshes = maps(reg.lead_share, "leading pulse share of sum(strain$^2$) behind the front [-]",
                        colors.Normalize(0, 1), cmap="YlGnBu", name="phase_compactness",
                        overlay=lambda ax, b: P.safe_contour(ax, P_, V_, reg.lead_share.sel(base_rigidity=b).transpose("v0", "prestrain").values,
                                                             [COMPACT], colors="k", linewidths=0.8),
                        suptitle=f"Compact pulse vs dispersive tail (black: share = {COMPACT})")

# %%
# regime summary: colour = softening / linear-like / stiffening / jump, hatching = dispersive (share < COMPACT)
JUMP = 1.5
cat = xr.where(np.abs(reg.alpha) > JUMP, 3,
               xr.where(reg.stiffening == 1, 2, xr.where(reg.softening == 1, 0, 1))).where(np.isfinite(reg.alpha))
cmap4 = colors.ListedColormap(["#4575b4", "#d9d9d9", "#d73027", "#222222"])
fig, axes = panel_grid(len(B_))
regime_meshes = {}
for i, (ax, b) in enumerate(zip(axes, B_)):
    mesh, _ = P.phase_map(ax, cat.sel(base_rigidity=b), cmap=cmap4, norm=colors.BoundaryNorm([-0.5, 0.5, 1.5, 2.5, 3.5], 4),
                          colorbar=False)
    regime_meshes[float(b)] = mesh
    if "lead_share" in reg:
        P.hatch_cells(ax, reg.lead_share.sel(base_rigidity=b) < COMPACT, edgecolor="0.15")
    unresolved(ax, b)
    slack_line(ax, b)
    ax.set_title(beta_title(b))
    label_axes(ax, i % 3 == 0, i >= len(B_) - 3)
handles = [Patch(facecolor="#d73027", label=r"stiffening ($\alpha$ > 0.15)"),
           Patch(facecolor="#d9d9d9", label=r"linear-like (|$\alpha$| < 0.15)"),
           Patch(facecolor="#4575b4", label=r"softening ($\alpha$ < -0.15)"),
           Patch(facecolor="#222222", label=f"leading wave changes (|$\\alpha$| > {JUMP})"),
           *([Patch(facecolor="white", edgecolor="k", hatch="////", label=f"dispersive (share < {COMPACT})")]
             if "lead_share" in reg else []),
           Patch(facecolor="white", edgecolor="0.5", hatch="xxx", label=f"not resolved (< {MIN_SAMPLES} samples per passage)")]
fig.legend(handles=handles, loc="outside lower center", ncol=3, fontsize=7, frameon=False)
fig.suptitle("Regimes of the leading pulse (dashed white: amplitude = prestrain)")
P.save_figure(fig, "phase_regimes")
plt.show()

# %%
# numbers quoted in analysis/phase_diagrams.md
summary = xr.Dataset({"amplitude": amp, "speed": speed, "width": width, "width_10": width10,
                      "alpha": reg.alpha, **({"lead_share": reg.lead_share} if "lead_share" in reg else {})})
summary.to_dataframe().round(4)
