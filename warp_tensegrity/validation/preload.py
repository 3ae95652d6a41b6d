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

NumPy and SciPy only; no scene builder and no Warp.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .checks import J1_MAX, Check, CheckGroup, _run
from .closed_forms import RBChain, bessel_compression, rb_chain
from ..scene.columns import ColumnConfig

__all__ = ["PreloadPath", "preload_force", "preload_path", "check_preload"]


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


def check_preload(n_prisms: int = 8, prestrain: float = 0.01, load_of_tension: float = 3.0, peak_of_p: float = 1e-4,
                  t_end: float = 1.0, tolerance_static: float = 1e-7, tolerance_speed: float = 1e-3,
                  device: str = "cpu"):
    """The engine's preloaded RB column against :func:`preload_path`: F0 = ``load_of_tension`` x EA p.
    Two columns: one at rest (it must stay in its static state: its height and twist against the
    closed form), one struck by a small impact (its strain record against the chain's Bessel form,
    the chain's frequency fitted: the speed against the tangent-stiffness speed)."""
    from scipy.optimize import minimize_scalar

    cfg = ColumnConfig(n_prisms=n_prisms)
    EA = cfg.cable_EA
    F0 = load_of_tension * EA * prestrain
    path = preload_path(F0, EA, cfg.radius, cfg.height, cfg.unit_mass, prestrain)
    ch = path.chain()
    c_chain = ch.c0  # h sqrt(K_t/m_eff): the chain's speed in loaded heights per second
    v0 = peak_of_p * prestrain * c_chain / J1_MAX
    r = _run(cfg, {"prestrain": prestrain, "base_rigidity": 1.0, "preload": F0, "v0": np.array([0.0, v0])},
             t_end, 0.01, device)
    f = r.feasibility
    h_eng = float(np.mean(f["prism_height_ratio_min"][0])) * cfg.height
    phi_eng = float(np.mean(f["prism_twist_last"][0]))
    still = float(np.abs(r.strain[0]).max())
    eng = r.strain[1]
    ref = -bessel_compression(r.time, n_prisms, v0, ch)
    peak = float(np.abs(ref).max())

    def misfit(scale):  # the engine record against the Bessel form of a chain of frequency scale x omega_c
        return float(np.abs(eng + bessel_compression(r.time, n_prisms, v0, _scaled(ch, scale))).max())

    fit = minimize_scalar(misfit, bounds=(0.9, 1.1), method="bounded", options={"xatol": 1e-9})
    speed = path.speed * fit.x
    checks = [
        Check("preload_height", "|h_engine - h(F0)| / (h0 - h(F0)), the static shortening", h_eng, path.height,
              abs(h_eng - path.height) / (cfg.height - path.height), tolerance_static),
        Check("preload_twist", "|phi_engine - phi(F0)| / (phi(F0) - 5 pi/6), the static twist", phi_eng, path.twist,
              abs(phi_eng - path.twist) / (path.twist - cfg.twist), tolerance_static),
        Check("preload_at_rest", "max |strain| of the preloaded column left at rest / p", still / prestrain, 0.0,
              still / prestrain, tolerance_static),
        Check("preload_speed", "|c_fit - c_t| / c_t: the struck column's speed (Bessel fit) against "
              "h0 sqrt(K_t/m_eff)", speed, path.speed, abs(fit.x - 1.0), tolerance_speed),
        Check("preload_record", "max |engine - Bessel(K_t, m_eff)| over every prism and time / peak",
              misfit(1.0) / peak, 0.0, misfit(1.0) / peak, 5.0 * tolerance_speed),
    ]
    base = rb_chain(EA, cfg.radius, cfg.height, cfg.unit_mass, prestrain)
    notes = [f"{n_prisms} prisms, RB, p = {prestrain:g}, F0 = {F0:.6g} N ({load_of_tension:g} EA p): closed form "
             f"phi = {path.twist:.9g} rad, h/h0 = {path.height / cfg.height:.9g}, K_t = {path.stiffness:.6g} N/m "
             f"(unloaded K = {base.K:.6g}), m_eff = {path.m_eff:.6g} kg (unloaded {base.m_eff:.6g}), "
             f"c_t = {path.speed:.6g} m/s (unloaded c0 = {base.c0:.6g}); v0 = {v0:.3g} m/s, dt = {r.dt:.3g} s"]
    phis = np.linspace(cfg.twist, math.pi - 0.02, 200)
    return CheckGroup("preload", "End preload: static compression and small waves on the loaded RB column", checks,
                      {"time": r.time, "engine": eng, "bessel": ref, "path": path, "phi": phis,
                       "force": preload_force(phis, EA, cfg.radius, cfg.height, prestrain),
                       "height": np.sqrt(_geometry(cfg.radius, cfg.height)[2] - 2 * cfg.radius**2 * (1 - np.cos(phis))),
                       "h0": cfg.height, "engine_height": h_eng, "F0": F0}, notes)


def _scaled(ch: RBChain, scale: float) -> RBChain:
    """The chain with its frequencies (and speed) times ``scale``: K x scale^2."""
    return RBChain(m_eff=ch.m_eff, s0=ch.s0, K=ch.K * scale**2, k3=ch.k3, h0=ch.h0)
