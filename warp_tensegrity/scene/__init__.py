"""Scenes: networks of nodes, bars and cables (:mod:`.network`), T3-prism columns with prestress and
impact conventions (:mod:`.columns`), and batches of columns or networks with per-column
parameters (:mod:`.batch`). Pure NumPy, float64; no Warp."""

from .batch import NetworkBatch, column_batch, column_params, network_batch, omega_max_bound
from .columns import (
    ColumnConfig,
    ColumnScene,
    ColumnTopology,
    build_column,
    column_topology,
    equilibrium_residual,
    prism_heights,
)
from .network import Network, NetworkError

__all__ = [
    "ColumnConfig",
    "ColumnScene",
    "ColumnTopology",
    "Network",
    "NetworkBatch",
    "NetworkError",
    "build_column",
    "column_batch",
    "column_params",
    "column_topology",
    "equilibrium_residual",
    "network_batch",
    "omega_max_bound",
    "prism_heights",
]
