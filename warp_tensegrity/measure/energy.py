"""Energy measures of a column (NumPy, float64): where the impact energy goes. Definitions in
``docs/measurements.md`` ("Energy measures"); the engine records the parts on the device
(``sim.staged.kernels.record_energy_parts``) and computes the shares there
(:func:`warp_tensegrity.measure.device.measure_record`); this module is the reference the tests
compare against, and the definition of the parts.

Levels ``l = 0..n`` (nodes ``3l..3l+2``; level 0 clamped, level ``n`` the impacted end), prism
``j`` between levels ``j`` and ``j + 1``. A cut at level ``L`` splits the column into the nodes
below ``L`` with every member that has an end there, and the nodes at ``L`` and above with the
members that have both ends there: each node and member belongs to exactly one side, so the two
sides' energies add up to the column's. The energy of a part is its kinetic energy plus the
elastic energy of its members above their reference (prestressed, u = 0) values [J].
"""

from __future__ import annotations

import numpy as np

__all__ = ["ENERGY_SHARES", "end_energy_share", "end_prisms", "energy_parts", "part_nodes", "pulse_energy_share",
           "section_power", "station_prism"]

ENERGY_SHARES = ("pulse_energy_share", "end_energy_share")
"""The per-case energy measures, [1] each."""


def station_prism(n_prisms: int, station: int | None = None) -> int:
    """The station prism: ``station``, or (None) the prism at mid-column, (n_prisms - 1) // 2;
    ValueError naming ``energy_station`` unless 0 <= station < n_prisms."""
    if station is None:
        return max(0, (int(n_prisms) - 1) // 2)
    if not 0 <= int(station) < int(n_prisms):
        raise ValueError(f"energy_station = {station!r}: must be >= 0 and < n_prisms = {n_prisms}")
    return int(station)


def end_prisms(n_prisms: int, k: int) -> int:
    """Prisms of the end part: k, or the whole column where it has fewer."""
    return min(int(k), int(n_prisms))


def part_nodes(n_prisms: int, station: int, k: int, cut: int = 0) -> tuple[int, int]:
    """(below_node, end_node): the first node of the station's cut level ``station + 1`` and of the
    end part's ``n_prisms - k``, in a column simulated without its ``cut`` prisms at the clamp
    (its nodes ``3 (l - cut) ..``; levels that were cut away count as node 0: that part is at rest)."""
    return 3 * max(station + 1 - cut, 0), 3 * max(n_prisms - k - cut, 0)


def impact_energy(kinetic0, striker: dict | None = None) -> np.ndarray:
    """(B,) the impact energy [J] the shares are taken of: the kinetic energy at t = 0 (the column's
    ``kinetic0``), with a striker (``striker``: the run's record, ``mass`` (B,) [kg] and ``velocity``
    (B, n_time) [m s-1]) the striker's too, after the plastic blow that starts the contact."""
    e0 = np.asarray(kinetic0, dtype=np.float64)
    if striker is not None:
        e0 = e0 + 0.5 * np.asarray(striker["mass"], np.float64) * np.asarray(striker["velocity"], np.float64)[:, 0] ** 2
    return e0


def energy_parts(u, v, node_mass, cables, dref, EA, EAc, rest, below_node: int, end_node: int,
                 m_cross=None, partner=None, ext_force=None) -> tuple[np.ndarray, np.ndarray]:
    """(below, end) energies [J], each (B,), of the state ``u``, ``v`` (B, n_nodes, 3) [m, m s-1]:
    the part below node ``below_node`` (nodes n < below_node and the members with an end there) and
    the part from ``end_node`` up (nodes and members wholly there). ``node_mass`` (B or 1, n_nodes)
    [kg] (the diagonal of M; ``m_cross`` (B or 1, n_nodes) and ``partner`` (n_nodes,) its
    off-diagonal, massive bars); ``cables`` (m, 2), ``dref`` (m, 3) [m] reference member vectors;
    ``EA``, ``EAc`` (B or 1, m) [N] tension and compression stiffness, ``rest`` (B or 1, m) [m];
    ``ext_force`` (B or 1, n_nodes, 3) [N]: a dead load (the preload), whose potential -f . u joins
    each node's term (None: none)."""
    u, v = np.asarray(u, np.float64), np.asarray(v, np.float64)
    ke = np.asarray(node_mass, np.float64) * np.einsum("bni,bni->bn", v, v)
    if partner is not None:
        p = np.asarray(partner)
        has = p >= 0
        ke[:, has] += np.asarray(m_cross, np.float64)[:, has] * np.einsum("bni,bni->bn", v[:, has], v[:, p[has]])
    if ext_force is not None:
        ke = ke - 2.0 * np.einsum("bni,bni->bn", np.broadcast_to(np.asarray(ext_force, np.float64), u.shape), u)
    i, j = np.asarray(cables)[:, 0], np.asarray(cables)[:, 1]
    b0 = np.asarray(dref, np.float64)
    l0 = np.linalg.norm(b0, axis=1)
    lt = np.linalg.norm(b0 + u[:, j] - u[:, i], axis=2)
    rest = np.asarray(rest, np.float64)
    k = np.where(lt < rest, EAc, EA)
    k0 = np.where(l0 < rest, EAc, EA)
    # V(l) - V(l0) directly: this reference keeps fp64 and needs no rearranging
    elastic = 0.5 * (k * (lt - rest) ** 2 - k0 * (l0 - rest) ** 2) / rest
    node = np.arange(u.shape[1])
    first = np.minimum(i, j)
    below = 0.5 * ke[:, node < below_node].sum(axis=1) + elastic[:, first < below_node].sum(axis=1)
    end = 0.5 * ke[:, node >= end_node].sum(axis=1) + elastic[:, first >= end_node].sum(axis=1)
    return below, end


def _interp_peak_time(peak_time, y):
    """The leading peak's time at position y [prisms], linear between the prisms around it."""
    i = int(np.floor(y))
    f = y - i
    return peak_time[i] if f == 0.0 else (1.0 - f) * peak_time[i] + f * peak_time[i + 1]


def _interp_record(e, time, n_valid, t):
    """e(t), linear between the output samples; NaN past the last valid one."""
    if not (np.isfinite(t) and time[0] <= t <= time[n_valid - 1]):
        return np.nan
    k = min(int(np.searchsorted(time[:n_valid], t, side="right")) - 1, n_valid - 1)
    if time[k] == t:
        return e[k]
    return e[k] + (t - time[k]) / (time[k + 1] - time[k]) * (e[k + 1] - e[k])


def pulse_energy_share(below, kinetic0, time, arrival_time, peak_time, width_10, station: int, window: tuple[int, int],
                       n_valid=None) -> np.ndarray:
    """(B,) share of the impact energy the leading pulse carries through the station's section [1].

    ``below`` (B, n_out) [J]: the energy of the part on the clamp side of the section (the time
    integral of the energy flux through it); ``kinetic0`` (B,) [J]: the impact energy;
    ``arrival_time``, ``peak_time`` (B, n) [s], ``width_10`` (B,) [prisms]: the pulse measures;
    ``window`` = (lo, hi) the measurement window. With D = width_10 and T(y) the leading peak's time
    at position y: share = (E(T(s - D)) - E(T(s + 1 + D))) / kinetic0, E interpolated in time; NaN
    unless every prism from floor(s - D) to ceil(s + 1 + D) lies in the window with defined arrival
    and peak times, T(s + 1 + D) < T(s - D) <= the last valid output time, kinetic0 > 0."""
    below = np.asarray(below, np.float64)
    B, T = below.shape
    nv = np.full(B, T) if n_valid is None else np.asarray(n_valid)
    lo, hi = window
    out = np.full(B, np.nan)
    for b in range(B):
        e0, d = kinetic0[b], width_10[b]
        if not (np.isfinite(e0) and e0 > 0.0 and np.isfinite(d) and d > 0.0):
            continue
        ya, yb = station + 1.0 + d, station - d
        ja, jb = int(np.ceil(ya)), int(np.floor(yb))
        if jb < lo or ja > hi - 1:
            continue
        span = slice(jb, ja + 1)
        if not (np.isfinite(arrival_time[b, span]).all() and np.isfinite(peak_time[b, span]).all()):
            continue
        ta, tb = _interp_peak_time(peak_time[b], ya), _interp_peak_time(peak_time[b], yb)
        if not ta < tb:
            continue
        out[b] = (_interp_record(below[b], time, nv[b], tb) - _interp_record(below[b], time, nv[b], ta)) / e0
    return out


def end_energy_share(end, kinetic0, time, speed, prism_height, n_prisms: int, k: int, n_valid=None) -> np.ndarray:
    """(B,) share of the impact energy left in the end part at t_end [1]: ``end[:, -1] / kinetic0``,
    ``end`` (B, n_out) [J], ``kinetic0`` (B,) [J]. Only before the leading pulse, reflected at the
    clamp, can be back in it: NaN unless the pulse ``speed`` (B,) [m s-1] is defined and
    t_end < (2 n_prisms - k) prism_height / speed; NaN too where the column failed before t_end
    (n_valid < n_out) or kinetic0 <= 0."""
    end = np.asarray(end, np.float64)
    B, T = end.shape
    nv = np.full(B, T) if n_valid is None else np.asarray(n_valid)
    e0 = np.asarray(kinetic0, np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        back = (2 * n_prisms - k) * np.asarray(prism_height, np.float64) / np.asarray(speed, np.float64)
        ok = (nv >= T) & (e0 > 0.0) & (time[-1] < back)
        return np.where(ok, end[:, -1] / e0, np.nan)


def section_power(x, v, fixed, node_mass, bars, cables, EA, EAc, rest, below_node: int, bar_active=None) -> np.ndarray:
    """(B,) energy flux [W] into the part below node ``below_node`` (nodes n < below_node and every
    member with an end there) through the members that join it to the rest: the sum over those
    members of -F . v at their other end o, F the member's force on o (energy.md: d/dt of that
    part's energy). Host reference for one state (fp64, a dense solve per column: small columns).

    ``x``, ``v`` (B, n_nodes, 3) positions [m] and velocities [m s-1] (v admissible: the bars'
    length rates zero); ``fixed`` (n_nodes,) clamped nodes; ``node_mass`` (B or 1, n_nodes) [kg]
    lumped (massless bars); ``bars`` (nb, 2) rigid members, ``cables`` (m, 2) with ``EA``, ``EAc``,
    ``rest`` (B or 1, m) as :func:`energy_parts`; ``bar_active`` (B or 1, nb): 1 where the column has
    that rigid member (default: all). Bar forces are the constraint forces of the
    state: with b = x_j - x_i per bar, G (nb, 3 n) = [-b at i, b at j], M^-1 zero on clamped nodes,
    (G M^-1 G^T) lam = -G M^-1 f - |v_j - v_i|^2 (the bars' second length derivative zero); the
    force on j is lam b, on i -lam b."""
    x, v = np.asarray(x, np.float64), np.asarray(v, np.float64)
    B, n, _ = x.shape
    bars, cables = np.asarray(bars).reshape(-1, 2), np.asarray(cables).reshape(-1, 2)
    mass = np.broadcast_to(np.asarray(node_mass, np.float64), (B, n))
    EA, EAc, rest = (np.broadcast_to(np.asarray(a, np.float64), (B, len(cables))) for a in (EA, EAc, rest))
    active = np.ones((B, len(bars)), bool) if bar_active is None else np.broadcast_to(np.asarray(bar_active) != 0,
                                                                                         (B, len(bars)))
    all_bars = bars
    out = np.empty(B)
    for b in range(B):
        bars = all_bars[active[b]]
        ci, cj = cables[:, 0], cables[:, 1]
        d = x[b, cj] - x[b, ci]
        length = np.linalg.norm(d, axis=1)
        stretch = length - rest[b]
        tension = np.where(stretch < 0.0, EAc[b], EA[b]) * stretch / rest[b]
        fc = (tension / length)[:, None] * d  # the cable's force on its first node; minus on its second
        f = np.zeros((n, 3))
        np.add.at(f, ci, fc)
        np.add.at(f, cj, -fc)
        minv = np.where(np.asarray(fixed), 0.0, 1.0 / mass[b])
        bi, bj = bars[:, 0], bars[:, 1]
        bb = x[b, bj] - x[b, bi]
        G = np.zeros((len(bars), n, 3))
        G[np.arange(len(bars)), bi] -= bb
        G[np.arange(len(bars)), bj] += bb
        G = G.reshape(len(bars), 3 * n)
        gm = G * np.repeat(minv, 3)[None, :]
        dv = v[b, bj] - v[b, bi]
        lam = np.linalg.solve(gm @ G.T, -gm @ f.reshape(-1) - np.einsum("ki,ki->k", dv, dv)) if len(bars) else []
        power = 0.0
        for (i, j), force_j in ((cables[k], -fc[k]) for k in range(len(cables))):
            power += _cut_term(i, j, force_j, v[b], below_node)
        for k, (i, j) in enumerate(bars):
            power += _cut_term(i, j, lam[k] * bb[k], v[b], below_node)
        out[b] = power
    return out


def _cut_term(i: int, j: int, force_j, v, below_node: int) -> float:
    """-F . v at the member's end outside the part below ``below_node`` (F its force there), where
    the member joins the part to the rest; 0 otherwise. ``force_j``: its force on j (minus on i)."""
    if (i < below_node) == (j < below_node):
        return 0.0
    if j >= below_node:
        return -float(np.dot(force_j, v[j]))
    return float(np.dot(force_j, v[i]))
