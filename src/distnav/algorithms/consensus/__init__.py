"""Average consensus (paper 003 §3): protocols, schedules, the iteration and the probabilistic measure.

The front doors live in :mod:`distnav.algorithms.consensus.averaging` and are re-exported here, so
``from distnav.algorithms.consensus import average_consensus`` works.
"""

from distnav.algorithms.consensus.averaging import (
    ConsensusResult,
    ConsensusSchedule,
    ConsensusState,
    ConsensusWarning,
    average_consensus,
    consensus_probability,
    consensus_product,
    consensus_schedule,
    iterate_average_consensus,
    second_largest_eigenvalue_modulus,
)

__all__ = [
    "ConsensusResult",
    "ConsensusWarning",
    "ConsensusSchedule",
    "ConsensusState",
    "consensus_schedule",
    "iterate_average_consensus",
    "average_consensus",
    "consensus_product",
    "consensus_probability",
    "second_largest_eigenvalue_modulus",
]
