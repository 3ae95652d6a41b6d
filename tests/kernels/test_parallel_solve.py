"""The fused step's lane-parallel constraint solve (block cyclic reduction, sim/block/coop.py).

Warp's CPU device runs a block's lanes only with ``wp.config.enable_cpu_blocks``; every test here
switches it on, so the lane split and the barriers of the GPU kernel run in CI.
"""

import numpy as np
import pytest
import warp as wp

from warp_tensegrity import ColumnConfig, RunSettings, simulate_batch
from warp_tensegrity.sim.block import step as block_step
from warp_tensegrity.sim.block.coop import block_sync, make_cr_funcs


@pytest.fixture
def lanes(monkeypatch):
    """Emulated lanes on the CPU, with the solver and node rows in the block's shared buffer."""
    def use(n):
        monkeypatch.setattr(wp.config, "enable_cpu_blocks", True)
        monkeypatch.setattr(block_step, "FUSED_BLOCK_DIM", n)
        monkeypatch.setattr(block_step, "FUSED_SHARED_ON_CPU", True)
    return use


_SOLVE_KERNELS = {}


def _solve_kernel(S):
    """Test kernel: column w's system from ``sys[w]`` (layout of make_cr_funcs), reduce, solve."""
    if S in _SOLVE_KERNELS:
        return _SOLVE_KERNELS[S]
    cr = make_cr_funcs(wp.float64, S)

    @wp.kernel(enable_backward=False, module="unique")
    def cr_test(sys: wp.array2d(dtype=wp.float64), nb: int, ok: wp.array2d(dtype=int)):
        w, lane = wp.tid()
        x = sys[w]
        ok[w, lane] = cr.cr_factor(x, nb, lane, wp.block_dim())
        block_sync()
        cr.cr_solve(x, nb, lane, wp.block_dim())

    _SOLVE_KERNELS[S] = cr_test
    return cr_test


def _random_system(rng, nb, S, spd=True):
    """A random SPD block-tridiagonal matrix (diagonally weighted), its blocks in the kernel's layout."""
    n = nb * S
    Araw = np.zeros((n, n))
    for i in range(nb):
        Araw[i * S:(i + 1) * S, i * S:(i + 1) * S] = rng.normal(size=(S, S))
        if i:
            Araw[i * S:(i + 1) * S, (i - 1) * S:i * S] = rng.normal(size=(S, S))
    A = Araw @ Araw.T  # SPD, but with a wider band: keep its block-tridiagonal part and make it SPD
    mask = np.zeros((n, n), bool)
    for i in range(nb):
        for j in (i - 1, i, i + 1):
            if 0 <= j < nb:
                mask[i * S:(i + 1) * S, j * S:(j + 1) * S] = True
    A = np.where(mask, A, 0.0)
    A += np.eye(n) * (np.abs(A).sum(axis=1).max() if spd else -np.abs(A).sum(axis=1).max())
    b = rng.normal(size=n)
    D = np.stack([A[i * S:(i + 1) * S, i * S:(i + 1) * S] for i in range(nb)])
    E = np.stack([A[i * S:(i + 1) * S, (i - 1) * S:i * S] if i else np.zeros((S, S)) for i in range(nb)])
    row = np.concatenate([b, D.ravel(), E.ravel(), np.zeros(3 * nb * S * S)])
    return A, b, row


@pytest.mark.parametrize("S", [1, 3, 6])
@pytest.mark.parametrize("block_dim", [1, 4, 32])
def test_block_cyclic_reduction_matches_numpy(S, block_dim, monkeypatch):
    monkeypatch.setattr(wp.config, "enable_cpu_blocks", True)
    rng = np.random.default_rng(S * 100 + block_dim)
    kern = _solve_kernel(S)
    for nb in (1, 2, 3, 5, 8, 13, 50):
        systems = [_random_system(rng, nb, S) for _ in range(3)]
        sys = wp.array(np.stack([r for _, _, r in systems]), dtype=wp.float64, device="cpu")
        ok = wp.zeros((3, block_dim), dtype=int, device="cpu")
        wp.launch_tiled(kern, dim=[3], inputs=[sys, nb, ok], block_dim=block_dim, device="cpu")
        out = sys.numpy()
        assert np.all(ok.numpy().min(axis=1) == 1)
        for w, (A, b, _) in enumerate(systems):
            x = np.linalg.solve(A, b)
            np.testing.assert_allclose(out[w, :nb * S], x, rtol=0, atol=1e-12 * np.abs(x).max())


def test_block_cyclic_reduction_flags_an_indefinite_matrix(monkeypatch):
    monkeypatch.setattr(wp.config, "enable_cpu_blocks", True)
    rng = np.random.default_rng(7)
    kern = _solve_kernel(3)
    A, b, row = _random_system(rng, 9, 3, spd=False)
    assert np.linalg.eigvalsh(A).min() < 0
    sys = wp.array(row[None, :], dtype=wp.float64, device="cpu")
    ok = wp.zeros((1, 4), dtype=int, device="cpu")
    wp.launch_tiled(kern, dim=[1], inputs=[sys, 9, ok], block_dim=4, device="cpu")
    assert ok.numpy().min() == 0


def _pair(cfg, params, precision="fp64", t_end=0.03, dt=5e-4):
    out = {}
    for fused in (False, True):
        s = RunSettings(t_end=t_end, dt=dt, precision=precision, device="cpu", fused=fused, truncate=False,
                        output_interval=min(0.01, t_end))  # the options model: output_interval <= t_end
        out[fused] = simulate_batch(cfg, params, s)
    return out[False], out[True]


COLUMNS = {  # (config, params): FB, RB, continuous base rigidity (elastic base members), mixed handedness
    "FB-RB-beta": (ColumnConfig(n_prisms=7), {"base_rigidity": [0.0, 1.0, 0.4], "v0": [0.1, 0.1, 0.05],
                                              "prestrain": [0.002, 0.0, 0.001]}),
    "mixed": (ColumnConfig(n_prisms=7, handedness="LRRLRLL"), {"base_rigidity": [0.0, 1.0], "v0": [0.1, 0.1],
                                                               "prestrain": [0.002, 0.002]}),
    "1-prism": (ColumnConfig(n_prisms=1), {"base_rigidity": [0.0, 1.0], "v0": [0.1, 0.1]}),
    "2-prisms": (ColumnConfig(n_prisms=2, handedness="LR"), {"base_rigidity": [0.0, 1.0], "v0": [0.1, 0.1]}),
}


@pytest.mark.parametrize("case", list(COLUMNS))
def test_lane_parallel_step_matches_staged(case, lanes):
    lanes(4)
    cfg, params = COLUMNS[case]
    staged, fused = _pair(cfg, params)
    assert "block cyclic reduction, 4 lanes" in fused.info["step_path"]
    assert np.all(staged.status == 0) and np.all(fused.status == 0)
    scale = np.abs(staged.strain).max(axis=(1, 2))
    assert np.all(scale > 1e-7)
    rel = np.abs(fused.strain - staged.strain).max(axis=(1, 2)) / scale
    assert np.all(rel < 1e-10), rel
    assert np.all(fused.bar_length_error <= 1e-12) and np.all(fused.bar_length_error > 0)
    np.testing.assert_allclose(fused.final_velocity, staged.final_velocity, rtol=0,
                               atol=1e-10 * np.abs(staged.final_velocity).max())


def test_lane_parallel_step_50_prisms(lanes):
    """50 prisms (nb = 50 blocks: six CR levels) FB and RB, 32 lanes, few steps."""
    lanes(32)
    cfg = ColumnConfig(n_prisms=50)
    params = {"base_rigidity": [0.0, 1.0], "v0": [0.1, 0.1], "prestrain": [0.002, 0.002]}
    staged, fused = _pair(cfg, params, t_end=0.004, dt=5e-4)
    assert np.all(staged.status == 0) and np.all(fused.status == 0)
    for name in ("final_displacement", "final_velocity"):  # 8 steps: compare the end state
        a, b = getattr(staged, name), getattr(fused, name)
        scale = np.abs(a).max(axis=(1, 2))
        rel = np.abs(b - a).max(axis=(1, 2)) / scale
        assert np.all(scale > 0) and np.all(rel < 1e-10), (name, rel)
    assert np.all(fused.bar_length_error <= 1e-12) and np.all(fused.bar_length_error > 0)


def test_lane_parallel_step_fp32(lanes):
    lanes(8)
    cfg, params = COLUMNS["FB-RB-beta"]
    staged, fused = _pair(cfg, params, precision="fp32")
    scale = np.abs(staged.strain).max(axis=(1, 2))
    rel = np.abs(fused.strain - staged.strain).max(axis=(1, 2)) / scale
    assert np.all(rel < 1e-3), rel
    assert np.all(fused.bar_length_error <= 1e-6)


def test_fused_node_slots_are_the_types_slots():
    from warp_tensegrity.sim import common
    from warp_tensegrity.types import Slot

    assert common.NQ == len(Slot)
    assert [int(c) for c in (common.U, common.V, common.P, common.I)] == [int(s) for s in Slot]


def test_auto_path_policy_picks_the_fastest_measured_path():
    """On a GPU, 'auto' takes the fastest of fused (CR), fused-serial and staged measured for the
    band, precision and batch; the table is the benchmark's JSON (3 significant digits)."""
    import json
    from pathlib import Path as FsPath

    from warp_tensegrity import SettingsError
    from warp_tensegrity.policy.paths import FUSED_MAX_BANDWIDTH, MEASURED_H100, MEASURED_PATHS, choose_path
    from warp_tensegrity.types import Path

    res = FsPath(__file__).parents[2] / "benchmarks/results"
    doc = json.loads((res / "throughput_h100_solver.json").read_text())
    assert "H100" in doc["meta"]["device_name"]
    seen = 0
    for pt in doc["points"]:
        if pt.get("sweep") != "batch":
            continue
        band = 3 if pt["base"] == "FB" else 6
        rate = MEASURED_H100[band][pt["precision"]][pt["B"]][MEASURED_PATHS.index(Path(pt["path"]))]
        assert rate == pytest.approx(pt["column_steps_per_s"], rel=6e-3), pt
        seen += 1
    assert seen == 2 * 2 * 5 * 3
    for band, by_prec in MEASURED_H100.items():
        for prec, rows in by_prec.items():
            for B, rates in rows.items():
                fastest = MEASURED_PATHS[int(np.argmax(rates))]
                auto = RunSettings(precision=prec)
                assert choose_path(auto, True, B, band) == fastest
                fused = MEASURED_PATHS[int(np.argmax(rates[:2]))]
                assert choose_path(RunSettings(precision=prec, fused=True), True, B, band) == fused
    # the regression this table fixes: RB at 4,096 columns takes the serial solve, 65,536 the staged kernels
    assert choose_path(RunSettings(precision="fp32"), True, 4096, 6) == Path.FUSED_SERIAL
    assert choose_path(RunSettings(precision="fp64"), True, 4096, 6) == Path.FUSED_SERIAL
    assert choose_path(RunSettings(precision="fp64"), True, 100_000, 6) == Path.STAGED
    fp32 = RunSettings(precision="fp32")
    assert choose_path(fp32, True, 1, 3) == choose_path(fp32, True, 1024, 3)  # below the table: its first row
    assert choose_path(RunSettings(), False, 10**6, 6) == Path.FUSED  # CPU: one lane, no crossover measured
    assert choose_path(RunSettings(fused=True), False, 4, 6) == Path.FUSED
    assert choose_path(RunSettings(), False, 4, FUSED_MAX_BANDWIDTH + 1) == Path.STAGED  # generic wide band
    assert choose_path(RunSettings(method="rk4"), True, 4, 3) == Path.STAGED
    assert choose_path(RunSettings(fused=False), True, 4096, 6) == Path.STAGED
    with pytest.raises(SettingsError, match="Gram band is 12 wide"):
        choose_path(RunSettings(fused=True), True, 4, 12)


@pytest.mark.parametrize("case,shared", [("FB-RB-beta", True), ("mixed", True), ("mixed", False)])
def test_serial_solver_variant_matches_staged_and_cr(case, shared, lanes, monkeypatch):
    """The fused step with lane 0's banded Cholesky (Path.FUSED_SERIAL, the staged threads' band
    bodies) against the staged kernels and the CR fused step, fp64, 4 emulated lanes."""
    from warp_tensegrity.policy import decide as policy
    from warp_tensegrity.types import Path

    lanes(4)
    monkeypatch.setattr(block_step, "FUSED_SHARED_ON_CPU", shared)
    cfg, params = COLUMNS[case]
    s = RunSettings(t_end=0.03, dt=5e-4, device="cpu", truncate=False, output_interval=0.01)
    out = {}
    for path in (Path.STAGED, Path.FUSED, Path.FUSED_SERIAL):
        monkeypatch.setattr(policy, "choose_path", lambda *a, p=path, **k: p)
        out[path] = simulate_batch(cfg, params, s)
    ser = out[Path.FUSED_SERIAL]
    assert ser.info["step_path"].startswith("fused-serial (serial banded Cholesky on lane 0, 4 lanes")
    assert ("shared/" if shared else "global/") in ser.info["step_path"]
    assert np.all(ser.status == 0)
    for ref in (out[Path.STAGED], out[Path.FUSED]):
        scale = np.abs(ref.strain).max(axis=(1, 2))
        assert np.all(scale > 1e-7)
        assert np.all(np.abs(ser.strain - ref.strain).max(axis=(1, 2)) / scale < 1e-10)
        np.testing.assert_allclose(ser.final_velocity, ref.final_velocity, rtol=0,
                                   atol=1e-10 * np.abs(ref.final_velocity).max())
    assert np.all(ser.bar_length_error <= 1e-12) and np.all(ser.bar_length_error > 0)


def test_lane_parallel_step_with_massive_bars(lanes):
    """A free class-1 prism whose mass is in its bars: M^-1 couples each bar's two nodes, so lanes
    read the impulses and forces their partner nodes' lanes wrote (the barrier between the
    gather and the M^-1 pass)."""
    from warp_tensegrity import Network, network_batch, run_batch
    from tests.references.reference import ReferenceSystem
    from warp_tensegrity.scene.columns import build_column

    lanes(4)
    net = build_column(ColumnConfig(n_prisms=1), prestrain=0.01).network
    free = Network(positions=net.positions, node_mass=0.0, fixed=False, bars=net.bars, bar_mass=0.01,
                   cables=net.cables, cable_EA=net.cable_EA, cable_rest_length=net.cable_rest_length).validate()
    v = ReferenceSystem(free).project_velocities(free.positions,
                                                 np.random.default_rng(3).normal(scale=0.01, size=(free.n_nodes, 3)))
    out = {}
    for fused in (False, True):
        s = RunSettings(t_end=0.02, dt=2.5e-4, fused=fused, output_interval=0.01, device="cpu")
        out[fused] = run_batch(network_batch([free, free], [v, -v]), s)
    a, b = out[False], out[True]
    assert "4 lanes" in b.info["step_path"]
    scale = np.abs(a.final_velocity).max()
    assert scale > 1e-4
    np.testing.assert_allclose(b.final_velocity, a.final_velocity, rtol=0, atol=1e-10 * scale)
    np.testing.assert_allclose(b.final_displacement, a.final_displacement, rtol=0,
                               atol=1e-10 * np.abs(a.final_displacement).max())
    assert np.all(b.bar_length_error <= 1e-12)


def test_dry_run_names_the_fused_serial_path_on_a_gpu(monkeypatch):
    """decide (the dry run's run plan) reports the path the policy picks on a GPU: the lane step for
    columns it takes (flexible, elastic or rigid bases up to 1,024 prisms, past 64 on k warps per
    column) at any width; RB columns longer than that (the lane step refuses them) the measured table's RB rows: fused-serial at
    4,096 and 1,024 columns, staged at 65,536 (a stand-in device: CI has no GPU). The width is the
    plan's shard width (``n_columns``), so no 65,536-column batch is built."""
    from types import SimpleNamespace

    from warp_tensegrity.policy import decide as policy_decide
    from warp_tensegrity.policy.decide import decide

    monkeypatch.setattr(policy_decide, "resolve_device", lambda name: SimpleNamespace(
        is_cuda=True, alias="cuda:0", total_memory=80e9, free_memory=80e9, context=None))

    def path(cfg, betas, width):  # the run plan the dry run prints, for shards of ``width`` columns
        return str(decide(cfg, {"base_rigidity": np.asarray(betas, float)}, s, n_columns=width).path.value)

    cfg = ColumnConfig(n_prisms=3)
    s = RunSettings(t_end=0.01, precision="fp32", truncate=False)
    assert path(cfg, [1.0, 1.0], 4096) == "lanes"
    assert path(cfg, [0.0, 0.0], 65536) == path(cfg, [0.0, 0.0], 1024) == "lanes"
    assert path(ColumnConfig(n_prisms=65, impact_admissibility="end_twist"), [1.0, 1.0], 4096) == "lanes"
    long = ColumnConfig(n_prisms=1025, impact_admissibility="end_twist")
    assert path(long, [1.0, 1.0], 4096) == "fused-serial"
    one_rb = [0.0, 0.0, 1.0]  # a rigid-base column anywhere in the sweep keeps the lane step from long columns
    assert path(cfg, one_rb, 65536) == "lanes"
    assert path(long, one_rb, 65536) == "staged"
    assert path(long, one_rb, 1024) == "fused-serial"
