"""Fuzzed inputs (Hypothesis, derandomized: the same inputs on every run) over sweep specs, the
command line and the Python API. Every input must end in one of two ways:

* a clear error: non-zero exit (or an OptionError from the API), no traceback, and the message
  names the key and the value that were bad;
* a valid run: here a ``--dry-run`` (which plans the sweep and asks the engine's estimate), plus
  a few tiny real runs and subprocess checks at the end.

"Accepted nonsense" is decided by an oracle written here, independently of the options model:
:func:`physics_problems` states the physical rules of a spec (SI units, the paper's model) and a
spec it finds invalid must be refused; a spec it finds valid must be accepted.

Two classes hold sizes and settings to the budget (issue 30): ``run sizes`` draws every [run]
size (t_end, output_interval, dt, n_prisms, record_strain) and a spec must be refused up front
with its figure or planned with bounded memory; ``api to_xarray`` runs ``simulate_batch`` with any
combination of what it keeps and measures, then ``.to_xarray()``.

Per-class counts are printed and, with ``FUZZ_COUNTS_DIR=dir``, written there as JSON
(``tests/artifacts/fuzz_counts.json`` holds the committed record).
"""

from __future__ import annotations

import contextlib
import io
import json
import math
import os
import re
import subprocess
import sys
import tomllib
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
import tomli_w
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from warp_tensegrity import cli
from warp_tensegrity.options import OptionError, RunSettings, check_column_param
from warp_tensegrity.scene import ColumnConfig, NetworkError

from tests.memory_cap import address_space_cap

REPO = Path(__file__).resolve().parents[1]

EXPLORE = int(os.environ.get("FUZZ_EXPLORE", "0"))
"""0 (CI): derandomized, the quotas below. N > 0 (a local bug hunt): random seeds, N x the quotas."""
FUZZ = settings(derandomize=not EXPLORE, deadline=None, database=None, print_blob=True,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large, HealthCheck.filter_too_much,
                                       HealthCheck.function_scoped_fixture])
QUOTAS = {"spec values": 260, "spec structure": 220, "spec bytes": 170, "cli arguments": 220, "python api": 300,
          "run sizes": 100, "api to_xarray": 80, "profiles": 90}
"""Generated inputs per class (1,440 in all). Derandomized Hypothesis may stop a little early
once it has exhausted a strategy, so each class asserts at least 90 % of its quota."""


def fuzz(cls: str):
    return settings(FUZZ, max_examples=QUOTAS[cls] * max(1, EXPLORE))

BASE = {
    "title": "fuzz base",
    "scene": {"n_prisms": 3},
    "sweep": {"grid": {"v0": [0.001, 0.002]}, "fixed": {"prestrain": 0.001}},
    "run": {"t_end": 0.02, "output_interval": 0.005},
}

# ---------------------------------------------------------------------- the oracle (independent of options.py)
PI = math.pi


def _real(x):
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)


def _integral(x):
    return _real(x) and float(x).is_integer()


SCENE_RULES = {
    "n_prisms": lambda x: _integral(x) and 1 <= x <= 100_000,  # longer: 600 m of the paper's prisms
    "handedness": lambda x: isinstance(x, str),  # checked with n_prisms below
    # physical ranges (SI): micro-fabricated to building-scale columns
    "radius": lambda x: _real(x) and 1e-6 <= x <= 1e3,
    "height": lambda x: _real(x) and 1e-6 <= x <= 1e3,
    # a regular minimal prism has a self-stress only at twist 5 pi/6 (paper Sec. 3)
    "twist": lambda x: _real(x) and abs(x - 5 * PI / 6) < 1e-9,
    "cable_modulus": lambda x: _real(x) and 1.0 <= x <= 1e13,  # gels .. above diamond
    "cable_radius": lambda x: _real(x) and 1e-9 <= x <= 1.0,
    "unit_mass": lambda x: _real(x) and 1e-15 <= x <= 1e6,
    "end_base_mass": lambda x: x in ("half", "full"),
    "bar_mass": lambda x: _real(x) and 0 <= x <= 1e6,
    "impact_admissibility": lambda x: x in ("rigid_members", "project", "end_twist"),
}
PARAM_RULES = {
    "prestrain": lambda x: _real(x) and 0 <= x < 1,  # p = 1: zero cable rest length
    "v0": lambda x: _real(x) and 0 <= x <= 1e4,  # compressive impact speed, up to 10 km/s
    "base_rigidity": lambda x: _real(x) and 0 <= x <= 1,  # FB .. RB
    "cable_EA": lambda x: _real(x) and 0 < x <= 1e20,
    "unit_mass": lambda x: _real(x) and 1e-15 <= x <= 1e6,
}
_POS_INT = lambda x: _integral(x) and x >= 1  # noqa: E731
_BOOL = lambda x: isinstance(x, bool)  # noqa: E731
RUN_RULES = {
    # times: a femtosecond to ~30 years
    "t_end": lambda x: _real(x) and 0 < x <= 1e9,
    "dt": lambda x: x == "auto" or (_real(x) and x >= 1e-15),
    "output_interval": lambda x: x == "auto" or (_real(x) and x >= 1e-15),
    "method": lambda x: x in ("rattle", "rk4", "yoshida4", "symplectic_euler"),
    "precision": lambda x: x in ("fp32", "fp64"),
    "device": lambda x: x in ("cpu", "auto"),  # this machine; cuda is checked by the engine
    "shard_size": _POS_INT,
    "record_strain": _BOOL,
    "record_energy": _BOOL,
    "dt_safety": lambda x: _real(x) and 1e-6 <= x <= 0.5,  # strong impacts lower the limit to ~0.45
    "allow_unstable_dt": _BOOL,
    "projection_tol": lambda x: _real(x) and 0 < x < 1e-2,
    "max_projection_iters": _POS_INT,
    "failure_bar_error": lambda x: _real(x) and x > 0,
    "steps_per_graph": _POS_INT,
    "fused": lambda x: x is True or x is False or x == "auto",
    "accuracy": lambda x: _real(x) and 1e-15 <= x < 1,  # not below fp64 round-off
    "truncate": _BOOL,
}


def physics_problems(data: dict) -> list[str]:
    """Key paths whose value breaks the physical rules of a spec ([] = a valid spec)."""
    bad = []
    scene, sweep, run = (data.get(k, {}) for k in ("scene", "sweep", "run"))
    scene, sweep, run = (t if isinstance(t, dict) else {} for t in (scene, sweep, run))
    for k, v in scene.items():
        rule = SCENE_RULES.get(k) or PARAM_RULES.get(k)
        if rule is None or not rule(v):
            bad.append(f"scene.{k}")
    n = scene.get("n_prisms", 50)
    h = scene.get("handedness", "right")
    if isinstance(h, str) and h not in ("right", "left", "alternating") and _integral(n):
        if not (len(h) == n and set(h.upper()) <= {"R", "L"}):
            bad.append("scene.handedness")
    a, h, rc = scene.get("radius", 5e-3), scene.get("height", 6.2e-3), scene.get("cable_radius", 0.14e-3)
    if all(_real(x) and x > 0 for x in (a, h, rc)):
        if not 1e-2 <= h / a <= 1e2:  # needle or disc: not a prism column
            bad.append("scene.height" if "height" in scene else "scene.radius")
        elif rc > a:  # a cable thicker than the prism
            bad.append("scene.cable_radius" if "cable_radius" in scene else "scene.radius")
    if _real(scene.get("bar_mass", 0)) and scene.get("bar_mass", 0) > 0 and n != 1 and "scene.bar_mass" not in bad:
        bad.append("scene.bar_mass")  # a massive bar's inertia needs class-1 networks: one prism
    grid = sweep.get("grid", {})
    grid = grid if isinstance(grid, dict) else {}
    for k, vals in grid.items():
        if isinstance(vals, dict):  # a range table: structure_ok
            continue
        if k not in PARAM_RULES or not isinstance(vals, list) or not vals or k in scene:
            bad.append(f"sweep.grid.{k}")
            continue
        for i, v in enumerate(vals):
            if not PARAM_RULES[k](v):
                bad.append(f"sweep.grid.{k}[{i}]")
        if all(_real(v) for v in vals) and len(set(vals)) != len(vals):
            bad.append(f"sweep.grid.{k}")
    fixed = sweep.get("fixed", {})
    for k, v in (fixed.items() if isinstance(fixed, dict) else [("fixed", None)]):
        if k not in PARAM_RULES or not PARAM_RULES[k](v) or k in grid:
            bad.append(f"sweep.fixed.{k}")
    for k, v in run.items():
        if k not in RUN_RULES or not RUN_RULES[k](v):
            bad.append(f"run.{k}")
    t_end = run.get("t_end", 1.0)
    if _real(t_end) and t_end > 0:
        for k in ("dt", "output_interval"):
            v = run.get(k, "auto")
            if _real(v) and v > t_end:
                bad.append(f"run.{k}")
    if run.get("fused") is True and run.get("method", "rattle") != "rattle":
        bad.append("run.fused")
    if "accuracy" in run:
        bad += [f"run.{k}" for k in ("method", "precision", "dt", "dt_safety") if k in run]
    return bad


# ---------------------------------------------------------------------- running one input
COUNTS: dict[str, Counter] = {}


def _count(cls: str, outcome: str):
    COUNTS.setdefault(cls, Counter())[outcome] += 1


def run_cli(argv) -> tuple[int, str, str]:
    """cli.main in-process: (exit code, stdout, stderr); SystemExit (argparse) is an exit code.
    Any other exception propagates: it is a traceback the user would see."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            rc = cli.main([str(a) for a in argv])
        except SystemExit as e:
            rc = e.code if isinstance(e.code, int) else 1
    return rc, out.getvalue(), err.getvalue()


def _value_texts(v) -> list[str]:
    """How a message may quote the value v."""
    if isinstance(v, float):
        return [repr(v), format(v, "g"), str(v)]
    if isinstance(v, (list, dict)):
        return [repr(v)[:40], json.dumps(v)[:40]]
    return [repr(v), str(v)]


def check_clear_error(rc, out, err, key: str | None = None, value=None):
    assert rc != 0, (out, err)
    assert "Traceback" not in err and "Traceback" not in out, err
    assert err.strip(), "an error needs a message"
    if key is not None:
        leaf = key.split(".")[-1].split("[")[0]
        assert leaf in err, (key, err)
    if value is not None and not (isinstance(value, str) and len(value) > 60):
        texts = _value_texts(value)
        assert any(t in err for t in texts), (texts, err)


def dry_run_spec(tmp_path: Path, payload: bytes, extra=()) -> tuple[int, str, str]:
    p = tmp_path / "spec.toml"
    p.write_bytes(payload)
    return run_cli(["run", p, "-o", tmp_path / "out.nc", "--device", "cpu", "--dry-run", *extra])


def judge_spec(cls: str, tmp_path: Path, data: dict, key: str | None = None, value=None, extra=()):
    """Dry-run a spec (as a dict) and hold the outcome to the oracle."""
    rc, out, err = dry_run_spec(tmp_path, tomli_w.dumps(data).encode(), extra)
    bad = physics_problems(data)
    if bad:
        check_clear_error(rc, out, err, key if key in bad else bad[0], value if key in bad else None)
        _count(cls, "clear error")
    elif rc == 0:
        assert "fits:" in out and "columns:" in out, out
        _count(cls, "valid (dry run)" if "fits:        yes" in out else "valid, refused by the estimate")
    else:  # valid by the oracle but refused: only the estimate may do that, with its figures
        check_clear_error(rc, out, err)
        assert ("needs about" in err or "need about" in err or "estimate" in err or "stability limit" in err
                or "cannot be done" in err), err
        _count(cls, "refused by the estimate")


# ---------------------------------------------------------------------- strategies
NASTY = st.one_of(
    st.sampled_from([0, 0.0, -0.0, -1, -1e-300, 1e-300, 1e308, -1e308, float("nan"), float("inf"), float("-inf"),
                     1, 2, 0.5, 0.4999, 0.5001, 1.0, 0.999999, 1.0000001, 2**31, 2**63 - 1, True, False,
                     "", "auto", "x", "1.0", "nan", [], [1.0], {}, {"a": 1}]),
    st.floats(allow_nan=True, allow_infinity=True),
    st.floats(min_value=-2.0, max_value=2.0),
    st.integers(min_value=-10, max_value=10),
    st.text(max_size=8),
    st.booleans(),
)

SCENE_KEYS = sorted(SCENE_RULES) + ["prestrain", "v0", "base_rigidity", "cable_EA"]
VALUE_TARGETS = ([("scene", k) for k in SCENE_KEYS] + [("run", k) for k in sorted(RUN_RULES)]
                 + [("sweep.grid", k) for k in PARAM_RULES] + [("sweep.fixed", k) for k in ("prestrain", "cable_EA")])

# values that would need more than this machine: these must be refused, never run
HUGE_SCENE = {"n_prisms": lambda x: _integral(x) and x > 10_000}


def _with(section: str, key: str, value) -> dict:
    data = json.loads(json.dumps(BASE))
    if section == "sweep.grid":
        data["sweep"]["grid"] = {key: [value] if not isinstance(value, list) else value}
        data["sweep"]["fixed"] = {k: v for k, v in data["sweep"]["fixed"].items() if k != key}
    elif section == "sweep.fixed":
        data["sweep"]["fixed"][key] = value
    else:
        data[section][key] = value
    if section == "scene" and key in data["sweep"]["fixed"]:
        del data["sweep"]["fixed"][key]
    return data


@pytest.fixture
def work(tmp_path_factory):
    return tmp_path_factory.mktemp("fuzz")


_PROBE = {}


@pytest.fixture(autouse=True)
def one_probe(monkeypatch, tmp_path_factory):
    """The dry run's calibration probe (seconds of stepping plus a fresh process, cached per
    scene) would run for every valid fuzzed scene: far too long (a fuzzed 200-prism column on the
    CPU alone takes minutes). The harness judges input handling, not the estimate
    (tests/policy/test_decide_and_cost.py does), so every dry run here reuses ONE real probe, of ci_small's
    scene; the prediction from it (calibrate.predict) still runs on each fuzzed plan."""
    from warp_tensegrity.policy import calibrate
    from warp_tensegrity.sweep import plan as sweep_plan
    from warp_tensegrity.sweep.spec import load_spec

    real = calibrate.probe

    def probe_once(config, params, run, shard_size, use_cache=True):
        if "cal" not in _PROBE:
            plan = sweep_plan.plan_sweep(load_spec(Path(__file__).resolve().parents[1] / "sweeps" / "ci_small.toml"),
                                         tmp_path_factory.mktemp("probe") / "ci_small.nc", device="cpu")
            shard = max(b - a for a, b in plan.shards)
            _PROBE["cal"] = real(plan.spec.scene, plan.params, plan.run, shard, use_cache=use_cache)
        return _PROBE["cal"]

    monkeypatch.setattr(calibrate, "probe", probe_once)


def _report(cls: str, minimum: int):
    c = COUNTS.get(cls, Counter())
    total = sum(c.values())
    print(f"\nfuzz class {cls!r}: {total} inputs {dict(c)}")
    d = os.environ.get("FUZZ_COUNTS_DIR")
    if d:
        Path(d).mkdir(parents=True, exist_ok=True)
        (Path(d) / f"{cls}.json").write_text(json.dumps({"class": cls, "total": total, "outcomes": dict(c)}, indent=1))
    assert total >= minimum, (cls, total)


# ---------------------------------------------------------------------- 1. spec values
@fuzz("spec values")
@given(target=st.sampled_from(VALUE_TARGETS), value=NASTY)
# the named cases of the issue, always run beside the generated ones
@example(target=("run", "dt"), value=1e-300)  # below a femtosecond: refused by the model
@example(target=("run", "dt"), value=1e-14)  # absurd dt: 2e12 steps, refused by the estimate
@example(target=("run", "dt_safety"), value=2.225073858507203e-309)  # subnormal: overflowed the estimate
@example(target=("run", "dt"), value=1e300)
@example(target=("run", "t_end"), value=1e300)
@example(target=("run", "output_interval"), value=1e-300)
@example(target=("sweep.grid", "prestrain"), value=1.0)  # prestrain >= 1
@example(target=("sweep.fixed", "prestrain"), value=1.5)
@example(target=("sweep.grid", "base_rigidity"), value=1.0000001)  # base rigidity outside [0, 1]
@example(target=("sweep.grid", "base_rigidity"), value=-1e-300)
@example(target=("scene", "n_prisms"), value=10**9)  # huge scene: planning would not fit
@example(target=("scene", "n_prisms"), value=0)
@example(target=("sweep.grid", "v0"), value=float("nan"))
@example(target=("sweep.grid", "cable_EA"), value=float("inf"))
def _spec_values(work, target, value):
    """One key of a valid spec set to a wrong type, negative, zero, NaN, inf, huge or tiny value."""
    section, key = target
    if section == "scene" and HUGE_SCENE.get(key, lambda x: False)(value):
        value = value  # kept: planning must refuse it from the estimate, not hang
    judge_spec("spec values", work, _with(section, key, value), key=key, value=value)


def test_fuzz_spec_values(work):
    COUNTS.pop("spec values", None)
    _spec_values(work)
    _report("spec values", int(0.9 * QUOTAS["spec values"]))


# ---------------------------------------------------------------------- 2. spec structure
IDENT = st.text(alphabet="abcdefghijklmnopqrstuvwxyz_0123456789", min_size=1, max_size=12)


@st.composite
def structures(draw):
    data = json.loads(json.dumps(BASE))
    kind = draw(st.sampled_from(["unknown", "missing", "grid", "cases", "range", "both", "types", "typo"]))
    if kind == "unknown":
        where = draw(st.sampled_from(["", "scene", "run", "sweep", "sweep.grid", "sweep.fixed"]))
        name = draw(IDENT)
        t = data
        for part in [p for p in where.split(".") if p]:
            t = t[part]
        if name in t or (where == "" and name in ("title", "description")):
            name = name + "_x"
        t[name] = draw(NASTY)
    elif kind == "missing":
        for sec in draw(st.lists(st.sampled_from(["scene", "sweep", "run", "title"]), min_size=1, unique=True)):
            data.pop(sec, None)
    elif kind == "grid":
        data["sweep"]["grid"] = draw(st.one_of(
            st.just({}), st.just({"v0": []}),
            st.dictionaries(st.sampled_from(["v0", "prestrain", "base_rigidity", "n_prisms", "vo"]),
                            st.lists(st.floats(-0.5, 1.5), max_size=5), max_size=3)))
        data["sweep"]["fixed"] = {}
    elif kind == "cases":
        data["sweep"] = {"cases": draw(st.one_of(
            st.just([]), st.just({}),
            st.lists(st.dictionaries(st.sampled_from(["v0", "prestrain", "label", "x"]),
                                     st.one_of(st.floats(-1, 2), st.text(max_size=3)), max_size=3), max_size=4)))}
    elif kind == "range":
        rng = draw(st.dictionaries(st.sampled_from(["start", "stop", "num", "spacing", "step"]),
                                   st.one_of(st.floats(-1, 1e12), st.integers(-5, 10**12), st.sampled_from(["log", "linear", "lg"])),
                                   max_size=5))
        data["sweep"]["grid"] = {"v0": rng}
    elif kind == "both":
        data["sweep"]["cases"] = [{"v0": 0.001}]
    elif kind == "types":
        sec = draw(st.sampled_from(["scene", "sweep", "run", "title", "description"]))
        data[sec] = draw(st.one_of(st.integers(), st.text(max_size=4), st.lists(st.integers(), max_size=2)))
    else:  # typo of a real key
        sec = draw(st.sampled_from(["scene", "run"]))
        key = draw(st.sampled_from(sorted(SCENE_RULES) if sec == "scene" else sorted(RUN_RULES)))
        i = draw(st.integers(0, len(key) - 1))
        typo = key[:i] + key[i + 1:] if len(key) > 2 else key + "x"
        if typo not in SCENE_RULES and typo not in RUN_RULES:
            data[sec][typo] = 1.0
    return data


def structure_ok(data) -> bool:
    """The oracle's structural rules: known tables and keys, one non-empty grid or case list."""
    if set(data) - {"title", "description", "scene", "sweep", "run"}:
        return False
    if any(not isinstance(data.get(k, ""), str) for k in ("title", "description")):
        return False
    if not all(isinstance(data.get(k, {}), dict) for k in ("scene", "sweep", "run")) or "sweep" not in data:
        return False
    sw = data["sweep"]
    if set(sw) - {"grid", "cases", "fixed"} or ("grid" in sw) == ("cases" in sw):
        return False
    if "grid" in sw:
        g = sw["grid"]
        if not isinstance(g, dict) or not g:
            return False
        for k, v in g.items():
            if isinstance(v, dict):
                if set(v) - {"start", "stop", "num", "spacing"} or not {"start", "stop", "num"} <= set(v):
                    return False
                if not (_integral(v["num"]) and v["num"] >= 1) or v.get("spacing", "linear") not in ("linear", "log"):
                    return False
                if k not in PARAM_RULES or not (PARAM_RULES[k](v["start"]) and PARAM_RULES[k](v["stop"])):
                    return False
                if v.get("spacing") == "log" and not (v["start"] > 0 and v["stop"] > 0):
                    return False
                if v["num"] > 1 and v["start"] == v["stop"]:
                    return False  # repeated values
            elif not isinstance(v, list):
                return False
    else:
        cs = sw["cases"]
        if not isinstance(cs, list) or not cs:
            return False
        for c in cs:
            if not isinstance(c, dict) or set(c) - set(PARAM_RULES) - {"label"}:
                return False
            if not isinstance(c.get("label", ""), str):
                return False
            if any(k != "label" and not PARAM_RULES[k](v) for k, v in c.items()):
                return False
            if any(k in sw.get("fixed", {}) or k in data.get("scene", {}) for k in c if k != "label"):
                return False
    return True


@fuzz("spec structure")
@given(data=structures())
@example(data={**BASE, "sweep": {"grid": {"v0": {"start": 1e-3, "stop": 0.1, "num": 10**12}}}})  # huge grid
@example(data={**BASE, "sweep": {"grid": {"v0": []}}})  # empty grid axis
@example(data={**BASE, "sweep": {"grid": {}}})  # empty grid
@example(data={"scene": {"n_prisms": 3}})  # missing [sweep] and [run]
def _spec_structure(work, data):
    """Unknown keys and tables, missing sections, empty and huge grids, malformed ranges and cases."""
    rc, out, err = dry_run_spec(work, tomli_w.dumps(data).encode())
    valid = structure_ok(data) and not physics_problems(data)
    if not valid or rc != 0:
        if valid:  # a structurally valid spec refused: only by the estimate (huge grid), with figures
            assert "need about" in err or "needs about" in err or "estimate" in err or "distinct" in err, err
        check_clear_error(rc, out, err)
        # the message names a key path of the spec
        assert any(s in err for s in ("scene", "sweep", "run", "title", "description", "top-level", "columns")), err
        _count("spec structure", "clear error")
    else:
        assert "fits:" in out
        _count("spec structure", "valid (dry run)")


def test_fuzz_spec_structure(work):
    COUNTS.pop("spec structure", None)
    _spec_structure(work)
    _report("spec structure", int(0.9 * QUOTAS["spec structure"]))


# ---------------------------------------------------------------------- 3. bytes: non-UTF-8, truncated TOML
VALID_TEXT = tomli_w.dumps(BASE).encode()


@fuzz("spec bytes")
@given(kind=st.sampled_from(["truncated", "binary", "latin1", "insert"]), cut=st.integers(0, len(VALID_TEXT)),
       blob=st.binary(max_size=40))
def _spec_bytes(work, kind, cut, blob):
    """Truncated TOML, non-UTF-8 bytes, binary garbage spliced into a valid spec."""
    if kind == "truncated":
        payload = VALID_TEXT[:cut]
    elif kind == "binary":
        payload = blob
    elif kind == "latin1":
        payload = VALID_TEXT.replace(b"fuzz base", "f\u00fczz b\u00e4se".encode("latin-1"))
    else:
        payload = VALID_TEXT[:cut] + blob + VALID_TEXT[cut:]
    rc, out, err = dry_run_spec(work, payload)
    try:
        data = tomllib.loads(payload.decode("utf-8"))
    except (UnicodeDecodeError, tomllib.TOMLDecodeError):
        data = None
    if data is None:
        check_clear_error(rc, out, err)
        assert "UTF-8" in err or "not valid TOML" in err, err
        _count("spec bytes", "clear error (not UTF-8 / not TOML)")
    elif rc == 0:
        assert structure_ok(data) and not physics_problems(data), data
        _count("spec bytes", "valid (dry run)")
    else:
        check_clear_error(rc, out, err)
        assert not structure_ok(data) or physics_problems(data), (data, err)
        _count("spec bytes", "clear error")


def test_fuzz_spec_bytes(work):
    COUNTS.pop("spec bytes", None)
    _spec_bytes(work)
    _report("spec bytes", int(0.9 * QUOTAS["spec bytes"]))


# ---------------------------------------------------------------------- 3b. profiles along the column
PROFILED = {"prestrain": "prism", "cable_EA": "prism", "unit_mass": "level"}
N_BASE = BASE["scene"]["n_prisms"]


def profile_ok(key: str, table, n: int = N_BASE) -> bool:
    """The oracle of a profile table for parameter ``key`` in a column of ``n`` prisms."""
    if key not in PROFILED or not isinstance(table, dict):
        return False
    kinds = [k for k in ("values", "grade", "segments") if k in table]
    if len(kinds) != 1 or set(table) - {"values", "grade", "segments", "at"}:
        return False
    kind, vals = kinds[0], table[kinds[0]]
    if not isinstance(vals, list) or not vals or not all(PARAM_RULES[key](v) for v in vals):
        return False
    if kind == "values":
        return "at" not in table and len(vals) == n + (PROFILED[key] == "level")
    if len(vals) != 2:
        return False
    if kind == "grade":
        return "at" not in table
    at = table.get("at")
    return isinstance(at, int) and not isinstance(at, bool) and 1 <= at <= n - 1


PROFILE_VALUE = st.one_of(st.sampled_from([0.0, 1e-3, 0.02, 0.5, 0.99, 1.0, 1.5, -1e-3, 1e-16, 1e7, 1e21,
                                           float("nan"), float("inf"), True, "x", None]),
                          st.floats(min_value=-0.1, max_value=1.2))
GOOD_VALUE = st.floats(min_value=0.001, max_value=0.9)  # in bounds for prestrain, cable_EA and unit_mass


@st.composite
def profile_tables(draw):
    """Half well-formed tables of good values (valid where the key takes a profile), half anything."""
    good = draw(st.booleans())
    kinds = ["values", "grade", "segments"] + ([] if good else ["grad", "at"])
    kind = draw(st.sampled_from(kinds))
    value = GOOD_VALUE if good else PROFILE_VALUE
    if kind == "values":
        size = draw(st.sampled_from([N_BASE, N_BASE + 1])) if good else draw(st.integers(0, 6))
    else:
        size = 2 if good else draw(st.sampled_from([2, 2, 1, 3]))
    vals = [draw(value) for _ in range(size)]
    table = {kind: [v for v in vals if v is not None]} if kind != "at" else {}
    if kind == "segments" or (not good and draw(st.integers(0, 9)) == 0):
        table["at"] = draw(st.integers(1, N_BASE - 1)) if good else draw(
            st.one_of(st.integers(-1, N_BASE + 1), st.sampled_from([1.0, 1.5, "1", True])))
    return table


@fuzz("profiles")
@given(where=st.sampled_from(["python", "sweep.fixed", "case", "grid_at", "scene"]),
       key=st.sampled_from(["prestrain", "unit_mass", "cable_EA", "v0", "base_rigidity", "radius"]),
       table=profile_tables(), at=st.lists(st.one_of(st.integers(-1, N_BASE + 1), st.just(1.5)), min_size=1, max_size=3))
@example(where="sweep.fixed", key="prestrain", table={"values": [0.01, 0.02]}, at=[1])  # wrong length
@example(where="sweep.fixed", key="unit_mass", table={"grade": [0.02, -0.01]}, at=[1])  # negative mass
@example(where="sweep.fixed", key="prestrain", table={"segments": [0.01, 1.0], "at": 1}, at=[1])  # prestrain >= 1
@example(where="scene", key="radius", table={"grade": [1e-3, 2e-3]}, at=[1])  # a profile on a scene parameter
@example(where="grid_at", key="prestrain", table={"segments": [0.01, 0.02], "at": 1}, at=[1, 3])  # at = n
def _profiles(work, where, key, table, at):
    """Profile tables (explicit values, grades, segments, malformed ones) on every kind of key, in the
    spec (dry run through the CLI: a clear error naming the key, or a valid spec) and in the Python API."""
    if where == "python":
        from warp_tensegrity.scene.batch import column_batch

        cfg = ColumnConfig(n_prisms=N_BASE)
        try:
            column_batch(cfg, {key: table}) if key != "radius" else ColumnConfig(n_prisms=N_BASE, radius=table)
        except (NetworkError, OptionError) as e:
            assert not (profile_ok(key, table) and key != "radius"), (key, table, e)
            assert "\n" not in str(e) and key in str(e), str(e)
            _count("profiles", "clear error (python)")
        else:
            assert profile_ok(key, table), (key, table)
            _count("profiles", "valid (python)")
        return
    data = json.loads(json.dumps(BASE))
    data["sweep"]["fixed"] = {}
    expect_ok = profile_ok(key, table)
    if where == "sweep.fixed":
        data["sweep"]["fixed"][key] = table
    elif where == "scene":
        data["scene"][key] = table
        expect_ok = expect_ok and key != "unit_mass"  # a scene field: one value for the whole column
    elif where == "case":
        data["sweep"] = {"cases": [{"v0": 0.001}, {"v0": 0.002, key: table}]}
        expect_ok = expect_ok and key != "v0"
    else:  # a grid over the interface of a two-segment template
        data["sweep"]["fixed"][key] = table
        data["sweep"]["grid"] = {"v0": [0.001], f"{key}_at": at}
        expect_ok = (expect_ok and table.get("segments") is not None and len(set(at)) == len(at)
                     and all(isinstance(a, int) and 1 <= a <= N_BASE - 1 for a in at))
    rc, out, err = dry_run_spec(work, tomli_w.dumps(data).encode())
    if expect_ok:
        assert rc == 0 and "fits:" in out, (data, err)
        _count("profiles", "valid (dry run)")
    else:
        check_clear_error(rc, out, err, key=key)
        assert len(err.strip().splitlines()) <= 3, err  # the problem on one line (plus the tool's own lines)
        _count("profiles", "clear error")


def test_fuzz_profiles(work):
    COUNTS.pop("profiles", None)
    _profiles(work)
    _report("profiles", int(0.9 * QUOTAS["profiles"]))


# ---------------------------------------------------------------------- 4. command-line arguments
ARG_WORDS = ["run", "resume", "status", "combine", "--dry-run", "-o", "--device", "--shard-size", "--set",
             "--time-limit", "--ignore-estimate", "--dask", "--scheduler", "--overwrite", "--json", "--no-progress",
             "cpu", "cuda:7", "gpu", "auto", "0", "-1", "3", "nan", "inf", "1e309", "run.t_end=0.01",
             "run.t_end=-1", "run.t_ned=1", "scene.n_prisms=0", "scene.n_prisms=2", "run.method=rk5", "x=1", "run.",
             "SPEC", "OUT", "MISSING", "DIR", "", "--", "-h"]


OPTION_VALUES = ["cpu", "cuda:7", "gpu", "auto", "0", "-1", "3", "nan", "inf", "1e309", "0.5", "", "x", "SPEC", "OUT",
                 "MISSING", "DIR"]
SET_KEYS = [f"run.{k}" for k in RUN_RULES] + [f"scene.{k}" for k in SCENE_RULES] + ["run.t_ned", "scen.x", "run", ""]
SET_VALUES = ["0.01", "-1", "0", "nan", "inf", "-inf", "1e308", "true", "false", "auto", "rk4", "rk5", "fp16", "3",
              "2.5", "[1, 2]", "{a = 1}", '"cpu"', "cuda:0", "", "=", "0x10", "1_000"]


@st.composite
def argvs(draw):
    """Mostly well-formed commands with fuzzed option values; sometimes a random word salad."""
    if draw(st.integers(0, 9)) == 0:
        return draw(st.lists(st.sampled_from(ARG_WORDS), max_size=8))
    cmd = draw(st.sampled_from(["run", "run", "run", "resume", "status", "combine"]))
    argv = [cmd]
    if cmd == "run":
        argv += [draw(st.sampled_from(["SPEC", "SPEC", "SPEC", "MISSING", "DIR"])), "-o", "OUT"]
    elif cmd == "resume":
        argv += draw(st.sampled_from([["OUT"], ["SPEC", "-o", "OUT"], ["SPEC"], ["MISSING"]]))
    else:
        argv += [draw(st.sampled_from(["OUT", "MISSING", "DIR"]))]
    for _ in range(draw(st.integers(0, 4))):
        opt = draw(st.sampled_from(["--device", "--shard-size", "--set", "--set", "--set", "--time-limit",
                                    "--ignore-estimate", "--overwrite", "--no-progress", "--json", "--verbose"]))
        argv.append(opt)
        if opt == "--set":
            argv.append(f"{draw(st.sampled_from(SET_KEYS))}={draw(st.sampled_from(SET_VALUES))}")
        elif opt in ("--device", "--shard-size", "--time-limit"):
            argv.append(draw(st.sampled_from(OPTION_VALUES)))
    return argv


@fuzz("cli arguments")
@given(words=argvs())
def _cli_arguments(work, words):
    """Commands with fuzzed options and --set overrides (and some word salad): every one ends in a
    usage error, a clear error naming the option, or a dry run; never a traceback, never a real run
    (``run``/``resume`` are forced to --dry-run)."""
    spec = work / "ok.toml"
    spec.write_bytes(VALID_TEXT)
    subs = {"SPEC": spec, "OUT": work / "o.nc", "MISSING": work / "missing.toml", "DIR": work}
    argv = [subs.get(w, w) for w in words]
    if argv and argv[0] in ("run", "resume") and "--dry-run" not in argv:
        argv.append("--dry-run")
    rc, out, err = run_cli(argv)
    assert "Traceback" not in err and "Traceback" not in out, (argv, err)
    sets = [a for a in argv if isinstance(a, str) and "=" in a and a.split("=")[0] in SET_KEYS]
    if rc == 0:
        assert out.strip(), argv
        for a in sets:  # an accepted override was a valid one
            key, _, val = a.partition("=")
            sec, _, name = key.partition(".")
            rules = RUN_RULES if sec == "run" else SCENE_RULES
            assert name in rules, (argv, out)
        _count("cli arguments", "ok (dry run / help / status)")
    else:
        assert err.strip() or rc == 3, (argv, rc)
        assert "error" in err or rc == 3, (argv, err)
        _count("cli arguments", "usage error (exit 2)" if rc == 2 else "clear error")


def test_fuzz_cli_arguments(work):
    COUNTS.pop("cli arguments", None)
    _cli_arguments(work)
    _report("cli arguments", int(0.9 * QUOTAS["cli arguments"]))


# ---------------------------------------------------------------------- 5. Python API
API_KEYS = {
    RunSettings: sorted(RUN_RULES),
    ColumnConfig: sorted(SCENE_RULES),
}


def _param_ok(k, v) -> bool:
    """A per-column parameter given to the API: a number or a non-empty list of numbers, each valid."""
    vals = v if isinstance(v, list) and v else [v]
    return all(PARAM_RULES[k](x) for x in vals)


@fuzz("python api")
@given(cls=st.sampled_from([RunSettings, ColumnConfig, "params"]),
       kw=st.dictionaries(st.sampled_from(sorted(set(RUN_RULES) | set(SCENE_RULES) | set(PARAM_RULES) | {"t_ned", "x"})),
                          NASTY, max_size=3))
def _python_api(cls, kw):
    """RunSettings(**kw), ColumnConfig(**kw) and the per-column parameter check: a valid object
    or an OptionError naming the key; never another exception."""
    if cls == "params":
        kw = {k: v for k, v in kw.items() if k in PARAM_RULES}
        outcome = "valid"
        for k, v in kw.items():
            arr_ok = isinstance(v, (int, float)) and not isinstance(v, bool)
            try:
                check_column_param(k, [0.5 if k != "v0" else 0.0, v] if arr_ok else v)
            except OptionError as e:
                assert k in str(e) and not _param_ok(k, v), (k, v, e)
                outcome = "clear error"
                continue
            assert _param_ok(k, v), (k, v)
        _count("python api", outcome)
        return
    data = {"run": kw} if cls is RunSettings else {"scene": kw}
    if cls is ColumnConfig and "device" in kw:
        pass
    try:
        obj = cls(**kw)
    except (OptionError, NetworkError) as e:
        msg = str(e)
        bad = [k for k in kw if k not in API_KEYS[cls]] or [p.split(".")[-1] for p in physics_problems(data)]
        assert bad, (kw, msg)  # refused although the oracle finds nothing wrong
        assert any(b in msg for b in bad), (bad, msg)
        _count("python api", "clear error")
        return
    unknown = [k for k in kw if k not in API_KEYS[cls]]
    if cls is RunSettings:
        # the API accepts any device string the engine may know (cuda:N) and None for 'auto'
        data["run"] = {k: v for k, v in kw.items() if k != "device"}
    assert not unknown and not physics_problems(data), (kw, obj)
    _count("python api", "valid")


def test_fuzz_python_api():
    COUNTS.pop("python api", None)
    _python_api()
    _report("python api", int(0.9 * QUOTAS["python api"]))




# ---------------------------------------------------------------------- 5b. [run] sizes against the budget (issue 30)
MAX_STEPS = 2**31 - 1  # the device's int32 step counter
PLAN_PEAK_BYTES = 16e6
"""What planning and pricing a fuzzed spec of at most 2,000 prisms may allocate (tracemalloc peak;
measured: under 1 MB), whatever its output count: nothing of the run's size is built before it is
refused or run."""


def _e(lo, hi):
    """A power of ten with 3 significant digits, 10**lo .. 10**hi."""
    return st.floats(lo, hi).map(lambda e: float(f"{10 ** e:.3g}"))


@st.composite
def run_sizes(draw):
    """A valid base spec with its sizes drawn: t_end from 1 us to 1e9 s, output intervals down to
    1e-16 of it, explicit steps down to 1e-16 of it, up to 2,000 prisms, strain and energy kept or not."""
    data = json.loads(json.dumps(BASE))
    t_end = draw(_e(-6, 9))
    run = data["run"] = {"t_end": t_end}
    if draw(st.integers(0, 4)):
        run["output_interval"] = float(f"{t_end * draw(_e(-16, 0)):.3g}")
    if not draw(st.integers(0, 3)):
        run["dt"] = float(f"{t_end * draw(_e(-16, 0)):.3g}")
        run["allow_unstable_dt"] = True
    for k in ("record_strain", "record_energy", "truncate"):
        if draw(st.booleans()):
            run[k] = draw(st.booleans())
    run["method"] = draw(st.sampled_from(["rattle", "rk4"]))
    run["precision"] = draw(st.sampled_from(["fp32", "fp64"]))
    # (not 9-100 prisms: their dense equilibrium check takes ~1 s a plan on the 2-core host; beyond 100
    # it is sparse, tests/test_fuzz.py::test_fuzz_long_columns_plan_or_refuse)
    data["scene"]["n_prisms"] = draw(st.sampled_from([1, 2, 3, 8, 400, 2000]))
    return data


def size_oracle(data) -> tuple[float, float]:
    """(steps, host bytes of one column) at least, by the [run] rules alone: dt <= the output
    interval when 'auto'; outputs every round(interval / dt) steps otherwise; a column's time axis
    (16 B), energies (16 B) and strain (8 B a prism, when kept) per output."""
    run = data["run"]
    t_end, dt = run["t_end"], run.get("dt", "auto")
    interval = run.get("output_interval", t_end / 200)
    steps = t_end / (interval if dt == "auto" else dt)
    outputs = t_end / (interval if dt == "auto" else 2 * max(interval, dt))  # round(): at most 2x fewer
    per_output = 32 + (8 * data["scene"]["n_prisms"] if run.get("record_strain", True) else 0)
    return steps, outputs * per_output


def _host_total() -> int:
    return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")


@fuzz("run sizes")
@given(data=run_sizes())
@example(data={**BASE, "scene": {"n_prisms": 8}, "run": {"t_end": 2.0, "output_interval": 1e-9}})  # issue 30 item 1
@example(data={**BASE, "scene": {"n_prisms": 8}, "run": {"t_end": 1e3, "output_interval": 1e-9}})
@example(data={**BASE, "scene": {"n_prisms": 8}, "run": {"t_end": 1e9, "output_interval": 1.0}})
@example(data={**BASE, "scene": {"n_prisms": 400}, "run": {"t_end": 100.0, "output_interval": 1e-7}})
@example(data={**BASE, "run": {"t_end": 1e9, "output_interval": 1e-15}})  # the extremes of [run]
@example(data={**BASE, "run": {"t_end": 1e-6, "dt": 1e-15, "allow_unstable_dt": True}})
def _run_sizes(work, data):
    """Every [run] size against the budget: a spec is refused up front with its figure and a remedy
    when a column's records cannot fit this machine or its steps the step counter (by the oracle),
    or planned and priced (dry run) with at most PLAN_PEAK_BYTES allocated; never a MemoryError, a
    traceback or a plan that admits more than the machine holds."""
    import tracemalloc

    steps, column = size_oracle(data) if not physics_problems(data) else (0.0, 0.0)
    traced = column > 1e8  # where an O(n_out) array would show (tracemalloc triples a dry run's time)
    if traced:
        tracemalloc.start()
    try:
        with address_space_cap():
            rc, out, err = dry_run_spec(work, tomli_w.dumps(data).encode())
        peak = tracemalloc.get_traced_memory()[1] if traced else 0
    finally:
        tracemalloc.stop()
    assert "Traceback" not in err and "MemoryError" not in err, err
    assert peak < PLAN_PEAK_BYTES, (data, peak)
    bad = physics_problems(data)
    if bad:
        check_clear_error(rc, out, err, bad[0])
        _count("run sizes", "clear error (spec)")
        return
    if steps > 1.01 * MAX_STEPS or column > 1.01 * _host_total():
        check_clear_error(rc, out, err)
        assert "the run cannot be done" in err and "lower run.t_end" in err, (data, err)
        assert "step counter" in err or re.search(r"outputs per column .* need about [\d.]+ [kMGTP]B", err), err
        _count("run sizes", "refused up front (cannot be done)")
    elif rc != 0:  # by the plan's own figures, which count more than the oracle (the engine's arrays)
        check_clear_error(rc, out, err)
        assert "cannot be done" in err, (data, err)
        _count("run sizes", "refused up front (by the plan's figures)")
    else:
        m = re.search(r"steps: +(\d+) to t_end = \S+ s, (\d+) outputs", out)
        assert m and "fits:" in out, out
        n_steps, n_out = int(m.group(1)), int(m.group(2))
        per_output = 32 + (8 * data["scene"]["n_prisms"] if data["run"].get("record_strain", True) else 0)
        assert n_steps <= MAX_STEPS and n_out * per_output <= _host_total(), (data, out)  # a bounded plan
        _count("run sizes", "planned (dry run)" + ("" if "fits:        yes" in out else ", refused by the estimate"))


def test_fuzz_run_sizes(work):
    COUNTS.pop("run sizes", None)
    _run_sizes(work)
    _report("run sizes", int(0.9 * QUOTAS["run sizes"]))


@st.composite
def small_runs(draw):
    """Settings of a cheap real run (a few prisms and columns, tens of steps), any combination of
    what it keeps and measures; now and then sizes the budget refuses."""
    t_end = draw(_e(-4, -1.3))
    kw = {"t_end": t_end, "device": "cpu"}
    if draw(st.integers(0, 3)):
        kw["output_interval"] = float(f"{t_end * draw(_e(-2.5, 0)):.3g}")
    for k in ("record_strain", "record_energy", "truncate"):
        if draw(st.booleans()):
            kw[k] = draw(st.booleans())
    if draw(st.booleans()):
        kw["measure"] = draw(st.sampled_from(["device", "host", "none"]))
    if not draw(st.integers(0, 7)):  # beyond the budget: refused before anything is built
        kw.update(t_end=draw(st.sampled_from([2.0, 1e3, 1e9])), output_interval=draw(st.sampled_from([1e-9, 1e-12])))
    n = draw(st.integers(1, 6))
    cols = draw(st.integers(1, 3))
    params = {"prestrain": [draw(st.sampled_from([0.0, 0.001, 0.002])) for _ in range(cols)],
              "v0": draw(st.sampled_from([0.001, 0.005, 0.02]))}
    return n, params, kw


@fuzz("api to_xarray")
@given(case=small_runs())
@example(case=(3, {"prestrain": [0.0, 0.001], "v0": 0.01}, {"t_end": 0.01, "output_interval": 0.002, "device": "cpu",
                                                            "record_strain": False}))  # issue 30 item 17
def _api_to_xarray(case):
    """simulate_batch with any combination of the settings, then .to_xarray(): a dataset with one
    case per column and one time per output (the strain when kept), or, for sizes beyond the
    budget, a SettingsError naming t_end and output_interval before anything is built."""
    import warp_tensegrity as W
    from warp_tensegrity.options import SettingsError

    n, params, kw = case
    settings = RunSettings(**kw)
    try:
        with address_space_cap():
            r = W.simulate_batch(ColumnConfig(n_prisms=n), params, settings)
    except SettingsError as e:
        assert "the run cannot be done" in str(e) and "run.t_end" in str(e) and "run.output_interval" in str(e), e
        assert kw["t_end"] >= 2.0, (kw, str(e))  # only the sizes drawn beyond the budget
        _count("api to_xarray", "refused up front")
        return
    ds = r.to_xarray()
    B, T = len(params["prestrain"]), len(r.time)
    assert ds.sizes["case"] == B and ds.sizes["t"] == T, (kw, dict(ds.sizes))
    assert ("strain" in ds) == settings.record_strain, (kw, list(ds))
    if settings.record_strain:
        assert ds["strain"].shape == (B, T, n), (kw, ds["strain"].shape)
    _count("api to_xarray", "dataset")


def test_fuzz_api_settings_to_xarray():
    COUNTS.pop("api to_xarray", None)
    _api_to_xarray()
    _report("api to_xarray", int(0.9 * QUOTAS["api to_xarray"]))


# ---------------------------------------------------------------------- subprocess checks and tiny real runs
def _python_m(args, cwd, timeout=120):
    env = dict(os.environ, PYTHONPATH=str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    return subprocess.run([sys.executable, "-m", "warp_tensegrity", *map(str, args)], capture_output=True, text=True,
                          env=env, cwd=cwd, timeout=timeout)


@pytest.mark.slow  # a dozen fresh interpreters, each importing Warp (~4 s)
def test_subprocess_clear_errors_and_refusals(tmp_path):
    """As a user sees it: one clear message, exit 1, no traceback; a run that would not finish
    (or does not fit) is refused up front by the estimate with its figures, never started."""
    bad = tmp_path / "bad.toml"
    bad.write_bytes(VALID_TEXT.replace(b"fuzz base", b"fuzz \xff base"))
    r = _python_m(["run", bad, "-o", tmp_path / "o.nc", "--device", "cpu"], tmp_path)
    assert r.returncode == 1 and "not UTF-8" in r.stderr and "Traceback" not in r.stderr, r.stderr

    slow = _with("run", "dt", 1e-9)
    slow["run"]["allow_unstable_dt"] = True
    (tmp_path / "slow.toml").write_text(tomli_w.dumps(slow))
    r = _python_m(["run", tmp_path / "slow.toml", "-o", tmp_path / "slow.nc", "--device", "cpu", "--time-limit", "60"],
                  tmp_path, timeout=120)
    assert r.returncode == 1 and "Traceback" not in r.stderr, r.stderr
    assert "does not fit" in r.stderr and "time limit is 1m00s" in r.stderr and "20,000,000 steps" in r.stderr, r.stderr
    assert not (tmp_path / "slow.nc").exists()

    never = _with("run", "dt", 1e-12)
    never["run"]["allow_unstable_dt"] = True
    (tmp_path / "never.toml").write_text(tomli_w.dumps(never))
    r = _python_m(["run", tmp_path / "never.toml", "-o", tmp_path / "n.nc", "--device", "cpu", "--ignore-estimate"],
                  tmp_path)
    assert r.returncode == 1 and "2e+10 steps" in r.stderr and "step counter" in r.stderr, r.stderr

    huge = json.loads(json.dumps(BASE))
    huge["sweep"]["grid"] = {"v0": {"start": 0.001, "stop": 0.1, "num": 10**6},
                             "base_rigidity": {"start": 0.0, "stop": 1.0, "num": 10**6}}
    (tmp_path / "huge.toml").write_text(tomli_w.dumps(huge))
    r = _python_m(["run", tmp_path / "huge.toml", "-o", tmp_path / "h.nc", "--device", "cpu", "--dry-run"], tmp_path)
    assert r.returncode == 1 and "1,000,000,000,000 columns" in r.stderr and "host memory" in r.stderr, r.stderr


@pytest.mark.parametrize("overrides", [[], ["--set", "run.method=rk4", "--set", "run.precision=fp32"]])
def test_tiny_real_runs(tmp_path, overrides):
    """The other end of the oracle: a valid spec really runs (in process) and its dataset holds
    every column, ok."""
    import xarray as xr

    spec = tmp_path / "ok.toml"
    spec.write_bytes(VALID_TEXT)
    out = tmp_path / "ok.nc"
    rc, o, err = run_cli(["run", spec, "-o", out, "--device", "cpu", "--no-progress", *overrides])
    assert rc == 0, err
    with xr.open_dataset(out) as ds:
        assert ds.sizes["v0"] == 2 and (ds.status.values == 0).all()
        assert ds.attrs["method"] == ("rk4" if overrides else "rattle")


def test_budget_names_every_shortfall_with_figures(tmp_path):
    from warp_tensegrity.sweep import budget, plan_sweep
    from warp_tensegrity.sweep.spec import parse_spec

    from warp_tensegrity.policy.calibrate import estimate_plan

    plan = plan_sweep(parse_spec(tomli_w.dumps(BASE)), tmp_path / "o.nc", device="cpu")
    need = estimate_plan(plan)
    assert budget.problems(plan, need) == [] and budget.hard_problems(plan) == []
    found = budget.problems(plan, need, device_bytes=need["device_bytes_per_column"] - 1, host_bytes=need["host_bytes_per_shard"] - 1,
                            disk_bytes=need["output_bytes"] - 1, time_limit=need["seconds"] / 2)
    assert len(found) == 4, found
    assert "one column does not fit" in found[0] and "use --shard-size 1 or less" in found[1]
    assert "free on" in found[2] and "time limit" in found[3]
    with pytest.raises(budget.BudgetError, match="--ignore-estimate"):
        budget.check_run(plan, need, time_limit=need["seconds"] / 2)
    budget.check_run(plan, None, ignore=True, time_limit=need["seconds"] / 2)  # the override
    with pytest.raises(budget.BudgetError, match=r"planning it needs about .* of host memory and 1 kB is available"):
        budget.check_plan(plan.spec, available=1000)


# ---------------------------------------------------------------------- 6. issue 23: readers, long columns, argument types
# Our own seeded generator (no Hypothesis): every input below is one of a few kinds that ended in a
# traceback or a hang before issue 23; each must end in a valid result or a clear error of the
# project's own class, in a few seconds for the whole class (FUZZ_EXPLORE=N draws N x as many, at random).
import random  # noqa: E402
import time as _time  # noqa: E402

SEED = int(os.environ.get("FUZZ_SEED", "23")) if not EXPLORE else random.SystemRandom().randrange(2**32)


def _nasty_value(rng: random.Random) -> tuple[str, bool]:
    """(TOML value text, True if TOML can hold it): deep arrays / inline tables (to 5,000 levels),
    integers of up to 6,000 digits, and ordinary values."""
    kind = rng.choice(["array", "table", "mixed", "int", "int", "float", "string"])
    depth = rng.choice([1, 2, 15, 16, 17, 100, 450, 500, 1000, 3000, 5000])
    if kind == "array":
        return "[" * depth + "1" + "]" * depth, depth < 16
    if kind == "table":
        return "{a = " * depth + "1" + "}" * depth, depth < 16
    if kind == "mixed":
        return "[{a = " * (depth // 2) + "1" + "}]" * (depth // 2), 2 * (depth // 2) < 16
    if kind == "int":
        digits = rng.choice([1, 20, 400, 4300, 4301, 6000])
        return rng.choice(["", "-"]) + "9" * digits, digits <= 4300
    if kind == "float":
        return rng.choice(["1e99999", "-0.0", "nan", "inf", "1e-320", "0.1"]), True
    return rng.choice(['"x"', "'caf\u00e9'", '"\\u00ff"', '""']), True


def _inputs(rng, n):
    for _ in range(n * max(1, EXPLORE)):
        yield _nasty_value(rng)


def test_fuzz_every_toml_reader_answers_cleanly(tmp_path):
    """Sweep specs, lens specs and --set values through the one reader (tomlread): nested TOML
    (RecursionError before), integers > 4,300 digits (ValueError before), Latin-1 bytes in a lens
    spec (UnicodeDecodeError before). The generated key is never a valid option, so every input
    must be refused, with the project's error naming the file or the option."""
    from warp_tensegrity.lens.spec import LensSpecError, load_lens_spec
    from warp_tensegrity.options import OptionError
    from warp_tensegrity.overrides import parse_set
    from warp_tensegrity.sweep.spec import load_spec

    rng = random.Random(SEED)
    lens_text = (REPO / "sweeps" / "lens_ci.toml").read_bytes()
    counts, t0 = Counter(), _time.perf_counter()
    for value, holdable in _inputs(rng, 60):
        doc = f"fuzz_key = {value}\n".encode()
        sweep_file, lens_file = tmp_path / "s.toml", tmp_path / "l.toml"
        sweep_file.write_bytes(doc + VALID_TEXT)
        lens_file.write_bytes(doc + lens_text)
        with pytest.raises(OptionError) as e:  # SpecError
            load_spec(sweep_file)
        assert "s.toml" in str(e.value) and ("fuzz_key" in str(e.value) or not holdable), str(e.value)[:300]
        with pytest.raises(LensSpecError) as e:
            load_lens_spec(lens_file)
        assert "l.toml" in str(e.value), str(e.value)[:300]
        with pytest.raises(OptionError) as e:  # an override is held to the file's rules (no value is a method)
            load_spec(VALID_TEXT.decode(), overrides=parse_set([f"run.method={value}"]))
        assert "method" in str(e.value), str(e.value)[:300]
        counts["refused" if holdable else "refused by the reader"] += 1
    for blob in (b"\xe9", b"\xff\xfe", b"caf\xe9 = 1", bytes(range(128, 256))):  # Latin-1 and binary
        (tmp_path / "l.toml").write_bytes(lens_text.replace(b"title", blob + b"\ntitle", 1))
        with pytest.raises(LensSpecError, match="not UTF-8"):
            load_lens_spec(tmp_path / "l.toml")
        counts["not UTF-8"] += 1
    print(f"\nfuzz toml readers: {dict(counts)} in {_time.perf_counter() - t0:.2f} s")
    assert sum(counts.values()) >= 64


PUBLIC_CALLS = {  # each public function: valid arguments, and the names of those the generator spoils
    "simulate_batch": (["config", "params", "settings"], {"progress": None, "prisms_simulated": 1}),
    "run_batch": (["batch", "settings"], {"progress": None, "pulse": None}),
    "estimate_batch": (["config", "params", "settings"], {}),
    "decide": (["config", "params", "settings"], {"prisms_simulated": 1}),
    "column_batch": (["config", "params"], {}),
    "build_column": (["config", "prestrain", "v0", "base_rigidity"], {}),
    "column_topology": (["config"], {}),
    "network_batch": (["networks"], {}),
    "measure_pulse": (["strain", "time", "prism_height"], {}),
    "ColumnConfig": ([], {"n_prisms": 2}),
    "RunSettings": ([], {"t_end": 0.01}),
}


def _valid_arguments(name):
    import warp_tensegrity as W

    cfg = W.ColumnConfig(n_prisms=2)
    rs = W.RunSettings(t_end=0.002, output_interval=0.001, device="cpu")
    params = {"prestrain": [0.0], "v0": [0.01]}
    return {"config": cfg, "params": params, "settings": rs, "batch": W.column_batch(cfg, params),
            "prestrain": 0.0, "v0": 0.01, "base_rigidity": 0.0, "networks": [W.build_column(cfg).network],
            "strain": np.zeros((1, 4, 2)), "time": np.arange(4.0), "prism_height": 0.006}


def _wrong(rng: random.Random):
    """A value of the wrong type (or NaN, or a masked array with a masked entry) for any parameter."""
    return rng.choice([None, "x", object(), {}, [], (1, 2), float("nan"), 1j, b"\xff", [[1.0], [2.0, 3.0]],
                       np.ma.masked_array([0.0, 0.001], mask=[0, 1])])


def test_fuzz_wrong_argument_types_for_every_public_function():
    """Every public function (warp_tensegrity.__all__) with one argument spoiled: an error that is
    a TypeError or ValueError and names the parameter (before issue 23: AttributeError 'truncate'
    for settings=None, 'n_prisms' for config=None, ...), never another exception, never a run."""
    import warp_tensegrity as W

    public = {n for n in W.__all__ if callable(getattr(W, n, None))}
    containers = {"BatchResult", "ColumnScene", "Network", "NetworkBatch", "Method", "Status", "NetworkError",
                  "SettingsError", "RunPlan", "Profile"}  # data classes, enums and exception classes: nothing to check
    assert public - containers == set(PUBLIC_CALLS), public - containers - set(PUBLIC_CALLS)
    valid = _valid_arguments
    rng = random.Random(SEED)
    args = valid(None)
    counts = Counter()
    for _ in range(8 * max(1, EXPLORE)):
        for fname, (names, extra) in PUBLIC_CALLS.items():
            f = getattr(W, fname)
            spoil = names + list(extra)
            k = rng.choice(spoil)
            kw = {n: args[n] for n in names} | dict(extra)
            bad = _wrong(rng)
            if fname in ("ColumnConfig", "RunSettings"):
                kw = {k: bad}
            elif k == "params" and rng.random() < 0.5:
                bad = {"v0": bad}  # a bad value inside the parameters
            kw[k] = bad
            if fname == "build_column" and k == "config" and bad is None:
                continue  # None: the default scene (valid)
            try:
                f(**kw)
            except (TypeError, ValueError) as e:  # ArgumentError, OptionError, NetworkError are both or one
                assert k in str(e) or (k == "params" and "v0" in str(e)), (fname, k, bad, str(e)[:300])
                counts["clear error"] += 1
                continue
            pytest.fail(f"{fname}({k}={bad!r:.60}) was accepted")
    kw = {n: args[n] for n in PUBLIC_CALLS["simulate_batch"][0]}
    for n_sim in (float("nan"), 10**9, 0, -1, 2.5, "2", True):  # the NaN and huge prisms_simulated
        with pytest.raises(ValueError, match="prisms_simulated"):
            W.simulate_batch(**kw, prisms_simulated=n_sim)
        counts["clear error"] += 1
    print(f"\nfuzz public functions: {dict(counts)}")


@pytest.mark.parametrize("mode", ["rigid_members", "end_twist", "project"])
def test_fuzz_long_columns_plan_or_refuse(mode, tmp_path):
    """A legal long column (up to n_prisms = 100,000, the allowed maximum) is planned, in linear
    time, or refused up front with its figure, in every impact mode; beyond the maximum it is
    refused when the spec is read (before issue 23: 30 s at 1,000 prisms, > 1 min at 3,000, 1.96 TiB
    at 100,000). CI plans 5,000 prisms and bounds 100,000 by the estimate; FUZZ_EXPLORE plans 100,000."""
    from warp_tensegrity.sweep import budget
    from warp_tensegrity.sweep import plan as sweep_plan
    from warp_tensegrity.sweep.spec import load_spec

    rng = random.Random(SEED)
    for n in (100_001, 10**6, rng.choice([10**9, 2**63])):
        with pytest.raises(OptionError, match="n_prisms"):
            load_spec(VALID_TEXT.decode(), overrides={"scene": {"n_prisms": n, "impact_admissibility": mode}})
    big = load_spec(VALID_TEXT.decode(), overrides={"scene": {"n_prisms": 100_000, "impact_admissibility": mode}})
    budget.check_plan(big)  # two columns of 100,000 prisms: within the planning limit, with its figure
    assert budget.plan_seconds(big.n_columns, 100_000, mode) < budget.PLAN_TIME_LIMIT
    huge = load_spec(VALID_TEXT.decode(), overrides={"scene": {"n_prisms": 100_000, "impact_admissibility": mode},
                                                      "sweep": {"grid": {"v0": {"start": 0.001, "stop": 0.1,
                                                                                "num": 20_000}}}})
    with pytest.raises(budget.BudgetError, match=r"planning builds every column .* about .* \(limit 10m00s\)"):
        budget.check_plan(huge, available=10**15)  # (here its memory is refused first)
    n = 100_000 if EXPLORE else 5_000
    spec = load_spec(VALID_TEXT.decode(), overrides={"scene": {"n_prisms": n, "impact_admissibility": mode}})
    t0 = _time.perf_counter()
    plan = sweep_plan.plan_sweep(spec, tmp_path / "long.nc", device="cpu")
    seconds = _time.perf_counter() - t0
    assert plan.n_columns == 2 and seconds < 5.0 + budget.plan_seconds(2, n, mode), seconds
    print(f"\nplanned {n:,} prisms ({mode}) in {seconds:.2f} s")
