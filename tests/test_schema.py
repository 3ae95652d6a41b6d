"""The device arrays are declared once (types.MODEL_FIELDS, DATA_FIELDS, SCRATCH_FIELDS): the
docstring table, Model, Data, the fused step's struct, the launch argument groups and the
hand-written kernels' ``# Model:`` arguments agree with the declarations, and a new field
declared there reaches Model, the struct and its argument groups with no other edit (besides
computing its values in model.host_arrays and reading it in a kernel)."""

import dataclasses

import numpy as np
import pytest
import warp as wp

from warp_tensegrity import ColumnConfig, RunSettings, types
from warp_tensegrity.sim import fields_gen, model
from warp_tensegrity.sim.integrate import Integrator
from warp_tensegrity.sim.block import kernels as fused
from warp_tensegrity.sim.staged.kernels import make_kernels
from warp_tensegrity.sim.staged.solver import make_gram_struct, make_solver_kernels
from warp_tensegrity.scene.batch import column_batch
from warp_tensegrity.types import ARGUMENT_GROUPS, DATA_FIELDS, MODEL_FIELDS, SCRATCH_FIELDS, Field, Path, group_fields

PARAMS = {"prestrain": [0.002, 0.0], "v0": [0.05, 0.1], "base_rigidity": [0.0, 1.0]}
FUSED_CACHES = (fused.make_node_funcs, fused.make_factor_funcs, fused.make_column_funcs, fused.make_step_funcs,
                fused.make_fused_kernels)


def _integrator(path=Path.FUSED, n_prisms=3):
    batch = column_batch(ColumnConfig(n_prisms=n_prisms), PARAMS)
    return Integrator(batch, RunSettings(device="cpu", precision="fp64"), 2e-4, 5, 3, path=path)


def test_names_are_unique_and_groups_known():
    names = [f.name for f in MODEL_FIELDS + DATA_FIELDS + SCRATCH_FIELDS]
    assert len(names) == len(set(names))
    assert {g for f in MODEL_FIELDS for g in f.groups} == set(ARGUMENT_GROUPS)
    assert all(f.dtype in ("int32", "real", "vec3") for f in MODEL_FIELDS + DATA_FIELDS + SCRATCH_FIELDS)


def test_docstring_model_data_and_struct_agree_with_the_schema():
    for owner, fields in (("Model", MODEL_FIELDS), ("Data", DATA_FIELDS), ("FusedStep", SCRATCH_FIELDS)):
        for f in fields:
            row = f"{owner}.{f.name}"
            lines = [line for line in types.__doc__.splitlines() if line.split()[:1] == [row]]
            assert len(lines) == 1 and f"{f.shape} {f.dtype}" in lines[0] and f.doc in lines[0], row
    sizes = [n for n, _ in fields_gen.MODEL_SIZES]
    assert [f.name for f in dataclasses.fields(model.Model)] == sizes + [f.name for f in MODEL_FIELDS]
    assert [f.name for f in dataclasses.fields(model.Data)] == [f.name for f in DATA_FIELDS] + ["rk"]
    for real in (wp.float32, wp.float64):
        vars_ = fused.make_node_funcs(real).ColumnModel.vars
        assert list(vars_) == [f.name for f in group_fields("fused")]
        for f in group_fields("fused"):
            assert vars_[f.name].type.ndim == f.ndim

    integ = _integrator()
    m, vec = integ.model, wp.types.vector(3, wp.float64)
    for f in MODEL_FIELDS:
        a = getattr(m, f.name)
        if a is None:  # the pair fields of a column (a network's are checked in tests/test_feasibility.py)
            assert f.optional and f.name.startswith("pair_"), f.name
            continue
        assert a.ndim == f.ndim and a.dtype == {"int32": wp.int32, "real": wp.float64, "vec3": vec}[f.dtype], f.name
        if f.per_column:
            assert a.shape[1] in (1, m.n_columns), f.name
    for f in SCRATCH_FIELDS:
        assert getattr(integ.stepper, f.name).ndim == f.ndim, f.name
    for f in DATA_FIELDS:
        assert getattr(integ.data, f.name).ndim == f.ndim, f.name


def test_kernel_model_arguments_are_their_group():
    """Each hand-written kernel lists its groups' fields first, by name, in the declared order (the
    group "gram" as one struct argument of its name, the struct's fields the group's)."""
    k, ks = make_kernels(wp.float64), make_solver_kernels(wp.float64, 3)
    for kernel, groups in ((k.gather_accel, ["gather"]), (ks.project_positions, ["positions"]),
                           (ks.factor_project, ["gram", "velocities"]),
                           (ks.factor_only, ["gram"]), (k.record_energy, ["energy"]), (k.record_strain, ["strain"]),
                           (k.record_feasibility, ["feasibility"]), (k.record_pairs, ["pairs"])):
        names = [n for g in groups for n in ([g] if g == "gram" else [f.name for f in group_fields(g)])]
        assert [a.label for a in kernel.adj.args[: len(names)]] == names, kernel.key
    gram = make_gram_struct(wp.float64).vars
    assert list(gram) == [f.name for f in group_fields("gram")]
    assert all(gram[f.name].type.ndim == f.ndim for f in group_fields("gram"))


@pytest.fixture
def fresh_fused():
    """Afterwards the kernel factories forget the structs made from the extended schema."""
    yield
    for f in FUSED_CACHES:
        f.cache_clear()


def test_adding_a_field_is_one_declaration(monkeypatch, fresh_fused):
    """One entry more in MODEL_FIELDS (with its host values; sim/fields.py written again): Model, the docstring table, the fused
    struct (filled by FusedStep) and the argument group all carry it, and the fused step runs
    with it as before."""
    base = _integrator()
    base.run(10)
    extra = Field("con_k", "real", "(nc, Bp)", "N m-1", "an extra per-column bar parameter", ("fused", "positions"))
    monkeypatch.setattr(types, "MODEL_FIELDS", MODEL_FIELDS + (extra,))
    monkeypatch.setattr(model, "Model", fields_gen.classes()[0])  # the written-out Model, regenerated
    for f in FUSED_CACHES:  # the kernel factories are cached per precision (the schema is fixed at import)
        f.cache_clear()
    host_arrays = model.host_arrays

    def with_extra(batch, precision):
        sizes, arrays = host_arrays(batch, precision)
        return sizes, {**arrays, "con_k": np.full((2, sizes["n_constraints"]), 7.0)}  # (Bp, nc)

    monkeypatch.setattr(model, "host_arrays", with_extra)
    integ = _integrator()
    m = integ.model
    assert m.con_k.shape == (m.n_constraints, 2) and np.all(m.con_k.numpy() == 7.0)
    assert "Model.con_k" in types.field_table()
    assert "con_k" in fused.make_node_funcs(wp.float64).ColumnModel.vars
    assert integ.stepper.cm.con_k.shape == m.con_k.shape  # a column-major view of it
    assert np.all(integ.stepper.cm.con_k.numpy() == 7.0)
    assert any(a is m.con_k for a in integ.launcher.args["positions"]) and len(integ.launcher.args["positions"]) == len(
        base.launcher.args["positions"]) + 1
    integ.run(10)
    for name in ("u", "v", "a"):
        assert np.array_equal(getattr(integ.data, name).numpy(), getattr(base.data, name).numpy()), name


def test_a_batch_array_is_one_edit_in_types(monkeypatch, fresh_fused):
    """A field whose host values the batch holds (``source``): its declaration in types.MODEL_FIELDS is
    the only edit (and sim/fields.py written again). Model, the table, the fused struct and its argument group carry it, with the
    batch's values laid out as declared, and the step runs as before."""
    base = _integrator()
    base.run(10)
    extra = Field("cab_c", "real", "(ne, Bp)", "N s m-1", "a per-column cable parameter", ("fused",),
                  source="cable_rest_length")
    monkeypatch.setattr(types, "MODEL_FIELDS", MODEL_FIELDS + (extra,))
    monkeypatch.setattr(model, "Model", fields_gen.classes()[0])  # the written-out Model, regenerated
    for f in FUSED_CACHES:
        f.cache_clear()
    integ = _integrator()
    m = integ.model
    assert np.array_equal(m.cab_c.numpy(), m.cab_L.numpy())  # (ne, Bp), the column index fastest
    assert "Model.cab_c" in types.field_table() and integ.stepper.cm.cab_c.shape == m.cab_c.shape
    assert "cab_c" in fused.make_node_funcs(wp.float64).ColumnModel.vars
    integ.run(10)
    for name in ("u", "v", "a"):
        assert np.array_equal(getattr(integ.data, name).numpy(), getattr(base.data, name).numpy()), name


def test_an_undeclared_host_array_is_an_error(monkeypatch):
    host_arrays = model.host_arrays
    monkeypatch.setattr(model, "host_arrays", lambda b, p: (host_arrays(b, p)[0], {**host_arrays(b, p)[1], "x": 0}))
    with pytest.raises(KeyError, match="x"):
        model.build_model(column_batch(ColumnConfig(n_prisms=2), {}), "fp64", "cpu")
