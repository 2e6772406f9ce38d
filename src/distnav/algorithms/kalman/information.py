"""Information filter with the BLUP start — paper 003 §2.3, Fig. 1.

:func:`information_filter` runs the central (network) filter, the single-node *local* filters, or the local
filters fed with exact averages ``n N̄_t, n r̄_t`` (eqs. (25)–(28)), vectorized over nodes, from no prior.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass

import numpy as np

from distnav._settings import runs
from distnav.algorithms.kalman.dynamics import DynamicModel
from distnav.algorithms.kalman.kernel import InformationKernel, masked_std
from distnav.algorithms.kalman.measurements import MeasurementSeries, check_model
from distnav.algorithms.kalman.results import FilterMode, FilterResult, FilterSeries
from distnav.algorithms.result import TraceBuilder
from distnav.errors import ModelError
from distnav.exchange.core import CommTotals
from distnav.typing import BoolArray, FloatArray, IntArray

__all__ = [
    "FilterState",
    "central_filter",
    "exact_average_filters",
    "information_filter",
    "iterate_information_filter",
    "local_filters",
]


@dataclass(frozen=True, eq=False)
class FilterState:
    """State of a bank of information filters after the measurement update of ``epoch``."""

    epoch: int
    information: FloatArray
    info_vector: FloatArray
    estimates: FloatArray
    estimable: BoolArray
    covariance: FloatArray


_MODES = ("central", "local", "exact_average")


def iterate_information_filter(
    dynamics: DynamicModel,
    measurements: MeasurementSeries,
    *,
    mode: FilterMode = "central",
    nodes: Sequence[int] | IntArray | None = None,
) -> Iterator[FilterState]:
    """Yield the information filter state (paper 003 Fig. 1) after each epoch's measurement update.

    mode "central": one filter fed ``N_t = Σ_i N_i,t``, ``r_t = Σ_i r_i,t`` over ``nodes`` (default all; eq. (25));
    "local": one filter per node fed only its own ``N_i,t, r_i,t`` (single-receiver solutions of §5.3);
    "exact_average": one filter per node fed ``n N̄_t, n r̄_t`` (eqs. (27)–(28)); identical to "central".
    """
    if mode not in _MODES:
        raise ModelError(f"mode must be one of {', '.join(_MODES)}, got {mode!r}")
    check_model(dynamics, measurements)
    idx = measurements.node_ids(nodes)
    if idx.size == 0:
        raise ModelError("no nodes selected")
    p = measurements.n_states
    rows = 1 if mode == "central" else idx.size
    ker = InformationKernel(rows, p, track_error=False)
    for t in range(measurements.n_epochs):
        if t > 0:
            ker.time_update(dynamics, t)
        N, r = measurements.normals(t, idx)
        if mode == "central":
            ker.measurement_update(N.sum(axis=0, keepdims=True), r.sum(axis=0, keepdims=True))
        elif mode == "local":
            ker.measurement_update(N, r)
        else:
            n = idx.size
            ker.measurement_update(
                np.broadcast_to(N.mean(axis=0), N.shape), np.broadcast_to(r.mean(axis=0), r.shape), scale=float(n)
            )
        x, est, inv, _ = ker.estimates()
        yield FilterState(t, ker.I, ker.i, x, est, inv)


@runs(iterate_information_filter, adds=("store_matrices",))
def information_filter(
    dynamics: DynamicModel,
    measurements: MeasurementSeries,
    *,
    mode: FilterMode = "central",
    nodes: Sequence[int] | IntArray | None = None,
    store_matrices: bool = False,
) -> FilterResult:
    """Run :func:`iterate_information_filter` over all epochs.

    Returns a :class:`FilterResult`: ``estimates`` = last-epoch estimates (rows = filters), ``iterations`` =
    epochs, ``series`` = :class:`FilterSeries`, ``information`` / ``info_vector`` = final ``I_t|t``, ``i_t|t``,
    ``mode``. Trace: ``n_estimable`` (epochs × rows).
    """
    idx = measurements.node_ids(nodes)
    xs: list[FloatArray] = []
    stds: list[FloatArray] = []
    ests: list[BoolArray] = []
    covs: list[FloatArray] = []
    infos: list[FloatArray] = []
    tb = TraceBuilder()
    last: FilterState | None = None
    for st in iterate_information_filter(dynamics, measurements, mode=mode, nodes=idx):
        xs.append(st.estimates)
        stds.append(masked_std(st.covariance, st.estimable))
        ests.append(st.estimable)
        if store_matrices:
            covs.append(st.covariance)
            infos.append(st.information)
        tb.add(n_estimable=st.estimable.sum(axis=1))
        last = st
    assert last is not None
    series = FilterSeries(
        estimates=np.stack(xs),
        std=np.stack(stds),
        estimable=np.stack(ests),
        nodes=np.array([-1]) if mode == "central" else idx,
        covariance=np.stack(covs) if store_matrices else None,
        information=np.stack(infos) if store_matrices else None,
    )
    complete = bool(last.estimable.all())
    return FilterResult(
        estimates=last.estimates,
        converged=complete,
        iterations=measurements.n_epochs,
        status="converged" if complete else "stopped",
        message=f"{mode} information filter over {measurements.n_epochs} epochs; "
        f"{int(last.estimable.sum())}/{last.estimable.size} entries estimable at the last epoch",
        trace=tb.build(),
        comm=CommTotals.empty(measurements.n_nodes),
        series=series,
        information=last.information,
        info_vector=last.info_vector,
        mode=mode,
    )


@runs(iterate_information_filter, drops=("mode",), adds=("store_matrices",))
def central_filter(
    dynamics: DynamicModel,
    measurements: MeasurementSeries,
    *,
    nodes: Sequence[int] | IntArray | None = None,
    store_matrices: bool = False,
) -> FilterResult:
    """The central (network, fusion-centre) information filter (eq. (25)); one row.

    Examples
    --------
    A constant (no system noise) observed once per epoch by each of three nodes, unit variance: after two epochs
    the estimate is the mean of the six observations and its standard deviation ``1/√6``:

    >>> import numpy as np
    >>> from distnav.algorithms.kalman import DynamicModel, ObservationSeries, central_filter
    >>> y = [[4.0, 5.0, 6.0], [5.5, 4.5, 5.0]]  # epochs × nodes
    >>> series = ObservationSeries(1, [[(np.ones((1, 1)), np.ones(1), np.array([v])) for v in row] for row in y])
    >>> res = central_filter(DynamicModel(1), series)
    >>> round(float(res.estimates[0, 0]), 9), round(float(res.series.std[-1, 0, 0] * np.sqrt(6)), 9)
    (5.0, 1.0)
    """
    return information_filter(dynamics, measurements, mode="central", nodes=nodes, store_matrices=store_matrices)


@runs(iterate_information_filter, drops=("mode",), adds=("store_matrices",))
def local_filters(
    dynamics: DynamicModel,
    measurements: MeasurementSeries,
    *,
    nodes: Sequence[int] | IntArray | None = None,
    store_matrices: bool = False,
) -> FilterResult:
    """Single-node filters, each with its own data only (paper 003 §5.3); one row per node."""
    return information_filter(dynamics, measurements, mode="local", nodes=nodes, store_matrices=store_matrices)


@runs(iterate_information_filter, drops=("mode",), adds=("store_matrices",))
def exact_average_filters(
    dynamics: DynamicModel,
    measurements: MeasurementSeries,
    *,
    nodes: Sequence[int] | IntArray | None = None,
    store_matrices: bool = False,
) -> FilterResult:
    """Local filters fed with the exact averages ``n N̄_t``, ``n r̄_t`` (eqs. (26)–(28)): equal to the central one."""
    return information_filter(dynamics, measurements, mode="exact_average", nodes=nodes, store_matrices=store_matrices)
