"""Refuse up front, with the figures, a sweep the machine cannot hold or finish.

Two checks, both before any kernel runs:

* :func:`check_plan` (hard; :func:`warp_tensegrity.sweep.plan.plan_sweep` calls it): the host memory
  that planning itself needs (the per-column parameters and the engine's estimate, which builds
  every column of the sweep once) against the memory available.
* :func:`check_run` (the CLI calls it before a run; ``--ignore-estimate`` skips it): the
  cost model's device memory and host memory per shard, the disk the store and the netCDF export take
  together against the free disk,
  and the estimated time against a time limit: the figures the dry run prints
  (:mod:`warp_tensegrity.policy.cost`). What no override can run (the step count against the
  device's int32 step counter, one column's records against the machine's memory:
  :func:`hard_problems`) is refused before that, when the run is decided.
"""

from __future__ import annotations

import logging
import math
import os
from pathlib import Path

from ..atomic import free_bytes
from ..policy.cost import DEFAULT_TIME_LIMIT, fmt_bytes, fmt_seconds, size_problems
from ..runtime import cuda_memory
from .errors import SweepError

PLAN_BYTES_PER_LEVEL = 720
"""Host bytes per column and per base level that planning needs: tracemalloc peak of
``estimate_batch`` measured at 5.9 kB per column for 8 prisms and 35 kB for 50 prisms."""
PARAM_BYTES = 8 * 5
"""Five float64 per-column parameters."""


class BudgetError(SweepError):
    """The estimate says the sweep does not fit the machine; the message gives the figures."""


def host_memory_available() -> int:
    """Bytes of host memory available now (MemAvailable; total physical memory elsewhere)."""
    try:
        with open("/proc/meminfo", encoding="ascii") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:  # pragma: no cover - not Linux
        pass
    try:  # pragma: no cover
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):  # pragma: no cover
        return 2**63


def device_memory(device: str | None) -> tuple[str, int]:
    """(device name, bytes of memory a shard may use) for a Warp device; the CPU uses host memory."""
    if device in (None, "auto") or str(device).startswith("cuda"):
        import warp as wp  # only a run on a GPU gets here

        name = device if device not in (None, "auto") else ("cuda:0" if wp.get_cuda_device_count() else "cpu")
        if name != "cpu":
            free, total = cuda_memory(wp.get_device(name))
            return name, free or total
    return "cpu", host_memory_available()


def plan_bytes(n_columns: int, n_prisms: int) -> int:
    """Host bytes that planning a sweep of ``n_columns`` columns needs (see PLAN_BYTES_PER_LEVEL)."""
    return int(n_columns) * (PARAM_BYTES + PLAN_BYTES_PER_LEVEL * (int(n_prisms) + 1))


PLAN_SECONDS_PER_PRISM = 4e-5
"""Seconds per prism of planning one scene, whatever its column count: the topology, the members'
coupling and masses of the engine's estimate and each impact solve, all O(n) (the impact and the
equilibrium check by sparse solves beyond 100 prisms, scene/sparse.py); measured on the 2-core CPU
(two 100,000-prism columns planned in 2.9-3.7 s by impact mode, FUZZ_EXPLORE=1 pytest
tests/test_fuzz.py -k long_columns; the members' coupling and masses of model.py vectorised)."""
PLAN_SECONDS_PER_COLUMN_PRISM = 2e-6
"""Seconds per prism and column of planning (each column's frequency bound is built, a few MB at
a time); measured: 128 columns of 10,000 prisms plan in 3.0 s, 8 of them in 1.2 s."""
PLAN_TIME_LIMIT = 600.0
"""Seconds planning may be estimated to take before a sweep is refused."""
PLAN_NOTICE_SECONDS = 5.0
"""Planning estimated to take longer is announced up front, with its figure."""


def plan_seconds(n_columns: int, n_prisms: int, impact: str = "rigid_members") -> float:
    """Seconds planning a sweep is estimated to take on this machine's reference CPU (linear in
    prisms and columns for every ``impact`` convention since the solves are sparse)."""
    return float(n_prisms) * (PLAN_SECONDS_PER_PRISM + float(n_columns) * PLAN_SECONDS_PER_COLUMN_PRISM)


def check_plan(spec, available: int | None = None) -> None:
    """Refuse a sweep whose planning alone would not fit in host memory or would take longer than
    PLAN_TIME_LIMIT (before any array of the sweep's size is made)."""
    need = plan_bytes(spec.n_columns, spec.scene.n_prisms)
    have = host_memory_available() if available is None else int(available)
    if need > have:
        raise BudgetError(
            f"sweep of {spec.n_columns:,} columns x {spec.scene.n_prisms} prisms: planning it needs about "
            f"{fmt_bytes(need)} of host memory and {fmt_bytes(have)} is available; split the sweep "
            "into several specs (fewer grid values per spec)"
        )
    secs = plan_seconds(spec.n_columns, spec.scene.n_prisms, spec.scene.impact_admissibility)
    if secs > PLAN_TIME_LIMIT:
        raise BudgetError(
            f"sweep of {spec.n_columns:,} columns x {spec.scene.n_prisms} prisms: planning builds every "
            f"column (its frequency bound and impact), about {fmt_seconds(secs)} here (limit "
            f"{fmt_seconds(PLAN_TIME_LIMIT)}); use fewer prisms, or split the sweep into several specs"
        )
    if secs > PLAN_NOTICE_SECONDS:
        logging.getLogger(__name__).info("planning %s columns x %s prisms: about %s", f"{spec.n_columns:,}",
                                         f"{spec.scene.n_prisms:,}", fmt_seconds(secs))


def hard_problems(plan) -> list[str]:
    """What no override can run (:func:`warp_tensegrity.policy.cost.size_problems`): more steps than
    the device's int32 step counter holds, or one column whose records exceed the machine's memory.
    :func:`~warp_tensegrity.policy.decide.decide` refuses such a run already; this lists them for a
    plan whose run was decided elsewhere."""
    return size_problems(plan.run)


def problems(plan, cost: dict, *, time_limit: float = DEFAULT_TIME_LIMIT, device_bytes: int | None = None,
             host_bytes: int | None = None, disk_bytes: int | None = None) -> list[str]:
    """Every way the planned run exceeds this machine, one line each with the figures ([] if it fits;
    :func:`hard_problems` are listed apart), from its ``cost``
    (:func:`warp_tensegrity.policy.calibrate.estimate_plan`: the figures the dry run prints)."""
    need = cost | {"shard": max(b - a for a, b in plan.shards), "n_steps": plan.run.n_steps}
    out = []
    if device_bytes is None:
        dev_name, device_bytes = device_memory(plan.device)
    else:
        dev_name = plan.device or "device"
    if need["device_bytes_per_shard"] > device_bytes:
        fit = device_bytes // max(need["device_bytes_per_column"], 1)
        out.append(f"a shard of {need['shard']:,} columns needs {fmt_bytes(need['device_bytes_per_shard'])} of "
                   f"{dev_name} memory and {fmt_bytes(device_bytes)} is available; "
                   + (f"use --shard-size {fit:,} or less" if fit >= 1 else "one column does not fit: "
                      "raise run.output_interval or set record_strain = false"))
    host = host_memory_available() if host_bytes is None else int(host_bytes)
    if need["host_bytes_per_shard"] > host:
        fit = host // max(need["host_bytes_per_column"], 1)
        out.append(f"a shard of {need['shard']:,} columns needs {fmt_bytes(need['host_bytes_per_shard'])} of "
                   f"host memory for its results and {fmt_bytes(host)} is available; "
                   + (f"use --shard-size {fit:,} or less" if fit >= 1 else "raise run.output_interval"))
    if plan.out is not None:
        if disk_bytes is None:
            disk_bytes = free_bytes(plan.out)[0]
        if need["disk_bytes"] > disk_bytes:
            out.append(f"the output needs up to {fmt_bytes(need['disk_bytes'])} of disk, uncompressed (the store "
                       f"{Path(plan.out).name}.sweep/ {fmt_bytes(need['store_bytes'])} and {Path(plan.out).name} "
                       f"{fmt_bytes(need['netcdf_bytes'])}, both there when the export ends) and "
                       f"{fmt_bytes(disk_bytes)} is free on {Path(plan.out).parent}")
    if math.isfinite(need["seconds"]) and need["seconds"] > time_limit:
        out.append(f"the estimate is {fmt_seconds(need['seconds'])} ({plan.n_columns:,} columns x "
                   f"{need['n_steps']:,} steps) and the time limit is {fmt_seconds(time_limit)} "
                   "(--time-limit SECONDS)")
    return out


def check_run(plan, cost: dict | None, *, ignore: bool = False, **kw) -> None:
    """Raise :class:`BudgetError` listing every way the planned run does not fit its ``cost``; with
    ``ignore`` (``cost`` may then be None) only what cannot run at all (:func:`hard_problems`)."""
    hard = hard_problems(plan)
    if hard:
        raise BudgetError("the run cannot be done:\n  - " + "\n  - ".join(hard))
    found = [] if ignore else problems(plan, cost, **kw)
    if found:
        raise BudgetError("the run does not fit this machine (by the estimate the dry run prints; "
                          "--ignore-estimate runs it anyway):\n  - " + "\n  - ".join(found))
