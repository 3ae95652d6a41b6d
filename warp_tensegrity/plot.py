"""Figures of sweep datasets: phase diagrams, space-time maps, pulse profiles, work-precision charts,
band diagrams.

Each function takes a dataset (or DataArray) in the layout the CLI writes (``warp-tensegrity run``,
:meth:`BatchResult.to_xarray`), draws on ``ax`` (a new figure when None) and returns the Axes.
The artists keep the dataset's numbers (``ax.collections[0].get_array()``, ``line.get_ydata()``),
which is what ``tests/test_plot.py`` checks. ``warp-tensegrity plot`` and the notebooks in
``analysis/`` use these functions; matplotlib is imported only here.

Units: strain [1] ((h - h0)/h, negative in compression), time ``t`` [s], speed [m s-1].
"""

from __future__ import annotations

import errno as _errno
import os
import re
from contextlib import nullcontext
from pathlib import Path

import numpy as np

from .atomic import oserror_line, replacing
from .scene.columns import ColumnConfig
from .types import TIME  # xarray and matplotlib load on first use: `warp-tensegrity --help` stays instant
from .validation.dispersion import Bands, bands, ringing_frequency

KINDS = {
    "phase": "a measured variable over two swept parameters",
    "spacetime": "strain over prism and time, one column",
    "profile": "strain against prism at a few times, one column",
    "work-precision": "error against cost of a work-precision study (benchmarks/work_precision.py)",
    "dispersion": "band diagram omega(k) of one column's periodic prism, with its measured speed and ringing",
}

STRAIN_LABEL = r"axial strain $\varepsilon = (h - h_0)/h$ [-]"
PRISM_LABEL = "prism j (0: clamped end; impact at the last)"


class PlotError(ValueError):
    """A figure cannot be drawn from this dataset as asked; the message says why."""


def _axes(ax):
    if ax is None:
        import matplotlib.pyplot as plt

        _, ax = plt.subplots(layout="constrained")
    return ax


def _drawable(text: str) -> str:
    """``text`` as a figure may show it: each line unchanged where it holds no mathtext (``$...$``)
    or its mathtext parses, else with every ``$`` escaped, so it is drawn as plain text. A dataset's
    title, labels and attributes are the user's, and matplotlib raises on bad mathtext only when
    the figure is drawn. Line by line, as matplotlib lays text out."""
    from matplotlib import cbook
    from matplotlib.mathtext import MathTextParser

    lines = str(text).split("\n")
    for i, line in enumerate(lines):
        if cbook.is_math_text(line):
            try:
                MathTextParser("path").parse(line)
            except ValueError:  # pyparsing's ParseException, as matplotlib raises it
                lines[i] = re.sub(r"(?<!\\)\$", r"\\$", line)
    return "\n".join(lines)


def _label(da, name: str) -> str:
    lab = da.attrs.get("long_name", name)
    units = da.attrs.get("units")
    return _drawable(f"{lab} [{units}]" if units and units != "1" else str(lab))


def _short_label(da, name: str) -> str:
    units = da.attrs.get("units")
    return _drawable(f"{name} [{units}]" if units and units != "1" else name)


def robust_limit(values, q: float = 99.5) -> float:
    """Symmetric colour limit: the q-th percentile of |values| (finite ones), so that one spike at
    the impacted end does not wash out a map; > 0."""
    a = np.abs(np.asarray(values, dtype=float))
    a = a[np.isfinite(a)]
    v = float(np.percentile(a, q)) if a.size else 1.0
    return v if v > 0 else 1.0


def cell_edges(centres, log: bool = False) -> np.ndarray:
    """Edges of cells centred on ``centres`` (midpoints; geometric midpoints when ``log``; the end
    cells are symmetric about their centre). A single centre gets a cell of +-50 % (log) or +-0.5."""
    c = np.asarray(centres, dtype=float)
    if log:
        return np.exp(cell_edges(np.log(c)))
    if c.size == 1:
        return np.array([c[0] - 0.5, c[0] + 0.5])
    mid = 0.5 * (c[1:] + c[:-1])
    return np.concatenate([[2 * c[0] - mid[0]], mid, [2 * c[-1] - mid[-1]]])


def _select(obj, sel: dict | None):
    """Nearest-value selection that names the dimension and the values on a miss. A parameter
    fixed in the file (a scalar coordinate) may be given at its value, which selects nothing."""
    for name, value in (sel or {}).items():
        if name not in obj.dims and name not in obj.coords:
            raise PlotError(f"no dimension {name!r} to select (dims: {', '.join(map(str, obj.dims))})")
        if name not in obj.dims:  # a coordinate without an index: xarray's error names its internals
            _check_fixed(obj[name], name, value)
            continue
        try:
            obj = obj.sel({name: value}, method=None if isinstance(value, str) or name == "case" else "nearest")
        except (KeyError, ValueError, TypeError) as e:
            raise PlotError(f"{name} = {value!r} not found ({e})") from None
    return obj


def _check_fixed(coord, name: str, value) -> None:
    """PlotError unless ``value`` is the value of ``name``, a parameter fixed in the file; or, for a
    coordinate along another dimension (a case list's parameters along ``case``), how to pick."""
    if coord.ndim:
        raise PlotError(f"{name} is not a dimension of this file: it lies along {', '.join(map(str, coord.dims))} "
                        f"({_how_to_select(str(coord.dims[0]))})")
    fixed = coord.values.item()
    if isinstance(fixed, str) or isinstance(value, str):
        same = fixed == value
    else:
        same = bool(np.isclose(fixed, value, rtol=1e-9, atol=0.0))
    if not same:
        shown = f"{fixed:g}" if isinstance(fixed, float) else str(fixed)
        raise PlotError(f"{name} = {value!r}: {name} is fixed at {shown} in this file (not swept); leave it out")


def _how_to_select(dim: str) -> str:
    """How to pick one value of ``dim``, for the command line and for Python."""
    return f"--sel {dim}=VALUE on the command line, sel={{{dim!r}: VALUE}} in Python"


TITLE_COORDS = ("case", "case_label", "prestrain", "v0", "base_rigidity")
"""Scalar coordinates a figure's title names (which column, or the fixed parameters of a map)."""


def selection_text(ds, sel: dict | None, exclude=()) -> str:
    """'case = 9 (Fig. 7a ...), prestrain = 0.002, ...': the parameters fixed in the figure of ``ds``
    after ``sel`` (selected, or not swept), those on an axis (``exclude``) left out."""
    picked = _select(ds, sel)
    parts = []
    for k in dict.fromkeys([*TITLE_COORDS, *(sel or {})]):
        if k in picked.coords and picked[k].ndim == 0 and k not in exclude:
            v = picked[k].values.item() if hasattr(picked[k].values, "item") else picked[k].values
            parts.append(f"{k} = {v:g}" if isinstance(v, float) else f"{k} = {v}")
    return ", ".join(parts)


def _strain_of_one_column(data, sel: dict | None):
    if hasattr(data, "data_vars"):  # a Dataset
        if "strain" not in data:
            raise PlotError("the dataset has no strain: run with record_strain = true")
        data = data["strain"]
    da = _select(data, sel)
    extra = [d for d in da.dims if d not in (TIME, "prism")]
    if extra:
        raise PlotError(f"pick one column first: give a value for {', '.join(map(str, extra))} "
                        f"({_how_to_select(extra[0])})")
    return da.transpose(TIME, "prism")


# ---------------------------------------------------------------------- figures
def phase_diagram(data, var: str = "speed", x: str | None = None, y: str | None = None, ax=None,
                  sel: dict | None = None, log_y: bool | None = None, colorbar: bool = True,
                  cbar_label: str | None = None, **pcolormesh_kw):
    """Colour map of the measured variable ``var`` over the swept parameters ``x`` and ``y`` of a
    grid sweep (defaults: the first two grid dimensions), one cell per grid point; columns whose
    status is not ok are blank, and those that left the model's feasible set (``feasibility_flag``
    not 0: bars crossed, cables touched, a prism inverted; docs/model.md) are hatched (``ax.patches``). ``data``: the dataset, or a DataArray over the grid (e.g. a derived
    quantity; then ``var`` is ignored). Other grid dimensions must be fixed with ``sel``. ``log_y``
    (default: when y spans more than a decade and is > 0) uses geometric cell edges. Returns the Axes;
    ``ax.collections[-1].get_array()`` is the variable with y as rows."""
    if hasattr(data, "data_vars"):
        if var not in data:
            raise PlotError(f"no variable {var!r} in the dataset (have: {', '.join(map(str, data.data_vars))})")
        da = data[var].where(data["status"] == 0) if "status" in data else data[var]
    else:
        da, var = data, str(data.name)
    da = _select(da, sel)
    dims = [d for d in da.dims if d not in ("prism", TIME)]
    if "case" in dims:
        raise PlotError("a phase diagram needs a grid sweep ([sweep] grid = ...); this dataset is a case list")
    x = x or (dims[0] if dims else None)
    y = y or next((d for d in dims if d != x), None)
    if x is None or y is None or x not in dims or y not in dims:
        raise PlotError(f"give x and y among the grid dimensions {dims}")
    rest = [d for d in dims if d not in (x, y)]
    if rest:
        raise PlotError(f"fix the other grid dimensions: {', '.join(rest)} ({_how_to_select(rest[0])})")
    d = da.transpose(y, x, ...)
    if d.ndim != 2:
        raise PlotError(f"{var} is not a per-column variable (dims {da.dims})")
    yv = d[y].values.astype(float)
    if log_y is None:
        log_y = bool(np.all(yv > 0) and yv.max() / yv.min() > 10)
    ax = _axes(ax)
    kw = {"cmap": "viridis", "shading": "flat"}
    kw.update(pcolormesh_kw)
    xe, ye = cell_edges(d[x].values), cell_edges(yv, log=log_y)
    mesh = ax.pcolormesh(xe, ye, np.ma.masked_invalid(d.values), **kw)
    if hasattr(data, "data_vars") and "feasibility_flag" in data:
        _hatch(ax, _select(data["feasibility_flag"], sel).transpose(y, x).values != 0, xe, ye)
    if log_y:
        ax.set_yscale("log")
    from matplotlib.ticker import MaxNLocator

    ax.xaxis.set_major_locator(MaxNLocator(5))
    ax.set_xlabel(_label(d[x], x))
    ax.set_ylabel(_label(d[y], y))
    if colorbar:
        cb = ax.figure.colorbar(mesh, ax=ax, pad=0.01)
        cb.set_label(cbar_label if cbar_label is not None else _short_label(da, var))
    return ax


def _hatch(ax, cells, xe, ye):
    """Hatch the cells (rows y, columns x) where ``cells`` is True, with one legend entry."""
    from matplotlib.patches import Rectangle

    kw = {"fill": False, "hatch": "///", "edgecolor": "0.3", "linewidth": 0.0}
    for k, i in zip(*np.nonzero(cells)):
        ax.add_patch(Rectangle((xe[i], ye[k]), xe[i + 1] - xe[i], ye[k + 1] - ye[k], **kw))
    if cells.any():
        ax.legend(handles=[Rectangle((0, 0), 1, 1, **kw, label="left the feasible set")], loc="upper left",
                  fontsize="small", framealpha=0.8)


def spacetime(data, ax=None, sel: dict | None = None, vmax: float | None = None, cmap: str = "RdBu_r",
              colorbar: bool = True, cbar_label: str = STRAIN_LABEL):
    """Space-time map of one column's strain: prism on x, time on y, a diverging colour map centred at
    0 (blue: compression), limits +-``vmax`` (default :func:`robust_limit`). ``data``: a dataset
    (pick the column with ``sel``, e.g. ``{"case": 3}``) or a (t, prism) DataArray in any order.
    Returns the Axes; ``ax.collections[0].get_array()`` is the strain, time-major."""
    from matplotlib import colors

    s = _strain_of_one_column(data, sel)
    v = robust_limit(s.values) if vmax is None else float(vmax)
    ax = _axes(ax)
    mesh = ax.pcolormesh(s["prism"].values, s[TIME].values, s.values, cmap=cmap, shading="nearest",
                         norm=colors.TwoSlopeNorm(vcenter=0.0, vmin=-v, vmax=v), rasterized=True)
    ax.set_xlabel(PRISM_LABEL)
    ax.set_ylabel("time t [s]")
    if colorbar:
        cb = ax.figure.colorbar(mesh, ax=ax, extend="both", pad=0.01)
        cb.set_label(cbar_label)
        cb.formatter.set_powerlimits((-2, 2))
        cb.update_ticks()
    return ax


def pulse_profile(data, times=None, ax=None, sel: dict | None = None, cmap: str = "viridis", marker: str = "."):
    """Strain against prism at the output times nearest to ``times`` [s] (default: five times evenly
    over the record), one line each, labelled with the time actually drawn: the paper's "time
    shots". Returns the Axes; each line's y-data is the dataset's strain at that time."""
    import matplotlib.pyplot as plt

    s = _strain_of_one_column(data, sel)
    t = s[TIME].values
    if times is None:
        times = t[np.linspace(0, len(t) - 1, 5).round().astype(int)]
    ax = _axes(ax)
    cm = plt.get_cmap(cmap)
    n = len(times)
    for i, ti in enumerate(times):
        si = s.sel({TIME: ti}, method="nearest")
        ax.plot(s["prism"].values, si.values, marker=marker, color=cm(0.9 * i / max(n - 1, 1)),
                label=f"t = {float(si[TIME]):g} s")
    ax.axhline(0.0, color="0.6", lw=0.6, zorder=0)
    ax.set_xlabel(PRISM_LABEL)
    ax.set_ylabel(STRAIN_LABEL)
    ax.set_xlim(s["prism"].values[0] - 0.5, s["prism"].values[-1] + 0.5)
    ax.legend()
    return ax


def work_precision(ds, measure: str = "speed", case=None, cost: str = "cost_device", ax=None):
    """Error of ``measure`` against cost for every method and precision of a work-precision study
    (the dataset ``benchmarks/work_precision.py`` writes: ``err_<measure>`` over (method, precision,
    k, case) and ``cost`` over (method, precision, k)), log-log; fp64 solid, fp32 dashed; a star at
    ``dt = "auto"`` where the study has it. ``case``: a case label (default: the worst case, max over
    cases). Returns the Axes; each line's (x, y) are the study's (cost, error) with non-positive errors left out."""
    ev = f"err_{measure}"
    if ev not in ds or cost not in ds:
        raise PlotError(f"not a work-precision study: needs {ev!r} and {cost!r} (have: {', '.join(map(str, ds.data_vars))})")
    err = ds[ev].max("case") if case is None else _select(ds[ev], {"case": case})
    ax = _axes(ax)
    for method in ds["method"].values:
        for prec in ds["precision"].values:
            sel = {"method": method, "precision": prec}
            xv, yv = ds[cost].sel(sel).values, err.sel(sel).values
            ok = np.isfinite(xv) & np.isfinite(yv) & (yv > 0)
            (ln,) = ax.plot(xv[ok], yv[ok], "-" if prec == "fp64" else "--", marker="o" if prec == "fp64" else "^",
                            ms=3.5, label=f"{method} {prec}")
            auto_e, auto_c = f"auto_{ev}", f"auto_{cost}"
            if auto_e in ds and auto_c in ds:
                ae = ds[auto_e].max("case") if case is None else ds[auto_e].sel(case=case)
                ya, xa = float(ae.sel(sel)), float(ds[auto_c].sel(sel))
                if np.isfinite(ya) and ya > 0:
                    ax.plot([xa], [ya], marker="*", ms=9, color=ln.get_color(), mec="k", mew=0.5, ls="none")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel(_label(ds[cost], cost))
    ax.set_ylabel(f"relative error of {measure}" + (" (max over cases)" if case is None else f" ({case})"))
    ax.grid(True, which="major", alpha=0.3)
    ax.legend(fontsize=7)
    return ax


def _column_scene(ds, sel: dict | None):
    """(ColumnConfig, prestrain, base_rigidity, cable_EA, unit_mass, column) of one column of a dataset."""
    import dataclasses

    kw = {}
    for f in dataclasses.fields(ColumnConfig):
        key = f"scene_{f.name}"
        if key not in ds.attrs:
            raise PlotError(f"the dataset has no {key!r} attribute: not written by warp-tensegrity")
        kw[f.name] = type(f.default)(ds.attrs[key]) if not isinstance(f.default, str) else str(ds.attrs[key])
    col = _select(ds, sel)
    for p in ("prestrain", "cable_EA", "unit_mass"):  # a profile along the column (docs/sweeps.md, Profiles)
        along = [d for d in ("prism", "level") if p in col.coords and d in col[p].dims]
        if along and col[p].ndim == 1 and np.all(col[p].values == col[p].values[0]):
            col = col.assign_coords({p: col[p].values[0]})
        elif along and col[p].ndim == 1:
            raise PlotError(f"{p} varies along the column (a profile over {along[0]}): a band diagram is of a "
                            "uniform periodic column")
    extra = [d for d in col.dims if d not in (TIME, "prism", "level")]
    if extra:
        raise PlotError(f"pick one column first: give a value for {', '.join(map(str, extra))} (e.g. --sel {extra[0]}=...)")
    hand = kw["handedness"]
    if hand not in ("right", "left"):
        letters = set(hand.upper()) if len(hand) == kw["n_prisms"] else set()
        if letters not in ({"R"}, {"L"}):
            raise PlotError(f"handedness = {hand!r}: a band diagram needs prisms of one handedness")
        hand = "right" if letters == {"R"} else "left"
    cfg = ColumnConfig(**{**kw, "n_prisms": 1, "handedness": hand, "bar_mass": 0.0})
    par = {p: float(col[p]) if p in col.coords else None for p in ("prestrain", "base_rigidity", "cable_EA", "unit_mass")}
    if par["prestrain"] is None or par["base_rigidity"] is None:
        raise PlotError("the dataset has no prestrain or base_rigidity coordinate")
    return cfg, par, col


def dispersion(data, ax=None, sel: dict | None = None, speed: float | None = None, cutoff: float | None = None,
               n_k: int = 121, omega_max: float | None = None):
    """Band diagram of the periodic column: omega [rad s-1] against the Bloch wavenumber k h0 [rad]
    (:func:`warp_tensegrity.validation.dispersion.bands`). Every branch in grey, the 3-fold symmetric
    (axial-torsional) branches an axial impact excites in colour; a measured front ``speed`` [m s-1]
    as the line omega = speed k (dashed) and a measured ``cutoff`` [rad s-1] as a horizontal line
    (dotted). ``data``: a :class:`~warp_tensegrity.validation.dispersion.Bands`, or a dataset with
    ``sel`` picking one column: its scene, prestrain and base rigidity give the bands, its
    ``speed`` measure and the ringing of its struck prism (``validation.dispersion.ringing_frequency``,
    when the strain is recorded) the speed and cut-off, unless given. ``omega_max``: upper limit of
    the axis (default: 1.1 x the highest branch). Returns the Axes; ``ax.lines`` keep the numbers
    (symmetric branches labelled ``symmetric branch i``)."""
    title = None
    if isinstance(data, Bands):
        b = data
    else:
        cfg, par, col = _column_scene(data, sel)
        b = bands(cfg, par["prestrain"], par["base_rigidity"], n_k=n_k, cable_EA=par["cable_EA"], unit_mass=par["unit_mass"])
        if speed is None and "speed" in col:
            speed = float(col["speed"])
        if cutoff is None and "strain" in col:
            cutoff = ringing_frequency(col["strain"].transpose(TIME, "prism").values, col[TIME].values)
        title = f"p = {par['prestrain']:g}, base rigidity = {par['base_rigidity']:g}"
    ax = _axes(ax)
    x = b.k * b.height
    for i in range(b.omega.shape[1]):
        ax.plot(x, b.omega[:, i], color="0.75", lw=0.8, label="all branches" if i == 0 else None)
    for i in range(b.omega_symmetric.shape[1]):
        ax.plot(x, b.omega_symmetric[:, i], color=f"C{i}", lw=1.6, label=f"symmetric branch {i + 1}")
    top = float(np.nanmax(b.omega_symmetric))
    if speed is not None and np.isfinite(speed):
        xs = x[x * speed / b.height <= 1.3 * (top if omega_max is None else omega_max)]
        ax.plot(xs, speed / b.height * xs, "k--", lw=0.9, label=f"measured speed {speed:.4g} m/s")
    if cutoff is not None and np.isfinite(cutoff):
        ax.axhline(cutoff, color="k", ls=":", lw=0.9, label=f"measured ringing {cutoff:.4g} rad/s")
    ax.set_xlim(0.0, np.pi)
    ax.set_ylim(0.0, 1.1 * float(np.nanmax(b.omega)) if omega_max is None else float(omega_max))
    ax.set_xlabel(r"Bloch wavenumber $k h_0$ [rad]")
    ax.set_ylabel(r"$\omega$ [rad s$^{-1}$]")
    if title:
        ax.set_title(title, fontsize=9)
    ax.legend(fontsize=7)
    return ax


# ---------------------------------------------------------------------- the CLI's entry
def plot_file(path, kind: str, var: str = "speed", x=None, y=None, sel: dict | None = None, times=None,
              output=None):
    """Open ``path`` and draw one figure of ``kind`` (:data:`KINDS`); returns the Figure.
    ``output``: also save it there, atomically (format from the suffix, png without one); a place
    that cannot be written is refused before anything is opened or drawn."""
    from .io import open_sweep  # imports xarray: not at `--help`

    if kind not in KINDS:
        raise PlotError(f"plot kind {kind!r}: give one of {', '.join(sorted(KINDS))}")
    fmt = _figure_format(output) if output is not None else None
    try:
        with replacing(output) if output is not None else nullcontext() as tmp:  # made before drawing: an
            try:                                                                 # unwritable place is refused first
                ds = open_sweep(path)
            except (OSError, ValueError) as e:
                raise PlotError(f"{path} does not open as netCDF ({e})") from None
            fig = _draw(ds, kind, var, x, y, sel, times)
            if tmp is not None:
                fig.savefig(tmp, format=fmt)
    except OSError as e:
        raise PlotError(oserror_line(e, output)) from None
    return fig


def _figure_format(output) -> str:
    """The format of a figure file from its suffix (png without one); PlotError naming the path
    where matplotlib has no such format or the path is a directory."""
    from matplotlib.backend_bases import FigureCanvasBase

    out = Path(output)
    fmt = out.suffix[1:].lower() or "png"
    formats = FigureCanvasBase.get_supported_filetypes()
    if fmt not in formats:
        raise PlotError(f"{out}: no figure format {fmt!r} (give one of {', '.join(sorted(formats))})")
    if out.is_dir():
        raise PlotError(oserror_line(IsADirectoryError(_errno.EISDIR, os.strerror(_errno.EISDIR)), out))
    return fmt


def _draw(ds, kind: str, var: str, x, y, sel: dict | None, times):
    sel = dict(sel or {})
    if kind == "phase":
        ax = phase_diagram(ds, var=var, x=x, y=y, sel=sel)
    elif kind == "spacetime":
        ax = spacetime(ds, sel=sel)
    elif kind == "profile":
        ax = pulse_profile(ds, times=times, sel=sel)
    elif kind == "dispersion":
        ax = dispersion(ds, sel=sel)
    else:
        ax = work_precision(ds, measure=var, case=sel.pop("case", None))
    title = str(ds.attrs.get("title") or "")
    if kind != "work-precision":  # which column (or which fixed parameters) the figure shows
        axes = {x or "", y or ""} if kind == "phase" else set()
        shown = selection_text(ds, sel, exclude=axes | {"case"} if kind == "phase" else axes)
        title = "\n".join(t for t in (title, shown) if t)
    if title:
        ax.set_title(_drawable(title), fontsize=9)
    return ax.figure


