"""Cooperative in-block band solves: serial Cholesky on lane 0 and block cyclic reduction across
lanes, for the fused step (:mod:`.fused`, a thread block per column), with the block primitives
they stand on (the barrier :func:`block_sync`, Warp's tile barrier ``__syncthreads()``, and
block-shared buffers) and the size of a column's solver rows.

With level-by-level constraint order the Gram matrix A = G M^-1 G^T is banded with half-bandwidth
BW (3 FB, 6 RB), so rows grouped in chunks of S = max(BW, 1) make it block tridiagonal with S x S
blocks, for any banded network. It is solved by block cyclic reduction (CR): level s = 1, 2, 4, ...
eliminates the blocks i = s, 3s, 5s, ... (one lane each: the SPD block inverse by Gauss-Jordan,
whose pivots are the Cholesky pivots, and W- = D^-1 E_i, W+ = D^-1 E_{i+s}^T), then every kept
block j = 0, 2s, ... forms its Schur complement. CR is block Cholesky of the odd-even permuted SPD
matrix, so it needs no pivoting; the stored reduction (D^-1, W-, W+ per block) is reused by every
Newton iteration and the velocity projection: a solve is log2(nb) forward levels, the root, and
log2(nb) backward levels, each one S x S mat-vec per lane.

The serial solver's lane 0 runs the staged threads' banded Cholesky (:func:`.common.make_band_funcs`,
the same bodies; :mod:`.fused` calls it) while the other lanes wait at the barrier; here only its
storage (:func:`band_reals`). Imports Warp only, no package module (import chains stay short:
tests/test_layout.py).
"""

import functools
from typing import NamedTuple

import warp as wp


@wp.func_native("WP_TILE_SYNC();")
def block_sync(): ...


def block_size(bandwidth: int) -> int:
    """S: rows per block of the block-tridiagonal Gram matrix."""
    return max(int(bandwidth), 1)


SOLVERS = ("cr", "serial")


def band_reals(n_constraints: int, bandwidth: int, solver: str = "cr") -> int:
    """Reals of the serial solver's band (nc (bw+1)) ahead of its solver rows; 0 for CR."""
    return max(n_constraints, 1) * (int(bandwidth) + 1) if solver == "serial" else 0


def solver_reals(n_constraints: int, bandwidth: int, block_dim: int, solver: str = "cr") -> int:
    """Reals of one column's solver rows. CR: multipliers (nb S), then D^-1, E (two buffers), W-,
    W+ (nb S^2 each), then one reduction slot per lane. Serial: the band (:func:`band_reals`), then
    the multipliers (nc) and the reduction slots."""
    if solver not in SOLVERS:
        raise ValueError(f"solver = {solver!r}: expected one of {SOLVERS}")
    if solver == "serial":
        return band_reals(n_constraints, bandwidth, solver) + max(n_constraints, 1) + block_dim
    S = block_size(bandwidth)
    nb = max(-(-n_constraints // S), 1)
    return nb * S * (1 + 5 * S) + block_dim


def shared_snippet(ctype: str, n: int, name: str) -> str:
    """Native body returning the address of a block-shared buffer of n ``ctype`` (``static`` on
    the CPU: blocks run one after another there, and emulated lanes share it)."""
    return f"""
#if defined(__CUDA_ARCH__)
    __shared__ {ctype} {name}[{max(n, 1)}];
#else
    static {ctype} {name}[{max(n, 1)}];
#endif
    return (uint64_t)(&{name}[0]);
"""


@functools.cache
def make_block_max(real):
    """The lanes' reduction, through one slot per lane at x[red : red + bd, 0] (after the solver rows)."""

    @wp.func
    def block_max(x: wp.array2d(dtype=real), red: int, v: real, lane: int, bd: int):
        """Max of v over the block's lanes (NaN wins), the same on every lane."""
        x[red + lane, 0] = v
        block_sync()
        m = x[red, 0]
        for t in range(1, bd):
            y = x[red + t, 0]
            if wp.isnan(y) or y > m:
                m = y
        block_sync()
        return m

    return block_max


class BlockFuncs(NamedTuple):
    """Small dense blocks of the cyclic reduction: types and bodies."""

    mat: type
    vec: type
    mload: wp.Function
    mstore: wp.Function
    vload: wp.Function
    vstore: wp.Function
    spd_inverse: wp.Function
    col: wp.Function
    col_store: wp.Function
    mv: wp.Function
    mtv: wp.Function


@functools.cache
def make_block_funcs(real, S: int):
    """S x S block helpers over a column's solver rows x (row-major blocks at an offset):
    loads and stores of blocks, vectors and columns, streamed mat-vecs, the SPD block inverse."""
    mat = wp.types.matrix((S, S), real)
    vecS = wp.types.vector(S, real)

    @wp.func
    def mload(x: wp.array2d(dtype=real), off: int):
        m = mat()
        for r in range(S):
            for c in range(S):
                m[r, c] = x[off + r * S + c, 0]
        return m

    @wp.func
    def mstore(x: wp.array2d(dtype=real), off: int, m: mat):
        for r in range(S):
            for c in range(S):
                x[off + r * S + c, 0] = m[r, c]

    @wp.func
    def vload(x: wp.array2d(dtype=real), off: int):
        b = vecS()
        for r in range(S):
            b[r] = x[off + r, 0]
        return b

    @wp.func
    def vstore(x: wp.array2d(dtype=real), off: int, b: vecS):
        for r in range(S):
            x[off + r, 0] = b[r]

    @wp.func
    def spd_inverse(a: mat):
        """In-place Gauss-Jordan inverse of an SPD block; its pivots are the squared Cholesky
        pivots, so ok = 0 exactly when a pivot is not positive (not positive definite)."""
        ok = int(1)
        for k in range(S):
            p = a[k, k]
            if not (p > real(0.0)):
                ok = 0
                p = real(1.0)
            ip = real(1.0) / p
            for j in range(S):
                if j != k:
                    a[k, j] = a[k, j] * ip
            a[k, k] = ip
            for i in range(S):
                if i != k:
                    f = a[i, k]
                    for j in range(S):
                        if j != k:
                            a[i, j] = a[i, j] - f * a[k, j]
                    a[i, k] = -f * ip
        return a, ok

    @wp.func
    def col(x: wp.array2d(dtype=real), off: int, c: int):
        """Column c of the block at off."""
        v = vecS()
        for r in range(S):
            v[r] = x[off + r * S + c, 0]
        return v

    @wp.func
    def col_store(x: wp.array2d(dtype=real), off: int, c: int, v: vecS):
        for r in range(S):
            x[off + r * S + c, 0] = v[r]

    @wp.func
    def mv(x: wp.array2d(dtype=real), off: int, v: vecS):
        """(block at off) v, the block streamed from x row by row."""
        y = vecS()
        for r in range(S):
            t = real(0.0)
            for k in range(S):
                t += x[off + r * S + k, 0] * v[k]
            y[r] = t
        return y

    @wp.func
    def mtv(x: wp.array2d(dtype=real), off: int, v: vecS):
        """(block at off)^T v."""
        y = vecS()
        for k in range(S):
            for r in range(S):
                y[r] += x[off + k * S + r, 0] * v[k]
        return y

    return BlockFuncs(mat=mat, vec=vecS, mload=mload, mstore=mstore, vload=vload, vstore=vstore,
                      spd_inverse=spd_inverse, col=col, col_store=col_store, mv=mv, mtv=mtv)


class CRFuncs(NamedTuple):
    """The block cyclic reduction's factor and solve."""

    cr_factor: wp.Function
    cr_solve: wp.Function
    mat: type
    vec: type


@functools.cache
def make_cr_funcs(real, S: int):
    """Block cyclic reduction of a block-tridiagonal SPD matrix with S x S blocks, lanes of a
    block in parallel. Layout of the column's solver rows x: x[0 : nb S, 0] right-hand side /
    solution, then at D, E, WM, WP (each nb S^2, row-major blocks): D_i (D_i^-1 once block i is
    eliminated), E_i (the block coupling row-block i to i - s at the current level), W-_i, W+_i."""
    SS = S * S
    bf = make_block_funcs(real, S)
    mload, mstore, vload, vstore, spd_inverse = bf.mload, bf.mstore, bf.vload, bf.vstore, bf.spd_inverse
    col, col_store, mv, mtv = bf.col, bf.col_store, bf.mv, bf.mtv

    @wp.func
    def cr_factor(x: wp.array2d(dtype=real), nb: int, lane: int, bd: int):
        """Reduce the assembled D, E in place. Returns this lane's ok flag (0: a pivot <= 0).
        Per level: one lane per eliminated block inverts it; then one lane per (block, column)
        forms that column of W-, W+ and, for the kept blocks, of the Schur complement and the
        new coupling (written to the other E buffer: the old one is still being read)."""
        D = nb * S
        WM = D + 3 * nb * SS
        WP = WM + nb * SS
        cur = D + nb * SS
        nxt = cur + nb * SS
        ok = int(1)
        s = int(1)
        while s < nb:
            n_el = (nb + s - 1) / (2 * s)  # eliminated i = s, 3s, ...
            for q in range(lane, n_el, bd):
                i = s * (2 * q + 1)
                dinv, okq = spd_inverse(mload(x, D + i * SS))
                ok = wp.min(ok, okq)
                mstore(x, D + i * SS, dinv)
            block_sync()
            for t in range(lane, n_el * S, bd):
                q = t / S
                c = t - q * S
                i = s * (2 * q + 1)
                col_store(x, WM + i * SS, c, mv(x, D + i * SS, col(x, cur + i * SS, c)))
                if i + s < nb:  # W+ column c: D_i^-1 (row c of E_{i+s})
                    col_store(x, WP + i * SS, c, mv(x, D + i * SS, vload(x, cur + (i + s) * SS + c * S)))
            block_sync()
            for t in range(lane, ((nb + 2 * s - 1) / (2 * s)) * S, bd):  # kept j = 0, 2s, ...
                q = t / S
                c = t - q * S
                j = 2 * s * q
                d = col(x, D + j * SS, c)
                if j > 0:
                    d = d - mv(x, cur + j * SS, col(x, WP + (j - s) * SS, c))
                    col_store(x, nxt + j * SS, c, -mv(x, cur + j * SS, col(x, WM + (j - s) * SS, c)))
                if j + s < nb:
                    d = d - mtv(x, cur + (j + s) * SS, col(x, WM + (j + s) * SS, c))
                col_store(x, D + j * SS, c, d)
            block_sync()
            tmp = cur
            cur = nxt
            nxt = tmp
            s = s * 2
        if lane == 0:
            dinv, okq = spd_inverse(mload(x, D))
            ok = wp.min(ok, okq)
            mstore(x, D, dinv)
        return ok

    @wp.func
    def cr_solve(x: wp.array2d(dtype=real), nb: int, lane: int, bd: int):
        """Solve A y = x[0 : nb S, 0] in place with the stored reduction; ends with a barrier."""
        D = nb * S
        WM = D + 3 * nb * SS
        WP = WM + nb * SS
        s = int(1)
        while s < nb:  # forward: kept blocks take the eliminated neighbours' right-hand sides
            for q in range(lane, (nb + 2 * s - 1) // (2 * s), bd):
                j = 2 * s * q
                b = vload(x, j * S)
                if j > 0:
                    b = b - wp.transpose(mload(x, WP + (j - s) * SS)) @ vload(x, (j - s) * S)
                if j + s < nb:
                    b = b - wp.transpose(mload(x, WM + (j + s) * SS)) @ vload(x, (j + s) * S)
                vstore(x, j * S, b)
            block_sync()
            s = s * 2
        if lane == 0:
            vstore(x, 0, mload(x, D) @ vload(x, 0))
        block_sync()
        s = s / 2
        while s >= 1:  # backward: eliminated blocks from their solved neighbours
            for q in range(lane, (nb + s - 1) // (2 * s), bd):
                i = s * (2 * q + 1)
                y = mload(x, D + i * SS) @ vload(x, i * S) - mload(x, WM + i * SS) @ vload(x, (i - s) * S)
                if i + s < nb:
                    y = y - mload(x, WP + i * SS) @ vload(x, (i + s) * S)
                vstore(x, i * S, y)
            block_sync()
            s = s / 2

    return CRFuncs(cr_factor=cr_factor, cr_solve=cr_solve, mat=bf.mat, vec=bf.vec)
