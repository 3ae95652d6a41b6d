"""One source for every option (warp_tensegrity.options): the RunSettings fields, the spec's
[run] keys, the CLI's --set keys and the docs tables are the same sets; the docs are generated;
defaults and messages hold."""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import numpy as np
import pytest

from warp_tensegrity import options as O
from warp_tensegrity import options_docs as OD
from warp_tensegrity import overrides as OV
from warp_tensegrity.sweep import parse as P
from warp_tensegrity.sweep import spec as S
from warp_tensegrity.scene import ColumnConfig, NetworkError
from warp_tensegrity.options import RunSettings
from warp_tensegrity.types import Method, Precision

REPO = Path(__file__).resolve().parents[1]
DOCS = REPO / "docs" / "sweeps.md"


def _doc_keys(section: str) -> list[str]:
    """Keys of the options table of ``section`` as written in docs/sweeps.md."""
    text = DOCS.read_text()
    begin, end = OD.DOCS_BEGIN.format(section), OD.DOCS_END.format(section)
    assert begin in text and end in text, f"docs/sweeps.md lost the generated {section} table"
    block = text[text.index(begin): text.index(end)]
    return re.findall(r"^\| `(\w+)` \|", block, flags=re.M)


def test_each_run_option_defined_once_and_everywhere_the_same():
    settings_fields = [f.name for f in dataclasses.fields(RunSettings)]
    model_fields = list(O.RunSettings.__pydantic_fields__)
    spec_keys = list(P.RUN_KEYS)
    table_rows = [r["key"] for r in OD.options_table("run")]
    doc_rows = _doc_keys("run")
    set_keys = list(OV.set_keys()["run"])
    for keys in (settings_fields, model_fields, spec_keys, table_rows, doc_rows, set_keys):
        assert len(keys) == len(set(keys))  # nothing listed twice
        assert set(keys) == set(settings_fields)
    # the spec's parsed [run] holds exactly these keys
    assert set(S.parse_spec(_SPEC).run) == set(settings_fields)
    assert RunSettings is O.RunSettings  # settings.RunSettings is the model, not a copy
    assert O.sections() == {"scene": ColumnConfig, "sweep": O.ColumnParameters, "run": RunSettings}


def test_choices_are_the_enums():
    """options is a leaf of the import graph, so it spells the choices; they must be the enums'."""
    assert O.METHODS == tuple(m.value for m in Method) and O.PRECISIONS == tuple(p.value for p in Precision)
    assert O.opt_of(RunSettings, "method").choices == O.METHODS


def test_mkdocs_options_page_rows_are_the_model():
    """docs/options.md (the MkDocs hook) lists the same run and scene options, from options_table()."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("options_hook", REPO / "docs" / "hooks" / "options.py")
    hook = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(hook)
    keys = [r[0] for r in hook.option_rows()]
    run = [k[4:] for k in keys if k.startswith("run.")]
    assert sorted(run) == sorted(f.name for f in dataclasses.fields(RunSettings))
    scene = {k[6:] for k in keys if k.startswith("scene.")}
    assert scene == set(P.SCENE_FIELDS) | set(P.SCENE_PARAMS)


def test_scene_and_parameter_options_same_set_in_model_spec_and_docs():
    scene = [f.name for f in dataclasses.fields(ColumnConfig)]
    assert set(P.SCENE_FIELDS) == set(scene) == set(_doc_keys("scene")) == {r["key"] for r in OD.options_table("scene")}
    params = [f.name for f in dataclasses.fields(O.ColumnParameters)]
    assert set(O.COLUMN_PARAMETERS) == set(params) == set(_doc_keys("sweep"))


def test_docs_tables_are_generated_not_hand_edited():
    text = DOCS.read_text()
    assert OD.render_docs(text) == text, "docs/sweeps.md is stale: run options_docs.update_docs('docs/sweeps.md')"


def test_lens_docs_table_is_generated_from_the_options():
    """docs/lens.md's spec reference is the generated table of options_lens (issue 26: it was hand
    written, beside a second option system in lens/spec.py)."""
    text = (REPO / "docs" / "lens.md").read_text()
    begin, end = OD.DOCS_BEGIN.format("lens"), OD.DOCS_END.format("lens")
    assert begin in text and end in text, "docs/lens.md lost its generated options table"
    assert OD.render_docs(text) == text, "docs/lens.md is stale: run options_docs.update_docs('docs/lens.md')"
    block = text[text.index(begin): text.index(end)]
    keys = re.findall(r"^\| `([\w.]+)` \|", block, flags=re.M)
    assert keys == [f"{r['section']}.{r['key']}" if r["section"] else r["key"] for r in OD.lens_options_table()]


def test_defaults_unchanged():
    """The defaults every earlier result was made with (fp64 CPU outputs stay bit-identical)."""
    want = dict(t_end=1.0, dt="auto", method="rattle", precision="auto", output_interval=None,
                record_strain=True, record_energy=True, energy_precision="auto", compress_energy=False,
                device=None, shard_size=None, dt_safety=None,
                allow_unstable_dt=False, projection_tol=None, max_projection_iters=25, failure_bar_error=1e-3,
                steps_per_graph=50, fused="auto", accuracy=None, truncate=True, groups=True, error_estimate=True, measure="device",
                energy_station=None, energy_end_prisms=5)
    assert dataclasses.asdict(RunSettings()) == want
    # the spec and the API agree (record_strain used to default to false in specs only)
    assert S.parse_spec(_SPEC.replace("record_strain = true\n", "")).run["record_strain"] is True
    c = ColumnConfig()
    assert (c.n_prisms, c.radius, c.height, c.twist, c.cable_modulus, c.cable_radius, c.unit_mass) == (
        50, 5.0e-3, 6.2e-3, 5.0 * np.pi / 6.0, 5.48e6, 0.14e-3, 0.0249)
    assert (c.handedness, c.end_base_mass, c.bar_mass, c.impact_admissibility) == ("right", "half", 0.0, "rigid_members")


def test_public_constructor_and_replace_validate():
    s = RunSettings(t_end=2.0, output_interval=0.01)
    assert (s.t_end, s.output_interval, s.dt) == (2.0, 0.01, "auto")
    assert RunSettings(2.0).t_end == 2.0  # positional, as a dataclass
    assert RunSettings(t_end=np.float64(0.5), max_projection_iters=np.int64(3)).max_projection_iters == 3
    assert type(RunSettings(t_end=1).t_end) is float
    with pytest.raises(O.SettingsError, match=r"t_end = -2.0: must lie in \(0, 1e\+09\] \[s\]"):
        dataclasses.replace(s, t_end=-2.0)
    with pytest.raises(O.SettingsError, match="did you mean 't_end'"):
        RunSettings(t_ned=1.0)
    with pytest.raises(NetworkError, match=r"n_prisms = True: must be an integer"):
        ColumnConfig(n_prisms=True)


@pytest.mark.parametrize("kw, fragment", [
    (dict(t_end="1.0"), "t_end = '1.0': must be a number"),
    (dict(t_end=float("nan")), "t_end = nan: must be finite"),
    (dict(dt=float("inf")), "dt = inf: must be finite or 'auto'"),
    (dict(record_strain=1), "record_strain = 1: must be true or false"),
    (dict(precision="fp46"), "did you mean 'fp64'"),
    (dict(device="gpu"), "device = 'gpu': give \"cpu\", \"cuda\", \"cuda:N\" or 'auto'"),
    (dict(max_projection_iters=0.5), "max_projection_iters = 0.5: must be an integer"),
    (dict(t_end=0.1, output_interval=0.2), "output_interval = 0.2: must be <= t_end = 0.1 s"),
])
def test_api_messages_name_key_value_and_rule(kw, fragment):
    with pytest.raises(O.SettingsError) as info:
        RunSettings(**kw)
    assert fragment in str(info.value)


def test_set_overrides_are_typed_by_the_model(tmp_path):
    assert OV.parse_set(["run.t_end=2.0", "run.method=rk4", "run.dt=auto", "scene.n_prisms=8", "run.truncate=false"]) == {
        "run": {"t_end": 2.0, "method": "rk4", "dt": "auto", "truncate": False}, "scene": {"n_prisms": 8}}
    with pytest.raises(O.OptionError) as info:
        OV.parse_set(["run.t_ned=2", "scen.n_prisms=3", "t_end"])
    errs = info.value.errors
    assert "--set run.t_ned: unknown key; did you mean 't_end'?" in errs[0]
    assert "did you mean 'scene'" in errs[1] and "SECTION.KEY=VALUE" in errs[2]
    # a value is held to the file's rules, with the key path
    with pytest.raises(S.SpecError, match=r"run.t_end = -1: must lie in \(0, 1e\+09\] \[s\]"):
        S.parse_spec(_SPEC, overrides=OV.parse_set(["run.t_end=-1"]))
    # the spec text holds the overrides (a resumed run reads it) and reparses to the same spec
    sp = S.parse_spec(_SPEC, overrides=OV.parse_set(["run.t_end=0.2", "scene.n_prisms=4"]))
    assert sp.run["t_end"] == 0.2 and sp.scene.n_prisms == 4
    again = S.parse_spec(sp.text)
    assert again.canonical() == sp.canonical()


def test_cli_set_reaches_the_run(tmp_path, capsys):
    from warp_tensegrity import cli

    p = tmp_path / "s.toml"
    p.write_text(_SPEC)
    rc = cli.main(["run", str(p), "-o", str(tmp_path / "o.nc"), "--device", "cpu", "--dry-run",
                   "--set", "run.t_end=0.05", "--set", "run.method=rk4"])
    out = capsys.readouterr().out
    assert rc == 0 and "rk4 fp64" in out and "t_end = 0.05 s" in out
    rc = cli.main(["run", str(p), "-o", str(tmp_path / "o.nc"), "--dry-run", "--set", "run.t_end=soon"])
    err = capsys.readouterr().err
    assert rc == 1 and "run.t_end = 'soon': must be a number" in err


_SPEC = """
[scene]
n_prisms = 3
[sweep]
grid = { v0 = [0.001, 0.002] }
[run]
t_end = 0.1
output_interval = 0.01
record_strain = true
"""


# ---------------------------------------------------------------------- `warp-tensegrity init`
@pytest.mark.parametrize("example", ["paper", "phase", "lens", "interface"])
def test_init_writes_a_commented_spec_that_runs(example, tmp_path, capsys):
    """`init --example ...` writes a starting spec generated from the options model: it lists every
    option, parses, and (sweeps) passes a dry run; the lens spec validates (issue 23)."""
    from warp_tensegrity import cli
    from warp_tensegrity.init_spec import spec_text

    path = tmp_path / f"{example}.toml"
    assert cli.main(["init", "--example", example, "-o", str(path)]) == 0
    text = path.read_text()
    assert text == spec_text(example) and text.startswith("# warp_tensegrity")
    if example == "lens":
        from warp_tensegrity.lens.spec import load_lens_spec

        spec = load_lens_spec(path)
        assert spec.calibration.count == 64 and spec.column.config().n_prisms == 10
        for row in OD.lens_options_table():  # every option of every table, from options_lens
            assert f"# {row['key']}" in text, (row["section"], row["key"])
        return
    for row in OD.options_table():  # every option of every table, so the spec cannot drift
        assert f"# {row['key']}" in text, row["key"]
    capsys.readouterr()
    assert cli.main(["run", str(path), "-o", str(tmp_path / "o.nc"), "--device", "cpu", "--dry-run"]) == 0
    assert "fits:        yes" in capsys.readouterr().out
    assert cli.main(["init", "--example", example, "-o", str(path)]) == 1  # never overwrites
    assert "exists" in capsys.readouterr().err


def test_init_into_a_missing_directory_names_path_and_errno(tmp_path, capsys):
    """An OSError from `init -o` is one line with the path and the errno, number and name (issue 30)."""
    from warp_tensegrity import cli

    path = tmp_path / "no" / "such" / "dir" / "x.toml"
    assert cli.main(["init", "-o", str(path)]) == 1
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and str(path) in err and "[Errno 2 ENOENT]" in err, err
