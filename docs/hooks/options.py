"""MkDocs hook: the options table of ``docs/options.md``, generated from the options model.

Every key the spec parser accepts gets a row with its units, default, rule and meaning, read from
the one place it is declared: ``warp_tensegrity.options_docs.options_table()`` (the pydantic
options model: ``ColumnConfig``, ``ColumnParameters``, ``RunSettings``) for the options, and
``warp_tensegrity.sweep.spec.KEY_DOCS`` for the structural keys (tables, grid ranges, case
labels; the key tables of ``warp_tensegrity.sweep.parse``). The page holds the marker
``<!-- options-table -->``; ``tests/test_docs.py`` checks every key appears in the built site.
"""

from __future__ import annotations

MARKER = "<!-- options-table -->"


def option_rows() -> list[tuple[str, str, str, str, str]]:
    """(key path, units, default, rule, meaning) for every key a spec may hold. The options come
    from their one declaration (:func:`warp_tensegrity.options_docs.options_table`: ColumnConfig,
    ColumnParameters, RunSettings); the structural keys from ``spec.KEY_DOCS``."""
    import warp_tensegrity  # noqa: F401  (registers every options section)
    from warp_tensegrity.options_docs import options_table
    from warp_tensegrity.sweep import parse as P
    from warp_tensegrity.sweep import spec as S

    rows = [(k, "", "", "", S.KEY_DOCS[k]) for k in S.TOP_KEYS]
    for r in options_table("scene"):
        rows.append((f"scene.{r['key']}", r["unit"], r["default"], r["rule"], r["doc"]))
    params = options_table("sweep")
    for r in params:
        if r["key"] in P.SCENE_PARAMS:
            rows.append((f"scene.{r['key']}", r["unit"], r["default"], r["rule"],
                         f"{r['doc']} The same for every column."))
    for k in P.SWEEP_KEYS:
        rows.append((f"sweep.{k}", "", "", "", S.KEY_DOCS[f"sweep.{k}"]))
    for r in params:
        k = r["key"]
        rows.append((f"sweep.grid.{k}, sweep.cases[i].{k}, sweep.fixed.{k}", r["unit"], r["default"], r["rule"],
                     f"per-column parameter: {r['doc']}"))
    for k in P.RANGE_KEYS:
        rows.append((f"sweep.grid.<param>.{k}", "", '"linear"' if k == "spacing" else "", "",
                     S.KEY_DOCS[f"sweep.grid.<param>.{k}"]))
    for k in ("values", "grade", "segments", "at"):  # profiles along the column (docs/sweeps.md, Profiles)
        rows.append((f"<param>.{k}", "", "", "", S.KEY_DOCS[f"<param>.{k}"]))
    for k in ("from", "to", "at"):
        rows.append((f"sweep.grid.<param>_{k}", "", "", "", S.KEY_DOCS[f"sweep.grid.<param>_{k}"]))
    for k in P.CASE_EXTRA_KEYS:
        rows.append((f"sweep.cases[i].{k}", "", "", "", S.KEY_DOCS[f"sweep.cases[i].{k}"]))
    for r in options_table("run"):
        rows.append((f"run.{r['key']}", r["unit"], r["default"], r["rule"], r["doc"]))
    return rows


def options_markdown() -> str:
    lines = ["| key | units | default | rule | meaning |", "|---|---|---|---|---|"]
    for key, unit, default, rule, doc in option_rows():
        keys = ", ".join(f"`{k.strip()}`" for k in key.split(","))
        cells = [c.replace("|", "/") for c in (unit, f"`{default}`" if default else "", rule, doc)]
        lines.append(f"| {keys} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def on_page_markdown(markdown: str, page, config, files) -> str:
    if MARKER in markdown:
        return markdown.replace(MARKER, options_markdown())
    return markdown
