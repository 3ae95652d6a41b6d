"""The diatomic gap check (issue 34 item 5): its Bloch theory and the check itself."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from warp_tensegrity import ColumnConfig
from warp_tensegrity.validation import report
from warp_tensegrity.validation.checks import chain_of
from warp_tensegrity.validation.diatomic import band_edges, bloch_cell_two_levels, bloch_factor, check_diatomic, cos_q


def test_bloch_factor_is_the_chains_wave():
    """lambda + 1/lambda = 2 cos q at every frequency; |lambda| < 1 exactly in the gap and above the optical
    branch, the gap's edges where cos q = -1; the two-level cell's branches meet them at q = pi."""
    K, m1, m2 = 3.2, 0.18, 0.36
    lo, hi = band_edges(K, m1, m2)
    w = np.linspace(0.01, 1.5 * np.sqrt(2 * K * (1 / m1 + 1 / m2)), 400)
    lam = bloch_factor(w, K, m1, m2)
    np.testing.assert_allclose((lam + 1 / lam).real, 2 * cos_q(w, K, m1, m2), rtol=1e-12, atol=1e-12)
    inside = (w > lo) & (w < hi)
    assert np.all(np.abs(lam[inside]) < 1) and np.all(lam[inside].real < 0)
    band = (w < lo) | ((w > hi) & (w < np.sqrt(2 * K * (1 / m1 + 1 / m2))))
    np.testing.assert_allclose(np.abs(lam[band]), 1.0, rtol=1e-12)
    np.testing.assert_allclose(cos_q([lo, hi], K, m1, m2), -1.0, rtol=1e-12)
    cfg = ColumnConfig()
    ch = chain_of(cfg, 0.002)
    edge = bloch_cell_two_levels(cfg, 0.002, cfg.unit_mass, 2 * cfg.unit_mass, [np.pi])[0]
    np.testing.assert_allclose(edge, band_edges(ch.K, ch.m_eff, 2 * ch.m_eff), rtol=1e-9)


def test_the_bloch_factor_carries_a_record_down_a_semi_infinite_chain():
    """The theory of the check's prediction, on a chain integrated here (not the engine): a long diatomic
    chain driven at its end by a smooth force; the record of a spring c cells down is the first spring's
    filtered by lambda(w)^c, for a drive with content in the band and in the gap."""
    K, m1, m2, n = 1.0, 1.0, 2.0, 160
    mass = np.where(np.arange(n) % 2 == 0, m1, m2)

    def rhs(t, y):
        u, v = y[:n], y[n:]
        f = np.zeros(n)
        s = K * np.diff(np.r_[u, 0.0])  # springs i -> i+1, the last to a wall far away
        f += s
        f[1:] -= s[:-1]
        f[0] += np.exp(-0.5 * ((t - 12.0) / 3.0) ** 2) * np.cos(1.2 * t)  # the gap is 1 .. 1.414
        return np.r_[v, f / mass]

    t = np.arange(0.0, 45.0, 0.05)
    y = solve_ivp(rhs, (0, t[-1]), np.zeros(2 * n), t_eval=t, rtol=1e-11, atol=1e-14, method="DOP853").y
    strain = np.diff(y[:n].T, axis=1)  # springs between masses
    springs = 2 + 2 * np.arange(5)  # one kind, a cell apart
    n_fft = 64 * len(t)  # the check's padding (4x wraps 5e-3 of lambda^c's slowly decaying response)
    Y0 = np.fft.rfft(strain[:, springs[0]], n_fft)
    lam = bloch_factor(2 * np.pi * np.fft.rfftfreq(n_fft, t[1] - t[0]), K, m1, m2)
    for c, j in enumerate(springs[1:], start=1):
        pred = np.fft.irfft(Y0 * lam**c, n_fft)[: len(t)]
        assert np.abs(pred - strain[:, j]).max() < 3e-4 * np.abs(strain[:, springs[0]]).max(), c


def test_diatomic_check():
    g = check_diatomic()
    assert g.passed, report([g])
    assert g.data["kappa_w0"] > 0.5  # it does decay inside the gap, by a factor ~2 per cell
