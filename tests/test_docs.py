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


def _section(text: str, heading_start: str) -> str:
    """The text of the markdown section whose heading starts with ``heading_start``."""
    start = text.index("\n" + heading_start)
    end = text.find("\n## ", start + 1)
    return text[start:end if end > 0 else None]


def test_conventions_mark_the_options_defaults():
    """Issue 30 item 19: docs/conventions.md called `end_twist` the default impact after the default
    became `rigid_members`. Each choice the page lists is marked "(default)" exactly where the
    options model's default is."""
    from warp_tensegrity.scene.columns import ColumnConfig

    text = (ROOT / "docs" / "conventions.md").read_text()
    for field, heading in (("impact_admissibility", "## Impact"), ("end_base_mass", "## End masses")):
        marked = re.findall(r'`"(\w+)"` \(default\)', _section(text, heading))
        assert marked == [getattr(ColumnConfig(), field)], (field, marked)


def test_no_shard_files_left_in_the_docs():
    """Issue 30 item 19: a run's shards have been blocks of one Zarr store since issue 27, yet the
    docs, io's docstring (docs/architecture.md's module table) and the shard_size help said "one
    file per shard"."""
    texts = {p: p.read_text() for p in [*(ROOT / "docs").glob("*.md"), ROOT / "README.md",
                                         *(ROOT / "warp_tensegrity").rglob("*.py")]}
    stale = [str(p.relative_to(ROOT)) for p, t in texts.items()
             if re.search(r"file per shard|shard files?\b", t, re.IGNORECASE)]
    assert stale == [], stale


def python_blocks(page: Path, heading: str) -> list[str]:
    """The ```python blocks of the section of ``page`` whose heading starts with ``heading``."""
    return re.findall(r"```python\n(.*?)```", _section(page.read_text(), heading), re.DOTALL)


@pytest.mark.slow
def test_python_docs_sweep_example_runs_as_a_script(tmp_path):
    """Issue 30 item 19: docs/python.md's sweep example, run as a script, failed at its Dask line
    ("Nanny failed to start": the spawned workers import the script again) for want of an
    `if __name__ == "__main__":` guard. Run verbatim as a script in a directory with `sweeps/`;
    the Dask run's dataset is the single-process one."""
    import xarray as xr

    from warp_tensegrity.io import drop_run_dependent

    (block,) = python_blocks(ROOT / "docs" / "python.md", "## Sweeps")
    (tmp_path / "example.py").write_text(block)
    (tmp_path / "sweeps").symlink_to(ROOT / "sweeps")
    r = subprocess.run([sys.executable, "example.py"], cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-3000:]
    with xr.open_dataset(tmp_path / "ci_small.nc") as one, xr.open_dataset(tmp_path / "big.nc") as dask:
        xr.testing.assert_identical(drop_run_dependent(dask.load()), drop_run_dependent(one.load()))


@pytest.mark.slow
def test_readme_python_example_runs(tmp_path):
    """Issue 30 item 19: the README's Python example ran 4096 columns, about 70 minutes on a 2-core
    CPU with nothing shown. It now runs 8 with a progress callback (README: ~10 s of CPU time);
    run verbatim here, with its progress lines on stdout."""
    (block,) = re.findall(r"```python\n(.*?)```", _section((ROOT / "README.md").read_text(), "## Using it from Python"),
                          re.DOTALL)
    (tmp_path / "example.py").write_text(block + "\nassert r.strain.shape[0] == B and (r.status == 0).all()\n")
    r = subprocess.run([sys.executable, "example.py"], cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-3000:]
    assert re.search(r"step (\d+) of \1, 0 columns failed", r.stdout), r.stdout[-500:]


def test_readme_outputs_in_the_checkout_are_git_ignored(tmp_path):
    """Issue 30 item 19: the README's main job (`run sweeps/paper_2017.toml -o paper_2017.nc`, in the
    checkout root) left paper_2017.nc untracked and not ignored. Every output the README's and the
    specs' commands write there (the file, its store, the lock, a default figure) is ignored."""
    if not (ROOT / ".git").exists() or shutil.which("git") is None:
        pytest.skip("not a git checkout")
    texts = [(ROOT / "README.md").read_text(), *(p.read_text() for p in (ROOT / "sweeps").glob("*.toml"))]
    outs = sorted({m for t in texts for m in re.findall(r"-o ([\w.-]+\.nc)\b", t)})
    assert "paper_2017.nc" in outs and "ci_small.nc" in outs, outs
    paths = [q for o in outs for q in (o, f"{o}.sweep/store.zarr/zarr.json", f".{o}.lock", f"{o[:-3]}-phase.png")]
    r = subprocess.run(["git", "check-ignore", "--no-index", "--verbose", "--non-matching", *paths],
                       cwd=ROOT, capture_output=True, text=True)
    not_ignored = [line.split("\t")[-1] for line in r.stdout.splitlines() if line.startswith("::")]
    assert not_ignored == [], not_ignored
