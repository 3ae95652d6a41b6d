"""The striker check of the validation gallery (warp_tensegrity.validation.striker, docs/validation.md):
its reference against a direct integration, the engine passing it, and a 5 % error in the striker's mass
(on the engine side only) failing it."""

from contextlib import contextmanager

import numpy as np
from scipy.integrate import solve_ivp

from warp_tensegrity import ColumnConfig
from warp_tensegrity.scene.striker import blow_speed
from warp_tensegrity.validation import report
from warp_tensegrity.validation.closed_forms import rb_chain
from warp_tensegrity.validation.figures import write_figures
from warp_tensegrity.validation.checks import check_striker
from warp_tensegrity.validation.striker import striker_chain

from tests.validation.engine_patch import ORIGINAL, engine_builds_with


def test_the_reference_solves_the_chain():
    """striker_chain against DOP853 on the chain with the striker riding on its end level, up to the
    separation (the event F = 0), then the free flight of both to the end's return."""
    cfg = ColumnConfig()
    ch = rb_chain(cfg.cable_EA, cfg.radius, cfg.height, cfg.unit_mass, 0.002)
    N, M, v0 = 6, 0.1, 1e-6
    m = np.full(N, ch.m_eff)
    m[-1] *= 0.5

    def rhs(mass):
        def f(_t, y):
            u, ud = y[:N], y[N:]
            ext = np.concatenate([[0.0], u, [u[-1]]])
            return np.concatenate([ud, ch.K * (ext[:-2] - 2 * ext[1:-1] + ext[2:]) / mass])
        return f

    touch = m.copy()
    touch[-1] += M
    y0 = np.zeros(2 * N)
    y0[-1] = -blow_speed(v0, M, m[-1])
    leave = lambda t, y: ch.K * (y[N - 2] - y[N - 1])  # noqa: E731 (the last spring turns to tension)
    leave.terminal, leave.direction = True, -1
    a = solve_ivp(rhs(touch), (0, 5.0), y0, method="DOP853", rtol=1e-12, atol=1e-20, events=leave, dense_output=True)
    t_sep = float(a.t_events[0][0])
    y1 = a.y[:, -1]
    back = lambda t, y: y[N - 1] - (y1[N - 1] + y1[-1] * (t - t_sep))  # noqa: E731
    back.terminal, back.direction = True, 1
    b = solve_ivp(rhs(m), (t_sep, t_sep + 5.0), y1, method="DOP853", rtol=1e-12, atol=1e-20, events=back,
                  dense_output=True)
    events = striker_chain(ch, N, M, v0, [0.0, float(b.t[-1]) + 0.1])
    assert abs(events.separations[0] - t_sep) < 1e-9 and abs(events.contacts[0] - b.t_events[0][0]) < 1e-9
    t = np.linspace(0.0, float(b.t[-1]) * 0.999, 300)
    ref = striker_chain(ch, N, M, v0, t)
    direct = np.where(t < t_sep, a.sol(np.minimum(t, t_sep))[2 * N - 1], y1[-1])
    np.testing.assert_allclose(ref.velocity, direct, rtol=0, atol=1e-9 * v0)


def test_the_engine_passes_and_the_figure(tmp_path):
    g = check_striker()
    assert g.passed, report([g])
    (path,) = write_figures([g], tmp_path)
    assert path.name == "validation_striker.png" and path.stat().st_size > 10_000


@contextmanager
def heavier_striker(factor: float):
    """The engine (and its policy) build their columns with the striker ``factor`` times heavier, the blow
    consistent with it; the reference keeps the true mass."""

    def column_batch(config, params):
        batch = ORIGINAL(config, params)
        if batch.striker_mass is not None:
            M = batch.striker_mass * factor
            V1 = blow_speed(batch.params["v0"], M, batch.striker_end_mass)
            batch.velocity = batch.velocity * (V1 / -batch.striker_velocity)[:, None, None]
            batch.striker_mass, batch.striker_velocity = M, -V1
        return batch

    with engine_builds_with(column_batch):
        yield


def test_a_five_percent_error_in_the_striker_mass_fails():
    with heavier_striker(1.05):
        g = check_striker()
    failed = {c.name for c in g.checks if not c.passed}
    assert {"striker_velocity", "striker_energy"} <= failed, report([g])
