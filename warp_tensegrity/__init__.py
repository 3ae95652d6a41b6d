"""warp_tensegrity: batched wave dynamics of tensegrity lattices on NVIDIA Warp.

Data path: scene builder (:mod:`columns`, :mod:`network`) -> batch of per-column parameters
(:mod:`batch`) -> device model arrays (:mod:`model`) -> integrator step (:mod:`kernels`,
:mod:`simulate`) -> measurement (:mod:`measure`) -> sweep (:mod:`spec`, :mod:`sweep`) ->
xarray/netCDF (:mod:`dataset`) -> figures (:mod:`plot`) and analysis (``analysis/``).

``__version__`` is the build's version (setuptools-scm; :mod:`provenance`).
"""

from .batch import NetworkBatch, column_batch, network_batch
from .columns import ColumnConfig, ColumnScene, build_column, column_topology
from .network import Network, NetworkError
from .settings import COLUMN_PARAMETERS, BatchResult, RunSettings, SettingsError

__all__ = [
    "__version__",
    "BatchResult",
    "COLUMN_PARAMETERS",
    "ColumnConfig",
    "ColumnScene",
    "Network",
    "NetworkBatch",
    "NetworkError",
    "RunSettings",
    "SettingsError",
    "build_column",
    "column_batch",
    "column_topology",
    "network_batch",
    "run_batch",
    "simulate_batch",
]


def __getattr__(name):
    # the Warp-backed entry points load lazily so `import warp_tensegrity` stays instant
    if name == "__version__":
        from .provenance import package_version

        return package_version()
    if name in ("simulate_batch", "run_batch", "estimate_batch"):
        from .runtime import init_warp

        init_warp()  # no CUDA-driver warning on a CPU-only machine
        from . import simulate

        return getattr(simulate, name)
    raise AttributeError(name)
