"""Independent float64 reference dynamics of tensegrity networks (NumPy only, no Warp kernels).

This module is the yardstick the Warp engine is tested against (tests and benchmarks; it is not
part of the installed package: import it as ``tests.references.reference`` from the repository
root). It is written from the paper
(Fabbrocino & Carpentieri 2017, Sec. 2) and shares no code with the kernels. SI units
throughout: positions [m], velocities [m s-1], masses [kg], forces [N], times [s].

Two independent formulations:

A. **Class-1 matrix form** (paper Eqs. 12-14), :class:`ClassOneMatrixForm`,
   :func:`matrix_form_accel`, :func:`integrate_matrix_form`::

       N'' M + N K = W,
       M = C_B^T m^ C_B / 12 + C_R^T m^ C_R,
       K = C_S^T c^ C_S - C_B^T lambda^ C_B,
       lambda^ = -floor( B'^T B' m^ / 12 + B^T (W - S c^ C_S) C_B^T / 2 ) l^-2.

   ``N`` is the 3 x n_nodes node matrix (columns are nodes), ``B = N C_B^T``, ``S = N C_S^T``.
   Conventions fixed here (the extracted paper text lost its minus signs):

   * ``C_B[k, i] = -1``, ``C_B[k, j] = +1`` for bar ``b_k = n_j - n_i`` (so ``B = N C_B^T``);
     ``C_S`` likewise for cables;
   * ``C_R[k, i] = C_R[k, j] = 1/2`` so that ``R = N C_R^T`` holds the bar centres
     ``r_k = (n_i + n_j)/2`` (Eq. 6; with entries 1, M would not be the thin-rod inertia);
   * ``lambda_k`` is the bar force density with **compression positive** (the force on node
     ``i`` is ``-lambda_k b_k``). Its leading minus sign follows from ``d^2/dt^2 |b_k|^2 = 0``:
     a free spinning bar must be in tension, ``lambda = -m |b'|^2 / (12 l^2) < 0``.

   The closed-form multiplier uses ``C_B C_B^T = 2 I`` and ``C_R C_B^T = 0``, true only when
   every node belongs to exactly one bar (class 1). With the floor operator the formula is then
   exact; for class-k networks the off-diagonal couplings it discards are not zero and the bars
   would drift. It also needs every bar massive and no lumped node masses: M is singular
   otherwise. Both are checked.

B. **Lagrange-multiplier form** for any network (class k, massless or massive bars, clamped
   nodes), :class:`ReferenceSystem`. State ``q`` = free-node coordinates, ``v = q'``::

       M a = f(q) - G^T lam,     G a = -|b_k'|^2       (index-1 DAE)

   with ``g_k = (|b_k|^2 - L_k^2)/2`` and ``G = dg/dq``; ``lam_k`` is a force density with
   **tension positive** (the force on node ``j`` is ``-lam_k b_k``). M is the paper's
   consistent mass matrix (thin rods, (m/6)[[2, 1], [1, 2]] per bar) plus lumped node masses.
   Integrators: classic RK4 with position (Newton) and velocity (mass-metric) projection after
   each step, or scipy's DOP853 on the unprojected index-1 DAE.

Cable law (Eq. 10 plus the compressive branch of the column's base members): axial force
``EA/L (s - L)`` for ``s >= L`` and ``EA_compression/L (s - L)`` for ``s < L``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from warp_tensegrity.scene.network import Network
from warp_tensegrity.validation.constrained import ConstrainedNetwork

__all__ = [
    "ClassOneMatrixForm",
    "matrix_form_accel",
    "integrate_matrix_form",
    "ReferenceSystem",
    "rk4_step",
]


# ====================================================================== shared small helpers
def rk4_step(fun, t: float, y: np.ndarray, dt: float) -> np.ndarray:
    """One classic fourth-order Runge-Kutta step of y' = fun(t, y)."""
    k1 = fun(t, y)
    k2 = fun(t + 0.5 * dt, y + 0.5 * dt * k1)
    k3 = fun(t + 0.5 * dt, y + 0.5 * dt * k2)
    k4 = fun(t + dt, y + dt * k3)
    return y + (dt / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)


def _n_steps(t_end: float, dt: float) -> int:
    n = int(round(t_end / dt))
    if n < 1 or abs(n * dt - t_end) > 1e-9 * max(t_end, dt):
        raise ValueError(f"t_end = {t_end!r} s must be a positive integer multiple of dt = {dt!r} s")
    return n


# ====================================================================== A. class-1 matrix form
@dataclass
class ClassOneMatrixForm:
    """Connectivity and material matrices of a free class-1 network with massive bars (Eqs. 7-14)."""

    C_B: np.ndarray
    """(n_bars, n_nodes) bar connectivity: -1 at the tail i, +1 at the head j of b = n_j - n_i."""
    C_S: np.ndarray
    """(n_cables, n_nodes) cable connectivity, same sign convention."""
    C_R: np.ndarray
    """(n_bars, n_nodes) bar-centre map: 1/2 at both ends."""
    bar_mass: np.ndarray
    """(n_bars,) bar masses m_k [kg]."""
    k_tension: np.ndarray
    """(n_cables,) cable stiffness EA/L in tension [N m-1] (Eq. 8)."""
    k_compression: np.ndarray
    """(n_cables,) stiffness EA_compression/L for s < L [N m-1] (0 = tension-only cable)."""
    rest_length: np.ndarray
    """(n_cables,) rest lengths L [m]."""
    M: np.ndarray
    """(n_nodes, n_nodes) mass matrix of Eq. (13) [kg]."""

    @classmethod
    def from_network(cls, net: Network) -> "ClassOneMatrixForm":
        """Build the matrices; raise ValueError unless the network is free, class 1 and every
        node's inertia comes from exactly one massive bar."""
        nn, nb, ns = net.n_nodes, net.n_bars, net.n_cables
        if np.any(net.fixed):
            raise ValueError("matrix form: clamped nodes are not supported (use ReferenceSystem)")
        if np.any(net.node_mass != 0):
            raise ValueError("matrix form: lumped node masses are not part of Eq. (13); set node_mass = 0")
        if np.any(net.bar_mass <= 0):
            k = int(np.argmin(net.bar_mass > 0))
            raise ValueError(f"matrix form: bar {k} has mass {net.bar_mass[k]!r} kg; M is singular "
                             "without massive bars")
        count = np.bincount(net.bars.ravel(), minlength=nn)
        if np.any(count != 1):
            i = int(np.argmax(count != 1))
            raise ValueError(f"matrix form: node {i} belongs to {int(count[i])} bars; the closed-form "
                             "multiplier (Eq. 14) is exact only for class-1 networks with every node on a bar")
        C_B = np.zeros((nb, nn))
        C_R = np.zeros((nb, nn))
        for k, (i, j) in enumerate(net.bars):
            C_B[k, i], C_B[k, j] = -1.0, 1.0
            C_R[k, i], C_R[k, j] = 0.5, 0.5
        C_S = np.zeros((ns, nn))
        for k, (i, j) in enumerate(net.cables):
            C_S[k, i], C_S[k, j] = -1.0, 1.0
        m = np.diag(net.bar_mass)
        M = C_B.T @ m @ C_B / 12.0 + C_R.T @ m @ C_R
        L = net.cable_rest_length.copy()
        return cls(C_B, C_S, C_R, net.bar_mass.copy(), net.cable_EA / L, net.cable_EA_compression / L, L, M)

    def force_densities(self, N: np.ndarray) -> np.ndarray:
        """Cable force densities c_k [N m-1] (Eqs. 10-11, plus the compressive branch)."""
        S = N @ self.C_S.T
        s = np.linalg.norm(S, axis=0)
        k = np.where(s >= self.rest_length, self.k_tension, self.k_compression)
        return k * (1.0 - self.rest_length / s)

    def bar_force_densities(self, N: np.ndarray, Ndot: np.ndarray, W: np.ndarray | None = None) -> np.ndarray:
        """lambda_k [N m-1], compression positive (Eq. 14 with the floor operator; class 1 only)."""
        W = np.zeros_like(N) if W is None else W
        B = N @ self.C_B.T
        Bd = Ndot @ self.C_B.T
        S = N @ self.C_S.T
        c = self.force_densities(N)
        l2 = np.einsum("ik,ik->k", B, B)
        # floor(B'^T B') and floor(B^T X C_B^T): only the diagonals are needed
        bdot2 = np.einsum("ik,ik->k", Bd, Bd)
        X = (W - (S * c[None, :]) @ self.C_S) @ self.C_B.T
        return -(bdot2 * self.bar_mass / 12.0 + 0.5 * np.einsum("ik,ik->k", B, X)) / l2

    def stiffness(self, N: np.ndarray, Ndot: np.ndarray, W: np.ndarray | None = None) -> np.ndarray:
        """K = C_S^T c^ C_S - C_B^T lambda^ C_B (Eq. 13) [N m-1]."""
        c = self.force_densities(N)
        lam = self.bar_force_densities(N, Ndot, W)
        return self.C_S.T @ (c[:, None] * self.C_S) - self.C_B.T @ (lam[:, None] * self.C_B)

    def energy(self, N: np.ndarray, Ndot: np.ndarray) -> float:
        """Kinetic tr(N' M N'^T)/2 plus cable strain energy sum k (s - L)^2 / 2 [J]."""
        s = np.linalg.norm(N @ self.C_S.T, axis=0)
        k = np.where(s >= self.rest_length, self.k_tension, self.k_compression)
        return 0.5 * float(np.sum(Ndot * (Ndot @ self.M))) + 0.5 * float(np.sum(k * (s - self.rest_length) ** 2))


def matrix_form_accel(N: np.ndarray, Ndot: np.ndarray, form: ClassOneMatrixForm,
                      W: np.ndarray | None = None) -> np.ndarray:
    """N'' [m s-2] from N'' M + N K = W (Eq. 12); N, Ndot, W are 3 x n_nodes (columns = nodes)."""
    W = np.zeros_like(N) if W is None else W
    K = form.stiffness(N, Ndot, W)
    # N'' = (W - N K) M^-1, M symmetric
    return np.linalg.solve(form.M, (W - N @ K).T).T


def integrate_matrix_form(form: ClassOneMatrixForm, N0: np.ndarray, Ndot0: np.ndarray, t_end: float,
                          dt: float, stride: int = 1, W: np.ndarray | None = None):
    """Fixed-step classic RK4 on (N, N') without any projection.

    Returns (t, N, Ndot) with shapes (n_out,), (n_out, 3, n_nodes), (n_out, 3, n_nodes), the
    initial state first and then every ``stride`` steps up to ``t_end``.
    """
    n = _n_steps(t_end, dt)
    shape = np.shape(N0)

    def rhs(_t, y):
        Nc, Nd = y[: y.size // 2].reshape(shape), y[y.size // 2 :].reshape(shape)
        return np.concatenate([Nd.ravel(), matrix_form_accel(Nc, Nd, form, W).ravel()])

    y = np.concatenate([np.asarray(N0, float).ravel(), np.asarray(Ndot0, float).ravel()])
    ts, ys = [0.0], [y]
    for step in range(1, n + 1):
        y = rk4_step(rhs, (step - 1) * dt, y, dt)
        if step % stride == 0 or step == n:
            ts.append(step * dt)
            ys.append(y)
    ys = np.array(ys)
    h = ys.shape[1] // 2
    return np.array(ts), ys[:, :h].reshape((-1,) + shape), ys[:, h:].reshape((-1,) + shape)


# ====================================================================== B. Lagrange multipliers
class ReferenceSystem(ConstrainedNetwork):
    """Constrained dynamics of any :class:`Network` by Lagrange multipliers (dense float64).

    The model (coordinates, constraints and Jacobian, cable forces, consistent mass matrix) is
    :class:`~warp_tensegrity.validation.constrained.ConstrainedNetwork`, which the package's
    linearised checks use too; the accelerations, multipliers, projections and integrators are
    here. Public methods take and return full node arrays of shape (n_nodes, 3); clamped nodes stay at
    their reference positions with zero velocity and acceleration. Bar lengths L_k are those of
    ``network.positions``.
    """

    def __init__(self, network: Network, external_force: np.ndarray | None = None,
                 projection_tol: float = 1e-14, max_newton: int = 50):
        super().__init__(network, external_force)
        self.tol = projection_tol
        self.max_newton = max_newton

    def _accel_q(self, x: np.ndarray, vq: np.ndarray):
        f = self.to_q(self.nodal_forces(x))
        G = self.jacobian(x)
        v = self._to_v(vq)
        bd = v[self.bars[:, 1]] - v[self.bars[:, 0]]
        MiGT = self.Minv @ G.T
        A = G @ MiGT
        rhs = G @ (self.Minv @ f) + np.einsum("ij,ij->i", bd, bd)
        lam = np.linalg.solve(A, rhs) if len(self.bars) else np.zeros(0)
        return self.Minv @ f - MiGT @ lam, lam

    def accel(self, x: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Acceleration [m s-2], shape (n_nodes, 3), of M a = f - G^T lam with G a = -|b'|^2."""
        a, _ = self._accel_q(np.asarray(x, float), self.to_q(v))
        return self._to_v(a)

    def multipliers(self, x: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Bar force densities lam_k [N m-1], tension positive; bar tension = lam_k * |b_k|."""
        return self._accel_q(np.asarray(x, float), self.to_q(v))[1]

    def energy(self, x: np.ndarray, v: np.ndarray) -> float:
        """Kinetic v^T M v / 2 (consistent M) + cable strain energy sum k (s - L)^2 / 2 - W.x [J]."""
        x = np.asarray(x, float)
        vq = self.to_q(v)
        s = np.linalg.norm(x[self.cables[:, 1]] - x[self.cables[:, 0]], axis=1)
        k = np.where(s >= self.L_cable, self.k_t, self.k_c)
        return (0.5 * float(vq @ self.M @ vq) + 0.5 * float(np.sum(k * (s - self.L_cable) ** 2))
                - float(np.sum(self.W[self.free_nodes] * x[self.free_nodes])))

    # ---------------------------------------------------------------- projections
    def project_positions(self, x: np.ndarray) -> np.ndarray:
        """Newton iterations in the mass metric onto |b_k| = L_k, to max |g_k|/L_k^2 <= tol."""
        x = np.array(x, float)
        for _ in range(self.max_newton):
            g = self.constraints(x)
            if np.max(np.abs(g) / self.L_bar**2, initial=0.0) <= self.tol:
                return x
            G = self.jacobian(x)
            MiGT = self.Minv @ G.T
            mu = np.linalg.solve(G @ MiGT, g)
            x[self.free_nodes] -= (MiGT @ mu).reshape(-1, 3)
        g = self.constraints(x)
        raise RuntimeError(f"position projection did not converge: max |g|/L^2 = {np.max(np.abs(g) / self.L_bar**2):.3e}")

    def project_velocities(self, x: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Mass-metric projection of v onto G v = 0 (bar-length rates zero)."""
        vq = self.to_q(v)
        if len(self.bars):
            G = self.jacobian(np.asarray(x, float))
            MiGT = self.Minv @ G.T
            A = G @ MiGT
            for _ in range(3):  # one solve is exact in exact arithmetic; repeat to reach round-off
                r = G @ vq
                scale = np.linalg.norm(G, axis=1) * max(np.linalg.norm(vq), np.finfo(float).tiny)
                if np.max(np.abs(r) / scale) <= self.tol:
                    break
                vq = vq - MiGT @ np.linalg.solve(A, r)
        return self._to_v(vq)

    # ---------------------------------------------------------------- integration
    def integrate(self, x0: np.ndarray, v0: np.ndarray, t_end: float, dt: float, method: str = "rk4",
                  stride: int = 1, project: bool = True, rtol: float = 1e-12, atol: float = 1e-16):
        """Integrate from (x0, v0) to ``t_end`` [s].

        ``method="rk4"``: classic RK4 with fixed step ``dt`` and, after each step, projection of
        positions then velocities onto the constraint manifold (``project=False`` skips it).
        ``method="dop853"``: scipy's adaptive DOP853 on the index-1 DAE with ``rtol``/``atol``,
        no projection, output sampled at the same times.

        Returns (t, x, v) of shapes (n_out,), (n_out, n_nodes, 3), (n_out, n_nodes, 3): the
        initial state and then every ``stride`` steps of size ``dt``, ending at ``t_end``.
        """
        n = _n_steps(t_end, dt)
        x0 = np.asarray(x0, float)
        fill = x0.copy()
        fill[~self.free] = self.x_ref[~self.free]
        out_steps = sorted(set(list(range(0, n + 1, stride)) + [n]))
        out_set = set(out_steps)
        t_out = np.array(out_steps, float) * dt
        t_out[-1] = t_end
        nd = self.ndof

        def rhs(_t, y):
            x = self.to_x(y[:nd], fill)
            a, _ = self._accel_q(x, y[nd:])
            return np.concatenate([y[nd:], a])

        y0 = np.concatenate([self.to_q(x0), self.to_q(v0)])
        if method == "rk4":
            ys = [y0]
            y = y0
            for step in range(1, n + 1):
                y = rk4_step(rhs, (step - 1) * dt, y, dt)
                if project and len(self.bars):
                    x = self.project_positions(self.to_x(y[:nd], fill))
                    v = self.project_velocities(x, self._to_v(y[nd:]))
                    y = np.concatenate([self.to_q(x), self.to_q(v)])
                if step in out_set:
                    ys.append(y)
            Y = np.array(ys)
        elif method == "dop853":
            from scipy.integrate import solve_ivp  # lazy: scipy is a test/bench dependency

            sol = solve_ivp(rhs, (0.0, t_end), y0, method="DOP853", t_eval=t_out, rtol=rtol, atol=atol)
            if not sol.success:
                raise RuntimeError(f"DOP853 failed: {sol.message}")
            Y = sol.y.T
        else:
            raise ValueError(f"method = {method!r}; choose 'rk4' or 'dop853'")
        X = np.array([self.to_x(y[:nd], fill) for y in Y])
        V = np.array([self._to_v(y[nd:]) for y in Y])
        return t_out, X, V
