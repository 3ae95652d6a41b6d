"""The user docs build with MkDocs + mkdocstrings, warnings as errors, and the generated options
table names every key the spec parser accepts."""

from __future__ import annotations

import html
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("mkdocs")
pytest.importorskip("mkdocstrings")

ROOT = Path(__file__).resolve().parent.parent


def build(config: Path, site: Path) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")])))
    return subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "-f", str(config), "-d", str(site)],
                          cwd=config.parent, env=env, capture_output=True, text=True, timeout=300)


def spec_keys() -> list[str]:
    """Every key path a spec may hold, from the parser's own tables."""
    from warp_tensegrity.sweep import parse as P
    from warp_tensegrity.sweep import spec as S
    from warp_tensegrity.options import COLUMN_PARAMETERS

    keys = list(S.TOP_KEYS)
    keys += [f"scene.{k}" for k in P.SCENE_FIELDS + P.SCENE_PARAMS]
    keys += [f"sweep.{k}" for k in P.SWEEP_KEYS]
    keys += [f"sweep.{t}.{p}" for p in COLUMN_PARAMETERS for t in ("grid", "fixed")]
    keys += [f"sweep.cases[i].{p}" for p in tuple(COLUMN_PARAMETERS) + P.CASE_EXTRA_KEYS]
    keys += [f"sweep.grid.<param>.{k}" for k in P.RANGE_KEYS]
    keys += [f"run.{k}" for k in P.RUN_KEYS]
    return keys


def test_docs_build_strict_and_cover_every_spec_key(tmp_path):
    r = build(ROOT / "mkdocs.yml", tmp_path / "site")
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    page = html.unescape(re.sub(r"<[^>]+>", "", (tmp_path / "site" / "options" / "index.html").read_text()))
    missing = [k for k in spec_keys() if k not in page]
    assert not missing, f"keys missing from the options table: {missing}"
    api = (tmp_path / "site" / "api" / "index.html").read_text()
    for name in ("run_sweep", "to_xarray", "phase_diagram", "work_precision", "measure_pulse", "simulate_batch"):
        assert name in api, name
    for page, words in (("measurements", ("Amplitude", "Speed", "Width")),
                        ("conventions", ("end_twist", "project", "base_rigidity", "end_base_mass"))):
        text = (tmp_path / "site" / page / "index.html").read_text()
        assert all(w in text for w in words), page


def test_docs_build_fails_on_a_warning(tmp_path):
    """The strict build can fail: a broken link in a copy of the docs is an error (note: with -q,
    mkdocs 1.6 does not count warnings, so the build never runs quiet)."""
    shutil.copytree(ROOT / "docs", tmp_path / "docs")
    shutil.copy(ROOT / "mkdocs.yml", tmp_path / "mkdocs.yml")
    with open(tmp_path / "docs" / "index.md", "a") as f:
        f.write("\nSee [nowhere](no_such_page.md).\n")
    r = build(tmp_path / "mkdocs.yml", tmp_path / "site")
    assert r.returncode != 0 and "no_such_page.md" in r.stdout + r.stderr
