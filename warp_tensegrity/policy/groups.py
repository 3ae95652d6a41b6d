"""A sweep's columns in groups of like stiffness, each run with its own plan: :func:`decide_groups`.

One dt for a whole sweep is set by its stiffest column: in ``phase_large`` the beta = 0.95 columns
(omega_max bound 880 rad/s) set dt for the flexible-base ones (249 rad/s) and the rigid-base ones
(156 rad/s), which then step 3.5-5.6x more often than their own accuracy needs. So a sweep is cut
into groups, and each group is decided once (:func:`.decide.decide`: its own method, precision,
dt, step count, truncation and launch path, each with its reason):

* rigid-base columns (beta = 1) never share a group with the others: their base links are
  constraints, a different Gram band (6 against 3) and step kernel, and the lowest stiffness;
* within each base class, columns are sorted by their omega_max bound (the bound that sets the
  stability limit, so dt is proportional to 1/omega) and cut into bands of at most
  :data:`GROUP_RATIO` in omega: no column steps more than that many times as often as its own dt
  would have it;
* a band of fewer than :data:`MIN_GROUP_COLUMNS` columns joins its stiffer neighbour (a narrow
  launch costs nearly what a full one does on a GPU). The rule reads the spec alone, never the
  device, so a sweep's results do not depend on where it runs.

Output times do not depend on dt (dt divides the output interval), so every group writes the same
time axis. An explicit dt, or grouping switched off, gives one group: the run of today.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from ..options import RunSettings
from ..scene.batch import ColumnParams, column_batch, column_params, has_profiles, omega_max_bound
from ..scene.columns import ColumnConfig
from ..runtime import resolve_device
from ..types import Base, Precision
from .accuracy import ERROR_MODEL, MAX_FRACTION
from .decide import ESTIMATE_CHUNK_BYTES, RunPlan, decide, far_end

TWIN_COARSENING = 4.0
"""The error estimate's twin steps at about this many times the group's dt: a quarter of its steps."""
AUTO_FP32_ON_CPU = False
"""precision 'auto' verifies fp32 on a GPU only (where it is ~8x faster than fp64); on the CPU it
buys ~1.5x and fp64 runs (the tests set this to check the verification on the CPU)."""
GROUP_RATIO = 2.0
"""Largest ratio of omega_max bounds (so of stable dt) within one group."""
MIN_GROUP_COLUMNS = 64
"""A band of fewer columns joins its stiffer neighbour: on a GPU a launch of a few dozen columns
fills a sliver of the device and costs nearly as much per step as a full one."""


@dataclass(frozen=True)
class RunGroup:
    """Columns of a sweep that run with one plan."""

    columns: np.ndarray
    """Indices of the sweep's columns in the group, ascending."""
    plan: RunPlan
    """The group's run, decided once."""
    label: str
    """What the group holds: base class and omega_max bounds [rad s-1]."""
    twin: RunPlan | None = None
    """The error estimate's twin: the same columns at about TWIN_COARSENING x dt, on the same output
    times (:func:`twin_plan`); None where there is none."""
    fallback: RunPlan | None = None
    """precision 'auto' verified: the fp64 plan (and ``fallback_twin``, its twin) that reruns the
    cases whose fp32 measures the twin does not verify; None otherwise."""
    fallback_twin: RunPlan | None = None

    @property
    def n_columns(self) -> int:
        return int(self.columns.size)


def column_omega(config: ColumnConfig, params: ColumnParams) -> np.ndarray:
    """(B,) omega_max bound [rad s-1] of each column, from its last few prisms (the bound is a
    maximum over nodes, so a short piece of a uniform column gives the whole column's), a few MB of
    columns at a time."""
    # a profile along the column: the whole column (its stiffest prisms may lie anywhere)
    piece = config if has_profiles(params) else far_end(config, min(4, config.n_prisms))
    B = params["prestrain"].shape[0]
    chunk = max(16, ESTIMATE_CHUNK_BYTES // (400 * piece.n_prisms))
    return np.concatenate([omega_max_bound(column_batch(piece, params.take(slice(i, i + chunk))))
                           for i in range(0, B, chunk)])


def stiffness_bands(omega: np.ndarray, rigid: np.ndarray, ratio: float = GROUP_RATIO,
                    min_columns: int = 1) -> list[np.ndarray]:
    """Column indices in groups: rigid and non-rigid apart, each cut into bands of omega within
    ``ratio`` (from the softest up), bands of fewer than ``min_columns`` joined to their stiffer
    neighbour (the last to its softer one). Groups in order: rigid first, then by omega."""
    groups = []
    for cls in (True, False):
        idx = np.flatnonzero(rigid == cls)
        if idx.size == 0:
            continue
        idx = idx[np.argsort(omega[idx], kind="stable")]
        bands, start = [], 0
        for i in range(1, idx.size + 1):
            if i == idx.size or omega[idx[i]] > ratio * omega[idx[start]]:
                bands.append(idx[start:i])
                start = i
        merged = []
        for b in bands:
            if merged and merged[-1].size < min_columns:
                merged[-1] = np.concatenate([merged[-1], b])  # a narrow band runs at its stiffer neighbour's dt
            else:
                merged.append(b)
        if len(merged) > 1 and merged[-1].size < min_columns:
            last = merged.pop()
            merged[-1] = np.concatenate([merged[-1], last])
        groups += [np.sort(b) for b in merged]
    return groups


def twin_plan(config: ColumnConfig, params: ColumnParams, plan: RunPlan) -> RunPlan | None:
    """The error estimate's twin of ``plan`` (:data:`TWIN_COARSENING`): the same columns and method
    at dt_twin = interval / ceil(output_every / r), so both record the same output times, with r at
    most TWIN_COARSENING and dt_twin at most MAX_FRACTION of the stability limit. None when no
    coarser dt keeps the outputs (one step per output) or stays stable."""
    interval = plan.settings.output_interval or plan.settings.t_end / 200.0  # as choose_timestep has it
    r = min(TWIN_COARSENING, MAX_FRACTION * plan.dt_limit / plan.dt)
    every = math.ceil(plan.output_every / r - 1e-9) if r > 1 else plan.output_every
    if every >= plan.output_every:
        return None
    settings = replace(plan.settings, dt=min(interval / every, plan.settings.t_end), dt_safety=None)
    return decide(config, params, settings, n_columns=plan.n_columns, prisms_simulated=plan.prisms_simulated)


def twin_ratio(plan: RunPlan, twin: RunPlan) -> float:
    """The factor (dt_twin / dt)^p - 1 by which the twin's error exceeds the plan's (order p of the
    method, :data:`~.accuracy.ERROR_MODEL`; Richardson): |m - m_twin| / it estimates m's error."""
    p = ERROR_MODEL.get(plan.method, (None, 2))[1]
    return (twin.dt / plan.dt) ** p - 1.0


def verifies_fp32(settings: RunSettings, twins: bool) -> bool:
    """Whether precision 'auto' runs fp32 verified by the twins (else fp64): on a GPU, with twins."""
    return settings.precision == Precision.AUTO and twins and (AUTO_FP32_ON_CPU or resolve_device(settings.device).is_cuda)


def _group(config: ColumnConfig, params: ColumnParams, settings: RunSettings, width: int, columns: np.ndarray,
           label: str, twins: bool, verify: bool) -> RunGroup:
    """One group decided: its plan, twin, and (``verify``) its fp32 plan with the fp64 fallback."""
    if verify:
        plan = decide(config, params, replace(settings, precision=Precision.FP32), n_columns=width)
        back = decide(config, params, replace(settings, precision=Precision.FP64), n_columns=width)
        return RunGroup(columns, plan, label, twin_plan(config, params, plan), back, twin_plan(config, params, back))
    plan = decide(config, params, settings, n_columns=width)
    return RunGroup(columns, plan, label, twin_plan(config, params, plan) if twins else None)


def decide_groups(config: ColumnConfig, params: dict, settings: RunSettings, *, n_columns: int | None = None,
                  grouping: bool = True, twins: bool = False) -> tuple[RunGroup, ...]:
    """The sweep of scene ``config`` over ``params`` as groups of like stiffness, each decided once
    (:func:`.decide.decide`, ``n_columns`` columns per launch at most). One group when ``grouping``
    is off, dt is given, or the columns are alike. ``twins``: decide each group's error-estimate twin
    too (:func:`twin_plan`)."""
    params = column_params(config, params)
    B = int(params["prestrain"].shape[0])
    width = B if n_columns is None else int(n_columns)
    whole = np.arange(B)
    verify = verifies_fp32(settings, twins)
    if not grouping or settings.dt != "auto" or B == 1:
        return (_group(config, params, settings, min(width, B), whole, "every column", twins, verify),)
    omega = column_omega(config, params)
    rigid = params["base_rigidity"] >= Base.RIGID
    bands = stiffness_bands(omega, rigid, GROUP_RATIO, MIN_GROUP_COLUMNS)
    out = []
    for cols in bands:
        cls = "rigid bases" if rigid[cols[0]] else ("flexible bases" if np.all(params["base_rigidity"][cols] == 0)
                                                     else "flexible or elastic bases")
        out.append(_group(config, params.take(cols), settings, min(width, cols.size), cols,
                          f"{cls}, omega_max {omega[cols].min():.4g}-{omega[cols].max():.4g} rad/s", twins, verify))
    if len({g.plan.n_out for g in out}) != 1:  # pragma: no cover - dt divides the output interval
        raise AssertionError("groups with different output times")
    return tuple(out)
