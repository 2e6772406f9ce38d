"""Communication graphs, switching graphs, builders and consensus weights."""

from __future__ import annotations

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
