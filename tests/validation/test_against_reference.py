"""The Warp engine against the independent float64 NumPy reference and the linearised theory."""

import numpy as np
import pytest
import warp as wp

from warp_tensegrity.validation import linear
from warp_tensegrity import Network, RunSettings, column_batch, network_batch, run_batch, simulate_batch
from tests.references.reference import ClassOneMatrixForm, ReferenceSystem, integrate_matrix_form
from warp_tensegrity.sim.integrate import Integrator
from warp_tensegrity.scene.columns import ColumnConfig, build_column, prism_heights
from warp_tensegrity.types import Path


def free_prism_with_massive_bars(prestrain=0.01, seed=1, speed=0.002):
    """A free class-1 T3 prism whose mass is all in its bars, with a random admissible velocity."""
    s = build_column(ColumnConfig(n_prisms=1), prestrain=prestrain)
    net = s.network
    free = Network(
        positions=net.positions, node_mass=0.0, fixed=False, bars=net.bars, bar_mass=0.01,
        cables=net.cables, cable_EA=net.cable_EA, cable_rest_length=net.cable_rest_length,
    ).validate()
    ref = ReferenceSystem(free)
    rng = np.random.default_rng(seed)
    v = ref.project_velocities(free.positions, rng.normal(scale=speed, size=(free.n_nodes, 3)))
    return free, v


@pytest.mark.parametrize("method, dt, tol", [("rk4", 2.5e-4, 1e-6), ("rattle", 2.5e-4, 1e-2)])
def test_single_prism_matches_paper_matrix_form(method, dt, tol, device):
    """Class-1 prism, massive bars, taut cables: the paper's closed-form multiplier (Eq. 14) at a
    fine step against the engine's projected integrators."""
    net, v = free_prism_with_massive_bars()
    form = ClassOneMatrixForm.from_network(net)
    t_end = 0.1
    _, N, _ = integrate_matrix_form(form, net.positions.T.copy(), v.T.copy(), t_end, 1e-5)
    x_ref = N[-1].T
    r = run_batch(network_batch([net], [v]), RunSettings(t_end=t_end, dt=dt, method=method, output_interval=t_end, device=device))
    x = net.positions + r.final_displacement[0]
    disp = np.abs(x_ref - net.positions).max()
    assert disp > 1e-4  # it really moved
    assert np.abs(x - x_ref).max() < tol * disp
    assert r.bar_length_error[0] < 1e-12


def test_engine_rk4_equals_numpy_rk4_step_for_step(device):
    """Same scheme, independently coded: RK4 on the index-1 equations plus projection, same dt,
    here with slackening cables (random kicks of 0.02 m/s)."""
    net, v = free_prism_with_massive_bars(speed=0.02)
    ref = ReferenceSystem(net)
    dt, t_end = 5e-4, 0.1
    _, X, _ = ref.integrate(net.positions, v, t_end, dt, method="rk4", stride=int(round(t_end / dt)))
    r = run_batch(network_batch([net], [v]), RunSettings(t_end=t_end, dt=dt, method="rk4", output_interval=t_end, device=device))
    x = net.positions + r.final_displacement[0]
    assert np.abs(x - X[-1]).max() < 1e-12 * np.abs(X[-1] - net.positions).max() * 1e3


@pytest.mark.parametrize("beta", [0.0, 1.0])
def test_column_matches_lagrange_reference(beta, device):
    """Constrained (class-2) column with slackening cables: engine RK4 vs NumPy RK4, same dt."""
    cfg = ColumnConfig(n_prisms=4)
    scene = build_column(cfg, prestrain=0.002, v0=0.05, base_rigidity=beta)
    dt, t_end = 2e-4, 0.2
    ref = ReferenceSystem(scene.network)
    t, X, _ = ref.integrate(scene.network.positions, scene.velocity, t_end, dt, method="rk4", stride=50)
    h = prism_heights(scene.topology, X)
    eps_ref = (h - cfg.height) / h
    r = simulate_batch(cfg, {"prestrain": [0.002], "v0": [0.05], "base_rigidity": [beta]},
                       RunSettings(t_end=t_end, dt=dt, method="rk4", output_interval=50 * dt, device=device))
    np.testing.assert_allclose(r.time, t, rtol=1e-12, atol=1e-15)
    scale = np.abs(eps_ref).max()
    assert scale > 1e-3
    assert np.abs(r.strain[0] - eps_ref).max() < 1e-8 * scale / 1e-3
    # RATTLE agrees to its second-order accuracy
    r2 = simulate_batch(cfg, {"prestrain": [0.002], "v0": [0.05], "base_rigidity": [beta]},
                        RunSettings(t_end=t_end, dt=dt, method="rattle", output_interval=50 * dt, device=device))
    assert np.abs(r2.strain[0] - eps_ref).max() < 1e-2 * scale


def modal_strain(scene, times):
    """Strain history of the linearised column: q(t) = sum phi_i (phi_i^T M v0) sin(w_i t) / w_i."""
    net = scene.network
    res = linear.modal_analysis(net)
    assert np.all(res.omega2 > 0)
    M = np.kron(net.mass_matrix(), np.eye(3))
    phi = res.shapes.reshape(len(res.omega2), -1)
    w = np.sqrt(res.omega2)
    amp = (phi @ M @ scene.velocity.reshape(-1)) / w
    q = np.einsum("m,tm,mk->tk", amp, np.sin(np.outer(times, w)), phi).reshape(len(times), -1, 3)
    h = prism_heights(scene.topology, net.positions + q)
    return (h - scene.topology.config.height) / h


@pytest.mark.parametrize("beta", [0.0, 1.0])
def test_small_amplitude_wave_matches_linearised_theory(beta, device):
    cfg = ColumnConfig(n_prisms=16)
    v0 = 1e-6  # strain ~1e-5 << prestrain 2e-3: linear regime
    scene = build_column(cfg, prestrain=0.002, v0=v0, base_rigidity=beta)
    r = simulate_batch(cfg, {"prestrain": [0.002], "v0": [v0], "base_rigidity": [beta]},
                       RunSettings(t_end=2.0, dt=1e-3, method="rk4", output_interval=0.01, device=device))
    eps_lin = modal_strain(scene, r.time)
    scale = np.abs(eps_lin).max()
    # RK4's phase error is ~(w dt)^4/120: what remains is the O(strain/p) nonlinearity
    assert np.abs(r.strain[0] - eps_lin).max() < 0.01 * scale
    # the strain front travels at the eigen-analysis long-wave speed or below it
    c0 = linear.long_wave_speed(scene).c0
    assert 0.02 < c0 < 0.03


def displaced_batches():
    """(batch, per-column networks): columns that differ in prestrain, unit mass and base rigidity
    (fixed nodes, lumped masses; cable_EA shared, so parameter widths 1 and 3 mix), and free
    prisms whose mass is in their bars (M^-1 couples each bar's two nodes)."""
    cfg = ColumnConfig(n_prisms=3)
    cases = {"prestrain": [0.002, 0.01, 0.005], "base_rigidity": [0.0, 0.5, 1.0], "unit_mass": [0.02, 0.03, 0.01]}
    nets = [build_column(cfg, **{k: v[b] for k, v in cases.items()}).network for b in range(3)]
    yield column_batch(cfg, cases), nets
    prisms = [free_prism_with_massive_bars(prestrain=p)[0] for p in (0.01, 0.02)]
    yield network_batch(prisms), prisms


@pytest.mark.parametrize("precision, rtol", [("fp64", 1e-12), ("fp32", 1e-4)])
def test_gathered_acceleration_is_minv_f(precision, rtol, device):
    """The force gather (one thread per block of M) against the dense float64 M^-1 f(x) at a
    random displaced state."""
    rng = np.random.default_rng(3)
    for batch, nets in displaced_batches():
        integ = Integrator(batch, RunSettings(device=device, precision=precision, fused=False), 1e-4, 1, 1, path=Path.STAGED)
        dx = rng.normal(scale=2e-3, size=(len(nets), batch.positions.shape[0], 3))
        dx[:, batch.fixed] = 0.0
        d = integ.data
        vec = wp.types.vector(3, integ.real)
        d.u.assign(wp.array(np.ascontiguousarray(dx.transpose(1, 0, 2)), dtype=vec, device=d.u.device))
        integ.stepper.gather(d.u, d.v, 0.0, d.a, d.u_prev)  # v_out: a scratch row
        a = d.a.numpy().transpose(1, 0, 2)
        for b, net in enumerate(nets):
            ref = ReferenceSystem(net)
            x = net.positions + dx[b]
            a_ref = ref.to_x(ref.Minv @ ref.to_q(ref.nodal_forces(x)), fill=np.zeros_like(x))
            assert np.abs(a_ref).max() > 1.0  # cables really pull
            np.testing.assert_allclose(a[b], a_ref, rtol=0, atol=rtol * np.abs(a_ref).max())
