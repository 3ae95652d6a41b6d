"""RATTLE with one warp per column: state in registers, no shared memory, no barriers.

Lane map (P levels per lane, a segment of G lanes per column, G a power of two, 32/G columns
per warp)::

    level   0      1 .. P     P+1 .. 2P    ...   n            (level 0 clamped)
    lane           0          1                  ceil(n/P)-1  (lanes past the column: padding)
    chain k        node (L, k) for L = 0..n: the bars (L-1, k) -> (L, k) form three chains

Lane ``l`` owns levels ``L = P l + 1 .. P l + P`` (their 3 nodes: u, v, a in registers) and the
prisms below them (``m = L - 1``: 3 bars, 3 cross cables) and the base members of its levels.
The level below its first (``P l``) belongs to lane ``l - 1`` and arrives by a shuffle; the
forces its cross cables put on that level go back by a shuffle.

Constraint solve: with flexible bases the Gram matrix G M^-1 G^T is three independent scalar
tridiagonal chains (``../shared/notes/warp-per-column.md``), one row per bar. Each chain is held
as a vec3 over the chains, so the three solves run side by side. A lane eliminates its first
P - 1 rows (Thomas, in registers) in terms of the neighbouring lanes' last rows, which leaves a
tridiagonal system of one row per lane (its last); parallel cyclic reduction over shuffles
solves that (log2 G levels), and the lane back-substitutes. The factor (Thomas pivots, spikes,
PCR coefficients) is kept in registers and reused by every Newton iteration and the velocity
projection. All control flow is warp-uniform (votes), so the shuffles always run converged.

Same RATTLE, Newton and failure semantics as :mod:`.fused` and the staged kernels; the cable
law and the bar residual are the shared bodies of :mod:`.common`.
"""

from collections.abc import Callable
from typing import NamedTuple

import warp as wp

from ...policy.lane_fit import WARP


class LaneFuncs(NamedTuple):
    """The lane pieces of one precision and lane map, by name (:func:`make_lane_funcs`)."""

    Nodes: type
    Ext: type
    XY: type
    Lv: type
    Rows: type
    Fac: type
    Pv: type
    vec: type
    ops: tuple
    """The segment primitives (:class:`.lane_ops.LaneOps`)."""
    bars: wp.Function
    extend: wp.Function
    impulse: wp.Function
    forces: wp.Function
    energies: wp.Function
    base_ends: wp.Function
    cross_ends: wp.Function
    accelerations: wp.Function
    gram: wp.Function
    factor: wp.Function
    solve: wp.Function
    residuals: wp.Function
    velocity_rows: wp.Function
    finite_nodes: wp.Function
    bar_check: wp.Function
    member_residuals: Callable
    """``member_residuals(ref, off)``: the residuals' body for other members (the rigid bases' links)."""


class MixedFuncs(NamedTuple):
    """The fp32-factor pieces of fp64 columns, by name (:func:`make_mixed_funcs`)."""

    factor: wp.Function
    solve: wp.Function
    probe: wp.Function
    refinements: wp.Function
    Fac: type


def make_lane_funcs(real, P: int, G: int, ops, cable_force, bar_residual, cable_energy2,
                    robust_check: bool = False):  # once per cached kernel
    """The lane pieces for scalar type ``real``, P levels per lane and G lanes per column, over the
    segment primitives ``ops`` (:func:`.lane_ops.make_lane_ops`) and the shared bodies ``cable_force``,
    ``bar_residual`` and ``cable_energy2`` (:mod:`.common`; passed in, so this module imports Warp only and the
    import chains stay short). ``robust_check``: the bar-length check in a form that CUDA's approximate
    square root and division (fast math) leave exact to a few ulps (:func:`bar_check`)."""
    vec = ops.vec
    NI = P - 1  # interior rows a lane eliminates itself
    LG = G.bit_length() - 1  # PCR levels
    # factor rows (each a vec3 over the chains): Thomas multipliers, inverse pivots, upper
    # couplings and the two spikes of the interior rows; the last row's couplings; PCR alpha,
    # gamma per level; the reduced pivot's inverse
    F_M, F_IP, F_E = 0, max(NI - 1, 0), max(NI - 1, 0) + NI
    F_S = F_E + max(NI - 1, 0)
    F_T = F_S + NI
    F_LW = F_T + NI  # l[P-1] (to the last interior row)
    F_EW = F_LW + 1  # e[P-1] (to the next lane's first row)
    F_PCR = F_EW + 1
    F_IB = F_PCR + 2 * LG
    NF = F_IB + 1
    Nodes = wp.types.matrix((3 * P, 3), real)  # row 3 q + k: node k of level P l + 1 + q (or bar k of prism q)
    Ext = wp.types.matrix((3 * P + 3, 3), real)  # the same with the level below first
    XY = wp.types.matrix((3 * P + 3, 2), real)  # reference x, y of levels P l .. P l + P
    Lv = wp.types.vector(P + 1, real)  # per level j = 0..P (inverse node masses: equal within a level)
    Rows = wp.types.matrix((P, 3), real)  # per bar row q: a vec3 over the chains
    Fac = wp.types.matrix((NF, 3), real)
    Pv = wp.types.vector(P, real)  # per prism of the lane
    zero = real(0.0)
    one = real(1.0)

    @wp.func(inline=True)
    def extend(U: Nodes, below: Nodes, lane: int, g: int, wl: int):
        """The lane's nodes with the level below first (lane l - 1's top level; level 0 is clamped)."""
        X = Ext()
        for k in range(3):
            w = ops.shfl_up3(below[3 * P - 3 + k], 1, g, wl)
            if lane == 0:
                w = vec()
            X[k] = w
        for r in range(3 * P):
            X[3 + r] = U[r]
        return X

    @wp.func(inline=True)
    def dref(xy: XY, hz: Pv, q: int, k: int):
        """Reference vector [m] of bar k of the lane's prism q: node (q+1, k) - (q, k)."""
        r0 = 3 * q + k
        return vec(xy[r0 + 3, 0] - xy[r0, 0], xy[r0 + 3, 1] - xy[r0, 1], hz[q])

    @wp.func(inline=True)
    def bars(U: Nodes, xy: XY, hz: Pv, lane: int, g: int, wl: int):
        """Bar vectors [m] of the lane's prisms at displacement U: row 3 q + k = node (q+1, k) - (q, k)."""
        X = extend(U, U, lane, g, wl)
        Bm = Nodes()
        for r in range(wp.static(3 * P)):  # unrolled: q = r // 3 and k = r % 3 are constants
            Bm[r] = dref(xy, hz, r // 3, r % 3) + X[r + 3] - X[r]
        return Bm

    @wp.func(inline=True)
    def node_rows(Bm: Nodes, s: Rows):
        """G^T s: for node (q+1, k) the vector s[q]_k b(q, k) - s[q+1]_k b(q+1, k), without the next
        lane's first bar (added by :func:`impulse`)."""
        out = Nodes()
        for q in range(P):
            for k in range(3):
                out[3 * q + k] = Bm[3 * q + k] * s[q, k]
        return out

    @wp.func(inline=True)
    def impulse(Bm: Nodes, lam: Rows, minv: Lv, lane: int, g: int, wl: int):
        """M^-1 G^T lam per node of the lane [m or m s-1 per unit of lam's scale]."""
        gq = node_rows(Bm, lam)
        d = Nodes()
        for k in range(3):
            nxt = ops.shfl_down3(gq[k], 1, g, wl)
            if lane == g - 1:
                nxt = vec()
            for q in range(P):
                up = nxt
                if q < P - 1:
                    up = gq[wp.min(3 * q + 3 + k, 3 * P - 1)]
                d[3 * q + k] = (gq[3 * q + k] - up) * minv[q + 1]
        return d

    @wp.func(inline=True)
    def base_parts(xy: XY, X: Ext, j: int, k: int):
        """(reference vector, displacement of its second node, of its first) [m] of base member k of
        the level at rows j .. j + 2 of X: node k to node (k + 1) % 3."""
        kn = (k + 1) % 3
        return vec(xy[j + kn, 0] - xy[j + k, 0], xy[j + kn, 1] - xy[j + k, 1], zero), X[j + kn], X[j + k]

    @wp.func(inline=True)
    def cross_parts(xy: XY, X: Ext, hz: Pv, hand: Pv, q: int, k: int):
        """(reference vector, displacement of its top node, of its bottom node) [m] of cross cable k of
        the lane's prism q: bottom node k to top node (k + 2) % 3 (right-handed) or (k + 1) % 3
        (left-handed)."""
        j = 3 * q + 3
        kr = (k + 2) % 3
        kl = (k + 1) % 3
        xt = xy[j + kl]
        ut = X[j + kl]
        if hand[q] > zero:
            xt = xy[j + kr]
            ut = X[j + kr]
        i = j - 3 + k
        return vec(xt[0] - xy[i, 0], xt[1] - xy[i, 1], hz[q]), ut, X[i]

    @wp.func(inline=True)
    def base_member(xy: XY, X: Ext, j: int, k: int):
        """Vector [m] of base member k of the level at rows j .. j + 2 of X (:func:`base_parts`)."""
        b0, un, uk = base_parts(xy, X, j, k)
        return b0 + un - uk

    @wp.func(inline=True)
    def cross_member(xy: XY, X: Ext, hz: Pv, hand: Pv, q: int, k: int):
        """Vector [m] of cross cable k of the lane's prism q (:func:`cross_parts`)."""
        b0, ut, ub = cross_parts(xy, X, hz, hand, q, k)
        return b0 + ut - ub

    @wp.func(inline=True)
    def base_ends(xy: XY, X: Ext, j: int, k: int):
        """(reference vector, displacement difference) [m] of base member k (:func:`base_parts`)."""
        b0, un, uk = base_parts(xy, X, j, k)
        return b0, un - uk

    @wp.func(inline=True)
    def cross_ends(xy: XY, X: Ext, hz: Pv, hand: Pv, q: int, k: int):
        """(reference vector, displacement difference) [m] of cross cable k (:func:`cross_parts`)."""
        b0, ut, ub = cross_parts(xy, X, hz, hand, q, k)
        return b0, ut - ub

    @wp.func(inline=True)
    def forces(U: Nodes, xy: XY, hz: Pv, hand: Pv, ex: Pv, cross: vec, base_ea: vec,
               rest: wp.array2d(dtype=real), wr: int, n: int, lane: int, g: int, wl: int):
        """Cable forces [N] on the lane's nodes: base members of its levels and cross cables of
        its prisms; what the cross cables of its first prism put on the level below goes to lane
        l - 1. ``cross`` = (EA, EA_c, -) of the cross cables, ``base_ea`` of the base members; rest
        lengths per member from the column's row ``rest[wr]`` (cross cables, then base members:
        contiguous, so the lanes' loads coalesce; they stay in L1 between steps)."""
        X = extend(U, U, lane, g, wl)
        f = Ext()
        for q in range(P):
            j = 3 * q + 3  # rows of level q + 1 in X, f, xy
            m = wp.min(P * lane + q, n - 1)  # the prism (clamped for padding lanes, whose forces are masked)
            for k in range(3):
                kn = (k + 1) % 3
                F = cable_force(base_member(xy, X, j, k), base_ea[0], base_ea[1], rest[wr, 3 * n + 3 * m + 3 + k])
                if ex[q] == zero:
                    F = vec()
                f[j + k] = f[j + k] + F
                f[j + kn] = f[j + kn] - F
            for k in range(3):
                kr = (k + 2) % 3
                kl = (k + 1) % 3
                i = j - 3 + k
                F = cable_force(cross_member(xy, X, hz, hand, q, k), cross[0], cross[1], rest[wr, 3 * m + k])
                if ex[q] == zero:
                    F = vec()
                f[i] = f[i] + F
                if hand[q] > zero:
                    f[j + kr] = f[j + kr] - F
                else:
                    f[j + kl] = f[j + kl] - F
        out = Nodes()
        for k in range(3):
            nxt = ops.shfl_down3(f[k], 1, g, wl)
            if lane == g - 1:
                nxt = vec()
            out[3 * P - 3 + k] = f[3 * P + k] + nxt
        for r in range(3 * P - 3):
            out[r] = f[3 + r]
        return out

    @wp.func(inline=True)
    def accelerations(f: Nodes, minv: Lv):
        a = Nodes()
        for q in range(P):
            for k in range(3):
                a[3 * q + k] = f[3 * q + k] * minv[q + 1]
        return a

    @wp.func(inline=True)
    def energies(X: Ext, V: Nodes, F: Nodes, xy: XY, hz: Pv, hand: Pv, ex: Pv, cross: vec, base_ea: vec,
                 rest: wp.array2d(dtype=real), wr: int, n: int, mass: Lv, lane: int, g: int, wl: int):
        """(2 T, 2 W, f . u) [J] of the column, on every lane of its segment: twice its kinetic energy
        (the lane's nodes, masses ``mass`` per level), twice its elastic energy (the cross cables of
        the lane's prisms and the base members of its levels; lane 0 also the clamped level 0's) and
        the work of the dead load F on the lane's nodes (the preload; 0 without), each lane's share
        summed by :func:`.lane_ops.segment_sum3`. X: the lane's displacements with the level below
        first (:func:`extend`)."""
        ke = zero
        ee = zero
        wk = zero
        for q in range(P):
            m = wp.min(P * lane + q, n - 1)
            if ex[q] != zero:
                for k in range(3):
                    vv = V[3 * q + k]
                    ke += mass[q + 1] * wp.dot(vv, vv)
                    wk += wp.dot(F[3 * q + k], X[3 * q + 3 + k])
                    ee += cable_energy2(base_member(xy, X, 3 * q + 3, k), base_ea[0], base_ea[1],
                                        rest[wr, 3 * n + 3 * m + 3 + k])
                    ee += cable_energy2(cross_member(xy, X, hz, hand, q, k), cross[0], cross[1], rest[wr, 3 * m + k])
        if lane == 0:
            for k in range(3):
                ee += cable_energy2(base_member(xy, X, 0, k), base_ea[0], base_ea[1], rest[wr, 3 * n + k])
        return ops.segment_sum3(vec(ke, ee, wk), g, wl)

    @wp.func(inline=True)
    def gram(Bm: Nodes, minv: Lv, ex: Pv, n: int, lane: int, g: int, wl: int):
        """Rows of the three chains' tridiagonal Gram matrices at the bars Bm: diagonal d, upper e
        (to the next row), lower l, each (P, 3), and the bars above the lane's (the next lane's first
        for its last prism). Padding rows past the column are identity."""
        bnext = Nodes()
        for k in range(3):
            bnext[3 * P - 3 + k] = ops.shfl_down3(Bm[k], 1, g, wl)
        for r in range(3 * P - 3):
            bnext[r] = Bm[r + 3]
        ex_next = zero  # the next lane's first prism exists
        if lane < g - 1 and P * lane + P + 1 <= n:
            ex_next = one
        d = Rows()
        e = Rows()
        for q in range(P):
            exn = ex_next
            if q < P - 1:
                exn = ex[wp.min(q + 1, P - 1)]
            for k in range(3):
                b = Bm[3 * q + k]
                dd = (minv[q] + minv[q + 1]) * wp.dot(b, b)
                ee = -minv[q + 1] * wp.dot(b, bnext[3 * q + k])
                if ex[q] == zero:
                    dd = one
                    ee = zero
                if exn == zero:
                    ee = zero
                d[q, k] = dd
                e[q, k] = ee
        l = Rows()
        up = ops.shfl_up3(e[P - 1], 1, g, wl)
        if lane == 0:
            up = vec()
        l[0] = up
        for q in range(1, P):
            l[q] = e[wp.max(q - 1, 0)]
        return d, e, l, bnext

    @wp.func(inline=True)
    def factor(d: Rows, e: Rows, l: Rows, lane: int, g: int, wl: int):
        """Factor the three chains (see the module docstring). Returns (factor, ok): ok = 0 if a
        pivot is not positive (the constraints are singular) on this lane."""
        Fm = Fac()
        ok = int(1)
        # interior rows: Thomas pivots, then the spikes s (to the lane below) and t (to the own last row)
        piv = Rows()
        for i in range(NI):
            p = d[i]
            if i > 0:
                m = wp.cw_div(l[i], piv[wp.max(i - 1, 0)])
                Fm[F_M + wp.max(i - 1, 0)] = m
                p = p - wp.cw_mul(m, e[wp.max(i - 1, 0)])
            piv[i] = p
            for k in range(3):
                if not (p[k] > zero):
                    ok = 0
            Fm[F_IP + i] = wp.cw_div(vec(one, one, one), p)
            if i < NI - 1:
                Fm[F_E + i] = e[i]
        zs = Rows()
        zt = Rows()
        for i in range(NI):
            if i == 0:
                zs[0] = l[0]
            else:
                zs[i] = -wp.cw_mul(Fm[F_M + wp.max(i - 1, 0)], zs[wp.max(i - 1, 0)])
            if i == NI - 1:
                zt[i] = e[i]
        for ii in range(NI):
            i = NI - 1 - ii
            si = wp.cw_mul(zs[i], Fm[F_IP + i])
            ti = wp.cw_mul(zt[i], Fm[F_IP + i])
            if i < NI - 1:
                si = si - wp.cw_mul(wp.cw_mul(e[i], Fm[F_S + i + 1]), Fm[F_IP + i])
                ti = ti - wp.cw_mul(wp.cw_mul(e[i], Fm[F_T + i + 1]), Fm[F_IP + i])
            Fm[F_S + i] = si
            Fm[F_T + i] = ti
        # the reduced row of the lane's last bar: a x(lane - 1) + b x + c x(lane + 1)
        lw = l[P - 1]
        ew = e[P - 1]
        a = lw
        b = d[P - 1]
        c = ew
        if NI > 0:
            s0n = ops.shfl_down3(Fm[F_S], 1, g, wl)
            t0n = ops.shfl_down3(Fm[F_T], 1, g, wl)
            a = -wp.cw_mul(lw, Fm[F_S + NI - 1])
            b = b - wp.cw_mul(lw, Fm[F_T + NI - 1]) - wp.cw_mul(ew, s0n)
            c = -wp.cw_mul(ew, t0n)
        Fm[F_LW] = lw
        Fm[F_EW] = ew
        # parallel cyclic reduction over the segment (each lane inverts its own pivot once a level)
        for j in range(LG):
            s = 1 << j
            rb = wp.cw_div(vec(one, one, one), b)
            if wp.static(G > WARP):  # k warps: up and down of a value from one barrier
                au, ad = ops.shfl_updown3(a, s, g, wl)
                ru, rd = ops.shfl_updown3(rb, s, g, wl)
                cu, cd = ops.shfl_updown3(c, s, g, wl)
            else:  # one warp: the shuffles in the order the one-warp kernel was measured with
                au = ops.shfl_up3(a, s, g, wl)
                ru = ops.shfl_up3(rb, s, g, wl)
                cu = ops.shfl_up3(c, s, g, wl)
                ad = ops.shfl_down3(a, s, g, wl)
                rd = ops.shfl_down3(rb, s, g, wl)
                cd = ops.shfl_down3(c, s, g, wl)
            al = -wp.cw_mul(a, ru)
            ga = -wp.cw_mul(c, rd)
            Fm[F_PCR + 2 * j] = al
            Fm[F_PCR + 2 * j + 1] = ga
            a = wp.cw_mul(al, au)
            c = wp.cw_mul(ga, cd)
            b = b + wp.cw_mul(al, cu) + wp.cw_mul(ga, ad)
        for k in range(3):
            if not (b[k] > zero):
                ok = 0
        Fm[F_IB] = wp.cw_div(vec(one, one, one), b)
        return Fm, ok

    @wp.func(inline=True)
    def solve(Fm: Fac, r: Rows, lane: int, g: int, wl: int):
        """x with A x = r for the three chains (rows (P, 3)), with the stored factor."""
        y = Rows()
        z = Rows()
        for i in range(NI):
            zi = r[i]
            if i > 0:
                zi = zi - wp.cw_mul(Fm[F_M + wp.max(i - 1, 0)], z[wp.max(i - 1, 0)])
            z[i] = zi
        for ii in range(NI):
            i = NI - 1 - ii
            yi = z[i]
            if i < NI - 1:
                yi = yi - wp.cw_mul(Fm[F_E + i], y[i + 1])
            y[i] = wp.cw_mul(yi, Fm[F_IP + i])
        rho = r[P - 1]
        if NI > 0:
            y0n = ops.shfl_down3(y[0], 1, g, wl)
            rho = rho - wp.cw_mul(Fm[F_LW], y[NI - 1]) - wp.cw_mul(Fm[F_EW], y0n)
        for j in range(LG):
            s = 1 << j
            ru, rd = ops.shfl_updown3(rho, s, g, wl)
            rho = rho + wp.cw_mul(Fm[F_PCR + 2 * j], ru) + wp.cw_mul(Fm[F_PCR + 2 * j + 1], rd)
        xk = wp.cw_mul(rho, Fm[F_IB])
        x = Rows()
        x[P - 1] = xk
        if NI > 0:
            xm = ops.shfl_up3(xk, 1, g, wl)
            if lane == 0:
                xm = vec()
            for i in range(NI):
                x[i] = y[i] - wp.cw_mul(Fm[F_S + i], xm) - wp.cw_mul(Fm[F_T + i], xk)
        return x

    @wp.func(inline=True)
    def bar_check(b: vec, b0: vec):
        """(r, e) of :func:`.common.bar_residual` for a member b of reference vector b0 [m]. With
        ``robust_check`` r = (|b|^2 - |b0|^2)/2 needs no square root, and e = |2 r| / (L (|b| + L))
        has its square roots only in a factor: an approximate sqrt (2 ulp) there moves e by ~1e-7 of
        itself, where in |b| - L it would move e by ~2e-7 absolute, the fp32 tolerance."""
        if wp.static(robust_check):
            bb = wp.dot(b, b)
            LL = wp.dot(b0, b0)
            L = wp.sqrt(LL)
            return real(0.5) * (bb - LL), wp.abs(bb - LL) / (L * (wp.sqrt(bb) + L))
        return bar_residual(b, wp.length(b0))

    def member_residuals(ref, off):
        """The Newton residuals of the lane's members, one body for the bars (:func:`residuals`) and
        the rigid bases' ring links (:func:`.lane_rigid.make_rigid_funcs`): ``rows(M, xy, hz, ex, rig,
        e0)`` = (r, e), r[q, k] = (|m|^2 - L^2)/2 [m2] of member row 3 q + k of M against its reference
        vector ``ref(xy, hz, q, k)`` (L = its length, recomputed: fewer live registers), zero where
        ``off(ex[q], rig)``; e the largest relative length error, from e0 on (NaN wins)."""

        @wp.func(inline=True)
        def rows(Mm: Nodes, xy: XY, hz: Pv, ex: Pv, rig: real, e0: real):
            r = Rows()
            emax = e0
            for q in range(P):
                for k in range(3):
                    rr, ee = bar_check(Mm[3 * q + k], ref(xy, hz, q, k))
                    if off(ex[q], rig):
                        rr = zero
                        ee = zero
                    r[q, k] = rr
                    if wp.isnan(ee) or ee > emax:
                        emax = ee
            return r, emax

        return rows

    @wp.func(inline=True)
    def bar_off(ex: real, rig: real):
        """A bar's row is off where its prism is padding (ex = 0)."""
        return ex == zero

    residuals = member_residuals(dref, bar_off)
    """(r, e) of the bars: ``residuals(Bm, xy, hz, ex, rig, zero)`` (rig unused)."""

    @wp.func(inline=True)
    def velocity_rows(Bm: Nodes, V: Nodes, ex: Pv, lane: int, g: int, wl: int):
        """G V per bar: b . (v_top - v_bottom) [m2 s-1]."""
        X = extend(V, V, lane, g, wl)
        r = Rows()
        for q in range(P):
            for k in range(3):
                rr = wp.dot(Bm[3 * q + k], X[3 * q + 3 + k] - X[3 * q + k])
                if ex[q] == zero:
                    rr = zero
                r[q, k] = rr
        return r

    @wp.func(inline=True)
    def finite_nodes(V: Nodes):
        ok = int(1)
        for r in range(3 * P):
            for c in range(3):
                if not wp.isfinite(V[r, c]):
                    ok = 0
        return ok

    return LaneFuncs(Nodes=Nodes, Ext=Ext, XY=XY, Lv=Lv, Rows=Rows, Fac=Fac, Pv=Pv, vec=vec, ops=ops, bars=bars,
                     extend=extend, impulse=impulse, forces=forces, energies=energies, base_ends=base_ends,
                     cross_ends=cross_ends, accelerations=accelerations, gram=gram, factor=factor, solve=solve,
                     residuals=residuals, velocity_rows=velocity_rows, finite_nodes=finite_nodes, bar_check=bar_check,
                     member_residuals=member_residuals)


def make_mixed_funcs(real, P: int, f, f32, fr=None, fr32=None):  # once per cached kernel
    """fp64 columns with an fp32 factor: the Gram matrix formed and factored in fp32 (half the
    registers of the factor, fp32 arithmetic), each solve refined against fp64 residuals
    r - A x, A x = G M^-1 G^T x formed from the fp64 bars (and links) as :func:`impulse` then
    :func:`velocity_rows` do. ``f``, ``fr``: the fp64 pieces (``fr``: rigid bases, or None);
    ``f32``, ``fr32``: the same in fp32. Iterative refinement with an fp32 factor gains a factor
    ~ kappa u32 per pass (kappa: the Gram matrix's condition number, u32 = 2^-24) down to the fp64
    solve's own error; :func:`probe` measures that factor once per column (at its first factor), and
    :func:`refinements` turns it into a count."""
    r32 = wp.float32
    Nodes, Rows, Lv, Pv = f.Nodes, f.Rows, f.Lv, f.Pv
    Nodes32, Rows32, Lv32, Pv32 = f32.Nodes, f32.Rows, f32.Lv, f32.Pv
    ops = f.ops
    rigid = fr is not None
    u64_u32 = real(2.0 ** -29)  # u64 / u32

    # from one precision to the other through the vector and matrix types' converting constructors,
    # Rows32(x), Rows(x), ...: each element cast, as r32(x[q, k]) is
    @wp.func(inline=True)
    def apply(Bm: Nodes, Cm: Nodes, beta: Rows, mu: Rows, minv: Lv, ex: Pv, rig: real, lane: int, g: int, wl: int):
        """A [beta; mu] in fp64: the bars' rows and the links' rows (zero without rigid bases)."""
        d = f.impulse(Bm, beta, minv, lane, g, wl)
        rm = Rows()
        if wp.static(rigid):
            d = fr.link_impulse(d, Cm, mu, minv)
            rm = fr.link_velocity_rows(Cm, d, ex, rig)
        return f.velocity_rows(Bm, d, ex, lane, g, wl), rm

    if rigid:
        Fac32 = fr32.RFac

        @wp.func(inline=True)
        def factor(Bm: Nodes, Cm: Nodes, minv: Lv, ex: Pv, rig: real, n: int, lane: int, g: int, wl: int):
            return fr32.factor(Nodes32(Bm), Nodes32(Cm), Lv32(minv), Pv32(ex), r32(rig), n, lane, g, wl)

        @wp.func(inline=True)
        def solve32(Fm: Fac32, rb: Rows, rm: Rows, lane: int, g: int, wl: int):
            b, m = fr32.solve(Fm, Rows32(rb), Rows32(rm), lane, g, wl)
            return Rows(b), Rows(m)
    else:
        Fac32 = f32.Fac

        @wp.func(inline=True)
        def factor(Bm: Nodes, Cm: Nodes, minv: Lv, ex: Pv, rig: real, n: int, lane: int, g: int, wl: int):
            d, e, l, bnext = f32.gram(Nodes32(Bm), Lv32(minv), Pv32(ex), n, lane, g, wl)
            return f32.factor(d, e, l, lane, g, wl)

        @wp.func(inline=True)
        def solve32(Fm: Fac32, rb: Rows, rm: Rows, lane: int, g: int, wl: int):
            return Rows(f32.solve(Fm, Rows32(rb), lane, g, wl)), Rows()

    @wp.func(inline=True)
    def solve(Fm: Fac32, rb: Rows, rm: Rows, Bm: Nodes, Cm: Nodes, minv: Lv, ex: Pv, rig: real, passes: int,
              own: int, lane: int, g: int, wl: int):
        """(beta, mu) with A [beta; mu] = [rb; rm]: the fp32 solve, then the column's ``own``
        refinements (the loop runs the warp's most, ``passes``: the solves shuffle), A at the
        factor's bars Bm and links Cm."""
        beta, mu = solve32(Fm, rb, rm, lane, g, wl)
        for t in range(passes):
            ab, am = apply(Bm, Cm, beta, mu, minv, ex, rig, lane, g, wl)
            db, dm = solve32(Fm, rb - ab, rm - am, lane, g, wl)
            if t < own:
                beta = beta + db
                mu = mu + dm
        return beta, mu

    @wp.func(inline=True)
    def probe(Fm: Fac32, Bm: Nodes, Cm: Nodes, minv: Lv, ex: Pv, rig: real, alive: int, lane: int, g: int, wl: int):
        """The relative error of one fp32 solve, max over the column: for x of entries +-1 (signs
        mixed along each chain and across lanes, so that A x has its large eigencomponents), the
        solve of A x formed in fp64. It estimates kappa u32, the factor each refinement gains."""
        xb = Rows()
        xm = Rows()
        for q in range(P):
            for k in range(3):
                s = real(1.0)
                if ((lane * P + q) * 7 + k * 3 + (lane >> 1)) % 2 == 1:
                    s = real(-1.0)
                if ex[q] != real(0.0):
                    xb[q, k] = s
                    if wp.static(rigid):
                        if rig != real(0.0):
                            xm[q, k] = -s
        ab, am = apply(Bm, Cm, xb, xm, minv, ex, rig, lane, g, wl)
        yb, ym = solve32(Fm, ab, am, lane, g, wl)
        err = real(0.0)
        for q in range(P):
            for k in range(3):
                eb = wp.abs(yb[q, k] - xb[q, k])
                em = wp.abs(ym[q, k] - xm[q, k])
                if not (eb <= err):  # NaN wins
                    err = eb
                if not (em <= err):
                    err = em
        if alive == 0:  # (a frozen column's state may be anything)
            err = real(0.0)
        return ops.segment_max(err, g, wl)

    @wp.func(inline=True)
    def refinements(eta: real, target: real, most: int):
        """Passes k so that eta^(k + 1) <= target (eta: :func:`probe`'s error; target raised to the
        fp64 solve's own error, eta u64 / u32), at most ``most`` (also where eta >= 1 or NaN)."""
        t = wp.max(target, eta * u64_u32)
        k = int(0)
        e = eta
        while not (e <= t) and k < most:
            e = e * eta
            k += 1
        return k

    return MixedFuncs(factor=factor, solve=solve, probe=probe, refinements=refinements, Fac=Fac32)
