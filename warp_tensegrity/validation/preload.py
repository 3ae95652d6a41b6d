"""The end preload against its closed form (issue 34 item 5, "Preload"): the rigid-base (RB) column of
right-handed T3 prisms under a static compressive end force F0 (``docs/validation.md``).

**The mechanism path.** With rigid bars (length l) and rigid bases (circumradius a) a regular prism
keeps one degree of freedom, its twist phi; its height and its cross-cable length follow from it
(the cable joins bottom node k to top node k+2, turned by phi - 2 pi/3):

    h(phi)^2 = l^2 - 2 a^2 (1 - cos phi),
    s(phi)^2 = h^2 + 2 a^2 (1 - cos(phi - 2 pi/3)) = l^2 - 2 sqrt3 a^2 sin(phi - pi/3),

so s is shortest at phi = 5 pi/6 (the prestressable twist) and grows either way. Under compression
the prism shortens and twists toward pi (where h = sqrt(l^2 - 4 a^2): it locks).

**The force-displacement law.** Three cross cables of stiffness EA and rest length L = s0/(1+p)
carry T(phi) = EA (s - L)/L each. Virtual work along the path, F0 (-dh) = 3 T ds, gives

    F0(phi) = -3 T ds/dh = -3 sqrt3 T h cos(phi - pi/3) / (s sin phi),

positive for phi in (5 pi/6, pi), growing without bound toward pi. The same law holds for every
prism of the column (each carries F0 and no torque), so each shortens alike; :func:`preload_path`
inverts it for phi (Brent's method).

**Small waves on the preloaded column.** About the loaded state the RB column is again a chain: the
tangent stiffness per prism K_t = dF0/d(-h), and the effective mass of a level m_eff = m (1 + a^2
(dphi/dh)^2) with dphi/dh = -h / (a^2 sin phi) (at phi = 5 pi/6 both reduce to :func:`rb_chain`'s).
A small impact then gives the Bessel response of the chain (K_t, m_eff), whose long-wave speed is
c_t = h0 sqrt(K_t/m_eff) [m s-1] in the engine's unit (reference prism heights per second).

NumPy and SciPy only; no scene builder and no Warp. The check that runs the engine against it is
:func:`warp_tensegrity.validation.checks.check_preload`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .closed_forms import RBChain

__all__ = ["PreloadPath", "preload_force", "preload_height", "preload_path", "scaled_chain"]


@dataclass(frozen=True)
class PreloadPath:
    """The RB prism's static state under the end force F0 and its small-wave chain (SI units)."""

    F0: float
    twist: float
    """phi [rad]."""
    height: float
    """h [m]."""
    tension: float
    """Cross-cable tension T [N]."""
    stiffness: float
    """Tangent stiffness K_t = dF0/d(-h) [N m-1]."""
    m_eff: float
    """Effective mass of an interior level [kg]."""
    h0: float

    @property
    def strain(self) -> float:
        """Static strain (h - h0)/h0 [1]."""
        return (self.height - self.h0) / self.h0

    @property
    def speed(self) -> float:
        """Long-wave speed h0 sqrt(K_t/m_eff) [m s-1]."""
        return self.h0 * math.sqrt(self.stiffness / self.m_eff)

    def chain(self) -> RBChain:
        """The linear chain about this state, lattice spacing h (the strain it gives is delta/h)."""
        return RBChain(m_eff=self.m_eff, s0=float("nan"), K=self.stiffness, k3=0.0, h0=self.height)


def _geometry(radius: float, height: float, twist0: float = 5.0 * math.pi / 6.0):
    a, h0 = float(radius), float(height)
    l2 = h0**2 + 2.0 * a * a * (1.0 - math.cos(twist0))
    s_ref = math.sqrt(l2 - 2.0 * math.sqrt(3.0) * a * a * math.sin(twist0 - math.pi / 3.0))
    return a, h0, l2, s_ref


def preload_height(phi, radius: float, height: float):
    """h(phi) [m] of the RB prism along its mechanism path (bar length fixed)."""
    a, _, l2, _ = _geometry(radius, height)
    return np.sqrt(l2 - 2.0 * a * a * (1.0 - np.cos(np.asarray(phi, dtype=np.float64))))


def preload_force(phi, EA: float, radius: float, height: float, prestrain: float):
    """F0 [N] that holds the RB prism at twist ``phi`` [rad] (the law of the module docstring)."""
    a, h0, l2, s_ref = _geometry(radius, height)
    phi = np.asarray(phi, dtype=np.float64)
    h = np.sqrt(l2 - 2.0 * a * a * (1.0 - np.cos(phi)))
    s = np.sqrt(l2 - 2.0 * math.sqrt(3.0) * a * a * np.sin(phi - math.pi / 3.0))
    L = s_ref / (1.0 + prestrain)
    T = EA * (s - L) / L
    return -3.0 * math.sqrt(3.0) * T * h * np.cos(phi - math.pi / 3.0) / (s * np.sin(phi))


def preload_path(F0: float, EA: float, radius: float, height: float, unit_mass: float, prestrain: float) -> PreloadPath:
    """The state of the RB prism under F0 [N] > 0 and its chain (module docstring)."""
    from scipy.optimize import brentq

    a, h0, l2, s_ref = _geometry(radius, height)
    lo, hi = 5.0 * math.pi / 6.0, math.pi - 1e-12
    if not 0.0 < F0 < float(preload_force(hi, EA, radius, height, prestrain)):
        raise ValueError(f"F0 = {F0!r} N: outside the RB prism's path")
    phi = brentq(lambda x: float(preload_force(x, EA, radius, height, prestrain)) - F0, lo, hi, xtol=1e-15, rtol=1e-15)
    hf = lambda x: math.sqrt(l2 - 2.0 * a * a * (1.0 - math.cos(x)))  # noqa: E731
    h = hf(phi)
    # K_t = dF0/d(-h) = -(dF0/dphi) / (dh/dphi), dF0/dphi by a central difference of the closed form
    d = 1e-6 * (math.pi - phi)
    dF = (float(preload_force(phi + d, EA, radius, height, prestrain))
          - float(preload_force(phi - d, EA, radius, height, prestrain))) / (2.0 * d)
    dh = -a * a * math.sin(phi) / h
    s = math.sqrt(l2 - 2.0 * math.sqrt(3.0) * a * a * math.sin(phi - math.pi / 3.0))
    L = s_ref / (1.0 + prestrain)
    return PreloadPath(F0=float(F0), twist=phi, height=h, tension=EA * (s - L) / L, stiffness=-dF / dh,
                       m_eff=unit_mass * (1.0 + (h / (a * math.sin(phi))) ** 2),  # a^2 (dphi/dh)^2
                       h0=h0)


def scaled_chain(ch: RBChain, scale: float) -> RBChain:
    """The chain with its frequencies (and speed) times ``scale``: K x scale^2."""
    return RBChain(m_eff=ch.m_eff, s0=ch.s0, K=ch.K * scale**2, k3=ch.k3, h0=ch.h0)
