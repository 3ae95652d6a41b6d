"""Per-column constraint-solver kernels of the staged step (one thread per column), generated once
per precision and Gram half-bandwidth: position projection (SHAKE / RATTLE), factor-and-project
velocities, factor only, and the index-1 constrained acceleration.

Each thread assembles its column's Gram matrix G M^-1 G^T row by row and factors it as a banded
Cholesky (:func:`.common.make_band_funcs`), which handles bars sharing nodes and rigid-link loops
alike. Layout and argument grouping as in :mod:`.staged` (the per-node kernels and the records).
"""


import functools
from typing import NamedTuple

import warp as wp

from ... import types
from ..common import (
    STATUS_CONSTRAINT,
    STATUS_NONFINITE,
    STATUS_OK,
    array_type,
    bar_row,
    finite3,
    make_band_funcs,
    make_gram_row,
    member_vec,
    newton_stop,
    node_impulse,
    projection_status,
    set_failure,
)

wp.set_module_options({"enable_backward": False})


@functools.cache
def make_gram_struct(real):
    """``GramModel``: the Model arrays of the Gram matrix G M^-1 G^T (the argument group "gram" of
    :data:`warp_tensegrity.types.ARGUMENT_GROUPS`), one struct argument of the solver kernels that factor
    it (:meth:`.step.Launcher.launch` fills it from the Model by name)."""
    return wp.struct(type("GramModel", (), {"__module__": __name__, "__annotations__": {
        f.name: array_type(f.dtype, f.ndim, real) for f in types.group_fields("gram")}}))


@functools.cache
def _assemble_funcs(real, bandwidth: int, bar_window: bool):
    """Gram assembly of one column thread, each row factored as it is assembled: from
    common.gram_row (reload) or with the last bandwidth + 1 bar vectors in registers (window)."""
    vec = wp.types.vector(3, real)
    BW = int(bandwidth)
    LD = BW + 1
    GramModel = make_gram_struct(real)
    gram_row, rowvec = make_gram_row(real, BW)
    factor_store_row = make_band_funcs(real, bandwidth).factor_store_row

    @wp.func
    def assemble_factor_reload(g: GramModel, u: wp.array2d(dtype=vec), band: wp.array3d(dtype=real), w: int):
        """Assemble each row k of A = G M^-1 G^T at u in registers (common.gram_row), factor it
        and store it. Returns False on a non-positive pivot."""
        wa = w % g.con_active.shape[1]  # column w's index into per-column parameters (hoisted)
        ws = w % g.minv_self.shape[1]
        wx = w % g.minv_cross.shape[1]
        ok = bool(True)
        for k in range(g.con_i.shape[0]):
            r = gram_row(g.con_i, g.con_j, g.con_dref, g.con_active, g.cpl_start, g.cpl_l, g.cpl_a, g.cpl_cross,
                         g.cpl_sign, g.minv_self, g.minv_cross, u, w, k, wa, ws, wx)
            if not factor_store_row(band, r, k, w):
                ok = False
        return ok

    @wp.func
    def assemble_factor_window(g: GramModel, u: wp.array2d(dtype=vec), band: wp.array3d(dtype=real), w: int):
        """As assemble_factor_reload, with the bar vectors of rows k-BW..k kept in registers (zero
        for an inactive row): each is loaded once instead of once per coupling term (possible
        only because this thread assembles the rows in order)."""
        nc = g.con_i.shape[0]
        wa = w % g.con_active.shape[1]
        ws = w % g.minv_self.shape[1]
        wx = w % g.minv_cross.shape[1]
        bx = rowvec()  # bx[e], by[e], bz[e]: bar vector of row k - e
        by = rowvec()
        bz = rowvec()
        ok = bool(True)
        for k in range(nc):
            for e in range(BW):
                bx[BW - e] = bx[BW - 1 - e]
                by[BW - e] = by[BW - 1 - e]
                bz[BW - e] = bz[BW - 1 - e]
            r = rowvec()
            # zero for an inactive row (no branch: a generic function's vector type must not
            # replace a variable declared as another vector class inside an if)
            on = wp.where(g.con_active[k, wa] > real(0.0), real(1.0), real(0.0))
            bk = member_vec(g.con_dref, g.con_i, g.con_j, u, k, w) * on
            bx[0] = bk[0]
            by[0] = bk[1]
            bz[0] = bk[2]
            if g.con_active[k, wa] > real(0.0):
                for t in range(g.cpl_start[k], g.cpl_start[k + 1]):
                    na = g.cpl_a[t]
                    m = g.minv_self[na, ws]
                    if g.cpl_cross[t] != 0:
                        m = g.minv_cross[na, wx]
                    sm = g.cpl_sign[t] * m
                    d = k - g.cpl_l[t]
                    for e in range(LD):
                        if d == e:
                            r[e] += sm * (bk[0] * bx[e] + bk[1] * by[e] + bk[2] * bz[e])
            else:
                r[0] = real(1.0)
            if not factor_store_row(band, r, k, w):
                ok = False
        return ok

    return assemble_factor_window if bar_window else assemble_factor_reload


class ProjectionFuncs(NamedTuple):
    """The impulse and rate bodies of the projections."""

    apply_impulse: wp.Function
    project_rates: wp.Function


@functools.cache
def _projection_funcs(real, bandwidth: int):
    """Impulse application and the rate projection of one column thread."""
    vec = wp.types.vector(3, real)
    GramModel = make_gram_struct(real)
    band_solve = make_band_funcs(real, bandwidth).band_solve

    @wp.func
    def apply_impulse(
        con_i: wp.array(dtype=int), con_j: wp.array(dtype=int), con_dref: wp.array(dtype=vec),
        ncon_start: wp.array(dtype=int), ncon_member: wp.array(dtype=int),
        partner: wp.array(dtype=int), minv_self: wp.array2d(dtype=real), minv_cross: wp.array2d(dtype=real),
        ug: wp.array2d(dtype=vec), lam: wp.array2d(dtype=real), imp: wp.array2d(dtype=vec),
        scale: real, y: wp.array2d(dtype=vec), scale2: real, y2: wp.array2d(dtype=vec), w: int,
    ):
        """y -= scale * M^-1 G(ug)^T lam and y2 -= scale2 * M^-1 G(ug)^T lam. A node whose M^-1
        row is its own (partner -1) is updated at once; a massive bar's two free nodes go
        through imp, then M^-1 couples them."""
        nn = imp.shape[0]
        ws = w % minv_self.shape[1]
        wx = w % minv_cross.shape[1]
        n_coupled = int(0)
        for n in range(nn):
            g = node_impulse(con_i, con_j, con_dref, ncon_start, ncon_member, ug, w, lam, w, n)
            if partner[n] < 0:
                d = g * minv_self[n, ws]
                y[n, w] = y[n, w] - d * scale
                if scale2 != real(0.0):
                    y2[n, w] = y2[n, w] - d * scale2
            else:
                imp[n, w] = g
                n_coupled += 1
        if n_coupled > 0:
            for n in range(nn):
                p = partner[n]
                if p >= 0:
                    d = imp[n, w] * minv_self[n, ws] + imp[p, w] * minv_cross[n, wx]
                    y[n, w] = y[n, w] - d * scale
                    if scale2 != real(0.0):
                        y2[n, w] = y2[n, w] - d * scale2

    @wp.func
    def project_rates(
        g: GramModel, ncon_start: wp.array(dtype=int), ncon_member: wp.array(dtype=int),
        partner: wp.array(dtype=int), u: wp.array2d(dtype=vec), v: wp.array2d(dtype=vec), with_bdot: int,
        band: wp.array3d(dtype=real), y: wp.array2d(dtype=vec), lam: wp.array2d(dtype=real),
        imp: wp.array2d(dtype=vec), w: int,
    ):
        """With the band holding the factor of A(u): solve A lam = G(u) y (+ |b'|^2 if with_bdot, the
        index-1 acceleration term) and set y -= M^-1 G(u)^T lam. y = v: velocity projection; y = a:
        constrained acceleration."""
        wa = w % g.con_active.shape[1]
        for k in range(g.con_i.shape[0]):
            r = real(0.0)
            if g.con_active[k, wa] > real(0.0):
                b = member_vec(g.con_dref, g.con_i, g.con_j, u, k, w)
                r = wp.dot(b, y[g.con_j[k], w] - y[g.con_i[k], w])
                if with_bdot != 0:
                    bd = v[g.con_j[k], w] - v[g.con_i[k], w]
                    r += wp.dot(bd, bd)
            lam[k, w] = r
        band_solve(band, lam, lam.shape[0], w)
        apply_impulse(g.con_i, g.con_j, g.con_dref, ncon_start, ncon_member, partner, g.minv_self, g.minv_cross, u,
                      lam, imp, real(1.0), y, real(0.0), y, w)

    return ProjectionFuncs(apply_impulse=apply_impulse, project_rates=project_rates)


class SolverKernels(NamedTuple):
    """The staged step's per-column constraint-solver kernels, by name (:func:`make_solver_kernels`)."""

    real: type
    bandwidth: int
    project_positions: wp.Kernel
    factor_project: wp.Kernel
    factor_only: wp.Kernel


@functools.cache
def make_solver_kernels(real, bandwidth: int, max_registers: int | None = None,
                        bar_window: bool | None = None) -> SolverKernels:
    """Per-column constraint-solver kernels (one thread per column) for scalar type ``real``, with
    the Gram-matrix half-bandwidth ``bandwidth`` compiled in (see :func:`.common.make_band_funcs`).
    ``max_registers`` caps the registers per CUDA thread (``__maxnreg__``; None: the compiler's
    choice). ``bar_window`` keeps the bar vectors of the last ``bandwidth`` + 1 rows in registers
    while the Gram matrix is assembled (None: for fp32 only; fp64 spills them at 64 registers)."""
    if bar_window is None:
        bar_window = real == wp.float32
    kopts = {"enable_backward": False, "module": "unique", "cuda_max_registers": max_registers}
    return SolverKernels(real=real, bandwidth=int(bandwidth),
                         project_positions=_position_kernel(real, bandwidth, bar_window, kopts),
                         **_factor_kernels(real, bandwidth, bar_window, kopts))


def _position_kernel(real, bandwidth, bar_window, kopts):
    vec = wp.types.vector(3, real)
    fb = make_band_funcs(real, bandwidth)
    band_solve, apply_impulse = fb.band_solve, _projection_funcs(real, bandwidth).apply_impulse

    @wp.func
    def bar_rows(con_i: wp.array(dtype=int), con_j: wp.array(dtype=int), con_dref: wp.array(dtype=vec),
                 con_L: wp.array(dtype=real), con_active: wp.array2d(dtype=real), u: wp.array2d(dtype=vec),
                 lam: wp.array2d(dtype=real), w: int, wa: int):
        """The Newton residual of each bar of column w at u into lam[:, w] (0 for an inactive member),
        and the largest relative bar error (common.bar_row); wa: w's index into con_active."""
        err = real(0.0)
        for k in range(con_i.shape[0]):
            r = real(0.0)
            if con_active[k, wa] > real(0.0):
                r, e, err = bar_row(con_dref, con_i, con_j, con_L, u, k, w, err)
            lam[k, w] = r
        return err

    @wp.kernel(**kopts)
    def project_positions(
        # Model:
        con_i: wp.array(dtype=int), con_j: wp.array(dtype=int), con_dref: wp.array(dtype=vec),
        con_L: wp.array(dtype=real), con_active: wp.array2d(dtype=real),
        ncon_start: wp.array(dtype=int), ncon_member: wp.array(dtype=int),
        partner: wp.array(dtype=int), minv_self: wp.array2d(dtype=real), minv_cross: wp.array2d(dtype=real),
        tol: real, max_iter: int, fail_tol: real, inv_dt: real,
        # Data in:
        band: wp.array3d(dtype=real), ug: wp.array2d(dtype=vec), step: wp.array(dtype=int),
        # Data out:
        u: wp.array2d(dtype=vec), v: wp.array2d(dtype=vec), lam: wp.array2d(dtype=real), imp: wp.array2d(dtype=vec),
        bar_err: wp.array(dtype=real), iters: wp.array(dtype=int),
        status: wp.array(dtype=int), fail_step: wp.array(dtype=int),
    ):
        """Simplified Newton onto |b_k| = L_k along M^-1 G(ug)^T, with the band holding the factor of
        G(ug) M^-1 G(ug)^T. v -= inv_dt * du (RATTLE's velocity update; 0 for plain projection)."""
        w = wp.tid()
        if status[w] != STATUS_OK:
            return
        wa = w % con_active.shape[1]
        err = real(0.0)
        it = int(0)
        while True:
            prev = err
            err = bar_rows(con_i, con_j, con_dref, con_L, con_active, u, lam, w, wa)
            if newton_stop(err, prev, tol, it, max_iter):
                break
            band_solve(band, lam, lam.shape[0], w)
            apply_impulse(con_i, con_j, con_dref, ncon_start, ncon_member, partner, minv_self, minv_cross, ug,
                          lam, imp, real(1.0), u, inv_dt, v, w)
            it += 1
        iters[w] = wp.max(iters[w], it)
        code = projection_status(err, fail_tol)
        if code != STATUS_OK:
            set_failure(status, fail_step, w, code, step[0] + 1)
        if err > bar_err[w]:
            bar_err[w] = err

    return project_positions


def _factor_kernels(real, bandwidth, bar_window, kopts):
    vec = wp.types.vector(3, real)
    GramModel = make_gram_struct(real)
    assemble_factor = _assemble_funcs(real, bandwidth, bar_window)
    project_rates = _projection_funcs(real, bandwidth).project_rates

    @wp.func
    def factor_or_flag(g: GramModel, u: wp.array2d(dtype=vec), step: wp.array(dtype=int), band: wp.array3d(dtype=real),
                       status: wp.array(dtype=int), fail_step: wp.array(dtype=int), w: int):
        """Factor A(u) into the band; False (and column w flagged) if it is not positive definite."""
        ok = assemble_factor(g, u, band, w)
        if not ok:
            set_failure(status, fail_step, w, STATUS_CONSTRAINT, step[0] + 1)
        return ok

    @wp.kernel(**kopts)
    def factor_only(
        # Model:
        gram: GramModel,
        # Data in:
        u: wp.array2d(dtype=vec), step: wp.array(dtype=int),
        # Data out:
        band: wp.array3d(dtype=real), status: wp.array(dtype=int), fail_step: wp.array(dtype=int),
    ):
        w = wp.tid()
        if status[w] != STATUS_OK:
            return
        factor_or_flag(gram, u, step, band, status, fail_step, w)

    @wp.kernel(**kopts)
    def factor_project(
        # Model:
        gram: GramModel, ncon_start: wp.array(dtype=int), ncon_member: wp.array(dtype=int),
        partner: wp.array(dtype=int),
        # Data in:
        u: wp.array2d(dtype=vec), v: wp.array2d(dtype=vec), step: wp.array(dtype=int), rates: int,
        # Data out:
        band: wp.array3d(dtype=real), out: wp.array2d(dtype=vec), lam: wp.array2d(dtype=real),
        imp: wp.array2d(dtype=vec), status: wp.array(dtype=int), fail_step: wp.array(dtype=int),
    ):
        """Factor A(u) (kept for the next position projection), then ``rates`` = 0: project the
        velocities ``out`` (= v) onto G(u) v = 0; 1: the index-1 multipliers A lam = G a_free + |b'|^2,
        a = ``out`` -= M^-1 G^T lam (the paper's RK4 right-hand side)."""
        w = wp.tid()
        if status[w] != STATUS_OK:
            return
        if not factor_or_flag(gram, u, step, band, status, fail_step, w):
            return
        if rates == 1:
            project_rates(gram, ncon_start, ncon_member, partner, u, v, 1, band, out, lam, imp, w)
        else:  # v is not read: out is the one velocity array, read and written (no aliased second view)
            project_rates(gram, ncon_start, ncon_member, partner, u, out, 0, band, out, lam, imp, w)
            for n in range(u.shape[0]):
                if not finite3(out[n, w]):
                    set_failure(status, fail_step, w, STATUS_NONFINITE, step[0] + 1)
                    return

    return {"factor_project": factor_project, "factor_only": factor_only}
