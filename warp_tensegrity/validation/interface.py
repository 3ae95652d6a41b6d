"""The interface check: a long-wave pulse crossing the joint of two rigid-base (RB) segments of
different prestrain, against the impedance formula of the discrete chain (docs/validation.md,
"Interface").

Theory (SI units). The linearised RB column is exactly a chain of level displacements u_n: masses
m_eff = m (1 + 4 h0^2/a^2) (a level's axial mass plus the inertia of the twist its bars lock to it) and,
in prism j, the spring K_j = 12 sqrt3 EA p_j h0^2/(a^2 s0) (:mod:`.closed_forms`). A segment carries long
waves at c_j = h0 sqrt(K_j/m_eff) with the impedance (axial force per level velocity)

    Z_j = sqrt(K_j m_eff) = m_eff c_j / h0.

At the joint level (springs K1 on one side, K2 on the other) a harmonic wave e^(i(k n - w t)) meets
u_n = e^(i k1 n) + R e^(-i k1 n) (n <= 0), T e^(i k2 n) (n >= 0). With a_j = K_j (e^(i k_j) - 1), the
joint's equation gives, exactly for the discrete chain,

    R_u = (a1 - conj(a1)) / (a2 - conj(a1)) - 1,   T_u = 1 + R_u,

and as k -> 0 (a_j -> i K_j k_j = i w Z_j) R_u = (Z1 - Z2)/(Z1 + Z2), T_u = 2 Z1/(Z1 + Z2) for the
displacement and the velocity. A prism's strain is the difference of its levels' displacements: a wave
towards +n has strain -v/c, one towards -n +v/c, so the strain (and the force) follows

    R_eps = (Z2 - Z1)/(Z1 + Z2),   T_eps = T_u c1/c2 = 2 Z1 c1 / (c2 (Z1 + Z2)).

With equal level masses, Z2/Z1 = c2/c1 = sqrt(p2/p1), and T_u is real at every frequency (a2 - conj(a1) is
imaginary: its real part 2 K1 sin^2(k1/2) - 2 K2 sin^2(k2/2) = 0 by each side's dispersion relation), so the
joint adds no delay. Dispersion changes R and T by O((k h0)^2), so the check compares
the pulses' zeroth and first time moments at a station (their w = 0 content, where the formulas are
exact), not their peaks: the peaks differ from the formulas by the dispersion of a pulse a few prisms
long (a few per cent, reported).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import hetero
from .dispersion import bands
from .gallery import Check, CheckGroup
from ..engine import run_batch
from ..scene.columns import ColumnConfig

__all__ = ["InterfaceTheory", "interface_theory", "discrete_coefficients", "check_interface"]


@dataclass(frozen=True)
class InterfaceTheory:
    """The long-wave reflection and transmission of a joint between two RB segments."""

    c1: float
    """Long-wave speed of the incident segment [m s-1] (its Bloch cell)."""
    c2: float
    """The same, the transmitting segment [m s-1]."""
    Z1: float
    """Impedance m_eff c1/h0 of the incident segment [N s m-1]."""
    Z2: float
    """The same, transmitting segment [N s m-1]."""

    @property
    def reflected_strain(self) -> float:
        """R_eps = (Z2 - Z1)/(Z1 + Z2) [-]."""
        return (self.Z2 - self.Z1) / (self.Z1 + self.Z2)

    @property
    def transmitted_strain(self) -> float:
        """T_eps = 2 Z1 c1 / (c2 (Z1 + Z2)) [-]."""
        return 2.0 * self.Z1 * self.c1 / (self.c2 * (self.Z1 + self.Z2))

    @property
    def transmitted_velocity(self) -> float:
        """T_u = 2 Z1/(Z1 + Z2) [-] (displacement and velocity)."""
        return 2.0 * self.Z1 / (self.Z1 + self.Z2)

    height: float
    """Prism height h0 [m]."""

    def delay(self, d1: float, d2: float) -> float:
        """Travel time [s] of a long wave over d1 prism heights of the incident segment and d2 of the other."""
        return d1 * self.height / self.c1 + d2 * self.height / self.c2


def interface_theory(config: ColumnConfig, p1: float, p2: float) -> InterfaceTheory:
    """The joint of an RB segment at prestrain ``p1`` (incident side) and one at ``p2``, of ``config``'s
    prism and level mass: c from the Bloch cell's long-wave limit (:func:`.dispersion.bands`, k h0 = 1e-3),
    m_eff from the RB chain."""
    m_eff = hetero.chain_at(config, p1).m_eff
    k = 1e-3 / config.height
    c1, c2 = (bands(config, p, 1.0, k=[k]).long_wave_speed() for p in (p1, p2))
    return InterfaceTheory(c1, c2, m_eff * c1 / config.height, m_eff * c2 / config.height, config.height)


def discrete_coefficients(K1: float, K2: float, m_eff: float, omega):
    """(R_eps, T_eps) of the discrete chain's joint at angular frequencies ``omega`` [rad s-1] below both
    cut-offs, strain phases taken at the prisms next to the joint (the exact formulas of the module
    docstring); they tend to the long-wave ones as omega -> 0."""
    w = np.asarray(omega, dtype=float)
    k1, k2 = (2.0 * np.arcsin(w / (2.0 * np.sqrt(K / m_eff))) for K in (K1, K2))
    a1, a2 = K1 * (np.exp(1j * k1) - 1.0), K2 * (np.exp(1j * k2) - 1.0)
    R_u = (a1 - np.conj(a1)) / (a2 - np.conj(a1)) - 1.0
    T_u = 1.0 + R_u
    return (R_u * (np.exp(1j * k1) - 1.0) / (np.exp(-1j * k1) - 1.0),
            T_u * (np.exp(1j * k2) - 1.0) / (1.0 - np.exp(-1j * k1)))


def _moments(t, y, centre: float, half: float):
    """(area [s], centroid [s]) of the record y(t) over the window centre +- half."""
    sel = (t >= centre - half) & (t <= centre + half)
    area = float(np.trapezoid(y[sel], t[sel]))
    return area, float(np.trapezoid(t[sel] * y[sel], t[sel]) / area)


def check_interface(p1: float = 0.002, p2: float = 0.0005, n1: int = 42, n2: int = 19, d1: int = 21, d2: int = 8,
                    sigma: float = 4.0, strain_of_p: float = 1e-3, dt: float = 5e-3, window: float = 5.0,
                    tolerance: float = 1e-3, tolerance_delay: float = 1e-3, device: str = "cpu") -> CheckGroup:
    """A two-segment RB column: ``n1`` prisms at prestrain ``p1`` on the struck side, ``n2`` at ``p2`` on the
    clamped side. At t = 0 the levels near the free end move towards the clamp with a Gaussian profile of
    ``sigma`` levels (the half-mass free end is a mirror plane, so one pulse of that width leaves it, its
    strain ``strain_of_p`` x min(p1, p2)). The pulse's area and time centroid at a prism ``d1`` prisms
    before the joint (incident, then reflected) and ``d2`` after it (transmitted), each over a window of
    +- ``window`` x the pulse's time width around its long-wave arrival, against R_eps, T_eps and the
    long-wave travel time (module docstring)."""
    cfg = ColumnConfig(n_prisms=n1 + n2)
    N, h0, m = cfg.n_prisms, cfg.height, cfg.unit_mass
    th = interface_theory(cfg, p1, p2)
    level_mass = np.full(N + 1, m)
    level_mass[[0, N]] = 0.5 * m  # the engine's 'half' end bases: the free end is the chain's mirror plane
    V = 2.0 * strain_of_p * min(p1, p2) * th.c1  # the pulse leaving the end carries V/2, strain V/(2 c1)
    velocity = -V * np.exp(-0.5 * ((N - np.arange(N + 1)) / sigma) ** 2)
    velocity[0] = 0.0
    s1, s2 = n2 + d1, n2 - 1 - d2  # the stations (prisms); the joint is level n2
    t_inc = th.delay(N - s1 - 0.5, 0.0)
    t_ref = t_inc + th.delay(2 * d1 + 1.0, 0.0)
    t_tra = th.delay(n1, d2 + 0.5)
    half = window * sigma * h0 / th.c1  # the pulse's time width is the same in both segments
    # the windows must hold one pulse each, start after t = 0 and end before the clamp's echo returns
    if not (t_inc > half and t_ref - t_inc > 2 * half and th.delay(0.0, 2 * s2 + 1.0) > 2 * half):
        raise ValueError("check_interface: the stations are too close to the ends or the joint for the pulse width")
    pp = np.concatenate([np.full(n2, p2), np.full(n1, p1)])
    batch = hetero.graded_batch(cfg, pp, level_mass, velocity)
    settings = hetero.graded_settings(max(t_ref, t_tra) + half, dt, device, output_interval=0.02)
    r = hetero.checked(run_batch(batch, settings))
    t, q = r.time, r.strain[0]
    a_inc, c_inc = _moments(t, q[:, s1], t_inc, half)
    a_ref, _ = _moments(t, q[:, s1], t_ref, half)
    a_tra, c_tra = _moments(t, q[:, s2], t_tra, half)
    R, T = a_ref / a_inc, a_tra / a_inc
    delay, delay_th = c_tra - c_inc, th.delay(d1 + 0.5, d2 + 0.5)
    checks = [
        Check("interface_reflected", "reflected / incident strain pulse area at the station before the joint, "
              "against R_eps = (Z2 - Z1)/(Z1 + Z2)", R, th.reflected_strain, abs(R / th.reflected_strain - 1.0), tolerance),
        Check("interface_transmitted", "transmitted / incident strain pulse area, against T_eps = 2 Z1 c1/(c2 (Z1 + Z2))",
              T, th.transmitted_strain, abs(T / th.transmitted_strain - 1.0), tolerance),
        Check("interface_delay", "time between the incident and transmitted pulses' centroids at the two stations "
              "[s], against (d1 + 1/2) h0/c1 + (d2 + 1/2) h0/c2", delay, delay_th, abs(delay / delay_th - 1.0),
              tolerance_delay),
    ]
    # what the peaks would give: the dispersion of a pulse sigma levels wide
    pk = lambda tc, y: y[(t >= tc - half) & (t <= tc + half)]  # noqa: E731
    peak_inc = float(pk(t_inc, q[:, s1]).min())
    peak_R, peak_T = float(pk(t_ref, q[:, s1]).max()) / peak_inc, float(pk(t_tra, q[:, s2]).min()) / peak_inc
    ch1, ch2 = hetero.chain_at(cfg, p1), hetero.chain_at(cfg, p2)
    w_rms = th.c1 / (np.sqrt(2.0) * sigma * h0)
    R_w, T_w = discrete_coefficients(ch1.K, ch2.K, ch1.m_eff, [w_rms])
    notes = [f"{N} prisms (RB): {n1} at p1 = {p1:g} (struck side), {n2} at p2 = {p2:g}; stations {d1} prisms before and "
             f"{d2} after the joint; Gaussian pulse sigma = {sigma:g} levels, strain {strain_of_p:g} x {min(p1, p2):g}; "
             f"dt = {r.dt:g} s; equilibrium residual of the graded column {float(batch.equilibrium_residual[0]):.1e}",
             f"Bloch cells: c1 = {th.c1:.6g} m/s, c2 = {th.c2:.6g} m/s, Z2/Z1 = {th.Z2 / th.Z1:.6g}; R_eps = "
             f"{th.reflected_strain:.6g}, T_eps = {th.transmitted_strain:.6g}, T_u = {th.transmitted_velocity:.6g}",
             f"peak ratios (not checked: dispersion): reflected {peak_R:.5g} ({peak_R / th.reflected_strain - 1:+.2%}), "
             f"transmitted {peak_T:.5g} ({peak_T / th.transmitted_strain - 1:+.2%}); the discrete joint at the pulse's "
             f"rms frequency {w_rms:.3g} rad/s: |R_eps| {abs(R_w[0]) / abs(th.reflected_strain) - 1:+.2%}, "
             f"|T_eps| {abs(T_w[0]) / th.transmitted_strain - 1:+.2%}"]
    data = {"prestrain": (p1, p2), "time": t, "strain": q, "stations": (s1, s2), "joint": n2, "arrivals": (t_inc, t_ref, t_tra),
            "half": half, "theory": th, "areas": (a_inc, a_ref, a_tra), "delay": (delay, delay_th)}
    return CheckGroup("interface", "A pulse across the joint of two RB segments against the chain's impedances",
                      checks, data, notes)
