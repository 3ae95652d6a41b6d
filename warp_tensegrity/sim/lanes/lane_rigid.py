"""Rigid bases in the one-warp-per-column step: the ring links of each level as constraints.

The links of level L couple the three bar chains there, so the Gram matrix of a column with
rigid bases is block tridiagonal (a level's 3 bars and 3 links). Each lane first eliminates the
links of its own levels: the links of level L touch only the bars below and above it, so their
3 x 3 block W_L^-1 = (G_l M^-1 G_l^T)^-1 folds into the bars' system as a Schur complement

    D'_q = D_q - Kb_q^T W_q Kb_q - Ka_{q-1}^T W_{q-1} Ka_{q-1},   E'_q = E_q - Kb_q^T W_q Ka_q

(Kb: links against the bars below them, Ka: against the bars above). What is left is a block
tridiagonal system with dense 3 x 3 blocks, one block row per prism, solved the way the flexible
chains are (:mod:`.lane_funcs`): the lane eliminates its first row (block Thomas), then block
parallel cyclic reduction over shuffles, then back substitution; the links' multipliers follow
from mu_q = W_q (r_mu - Kb_q beta_q - Ka_q beta_{q+1}). Columns of the batch without rigid bases
have inactive links (identity blocks, no coupling): the same code gives their flexible solve.

Up to 2 levels per lane (64 prisms). The factor (about 200 reals a lane) lives in a matrix the
compiler keeps in local memory, read back by each solve. Imports Warp only.
"""

from typing import NamedTuple

import warp as wp

from ...policy.lane_fit import MAX_RIGID_LEVELS_PER_LANE, WARP


class RigidFuncs(NamedTuple):
    """The rigid bases' link pieces, by name (:func:`make_rigid_funcs`)."""

    links: wp.Function
    link_residuals: wp.Function
    link_velocity_rows: wp.Function
    link_impulse: wp.Function
    factor: wp.Function
    solve: wp.Function
    RFac: type


def make_rigid_funcs(real, P: int, G: int, ops, f):  # once per cached kernel
    """Link pieces for P (1 or 2) levels per lane, G lanes per column, over the segment
    primitives ``ops`` and the flexible pieces ``f`` (:func:`.lane_funcs.make_lane_funcs`)."""
    if P > MAX_RIGID_LEVELS_PER_LANE:
        raise ValueError(f"rigid bases take at most {MAX_RIGID_LEVELS_PER_LANE} levels per lane (P = {P})")
    vec = ops.vec
    mat3 = wp.types.matrix((3, 3), real)
    LG = G.bit_length() - 1
    # blocks of the factor: W (P), Kb (P), Ka (P), the first row's inverse pivot and spikes S, T
    # and the last row's couplings L, U (P = 2), PCR alpha, gamma per level, the reduced pivot's inverse
    B_W, B_KB, B_KA = 0, P, 2 * P
    B_PI = 3 * P
    B_S, B_T, B_L, B_U = B_PI + 1, B_PI + 2, B_PI + 3, B_PI + 4
    B_PCR = B_PI + 5
    B_BI = B_PCR + 2 * LG
    NB = B_BI + 1
    RFac = wp.types.matrix((3 * NB, 3), real)
    Nodes, XY, Lv, Rows, Pv = f.Nodes, f.XY, f.Lv, f.Rows, f.Pv
    zero = real(0.0)
    one = real(1.0)

    @wp.func(inline=True)
    def get(M: RFac, i: int):
        return wp.matrix_from_rows(M[3 * i], M[3 * i + 1], M[3 * i + 2])

    @wp.func(inline=True)
    def put(M: RFac, i: int, b: mat3):
        M[3 * i] = b[0]
        M[3 * i + 1] = b[1]
        M[3 * i + 2] = b[2]
        return M

    @wp.func(inline=True)
    def up3(b: mat3, s: int, g: int, wl: int):
        return wp.matrix_from_rows(ops.shfl_up3(b[0], s, g, wl), ops.shfl_up3(b[1], s, g, wl),
                                   ops.shfl_up3(b[2], s, g, wl))

    @wp.func(inline=True)
    def down3(b: mat3, s: int, g: int, wl: int):
        return wp.matrix_from_rows(ops.shfl_down3(b[0], s, g, wl), ops.shfl_down3(b[1], s, g, wl),
                                   ops.shfl_down3(b[2], s, g, wl))

    @wp.func(inline=True)
    def updown3(b: mat3, s: int, g: int, wl: int):
        """(:func:`up3`, :func:`down3`) (k warps per column: three exchanges, one barrier each)."""
        u0, d0 = ops.shfl_updown3(b[0], s, g, wl)
        u1, d1 = ops.shfl_updown3(b[1], s, g, wl)
        u2, d2 = ops.shfl_updown3(b[2], s, g, wl)
        return wp.matrix_from_rows(u0, u1, u2), wp.matrix_from_rows(d0, d1, d2)

    @wp.func(inline=True)
    def spd_inverse(a: mat3):
        """(a^-1, ok): ok = 0 unless a is positive definite (Sylvester: leading minors > 0)."""
        m2 = a[0, 0] * a[1, 1] - a[0, 1] * a[1, 0]
        d3 = wp.determinant(a)
        ok = int(1)
        if not (a[0, 0] > zero and m2 > zero and d3 > zero):
            ok = 0
        return wp.inverse(a), ok

    @wp.func(inline=True)
    def links(U: Nodes, xy: XY, lane: int, g: int, wl: int):
        """Link vectors [m] of the lane's levels at displacement U: row 3 q + k = node (q+1, k+1) - (q+1, k)."""
        Cm = Nodes()
        for q in range(P):
            for k in range(3):
                r0 = 3 * q + k
                r1 = 3 * q + (k + 1) % 3
                Cm[r0] = vec(xy[r1 + 3, 0] - xy[r0 + 3, 0], xy[r1 + 3, 1] - xy[r0 + 3, 1], zero) + U[r1] - U[r0]
        return Cm

    @wp.func(inline=True)
    def link_ref(xy: XY, hz: Pv, q: int, k: int):
        """Reference vector [m] of link k of the lane's level q + 1 (hz unused: the bars' signature)."""
        r0 = 3 * q + 3 + k
        r1 = 3 * q + 3 + (k + 1) % 3
        return vec(xy[r1, 0] - xy[r0, 0], xy[r1, 1] - xy[r0, 1], zero)

    @wp.func(inline=True)
    def link_off(ex: real, rig: real):
        """A link's row is off at a padding level (ex = 0) and in a column without rigid bases."""
        return ex == zero or rig == zero

    link_residuals = f.member_residuals(link_ref, link_off)
    """(r, e) of the links, e from the bars' on: ``link_residuals(Cm, xy, hz, ex, rig, e_bars)``."""

    @wp.func(inline=True)
    def link_velocity_rows(Cm: Nodes, V: Nodes, ex: Pv, rig: real):
        r = Rows()
        for q in range(P):
            for k in range(3):
                rr = wp.dot(Cm[3 * q + k], V[3 * q + (k + 1) % 3] - V[3 * q + k])
                if ex[q] == zero or rig == zero:
                    rr = zero
                r[q, k] = rr
        return r

    @wp.func(inline=True)
    def link_impulse(d: Nodes, Cm: Nodes, mu: Rows, minv: Lv):
        """d += M^-1 G_l^T mu: node k of a level gets -mu_k c_k + mu_{k-1} c_{k-1}."""
        for q in range(P):
            for k in range(3):
                km = (k + 2) % 3
                d[3 * q + k] = d[3 * q + k] + (Cm[3 * q + km] * mu[q, km] - Cm[3 * q + k] * mu[q, k]) * minv[q + 1]
        return d

    @wp.func(inline=True)
    def couplings(Bm: Nodes, bnext: Nodes, Cm: Nodes, m: real, q: int):
        """(Dll, Kb, Ka) of the links at the top of the lane's prism q (rows: links; Kb columns: the
        bars below them, Ka columns: the bars above them), for inverse node mass m of that level."""
        Dll = mat3()
        Kb = mat3()
        Ka = mat3()
        for a in range(3):
            for b in range(3):
                cc = wp.dot(Cm[3 * q + a], Cm[3 * q + b])
                if a == b:
                    Dll[a, b] = real(2.0) * m * cc
                else:
                    Dll[a, b] = -m * cc
        for k in range(3):
            km = (k + 2) % 3  # the link whose second node is node k
            bb = Bm[3 * q + k]
            ba = bnext[3 * q + k]
            Kb[k, k] = -m * wp.dot(bb, Cm[3 * q + k])
            Kb[km, k] = m * wp.dot(bb, Cm[3 * q + km])
            Ka[k, k] = m * wp.dot(ba, Cm[3 * q + k])
            Ka[km, k] = -m * wp.dot(ba, Cm[3 * q + km])
        return Dll, Kb, Ka

    @wp.func(inline=True)
    def factor(Bm: Nodes, Cm: Nodes, minv: Lv, ex: Pv, rig: real, n: int, lane: int, g: int, wl: int):
        """Factor of the column's bars and links at (Bm, Cm). Returns (factor, ok)."""
        d, e, l, bnext = f.gram(Bm, minv, ex, n, lane, g, wl)
        ex_next = zero
        if lane < g - 1 and P * lane + P + 1 <= n:
            ex_next = one
        Fm = RFac()
        ok = int(1)
        D = mat3()
        Dq = mat3()
        E = mat3()
        carry = mat3()  # Ka^T W Ka of the lane's last level: the next lane's first diagonal block
        for q in range(P):
            Dll, Kb, Ka = couplings(Bm, bnext, Cm, minv[q + 1], q)
            exn = ex_next
            if q < P - 1:
                exn = ex[wp.min(q + 1, P - 1)]
            if ex[q] == zero or rig == zero:
                Dll = wp.identity(3, real)
                Kb = mat3()
                Ka = mat3()
            if exn == zero:
                Ka = mat3()
            W, okw = spd_inverse(Dll)
            ok = wp.min(ok, okw)
            Fm = put(Fm, B_W + q, W)
            Fm = put(Fm, B_KB + q, Kb)
            Fm = put(Fm, B_KA + q, Ka)
            Dq = wp.diag(d[q]) - wp.transpose(Kb) @ W @ Kb
            if q == 0:
                D = Dq
            E = wp.diag(e[q]) - wp.transpose(Kb) @ W @ Ka
            carry = wp.transpose(Ka) @ W @ Ka
            if P == 2 and q == 0:
                Fm = put(Fm, B_U, E)  # U_0 for now; replaced below
                Fm = put(Fm, B_L, carry)  # Ka_0^T W Ka_0, added to row 1
        # rows of the lane: D0 (+ the lane below's carry), U0 = E0 [, D1 = Dq + carry0, L1 = E0^T, U1 = E1]
        below = up3(carry, 1, g, wl)
        Lb = up3(wp.transpose(E), 1, g, wl)  # the lower coupling of row 0: the lane below's last upper^T
        if lane == 0:
            below = mat3()
            Lb = mat3()
        D = D - below
        A = Lb
        B = D
        C = E
        if P == 2:
            U0 = get(Fm, B_U)
            D1 = Dq - get(Fm, B_L)
            pinv, okp = spd_inverse(D)
            ok = wp.min(ok, okp)
            S = pinv @ Lb
            T = pinv @ U0
            L1 = wp.transpose(U0)
            Fm = put(Fm, B_PI, pinv)
            Fm = put(Fm, B_S, S)
            Fm = put(Fm, B_T, T)
            Fm = put(Fm, B_L, L1)
            Fm = put(Fm, B_U, E)
            Sn = down3(S, 1, g, wl)
            Tn = down3(T, 1, g, wl)
            A = -(L1 @ S)
            B = D1 - L1 @ T - E @ Sn
            C = -(E @ Tn)
        for j in range(LG):
            s = 1 << j
            Bi, okb = spd_inverse(B)
            if wp.static(G > WARP):  # k warps: up and down of a block from one barrier
                Au, Ad = updown3(A, s, g, wl)
                Biu, Bid = updown3(Bi, s, g, wl)
                Cu, Cd = updown3(C, s, g, wl)
            else:  # one warp: the shuffles in the order the one-warp kernel was measured with
                Au = up3(A, s, g, wl)
                Biu = up3(Bi, s, g, wl)
                Cu = up3(C, s, g, wl)
                Ad = down3(A, s, g, wl)
                Bid = down3(Bi, s, g, wl)
                Cd = down3(C, s, g, wl)
            al = -(A @ Biu)
            ga = -(C @ Bid)
            Fm = put(Fm, B_PCR + 2 * j, al)
            Fm = put(Fm, B_PCR + 2 * j + 1, ga)
            A = al @ Au
            C = ga @ Cd
            B = B + al @ Cu + ga @ Ad
        Bi, okb = spd_inverse(B)
        ok = wp.min(ok, okb)
        Fm = put(Fm, B_BI, Bi)
        return Fm, ok

    @wp.func(inline=True)
    def solve(Fm: RFac, rb: Rows, rm: Rows, lane: int, g: int, wl: int):
        """(beta, mu): bars' and links' multipliers for right-hand sides rb, rm, with the stored factor."""
        carry = vec()
        rr = Rows()
        for q in range(P):
            wr = get(Fm, B_W + q) @ rm[q]
            rq = rb[q] - wp.transpose(get(Fm, B_KB + q)) @ wr
            if q > 0:
                rq = rq - carry
            rr[q] = rq
            carry = wp.transpose(get(Fm, B_KA + q)) @ wr
        below = ops.shfl_up3(carry, 1, g, wl)
        if lane == 0:
            below = vec()
        rr[0] = rr[0] - below
        rho = rr[P - 1]
        y0 = vec()
        if P == 2:
            y0 = get(Fm, B_PI) @ rr[0]
            y0n = ops.shfl_down3(y0, 1, g, wl)
            rho = rho - get(Fm, B_L) @ y0 - get(Fm, B_U) @ y0n
        for j in range(LG):
            s = 1 << j
            ru, rd = ops.shfl_updown3(rho, s, g, wl)
            rho = rho + get(Fm, B_PCR + 2 * j) @ ru + get(Fm, B_PCR + 2 * j + 1) @ rd
        xk = get(Fm, B_BI) @ rho
        beta = Rows()
        beta[P - 1] = xk
        if P == 2:
            xm = ops.shfl_up3(xk, 1, g, wl)
            if lane == 0:
                xm = vec()
            beta[0] = y0 - get(Fm, B_S) @ xm - get(Fm, B_T) @ xk
        bn = ops.shfl_down3(beta[0], 1, g, wl)  # the next lane's first bar row (Ka is 0 where there is none)
        mu = Rows()
        for q in range(P):
            above = bn
            if q < P - 1:
                above = beta[wp.min(q + 1, P - 1)]
            mu[q] = get(Fm, B_W + q) @ (rm[q] - get(Fm, B_KB + q) @ beta[q] - get(Fm, B_KA + q) @ above)
        return beta, mu

    return RigidFuncs(links=links, link_residuals=link_residuals, link_velocity_rows=link_velocity_rows,
                      link_impulse=link_impulse, factor=factor, solve=solve, RFac=RFac)
