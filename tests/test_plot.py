"""warp_tensegrity.plot: each figure holds the dataset's numbers; the `plot` subcommand draws them
in-process; bad requests get a PlotError naming what is missing."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402
import xarray as xr  # noqa: E402

from warp_tensegrity import cli  # noqa: E402
from warp_tensegrity import plot as W  # noqa: E402
from warp_tensegrity.io import write_netcdf  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent


def grid_dataset() -> xr.Dataset:
    p, v, b = np.array([0.0, 0.001, 0.002]), np.array([0.001, 0.01, 0.1]), np.array([0.0, 1.0])
    t, prism = np.linspace(0, 1, 21), np.arange(6)
    rng = np.random.default_rng(1)
    speed = rng.random((3, 3, 2))
    status = np.zeros((3, 3, 2), dtype=np.int8)
    status[2, 0, 1] = 1
    strain = -rng.random((3, 3, 2, 21, 6)) * 1e-3
    return xr.Dataset(
        {"speed": (("prestrain", "v0", "base_rigidity"), speed, {"long_name": "speed", "units": "m s-1"}),
         "status": (("prestrain", "v0", "base_rigidity"), status),
         "strain": (("prestrain", "v0", "base_rigidity", "t", "prism"), strain)},
        coords={"prestrain": p, "v0": v, "base_rigidity": b, "t": t, "prism": prism},
        attrs={"title": "test grid"})


def test_phase_diagram_holds_the_variable_and_blanks_failed_columns():
    ds = grid_dataset()
    ax = W.phase_diagram(ds, "speed", sel={"base_rigidity": 1.0})
    arr = ax.collections[-1].get_array()
    want = ds.speed.sel(base_rigidity=1.0).where(ds.status.sel(base_rigidity=1.0) == 0).transpose("v0", "prestrain")
    np.testing.assert_array_equal(np.ma.filled(arr, np.nan).ravel(), want.values.ravel())
    assert np.ma.getmaskarray(arr).sum() == 1  # the failed column
    assert ax.get_yscale() == "log" and "m s-1" in ax.figure.axes[-1].get_ylabel()  # colour bar label
    plt.close("all")


def test_phase_diagram_refuses_what_it_cannot_draw():
    ds = grid_dataset()
    with pytest.raises(W.PlotError, match="base_rigidity"):
        W.phase_diagram(ds, "speed")  # a third grid dim left free
    with pytest.raises(W.PlotError, match="no variable 'width'"):
        W.phase_diagram(ds, "width", sel={"base_rigidity": 0.0})
    cases = ds.stack(case=("prestrain", "v0", "base_rigidity")).reset_index("case")
    with pytest.raises(W.PlotError, match="case list"):
        W.phase_diagram(cases, "speed")


def test_spacetime_and_profile_hold_the_strain():
    ds = grid_dataset()
    sel = {"prestrain": 0.001, "v0": 0.01, "base_rigidity": 0.0}
    s = ds.strain.sel(sel)
    ax = W.spacetime(ds, sel=sel)
    np.testing.assert_array_equal(np.asarray(ax.collections[-1].get_array()).ravel(), s.transpose("t", "prism").values.ravel())
    ax = W.pulse_profile(ds, times=[0.25, 0.5], sel=sel)
    np.testing.assert_array_equal(ax.lines[0].get_ydata(), s.sel(t=0.25).values)
    assert ax.lines[1].get_label() == "t = 0.5 s"
    with pytest.raises(W.PlotError, match="pick one column"):
        W.spacetime(ds, sel={"v0": 0.01})
    plt.close("all")


def test_work_precision_chart_of_the_stored_study():
    ds = xr.open_dataset(ROOT / "analysis" / "data" / "wp_cuda0.nc").load()
    ax = W.work_precision(ds, "speed")
    ln = next(line for line in ax.lines if line.get_label() == "rattle fp64")
    pick = {"method": "rattle", "precision": "fp64"}  # a dict: method= is also sel's own keyword
    x, y = ds.cost_device.sel(pick).values, ds.err_speed.max("case").sel(pick).values
    ok = np.isfinite(y) & (y > 0) & np.isfinite(x)
    np.testing.assert_array_equal(ln.get_xdata(), x[ok])
    np.testing.assert_array_equal(ln.get_ydata(), y[ok])
    assert ax.get_xscale() == ax.get_yscale() == "log"
    plt.close("all")


def test_plot_subcommand(tmp_path, capsys):
    nc = write_netcdf(grid_dataset(), tmp_path / "g.nc")
    assert cli.main(["plot", str(nc), "phase", "--sel", "base_rigidity=0", "-o", str(tmp_path / "p.png")]) == 0
    assert (tmp_path / "p.png").stat().st_size > 1000
    assert cli.main(["plot", str(nc), "spacetime", "--sel", "prestrain=0", "--sel", "v0=0.1",
                     "--sel", "base_rigidity=1"]) == 0
    assert (tmp_path / "g-spacetime.png").exists()
    assert cli.main(["plot", str(nc), "phase"]) == 1
    err = capsys.readouterr().err  # in the CLI's own terms (issue 23: it said sel={...})
    assert "fix the other grid dimensions: base_rigidity (--sel base_rigidity=VALUE" in err, err
    assert cli.main(["plot", str(nc), "spacetime", "--sel", "prestrain=0"]) == 1
    assert "--sel v0=VALUE" in capsys.readouterr().err


def test_titles_name_the_column_and_the_fixed_parameters(tmp_path):
    """A figure's title says which column it shows (case and label) and what a map holds fixed
    (issue 23: `plot paper_2017.nc profile --sel case=9` did not say which case)."""
    nc = write_netcdf(grid_dataset(), tmp_path / "g.nc")
    fig = W.plot_file(nc, "phase", sel={"base_rigidity": 1.0})
    assert fig.axes[0].get_title() == "test grid\nbase_rigidity = 1"
    plt.close(fig)
    cases = grid_dataset().stack(case=("prestrain", "v0", "base_rigidity")).reset_index("case")
    cases = cases.assign_coords(case=np.arange(cases.sizes["case"]),
                                case_label=("case", [f"run {i}" for i in range(cases.sizes["case"])]))
    nc = write_netcdf(cases, tmp_path / "c.nc")
    fig = W.plot_file(nc, "profile", sel={"case": 9})
    title = fig.axes[0].get_title()
    assert title.endswith("case = 9, case_label = run 9, prestrain = 0.001, v0 = 0.01, base_rigidity = 1"), title
    plt.close(fig)


def test_a_title_that_is_not_valid_mathtext_is_drawn_as_plain_text(tmp_path, capsys):
    """Issue 30 item 7: a spec title with `$...$` that matplotlib cannot parse raised its
    ParseSyntaxException when the figure was saved; now the `$` are escaped and it is drawn as it
    reads. A title whose mathtext parses keeps it."""
    bad, good = r"strain $\frac{1$ of p", r"rigid bases, $\beta = 1$"
    for title, shown in ((bad, r"strain \$\frac{1\$ of p"), (good, good)):
        ds = grid_dataset()
        ds.attrs["title"] = title
        nc = write_netcdf(ds, tmp_path / "m.nc")
        for kind in ("spacetime", "profile", "phase"):
            png = tmp_path / f"{kind}.png"
            sel = ["--sel", "base_rigidity=1"] + (["--sel", "prestrain=0", "--sel", "v0=0.1"] if kind != "phase" else [])
            assert cli.main(["plot", str(nc), kind, *sel, "-o", str(png)]) == 0, capsys.readouterr().err
            assert png.stat().st_size > 1000
            fig = W.plot_file(nc, kind, sel={k: float(v) for k, v in (s.split("=") for s in sel[1::2])})
            assert fig.axes[0].get_title().split("\n")[0] == shown
            plt.close("all")


def test_plot_output_that_cannot_be_written_is_refused_before_drawing(tmp_path, capsys, monkeypatch):
    """Issue 30 item 8: `plot -o` into an unwritable place drew the figure, then raised a
    PermissionError traceback. Now one line names the path and the errno, before the dataset is
    opened or anything drawn; an existing figure is replaced only by a complete one."""
    nc = write_netcdf(grid_dataset(), tmp_path / "g.nc")
    plain = tmp_path / "plain.txt"
    plain.write_text("x")
    (tmp_path / "adir").mkdir()
    drawn = []
    real_draw = getattr(W, "_draw", None)
    monkeypatch.setattr(W, "_draw", lambda *a: drawn.append(1) or real_draw(*a), raising=False)
    sel = ["--sel", "base_rigidity=1"]
    cases = [(plain / "p.png", "[Errno 20 ENOTDIR]"), (tmp_path / "missing" / "p.png", "[Errno 2 ENOENT]"),
             (tmp_path / "adir", "[Errno 21 EISDIR]"), (tmp_path / "p.xyz", "no figure format 'xyz'")]
    for out, words in cases:
        assert cli.main(["plot", str(nc), "phase", *sel, "-o", str(out)]) == 1
        err = capsys.readouterr().err
        assert f"error: cannot write {out}: {words}" in err or words in err, err
        assert "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    assert drawn == []

    import tempfile

    def refuse(*a, **k):
        raise PermissionError(13, "Permission denied", str(k.get("dir", "")))

    monkeypatch.setattr(tempfile, "mkdtemp", refuse)
    out = tmp_path / "ro.png"
    assert cli.main(["plot", str(nc), "phase", *sel, "-o", str(out)]) == 1
    assert f"error: cannot write {out}: Permission denied [Errno 13 EACCES]" in capsys.readouterr().err
    assert drawn == [] and not out.exists()
    monkeypatch.undo()
    monkeypatch.setattr(W, "_draw", lambda *a: drawn.append(1) or real_draw(*a), raising=False)
    # atomic: a figure that fails to draw leaves the earlier file as it was, and no temporary
    fig = tmp_path / "fig.png"
    assert cli.main(["plot", str(nc), "phase", *sel, "-o", str(fig)]) == 0
    before = fig.read_bytes()
    assert cli.main(["plot", str(nc), "phase", "-o", str(fig)]) == 1  # a grid dimension left free
    assert fig.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["adir", "fig.png", "g.nc", "plain.txt"]
    plt.close("all")


def test_sel_on_a_parameter_fixed_in_the_file(tmp_path, capsys):
    """Issue 30 item 15: `--sel` on a parameter the file holds fixed (a scalar coordinate) leaked
    xarray's "Could not automatically create PandasIndex". Its own value selects nothing; another
    value is refused with the value it is fixed at; a case list's parameter says how to pick a column."""
    nc = write_netcdf(grid_dataset().sel(base_rigidity=1.0), tmp_path / "fixed.nc")
    column = ["--sel", "prestrain=0", "--sel", "v0=0.1"]
    assert cli.main(["plot", str(nc), "spacetime", *column, "--sel", "base_rigidity=1", "-o", str(tmp_path / "a.png")]) == 0
    assert cli.main(["plot", str(nc), "spacetime", *column, "--sel", "base_rigidity=0.5", "-o", str(tmp_path / "b.png")]) == 1
    err = capsys.readouterr().err
    assert "base_rigidity = 0.5: base_rigidity is fixed at 1 in this file (not swept)" in err, err
    assert "PandasIndex" not in err and not (tmp_path / "b.png").exists()
    cases = grid_dataset().stack(case=("prestrain", "v0", "base_rigidity")).reset_index("case")
    nc = write_netcdf(cases.assign_coords(case=np.arange(cases.sizes["case"])), tmp_path / "c.nc")
    assert cli.main(["plot", str(nc), "profile", "--sel", "prestrain=0.001", "-o", str(tmp_path / "c.png")]) == 1
    err = capsys.readouterr().err
    assert "prestrain is not a dimension of this file: it lies along case (--sel case=VALUE" in err, err
    plt.close("all")
