"""The one entry for every TOML the project reads: sweep specs, lens specs and ``--set`` values.

:func:`read_file` reads a spec file, bounded: a regular file of at most MAX_BYTES (a FIFO, a
device such as ``/dev/zero`` or a directory is refused without a read that could block or never
end). :func:`read_toml` turns any failure of reading (bytes that are not UTF-8, TOML syntax,
integers longer than Python converts, nesting deeper than Python's recursion limit or than any
spec needs) into a :class:`TomlError` whose message names the file or option, so callers raise
their own clean error (``SpecError``, ``LensSpecError``, ``OptionError``) and no input ends in a
traceback.

A leaf of the import graph: nothing of the package, no Warp.
"""

from __future__ import annotations

import os
import stat
import sys
import tomllib

MAX_DEPTH = 16
"""Deepest nesting of tables and arrays accepted. A sweep spec nests at most 4 levels
(``sweep.grid.v0.start``), a lens spec 3 (``design.focal_points[i][j]``); deeper input is refused
before anything walks it recursively (copies, validation, messages)."""


MAX_BYTES = 8 * 2**20
"""Largest spec file read (8 MiB). The largest committed spec is a few kB; a case list of 50,000
cases is about 4 MB (a grid says the same in a line)."""


class TomlError(ValueError):
    """TOML input that cannot be read. ``kind``: 'file', 'encoding', 'syntax', 'integer' or 'depth'
    (``--set`` takes a value that is not TOML syntax as a bare string)."""

    def __init__(self, reason: str, kind: str, where: str | None = None):
        super().__init__(f"{where}: {reason}" if where else reason)
        self.reason, self.kind, self.where = reason, kind, where


def decode(raw: bytes, where: str | None = None) -> str:
    """``raw`` as UTF-8 text, or :class:`TomlError` naming the first bad byte and its line."""
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as e:  # TOML is UTF-8
        line = raw[: e.start].count(b"\n") + 1
        raise TomlError(f"not UTF-8 text (TOML must be): byte {raw[e.start:e.start + 1]!r} at line {line}, "
                        f"byte offset {e.start}", "encoding", where) from None


def _kind(mode: int) -> str:
    for test, name in ((stat.S_ISFIFO, "a FIFO (named pipe)"), (stat.S_ISCHR, "a character device"),
                       (stat.S_ISBLK, "a block device"), (stat.S_ISDIR, "a directory"), (stat.S_ISSOCK, "a socket")):
        if test(mode):
            return name
    return "not a regular file"  # pragma: no cover


def read_file(path, where: str | None = None) -> bytes:
    """The bytes of the spec file ``path``: a regular file (or a link to one) of at most MAX_BYTES;
    :class:`TomlError` (kind 'file') for anything else, found before a read that could block (a
    FIFO) or never end (``/dev/zero``). An OSError of the file system is raised as it comes."""
    where = where or str(path)
    mode = os.stat(path).st_mode
    if stat.S_ISREG(mode):
        # O_NONBLOCK: should the name become a FIFO after the stat, open does not wait for a writer
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
        try:
            mode = os.fstat(fd).st_mode
            if stat.S_ISREG(mode):
                chunks, size = [], 0
                while size <= MAX_BYTES:  # at most one byte past the limit, however large the file
                    chunk = os.read(fd, MAX_BYTES + 1 - size)
                    if not chunk:
                        return b"".join(chunks)
                    chunks.append(chunk)
                    size += len(chunk)
                raise TomlError(f"larger than a spec may be ({MAX_BYTES // 2**20} MiB); a grid says in one line "
                                "what a long case list does", "file", where)
        finally:
            os.close(fd)
    raise TomlError(f"{_kind(mode)}, not a spec file: give a TOML file", "file", where)


def depth(value) -> int:
    """Nesting depth of parsed TOML (a scalar 0, ``[1]`` 1, ``{a = [1]}`` 2), found without recursion."""
    deepest, todo = 0, [(value, 0)]
    while todo:
        v, d = todo.pop()
        if isinstance(v, dict):
            todo.extend((x, d + 1) for x in v.values())
        elif isinstance(v, list):
            todo.extend((x, d + 1) for x in v)
        else:
            deepest = max(deepest, d)
            continue
        deepest = max(deepest, d + 1)
    return deepest


def read_toml(source: str | bytes, where: str | None = None) -> dict:
    """The TOML document ``source`` (text, or bytes that must be UTF-8) as a dict, or
    :class:`TomlError` whose message starts with ``where`` (a file name or ``--set run.t_end``)
    when given; ``TomlError.reason`` is the message without it."""
    text = decode(source, where) if isinstance(source, (bytes, bytearray)) else source
    if not isinstance(text, str):
        raise TomlError(f"TOML must be text, got {type(text).__name__}", "syntax", where)
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise TomlError(f"not valid TOML: {e}", "syntax", where) from None
    except RecursionError:
        raise TomlError(f"tables or arrays nested too deeply to read (a spec nests at most {MAX_DEPTH} levels)",
                        "depth", where) from None
    except ValueError as e:  # int(): a literal longer than Python converts (TOMLDecodeError is caught above)
        limit = sys.get_int_max_str_digits()
        why = f"an integer has more than {limit} digits" if "digits" in str(e) else str(e)
        raise TomlError(f"not valid TOML: {why}; no option takes such a number", "integer", where) from None
    n = depth(data)
    if n > MAX_DEPTH:
        raise TomlError(f"tables or arrays nested {n} levels deep; a spec nests at most {MAX_DEPTH}", "depth", where)
    return data
