"""Model and Data are written out from the schema (sim/fields.py, by sim/fields_gen.py): the checked-in
module is what the generator writes from types.MODEL_FIELDS and DATA_FIELDS now."""

import dataclasses

from warp_tensegrity import types
from warp_tensegrity.sim import fields, fields_gen


def test_the_written_out_model_and_data_are_current():
    assert fields_gen.TARGET.read_text() == fields_gen.source(), (
        "sim/fields.py is stale: run python -m warp_tensegrity.sim.fields_gen")


def test_a_new_declaration_makes_the_module_stale():
    """The control: one more declared field changes the text (so the test above would fail)."""
    extra = types.Field("con_k", "real", "(nc, Bp)", "N m-1", "an extra per-column bar parameter")
    assert fields_gen.source(types.MODEL_FIELDS + (extra,)) != fields_gen.TARGET.read_text()
    model, _ = fields_gen.classes(types.MODEL_FIELDS + (extra,))
    assert [f.name for f in dataclasses.fields(model)][-1] == "con_k"
    assert [f.name for f in dataclasses.fields(fields.Model)] == (
        [n for n, _ in fields_gen.MODEL_SIZES] + [f.name for f in types.MODEL_FIELDS])
