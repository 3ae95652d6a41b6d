"""Writes :mod:`.fields` (the Model and Data dataclasses, one written-out attribute per declared
field, so IDEs and grep find them) from the schema, :data:`warp_tensegrity.types.MODEL_FIELDS` and
:data:`~warp_tensegrity.types.DATA_FIELDS`. After declaring a field, run

    python -m warp_tensegrity.sim.fields_gen

(tests/sim/test_fields.py fails while the checked-in module differs from what this writes)."""

from __future__ import annotations

import sys
from pathlib import Path

from .. import types
from ..atomic import oserror_line, write_text

MODEL_SIZES = (("precision", str), ("device", str), ("n_columns", int), ("n_nodes", int), ("n_constraints", int),
               ("n_cables", int), ("bandwidth", int), ("n_prisms", int), ("n_pairs", int))
"""Model's sizes beside its arrays (``bandwidth``: half-bandwidth of the Gram matrix in the chosen ordering;
``n_pairs``: member pairs checked for crossing, networks that are not columns)."""

TARGET = Path(__file__).with_name("fields.py")

HEAD = '''"""The device Model and Data, written out from the declared fields (:data:`warp_tensegrity.types.MODEL_FIELDS`,
:data:`~warp_tensegrity.types.DATA_FIELDS`) by ``python -m warp_tensegrity.sim.fields_gen``. Generated:
do not edit (tests/sim/test_fields.py checks that it is current)."""

from __future__ import annotations

from dataclasses import dataclass

import warp as wp
'''


def _attr(f: types.Field) -> str:
    kind = "wp.array | None" if f.optional else "wp.array"
    return f'    {f.name}: {kind}\n    """{f.shape} {f.dtype} [{f.unit}]: {f.doc}."""\n'


def source(model_fields: tuple[types.Field, ...] | None = None,
           data_fields: tuple[types.Field, ...] | None = None) -> str:
    """The text of :mod:`.fields` for these declarations (default: the declared ones)."""
    mf = types.MODEL_FIELDS if model_fields is None else model_fields
    df = types.DATA_FIELDS if data_fields is None else data_fields
    sizes = "".join(f"    {n}: {t.__name__}\n" for n, t in MODEL_SIZES)
    return (HEAD + "\n\n@dataclass\nclass Model:\n"
            '    """Topology and per-column parameters on the device, and the sizes."""\n\n'
            + sizes + "".join(_attr(f) for f in mf)
            + "\n\n@dataclass\nclass Data:\n"
            '    """Mutable state of a batch on the device; ``rk``: RK4 scratch u0, v0, acc_u, acc_v, us, vs, each\n'
            '    (n, B) vec3."""\n\n'
            + "".join(_attr(f) for f in df) + "    rk: dict | None\n")


def classes(model_fields=None, data_fields=None) -> tuple[type, type]:
    """(Model, Data) for these declarations, made from the same text (a field declared at run time,
    e.g. in a test, before the module is written again)."""
    ns: dict = {"__name__": __name__.rsplit(".", 1)[0] + ".fields"}
    exec(compile(source(model_fields, data_fields), str(TARGET), "exec"), ns)  # noqa: S102 (our own generated text)
    return ns["Model"], ns["Data"]


def main() -> int:
    try:
        write_text(TARGET, source())
    except OSError as e:
        print(oserror_line(e, TARGET), file=sys.stderr)
        return 1
    print(f"wrote {TARGET}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
