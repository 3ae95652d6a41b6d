"""Per-prism profiles of the per-column parameters (issue 34 item 1): prestrain, cable_EA (per
prism) and unit_mass (per level) along the column."""

import numpy as np
import pytest

import warp_tensegrity as wt
from warp_tensegrity.options import Profile, RunSettings
from warp_tensegrity.policy.decide import decide, far_end
from warp_tensegrity.policy.lane_fit import lane_refusal, lane_support
from warp_tensegrity.scene.batch import column_batch, column_params, far_end_params
from warp_tensegrity.scene.columns import ColumnConfig, column_topology
from warp_tensegrity.scene.network import NetworkError

CFG = ColumnConfig(n_prisms=6)


def test_profile_arrays():
    assert np.allclose(Profile.grade(0.01, 0.06).check("prestrain", 6), np.linspace(0.01, 0.06, 6))
    assert Profile.segments(1.0, 2.0, 2).check("cable_EA", 6).tolist() == [1, 1, 2, 2, 2, 2]
    # unit_mass: one value per level, level at on in the second segment
    assert Profile.segments(1.0, 2.0, 2).check("unit_mass", 6).tolist() == [1, 1, 2, 2, 2, 2, 2]
    assert Profile.from_table("prestrain", {"segments": [0.01, 0.02], "at": 3}) == Profile.segments(0.01, 0.02, 3)
    assert Profile.from_table("prestrain", {"grade": [0.01, 0.02]}).table() == {"grade": [0.01, 0.02]}


@pytest.mark.parametrize("beta", [0.0, 0.5, 1.0])
def test_graded_prestrain_is_in_equilibrium(beta):
    """Each prism's self-stress at its own tension, superposed on the shared bases: the reference
    state balances (a base member at one prism's share alone, or the mean tension, does not)."""
    p = np.array([[0.01, 0.02, 0.03, 0.05, 0.05, 0.08]])
    ea = Profile.segments(0.3, 0.9, 2)
    b = column_batch(CFG, {"prestrain": p, "cable_EA": ea, "base_rigidity": beta})
    assert b.equilibrium_residual[0] < 1e-12
    # the cross cables carry T_m = EA_m p_m, prism by prism
    eam = ea.check("cable_EA", 6)
    L = b.cable_rest_length[0, :18]
    ell = np.linalg.norm(np.diff(b.positions[b.cables[:18]], axis=1)[:, 0], axis=1)
    assert np.allclose(b.cable_EA[0, :18] * (ell - L) / L, np.repeat(eam * p[0], 3), rtol=1e-12)


def test_interior_base_carries_both_shares():
    topo = column_topology(CFG)
    assert np.array_equal(topo.unit_base_force[:3], topo.unit_base_bottom[:3])
    assert np.array_equal(topo.unit_base_force[-3:], topo.unit_base_top[-3:])
    assert np.allclose(topo.unit_base_force[3:-3], topo.unit_base_bottom[3:] + topo.unit_base_top[:-3], rtol=0, atol=1e-15)


def test_uniform_profile_is_the_scalar_bit_for_bit():
    a = column_batch(CFG, {"prestrain": Profile.grade(0.02, 0.02), "unit_mass": np.full((1, 7), 0.03), "v0": 0.1})
    c = column_batch(CFG, {"prestrain": 0.02, "unit_mass": 0.03, "v0": 0.1})
    for k in ("cable_rest_length", "cable_EA", "cable_EA_compression", "node_mass", "velocity"):
        assert np.array_equal(getattr(a, k), getattr(c, k)), k
    assert a.params["prestrain"].shape == (1,)


def test_level_masses_and_their_impact():
    mu = np.array([[0.02, 0.04, 0.02, 0.04, 0.02, 0.04, 0.02]])  # a diatomic column
    b = column_batch(CFG, {"unit_mass": mu, "v0": 0.1})
    expect = mu[0] * np.array([0.5, 1, 1, 1, 1, 1, 0.5])  # end bases: half (end_base_mass = 'half')
    assert np.allclose(b.node_mass[0].reshape(7, 3).sum(axis=1), expect, rtol=1e-14)
    # the projected impact weighs the masses: admissible (bars rigid) and not the uniform column's
    cfg = ColumnConfig(n_prisms=6, impact_admissibility="project")
    v = column_batch(cfg, {"unit_mass": mu, "v0": 0.1}).velocity[0]
    bars, x = column_topology(cfg).bars, b.positions
    rate = np.einsum("ij,ij->i", x[bars[:, 1]] - x[bars[:, 0]], v[bars[:, 1]] - v[bars[:, 0]])
    assert np.abs(rate).max() < 1e-12 * 0.1 * np.abs(x).max()
    uniform = column_batch(cfg, {"unit_mass": 0.03, "v0": 0.1}).velocity[0]
    assert np.abs(v - uniform).max() > 1e-4
    scaled = column_batch(cfg, {"unit_mass": 3 * mu, "v0": 0.1}).velocity[0]  # invariant to a uniform scale
    assert np.allclose(v, scaled, rtol=0, atol=1e-14)


def test_truncated_column_takes_the_far_end_of_the_profile():
    p = column_params(CFG, {"prestrain": Profile.grade(0.01, 0.06), "unit_mass": Profile.segments(0.02, 0.03, 4)})
    part = column_batch(far_end(CFG, 3), far_end_params(p, 6, 3))
    whole = column_batch(CFG, p)
    assert np.allclose(part.cable_rest_length[0, :9], whole.cable_rest_length[0, 9:18], rtol=1e-14)
    assert np.array_equal(part.node_mass[0, 3:], whole.node_mass[0, 12:])


def test_a_truncated_run_steps_the_far_end_of_the_profile():
    """prisms_simulated < n_prisms: the simulated part takes the profile's last prisms (the wrong end
    would change the pulse by ~1e-2), the result keeps the whole profile and the whole column's energy."""
    cfg = ColumnConfig(n_prisms=12)
    params = {"prestrain": Profile.grade(0.005, 0.05), "unit_mass": Profile.grade(0.02, 0.04), "v0": 0.05,
              "base_rigidity": 0.5}
    s = RunSettings(t_end=0.03, dt=2e-5, output_interval=5e-3, precision="fp64", fused=False, measure="none")
    full = wt.simulate_batch(cfg, params, s, prisms_simulated=12)
    cut = wt.simulate_batch(cfg, params, s, prisms_simulated=6)
    assert np.abs(full.strain).max() > 0.1
    assert np.abs(full.strain - cut.strain).max() < 2e-4 * np.abs(full.strain).max()  # the clamp's precursor only
    assert np.abs(full.elastic_energy - cut.elastic_energy).max() < 1e-6 * full.elastic_energy.max()
    assert cut.params["prestrain"].shape == (1, 12)


def test_profiles_are_recorded():
    r = wt.simulate_batch(CFG, {"prestrain": Profile.segments(0.01, 0.05, 3), "unit_mass": Profile.grade(0.02, 0.03),
                                "v0": [0.05, 0.1]},
                          RunSettings(t_end=2e-3, dt=1e-5, output_interval=1e-3, precision="fp64", fused=False))
    ds = r.to_xarray()
    assert ds["prestrain"].dims == ("prism",) and ds["prestrain"].values.tolist() == [0.01] * 3 + [0.05] * 3
    assert ds["unit_mass"].dims == ("level",) and ds["level"].size == 7
    assert ds["unit_mass"].attrs["units"] == "kg" and "per level" in ds["unit_mass"].attrs["long_name"]


def test_ea_profile_is_kept_off_the_lane_step_and_paths_agree():
    """The lane step reads one EA per column (sim/lanes/lanes.py): the policy routes an EA profile off it,
    and the paths it may take give the staged path's numbers."""
    params = {"prestrain": Profile.segments(0.01, 0.05, 3), "cable_EA": Profile.grade(0.3, 0.6), "v0": 0.05,
              "base_rigidity": 0.5}
    filled = column_params(CFG, params)
    assert "cable_EA profile" in lane_refusal(CFG, filled)
    assert lane_support(column_batch(CFG, filled)) is not None
    assert lane_refusal(CFG, column_params(CFG, {"prestrain": Profile.grade(0.01, 0.05)})) is None
    with pytest.raises(wt.SettingsError, match="cable_EA profile"):
        decide(CFG, params, RunSettings(t_end=1e-3, precision="fp64", fused="lanes"))
    run = dict(t_end=3e-3, dt=1e-5, output_interval=1e-3, precision="fp64", truncate=False, measure="none")
    staged = wt.simulate_batch(CFG, params, RunSettings(**run, fused=False))
    fused = wt.simulate_batch(CFG, params, RunSettings(**run, fused="auto"))
    assert "staged" not in fused.info["step_path"]
    assert np.abs(staged.strain).max() > 1e-3
    assert np.abs(fused.strain - staged.strain).max() < 1e-11
    # prestrain and mass profiles: the lane step reads rest lengths and masses per member and level
    params = {"prestrain": Profile.segments(0.01, 0.05, 3), "unit_mass": Profile.grade(0.02, 0.04), "v0": 0.05,
              "base_rigidity": 0.5}
    staged = wt.simulate_batch(CFG, params, RunSettings(**run, fused=False))
    lanes = wt.simulate_batch(CFG, params, RunSettings(**run, fused="lanes"))
    assert lanes.info["step_path"].startswith("lanes")
    assert np.abs(lanes.strain - staged.strain).max() < 1e-11


@pytest.mark.parametrize("params, match", [
    ({"prestrain": np.zeros((1, 5))}, r"prestrain: shape \(1, 5\), expected \(B, 6\)"),
    ({"unit_mass": np.full((1, 6), 0.02)}, r"unit_mass: shape \(1, 6\), expected \(B, 7\): one value per level"),
    ({"prestrain": Profile.explicit([0.0] * 5)}, r"prestrain = .*give 6 values, one per prism"),
    ({"unit_mass": Profile.grade(0.02, -0.01)}, r"unit_mass.grade\[1\] = -0.01: must lie in"),
    ({"unit_mass": np.array([[0.02] * 6 + [-1.0]])}, r"unit_mass\[6\] = -1.0: must lie in"),
    ({"prestrain": Profile.segments(0.01, 1.0, 3)}, r"prestrain.segments\[1\] = 1.0: must lie in \[0, 1\)"),
    ({"prestrain": {"grade": [0.01, 1.5]}}, r"prestrain.grade\[1\] = 1.5"),
    ({"prestrain": Profile.segments(0.01, 0.02, 6)}, r"prestrain.at = 6: the interface must be a prism index in \[1, 5\]"),
    ({"v0": Profile.grade(0.01, 0.02)}, r"v0 = .*v0 takes one value per column, not a profile"),
    ({"base_rigidity": np.zeros((1, 6))}, r"base_rigidity = .*takes one value per column, not a profile"),
    ({"prestrain": {"grade": [0.01, 0.02], "at": 3}}, r"at belongs to segments"),
    ({"prestrain": {"segments": [0.01, 0.02]}}, r"segments need at = k"),
    ({"prestrain": {"grade": [0.01]}}, r"prestrain.grade = \[0.01\]: give \[first, last\]"),
    ({"prestrain": {"grad": [0.01, 0.02]}}, r"prestrain.grad: unknown profile key; did you mean 'grade'"),
    ({"prestrain": [[0.01], [0.02, 0.03]]}, r"prestrain = .*must be a number or an array of numbers"),  # ragged
    ({"prestrain": [["a"] * 6]}, r"prestrain = .*must be a number or an array of numbers"),
])
def test_bad_profiles_name_the_field_and_value(params, match):
    with pytest.raises(NetworkError, match=match) as e:
        column_batch(CFG, params)
    assert "\n" not in str(e.value)


def test_profile_on_a_scene_parameter_is_refused():
    with pytest.raises(NetworkError, match=r"^radius = Profile\(.*\): takes one value, not a profile \(profiles: "
                                          r"prestrain, cable_EA, unit_mass, per column\)$"):
        ColumnConfig(n_prisms=6, radius=Profile.grade(1e-3, 2e-3))


# ---------------------------------------------------------------------- specs
SPEC = """
[scene]
n_prisms = 6
[sweep]
fixed = {{prestrain = {{segments = [0.01, 0.05], at = 3}}, base_rigidity = 1.0, v0 = 0.01}}
{sweep}
[run]
t_end = 0.05
output_interval = 0.01
precision = "fp64"
"""


def _spec(sweep="grid = {prestrain_at = [2, 4], prestrain_to = [0.02, 0.04]}", **fmt):
    from warp_tensegrity.sweep import load_spec

    return load_spec(SPEC.format(sweep=sweep, **fmt))


def test_grid_over_a_profiles_fields():
    spec = _spec()
    p = spec.column_params()["prestrain"]
    assert p.shape == (4, 6)
    assert p.tolist() == [[0.01] * 2 + [0.02] * 4, [0.01] * 2 + [0.04] * 4,
                          [0.01] * 4 + [0.02] * 2, [0.01] * 4 + [0.04] * 2]
    assert spec.describe() == "4 columns (grid prestrain_at 2 x prestrain_to 2)"
    grade = _spec("grid = {prestrain_from = [0.0, 0.02]}").column_params()["prestrain"]
    assert grade[1].tolist() == [0.02] * 3 + [0.05] * 3  # the template's kind: segments
    from warp_tensegrity.sweep.spec import profile_rows

    rows = profile_rows(Profile.grade(0.01, 0.05), {"to": np.array([0.02, 0.04])}, 6)
    assert np.array_equal(rows[1], Profile.grade(0.01, 0.04).check("prestrain", 6))  # as the Python API makes it
    assert '"prestrain":{"at":3,"segments":[0.01,0.05]}' in spec.canonical()


@pytest.mark.parametrize("sweep, match", [
    ("grid = {prestrain_at = [2, 6]}", r"sweep.grid.prestrain_at = 6.0: the interface must be a prism index in \[1, 5\]"),
    ("grid = {prestrain_at = [2.5]}", r"sweep.grid.prestrain_at\[0\] = 2.5: must be a prism index"),
    ("grid = {cable_EA_at = [2]}", r"sweep.grid.cable_EA_at: needs the cable_EA profile it varies in \[sweep.fixed\]"),
    ("grid = {prestrain_at = [2], prestrain = [0.01]}", r"sweep.grid.prestrain_at: conflicts with sweep.grid.prestrain"),
    ("grid = {prestrain_to = [1.5]}", r"sweep.grid.prestrain_to\[0\] = 1.5: must lie in \[0, 1\)"),
    ("cases = [{v0 = 0.01, unit_mass = {values = [0.02, 0.03]}}]",
     r"sweep.cases\[0\].unit_mass = .*give 7 values, one per level \(n_prisms = 6\), not 2"),
    ("cases = [{v0 = {grade = [0.01, 0.02]}}]", r"sweep.cases\[0\].v0 = .*v0 takes one value per column, not a profile"),
    ("cases = [{unit_mass = {grade = [0.02, -1.0]}}]", r"sweep.cases\[0\].unit_mass.grade\[1\] = -1.0: must lie in"),
])
def test_bad_profiles_in_a_spec_name_the_key_and_value(sweep, match):
    from warp_tensegrity.sweep.errors import SpecError

    with pytest.raises(SpecError, match=match):
        _spec(sweep)


def test_profile_on_a_scene_field_in_a_spec():
    from warp_tensegrity.sweep import load_spec
    from warp_tensegrity.sweep.errors import SpecError

    with pytest.raises(SpecError, match=r"scene.radius = .*radius is a scene setting, one value for the whole column; "
                                        r"profiles are for prestrain, cable_EA, unit_mass"):
        load_spec("[scene]\nradius = {grade = [1e-3, 2e-3]}\n[sweep]\ngrid = {v0 = [0.01]}\n")


def test_case_list_with_profiles_runs_and_records(tmp_path):
    """Profiles per case (one over level) through the sweep's store: coordinates over (case, prism) and
    (case, level), a uniform case's row the scalar."""
    from warp_tensegrity import sweep

    spec = _spec("cases = [{label = \"uniform\"}, {unit_mass = {values = [0.02, 0.04, 0.02, 0.04, 0.02, 0.04, 0.02]}}]")
    out = sweep.run_sweep(spec, tmp_path / "c.nc", device="cpu", progress=False)
    import xarray as xr

    with xr.open_dataset(out) as ds:
        assert ds["unit_mass"].dims == ("case", "level") and ds["prestrain"].dims == ("prism",)
        assert ds["unit_mass"].values[0].tolist() == [0.0249] * 7
        assert ds["unit_mass"].values[1].tolist() == [0.02, 0.04] * 3 + [0.02]
        assert (ds["status"].values == 0).all()
    from warp_tensegrity.plot import PlotError, plot_file

    for case in (0, 1):  # a band diagram is of a uniform column: a clear error, not a traceback
        with pytest.raises(PlotError, match="prestrain varies along the column"):
            plot_file(out, "dispersion", sel={"case": case})
