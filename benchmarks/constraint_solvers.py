"""Constraint solvers side by side on FB and RB columns: iterations, residual reached, cost.

The position projection of one RATTLE step: given q* = q_n + dt v (off the bar manifold), find
q = q* - M^-1 G(q_n)^T lam with |b_k(q)| = L_k. Three solvers, float64 NumPy, the same start:

* ``newton_direct``: the engine's scheme. Simplified Newton with the Gram matrix
  A = G M^-1 G^T factored once (a banded Cholesky in the engine; dense here).
* ``gauss_seidel``: iterative SHAKE, one constraint at a time with the latest positions.
* ``jacobi``: all constraints at once from the same positions (what a naive one-thread-per-bar
  GPU kernel does), under-relaxed by 1/(max bars per node) so it can converge at all.

    python -m benchmarks.constraint_solvers --out analysis/data/solvers_cpu.json
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from warp_tensegrity import ColumnConfig, build_column
from tests.references.reference import ReferenceSystem

TOL = 1e-12
MAX_SWEEPS = 3000


def _residual(x, bars, L):
    b = x[bars[:, 1]] - x[bars[:, 0]]
    return np.abs(np.linalg.norm(b, axis=1) - L) / L


def newton_direct(x, x0, bars, L, minv):
    b0 = x0[bars[:, 1]] - x0[bars[:, 0]]
    n = x.shape[0]
    G = np.zeros((len(bars), 3 * n))
    for k, (i, j) in enumerate(bars):
        G[k, 3 * j : 3 * j + 3] += b0[k]
        G[k, 3 * i : 3 * i + 3] -= b0[k]
    Minv = np.repeat(minv, 3)
    A = (G * Minv) @ G.T
    cho = np.linalg.cholesky(A)
    it = 0
    while True:
        r = _residual(x, bars, L)
        if r.max() <= TOL or it >= MAX_SWEEPS:
            return x, it, r.max()
        b = x[bars[:, 1]] - x[bars[:, 0]]
        g = 0.5 * ((b * b).sum(1) - L**2)
        lam = np.linalg.solve(cho.T, np.linalg.solve(cho, g))
        x = x - (Minv * (G.T @ lam)).reshape(-1, 3)
        it += 1


def gauss_seidel(x, x0, bars, L, minv):
    x = x.copy()
    b0 = x0[bars[:, 1]] - x0[bars[:, 0]]
    for it in range(MAX_SWEEPS + 1):
        r = _residual(x, bars, L)
        if r.max() <= TOL or it == MAX_SWEEPS:
            return x, it, r.max()
        for k, (i, j) in enumerate(bars):
            b = x[j] - x[i]
            g = 0.5 * (b @ b - L[k] ** 2)
            denom = (minv[i] + minv[j]) * (b @ b0[k])
            lam = g / denom
            x[j] -= minv[j] * lam * b0[k]
            x[i] += minv[i] * lam * b0[k]


def jacobi(x, x0, bars, L, minv):
    x = x.copy()
    b0 = x0[bars[:, 1]] - x0[bars[:, 0]]
    omega = 1.0 / np.bincount(bars.ravel()).max()
    for it in range(MAX_SWEEPS + 1):
        r = _residual(x, bars, L)
        if r.max() <= TOL or it == MAX_SWEEPS or not np.isfinite(r.max()):
            return x, it, r.max()
        b = x[bars[:, 1]] - x[bars[:, 0]]
        g = 0.5 * ((b * b).sum(1) - L**2)
        lam = omega * g / ((minv[bars[:, 0]] + minv[bars[:, 1]]) * (b * b0).sum(1))
        dx = np.zeros_like(x)
        np.add.at(dx, bars[:, 1], -(minv[bars[:, 1]] * lam)[:, None] * b0)
        np.add.at(dx, bars[:, 0], (minv[bars[:, 0]] * lam)[:, None] * b0)
        x = x + dx


SOLVERS = {"newton_direct": newton_direct, "gauss_seidel": gauss_seidel, "jacobi": jacobi}


def start_state(base_rigidity: float, dt: float, n_prisms: int):
    """A state mid-impact and its unprojected drift: a few RK4 steps of the reference, then q* = q + dt v."""
    cfg = ColumnConfig(n_prisms=n_prisms)
    scene = build_column(cfg, prestrain=0.002, v0=0.1, base_rigidity=base_rigidity)
    net = scene.network
    ref = ReferenceSystem(net)
    _, X, V = ref.integrate(net.positions, scene.velocity, 0.05, 1e-3, method="rk4", stride=50)
    x0, v = X[-1], V[-1]
    minv = np.where(net.fixed, 0.0, 1.0 / np.where(net.node_mass > 0, net.node_mass, 1.0))
    return x0, x0 + dt * v, net.bars, net.bar_lengths(), minv


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default="analysis/data/solvers_cpu.json")
    ap.add_argument("--n-prisms", type=int, default=50)
    a = ap.parse_args(argv)
    rows = []
    for base, beta in (("FB", 0.0), ("RB", 1.0)):
        for dt in (0.0005, 0.002, 0.005):
            x0, xs, bars, L, minv = start_state(beta, dt, a.n_prisms)
            r0 = _residual(xs, bars, L).max()
            for name, solve in SOLVERS.items():
                t = time.perf_counter()
                _, it, res = solve(xs, x0, bars, L, minv)
                wall = time.perf_counter() - t
                nc = len(bars)
                bw = 3 if base == "FB" else 6
                # work per iteration: Newton = banded solve (2 nc bw) + residual/update (~30 nc);
                # GS/Jacobi = one sweep (~30 nc). The factorisation (nc bw^2) is shared with the
                # velocity projection in the engine and is not counted here.
                flops = it * (30 * nc + (4 * nc * bw if name == "newton_direct" else 0))
                rows.append({"base": base, "dt": dt, "solver": name, "constraints": nc,
                             "initial_residual": float(r0), "iterations": int(it),
                             "residual_reached": float(res), "converged": bool(res <= TOL),
                             "flops_estimate": int(flops), "numpy_wall_s": wall})
                print(f"{base} dt={dt:g} {name:14s} start {r0:.1e}: {it:5d} it, reached {res:.1e}, "
                      f"~{flops:.2e} flop ({'converged' if res <= TOL else 'NOT converged'})")
    with open(a.out, "w") as f:
        json.dump({"tolerance": TOL, "max_sweeps": MAX_SWEEPS, "n_prisms": a.n_prisms, "rows": rows}, f, indent=1)
    print(a.out)


if __name__ == "__main__":
    main()
