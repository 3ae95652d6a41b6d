"""The sweep store's durable bookkeeping: file names and paths, atomic writes, the output's lock,
array checksums and the manifest that records the done shards (with its own sha256); and the
fault hook the crash tests arm. :mod:`.store` writes the Zarr store on top of it.

Nothing here imports xarray, Zarr or Warp.
"""

from __future__ import annotations

import errno
import hashlib
import json
import os
import signal
import stat
import threading
import time as _time
from pathlib import Path

import numpy as np

from ..atomic import fsync_path as _fsync_path
from ..atomic import oserror_line, write_text
from .errors import SweepError

STORE = "store.zarr"
MANIFEST = "manifest.json"
SPEC_COPY = "spec.toml"
FORMAT = "warp_tensegrity-store-1"

# the fault hook's environment and the points the code passes it
FAULT_ENV = "WARP_TENSEGRITY_FAULT"
FAULT_FILE_ENV = "WARP_TENSEGRITY_FAULT_FILE"
FAULT_POINTS = ("stepping", "write-begin", "mid-write", "before-mark", "after-mark", "finalise", "mid-export",
                "before-replace")


class StoreError(SweepError):
    """The store cannot be used as asked; the message says what to do."""


# ---------------------------------------------------------------------- fault hook (tests)
_fault_hits: dict = {}


def fault(point: str) -> None:
    """Test hook: with ``WARP_TENSEGRITY_FAULT=POINT[@HIT][:ACTION]`` the HIT-th (default 1st)
    arrival at POINT kills this process with SIGKILL (ACTION ``kill``), or touches
    ``$WARP_TENSEGRITY_FAULT_FILE`` and waits to be killed (``pause``) or goes on (``mark``:
    the test then kills after a random delay). Unset: does nothing."""
    spec = os.environ.get(FAULT_ENV)
    if not spec:
        return
    name, _, action = spec.partition(":")
    name, _, hit = name.partition("@")
    if name != point:
        return
    _fault_hits[point] = _fault_hits.get(point, 0) + 1
    if _fault_hits[point] != int(hit or 1):
        return
    action = action or "kill"
    marker = os.environ.get(FAULT_FILE_ENV)
    if marker and action in ("pause", "mark"):
        Path(marker).write_text(point, encoding="utf-8")
    if action == "kill":
        os.kill(os.getpid(), signal.SIGKILL)
    elif action == "pause":
        while True:
            _time.sleep(1.0)


# ---------------------------------------------------------------------- paths
def work_dir_for(out) -> Path:
    out = Path(out)
    return out.with_name(out.name + ".sweep")


def lock_path_for(out) -> Path:
    out = Path(out)
    return out.with_name(f".{out.name}.lock")


def shard_dir_for(out) -> Path:
    """The run's work directory (store, manifest, spec copy)."""
    return work_dir_for(out)


def _atomic_write_text(path: Path, text: str) -> None:
    """UTF-8 text written atomically (:func:`warp_tensegrity.atomic.write_text`: an exclusive
    temporary beside it, never opened through a link; fsync, os.replace, fsync of the directory)."""
    write_text(path, text)


# ---------------------------------------------------------------------- locking
class SweepLock:
    """An exclusive lock on an output: a second run into the same output fails at once. The lock
    file ``.OUT.nc.lock`` exists only while a run holds it (removed when the run ends; a killed
    run leaves it, unlocked, and the next run takes it over).

    POSIX: ``flock`` on the lock file, which the holder unlinks before it lets go; a run that
    locked a file just unlinked sees that its file is no longer the one at the path and tries
    again, so two runs never hold two different files. Elsewhere: filelock, file kept."""

    def __init__(self, out):
        self.out = Path(out)
        self.path = lock_path_for(out)
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            raise StoreError(f"cannot write the output {self.out}: {oserror_line(e, self.path.parent, 'directory')}") from None
        self._fd: int | None = None
        self._lock = None

    def _held(self) -> StoreError:
        return StoreError(f"{self.out} is being written by another run (lock {self.path} is held); wait for that "
                          f"run to finish, or give another output")

    def __enter__(self):
        try:
            import fcntl
        except ImportError:  # pragma: no cover - not POSIX
            return self._enter_filelock()
        for _ in range(100):
            try:
                # never through a link planted at the lock's name (O_NOFOLLOW): it is refused
                fd = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC | getattr(os, "O_NOFOLLOW", 0), 0o644)
            except OSError as e:
                if e.errno == errno.ELOOP or self.path.is_symlink():
                    raise self._not_a_lock("a symbolic link") from None
                raise StoreError(f"cannot write the output {self.out}: {oserror_line(e, self.path, 'lock')}") from None
            if not stat.S_ISREG(os.fstat(fd).st_mode):
                os.close(fd)
                raise self._not_a_lock("not a regular file")
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError:
                os.close(fd)
                raise self._held() from None
            try:
                same = os.fstat(fd).st_ino == os.stat(self.path).st_ino
            except FileNotFoundError:
                same = False
            if same:
                self._fd = fd
                return self
            os.close(fd)  # locked a file its holder had just removed: take the new one
        raise self._held()  # pragma: no cover

    def _not_a_lock(self, what: str) -> StoreError:
        return StoreError(f"the lock {self.path} is {what}, not a lock file a run made; nothing was written "
                          "through it: remove it and run again")

    def _enter_filelock(self):  # pragma: no cover - not POSIX
        from filelock import FileLock, Timeout

        self._lock = FileLock(str(self.path), timeout=0)
        try:
            self._lock.acquire()
        except Timeout:
            raise self._held() from None
        except OSError as e:
            raise StoreError(f"cannot write the output {self.out}: {oserror_line(e, self.path, 'lock')}") from None
        return self

    def __exit__(self, *exc):
        if self._fd is not None:
            try:
                self.path.unlink(missing_ok=True)  # while still locked: see the class docstring
            finally:
                os.close(self._fd)
                self._fd = None
        elif self._lock is not None:  # pragma: no cover
            self._lock.release()
        return False


# ---------------------------------------------------------------------- checksums
def _canonical(a: np.ndarray) -> np.ndarray:
    """NaN payloads canonicalised (the CF encoding may rewrite them), C order."""
    a = np.ascontiguousarray(a)
    if a.dtype.kind == "f" and np.isnan(a).any():
        a = np.where(np.isnan(a), np.nan, a).astype(a.dtype)
    return a


STRING_KINDS = "OUT"
"""dtype kinds of text: object, fixed-width unicode and NumPy 2's variable-width StringDType ('T').
The same labels come back as any of them (xarray keeps object arrays; Zarr 3 under NumPy 2 reads
StringDType; NumPy 1 reads fixed-width or object), so they are hashed as text, whatever the kind."""


def array_sha256(a) -> str:
    """sha256 of an array's dtype, shape and contents. Text arrays (:data:`STRING_KINDS`) hash as
    their strings under one header, so a label written as object and read back as StringDType (or
    fixed-width unicode) has the same checksum; other arrays hash their canonical bytes."""
    a = np.asarray(a)
    if a.dtype.kind in STRING_KINDS:
        h = hashlib.sha256(f"|O{a.shape}".encode())  # '|O' is the object dtype's str: old manifests still match
        h.update("\x00".join(map(str, a.ravel())).encode())
    else:
        h = hashlib.sha256(f"{a.dtype.str}{a.shape}".encode())
        h.update(_canonical(a).tobytes())
    return h.hexdigest()


def _content_sha(content: dict) -> str:
    return hashlib.sha256(json.dumps(content, sort_keys=True).encode()).hexdigest()


def journal_path(manifest: Path) -> Path:
    """The journal of the shards done since ``manifest`` was last rewritten whole."""
    return Path(manifest).with_suffix(".journal")


def _append_line(path: Path, line: bytes) -> None:
    """Append ``line`` to ``path`` and fsync it (and the directory when the file is new). Never
    through a link (O_NOFOLLOW). A line torn by a crash or a full disk is cut off first, so the new
    one starts a line of its own."""
    flags = os.O_RDWR | os.O_CREAT | os.O_APPEND | os.O_CLOEXEC | getattr(os, "O_NOFOLLOW", 0)
    new = not path.exists()
    fd = os.open(path, flags, 0o644)
    try:
        _cut_torn_tail(fd)
        view = memoryview(line)
        while view:  # a short write near a full disk: the rest, or the error
            view = view[os.write(fd, view):]
        os.fsync(fd)
    finally:
        os.close(fd)
    if new:
        _fsync_path(path.parent)


def _cut_torn_tail(fd: int) -> None:
    """Truncate an open file after its last newline (nothing when it ends with one)."""
    end = os.fstat(fd).st_size
    if not end or os.pread(fd, 1, end - 1) == b"\n":
        return
    while end > 0:
        start = max(end - (1 << 16), 0)
        cut = os.pread(fd, end - start, start).rfind(b"\n")
        if cut >= 0:
            os.ftruncate(fd, start + cut + 1)
            return
        end = start
    os.ftruncate(fd, 0)


def _journal_records(path: Path) -> dict:
    """{shard: record} of the journal's lines that check out (a torn or damaged line is skipped:
    its shard is not done, and is recomputed)."""
    try:
        lines = path.read_bytes().splitlines()
    except OSError:  # none (no shard since the last rewrite), or unreadable: its shards recomputed
        return {}
    out = {}
    for ln in lines:
        try:
            entry = json.loads(ln)
            sha = entry.pop("sha256")
            if _content_sha(entry) == sha:
                out[str(int(entry["shard"]))] = entry["record"]
        except (ValueError, KeyError, TypeError, AttributeError):
            continue
    return out


# ---------------------------------------------------------------------- manifest
class Manifest:
    """The store's header and done-shard records. ``manifest.json`` holds the header and the records
    as of its last whole rewrite (atomic, with its own sha256); each shard done since is one line of
    ``manifest.journal`` beside it (appended and fsync'd, with the line's own sha256), so a shard costs
    one append however many are done. A whole rewrite (:meth:`save`: the store laid out, shards
    dropped, the run's end) folds the journal in and removes it."""

    def __init__(self, path: Path, content: dict, on_error=None):
        self.path = path
        self.content = content
        self._lock = threading.Lock()
        # called with a save's OSError: the rest of its one-line message (the store's: the space needed)
        self.on_error = on_error or (lambda e: "")

    @property
    def shards(self) -> dict:
        return self.content["shards"]

    @property
    def journal(self) -> Path:
        return journal_path(self.path)

    def save(self) -> None:
        """Rewrite manifest.json whole, then remove the journal it now holds."""
        with self._lock:
            # compact: json's C encoder; with indent= it runs the pure-Python one, whose piece list for
            # a manifest of 200 shards (1 MB) grew the resident memory by ~40 kB a shard
            body = json.dumps({**self.content, "sha256": _content_sha(self.content)}, sort_keys=True)
            try:
                _atomic_write_text(self.path, body + "\n")
                # after the rewrite: a crash between leaves the journal beside it, whose records are the
                # same, or a shard a resume dropped, which then fails its checks again and is recomputed
                self.journal.unlink(missing_ok=True)
            except OSError as e:
                raise StoreError(oserror_line(e, self.path) + self.on_error(e)) from None

    def mark_done(self, index: int, record: dict) -> None:
        """Record shard ``index`` as done: one line appended to the journal and fsync'd."""
        entry = {"shard": int(index), "record": record}
        line = json.dumps({**entry, "sha256": _content_sha(entry)}, sort_keys=True) + "\n"
        with self._lock:
            try:
                _append_line(self.journal, line.encode())
            except OSError as e:
                raise StoreError(oserror_line(e, self.journal) + self.on_error(e)) from None
            self.shards[str(index)] = record

    @staticmethod
    def read(path: Path) -> tuple[dict | None, str]:
        """(content, '') or (None, why it cannot be used)."""
        try:
            raw = json.loads(path.read_text(encoding="utf-8"))
        except FileNotFoundError:
            return None, "no manifest"
        except (OSError, ValueError, UnicodeDecodeError) as e:
            return None, f"manifest does not parse ({type(e).__name__}: {e})"
        if not isinstance(raw, dict) or "sha256" not in raw:
            return None, "manifest has no checksum"
        sha = raw.pop("sha256")
        if _content_sha(raw) != sha:
            return None, "manifest checksum does not match its contents"
        if raw.get("format") != FORMAT:
            return None, f"manifest format {raw.get('format')!r}, expected {FORMAT!r}"
        raw.setdefault("shards", {}).update(_journal_records(journal_path(path)))
        return raw, ""
