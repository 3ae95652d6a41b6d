"""Packaging and built-in provenance, as a user installs it.

From a fresh clone of this checkout's HEAD (as CI starts): ``python -m build`` makes an sdist
and a wheel, ``twine check`` passes, the wheel installs non-editably into a fresh virtual
environment (its dependencies come from this one through a .pth file, so nothing is downloaded),
and from outside the repository, with no git to ask, the installed command prints the
commit with ``--version`` and records it in the netCDF of ``sweeps/ci_small.toml``.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow  # a clone, a wheel and sdist build and a fresh virtual environment (~30 s)

ROOT = Path(__file__).resolve().parent.parent
HEX40 = re.compile(r"[0-9a-f]{40}")


def _git(*args, cwd=ROOT) -> str:
    return subprocess.run(["git", *args], cwd=cwd, capture_output=True, text=True, check=True).stdout.strip()


@pytest.fixture(scope="module")
def clone(tmp_path_factory):
    if shutil.which("git") is None or not (ROOT / ".git").exists():
        pytest.skip("needs git and a git checkout")
    d = tmp_path_factory.mktemp("pkg") / "clone"
    subprocess.run(["git", "clone", "--quiet", str(ROOT), str(d)], check=True)
    return d


@pytest.fixture(scope="module")
def dist(clone):
    pytest.importorskip("build")
    out = clone.parent / "dist"
    r = subprocess.run([sys.executable, "-m", "build", "--no-isolation", "--outdir", str(out), str(clone)],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    return out


def test_wheel_and_sdist_pass_twine_check(dist):
    pytest.importorskip("twine")
    files = sorted(dist.iterdir())
    assert [p.suffix for p in files] == [".whl", ".gz"], files
    r = subprocess.run([sys.executable, "-m", "twine", "check", "--strict", *map(str, files)],
                       capture_output=True, text=True)
    assert r.returncode == 0 and r.stdout.count("PASSED") == 2, r.stdout + r.stderr


def test_wheel_holds_the_runtime_not_the_test_references(dist):
    """The validation gallery's references ship (``warp-tensegrity validate`` needs them); the tests'
    fp64 simulator (``tests/references/reference.py``) and the old ``checks/`` package do not."""
    import zipfile

    names = zipfile.ZipFile(next(dist.glob("*.whl"))).namelist()
    pkg = [n for n in names if n.startswith("warp_tensegrity/")]
    assert not [n for n in pkg if n.startswith("warp_tensegrity/checks/")], pkg
    assert not [n for n in names if n.endswith("/reference.py") or n.startswith(("tests/", "benchmarks/"))], names
    for m in ("closed_forms", "constrained", "dispersion", "linear", "checks"):
        assert f"warp_tensegrity/validation/{m}.py" in pkg


def test_non_editable_install_records_the_commit(clone, dist, tmp_path):
    head = _git("rev-parse", "HEAD", cwd=clone)
    env_dir = tmp_path / "env"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(env_dir)], check=True)
    py = env_dir / "bin" / "python"
    site = Path(subprocess.run([str(py), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                               capture_output=True, text=True, check=True).stdout.strip())
    wheel = next(dist.glob("*.whl"))
    r = subprocess.run([sys.executable, "-m", "pip", "--python", str(py), "install", "--quiet", "--no-deps",
                        "--no-index", str(wheel)], capture_output=True, text=True)
    assert r.returncode == 0, r.stdout + r.stderr
    # then the dependencies from this environment, after the new one's own site-packages (the wheel
    # wins; written after the install, else pip sees CI's own install of the package and skips)
    (site / "_deps.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")

    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "GIT_COMMIT")}
    env["PATH"] = "/nonexistent"  # no git at run time: the commit must come from the build
    run = dict(cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
    exe = str(env_dir / "bin" / "warp-tensegrity")

    where = subprocess.run([str(py), "-c", "import warp_tensegrity; print(warp_tensegrity.__file__)"], **run)
    assert where.stdout.strip().startswith(str(site)), where.stdout + where.stderr  # the installed copy

    v = subprocess.run([exe, "--version"], **run)
    assert v.returncode == 0, v.stderr
    assert f"commit {head}\n" in v.stdout and "Warp 1.19" in v.stdout and "default device cpu" in v.stdout, v.stdout
    assert "CUDA warning" not in v.stderr and len(v.stderr.strip().splitlines()) <= 1, v.stderr

    out = tmp_path / "ci_small.nc"
    r = subprocess.run([exe, "-q", "run", str(ROOT / "sweeps" / "ci_small.toml"), "-o", str(out), "--device", "cpu"],
                       **run)
    assert r.returncode == 0 and r.stderr == "", r.stderr  # -q: nothing on stderr, no CUDA warning
    import xarray as xr

    with xr.open_dataset(out) as ds:
        a = dict(ds.attrs)
    assert HEX40.fullmatch(a["git_commit"]) and a["git_commit"] == head
    assert a["git_dirty"] == 0 and a["package_version"] in v.stdout
    assert a["warp_version"].startswith("1.19") and a["device"] == "cpu" and a["cuda_driver"] == "none"
    assert "run" in a["command_line"] and "ci_small.toml" in a["command_line"]
