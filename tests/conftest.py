"""Shared fixtures: Warp on the CPU device (as in CI), quiet, one kernel cache per run."""

import os

import pytest

from warp_tensegrity.runtime import init_warp


def pytest_addoption(parser):
    parser.addoption("--device", default="cpu", help="Warp device for engine tests (default: cpu)")


@pytest.fixture(scope="session")
def device(request):
    return request.config.getoption("--device")


@pytest.fixture(scope="session", autouse=True)
def _warp_init():
    init_warp()  # quiet: no CUDA-driver warning on a CPU-only machine
    yield


@pytest.fixture(scope="session")
def paper_2017_nc(tmp_path_factory):
    """The README's main job on the CPU (``warp-tensegrity run sweeps/paper_2017.toml``), run once per
    test session: the first xdist worker to need it runs it under a lock in the session's shared
    temporary directory, the others wait and read it (pytest-xdist's recipe for session data; fcntl
    from the standard library instead of the filelock package). With ``WT_TEST_SHARE`` (set by
    .ci/test) it goes there, and .ci/notebooks gives it to the paper notebook."""
    import fcntl
    from pathlib import Path

    from warp_tensegrity.cli import main as cli_main

    root = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        root = root.parent  # shared by the workers of this session
    if os.environ.get("WT_TEST_SHARE"):  # .ci/test: the notebook step reads it too
        root = Path(os.environ["WT_TEST_SHARE"])
    out = root / "paper_2017" / "paper_2017.nc"
    out.parent.mkdir(parents=True, exist_ok=True)
    spec = Path(__file__).resolve().parents[1] / "sweeps" / "paper_2017.toml"
    with open(out.parent / "lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not out.exists():
            assert cli_main(["run", str(spec), "-o", str(out), "--device", "cpu", "--no-progress"]) == 0
    return out
