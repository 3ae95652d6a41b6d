"""The validation gallery (warp_tensegrity.validation, docs/validation.md): the engine in fp64 on
the CPU against closed forms, and the closed forms themselves against the engine's own model
(finite differences of its potential and geometry, a direct integration of the 1-D chain).

Every comparison is with a closed form or an independent integration, never with stored engine
output; a negative control shows the Bessel check fails for the wrong mass convention."""

import math

import numpy as np
import pytest

from warp_tensegrity import ColumnConfig, build_column, cli
from warp_tensegrity.validation.closed_forms import (
    QUASI_CONTINUUM_SPEED_CONSTANT,
    bessel_compression,
    power_chain_soliton,
    rb_chain,
)
from warp_tensegrity.validation.dispersion import bands, ringing_frequency
from warp_tensegrity.validation.linear import axial_stiffness_per_prism, long_wave_speed
from tests.references.reference import ReferenceSystem
from warp_tensegrity.validation import CHECKS, report, run_validation
from warp_tensegrity.validation import checks as V

CFG = ColumnConfig()  # the paper's prism: a = 5 mm, h0 = 6.2 mm, EA = 0.337 N, m = 0.0249 kg


def _chain(p):
    return rb_chain(CFG.cable_EA, CFG.radius, CFG.height, CFG.unit_mass, p)


# ---------------------------------------------------------------------- the closed forms, checked
def _one_prism_rb(p):
    scene = build_column(ColumnConfig(n_prisms=1), prestrain=p, base_rigidity=1.0)
    return scene, ReferenceSystem(scene.network)


def _squeezed(scene, delta):
    """Positions of the 1-prism RB column with its top base lowered by delta and turned so the bars
    keep their length (the one degree of freedom of the prism)."""
    a, h0, phi0 = CFG.radius, CFG.height, CFG.twist
    l2 = h0**2 + 2 * a**2 * (1 - math.cos(phi0))
    h = h0 - delta
    phi = math.acos(1 - (l2 - h**2) / (2 * a**2))
    x = np.array(scene.network.positions, float)
    ang = -2 * np.pi * np.arange(3) / 3 - phi
    x[3:6] = np.stack([a * np.cos(ang), a * np.sin(ang), np.full(3, h)], axis=1)
    return x


def test_chain_constants_by_finite_differences_of_the_engine_model():
    """s0, K, k3 and m_eff against finite differences of the model's own potential (cable strain
    energy of ReferenceSystem) and kinetic energy along the prism's one degree of freedom."""
    h0 = CFG.height
    scene, rs = _one_prism_rb(0.002)
    ch = _chain(0.002)
    cross = np.linalg.norm(np.diff(scene.network.positions[scene.topology.cross], axis=1)[:, 0], axis=1)
    np.testing.assert_allclose(cross, ch.s0, rtol=1e-14)
    x0 = _squeezed(scene, 0.0)
    assert np.abs(x0 - scene.network.positions).max() < 1e-15  # the parametrisation passes through the reference
    assert np.abs(rs.constraints(_squeezed(scene, 1e-3 * h0))).max() < 1e-18  # bars and links keep their length

    def V(d):
        return rs.energy(_squeezed(scene, d), np.zeros((6, 3)))

    K = [(V(d) - 2 * V(0.0) + V(-d)) / d**2 for d in (2e-4 * h0, 1e-4 * h0)]
    assert (4 * K[1] - K[0]) / 3 == pytest.approx(ch.K, rel=1e-6)  # Richardson: the quartic term out
    assert ch.K == pytest.approx(axial_stiffness_per_prism(build_column(ColumnConfig(n_prisms=4), prestrain=0.002,
                                                                        base_rigidity=1.0)), rel=1e-9)
    scene0, rs0 = _one_prism_rb(0.0)
    k3 = [2 * (rs0.energy(_squeezed(scene0, e), 0 * x0) + rs0.energy(_squeezed(scene0, -e), 0 * x0)) / e**4
          for e in (2e-3 * h0, 1e-3 * h0)]
    assert (4 * k3[1] - k3[0]) / 3 == pytest.approx(ch.k3, rel=1e-6)  # Richardson: the delta^6 term out
    d = 1e-5 * h0
    v = (_squeezed(scene, d) - _squeezed(scene, -d)) / (2 * d)  # velocity per unit compression rate
    m_top = float(np.sum(scene.network.node_mass[:, None] * v**2))
    assert m_top == pytest.approx(ch.m_eff / 2, rel=1e-7)  # the end base carries half a unit ('half')


def test_rigid_members_impact_is_the_chains_initial_state():
    """At beta = 1 the default impact moves the struck base alone, with the chain's velocity."""
    v0 = 1e-3
    scene = build_column(ColumnConfig(n_prisms=4), prestrain=0.002, v0=v0, base_rigidity=1.0)
    vel, m = scene.velocity, scene.network.node_mass
    top = scene.topology.level_nodes[-1]
    np.testing.assert_allclose(vel[top, 2], -v0, rtol=1e-14)
    assert np.abs(np.delete(vel, top, axis=0)).max() < 1e-12 * v0
    ke = 0.5 * float(np.sum(m[:, None] * vel**2))
    assert ke == pytest.approx(0.5 * (_chain(0.002).m_eff / 2) * v0**2, rel=1e-10)


def test_bessel_form_solves_the_chain():
    """The Bessel form with its images against a direct integration of the 1-D chain (half-mass
    struck end, clamp), through two echoes."""
    from scipy.integrate import solve_ivp

    ch, n, v0 = _chain(0.002), 6, 1e-6
    m = np.full(n, ch.m_eff)
    m[0] /= 2  # level 0 here is the struck base; level n is the clamp

    def rhs(_t, y):
        u, w = y[:n], y[n:]
        f = ch.K * np.diff(np.append(u, 0.0))  # spring j: K (u_(j+1) - u_j), u toward the clamp
        return np.concatenate([w, (f - np.append(0.0, f[:-1])) / m])

    t = np.linspace(0, 4 * 2 * n / ch.omega_c * 2, 800)
    y0 = np.zeros(2 * n)
    y0[n] = v0
    sol = solve_ivp(rhs, (0, t[-1]), y0, t_eval=t, method="DOP853", rtol=1e-12, atol=1e-20)
    u = np.vstack([sol.y[:n], np.zeros((1, len(t)))])
    q = ((u[:-1] - u[1:]) / ch.h0).T[:, ::-1]  # compression, prism 0 at the clamp
    ref = bessel_compression(t, n, v0, ch)
    assert np.abs(q - ref).max() < 1e-8 * np.abs(ref).max()
    with pytest.raises(AssertionError):  # without the images the echo is missing
        np.testing.assert_allclose(bessel_compression(t, n, v0, ch, images=0), ref, atol=1e-3 * np.abs(ref).max())


def test_cubic_chain_constants():
    """Our integration of the cubic chain gives the literature's discrete constants, a steady
    pulse, and the quasi-continuum speed 6 % high."""
    s = power_chain_soliton(n_sites=40, first=10)
    assert s.speed_constant == pytest.approx(0.76842, abs=2e-5)
    assert s.amplitude_constant == pytest.approx(0.7991, abs=1e-4)
    assert s.spread < 1e-8
    assert QUASI_CONTINUUM_SPEED_CONSTANT / s.speed_constant - 1 == pytest.approx(0.0626, abs=5e-4)
    xi, y = s.profile
    assert y.max() == pytest.approx(1.0, abs=1e-6) and abs(xi[np.argmax(y)]) < 0.03


# ---------------------------------------------------------------------- the engine against them
def test_bessel_record():
    g = V.check_bessel()
    assert g.passed, report([g])
    assert g.checks[0].error < 1e-4


def test_bessel_check_fails_for_the_wrong_mass_convention():
    """Negative control: a full-mass end base is not the half-mass chain; the check sees it."""
    cfg = ColumnConfig(n_prisms=12, end_base_mass="full")
    ch = _chain(0.002)
    v0 = 0.005 * 0.002 * ch.c0 / V.J1_MAX
    r = V._run(cfg, {"prestrain": 0.002, "v0": v0, "base_rigidity": 1.0}, 4.0, 0.01, "cpu")
    ref = -bessel_compression(r.time, 12, v0, ch)
    assert np.abs(r.strain[0] - ref).max() > 0.3 * np.abs(ref).max()  # 0.75: far outside 1e-4


def test_soliton():
    g = V.check_soliton()
    assert g.passed, report([g])
    tol = {"soliton_speed_constant": 0.01, "soliton_amplitude_law": 0.01, "soliton_width": 0.02}
    for c in g.checks:
        assert c.tolerance == tol[c.name] and c.error <= c.tolerance
    raw = g.data["runs"][0]["c"] / g.data["soliton"].speed_constant
    assert raw > 1.01  # at A = 0.01 the geometry's O(A) terms are above the tolerance: the extrapolation matters


@pytest.fixture(scope="module")
def dispersion_group():
    return V.check_dispersion()


def test_dispersion(dispersion_group):
    g = dispersion_group
    assert g.passed, report([g])
    names = {c.name: c for c in g.checks}
    assert names["dispersion_long_wave"].tolerance == 1e-3 and names["dispersion_speed_measure"].tolerance == 5e-3
    assert names["dispersion_rb_modes"].tolerance == names["dispersion_fb_modes"].tolerance == 2e-4
    # the Bloch checks of the reference alone say so; every other check runs the engine
    assert {c.name for c in g.checks if not c.engine} == {"dispersion_long_wave", "dispersion_rb_branch"}
    assert "reference only" in report([g])
    for key in ("rb", "fb"):
        w_sim, w_ref = g.data["modes"][key]
        np.testing.assert_allclose(w_sim, w_ref, rtol=5e-5)  # measured: RB 4e-6, FB 3e-5 (its end levels)
    ch = _chain(0.002)
    assert 0.95 < g.data["speed_bessel"] / ch.c0 < 0.99  # the time-of-flight measure lags c0
    assert g.data["cutoff"][0] == pytest.approx(ch.omega_c, rel=5e-3)


def test_bands_against_the_column_modes():
    """Branch counts; FB long-wave speeds against the finite column's modes (validation.linear)."""
    rb, fb = bands(CFG, 0.002, 1.0, n_k=9), bands(CFG, 0.002, 0.0, k=[1e-3 / CFG.height])
    assert rb.omega.shape == (9, 3) and rb.omega_symmetric.shape == (9, 1)
    assert fb.omega.shape == (1, 6) and fb.omega_symmetric.shape == (1, 2)
    lw = long_wave_speed(build_column(ColumnConfig(n_prisms=20), prestrain=0.002, base_rigidity=0.0))
    np.testing.assert_allclose(fb.omega_symmetric[0] / fb.k[0], lw.c_branches_homogenised, rtol=1e-4)
    assert np.all(rb.omega >= -1e-6 * rb.omega.max())  # prestressed: stable
    left = bands(ColumnConfig(handedness="left"), 0.002, 1.0, n_k=9)  # the mirror image: the same bands
    np.testing.assert_allclose(left.omega, rb.omega, rtol=1e-9, atol=1e-7 * rb.omega.max())  # k = 0: round-off
    with pytest.raises(ValueError, match="one handedness"):
        bands(ColumnConfig(handedness="alternating"), 0.002, 1.0, n_k=3)


def test_reference_column_is_the_scene_builders_column():
    """The references' column (closed-form self-stress, own impact solve) and the engine's scene builder
    (SVD self-stress, scene.impact) are two independent builds of one column: they agree to round-off."""
    from warp_tensegrity.validation.reference_column import base_member_force, reference_column

    for hand in ("right", "left"):
        for beta in (0.0, 0.5, 1.0):
            for impact in ("rigid_members", "end_twist")[: 1 if beta == 1.0 else 2]:
                cfg = ColumnConfig(n_prisms=5, handedness=hand, impact_admissibility=impact)
                s = build_column(cfg, prestrain=0.002, v0=1e-3, base_rigidity=beta)
                r = reference_column(5, cfg.radius, cfg.height, cfg.cable_EA, cfg.unit_mass, 0.002, beta, v0=1e-3,
                                     handedness=hand, impact=impact)
                a, b = s.network, r.network
                assert np.abs(a.positions - b.positions).max() < 1e-15
                assert np.array_equal(a.bars, b.bars) and np.array_equal(a.cables, b.cables)
                np.testing.assert_allclose(b.cable_EA, a.cable_EA, rtol=1e-15)
                np.testing.assert_allclose(b.cable_EA_compression, a.cable_EA_compression, rtol=1e-15)
                np.testing.assert_allclose(b.cable_rest_length, a.cable_rest_length, rtol=1e-14)
                np.testing.assert_allclose(b.node_mass, a.node_mass, rtol=1e-15)
                assert np.abs(r.velocity - s.velocity).max() < 1e-10 * 1e-3
    # the closed-form self-stress: a base member carries T a / s0 per prism
    topo = build_column(ColumnConfig(n_prisms=3)).topology
    np.testing.assert_allclose(topo.unit_base_force, np.repeat([1, 2, 2, 1], 3) * base_member_force(CFG.radius, CFG.height, 1.0),
                               rtol=1e-12)
    with pytest.raises(ValueError, match="end_twist"):
        reference_column(2, CFG.radius, CFG.height, 0.3, 0.02, 0.002, 1.0, v0=1.0, impact="end_twist")


def test_mode_frequencies_of_the_chain():
    """The matrix pencil reads the RB chain's modes off its Bessel record exactly (they are the band at
    k_j); the FB column's soft modes (validation.linear on the reference column) sit within 5e-5 of its
    soft band at the same k_j (its end levels are not the periodic column's)."""
    from warp_tensegrity.validation.dispersion import chain_wavenumbers, mode_frequencies
    from warp_tensegrity.validation.linear import modal_analysis
    from warp_tensegrity.validation.reference_column import reference_column

    ch, n = _chain(0.002), 8
    t = np.arange(0.0, 8.0, 0.02)
    k = chain_wavenumbers(n, CFG.height)
    w = mode_frequencies(-bessel_compression(t, n, 1e-6, ch), t, n)
    np.testing.assert_allclose(w, ch.omega_c * np.sin(k * CFG.height / 2), rtol=1e-10)
    np.testing.assert_allclose(bands(CFG, 0.002, 1.0, k=k).omega_symmetric[:, 0], w, rtol=1e-6)
    col = reference_column(n, CFG.radius, CFG.height, CFG.cable_EA, CFG.unit_mass, 0.002, 0.0, v0=1.0)
    r = modal_analysis(col.network)
    excited = np.abs(np.einsum("mni,ni,n->m", r.shapes, col.velocity, col.network.node_mass)) > 1e-6
    soft = r.omega[excited][:n]
    fb = bands(CFG, 0.002, 0.0, k=k).omega_symmetric[:, 0]
    assert np.abs(soft / fb - 1).max() < 5e-5


def test_ringing_frequency_of_a_bessel_record():
    ch = _chain(0.002)
    t = np.linspace(0, 8, 801)
    assert ringing_frequency(-bessel_compression(t, 30, 1e-6, ch), t) == pytest.approx(ch.omega_c, rel=5e-3)
    assert np.isnan(ringing_frequency(np.ones((5, 2)), np.arange(5.0)))


def test_fb_modal():
    g = V.check_fb_modal()
    assert g.passed, report([g])


# ---------------------------------------------------------------------- figures, plot kind, CLI
def test_figures_and_plot_kind(dispersion_group, tmp_path):
    import matplotlib

    matplotlib.use("Agg")
    from warp_tensegrity import RunSettings, plot, simulate_batch
    from warp_tensegrity.validation.figures import write_figures

    (path,) = write_figures([dispersion_group], tmp_path)
    assert path.name == "validation_dispersion.png" and path.stat().st_size > 10_000
    ax = plot.dispersion(dispersion_group.data["rb"], speed=0.02, cutoff=8.0)
    sym = [ln for ln in ax.lines if str(ln.get_label()).startswith("symmetric")]
    np.testing.assert_allclose(sym[0].get_ydata(), dispersion_group.data["rb"].omega_symmetric[:, 0])
    # a dataset: the plot kind takes the scene from its attributes, the speed and ringing from its column
    cfg = ColumnConfig(n_prisms=10)
    r = simulate_batch(cfg, {"prestrain": 0.002, "v0": 1e-6, "base_rigidity": 1.0},
                       RunSettings(t_end=3.0, output_interval=0.01, device="cpu", truncate=False))
    nc = tmp_path / "rb.nc"
    r.to_xarray(cfg).to_netcdf(nc)
    assert cli.main(["plot", str(nc), "dispersion", "--sel", "case=0", "-o", str(tmp_path / "d.png")]) == 0
    assert (tmp_path / "d.png").stat().st_size > 10_000
    from warp_tensegrity.io import open_sweep

    ax = plot.dispersion(open_sweep(nc), sel={"case": 0}, n_k=5)
    assert len(ax.lines) == 3 + 1 + 2  # all branches, the symmetric one, speed and ringing


def test_validate_command(tmp_path, capsys):
    assert cli.main(["validate", "--only", "fb_modal", "-o", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "fb_modal_record" in out and "fb_modal_end_twist" in out and "pass" in out and "FAIL" not in out
    assert (tmp_path / "validation_fb_modal.png").exists() and (tmp_path / "validation_fb_modal_2.png").exists()
    assert cli.main(["validate", "--only", "nope"]) == 1
    assert set(CHECKS) == {"bessel", "soliton", "dispersion", "fb_modal", "interface", "diatomic", "striker", "preload"}
    with pytest.raises(ValueError):
        run_validation(["nope"])
