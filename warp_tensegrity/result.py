"""The batch result: what a run returns, on the host, and its dataset (:meth:`BatchResult.to_xarray`).

Apart from :mod:`.options` (what goes into a run) so that the result may know its dataset format
(:mod:`.io`) while the options, which every layer imports, stay at the bottom.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import partial

import numpy as np

from .measure.nan_reasons import measure_columns
from .provenance import provenance_attrs
from .runtime import warp_facts


@dataclass
class BatchResult:
    """What a batch run returns, on the host. B = number of columns."""

    params: dict
    """Per-column parameters actually used, each shape (B,)."""
    time: np.ndarray
    """(n_out,) output times [s]."""
    strain: np.ndarray | None
    """(B, n_out, n_prisms) prism axial strain (h - h0)/h [1], negative in compression; None if not kept."""
    kinetic_energy: np.ndarray
    """(B, n_out) [J]."""
    elastic_energy: np.ndarray
    """(B, n_out) elastic energy of all cables, prestress included [J]."""
    energy_error: np.ndarray
    """(B,) max_t |E(t) - E(0)| / KE(0) [1] over the outputs (E = kinetic + elastic)."""
    bar_length_error: np.ndarray
    """(B,) max over all steps and bars of |l - L| / L after projection [1]."""
    status: np.ndarray
    """(B,) :class:`~warp_tensegrity.types.Status`: 0 ok, 1 non-finite state, 2 bar constraint failed."""
    fail_step: np.ndarray
    """(B,) step at which the column was frozen, -1 if it never failed."""
    dt: float
    """Time step used [s]."""
    n_steps: int
    method: str
    precision: str
    device: str
    """Warp device alias the batch ran on."""
    device_name: str
    """Human-readable device name."""
    wall_time: float
    """Seconds spent stepping (excludes build and compile)."""
    final_displacement: np.ndarray | None = None
    """(B, n_nodes, 3) displacement from the reference positions at the last step [m]."""
    final_velocity: np.ndarray | None = None
    """(B, n_nodes, 3) velocity at the last step [m s-1]."""
    feasibility: dict | None = None
    """Whether each column stayed in the model's feasible set (docs/model.md): (B,) arrays
    ``feasibility_flag`` (bits of :data:`~warp_tensegrity.types.FEASIBILITY_FLAGS`), ``feasibility_time``
    [s] and ``feasibility_prism`` of the first event (NaN, -1: none), ``twist_max``, ``twist_min`` [rad],
    ``height_ratio_min`` and more (:func:`warp_tensegrity.measure.feasibility.prism_record`; networks
    that are not columns: :func:`~warp_tensegrity.measure.feasibility.pair_record`)."""
    dt_limit: float = float("nan")
    """Predicted stability limit of the method for the stiffest column [s]."""
    info: dict = field(default_factory=dict)
    """Extra facts: projection iterations, compile time, steps per graph, stage seconds, etc."""
    station_energy: np.ndarray | None = None
    """(B, n_out) energy above the reference state on the clamp side of the station's section
    (the time integral of the energy flux through it, :mod:`warp_tensegrity.measure.energy`) [J]."""
    end_energy: np.ndarray | None = None
    """(B, n_out) energy above the reference state of the end part (the ``energy_end_prisms``
    prisms at the impacted end) [J]."""
    measurements: dict | None = None
    """Pulse measures of every column (:func:`warp_tensegrity.measure.measure_pulse`'s dict and the
    record statistics of :func:`warp_tensegrity.measure.device.measure_record`), when
    ``RunSettings.measure`` is not 'none'."""

    @property
    def n_columns(self) -> int:
        return int(self.status.shape[0])

    def to_xarray(self, config=None, measure: bool = True):
        """The result as the CF dataset the CLI writes for a case list (``case`` dimension,
        parameters as coordinates, time axis ``t`` [s]), with the pulse measurements when the
        strain was kept. ``config``: the ColumnConfig (default: the prism height recorded by
        :func:`simulate_batch`). Built by :func:`warp_tensegrity.io.result_dataset`."""
        from .io import result_dataset  # imports xarray: not at package import

        height = float(config.height) if config is not None else self.info.get("prism_height")
        meas = None
        if measure and (self.strain is not None or self.measurements is not None):
            if height is None:
                raise ValueError("to_xarray(measure=True) needs the column's config (prism height)")
            meas = measure_columns(self, height)
            if "beta_limit" in self.info:  # set by simulate_batch: base_mode_ratio, beta_limit_flag
                meas.update(self.info["beta_limit"](meas["max_compression"]))
        attrs = {**provenance_attrs(), "cuda_driver": warp_facts(self.device)["cuda_driver"]}
        return result_dataset(self, config=config, measurements=meas, attrs=attrs)


_PER_COLUMN = ("strain", "kinetic_energy", "elastic_energy", "station_energy", "end_energy", "energy_error", "bar_length_error", "status", "fail_step",
               "final_displacement", "final_velocity")


def merge_results(parts: list, n_columns: int, group_ids: list[int] | None = None) -> BatchResult:
    """One BatchResult of ``n_columns`` columns from runs of groups of them (a sweep's groups of like
    stiffness, :mod:`warp_tensegrity.policy.groups`): ``parts`` = [(column indices, BatchResult)],
    every column once, all on one output time axis. Per-column arrays are put back in column order;
    ``dt`` and ``dt_limit`` are the smallest, ``n_steps`` the largest, ``wall_time`` and the stage
    seconds the sums; ``info['column_dt']`` and ``info['column_group']`` give each column's dt [s]
    and group (``group_ids[k]`` for part k; default k), ``info['groups']`` each group's facts. One
    part comes back as it is (with those two)."""
    cols = [np.asarray(c, dtype=np.int64) for c, _ in parts]
    results = [r for _, r in parts]
    if sorted(np.concatenate(cols).tolist()) != list(range(n_columns)):
        raise ValueError("merge_results: the parts do not hold every column exactly once")
    first = results[0]
    for r in results[1:]:
        if not np.array_equal(r.time, first.time):
            raise ValueError("merge_results: the groups have other output times")

    def stitch(name):
        arrays = [getattr(r, name) for r in results]
        if any(a is None for a in arrays):
            return None
        out = np.empty((n_columns,) + arrays[0].shape[1:], dtype=arrays[0].dtype)
        for c, a in zip(cols, arrays):
            out[c] = a
        return out

    column_dt = np.empty(n_columns)
    column_group = np.empty(n_columns, dtype=np.int32)
    column_bits = np.empty(n_columns, dtype=np.int8)
    for g, c, r in zip(group_ids or range(len(parts)), cols, results):
        column_dt[c] = r.info.get("column_dt", r.dt)
        column_group[c] = g
        column_bits[c] = r.info.get("column_bits", precision_bits(r.precision))
    if len(results) == 1:
        first.info.update(column_dt=column_dt, column_group=column_group, column_bits=column_bits)
        return first
    feasibility = None
    if all(r.feasibility is not None for r in results):  # per-column arrays of the record, stitched
        feasibility = {}
        for k, v in first.feasibility.items():
            v = np.asarray(v)
            out = np.empty((n_columns,) + v.shape[1:], dtype=v.dtype)
            for c, r in zip(cols, results):
                out[c] = np.asarray(r.feasibility[k])
            feasibility[k] = out
    measurements = None
    if all(r.measurements is not None for r in results):
        measurements = {}
        for k in first.measurements:
            vals = [np.asarray(r.measurements[k]) for r in results]
            if vals[0].ndim >= 1 and vals[0].shape[0] == first.n_columns and all(
                    v.shape[:1] == (r.n_columns,) for v, r in zip(vals, results)):
                out = np.empty((n_columns,) + vals[0].shape[1:], dtype=vals[0].dtype)
                for c, v in zip(cols, vals):
                    out[c] = v
                measurements[k] = out
            else:  # a run-level figure (timings): the first group's
                measurements[k] = first.measurements[k]
    stages = {}
    for r in results:
        for k, v in r.info.get("stages", {}).items():
            stages[k] = stages.get(k, 0.0) + v
    # a profile along the column (2-D) in any part: (n_columns, its length) in all
    tail = {k: max((np.shape(r.params[k])[1:] for r in results), key=len) for k in first.params}
    params = {k: np.empty((n_columns,) + tail[k], dtype=np.asarray(v).dtype) for k, v in first.params.items()}
    for c, r in zip(cols, results):
        for k in params:
            v = np.asarray(r.params[k])
            params[k][c] = np.broadcast_to(v[:, None] if v.ndim == 1 and tail[k] else v, (r.n_columns,) + tail[k])
    step_paths = []
    for r in results:
        if r.info.get("step_path") not in step_paths:
            step_paths.append(r.info.get("step_path"))
    # the output steps and the beta-limit closure are one group's: not the merged columns'
    info = {k: v for k, v in first.info.items() if k not in ("output_step", "stages", "beta_limit")}
    if all("striker" in r.info for r in results):  # the striker's per-column records, stitched
        info["striker"] = {k: np.empty((n_columns,) + np.shape(v)[1:], dtype=np.asarray(v).dtype)
                           for k, v in first.info["striker"].items()}
        for c, r in zip(cols, results):
            for k, v in r.info["striker"].items():
                info["striker"][k][c] = v
    if all("beta_limit" in r.info for r in results):  # each part's closure on its columns, stitched
        info["beta_limit"] = partial(_stitched_beta_limit, [(c, r.info["beta_limit"]) for c, r in zip(cols, results)],
                                     n_columns)
    info.update(stages=stages, column_dt=column_dt, column_group=column_group, column_bits=column_bits, step_path="; ".join(map(str, step_paths)),
                groups=[{"group": int(g), "columns": int(c.size), "dt": float(r.dt), "n_steps": int(r.n_steps),
                         "step_path": r.info.get("step_path"), "wall_time": float(r.wall_time)}
                        for g, c, r in zip(group_ids or range(len(parts)), cols, results)])
    return BatchResult(
        params=params, time=first.time, **{k: stitch(k) for k in _PER_COLUMN},
        dt=min(r.dt for r in results), n_steps=max(r.n_steps for r in results), method=first.method,
        precision=first.precision, device=first.device, device_name=first.device_name,
        wall_time=float(sum(r.wall_time for r in results)), dt_limit=min(r.dt_limit for r in results),
        info=info, measurements=measurements, feasibility=feasibility)


def _stitched_beta_limit(parts, n_columns: int, max_compression) -> dict:
    """The beta-limit measures of merged groups: each group's closure on its columns."""
    mc = np.asarray(max_compression)
    out = {}
    for c, f in parts:
        for k, v in f(mc[c]).items():
            v = np.asarray(v)
            if k not in out:
                out[k] = np.empty((n_columns,) + v.shape[1:], dtype=v.dtype)
            out[k][c] = v
    return out


def precision_bits(precision: str) -> int:
    """32 or 64: the bits of a precision name ('fp32', 'fp64')."""
    return 32 if str(precision) == "fp32" else 64


def overwrite_columns(result: BatchResult, index, other: BatchResult) -> None:
    """Put the columns of ``other`` (a run of ``result``'s columns ``index``, on the same output times)
    in their places in ``result``, in place: every per-column array, the measures, each column's dt and
    precision bits (``info['column_dt']``, ``info['column_bits']``). A precision 'auto' rerun in fp64."""
    index = np.asarray(index, dtype=np.int64)
    if other.n_columns != index.size or not np.array_equal(other.time, result.time):
        raise ValueError("overwrite_columns: other is not a run of those columns on the same output times")
    for name in _PER_COLUMN:
        a, b = getattr(result, name), getattr(other, name)
        if a is not None and b is not None:
            a[index] = b
    if result.feasibility is not None and other.feasibility is not None:
        for k, v in other.feasibility.items():
            result.feasibility[k][index] = np.asarray(v)
    if "striker" in result.info and "striker" in other.info:  # the striker's per-column records
        for k, v in other.info["striker"].items():
            result.info["striker"][k][index] = v
    if result.measurements is not None and other.measurements is not None:
        for k, v in other.measurements.items():
            mine = result.measurements.get(k)
            if isinstance(mine, np.ndarray) and mine.ndim >= 1 and mine.shape[0] == result.n_columns:
                mine[index] = np.asarray(v)
    B = result.n_columns
    dt = np.broadcast_to(np.asarray(result.info.get("column_dt", result.dt), dtype=np.float64), (B,)).copy()
    bits = np.broadcast_to(np.asarray(result.info.get("column_bits", precision_bits(result.precision)), dtype=np.int8),
                           (B,)).copy()
    dt[index], bits[index] = other.dt, precision_bits(other.precision)
    result.info.update(column_dt=dt, column_bits=bits)
    result.wall_time += other.wall_time
    for k, v in other.info.get("stages", {}).items():
        result.info.setdefault("stages", {})[k] = result.info["stages"].get(k, 0.0) + v
