"""The reference of the striker check (issue 34 item 5; :func:`.checks.check_striker`): a mass striking the
linear rigid-base (RB) chain, solved exactly. Derivation: docs/validation.md, "Striker".

The reference is the RB column's exact 1-D chain (:mod:`.closed_forms`): levels 1..N above the clamp,
masses m_eff (the struck end level m_eff / 2), springs K. The striker (mass M) moves with the end level
while they touch: one body of mass m_eff/2 + M. The contact force on the striker is

    F = M u_N'' = M / (m_eff/2 + M) * K (u_(N-1) - u_N)    (up, >= 0 while touching),

so the striker leaves when the last prism's force turns to tension (F = 0 from above). Then it flies at
its velocity of that instant and the chain goes on with its free end, until the end catches it up (the
end's height reaches the striker's): a plastic impact of the two (momentum kept), and contact again.
Each phase is linear with constant coefficients: from (u0, u0') at its start,

    u(t) = Phi [cos(w t) Phi^T M u0 + sin(w t)/w Phi^T M u0'],    K Phi = M Phi w^2,  Phi^T M Phi = 1,

exact (float64), with the events found by root bracketing (brentq) on a grid finer than the chain's
shortest period. The blow at t = 0 is the engine's (:mod:`warp_tensegrity.scene.striker`): plastic, the
end level and the striker leave together at V1 = v0 M / (M + m_eff/2).

The energy the striker hands to the column is E_col(t) = E_kin + E_el of the chain (the end level's
kinetic energy included): (1/2)(m_eff/2) V1^2 after the blow, then the work of F.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import eigh
from scipy.optimize import brentq

from .closed_forms import RBChain

__all__ = ["StrikerReference", "striker_chain"]


@dataclass
class StrikerReference:
    """The exact linear striker response at the requested times (SI units)."""

    time: np.ndarray
    velocity: np.ndarray
    """Striker velocity [m s-1] (negative: downward)."""
    force: np.ndarray
    """Contact force [N] (>= 0)."""
    column_energy: np.ndarray
    """Energy of the column above its reference state [J]."""
    strain: np.ndarray
    """(n_time, N) prism strain (h - h0)/h0, prism 0 at the clamp (the engine's order)."""
    separations: list
    """The times [s] the striker left the end."""
    contacts: list
    """The times [s] the end caught the striker up again."""
    blow_speed: float
    """V1 [m s-1]."""


def _modes(mass: np.ndarray, K: float):
    n = mass.size
    Kmat = K * (2.0 * np.eye(n) - np.eye(n, k=1) - np.eye(n, k=-1))
    Kmat[-1, -1] = K  # the free (struck) end has one spring
    w2, phi = eigh(Kmat, np.diag(mass))
    return np.sqrt(np.maximum(w2, 0.0)), phi, Kmat


def _evolve(modes, mass, u0, v0, t):
    """(u, u', u'') at times t (array) from (u0, v0) at t = 0."""
    w, phi, _ = modes
    a = phi.T @ (mass * u0)
    b = phi.T @ (mass * v0)
    t = np.atleast_1d(t)[:, None]
    c, s = np.cos(w * t), np.sin(w * t)
    return (c * a + s / w * b) @ phi.T, (-w * s * a + c * b) @ phi.T, (-(w**2) * (c * a + s / w * b)) @ phi.T


def striker_chain(chain: RBChain, n_prisms: int, striker_mass: float, v0: float, time) -> StrikerReference:
    """The exact response of the linear RB chain of ``n_prisms`` prisms to a striker of ``striker_mass``
    [kg] arriving at ``v0`` [m s-1], sampled at ``time`` [s] (increasing, from 0)."""
    time = np.asarray(time, dtype=np.float64)
    N, M, K = int(n_prisms), float(striker_mass), chain.K
    m_col = np.full(N, chain.m_eff)
    m_col[-1] = 0.5 * chain.m_eff
    m_touch = m_col.copy()
    m_touch[-1] += M
    free, touch = _modes(m_col, K), _modes(m_touch, K)
    Kmat = free[2]
    grid = 2.0 * np.pi / max(free[0].max(), touch[0].max()) / 40.0
    V1 = v0 * M / (M + m_col[-1])
    u = np.zeros(N)
    ud = np.zeros(N)
    ud[-1] = -V1
    t0, s0, Vs = 0.0, 0.0, -V1  # phase start; the striker's height and velocity when apart
    touching = True
    vel, force, energy = np.empty(time.size), np.empty(time.size), np.empty(time.size)
    strain = np.empty((time.size, N))
    seps, contacts = [], []
    done = 0
    t_end = float(time[-1]) if time.size else 0.0
    while done < time.size:
        modes, mass = (touch, m_touch) if touching else (free, m_col)
        if touching:  # F = M u_N'': the striker leaves where it turns negative
            event = lambda tau: _evolve(modes, mass, u, ud, tau)[2][0, -1]  # noqa: E731
        else:  # the end's height reaches the striker's
            event = lambda tau: _evolve(modes, mass, u, ud, tau)[0][0, -1] - (s0 + Vs * tau)  # noqa: E731
        # the first sign change past the start (touching: the force starts at 0 or above, rises first)
        taus = np.arange(1, int(np.ceil((t_end - t0) / grid)) + 2) * grid
        vals = np.array([event(x) for x in taus]) if taus.size else np.zeros(0)
        if touching:
            hit = np.flatnonzero((vals[:-1] >= 0) & (vals[1:] < 0) & (np.maximum.accumulate(vals)[:-1] > 0))
        else:
            hit = np.flatnonzero((vals[:-1] < 0) & (vals[1:] >= 0))
        t_ev = t0 + (brentq(event, taus[hit[0]], taus[hit[0] + 1], xtol=1e-15, rtol=1e-14) if hit.size else np.inf)
        sel = np.flatnonzero((time >= t0) & (time < t_ev)) if np.isfinite(t_ev) else np.flatnonzero(time >= t0)
        sel = sel[sel >= done]
        if sel.size:
            x, xd, xdd = _evolve(modes, mass, u, ud, time[sel] - t0)
            if touching:
                vel[sel], force[sel] = xd[:, -1], M * xdd[:, -1]
            else:
                vel[sel], force[sel] = Vs, 0.0
            energy[sel] = 0.5 * ((xd**2) @ m_col) + 0.5 * np.einsum("ti,ij,tj->t", x, Kmat, x)
            ext = np.concatenate([np.zeros((x.shape[0], 1)), x], axis=1)
            strain[sel] = np.diff(ext, axis=1) / chain.h0
            done = int(sel[-1]) + 1
        if not np.isfinite(t_ev) or t_ev > t_end:
            break
        x, xd, _ = _evolve(modes, mass, u, ud, t_ev - t0)
        u, ud = x[0], xd[0]
        if touching:  # the striker flies on from the end's position and velocity
            seps.append(t_ev)
            s0, Vs = u[-1], ud[-1]
        else:  # plastic impact of the end level and the striker (momentum kept)
            contacts.append(t_ev)
            s_now = s0 + Vs * (t_ev - t0)
            u[-1] = s_now
            ud[-1] = (m_col[-1] * ud[-1] + M * Vs) / (m_col[-1] + M)
        touching = not touching
        t0 = t_ev
        if not touching:
            s0 = u[-1]
    return StrikerReference(time, vel, force, energy, strain, seps, contacts, V1)

