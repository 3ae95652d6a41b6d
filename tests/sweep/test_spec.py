"""Sweep spec parsing and validation (warp_tensegrity.sweep.spec), the shipped specs, and the CLI's
lazy imports. Everything but the dt-limit test runs without Warp."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from warp_tensegrity import estimate_batch
from warp_tensegrity.sweep import SpecError, load_spec, parse_spec

REPO = Path(__file__).resolve().parents[2]
SWEEPS = REPO / "sweeps"

BASE = """
[scene]
n_prisms = 6

[sweep]
grid = { prestrain = [0.0, 0.002], v0 = [0.003, 0.006] }

[run]
t_end = 0.1
output_interval = 0.01
"""


def spec_text(scene="n_prisms = 6", sweep="grid = { prestrain = [0.0, 0.002], v0 = [0.003, 0.006] }",
              run="t_end = 0.1\noutput_interval = 0.01", top=""):
    return f"{top}\n[scene]\n{scene}\n\n[sweep]\n{sweep}\n\n[run]\n{run}\n"


def errors_of(text) -> str:
    with pytest.raises(SpecError) as info:
        parse_spec(text)
    return str(info.value)


# ---------------------------------------------------------------------- shipped specs
def test_ci_small_spec():
    spec = load_spec(SWEEPS / "ci_small.toml")
    assert spec.kind == "grid"
    assert spec.scene.n_prisms == 8
    assert spec.shape == (2, 2, 2) and spec.n_columns == 8
    assert spec.swept == ("prestrain", "v0", "base_rigidity")
    assert spec.run["t_end"] <= 2.0  # every case measured (the RB p = 0 pulses need ~2 s over 8 prisms)


def test_paper_spec_has_the_twelve_cases():
    spec = load_spec(SWEEPS / "paper_2017.toml")
    assert spec.kind == "cases" and spec.n_columns == 12
    assert spec.scene.n_prisms == 50
    assert spec.run["t_end"] == 10.0 and spec.run["output_interval"] == 0.01 and spec.run["dt"] == "auto"
    p = spec.column_params()
    got = {(p["base_rigidity"][i], p["prestrain"][i], p["v0"][i]) for i in range(12)}
    want = {(b, 0.0, v) for b in (0.0, 1.0) for v in (0.001, 0.002, 0.005)}
    want |= {(b, 0.002, v) for b in (0.0, 1.0) for v in (0.1, 0.125, 0.15)}
    assert got == want
    assert len(spec.labels) == 12 and all(spec.labels)


def test_phase_large_spec():
    spec = load_spec(SWEEPS / "phase_large.toml")
    assert spec.kind == "grid"
    assert 1500 <= spec.n_columns <= 3000
    assert spec.run["record_strain"] is False and spec.run["output_interval"] == 0.002  # resolves the fastest pulses
    v0 = spec.grid["v0"]
    assert v0[0] == 1e-3 and v0[-1] == 0.2
    np.testing.assert_allclose(np.diff(np.log(v0)), np.log(200) / (len(v0) - 1))
    assert spec.grid["prestrain"][0] == 0.0 and spec.grid["prestrain"][-1] == 0.01
    assert list(spec.grid["base_rigidity"]) == [0.0, 0.5, 0.8, 0.9, 0.95, 1.0]


# ---------------------------------------------------------------------- structure
def test_grid_order_and_column_params():
    spec = parse_spec(spec_text(sweep="grid = { v0 = [1e-3, 2e-3, 3e-3], prestrain = [0.0, 0.002] }\nfixed = { base_rigidity = 0.5 }"))
    assert spec.swept == ("v0", "prestrain") and spec.shape == (3, 2)
    p = spec.column_params()
    assert list(p["v0"]) == [1e-3, 1e-3, 2e-3, 2e-3, 3e-3, 3e-3]  # C order, first key slowest
    assert list(p["prestrain"]) == [0.0, 0.002] * 3
    assert (p["base_rigidity"] == 0.5).all()
    assert (p["cable_EA"] == spec.scene.cable_EA).all() and (p["unit_mass"] == spec.scene.unit_mass).all()
    assert spec.shards(4) == [(0, 4), (4, 6)]


def test_range_tables():
    spec = parse_spec(spec_text(sweep=(
        "grid.v0 = { start = 1e-3, stop = 0.1, num = 3, spacing = \"log\" }\n"
        "grid.prestrain = { start = 0.0, stop = 0.01, num = 5 }"
    )))
    np.testing.assert_allclose(spec.grid["v0"], [1e-3, 1e-2, 1e-1])
    np.testing.assert_allclose(spec.grid["prestrain"], [0, 0.0025, 0.005, 0.0075, 0.01])


def test_cases_and_scene_scalars():
    spec = parse_spec(spec_text(
        scene="n_prisms = 6\nbase_rigidity = 1.0",
        sweep='cases = [{ v0 = 0.001, label = "a" }, { v0 = 0.002, prestrain = 0.002 }]',
    ))
    assert spec.kind == "cases" and spec.n_columns == 2
    assert spec.swept == ("prestrain", "v0")
    p = spec.column_params()
    assert list(p["prestrain"]) == [0.0, 0.002] and list(p["v0"]) == [0.001, 0.002]
    assert (p["base_rigidity"] == 1.0).all()
    assert spec.labels == ["a", ""]


def test_fingerprint_ignores_formatting_device_and_shard_size():
    a = parse_spec(spec_text())
    b = parse_spec("# a comment\n" + spec_text(run="t_end = 0.1  # s\noutput_interval = 1e-2\nshard_size = 3\ndevice = \"cpu\""))
    c = parse_spec(spec_text(run="t_end = 0.2\noutput_interval = 0.01"))
    assert a.fingerprint("v1") == b.fingerprint("v1")
    assert a.fingerprint("v1") != c.fingerprint("v1")
    assert a.fingerprint("v1") != a.fingerprint("v2")  # code version is part of it
    assert a.text_sha256 != b.text_sha256


# ---------------------------------------------------------------------- typos
@pytest.mark.parametrize(
    "text, path, suggestion",
    [
        (spec_text(run="t_ned = 0.1"), "run.t_ned", "t_end"),
        (spec_text(run="t_end = 0.1\nshardsize = 4"), "run.shardsize", "shard_size"),
        (spec_text(scene="n_prism = 6"), "scene.n_prism", "n_prisms"),
        (spec_text(scene="cable_modulos = 5e6"), "scene.cable_modulos", "cable_modulus"),
        (spec_text(sweep="grid = { prestrian = [0.0, 0.002] }"), "sweep.grid.prestrian", "prestrain"),
        (spec_text(sweep="grid = { v0 = [0.001] }\nfixd = { prestrain = 0.0 }"), "sweep.fixd", "fixed"),
        (spec_text(sweep="cases = [{ v0 = 0.001 }, { vo = 0.002 }]"), "sweep.cases[1].vo", "v0"),
        (spec_text(top='titel = "x"'), "titel", "title"),
        (spec_text(run='t_end = 0.1\nmethod = "ratle"'), "run.method", "rattle"),
        (spec_text(run='t_end = 0.1\nprecision = "fp46"'), "run.precision", "fp64"),
    ],
)
def test_typo_rejected_with_suggestion(text, path, suggestion):
    msg = errors_of(text)
    assert path in msg
    assert f"did you mean {suggestion!r}" in msg


def test_unknown_table_rejected():
    msg = errors_of(BASE + "\n[secne]\nn_prisms = 4\n")
    assert "secne" in msg and "did you mean 'scene'" in msg


def test_scene_field_cannot_be_swept():
    msg = errors_of(spec_text(sweep="grid = { n_prisms = [4, 6] }"))
    assert "sweep.grid.n_prisms" in msg and "[scene]" in msg


# ---------------------------------------------------------------------- bad values
@pytest.mark.parametrize(
    "text, fragments",
    [
        (spec_text(sweep="grid = { v0 = [0.001, 0.002, -0.1] }"), ["sweep.grid.v0[2]", "-0.1", "in [0, 10000]"]),
        (spec_text(sweep="grid = { prestrain = [0.0, 1.0] }"), ["sweep.grid.prestrain[1]", "1.0", "[0, 1)"]),
        (spec_text(sweep="grid = { base_rigidity = [0.0, 1.5] }"), ["sweep.grid.base_rigidity[1]", "1.5", "[0, 1]"]),
        (spec_text(sweep="grid = { v0 = [0.001, \"fast\"] }"), ["sweep.grid.v0[1]", "'fast'", "number"]),
        (spec_text(sweep="cases = [{ v0 = 0.001 }, { v0 = -2.0 }]"), ["sweep.cases[1].v0", "-2.0"]),
        (spec_text(sweep="grid = { v0 = [0.001] }\nfixed = { unit_mass = 0.0 }"), ["sweep.fixed.unit_mass", "0.0", "[1e-15, 1e+06] [kg]"]),
        (spec_text(sweep="grid = { cable_EA = [0.3, -1.0] }"), ["sweep.grid.cable_EA[1]", "-1.0"]),
        (spec_text(sweep="grid.v0 = { start = 0.0, stop = 0.1, num = 4, spacing = \"log\" }"), ["sweep.grid.v0.start", "log"]),
        (spec_text(sweep="grid.v0 = { start = 0.001, stop = 0.1 }"), ["sweep.grid.v0", "num"]),
        (spec_text(sweep="grid = { v0 = [0.001, 0.001] }"), ["sweep.grid.v0", "distinct"]),
        (spec_text(scene="n_prisms = 0"), ["scene.n_prisms", "0", "positive integer"]),
        (spec_text(scene="n_prisms = 2.5"), ["scene.n_prisms", "2.5", "integer"]),
        (spec_text(scene="n_prisms = 6\nradius = -5e-3"), ["scene.radius", "-0.005", "[1e-06, 1000] [m]"]),
        (spec_text(scene="n_prisms = 6\nunit_mass = 0"), ["scene.unit_mass", "[1e-15, 1e+06] [kg]"]),
        (spec_text(scene="n_prisms = 6\ntwist = 0.5"), ["scene.twist", "0.5", "pi/3"]),
        (spec_text(scene="n_prisms = 6\nbar_mass = -1.0"), ["scene.bar_mass", "-1.0"]),
        (spec_text(scene='n_prisms = 6\nhandedness = "RRL"'), ["scene.handedness", "RRL"]),
        (spec_text(scene='n_prisms = 6\nend_base_mass = "halve"'), ["scene.end_base_mass", "did you mean 'half'"]),
        (spec_text(run='dt = "fast"'), ["run.dt", "'fast'", "auto"]),
        (spec_text(run="dt = 0"), ["run.dt", "0", ">= 1e-15 [s]"]),
        (spec_text(run="t_end = -1.0"), ["run.t_end", "-1.0", "in (0, 1e+09] [s]"]),
        (spec_text(run="t_end = 0.1\ndt = 0.5"), ["run.dt", "0.5", "t_end"]),
        (spec_text(run="t_end = 0.1\nshard_size = 0"), ["run.shard_size", "0", "positive integer"]),
        (spec_text(run="t_end = 0.1\nrecord_strain = 1"), ["run.record_strain", "true or false"]),
        (spec_text(run='t_end = 0.1\ndevice = "gpu"'), ["run.device", "'gpu'", "cuda:N"]),
        (spec_text(run="t_end = 0.1\ndt_safety = 2.0"), ["run.dt_safety", "2.0", "[1e-06, 0.5]"]),
    ],
)
def test_bad_value_names_key_path_and_value(text, fragments):
    msg = errors_of(text)
    for f in fragments:
        assert f in msg, (f, msg)


def test_swept_and_fixed_conflict():
    msg = errors_of(spec_text(sweep="grid = { v0 = [0.001] }\nfixed = { v0 = 0.002 }"))
    assert "sweep.fixed.v0" in msg and "sweep.grid.v0" in msg
    msg = errors_of(spec_text(scene="n_prisms = 6\nunit_mass = 0.02", sweep="grid = { unit_mass = [0.01, 0.02] }"))
    assert "scene.unit_mass" in msg


def test_missing_or_double_sweep():
    assert "sweep" in errors_of("[scene]\nn_prisms = 4\n[run]\nt_end = 0.1\n")
    msg = errors_of(spec_text(sweep="grid = { v0 = [0.001] }\ncases = [{ v0 = 0.001 }]"))
    assert "either grid or cases" in msg


def test_every_problem_reported_at_once():
    with pytest.raises(SpecError) as info:
        parse_spec(spec_text(scene="n_prisms = -1", sweep="grid = { v0 = [-1.0] }", run="t_ned = 1"))
    paths = " ".join(info.value.errors)
    assert "scene.n_prisms" in paths and "sweep.grid.v0[0]" in paths and "run.t_ned" in paths
    assert len(info.value.errors) == 3


def test_invalid_toml():
    assert "not valid TOML" in errors_of("[scene\nn_prisms = 4")


# ---------------------------------------------------------------------- dt stability limit (needs the engine's estimate)
def test_dt_above_stability_limit_refused_with_the_limit():
    from warp_tensegrity import sweep

    spec = parse_spec(spec_text(run="t_end = 0.1\ndt = 0.05"))
    with pytest.raises(SpecError) as info:
        sweep.plan_sweep(spec, device="cpu")
    msg = str(info.value)
    est = estimate_batch(spec.scene, spec.column_params(), spec.run_settings(device="cpu", dt="auto"))
    assert "run.dt = 0.05" in msg and "stability limit" in msg
    assert f"{est['dt_limit']:.6g}" in msg
    assert "allow_unstable_dt" in msg

    ok = parse_spec(spec_text(run="t_end = 0.1\ndt = 0.05\nallow_unstable_dt = true"))
    plan = sweep.plan_sweep(ok, device="cpu")
    assert plan.dt == 0.05 and plan.dt_limit == pytest.approx(est["dt_limit"])

    auto = sweep.plan_sweep(parse_spec(spec_text()), device="cpu")
    assert auto.dt <= auto.dt_limit * auto.run.settings.dt_safety * (1 + 1e-12)  # default: from the accuracy policy


# ---------------------------------------------------------------------- CLI stays light
def test_cli_help_does_not_import_warp():
    code = textwrap.dedent(
        """
        import sys
        from warp_tensegrity import cli
        try:
            cli.main(["run", "--help"])
        except SystemExit:
            pass
        bad = [m for m in ("warp", "xarray", "netCDF4", "distributed") if m in sys.modules]
        assert not bad, bad
        """
    )
    env = dict(os.environ, PYTHONPATH=str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=60)
    assert out.returncode == 0, out.stderr
    assert "--dry-run" in out.stdout and "--device" in out.stdout


def test_cli_reports_spec_errors(tmp_path, capsys):
    from warp_tensegrity import cli

    bad = tmp_path / "bad.toml"
    bad.write_text(spec_text(run="t_ned = 0.1"))
    assert cli.main(["run", str(bad), "-o", str(tmp_path / "out.nc")]) == 1
    err = capsys.readouterr().err
    assert "run.t_ned" in err and "did you mean 't_end'" in err
