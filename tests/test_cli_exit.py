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


def _spec(tmp_path, grid: str, run: str = "", fixed: str = "prestrain = 0.002, base_rigidity = 1.0") -> Path:
    p = tmp_path / "v.toml"
    p.write_text(f'title = "exit"\n[scene]\nn_prisms = 4\n[sweep]\ngrid = {{ {grid} }}\nfixed = {{ {fixed} }}\n'
                 f'[run]\nt_end = 0.1\noutput_interval = 0.005\n{run}\n')
    return p


def test_every_case_failed_exits_non_zero_and_names_v0_far_above_the_sound_speed(tmp_path, capsys):
    """Issue 30 item 13: v0 given in mm/s (3 and 5 m/s) made every case non-finite, and the run
    exited 0 advising a smaller dt. Now it exits EXIT_ALL_FAILED with one line naming v0 against
    the columns' long-wave speed c0 (checked here against the Bloch bands' long-wave limit)."""
    from warp_tensegrity.scene.columns import ColumnConfig
    from warp_tensegrity.validation.dispersion import bands

    out = tmp_path / "o.nc"
    assert cli.main(["run", str(_spec(tmp_path, "v0 = [3.0, 5.0]")), "-o", str(out), "--device", "cpu"]) == cli.EXIT_ALL_FAILED
    assert cli.EXIT_ALL_FAILED not in (cli.EXIT_OK, cli.EXIT_ERROR, cli.EXIT_INCOMPLETE)
    err = capsys.readouterr().err
    cfg = ColumnConfig(n_prisms=4)
    c0 = bands(cfg, 0.002, 1.0, k=[1e-3 / cfg.height]).long_wave_speed()
    want = (f"error: every case failed (2 of 2: the state became non-finite or a bar constraint failed; no column "
            f"ran to t_end); likely cause: the impact speed v0 = 3 to 5 m/s is {3 / c0:.0f}x to {5 / c0:.0f}x the "
            f"long-wave sound speed c0 = {c0:.2g} m/s of the columns (v0 is in m s-1: was it given in mm/s?)")
    assert want in err, err
    assert "try a smaller dt" not in err and out.exists()  # the output is kept: it is what failed
    assert "exit status: 0 done" in cli.build_parser().format_help().lower()


def test_a_partial_failure_exits_0_with_its_summary(tmp_path, capsys):
    """One case of two failed: exit 0 (the other's result is in the file), the summary line says which."""
    out = tmp_path / "o.nc"
    assert cli.main(["run", str(_spec(tmp_path, "v0 = [0.002, 5.0]")), "-o", str(out), "--device", "cpu"]) == cli.EXIT_OK
    err = capsys.readouterr().err
    assert "1 of 2 cases: the state became non-finite" in err and "every case failed" not in err, err


def test_every_case_failed_at_an_unstable_dt_names_the_dt(tmp_path, capsys):
    """With allow_unstable_dt and a dt above the stability limit, the line names the dt, not v0."""
    spec = _spec(tmp_path, "v0 = [0.01, 0.02]", "dt = 0.05\nallow_unstable_dt = true\n").read_text()
    spec = spec.replace("t_end = 0.1\noutput_interval = 0.005", "t_end = 1.0\noutput_interval = 0.05")
    (tmp_path / "v.toml").write_text(spec)
    assert cli.main(["run", str(tmp_path / "v.toml"), "-o", str(tmp_path / "o.nc"), "--device", "cpu"]) == cli.EXIT_ALL_FAILED
    err = capsys.readouterr().err
    assert "every case failed (2 of 2" in err and "likely cause: dt = 0.05 s is" in err and "its stability limit" in err, err


def test_all_failed_on_datasets():
    """nan_reasons.all_failed: None while one case ran to t_end; unstressed columns (c0 = 0) are left
    out of the v0 comparison; a v0 within FAR_ABOVE_SOUND of c0 gives the generic advice."""
    import numpy as np
    import xarray as xr

    from warp_tensegrity.measure.nan_reasons import FLAG, all_failed
    from warp_tensegrity.validation.closed_forms import long_wave_speeds

    def grid(flags, prestrain, v0):
        return xr.Dataset({"measurement_flag": (("prestrain", "v0"), np.array(flags, dtype=np.int8))},
                          coords={"prestrain": prestrain, "v0": v0, "cable_EA": 0.3374, "unit_mass": 0.0249},
                          attrs={"scene_radius": 5e-3, "scene_height": 6.2e-3, "dt": 1e-4, "dt_limit": 1e-3})

    bad, ok = FLAG["non_finite"], FLAG["ok"]
    assert all_failed(grid([[bad, bad], [bad, ok]], [0.0, 0.002], [1.0, 2.0]), long_wave_speeds) is None
    line = all_failed(grid([[bad, bad], [FLAG["constraint_failure"], bad]], [0.0, 0.002], [1.0, 2.0]), long_wave_speeds)
    assert "every case failed (4 of 4" in line and "v0 = 1 to 2 m/s is 38x to 76x" in line and "c0 = 0.026 m/s" in line, line
    line = all_failed(grid([[bad, bad], [bad, bad]], [0.0, 0.002], [0.01, 0.2]), long_wave_speeds)
    assert line.endswith(": try a smaller dt (run.dt_safety or run.dt)"), line  # 0.38 and 7.6 c0: not the cause
    line = all_failed(grid([[bad, bad]], [0.0], [1.0, 2.0]), long_wave_speeds)
    assert line.endswith(": try a smaller dt (run.dt_safety or run.dt)"), line  # unstressed: no c0 to compare with
