"""The satellite code-bias model of paper 000 §5: triple-frequency observable (24), between-satellite
differencing (26), S-basis with receiver 1 lumped into the satellite biases, per-station normal equations, the
centralized solution and its recursive (Kalman, constant-parameter) form over time.

Per station ``i`` and epoch ``t`` the code-bias observable ``y = ȳ₃ − ȳ_IF − μ₃ ȳ_GF`` of every visible satellite
``s`` obeys ``E(y_i^s) = b_i + b^s`` (receiver and satellite code-bias combinations; geometry, clocks, troposphere
and first-order ionosphere are gone). With the S-basis of §5.1 the estimable parameters are
``x_s = b^s + b_1`` (receiver 1 = the *reference* station) and

* reference station:  ``E(y_1) = Ā_1 x``,           ``R_1 = Q_1``            (undifferenced),
* other stations:     ``E(D_mᵀ y_i) = D_mᵀ Ā_i x``, ``R_i = D_mᵀ Q_i D_m``   (between-satellite differences),

``Q_i = diag(σ_s²)`` with ``σ_s²`` the variance of the combination (full propagation of the three code
variances). The normal-equation contribution of a differenced epoch equals
``N = Q⁻¹ − Q⁻¹e(eᵀQ⁻¹e)⁻¹eᵀQ⁻¹`` (elimination of the epoch's receiver term), which is what
:meth:`CodeBiasData.node_normals` computes in batch; :meth:`CodeBiasData.node_system` builds the explicit
``(A_i, R_i, y_i)`` of eqs. (24)/(26) (tests check both agree).

Units: metres throughout (``*_m``); :data:`~distnav.models.gnss.constants.NS_TO_M` converts to ns.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from distnav.errors import ModelError
from distnav.models.gnss.constants import NS_TO_M
from distnav.models.gnss.observables import (
    between_satellite_operator,
    codebias_coefficients,
    elevation_sigma,
    sbasis_design,
)

__all__ = [
    "CodeBiasData",
    "CodeBiasSolution",
    "combination_sigma",
    "sat_bias_combination",
]


def combination_sigma(
    el_rad: np.ndarray, sigma0_m: float, weighting: str = "euler-goad", mus: Sequence[float] | np.ndarray | None = None
) -> np.ndarray:
    """Standard deviation of the code-bias observable (24) from three uncorrelated codes with the same
    elevation-dependent σ(θ): ``σ_y = σ(θ)·‖c‖`` (c the combination coefficients, ‖c‖ ≈ 1.60 for GPS L1/L2/L5)."""
    c = codebias_coefficients(mus)
    return elevation_sigma(el_rad, sigma0_m, weighting) * float(np.sqrt(np.sum(c * c)))


def sat_bias_combination(
    dsb12: np.ndarray | float, dsb13: np.ndarray | float, mus: Sequence[float] | np.ndarray | None = None
) -> np.ndarray:
    """The code-bias combination ``b = c₁d₁ + c₂d₂ + d₃`` from DSBs ``d₁−d₂`` and ``d₁−d₃`` (any unit).

    Since ``c₁ + c₂ + 1 = 0``: ``b = −c₂ (d₁ − d₂) − (d₁ − d₃)``. Used to turn published DSBs (Bias-SINEX, additive
    biases) into the quantity the network estimates.
    """
    c = codebias_coefficients(mus)
    return np.asarray(-c[1] * np.asarray(dsb12, dtype=float) - np.asarray(dsb13, dtype=float))


@dataclass(frozen=True)
class CodeBiasSolution:
    """A code-bias estimate ``x_m`` over satellites ``svs`` with covariance ``cov_m2`` (metres)."""

    svs: tuple[str, ...]
    x_m: np.ndarray
    cov_m2: np.ndarray
    reference_station: str

    @property
    def sigma_m(self) -> np.ndarray:
        return np.sqrt(np.diag(self.cov_m2))

    @property
    def x_ns(self) -> np.ndarray:
        return self.x_m / NS_TO_M

    @property
    def sigma_ns(self) -> np.ndarray:
        return self.sigma_m / NS_TO_M


@dataclass(frozen=True)
class CodeBiasData:
    """Code-bias observables (24) of a network: ``y_m`` and ``sigma_m`` are ``(n, T, p)`` (station, epoch,
    satellite), NaN where a satellite is not observed (below the mask or a code missing).

    ``reference`` is the station whose bias is lumped into the satellite biases (S-basis, paper 000 §5.1).
    ``truth_m`` (simulations only) is the true estimable ``x``.
    """

    stations: tuple[str, ...]
    svs: tuple[str, ...]
    t_gps_s: np.ndarray
    y_m: np.ndarray
    sigma_m: np.ndarray
    reference: int = 0
    elevation_rad: np.ndarray | None = None
    truth_m: np.ndarray | None = None
    positions_ecef_m: np.ndarray | None = None
    meta: dict[str, Any] = field(default_factory=dict)
    _cache: dict[str, Any] = field(default_factory=dict, repr=False, compare=False)

    def __post_init__(self) -> None:
        n, p = len(self.stations), len(self.svs)
        t = np.asarray(self.t_gps_s)
        if self.y_m.shape != (n, t.size, p) or self.sigma_m.shape != self.y_m.shape:
            raise ModelError(
                f"y_m/sigma_m must be (stations, epochs, satellites) = {(n, t.size, p)}, got "
                f"{self.y_m.shape} and {self.sigma_m.shape}"
            )
        if not 0 <= self.reference < n:
            raise ModelError(f"reference station index {self.reference} out of range 0..{n - 1}")
        ok = np.isfinite(self.y_m)
        bad = ok & ~(np.isfinite(self.sigma_m) & (self.sigma_m > 0))
        if bad.any():
            i, k, s = (int(v[0]) for v in np.nonzero(bad))
            raise ModelError(
                f"station {self.stations[i]}, epoch {k}, {self.svs[s]}: observation without a "
                f"positive standard deviation"
            )

    # ------------------------------------------------------------------ shape
    @property
    def n_stations(self) -> int:
        return len(self.stations)

    @property
    def n_sats(self) -> int:
        return len(self.svs)

    @property
    def n_epochs(self) -> int:
        return int(np.asarray(self.t_gps_s).size)

    @property
    def observed(self) -> np.ndarray:
        """``(n, T, p)`` mask of the observations used."""
        return np.asarray(np.isfinite(self.y_m))

    def window(self, epochs: slice | np.ndarray) -> CodeBiasData:
        """The same network over a subset of epochs."""
        return CodeBiasData(
            self.stations,
            self.svs,
            np.asarray(self.t_gps_s)[epochs],
            self.y_m[:, epochs],
            self.sigma_m[:, epochs],
            self.reference,
            None if self.elevation_rad is None else self.elevation_rad[:, epochs],
            self.truth_m,
            self.positions_ecef_m,
            dict(self.meta),
        )

    # ------------------------------------------------------------------ checks
    def check(self) -> None:
        """Raise :class:`~distnav.errors.ModelError` when the network cannot determine every satellite bias:
        a station with no epoch of two satellites, a station sharing no satellite with the rest of the network,
        or satellites not linked to the reference station through common observations (named)."""
        obs = self.observed
        n = self.n_stations
        if not bool(np.any(obs[self.reference])):
            raise ModelError(f"reference station {self.stations[self.reference]} has no observation")
        seen = np.asarray(obs.any(axis=1))  # (n, p)
        for i in range(n):
            if i == self.reference:
                continue
            if not (obs[i].sum(axis=1) >= 2).any():
                raise ModelError(
                    f"station {self.stations[i]} never observes two satellites at one epoch: its "
                    f"between-satellite differences are empty"
                )
            others = np.asarray(np.delete(seen, i, axis=0).any(axis=0))
            if n > 1 and not bool(np.any(seen[i] & others)):
                raise ModelError(f"station {self.stations[i]} shares no satellites with the rest of the network")
        unlinked = self.unestimable()
        if unlinked:
            raise ModelError(
                f"satellite code biases not estimable (never linked to the reference station "
                f"{self.stations[self.reference]} through common observations): {', '.join(unlinked)}"
            )

    def estimable_subset(self) -> CodeBiasData:
        """The same network restricted to the satellites whose biases are estimable (see :meth:`unestimable`)."""
        keep = np.asarray(self._anchored_after_each_epoch()[-1]) if self.n_epochs else np.zeros(self.n_sats, bool)
        idx = np.flatnonzero(keep)
        if idx.size == 0:
            raise ModelError("no satellite code bias is estimable from these data")
        return CodeBiasData(
            self.stations,
            tuple(self.svs[k] for k in idx),
            self.t_gps_s,
            self.y_m[..., idx],
            self.sigma_m[..., idx],
            self.reference,
            None if self.elevation_rad is None else self.elevation_rad[..., idx],
            None if self.truth_m is None else self.truth_m[idx],
            self.positions_ecef_m,
            dict(self.meta),
        )

    def unestimable(self, epochs: int | None = None) -> list[str]:
        """Satellites whose bias is not estimable from the first ``epochs`` epochs (all by default)."""
        anchored = self._anchored_after_each_epoch()[-1 if epochs is None else epochs - 1]
        return [s for s, a in zip(self.svs, anchored, strict=True) if not a]

    def _anchored_after_each_epoch(self) -> np.ndarray:
        """``(T, p)``: satellite estimable from epochs ``0..t``: reachable from the datum (the satellites the
        reference station observed) through satellites co-observed by one station at one epoch."""
        cached = self._cache.get("anchored")
        if isinstance(cached, np.ndarray):
            return cached
        obs = self.observed.astype(np.int64)  # (n, T, p)
        others = np.delete(obs, self.reference, axis=0)
        co = np.einsum("ntp,ntq->tpq", others, others) > 0  # co-observed at epoch t
        adj = np.cumsum(co, axis=0) > 0  # links known after epoch t
        datum = np.cumsum(obs[self.reference], axis=0) > 0  # (T, p)
        reach = datum.copy()
        for _ in range(self.n_sats):
            new = reach | (np.einsum("tpq,tq->tp", adj.astype(np.int64), reach.astype(np.int64)) > 0)
            if np.array_equal(new, reach):
                break
            reach = new
        self._cache["anchored"] = reach
        return reach

    # ------------------------------------------------------------------ normal equations
    def epoch_normals(self) -> tuple[np.ndarray, np.ndarray]:
        """Per-station, per-epoch normals ``N (n, T, p, p)`` and ``r (n, T, p)`` (see the module docstring)."""
        obs = self.observed
        w = np.where(obs, 1.0 / np.where(obs, self.sigma_m, 1.0) ** 2, 0.0)  # (n, T, p)
        wy = np.where(obs, w * np.nan_to_num(self.y_m), 0.0)
        N = w[..., :, None] * np.eye(self.n_sats)  # diag(w)
        r = wy.copy()
        sw = w.sum(axis=-1)  # (n, T)
        diff = np.ones(self.n_stations, dtype=bool)
        diff[self.reference] = False
        with np.errstate(invalid="ignore", divide="ignore"):
            inv = np.where(sw > 0, 1.0 / sw, 0.0)
        inv[~diff] = 0.0
        N = N - inv[..., None, None] * w[..., :, None] * w[..., None, :]
        r = r - inv[..., None] * w * wy.sum(axis=-1, keepdims=True)
        return N, r

    def node_normals(self) -> tuple[np.ndarray, np.ndarray]:
        """``N_i = Σ_t A_itᵀR_it⁻¹A_it`` ``(n, p, p)``, ``r_i = Σ_t A_itᵀR_it⁻¹y_it`` ``(n, p)`` (paper 000, (4))."""
        N, r = self.epoch_normals()
        return N.sum(axis=1), r.sum(axis=1)

    def node_system(self, i: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Explicit ``(A_i, R_i, y_i)`` of paper 000 eqs. (24)/(26) for station ``i``, stacked over epochs
        (``R_i`` block diagonal). The reference station is undifferenced; others use ``D_mᵀ`` per epoch with the
        first visible satellite as pivot; epochs with fewer than two satellites contribute no rows."""
        if not 0 <= i < self.n_stations:
            raise ModelError(f"station index {i} out of range 0..{self.n_stations - 1}")
        blocks_a, blocks_r, blocks_y = [], [], []
        for t in range(self.n_epochs):
            vis = np.nonzero(self.observed[i, t])[0]
            if vis.size == 0 or (i != self.reference and vis.size < 2):
                continue
            q = np.diag(self.sigma_m[i, t, vis] ** 2)
            y = self.y_m[i, t, vis]
            a = sbasis_design(vis, self.n_sats, reference_receiver=(i == self.reference))
            if i == self.reference:
                blocks_a.append(a)
                blocks_r.append(q)
                blocks_y.append(y)
            else:
                d = between_satellite_operator(vis.size)
                blocks_a.append(a)
                blocks_r.append(d.T @ q @ d)
                blocks_y.append(d.T @ y)
        if not blocks_a:
            return np.zeros((0, self.n_sats)), np.zeros((0, 0)), np.zeros(0)
        m = sum(b.shape[0] for b in blocks_a)
        R = np.zeros((m, m))
        k = 0
        for b in blocks_r:
            R[k : k + b.shape[0], k : k + b.shape[0]] = b
            k += b.shape[0]
        return np.vstack(blocks_a), R, np.concatenate(blocks_y)

    def compressed_problem(self) -> tuple[np.ndarray, np.ndarray]:
        """Square-root form ``(A (n, p, p), y (n, p))`` with unit weights and ``A_iᵀA_i = N_i``, ``A_iᵀy_i = r_i``.

        Gives the same BLUE and the same ADMM iterates as the full ``(A_i, R_i, y_i)`` (both depend on the data only
        through ``N_i`` and ``r_i``), with ``p`` rows per station instead of thousands. Built from the eigen-
        decomposition ``N_i = V Λ Vᵀ``: ``A_i = Λ^½ Vᵀ``, ``y_i = Λ^{−½} Vᵀ r_i`` (zero rows for null directions).
        """
        N, r = self.node_normals()
        lam, V = np.linalg.eigh(N)  # (n, p), (n, p, p)
        tol = 1e-10 * np.maximum(lam.max(axis=1, keepdims=True), 1e-300)
        keep = lam > tol
        sq = np.where(keep, np.sqrt(np.where(keep, lam, 0.0)), 0.0)
        A = sq[..., :, None] * np.swapaxes(V, 1, 2)
        vr = np.einsum("npk,np->nk", V, r)
        y = np.where(keep, vr / np.where(keep, sq, 1.0), 0.0)
        return A, y

    def linear_problem(self, *, per_epoch: bool = False) -> Any:
        """The network as a :class:`distnav.algorithms.lsq.blue.LinearProblem` in the compressed square-root form
        (``p`` rows per station, unit weights; same BLUE and ADMM iterates as the full eqs. (24)/(26)).

        ``per_epoch=True`` divides every station's normal equations by the number of epochs (``N_i/T``,
        ``r_i/T``): the same BLUE, but the information per epoch, so that an ADMM weight ``W = ρI`` is measured
        against one epoch's information (equivalently ``W = ρ·T·I`` on the session's normals).
        """
        from distnav.algorithms.lsq.blue import LinearProblem

        A, y = self.compressed_problem()
        if per_epoch:
            f = 1.0 / np.sqrt(max(self.n_epochs, 1))
            A, y = A * f, y * f
        return LinearProblem.from_stacked(A, y, None, parameter_names=self.svs, node_names=self.stations)

    # ------------------------------------------------------------------ solutions
    def centralized(self, *, check: bool = True) -> CodeBiasSolution:
        """The BLUE ``x̂ = N⁻¹ r`` (paper 000, eq. (4)) with its covariance ``N⁻¹``."""
        if check:
            self.check()
        N, r = self.node_normals()
        Nt, rt = N.sum(axis=0), r.sum(axis=0)
        try:
            cov = np.linalg.inv(Nt)
        except np.linalg.LinAlgError:
            raise ModelError("the network normal matrix is singular: " + ", ".join(self.unestimable())) from None
        return CodeBiasSolution(self.svs, cov @ rt, cov, self.stations[self.reference])

    def recursive_solution(self) -> tuple[np.ndarray, np.ndarray]:
        """Centralized solution after each epoch, ``x (T, p)`` and ``σ (T, p)`` in metres (NaN while a satellite
        is not yet estimable): the Kalman filter of constant parameters used for paper 000 Fig. 8."""
        N, r = self.epoch_normals()
        Nc = np.cumsum(N.sum(axis=0), axis=0)
        rc = np.cumsum(r.sum(axis=0), axis=0)
        anchored = self._anchored_after_each_epoch()
        x = np.full((self.n_epochs, self.n_sats), np.nan)
        s = np.full_like(x, np.nan)
        for t in range(self.n_epochs):
            k = np.nonzero(anchored[t])[0]
            if k.size == 0:
                continue
            sub = Nc[t][np.ix_(k, k)]
            try:
                cov = np.linalg.inv(sub)
            except np.linalg.LinAlgError:  # pragma: no cover - anchored ⇒ regular
                continue
            x[t, k] = cov @ rc[t, k]
            s[t, k] = np.sqrt(np.diag(cov))
        return x, s

    def observation_counts(self) -> np.ndarray:
        """Number of station-epochs observing each satellite ``(p,)``."""
        return np.asarray(self.observed.sum(axis=(0, 1)))
