"""Warp start-up without noise: one call, :func:`init_warp`, before any kernel runs.

Warp 1.19 has two sources of start-up output. Its Python banner ("Warp 1.19.0 initialized: ...")
obeys ``wp.config.log_level``. The CUDA-driver warning on a machine without a GPU ("Warp CUDA
warning: Could not find or load the NVIDIA CUDA driver ...") is printed by the native library
straight to file descriptor 2 and has no switch. So :func:`init_warp` runs ``wp.init()`` with fd 2
pointed at a temporary file (hand-written: no library offers this for a native library's stderr),
drops the known driver lines, hands any other line to :mod:`logging` as a warning, and logs one
line that the CPU will be used. :func:`warp_facts` gives the device facts every output records;
:func:`drive` runs a stepping generator (a run that yields between its launches) to its end.

Warp's kernel cache (``WARP_CACHE_PATH``, else ``~/.cache/warp``) is created by ``wp.init()``; where
it cannot be (a read-only ``HOME``), a command that compiles kernels stops with one line
(:class:`WarpSetupError`), and one that compiles none (``init_warp(kernels=False)``: ``--version``,
``status``, ``combine``) goes on with a private temporary cache.
"""

from __future__ import annotations

import atexit
import logging
import os
import shutil
import sys
import tempfile

from .options import SettingsError
from .outputs import oserror_text

log = logging.getLogger("warp_tensegrity")

_NO_DRIVER = ("Could not find or load the NVIDIA CUDA driver", "Unable to determine CUDA driver version")
_done = False
_startup: float | None = None


def process_age() -> float:
    """Seconds since this process was created (interpreter start included). Linux: /proc (10 ms
    ticks; psutil's create_time rounds the boot time to whole seconds); elsewhere psutil."""
    try:
        with open("/proc/self/stat") as f:
            start = int(f.read().rsplit(")", 1)[1].split()[19])
        with open("/proc/uptime") as f:
            up = float(f.read().split()[0])
        return up - start / os.sysconf("SC_CLK_TCK")
    except OSError:
        import psutil
        import time

        return time.time() - psutil.Process().create_time()


def startup_seconds() -> float:
    """Seconds this process took from its start until Warp was ready (:func:`init_warp`): the
    interpreter, the package's imports and Warp's initialisation, which every run pays once."""
    init_warp()
    return float(_startup)


class WarpSetupError(RuntimeError):
    """Warp cannot start as asked (its kernel cache cannot be written); the message says what to do."""


def _cache_problem(path) -> OSError | None:
    """Why Warp's kernel cache ``path`` cannot take a file (None: it can): a file is created in it
    and dropped (O_TMPFILE where there is one: no name ever appears)."""
    try:
        with tempfile.TemporaryFile(dir=path):
            return None
    except OSError as e:
        return e


def _cache_error(path, e: OSError) -> WarpSetupError:
    return WarpSetupError(f"Warp's kernel cache {path} cannot be written: {oserror_text(e)}; set WARP_CACHE_PATH "
                          f"to a writable directory (Warp compiles its kernels there)")


def init_warp(verbose: bool = False, kernels: bool = True):
    """Import and initialise Warp once, quietly (``verbose``: keep Warp's own banner). Returns ``warp``.

    ``kernels``: the caller will compile kernels, so Warp's kernel cache must be writable
    (:class:`WarpSetupError` if not); False (no kernels: version, device facts, status) goes on
    with a private temporary cache where the usual one cannot be created. The first call decides."""
    global _done
    import warp as wp  # with the first run, not with the package

    if _done:
        return wp
    if hasattr(wp.config, "log_level"):
        wp.config.log_level = wp.LOG_INFO if verbose else wp.LOG_WARNING
    try:
        _init_quietly(wp)
    except OSError as e:
        cache = wp.config.kernel_cache_dir  # Warp sets it before it creates the directory
        if not (cache and e.filename and str(cache).startswith(str(e.filename))):
            raise  # not the kernel cache
        if kernels:
            raise _cache_error(cache, e) from None
        private = tempfile.mkdtemp(prefix="warp-tensegrity-kernels-")
        atexit.register(shutil.rmtree, private, True)
        log.debug("Warp's kernel cache %s cannot be created (%s): using %s", cache, oserror_text(e), private)
        wp.config.kernel_cache_dir = private
        _init_quietly(wp)
    if kernels:
        problem = _cache_problem(wp.config.kernel_cache_dir)
        if problem is not None:
            raise _cache_error(wp.config.kernel_cache_dir, problem)
    global _startup
    _done, _startup = True, process_age()
    if not wp.is_cuda_available():
        log.info("no CUDA device: Warp runs on the CPU")
    return wp


def _init_quietly(wp) -> None:
    """``wp.init()`` with its native stderr lines captured and re-logged (see the module docstring)."""
    captured = ""
    try:
        sys.stderr.flush()
        saved = os.dup(2)
    except (OSError, ValueError):  # no real fd 2 (embedded interpreters): let Warp print
        saved = None
    if saved is None:
        wp.init()
    else:
        with tempfile.TemporaryFile(mode="w+b") as tmp:
            try:
                os.dup2(tmp.fileno(), 2)
                wp.init()
            finally:
                sys.stderr.flush()
                os.dup2(saved, 2)
                os.close(saved)
            tmp.seek(0)
            captured = tmp.read().decode("utf-8", "replace")
    for line in captured.splitlines():
        if line.strip():  # the known no-driver lines only with -v; anything else is a warning
            log.log(logging.DEBUG if any(s in line for s in _NO_DRIVER) else logging.WARNING, "%s", line)


def default_device() -> str:
    """The first CUDA device if there is one, else the CPU."""
    wp = init_warp()

    return "cuda:0" if wp.get_cuda_device_count() > 0 else "cpu"


def resolve_device(name: str | None):
    """The Warp device ``name`` (None: :func:`default_device`); SettingsError if there is none."""
    wp = init_warp()
    name = name or default_device()
    if str(name).startswith("cuda") and not wp.is_cuda_available():
        # Warp's "cuda" alias asks the driver for its current context, which prints two raw
        # "Warp CUDA error" lines to fd 2 when there is no driver: refuse before asking
        raise SettingsError(f"device = {name!r} is not available (no CUDA device on this machine); use 'cpu'")
    try:
        return wp.get_device(name)
    except Exception as exc:  # warp raises RuntimeError/ValueError for unknown aliases
        raise SettingsError(f"device = {name!r} is not available ({exc}); use 'cpu' or 'cuda:N'") from None


def warp_facts(device: str | None = None) -> dict:
    """Warp version, the device (alias and name) and the CUDA driver version ('none' without one)."""
    wp = init_warp()
    dev = wp.get_device(device)
    drv = wp.get_cuda_driver_version() if wp.is_cuda_available() else None
    return {
        "warp_version": str(wp.config.version),
        "device": str(dev.alias),
        "device_name": str(dev.name),
        "cuda_driver": _driver_text(drv),
    }


def _driver_text(drv) -> str:
    """'13.0' from Warp's CUDA driver version: a (major, minor) tuple (Warp 1.19) or an int 13000."""
    if not drv:
        return "none"
    if isinstance(drv, tuple):
        return ".".join(str(int(x)) for x in drv[:2])
    return f"{int(drv) // 1000}.{(int(drv) % 1000) // 10}"


def drive(gen):
    """Run a generator that yields while it steps (:meth:`warp_tensegrity.sim.integrate.Integrator.run_steps`,
    :func:`warp_tensegrity.engine.simulate_batch_steps`) to its end and return its value. A value it
    yields is None (resume it at once) or a CUDA event it waits for (resumed once that is complete)."""
    while True:
        try:
            got = next(gen)
        except StopIteration as stop:
            return stop.value
        if got is not None:
            import warp as wp  # only a CUDA run yields an event

            wp.synchronize_event(got)


def cuda_memory(device) -> tuple[int, int]:
    """(free, total) bytes of a Warp CUDA device. Its primary context is made first: without one the
    driver makes and destroys a temporary context for each query (0.16 s each on the H200's host,
    seven of them in phase_large's plan); the run makes that context anyway."""
    device.context  # noqa: B018 - the property retains the device's primary context
    return int(device.free_memory), int(device.total_memory)

