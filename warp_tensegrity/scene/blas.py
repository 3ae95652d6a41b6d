"""One BLAS thread for the host's small dense linear algebra (:func:`one_blas_thread`).

The scene build and the base-mode analysis solve many small problems (300 x 300 eigensolves,
450 x 150 least squares). OpenBLAS splits each over all its threads by default, which costs more
than it gains at that size, and collapses when two threads call it at once or the cores are
shared: phase_large's base-mode analysis took 1.9 s with one thread and 55.7 s with two on a loaded
2-core host (issue 33). The column build (:func:`~warp_tensegrity.scene.batch.column_batch`) always
takes it: its outputs are bit-identical under one thread (the reference outputs, made with two). An
eigensolve's last bits can follow the thread count (base_mode_ratio of paper_2017 by one ulp), so
the base-mode analysis takes it only on a GPU run (:mod:`warp_tensegrity.sweep.shard`); on the CPU
device it keeps the host's default. threadpoolctl is the maintained way to set it at run time; the limit is process-wide, so it is
taken once by the first caller and given back by the last (callers may nest).
"""

from __future__ import annotations

import contextlib
import threading

_lock = threading.Lock()
_users = 0
_limiter = None


@contextlib.contextmanager
def one_blas_thread():
    """Run the block with the BLAS limited to one thread (re-entrant, across threads too)."""
    global _users, _limiter
    with _lock:
        if _users == 0:
            try:
                from threadpoolctl import threadpool_limits  # scans the loaded libraries: ~1 ms
            except ImportError:  # a dependency, but an environment put together by hand may lack it: only slower
                _limiter = None
            else:
                _limiter = threadpool_limits(limits=1, user_api="blas")
        _users += 1
    try:
        yield
    finally:
        with _lock:
            _users -= 1
            if _users == 0 and _limiter is not None:
                _limiter.restore_original_limits()
                _limiter = None


def single_blas_thread(fn):
    """Decorator: ``fn`` runs under :func:`one_blas_thread`."""
    import functools

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        with one_blas_thread():
            return fn(*args, **kwargs)

    return wrapper
