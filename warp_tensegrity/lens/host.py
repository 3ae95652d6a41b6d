"""Host medium: array geometry and the one-way Huygens superposition (pure NumPy, float64).

Coupling model (``docs/lens.md``): column i's exit face, at x_i in the plane z = 0, is a point
source (a line source along y when ``dimension = 2``) that radiates its exit signal s_i(t) into a
homogeneous linear host of wave speed c_h:

    phi(r, t) = sum_i g(|r - x_i|) s_i(t - d_i - |r - x_i| / c_h),
    g(R) = 1 / R (dimension 3),  g(R) = 1 / sqrt(R) (dimension 2, far field R >> c_h tau),

d_i being column i's strike delay. The host does not load the columns back (one-way).
The signals are sampled on a uniform time grid and interpolated linearly between samples; a
signal is zero before its first sample (the column is at rest before it is struck).
"""

from __future__ import annotations

import numpy as np


def column_positions(layout: str, shape: tuple[int, int], spacing: float) -> np.ndarray:
    """(N, 3) exit-face centres [m], centred on the z axis, z = 0; a grid runs x fastest."""
    nx, ny = shape
    x = (np.arange(nx) - (nx - 1) / 2) * spacing
    y = (np.arange(ny) - (ny - 1) / 2) * spacing if layout == "grid" else np.zeros(1)
    X, Y = np.meshgrid(x, y, indexing="xy")
    return np.stack([X.ravel(), Y.ravel(), np.zeros(X.size)], axis=1)


def plane_wave_delays(positions: np.ndarray, angle_deg: float, azimuth_deg: float, speed: float) -> np.ndarray:
    """(N,) strike delays [s] of a plane incident wave, the earliest column at 0."""
    if angle_deg == 0.0 or not np.isfinite(speed):
        return np.zeros(len(positions))
    a, b = np.radians(angle_deg), np.radians(azimuth_deg)
    d = (positions[:, 0] * np.cos(b) + positions[:, 1] * np.sin(b)) * np.sin(a) / speed
    return d - d.min()


def spreading(R, dimension: int):
    """Geometric spreading g(R) [m^-1 or m^-1/2]: 1/R (3D) or 1/sqrt(R) (2D)."""
    R = np.asarray(R, dtype=np.float64)
    return 1.0 / R if dimension == 3 else 1.0 / np.sqrt(R)


def distances(receivers: np.ndarray, sources: np.ndarray) -> np.ndarray:
    """(P, N) distances [m]."""
    return np.linalg.norm(np.asarray(receivers, float)[:, None, :] - np.asarray(sources, float)[None, :, :], axis=-1)


def sample(signals: np.ndarray, dt: float, t) -> np.ndarray:
    """Signals (N, K), sampled at k dt, read at times t (N, ...) by linear interpolation;
    zero before t = 0 (the column is at rest before it is struck, its first sample is the rest
    state 0 or later) and NaN after the last sample (unknown)."""
    signals = np.asarray(signals, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64)
    K = signals.shape[1]
    grid = np.arange(-1, K) * dt  # a leading rest sample at -dt
    out = np.empty(t.shape)
    for i in range(signals.shape[0]):
        out[i] = np.interp(t[i], grid, np.concatenate([[0.0], signals[i]]), left=0.0, right=np.nan)
    return out


def field(signals, dt, sources, delays, receivers, times, wave_speed, dimension) -> np.ndarray:
    """phi(r_p, t_k) (P, T) of the superposition for receivers (P, 3) [m] and times (T,) [s]."""
    signals = np.asarray(signals, dtype=np.float64)
    R = distances(receivers, sources)  # (P, N)
    g = spreading(R, dimension)
    lag = np.asarray(delays, float)[None, :] + R / wave_speed
    times = np.asarray(times, float)
    K = signals.shape[1]
    grid = np.arange(-1, K) * dt
    phi = np.zeros((R.shape[0], times.size))
    for i in range(signals.shape[0]):  # one np.interp per column over all (receiver, time) pairs
        s = np.interp(times[None, :] - lag[:, i:i + 1], grid, np.concatenate([[0.0], signals[i]]),
                      left=0.0, right=np.nan)
        phi += g[:, i:i + 1] * s
    return phi


def peak_over_time(signals, dt, sources, delays, receivers, wave_speed, dimension, chunk: int = 256) -> np.ndarray:
    """(P,) max_t phi(r_p, t) over every time at which all contributions are known (each
    signal's record, shifted by its delay and flight time), with a parabolic sub-sample vertex.

    The time grid is the signals' own grid dt, starting at 0."""
    signals = np.asarray(signals, float)
    receivers = np.asarray(receivers, float)
    K = signals.shape[1]
    out = np.empty(len(receivers))
    R_all = distances(receivers, sources)
    t_known = (K - 1) * dt + (np.asarray(delays, float)[None, :] + R_all / wave_speed).min(axis=1)
    n_t = int(np.ceil(t_known.max() / dt)) + 1
    times = np.arange(n_t) * dt
    for a in range(0, len(receivers), chunk):
        b = min(a + chunk, len(receivers))
        phi = field(signals, dt, sources, delays, receivers[a:b], times, wave_speed, dimension)
        phi = np.where(times[None, :] <= t_known[a:b, None] + 1e-12 * dt, phi, -np.inf)
        phi = np.where(np.isnan(phi), -np.inf, phi)
        out[a:b] = _vertex(phi)
    return out


def _vertex(phi: np.ndarray) -> np.ndarray:
    """Row maxima, refined by the parabola through the maximum and its two neighbours."""
    k = np.argmax(phi, axis=1)
    rows = np.arange(phi.shape[0])
    y1 = phi[rows, k]
    km, kp = np.clip(k - 1, 0, phi.shape[1] - 1), np.clip(k + 1, 0, phi.shape[1] - 1)
    y0, y2 = phi[rows, km], phi[rows, kp]
    inner = (k > 0) & (k < phi.shape[1] - 1) & np.isfinite(y0) & np.isfinite(y2)
    den = y0 - 2 * y1 + y2
    with np.errstate(invalid="ignore", divide="ignore"):
        peak = y1 - (y0 - y2) ** 2 / (8 * den)
    return np.where(inner & (den < 0), peak, y1)


def map_grid(foci, half_width: float, half_depth: float, points: int, grid_array: bool):
    """Axes (x, y, z) [m] of one map that covers every focal point with the margins
    ``half_width`` (x, and y for a grid array) and ``half_depth`` (z); the step is
    2 half_width / (points - 1) across and 2 half_depth / (points - 1) along z; y has one point
    for a line array; z > 0."""
    F = np.atleast_2d(np.asarray(foci, float))

    def axis(lo, hi, step):
        n = int(round((hi - lo) / step)) + 1
        return lo + (hi - lo) * np.linspace(0.0, 1.0, max(n, 2)) if hi > lo else np.array([lo])

    sx, sz = 2 * half_width / (points - 1), 2 * half_depth / (points - 1)
    x = axis(F[:, 0].min() - half_width, F[:, 0].max() + half_width, sx)
    y = axis(F[:, 1].min() - half_width, F[:, 1].max() + half_width, sx) if grid_array else np.array([F[0, 1]])
    if not grid_array and np.ptp(F[:, 1]) > 0:
        raise ValueError("a line array maps the plane y = const: give its focal points one y")
    z_lo = max(F[:, 2].min() - half_depth, sz)
    z = axis(z_lo, F[:, 2].max() + half_depth, sz)
    return x, y, z


def focal_map(signals, dt, sources, delays, axes, wave_speed, dimension) -> np.ndarray:
    """Peak over time of the host field on the grid ``axes`` = (x, y, z): array (z, y, x)."""
    x, y, z = axes
    Z, Y, X = np.meshgrid(z, y, x, indexing="ij")
    pts = np.stack([X.ravel(), Y.ravel(), Z.ravel()], axis=1)
    return peak_over_time(signals, dt, sources, delays, pts, wave_speed, dimension).reshape(Z.shape)


def map_peak(m: np.ndarray, axes) -> np.ndarray:
    """Location [m] (x, y, z) of a map's maximum, refined per axis by a parabola (sub-grid)."""
    x, y, z = axes
    idx = np.unravel_index(np.nanargmax(m), m.shape)  # (iz, iy, ix)
    loc = []
    for ax, coord in zip((2, 1, 0), (x, y, z)):
        i = idx[ax]
        c = float(coord[i])
        if 0 < i < len(coord) - 1:
            sl = list(idx)
            sl[ax] = i - 1
            y0 = m[tuple(sl)]
            sl[ax] = i + 1
            y2 = m[tuple(sl)]
            y1 = m[idx]
            den = y0 - 2 * y1 + y2
            if den < 0:
                c += 0.5 * (y0 - y2) / den * (coord[1] - coord[0])
        loc.append(c)
    return np.array(loc)
