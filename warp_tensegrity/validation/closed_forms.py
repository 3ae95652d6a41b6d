"""Closed forms of the rigid-base (RB) column: its exact 1-D chain, the linear impact response
(Schrödinger 1914) and the sonic-vacuum solitary wave of the unstressed column (Nesterenko).

Float64 NumPy/SciPy on the host; SI units. Used by :mod:`warp_tensegrity.validate` and the tests,
never by the engine. Derivations (``docs/validation.md``):

* **The chain.** With rigid bars and rigid bases a regular T3 prism keeps one degree of freedom:
  its height h fixes its twist phi through the bar length, h^2 + 2 a^2 (1 - cos phi) = l^2, so
  dphi/dh = -h / (a^2 sin phi) = -2 h0 / a^2 at phi = 5 pi/6. An axial impact on the symmetric
  column moves only these coordinates, so the RB column is exactly a 1-D chain of level
  displacements u_n. A level of mass m at radius a turning by 2 h0/a^2 per metre of axial motion
  has the kinetic energy of the mass ``m_eff = m (1 + 4 h0^2 / a^2)`` (massless bars).
* **The cable.** A cross cable joins bottom node k to top node k+2 (turned by phi - 2 pi/3), so
  s^2 = h^2 + 2 a^2 (1 - cos(phi - 2 pi/3)); at phi = 5 pi/6, ``s0^2 = h0^2 + a^2 (2 - sqrt 3)``.
  ds/dh = 0 there (the cable is at its shortest) and d2s/dh2 = 4 sqrt3 h0^2 / (a^2 s0).
* **The springs.** Three cross cables of stiffness EA/L, L = s0/(1+p): to second order in the
  compression delta = h0 - h, V = (3 EA/2) [p s'' delta^2 + s''^2 delta^4 / (4 L)], so
  ``K = 12 sqrt3 EA p h0^2 / (a^2 s0)`` (prestrain p) and, at p = 0, the cubic force
  F = k3 delta^3 with ``k3 = 72 EA h0^4 / (a^4 s0^3)``.
* **Linear impact.** Masses m_eff (the impacted end base m_eff/2: ``end_base_mass = 'half'``),
  springs K, the end base struck with -v0 (the ``rigid_members`` impact at beta = 1 gives it
  exactly the chain's velocity, the other levels at rest). The half-mass end is the mirror plane
  of an infinite chain struck at one mass, so level n (from the impacted end) moves with
  v0 J_2n(omega_c t) and prism n is compressed by ``q_n = (v0/c0) J_(2n+1)(omega_c t)``,
  c0 = h0 sqrt(K/m_eff), omega_c = 2 c0 / h0; the clamp (N prisms away) is an antisymmetric
  mirror: images at n -> n - 2kN with sign (-1)^k.
* **Sonic vacuum.** m_eff d2u/dt2 = k3 (delta_(n-1)^3 - delta_n^3): scaling delta by A h0 and
  time by 1/(A h0 sqrt(k3/m_eff)) leaves the equation unchanged, so the solitary wave has speed
  ``V = c* h0^2 sqrt(k3/m_eff) A`` (A = delta_max/h0), a width in prisms independent of A and,
  under the half-mass impact, ``delta_max = a* (v0^2 m_eff / k3)^(1/4)``. c*, a* and the width
  are numbers of the dimensionless chain: :func:`power_chain_soliton` computes them. The
  quasi-continuum (long-wave) approximation gives c* = sqrt(2/3).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

__all__ = ["RBChain", "rb_chain", "bessel_compression", "SolitonConstants", "power_chain_soliton",
           "QUASI_CONTINUUM_SPEED_CONSTANT"]

QUASI_CONTINUUM_SPEED_CONSTANT = math.sqrt(2.0 / 3.0)
"""c* of the long-wave (quasi-continuum) approximation of the cubic chain."""


@dataclass(frozen=True)
class RBChain:
    """The 1-D chain of a rigid-base column of regular minimal T3 prisms (SI units)."""

    m_eff: float
    """Effective mass of an interior level [kg]: m (1 + 4 h0^2/a^2)."""
    s0: float
    """Cross-cable length in the reference state [m]."""
    K: float
    """Linear axial stiffness per prism [N m-1] (0 at p = 0: the sonic vacuum)."""
    k3: float
    """Cubic stiffness per prism at p = 0 [N m-3]: F = k3 delta^3."""
    h0: float
    """Prism height [m]."""

    @property
    def c0(self) -> float:
        """Long-wave speed h0 sqrt(K/m_eff) [m s-1]."""
        return self.h0 * math.sqrt(self.K / self.m_eff)

    @property
    def omega_c(self) -> float:
        """Cut-off frequency of the chain 2 sqrt(K/m_eff) = 2 c0/h0 [rad s-1]."""
        return 2.0 * math.sqrt(self.K / self.m_eff)

    @property
    def soliton_scale(self) -> float:
        """h0^2 sqrt(k3/m_eff) [m s-1]: the solitary wave's speed is c* times this times A."""
        return self.h0**2 * math.sqrt(self.k3 / self.m_eff)

    def soliton_amplitude_scale(self, v0: float) -> float:
        """(v0^2 m_eff/k3)^(1/4) [m]: the solitary wave's delta_max is a* times this."""
        return (v0**2 * self.m_eff / self.k3) ** 0.25


def rb_chain(EA: float, radius: float, height: float, unit_mass: float, prestrain: float) -> RBChain:
    """The chain constants from the prism's geometry and material alone (see the module docstring).
    ``EA`` [N] cable axial stiffness, ``radius`` a [m], ``height`` h0 [m], ``unit_mass`` m [kg]
    (one level's mass), ``prestrain`` p [-] of the cross cables. Valid at the minimal twist 5 pi/6."""
    a, h0 = float(radius), float(height)
    s0 = math.sqrt(h0**2 + a**2 * (2.0 - math.sqrt(3.0)))
    return RBChain(
        m_eff=unit_mass * (1.0 + 4.0 * h0**2 / a**2),
        s0=s0,
        K=12.0 * math.sqrt(3.0) * EA * prestrain * h0**2 / (a**2 * s0),
        k3=72.0 * EA * h0**4 / (a**4 * s0**3),
        h0=h0,
    )


def long_wave_speeds(ds):
    """The long-wave speed c0 [m s-1] of every column of a sweep dataset: its rigid-base chain's
    (:func:`rb_chain`) from the scene attributes (``scene_radius``, ``scene_height``) and the
    ``prestrain``, ``cable_EA`` and ``unit_mass`` coordinates; 0 where unstressed. A DataArray over
    the dimensions those coordinates vary along; None without the scene attributes. Flexible bases
    lower it little (the paper's column at p = 0.002: 0.02632 m s-1 against 0.02633 rigid)."""
    try:
        a, h0 = float(ds.attrs["scene_radius"]), float(ds.attrs["scene_height"])
        p, ea, m = (ds[k] for k in ("prestrain", "cable_EA", "unit_mass"))
    except (KeyError, TypeError, ValueError):
        return None
    import xarray as xr  # a dataset's library: the closed forms themselves need only NumPy

    c0 = np.vectorize(lambda pk, eak, mk: rb_chain(eak, a, h0, mk, max(pk, 0.0)).c0, otypes=[float])
    p, ea, m = xr.broadcast(*(x.reset_coords(drop=True) for x in (p, ea, m)))
    return p.copy(data=c0(p.values, ea.values, m.values))


def bessel_compression(time, n_prisms: int, v0: float, chain: RBChain, images: int | None = None) -> np.ndarray:
    """Linear compressive strain q = delta/h0 [-] of every prism, shape (n_time, n_prisms), prism 0
    at the clamp and prism n_prisms - 1 struck (the engine's order). Prism n from the impacted end:
    (v0/c0) sum_k (-1)^k J_(2(n - 2kN) + 1)(omega_c t), k over the images of the clamp and the
    struck end (by default every image that can reach the record: |k| <= omega_c t_max/(4N) + 2).
    """
    from scipy.special import jv

    t = np.asarray(time, dtype=np.float64)
    N = int(n_prisms)
    x = chain.omega_c * t[:, None]
    if images is None:
        images = int(np.ceil(chain.omega_c * float(t.max(initial=0.0)) / (4.0 * N))) + 2
    n = np.arange(N)  # from the impacted end
    q = np.zeros((t.size, N))
    for k in range(-images, images + 1):
        q += (-1.0) ** k * jv(2 * (n - 2 * k * N) + 1, x)
    return (v0 / chain.c0) * q[:, ::-1]


# ---------------------------------------------------------------------- the dimensionless cubic chain
@dataclass(frozen=True)
class SolitonConstants:
    """Solitary wave of the chain d2u_n/dt2 = delta_(n-1)^3 - delta_n^3 (unit masses and k3, the
    struck end a half mass with unit velocity), measured on its leading pulse."""

    speed_constant: float
    """c*: speed [sites per unit time] / delta_max."""
    amplitude_constant: float
    """a*: delta_max of the leading pulse (the impact's (v0^2 m/k3)^(1/4) is 1)."""
    width_fwhm: float
    """Full width at half maximum of delta, in sites (time FWHM at one site times the speed)."""
    spread: float
    """Largest relative change of c*, a* and width between the first and second half of the
    measured sites (the pulse is steady when this is at round-off)."""
    profile: tuple = field(default=(), repr=False, compare=False)
    """(xi, delta/delta_max): the pulse against xi = (t - t_peak) x speed [sites] at a middle site
    (xi < 0: the front, which passes first)."""


def _chain_rhs(n: int):
    m = np.ones(n)
    m[0] = 0.5

    def rhs(_t, y):
        x, v = y[:n], y[n:]
        d = np.append(x[:-1] - x[1:], x[-1])  # spring n-1 joins the last mass to a clamp
        f = d**3
        return np.concatenate([v, np.append(-f[0], f[:-1] - f[1:]) / m])

    return rhs


def _site_pulse(sol, i: int, t_guess: float, dt: float):
    """Peak (time, value) and FWHM in time of delta_i = x_i - x_(i+1) near t_guess (dense output)."""
    from scipy.optimize import brentq, minimize_scalar

    def d(t):
        y = sol.sol(t)
        return y[i] - y[i + 1]

    r = minimize_scalar(lambda t: -d(t), bracket=(t_guess - dt, t_guess, t_guess + dt), tol=1e-12)
    tp, dm = float(r.x), float(-r.fun)
    half = lambda t: d(t) - 0.5 * dm  # noqa: E731
    a = tp
    while half(a) > 0:
        a -= dt
    b = tp
    while half(b) > 0:
        b += dt
    return tp, dm, brentq(half, tp, b, xtol=1e-13) - brentq(half, a, tp, xtol=1e-13)


def power_chain_soliton(n_sites: int = 60, first: int = 15, rtol: float = 1e-11) -> SolitonConstants:
    """c*, a* and the width of the cubic chain's solitary wave, by integrating the dimensionless
    chain (``n_sites`` masses, DOP853 at ``rtol``) until its leading pulse has crossed it, and
    measuring that pulse at the sites ``first`` .. ``n_sites - first`` (away from both ends).
    The speed is the least-squares slope of the sites against their peak times."""
    from scipy.integrate import solve_ivp

    n = int(n_sites)
    y0 = np.zeros(2 * n)
    y0[n] = 1.0  # the struck half mass
    t_end = 1.6 * n  # the pulse runs at ~0.61 sites per unit time
    sol = solve_ivp(_chain_rhs(n), (0.0, t_end), y0, method="DOP853", rtol=rtol, atol=1e-14, dense_output=True)
    ts = np.linspace(0.0, t_end, 40 * n)
    x = sol.sol(ts)[:n]
    sites = np.arange(first, n - first)
    dt = ts[1] - ts[0]
    rows = []
    for i in sites:
        di = x[i] - x[i + 1]
        k = int(np.argmax(di > 0.5 * di.max()))  # the leading pulse: first to pass half the largest
        k = k + int(np.argmax(np.diff(di[k:]) < 0))  # its peak sample
        rows.append(_site_pulse(sol, int(i), ts[k], dt))
    tp, dm, fw = np.array(rows).T
    speed = np.polyfit(tp, sites, 1)[0]
    c = speed / dm
    w = fw * speed
    h = len(sites) // 2
    halves = [np.array([np.mean(q[:h]), np.mean(q[h:])]) for q in (c, dm, w)]
    spread = max(abs(q[1] / q[0] - 1.0) for q in halves)
    mid = h  # a middle site: its pulse against (t - t_peak) x speed
    xi = np.linspace(-4.0, 4.0, 401)
    y = sol.sol(tp[mid] + xi / speed)
    profile = (xi, (y[sites[mid]] - y[sites[mid] + 1]) / dm[mid])
    return SolitonConstants(float(np.mean(c)), float(np.mean(dm)), float(np.mean(w)), float(spread), profile)
