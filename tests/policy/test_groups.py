"""A sweep's columns in groups of like stiffness (policy/groups.py): bands of omega within
GROUP_RATIO, rigid bases apart, narrow bands joined to a stiffer neighbour, one plan per group."""

import numpy as np

from warp_tensegrity import ColumnConfig, RunSettings
from warp_tensegrity.policy.decide import decide
from warp_tensegrity.policy.groups import GROUP_RATIO, column_omega, decide_groups, stiffness_bands
from warp_tensegrity.scene.batch import column_batch, column_params, omega_max_bound


def test_bands_keep_rigid_apart_and_omega_within_the_ratio():
    rng = np.random.default_rng(0)
    omega = np.exp(rng.uniform(np.log(100), np.log(2000), 300))
    rigid = rng.random(300) < 0.3
    groups = stiffness_bands(omega, rigid)
    assert sorted(np.concatenate(groups).tolist()) == list(range(300))  # a partition
    for g in groups:
        assert len(set(rigid[g])) == 1
        assert omega[g].max() <= GROUP_RATIO * omega[g].min()
    # narrow bands join a stiffer neighbour: every group but possibly one per class holds >= 40
    for g in stiffness_bands(omega, rigid, min_columns=40):
        assert g.size >= 40


def test_column_omega_is_each_columns_bound():
    cfg = ColumnConfig(n_prisms=12)
    p = column_params(cfg, {"prestrain": [0.0, 0.004, 0.01], "v0": 0.01, "base_rigidity": [0.0, 0.9, 1.0]})
    np.testing.assert_allclose(column_omega(cfg, p), omega_max_bound(column_batch(cfg, p)), rtol=1e-12)


def test_groups_step_each_at_its_own_dt():
    cfg = ColumnConfig(n_prisms=8)
    beta = np.repeat([0.0, 0.95, 1.0, 0.5], 70)  # bands of 70 columns: none narrower than MIN_GROUP_COLUMNS
    params = {"prestrain": 0.002, "v0": 0.01, "base_rigidity": beta}
    s = RunSettings(t_end=0.5, output_interval=0.01, device="cpu")
    groups = decide_groups(cfg, params, s)
    one = decide(cfg, params, s)
    assert sorted(np.concatenate([g.columns for g in groups]).tolist()) == list(range(beta.size))
    assert {g.plan.n_out for g in groups} == {one.n_out}
    assert max(g.plan.dt for g in groups) > 3 * one.dt  # the rigid-base group steps far less often
    assert min(g.plan.dt for g in groups) == one.dt  # the stiffest group sets the one-plan dt
    assert len(groups) == 3  # rigid; FB with beta = 0.5 (omega 1.3x); beta = 0.95 (omega 3.5x FB)
    for g in groups:  # each group's dt is the plan decide gives its columns alone
        assert g.plan.dt == decide(cfg, {k: np.broadcast_to(v, beta.size)[g.columns] for k, v in params.items()}, s).dt
    # grouping off, or an explicit dt: one group, the one plan
    (only,) = decide_groups(cfg, params, s, grouping=False)
    assert only.plan.dt == one.dt and only.n_columns == beta.size
