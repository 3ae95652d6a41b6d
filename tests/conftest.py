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
