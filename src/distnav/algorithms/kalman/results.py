"""Results of the Kalman/CKF family: per-epoch series of a bank of filters and the typed :class:`FilterResult`."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from distnav.algorithms.result import ObservationTests, Precision, SolverResult
from distnav.errors import ModelError
from distnav.typing import BoolArray, FloatArray, IntArray

__all__ = ["FilterMode", "FilterResult", "FilterSeries", "InnovationTests", "std_ratio"]

FilterMode = Literal["central", "local", "exact_average", "covariance", "ckf"]
"""Which filter produced a :class:`FilterResult`: the information filter's three modes, the covariance form
(:func:`~distnav.algorithms.kalman.kalman_filter`) or the consensus Kalman filter."""


@dataclass(frozen=True, eq=False)
class FilterSeries:
    """Per-epoch outputs of a bank of filters (rows = nodes, or one row for the central filter).

    estimates : (T, k, p) ``x̂_t|t``; NaN where the entry is not (yet) estimable.
    std : (T, k, p) standard deviations of the prediction errors ``x_t − x̂_t|t`` (NaN where not estimable).
        For the CKF these come from the error-variance recursion (Fig. 7), not from ``I_i⁻¹``.
    estimable : (T, k, p) bool.
    nominal_std : (T, k, p) ``sqrt(diag I⁻¹)``, only for the CKF (where it is *not* the error std).
    covariance, information : (T, k, p, p) error variance matrices and information matrices when stored.
    nodes : global node id of each row (``-1`` for the central filter).
    """

    estimates: FloatArray
    std: FloatArray
    estimable: BoolArray
    nodes: IntArray
    nominal_std: FloatArray | None = None
    covariance: FloatArray | None = None
    information: FloatArray | None = None

    @property
    def n_epochs(self) -> int:
        """Number of epochs ``T``."""
        return int(self.estimates.shape[0])


def std_ratio(series: FilterSeries, reference: FilterSeries) -> FloatArray:
    """Standard-deviation ratios ``std(series) / std(reference)`` per epoch, row and parameter, (T, k, p).

    ``reference`` is usually the central filter (one row, broadcast over the nodes): this gives the
    local-to-central and CKF-to-central ratios of paper 003 Figs. 11–12. NaN where either is not estimable.
    """
    a, b = series.std, reference.std
    if a.shape[0] != b.shape[0] or a.shape[2] != b.shape[2]:
        raise ModelError(f"series of shape {a.shape} and reference of shape {b.shape} do not match")
    if b.shape[1] not in (1, a.shape[1]):
        raise ModelError(f"reference must have one row or {a.shape[1]} rows, got {b.shape[1]}")
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio: FloatArray = a / b
    return ratio


@dataclass(frozen=True, eq=False, kw_only=True)
class InnovationTests(ObservationTests):
    """Local innovation tests of a filter: :class:`ObservationTests` of every tested observation, plus where it is.

    One entry per tested (whitened) observation row, in the order epoch, node, row. ``w`` is the statistic of the
    first test at that node and epoch (before any rejection there), ``flagged`` whether it exceeded the critical
    value then, ``removed`` the indices (into these arrays) rejected before the consensus.

    Extra attributes: ``epoch`` and ``row`` (row within the node's observations of that epoch) of each entry;
    ``chi2`` (T, n) local χ² of the predicted residuals (NaN: nothing tested), ``chi2_dof`` (T, n) their number,
    ``chi2_flagged`` (T, n) χ² above its critical value at the same level.
    """

    epoch: IntArray
    row: IntArray
    chi2: FloatArray
    chi2_dof: IntArray
    chi2_flagged: BoolArray

    @property
    def n_removed(self) -> int:
        """Number of rejected observations."""
        return len(self.removed)


@dataclass(frozen=True, eq=False, kw_only=True)
class FilterResult(SolverResult):
    """Outcome of a Kalman-family filter: the :class:`SolverResult` fields plus what the filters return.

    ``estimates`` are the last-epoch estimates (one row per filter), ``iterations`` the number of epochs.

    Attributes
    ----------
    series : per-epoch :class:`FilterSeries` of every row.
    mode : :data:`FilterMode`, which filter this is.
    information, info_vector : last-epoch ``I_t|t`` (k×p×p) and ``i_t|t`` (k×p) of the information forms.
    covariance : last-epoch error variance: ``P_t|t`` (p×p) of the covariance form, ``P_i,t|t`` (n×p×p) of the
        CKF's Fig. 7 recursion (``None`` without it).
    init_epoch : covariance form only: the epoch at which the BLUP start initialized the recursion (−1: never).
    rounds : CKF only: consensus rounds per epoch ``k_n``.
    product : CKF only: the dense consensus product ``L = W_(k_n) ⋯ W_(1)`` (eq. (33)); ``None`` without the
        variance recursion.
    alpha : CKF only: ``α_i = n Σ_j l_ij²`` (eq. (46)).
    precision : CKF only: the node-local :class:`Precision` of every node at the last epoch (``kind`` "exact" or
        "bound", ``comm`` = the bytes it added to the consensus messages); ``None`` when not computed.
    local_std : CKF only: (T, n, p) standard deviations from the node-local precision (``None`` without it).
    tests : CKF only: the local :class:`InnovationTests`, ``None`` when not run.
    """

    series: FilterSeries
    mode: FilterMode
    information: FloatArray | None = None
    info_vector: FloatArray | None = None
    covariance: FloatArray | None = None
    init_epoch: int | None = None
    rounds: int | None = None
    product: FloatArray | None = None
    alpha: FloatArray | None = None
    precision: Precision | None = None
    local_std: FloatArray | None = None
    tests: InnovationTests | None = None
