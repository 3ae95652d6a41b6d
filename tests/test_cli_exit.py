"""The command line's exit status and its last raw lines (issue 30 items 13, 14): a run in which
every case failed exits EXIT_ALL_FAILED and names the likely cause; `--device cuda` on a machine
without CUDA says so in one line, with none of Warp's own."""

from __future__ import annotations

from pathlib import Path

import pytest

from warp_tensegrity import cli

SPEC = """
title = "exit status"
[scene]
n_prisms = 3
[sweep]
grid = { v0 = [0.001, 0.002] }
fixed = { prestrain = 0.001 }
[run]
t_end = 0.02
output_interval = 0.005
"""


@pytest.fixture
def spec(tmp_path) -> Path:
    p = tmp_path / "s.toml"
    p.write_text(SPEC)
    return p


def test_cuda_without_cuda_is_one_line(spec, tmp_path, capfd):
    """`--device cuda` printed two raw "Warp CUDA error" lines (Warp asking the driver for its
    current context) before the clear one; now only the clear one (fd 2 read, as Warp writes there)."""
    import warp as wp

    if wp.is_cuda_available():
        pytest.skip("this machine has CUDA: 'cuda' is a device here")
    capfd.readouterr()
    assert cli.main(["run", str(spec), "-o", str(tmp_path / "o.nc"), "--device", "cuda"]) == cli.EXIT_ERROR
    err = capfd.readouterr().err
    assert "Warp CUDA error" not in err, err
    assert err.strip().splitlines() == [
        "warp-tensegrity: error: device = 'cuda' is not available (no CUDA device on this machine); use 'cpu'"], err
    assert not (tmp_path / "o.nc").exists()
