"""MkDocs hook: the options table of ``docs/options.md``, generated from the spec definitions.

Every key the spec parser accepts (``warp_tensegrity.sweep.spec``: TOP_KEYS, SCENE_FIELDS, SCENE_PARAMS,
SWEEP_KEYS, RANGE_KEYS, CASE_EXTRA_KEYS, RUN_DEFAULTS) gets a row with its default and its meaning,
read from the one place it is written: the field docstrings of ``ColumnConfig`` and ``RunSettings``
(via griffe, mkdocstrings' own loader), the coordinate attributes of the per-column parameters
(``dataset.COORD_ATTRS``) and ``spec.KEY_DOCS`` for the rest. The page holds the marker
``<!-- options-table -->``; ``tests/test_docs.py`` checks every key appears in the built site.
"""

from __future__ import annotations

import dataclasses
import math
import re

MARKER = "<!-- options-table -->"


def _fmt_default(v) -> str:
    if v is None:
        return "engine's choice"
    if isinstance(v, bool):
        return f"`{str(v).lower()}`"
    if isinstance(v, str):
        return f'`"{v}"`'
    if isinstance(v, float) and math.isclose(v, 5 * math.pi / 6):
        return "`5*pi/6`"
    return f"`{v!r}`"


def _plain(doc: str) -> str:
    """One line of markdown from a docstring: Sphinx roles and double backquotes become code spans."""
    doc = re.sub(r":(?:mod|data|func|class|meth|attr):`~?([^`]+)`", r"`\1`", " ".join(doc.split()))
    return doc.replace("``", "`")


def _docstrings(path: str) -> dict:
    import griffe

    obj = griffe.load(path, resolve_aliases=False, docstring_parser=None)
    return {n: _plain(m.docstring.value) for n, m in obj.members.items() if m.docstring}


def option_rows() -> list[tuple[str, str, str]]:
    """(key path, default, meaning) for every key a spec may hold."""
    from warp_tensegrity.sweep import spec as S
    from warp_tensegrity.scene.columns import ColumnConfig
    from warp_tensegrity.io import COORD_ATTRS
    from warp_tensegrity.settings import COLUMN_PARAMETERS

    col_doc = _docstrings("warp_tensegrity.scene.columns.ColumnConfig")
    run_doc = _docstrings("warp_tensegrity.settings.RunSettings")
    col_default = {f.name: f.default for f in dataclasses.fields(ColumnConfig)}
    rows = [(k, "", S.KEY_DOCS[k]) for k in S.TOP_KEYS]
    for k in S.SCENE_FIELDS:
        rows.append((f"scene.{k}", _fmt_default(col_default[k]), col_doc[k]))
    for k in S.SCENE_PARAMS:
        rows.append((f"scene.{k}", _fmt_default(S.PARAM_DEFAULTS[k]) if k in S.PARAM_DEFAULTS else "the scene's value",
                     f"{COORD_ATTRS[k]['long_name']} [{COLUMN_PARAMETERS[k]}], the same for every column"))
    for k in S.SWEEP_KEYS:
        rows.append((f"sweep.{k}", "", S.KEY_DOCS[f"sweep.{k}"]))
    for k in COLUMN_PARAMETERS:
        d = S.PARAM_DEFAULTS.get(k)
        rows.append((f"sweep.grid.{k}, sweep.cases[i].{k}, sweep.fixed.{k}",
                     _fmt_default(d) if d is not None else "the scene's value",
                     f"per-column parameter: {COORD_ATTRS[k]['long_name']} [{COLUMN_PARAMETERS[k]}]"))
    for k in S.RANGE_KEYS:
        rows.append((f"sweep.grid.<param>.{k}", "`\"linear\"`" if k == "spacing" else "",
                     S.KEY_DOCS[f"sweep.grid.<param>.{k}"]))
    for k in S.CASE_EXTRA_KEYS:
        rows.append((f"sweep.cases[i].{k}", "", S.KEY_DOCS[f"sweep.cases[i].{k}"]))
    for k, v in S.RUN_DEFAULTS.items():
        doc = S.KEY_DOCS.get(f"run.{k}") or run_doc[k]
        rows.append((f"run.{k}", _fmt_default(v), doc))
    return rows


def options_markdown() -> str:
    lines = ["| key | default | meaning |", "|---|---|---|"]
    for key, default, doc in option_rows():
        keys = ", ".join(f"`{k.strip()}`" for k in key.split(","))
        lines.append(f"| {keys} | {default} | {doc.replace('|', '/')} |")
    return "\n".join(lines)


def on_page_markdown(markdown: str, page, config, files) -> str:
    if MARKER in markdown:
        return markdown.replace(MARKER, options_markdown())
    return markdown
