"""Run settings: what goes into a run (host side). What comes out: :mod:`.result`."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .types import COLUMN_PARAMETERS, STATUS_MEANINGS, TIME, Method, Precision  # noqa: F401 (re-exported)

METHODS = tuple(m.value for m in Method)
PRECISIONS = tuple(p.value for p in Precision)
STATUS_NAMES = {int(k): v for k, v in STATUS_MEANINGS.items()}



class SettingsError(ValueError):
    """Invalid run setting; the message names the field and the value."""


@dataclass
class RunSettings:
    """How to integrate a batch (SI units)."""

    t_end: float = 1.0
    """Simulated time [s]."""
    dt: float | str = "auto"
    """Time step [s], or 'auto': dt_safety times the method's stability limit from omega_max."""
    method: str = "rattle"
    """'rattle' (default: velocity Verlet + position/velocity projection), 'rk4' (the paper's
    RK4 with projection), 'yoshida4' (RATTLE triple-jump composition), 'symplectic_euler'."""
    precision: str = "fp64"
    """'fp32' or 'fp64'."""
    output_interval: float | None = None
    """Time between recorded outputs [s]; None: about 200 outputs over t_end."""
    record_strain: bool = True
    """Keep the prism strain history (n_out x n_prisms per column)."""
    device: str | None = None
    """Warp device ('cpu', 'cuda:0'); None: the GPU if there is one, else the CPU."""
    dt_safety: float | None = None
    """Fraction of the predicted stability limit used when dt = 'auto' (at most 0.5); None: the
    fraction that meets :data:`~warp_tensegrity.engine.DEFAULT_ACCURACY` (1e-3) on the pulse
    measures (:func:`~warp_tensegrity.engine.default_dt_safety`)."""
    allow_unstable_dt: bool = False
    """Accept an explicit dt above the stability limit (for stability studies)."""
    projection_tol: float | None = None
    """Relative bar-length tolerance of the projection; None: 1e-13 (fp64) or 3e-7 (fp32, just above
    the ~2.4e-7 round-off floor of a fp32 bar length: a tighter one only buys stalled iterations)."""
    max_projection_iters: int = 25
    """Newton iterations allowed per projection before a column is flagged."""
    failure_bar_error: float = 1e-3
    """Relative bar-length error above which a column is frozen and flagged."""
    steps_per_graph: int = 50
    """Steps captured in one CUDA graph."""
    fused: bool | str = "auto"
    """RATTLE as one fused kernel, a thread block per column and several steps per launch
    (:mod:`warp_tensegrity.kernels.fused`); False: one kernel per stage (the only path of the other
    methods). 'auto': for RATTLE on a GPU the fastest measured of the fused step (constraint
    solve by block cyclic reduction or serially on lane 0) and the staged kernels for the band,
    precision and batch (:func:`~warp_tensegrity.engine.choose_path`); the fused step on the CPU;
    staged for Gram bands wider than ``FUSED_MAX_BANDWIDTH`` (generic networks). True: the faster
    fused variant. The paths give the same numbers to round-off."""
    accuracy: float | None = None
    """Target relative error of the pulse measures (speed, amplitude). When given, the engine
    chooses method, precision and dt from the measured work-precision curves
    (:mod:`warp_tensegrity.engine`) and says what it chose in ``BatchResult.info['choices']``."""
    truncate: bool = True
    """Simulate only the prisms a disturbance can reach within t_end (plus a margin), clamping the
    column there; results are padded back to the full column (the far prisms stay at rest).
    Mixed-handed columns with rigid bases are never truncated (see :mod:`warp_tensegrity.engine`)."""
    measure: str = "device"
    """Pulse measures (``BatchResult.measurements``) of :func:`~warp_tensegrity.engine.simulate_batch`:
    'device' (Warp kernels on the device record; only the measures cross to the host), 'host'
    (NumPy reference on a host copy) or 'none'. Except with 'none', the strain record is kept on
    the device (n_out x n_prisms per column) even when record_strain is False."""

    def __post_init__(self):
        if self.method not in METHODS:
            raise SettingsError(f"method = {self.method!r}; choose one of {METHODS}")
        if self.precision not in PRECISIONS:
            raise SettingsError(f"precision = {self.precision!r}; choose one of {PRECISIONS}")
        if not (np.isfinite(self.t_end) and self.t_end > 0):
            raise SettingsError(f"t_end = {self.t_end!r} s must be finite and > 0")
        if isinstance(self.dt, str):
            if self.dt != "auto":
                raise SettingsError(f"dt = {self.dt!r}; give seconds or 'auto'")
        elif not (np.isfinite(self.dt) and 0 < self.dt <= self.t_end):
            raise SettingsError(f"dt = {self.dt!r} s must be finite, > 0 and <= t_end")
        if self.output_interval is not None and not (
            np.isfinite(self.output_interval) and self.output_interval > 0
        ):
            raise SettingsError(f"output_interval = {self.output_interval!r} s must be finite and > 0")
        if self.dt_safety is not None and not (0 < self.dt_safety <= 0.5):
            # measured (analysis/work_precision.md): strong impacts stiffen the prisms and lower the
            # real limit to ~0.45 of 2/omega_max; the default 0.25 keeps a margin of >= 2.5x
            raise SettingsError(
                f"dt_safety = {self.dt_safety!r} must lie in (0, 0.5]: strong impacts lower the stability "
                "limit to ~0.45 of the linear prediction"
            )
        if self.projection_tol is not None and not (0 < self.projection_tol < 1e-2):
            raise SettingsError(f"projection_tol = {self.projection_tol!r} must lie in (0, 1e-2)")
        if int(self.max_projection_iters) < 1:
            raise SettingsError(f"max_projection_iters = {self.max_projection_iters!r} must be >= 1")
        if self.accuracy is not None and not (np.isfinite(self.accuracy) and 0 < self.accuracy < 1):
            raise SettingsError(f"accuracy = {self.accuracy!r} must lie in (0, 1) (relative error of the pulse measures)")
        if self.fused not in (True, False, "auto"):
            raise SettingsError(f"fused = {self.fused!r}; choose true, false or 'auto'")
        if self.fused is True and self.method != "rattle":
            raise SettingsError(f"fused = true needs method = 'rattle' (got method = {self.method!r})")
        if self.measure not in ("device", "host", "none"):
            raise SettingsError(f"measure = {self.measure!r}; choose 'device', 'host' or 'none'")
        if int(self.steps_per_graph) < 1:
            raise SettingsError(f"steps_per_graph = {self.steps_per_graph!r} must be >= 1")

    @property
    def tolerance(self) -> float:
        if self.projection_tol is not None:
            return self.projection_tol
        return 1e-13 if self.precision == "fp64" else 3e-7
