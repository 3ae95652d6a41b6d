"""``warp-tensegrity init [--example paper|phase|lens|interface] [-o SPEC.toml]``: a commented starting spec.

The text is generated from the options model (:func:`~warp_tensegrity.options_docs.options_table`
for sweep specs, :func:`~warp_tensegrity.options_docs.lens_options_table` for lens specs): every
option of every table is listed with its unit, rule and meaning, the example's own values set and
the others commented out at their defaults, so the starting spec can never drift from the code.
A test runs each written spec (``tests/test_options.py``).
"""

from __future__ import annotations

import sys
import textwrap
from pathlib import Path

from .atomic import create_text, oserror_line
from .options_docs import lens_options_table, options_table
from .options_lens import LENS_SECTIONS
from .scene.columns import ColumnConfig  # noqa: F401 - registers the [scene] options

EXAMPLES = {
    "paper": "the paper's Sec. 4 column (50 prisms), four of its impact cases as a case list",
    "phase": "a phase diagram: a prestrain x impact-speed grid of short rigid-base columns",
    "lens": "an acoustic lens: calibrate, design and verify an array of columns (docs/lens.md)",
    "interface": "a two-segment column: a grid over the interface position and the prestrain of one segment "
                 "(profiles along the column, docs/sweeps.md)",
}

# the values each sweep example sets (everything else is listed commented out, at its default)
_VALUES = {
    "paper": {
        "title": "My paper-style run", "scene": {"n_prisms": 50, "impact_admissibility": "end_twist"},
        "sweep": 'cases = [\n'
                 '  { label = "FB p=0.002 v0=0.1",  base_rigidity = 0.0, prestrain = 0.002, v0 = 0.1 },\n'
                 '  { label = "FB p=0.002 v0=0.15", base_rigidity = 0.0, prestrain = 0.002, v0 = 0.15 },\n'
                 '  { label = "RB p=0.002 v0=0.1",  base_rigidity = 1.0, prestrain = 0.002, v0 = 0.1 },\n'
                 '  { label = "RB p=0.002 v0=0.15", base_rigidity = 1.0, prestrain = 0.002, v0 = 0.15 },\n'
                 ']',
        "run": {"t_end": 1.0, "output_interval": 0.01, "shard_size": 4},
    },
    "phase": {
        "title": "My phase diagram", "scene": {"n_prisms": 16},
        "sweep": '[sweep.grid]  # axes in this order; the first varies slowest\n'
                 'prestrain = { start = 0.0, stop = 0.004, num = 5 }\n'
                 'v0 = { start = 0.01, stop = 0.1, num = 4, spacing = "log" }\n'
                 '[sweep.fixed]\n'
                 'base_rigidity = 1.0',
        "run": {"t_end": 0.5, "output_interval": 0.005, "shard_size": 64},
    },
    "interface": {
        "title": "My interface sweep", "scene": {"n_prisms": 20},
        "sweep": '# a profile along the column: {values = [...]} (one per prism; unit_mass: per level),\n'
                 '# {grade = [first, last]} or {segments = [first, last], at = k}; prism 0 is at the clamped base\n'
                 '[sweep.fixed]\n'
                 'prestrain = { segments = [0.01, 0.04], at = 10 }\n'
                 'base_rigidity = 1.0\n'
                 'v0 = 0.02\n'
                 '[sweep.grid]  # <param>_from, <param>_to, <param>_at set the fixed profile\'s fields per column\n'
                 'prestrain_at = [5, 10, 15]\n'
                 'prestrain_to = [0.005, 0.01, 0.02, 0.04]',
        "run": {"t_end": 1.5, "output_interval": 0.005, "shard_size": 64},
    },
}


def _toml(value) -> str:
    """A value as TOML writes it, on one line."""
    import tomli_w

    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml(x) for x in value) + "]"
    if isinstance(value, dict):
        return "{ " + ", ".join(f"{k} = {_toml(v)}" for k, v in value.items()) + " }"
    return tomli_w.dumps({"v": value}).strip()[4:]


def _comment(text: str, width: int = 98) -> list[str]:
    return textwrap.wrap(text, width, initial_indent="# ", subsequent_indent="#   ") or ["#"]


def _option_lines(row: dict, value=None) -> list[str]:
    unit = f" [{row['unit']}]" if row["unit"] and row["unit"] != "1" else ""
    lines = _comment(f"{row['key']}{unit}: {row['doc']} Rule: {row['rule']}. Default: {row['default']}.")
    if value is not None:
        return lines + [f"{row['key']} = {_toml(value)}", ""]
    default = row["default"]
    shown = default if default.startswith('"') or default in ("true", "false") else default
    ok = shown.replace(".", "", 1).replace("e", "", 1).replace("-", "").replace("+", "").isdigit() \
        or shown.startswith('"') or shown in ("true", "false", "inf")
    return lines + [f"# {row['key']} = {shown}" if ok else f"# {row['key']} = ...  ({default})", ""]


def sweep_spec_text(example: str) -> str:
    """The commented sweep spec of ``example`` ('paper', 'phase' or 'interface')."""
    ex = _VALUES[example]
    out = _comment(f"warp_tensegrity sweep spec: {EXAMPLES[example]}. Written by `warp-tensegrity init "
                   f"--example {example}` from the options model; run it with `warp-tensegrity run "
                   "THIS.toml -o OUT.nc` (add --dry-run to see its size and time first). Every key: "
                   "docs/options.md. Units are SI.")
    out += ["", f"title = {_toml(ex['title'])}", "", "[scene]"]
    out += _comment("The fixed scene, the same for every column.") + [""]
    for row in options_table("scene"):
        out += _option_lines(row, ex["scene"].get(row["key"]))
    out += ["[sweep]"]
    out += _comment("The swept per-column parameters: a grid (one axis per parameter: a list, or a range "
                    "table {start, stop, num, spacing}) or a list of cases; `fixed` sets the others.")
    for row in options_table("sweep"):
        out += _comment(f"{row['key']} [{row['unit']}]: {row['doc']} Rule: {row['rule']}. Default: {row['default']}.")
    out += [ex["sweep"], "", "[run]"]
    out += _comment("How the columns are integrated and stored.") + [""]
    for row in options_table("run"):
        out += _option_lines(row, ex["run"].get(row["key"]))
    return "\n".join(out).rstrip() + "\n"


def lens_spec_text() -> str:
    """The commented lens spec (every option of :mod:`warp_tensegrity.options_lens`, the CI lens's values)."""
    values = {"": {"title": "My lens"}, "column": {"base_rigidity": 1.0, "scene": {"n_prisms": 10}},
              "array": {"count": 8, "spacing": 0.012}, "calibration": {"count": 64},
              "design": {"focal_points": [[0.0, 0.0, 0.06], [0.015, 0.0, 0.07]]},
              "map": {"half_width": 0.03, "half_depth": 0.03, "points": 25},
              "run": {"t_end": 0.9, "output_interval": 0.002}}
    out = _comment(f"warp_tensegrity lens spec: {EXAMPLES['lens']}. Written by `warp-tensegrity init "
                   "--example lens` from the lens options model; run it with `warp-tensegrity lens THIS.toml "
                   "-o OUT.nc`. Every key: docs/lens.md. Units are SI.")
    out.append("")
    rows = lens_options_table()
    for section, cls in LENS_SECTIONS.items():
        if section:
            out += [f"[{section}]"] + _comment(" ".join((cls.__doc__ or "").split())) + [""]
        for row in rows:
            if row["section"] == section:
                out += _option_lines(row, values.get(section, {}).get(row["key"]))
    return "\n".join(out).rstrip() + "\n"


def spec_text(example: str) -> str:
    return lens_spec_text() if example == "lens" else sweep_spec_text(example)


def add_init_parser(sub, parents=()) -> None:
    p = sub.add_parser("init", parents=list(parents), help="write a commented starting spec",
                       description="Write a starting spec, every option listed with its unit, rule and "
                                   "default (generated from the options model).")
    p.add_argument("--example", choices=sorted(EXAMPLES), default="phase",
                   help="; ".join(f"{k}: {v}" for k, v in EXAMPLES.items()) + " (default: phase)")
    p.add_argument("-o", "--output", default=None, metavar="SPEC.toml",
                   help="file to write (refused if it exists); default: standard output")


def run_init(args) -> int:
    text = spec_text(args.example)
    if args.output is None:
        sys.stdout.write(text)
        return 0
    path = Path(args.output)
    if path.exists():
        print(f"warp-tensegrity: error: {path} exists; give another file name", file=sys.stderr)
        return 1
    try:
        create_text(path, text)  # UTF-8; refused if a file or link appeared at the name meanwhile
    except OSError as e:
        print(f"warp-tensegrity: error: {oserror_line(e, path)}", file=sys.stderr)
        return 1
    print(f"wrote {path}: run it with `warp-tensegrity {'lens' if args.example == 'lens' else 'run'} {path} -o OUT.nc`")
    return 0
