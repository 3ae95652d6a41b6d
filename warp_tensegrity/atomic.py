"""Every file the package writes: created exclusively and never through a link, replaced atomically,
text as UTF-8; and an :class:`OSError` told in one line (path, reason, errno).

A temporary gets a unique name beside its target and is created with ``O_CREAT | O_EXCL |
O_NOFOLLOW`` (:func:`tempfile.mkstemp`), so a file or link planted at a guessable name is never
opened. A library that opens its file by name (netCDF-C, matplotlib) writes into a fresh private
directory beside the target instead (:func:`tempfile.mkdtemp`, mode 0700), where no one else can
plant anything. Then fsync, :func:`os.replace` (which replaces a link at the target, never the file
it points to) and an fsync of the directory.

A leaf of the import graph: nothing of the package.
"""

from __future__ import annotations

import contextlib
import errno
import os
import shutil
import tempfile
from pathlib import Path

TMP_SUFFIX = ".tmp"
"""Temporaries of ``DIR/NAME`` are ``DIR/.NAME.<random>.tmp`` (files, or private directories)."""


def _umask() -> int:
    """The process's umask, read without changing it where Linux tells it (/proc), else set and restored."""
    try:
        with open("/proc/self/status", encoding="ascii") as f:
            for line in f:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError):  # pragma: no cover - not Linux
        pass
    mask = os.umask(0o022)  # pragma: no cover
    os.umask(mask)  # pragma: no cover
    return mask  # pragma: no cover


FILE_MODE = 0o666 & ~_umask()
"""Mode of a replaced file: what ``open(path, "w")`` would have given it (mkstemp creates 0600)."""


def tmp_glob(path) -> str:
    """The glob of ``path``'s temporaries in its directory."""
    return f".{Path(path).name}.*{TMP_SUFFIX}"


def fsync_path(path) -> None:
    """fsync a file or directory by name."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def write_bytes(path, data: bytes, fsync: bool = True) -> Path:
    """Replace ``path`` with ``data`` atomically: an exclusive temporary beside it, fsync,
    os.replace, fsync of the directory (``fsync`` False: no fsyncs, for a cache)."""
    path = Path(path)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=TMP_SUFFIX)
    try:
        with os.fdopen(fd, "wb") as f:
            os.fchmod(f.fileno(), FILE_MODE)
            f.write(data)
            f.flush()
            if fsync:
                os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise
    if fsync:
        fsync_path(path.parent)
    return path


def write_text(path, text: str, fsync: bool = True) -> Path:
    """:func:`write_bytes` of ``text`` encoded as UTF-8, whatever the locale."""
    return write_bytes(path, text.encode("utf-8"), fsync)


def create_text(path, text: str) -> Path:
    """Write ``text`` (UTF-8) to ``path``, which must not exist: ``O_EXCL | O_NOFOLLOW`` refuse a
    file or link already there (FileExistsError) instead of writing through it."""
    path = Path(path)
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0), 0o666)
    with os.fdopen(fd, "wb") as f:
        f.write(text.encode("utf-8"))
    return path


@contextlib.contextmanager
def replacing(path, fsync: bool = True):
    """For a library that writes by name: yields ``PRIVATE/NAME``, a path in a new private directory
    beside ``path`` (same file system, same extension). When the block ends without an exception the
    file is fsync'd and moved onto ``path``; the directory is removed in every case."""
    path = Path(path)
    try:
        d = Path(tempfile.mkdtemp(dir=path.parent, prefix=f".{path.name}.", suffix=TMP_SUFFIX))
    except OSError as e:  # name the file the user asked for, not our temporary's random name
        raise type(e)(e.errno, e.strerror, str(path)) from None
    try:
        tmp = d / path.name
        yield tmp
        if fsync:
            fsync_path(tmp)
        os.replace(tmp, path)
        if fsync:
            fsync_path(path.parent)
    finally:
        shutil.rmtree(d, ignore_errors=True)


def remove_tmp(path) -> None:
    """Remove one leftover temporary (a file, link or private directory) without following a link."""
    p = Path(path)
    if p.is_dir() and not p.is_symlink():
        shutil.rmtree(p, ignore_errors=True)
    else:
        p.unlink(missing_ok=True)


def errno_text(e: OSError) -> str:
    """'No space left on device [Errno 28 ENOSPC]': the reason and the errno, number and name."""
    code = e.errno
    reason = e.strerror or str(e) or type(e).__name__
    return f"{reason} [Errno {code} {errno.errorcode.get(code, '?')}]" if code else reason


def oserror_line(e: OSError, path=None, doing: str = "cannot write") -> str:
    """One line for an OSError: 'cannot write PATH: No space left on device [Errno 28 ENOSPC]'.
    ``path``: the file the user knows (default: the error's own)."""
    where = path if path is not None else (e.filename or "")
    return f"{doing} {where}: {errno_text(e)}" if where else f"{doing}: {errno_text(e)}"


def is_no_space(e: BaseException) -> bool:
    """Whether ``e`` is a full disk or an exceeded quota."""
    return isinstance(e, OSError) and e.errno in (errno.ENOSPC, getattr(errno, "EDQUOT", errno.ENOSPC))


def free_bytes(path) -> tuple[int, Path]:
    """(bytes free to this user, the directory asked) on the file system that holds ``path`` (the
    nearest existing directory above it)."""
    d = Path(path).absolute()
    while not d.is_dir() and d != d.parent:
        d = d.parent
    return shutil.disk_usage(d).free, d
