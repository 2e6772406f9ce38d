"""Covariance-form Kalman filter and batch BLUP — paper 003 §2.2–2.3: the independent references.

* :func:`kalman_filter` — the three-step recursion of §2.2 (eqs. (7)–(12)), the independent reference of the
  information form.
* :func:`batch_blup` — the batch BLUP of ``x_t`` from all data up to ``t`` (Henderson's mixed-model equations
  with ``x_1`` as fixed effect and the system noises as random effects); it initializes the covariance form and
  is a third, non-recursive reference.

The covariance form cannot carry infinite variances, so it reports the batch BLUP (estimable entries only) until
the first epoch at which the whole state is estimable, initializes there from the batch solution, and runs the
three-step recursion afterwards.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from distnav._checks import whole_number
from distnav.algorithms.kalman.dynamics import DynamicModel
from distnav.algorithms.kalman.kernel import EST_TOL, RANK_RTOL, masked_std
from distnav.algorithms.kalman.measurements import MeasurementSeries, check_model
from distnav.algorithms.kalman.results import FilterResult, FilterSeries
from distnav.algorithms.result import TraceBuilder
from distnav.errors import ModelError
from distnav.exchange.core import CommTotals
from distnav.typing import BoolArray, FloatArray, IntArray

__all__ = ["batch_blup", "kalman_filter"]


class _Batch:
    """Henderson's mixed-model equations for ``θ = (x_0, e_1, …, e_t)``: ``x_t = G_t θ``."""

    def __init__(self, p: int) -> None:
        self.p = p
        self.G = np.eye(p)
        self.C = np.zeros((p, p))
        self.b = np.zeros(p)

    def advance(self, dyn: DynamicModel, t: int) -> None:
        F = dyn.transition_at(t)
        H, _St, St_inv = dyn.noise_factor_at(t)
        q = H.shape[1]
        m = self.G.shape[1]
        self.G = np.concatenate([F @ self.G, H], axis=1)
        C = np.zeros((m + q, m + q))
        C[:m, :m] = self.C
        C[m:, m:] = St_inv
        self.C = C
        self.b = np.concatenate([self.b, np.zeros(q)])

    def add(self, N: FloatArray, r: FloatArray) -> None:
        self.C += self.G.T @ N @ self.G
        self.b += self.G.T @ r

    def solve(self) -> tuple[FloatArray, BoolArray, FloatArray]:
        w, U = np.linalg.eigh(0.5 * (self.C + self.C.T))
        keep = w > RANK_RTOL * max(w[-1], 1e-300)
        Cinv = (U[:, keep] / w[keep]) @ U[:, keep].T
        null = U[:, ~keep]
        resid = self.G @ null  # row k of G must be orthogonal to the null space of C
        scale = np.maximum((self.G**2).sum(axis=1), 1e-300)
        est = (resid**2).sum(axis=1) / scale < EST_TOL
        x = self.G @ (Cinv @ self.b)
        P = self.G @ Cinv @ self.G.T
        Psym: FloatArray = 0.5 * (P + P.T)
        return x, est, Psym


def batch_blup(
    dynamics: DynamicModel,
    measurements: MeasurementSeries,
    epoch: int,
    *,
    nodes: Sequence[int] | IntArray | None = None,
) -> tuple[FloatArray, BoolArray, FloatArray]:
    """Batch BLUP of ``x_epoch`` from all data up to ``epoch`` (paper 003 §2.3; Henderson's mixed model).

    ``x_0`` is a fixed effect (no prior: the BLUP start), the reduced system noises ``e_t`` (``d_t = H_t e_t``)
    random effects with variance ``S̃_t``. Returns ``(x̂ (NaN where not estimable), estimable, P)`` where ``P`` is
    the prediction-error variance ``G C⁻¹ Gᵀ`` (meaningful on the estimable block). Cost grows with the epoch:
    a reference, not a filter.
    """
    check_model(dynamics, measurements)
    idx = measurements.node_ids(nodes)
    measurements.check_epoch(epoch)
    b = _Batch(measurements.n_states)
    for t in range(epoch + 1):
        if t > 0:
            b.advance(dynamics, t)
        N, r = measurements.normals(t, idx)
        b.add(N.sum(axis=0), r.sum(axis=0))
    x, est, P = b.solve()
    x[~est] = np.nan
    return x, est, P


# ----------------------------------------------------------------------------------------------- covariance form
def kalman_filter(
    dynamics: DynamicModel,
    measurements: MeasurementSeries,
    *,
    nodes: Sequence[int] | IntArray | None = None,
    max_batch_epochs: int = 500,
    store_matrices: bool = False,
) -> FilterResult:
    """Covariance-form Kalman filter, three-step recursion of paper 003 §2.2 with the BLUP start of §2.3.

    Uses the stacked raw observations of ``nodes`` (default all: the central filter; ``nodes=[i]`` gives node
    ``i``'s local filter). Until the whole state is estimable the batch BLUP (:func:`batch_blup`) supplies the
    estimable entries; at the first epoch where everything is estimable it initializes ``x̂_t|t, P_t|t``
    (eq. (15)), then runs time update ``x̂⁻ = Φ x̂``, ``P⁻ = Φ P Φᵀ + S`` (eqs. (8)–(9)) and measurement update
    ``K = P⁻Aᵀ(R + A P⁻ Aᵀ)⁻¹``, ``x̂ = x̂⁻ + K (y − A x̂⁻)``, ``P = (I − KA) P⁻ (I − KA)ᵀ + K R Kᵀ``
    (eqs. (10)–(12), Joseph form), one node's observations at a time (their noises are uncorrelated, eq. (23)).
    Returns a :class:`FilterResult` (``mode="covariance"``, one row) with ``series``, ``init_epoch`` (the BLUP-start
    epoch, −1 if never) and ``covariance`` (last-epoch ``P_t|t``). Raises :class:`ModelError` if the state is
    still not estimable after
    ``max_batch_epochs`` epochs. Before the initialization every epoch re-solves the batch (O((p + Σ q_t)³)): a
    reference for moderate rank-deficient phases; the information form is the production path.
    """
    max_batch_epochs = whole_number(max_batch_epochs, "max_batch_epochs", error=ModelError)
    check_model(dynamics, measurements)
    idx = measurements.node_ids(nodes)
    p = measurements.n_states
    T = measurements.n_epochs
    xs = np.full((T, 1, p), np.nan)
    ests = np.zeros((T, 1, p), bool)
    covs = np.full((T, 1, p, p), np.nan)
    batch: _Batch | None = _Batch(p)
    x = np.zeros(p)
    P = np.zeros((p, p))
    init_epoch = -1
    for t in range(T):
        A, y, row_node = measurements.observations(t, idx)  # whitened: R = I
        if batch is not None:
            if t > max_batch_epochs:
                raise ModelError(
                    f"state not estimable after {max_batch_epochs} epochs (entries "
                    f"{np.flatnonzero(~ests[t - 1, 0]).tolist()[:10]} never determined)"
                )
            if t > 0:
                batch.advance(dynamics, t)
            batch.add(A.T @ A, A.T @ y)
            xb, est, Pb = batch.solve()
            if est.all():
                x, P, batch, init_epoch = xb, Pb, None, t
            else:
                xs[t, 0, est] = xb[est]
                ests[t, 0] = est
                covs[t, 0] = np.where(est[:, None] & est[None, :], Pb, np.nan)
                continue
        else:
            x, P = _covariance_step(dynamics, t, x, P, A, y, row_node)
        xs[t, 0] = x
        ests[t, 0] = True
        covs[t, 0] = P
    return _covariance_result(xs, ests, covs, init_epoch, store_matrices, measurements.n_nodes)


def _covariance_step(
    dynamics: DynamicModel,
    t: int,
    x: FloatArray,
    P: FloatArray,
    A: FloatArray,
    y: FloatArray,
    row_node: IntArray,
) -> tuple[FloatArray, FloatArray]:
    """Time update (eqs. (8)–(9)) and measurement update (eqs. (10)–(12), Joseph form) of epoch ``t``, one node's
    whitened rows at a time: node blocks are uncorrelated (eq. (23)), so this is exact and O(Σ m_i³) instead of
    O((Σ m_i)³)."""
    p = x.size
    F = dynamics.transition_at(t)
    x = F @ x
    P = F @ P @ F.T + dynamics.noise_cov_at(t)
    for blk in np.split(np.arange(A.shape[0]), np.flatnonzero(np.diff(row_node)) + 1):
        if blk.size == 0:
            continue
        Ab, yb = A[blk], y[blk]
        S = np.eye(blk.size) + Ab @ P @ Ab.T  # Q_vv = R + A P⁻ Aᵀ (eq. (13)), R = I after whitening
        K = np.linalg.solve(S, Ab @ P).T
        x = x + K @ (yb - Ab @ x)
        IKA = np.eye(p) - K @ Ab
        P = IKA @ P @ IKA.T + K @ K.T
    return x, 0.5 * (P + P.T)


def _covariance_result(
    xs: FloatArray, ests: BoolArray, covs: FloatArray, init_epoch: int, store_matrices: bool, n_nodes: int
) -> FilterResult:
    """The :class:`FilterResult` of :func:`kalman_filter` from its per-epoch arrays."""
    T = xs.shape[0]
    series = FilterSeries(
        estimates=xs,
        std=masked_std(np.nan_to_num(covs), ests),
        estimable=ests,
        nodes=np.array([-1]),
        covariance=covs if store_matrices else None,
    )
    return FilterResult(
        estimates=xs[-1],
        converged=init_epoch >= 0,
        iterations=T,
        status="converged" if init_epoch >= 0 else "stopped",
        message=(
            f"covariance-form Kalman filter, BLUP start at epoch {init_epoch}"
            if init_epoch >= 0
            else "covariance-form Kalman filter: state never fully estimable"
        ),
        trace=TraceBuilder().build(),
        comm=CommTotals.empty(n_nodes),
        series=series,
        mode="covariance",
        init_epoch=init_epoch,
        covariance=covs[-1, 0],
    )
