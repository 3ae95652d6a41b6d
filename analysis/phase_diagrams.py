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
# the response changes character (linear / stiffening / softening; whether the leading pulse carries
# the impact or only part of it). The reading of each figure is in `analysis/phase_diagrams.md`.
# Measures: `docs/measurements.md`.
#
# | variable | default | meaning |
# |---|---|---|
# | `WT_PHASE_NC` | `analysis/data/phase_large.nc` | the grid sweep (relative paths: from the repository root) |
# | `WT_PHASE_FALLBACK_SPEC` | `sweeps/ci_small.toml` | run (CPU, seconds) when `WT_PHASE_NC` does not exist |
# | `WT_PHASE_FALLBACK_NC` | `<tmp>/warp_tensegrity/phase_fallback.nc` | where that fallback run goes |
# | `WT_FIG_DIR` | `analysis/output/figures` (git-ignored; fallback data: `<tmp>/warp_tensegrity/figures`) | where the PNGs go |
# | `WT_DEVICE` | `cpu` | Warp device of the fallback run and of the strain cross-check |
# | `WT_PHASE_RERUN` | `1` | `0` skips the strain cross-check (a few cells run again with the strain recorded; ~25 s on 2 CPU cores for phase_large) |

# %%
import os
import sys
import tempfile
import warnings
from pathlib import Path

_here = Path(__file__).resolve().parent if "__file__" in globals() else Path.cwd()
sys.path.insert(0, str(_here if (_here / "plotting.py").exists() else _here / "analysis"))

import matplotlib.pyplot as plt
import numpy as np
import pandas as pd
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
ds = P.open_sweep(NC)
print(NC, "| figures ->", P.figure_dir())
print(ds.attrs.get("title"), "|", {k: ds.attrs.get(k) for k in ("n_columns", "device", "t_end", "output_interval")})
print({d: ds.sizes[d] for d in P.GRID_DIMS}, "| status != 0:", int((ds.status != 0).sum()))
P_, V_, B_ = (ds[d].values for d in P.GRID_DIMS)
H = float(ds.attrs["scene_height"])
N_PRISMS = int(ds.attrs["scene_n_prisms"])


def pct(da, q):
    """Percentiles of the finite values of ``da`` (NaN if none), rounded for printing."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN panels (e.g. RB in the short fallback sweep)
        return np.round(np.nanpercentile(np.asarray(da, dtype=float), q), 2).tolist()


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
FLAGGED = SAMPLES < MIN_SAMPLES
print(f"output interval {ds.attrs.get('output_interval')} s; cells with < {MIN_SAMPLES} output samples per pulse "
      f"passage (time of flight unreliable, cross-hatched): {int(FLAGGED.sum())} of {SAMPLES.size}; < 1 sample "
      f"(amplitude biased low): {int((SAMPLES < 1).sum())}; unknown (width or speed NaN, not masked): "
      f"{int(SAMPLES.isnull().sum())}")
print("samples per passage, min / 1st percentile / median by base rigidity:",
      {float(b): pct(SAMPLES.sel(base_rigidity=b), [0, 1, 50]) for b in B_})
if FLAGGED.any():  # which cells, and why: a fast pulse, or a width that cannot be a pulse's
    print(xr.Dataset({"samples": SAMPLES, "speed": speed, "width": width, "width_10": width10, "amplitude": amp})
          .where(FLAGGED).reset_coords(drop=True).to_dataframe().dropna(subset=["samples"]).round(4).to_string())


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
# speeds of that prestrain (`plotting.branch_speeds`, a 10-prism column of the same scene, which
# reads the stiff branches 2-4 % above the 50-prism column's; the soft branch is the same): soft
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
# * **Does the leading pulse carry the impact?** (`plotting.momentum_share`, no strain record needed)
#   the axial momentum of the measured pulse, level mass x speed x 1.135 x amplitude x FWHM, over the
#   impact's. Around 1 or more: one pulse carries the impact; < 0.5: most of it travels in other waves
#   (a precursor ahead, or slower waves and a tail behind).
# * **Pulse shape**: width_10 / FWHM at mid-column (sech^2: 2.06, Gaussian: 1.82; larger when the 10 %
#   level runs into a plateau or a tail).
# * With the strain stored (the fallback sweep; the cross-check below), also the **lead share**: the
#   pulse's share of sum(strain^2) behind the front (`plotting.lead_fraction`).

# %%
IMPACT = P.impact_momentum(ds)  # axial momentum of the impact per unit v0, level masses
reg = P.regimes(ds, linear_tol=0.15, min_samples=MIN_SAMPLES, impact=IMPACT)
alpha_meshes = maps(reg.alpha, r"$\alpha = d\,\log c / d\,\log v_0$ [-]", colors.TwoSlopeNorm(0.0, -1.0, 1.0),
                    cmap="RdBu_r", name="phase_nonlinearity",
                    overlay=lambda ax, b: (P.safe_contour(ax, P_, V_, reg.alpha.sel(base_rigidity=b).transpose("v0", "prestrain").values,
                                                          [-0.15, 0.15], colors="k", linewidths=0.7), slack_line(ax, b)),
                    suptitle=r"Nonlinearity: $\alpha$ = d log speed / d log $v_0$ (black: $\alpha$ = $\pm$0.15; dashed: amplitude = p)")

# %%
CARRY = 0.5  # momentum share below which the measured pulse carries less than half of the impact
mu = reg.momentum_share
print("momentum share by base rigidity (min / median / max):",
      {float(b): pct(mu.sel(base_rigidity=b), [0, 50, 100]) for b in B_})
share_meshes = maps(mu, "leading-pulse momentum / impact momentum [-]", colors.LogNorm(0.1, 3.0), cmap="PuOr",
                    name="phase_compactness",
                    overlay=lambda ax, b: (P.safe_contour(ax, P_, V_, mu.sel(base_rigidity=b).transpose("v0", "prestrain").values,
                                                          [CARRY], colors="k", linewidths=0.8), slack_line(ax, b)),
                    suptitle=f"Share of the impact's axial momentum in the leading pulse (estimate; black: {CARRY}; "
                             "dashed: amplitude = p)")
shape_meshes = maps(reg.tail_ratio, "10 % width / FWHM at mid-column [-]", colors.Normalize(1.0, 4.0),
                    cmap="YlGnBu_r", name="phase_shape", overlay=slack_line,
                    suptitle="Pulse shape: 10 % width / FWHM (sech$^2$: 2.06, Gaussian: 1.82; dashed: amplitude = p)")
COMPACT = 0.35
if "lead_share" in reg:
    lead_meshes = maps(reg.lead_share, "leading pulse share of sum(strain$^2$) behind the front [-]",
                       colors.Normalize(0, 1), cmap="YlGnBu", name="phase_lead_share",
                       overlay=lambda ax, b: P.safe_contour(ax, P_, V_, reg.lead_share.sel(base_rigidity=b).transpose("v0", "prestrain").values,
                                                            [COMPACT], colors="k", linewidths=0.8),
                       suptitle=f"Lead share of the strain field (black: share = {COMPACT})")
else:
    print("no strain record in this dataset: no lead-share map (the cross-check below reruns a few cells with it)")

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
    P.hatch_cells(ax, reg.momentum_share.sel(base_rigidity=b) < CARRY, edgecolor="0.15")
    unresolved(ax, b)
    slack_line(ax, b)
    ax.set_title(beta_title(b))
    label_axes(ax, i % 3 == 0, i >= len(B_) - 3)
handles = [Patch(facecolor="#d73027", label=r"stiffening ($\alpha$ > 0.15)"),
           Patch(facecolor="#d9d9d9", label=r"linear-like (|$\alpha$| < 0.15)"),
           Patch(facecolor="#4575b4", label=r"softening ($\alpha$ < -0.15)"),
           Patch(facecolor="#222222", label=f"leading wave changes (|$\\alpha$| > {JUMP})"),
           Patch(facecolor="white", edgecolor="k", hatch="////", label=f"pulse carries < {CARRY} of the impact momentum"),
           Patch(facecolor="white", edgecolor="0.5", hatch="xxx", label=f"not resolved (< {MIN_SAMPLES} samples per passage)")]
fig.legend(handles=handles, loc="outside lower center", ncol=3, fontsize=7, frameon=False)
fig.suptitle("Regimes of the leading pulse (dashed white: amplitude = prestrain)")
P.save_figure(fig, "phase_regimes")
plt.show()

# %% [markdown]
# ## Cross-check with the strain: a few cells run again
#
# The sweep keeps no strain. A dozen cells, one per regime of the reading, are run again (CPU by
# default) with the sweep's scene, time step and output interval and the strain recorded. The table
# gives the largest relative difference of their measures from the sweep's (the GPU run), the
# momentum share estimated from the measures against the one summed from the strain snapshot
# (`plotting.lead_pulse_snapshot`), the lead share, and the largest compression anywhere in the record
# over the leading pulse's amplitude (large: much bigger waves follow the leading pulse).

# %%
RERUN_POINTS = [dict(base_rigidity=b, prestrain=p, v0=v) for b, p, v in [
    (0.0, 0.0, 0.0083), (0.0, 0.002, 0.0041), (0.0, 0.002, 0.0169), (0.0, 0.002, 0.0487), (0.0, 0.00067, 0.002),
    (0.5, 0.0053, 0.0169), (0.95, 0.002, 0.002), (0.95, 0.0, 0.0041),
    (1.0, 0.0, 0.0041), (1.0, 0.01, 0.001), (1.0, 0.002, 0.0693), (1.0, 0.002, 0.2)]]
if os.environ.get("WT_PHASE_RERUN", "1") != "0":
    rr = P.rerun_cells(ds, RERUN_POINTS, device=os.environ.get("WT_DEVICE", "cpu"))
    snap = P.lead_pulse_snapshot(rr.strain, H)
    level_mass, p0 = (IMPACT[k].sel(prestrain=xr.DataArray(rr.prestrain.values, dims="cell"),
                                 base_rigidity=xr.DataArray(rr.base_rigidity.values, dims="cell")).values
                      for k in ("level_mass", "p0"))
    per_v0 = rr.speed.values / (p0 * rr.v0.values)
    with np.errstate(divide="ignore", invalid="ignore"):
        check = pd.DataFrame({
            "base_rigidity": rr.base_rigidity.values, "prestrain": rr.prestrain.values, "v0": rr.v0.values,
            "max_rel_diff": np.max([np.abs(rr[k].values / rr[f"sweep_{k}"].values - 1) for k in ("amplitude", "speed", "width")], axis=0),
            **{k: rr[k].values for k in ("amplitude", "speed", "width", "width_10")},
            "momentum_est": level_mass * per_v0 * P.SECH2_AREA * rr.amplitude.values * rr.width.values,
            "momentum_strain": level_mass * per_v0 * snap.sum_q.values,
            "lead_share": (snap.sum_q2 / snap.sum_q2_behind).values,
            "qmax_over_amp": (snap.q_max / rr.amplitude).values,
        }).set_index(["base_rigidity", "prestrain", "v0"])
    print(f"rerun on {rr.attrs['device']}, dt = {sorted(set(rr.time_step.values.tolist()))} s")
    print(check.to_string(float_format=lambda x: f"{x:.3g}"))

# %% [markdown]
# ## Numbers quoted in `analysis/phase_diagrams.md`

# %%
# weakest impact: measured speed against the linearised branch speeds (10-prism column)
weak = xr.Dataset({"speed": speed.isel(v0=0), "width": width.isel(v0=0), **{k: branches[k] for k in branches}})
print(f"v0 = {V_[0]:g} m/s")
print(weak.isel(prestrain=slice(None, None, step)).reset_coords(drop=True).to_dataframe()
      .unstack("base_rigidity").round(4).to_string())

# %%
# the precursor's amplitude cap and where the measured wave changes: for each (beta, p > 0), the first
# v0 at which the speed drops below 0.75 x its weakest-impact value, and the largest amplitude / p before it
rows = []
for b in B_:
    for p in P_[P_ > 0]:
        s_ = speed.sel(base_rigidity=b, prestrain=p).values
        a_ = (amp.sel(base_rigidity=b, prestrain=p) / p).values
        drop = np.flatnonzero(s_ < 0.75 * s_[0])
        j = drop[0] if drop.size else len(V_)
        if 0 < j < len(V_):
            rows.append({"base_rigidity": float(b), "prestrain": float(p), "v0_drop": V_[j],
                         "max_amp_over_p_before": np.nanmax(a_[:j]),
                         "max_width_before": np.nanmax(width.sel(base_rigidity=b, prestrain=p).values[:j])})
switch = pd.DataFrame(rows, columns=["base_rigidity", "prestrain", "v0_drop", "max_amp_over_p_before", "max_width_before"])
print(switch.groupby("base_rigidity").agg(cells_with_drop=("v0_drop", "count"),
                                          amp_over_p_min=("max_amp_over_p_before", "min"),
                                          amp_over_p_median=("max_amp_over_p_before", "median"),
                                          amp_over_p_max=("max_amp_over_p_before", "max"),
                                          v0_drop_min=("v0_drop", "min"), v0_drop_max=("v0_drop", "max"),
                                          width_before_max=("max_width_before", "max")).round(3).to_string())

# %%
# per base rigidity: the counts of each regime, and the weak-impact corner (v0 <= 4.2 mm/s, p >= 0.0026)
corner = (ds.v0 <= 0.0042) & (ds.prestrain >= 0.0026)
slow = (speed < 0.1 * speed.max("v0")) & (ds.base_rigidity < 1)  # the slow (soft-branch) wave read instead of the fast one
table = {}
for b in B_:
    a = reg.alpha.sel(base_rigidity=b)
    c = corner.broadcast_like(a)
    table[float(b)] = {
        "linear": int((np.abs(a) < 0.15).sum()), "stiffening": int(((a >= 0.15) & (a <= JUMP)).sum()),
        "softening": int(((a <= -0.15) & (a >= -JUMP)).sum()), "jump": int((np.abs(a) > JUMP).sum()),
        "slow_wave_cells": int(slow.sel(base_rigidity=b).sum()),
        "carries_impact": int((mu.sel(base_rigidity=b) >= CARRY).sum()),
        "corner_speed": float(speed.sel(base_rigidity=b).where(c).median()),
        "corner_width": float(width.sel(base_rigidity=b).where(c).median()),
        "corner_w10_over_w": float(reg.tail_ratio.sel(base_rigidity=b).where(c).median()),
        "corner_momentum": float(mu.sel(base_rigidity=b).where(c).median()),
        "max_amplitude": float(amp.sel(base_rigidity=b).max()),
        "energy_error_max": float(ds.energy_error.sel(base_rigidity=b).max()),
    }
pd.DataFrame(table).round(4)

# %%
# everything per cell
summary = xr.Dataset({"amplitude": amp, "speed": speed, "width": width, "width_10": width10,
                      "alpha": reg.alpha, "momentum_share": mu, "samples": SAMPLES,
                      **({"lead_share": reg.lead_share} if "lead_share" in reg else {})})
summary.reset_coords(drop=True).to_dataframe().round(4)
