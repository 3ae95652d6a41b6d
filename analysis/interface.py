# %% [markdown]
# # The transmitted amplitude across a prestrain interface (issue 34, must-show 3)
#
# Input: a grid sweep over a two-segment prestrain profile, `prestrain_at` x `prestrain_to`
# (`sweeps/interface.toml`: 60-prism rigid-base columns, GPU), with the strain recorded. Output: a
# phase diagram of the transmitted amplitude and of the transmission ratio, and their numbers as JSON.
#
# **Definitions** (from the stored strain alone; the column is clamped at prism 0 and struck at
# prism n - 1, so the pulse runs toward lower prism indices and crosses the interface from prism
# `at` into prism `at - 1`):
#
# * the *peak* of a prism: its largest compression, max_t (-strain), over the outputs before the
#   front reaches the clamped base (the first output at which prism 0 is compressed by more than
#   1e-3 of the record's largest compression), so no wave reflected at the base is counted;
# * the *transmitted amplitude* A_T: the median of the peaks of the `WINDOW` prisms past the
#   interface, at - 1 - WINDOW .. at - 2 (the interface prism at - 1 itself is left out: it carries
#   the interface's near field); fewer where the far segment is shorter;
# * the *incident amplitude* A_I: the same on the `WINDOW` prisms before the interface,
#   at + 1 .. at + WINDOW (where the reflected wave overlaps the incident one, their sum);
# * the *transmission ratio* A_T / A_I.
#
# | variable | default | meaning |
# |---|---|---|
# | `WT_INTERFACE_NC` | `analysis/data/interface.nc` | the grid sweep (relative paths: from the repository root) |
# | `WT_INTERFACE_FALLBACK_NC` | `<tmp>/warp_tensegrity/interface_fallback.nc` | where the CPU run goes when `WT_INTERFACE_NC` does not exist (`sweeps/interface.toml` with `CPU_OVERRIDES`) |
# | `WT_FIG_DIR` | `analysis/output/figures` (fallback data: `<tmp>/warp_tensegrity/figures`) | where the PNG and the JSON go |

# %%
from __future__ import annotations

import json
import os
import sys
import tempfile
from pathlib import Path

import numpy as np
import xarray as xr

WINDOW = 3
"""Prisms on each side of the interface whose peaks give A_T and A_I."""
BASE_FRACTION = 1e-3
"""The front reaches the clamped base when prism 0's compression exceeds this fraction of the largest."""
CPU_OVERRIDES = {"scene": {"n_prisms": 30},
                 "sweep": {"grid": {"prestrain_at": [8, 15, 22], "prestrain_to": [0.005, 0.01, 0.02, 0.04]}},
                 "run": {"t_end": 2.0}}
"""The small CPU run of sweeps/interface.toml (12 columns of 30 prisms, ~20 s on 2 cores): the
fallback when there is no GPU dataset, and what tests/test_analysis.py checks."""


def peaks_before_base(strain: xr.DataArray) -> xr.DataArray:
    """Each prism's largest compression -strain over the outputs before the front reaches prism 0
    (``strain`` over (..., t, prism)); NaN where the record holds nothing."""
    comp = -strain
    top = comp.max(dim=("t", "prism"))
    reached = comp.isel(prism=0) > BASE_FRACTION * top
    t_base = xr.where(reached.any("t"), comp["t"].where(reached).min("t"), np.inf)
    return comp.where(comp["t"] < t_base).max("t")


def transmission(ds: xr.Dataset, window: int = WINDOW) -> xr.Dataset:
    """``A_T``, ``A_I`` and ``ratio`` (A_T / A_I) of every case of a sweep whose grid has a
    ``prestrain_at`` axis (definitions: this file's head), with units and long names."""
    if "strain" not in ds or "prestrain_at" not in ds.dims:
        raise ValueError("needs a grid over prestrain_at with the strain recorded (run.record_strain = true)")
    peak = peaks_before_base(ds["strain"])
    n = ds.sizes["prism"]
    a_t, a_i = [], []
    for at in ds["prestrain_at"].values.astype(int):
        p = peak.sel(prestrain_at=at)
        past = np.arange(max(at - 1 - window, 0), at - 1)
        before = np.arange(at + 1, min(at + 1 + window, n))
        a_t.append(p.isel(prism=past).median("prism") if past.size else xr.full_like(p.isel(prism=0), np.nan))
        a_i.append(p.isel(prism=before).median("prism") if before.size else xr.full_like(p.isel(prism=0), np.nan))
    at_dim = ds["prestrain_at"]
    out = xr.Dataset({"A_T": xr.concat(a_t, at_dim), "A_I": xr.concat(a_i, at_dim)})
    out["ratio"] = out["A_T"] / out["A_I"]
    out["A_T"].attrs = {"units": "1", "long_name": f"transmitted amplitude: median peak compression of the {window} "
                                                   "prisms past the interface, before the front reaches the base"}
    out["A_I"].attrs = {"units": "1", "long_name": f"incident amplitude: median peak compression of the {window} "
                                                   "prisms before the interface"}
    out["ratio"].attrs = {"units": "1", "long_name": "transmission ratio A_T / A_I"}
    return out.drop_vars([c for c in out.coords if c not in out.dims], errors="ignore")


def phase_diagram(tr: xr.Dataset, path: Path, far: float | None = None) -> Path:
    """Maps of A_T and of A_T / A_I over (prestrain_to, prestrain_at), written to ``path``."""
    import matplotlib
    import matplotlib.ticker

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 4), constrained_layout=True)
    for ax, name, cmap in ((axes[0], "A_T", "viridis"), (axes[1], "ratio", "RdBu_r")):
        da = tr[name].transpose("prestrain_at", "prestrain_to")
        m = ax.pcolormesh(da["prestrain_to"], da["prestrain_at"], da.values, shading="nearest", cmap=cmap)
        ax.set_xscale("log")
        ax.set_xticks(da["prestrain_to"].values[:: max(1, da.sizes["prestrain_to"] // 4)])
        ax.xaxis.set_major_formatter(matplotlib.ticker.FormatStrFormatter("%.3g"))
        ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
        ax.set_xlabel("prestrain_to (impacted segment)")
        ax.set_ylabel("prestrain_at (interface prism)")
        if far is not None:  # the far segment's prestrain: no interface there
            ax.axvline(far, color="k", lw=0.8, ls="--")
        fig.colorbar(m, ax=ax, label={"A_T": "A_T [1]", "ratio": "A_T / A_I [1]"}[name])
        ax.set_title({"A_T": "transmitted amplitude A_T", "ratio": "transmission ratio A_T / A_I"}[name])
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def main() -> dict:
    here = Path(__file__).resolve().parent
    root = here.parent
    nc = Path(os.environ.get("WT_INTERFACE_NC", "analysis/data/interface.nc"))
    nc = nc if nc.is_absolute() else root / nc
    fig_dir = Path(os.environ.get("WT_FIG_DIR", str(root / "analysis" / "output" / "figures")))
    fallback = not nc.exists()
    if fallback:  # the small CPU run: figures beside it, never over the real ones
        from warp_tensegrity.sweep import load_spec, run_sweep

        tmp = Path(tempfile.gettempdir()) / "warp_tensegrity"
        nc = Path(os.environ.get("WT_INTERFACE_FALLBACK_NC", str(tmp / "interface_fallback.nc")))
        if not nc.exists():
            run_sweep(load_spec(root / "sweeps" / "interface.toml", overrides=CPU_OVERRIDES), nc, device="cpu", overwrite=True,
                      progress=False)
        fig_dir = Path(os.environ.get("WT_FIG_DIR", str(tmp / "figures")))
    ds = xr.open_dataset(nc)
    tr = transmission(ds)
    far = float(ds["prestrain"].isel(prism=0).max()) if "prestrain" in ds else None
    png = phase_diagram(tr, fig_dir / "interface_transmission.png", far)
    record = {"source": nc.name, "spec": "sweeps/interface.toml" + (" with CPU_OVERRIDES" if fallback else ""),
              "device": str(ds.attrs.get("device_name", ds.attrs.get("device", "unknown"))),
              "wall_time_s": float(ds.attrs.get("wall_time", float("nan"))), "n_columns": int(ds.attrs.get("n_columns", 0)),
              "n_prisms": int(ds.sizes["prism"]), "window": WINDOW, "prestrain_far": far,
              "prestrain_at": tr["prestrain_at"].values.tolist(), "prestrain_to": tr["prestrain_to"].values.tolist(),
              **{k: tr[k].transpose("prestrain_at", "prestrain_to").values.round(6).tolist() for k in ("A_T", "A_I", "ratio")}}
    (fig_dir / "interface_transmission.json").write_text(json.dumps(record, indent=1))
    print(f"wrote {png} and {fig_dir / 'interface_transmission.json'}", file=sys.stderr)
    return record


if __name__ == "__main__":
    main()
