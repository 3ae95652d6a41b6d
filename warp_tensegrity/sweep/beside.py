"""Host work in a process beside the run: a GPU sweep's base-mode analysis while its shard steps.

The analysis (:func:`warp_tensegrity.scene.base_modes.base_mode_ratios`, ~3 s for phase_large's 96
distinct pairs on one core) reads the parameters only, so it can run while the device steps. Not in
a thread: the host loop that feeds the device gives up the GIL at every launch and waits up to the
switch interval to get it back, which left 26 s of phase_large waiting on an H200 (issue 33). Turn by
turn between the launches (:class:`warp_tensegrity.engine.HostWork`) it shares no GIL but holds the
loop: the device idled while each pair was solved (2.9 s of phase_large's 23.2 s on an H200,
benchmarks/results/issue33_h200_third). A process shares neither.

:mod:`concurrent.futures` runs it: one worker, started with ``spawn`` (a fresh interpreter: the
run's CUDA context is not forked), kept for the life of the process, so a sweep's shards reuse it
(and the analysis's cache of modes). Where no process can be started (a daemonic Dask worker, a
host out of processes) or the worker dies, :func:`submit` and :func:`result` say so once and the
caller computes in its own process.
"""

from __future__ import annotations

import concurrent.futures as cf
import logging
import multiprocessing as mp

__all__ = ["result", "submit"]

_pool: cf.ProcessPoolExecutor | None = None
_refused: str | None = None  # why no worker can be started here (said once)


def _say_once(why: str) -> None:
    global _refused
    if _refused is None:
        logging.getLogger(__name__).info("host work runs in this process: %s", why)
    _refused = why


def submit(fn, *args) -> cf.Future | None:
    """``fn(*args)`` in the worker process (``fn`` and its arguments picklable), or None where no
    worker can run it (the caller computes it itself)."""
    global _pool
    if _refused is not None:
        return None
    if mp.current_process().daemon:  # multiprocessing refuses children to a daemonic process
        _say_once("this is a daemonic process (a Dask worker?), which may not start processes")
        return None
    try:
        if _pool is None:
            _pool = cf.ProcessPoolExecutor(1, mp_context=mp.get_context("spawn"))
        return _pool.submit(fn, *args)
    except (OSError, RuntimeError) as e:  # out of processes or file descriptors; a pool shut down
        _pool = None
        _say_once(f"no worker process ({type(e).__name__}: {e})")
        return None


def result(future: cf.Future, fallback):
    """The worker's value of ``future``; ``fallback()`` (the same work in this process) if the worker
    died before giving it. An exception ``fn`` raised is raised here."""
    global _pool
    try:
        return future.result()
    except cf.process.BrokenProcessPool as e:
        _pool = None
        _say_once(f"the worker process died ({e})")
        return fallback()
