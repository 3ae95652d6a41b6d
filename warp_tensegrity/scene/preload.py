"""The end preload (global prestress): a column in static equilibrium under a compressive dead
load F0 on its free end, the state the impact then strikes (issue 34 item 3).

The load F0 [N] acts along -z, F0/3 on each node of the free-end base. The equilibrium of the
nonlinear network (rigid bars and, at beta = 1, rigid base links as constraints g_k = (|b_k|^2 -
l_k^2)/2 = 0; cables with their bilinear law, tension-only where EA_c = 0) is solved by Newton's
method on the KKT system

    [ H(x, lam)  J^T ] [dx  ]     [ f(x) + f_ext + J^T lam ]
    [ J          0   ] [dlam] = - [ g(x)                   ],   H = -K_cables + sum_k lam_k d2g_k,

with the cables' tangent stiffness K (material and geometric terms). The matrix is sparse and,
for a column, banded: SciPy's sparse LU solves it in O(n). Under compression a T3 column follows
its mechanism path (each prism twists as it shortens; docs/model.md), so the load is applied in
increments, each step starting from the last equilibrium; an increment that does not converge is
halved. Hand-written rather than a general solver (scipy.optimize.root) because the constraints
must hold exactly and the Jacobian is known in closed form: Newton converges quadratically in a few
iterations where a derivative-free or least-squares root finder would not hold the bars rigid.

A load the column cannot carry is refused (:class:`~.network.NetworkError` naming ``preload`` and
the largest load reached): when the solve does not converge (a limit point: the column buckles or
snaps), when a tension-only member goes slack, or when a prism's bars reach a twist of pi.

NumPy and SciPy; no Warp.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .network import Network, NetworkError

NEWTON_TOL = 1e-12
"""Relative residual (force over the load scale, bar error over the bar length) of a converged state."""
MAX_NEWTON = 15
"""Newton iterations per load increment (from the last equilibrium it converges in ~5; an increment
that needs more is cut instead)."""
FIRST_INCREMENTS = 4
"""Load increments tried first (an increment is halved when it fails, down to 1/2^MAX_HALVINGS of
the first, and doubled after each success)."""
MAX_HALVINGS = 12
MAX_TURN = 0.2
"""Largest turn [rad] of a prism within one load increment accepted as the same branch of the path."""


@dataclass
class PreloadState:
    """The static equilibrium of one column under its end load."""

    positions: np.ndarray
    """(n_nodes, 3) equilibrium positions [m]."""
    residual: float
    """Largest nodal force imbalance at free nodes [N] (bars at their least-squares forces)."""
    tensions: np.ndarray
    """(n_cables,) axial forces of the cables at equilibrium [N], positive in tension."""
    bar_forces: np.ndarray
    """(n_bars,) axial forces of the rigid members [N], positive in tension."""
    load: float
    """F0 [N]."""


def end_load(n_nodes: int, end_nodes, F0: float) -> np.ndarray:
    """(n_nodes, 3) nodal forces [N] of the preload: -F0/3 along z on each free-end node."""
    f = np.zeros((n_nodes, 3))
    f[np.asarray(end_nodes), 2] = -float(F0) / 3.0
    return f


def _cable_state(net: Network, x: np.ndarray):
    c = net.cables
    b = x[c[:, 1]] - x[c[:, 0]]
    s = np.linalg.norm(b, axis=1)
    L = net.cable_rest_length
    stretch = s - L
    EA = np.where(stretch > 0, net.cable_EA, net.cable_EA_compression)
    T = EA / L * stretch
    return b, s, EA, T


def _forces(net: Network, x: np.ndarray, f_ext: np.ndarray) -> np.ndarray:
    """(n_nodes, 3) cable forces plus the external load [N]."""
    b, s, _, T = _cable_state(net, x)
    fe = (T / s)[:, None] * b  # on the first node, toward the second
    f = f_ext.copy()
    np.add.at(f, net.cables[:, 0], fe)
    np.add.at(f, net.cables[:, 1], -fe)
    return f


def _jacobian(net: Network, x: np.ndarray, dof: np.ndarray):
    """Sparse J (n_bars x n_free_dof) of g_k = |b_k|^2/2 over the free degrees of freedom."""
    from scipy import sparse

    bars = net.bars
    b = x[bars[:, 1]] - x[bars[:, 0]]
    rows = np.repeat(np.arange(len(bars)), 6)
    nodes = np.repeat(bars[:, ::-1], 3, axis=1)  # j, j, j, i, i, i
    cols = dof[nodes * 3 + np.tile(np.arange(3), 2)[None, :]].ravel()
    vals = np.concatenate([b, -b], axis=1).ravel()
    keep = cols >= 0
    return sparse.csr_matrix((vals[keep], (rows[keep], cols[keep])), shape=(len(bars), int(dof.max()) + 1))


def _pair_blocks(pairs: np.ndarray, blocks: np.ndarray, dof: np.ndarray, size: int):
    """Sparse sum over members (i, j) of [[K, -K], [-K, K]] (K: (m, 3, 3)) on the free dofs."""
    from scipy import sparse

    i, j = pairs[:, 0], pairs[:, 1]
    r3 = np.arange(3)
    rows, cols, vals = [], [], []
    for a, bnode, sign in ((i, i, 1.0), (j, j, 1.0), (i, j, -1.0), (j, i, -1.0)):
        ra = dof[3 * a[:, None, None] + r3[None, :, None]] * np.ones((1, 1, 3), dtype=np.int64)
        cb = dof[3 * bnode[:, None, None] + r3[None, None, :]] * np.ones((1, 3, 1), dtype=np.int64)
        keep = (ra >= 0) & (cb >= 0)
        rows.append(ra[keep])
        cols.append(cb[keep])
        vals.append((sign * blocks)[keep])
    return sparse.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(size, size))


def _hessian(net: Network, x: np.ndarray, lam: np.ndarray, dof: np.ndarray, size: int):
    """d(f + J^T lam)/dx on the free dofs: minus the cables' tangent stiffness plus sum lam_k d2g_k."""
    b, s, EA, T = _cable_state(net, x)
    e = b / s[:, None]
    ee = e[:, :, None] * e[:, None, :]
    K = (EA / net.cable_rest_length)[:, None, None] * ee + (T / s)[:, None, None] * (np.eye(3)[None] - ee)
    G = lam[:, None, None] * np.eye(3)[None]  # d2g_k = [[I, -I], [-I, I]]
    return _pair_blocks(net.cables, -K, dof, size) + _pair_blocks(net.bars, G, dof, size)


def _multipliers(J, f_free: np.ndarray) -> np.ndarray:
    """Least-squares lam with J^T lam = -f (the bar forces that balance the cables best)."""
    from scipy.sparse.linalg import lsqr

    return lsqr(J.T, -f_free, atol=1e-15, btol=1e-15, iter_lim=20 * J.shape[0] + 100)[0]


def static_residual(net: Network, x: np.ndarray, f_ext: np.ndarray) -> float:
    """Largest nodal force imbalance [N] at free nodes of the state x under f_ext, with the rigid
    members at the least-squares forces that balance the rest (the self-stress residual's measure,
    :func:`warp_tensegrity.scene.columns.equilibrium_residual`, with the load)."""
    from . import sparse as sp

    free = np.repeat(~net.fixed, 3)
    rhs = _forces(net, x, f_ext).reshape(-1)[free]
    if not rhs.size:
        return 0.0
    J = sp.jacobian(x, net.bars, net.fixed)[:, np.flatnonzero(free)]
    return float(sp.lsq_residual(J, rhs))


def _newton(net, x, lam, f_ext, dof, scale_f):
    """Newton from (x, lam) to the equilibrium under f_ext; (x, lam) or None if it does not converge."""
    from scipy import sparse
    from scipy.sparse.linalg import splu

    nf = int(dof.max()) + 1
    free = np.flatnonzero(dof >= 0)
    L2 = net.bar_lengths() ** 2  # the reference bar lengths (positions of ``net``)
    Lmax = float(np.sqrt(L2.max()))
    # round-off floor: coordinates far from the origin (a long column) carry eps |x| absolute error
    xerr = 16.0 * np.finfo(float).eps * float(np.abs(x).max())
    tol_f = max(NEWTON_TOL * scale_f, xerr * float((net.cable_EA / net.cable_rest_length).max(initial=0.0)))
    tol_g = max(NEWTON_TOL * Lmax, xerr) * Lmax
    r0 = None
    for _ in range(MAX_NEWTON):
        J = _jacobian(net, x, dof)
        b = x[net.bars[:, 1]] - x[net.bars[:, 0]]
        g = 0.5 * ((b * b).sum(axis=1) - L2)
        r = _forces(net, x, f_ext).reshape(-1)[free] + J.T @ lam
        if np.abs(r).max() <= tol_f and np.abs(g).max() <= tol_g:
            return x, lam
        r0 = np.abs(r).max() if r0 is None else r0
        if np.abs(r).max() > 1e3 * r0:  # diverging: cut the increment now
            return None
        H = _hessian(net, x, lam, dof, nf)
        A = sparse.bmat([[H, J.T], [J, None]], format="csc")
        try:
            sol = splu(A).solve(-np.concatenate([r, g]))
        except RuntimeError:  # singular: a limit point of the load path
            return None
        if not np.all(np.isfinite(sol)):
            return None
        dx = np.zeros(3 * x.shape[0])
        dx[free] = sol[:nf]
        x = _cylindrical_step(x, dx.reshape(-1, 3))
        lam = lam + sol[nf:]
    return None


def _cylindrical_step(x: np.ndarray, dx: np.ndarray) -> np.ndarray:
    """x + dx with the step's radial, angular and axial parts applied in cylindrical coordinates
    about the z axis: the levels of a long column turn far about it (each prism twists as it
    shortens, the turns add up along the column), and a Cartesian step would move a turning node off
    its circle by half the angle squared; this retraction agrees with x + dx to first order, so
    Newton keeps its quadratic convergence."""
    r = np.hypot(x[:, 0], x[:, 1])
    ok = r > 0
    safe = np.where(ok, r, 1.0)
    dr = (x[:, 0] * dx[:, 0] + x[:, 1] * dx[:, 1]) / safe
    dth = (x[:, 0] * dx[:, 1] - x[:, 1] * dx[:, 0]) / safe**2
    th = np.arctan2(x[:, 1], x[:, 0]) + dth
    out = x + dx  # nodes on the axis: Cartesian
    out[ok, 0] = ((r + dr) * np.cos(th))[ok]
    out[ok, 1] = ((r + dr) * np.sin(th))[ok]
    return out


def solve_preload(net: Network, end_nodes, F0: float, level_nodes: np.ndarray | None = None,
                  twist_limit: float = np.pi) -> PreloadState:
    """The static equilibrium of ``net`` (its positions: the self-stressed reference) under the end
    load F0 [N] on ``end_nodes``. Raises NetworkError naming ``preload`` when the column cannot carry
    it (see the module docstring); ``level_nodes`` (a column's bases) adds the twist check."""
    F0 = float(F0)
    X = net.positions
    n = X.shape[0]
    dof = np.full(3 * n, -1, dtype=np.int64)
    free = np.repeat(~net.fixed, 3)
    dof[free] = np.arange(int(free.sum()))
    f0 = np.zeros((n, 3))
    T_ref = np.abs(net.cable_tensions()).max()
    scale_f = max(F0 / 3.0, float(T_ref), np.finfo(float).tiny)
    lam = _multipliers(_jacobian(net, X, dof), _forces(net, X, f0).reshape(-1)[free])
    x, done, step = X.copy(), 0.0, F0 / FIRST_INCREMENTS
    twist = _level_angles(X, level_nodes)
    smallest = F0 / (FIRST_INCREMENTS * 2.0**MAX_HALVINGS)
    while done < F0:
        target = min(F0, done + step)
        out = _newton(net, x, lam, end_load(n, end_nodes, target), dof, scale_f)
        if out is not None:  # the same branch: no prism turned over or inverted within an increment
            turn = _level_angles(out[0], level_nodes) - _level_angles(x, level_nodes)
            turn = np.angle(np.exp(1j * turn))
            if np.abs(turn).max(initial=0.0) > MAX_TURN or _min_height(out[0], level_nodes) <= 0.0:
                out = None
        if out is None:
            step *= 0.5
            if step < smallest:
                raise NetworkError(f"preload = {F0!r} N: beyond the column's capacity: the static solve does not "
                                   f"converge above F0 = {done:.6g} N (a limit point of the load path)")
            continue
        twist = twist + turn
        why = _slack(net, out[0]) or _twisted(twist, twist_limit)
        if why:
            raise NetworkError(f"preload = {F0!r} N: beyond the column's capacity: {why} at F0 = {target:.6g} N "
                               f"(the last equilibrium found: F0 = {done:.6g} N)")
        x, lam = out
        done = target
        step *= 2.0  # the path is smooth again: lengthen the increments
    f_ext = end_load(n, end_nodes, F0)
    _, _, _, T = _cable_state(net, x)
    return PreloadState(x, static_residual(net, x, f_ext), T, -lam * net.bar_lengths(x), F0)


def _slack(net: Network, x: np.ndarray) -> str:
    """'' or which tension-only member went slack at the state x."""
    _, _, _, T = _cable_state(net, x)
    slack = np.flatnonzero((net.cable_EA_compression == 0) & (T <= 0))
    return f"{net.cable_name(int(slack[0]))} goes slack" if slack.size else ""


def _level_angles(x: np.ndarray, level_nodes) -> np.ndarray:
    """(n_prisms, 3) angle [rad] about z from each bottom node to its top node, both from their
    base's centroid (a prism's twist, signed); empty without levels."""
    if level_nodes is None:
        return np.zeros((0, 3))
    P = x[level_nodes]  # (levels, 3, 3)
    r = P - P.mean(axis=1, keepdims=True)
    ang = np.arctan2(r[..., 1], r[..., 0])
    return np.angle(np.exp(1j * (ang[1:] - ang[:-1])))


def _min_height(x: np.ndarray, level_nodes) -> float:
    if level_nodes is None:
        return np.inf
    return float(np.diff(x[level_nodes, 2].mean(axis=1)).min())


def _twisted(twist: np.ndarray, limit: float) -> str:
    """'' or which prism's twist (unwrapped along the load path) reached ``limit`` (pi: its bars touch)."""
    bad = np.flatnonzero(np.abs(twist).mean(axis=1) >= limit) if twist.size else np.zeros(0, int)
    return f"prism {int(bad[0])} twists to pi (its bars touch)" if bad.size else ""


# ---------------------------------------------------------------------- a batch of columns
SOLVED_CACHE = 256
"""Static states kept (a run builds its columns several times: planning, shards, the twin)."""
_SOLVED: dict = {}
"""(scene, prestrain, base rigidity, EA, F0) -> (positions, residual, impact velocity at v0 = 1 m/s):
the state depends on these alone (the impact velocity is invariant to a uniform mass scale)."""


def column_network(batch, b: int) -> Network:
    """Column b of a batch (scene.batch.NetworkBatch) as a Network: its active rigid members, its
    cables with EA > 0 (a rigid base's members are links instead), exactly the members the engine steps."""
    row = lambda a: np.broadcast_to(a, (batch.n_columns,) + a.shape[1:])[b]  # noqa: E731 (a (B or 1, ...) field)
    bars = row(batch.constraint_active) > 0
    cab = row(batch.cable_EA) > 0
    names = [nm for nm, keep in zip(batch.cable_names or [], cab) if keep] or None
    return Network(positions=batch.positions, node_mass=row(batch.node_mass), fixed=batch.fixed,
                   bars=batch.constraints[bars], bar_mass=row(batch.constraint_mass)[bars], cables=batch.cables[cab],
                   cable_EA=row(batch.cable_EA)[cab], cable_rest_length=row(batch.cable_rest_length)[cab],
                   cable_EA_compression=row(batch.cable_EA_compression)[cab], cable_names=names)


def apply_preload(batch, config, p, impact) -> None:
    """Put the columns of ``batch`` (scene.batch.column_batch's, parameters ``p``, scene ``config``) with
    preload > 0 into their static equilibrium: their initial displacement, the dead load, the prism
    heights the strain is recorded from, an impact velocity admissible at that state (the scene's
    convention at the loaded geometry; ``impact``: scene.columns.impact_velocity, passed in since this
    module sits below the scene builder) and the equilibrium residual (over max(EA p, F0)). One solve
    per distinct (prestrain, base rigidity, EA, F0); columns with F0 = 0 are left as they are."""
    B, X, levels = batch.n_columns, batch.positions, batch.level_nodes
    n = X.shape[0]
    F = p["preload"]
    key = np.stack([p["prestrain"], p["base_rigidity"], p["cable_EA"], F], axis=1)
    loaded = np.flatnonzero(F > 0)
    uniq, first, inverse = np.unique(key[loaded], axis=0, return_index=True, return_inverse=True)
    end = levels[-1]
    disp = np.zeros((B, n, 3))
    dz = np.zeros((B, levels.shape[0] - 1))
    heights = lambda x: np.diff(x[levels, 2].mean(axis=1))  # noqa: E731 (prism heights [m])
    for s, (prestrain, beta, EA, F0) in enumerate(uniq):
        key = (config, float(prestrain), float(beta), float(EA), float(F0))
        if key not in _SOLVED:
            net = column_network(batch, int(loaded[first[s]]))
            try:
                state = solve_preload(net, end, F0, levels)
            except NetworkError as e:
                raise NetworkError(f"{e} (prestrain = {prestrain!r}, base_rigidity = {beta!r}, "
                                   f"cable_EA = {EA!r} N)") from None
            v1 = _unit_impact(config, net, levels, state.positions, impact)
            if len(_SOLVED) >= SOLVED_CACHE:
                _SOLVED.pop(next(iter(_SOLVED)))
            _SOLVED[key] = (state.positions, state.residual, v1)
        x, residual, v1 = _SOLVED[key]
        cols = loaded[inverse.reshape(-1) == s]
        disp[cols] = x - X
        dz[cols] = heights(x) - heights(X)
        batch.velocity[cols] = p["v0"][cols, None, None] * v1[None]
        batch.equilibrium_residual[cols] = residual / max(EA * prestrain, F0)
    batch.initial_displacement = disp
    batch.external_force = np.zeros((B, n, 3))
    batch.external_force[:, end, 2] = -F[:, None] / 3.0
    batch.static_dz = dz


def _unit_impact(config, net: Network, levels: np.ndarray, x: np.ndarray, impact) -> np.ndarray:
    """(n_nodes, 3) the scene's impact velocity at v0 = 1 m/s, admissible at the state x."""
    from . import sparse
    from .impact import least_energy_impact

    end = levels[-1]
    if config.impact_admissibility == "rigid_members":  # bars and base members rigid at x
        n = levels.shape[0] - 1
        k = np.arange(3)
        bars = np.stack([(3 * np.arange(n)[:, None] + k).ravel(), (3 * np.arange(1, n + 1)[:, None] + k).ravel()], 1)
        base = np.stack([(3 * np.arange(n + 1)[:, None] + k).ravel(), (3 * np.arange(n + 1)[:, None] + (k + 1) % 3).ravel()], 1)
        members = np.concatenate([bars, base])
        if sparse.use_dense(9 * n):
            return least_energy_impact(x, np.diag(net.node_mass), net.fixed, members, end, 1.0)
        return sparse.least_energy_impact(x, net.node_mass, net.fixed, members, end, 1.0)
    moved = Network(positions=x, node_mass=net.node_mass, fixed=net.fixed, bars=net.bars, bar_mass=net.bar_mass,
                    cables=net.cables, cable_EA=net.cable_EA, cable_rest_length=net.cable_rest_length,
                    cable_EA_compression=net.cable_EA_compression)
    return impact(moved, end, 1.0, config.impact_admissibility)
