"""The lane step (one warp per column, sim/lanes/lanes.py; on the CPU each warp is emulated by 32
fibers) against the staged kernels, an independent implementation of the same RATTLE: same numbers
to round-off, same flags; which batches it takes (``lane_support`` on a batch, ``lane_refusal`` on a
scene: they agree); and the policy that picks it (GPU decisions are pure functions of the inputs)."""

import dataclasses

import numpy as np
import pytest
import warp as wp

from warp_tensegrity import ColumnConfig, RunSettings, SettingsError, simulate_batch
from warp_tensegrity.sim.lanes.lanes import LANE_STEPS, LaneStep
from warp_tensegrity.policy.decide import decide, far_end
from warp_tensegrity.policy.lane_fit import lane_map, lane_refusal, lane_support
from warp_tensegrity.policy.paths import NOT_CHECKED, choose_path
from warp_tensegrity.scene.batch import column_batch
from warp_tensegrity.sweep import parse_spec
from warp_tensegrity.sweep.plan import plan_sweep
from warp_tensegrity.sweep.shard import compute_shard
from warp_tensegrity.types import Path

# flexible, elastic and nearly rigid bases in one batch; slack and prestressed impacts
MIXED = {"prestrain": [0.0, 0.002, 0.002], "v0": [0.005, 0.1, 0.05], "base_rigidity": [0.0, 0.5, 0.95]}
# the same with rigid bases (ring links as constraints: sim/lanes/lane_rigid.py), slack and prestressed
RIGID = {"prestrain": [0.0, 0.002, 0.002, 0.0, 0.002], "v0": [0.005, 0.1, 0.05, 0.005, 0.1],
         "base_rigidity": [0.0, 0.5, 0.95, 1.0, 1.0]}


def _run(cfg, params, fused, device, precision="fp64", **kw):
    kw = {"t_end": 0.05, "dt": 5e-4, "output_interval": 0.01, **kw}
    s = RunSettings(precision=precision, device=device, truncate=False, fused=fused, **kw)
    return simulate_batch(cfg, params, s)


def _rel(a, b, axis=(1, 2)):
    return np.abs(a - b).max(axis=axis) / np.abs(b).max(axis=axis)


@pytest.mark.parametrize("n, hand, shape, params", [
    (1, "right", (1, 1), RIGID),
    (2, "left", (1, 2), MIXED),
    (7, "RRLRLLR", (1, 8), RIGID),  # 4 columns per warp
    (50, "alternating", (1, 64), RIGID),  # rigid bases in fp64: 1 level per lane on 2 warps (lane_map)
    (100, "right", (4, 32), MIXED),
])
def test_lanes_match_staged_fp64(n, hand, shape, params, device):
    rigid = np.any(np.asarray(params["base_rigidity"]) >= 1.0)
    assert lane_map(n, rigid, "fp64") == shape
    cfg = ColumnConfig(n_prisms=n, handedness=hand)
    before = wp.config.enable_cpu_blocks
    staged = _run(cfg, params, False, device)
    lanes = _run(cfg, params, "lanes", device)
    assert wp.config.enable_cpu_blocks == before  # the CPU emulation is on only while the lane step runs
    P, G = shape
    assert lanes.info["step_path"].startswith(
        f"lanes (one warp per column: {P} levels per lane, {G} lanes per column" if G <= 32 else
        f"lanes ({G // 32} warps per column, one block: {P} levels per lane, {G} lanes per column")
    assert staged.info["step_path"].startswith("staged")
    assert np.all(staged.status == 0) and np.all(lanes.status == 0)
    assert np.all(np.abs(staged.strain).max(axis=(1, 2)) > 1e-3)  # every column moves
    assert np.all(_rel(lanes.strain, staged.strain) <= 1e-11), _rel(lanes.strain, staged.strain)
    # the whole state at t_end (the strain alone does not see a mirrored twist)
    for name in ("final_displacement", "final_velocity"):
        rel = _rel(getattr(lanes, name), getattr(staged, name))
        assert np.all(rel <= 1e-11), (name, rel)
    assert np.all(lanes.bar_length_error <= 1e-12), lanes.bar_length_error
    assert lanes.info["max_projection_iterations"] <= RunSettings().max_projection_iters


@pytest.mark.parametrize("params", [MIXED, RIGID], ids=["MIXED", "RIGID"])
def test_lanes_fp32_hold_the_bars(params, device, monkeypatch):
    """fp32, 64-step launches that end on every output step (100 steps per output). With the bar
    check in its fast-math form (lane_funcs.bar_check; on CUDA also with the approximate division
    and square root everywhere else, LANE_FAST_MATH and LANE_FAST_MATH_RIGID: issue 33 item 2)."""
    from warp_tensegrity.sim.lanes import lanes as lane_module

    make = lane_module.make_lane_kernel
    # fast math's form of the check on the CPU too, for rigid bases (flexible: the default kernel, kept lean)
    monkeypatch.setattr(lane_module, "make_lane_kernel",
                        lambda *a: make(*a[:5], a[5] or (a[0] == wp.float32 and a[4]), *a[6:]))
    cfg = ColumnConfig(n_prisms=7, handedness="left")
    kw = {"t_end": 0.1, "dt": 5e-4, "output_interval": 0.05}
    lanes = _run(cfg, params, "lanes", device, "fp32", **kw)
    ref = _run(cfg, params, False, device, "fp64", **kw)
    assert lanes.info["output_every"] == 100 and np.all(lanes.status == 0)
    assert np.all(lanes.bar_length_error <= 3e-7), lanes.bar_length_error
    assert np.all(_rel(lanes.strain, ref.strain) < 1e-4), _rel(lanes.strain, ref.strain)
    # the bars and ring links at the end, measured here (not through the kernel's own check)
    batch = column_batch(cfg, params)
    i, j = batch.constraints.T
    X = batch.positions[None] + lanes.final_displacement
    L0 = np.linalg.norm(batch.positions[j] - batch.positions[i], axis=-1)
    err = np.abs(np.linalg.norm(X[:, j] - X[:, i], axis=-1) / L0 - 1) * (batch.constraint_active > 0)
    assert np.all(err.max(axis=1) <= 4e-7), err.max(axis=1)


def test_lanes_flag_diverging_columns_and_spare_the_rest(device):
    """Columns 1 and 3 get cables 1e6 and 250 times stiffer: dt is then far (or ~2x) above their
    stability limit. Column 1 fails at once, column 3 after the first 64-step launch; the others
    (sharing their warp: 16 two-prism columns per warp) are bit for bit those of a batch without them."""
    cfg = ColumnConfig(n_prisms=2)
    cab = cfg.cable_EA
    params = {"prestrain": [0.002] * 4, "v0": [0.05] * 4, "base_rigidity": [0.0, 0.0, 0.5, 0.0],
              "cable_EA": [cab, cab * 1e6, cab, cab * 250]}
    kw = {"t_end": 0.1, "dt": 1e-3, "output_interval": 0.1, "allow_unstable_dt": True}
    r = _run(cfg, params, "lanes", device, **kw)
    alone = _run(cfg, {k: np.asarray(v)[[0, 2]] for k, v in params.items()}, "lanes", device, **kw)
    staged = _run(cfg, params, False, device, **kw)
    assert r.status[1] != 0 and r.fail_step[1] == staged.fail_step[1] == 1
    assert r.status[3] != 0 and 1 < r.fail_step[3] <= r.n_steps
    assert np.all(r.status[[0, 2]] == 0) and np.all(r.fail_step[[0, 2]] == -1)
    for name in ("strain", "final_displacement", "final_velocity", "bar_length_error"):
        np.testing.assert_array_equal(getattr(r, name)[[0, 2]], getattr(alone, name), err_msg=name)


SCENES = [  # (config, params, simulated prisms, words of the refusal or None)
    (ColumnConfig(n_prisms=7, handedness="alternating"), MIXED, None, None),
    (ColumnConfig(n_prisms=7), {"base_rigidity": [0.0, 1.0]}, None, None),
    (ColumnConfig(n_prisms=1, bar_mass=0.01), {}, None, "massive bars"),
    (ColumnConfig(n_prisms=1), {"base_rigidity": [1.0]}, None, None),
    (ColumnConfig(n_prisms=64, impact_admissibility="end_twist"), {"base_rigidity": [1.0]}, None, None),
    (ColumnConfig(n_prisms=65, impact_admissibility="end_twist"), {"base_rigidity": [0.0, 1.0]}, None, None),
    (ColumnConfig(n_prisms=1025, impact_admissibility="end_twist"), {"base_rigidity": [0.0, 1.0]}, None,
     "rigid bases with 1025 prisms"),
    (ColumnConfig(n_prisms=65, impact_admissibility="end_twist"), {"base_rigidity": [1.0]}, 64, None),
    # long columns (their impact velocity is not what is checked: the cheaper 'end_twist' one)
    (ColumnConfig(n_prisms=128, impact_admissibility="end_twist"), {"base_rigidity": [0.3]}, None, None),
    (ColumnConfig(n_prisms=129, impact_admissibility="end_twist"), {}, None, None),  # 2 warps a column
    (ColumnConfig(n_prisms=2049, impact_admissibility="end_twist"), {}, None, "levels per lane"),
    (ColumnConfig(n_prisms=129, handedness="alternating", impact_admissibility="end_twist"), {}, 100, None),
]  # the last: truncated to the 100 prisms at the impacted end


@pytest.mark.parametrize("cfg, params, n_sim, words", SCENES)
def test_lane_refusal_agrees_with_lane_support(cfg, params, n_sim, words):
    sim = far_end(cfg, n_sim) if n_sim else cfg
    on_batch = lane_support(column_batch(sim, params))
    on_scene = lane_refusal(cfg, params, n_sim)
    if words is None:
        assert on_batch is None and on_scene is None, (on_batch, on_scene)
    else:
        assert words in on_batch and words in on_scene, (on_batch, on_scene)


def test_the_cpu_runs_the_lane_step_only_emulated(monkeypatch):
    """Without Warp's CPU blocks each lane would be a block of its own (shuffles and votes would
    read nothing): the Integrator refuses rather than hang or compute garbage."""
    from warp_tensegrity.sim.integrate import Integrator

    monkeypatch.setattr(wp.config, "enable_cpu_blocks", False)
    with pytest.raises(SettingsError, match="CPU blocks"):
        Integrator(column_batch(ColumnConfig(n_prisms=2), {}), RunSettings(device="cpu"), 1e-4, 1, 2, path=Path.LANES)


def test_lane_support_refuses_other_networks():
    b = column_batch(ColumnConfig(n_prisms=3), {})
    assert lane_support(dataclasses.replace(b, level_nodes=None)) == "not a T3 column (no levels)"
    # one column of the batch with stiffer cross cables on one side: not a uniform column
    ea = np.array(b.cable_EA, dtype=np.float64, copy=True)
    ea[:, 0] *= 2
    assert "cross cables" in lane_support(dataclasses.replace(b, cable_EA=ea))


def test_policy_picks_the_lane_step_on_a_gpu():
    for prec in ("fp32", "fp64"):
        for B in (1, 1536, 16384, 131072):
            for fused in ("auto", True, "lanes"):
                assert choose_path(RunSettings(precision=prec, fused=fused), True, B, 3, None) == Path.LANES
            # a batch it does not take (or one nobody checked): the measured policy as before
            for why in ("rigid bases with 65 prisms", NOT_CHECKED):
                for fused in ("auto", True):
                    s = RunSettings(precision=prec, fused=fused)
                    assert choose_path(s, True, B, 3, why) == choose_path(s, True, B, 3) != Path.LANES
    assert choose_path(RunSettings(fused=False), True, 4096, 3, None) == Path.STAGED
    assert choose_path(RunSettings(method="rk4"), True, 4096, 3, None) == Path.STAGED
    # the CPU: never chosen (fiber emulation is slow), only asked for
    assert choose_path(RunSettings(), False, 4, 3, None) == Path.FUSED
    assert choose_path(RunSettings(fused=True), False, 4, 3, None) == Path.FUSED
    assert choose_path(RunSettings(fused="lanes"), False, 4, 3, None) == Path.LANES
    for on_gpu in (True, False):
        with pytest.raises(SettingsError, match="fused = 'lanes'.*massive bars"):
            choose_path(RunSettings(fused="lanes"), on_gpu, 4, 3, "massive bars (consistent bar inertia)")
    with pytest.raises(SettingsError, match="not checked"):
        choose_path(RunSettings(fused="lanes"), True, 4, 3)
    with pytest.raises(SettingsError, match="rattle"):
        RunSettings(fused="lanes", method="rk4")
    with pytest.raises(SettingsError, match="fused"):
        RunSettings(fused="lane")


def test_estimate_plan_and_run_name_the_same_path(device):
    cfg = ColumnConfig(n_prisms=4)
    params = {"v0": [0.01, 0.02], "base_rigidity": [0.0, 0.5]}
    s = RunSettings(t_end=0.01, dt=5e-4, device=device, truncate=False, fused="lanes")
    est = decide(cfg, params, s)
    assert est.path == Path.LANES and est.lane_refusal is None
    auto = decide(cfg, params, dataclasses.replace(s, fused="auto"))
    assert auto.path == choose_path(RunSettings(), auto.on_gpu, 2, auto.bandwidth, None)
    long = ColumnConfig(n_prisms=1025, impact_admissibility="end_twist")
    with pytest.raises(SettingsError, match="rigid bases with 1025 prisms"):
        decide(long, {"base_rigidity": [0.0, 1.0]}, s)
    with pytest.raises(SettingsError, match="rigid bases with 1025 prisms"):
        simulate_batch(long, {"base_rigidity": [0.0, 1.0]}, s)
    # a sweep: the plan names the path, and its shards take it (decided once for all columns)
    spec = parse_spec('[scene]\nn_prisms = 4\n[sweep]\ngrid = { v0 = [0.01, 0.02] }\n[run]\nt_end = 0.01\n'
                      f'dt = 5e-4\ntruncate = false\nfused = "lanes"\ndevice = "{device}"\n')
    plan = plan_sweep(spec, shard_size=1)
    assert plan.run.path == Path.LANES
    assert compute_shard(plan, 1).attrs["step_path"].startswith("lanes")
    # a shard runs its group's plan and path, whatever its columns (one group here: dt is given)
    (g,) = plan.groups
    plan.groups = (dataclasses.replace(g, plan=dataclasses.replace(g.plan, path=Path.STAGED)),)
    assert compute_shard(plan, 0).attrs["step_path"].startswith("staged")


def test_plan_names_the_lane_step_on_a_gpu(monkeypatch):
    """The dry run on a GPU (a stand-in device: CI has none) names the lane step for a sweep with
    flexible, elastic or rigid bases up to 1,024 prisms (past 64 on k warps per column), and the
    measured table's path for a rigid-base sweep of longer columns (decided per sweep)."""
    from types import SimpleNamespace

    from warp_tensegrity.policy import decide as policy_decide

    monkeypatch.setattr(policy_decide, "resolve_device", lambda name: SimpleNamespace(
        is_cuda=True, alias="cuda:0", total_memory=80e9, free_memory=80e9, context=None))
    text = '[scene]\nn_prisms = %d\nimpact_admissibility = "end_twist"\n' \
           '[sweep]\ngrid = { v0 = [0.01, 0.02], base_rigidity = [0.0, %s] }\n' \
           '[run]\nt_end = 0.01\nprecision = "fp32"\ntruncate = false\n'
    for n, beta in ((4, "0.5"), (4, "1.0"), (64, "1.0"), (65, "1.0")):
        plan = plan_sweep(parse_spec(text % (n, beta)), shard_size=2)
        assert plan.run.lane_refusal is None and plan.run.path == Path.LANES, (n, beta)
    plan = plan_sweep(parse_spec(text % (1025, "1.0")), shard_size=2)
    assert "rigid bases with 1025" in plan.run.lane_refusal and plan.run.path == Path.FUSED_SERIAL


DIVERGING = {"prestrain": [0.002] * 4, "v0": [0.05] * 4, "base_rigidity": [0.0, 0.0, 0.5, 0.0],
             "cable_EA": [1.0, 1e6, 1.0, 250.0]}  # x the scene's EA: columns 1 and 3 fail (see above)


@pytest.mark.parametrize("n, hand, params, precision, kw", [
    (7, "RRLRLLR", RIGID, "fp64", {}),  # 4 columns per warp, rigid bases
    (50, "alternating", MIXED, "fp32", {}),  # 2 levels per lane
    (2, "right", DIVERGING, "fp64", {"t_end": 0.1, "dt": 1e-3, "allow_unstable_dt": True}),
    (5, "right", {"prestrain": [0.002, 0.004], "v0": [0.01, 0.02], "base_rigidity": [1.0, 0.0],
                  "preload": [1e-3, 5e-4]}, "fp64", {}),  # an end preload: a dead load, strain from its equilibrium
])
def test_records_inside_the_lane_step_are_the_record_kernels(n, hand, params, precision, kw, device, monkeypatch):
    """Issue 33 item 1: the lane kernel writes the records of the outputs its launches span. Against
    the record kernels run after launches that end on every output (as before): the same strain
    and feasibility record, bit for bit (the same @wp.func bodies on the same state; on CUDA in fp32
    to a few ulps, the lane kernel's fast math), and the energies to round-off (summed lane by lane,
    in another order)."""
    cfg = ColumnConfig(n_prisms=n, handedness=hand)
    if "cable_EA" in params:
        params = {**params, "cable_EA": np.asarray(params["cable_EA"]) * cfg.cable_EA}
    kw = {"t_end": 0.05, "dt": 5e-4, "output_interval": 4 * kw.get("dt", 5e-4), **kw}
    inside = _run(cfg, params, "lanes", device, precision, **kw)
    assert round(kw["output_interval"] / kw["dt"]) < LANE_STEPS < inside.n_steps  # a launch spans outputs
    monkeypatch.setattr(LaneStep, "records_inside", False)
    after = _run(cfg, params, "lanes", device, precision, **kw)
    np.testing.assert_array_equal(inside.status, after.status)
    np.testing.assert_array_equal(inside.fail_step, after.fail_step)
    if "cable_EA" in params:
        assert np.count_nonzero(inside.status) == 2
    if device != "cpu" and precision == "fp32" and not np.any(np.asarray(params["base_rigidity"]) >= 1):
        # CUDA's approximate division and square root in the lane kernel (LANE_FAST_MATH), not in the
        # record kernels: the same to a few fp32 ulps
        np.testing.assert_allclose(inside.strain, after.strain, rtol=0, atol=1e-5 * np.abs(after.strain).max())
        for k, v in after.feasibility.items():
            np.testing.assert_allclose(inside.feasibility[k], v, rtol=1e-5, atol=0, err_msg=k)
    else:
        np.testing.assert_array_equal(inside.strain, after.strain)
        for k, v in after.feasibility.items():
            np.testing.assert_array_equal(inside.feasibility[k], v, err_msg=k)
    if precision == "fp32":  # each member's stretch rounds differently here (lane geometry): against fp64
        ref = _run(cfg, params, False, device, "fp64", **kw)
    for name in ("kinetic_energy", "elastic_energy", "station_energy", "end_energy"):  # the last two: energy measures
        a, b = getattr(inside, name), getattr(after, name)
        assert np.nanmax(np.abs(b)) > 0, name
        np.testing.assert_array_equal(np.isnan(a), np.isnan(b))
        scale = np.nanmax(np.abs(b), axis=1)
        if precision == "fp64":
            assert np.all(np.nanmax(np.abs(a - b), axis=1) <= 1e-13 * scale), name
        else:  # no further from fp64 than the record kernels' (1.9e-4 of a p = 0 column's elastic energy)
            err = [np.nanmax(np.abs(x - getattr(ref, name)), axis=1) / scale for x in (a, b)]
            assert np.all(err[0] <= 1.25 * err[1]), (name, err)


def _lanes_with(monkeypatch, device, cfg, params, precision, knobs, **kw):
    """A lane run with the lane module's switches ``knobs`` ({dict name: value} for ``precision``);
    returns (result, u, v, a, iters) at the end."""
    from warp_tensegrity.sim import integrate
    from warp_tensegrity.sim.lanes import lanes

    seen = []

    class Seen(integrate.Integrator):
        def run_steps(self, *a, **k):  # the engine steps through it (Integrator.run drives it too)
            seen.append(self)
            return super().run_steps(*a, **k)

    with monkeypatch.context() as m:
        for name, value in knobs.items():
            m.setitem(getattr(lanes, name), precision, value)
        m.setattr(integrate, "Integrator", Seen)
        r = _run(cfg, params, "lanes", device, precision, **kw)
    d = seen[0].data
    return r, d.u.numpy(), d.v.numpy(), d.a.numpy(), d.iters.numpy()


def test_lanes_keep_the_accelerations_in_memory_bit_for_bit(device, monkeypatch):
    """Issue 33 item 2: with the accelerations in memory between the forces and the next half kick
    (LANE_A_MEM: not in registers through the factor and Newton), the same bits everywhere, the
    state a failing column leaves (its u, v and the a of its last good step) included."""
    cfg = ColumnConfig(n_prisms=2)
    params = {**DIVERGING, "cable_EA": np.asarray(DIVERGING["cable_EA"]) * cfg.cable_EA}
    kw = {"t_end": 0.1, "dt": 1e-3, "output_interval": 0.1, "allow_unstable_dt": True}
    on = _lanes_with(monkeypatch, device, cfg, params, "fp64", {"LANE_A_MEM": True}, **kw)
    off = _lanes_with(monkeypatch, device, cfg, params, "fp64", {"LANE_A_MEM": False}, **kw)
    assert np.count_nonzero(on[0].status) == 2 and np.any(on[3] != 0)
    np.testing.assert_array_equal(on[0].status, off[0].status)
    np.testing.assert_array_equal(on[0].fail_step, off[0].fail_step)
    for x, y, name in zip(on[1:], off[1:], ("u", "v", "a", "iters")):
        np.testing.assert_array_equal(x, y, err_msg=name)


def test_lanes_mixed_precision_is_fp64(device, monkeypatch):
    """Issue 33 item 2: fp64 columns with an fp32 factor and solves, fp64 residuals and iterative
    refinement (LANE_MIXED; passes from the probe's kappa u32: 2 here, for the rigid bases'
    kappa ~ 1e4; flexible bases get 1) against the fp64 factor: the same to 1e-12, with the same Newton counts. (Without the
    refinement the velocities differ by ~1e-8.)"""
    cfg = ColumnConfig(n_prisms=7, handedness="RRLRLLR")
    on = _lanes_with(monkeypatch, device, cfg, RIGID, "fp64", {"LANE_MIXED": True})
    off = _lanes_with(monkeypatch, device, cfg, RIGID, "fp64", {"LANE_MIXED": False})
    for name in ("strain", "final_displacement", "final_velocity"):
        rel = _rel(getattr(on[0], name), getattr(off[0], name))
        assert np.all(rel <= 1e-12), (name, rel)
    np.testing.assert_array_equal(on[4], off[4])  # Newton iterations per column
    assert np.all(on[0].bar_length_error <= 1e-12)


@pytest.mark.parametrize("real", [wp.float32, wp.float64])
def test_the_fast_math_bar_check_is_the_bar_check(real):
    """lane_funcs.bar_check's fast-math form (no square root in r, square roots only in a factor of
    e) against common.bar_residual: r to round-off of |b|^2, e to 1e-6 of itself wherever e is above
    the rounding of |b| - L."""
    from warp_tensegrity.sim.common import bar_residual, cable_energy2, cable_force
    from warp_tensegrity.sim.lanes.lane_funcs import make_lane_funcs
    from warp_tensegrity.sim.lanes.lane_ops import make_lane_ops

    plain, fast = (make_lane_funcs(real, 1, 2, make_lane_ops(real), cable_force, bar_residual, cable_energy2,
                                   robust_check=c).bar_check for c in (False, True))
    vec = make_lane_ops(real).vec

    @wp.kernel(enable_backward=False, module="unique")
    def both(b: wp.array(dtype=vec), b0: wp.array(dtype=vec), out: wp.array2d(dtype=real)):
        i = wp.tid()
        r, e = plain(b[i], b0[i])
        rr, ee = fast(b[i], b0[i])
        out[i, 0] = r
        out[i, 1] = e
        out[i, 2] = rr
        out[i, 3] = ee

    rng = np.random.default_rng(3)
    b0 = rng.normal(size=(4000, 3))
    b = b0 * (1 + np.logspace(-7, -1, 4000) * rng.choice([-1, 1], 4000))[:, None]  # relative errors 1e-7 .. 0.1
    npr = np.float32 if real == wp.float32 else np.float64
    out = wp.zeros((4000, 4), dtype=real, device="cpu")
    wp.launch(both, 4000, inputs=[wp.array(b.astype(npr), dtype=vec, device="cpu"),
                                  wp.array(b0.astype(npr), dtype=vec, device="cpu"), out], device="cpu")
    r, e, rr, ee = out.numpy().astype(np.float64).T
    eps = np.finfo(npr).eps
    bb = (b.astype(npr).astype(np.float64) ** 2).sum(1)
    assert np.all(np.abs(rr - r) <= 4 * eps * bb)
    big = e > 100 * eps
    assert big.sum() > 2000 and np.all(np.abs(ee[big] / e[big] - 1) <= 1e-6 + 20 * eps / e[big])
