"""Shared fixtures: Warp on the CPU device (as in CI), quiet, one kernel cache per run."""

import os
from pathlib import Path

# One BLAS thread per process: xdist already runs a worker per core, and OpenBLAS's own threads on
# top of that oversubscribe the cores and spin (the small dense solves of the fp64 references went
# from 0.04 s alone to 8-20 s in a loaded 2-core run). Set here, before any worker imports NumPy:
# the xdist workers and the CLI subprocesses inherit it. An explicit setting wins.
# The committed reference outputs were made under one OpenBLAS kernel set and thread count, which
# tests/test_reference_outputs.py pins again for its own subprocess: WT_TEST_BLAS_CAPPED names what
# was set here, for it to undo.
_capped = [v for v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS") if v not in os.environ]
for _var in _capped:
    os.environ[_var] = "1"
if _capped:
    os.environ["WT_TEST_BLAS_CAPPED"] = ",".join(_capped)

import pytest  # noqa: E402

from warp_tensegrity.runtime import init_warp  # noqa: E402


def pytest_addoption(parser):
    parser.addoption("--device", default="cpu", help="Warp device for engine tests (default: cpu)")


@pytest.fixture(scope="session")
def device(request):
    return request.config.getoption("--device")


@pytest.fixture(scope="session", autouse=True)
def _warp_init():
    init_warp()  # quiet: no CUDA-driver warning on a CPU-only machine
    yield


def _shared_cli_run(tmp_path_factory, name: str) -> Path:
    """``warp-tensegrity run sweeps/<name>.toml`` on the CPU, once per test session: the first xdist
    worker to need it runs it under a lock in the session's shared temporary directory, the others
    wait and read it (pytest-xdist's recipe for session data; fcntl from the standard library
    instead of the filelock package). With ``WT_TEST_SHARE`` (set by .ci/test) it goes there, and
    .ci/notebooks gives the paper's to the paper notebook. Tests read the file; none may write it."""
    import fcntl

    from warp_tensegrity.cli import main as cli_main

    root = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        root = root.parent  # shared by the workers of this session
    if os.environ.get("WT_TEST_SHARE"):  # .ci/test: the notebook step reads it too
        root = Path(os.environ["WT_TEST_SHARE"])
    out = root / name / f"{name}.nc"
    out.parent.mkdir(parents=True, exist_ok=True)
    spec = Path(__file__).resolve().parents[1] / "sweeps" / f"{name}.toml"
    with open(out.parent / "lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not out.exists():
            assert cli_main(["run", str(spec), "-o", str(out), "--device", "cpu", "--no-progress"]) == 0
    return out


@pytest.fixture(scope="session")
def paper_2017_nc(tmp_path_factory):
    """The README's main job on the CPU (``warp-tensegrity run sweeps/paper_2017.toml``), run once per
    test session and shared by the xdist workers (:func:`_shared_cli_run`). Its tests are marked
    ``slow``: the run is the longest single setup of the suite."""
    return _shared_cli_run(tmp_path_factory, "paper_2017")


@pytest.fixture(scope="session")
def ci_small_nc(tmp_path_factory):
    """``warp-tensegrity run sweeps/ci_small.toml`` on the CPU, once per test session and shared by
    the xdist workers (:func:`_shared_cli_run`): the CLI's output of a small grid sweep, read by the
    base-mode, NaN-flag and time-coordinate tests."""
    return _shared_cli_run(tmp_path_factory, "ci_small")


def pytest_collection_modifyitems(config, items):
    """The ``notebook`` tests check what .ci/notebooks made: deselected unless that step runs them
    (it sets WT_NOTEBOOK_OUT) or ``-m`` names the marker. pyproject's ``-m 'not notebook'`` does the
    same, but any other ``-m`` (``pytest -m "not slow"``, the developer loop) replaces it."""
    if os.environ.get("WT_NOTEBOOK_OUT") or "notebook" in (config.getoption("markexpr") or ""):
        return
    keep = [i for i in items if i.get_closest_marker("notebook") is None]
    if len(keep) < len(items):
        config.hook.pytest_deselected(items=[i for i in items if i.get_closest_marker("notebook") is not None])
        items[:] = keep
