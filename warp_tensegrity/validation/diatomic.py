"""The diatomic gap check: a rigid-base (RB) column whose level masses alternate m, 2m, driven by a
narrow-band wave packet inside and outside its band gap (docs/validation.md, "Diatomic gap").

Theory (SI units). The linearised RB column is exactly a chain of level displacements (:mod:`.closed_forms`):
springs K = 12 sqrt3 EA p h0^2/(a^2 s0) and level masses m_eff = m (1 + 4 h0^2/a^2) (the twist the bars
lock to a level's axial motion adds to its inertia in proportion to its mass). With masses m1 = m_eff and
m2 = 2 m_eff alternating, a cell of two levels carries u_(n+1) = lambda u_n, lambda = e^(i q), with

    cos q = 1 - (m1 + m2) w^2/K + m1 m2 w^4/(2 K^2),

two branches below sqrt(2K/m2) (acoustic) and from sqrt(2K/m1) to sqrt(2K (1/m1 + 1/m2)) (optical). In the
gap between them cos q < -1: q = pi + i kappa, cosh kappa = -cos q, and a wave dies by e^(-kappa) per
cell, each cell's prism in antiphase with the one a cell before. The two-level Bloch cell of the 3-D
column (:func:`bloch_cell_two_levels`, from :func:`.dispersion.bloch_cell`) gives the same branches
(a check of the reference only).

The drive. The engine has no external force, so the column is driven by a wave packet: a monatomic lead
of light levels (mass m, cut-off 2 sqrt(K/m_eff), above the gap) joins the diatomic segment; at t = 0 the
lead's levels near the free end move with a Gaussian-enveloped carrier of frequency w0 (the half-mass
free end is a mirror plane, so one packet leaves it). In the diatomic segment, a semi-infinite periodic
chain driven from one side, the record of a prism c cells from the joint is the record of the same
prism at the joint filtered by lambda(w)^c (the decaying or outgoing Bloch wave at every frequency), so
the engine's record at the joint and the complex Bloch wavenumber predict every other cell's record,
the packet's bandwidth included.
"""

from __future__ import annotations

import numpy as np

from . import hetero
from .dispersion import _omega, _rank, bloch_cell
from .gallery import Check, CheckGroup
from ..engine import run_batch
from ..scene.columns import ColumnConfig

__all__ = ["cos_q", "bloch_factor", "band_edges", "bloch_cell_two_levels", "check_diatomic"]


def cos_q(omega, K: float, m1: float, m2: float):
    """cos of the Bloch wavenumber per cell q [rad] of the chain of springs K [N m-1] and alternating masses
    m1, m2 [kg] at angular frequency ``omega`` [rad s-1] (module docstring); < -1 in the gap."""
    w2 = np.asarray(omega, dtype=float) ** 2
    return 1.0 - (m1 + m2) * w2 / K + m1 * m2 * w2**2 / (2.0 * K**2)


def bloch_factor(omega, K: float, m1: float, m2: float) -> np.ndarray:
    """lambda(w) [-]: a prism's record c cells further from the source is its record filtered by lambda^c
    (Fourier transforms X(w) = sum x(t) e^(-i w t)). In the gap -e^(-kappa); in a band the outgoing wave
    e^(-i q) (q in (0, pi) on the acoustic branch, whose group velocity has the phase's sign; the optical
    branch's has the other sign: conj); above the optical branch e^(-kappa) (kappa = arccosh cos q)."""
    c = cos_q(omega, K, m1, m2)
    w = np.asarray(omega, dtype=float)
    out = np.empty(c.shape, dtype=complex)
    gap, top, band = c < -1.0, c > 1.0, np.abs(c) <= 1.0
    out[gap] = -np.exp(-np.arccosh(-c[gap]))
    out[top] = np.exp(-np.arccosh(np.where(top, c, 1.0)[top]))
    out[band] = np.exp(-1j * np.arccos(c[band]))
    optical = band & (w > np.sqrt(2.0 * K / max(m1, m2)))
    out[optical] = np.conj(out[optical])
    return out


def band_edges(K: float, m1: float, m2: float) -> tuple[float, float]:
    """(top of the acoustic branch, bottom of the optical one) [rad s-1]: sqrt(2K/max m), sqrt(2K/min m)."""
    return float(np.sqrt(2.0 * K / max(m1, m2))), float(np.sqrt(2.0 * K / min(m1, m2)))


def bloch_cell_two_levels(config: ColumnConfig, prestrain: float, mass_a: float, mass_b: float, q) -> np.ndarray:
    """(n_q, 2) symmetric (axial-torsional) branches [rad s-1] of the RB column whose levels carry ``mass_a``,
    ``mass_b`` [kg] in turn, at cell wavenumbers ``q`` [rad per two levels]: the one-level cell of
    :func:`.dispersion.bloch_cell` (built from the reference column, not the engine's scene builder) made a
    cell of two levels A, B: D(q) = [[K0, K1 + K1^T e^(-iq)], [K1^T + K1 e^(iq), K0]], its rigid members
    G = [[G0, G1], [G1 e^(iq), G0]] (the bars and links above each level), masses scaled per level."""
    cell = bloch_cell(config, prestrain, 1.0)
    m0 = np.trace(cell.M) / 3.0
    Ma, Mb = cell.M * (mass_a / m0), cell.M * (mass_b / m0)
    Z9 = np.zeros_like(cell.K0)
    S = np.block([[cell.sym, np.zeros((9, 3))], [np.zeros((9, 3)), cell.sym]])
    M = S.T @ np.block([[Ma, Z9], [Z9, Mb]]) @ S
    out = []
    ranks = None
    for qq in np.atleast_1d(np.asarray(q, dtype=float)):
        e = np.exp(1j * qq)
        D = np.block([[cell.K0, cell.K1 + cell.K1.T * np.conj(e)], [cell.K1.T + cell.K1 * e, cell.K0]])
        G = np.block([[cell.G0, cell.G1], [cell.G1 * e, cell.G0]]) @ S
        if ranks is None:
            ranks = _rank(np.block([[cell.G0, cell.G1], [cell.G1 * np.exp(1j), cell.G0]]) @ S)
        out.append(_omega(S.T @ D @ S, G, M, ranks))
    return np.array(out)


def _packet(N: int, n_lead: int, omega0: float, sigma: float, Omega: float, amplitude: float) -> np.ndarray:
    """(N + 1,) level velocities [m s-1]: a Gaussian envelope of ``sigma`` levels about the free end (level
    N) times the lead's Bloch wave at ``omega0`` (wavenumber 2 arcsin(omega0/(2 Omega)) per level), zero
    outside the lead and at the clamp; towards the clamp."""
    x = N - np.arange(N + 1.0)
    k0 = 2.0 * np.arcsin(omega0 / (2.0 * Omega))
    v = -amplitude * np.exp(-0.5 * (x / sigma) ** 2) * np.cos(k0 * x)
    v[: N - n_lead] = 0.0
    return v


def _group_velocity(omega0: float, K: float, m1: float, m2: float) -> float:
    """Group velocity [levels s-1] of the diatomic chain's band at ``omega0`` (dw/dq per cell, twice that in
    levels)."""
    c = float(cos_q(omega0, K, m1, m2))
    dc = -2.0 * (m1 + m2) * omega0 / K + 2.0 * m1 * m2 * omega0**3 / K**2
    return float(2.0 * abs(np.sqrt(1.0 - c * c) / dc))


def _decay_per_cell(amplitudes) -> float:
    """kappa [per cell]: minus the slope of a least-squares line through log(amplitude) over cells 1, 2, ..."""
    a = np.asarray(amplitudes, dtype=float)
    return float(-np.polyfit(np.arange(1, a.size + 1), np.log(a), 1)[0])


def check_diatomic(prestrain: float = 0.002, mass_ratio: float = 2.0, n_diatomic: int = 32, n_lead: int = 70,
                   n_lead_band: int = 32, omega_gap: float = 1.27, sigma_gap: float = 16.0, omega_band: float = 0.6,
                   sigma_band: float = 7.0, cells: int = 5, strain_of_p: float = 1e-3, dt: float = 0.0125,
                   tolerance_gap: float = 3e-3, tolerance_band: float = 1e-3, tolerance_cell: float = 1e-8, device: str = "cpu") -> CheckGroup:
    """An RB column at ``prestrain``: ``n_diatomic`` prisms at the clamp whose levels alternate m and
    ``mass_ratio`` m (the level at the joint light), a lead of ``n_lead`` prisms of light levels at the free
    end (``n_lead_band`` for the band packet). Two runs: a packet at ``omega_gap`` x sqrt(K/m_eff) (inside the
    gap, ``sigma_gap`` levels) and one at ``omega_band`` x sqrt(K/m_eff) (in the acoustic band, ``sigma_band``
    levels). Over the prisms of one kind in the ``cells`` cells after the joint's: inside the gap, the decay
    per cell of the records' peaks, engine against the records the complex Bloch wavenumber predicts from the
    joint's record; outside, the decay per cell of the first passage's rms strain (the energy that passes,
    whatever the packet's spreading) against none. And the two-level Bloch cell against the chain's branches
    (reference only). Frequencies in units of sqrt(K/m_eff) (the lead's cut-off is 2)."""
    cfg = ColumnConfig(n_prisms=n_diatomic + n_lead)
    m, h0 = cfg.unit_mass, cfg.height
    ch = hetero.chain_at(cfg, prestrain)
    K, m1, m2 = ch.K, ch.m_eff, mass_ratio * ch.m_eff
    Omega = np.sqrt(K / m1)
    edges = band_edges(K, m1, m2)
    q = np.linspace(1e-3, np.pi, 61)
    cell_branches = bloch_cell_two_levels(cfg, prestrain, m, mass_ratio * m, q)
    s = 1.0 / m1 + 1.0 / m2
    root = np.sqrt(s**2 - 4.0 * np.sin(q / 2) ** 2 / (m1 * m2))
    chain_branches = np.sqrt(K * np.stack([s - root, s + root], axis=1))
    cell_err = float(np.abs(cell_branches - chain_branches).max() / chain_branches.max())

    amplitude = 2.0 * strain_of_p * prestrain * Omega * h0  # the packet's strain ~ strain_of_p x p
    prisms = n_diatomic - 1 - 2 * np.arange(cells + 1)  # the prism below the joint, and one a cell further each
    runs = {}
    for name, w0, sig, lead in (("gap", omega_gap, sigma_gap, n_lead), ("band", omega_band, sigma_band, n_lead_band)):
        N = n_diatomic + lead
        level = np.arange(N + 1)
        level_mass = np.full(N + 1, m)
        level_mass[N] = 0.5 * m  # the engine's half end base: the free end is the lead's mirror plane
        level_mass[(level < n_diatomic) & ((n_diatomic - level) % 2 == 1)] = mass_ratio * m
        v_lead = Omega * np.cos(np.arcsin(w0 / 2.0))  # the lead's group velocity [levels s-1]
        batch = hetero.graded_batch(ColumnConfig(n_prisms=N), np.full(N, prestrain), level_mass,
                                    _packet(N, lead, w0 * Omega, sig, Omega, amplitude))
        t_joint = lead / v_lead
        t_end = t_joint + 4.0 * sig / v_lead + 8.0 / Omega
        r = hetero.checked(run_batch(batch, hetero.graded_settings(t_end, dt, device)))
        runs[name] = {"time": r.time, "strain": r.strain[0], "omega0": w0 * Omega, "sigma": sig, "t_joint": t_joint,
                      "dt": r.dt, "residual": float(batch.equilibrium_residual[0]), "n_prisms": N}
    # inside the gap: every cell's record predicted from the joint's through lambda(w)^c
    g = runs["gap"]
    t, y = g["time"], g["strain"][:, prisms]
    n_fft = 64 * len(t)  # zero padding: lambda^c's response decays as t^(-3/2) (band edges); 4x wraps 5e-3 of it
    Y0 = np.fft.rfft(y[:, 0], n_fft)
    lam = bloch_factor(2.0 * np.pi * np.fft.rfftfreq(n_fft, t[1] - t[0]), K, m1, m2)
    predicted = np.stack([np.fft.irfft(Y0 * lam**c, n_fft)[: len(t)] for c in range(cells + 1)], axis=1)
    peak_engine, peak_theory = np.abs(y).max(axis=0), np.abs(predicted).max(axis=0)
    kappa_engine, kappa_theory = _decay_per_cell(peak_engine[1:]), _decay_per_cell(peak_theory[1:])
    kappa_w0 = float(np.arccosh(-cos_q(g["omega0"], K, m1, m2)))
    g.update(prisms=prisms, predicted=predicted, peaks=(peak_engine, peak_theory))
    # outside: the first passage of each prism, cut halfway to the clamp's echo
    b = runs["band"]
    vg = _group_velocity(b["omega0"], K, m1, m2)
    t_first = b["t_joint"] + (n_diatomic - prisms - 0.5) / vg
    cut = t_first + (prisms + 0.5) / vg
    tb = b["time"]  # rms over the first passage: the energy that passes, whatever the packet's spreading
    peak_band = np.array([np.sqrt(np.trapezoid(b["strain"][tb <= tc, j] ** 2, tb[tb <= tc]))
                          for j, tc in zip(prisms, cut)])
    kappa_band = _decay_per_cell(peak_band[1:])
    b.update(prisms=prisms, cut=cut, peaks=peak_band)
    w_gap = np.linspace(edges[0], edges[1], 200)[1:-1]  # for the figure: kappa across the gap
    checks = [
        Check("diatomic_gap_decay", f"inside the gap (w0 = {omega_gap:g} sqrt(K/m_eff)): decay per cell of the "
              f"records' peaks over {cells} cells, engine against the complex Bloch wavenumber's prediction from "
              "the joint's record", kappa_engine, kappa_theory, abs(kappa_engine / kappa_theory - 1.0), tolerance_gap),
        Check("diatomic_band_decay", f"outside the gap (w0 = {omega_band:g} sqrt(K/m_eff)): decay per cell of the "
              f"rms strain of the first passage over {cells} cells, against none [1/cell]", kappa_band, 0.0,
              abs(kappa_band), tolerance_band),
        Check("diatomic_bloch_cell", "reference only: max over q of |two-level Bloch cell's symmetric branches - "
              "the diatomic chain's| / their top", cell_err, 0.0, cell_err, tolerance_cell, engine=False),
    ]
    notes = [f"RB, p = {prestrain:g}: {n_diatomic} diatomic prisms at the clamp (masses m, {mass_ratio:g} m), a lead of "
             f"{n_lead} ({n_lead_band} for the band packet) prisms of light levels; dt = {g['dt']:g} s; equilibrium "
             f"residual {max(g['residual'], runs['band']['residual']):.1e}",
             f"band edges (chain, and the Bloch cell at q = pi): {edges[0]:.6g} and {edges[1]:.6g} rad/s "
             f"(cell {cell_branches[-1, 0]:.6g}, {cell_branches[-1, 1]:.6g}); sqrt(K/m_eff) = {Omega:.6g} rad/s",
             f"gap packet at {g['omega0']:.5g} rad/s, sigma = {sigma_gap:g} levels: kappa(w0) = {kappa_w0:.5f} per cell; "
             f"the packet's bandwidth lowers the peaks' decay to {kappa_theory:.5f} (prediction) / "
             f"{kappa_engine:.5f} (engine)",
             f"band packet at {b['omega0']:.5g} rad/s, sigma = {sigma_band:g} levels, group velocity {vg:.4g} levels/s: "
             f"first-passage rms strain / the joint's: " + " ".join(f"{x:.6f}" for x in peak_band / peak_band[0])]
    return CheckGroup("diatomic", "Band gap of a diatomic RB column: decay inside, none outside", checks,
                      {"runs": runs, "edges": edges, "q": q, "branches": cell_branches, "height": h0,
                       "gap_omega": w_gap, "gap_kappa": np.arccosh(-cos_q(w_gap, K, m1, m2)),
                       "kappa_w0": kappa_w0, "Omega": Omega, "K": K, "masses": (m1, m2)}, notes)
