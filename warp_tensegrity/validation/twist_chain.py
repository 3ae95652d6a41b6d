"""An independent reference for bar contact (issue 32): the rigid-base (RB) column of right-handed
T3 prisms under an axial impact, reduced to its symmetric motion and integrated by SciPy.

Under an axial impact the RB column keeps its three-fold symmetry, so each level is a rigid
triangle with two degrees of freedom, its height z_l and its rotation theta_l about the axis. A
prism's bars then fix its height by its twist phi_j = theta_j - theta_{j+1}:

    h(phi)^2 = L^2 - 2 a^2 (1 - cos phi),

so the column has one generalized coordinate per prism, phi_j. The kinetic energy is
sum_l m_l (z_l'^2 + a^2 theta_l'^2) / 2 with z_l = sum_{j<l} h(phi_j) and theta_l = -sum_{j<l} phi_j; the
elastic energy is that of the three cross cables of each prism (tension only, rest length from the
prestrain p), whose length obeys s^2 = h^2 + 2 a^2 (1 - cos(phi - 2 pi/3)). The equations of motion
M(phi) phi'' = -dV/dphi - J_z^T m (dJ_z/dt) phi' are integrated with ``scipy.integrate.solve_ivp``
(DOP853 at tight tolerances), a different method from the engine's RATTLE.

Contact (``bar_radius`` > 0): the bars of a prism touch at the twist phi_c where their axes are
2 r apart (:func:`warp_tensegrity.scene.contact.contact_twist`), a hard stop phi_j <= phi_c. A
terminal event stops the integration at each impact, Newton's impact law with restitution e acts
along the stop's normal in the kinetic metric (phi'+ = phi'- - (1 + e) M^-1 n (n.phi'-)/(n.M^-1 n)),
and the integration restarts. Without contact the twist runs through pi (the bars cross).

The initial velocity is the engine's default ('rigid_members') impact: the least kinetic energy
with the free end moving at -v0, which for this symmetric column is q' = -v0 M^-1 c / (c.M^-1 c),
c = dz_n/dphi.

Only NumPy and SciPy; no Warp.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..scene.columns import ColumnConfig
from ..scene.contact import contact_twist


@dataclass
class TwistChainResult:
    time: np.ndarray
    """(n_out,) output times [s]."""
    twist: np.ndarray
    """(n_out, n_prisms) twist of each prism [rad]."""
    strain: np.ndarray
    """(n_out, n_prisms) axial strain (h - h0)/h [1], the engine's measure."""
    energy: np.ndarray
    """(n_out,) kinetic plus elastic energy [J]."""
    impacts: int
    """Impacts at the hard stop."""
    contact_twist: float | None
    """The stop phi_c [rad], None without contact."""


class TwistChain:
    """The RB column of ``config`` (right-handed, rigid bases) at prestrain ``prestrain``."""

    def __init__(self, config: ColumnConfig, prestrain: float, bar_radius: float = 0.0, restitution: float = 1.0,
                 cable_EA: float | None = None, unit_mass: float | None = None):
        if config.handedness != "right":
            raise ValueError(f"handedness = {config.handedness!r}: the twist chain is a right-handed column")
        self.n = n = int(config.n_prisms)
        self.a = a = float(config.radius)
        self.h0 = float(config.height)
        self.phi0 = float(config.twist)
        self.L2 = self.h0**2 + 2.0 * a * a * (1.0 - math.cos(self.phi0))  # bar length squared
        EA = config.cable_EA if cable_EA is None else float(cable_EA)
        mu = config.unit_mass if unit_mass is None else float(unit_mass)
        s_ref = math.sqrt(self.h0**2 + 2.0 * a * a * (1.0 - math.cos(self.phi0 - 2.0 * math.pi / 3.0)))
        self.Lc = s_ref / (1.0 + prestrain)  # cross-cable rest length
        self.k = EA / self.Lc
        m = np.full(n, mu)  # levels 1..n; level 0 is clamped
        if config.end_base_mass == "half":
            m[-1] = 0.5 * mu
        self.m = m
        self.lower = np.tril(np.ones((n, n)))  # J[l, j] = 1 for prism j below level l+1
        self.phi_c = contact_twist(a, self.h0, self.phi0, bar_radius) if bar_radius > 0 else None
        self.e = float(restitution)

    # ------------------------------------------------------------------ kinematics
    def height(self, phi):
        """h(phi) [m] and its first two derivatives."""
        a2 = self.a * self.a
        h = np.sqrt(self.L2 - 2.0 * a2 * (1.0 - np.cos(phi)))
        dh = -a2 * np.sin(phi) / h
        ddh = (-a2 * np.cos(phi) - dh * dh) / h
        return h, dh, ddh

    def mass_matrix(self, phi):
        _, dh, _ = self.height(phi)
        Jz = self.lower * dh[None, :]
        return Jz.T @ (self.m[:, None] * Jz) + self.a**2 * self.lower.T @ (self.m[:, None] * self.lower), Jz

    def potential(self, phi):
        """Elastic energy [J] and its gradient in phi."""
        h, dh, _ = self.height(phi)
        a2 = self.a * self.a
        psi = phi - 2.0 * math.pi / 3.0
        s = np.sqrt(h * h + 2.0 * a2 * (1.0 - np.cos(psi)))
        stretch = np.maximum(s - self.Lc, 0.0)  # tension only
        ds = (h * dh + a2 * np.sin(psi)) / s
        return 1.5 * self.k * float((stretch**2).sum()), 3.0 * self.k * stretch * ds

    def energy(self, phi, w):
        M, _ = self.mass_matrix(phi)
        return 0.5 * float(w @ M @ w) + self.potential(phi)[0]

    def rhs(self, t, y):
        n = self.n
        phi, w = y[:n], y[n:]
        _, dh, ddh = self.height(phi)
        M, Jz = self.mass_matrix(phi)
        zdd_vel = self.lower @ (ddh * w * w)  # (dJ_z/dt) phi'
        f = -self.potential(phi)[1] - Jz.T @ (self.m * zdd_vel)
        return np.concatenate([w, np.linalg.solve(M, f)])

    def impact_velocity(self, phi, v0: float):
        """The least-kinetic-energy twist rates with the free end at z' = -v0."""
        M, Jz = self.mass_matrix(phi)
        c = Jz[-1]
        x = np.linalg.solve(M, c)
        return -v0 * x / float(c @ x)

    # ------------------------------------------------------------------ integration
    def simulate(self, v0: float, t_end: float, times=None, rtol: float = 1e-11, atol: float = 1e-14,
                 max_impacts: int = 10_000) -> TwistChainResult:
        """Integrate from the reference at impact speed ``v0`` [m s-1] to ``t_end`` [s]; output at
        ``times`` (default 200 equal intervals)."""
        from scipy.integrate import solve_ivp

        n = self.n
        times = np.linspace(0.0, t_end, 201) if times is None else np.asarray(times, dtype=np.float64)
        phi = np.full(n, self.phi0)
        y = np.concatenate([phi, self.impact_velocity(phi, v0)])
        t, out, impacts = 0.0, np.full((len(times), 2 * n), np.nan), 0
        stops = []
        if self.phi_c is not None:
            for j in range(n):
                ev = (lambda t, y, j=j: y[j] - self.phi_c)
                ev.terminal, ev.direction = True, 1.0
                stops.append(ev)
        while t < t_end:
            sol = solve_ivp(self.rhs, (t, t_end), y, method="DOP853", rtol=rtol, atol=atol, events=stops or None,
                            dense_output=True)
            if sol.status < 0:
                raise RuntimeError(f"twist chain: {sol.message}")
            t_stop = float(sol.t[-1])
            sel = (times >= t) & (times <= t_stop)
            if sel.any():
                out[sel] = sol.sol(times[sel]).T
            y = sol.y[:, -1].copy()
            t = t_stop
            if sol.status == 1:  # an impact at the stop
                hit = [j for j, te in enumerate(sol.t_events) if len(te)]
                y[:n][hit] = self.phi_c
                M, _ = self.mass_matrix(y[:n])
                Minv = np.linalg.inv(M)
                for j in hit:  # one prism at a time (simultaneous stops are distinct prisms)
                    if y[n + j] > 0.0:
                        y[n:] = y[n:] - (1.0 + self.e) * Minv[:, j] * y[n + j] / Minv[j, j]
                        impacts += 1
                if impacts > max_impacts:
                    raise RuntimeError(f"twist chain: more than {max_impacts} impacts (chattering)")
                # restart at the stop: moving away from it, its event cannot fire at once
        phi = out[:, :n]
        h = self.height(phi)[0]
        energy = np.array([self.energy(o[:n], o[n:]) for o in out])
        return TwistChainResult(time=times, twist=phi, strain=(h - self.h0) / h, energy=energy, impacts=impacts,
                                contact_twist=self.phi_c)
