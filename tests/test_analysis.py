"""Checks of the analysis helpers (analysis/plotting.py): the data each figure and table is made of.

Synthetic datasets with known pulses for the paper table and the phase-diagram numbers; one real
CI-sized sweep (sweeps/ci_small.toml, seconds on the CPU) for the dataset layout end to end.
"""

import subprocess
import sys
import tomllib
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402
import xarray as xr  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "analysis"))
import plotting as P  # noqa: E402

H = 6.2e-3


@pytest.fixture(autouse=True)
def _close_figures():
    yield
    plt.close("all")


# ---------------------------------------------------------------------- synthetic data
def travelling_pulse(amp, speed, t, n=50, width=1.5, start=None):
    """Compressive sech^2 pulse, strain (time, prism), launched at the impacted end."""
    j = np.arange(n)
    start = n - 1 if start is None else start
    x = start - speed * t[:, None] / H
    return -amp / np.cosh((j[None, :] - x) / width) ** 2


def paper_like_dataset(amps=None, speeds=None):
    """12 cases laid out as warp-tensegrity writes sweeps/paper_2017.toml, synthetic strain."""
    c = P.PAPER_2017
    amps = np.array([x.amplitude for x in c]) if amps is None else amps
    speeds = np.array([x.speed if np.isfinite(x.speed) else 0.3 for x in c]) if speeds is None else speeds
    t = np.round(np.arange(0, 1.5001, 0.01), 10)
    strain = np.stack([travelling_pulse(a, s, t) for a, s in zip(amps, speeds)])
    n = len(c)
    ds = xr.Dataset(
        {
            "strain": (("case", "t", "prism"), strain),
            "amplitude": ("case", amps * 1.01),
            "speed": ("case", speeds * 0.99),
            "width": ("case", np.full(n, 2.0)),
            "width_10": ("case", np.full(n, 3.5)),
            "prisms_measured": ("case", np.full(n, 40.0)),
            "energy_error": ("case", np.full(n, 1e-3)),
            "status": ("case", np.zeros(n, dtype=np.int8)),
        },
        coords={
            "case": np.arange(n), "t": t, "prism": np.arange(50),
            "base_rigidity": ("case", [x.base_rigidity for x in c]),
            "prestrain": ("case", [x.prestrain for x in c]),
            "v0": ("case", [x.v0 for x in c]),
            "case_label": ("case", [f"Fig. {x.figure}" for x in c]),
        },
        attrs={"scene_height": H},
    )
    return ds.isel(case=np.r_[6:12, 0:6])  # stored order must not matter


def grid_dataset(alpha_by_beta=(0.0, 0.5), n_p=3, n_v=5):
    """Grid sweep layout (prestrain, v0, base_rigidity): speed = 0.1 (v0 / 0.01)^alpha(beta)."""
    p = np.linspace(0.0, 0.01, n_p)
    v0 = np.geomspace(1e-3, 0.1, n_v)
    b = np.array([0.0, 1.0])[: len(alpha_by_beta)]
    al = np.array(alpha_by_beta)
    speed = 0.1 * (v0[None, :, None] / 0.01) ** al[None, None, :] * np.ones((n_p, 1, 1))
    amp = 0.5 * v0[None, :, None] ** (2 * al[None, None, :] + (al == 0)) * np.ones((n_p, 1, 1))
    dims = ("prestrain", "v0", "base_rigidity")
    ds = xr.Dataset(
        {"speed": (dims, speed), "amplitude": (dims, amp), "width": (dims, np.full(speed.shape, 2.0)),
         "width_10": (dims, np.full(speed.shape, 4.0)), "status": (dims, np.zeros(speed.shape, np.int8))},
        coords={"prestrain": p, "v0": v0, "base_rigidity": b},
    )
    ds["status"][0, 0, 0] = 2  # a failed column
    return ds


# ---------------------------------------------------------------------- the paper's numbers
def test_paper_cases_follow_the_spec():
    spec = tomllib.loads((ROOT / "sweeps" / "paper_2017.toml").read_text())
    cases = spec["sweep"]["cases"]
    assert len(P.PAPER_2017) == len(cases) == 12
    for c, s in zip(P.PAPER_2017, cases):
        assert (c.base_rigidity, c.prestrain, c.v0) == (s["base_rigidity"], s["prestrain"], s["v0"])
        assert s["label"].startswith(f"Fig. {c.figure} {c.base}")
    # the paper's text, Sec. 4 (amplitudes in the order of Figs. 4-7)
    assert [c.amplitude for c in P.PAPER_2017] == [7.19e-4, 1.44e-3, 3.59e-3, 7.33e-3, 1.25e-2, 1.77e-2,
                                                   5.4e-2, 6.97e-2, 8.5e-2, 8.93e-2, 0.106, 0.106]
    sp = [c.speed for c in P.PAPER_2017]
    assert np.isnan(sp[7]) and [x for i, x in enumerate(sp) if i != 7] == [
        0.248, 0.248, 0.248, 0.0248, 0.031, 0.0496, 0.248, 0.372, 0.186, 0.248, 0.248]


def test_paper_speeds_are_whole_prisms_per_second():
    sp = np.array([c.speed for c in P.PAPER_2017 if np.isfinite(c.speed)]) / H
    np.testing.assert_allclose(sp, np.round(sp), atol=1e-9)


def test_reproduction_table_holds_paper_and_ours():
    ds = paper_like_dataset()
    df = P.reproduction_table(ds, t_read=0.5)
    assert list(df.figure) == [c.figure for c in P.PAPER_2017]
    np.testing.assert_array_equal(df.paper_amplitude, [c.amplitude for c in P.PAPER_2017])
    np.testing.assert_array_equal(df.paper_speed, [c.speed for c in P.PAPER_2017])
    np.testing.assert_array_equal(df.paper_span, [c.span for c in P.PAPER_2017])
    order = P.match_cases(ds)
    np.testing.assert_array_equal(df.amplitude, ds.amplitude.values[order])
    np.testing.assert_array_equal(df.speed, ds.speed.values[order])
    np.testing.assert_array_equal(df.width_10, ds.width_10.values[order])
    np.testing.assert_allclose(df.amplitude_ratio, df.amplitude / df.paper_amplitude)
    np.testing.assert_allclose(df.speed_prisms, df.speed / H)
    # the synthetic pulse is sech^2 of the paper's amplitude: the t = 0.5 s reading is its sampled maximum
    assert np.all(df.amp_t <= df.paper_amplitude * (1 + 1e-12))
    assert np.all(df.amp_t >= df.paper_amplitude / np.cosh(0.5 / 1.5) ** 2 * (1 - 1e-12))
    np.testing.assert_allclose(df.max_t, df.amp_t)  # one pulse only


def test_match_cases_refuses_missing_case():
    ds = paper_like_dataset().isel(case=slice(0, 11))
    with pytest.raises(KeyError, match="found 0 times"):
        P.match_cases(ds)


def test_leading_pulse_at_reads_the_snapshot():
    t = np.arange(0, 2.0001, 0.01)
    c, a = 0.1, 0.02
    da = xr.DataArray(travelling_pulse(a, c, t), dims=("t", "prism"), coords={"t": t, "prism": np.arange(50)})
    r = P.leading_pulse_at(da, 0.5)
    pos = 49 - c * 0.5 / H
    assert r["time"] == pytest.approx(0.5)
    assert int(r["prism"]) == round(pos)
    assert float(r["amplitude"]) == pytest.approx(float(-da.sel(t=0.5).values.min()))
    assert float(r["width"]) == pytest.approx(2 * 1.5 * np.arccosh(np.sqrt(2)), rel=0.08)
    assert float(r["support"]) >= 5


def test_reading_interval_and_power_law():
    assert P.reading_interval(0.272, 0.248) == pytest.approx(H / 0.024)
    assert np.isinf(P.reading_interval(0.1, 0.1))
    x = np.geomspace(1e-3, 1e-2, 6)
    b, a = P.power_law_fit(x, 3.0 * x**0.5)
    assert b == pytest.approx(0.5) and a == pytest.approx(3.0)
    assert np.isnan(P.power_law_fit([1.0], [1.0])[0])


# ---------------------------------------------------------------------- strain figures
def test_strain_snapshots_plot_the_dataset():
    ds = paper_like_dataset()
    s = ds.strain.isel(case=0)
    fig, ax = plt.subplots()
    lines = P.strain_snapshots(ax, s, [0.25, 0.5, 0.7449])
    assert len(lines) == 3
    for ln, t in zip(lines, [0.25, 0.5, 0.74]):
        np.testing.assert_array_equal(ln.get_xdata(), ds.prism.values)
        np.testing.assert_array_equal(ln.get_ydata(), s.sel(t=t).values)
        assert ln.get_label() == f"t = {t:g} s"
    assert "strain" in ax.get_ylabel() and "prism" in ax.get_xlabel()


def test_spacetime_map_array_is_the_strain():
    ds = paper_like_dataset()
    s = ds.strain.isel(case=3)
    fig, ax = plt.subplots()
    mesh, cb = P.spacetime_map(ax, s.transpose("prism", "t"))  # any dim order in
    np.testing.assert_array_equal(np.asarray(mesh.get_array()).reshape(s.shape), s.values)
    norm = mesh.norm
    assert norm.vcenter == 0.0 and norm.vmin == -norm.vmax > -np.inf
    assert cb is not None and "strain" in cb.ax.get_ylabel()
    assert ax.get_ylabel() == "time t [s]"
    ln = P.overlay_peak_track(ax, np.linspace(1, 0, 50), ds.prism.values)
    np.testing.assert_array_equal(ln.get_xdata(), ds.prism.values)


def test_robust_limit():
    v = np.r_[np.ones(999), 1000.0]
    assert P.robust_limit(v) < 1000.0
    assert P.robust_limit(np.zeros(4)) == 1.0


# ---------------------------------------------------------------------- phase diagrams
def test_grid_variable_masks_failed_columns_and_refuses_cases():
    ds = grid_dataset()
    da = P.grid_variable(ds, "speed")
    assert da.dims == P.GRID_DIMS
    assert np.isnan(da[0, 0, 0]) and np.isfinite(da[0, 1, 0])
    with pytest.raises(ValueError, match="grid sweep"):
        P.grid_variable(paper_like_dataset(), "speed")


def test_log_slope_of_power_laws():
    ds = grid_dataset((0.0, 0.5))
    sl = P.log_slope(P.grid_variable(ds, "speed"), "v0")
    np.testing.assert_allclose(sl.sel(base_rigidity=1.0).values, 0.5, atol=1e-12)
    # the failed column's neighbours fall back to one-sided differences
    np.testing.assert_allclose(sl.sel(base_rigidity=0.0).values[1:], 0.0, atol=1e-12)
    assert np.isnan(sl.values[0, 0, 0]) and np.isfinite(sl.values[0, 1, 0])


def test_regimes_classify_by_alpha():
    ds = grid_dataset((0.0, 0.5))
    r = P.regimes(ds)
    assert set(r.alpha.dims) == set(P.GRID_DIMS)
    lin = r.linear.sel(base_rigidity=0.0).values
    assert np.all(lin[np.isfinite(lin)] == 1)
    assert np.all(r.stiffening.sel(base_rigidity=1.0) == 1)
    assert np.all(r.softening.sel(base_rigidity=1.0) == 0)
    np.testing.assert_allclose(r.tail_ratio.values[1:], 2.0)
    assert "lead_share" not in r  # no strain stored


def test_unresolved_cells_are_left_out():
    ds = grid_dataset((0.0, 0.5))
    ds.attrs.update(output_interval=0.05, scene_height=H)
    n = P.samples_per_passage(ds)
    np.testing.assert_allclose(n.values[1:], (2.0 * H / (ds.speed * 0.05)).values[1:])
    ds["speed"][1, 2, 1] = 50.0  # an absurd time of flight: 0.005 samples per passage
    r = P.regimes(ds, min_samples=0.5)
    assert r.resolved[1, 2, 1] == 0 and r.resolved[1, 1, 1] == 1
    assert np.isnan(r.alpha[1, 2, 1])
    np.testing.assert_allclose(r.alpha[1, [0, 1, 3, 4], 1], 0.5)  # neighbours fall back to one-sided differences
    assert r.resolved[1, 4, 1] == 1 and P.regimes(ds, min_samples=0.8).resolved[1, 4, 1] == 0  # 0.78 samples


def test_phase_map_grid_matches_coords():
    ds = grid_dataset()
    da = P.grid_variable(ds, "amplitude").sel(base_rigidity=1.0)
    fig, ax = plt.subplots()
    mesh, cb = P.phase_map(ax, da, cbar_label="amplitude [-]")
    arr = np.ma.masked_invalid(da.transpose("v0", "prestrain").values)
    got = np.ma.asarray(mesh.get_array()).reshape(arr.shape)
    np.testing.assert_array_equal(got.filled(np.nan), arr.filled(np.nan))
    xy = mesh.get_coordinates()  # (ny + 1, nx + 1, 2) cell corners
    xe, ye = xy[0, :, 0], xy[:, 0, 1]
    np.testing.assert_allclose(np.sqrt(ye[1:] * ye[:-1]), da.v0.values)  # log cells centred on the grid
    np.testing.assert_allclose(0.5 * (xe[1:] + xe[:-1]), da.prestrain.values)
    assert ax.get_yscale() == "log" and cb.ax.get_ylabel() == "amplitude [-]"
    patches = P.hatch_cells(ax, da > 0.0)
    assert len(patches) == int(np.sum(da.values > 0))


def test_cell_edges():
    np.testing.assert_allclose(P.cell_edges([0.0, 1.0, 3.0]), [-0.5, 0.5, 2.0, 4.0])
    np.testing.assert_allclose(P.cell_edges([1.0, 100.0], log=True), [0.1, 10.0, 1000.0])
    np.testing.assert_allclose(P.cell_edges([2.0]), [1.5, 2.5])


def test_lead_fraction_compact_and_tail():
    t = np.arange(0, 3.0001, 0.01)
    compact = travelling_pulse(0.01, 0.1, t, n=30)
    tail = compact + travelling_pulse(0.03, 0.02, t, n=30)  # a big slow wave behind
    da = xr.DataArray(np.stack([compact, tail]), dims=("v0", "t", "prism"),
                      coords={"v0": [1.0, 2.0], "t": t, "prism": np.arange(30)})
    share = P.lead_fraction(da)
    assert share.dims == ("v0",)
    assert share.values[0] > 0.95
    assert share.values[1] < 0.35


def test_lead_pulse_snapshot_sums_the_pulse():
    t = np.arange(0, 3.0001, 0.01)
    amp, width = 0.01, 1.5
    da = xr.DataArray(travelling_pulse(amp, 0.1, t, n=30, width=width)[None], dims=("v0", "t", "prism"),
                      coords={"v0": [1.0], "t": t, "prism": np.arange(30)})
    snap = P.lead_pulse_snapshot(da)
    assert snap.sum_q.dims == ("v0",)
    # integral of a sech^2 pulse: 2 w amp = SECH2_AREA x amplitude x FWHM (the 10 % window holds 95 % of it)
    fwhm = 2 * width * np.arccosh(np.sqrt(2))
    assert 2 * width * amp == pytest.approx(P.SECH2_AREA * amp * fwhm)
    assert float(snap.sum_q[0]) == pytest.approx(2 * width * amp, rel=0.08)
    assert float(snap.q_max[0]) == pytest.approx(amp, rel=1e-6)
    np.testing.assert_allclose(P.lead_fraction(da), snap.sum_q2 / snap.sum_q2_behind)


def scene_grid_dataset(n_prisms=4):
    """grid_dataset with the scene attributes a sweep writes (a short paper column)."""
    ds = grid_dataset((0.0, 0.5))
    ds.attrs.update(scene_n_prisms=n_prisms, scene_height=H, scene_unit_mass=0.0249, output_interval=0.002)
    return ds


def test_impact_momentum_is_the_end_base_mass():
    ds = scene_grid_dataset()
    imp = P.impact_momentum(ds)
    assert imp.p0.dims == ("prestrain", "base_rigidity")
    # end_twist keeps v_z = -v0 on the end nodes; "half" puts half a unit's mass on the end base
    np.testing.assert_allclose(imp.p0, 0.0249 / 2, rtol=1e-12)
    np.testing.assert_allclose(imp.level_mass, 0.0249, rtol=1e-12)


def test_momentum_share_from_the_measures():
    ds = scene_grid_dataset()
    mu = P.momentum_share(ds)
    assert mu.dims == P.GRID_DIMS
    g = {k: P.grid_variable(ds, k) for k in ("speed", "amplitude", "width")}
    want = 2 * P.SECH2_AREA * g["speed"] * g["amplitude"] * g["width"] / ds.v0
    np.testing.assert_allclose(mu.values, want.transpose(*P.GRID_DIMS).values, rtol=1e-12)
    assert np.isnan(mu.values[0, 0, 0])  # the failed column
    reg = P.regimes(ds, carry_share=0.5)
    np.testing.assert_array_equal(reg.momentum_share.values, mu.values)
    ok = np.isfinite(mu.values)
    np.testing.assert_array_equal(reg.carries_impact.values[ok], (mu.values[ok] >= 0.5).astype(float))
    assert "momentum_share" not in P.regimes(grid_dataset())  # no scene attributes: not computed


def test_input_path_and_existing_sweep(tmp_path, monkeypatch):
    monkeypatch.setenv("WT_TEST_X", "analysis/data/some.nc")
    assert P.input_path("WT_TEST_X", "x") == ROOT / "analysis" / "data" / "some.nc"
    monkeypatch.setenv("WT_TEST_X", str(tmp_path / "abs.nc"))
    assert P.input_path("WT_TEST_X", "x") == tmp_path / "abs.nc"
    monkeypatch.delenv("WT_TEST_X")
    assert P.input_path("WT_TEST_X", "analysis/y.nc") == ROOT / "analysis" / "y.nc"
    f = tmp_path / "exists.nc"
    f.write_bytes(b"")
    assert P.ensure_sweep(f, "does/not/matter.toml") == f  # nothing run
    monkeypatch.setenv("WT_FIG_DIR", str(tmp_path / "figs"))
    assert P.figure_dir() == tmp_path / "figs" and (tmp_path / "figs").is_dir()


# ---------------------------------------------------------------------- a real CI-sized sweep
@pytest.fixture(scope="module")
def ci_small(tmp_path_factory):
    out = tmp_path_factory.mktemp("ci_small") / "ci_small.nc"
    return xr.open_dataset(P.ensure_sweep(out, ROOT / "sweeps" / "ci_small.toml", device="cpu")).load()


def test_ensure_sweep_runs_the_cli(ci_small):
    assert ci_small.attrs["spec_file"].endswith("ci_small.toml")
    assert {d: ci_small.sizes[d] for d in P.GRID_DIMS} == {"prestrain": 2, "v0": 2, "base_rigidity": 2}


def test_phase_grids_match_the_dataset(ci_small):
    for name in ("amplitude", "speed", "width"):
        da = P.grid_variable(ci_small, name)
        for d in P.GRID_DIMS:
            np.testing.assert_array_equal(da[d].values, ci_small[d].values)
    reg = P.regimes(ci_small)
    for d in P.GRID_DIMS:
        np.testing.assert_array_equal(reg[d].values, ci_small[d].values)
    assert reg.lead_share.dims == P.GRID_DIMS
    share = reg.lead_share.values
    assert np.all((share[np.isfinite(share)] >= 0) & (share[np.isfinite(share)] <= 1))
    fig, ax = plt.subplots()
    da = P.grid_variable(ci_small, "speed").sel(base_rigidity=0.0)
    mesh, _ = P.phase_map(ax, da)
    np.testing.assert_array_equal(np.ma.asarray(mesh.get_array()).reshape(2, 2).filled(np.nan),
                                  da.transpose("v0", "prestrain").values)


def test_rerun_cells_reproduces_the_sweep(ci_small):
    pts = [dict(base_rigidity=0.0, prestrain=0.0021, v0=0.0049), dict(base_rigidity=0.0, prestrain=0.002, v0=0.005),
           dict(base_rigidity=1.0, prestrain=0.0, v0=0.002)]
    rr = P.rerun_cells(ci_small, pts, device="cpu")
    assert rr.sizes["cell"] == 2  # the first two snap to the same grid cell
    assert rr.strain.dims == ("cell", "t", "prism")
    np.testing.assert_allclose(rr.t, ci_small.t)
    assert list(rr.prestrain.values) == [0.002, 0.0] and list(rr.base_rigidity.values) == [0.0, 1.0]
    for k in ("amplitude", "speed", "width"):
        np.testing.assert_array_equal(rr[k].values, rr[f"sweep_{k}"].values)  # same CPU, same settings


def test_branch_speeds_on_the_grid(ci_small):
    br = P.branch_speeds(ci_small, n_prisms=6)
    assert br.c_soft.dims == ("prestrain", "base_rigidity")
    np.testing.assert_array_equal(br.prestrain.values, ci_small.prestrain.values)
    assert np.all(br.c_soft.sel(prestrain=0.0).values == 0.0)  # unstressed: zero-stiffness mechanism
    assert np.all(br.c_soft.sel(prestrain=0.002).values == pytest.approx(0.0263, rel=0.02))
    assert np.all(np.isnan(br.c_stiff.sel(base_rigidity=1.0)))  # RB: one branch
    fb = br.sel(base_rigidity=0.0)
    assert np.all(fb.c_stiff_slack < fb.c_stiff)  # slack cross cables soften the stiff branch


def test_simulate_cases_measures_like_the_sweep():
    from warp_tensegrity import ColumnConfig

    df = P.simulate_cases({"prestrain": 0.0, "v0": np.array([0.002, 0.005]), "base_rigidity": 0.0},
                          ColumnConfig(n_prisms=8, impact_admissibility="end_twist"), t_end=0.5, output_interval=0.005)
    assert list(df.v0) == [0.002, 0.005]
    assert set(df.columns) >= {"amplitude", "speed", "width", "energy_error", "ke0", "status", "impact_admissibility"}
    assert (df.status == 0).all() and (df.ke0 > 0).all()
    # FB p = 0 responds like a (bilinear) linear chain: amplitude proportional to v0
    assert df.amplitude[1] / df.amplitude[0] == pytest.approx(2.5, rel=0.05)


def test_cli_is_callable():
    r = subprocess.run([sys.executable, "-m", "warp_tensegrity", "--help"], cwd=ROOT, capture_output=True, text=True)
    assert r.returncode == 0
