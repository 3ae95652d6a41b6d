"""warp_tensegrity: batched wave dynamics of tensegrity lattices on NVIDIA Warp.

Data path (``docs/architecture.md``): scene (:mod:`.scene`: network, columns, batch) -> policy
(:mod:`.policy`: :func:`decide` -> :class:`RunPlan`, the cost model, calibration) -> device model
(:mod:`.model`) -> kernels -> :mod:`.integrate` (the step) -> :mod:`.engine` (runs a plan) ->
:mod:`.measure` -> :mod:`.io` (CF datasets) -> :mod:`.sweep` -> :mod:`.cli`.
Importing the package (and reading a spec) does not import Warp; the first run does.
Figures: :mod:`.plot`. ``__version__`` is the build's version (setuptools-scm; :mod:`.provenance`).
"""

from .engine import run_batch, simulate_batch
from .policy.calibrate import estimate_batch  # the run plan, with time and memory from a probe on the device
from .policy.decide import RunPlan, decide
from .measure import measure_pulse
from .scene import (
    ColumnConfig,
    ColumnScene,
    Network,
    NetworkBatch,
    NetworkError,
    build_column,
    column_batch,
    column_topology,
    network_batch,
)
from .result import BatchResult
from .options import COLUMN_PARAMETERS, Profile, RunSettings, SettingsError
from .provenance import package_version
from .types import Method, Status

__all__ = [
    "__version__",
    "BatchResult",
    "COLUMN_PARAMETERS",
    "ColumnConfig",
    "ColumnScene",
    "Method",
    "Network",
    "NetworkBatch",
    "NetworkError",
    "Profile",
    "RunPlan",
    "RunSettings",
    "SettingsError",
    "Status",
    "build_column",
    "column_batch",
    "column_topology",
    "decide",
    "estimate_batch",
    "measure_pulse",
    "network_batch",
    "run_batch",
    "simulate_batch",
]


def __getattr__(name):
    if name == "__version__":  # the build's version (setuptools-scm; provenance.py)
        return package_version()
    raise AttributeError(name)
