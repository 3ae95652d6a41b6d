"""The feasibility record (issue 32): each case says whether, how, when and where it left the
model's feasible set (docs/model.md), on the CPU, through the public API.

The twist is checked against an independent NumPy computation from the final node positions
(``reference + final_displacement``), the timing by stopping a run at the flagged output and at
the one before, the inversion against the strain record, the bar crossing of a flexible-base
column against the sign of the oriented distance of its bar axes, and a network's pair check
against a column's twist check of the same prism."""

from __future__ import annotations

import types

import numpy as np
import pytest

from warp_tensegrity import ColumnConfig, RunSettings, simulate_batch
from warp_tensegrity.engine import run_batch
from warp_tensegrity.measure import feasibility as F
from warp_tensegrity.measure.nan_reasons import FLAG, measure_columns
from warp_tensegrity.scene.batch import column_batch, network_batch
from warp_tensegrity.scene.columns import build_column, column_topology
from warp_tensegrity.scene.network import Network
from warp_tensegrity.types import FEASIBILITY_FLAGS

CROSSED, STRINGS, INVERTED = (1 << i for i in range(3))
DT_OUT = 0.002  # s: every run here shares the output interval, so dt and the trajectories are the same


def settings(t_end, **kw):
    return RunSettings(device="cpu", t_end=t_end, output_interval=DT_OUT, truncate=False, **kw)


def numpy_twist(config: ColumnConfig, displacement: np.ndarray) -> np.ndarray:
    """(B, n_prisms) twist [rad] in [0, 2 pi) from node displacements (B, n_nodes, 3): the angle about
    the centroid axis from each bar's bottom node to its top node, clockwise seen from the top for a
    right-handed prism, averaged over the three bars. Written apart from the kernel (no unwrapping)."""
    topo = column_topology(config)
    x = topo.positions + displacement
    L = topo.level_nodes
    c = x[:, L].mean(axis=2)
    axis = c[:, 1:] - c[:, :-1]
    axis /= np.linalg.norm(axis, axis=-1, keepdims=True)
    a = axis[:, :, None, :]
    rb = x[:, L[:-1]] - c[:, :-1, None]
    rt = x[:, L[1:]] - c[:, 1:, None]
    pb = rb - (rb * a).sum(-1, keepdims=True) * a
    pt = rt - (rt * a).sum(-1, keepdims=True) * a
    ccw = np.arctan2((np.cross(pb, pt) * a).sum(-1), (pb * pt).sum(-1))
    hand = config.prism_handedness()[None, :, None]
    return np.mod(-hand * ccw, 2 * np.pi).mean(axis=-1)


def bar_sides(config: ColumnConfig, displacement: np.ndarray, prism: int) -> np.ndarray:
    """(B, 3) sign of (x_j0 - x_i0) . (b_i x b_j) for the three bar pairs of ``prism``, 0 where the
    closest points of the two axes are not inside both bars."""
    topo = column_topology(config)
    x = topo.positions + displacement
    bot, top = topo.level_nodes[prism], topo.level_nodes[prism + 1]
    out = []
    for i, j in ((0, 1), (1, 2), (2, 0)):
        bi, bj = x[:, top[i]] - x[:, bot[i]], x[:, top[j]] - x[:, bot[j]]
        w0 = x[:, bot[j]] - x[:, bot[i]]
        A = np.stack([np.stack([(bi * bi).sum(-1), -(bi * bj).sum(-1)], -1),
                      np.stack([(bi * bj).sum(-1), -(bj * bj).sum(-1)], -1)], -2)
        rhs = np.stack([(w0 * bi).sum(-1), (w0 * bj).sum(-1)], -1)[..., None]
        s, t = np.moveaxis(np.linalg.solve(A, rhs)[..., 0], -1, 0)
        inside = (s > 0) & (s < 1) & (t > 0) & (t < 1)
        out.append(np.where(inside, np.sign((w0 * np.cross(bi, bj)).sum(-1)), 0.0))
    return np.stack(out, axis=1)


RB = ColumnConfig(n_prisms=30)
RB_V0 = [0.01, 0.03, 0.1, 0.2]


@pytest.fixture(scope="module")
def rigid():
    return simulate_batch(RB, {"prestrain": 0.002, "v0": RB_V0, "base_rigidity": 1.0}, settings(0.4))


def test_rigid_bases_cross_their_bars_and_the_controls_do_not(rigid):
    """Issue 32's table: the largest twist of RB, p = 0.002, 30 prisms, and the prisms past 180 deg."""
    f = rigid.feasibility
    assert f["feasibility_flag"].tolist() == [0, 0, CROSSED, CROSSED]
    assert np.isnan(f["feasibility_time"][:2]).all() and f["feasibility_prism"][:2].tolist() == [-1, -1]
    np.testing.assert_allclose(np.degrees(f["twist_max"]), [163.87, 175.04, 199.21, 226.68], atol=0.01)
    assert (f["prism_twist_max"] >= np.pi).sum(axis=1).tolist() == [0, 0, 14, 18]
    # the impacted end crosses first, at v0 = 0.2 twice as early as at 0.1
    assert f["feasibility_prism"][2:].tolist() == [29, 29]
    np.testing.assert_allclose(f["feasibility_time"][2:], [0.012, 0.006], atol=1e-12)
    assert np.all(f["height_ratio_min"] > 0.9) and np.all(f["twist_min"] > np.pi / 3)


def test_the_issue_prism_26_twist_from_final_positions():
    """At v0 = 0.1 the twist of prism 26 is 182.9 deg at t = 0.1 s; the kernel's (last output) equals
    the NumPy one of the final positions."""
    r = simulate_batch(RB, {"prestrain": 0.002, "v0": 0.1, "base_rigidity": 1.0}, settings(0.1))
    tw = numpy_twist(RB, r.final_displacement)
    assert np.degrees(tw[0, 26]) == pytest.approx(182.9, abs=0.05)
    np.testing.assert_allclose(r.feasibility["prism_twist_last"], tw, rtol=0, atol=1e-9)
    assert np.all(r.feasibility["prism_twist_max"] >= tw - 1e-12)


@pytest.mark.parametrize("v0", [0.1, 0.2])
def test_bars_crossed_at_the_flagged_output_and_not_before(rigid, v0):
    """Stopped at the flagged time, the flagged prism's twist (NumPy, final positions) is past pi; one
    output earlier, no prism's is. A later threshold (pi * 1.02) or a slot off by one fails here."""
    b = RB_V0.index(v0)
    t1, prism = float(rigid.feasibility["feasibility_time"][b]), int(rigid.feasibility["feasibility_prism"][b])
    for t_end, past in ((t1, True), (t1 - DT_OUT, False)):
        r = simulate_batch(RB, {"prestrain": 0.002, "v0": v0, "base_rigidity": 1.0}, settings(t_end))
        tw = numpy_twist(RB, r.final_displacement)[0]
        if past:
            assert tw[prism] >= np.pi and r.feasibility["feasibility_flag"][0] == CROSSED
        else:
            assert tw.max() < np.pi and r.feasibility["feasibility_flag"][0] == 0


FB = ColumnConfig(n_prisms=50)
FB_V0 = [0.1, 0.15, 0.2]


@pytest.fixture(scope="module")
def flexible():
    return simulate_batch(FB, {"prestrain": 0.002, "v0": FB_V0, "base_rigidity": 0.0}, settings(0.4))


def test_flexible_bases_invert_from_the_issue_times(flexible):
    """FB, rigid_members impact: v0 = 0.15 inverts from t = 0.046 s, v0 = 0.2 too; v0 = 0.1 does not
    (smallest h 2.25 mm). The inversion time is the strain record's first h <= 0 (strain >= 1)."""
    f = flexible.feasibility
    inv = f["feasibility_times"][:, FEASIBILITY_FLAGS.index("prism_inverted")]
    assert np.isnan(inv[0]) and inv[1] == pytest.approx(0.046) and inv[2] == pytest.approx(0.026)
    assert ((f["feasibility_flag"] & INVERTED) != 0).tolist() == [False, True, True]
    assert f["height_ratio_min"][0] * FB.height == pytest.approx(2.255e-3, abs=5e-6)
    s = flexible.strain  # (h - h0)/h: h <= 0 where it is > 1, or -inf (h = 0)
    inverted = (s > 1) | (s == -np.inf)
    first = [flexible.time[np.flatnonzero(inverted[b].any(axis=1))[0]] for b in (1, 2)]
    np.testing.assert_allclose(first, inv[1:], atol=1e-12)
    assert np.all(f["height_ratio_min"][1:] < 0)


def test_flexible_base_bars_cross_at_the_impacted_end(flexible):
    """A finding, not the issue's claim: every FB case here, v0 = 0.1 included, has its impacted-end
    prism's bars pass through each other (twist past pi) long before any inversion. The oriented
    distance of the bar axes (NumPy, final positions) confirms it: it keeps its sign up to the output
    before the flagged one and has flipped, for all three pairs, at it."""
    f = flexible.feasibility
    assert ((f["feasibility_flag"] & CROSSED) != 0).all() and f["feasibility_prism"].tolist() == [49, 49, 49]
    t1 = float(f["feasibility_time"][0])
    assert t1 == pytest.approx(0.012)
    ref = bar_sides(FB, np.zeros((1, 3 * 51, 3)), 49)
    for t_end, flipped in ((t1 - DT_OUT, False), (t1, True)):
        r = simulate_batch(FB, {"prestrain": 0.002, "v0": 0.1, "base_rigidity": 0.0}, settings(t_end))
        sides = bar_sides(FB, r.final_displacement, 49)
        assert np.all(sides != 0)
        assert np.all(sides == -ref) if flipped else np.all(sides == ref)


@pytest.mark.parametrize("fused", [False, "lanes"])
def test_paths_record_the_same(rigid, fused):
    """The staged path (one kernel per stage) and the lane step (emulated on the CPU) record what the
    fused one does."""
    r = simulate_batch(RB, {"prestrain": 0.002, "v0": RB_V0, "base_rigidity": 1.0}, settings(0.4, fused=fused))
    assert r.info["step_path"].startswith("staged" if fused is False else "lanes")
    for k in ("feasibility_flag", "feasibility_prism", "feasibility_time"):
        np.testing.assert_array_equal(r.feasibility[k], rigid.feasibility[k])
    np.testing.assert_allclose(r.feasibility["prism_twist_max"], rigid.feasibility["prism_twist_max"], atol=1e-9)


def test_network_pairs_agree_with_the_column_twist():
    """One prism as a network (no levels: the bar-pair check) and as a column (the twist check): the
    bars cross at the same output, rigid and flexible bases alike."""
    cfg = ColumnConfig(n_prisms=1)
    v0 = [0.05, 0.2, 0.5]
    s = RunSettings(device="cpu", t_end=0.05, output_interval=0.0005)
    for beta in (1.0, 0.0):
        scenes = [build_column(cfg, prestrain=0.002, v0=v, base_rigidity=beta) for v in v0]
        net = run_batch(network_batch([c.network for c in scenes], [c.velocity for c in scenes]), s).feasibility
        col = run_batch(column_batch(cfg, {"prestrain": 0.002, "v0": v0, "base_rigidity": beta}), s).feasibility
        assert (net["feasibility_flag"] & CROSSED).all() and (col["feasibility_flag"] & CROSSED).all()
        np.testing.assert_array_equal(net["feasibility_times"][:, 0], col["feasibility_times"][:, 0])
        # the bars (1.77 mm apart at the reference) meet on the axis, sampled at the outputs
        assert np.all(net["member_distance_min"] < 3.5e-4)


def _two_bars(x0: float):
    """Bar A along x from -1 to 1 m at rest; bar B along y at x = x0, 5 cm above, falling at 1 m/s."""
    X = np.array([[-1, 0, 0], [1, 0, 0], [x0, -1, 0.05], [x0, 1, 0.05]], float)
    v = np.zeros((1, 4, 3))
    v[0, 2:, 2] = -1.0
    net = Network(positions=X, node_mass=0.1, fixed=False, bars=[[0, 1], [2, 3]], bar_mass=0.0,
                  cables=np.zeros((0, 2)), cable_EA=np.zeros(0), cable_rest_length=np.zeros(0))
    return run_batch(network_batch([net], v), RunSettings(device="cpu", t_end=0.1, output_interval=0.01))


def test_a_bar_through_a_bar_is_flagged_one_past_its_end_is_not():
    """Bar B falls through bar A (x0 = 0.5): crossed at the first output after t = 0.05 s. At x0 = 1.5
    the axes' lines cross too (their oriented distance changes sign), but beyond A's end: no flag."""
    through = _two_bars(0.5).feasibility
    assert through["feasibility_flag"][0] == CROSSED and through["feasibility_time"][0] == pytest.approx(0.06)
    assert through["feasibility_nodes"][0].tolist() == [0, 1, 2, 3] and through["member_distance_min"][0] < 1e-12
    past = _two_bars(1.5).feasibility
    assert past["feasibility_flag"][0] == 0 and past["member_distance_min"][0] == pytest.approx(0.5)


def test_cross_cables_of_a_regular_prism_meet_at_minus_pi_over_3():
    """docs/model.md: the paper's lower bound pi/3 ('strings touching') is kept as the flag, but in the
    builder's prism the cross cables meet at twist -pi/3 (mod 2 pi), not at pi/3; bars at pi."""
    topo = column_topology(ColumnConfig(n_prisms=1))

    def closest(phi, members):
        X = topo.positions.copy()
        r, ang = np.hypot(X[3:, 0], X[3:, 1]), np.arctan2(X[3:, 1], X[3:, 0]) + (5 * np.pi / 6 - phi)
        X[3:, 0], X[3:, 1] = r * np.cos(ang), r * np.sin(ang)  # the top base turned to twist phi
        d = []
        for i in range(3):
            for j in range(i + 1, 3):
                (a0, a1), (b0, b1) = members[i], members[j]
                p, q = np.linspace(X[a0], X[a1], 401), np.linspace(X[b0], X[b1], 401)
                d.append(np.linalg.norm(p[:, None] - q[None], axis=-1).min())
        return min(d)

    assert closest(np.pi, topo.bars) < 1e-4 and closest(5 * np.pi / 6, topo.bars) > 1e-3
    assert closest(-np.pi / 3, topo.cross) < 1e-4 and closest(np.pi / 3, topo.cross) > 5e-3


def test_measures_after_leaving_are_nan_with_the_flag_before_the_window_kept_after(rigid):
    """docs/model.md's rule: RB v0 = 0.1 left the set before its pulse crossed the window: NaN
    measures, measurement_flag left_feasible_set; the same record said to have left after the
    pulse's last peak in the window keeps its measures."""
    m = measure_columns(rigid, RB.height)
    assert m["measurement_flag"][2:].tolist() == [FLAG["left_feasible_set"]] * 2
    assert np.isnan(m["amplitude"][2:]).all() and np.isnan(m["max_compression"][2:]).all()
    assert FLAG["left_feasible_set"] not in m["measurement_flag"][:2]
    # the same columns with the event moved: after the last leading peak in the window, and never
    ref = types.SimpleNamespace(**{k: getattr(rigid, k) for k in ("status", "strain", "time", "measurements")},
                                feasibility={"feasibility_time": np.full(4, np.nan)})
    kept = measure_columns(ref, RB.height)
    late = dict(ref.feasibility)
    peaks = rigid.measurements["peak_time"]
    late["feasibility_time"] = np.where(np.isfinite(peaks), peaks, -np.inf).max(axis=1) + DT_OUT  # -inf: no peak
    ref.feasibility = late
    m_late = measure_columns(ref, RB.height)
    for k in ("amplitude", "speed", "measurement_flag"):
        np.testing.assert_array_equal(m_late[k], kept[k])
    assert np.isfinite(kept["amplitude"][2:]).all()


def test_summary_counts_each_reason():
    lines = F.summary(np.array([0, CROSSED, CROSSED | INVERTED, INVERTED, STRINGS], np.int8))
    assert [ln.split(" cases")[0] for ln in lines] == ["2 of 5", "1 of 5", "2 of 5"]
    assert [ln.split("(")[1].split(")")[0] for ln in lines] == list(FEASIBILITY_FLAGS)
    assert F.summary(np.zeros(3, np.int8)) == []


def test_dataset_carries_the_flag_with_cf_masks(rigid):
    ds = rigid.to_xarray()
    flag = ds["feasibility_flag"]
    assert flag.attrs["flag_masks"].tolist() == [1, 2, 4] and flag.attrs["flag_meanings"].split() == list(FEASIBILITY_FLAGS)
    assert flag.values.tolist() == [0, 0, 1, 1] and ds["feasibility_prism"].values.tolist() == [-1, -1, 29, 29]
    assert ds["twist_max"].attrs["units"] == "rad"
    np.testing.assert_array_equal(ds["feasibility_time_bars_crossed"].values, rigid.feasibility["feasibility_times"][:, 0])


def test_plot_phase_hatches_the_cases_that_left():
    """`plot phase`: one hatched patch per case with feasibility_flag != 0; the mesh keeps the variable."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import xarray as xr

    from warp_tensegrity import plot as W

    p, v = np.array([0.0, 0.001, 0.002]), np.array([0.01, 0.1, 0.2, 0.3])
    flag = np.zeros((3, 4), np.int8)
    flag[1, 2], flag[2, 3], flag[0, 3] = CROSSED, CROSSED | INVERTED, STRINGS
    ds = xr.Dataset({"speed": (("prestrain", "v0"), np.arange(12.0).reshape(3, 4)),
                     "status": (("prestrain", "v0"), np.zeros((3, 4), np.int8)),
                     "feasibility_flag": (("prestrain", "v0"), flag)}, coords={"prestrain": p, "v0": v})
    ax = W.phase_diagram(ds, "speed", x="prestrain", y="v0")
    assert len(ax.patches) == 3 and ax.get_legend() is not None
    np.testing.assert_array_equal(np.ma.filled(ax.collections[-1].get_array(), np.nan).ravel(),
                                  ds.speed.transpose("v0", "prestrain").values.ravel())
    for (x, y) in [(0.001, 0.2), (0.002, 0.3), (0.0, 0.3)]:  # each flagged cell has its patch (log y edges)
        assert sum(r.get_x() < x < r.get_x() + r.get_width() and r.get_y() < y < r.get_y() + r.get_height()
                   for r in ax.patches) == 1
    ax = W.phase_diagram(ds.drop_vars("feasibility_flag"), "speed", x="prestrain", y="v0")
    assert len(ax.patches) == 0 and ax.get_legend() is None
    plt.close("all")
