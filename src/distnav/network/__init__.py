"""Communication graphs, switching graphs, builders and consensus weights.

The names below are imported on first use (PEP 562), so ``from distnav.network.graph import Graph`` — what the
exchange and an MPI job need — does not pay for the builders and weights (and the parts of scipy they use).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from distnav.network import builders
    from distnav.network.graph import Graph, SwitchingGraph
    from distnav.network.partition import partition_nodes, rcm_order
    from distnav.network.weights import (
        ConsensusWeights,
        WeightsReport,
        check_weights,
        consensus_weights,
        koppanyi_weights,
        metropolis_hastings,
        protocol_weights,
        second_largest_eigenvalue_modulus,
    )

_WHERE = {
    "Graph": "graph",
    "SwitchingGraph": "graph",
    "partition_nodes": "partition",
    "rcm_order": "partition",
    "ConsensusWeights": "weights",
    "WeightsReport": "weights",
    "check_weights": "weights",
    "consensus_weights": "weights",
    "protocol_weights": "weights",
    "metropolis_hastings": "weights",
    "koppanyi_weights": "weights",
    "second_largest_eigenvalue_modulus": "weights",
}

__all__ = [
    "Graph",
    "SwitchingGraph",
    "builders",
    "partition_nodes",
    "rcm_order",
    "ConsensusWeights",
    "WeightsReport",
    "check_weights",
    "consensus_weights",
    "protocol_weights",
    "metropolis_hastings",
    "koppanyi_weights",
    "second_largest_eigenvalue_modulus",
]


def __getattr__(name: str) -> Any:
    if name == "builders":
        value: Any = importlib.import_module("distnav.network.builders")
    elif name in _WHERE:
        value = getattr(importlib.import_module(f"distnav.network.{_WHERE[name]}"), name)
    else:
        raise AttributeError(f"module 'distnav.network' has no attribute {name!r}")
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
