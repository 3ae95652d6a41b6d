"""Shared helpers of the analysis notebooks (``paper_2017.py``, ``phase_diagrams.py``).

Three jobs, each kept free of notebook state so that ``tests/test_analysis.py`` can check the
data every figure and table is made of (not pixels):

* **inputs**: netCDF paths from environment variables (relative paths are taken from the
  repository root), and the fallback that makes a missing input by running the command line on
  the matching spec (:func:`input_path`, :func:`ensure_sweep`);
* **figures**: strain snapshots, space-time maps, parameter maps; each function draws on a given
  ``Axes`` and returns the matplotlib artists it made, whose data the tests read back;
* **numbers**: the paper's Section 4 values, the reproduction table, power-law fits,
  logarithmic derivatives and the regime masks of the phase diagrams.

Units: strain [-] (``(h - h0)/h``, negative in compression), speed [m s-1], widths [prisms],
time [s]. Pulse measures are those of ``warp_tensegrity.measure`` (``docs/measurements.md``).
"""

from __future__ import annotations

import os
import shutil
import sys
from dataclasses import dataclass
from pathlib import Path

import matplotlib as mpl
import matplotlib.pyplot as plt
import numpy as np
import xarray as xr
from matplotlib import colors

__all__ = [
    "H0",
    "PAPER_2017",
    "PaperCase",
    "repo_root",
    "input_path",
    "figure_dir",
    "output_dir",
    "open_sweep",
    "ensure_sweep",
    "use_style",
    "save_figure",
    "strain_snapshots",
    "spacetime_map",
    "overlay_peak_track",
    "match_cases",
    "leading_pulse_at",
    "reproduction_table",
    "markdown_table",
    "power_law_fit",
    "reading_interval",
    "grid_variable",
    "log_slope",
    "phase_map",
    "cell_edges",
    "hatch_cells",
    "regimes",
    "samples_per_passage",
    "safe_contour",
    "scene_config",
    "branch_speeds",
    "lead_fraction",
    "lead_pulse_snapshot",
    "SECH2_AREA",
    "impact_momentum",
    "momentum_share",
    "simulate_cases",
    "rerun_cells",
]

H0 = 6.2e-3
"""Reference prism height of the paper's columns [m] (the length unit of speeds in prisms/s)."""

REPO_ROOT = Path(__file__).resolve().parent.parent

try:  # the notebooks also run from a plain checkout (package not installed)
    import warp_tensegrity  # noqa: F401
except ImportError:  # pragma: no cover
    sys.path.insert(0, str(REPO_ROOT))

from warp_tensegrity import plot as W  # noqa: E402  (the package's plot API draws every figure)
from warp_tensegrity.types import TIME  # noqa: E402  (the time axis, "t")


# ====================================================================== inputs and outputs
OUTPUT_DIR = "analysis/output"
"""Default folder of everything the notebooks write (git-ignored)."""


def output_dir(env: str, sub: str = "") -> Path:
    """``$env`` or ``analysis/output/<sub>`` (created): where a notebook writes."""
    d = input_path(env, f"{OUTPUT_DIR}/{sub}".rstrip("/"))
    d.mkdir(parents=True, exist_ok=True)
    return d


def open_sweep(path) -> xr.Dataset:
    """A sweep's dataset, loaded; files written before the time axis became ``t`` (CF: simulated
    time is no calendar time) have their ``time`` axis renamed."""
    ds = xr.open_dataset(path, decode_timedelta=False).load()
    if "time" in ds.dims and TIME not in ds.dims:
        ds = ds.rename({"time": TIME})
    return ds


def repo_root() -> Path:
    """The repository root (the parent of ``analysis/``)."""
    return REPO_ROOT


def input_path(env: str, default: str) -> Path:
    """Path from environment variable ``env`` (else ``default``); relative paths are taken
    from the repository root, so the notebooks read the same files from any working directory."""
    p = Path(os.environ.get(env) or default).expanduser()
    return p if p.is_absolute() else repo_root() / p


def figure_dir() -> Path:
    """Where figures go: ``$WT_FIG_DIR``, default ``analysis/output/figures`` (created; git-ignored,
    so running a notebook never rewrites a tracked file; the committed figures in
    ``analysis/figures`` are refreshed on purpose with ``WT_FIG_DIR=analysis/figures``)."""
    d = input_path("WT_FIG_DIR", f"{OUTPUT_DIR}/figures")
    d.mkdir(parents=True, exist_ok=True)
    return d


def ensure_sweep(path, spec, device: str | None = None) -> Path:
    """Return ``path``; if it does not exist, make it first with the Python sweep API
    (:func:`warp_tensegrity.sweep.run_sweep`, the engine of ``warp-tensegrity run``; device:
    ``$WT_DEVICE``, default ``cpu``). The store the run leaves next to ``PATH`` (``PATH.sweep/``) and its lock are removed."""
    from warp_tensegrity.sweep import run_sweep

    path = Path(path)
    if path.exists():
        return path
    spec = Path(spec)
    if not spec.is_absolute():
        spec = repo_root() / spec
    device = device or os.environ.get("WT_DEVICE", "cpu")
    print(f"{path} not found: running {spec.name} on {device}", flush=True)
    run_sweep(spec, path, device=device, progress=False, overwrite=True)
    shutil.rmtree(Path(str(path) + ".sweep"), ignore_errors=True)  # the run's store; the export stays
    path.with_name(f".{path.name}.lock").unlink(missing_ok=True)
    return path


def use_style() -> None:
    """Publication style: 8-9 pt text, thin lines, 200 dpi PNGs, constrained layout."""
    mpl.rcParams.update({
        "font.size": 9,
        "axes.titlesize": 9,
        "axes.labelsize": 9,
        "legend.fontsize": 7.5,
        "xtick.labelsize": 8,
        "ytick.labelsize": 8,
        "lines.linewidth": 1.2,
        "lines.markersize": 3,
        "axes.grid": False,
        "figure.dpi": 100,
        "savefig.dpi": 200,
        "savefig.bbox": "tight",
        "figure.constrained_layout.use": True,
        "image.cmap": "viridis",
    })


def save_figure(fig, name: str) -> Path:
    """Save ``fig`` as ``<figure_dir()>/<name>.png`` and return the path."""
    path = figure_dir() / f"{name}.png"
    fig.savefig(path)
    return path


# ====================================================================== strain figures
STRAIN_LABEL = W.STRAIN_LABEL
PRISM_LABEL = W.PRISM_LABEL
robust_limit = W.robust_limit


def strain_snapshots(ax, strain: xr.DataArray, times, cmap: str = "viridis", marker: str = ".") -> list:
    """Axial strain against prism at the output times nearest to ``times`` (the paper's "time
    shots"), drawn by :func:`warp_tensegrity.plot.pulse_profile`. ``strain`` has dims (t, prism).
    Returns the Line2D objects, one per time, whose y-data are the dataset's strain at that time
    and whose label gives the time actually drawn."""
    before = len(ax.lines)
    W.pulse_profile(strain, times, ax=ax, cmap=cmap, marker=marker)
    ax.get_legend().remove()  # the notebooks place their own legends
    return ax.lines[before:before + len(times)]


def spacetime_map(ax, strain: xr.DataArray, vmax: float | None = None, cmap: str = "RdBu_r",
                  colorbar: bool = True, cbar_label: str = STRAIN_LABEL):
    """Space-time map of the strain (:func:`warp_tensegrity.plot.spacetime`). Returns
    (QuadMesh, Colorbar or None); the mesh's array is the dataset's strain, time-major."""
    W.spacetime(strain, ax=ax, vmax=vmax, cmap=cmap, colorbar=colorbar, cbar_label=cbar_label)
    mesh = ax.collections[-1]
    return mesh, mesh.colorbar if colorbar else None


def overlay_peak_track(ax, peak_time, prism, **kw):
    """Mark the measured leading peak (time of the peak at each prism) on a space-time map."""
    style = dict(marker="o", ms=2.2, mfc="none", mec="#ff8c00", mew=0.7, ls="none", label="leading peak (measured)")
    style.update(kw)
    (ln,) = ax.plot(np.asarray(prism), np.asarray(peak_time), **style)
    return ln


# ====================================================================== the paper's numbers
@dataclass(frozen=True)
class PaperCase:
    """One of the twelve cases of Fabbrocino & Carpentieri (2017), Section 4, as the paper states it."""

    figure: str
    base: str  # "FB" or "RB"
    base_rigidity: float
    prestrain: float
    v0: float  # [m s-1]
    amplitude: float  # leading-pulse compressive strain, positive [-]
    speed: float  # "mean speed" of the leading pulse [m s-1]; NaN: not stated
    span: float  # "span approximately N prisms" [prisms]
    span_when: str  # when the paper says the span holds
    note: str = ""


PAPER_2017 = (
    # Sec. 4.1, Fig. 4: "amplitudes of the leading pulses at time t = 0.5 s"; "mean speed ... equal to
    # 0.248 m/s" in all three cases; "span approximately 6 prisms at t = 0.5 s"
    PaperCase("4a", "FB", 0.0, 0.0, 0.001, 7.19e-4, 0.248, 6, "t = 0.5 s", "one mean speed for all three"),
    PaperCase("4b", "FB", 0.0, 0.0, 0.002, 1.44e-3, 0.248, 6, "t = 0.5 s", "one mean speed for all three"),
    PaperCase("4c", "FB", 0.0, 0.0, 0.005, 3.59e-3, 0.248, 6, "t = 0.5 s", "one mean speed for all three"),
    # Fig. 5: amplitudes 7.33e-3, 1.25e-2, 1.77e-2; mean speeds 0.0248, 0.031, 0.0496 m/s; "span about 3 prisms"
    PaperCase("5a", "RB", 1.0, 0.0, 0.001, 7.33e-3, 0.0248, 3, "not stated"),
    PaperCase("5b", "RB", 1.0, 0.0, 0.002, 1.25e-2, 0.031, 3, "not stated"),
    PaperCase("5c", "RB", 1.0, 0.0, 0.005, 1.77e-2, 0.0496, 3, "not stated"),
    # Sec. 4.2, Fig. 6: "span approximatively 4 prisms at t = 0.5 s", "speed varying from 0.248 m/s for
    # v0 = 0.1 m/s to 0.372 m/s for v0 = 0.15 m/s" (none given for 0.125); amplitudes 5.4e-2, 6.97e-2, 8.5e-2
    PaperCase("6a", "FB", 0.0, 0.002, 0.100, 5.4e-2, 0.248, 4, "t = 0.5 s"),
    PaperCase("6b", "FB", 0.0, 0.002, 0.125, 6.97e-2, np.nan, 4, "t = 0.5 s", "speed not stated"),
    PaperCase("6c", "FB", 0.0, 0.002, 0.150, 8.5e-2, 0.372, 4, "t = 0.5 s"),
    # Fig. 7: "compact solitary pulses spanning about 3 units"; amplitude 8.93e-2 for v0 = 0.1 and 0.106
    # for v0 = 0.125-0.15 m/s; mean speeds 0.186 m/s (0.1) and 0.248 m/s (0.125-0.15)
    PaperCase("7a", "RB", 1.0, 0.002, 0.100, 8.93e-2, 0.186, 3, "not stated"),
    PaperCase("7b", "RB", 1.0, 0.002, 0.125, 0.106, 0.248, 3, "not stated", "one value for v0 = 0.125-0.15"),
    PaperCase("7c", "RB", 1.0, 0.002, 0.150, 0.106, 0.248, 3, "not stated", "one value for v0 = 0.125-0.15"),
)
"""The paper's Section 4 numbers, in the order of sweeps/paper_2017.toml."""


def match_cases(ds: xr.Dataset, cases=PAPER_2017) -> list[int]:
    """Index along ``case`` of each paper case (matched on base rigidity, prestrain and v0)."""
    b, p, v = (ds[k].values for k in ("base_rigidity", "prestrain", "v0"))
    out = []
    for c in cases:
        hit = np.flatnonzero(np.isclose(b, c.base_rigidity) & np.isclose(p, c.prestrain, atol=1e-12)
                             & np.isclose(v, c.v0, rtol=1e-9))
        if len(hit) != 1:
            raise KeyError(f"paper case {c.figure} ({c.base}, p = {c.prestrain}, v0 = {c.v0}) "
                           f"found {len(hit)} times in the dataset")
        out.append(int(hit[0]))
    return out


def leading_pulse_at(strain: xr.DataArray, t_read: float, h: float = H0, search: int = 2) -> dict:
    """The leading pulse in the snapshot nearest to ``t_read`` [s], read the way one reads a
    strain-vs-prism figure. ``strain``: dims (..., time, prism).

    The prism it sits at is the one whose measured leading-peak time (``measure_pulse``'s
    ``peak_time``) is closest to ``t_read``; in the snapshot the reading is the largest compression
    within ``search`` prisms of it (a sampled value, no interpolation). Also: the largest compression
    anywhere in the column at that time, and the pulse's full widths at 50 % and 10 % of its
    (parabolic) peak in the snapshot, and its ``support``: the number of contiguous prisms around
    the peak compressed by at least 1 % of the reading [prisms]. Arrays of shape (...)."""
    from warp_tensegrity.measure import measure_pulse, pulse_width

    s = strain.transpose(..., TIME, "prism")
    t = s[TIME].values
    vals = s.values
    m = measure_pulse(vals, t, h)
    k = int(np.abs(t - t_read).argmin())
    snap = -vals[..., k, :]  # compression, positive
    pt = m["peak_time"]
    ok = np.isfinite(pt).any(axis=-1)
    j0 = np.nanargmin(np.where(np.isfinite(pt), np.abs(pt - t[k]), np.inf), axis=-1)
    P = snap.shape[-1]
    jj = np.arange(P)
    near = np.abs(jj - j0[..., None]) <= search
    lead = np.where(near, snap, -np.inf)
    j_peak = lead.argmax(axis=-1)
    value = np.take_along_axis(snap, j_peak[..., None], axis=-1)[..., 0]
    w50 = pulse_width(-snap, 0.5, near=j_peak, search=0)
    w10 = pulse_width(-snap, 0.1, near=j_peak, search=0)
    # support: contiguous prisms around the peak compressed by at least 1 % of the peak value
    above = snap >= 0.01 * value[..., None]
    left = np.where(~above & (jj < j_peak[..., None]), jj, -1).max(axis=-1)
    right = np.where(~above & (jj > j_peak[..., None]), jj, P).min(axis=-1)
    nan = np.where(ok, 1.0, np.nan)
    return {
        "time": float(t[k]),
        "prism": np.where(ok, j_peak, -1),
        "amplitude": value * nan,
        "max_compression": snap.max(axis=-1),
        "width": w50 * nan,
        "width_10": w10 * nan,
        "support": (right - left - 1) * nan,
    }


def reproduction_table(ds: xr.Dataset, t_read: float = 0.5, cases=PAPER_2017):
    """Paper against ours, one row per paper case (a pandas DataFrame).

    Ours: ``amplitude``, ``speed``, ``width`` (FWHM at mid-column), ``width_10`` straight from the
    dataset (``measure_pulse``, docs/measurements.md); ``amp_t`` (leading pulse read at ``t_read``),
    ``max_t`` (largest compression anywhere at ``t_read``), ``width_t``/``width_10_t``/``support_t``
    (snapshot widths at ``t_read``) from :func:`leading_pulse_at`; speeds also in prisms per second (``/ H0``);
    ``left_feasible_set_s``: when the case left the model's feasible set (NaN: never, or no record of it)."""
    import pandas as pd

    idx = match_cases(ds, cases)
    sub = ds.isel(case=idx)
    at = leading_pulse_at(sub["strain"], t_read)
    h = float(ds.attrs.get("scene_height", H0))
    rows = []
    for i, c in enumerate(cases):
        r = sub.isel(case=i)
        rows.append({
            "figure": c.figure,
            "case": f"{c.base} p={c.prestrain:g} v0={c.v0:g}",
            "base": c.base,
            "prestrain": c.prestrain,
            "v0": c.v0,
            "left_feasible_set_s": float(r["feasibility_time"]) if "feasibility_time" in r else float("nan"),
            "paper_amplitude": c.amplitude,
            "amplitude": float(r["amplitude"]),
            "amp_t": float(at["amplitude"][i]),
            "max_t": float(at["max_compression"][i]),
            "paper_speed": c.speed,
            "speed": float(r["speed"]),
            "paper_speed_prisms": c.speed / h,
            "speed_prisms": float(r["speed"]) / h,
            "paper_span": c.span,
            "width": float(r["width"]),
            "width_10": float(r["width_10"]),
            "width_t": float(at["width"][i]),
            "width_10_t": float(at["width_10"][i]),
            "support_t": float(at["support"][i]),
            "prisms_measured": float(r["prisms_measured"]),
            "energy_error": float(r["energy_error"]),
            "status": int(r["status"]),
        })
    df = pd.DataFrame(rows)
    df["amplitude_ratio"] = df["amplitude"] / df["paper_amplitude"]
    df["amp_t_ratio"] = df["amp_t"] / df["paper_amplitude"]
    df["speed_ratio"] = df["speed"] / df["paper_speed"]
    df.attrs["t_read"] = at["time"]
    return df


def _fmt(v, fmt):
    if isinstance(v, str):
        return v
    if v is None or (isinstance(v, float) and not np.isfinite(v)):
        return "–"
    return format(v, fmt)


def markdown_table(df, columns: dict) -> str:
    """Markdown table of ``df``: ``columns`` maps column name -> (header, format spec)."""
    head = "| " + " | ".join(h for h, _ in columns.values()) + " |"
    rule = "|" + "|".join("---" for _ in columns) + "|"
    body = ["| " + " | ".join(_fmt(row[c], f) for c, (_, f) in columns.items()) + " |" for _, row in df.iterrows()]
    return "\n".join([head, rule, *body])


# ====================================================================== simulations for side studies
def simulate_cases(params: dict, config=None, t_end: float = 10.0, output_interval: float = 0.01,
                   dt="auto", device: str | None = None, keep_strain: bool = False, dt_safety: float | None = 0.25):
    """Run one batch (``warp_tensegrity.simulate_batch``) and measure it as the sweeps do
    (``warp_tensegrity.sweep.measure_columns``). ``params``: per-column arrays (prestrain, v0,
    base_rigidity, ...). Returns a DataFrame, one row per column: the parameters, the scene's
    conventions, ``amplitude``, ``speed``, ``width``, ``width_10``, ``prisms_measured``,
    ``energy_error``, ``ke0`` (initial kinetic energy [J]), ``status``; and the BatchResult if
    ``keep_strain``. ``dt_safety`` 0.25 (with dt = "auto"): the paper run's dt fraction, so the side
    studies stay as they were; None: the engine's default accuracy."""
    import pandas as pd
    from warp_tensegrity import ColumnConfig, RunSettings, simulate_batch
    from warp_tensegrity.sweep import measure_columns

    config = config or ColumnConfig()
    device = device or os.environ.get("WT_DEVICE", "cpu")
    r = simulate_batch(config, params, RunSettings(t_end=t_end, dt=dt, output_interval=output_interval,
                                                   device=device, record_strain=True,
                                                   dt_safety=dt_safety if dt == "auto" else None))
    m = measure_columns(r, config.height)
    B = r.n_columns
    df = pd.DataFrame({k: np.broadcast_to(np.asarray(v, float), (B,)) for k, v in params.items()})
    df["impact_admissibility"] = config.impact_admissibility
    df["end_base_mass"] = config.end_base_mass
    for k in ("amplitude", "speed", "width", "width_10", "prisms_measured"):
        df[k] = m[k]
    df["energy_error"] = r.energy_error
    df["ke0"] = r.kinetic_energy[:, 0]
    df["status"] = r.status
    df["dt"] = r.dt
    return (df, r) if keep_strain else df


# ====================================================================== fits and readings
def power_law_fit(x, y):
    """Least-squares fit of log y = log a + b log x over the finite, positive pairs: (b, a)."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    ok = np.isfinite(x) & np.isfinite(y) & (x > 0) & (y > 0)
    if ok.sum() < 2:
        return np.nan, np.nan
    b, loga = np.polyfit(np.log(x[ok]), np.log(y[ok]), 1)
    return float(b), float(np.exp(loga))


def reading_interval(speed, paper_speed, h: float = H0):
    """Longest snapshot interval [s] over which our pulse and one moving at the paper's speed
    drift apart by less than one prism: ``h / |speed - paper_speed|``. If positions are read
    off time shots to the nearest prism, a speed taken from shots this far apart cannot tell the
    two apart (``inf``: equal speeds)."""
    d = np.abs(np.asarray(speed, float) - np.asarray(paper_speed, float))
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(d > 0, h / d, np.inf)


# ====================================================================== phase diagrams
GRID_DIMS = ("prestrain", "v0", "base_rigidity")


def grid_variable(ds: xr.Dataset, name: str) -> xr.DataArray:
    """``ds[name]`` on the (prestrain, v0, base_rigidity) grid (other dims after), NaN where the
    column's status is not 0. Raises for a case-stacked dataset (no grid to map)."""
    missing = [d for d in GRID_DIMS if d not in ds[name].dims]
    if missing:
        raise ValueError(f"{name} lacks grid dims {missing}: a phase diagram needs a grid sweep "
                         f"over {GRID_DIMS} (got dims {ds[name].dims})")
    da = ds[name].where(ds["status"] == 0)
    return da.transpose(*GRID_DIMS, ...)


def log_slope(da: xr.DataArray, dim: str) -> xr.DataArray:
    """d log(da) / d log(dim) by finite differences on the log grid (second-order centred inside,
    one-sided at the ends and next to a NaN); NaN where ``da`` is NaN or <= 0, or no neighbour is
    defined.
    Needs ``dim`` coordinates > 0 (e.g. v0)."""
    x = np.log(da[dim].values.astype(float))
    ax = da.get_axis_num(dim)
    with np.errstate(invalid="ignore", divide="ignore"):
        y = np.log(np.where(da.values > 0, da.values, np.nan))
    y = np.moveaxis(y, ax, -1)
    n = y.shape[-1]
    out = np.full(y.shape, np.nan)
    for i in range(n):
        cands = []
        if 0 < i < n - 1:
            cands.append((y[..., i + 1] - y[..., i - 1]) / (x[i + 1] - x[i - 1]))
        if i < n - 1:
            cands.append((y[..., i + 1] - y[..., i]) / (x[i + 1] - x[i]))
        if i > 0:
            cands.append((y[..., i] - y[..., i - 1]) / (x[i] - x[i - 1]))
        for c in cands:  # first defined candidate wins: centred, then forward, then backward
            out[..., i] = np.where(np.isfinite(out[..., i]), out[..., i], c)
    out = np.where(np.isfinite(y), out, np.nan)  # no slope at an undefined point
    return da.copy(data=np.moveaxis(out, -1, ax))


cell_edges = W.cell_edges


def phase_map(ax, da: xr.DataArray, x: str = "prestrain", y: str = "v0", logy: bool = True,
              norm=None, cmap: str = "viridis", cbar_label: str | None = None, colorbar: bool = True):
    """Colour map of a 2-D DataArray over (x, y) (:func:`warp_tensegrity.plot.phase_diagram`), one
    cell per grid point, NaN cells blank. Returns (QuadMesh, Colorbar or None); the mesh's array is
    ``da`` with y as rows (``mesh.get_array()`` flattened)."""
    W.phase_diagram(da, x=x, y=y, ax=ax, log_y=logy, norm=norm, cmap=cmap, colorbar=colorbar,
                    cbar_label=cbar_label or "")
    ax.xaxis.set_major_locator(mpl.ticker.MaxNLocator(5))
    mesh = ax.collections[-1]
    return mesh, mesh.colorbar if colorbar else None


def hatch_cells(ax, da: xr.DataArray, x: str = "prestrain", y: str = "v0", logy: bool = True,
                hatch: str = "////", **kw) -> list:
    """Hatch the cells (as :func:`phase_map` draws them) where the boolean 2-D ``da`` is true.
    Returns the Rectangle patches, in (y, x) row-major order of the true cells."""
    from matplotlib.patches import Rectangle

    d = da.transpose(y, x)
    xe, ye = cell_edges(d[x].values), cell_edges(d[y].values, log=logy)
    patches = []
    style = dict(fill=False, hatch=hatch, lw=0.0, edgecolor="k")
    style.update(kw)
    for i, j in zip(*np.nonzero(np.asarray(d.values, dtype=float) == 1)):
        r = Rectangle((xe[j], ye[i]), xe[j + 1] - xe[j], ye[i + 1] - ye[i], **style)
        ax.add_patch(r)
        patches.append(r)
    return patches


def scene_config(ds: xr.Dataset, **changes):
    """The ``ColumnConfig`` of a sweep, from its ``scene_*`` attributes (``changes`` override)."""
    import dataclasses

    from warp_tensegrity import ColumnConfig

    kw = {}
    for f in dataclasses.fields(ColumnConfig):
        v = ds.attrs.get(f"scene_{f.name}")
        if v is not None:
            kw[f.name] = v.item() if hasattr(v, "item") else v
    kw.update(changes)
    return ColumnConfig(**kw)


def branch_speeds(ds: xr.Dataset, n_prisms: int = 10) -> xr.Dataset:
    """Linearised long-wave speeds [m s-1] on the (prestrain, base_rigidity) grid of a sweep, from
    ``warp_tensegrity.linear.long_wave_speed`` on a column of ``n_prisms`` prisms of the sweep's scene:

    * ``c_soft``: the soft (prestress-stiffened twist mechanism) branch; 0 at p = 0;
    * ``c_stiff``: the stiff branch with every cable taut (NaN for rigid bases, which have one branch);
    * ``c_stiff_slack``: the stiff branch with the cross cables' stiffness removed (the bilinear state
      of a compression pulse larger than the prestrain, which slackens the cross cables).

    Short columns make this quick; the stiff-branch speed of 10 prisms is ~2.5 % above that of 50."""
    import dataclasses

    from warp_tensegrity import build_column
    from warp_tensegrity.validation.linear import long_wave_speed

    handed = ds.attrs.get("scene_handedness", "right")
    cfg = scene_config(ds, **({"n_prisms": n_prisms} if handed in ("right", "left", "alternating") else {}))
    ps, bs = ds["prestrain"].values, ds["base_rigidity"].values
    out = {k: np.full((len(ps), len(bs)), np.nan) for k in ("c_soft", "c_stiff", "c_stiff_slack")}
    for i, p in enumerate(ps):
        for j, b in enumerate(bs):
            scene = build_column(cfg, prestrain=float(p), base_rigidity=float(b))
            lw = long_wave_speed(scene)
            out["c_soft"][i, j] = lw.c0
            if len(lw.c_branches_modal) > 1:
                out["c_stiff"][i, j] = lw.c_branches_modal[1]
                n_cross = len(scene.topology.cross)
                ea = scene.network.cable_EA.copy()
                ea[:n_cross] *= 1e-9
                slack = dataclasses.replace(scene, network=dataclasses.replace(scene.network, cable_EA=ea))
                c = long_wave_speed(slack).c_branches_modal
                out["c_stiff_slack"][i, j] = c[1] if len(c) > 1 else np.nan
    coords = {"prestrain": ps, "base_rigidity": bs}
    res = xr.Dataset({k: (("prestrain", "base_rigidity"), v) for k, v in out.items()}, coords=coords)
    for k in res:
        res[k].attrs["units"] = "m s-1"
    return res


def lead_pulse_snapshot(strain: xr.DataArray, h: float = H0) -> xr.Dataset:
    """The leading pulse in the strain snapshot taken as it passes mid-column, one record at a time.

    At the output time nearest to the leading peak's passage at the middle of the measurement window
    (``measure_pulse``'s ``peak_time``), with the peak at prism ``p`` (largest compression within 2
    prisms of the middle) and half-width ``w = max(1, width_10 / 2)``, in compression ``q = -strain``:

    * ``sum_q`` = sum_{|j - p| <= w} q_j [-]: the pulse's strain integral, in prisms (its axial
      momentum is ``level mass x speed x sum_q`` for a steady travelling wave);
    * ``sum_q2`` = sum_{|j - p| <= w} q_j^2 and ``sum_q2_behind`` = sum_{j >= p - w} q_j^2 [-];
    * ``q_max``: the largest compression anywhere in the column at any time [-];
    * ``amplitude``: the measured leading-pulse amplitude (``measure_pulse``) [-].

    NaN where the leading peak does not reach mid-window. ``strain``: dims (..., time, prism);
    every variable has dims (...)."""
    from warp_tensegrity.measure import measure_pulse, measurement_window

    s = strain.transpose(..., TIME, "prism")
    vals, t = s.values, s[TIME].values
    lead_dims = s.dims[:-2]
    P = vals.shape[-1]
    flat = vals.reshape(-1, len(t), P)
    m = measure_pulse(flat, t, h)
    lo, hi = measurement_window(P)
    jm = (lo + hi - 1) // 2
    keys = ("sum_q", "sum_q2", "sum_q2_behind")
    out = {k: np.full(flat.shape[0], np.nan) for k in keys}
    jj = np.arange(P)
    for b in range(flat.shape[0]):
        tp = m["peak_time"][b, jm]
        if not np.isfinite(tp):
            continue
        snap = -flat[b, int(np.abs(t - tp).argmin())]
        win = np.abs(jj - jm) <= 2
        p = int(np.argmax(np.where(win, snap, -np.inf)))
        w = max(1.0, 0.5 * m["width_10"][b]) if np.isfinite(m["width_10"][b]) else 1.0
        pulse = np.abs(jj - p) <= w
        out["sum_q"][b] = snap[pulse].sum()
        out["sum_q2"][b] = (snap[pulse] ** 2).sum()
        out["sum_q2_behind"][b] = (snap[jj >= p - w] ** 2).sum()
    out["q_max"] = np.where(np.isfinite(flat).all(axis=(1, 2)), -flat.min(axis=(1, 2)), np.nan)
    out["amplitude"] = m["amplitude"]
    shape = vals.shape[:-2]
    coords = {d: s[d] for d in lead_dims if d in s.coords}
    return xr.Dataset({k: xr.DataArray(v.reshape(shape), dims=lead_dims, coords=coords) for k, v in out.items()})


def lead_fraction(strain: xr.DataArray, h: float = H0) -> xr.DataArray:
    """Share of the leading pulse in the strain field behind the wave front, at mid-column [-].

    ``sum_q2 / sum_q2_behind`` of :func:`lead_pulse_snapshot`: at the output time nearest to the
    leading peak's passage at the middle of the measurement window, with the peak at prism ``p`` and
    half-width ``w = max(1, width_10 / 2)``, ``sum_{|j - p| <= w} eps_j^2 / sum_{j >= p - w} eps_j^2``
    (strain squared as a proxy for the elastic energy). Near 1: a compact pulse carries the motion;
    small: a dispersive tail or slower waves behind it hold most of the strain. Strain squared weighs
    soft waves (large strain, little force) as much as stiff ones, so a small share can also mean
    slow soft-branch waves behind a pulse that carries the whole impact (``analysis/phase_diagrams.md``).
    ``strain``: dims (..., time, prism); returns dims (...)."""
    snap = lead_pulse_snapshot(strain, h)
    with np.errstate(divide="ignore", invalid="ignore"):
        da = (snap["sum_q2"] / snap["sum_q2_behind"]).where(snap["sum_q2_behind"] > 0)
    da.attrs.update(long_name="share of the leading pulse in sum(strain^2) behind the front", units="1")
    return da


SECH2_AREA = 1.0 / np.arccosh(np.sqrt(2.0))
"""Integral of a sech^2 pulse over its amplitude x FWHM: 2 w / (2 w arcosh(sqrt 2)) = 1.1346."""


def impact_momentum(ds: xr.Dataset) -> xr.Dataset:
    """Per unit impact speed, on the (prestrain, base_rigidity) grid of a sweep, from its scene
    (``scene_*`` attributes; :func:`scene_config`):

    * ``p0``: the axial momentum of the admissible impact, -sum_i m_i v_z,i at v0 = 1 m/s [kg];
      ``end_twist`` keeps v_z = -v0 on the end nodes, so this is the end base's mass;
    * ``level_mass``: the mass of one interior level (a prism's share of the column) [kg].

    Neither depends on the prestrain (masses, reference geometry and bar constraints do not), so one
    column per base rigidity is built and the values are repeated along ``prestrain``."""
    from warp_tensegrity import build_column

    cfg = scene_config(ds)
    ps, bs = ds["prestrain"].values, ds["base_rigidity"].values
    p0 = np.full(len(bs), np.nan)
    m_level = np.full(len(bs), np.nan)
    for j, b in enumerate(bs):
        scene = build_column(cfg, prestrain=float(ps[0]), v0=1.0, base_rigidity=float(b))
        m = scene.network.node_mass
        p0[j] = -float(np.sum(m * scene.velocity[:, 2]))
        m_level[j] = float(m[scene.topology.level_nodes[1]].sum())
    dims = ("prestrain", "base_rigidity")
    coords = {"prestrain": ps, "base_rigidity": bs}
    rep = lambda v: np.broadcast_to(v, (len(ps), len(bs))).copy()  # noqa: E731
    return xr.Dataset({"p0": (dims, rep(p0), {"units": "kg"}), "level_mass": (dims, rep(m_level), {"units": "kg"})},
                      coords=coords)


def momentum_share(ds: xr.Dataset, shape_factor: float = SECH2_AREA, impact: xr.Dataset | None = None) -> xr.DataArray:
    """Axial momentum carried by the leading pulse over the impact's, estimated from the per-column
    measures alone (no strain record needed), on the grid [-]:

        level_mass x speed x (shape_factor x amplitude x width) / (p0 x v0)

    A steady wave moving at c toward the clamp gives each level the velocity c x strain, so its
    momentum is level_mass x c x sum_j q_j; the sum is taken as ``shape_factor`` x amplitude x FWHM
    (sech^2: 1.135; Gaussian: 1.064; a pulse more compact than sech^2 less). ``impact``:
    :func:`impact_momentum` (computed if None). Around 1 or more: the leading pulse carries the impact
    (more than 1 when the light end base rebounds); well below 1: most of the impact's momentum
    travels elsewhere, in waves ahead of the measured pulse or behind it. An estimate: the shape of
    the pulse sets it to about +-25 % (see :func:`lead_pulse_snapshot` for the strain-based value)."""
    impact = impact_momentum(ds) if impact is None else impact
    c, a, w = (grid_variable(ds, k) for k in ("speed", "amplitude", "width"))
    mu = impact["level_mass"] * c * shape_factor * a * w / (impact["p0"] * ds["v0"])
    mu = mu.transpose(*GRID_DIMS, ...)
    mu.attrs.update(long_name="leading-pulse momentum over impact momentum (estimate)", units="1")
    return mu


def rerun_cells(ds: xr.Dataset, points, device: str | None = None) -> xr.Dataset:
    """Run again, with the strain recorded, the grid cells of a sweep nearest to ``points`` (a list
    of {"base_rigidity": b, "prestrain": p, "v0": v} targets; duplicates dropped), with the sweep's
    scene, time step, duration and output interval (its attributes), on ``device`` (``$WT_DEVICE``,
    default cpu). Returns a dataset along ``cell``: ``strain`` (cell, time, prism), the rerun's
    measures, the sweep's as ``sweep_<name>``, and the cell's coordinates."""
    cells = []
    for pt in points:
        sel = {d: float(ds[d].values[np.abs(ds[d].values - pt[d]).argmin()]) for d in GRID_DIMS}
        if sel not in cells:
            cells.append(sel)
    params = {d: np.array([c[d] for c in cells]) for d in GRID_DIMS}
    # each cell at the dt it was stepped with: its run group's (the time_step variable), else the sweep's
    if "time_step" in ds:
        dts = np.array([float(ds["time_step"].sel(c)) for c in cells])
    else:
        dt = ds.attrs.get("dt", "auto")
        dts = np.full(len(cells), np.nan if isinstance(dt, str) else float(dt))
    frames, strain, rows = [], np.empty(len(cells), dtype=object), []
    for dt in dict.fromkeys(dts.tolist()):  # distinct dts, in order (NaN: "auto")
        idx = np.flatnonzero((dts == dt) | (np.isnan(dts) & np.isnan(dt)))
        df, r = simulate_cases({d: v[idx] for d, v in params.items()}, scene_config(ds), t_end=float(ds.attrs["t_end"]),
                               output_interval=float(ds.attrs["output_interval"]),
                               dt="auto" if np.isnan(dt) else dt, device=device, keep_strain=True)
        frames.append(df.set_index(idx))
        for i, s in zip(idx, np.asarray(r.strain)):
            strain[i] = s
        rows.append(r)
    import pandas as pd

    df = pd.concat(frames).sort_index()
    r = rows[0]
    out = xr.Dataset({"strain": (("cell", TIME, "prism"), np.stack(list(strain)))},
                     coords={"cell": np.arange(len(cells)), TIME: r.time, "prism": np.arange(r.strain.shape[-1]),
                             **{d: ("cell", params[d]) for d in GRID_DIMS}})
    for k in ("amplitude", "speed", "width", "width_10", "energy_error", "status"):
        out[k] = ("cell", df[k].to_numpy())
        if k in ds:
            out[f"sweep_{k}"] = ("cell", np.array([float(ds[k].sel(c)) for c in cells]))
    out["time_step"] = ("cell", df["dt"].to_numpy())
    out.attrs.update(device=r.device)
    return out


def safe_contour(ax, x, y, z, levels, filled: bool = False, **kw):
    """``ax.contour`` (or ``contourf``) of z (len(y), len(x)) if it can be drawn: both axes at least
    2 long, at least 4 finite values and some level inside their range; else None."""
    z = np.asarray(z, dtype=float)
    if min(z.shape) < 2 or np.isfinite(z).sum() < 4:
        return None
    lo, hi = np.nanmin(z), np.nanmax(z)
    if not filled and not any(lo < lv < hi for lv in levels):
        return None
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return (ax.contourf if filled else ax.contour)(x, y, z, levels=levels, **kw)


def samples_per_passage(ds: xr.Dataset) -> xr.DataArray:
    """Output samples per passage of the leading pulse at a prism [-]: width (FWHM, prisms) x h0 /
    (speed x output interval), on the grid; NaN where the width or speed is undefined. Below ~1 the
    time sampling cannot resolve the pulse: its amplitude reads low, and below ~0.5 even its time of
    flight becomes unreliable (phase_large.toml with 0.05 s outputs read speeds of 1-300 m/s there).
    With phase_large's 2 ms outputs every cell has >= 4.7 samples but one, whose FWHM is misread
    (0.03 prism): the criterion then flags a width that cannot be a pulse's."""
    dt_out = float(ds.attrs.get("output_interval", np.nan))
    if not np.isfinite(dt_out) and TIME in ds.coords and ds.sizes[TIME] > 1:
        dt_out = float(np.median(np.diff(ds[TIME].values)))  # NaN if the interval is unknown
    h = float(ds.attrs.get("scene_height", H0))
    with np.errstate(divide="ignore", invalid="ignore"):
        n = grid_variable(ds, "width") * h / (grid_variable(ds, "speed") * dt_out)
    n.attrs.update(long_name="output samples per leading-pulse passage", units="1")
    return n


def regimes(ds: xr.Dataset, linear_tol: float = 0.15, compact_share: float = 0.5,
            min_samples: float = 0.5, carry_share: float = 0.5, impact: xr.Dataset | None = None) -> xr.Dataset:
    """Where the leading pulse changes character, on the grid (prestrain, v0, base_rigidity):

    * ``alpha`` = d log speed / d log v0 (:func:`log_slope`): ~0 for a linear(-like) response whose
      speed does not depend on the impact; > 0 for a stiffening, strongly nonlinear pulse (sonic
      vacuum with a cubic force law: 1/2); < 0 for a softening one;
    * ``beta_amp`` = d log amplitude / d log v0: 1 for a linear(-like) response;
    * ``linear`` = |alpha| < linear_tol; ``stiffening`` = alpha >= linear_tol;
      ``softening`` = alpha <= -linear_tol (1.0/0.0, NaN where alpha is undefined);
    * ``tail_ratio`` = width_10 / width at mid-column: ~2 for a compact bell-shaped pulse (sech^2:
      2.06, Gaussian: 1.82), larger when the 10 % level runs into a tail;
    * ``momentum_share`` (only if the dataset has its ``scene_*`` attributes): :func:`momentum_share`
      (``impact``: :func:`impact_momentum`, computed if None);
      ``carries_impact`` = momentum_share >= carry_share (else most of the impact's momentum travels
      in other waves, ahead of the measured pulse or behind it);
    * ``lead_share`` (only if the sweep stored its strain): :func:`lead_fraction`;
      ``compact`` = lead_share >= compact_share (else the tail or slower waves dominate);
    * ``samples`` = :func:`samples_per_passage`; ``resolved`` = samples >= min_samples (or unknown).
      Unresolved cells are left out (NaN) of alpha and beta_amp, and of their neighbours' differences."""
    samples = samples_per_passage(ds)
    resolved = (samples >= min_samples) | np.isnan(samples)  # unknown sampling: not masked
    speed = grid_variable(ds, "speed").where(resolved)
    amp = grid_variable(ds, "amplitude").where(resolved)
    w = grid_variable(ds, "width")
    w10 = grid_variable(ds, "width_10")
    alpha = log_slope(speed, "v0")
    defined = np.isfinite(alpha)
    out = xr.Dataset({
        "alpha": alpha,
        "beta_amp": log_slope(amp, "v0"),
        "linear": (np.abs(alpha) < linear_tol).where(defined),
        "stiffening": (alpha >= linear_tol).where(defined),
        "softening": (alpha <= -linear_tol).where(defined),
        "tail_ratio": w10 / w,
        "samples": samples,
        "resolved": resolved.where(np.isfinite(samples)),
    })
    if "scene_n_prisms" in ds.attrs:
        mu = momentum_share(ds, impact=impact)
        out["momentum_share"] = mu
        out["carries_impact"] = (mu >= carry_share).where(np.isfinite(mu))
    if "strain" in ds:
        share = lead_fraction(ds["strain"], float(ds.attrs.get("scene_height", H0)))
        share = share.transpose(*GRID_DIMS).where(ds["status"] == 0)
        out["lead_share"] = share
        out["compact"] = (share >= compact_share).where(np.isfinite(share))
    return out
