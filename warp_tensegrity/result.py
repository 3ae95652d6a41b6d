"""The batch result: what a run returns, on the host, and its dataset (:meth:`BatchResult.to_xarray`).

Apart from :mod:`.options` (what goes into a run) so that the result may know its dataset format
(:mod:`.io`) while the options, which every layer imports, stay at the bottom.
"""

from __future__ import annotations

from dataclasses import dataclass, field

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
