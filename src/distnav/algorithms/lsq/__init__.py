"""Linear least squares over a network (paper 000 §2–4): the BLUE, the method of multipliers and ADMM.

Rooms, from the bottom up: :mod:`~distnav.algorithms.lsq.blue` (the problem, the centralized BLUE with its rank
check, the method of multipliers and single-consensus ADMM), :mod:`~distnav.algorithms.lsq.xupdate` (the x-update
methods), :mod:`~distnav.algorithms.lsq.kernel` (the ADMM iteration over a block of nodes),
:mod:`~distnav.algorithms.lsq.driver` (options, stopping, results), :mod:`~distnav.algorithms.lsq.admm` (the front
door), :mod:`~distnav.algorithms.lsq.nonlinear` (linearized and nonlinear ADMM) and :mod:`~distnav.algorithms.lsq.qc`
(distributed precision and data snooping). The problem and the BLUE are re-exported here.
"""

from distnav.algorithms.lsq.blue import (
    BlueSolution,
    LinearProblem,
    MultiplierResult,
    MultiplierState,
    blue,
    dual_function,
    inestimable_directions,
    iterate_method_of_multipliers,
    iterate_single_consensus_admm,
    method_of_multipliers,
    multiplier_step,
    null_space_directions,
    single_consensus_admm,
    weight_matrix,
)

__all__ = [
    "LinearProblem",
    "BlueSolution",
    "weight_matrix",
    "null_space_directions",
    "inestimable_directions",
    "blue",
    "MultiplierResult",
    "dual_function",
    "multiplier_step",
    "MultiplierState",
    "iterate_method_of_multipliers",
    "method_of_multipliers",
    "iterate_single_consensus_admm",
    "single_consensus_admm",
]
