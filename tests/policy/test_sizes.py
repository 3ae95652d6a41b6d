"""Every size that follows from a run's plan is checked before anything of that size is allocated
(issue 30 item 1): the step count against the device's int32 step counter, and one column's
records (output count x energies and strain) against the machine's memory
(warp_tensegrity.policy.cost.size_problems), refused as the run is decided, in the CLI (run, dry
run, resume), the Python API and the lens, with the figure and a remedy; the plan builds its
output times only for the run itself; the probe neither builds them nor caches a peak RSS that
earlier work left."""

import os
import re
import resource
import subprocess
import sys
import time
import tracemalloc
from pathlib import Path

import numpy as np
import psutil
import pytest

import warp_tensegrity as W
from warp_tensegrity.options import SettingsError
from warp_tensegrity.policy import calibrate as C
from warp_tensegrity.policy import cost
from warp_tensegrity.policy import decide as D

from tests.memory_cap import address_space_cap

ROOT = Path(__file__).resolve().parents[2]
CI_SMALL = ROOT / "sweeps" / "ci_small.toml"
SECONDS, RSS = 5.0, 1e9
"""Must-show 2 of issue 30: each spec refused in under 5 s at under 1 GB peak RSS. The seconds are
the child's CPU seconds (user + system, from wait4), most of them the interpreter's start-up and
imports (~2 s alone): its wall time on a 2-core host that xdist and other jobs share runs 3x that
(WALL_SECONDS bounds it, for a refusal that would sleep or block)."""
WALL_SECONDS = 30.0
KILL_RSS = 2e9
"""A child past this is killed at once: a regression fails the test instead of taking the machine
(the unfixed code grew to the host's 24 GB)."""

# the specs of issue 30 item 1, as overrides of ci_small (8 prisms, record_strain = true, t_end = 2 s)
ITEM_1 = {
    "2e9 outputs": (["run.output_interval=1e-9"], [], r"2,000,000,001 outputs per column \(run\.t_end = 2 s / "
                    r"run\.output_interval = 1e-09 s\)"),
    "1e12 outputs, dry run": (["run.t_end=1e3", "run.output_interval=1e-9"], ["--dry-run"],
                              r"1,000,000,000,001 outputs per column"),
    "t_end 1e9 s, dry run": (["run.t_end=1e9", "run.output_interval=1"], ["--dry-run"],
                             r"\d\.\d+e\+1[12] steps \(run\.t_end = 1e\+09 s at dt = .*step counter"),  # the first group's
    "400 prisms of strain, dry run": (["scene.n_prisms=400", "run.record_strain=true", "run.t_end=100",
                                       "run.output_interval=1e-7"], ["--dry-run"],
                                      r"1,000,000,001 outputs per column .* the strain of 400 prisms"),
}


def run_measured(argv, cwd, timeout=60.0) -> tuple[int, float, float, int, str]:
    """``python -m warp_tensegrity ARGV`` in a subprocess: (exit code, wall seconds, CPU seconds,
    peak RSS [bytes], stderr), the last three its own (wait4). A child past KILL_RSS is killed (its
    RSS then reads as at least that)."""
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""),
               WARP_TENSEGRITY_CACHE=str(cwd / "cache"))
    err_path = cwd / "stderr.txt"
    t0 = time.perf_counter()
    with open(err_path, "w") as err:
        p = subprocess.Popen([sys.executable, "-m", "warp_tensegrity", *map(str, argv)], stdout=subprocess.DEVNULL,
                             stderr=err, env=env, cwd=cwd)
    killed = False
    try:
        proc = psutil.Process(p.pid)
        while True:
            pid, status, usage = os.wait4(p.pid, os.WNOHANG)
            if pid:
                break
            try:
                over = proc.memory_info().rss > KILL_RSS
            except psutil.NoSuchProcess:
                over = False
            if over or time.perf_counter() - t0 > timeout:
                p.kill()
                killed = True
            time.sleep(0.02)
    finally:
        p.returncode = 0 if not killed else -9  # reaped here: Popen must not wait again
    wall = time.perf_counter() - t0
    rss = usage.ru_maxrss * (1 if sys.platform == "darwin" else 1024)
    rc = os.waitstatus_to_exitcode(status)
    return rc, wall, usage.ru_utime + usage.ru_stime, max(rss, int(KILL_RSS) if killed else 0), err_path.read_text()


@pytest.mark.parametrize("name", list(ITEM_1))
def test_item_1_specs_are_refused_fast_in_little_memory(name, tmp_path):
    """Each spec of issue 30 item 1 through the CLI: exit 1 in under 5 s at under 1 GB peak RSS,
    one line with its figure and a remedy (before: a 7.3 TiB ArrayMemoryError, 23.6 GB for 27 s,
    or an OOM kill at the host's 24 GB)."""
    sets, extra, figure = ITEM_1[name]
    argv = ["run", CI_SMALL, "-o", tmp_path / "o.nc", "--device", "cpu", "--no-progress",
            *[a for s in sets for a in ("--set", s)], *extra]
    rc, wall, cpu, rss, err = run_measured(argv, tmp_path)
    print(f"\n{name}: exit {rc} in {cpu:.2f} s CPU ({wall:.2f} s wall) at {rss / 1e6:.0f} MB peak RSS")
    assert "Traceback" not in err and rc == 1, err[-2000:]
    line = err.strip().splitlines()[-1]
    assert line.startswith("warp-tensegrity: error: the run cannot be done: "), err
    assert re.search(figure, line), line
    assert "lower run.t_end" in line, line  # the remedy
    if "outputs per column" in line:
        assert re.search(r"need about [\d.]+ [kMGTP]B of host memory and this machine has [\d.]+ [kMGTP]B; "
                         r"raise run\.output_interval, lower run\.t_end or set run\.record_strain = false", line), line
    assert cpu < SECONDS and wall < WALL_SECONDS and rss < RSS, (cpu, wall, rss)
    assert not (tmp_path / "o.nc").exists() and not (tmp_path / "cache").exists()  # nothing probed or cached


def test_ignore_estimate_and_resume_refuse_too(tmp_path, capsys):
    """No override runs it: --ignore-estimate, and resume SPEC -o OUT (also a dry run) refuse the
    same way, before any store exists."""
    from warp_tensegrity.cli import main

    out = tmp_path / "o.nc"
    with address_space_cap():
        _ignore_estimate_and_resume(out, tmp_path, capsys, main)


def _ignore_estimate_and_resume(out, tmp_path, capsys, main):
    for argv in (["run", CI_SMALL, "-o", out, "--ignore-estimate", "--set", "run.output_interval=1e-9"],
                 ["run", CI_SMALL, "-o", out, "--memory-limit", "64MB", "--set", "run.output_interval=1e-9"]):
        assert main([str(a) for a in [*argv, "--device", "cpu"]]) == 1
        assert "2,000,000,001 outputs per column" in capsys.readouterr().err
    spec = tmp_path / "long.toml"
    spec.write_text(CI_SMALL.read_text().replace("output_interval = 0.005", "output_interval = 1e-9"))
    for extra in ([], ["--dry-run"]):
        assert main(["resume", str(spec), "-o", str(out), "--device", "cpu", *extra]) == 1
        err = capsys.readouterr().err
        assert "2,000,000,001 outputs per column" in err and "Traceback" not in err, err
    assert not out.exists() and not Path(str(out) + ".sweep").exists()


@pytest.mark.parametrize("call", ["simulate_batch", "estimate_batch", "decide", "run_batch"])
def test_the_python_api_refuses_before_allocating(call):
    """simulate_batch, estimate_batch, decide and run_batch refuse the 2e9-output run with a
    SettingsError naming t_end, output_interval and the count, having allocated (tracemalloc) a
    few MB at most."""
    cfg = W.ColumnConfig(n_prisms=8)
    params = {"prestrain": [0.0, 0.002], "v0": 0.005}
    settings = W.RunSettings(t_end=2.0, output_interval=1e-9, device="cpu")
    f = {"simulate_batch": lambda: W.simulate_batch(cfg, params, settings),
         "estimate_batch": lambda: W.estimate_batch(cfg, params, settings),
         "decide": lambda: W.decide(cfg, params, settings),
         "run_batch": lambda: W.run_batch(W.column_batch(cfg, params), settings)}[call]
    tracemalloc.start()
    try:
        with address_space_cap(), pytest.raises(SettingsError) as e:
            f()
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    msg = str(e.value)
    assert "2,000,000,001 outputs per column (run.t_end = 2 s / run.output_interval = 1e-09 s)" in msg, msg
    assert "raise run.output_interval" in msg and "\n" not in msg, msg
    assert peak < 20e6, peak


def test_size_problems_figures_and_bounds():
    """The bound, stated once (policy.cost): steps above the int32 counter; one column's records
    (time axis, energies, strain; the engine's arrays on the CPU) above the machine's memory, on
    the host or on a GPU; nothing when they fit."""
    run = D.RunPlan(settings=W.RunSettings(t_end=1.0, output_interval=1e-3), dt=1e-4, dt_limit=1e-3, n_steps=10_000,
                    output_every=10, omega_max_bound=100.0, bandwidth=3, n_nodes=30, n_constraints=30, n_cables=60,
                    path=D.Path.FUSED, lane_refusal=None, device="cpu", on_gpu=False, n_columns=4, prisms=10,
                    prisms_simulated=10)
    host, dev = cost.column_bytes(run)
    assert dev == 0 and host == 16 * 1001 + cost.output_bytes_per_column(1001, 10, True) + cost.state_bytes_per_column(run)
    assert cost.size_problems(run, host_bytes=host) == []
    (line,) = cost.size_problems(run, host_bytes=host - 1)
    assert line.startswith("1,001 outputs per column (run.t_end = 1 s / run.output_interval = 0.001 s)"), line
    assert "set run.record_strain = false" in line
    import dataclasses

    gpu = dataclasses.replace(run, on_gpu=True, device="cuda:0")
    host, dev = cost.column_bytes(gpu)
    assert dev == cost.state_bytes_per_column(gpu) and host == 16 * 1001 + cost.output_bytes_per_column(1001, 10, True)
    (line,) = cost.size_problems(gpu, host_bytes=host, device_bytes=dev - 1)
    assert "of cuda:0 memory" in line
    long = dataclasses.replace(run, n_steps=cost.MAX_STEPS + 1, output_every=cost.MAX_STEPS + 1)
    (line,) = cost.size_problems(long, host_bytes=10**12)
    assert "2.15e+09 steps" in line and "step counter (2,147,483,647 steps); lower run.t_end" in line, line


def test_the_plan_builds_a_head_of_its_outputs_only():
    """first_output_times is the head of output_times, bit for bit (the probe reads it), and costs
    its head only."""
    params = {"prestrain": [0.0], "v0": 0.005}
    run = D.decide(W.ColumnConfig(n_prisms=4), params, W.RunSettings(t_end=0.37, output_interval=0.0013, device="cpu"))
    for n in (0, 1, 2, 17, run.n_out, run.n_out + 5):
        np.testing.assert_array_equal(run.first_output_times(n), run.output_times[:n])
        np.testing.assert_array_equal(run.first_output_steps(n), run.output_steps[:n])


def test_the_probe_caches_no_peak_of_earlier_work(tmp_path, monkeypatch):
    """The probe records what the process holds (its RSS after the probe), not the lifetime peak:
    a probe after 400 MB of earlier work (freed) does not cache it as the run's baseline (the issue:
    a probe cached "24.2 GB peak host memory" from the output steps of a huge run)."""
    monkeypatch.setenv("WARP_TENSEGRITY_CACHE", str(tmp_path / "cache"))
    cfg = W.ColumnConfig(n_prisms=4)
    params = D.column_params(cfg, {"prestrain": [0.0, 0.001], "v0": 0.005})
    run = D.decide(cfg, params, W.RunSettings(t_end=0.02, output_interval=0.005, device="cpu"))
    big = np.ones(50_000_000)  # 400 MB, touched, then returned to the system
    del big
    cal = C.probe(cfg, params, run, 2, use_cache=False)
    import resource

    lifetime_peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    assert cal["base_rss"] < lifetime_peak - 300e6, (cal["base_rss"], lifetime_peak)
    assert cal["base_rss"] <= psutil.Process().memory_info().rss + 100e6


def test_the_lens_names_the_batch_it_refuses(tmp_path, capsys):
    """The lens decides its batches with the same plan: one that cannot be done is refused before
    its probe, naming the batch, with the figure (a dry run too)."""
    from warp_tensegrity.cli import main

    spec = tmp_path / "lens.toml"
    spec.write_text((ROOT / "sweeps" / "lens_ci.toml").read_text().replace("t_end = 0.9 ", "t_end = 1e9 ").replace(
        "output_interval = 0.002 ", "output_interval = 1e7 "))
    with address_space_cap():
        assert main(["lens", str(spec), "-o", str(tmp_path / "o.nc"), "--device", "cpu", "--dry-run"]) == 1
    err = capsys.readouterr().err
    assert "the calibration batch: the run cannot be done: " in err and "step counter" in err, err
    assert "Traceback" not in err
