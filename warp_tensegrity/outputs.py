"""An output file's checks before anything is computed (``run``, ``resume``, ``lens``): not a
directory or a special file, not an existing file unless it may be replaced, and a directory that
takes a file; and an OSError in one line (what failed, the errno's name, the path)."""

from __future__ import annotations

import os
import stat
import tempfile
from pathlib import Path

from .atomic import errno_text


class OutputError(ValueError):
    """An output that cannot be written as asked; the message names the path and what to do."""


def oserror_text(e: OSError) -> str:
    """One line: the error, its errno and the path(s), e.g.
    ``Permission denied [Errno 13 EACCES]: /data/fig.png`` (:func:`.atomic.errno_text`)."""
    paths = " -> ".join(str(f) for f in (e.filename, e.filename2) if f is not None)
    return f"{errno_text(e)}{': ' + paths if paths else ''}"


def check_output_file(out, *, exists_ok: bool = False) -> None:
    """Refuse (:class:`OutputError`) an output that is a directory or not a regular file, one that
    exists unless ``exists_ok`` (--overwrite), and one whose directory cannot take a file (the
    directory is made if missing; a file is created in it and dropped)."""
    out = Path(out)
    try:
        mode = os.stat(out).st_mode
    except FileNotFoundError:
        mode = None
    except OSError as e:  # ENOTDIR (a file where a directory should be), EACCES, ELOOP
        raise OutputError(f"cannot use the output {out}: {oserror_text(e)}") from None
    if mode is not None and not stat.S_ISREG(mode):
        if stat.S_ISDIR(mode):
            raise OutputError(f"the output {out} is a directory; give a file name, e.g. -o {out / 'out.nc'}")
        raise OutputError(f"the output {out} is not a regular file; give a file name")
    if mode is not None and not exists_ok:
        raise OutputError(f"{out} exists; give another output, or replace it with --overwrite")
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=out.parent):  # O_TMPFILE where there is one: no name appears
            pass
    except OSError as e:
        raise OutputError(f"cannot write the output {out}: {oserror_text(e)}") from None
