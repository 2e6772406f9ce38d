"""The CKF's design tools: ``k_n`` from the two time scales, the α factor and the error-variance recursion of Fig. 7
alone (paper 003 §4.1–§4.2) — no data, no messages. Re-exported by :mod:`distnav.algorithms.kalman.ckf`."""

from __future__ import annotations

import math

import numpy as np

from distnav._checks import real_number
from distnav.algorithms.kalman.dynamics import DynamicModel
from distnav.algorithms.kalman.kernel import InformationKernel, masked_std, pseudo_inverse_psd
from distnav.algorithms.kalman.measurements import MeasurementSeries, check_model
from distnav.algorithms.kalman.results import FilterSeries, std_ratio
from distnav.errors import ModelError, WeightsError
from distnav.typing import ArrayLike, BoolArray, FloatArray

__all__ = ["consensus_rounds", "alpha_factor", "ckf_error_variance", "ckf_std_ratio"]


def consensus_rounds(sampling_interval_s: float, sending_interval_s: float) -> int:
    """``k_n = ⌊Δ/δ⌋``: consensus rounds that fit in one sampling interval (paper 003 §4.1, Fig. 5).

    Δ = 60 s with δ = 15, 10, 5 s gives 4, 6, 12 (paper 003 §5.2).
    """
    D = real_number(
        sampling_interval_s, "sampling_interval_s (the sampling interval Δ)", positive=True, unit="s", error=ModelError
    )
    d = real_number(
        sending_interval_s, "sending_interval_s (the sending interval δ)", positive=True, unit="s", error=ModelError
    )
    if d > D:
        raise ModelError(
            f"sending_interval_s = {d} s (δ) exceeds sampling_interval_s = {D} s (Δ): no consensus round "
            f"fits in an epoch (the CKF needs δ ≤ Δ, paper 003 §4.1)"
        )
    return int(math.floor(D / d + 1e-9))


def alpha_factor(product: ArrayLike) -> FloatArray:
    """``α_i = n Σ_j l_ij²`` per node (paper 003 eq. (46)); ``α_i ≥ 1`` with equality iff ``l_i = e/n`` (eq. (48))."""
    L = np.asarray(product, dtype=float)
    if L.ndim != 2 or L.shape[0] != L.shape[1]:
        raise WeightsError(f"product matrix must be square, got shape {L.shape}")
    alpha: FloatArray = L.shape[0] * (L**2).sum(axis=1)
    return alpha


def ckf_error_variance(
    dynamics: DynamicModel, measurements: MeasurementSeries, product: ArrayLike, *, store_matrices: bool = False
) -> FilterSeries:
    """The CKF error-variance recursion of Fig. 7 alone, for every node and epoch, from ``L`` (= ``W^(k_n)``).

    No data and no messages: the consensus normals are ``N_i^(k_n) = Σ_j l_ij N_j`` (eq. (35)), so ``I_i,t|t``
    and ``P_i,t|t`` follow from the normal matrices and ``L`` — the a-priori design tool of paper 003 §4.2.
    Returns a :class:`FilterSeries` with ``std`` = sqrt diag ``P_i,t|t`` and ``nominal_std`` = sqrt diag
    ``I_i,t|t⁻¹`` (``estimates`` are NaN).

    Cost per epoch: one dense GEMM ``[L; L∘L] · tri(N)`` of (2n × n) by (n × p(p+1)/2) — O(n² p²) flops, the
    dominant term (≈ 1.1 GFLOP at n = 1,000, p = 33) — plus O(n p³) for the batched time update and inverses;
    memory O(n² + n p²). Measured in ``benchmarks/bench_ckf.py`` against a bare batched-numpy implementation of the
    same recursion (issue 17: ≤ 2×). For the node-local form that needs no global knowledge see
    ``ckf(..., local_precision=...)``.

    Examples
    --------
    Three nodes on a path, two Metropolis rounds per epoch: the recursion alone gives the same standard deviations
    as the CKF run on the data (and the middle node, which averages best, is the most precise):

    >>> import numpy as np
    >>> from distnav.algorithms.consensus.averaging import consensus_product, consensus_schedule
    >>> from distnav.algorithms.kalman import DynamicModel, ObservationSeries
    >>> from distnav.algorithms.kalman.ckf import ckf, ckf_error_variance
    >>> from distnav.network import builders
    >>> rng = np.random.default_rng(1)
    >>> dyn = DynamicModel(1, noise_cov=np.array([[0.01]]))
    >>> epochs = [[(np.ones((1, 1)), np.ones(1), rng.normal(5.0, 1.0, 1)) for _ in range(3)] for _ in range(4)]
    >>> series = ObservationSeries(1, epochs)
    >>> L = consensus_product(consensus_schedule(builders.path(3), "P3"), 2)
    >>> design = ckf_error_variance(dyn, series, L)
    >>> bool(np.allclose(design.std, ckf(dyn, series, graph=builders.path(3), rounds=2).series.std))
    True
    >>> design.std[-1].ravel().round(4).tolist()
    [0.3413, 0.3028, 0.3413]
    """
    check_model(dynamics, measurements)
    n, p = measurements.n_nodes, measurements.n_states
    L = np.asarray(product, dtype=float)
    if L.shape != (n, n):
        raise ModelError(f"product matrix must be {n}×{n}, got {L.shape}")
    LL = np.concatenate([L, L**2])  # one GEMM per epoch gives Σ_j l_ij N_j and Σ_j l_ij² N_j
    iu = np.triu_indices(p)
    ker = InformationKernel(n, p, track_error=True)
    T = measurements.n_epochs
    stds: list[FloatArray] = []
    nstds: list[FloatArray] = []
    ests: list[BoolArray] = []
    covs: list[FloatArray] = []
    infos: list[FloatArray] = []
    for t in range(T):
        if t > 0:
            ker.time_update(dynamics, t)
        N, _ = measurements.normals(t)
        tri = N[:, iu[0], iu[1]]
        both = LL @ tri
        Nk = np.zeros((n, p, p))
        Nk[:, iu[0], iu[1]] = both[:n]
        Nk[:, iu[1], iu[0]] = both[:n]
        extra = np.zeros((n, p, p))
        extra[:, iu[0], iu[1]] = (n * n) * both[n:]
        extra[:, iu[1], iu[0]] = (n * n) * both[n:]
        ker.measurement_update(Nk, np.zeros((n, p)), scale=float(n), extra_error=extra)
        inv, est = pseudo_inverse_psd(ker.I)
        assert ker.Q is not None
        P = inv @ ker.Q @ inv
        stds.append(masked_std(P, est))
        nstds.append(masked_std(inv, est))
        ests.append(est)
        if store_matrices:
            covs.append(0.5 * (P + np.swapaxes(P, 1, 2)))
            infos.append(ker.I)
    std = np.stack(stds)
    return FilterSeries(
        estimates=np.full_like(std, np.nan),
        std=std,
        estimable=np.stack(ests),
        nodes=np.arange(n),
        nominal_std=np.stack(nstds),
        covariance=np.stack(covs) if store_matrices else None,
        information=np.stack(infos) if store_matrices else None,
    )


def ckf_std_ratio(ckf_series: FilterSeries, central_series: FilterSeries) -> FloatArray:
    """CKF-to-central standard-deviation ratios per epoch, node and parameter (paper 003 Fig. 12), (T, n, p)."""
    return std_ratio(ckf_series, central_series)
