"""Why the engine solves the projection by Newton with a direct solve: iterative SHAKE stalls on RB loops."""

import numpy as np

from benchmarks import constraint_solvers as cs


def test_newton_direct_converges_where_gauss_seidel_and_jacobi_stall(monkeypatch):
    monkeypatch.setattr(cs, "MAX_SWEEPS", 300)
    x0, xs, bars, L, minv = cs.start_state(1.0, 0.002, n_prisms=6)  # RB: base triangles close loops
    _, it_n, res_n = cs.newton_direct(xs, x0, bars, L, minv)
    _, it_gs, res_gs = cs.gauss_seidel(xs, x0, bars, L, minv)
    _, it_j, res_j = cs.jacobi(xs, x0, bars, L, minv)
    assert res_n <= cs.TOL and it_n <= 15
    assert it_gs == 300 and res_gs > 1e3 * cs.TOL
    assert it_j == 300 and res_j > 1e3 * cs.TOL


def test_all_three_converge_on_fb_chains_newton_fastest():
    x0, xs, bars, L, minv = cs.start_state(0.0, 0.002, n_prisms=6)
    its = {name: solve(xs, x0, bars, L, minv)[1:] for name, solve in cs.SOLVERS.items()}
    assert all(res <= cs.TOL for _, res in its.values())
    assert its["newton_direct"][0] < its["gauss_seidel"][0] < its["jacobi"][0]
