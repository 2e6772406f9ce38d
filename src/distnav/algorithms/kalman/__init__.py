"""Kalman filter (covariance form) and information filter with a BLUP start — paper 003 §2.

Model (paper 003 eqs. (2)–(6), (22)–(23)); epochs are 0-based here (epoch ``t`` = the paper's ``t+1``):

* dynamic model, common to all nodes: ``x_t = Φ_t x_{t−1} + d_t``, ``D(d_t) = S_t = H_t S̃_t H_tᵀ`` with
  ``H_t`` of full column rank and ``S̃_t`` positive definite (eq. (19); a singular ``S_t``, e.g. constant
  biases, is the normal case). :class:`DynamicModel`.
* measurement model, node ``i`` at epoch ``t``: ``y_i,t = A_i,t x_t + ε_i,t``, ``D(ε_i,t) = R_i,t``, mutually
  uncorrelated over nodes and epochs. The rows of ``A_i,t`` may change from epoch to epoch (satellites rise and
  set); a state entry no node observes simply has zero columns. :class:`ObservationSeries` holds
  ``(A_i,t, R_i,t, y_i,t)``; :class:`NormalSeries` holds the normals ``N_i,t = A_i,tᵀ R_i,t⁻¹ A_i,t`` and
  ``r_i,t = A_i,tᵀ R_i,t⁻¹ y_i,t`` (eq. (24)) directly.

Filters (all start from *no prior*: the BLUP start of §2.3):

* :func:`information_filter` — Fig. 1 with the singular-noise time update of eqs. (19)–(21), for the central
  (network) filter, the single-node *local* filters, or the local filters fed with exact averages
  ``n N̄_t, n r̄_t`` (eqs. (26)–(28)). Vectorized over nodes.
* :func:`kalman_filter` — the covariance-form three-step recursion of §2.2 (eqs. (7)–(12)), used as the
  independent reference of the information form.
* :func:`batch_blup` — the batch BLUP of ``x_t`` from all data up to ``t`` (Henderson's mixed-model
  equations with ``x_1`` as fixed effect and the system noises as random effects); it initializes the
  covariance form and is a third, non-recursive reference.

**Epochs before a parameter is estimable.** The information form carries singular information without
difficulty: ``I_{t|t}`` may be rank deficient (zero information start, an unobserved entry), and the time update
only inverts ``H_tᵀ M_t H_t + S̃_t⁻¹``, which is always positive definite. Estimates are reported per entry:
entry ``k`` is *estimable* when the unit vector ``e_k`` lies in the range of ``I_{t|t}``; its estimate is
``e_kᵀ I⁺ i`` and its error variance ``(I⁺)_kk`` (unique for estimable entries); every other entry is reported as
``NaN`` and flagged in :attr:`FilterSeries.estimable`. The covariance form cannot carry infinite variances, so it
reports the batch BLUP (estimable entries only) until the first epoch at which the whole state is estimable,
initializes there from the batch solution, and runs the three-step recursion afterwards.

The package is split by role (like Stone Soup's models / predictor / updater):

* :mod:`~distnav.algorithms.kalman.dynamics` — :class:`DynamicModel`, :func:`noise_factor`, :func:`simulate_states`;
* :mod:`~distnav.algorithms.kalman.measurements` — the measurement series and :func:`normal_equations`;
* :mod:`~distnav.algorithms.kalman.kernel` — :class:`InformationKernel` (shared with the CKF) and
  :func:`pseudo_inverse_psd`;
* :mod:`~distnav.algorithms.kalman.information` — the information-form filter with the BLUP start;
* :mod:`~distnav.algorithms.kalman.covariance` — :func:`kalman_filter` and :func:`batch_blup`;
* :mod:`~distnav.algorithms.kalman.results` — :class:`FilterSeries`, :class:`FilterResult`, :func:`std_ratio`.
"""

from __future__ import annotations

from distnav.algorithms.kalman.covariance import batch_blup, kalman_filter
from distnav.algorithms.kalman.dynamics import DynamicModel, noise_factor, simulate_states
from distnav.algorithms.kalman.information import (
    FilterState,
    central_filter,
    exact_average_filters,
    information_filter,
    iterate_information_filter,
    local_filters,
)
from distnav.algorithms.kalman.kernel import InformationKernel, masked_std, pseudo_inverse_psd
from distnav.algorithms.kalman.measurements import (
    FunctionSeries,
    MeasurementSeries,
    NodeData,
    NodeEpoch,
    NormalSeries,
    ObservationSeries,
    check_model,
    normal_equations,
)
from distnav.algorithms.kalman.results import FilterMode, FilterResult, FilterSeries, InnovationTests, std_ratio

__all__ = [
    "DynamicModel",
    "NodeEpoch",
    "NodeData",
    "MeasurementSeries",
    "ObservationSeries",
    "NormalSeries",
    "FunctionSeries",
    "FilterSeries",
    "FilterState",
    "FilterMode",
    "FilterResult",
    "InnovationTests",
    "InformationKernel",
    "check_model",
    "masked_std",
    "noise_factor",
    "normal_equations",
    "simulate_states",
    "iterate_information_filter",
    "information_filter",
    "central_filter",
    "local_filters",
    "exact_average_filters",
    "kalman_filter",
    "batch_blup",
    "std_ratio",
    "pseudo_inverse_psd",
]
