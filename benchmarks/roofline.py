"""Roofline of one RATTLE step of a T3 column: DRAM bytes and flops per column-step, per kernel.

Counts follow the loops of ``warp_tensegrity/kernels.py`` (RATTLE: kick_drift,
project_positions, gather_accel, factor_project_velocities, advance_counter, record_energy).

Symbols, per column: n nodes (all, clamped ones included: the node kernels launch n x B
threads), ne cables (cross cables and base members; RB keeps its base members as EA = 0
cables), nc constraints (bars, plus rigid links in RB), bw the Gram-matrix half-bandwidth,
ncpl the coupling terms of the band assembly (model.constraint_coupling), r the bytes of a
real (4 or 8), V = 3 r a vec3, it the Newton solve iterations of the position projection.

Assumptions (stated once, used everywhere):

1. Each distinct per-column array element is moved between DRAM and the chip once per
   kernel (per pass over it): re-reads of the same node within one pass (a node shared by
   several members or constraints) hit L1/L2. Passes that sweep all constraints or nodes
   again later in the same kernel (Cholesky after assembly, the two triangular solves, each
   Newton iteration) re-read from DRAM, because at large B the per-pass footprint
   (B x per-column bytes) is far larger than L2 (50 MB H100, 60 MB H200).
   Rows of the band reused within bw rows (Cholesky's l = k - d, the solves' neighbours) hit L2.
2. Arrays shared by all columns (topology, reference vectors, coupling CSR, and per-column
   parameters that the batch holds once because they are equal: EA, EA_c, masses,
   constraint_active) cost nothing per column at large B. The benchmark batches vary
   prestrain (so cable rest lengths, ne reals per column) and v0 (initial state only);
   ``per_column_params="all"`` counts EA, EA_c, M^-1 and constraint_active per column too.
3. Bars are massless (the paper's columns): M^-1 is diagonal, so the impulse updates each node
   at once, without the scratch row that massive bars' coupled nodes go through.
4. The output kernel (record_energy) works one step in ``output_every`` and is amortised.
5. flops: add, mul, FMA as 1 / 1 / 2; division and sqrt count 1 each. Integer index work,
   compares and branches are not counted.
6. it (solve iterations per column-step, mean over columns and steps) defaults to what this
   harness measured on the H200 at large B (DEFAULT_ITERS): FB fp32 2.0, FB fp64 3.5,
   RB fp32 2.2 (fp32 tolerance 3e-7), RB fp64 5.6. On the GPU a warp of 32 columns runs as
   many iterations as its slowest column (RB fp32: mean 2.26, warp max 2.5 at B = 262,144),
   which costs time but not DRAM bytes; the bound does not include it.

Bounds: memory = measured device-to-device copy bandwidth / bytes; compute = non-tensor peak
of the precision / flops; roof = min. ``sm_fill(B)`` reports how much of the GPU the
one-thread-per-column kernels can occupy (ceil(B / 256) blocks of 256 threads on 132 SMs):
below B ~ 34k columns those kernels leave SMs idle, so no bound of this kind is reachable.
"""

from __future__ import annotations

import argparse
import functools
import json
import math
from types import SimpleNamespace

import numpy as np

# device figures: spec and measured HBM bandwidth (device-to-device copy, bytes read + written,
# as measured on this workplace's machines), non-tensor FP32/FP64 peak (SXM), SMs, L2
DEVICES = {
    "h100": {"name": "NVIDIA H100 80GB HBM3 (SXM)", "bw_spec": 3.35e12, "bw_measured": 3.0e12,
             "fp32": 67e12, "fp64": 34e12, "sm": 132, "l2_bytes": 50e6},
    "h200": {"name": "NVIDIA H200 (SXM)", "bw_spec": 4.8e12, "bw_measured": 4.3e12,
             "fp32": 67e12, "fp64": 34e12, "sm": 132, "l2_bytes": 60e6},
}
DEFAULT_ITERS = {("FB", "fp32"): 2.0, ("FB", "fp64"): 3.5, ("RB", "fp32"): 2.2, ("RB", "fp64"): 5.6}
BLOCK = 256  # Warp's default CUDA block size (wp.launch without block_dim)
NODE_FLOPS_KICK = 12


def base_label(base) -> str:
    if isinstance(base, str):
        b = base.upper()
        if b not in ("FB", "RB"):
            raise ValueError(f"base = {base!r}: use 'FB', 'RB', 0 or 1")
        return b
    return "RB" if float(base) >= 1.0 else "FB"


@functools.lru_cache(maxsize=64)
def column_counts(n_prisms: int, base) -> dict:
    """n, ne, nc, bw, ncpl of the engine's column model (same constraint order as column_batch)."""
    from warp_tensegrity.scene import columns as col
    from warp_tensegrity.sim.model import constraint_coupling

    lab = base_label(base)
    topo = col.column_topology(col.ColumnConfig(n_prisms=n_prisms))
    cons = []
    for m in range(n_prisms):
        cons += [topo.bars[3 * m + k] for k in range(3)]
        if lab == "RB":
            cons += [topo.base[3 * (m + 1) + k] for k in range(3)]
    cons = np.array(cons, dtype=np.int64)
    partner = -np.ones(topo.n_nodes, dtype=np.int32)
    start, ls, *_rest, bw = constraint_coupling(SimpleNamespace(constraints=cons, fixed=topo.fixed,
                                                                positions=topo.positions), partner)
    return {
        "n_nodes": int(topo.n_nodes),
        "n_cables": int(len(topo.cross) + len(topo.base)),
        "n_constraints": int(len(cons)),
        "bandwidth": int(bw),
        "n_coupling": int(len(ls)),
    }


def kernel_costs(n: int, ne: int, nc: int, bw: int, ncpl: int, r: int, it: float,
                 output_every: int = 100, per_column_params: str = "rest_length") -> dict:
    """{kernel: (bytes, flops)} per column-step (see the module docstring for the model)."""
    V = 3 * r
    I = 4
    band = nc * (bw + 1) * r
    allp = per_column_params == "all"
    ea_bytes = 2 * ne * r if allp else 0  # EA, EA_c
    minv_bytes = 2 * n * r if allp else 0  # minv_self, minv_cross
    act_bytes = nc * r if allp else 0  # constraint_active

    k = {}
    # kick_drift: read a, v, u; write v, u, u_prev
    k["kick_drift"] = (6 * V * n + I, NODE_FLOPS_KICK * n)

    # project_positions: (it+1) residual passes; it x (band solve + impulse with y=u, y2=v)
    res_b = V * n + r * nc + act_bytes
    res_f = 18 * nc
    solve_b = 2 * band + 4 * nc * r
    solve_f = nc * (4 * bw + 2)
    # impulse: each node gathers its members (read u_prev, lam) and updates u, v (RMW); massive
    # bars' nodes (none here, assumption 3) would also write and re-read the scratch row imp
    imp_b = 5 * V * n + r * nc + minv_bytes
    imp_f = 24 * nc + 15 * n
    k["project_positions"] = ((it + 1) * res_b + it * (solve_b + imp_b) + 4 * I + 2 * r,
                              (it + 1) * res_f + it * (solve_f + imp_f))

    # gather_accel: u (neighbours cached), v, cable rest lengths; write a, v_out
    k["gather_accel"] = (4 * V * n + ne * r + ea_bytes + minv_bytes + I,
                         2 * ne * 22 + 15 * n)

    # factor_project_velocities: assemble and factor each row in registers (band written once; the
    # bw rows above are re-read from L2), rhs, solve, impulse on v (scale2 = 0), finiteness check of v
    chol_f = nc * (bw + 1) ** 2
    asm_f = 6 * nc + 14 * ncpl
    k["factor_project_velocities"] = (
        band + V * n + act_bytes + minv_bytes  # assemble + Cholesky, u
        + V * n + nc * r  # rhs: v, lam
        + solve_b  # triangular solves
        + 3 * V * n + nc * r + minv_bytes  # impulse on v: read u, lam; v RMW
        + V * n,  # isfinite(v)
        asm_f + chol_f + 14 * nc + solve_f + 24 * nc + 9 * n)

    k["advance_counter"] = (0, 0)
    # record_energy: u, v, rest lengths, 2 outputs, once every output_every steps
    k["record_energy"] = ((2 * V * n + ne * r + 2 * r) / output_every,
                          (n * 12 + ne * 25) / output_every)
    return k


def fused_costs(n: int, ne: int, nc: int, bw: int, ncpl: int, r: int, it: float, output_every: int = 100,
                steps_per_launch: int = 16, rows_in_shared: bool = True, solver: str = "cr") -> dict:
    """{part: (bytes, flops)} per column-step of the fused step with the block-cyclic-reduction
    solve (warp_tensegrity/sim/block/kernels.py, the CR in sim/block/coop.py), counted from their loops.

    Flops (S = max(bw, 1), nb = nc / S blocks): kick-drift 9n; per Newton iteration the residual
    (bar vector 6, |b|^2 5, r and e 6: 17 nc), the CR solve (forward: kept blocks two S x S
    transposed mat-vecs, ~4 S^2 per block; backward: eliminated blocks three mat-vecs, ~6 S^2:
    10 S nc), the impulse gather (2 incidences per bar, 12 each: 24 nc) and M^-1 with the U and V
    updates (21 n); the force gather (2 incidences per cable, ~24 each: 48 ne, + 15 n); the Gram
    rows (6 nc + 20 per coupling term); the CR factor (per block: Gauss-Jordan inverse 2 S^3, W-
    and W+ 4 S^3, Schur complement and coupling 6 S^3: 12 S^2 nc); the velocity projection (residual
    11 nc, a solve, an impulse). One more factor per launch.

    ``solver='serial'`` (lane 0's banded Cholesky): a solve is two sweeps of (2 bw + 1) flops per
    row, (4 bw + 2) nc; the factor nc (bw + 1)^2 after the Gram rows. (That variant is bound by
    lane 0's dependent chain, not by these counts: its bound here is an upper bound only.)

    DRAM bytes: u, v, a read and written once per launch (6 V n / steps_per_launch); with the rows
    in global memory (``rows_in_shared`` False) they are written back once per launch as well
    (5 V n + the solver rows); the per-column rest lengths each step (ne r, upper estimate); outputs.
    """
    V = 3 * r
    S = max(bw, 1)
    serial = solver == "serial"
    solve = (4 * bw + 2) * nc if serial else 10 * S * nc
    impulse = 24 * nc + 21 * n
    factor = 6 * nc + 20 * ncpl + (nc * (bw + 1) ** 2 if serial else 12 * S * S * nc)
    newton = 17 * nc + solve + impulse
    vel = 11 * nc + solve + impulse + 3 * n
    rows = 0.0 if rows_in_shared else (5 * V * n + r * nc * (1 + 5 * S)) / steps_per_launch
    return {
        "launch_io": (6 * V * n / steps_per_launch + rows, 0.0),
        "rest_lengths": (ne * r, 0.0),
        "outputs": ((2 * r) / output_every, 0.0),
        "kick_drift": (0.0, 9 * n),
        "newton": (0.0, it * newton),
        "forces": (0.0, 48 * ne + 15 * n),
        "factor": (0.0, factor * (1 + 1 / steps_per_launch)),
        "velocity_projection": (0.0, vel),
    }


def lanes_costs(n_prisms: int, r: int, it: float, output_every: int = 100, steps_per_launch: int = 64) -> dict:
    """{part: (bytes, flops)} per column-step of the warp-per-column step (sim/lanes/lanes.py,
    flexible bases), counted from its loops. nn = 3 n free nodes, nc = 3 n bars, ne = 6 n + 3
    cables; P levels per lane and G lanes (sim.lanes.lanes.lane_shape). A bar row of a chain solve
    costs the lane's Thomas sweep (5 (P - 1) / P), its reduced row (4 / P), 2 log2 G PCR FMAs per
    lane (4 log2 G / P per row) and the back substitution (4 (P - 1) / P); the factor about twice
    that plus 14 per row for the Gram entries. Bars: vector 8, residual 12; impulse 18 per node;
    a cable 21 + 6 accumulation. DRAM: u, v, a read and written once per launch, the rest
    lengths read once per launch, the outputs."""
    n = int(n_prisms)
    P = -(-n // 32)
    lanes = -(-n // P)
    LG = max(lanes - 1, 0).bit_length()
    nn, nc, ne = 3 * n, 3 * n, 6 * n + 3
    V = 3 * r
    row = (5 * (P - 1) + 4 + 4 * LG + 4 * (P - 1)) / P
    solve = row * nc
    impulse = 18 * nn
    return {
        "launch_io": (6 * V * nn / steps_per_launch + ne * r / steps_per_launch, 0.0),
        "outputs": ((2 * r) / output_every, 0.0),
        "kick_drift": (0.0, 12 * nn),
        "newton": (0.0, it * (20 * nc + solve + impulse)),
        "forces": (0.0, 27 * ne + 3 * nn),
        "factor": (0.0, (14 + 2 * row) * nc),
        "velocity_projection": (0.0, 8 * nc + solve + impulse),
    }


def lanes_rigid_costs(n_prisms: int, r: int, it: float, output_every: int = 100, steps_per_launch: int = 64) -> dict:
    """:func:`lanes_costs` plus the ring links of rigid bases (sim/lanes/lane_rigid.py), per lane
    (ceil(n / P) lanes): per level the link vectors and residuals (~30 a Newton iteration), the
    couplings (~105), the links' 3 x 3 inverse (~40) and their Schur complement (~270); the first
    row's block inverse and spikes (~265, P = 2); block PCR ~240 a level, a final inverse; a solve
    3 mat-vecs a level for the links' right-hand side and 3 for their multipliers (~90), ~45 for the
    first row, 2 mat-vecs a PCR level (~36) and the back substitution (~45)."""
    n = int(n_prisms)
    P = -(-n // 32)
    lanes = -(-n // P)
    LG = max(lanes - 1, 0).bit_length()
    k = lanes_costs(n, r, it, output_every, steps_per_launch)
    solve = lanes * (90 * P + 45 * (P - 1) + 36 * LG + 60)
    factor = lanes * (415 * P + 265 * (P - 1) + 240 * LG + 40)
    k["newton"] = (0.0, k["newton"][1] + it * (solve + 30 * 3 * n))
    k["factor"] = (0.0, k["factor"][1] + factor)
    k["velocity_projection"] = (0.0, k["velocity_projection"][1] + solve + 8 * 3 * n)
    return k


def bound(n_prisms: int = 50, base="FB", precision: str = "fp64", device_kind: str = "h100",
          it: float | None = None, output_every: int = 100, per_column_params: str = "rest_length",
          B: int | None = None, path: str = "staged") -> dict:
    """Bytes, flops and the roofline bound (column-steps/s) of one RATTLE column-step of the
    staged kernels (path='staged') or of the fused step (path='fused'; see fused_costs)."""
    if path in ("fused", "fused-serial", "lanes"):
        return _bound_fused(n_prisms, base, precision, device_kind, it, output_every, B,
                            path if path == "lanes" else "serial" if path == "fused-serial" else "cr")
    lab = base_label(base)
    if precision not in ("fp32", "fp64"):
        raise ValueError(f"precision = {precision!r}")
    kind = device_kind.lower()
    if kind not in DEVICES:
        raise ValueError(f"device_kind = {device_kind!r}; known: {sorted(DEVICES)}")
    dev = DEVICES[kind]
    c = column_counts(int(n_prisms), lab)
    r = 4 if precision == "fp32" else 8
    it = DEFAULT_ITERS[(lab, precision)] if it is None else float(it)
    k = kernel_costs(c["n_nodes"], c["n_cables"], c["n_constraints"], c["bandwidth"], c["n_coupling"], r, it,
                     output_every, per_column_params)
    byts = sum(b for b, _ in k.values())
    flops = sum(f for _, f in k.values())
    peak = dev[precision]
    mem = dev["bw_measured"] / byts
    comp = peak / flops
    out = {
        "n_prisms": int(n_prisms), "base": lab, "precision": precision, "device_kind": kind,
        **c, "real_bytes": r, "newton_iters": it, "output_every": output_every,
        "per_column_params": per_column_params,
        "kernels": {name: {"bytes": float(b), "flops": float(f)} for name, (b, f) in k.items()},
        "bytes_per_column_step": float(byts),
        "flops_per_column_step": float(flops),
        "arithmetic_intensity": flops / byts,
        "ridge_intensity": peak / dev["bw_measured"],
        "bandwidth_measured": dev["bw_measured"], "bandwidth_spec": dev["bw_spec"], "peak_flops": peak,
        "memory_bound_column_steps_per_s": mem,
        "memory_bound_spec_column_steps_per_s": dev["bw_spec"] / byts,
        "compute_bound_column_steps_per_s": comp,
        "bound_column_steps_per_s": min(mem, comp),
        "bound_node_steps_per_s": min(mem, comp) * c["n_nodes"],
        "limiter": "memory" if mem <= comp else "compute",
        "l2_bytes": dev["l2_bytes"],
    }
    if B is not None:
        out["B"] = int(B)
        out["sm_fill_per_column_kernels"] = sm_fill(int(B), dev["sm"])
    return out


def _bound_fused(n_prisms, base, precision, device_kind, it, output_every, B, solver="cr") -> dict:
    lab = base_label(base)
    dev = DEVICES[device_kind.lower()]
    c = column_counts(int(n_prisms), lab)
    r = 4 if precision == "fp32" else 8
    it = DEFAULT_ITERS[(lab, precision)] if it is None else float(it)
    if solver == "lanes":
        k = (lanes_costs if lab == "FB" else lanes_rigid_costs)(int(n_prisms), r, it, output_every)
    else:
        k = fused_costs(c["n_nodes"], c["n_cables"], c["n_constraints"], c["bandwidth"], c["n_coupling"], r, it,
                        output_every, solver=solver)
    byts = sum(b for b, _ in k.values())
    flops = sum(f for _, f in k.values())
    peak = dev[precision]
    mem = dev["bw_measured"] / byts
    comp = peak / flops
    out = {
        "path": {"cr": "fused", "serial": "fused-serial"}.get(solver, solver), "n_prisms": int(n_prisms), "base": lab, "precision": precision, "device_kind": device_kind,
        **c, "real_bytes": r, "newton_iters": it, "output_every": output_every,
        "parts": {name: {"bytes": float(b), "flops": float(f)} for name, (b, f) in k.items()},
        "bytes_per_column_step": float(byts), "flops_per_column_step": float(flops),
        "arithmetic_intensity": flops / byts, "peak_flops": peak, "bandwidth_measured": dev["bw_measured"],
        "memory_bound_column_steps_per_s": mem, "compute_bound_column_steps_per_s": comp,
        "bound_column_steps_per_s": min(mem, comp),
        "limiter": "memory" if mem <= comp else "compute",
    }
    if B is not None:
        out["B"] = int(B)
    return out


def issue_bound(warp_instructions_per_column_step: float, device_kind: str = "h100",
                clock_hz: float = 1.755e9) -> float:
    """Column-steps/s at which the SMs' warp schedulers (4 per SM, one warp-instruction per cycle
    each) issue a measured instruction count (Nsight Compute: Executed Instructions / column-steps
    of the launch): the bound of a latency- and issue-limited kernel such as the fused step."""
    return DEVICES[device_kind.lower()]["sm"] * 4 * clock_hz / warp_instructions_per_column_step


def sm_fill(B: int, n_sm: int = 132, block: int = BLOCK) -> float:
    """Fraction of SMs that a dim=B launch of `block`-thread blocks can keep busy."""
    return min(1.0, math.ceil(B / block) / n_sm)


def measured_peak(results: dict, n_prisms: int, base: str, precision: str, path: str = "staged"):
    """Largest measured column_steps_per_s for (n_prisms, base, precision, path) in a throughput JSON
    (points without a path are the staged kernels')."""
    best = None
    for p in results.get("points", []):
        if p.get("error") or p.get("n_prisms") != n_prisms or p.get("base") != base or p.get("precision") != precision:
            continue
        if p.get("path", "staged") != path:
            continue
        if best is None or p["column_steps_per_s"] > best["column_steps_per_s"]:
            best = p
    return best


def table(device_kind: str, prisms=(10, 25, 50, 100, 200, 400), results: dict | None = None) -> str:
    rows = ["| prisms | base | prec | n | nc | bw | it* | KB/col-step | kflop/col-step | flop/B | "
            "mem bound [col-steps/s] | compute bound | measured (best B) | % of bound |",
            "|---:|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    note = ("\n\n*it: Newton solve iterations per column-step (measured at the best point when results are "
            "given, else DEFAULT_ITERS).")
    for npr in prisms:
        for base in ("FB", "RB"):
            for prec in ("fp32", "fp64"):
                b = bound(npr, base, prec, device_kind)
                meas, pct = "", ""
                if results is not None:
                    p = measured_peak(results, npr, base, prec)
                    if p is not None and p.get("mean_iters") is not None:
                        b = bound(npr, base, prec, device_kind, it=p["mean_iters"])  # the run's own iterations
                    if p is not None:
                        meas = f"{p['column_steps_per_s']:.3g} (B={p['B']})"
                        pct = f"{100 * p['column_steps_per_s'] / b['bound_column_steps_per_s']:.1f}"
                rows.append(
                    f"| {npr} | {base} | {prec} | {b['n_nodes']} | {b['n_constraints']} | {b['bandwidth']} | "
                    f"{b['newton_iters']:.1f} | {b['bytes_per_column_step'] / 1e3:.1f} | "
                    f"{b['flops_per_column_step'] / 1e3:.1f} | {b['arithmetic_intensity']:.2f} | "
                    f"{b['memory_bound_column_steps_per_s']:.3g} | {b['compute_bound_column_steps_per_s']:.3g} | "
                    f"{meas} | {pct} |")
    return "\n".join(rows) + note


# warp-instructions per column-step of the fused kernel, from Nsight Compute ("Executed Instructions"
# of one 16-step launch / (16 B)): benchmarks/results/ncu_fused_*_B16384.csv (H100, B = 16,384)
FUSED_NCU_INSTRUCTIONS = {("FB", "fp32"): 8.005853952e9 / (16 * 16384), ("RB", "fp64"): 48.088379904e9 / (16 * 16384)}


def fused_table(device_kind: str, prisms=(10, 25, 50, 100, 200, 400), results: dict | None = None) -> str:
    rows = ["| prisms | base | prec | it* | KB/col-step (DRAM) | kflop/col-step | mem bound | compute bound | "
            "measured (best B) | % of compute bound | warp-instr/col-step (ncu) | issue bound | % of issue bound |",
            "|---:|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for npr in prisms:
        for base in ("FB", "RB"):
            for prec in ("fp32", "fp64"):
                p = measured_peak(results, npr, base, prec, "fused") if results is not None else None
                it = p.get("mean_iters") if p is not None else None
                b = bound(npr, base, prec, device_kind, it=it, path="fused")
                meas = pc = ins = ib = pi = ""
                if p is not None:
                    x = p["column_steps_per_s"]
                    meas = f"{x:.3g} (B={p['B']})"
                    pc = f"{100 * x / b['compute_bound_column_steps_per_s']:.2f}"
                    if npr == 50 and (base, prec) in FUSED_NCU_INSTRUCTIONS and device_kind == "h100":
                        n_ins = FUSED_NCU_INSTRUCTIONS[(base, prec)]
                        bi = issue_bound(n_ins, device_kind)
                        ins, ib, pi = f"{n_ins:.3g}", f"{bi:.3g}", f"{100 * x / bi:.0f}"
                rows.append(
                    f"| {npr} | {base} | {prec} | {b['newton_iters']:.1f} | {b['bytes_per_column_step'] / 1e3:.2f} | "
                    f"{b['flops_per_column_step'] / 1e3:.1f} | {b['memory_bound_column_steps_per_s']:.3g} | "
                    f"{b['compute_bound_column_steps_per_s']:.3g} | {meas} | {pc} | {ins} | {ib} | {pi} |")
    return "\n".join(rows) + ("\n\n*it: Newton solve iterations per column-step (measured at the best point "
                              "when results are given, else DEFAULT_ITERS).")


def kernel_table(n_prisms: int, base: str, precision: str, device_kind: str) -> str:
    b = bound(n_prisms, base, precision, device_kind)
    rows = [f"{n_prisms} prisms, {base_label(base)}, {precision}, {device_kind}: "
            f"n={b['n_nodes']} ne={b['n_cables']} nc={b['n_constraints']} bw={b['bandwidth']} "
            f"ncpl={b['n_coupling']} it={b['newton_iters']}",
            "| kernel | bytes/col-step | flops/col-step | share of bytes |", "|---|---:|---:|---:|"]
    tot = b["bytes_per_column_step"]
    for name, v in b["kernels"].items():
        rows.append(f"| {name} | {v['bytes']:.0f} | {v['flops']:.0f} | {100 * v['bytes'] / tot:.1f}% |")
    rows.append(f"| total | {tot:.0f} | {b['flops_per_column_step']:.0f} | 100% |")
    return "\n".join(rows)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--device", default=None, choices=sorted(DEVICES),
                    help="device figures to use (default: from --results' device name, else h100)")
    ap.add_argument("--prisms", type=int, nargs="+", default=[10, 25, 50, 100, 200, 400])
    ap.add_argument("--results", default=None, help="throughput JSON to compare against (largest measured rate)")
    ap.add_argument("--kernels", action="store_true", help="also print the per-kernel split for 50 prisms")
    ap.add_argument("--json", default=None, help="write the bounds as JSON here")
    a = ap.parse_args(argv)
    res = None
    if a.results:
        with open(a.results) as f:
            res = json.load(f)
    if a.device is None:
        name = ((res or {}).get("meta", {}).get("device_name") or "").lower()
        a.device = "h200" if "h200" in name else "h100"
    d = DEVICES[a.device]
    print(f"# Roofline, {d['name']}: {d['bw_measured'] / 1e12:.2f} TB/s measured copy bandwidth "
          f"({d['bw_spec'] / 1e12:.2f} spec), {d['fp32'] / 1e12:.0f} TFLOP/s fp32, {d['fp64'] / 1e12:.0f} fp64\n")
    print("## Staged kernels (one kernel per stage; the column solves one thread per column)\n")
    print(table(a.device, a.prisms, res))
    print("\n## Fused step (one block per column, 16 steps per launch)\n")
    print(fused_table(a.device, a.prisms, res))
    if a.kernels:
        for base in ("FB", "RB"):
            for prec in ("fp32", "fp64"):
                print()
                print(kernel_table(50, base, prec, a.device))
    if a.json:
        out = [bound(npr, base, prec, a.device) for npr in a.prisms for base in ("FB", "RB") for prec in ("fp32", "fp64")]
        with open(a.json, "w") as f:
            json.dump(out, f, indent=1)


if __name__ == "__main__":
    main()
