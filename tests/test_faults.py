"""Faults a fuzzer misses (issue 30): temporaries and locks planted as symbolic links, a full disk,
an unwritable calibration cache, a non-UTF-8 interpreter, a spec that is a FIFO or /dev/zero.

Each section is self-contained (its own specs and helpers), so other fault tests (signals, Warp's
cache) can be added as sections of their own. Root ignores file modes, and a tmpfs needs root: an
unwritable place is a path under a regular file, a full disk is an OSError(ENOSPC) injected where
the libraries write, and, where this kernel lets a user mount one (``unshare -Urm``), a real small
tmpfs (marked slow).
"""

from __future__ import annotations

import errno
import itertools
import json
import os
import re
import resource
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest
import xarray as xr

from warp_tensegrity import atomic, cli
from warp_tensegrity import io as D
from warp_tensegrity.sweep import manifest as zmanifest
from warp_tensegrity.sweep import store as zstore

REPO = Path(__file__).resolve().parents[1]

SPEC = """
title = "faults"
[scene]
n_prisms = 3
[sweep]
grid = { v0 = [0.001, 0.002, 0.003] }
fixed = { prestrain = 0.001 }
[run]
t_end = 0.02
output_interval = 0.005
device = "cpu"
shard_size = 1
"""


def _spec(d: Path, text: str = SPEC, name: str = "s.toml") -> Path:
    p = d / name
    p.write_text(text, encoding="utf-8")
    return p


def _cli(*args) -> int:
    extra = ["--no-progress"] if args[0] in ("run", "resume") else []
    return cli.main([*map(str, args), *extra])


def _env(**extra) -> dict:
    env = dict(os.environ, PYTHONPATH=str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    env.pop(zmanifest.FAULT_ENV, None)
    env.update(extra)
    return env


def _error_lines(err: str) -> list[str]:
    return [line for line in err.splitlines() if re.match(r"warp-tensegrity( lens)?: error", line)]


# ====================================================================== symlinks (issue 30 item 3)
# A symbolic link planted at a temporary's name must never be written through: the test plants one,
# pointing at a victim file, at the name the code used before (.NAME.<pid>.tmp) and at the first
# name tempfile will try (its candidate names patched to start with "planted").
VICTIM = b"precious data, not the sweep's\n"


@pytest.fixture
def planted(tmp_path, monkeypatch):
    """plant(path): symlinks to a victim file at ``path``'s temporary names; check(): victims untouched."""
    real = tempfile._get_candidate_names
    monkeypatch.setattr(tempfile, "_get_candidate_names", lambda: itertools.chain(["planted"], real()))
    victims = []

    def plant(path: Path) -> None:
        for name in (f".{path.name}.{os.getpid()}.tmp", f".{path.name}.planted.tmp"):
            victim = tmp_path / f"victim{len(victims)}"
            victim.write_bytes(VICTIM)
            victims.append(victim)
            (path.parent / name).symlink_to(victim)

    def check() -> None:
        for v in victims:
            assert v.read_bytes() == VICTIM, v

    plant.check = check
    return plant


def _small_dataset(n=3) -> xr.Dataset:
    rng = np.random.default_rng(1)
    return xr.Dataset({"strain": (("case", "t", "prism"), rng.standard_normal((n, 40, 30)))},
                      coords={"t": np.arange(40.0)})


def test_manifest_and_spec_copy_temporaries_never_follow_a_link(tmp_path, planted):
    for name in ("manifest.json", "spec.toml"):
        target = tmp_path / name
        planted(target)
        zmanifest._atomic_write_text(target, "text é\n")
        assert target.read_bytes() == "text é\n".encode() and not target.is_symlink()
    m = zmanifest.Manifest(tmp_path / "manifest.json", {"format": zmanifest.FORMAT, "shards": {}})
    m.save()
    assert zmanifest.Manifest.read(m.path)[0]["shards"] == {}
    planted.check()


def test_netcdf_temporaries_never_follow_a_link(tmp_path, planted):
    """The sweep's export (.OUT.nc.<pid>.tmp was truncated through a link, then the link moved onto
    OUT.nc), and io.write_netcdf (the lens output, the probe's files)."""
    ds = _small_dataset()
    for write, name in ((zstore.export_netcdf, "export.nc"), (D.write_netcdf, "lens.nc")):
        target = tmp_path / name
        planted(target)
        write(ds.chunk({"case": 1}) if write is zstore.export_netcdf else ds, target)
        assert not target.is_symlink()
        with xr.open_dataset(target, engine="netcdf4") as back:
            assert np.array_equal(back["strain"].values, ds["strain"].values)
    planted.check()


def test_calibration_cache_temporary_never_follows_a_link(tmp_path, planted, monkeypatch):
    from warp_tensegrity.policy import calibrate
    from warp_tensegrity.sweep.plan import plan_sweep
    from warp_tensegrity.sweep.spec import load_spec

    monkeypatch.setenv("WARP_TENSEGRITY_CACHE", str(tmp_path / "cache"))
    plan = plan_sweep(load_spec(SPEC), tmp_path / "o.nc")
    key, _ = calibrate._key(plan.spec.scene, plan.params, plan.run, plan.shard_size)
    entry = calibrate.cache_dir() / f"{key}.json"
    entry.parent.mkdir(parents=True)
    planted(entry)
    cal = calibrate.probe(plan.spec.scene, plan.params, plan.run, plan.shard_size, use_cache=False)
    assert json.loads(entry.read_text(encoding="utf-8"))["key"] == cal["key"] and not entry.is_symlink()
    planted.check()


def test_lock_planted_as_a_link_is_refused_and_its_target_untouched(tmp_path, capsys):
    """The lock opened without O_NOFOLLOW: a link at .OUT.nc.lock made the run create (and lock)
    the file it points to."""
    out = tmp_path / "o.nc"
    lock = zmanifest.lock_path_for(out)
    for victim in (tmp_path / "victim-absent", tmp_path / "victim-present"):
        if victim.name.endswith("present"):
            victim.write_bytes(VICTIM)
        lock.unlink(missing_ok=True)
        lock.symlink_to(victim)
        with pytest.raises(zmanifest.StoreError, match="symbolic link"):
            with zmanifest.SweepLock(out):
                pass
        assert _cli("run", _spec(tmp_path), "-o", out) == 1
        err = capsys.readouterr().err
        assert len(_error_lines(err)) == 1 and "is a symbolic link" in err and str(lock) in err, err
        assert "Traceback" not in err and not out.exists()
        assert victim.read_bytes() == VICTIM if victim.name.endswith("present") else not victim.exists()
        assert lock.is_symlink()


def test_cli_run_and_resume_with_links_at_every_temporary_name(tmp_path, planted, monkeypatch):
    """End to end: links at the output's temporaries before the run, and at the store's and the
    output's once a resume has cleaned the leftovers (its manifest and export are rewritten);
    every victim untouched, every output a file, the results complete."""
    out = tmp_path / "o.nc"
    planted(out)
    assert _cli("run", _spec(tmp_path), "-o", out) == 0
    store = zstore.SweepStore(out)
    clean = zstore.SweepStore.clean_tmp

    def clean_then_plant(self):
        clean(self)
        for path in (store.manifest_path, store.dir / "spec.toml", out):
            planted(path)

    monkeypatch.setattr(zstore.SweepStore, "clean_tmp", clean_then_plant)
    (store.zarr / "strain" / "c" / "1" / "0" / "0").write_bytes(b"garbage")  # shard 1 corrupt: recomputed
    assert _cli("resume", out) == 0
    planted.check()
    for path in (out, store.manifest_path, store.dir / "spec.toml"):
        assert path.is_file() and not path.is_symlink(), path
    assert zmanifest.Manifest.read(store.manifest_path)[0] is not None
    assert xr.open_dataset(out, engine="netcdf4")["strain"].notnull().all()


# ====================================================================== a full disk (issue 30 item 4)
def _no_space(path="") -> OSError:
    return OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), path or None)


def test_up_front_check_counts_the_store_and_the_netcdf(tmp_path):
    """The check counted one uncompressed output while a run keeps the store and the .nc (issue: 387 kB
    counted, 1.22 MB needed): a disk with twice the uncompressed output free is refused, with the figure."""
    from warp_tensegrity.policy.calibrate import estimate_plan
    from warp_tensegrity.sweep import budget
    from warp_tensegrity.sweep.plan import plan_sweep
    from warp_tensegrity.sweep.spec import load_spec

    plan = plan_sweep(load_spec(SPEC), tmp_path / "o.nc")
    cost = estimate_plan(plan)
    found = budget.problems(plan, cost, disk_bytes=2 * cost["output_bytes"], time_limit=1e9,
                            device_bytes=2**40, host_bytes=2**40)
    assert len(found) == 1 and "of disk" in found[0] and "o.nc.sweep/" in found[0], found
    assert cost["disk_bytes"] == cost["store_bytes"] + cost["netcdf_bytes"] > 2 * cost["output_bytes"]
    assert budget.problems(plan, cost, disk_bytes=cost["disk_bytes"], time_limit=1e9, device_bytes=2**40,
                           host_bytes=2**40) == []


def _disk_usage(*paths: Path) -> int:
    """Bytes the files and directories under ``paths`` take on disk (their blocks)."""
    total = 0
    for p in paths:
        for q in [p, *p.rglob("*")] if p.is_dir() else [p]:
            total += q.lstat().st_blocks * 512
    return total


@pytest.mark.parametrize("shard_size, record", [(1, "small"), (3, "large")])
def test_disk_estimate_bounds_the_store_and_the_netcdf(tmp_path, shard_size, record):
    """The estimate (store + export, uncompressed, with each file's and directory's blocks) is at
    least what the run takes on this disk, and not far above it: for a small record, where the
    files' blocks dominate, and a larger one (~150 kB of strain), where the data do."""
    from warp_tensegrity.policy.calibrate import estimate_plan
    from warp_tensegrity.sweep.plan import plan_sweep
    from warp_tensegrity.sweep.spec import load_spec

    text = SPEC.replace("t_end = 0.02", "t_end = 0.2").replace("shard_size = 1", f"shard_size = {shard_size}")
    if record == "large":
        text = text.replace("n_prisms = 3", "n_prisms = 12").replace("t_end = 0.2", "t_end = 0.1").replace(
            "output_interval = 0.005", "output_interval = 0.0002")
    out = tmp_path / "o.nc"
    cost = estimate_plan(plan_sweep(load_spec(text), out))
    assert _cli("run", _spec(tmp_path, text), "-o", out) == 0
    used = _disk_usage(zstore.SweepStore(out).dir, out)
    assert used <= cost["disk_bytes"] <= 3 * used, (used, cost["disk_bytes"], cost["output_bytes"])
    assert _disk_usage(out) <= cost["netcdf_bytes"]


def test_full_disk_while_a_shard_is_written_is_one_line_and_resumes(tmp_path, monkeypatch, capsys):
    """zarr's OSError [Errno 28] was a traceback; now one line (path, errno, the space the rest of
    the run needs, what is free), and resume completes once there is space."""
    import zarr.storage._local as local

    real, calls = local._put, []

    def put(path, value, exclusive=False):
        if "/strain/c/" in str(path):
            calls.append(path)
            if len(calls) > 1:
                raise _no_space()  # the second shard's strain chunk: the disk is full
        return real(path, value, exclusive)

    monkeypatch.setattr(local, "_put", put)
    out = tmp_path / "o.nc"
    assert _cli("run", _spec(tmp_path), "-o", out, "--ignore-estimate") == 1
    err = capsys.readouterr().err
    lines = _error_lines(err)
    assert len(lines) == 1 and "Traceback" not in err, err
    assert "No space left on device [Errno 28 ENOSPC]" in lines[0] and "o.nc.sweep" in lines[0], lines
    assert "the rest of the run needs up to" in lines[0] and "is free on" in lines[0], lines
    assert f"resume {out}" in lines[0] and not out.exists()
    monkeypatch.setattr(local, "_put", real)
    assert _cli("resume", out) == 0
    assert xr.open_dataset(out, engine="netcdf4")["strain"].notnull().all()


@pytest.fixture(scope="module")
def finished_run(tmp_path_factory) -> Path:
    """A finished run's output (its store beside it), made once: tests copy it."""
    d = tmp_path_factory.mktemp("finished")
    assert _cli("run", _spec(d), "-o", d / "o.nc") == 0
    return d / "o.nc"


@pytest.mark.parametrize("said", ["hdf", "eacces", "enospc"])
def test_full_disk_during_the_export_is_one_line_and_the_old_output_kept(tmp_path, monkeypatch, capsys, said,
                                                                          finished_run):
    """netCDF-C reports a full disk as 'NetCDF: HDF error' (combine) or a PermissionError (the export):
    told by the free space, it is ENOSPC with the space the file needs; the previous OUT.nc is kept,
    no temporary is left, and `combine` works once there is space."""
    from xarray.backends import netCDF4_

    out = tmp_path / "o.nc"
    shutil.copy2(finished_run, out)
    shutil.copytree(zstore.SweepStore(finished_run).dir, zstore.SweepStore(out).dir)
    before = out.read_bytes()
    real_close = netCDF4_.NetCDF4DataStore.close
    error = {"hdf": RuntimeError("NetCDF: HDF error"), "eacces": PermissionError(errno.EACCES, "Permission denied"),
             "enospc": _no_space()}[said]

    def close(self, **kw):
        real_close(self, **kw)
        raise error

    monkeypatch.setattr(netCDF4_.NetCDF4DataStore, "close", close)
    monkeypatch.setattr(shutil, "disk_usage", lambda p: shutil._ntuple_diskusage(10**9, 10**9 - 4096, 4096))
    assert _cli("combine", out) == 1
    err = capsys.readouterr().err
    lines = _error_lines(err)
    assert len(lines) == 1 and "Traceback" not in err, err
    assert f"cannot write {out}: No space left on device" in lines[0] and "[Errno 28 ENOSPC]" in lines[0], lines
    assert "o.nc needs up to" in lines[0] and "is free on" in lines[0] and f"combine {out}" in lines[0], lines
    assert out.read_bytes() == before and not list(tmp_path.glob(".o.nc.*"))
    # plenty of room: the error is what it is, with the path and its errno
    monkeypatch.setattr(shutil, "disk_usage", lambda p: shutil._ntuple_diskusage(10**12, 0, 10**12))
    assert _cli("combine", out) == 1
    line = _error_lines(capsys.readouterr().err)[0]
    if said == "eacces":
        assert f"cannot write {out}: Permission denied [Errno 13 EACCES]" in line, line
    elif said == "hdf":
        assert f"cannot write {out}: NetCDF: HDF error" in line, line
    monkeypatch.undo()
    assert _cli("combine", out) == 0


def _can_mount_tmpfs() -> bool:
    if not shutil.which("unshare"):
        return False
    r = subprocess.run(["unshare", "-Urm", "sh", "-c", "mount -t tmpfs -o size=64k tmpfs /mnt"],
                       capture_output=True, timeout=30)
    return r.returncode == 0


@pytest.mark.slow  # five CLI subprocesses in a user namespace (~30 s)
@pytest.mark.skipif(sys.platform != "linux", reason="user namespaces: Linux")
def test_a_real_small_filesystem(tmp_path):
    """A tmpfs of a few hundred kB (mounted in a user namespace): a run the old check let through
    (it counted 258 kB) is refused up front with the disk figure; with --ignore-estimate, a full disk
    at the export and at the store are one line each; the tmpfs grown, resume completes."""
    if not _can_mount_tmpfs():
        pytest.skip("this kernel does not let a user mount a tmpfs (unshare -Urm)")
    spec = REPO / "sweeps" / "ci_small.toml"  # its store takes 732 KiB of a tmpfs, its export 344 kB: 800k holds
    mnt = tmp_path / "small"                    # the store, not both
    mnt.mkdir()
    out = mnt / "a.nc"
    wt = f"{sys.executable} -m warp_tensegrity"
    log = tmp_path / "log"
    script = f"""
    mount -t tmpfs -o size=800k tmpfs {mnt} || exit 99
    {wt} run {spec} -o {out} --no-progress 2> {log}.checked; echo $? > {log}.checked.rc
    {wt} run {spec} -o {out} --no-progress --ignore-estimate 2> {log}.export; echo $? > {log}.export.rc
    rm -rf {out}.sweep; mount -o remount,size=300k tmpfs {mnt} || exit 98
    {wt} run {spec} -o {out} --no-progress --ignore-estimate 2> {log}.store; echo $? > {log}.store.rc
    mount -o remount,size=4m tmpfs {mnt} || exit 97
    {wt} resume {out} --no-progress 2> {log}.resume; echo $? > {log}.resume.rc
    {wt} status {out} > {log}.status 2>&1
    """
    r = subprocess.run(["unshare", "-Urm", "bash", "-c", script], capture_output=True, text=True, timeout=900,
                       env=_env(WARP_TENSEGRITY_CACHE=str(tmp_path / "cache")))
    assert r.returncode == 0, r.stderr
    step = {k: (int(Path(f"{log}.{k}.rc").read_text()), Path(f"{log}.{k}").read_text())
            for k in ("checked", "export", "store", "resume")}
    for k, (rc, err) in step.items():
        assert "Traceback" not in err and rc == (0 if k == "resume" else 1), (k, rc, err[-3000:])
        assert len(_error_lines(err)) == (0 if k == "resume" else 1), (k, err)
    assert "of disk" in step["checked"][1] and "is free on" in step["checked"][1], step["checked"]
    assert f"cannot write {out}: No space left on device" in step["export"][1], step["export"]
    assert "[Errno 28 ENOSPC]" in step["store"][1] and "the rest of the run needs up to" in step["store"][1]
    assert "remaining:  0 cases" in Path(f"{log}.status").read_text()


# ====================================================================== calibration cache (issue 30 item 5)
@pytest.mark.parametrize("dry_run", [True, False])
def test_unwritable_calibration_cache_is_one_warning_and_the_run_goes_on(tmp_path, monkeypatch, capsys, dry_run):
    blocker = tmp_path / "not-a-dir"
    blocker.write_text("", encoding="utf-8")  # the cache under a regular file: unwritable, even for root
    monkeypatch.setenv("WARP_TENSEGRITY_CACHE", str(blocker))
    out = tmp_path / "o.nc"
    assert _cli("run", _spec(tmp_path), "-o", out, *(["--dry-run"] if dry_run else [])) == 0
    err = capsys.readouterr().err
    warned = [line for line in err.splitlines() if "calibration cache" in line]
    assert len(warned) == 1 and "Traceback" not in err, err
    assert f"{blocker}/calibration" in warned[0] and "[Errno 20 ENOTDIR]" in warned[0], warned
    assert out.exists() != dry_run


# ====================================================================== a non-UTF-8 interpreter (issue 30 item 9)
@pytest.mark.slow  # four CLI subprocesses (~15 s)
def test_non_ascii_title_under_a_c_locale(tmp_path):
    """`LC_ALL=C PYTHONUTF8=0` (as on Windows): the spec copy and the export wrote with the locale's
    codec (UnicodeEncodeError); every file is UTF-8 now, whatever the locale."""
    title = "Säule ε — Prüfung"
    spec = _spec(tmp_path, SPEC.replace('title = "faults"', f'title = "{title}"'))
    out = tmp_path / "o.nc"
    env = _env(LC_ALL="C", LANG="C", PYTHONUTF8="0", PYTHONCOERCECLOCALE="0")
    env.pop("PYTHONIOENCODING", None)
    probe = subprocess.run([sys.executable, "-c", "import locale; print(locale.getpreferredencoding())"],
                           env=env, capture_output=True, text=True)
    assert "utf" not in probe.stdout.lower(), probe.stdout  # the test means a non-UTF-8 locale
    for args in (["run", spec, "-o", out, "--no-progress"], ["status", out], ["resume", out, "--no-progress"],
                 ["combine", out]):
        r = subprocess.run([sys.executable, "-m", "warp_tensegrity", *map(str, args)], env=env, capture_output=True)
        assert r.returncode == 0 and b"Traceback" not in r.stderr, (args, r.stderr.decode(errors="replace")[-3000:])
    assert (zstore.SweepStore(out).dir / "spec.toml").read_bytes() == spec.read_bytes()
    with xr.open_dataset(out, engine="netcdf4") as ds:
        assert ds.attrs["title"] == title


# ====================================================================== the spec read, bounded (issue 30 item 10)
def _run_bounded(args, timeout=120):
    """The CLI in a subprocess with 4 GB of data and a timeout: before the fix, /dev/zero was read
    without limit and a FIFO blocked forever."""
    def limit():
        resource.setrlimit(resource.RLIMIT_DATA, (2**32, 2**32))

    return subprocess.run([sys.executable, "-m", "warp_tensegrity", *map(str, args)], env=_env(),
                          capture_output=True, text=True, timeout=timeout, preexec_fn=limit)


@pytest.mark.parametrize("kind", ["fifo", "dev-zero", "directory", "huge"])
def test_spec_that_is_not_a_regular_file_or_too_large_is_refused_at_once(tmp_path, kind, capsys):
    from warp_tensegrity.tomlread import MAX_BYTES, TomlError, read_file

    path = {"fifo": tmp_path / "spec.fifo", "dev-zero": Path("/dev/zero"), "directory": tmp_path,
            "huge": tmp_path / "huge.toml"}[kind]
    if kind == "fifo":
        os.mkfifo(path)
    if kind == "huge":
        with open(path, "wb") as f:
            f.write(SPEC.encode())
            f.truncate(MAX_BYTES + 1)  # sparse: a valid spec, then zeros
    with pytest.raises(TomlError, match="not a spec file|larger than a spec"):
        read_file(path)
    want = {"fifo": "a FIFO (named pipe), not a spec file", "dev-zero": "a character device, not a spec file",
            "directory": "a directory, not a spec file", "huge": "larger than a spec may be (8 MiB)"}[kind]
    for command in ("run", "lens") if kind == "fifo" else ("run",):  # the lens reads its spec the same way
        args = [command, path, "-o", tmp_path / "o.nc", "--dry-run"]
        if kind in ("fifo", "dev-zero"):  # a subprocess: a regression would block, or fill the memory
            try:
                r = _run_bounded(args)
            except subprocess.TimeoutExpired:
                pytest.fail(f"{command} {path} did not return")
            rc, err = r.returncode, r.stderr
        else:
            rc, err = _cli(*args), capsys.readouterr().err
        assert rc == 1 and "Traceback" not in err, err[-3000:]
        assert len(_error_lines(err)) == 1 and str(path) in err and want in err, err


# ---------------------------------------------------------------------- a signal during the last write
def test_a_signal_during_the_last_write_lets_it_finish_before_the_lock_goes():
    """SIGTERM or Ctrl-C while the writer thread writes the last shard: ShardWriter.close lets that
    shard be written and marked before the signal's exception reaches the caller, whose ``with``
    then releases the store's lock (issue 30: the lock went while the write went on)."""
    import signal
    import threading
    import time
    from types import SimpleNamespace

    from warp_tensegrity.sweep.store import ShardWriter

    events = []

    class SlowStore:
        manifest = SimpleNamespace(mark_done=lambda i, rec: events.append(("marked", i)))

        def write_shard(self, plan, i, ds, t):
            time.sleep(0.4)
            events.append(("written", i))
            return {}

    def interrupt(*_):
        events.append(("signal", None))
        raise KeyboardInterrupt

    assert threading.current_thread() is threading.main_thread()
    w = ShardWriter(SlowStore(), None, None)
    w.acquire()
    w.submit(0, xr.Dataset())
    previous = signal.signal(signal.SIGALRM, interrupt)
    try:
        signal.setitimer(signal.ITIMER_REAL, 0.1)  # arrives while shard 0 is being written
        with pytest.raises(KeyboardInterrupt):
            w.close()
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)
    assert events == [("signal", None), ("written", 0), ("marked", 0)], events
    assert not w.thread.is_alive()
