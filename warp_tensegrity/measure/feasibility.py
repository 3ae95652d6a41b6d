"""Whether each case stayed in the feasible set of the model (the paper's Sec. 3: a prism's twist
between pi/3 and pi, where its bars touch; and a positive height), from the engine's feasibility
record, and the end-of-run summary of it.

The engine keeps, per prism (or, in a network that is not a column, per member pair) and column,
running extremes and the first output slot of each reason (:data:`~warp_tensegrity.types.FEASIBILITY_FLAGS`,
``sim.staged.kernels.record_feasibility`` and ``record_pairs``); :func:`prism_record` and
:func:`pair_record` reduce them to one value per case. Pure NumPy; docs/model.md states the
domain and what a flag means for the measures (:func:`left_before_measured`).
"""

from __future__ import annotations

import numpy as np

from ..types import FEASIBILITY_FLAGS
from .pulse_core import measurement_window

def _first(left_slot: np.ndarray):
    """(slot, item) of the earliest event over the items (axis -2 of (..., items, B)); -1 where none."""
    big = np.iinfo(np.int64).max
    s = np.where(left_slot >= 0, left_slot.astype(np.int64), big)
    item = s.argmin(axis=-2)
    slot = np.take_along_axis(s, item[..., None, :], axis=-2)[..., 0, :]
    none = slot == big
    return np.where(none, -1, slot), np.where(none, -1, item)


def _times(slot: np.ndarray, time: np.ndarray) -> np.ndarray:
    return np.where(slot >= 0, np.asarray(time, dtype=np.float64)[np.clip(slot, 0, len(time) - 1)], np.nan)


def _case_values(slot_r: np.ndarray, item_r: np.ndarray, time: np.ndarray) -> dict:
    """flag, first time and item over the reasons ((nr, B) slots and items)."""
    bits = (slot_r >= 0) * (1 << np.arange(len(slot_r)))[:, None]
    r = np.where(slot_r >= 0, slot_r, np.iinfo(np.int64).max).argmin(axis=0)  # earliest reason (lowest bit on ties)
    slot = np.take_along_axis(slot_r, r[None], axis=0)[0]
    item = np.take_along_axis(item_r, r[None], axis=0)[0]
    return {"feasibility_flag": bits.sum(axis=0).astype(np.int8), "feasibility_time": _times(slot, time),
            "feasibility_index": np.where(slot >= 0, item, -1).astype(np.int32),
            "feasibility_times": _times(slot_r, time).T.copy()}


def prism_record(left_slot, twist_max, twist_min, height_min, twist, time) -> dict:
    """Per-case values of a column run's record: ``left_slot`` (nr, np, B), the others (np, B),
    output ``time`` (n_out,) [s]. Returns (B,) arrays: ``feasibility_flag`` (bits
    of FEASIBILITY_FLAGS), ``feasibility_time`` [s] and ``feasibility_prism`` of the first event
    (NaN, -1 if none; ties: the lowest reason bit, then the lowest prism), ``feasibility_times``
    (B, nr) [s] of each reason, ``twist_max``, ``twist_min`` [rad] and ``height_ratio_min`` over the
    prisms; and per prism (B, np): ``prism_twist_max``, ``prism_twist_min``,
    ``prism_height_ratio_min`` and ``prism_twist_last`` (at the last output; for a column frozen by a
    failure, its last output before it). The extremes cover the outputs of each column up to the
    last it recorded."""
    slot_r, prism_r = _first(np.asarray(left_slot))
    out = _case_values(slot_r, prism_r, time)
    out["feasibility_prism"] = out.pop("feasibility_index")
    per = {"prism_twist_max": twist_max, "prism_twist_min": twist_min, "prism_height_ratio_min": height_min,
           "prism_twist_last": twist}
    for k, v in per.items():
        out[k] = np.asarray(v, dtype=np.float64).T.copy()
    out["twist_max"] = out["prism_twist_max"].max(axis=1)
    out["twist_min"] = out["prism_twist_min"].min(axis=1)
    out["height_ratio_min"] = out["prism_height_ratio_min"].min(axis=1)
    return out


def pair_record(pair_left_slot, pair_kind, distance_min, pair_nodes, time) -> dict:
    """Per-case values of a network's record: ``pair_left_slot`` and ``distance_min`` (npr, B),
    ``pair_kind`` (npr,) (0 bars, 1 cables), ``pair_nodes`` (npr, 4). Returns (B,) arrays:
    ``feasibility_flag`` (bars_crossed, strings_touched), ``feasibility_time`` [s],
    ``feasibility_pair`` (-1 if none) and ``feasibility_nodes`` (B, 4) (the pair's end nodes, -1)
    of the first crossing, ``feasibility_times`` (B, nr), ``member_distance_min`` [m] (smallest
    distance of two bar axes, the cables' apart)."""
    left = np.asarray(pair_left_slot)
    kind = np.asarray(pair_kind)
    B = left.shape[1]
    nr = len(FEASIBILITY_FLAGS)
    slot_r = np.full((nr, B), -1, dtype=np.int64)
    pair_r = np.full((nr, B), -1, dtype=np.int64)
    for r in (0, 1):
        rows = np.flatnonzero(kind == r)
        if rows.size:
            s, i = _first(left[rows])
            slot_r[r], pair_r[r] = s, np.where(i >= 0, rows[np.clip(i, 0, None)], -1)
    out = _case_values(slot_r, pair_r, time)
    out["feasibility_pair"] = pair = out.pop("feasibility_index")
    out["feasibility_nodes"] = np.where(pair[:, None] >= 0, np.asarray(pair_nodes)[np.clip(pair, 0, None)], -1)
    d = np.asarray(distance_min, dtype=np.float64)[kind == 0]
    out["member_distance_min"] = d.min(axis=0) if d.size else np.full(B, np.nan)
    return out


def feasible_record(n_columns: int) -> dict:
    """The record of ``n_columns`` cases that never left the set, with no extremes (NaN): the
    layout of a sweep store (:func:`warp_tensegrity.sweep.shard.template_dataset`)."""
    nan = np.full(n_columns, np.nan)
    return {"feasibility_flag": np.zeros(n_columns, np.int8), "feasibility_time": nan.copy(),
            "feasibility_prism": np.full(n_columns, -1, np.int32), "twist_max": nan.copy(), "twist_min": nan.copy(),
            "height_ratio_min": nan.copy(), "feasibility_times": np.full((n_columns, len(FEASIBILITY_FLAGS)), np.nan)}


def left_before_measured(feasibility_time, peak_time) -> np.ndarray:
    """(B,) True where a case left the feasible set before its measured pulse had passed the
    measurement window: before the latest leading-peak time in the window (``peak_time`` (B, P)
    [s], measure_pulse's), or at any time where no peak was found there. Its pulse measures are
    then NaN (measurement_flag left_feasible_set); later, they are kept (feasibility_flag set)."""
    t_left = np.asarray(feasibility_time, dtype=np.float64)
    pt = np.asarray(peak_time, dtype=np.float64)
    lo, hi = measurement_window(pt.shape[-1])
    win = pt[:, lo:hi]
    t_pass = np.where(np.isfinite(win).any(axis=1), np.nanmax(np.where(np.isfinite(win), win, -np.inf), axis=1),
                      np.inf)
    return np.isfinite(t_left) & (t_left <= t_pass)


WHY = {
    "bars_crossed": "a prism's twist reached pi: its bars touched and passed through each other (two bar axes "
                    "crossed, in a network)",
    "strings_touched": "a prism's twist fell to pi/3, the paper's bound for touching cross cables (two cable axes "
                       "crossed, in a network)",
    "prism_inverted": "a prism's height reached 0: its bases passed through each other",
}


def summary(flags) -> list[str]:
    """One line per reason (:data:`~warp_tensegrity.types.FEASIBILITY_FLAGS`) that some case has:
    how many cases, and what happened (a case may count under several reasons)."""
    flags = np.asarray(flags).reshape(-1).astype(np.int64)
    n = flags.size
    lines = []
    for bit, name in enumerate(FEASIBILITY_FLAGS):
        k = int(((flags >> bit) & 1).sum())
        if k:
            lines.append(f"{k} of {n} cases left the feasible set ({name}): {WHY[name]}")
    return lines


def dataset_summary(ds) -> list[str]:
    """:func:`summary` of a sweep or batch dataset with ``feasibility_flag`` ([] without)."""
    return summary(ds["feasibility_flag"].values) if "feasibility_flag" in ds else []
