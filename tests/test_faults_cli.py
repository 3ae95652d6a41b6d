"""Faults of issue 30 at the command line: SIGTERM (item 11), unwritable kernel caches (5), an
output that is a directory or special file (6), `resume` over finished work (2), `lens` outputs
(12), `status` while a store is initialised (16), and the last-resort one-line OSError."""

from __future__ import annotations

import errno
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import xarray as xr

from warp_tensegrity import cli, sweep
from warp_tensegrity.io import drop_run_dependent
from warp_tensegrity.io import open_sweep as open_nc
from warp_tensegrity.sweep import manifest as zmanifest
from warp_tensegrity.sweep.store import SweepStore

ROOT = Path(__file__).resolve().parents[1]

SPEC = """
title = "faults"
[scene]
n_prisms = 3
[sweep]
grid = { v0 = [0.001, 0.002] }
fixed = { prestrain = 0.001 }
[run]
t_end = 0.02
output_interval = 0.005
shard_size = 4
"""


def write(d: Path, text: str = SPEC, name: str = "s.toml") -> Path:
    p = d / name
    p.write_text(text)
    return p


def run_cli(*args) -> int:
    extra = ["--no-progress", "--device", "cpu"] if args[0] in ("run", "resume") else []
    return cli.main([*map(str, args), *extra])


def subprocess_env(**extra) -> dict:
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    env.pop(zmanifest.FAULT_ENV, None)
    env.update(extra)
    return env


def assert_bitwise(a: xr.Dataset, b: xr.Dataset):
    a, b = drop_run_dependent(a), drop_run_dependent(b)
    xr.testing.assert_identical(a, b)
    for k in a.variables:
        x, y = np.asarray(a[k].values), np.asarray(b[k].values)
        if x.dtype.kind in "OUT":
            assert [str(s) for s in x.ravel()] == [str(s) for s in y.ravel()], k
        else:
            assert x.dtype == y.dtype and x.tobytes() == y.tobytes(), k


def chunk_mtimes(out: Path) -> dict:
    z = SweepStore(out).zarr / "strain" / "c"
    return {p.relative_to(z).parts[0]: p.stat().st_mtime_ns for p in z.rglob("*") if p.is_file()}


def manifest_shards(out: Path) -> dict:
    """The shards recorded as done: manifest.json and its journal (Manifest.read)."""
    from warp_tensegrity.sweep.manifest import Manifest

    return Manifest.read(SweepStore(out).manifest_path)[0]["shards"]


# ---------------------------------------------------------------------- item 11: SIGTERM
def _sigterm_at_stepping(args, tmp_path: Path) -> tuple[int, str]:
    """Run the CLI in a subprocess paused by the fault hook at its first stepping callback,
    send SIGTERM there; returns (exit code, stderr)."""
    marker = tmp_path / f"paused-{time.monotonic_ns()}"
    proc = subprocess.Popen(
        [sys.executable, "-m", "warp_tensegrity", *map(str, args), "--no-progress", "--device", "cpu"],
        env=subprocess_env(**{zmanifest.FAULT_ENV: "stepping@1:pause", zmanifest.FAULT_FILE_ENV: str(marker)}),
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        deadline = time.monotonic() + 300
        while not marker.exists():
            assert proc.poll() is None, f"exited early (rc {proc.returncode}): {proc.stderr.read().decode()[-3000:]}"
            assert time.monotonic() < deadline, "fault hook not reached"
            time.sleep(0.02)
        proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=120)
        return proc.returncode, proc.stderr.read().decode()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        proc.stderr.close()


@pytest.mark.slow  # two CLI subprocesses and two resumes of ci_small (~40 s on 2 loaded cores)
def test_sigterm_is_an_interrupt_that_keeps_shards_and_releases_the_lock(tmp_path, ci_small_nc):
    """SIGTERM (what batch schedulers send) killed silently and left the lock. Now it unwinds as
    Ctrl-C does: the lock is released, finished shards are kept, one message, exit 143; and
    `resume` finishes byte-identical to an uninterrupted run."""
    spec = ROOT / "sweeps" / "ci_small.toml"
    out = tmp_path / "t.nc"
    lock = zmanifest.lock_path_for(out)
    # `run`, terminated while stepping its first shard
    rc, err = _sigterm_at_stepping(("run", spec, "-o", out), tmp_path)
    assert rc == 128 + signal.SIGTERM, err[-3000:]  # 143, as a shell reports it
    assert "terminated (SIGTERM)" in err and f"resume {out}" in err and "Traceback" not in err, err
    assert not lock.exists() and SweepStore(out).manifest_path.exists() and not out.exists()
    assert run_cli("resume", out) == 0
    assert_bitwise(open_nc(out), open_nc(ci_small_nc))

    # `resume` with shard 0 done (shard 1 dropped, as if killed before it was recorded), terminated
    # while stepping shard 1: shard 0 stays recorded and untouched
    content, _ = zmanifest.Manifest.read(SweepStore(out).manifest_path)
    content["shards"].pop("1")
    zmanifest.Manifest(SweepStore(out).manifest_path, content).save()
    out.unlink()
    kept, mtimes = manifest_shards(out), chunk_mtimes(out)
    rc, err = _sigterm_at_stepping(("resume", out), tmp_path)
    assert rc == 128 + signal.SIGTERM and "terminated (SIGTERM)" in err and "Traceback" not in err, err[-3000:]
    assert not lock.exists()
    assert manifest_shards(out) == kept and {k: v for k, v in chunk_mtimes(out).items() if k == "0"} == \
        {k: v for k, v in mtimes.items() if k == "0"}
    assert run_cli("resume", out) == 0
    assert_bitwise(open_nc(out), open_nc(ci_small_nc))
    assert chunk_mtimes(out)["0"] == mtimes["0"]  # reused, not rewritten


def test_sigterm_raises_in_the_command_and_the_handler_is_put_back(tmp_path, monkeypatch, capsys):
    """In process: SIGTERM during a command unwinds it like Ctrl-C (exit 143, one line); cli.main
    installs its handler for the command only and puts back the one it found."""
    from warp_tensegrity import cli as cli_module

    def sigterm_during(args):
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(5)  # the handler raises in this thread before the sleep ends
        raise AssertionError("SIGTERM did not interrupt the command")

    def not_handled(signum, frame):  # the test's own, in place of the default (which ends pytest)
        raise AssertionError("cli.main did not handle SIGTERM")

    outer = signal.signal(signal.SIGTERM, not_handled)
    try:
        monkeypatch.setattr(cli_module, "run_init", sigterm_during)
        assert cli.main(["init", "-o", str(tmp_path / "i.toml")]) == 128 + signal.SIGTERM
        assert capsys.readouterr().err.strip() == "warp-tensegrity: terminated (SIGTERM)"
        assert signal.getsignal(signal.SIGTERM) is not_handled
    finally:
        signal.signal(signal.SIGTERM, outer)


# ---------------------------------------------------------------------- item 5: Warp's kernel cache
@pytest.mark.slow  # three CLI subprocesses (~30 s on 2 loaded cores)
def test_unwritable_kernel_cache(tmp_path):
    """A HOME where ~/.cache cannot be made (here a file stands in the way: ENOTDIR, which root
    cannot override either) gave a traceback from Warp's kernel cache even for --version and
    status. Those need no kernels and now work; a run stops with Warp's error in one line and
    the WARP_CACHE_PATH hint."""
    spec = write(tmp_path)
    out = tmp_path / "o.nc"
    assert run_cli("run", spec, "-o", out) == 0
    home = tmp_path / "home"
    home.write_text("not a directory")
    env = subprocess_env(HOME=str(home), MPLCONFIGDIR=str(tmp_path / "mpl"))
    for k in ("WARP_CACHE_PATH", "XDG_CACHE_HOME"):
        env.pop(k, None)

    def cli_sub(*args):
        p = subprocess.run([sys.executable, "-m", "warp_tensegrity", *map(str, args)], env=env,
                           capture_output=True, text=True, timeout=300)
        assert "Traceback" not in p.stderr, p.stderr[-3000:]
        return p

    p = cli_sub("--version")
    assert p.returncode == 0 and "Warp " in p.stdout, p.stderr
    p = cli_sub("status", out)
    assert p.returncode == 0 and "done:       2 cases" in p.stdout, p.stderr
    p = cli_sub("run", spec, "-o", tmp_path / "x.nc", "--device", "cpu")
    assert p.returncode == 1, p.stderr
    (line,) = [ln for ln in p.stderr.splitlines() if "error" in ln]
    assert "kernel cache" in line and "ENOTDIR" in line and str(home) in line and "WARP_CACHE_PATH" in line, line
    assert not (tmp_path / "x.nc").exists()


def test_kernel_cache_that_exists_but_takes_no_file(tmp_path):
    """A cache directory that exists but cannot take a file (read-only, or not a directory) passes
    wp.init(); init_warp(kernels=True) then probes it with a file and words the refusal."""
    from warp_tensegrity import runtime

    blocked = tmp_path / "cache"
    blocked.write_text("")
    e = runtime._cache_problem(blocked)
    assert isinstance(e, OSError) and e.errno == errno.ENOTDIR and runtime._cache_problem(tmp_path) is None
    msg = str(runtime._cache_error(blocked, e))
    assert f"{blocked}" in msg and "ENOTDIR" in msg and "WARP_CACHE_PATH" in msg, msg


# ---------------------------------------------------------------------- item 6: -o a directory
def test_output_that_is_a_directory_or_special_file(tmp_path, capsys):
    """`run -o DIR --overwrite` raised IsADirectoryError; without --overwrite the message suggested
    `resume` on a directory. A FIFO (or /dev/null) at -o was unlinked by --overwrite."""
    spec = write(tmp_path)
    d = tmp_path / "d"
    (d / "keep").mkdir(parents=True)
    for extra in ((), ("--overwrite",)):
        capsys.readouterr()
        assert run_cli("run", spec, "-o", d, *extra) == 1
        err = capsys.readouterr().err
        assert "is a directory" in err and "resume" not in err and "Traceback" not in err, err
        assert (d / "keep").is_dir()
    fifo = tmp_path / "f.nc"
    os.mkfifo(fifo)
    assert run_cli("run", spec, "-o", fifo, "--overwrite") == 1
    assert "not a regular file" in capsys.readouterr().err and fifo.is_fifo()
    # a file where a directory should be: the errno and the path, before anything runs
    assert run_cli("run", spec, "-o", spec / "o.nc") == 1
    err = capsys.readouterr().err
    assert "ENOTDIR" in err and str(spec) in err and "Traceback" not in err, err


# ---------------------------------------------------------------------- item 2: resume over finished work
def test_resume_does_not_replace_a_finished_run(tmp_path, capsys):
    """`resume SPEC -o OUT.nc` with an edited spec recreated the store of a finished run and
    replaced OUT.nc. Now it refuses, naming the difference and --overwrite; a resume of the same
    finished run writes nothing, and exports again only when OUT.nc is missing."""
    spec = write(tmp_path)
    out = tmp_path / "o.nc"
    assert run_cli("run", spec, "-o", out) == 0
    data, manifest = out.read_bytes(), SweepStore(out).manifest_path.read_bytes()
    edited = write(tmp_path, SPEC.replace("0.002]", "0.003]"), "edited.toml")
    capsys.readouterr()
    assert run_cli("resume", edited, "-o", out) == 1
    err = capsys.readouterr().err
    assert "finished shard of another run: its spec differs" in err and "--overwrite" in err, err
    assert out.read_bytes() == data and SweepStore(out).manifest_path.read_bytes() == manifest
    # the same run, finished: nothing to do, nothing written
    mtime = out.stat().st_mtime_ns
    assert run_cli("resume", out) == 0 and run_cli("resume", spec, "-o", out) == 0
    err = capsys.readouterr().err
    assert "is complete: nothing to resume" in err and "wrote" not in err, err
    assert out.stat().st_mtime_ns == mtime
    out.unlink()  # ... exported again when its output is gone
    assert run_cli("resume", out) == 0 and out.exists()
    (tmp_path / "first.nc").write_bytes(data)
    assert_bitwise(open_nc(out), open_nc(tmp_path / "first.nc"))
    # --overwrite discards it
    assert run_cli("resume", edited, "-o", out, "--overwrite") == 0
    assert list(open_nc(out)["v0"].values) == [0.001, 0.003]


def test_resume_with_no_store_keeps_an_output_of_another_run(tmp_path, capsys):
    """A run with --no-keep-store leaves OUT.nc alone: `resume SPEC -o OUT.nc` recomputed the whole
    sweep and replaced it whatever its spec. The same spec: nothing to resume; another: refused."""
    spec = write(tmp_path)
    out = tmp_path / "o.nc"
    assert run_cli("run", spec, "-o", out, "--no-keep-store") == 0
    data = out.read_bytes()
    capsys.readouterr()
    assert run_cli("resume", spec, "-o", out) == 0
    assert "complete (its store was removed)" in capsys.readouterr().err and not SweepStore(out).dir.exists()
    edited = write(tmp_path, SPEC.replace("0.002]", "0.003]"), "edited.toml")
    assert run_cli("resume", edited, "-o", out) == 1
    assert "is not this run's export" in capsys.readouterr().err and out.read_bytes() == data


def test_resume_spec_takes_the_recorded_shard_size(tmp_path, capsys):
    """`resume SPEC -o OUT.nc` planned with the spec's shard size: after `run --shard-size 1` every
    done shard was 'stale' and recomputed. It now takes the run's, as `resume OUT.nc` does; an
    explicit other --shard-size is refused while shards are done (naming both sizes), and so is a
    file at OUT.nc that is not this run's export."""
    spec = write(tmp_path)
    out = tmp_path / "o.nc"
    assert run_cli("run", spec, "-o", out, "--shard-size", 1) == 0
    content, _ = zmanifest.Manifest.read(SweepStore(out).manifest_path)
    content["shards"].pop("1")  # as if killed before shard 1 was recorded
    zmanifest.Manifest(SweepStore(out).manifest_path, content).save()
    out.write_bytes(b"someone else's file")  # not this run's export: kept, whatever the store holds
    mtimes = chunk_mtimes(out)
    capsys.readouterr()
    assert run_cli("resume", out) == 1
    assert "is not this run's export" in capsys.readouterr().err and out.read_bytes() == b"someone else's file"
    out.unlink()
    assert run_cli("resume", spec, "-o", out, "--shard-size", 2) == 1
    err = capsys.readouterr().err
    assert "its shard size is 1, this run's 2" in err and "--overwrite" in err, err
    assert run_cli("resume", spec, "-o", out) == 0
    assert "recomputing" not in capsys.readouterr().err
    assert chunk_mtimes(out)["0"] == mtimes["0"] and sorted(manifest_shards(out)) == ["0", "1"]


def test_resume_refuses_a_spec_copy_that_does_not_match_its_manifest(tmp_path, capsys):
    """A store whose spec.toml no longer matches the manifest's spec_sha256 (edited, bit-rotted)
    lost its header, and `resume OUT.nc` reran the altered copy over the verified shards. Now
    resume and status refuse it as corrupt; `resume SPEC -o OUT.nc` with the run's spec reuses
    the shards and restores the copy."""
    spec = write(tmp_path)
    out = tmp_path / "o.nc"
    assert run_cli("run", spec, "-o", out) == 0
    copy = SweepStore(out).dir / zmanifest.SPEC_COPY
    original, data, mtimes = copy.read_bytes(), out.read_bytes(), chunk_mtimes(out)
    copy.write_text(copy.read_text().replace("t_end = 0.02", "t_end = 0.03"))
    capsys.readouterr()
    for args in (("resume", out), ("status", out)):
        assert run_cli(*args) == 1
        err = capsys.readouterr().err
        assert "is not the spec its manifest recorded" in err and "Traceback" not in err, err
    assert out.read_bytes() == data and chunk_mtimes(out) == mtimes
    assert run_cli("resume", spec, "-o", out) == 0
    assert "restored" in capsys.readouterr().err
    assert copy.read_bytes() == original and chunk_mtimes(out) == mtimes


# ---------------------------------------------------------------------- item 12: lens outputs
def test_lens_checks_its_output_before_computing(tmp_path, capsys, monkeypatch):
    """`lens` replaced an existing output silently, and found an unwritable one only after its
    batches. Now it behaves like `run`: an existing output needs --overwrite, and a directory or
    an unwritable place is refused before any batch runs."""
    from warp_tensegrity.lens import estimate, run

    def computed(*a, **k):
        raise AssertionError("the lens computed before checking its output")

    monkeypatch.setattr(run, "run_lens", computed)
    monkeypatch.setattr(estimate, "estimate_lens", computed)
    spec = ROOT / "sweeps" / "lens_ci.toml"
    old = tmp_path / "old.nc"
    old.write_bytes(b"earlier result")
    cases = [(old, "exists; give another output, or replace it with --overwrite"),
             (tmp_path, "is a directory"),
             (old / "x.nc", "ENOTDIR")]
    for path, words in cases:
        assert cli.main(["lens", str(spec), "-o", str(path), "--device", "cpu"]) == 1
        err = capsys.readouterr().err
        assert words in err and "Traceback" not in err, err
    assert old.read_bytes() == b"earlier result"
    with pytest.raises(AssertionError, match="computed"):  # --overwrite lets it through to the batches
        cli.main(["lens", str(spec), "-o", str(old), "--device", "cpu", "--overwrite"])


# ---------------------------------------------------------------------- item 16: status during initialisation
def test_status_while_a_store_is_initialised(tmp_path, monkeypatch):
    """While `run --shard-size 1` initialises its store, `status` reported every shard 'corrupt'
    (no manifest yet) or, when the manifest appeared between its two reads, 'stale' (the spec's
    shard size against the run's). Now: missing while there is no manifest, and read again
    when one appears."""
    from warp_tensegrity.sweep import run as sweep_run

    spec = write(tmp_path)
    out = tmp_path / "o.nc"
    assert run_cli("run", spec, "-o", out, "--shard-size", 1) == 0
    store = SweepStore(out)
    saved = store.manifest_path.read_bytes()
    store.manifest_path.unlink()
    st = sweep.sweep_status(out)
    assert (st["shards_missing"], st["shards_corrupt"], st["shards_stale"]) == ([0], [], []), st
    real = sweep_run.template_dataset

    def manifest_appears(plan):  # the initialising run writes its manifest between status's reads
        store.manifest_path.write_bytes(saved)
        return real(plan)

    monkeypatch.setattr(sweep_run, "template_dataset", manifest_appears)
    st = sweep.sweep_status(out)
    assert st["shard_size"] == 1 and st["shards_done"] == 2 and st["shards_stale"] == [], st


def test_interrupted_initialisation_never_records_spec_file_none(tmp_path, capsys, monkeypatch):
    """A run stopped before its manifest existed left a spec copy without the spec's path, and
    `resume OUT.nc` then recorded spec_file = none. The copy is now written after the store's
    attributes (which hold the path): `resume OUT.nc` asks for the spec, and records it."""
    spec = write(tmp_path)
    out = tmp_path / "o.nc"

    def interrupted(self, *a, **k):
        raise KeyboardInterrupt

    with monkeypatch.context() as m:
        m.setattr(xr.Dataset, "to_zarr", interrupted)
        assert run_cli("run", spec, "-o", out) == 130  # as Ctrl-C
    assert SweepStore(out).dir.is_dir() and not SweepStore(out).manifest_path.exists()
    capsys.readouterr()
    rc = run_cli("resume", out)
    err = capsys.readouterr().err
    assert rc == 1 and f"resume SPEC -o {out}" in err, (rc, err)
    assert run_cli("resume", spec, "-o", out) == 0
    assert zmanifest.Manifest.read(SweepStore(out).manifest_path)[0]["spec_file"] == str(spec)


# ---------------------------------------------------------------------- every OSError in one line
def test_oserror_reaching_the_cli_is_one_line(tmp_path, capsys):
    """An OSError no command words itself (here: plot's figure into a place that cannot be made)
    ends as one line with the errno's name and the path, never a traceback."""
    spec = write(tmp_path)
    out = tmp_path / "o.nc"
    assert run_cli("run", spec, "-o", out) == 0
    capsys.readouterr()
    fig = spec / "fig.png"  # under a file: ENOTDIR
    assert cli.main(["plot", str(out), "spacetime", "--sel", "v0=0.001", "-o", str(fig)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "ENOTDIR" in err[0] and str(fig) in err[0], err
    from warp_tensegrity.outputs import oserror_text

    e = OSError(13, "Permission denied", "/a/b.png")
    assert oserror_text(e) == "Permission denied [Errno 13 EACCES]: /a/b.png"
