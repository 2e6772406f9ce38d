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
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from distnav.algorithms.result import LegacyResult, SolverResult, TraceBuilder
from distnav.errors import ModelError
from distnav.exchange.base import CommTotals

__all__ = [
    "DynamicModel",
    "NodeEpoch",
    "MeasurementSeries",
    "ObservationSeries",
    "NormalSeries",
    "FunctionSeries",
    "FilterSeries",
    "FilterState",
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

_RANK_RTOL = 1e-10  # eigenvalues below rtol·λ_max count as zero information
_EST_TOL = 1e-8  # e_k is in range(I) when its squared projection on the null space is below this


# ----------------------------------------------------------------------------------------------- dynamic model
def noise_factor(noise_cov: np.ndarray, *, rtol: float = 1e-12,
                 epoch: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Factor a (possibly singular) system-noise variance ``S = H S̃ Hᵀ`` (paper 003 eq. (19)).

    When ``S`` is diagonal-block shaped with zero rows, ``H`` is made of the columns of the identity for the
    entries with noise and ``S̃`` is the corresponding sub-matrix (eq. (20)); otherwise an eigen-decomposition
    ``H = U₊``, ``S̃ = diag(λ₊)`` is used. Returns ``(H (p×q), S̃ (q×q))``; ``q = 0`` when ``S = 0``.
    """
    where = f" at epoch {epoch}" if epoch is not None else ""
    S = np.asarray(noise_cov, dtype=float)
    if S.ndim != 2 or S.shape[0] != S.shape[1]:
        raise ModelError(f"system-noise variance{where} must be square, got shape {S.shape}")
    if not np.all(np.isfinite(S)):
        raise ModelError(f"system-noise variance{where} is not finite")
    scale = float(np.abs(S).max()) if S.size else 0.0
    if not np.allclose(S, S.T, atol=1e-12 * max(scale, 1e-300), rtol=0.0):
        raise ModelError(f"system-noise variance{where} is not symmetric")
    p = S.shape[0]
    if scale == 0.0:
        return np.zeros((p, 0)), np.zeros((0, 0))
    nz = np.flatnonzero(np.abs(S).max(axis=1) > 0)
    sub = S[np.ix_(nz, nz)]
    w = np.linalg.eigvalsh(sub)
    if w.min() < -1e-10 * w.max():
        raise ModelError(f"system-noise variance{where} is not positive semi-definite (eigenvalue {w.min():.3g})")
    if w.min() > rtol * w.max():  # the representation of eq. (20): identity columns + invertible sub-matrix
        return np.eye(p)[:, nz], 0.5 * (sub + sub.T)
    w, U = np.linalg.eigh(S)
    keep = w > rtol * w.max()
    return U[:, keep], np.diag(w[keep])


def _per_epoch(value: Any, what: str) -> tuple[bool, list[np.ndarray]]:
    """(constant?, list of matrices) from a single matrix, a 3-D array or a sequence of matrices."""
    if isinstance(value, np.ndarray) and value.ndim == 2:
        return True, [np.asarray(value, dtype=float)]
    if isinstance(value, np.ndarray) and value.ndim == 3:
        return False, [np.asarray(v, dtype=float) for v in value]
    if isinstance(value, (list, tuple)):
        mats = [np.asarray(v, dtype=float) for v in value]
        if not mats:
            raise ModelError(f"{what}: empty sequence")
        return False, mats
    arr = np.asarray(value, dtype=float)
    if arr.ndim == 2:
        return True, [arr]
    raise ModelError(f"{what} must be a matrix, a 3-D array (one per epoch) or a sequence of matrices, "
                     f"got shape {arr.shape}")


def _identity_columns(H: np.ndarray) -> np.ndarray | None:
    """Column indices if every column of ``H`` is a distinct unit vector, else ``None``."""
    if H.shape[1] == 0 or not np.all((H == 0) | (H == 1)) or not np.all(H.sum(axis=0) == 1):
        return None
    sel = np.argmax(H, axis=0)
    return sel if np.unique(sel).size == sel.size else None


class DynamicModel:
    """The common dynamic model ``x_t = Φ_t x_{t−1} + d_t``, ``D(d_t) = S_t = H_t S̃_t H_tᵀ`` (paper 003 eqs. (2), (19)).

    Parameters (each a single matrix = constant in time, or one per epoch as a 3-D array or a sequence;
    entry ``t`` is the model of the step ``t−1 → t``, entry 0 is never used):

    n_states : ``p``.
    transition : ``Φ_t`` (p×p, nonsingular); ``None`` = identity.
    noise_cov : ``S_t`` (p×p, symmetric PSD, may be singular); it is factored with :func:`noise_factor`.
    noise_map, noise_reduced_cov : the factor ``H_t`` (p×q, full column rank) and ``S̃_t`` (q×q, PD) directly,
        instead of ``noise_cov``. Neither given = no system noise (a static state).
    """

    def __init__(self, n_states: int, *, transition: Any = None, noise_cov: Any = None, noise_map: Any = None,
                 noise_reduced_cov: Any = None) -> None:
        p = int(n_states)
        if p < 1:
            raise ModelError(f"n_states must be ≥ 1, got {n_states}")
        self.n_states = p
        if transition is None:
            self._phi_const, phis = True, [np.eye(p)]
        else:
            self._phi_const, phis = _per_epoch(transition, "transition")
        self._phi: list[np.ndarray] = []
        self._phi_inv: list[np.ndarray | None] = []
        for t, F in enumerate(phis):
            e = "" if self._phi_const else f" of epoch {t}"
            if F.shape != (p, p):
                raise ModelError(f"transition matrix{e} must be {p}×{p}, got {F.shape}")
            if not np.all(np.isfinite(F)):
                raise ModelError(f"transition matrix{e} is not finite")
            if np.array_equal(F, np.eye(p)):
                self._phi.append(F)
                self._phi_inv.append(None)
                continue
            if np.linalg.cond(F) > 1e12:
                raise ModelError(f"transition matrix{e} is singular (paper 003 eq. (2) needs Φ nonsingular)")
            self._phi.append(F)
            self._phi_inv.append(np.linalg.inv(F))
        if noise_cov is not None and (noise_map is not None or noise_reduced_cov is not None):
            raise ModelError("give either noise_cov or (noise_map, noise_reduced_cov), not both")
        if (noise_map is None) != (noise_reduced_cov is None):
            raise ModelError("noise_map and noise_reduced_cov must be given together")
        pairs: list[tuple[np.ndarray, np.ndarray]]
        if noise_cov is not None:
            self._noise_const, covs = _per_epoch(noise_cov, "noise_cov")
            pairs = []
            for t, S in enumerate(covs):
                if S.shape != (p, p):
                    e = "" if self._noise_const else f" of epoch {t}"
                    raise ModelError(f"noise_cov{e} must be {p}×{p}, got {S.shape}")
                pairs.append(noise_factor(S, epoch=None if self._noise_const else t))
        elif noise_map is not None:
            cH, Hs = _per_epoch(noise_map, "noise_map")
            cS, Ss = _per_epoch(noise_reduced_cov, "noise_reduced_cov")
            if cH != cS or len(Hs) != len(Ss):
                raise ModelError("noise_map and noise_reduced_cov must both be constant or both per epoch "
                                 "with the same length")
            self._noise_const = cH
            pairs = list(zip(Hs, Ss, strict=True))
        else:
            self._noise_const = True
            pairs = [(np.zeros((p, 0)), np.zeros((0, 0)))]
        self._H: list[np.ndarray] = []
        self._sel: list[np.ndarray | None] = []
        self._St: list[np.ndarray] = []
        self._St_inv: list[np.ndarray] = []
        for t, (H, St) in enumerate(pairs):
            e = "" if self._noise_const else f" of epoch {t}"
            if H.ndim != 2 or H.shape[0] != p:
                raise ModelError(f"noise_map{e} must have {p} rows, got shape {H.shape}")
            q = H.shape[1]
            if St.shape != (q, q):
                raise ModelError(f"noise_reduced_cov{e} must be {q}×{q} to match noise_map, got {St.shape}")
            if not (np.all(np.isfinite(H)) and np.all(np.isfinite(St))):
                raise ModelError(f"system-noise factor{e} is not finite")
            if q:
                if np.linalg.matrix_rank(H) < q:
                    raise ModelError(f"noise_map{e} must have full column rank (paper 003 eq. (19))")
                if not np.allclose(St, St.T, rtol=0, atol=1e-12 * np.abs(St).max()):
                    raise ModelError(f"noise_reduced_cov{e} is not symmetric")
                try:
                    np.linalg.cholesky(St)
                except np.linalg.LinAlgError:
                    raise ModelError(f"noise_reduced_cov{e} is not positive definite (paper 003 eq. (19) needs "
                                     f"S̃ invertible)") from None
            self._H.append(H)
            self._sel.append(_identity_columns(H))
            self._St.append(0.5 * (St + St.T))
            self._St_inv.append(np.linalg.inv(St) if q else St.copy())

    # -- accessors: epoch t ≥ 1 (the step t−1 → t)
    def _idx(self, const: bool, n: int, t: int, what: str) -> int:
        if const:
            return 0
        if t >= n:
            raise ModelError(f"{what} given for {n} epochs, epoch {t} requested")
        return t

    def transition_at(self, t: int) -> np.ndarray:
        return self._phi[self._idx(self._phi_const, len(self._phi), t, "transition")]

    def transition_inverse_at(self, t: int) -> np.ndarray | None:
        """``Φ_t⁻¹``, or ``None`` when ``Φ_t`` is the identity."""
        return self._phi_inv[self._idx(self._phi_const, len(self._phi), t, "transition")]

    def noise_factor_at(self, t: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(H_t, S̃_t, S̃_t⁻¹)``."""
        k = self._idx(self._noise_const, len(self._H), t, "system noise")
        return self._H[k], self._St[k], self._St_inv[k]

    def noise_selection_at(self, t: int) -> np.ndarray | None:
        """Indices ``sel`` when ``H_t`` is made of identity columns ``I[:, sel]`` (eq. (20)), else ``None``."""
        k = self._idx(self._noise_const, len(self._H), t, "system noise")
        return self._sel[k]

    def noise_cov_at(self, t: int) -> np.ndarray:
        H, St, _ = self.noise_factor_at(t)
        return H @ St @ H.T

    def check_epochs(self, n_epochs: int) -> None:
        if not self._phi_const and len(self._phi) < n_epochs:
            raise ModelError(f"transition given for {len(self._phi)} epochs, the measurements have {n_epochs}")
        if not self._noise_const and len(self._H) < n_epochs:
            raise ModelError(f"system noise given for {len(self._H)} epochs, the measurements have {n_epochs}")

    @classmethod
    def random_walk(cls, noise_std: np.ndarray | Sequence[float]) -> DynamicModel:
        """``Φ = I``, ``S = diag(noise_std²)`` (zeros allowed: constant entries)."""
        s = np.asarray(noise_std, dtype=float)
        if s.ndim != 1 or np.any(s < 0) or not np.all(np.isfinite(s)):
            raise ModelError("noise_std must be a 1-D array of non-negative finite values")
        return cls(s.size, noise_cov=np.diag(s**2))

    def __repr__(self) -> str:
        q = self._H[0].shape[1]
        return f"DynamicModel(n_states={self.n_states}, noise rank={q}{'' if self._noise_const else ' (varying)'})"


def simulate_states(dynamics: DynamicModel, n_epochs: int, *, rng: np.random.Generator,
                    initial_state: np.ndarray | None = None) -> np.ndarray:
    """One realization ``x_0..x_{T−1}`` (T×p) of the dynamic model; ``x_0 = initial_state`` (default zeros)."""
    p = dynamics.n_states
    x = np.zeros((n_epochs, p))
    x[0] = 0.0 if initial_state is None else np.asarray(initial_state, float)
    for t in range(1, n_epochs):
        H, St, _ = dynamics.noise_factor_at(t)
        d = H @ (np.linalg.cholesky(St) @ rng.standard_normal(St.shape[0])) if St.size else 0.0
        x[t] = dynamics.transition_at(t) @ x[t - 1] + d
    return x


# ----------------------------------------------------------------------------------------------- measurements
@dataclass(frozen=True, eq=False)
class NodeEpoch:
    """Observations of one node at one epoch: ``y = A x + ε``, ``D(ε) = R``.

    ``design`` is m×p; ``cov`` is m×m or a vector of m variances; ``obs`` has m entries (may be ``None`` for a
    variance-only analysis: ``r`` is then zero).
    """

    design: np.ndarray
    cov: np.ndarray
    obs: np.ndarray | None = None


def _whiten(design: Any, cov: Any, obs: Any, p: int, where: str) -> tuple[np.ndarray, np.ndarray]:
    A = np.asarray(design, dtype=float)
    if A.ndim != 2 or A.shape[1] != p:
        raise ModelError(f"{where}: design must be m×{p}, got shape {A.shape}")
    m = A.shape[0]
    R = np.asarray(cov, dtype=float)
    y = np.zeros(m) if obs is None else np.asarray(obs, dtype=float)
    if y.shape != (m,):
        raise ModelError(f"{where}: {m} design rows but observations of shape {y.shape}")
    if not (np.all(np.isfinite(A)) and np.all(np.isfinite(R)) and np.all(np.isfinite(y))):
        raise ModelError(f"{where}: design, variance or observations not finite")
    if R.ndim == 1:
        if R.shape != (m,):
            raise ModelError(f"{where}: {m} observations but {R.shape[0]} variances")
        if np.any(R <= 0):
            raise ModelError(f"{where}: variances must be positive (observation {int(np.argmin(R))})")
        s = 1.0 / np.sqrt(R)
        return A * s[:, None], y * s
    if R.shape != (m, m):
        raise ModelError(f"{where}: variance matrix must be {m}×{m}, got {R.shape}")
    if not np.allclose(R, R.T, rtol=0, atol=1e-12 * max(float(np.abs(R).max()), 1e-300)):
        raise ModelError(f"{where}: variance matrix is not symmetric")
    try:
        C = np.linalg.cholesky(R)
    except np.linalg.LinAlgError:
        raise ModelError(f"{where}: variance matrix is not positive definite") from None
    import scipy.linalg as sla

    return sla.solve_triangular(C, A, lower=True), sla.solve_triangular(C, y, lower=True)


def normal_equations(design: Any, cov: Any, obs: Any = None) -> tuple[np.ndarray, np.ndarray]:
    """``N = Aᵀ R⁻¹ A`` and ``r = Aᵀ R⁻¹ y`` (paper 003 eq. (24)); ``cov`` is a matrix or a variance vector."""
    A = np.asarray(design, dtype=float)
    if A.ndim != 2:
        raise ModelError(f"design must be a matrix, got shape {A.shape}")
    Aw, yw = _whiten(A, cov, obs, A.shape[1], "normal_equations")
    return Aw.T @ Aw, Aw.T @ yw


class MeasurementSeries:
    """Per-node, per-epoch measurement information (the interface every filter reads).

    Subclasses provide :meth:`normals` and, when the raw observations exist, :meth:`observations`.
    ``nodes`` are global node ids, so a block of an MPI exchange asks only for its own nodes.
    """

    n_nodes: int
    n_epochs: int
    n_states: int

    def normals(self, epoch: int, nodes: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """``(N (k×p×p), r (k×p))`` of the given nodes (default all) at ``epoch`` (eq. (24))."""
        raise NotImplementedError

    def observations(self, epoch: int, nodes: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Stacked whitened ``(A, y)`` of the given nodes plus the node of each row: ``(A_w, y_w, node)``.

        Whitened means ``R = I``; only series built from raw observations have them.
        """
        raise ModelError(f"{type(self).__name__} holds normal equations only; the covariance-form filter needs "
                         f"an ObservationSeries")

    def _nodes(self, nodes: np.ndarray | None) -> np.ndarray:
        if nodes is None:
            return np.arange(self.n_nodes)
        idx = np.asarray(nodes, dtype=np.int64).reshape(-1)
        if idx.size and (idx.min() < 0 or idx.max() >= self.n_nodes):
            raise ModelError(f"node ids must lie in 0..{self.n_nodes - 1}, got {idx.min()}..{idx.max()}")
        return idx

    def _epoch(self, epoch: int) -> int:
        if not 0 <= epoch < self.n_epochs:
            raise ModelError(f"epoch {epoch} outside 0..{self.n_epochs - 1}")
        return int(epoch)


class ObservationSeries(MeasurementSeries):
    """``(A_i,t, R_i,t, y_i,t)`` for every epoch ``t`` and node ``i``: ``epochs[t][i]`` is a :class:`NodeEpoch`,
    a tuple ``(A, R)`` / ``(A, R, y)``, or ``None`` (no data). The number of rows may vary freely.

    Validated once at construction; errors name the epoch and node.
    """

    def __init__(self, n_states: int, epochs: Sequence[Sequence[Any]]) -> None:
        p = int(n_states)
        if p < 1:
            raise ModelError(f"n_states must be ≥ 1, got {n_states}")
        if len(epochs) == 0:
            raise ModelError("an ObservationSeries needs at least one epoch")
        n = len(epochs[0])
        if n == 0:
            raise ModelError("epoch 0 has no nodes")
        self.n_states, self.n_epochs, self.n_nodes = p, len(epochs), n
        self._A: list[list[np.ndarray]] = []
        self._y: list[list[np.ndarray]] = []
        for t, row in enumerate(epochs):
            if len(row) != n:
                raise ModelError(f"epoch {t} lists {len(row)} nodes, epoch 0 lists {n}")
            Ar: list[np.ndarray] = []
            yr: list[np.ndarray] = []
            for i, item in enumerate(row):
                if item is None:
                    Ar.append(np.zeros((0, p)))
                    yr.append(np.zeros(0))
                    continue
                if isinstance(item, NodeEpoch):
                    A, R, y = item.design, item.cov, item.obs
                elif isinstance(item, tuple) and len(item) in (2, 3):
                    A, R = item[0], item[1]
                    y = item[2] if len(item) == 3 else None
                else:
                    raise ModelError(f"epoch {t}, node {i}: expected NodeEpoch, (A, R[, y]) or None, "
                                     f"got {type(item).__name__}")
                Aw, yw = _whiten(A, R, y, p, f"epoch {t}, node {i}")
                Ar.append(Aw)
                yr.append(yw)
            self._A.append(Ar)
            self._y.append(yr)

    def normals(self, epoch: int, nodes: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        t = self._epoch(epoch)
        idx = self._nodes(nodes)
        p = self.n_states
        N = np.zeros((idx.size, p, p))
        r = np.zeros((idx.size, p))
        for k, i in enumerate(idx):
            A = self._A[t][i]
            if A.shape[0]:
                N[k] = A.T @ A
                r[k] = A.T @ self._y[t][i]
        return N, r

    def observations(self, epoch: int, nodes: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        t = self._epoch(epoch)
        idx = self._nodes(nodes)
        A = [self._A[t][i] for i in idx]
        y = [self._y[t][i] for i in idx]
        node = np.concatenate([np.full(a.shape[0], i, np.int64) for a, i in zip(A, idx, strict=True)]) \
            if idx.size else np.zeros(0, np.int64)
        return (np.concatenate(A, axis=0) if A else np.zeros((0, self.n_states)),
                np.concatenate(y) if y else np.zeros(0), node)


class NormalSeries(MeasurementSeries):
    """Normals given directly: ``N`` of shape (T, n, p, p) and ``r`` of shape (T, n, p) (eq. (24))."""

    def __init__(self, normal_matrices: np.ndarray, rhs: np.ndarray | None = None) -> None:
        N = np.asarray(normal_matrices, dtype=float)
        if N.ndim != 4 or N.shape[2] != N.shape[3]:
            raise ModelError(f"normal matrices must have shape (epochs, nodes, p, p), got {N.shape}")
        T, n, p, _ = N.shape
        r = np.zeros((T, n, p)) if rhs is None else np.asarray(rhs, dtype=float)
        if r.shape != (T, n, p):
            raise ModelError(f"right-hand sides must have shape {(T, n, p)}, got {r.shape}")
        if not (np.all(np.isfinite(N)) and np.all(np.isfinite(r))):
            bad = np.argwhere(~np.isfinite(N).all(axis=(2, 3)) | ~np.isfinite(r).all(axis=2))[0]
            raise ModelError(f"epoch {bad[0]}, node {bad[1]}: normals not finite")
        asym = np.abs(N - np.swapaxes(N, 2, 3)).max(axis=(2, 3)) > 1e-10 * (1 + np.abs(N).max(axis=(2, 3)))
        if asym.any():
            t, i = np.argwhere(asym)[0]
            raise ModelError(f"epoch {t}, node {i}: normal matrix is not symmetric")
        neg = (np.diagonal(N, axis1=2, axis2=3) < 0).any(axis=2)
        if neg.any():
            t, i = np.argwhere(neg)[0]
            raise ModelError(f"epoch {t}, node {i}: normal matrix has a negative diagonal entry (not PSD)")
        self._N, self._r = N, r
        self.n_epochs, self.n_nodes, self.n_states = T, n, p

    def normals(self, epoch: int, nodes: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        t = self._epoch(epoch)
        if nodes is None:
            return self._N[t], self._r[t]
        idx = self._nodes(nodes)
        return self._N[t, idx], self._r[t, idx]


class FunctionSeries(MeasurementSeries):
    """Normals computed on demand by ``fn(epoch, nodes) -> (N (k×p×p), r (k×p))`` (large runs, streaming data)."""

    def __init__(self, n_nodes: int, n_epochs: int, n_states: int,
                 fn: Callable[[int, np.ndarray], tuple[np.ndarray, np.ndarray]]) -> None:
        if min(n_nodes, n_epochs, n_states) < 1:
            raise ModelError("n_nodes, n_epochs and n_states must be ≥ 1")
        self.n_nodes, self.n_epochs, self.n_states = int(n_nodes), int(n_epochs), int(n_states)
        self._fn = fn

    def normals(self, epoch: int, nodes: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        t = self._epoch(epoch)
        idx = self._nodes(nodes)
        N, r = self._fn(t, idx)
        p = self.n_states
        if np.shape(N) != (idx.size, p, p) or np.shape(r) != (idx.size, p):
            raise ModelError(f"epoch {t}: fn returned shapes {np.shape(N)}, {np.shape(r)}; expected "
                             f"{(idx.size, p, p)}, {(idx.size, p)}")
        return np.asarray(N, float), np.asarray(r, float)


# ----------------------------------------------------------------------------------------------- linear algebra
def pseudo_inverse_psd(info: np.ndarray, *, rtol: float = _RANK_RTOL) -> tuple[np.ndarray, np.ndarray]:
    """Batched pseudo-inverse of PSD information matrices ``(k, p, p)`` and the estimable entries ``(k, p)``.

    Entries with zero diagonal (never observed) are dropped first; the rest is tried with a batched inverse
    (accepted when every variance-inflation factor ``(I⁻¹)_jj I_jj`` lies in [1, 1e7)) and otherwise falls back to
    an eigen-decomposition of the unit-diagonal scaled matrix (eigenvalues below ``rtol·λ_max`` are zero), where
    entry ``j`` is estimable when its squared projection on the null space is below 1e-8. The returned matrix is a
    generalized inverse (the pseudo-inverse when ``I`` is invertible or its singular part is unit-free); on the
    estimable entries every generalized inverse gives the same estimates and variances.
    """
    k, p, _ = info.shape
    inv = np.zeros_like(info)
    est = np.zeros((k, p), bool)
    if k == 0:
        return inv, est
    d = np.diagonal(info, axis1=1, axis2=2)
    seen = d > 0  # exactly zero: no information ever (structural); the rest is decided scale-free below
    if seen.all():
        return _inv_or_pinv(info, rtol)
    if (seen == seen[0]).all():
        groups: list[tuple[np.ndarray, np.ndarray]] = [(np.arange(k), seen[0])]
    else:
        keys, inverse = np.unique(seen, axis=0, return_inverse=True)
        inverse = np.asarray(inverse).reshape(-1)
        groups = [(np.flatnonzero(inverse == g), keys[g]) for g in range(keys.shape[0])]
    for rows, mask in groups:
        cols = np.flatnonzero(mask)
        if cols.size == 0:
            continue
        sub = info[rows].take(cols, axis=1).take(cols, axis=2)
        sub_inv, sub_est = _inv_or_pinv(sub, rtol)
        inv[np.ix_(rows, cols, cols)] = sub_inv
        est[np.ix_(rows, cols)] = sub_est
    return inv, est


def _inv_or_pinv(sub: np.ndarray, rtol: float) -> tuple[np.ndarray, np.ndarray]:
    k, m, _ = sub.shape
    try:
        inv = np.linalg.inv(sub)
        # well-conditioned PD check: 1 ≤ (I⁻¹)_jj I_jj (Cauchy–Schwarz), large values flag near-singularity
        vif = np.diagonal(inv, axis1=1, axis2=2) * np.diagonal(sub, axis1=1, axis2=2)
        if np.all(vif >= 1.0 - 1e-6) and np.all(vif < 1e-3 / rtol) and np.all(np.isfinite(inv)):
            return 0.5 * (inv + np.swapaxes(inv, 1, 2)), np.ones((k, m), bool)
    except np.linalg.LinAlgError:
        pass
    # eigen-decomposition of the scaled matrix C = D^-1/2 I D^-1/2 (unit diagonal): the rank decision does not
    # depend on the units of the state entries. G = D^-1/2 C⁺ D^-1/2 is a generalized inverse of I, and for
    # estimable entries e_kᵀ G i and e_kᵀ G Q G e_k do not depend on which generalized inverse is used.
    dsq = np.sqrt(np.diagonal(sub, axis1=1, axis2=2))
    scale = 1.0 / np.where(dsq > 0, dsq, 1.0)
    C = sub * scale[:, :, None] * scale[:, None, :]
    w, U = np.linalg.eigh(C)
    keep = w > rtol * np.maximum(w[:, -1:], 1e-300)
    winv = np.where(keep, 1.0 / np.where(keep, w, 1.0), 0.0)
    inv = ((U * winv[:, None, :]) @ np.swapaxes(U, 1, 2)) * scale[:, :, None] * scale[:, None, :]
    null_proj = np.einsum("kij,kj->ki", U**2, (~keep).astype(float))
    return inv, null_proj < _EST_TOL


# ----------------------------------------------------------------------------------------------- filter kernel
class _InfoKernel:
    """Batched information filter state ``I (k,p,p)``, ``i (k,p)`` and optionally the information-error
    variance ``Q = D(I x − i)`` (``Q = I P I`` when ``I`` is invertible; used by the CKF variance recursion).

    Time update (paper 003 Fig. 1 with eqs. (19)–(21)), ``M = Φ⁻ᵀ I Φ⁻¹``, ``K = Hᵀ M H + S̃⁻¹``:
    ``I⁻ = M − M H K⁻¹ Hᵀ M``, ``i⁻ = (I − M H K⁻¹ Hᵀ) Φ⁻ᵀ i``. With ``B = I − M H K⁻¹ Hᵀ`` the information
    error ``u = I x − i`` evolves as ``u⁻ = B Φ⁻ᵀ u + B M H e_t`` (``d_t = H e_t``), hence
    ``Q⁻ = B Φ⁻ᵀ Q Φ⁻¹ Bᵀ + (M H K⁻¹ S̃⁻¹) S̃ (M H K⁻¹ S̃⁻¹)ᵀ`` — the paper's ``P⁻ = Φ P Φᵀ + S`` pre- and
    post-multiplied by ``I⁻``, but valid for singular ``I`` as well.
    """

    def __init__(self, k: int, p: int, track_error: bool) -> None:
        self.I = np.zeros((k, p, p))
        self.i = np.zeros((k, p))
        self.Q = np.zeros((k, p, p)) if track_error else None
        self.p = p

    def time_update(self, dyn: DynamicModel, t: int) -> None:
        Finv = dyn.transition_inverse_at(t)
        H, _St, St_inv = dyn.noise_factor_at(t)
        M, v = self.I, self.i
        Q = self.Q
        if Finv is not None:
            M = Finv.T @ M @ Finv
            v = v @ Finv  # (Φ⁻ᵀ i) row-wise
            if Q is not None:
                Q = Finv.T @ Q @ Finv
        q = H.shape[1]
        if q == 0:
            self.I, self.i, self.Q = M, v, Q
            return
        sel = dyn.noise_selection_at(t)
        if sel is not None:  # H = columns `sel` of the identity (eq. (20)): slicing instead of products
            MH = M[:, :, sel]  # (k,p,q)
            K = MH[:, sel, :] + St_inv
        else:
            MH = M @ H
            K = np.swapaxes(MH, 1, 2) @ H + St_inv  # Hᵀ M H + S̃⁻¹, (k,q,q)
        G = MH @ np.linalg.inv(K)  # M H K⁻¹, (k,p,q)
        I_new = M - G @ np.swapaxes(MH, 1, 2)
        self.I = 0.5 * (I_new + np.swapaxes(I_new, 1, 2))
        vH = v[:, sel] if sel is not None else v @ H
        self.i = v - (G @ vH[..., None])[..., 0]
        if Q is not None:
            # B Q Bᵀ with B = I − G Hᵀ as rank-q corrections, plus F S̃ Fᵀ with F = B M H = G S̃⁻¹
            HtQ = Q[:, sel, :] if sel is not None else np.swapaxes(H, 0, 1) @ Q  # (k,q,p)
            BQ = Q - G @ HtQ
            BQH = BQ[:, :, sel] if sel is not None else BQ @ H  # (k,p,q)
            F = G @ St_inv
            Q_new = BQ - BQH @ np.swapaxes(G, 1, 2) + F @ (_St @ np.swapaxes(F, 1, 2))
            self.Q = 0.5 * (Q_new + np.swapaxes(Q_new, 1, 2))

    def measurement_update(self, N: np.ndarray, r: np.ndarray, scale: float = 1.0,
                           extra_error: np.ndarray | None = None) -> None:
        """``I += scale N``, ``i += scale r`` (Fig. 1 / Fig. 6); ``Q += extra_error`` (Fig. 7)."""
        self.I = self.I + scale * N
        self.i = self.i + scale * r
        if self.Q is not None and extra_error is not None:
            self.Q = self.Q + extra_error

    def estimates(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
        """``(x̂ (NaN where not estimable), estimable, I⁺, P = I⁺ Q I⁺ or None)``."""
        inv, est = pseudo_inverse_psd(self.I)
        x = (inv @ self.i[..., None])[..., 0]
        x[~est] = np.nan
        P = None
        if self.Q is not None:
            P = inv @ self.Q @ inv
            P = 0.5 * (P + np.swapaxes(P, 1, 2))
        return x, est, inv, P


# ----------------------------------------------------------------------------------------------- results
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

    estimates: np.ndarray
    std: np.ndarray
    estimable: np.ndarray
    nodes: np.ndarray
    nominal_std: np.ndarray | None = None
    covariance: np.ndarray | None = None
    information: np.ndarray | None = None

    @property
    def n_epochs(self) -> int:
        return int(self.estimates.shape[0])


def std_ratio(series: FilterSeries, reference: FilterSeries) -> np.ndarray:
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
        return a / b


@dataclass(frozen=True, eq=False)
class FilterState:
    """State of a bank of information filters after the measurement update of ``epoch``."""

    epoch: int
    information: np.ndarray
    info_vector: np.ndarray
    estimates: np.ndarray
    estimable: np.ndarray
    covariance: np.ndarray


_MODES = ("central", "local", "exact_average")


def iterate_information_filter(dynamics: DynamicModel, measurements: MeasurementSeries, *,
                               mode: str = "central", nodes: Sequence[int] | np.ndarray | None = None,
                               ) -> Iterator[FilterState]:
    """Yield the information filter state (paper 003 Fig. 1) after each epoch's measurement update.

    mode "central": one filter fed ``N_t = Σ_i N_i,t``, ``r_t = Σ_i r_i,t`` over ``nodes`` (default all; eq. (25));
    "local": one filter per node fed only its own ``N_i,t, r_i,t`` (single-receiver solutions of §5.3);
    "exact_average": one filter per node fed ``n N̄_t, n r̄_t`` (eqs. (27)–(28)); identical to "central".
    """
    if mode not in _MODES:
        raise ModelError(f"mode must be one of {', '.join(_MODES)}, got {mode!r}")
    _check_pair(dynamics, measurements)
    idx = measurements._nodes(None if nodes is None else np.asarray(nodes))
    if idx.size == 0:
        raise ModelError("no nodes selected")
    p = measurements.n_states
    rows = 1 if mode == "central" else idx.size
    ker = _InfoKernel(rows, p, track_error=False)
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
            ker.measurement_update(np.broadcast_to(N.mean(axis=0), N.shape), np.broadcast_to(r.mean(axis=0), r.shape),
                                   scale=float(n))
        x, est, inv, _ = ker.estimates()
        yield FilterState(t, ker.I, ker.i, x, est, inv)


def _check_pair(dynamics: DynamicModel, measurements: MeasurementSeries) -> None:
    if dynamics.n_states != measurements.n_states:
        raise ModelError(f"dynamic model has {dynamics.n_states} states, measurements {measurements.n_states}")
    dynamics.check_epochs(measurements.n_epochs)


def _std(cov: np.ndarray, est: np.ndarray) -> np.ndarray:
    s = np.sqrt(np.maximum(np.diagonal(cov, axis1=-2, axis2=-1), 0.0))
    return np.where(est, s, np.nan)


def information_filter(dynamics: DynamicModel, measurements: MeasurementSeries, *, mode: str = "central",
                       nodes: Sequence[int] | np.ndarray | None = None, store_matrices: bool = False) -> SolverResult:
    """Run :func:`iterate_information_filter` over all epochs.

    Returns a :class:`SolverResult`: ``estimates`` = last-epoch estimates (rows = filters), ``iterations`` =
    epochs, ``extras["series"]`` = :class:`FilterSeries`, ``extras["information"]`` / ``["info_vector"]`` =
    final ``I_t|t``, ``i_t|t``. Trace: ``n_estimable`` (epochs × rows).
    """
    idx = measurements._nodes(None if nodes is None else np.asarray(nodes))
    xs, stds, ests, covs, infos = [], [], [], [], []
    tb = TraceBuilder()
    last: FilterState | None = None
    for st in iterate_information_filter(dynamics, measurements, mode=mode, nodes=idx):
        xs.append(st.estimates)
        stds.append(_std(st.covariance, st.estimable))
        ests.append(st.estimable)
        if store_matrices:
            covs.append(st.covariance)
            infos.append(st.information)
        tb.add(n_estimable=st.estimable.sum(axis=1))
        last = st
    assert last is not None
    series = FilterSeries(
        estimates=np.stack(xs), std=np.stack(stds), estimable=np.stack(ests),
        nodes=np.array([-1]) if mode == "central" else idx,
        covariance=np.stack(covs) if store_matrices else None,
        information=np.stack(infos) if store_matrices else None,
    )
    complete = bool(last.estimable.all())
    return LegacyResult(
        estimates=last.estimates, converged=complete, iterations=measurements.n_epochs,
        status="converged" if complete else "stopped",
        message=f"{mode} information filter over {measurements.n_epochs} epochs; "
                f"{int(last.estimable.sum())}/{last.estimable.size} entries estimable at the last epoch",
        trace=tb.build(), comm=CommTotals.empty(measurements.n_nodes),
        legacy={"series": series, "information": last.information, "info_vector": last.info_vector,
                "mode": mode},
    )


def central_filter(dynamics: DynamicModel, measurements: MeasurementSeries, **kw: Any) -> SolverResult:
    """The central (network, fusion-centre) information filter (eq. (25)); one row."""
    return information_filter(dynamics, measurements, mode="central", **kw)


def local_filters(dynamics: DynamicModel, measurements: MeasurementSeries, **kw: Any) -> SolverResult:
    """Single-node filters, each with its own data only (paper 003 §5.3); one row per node."""
    return information_filter(dynamics, measurements, mode="local", **kw)


def exact_average_filters(dynamics: DynamicModel, measurements: MeasurementSeries, **kw: Any) -> SolverResult:
    """Local filters fed with the exact averages ``n N̄_t``, ``n r̄_t`` (eqs. (26)–(28)): equal to the central one."""
    return information_filter(dynamics, measurements, mode="exact_average", **kw)


# ----------------------------------------------------------------------------------------------- batch BLUP
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

    def add(self, N: np.ndarray, r: np.ndarray) -> None:
        self.C += self.G.T @ N @ self.G
        self.b += self.G.T @ r

    def solve(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        w, U = np.linalg.eigh(0.5 * (self.C + self.C.T))
        keep = w > _RANK_RTOL * max(w[-1], 1e-300)
        Cinv = (U[:, keep] / w[keep]) @ U[:, keep].T
        null = U[:, ~keep]
        resid = self.G @ null  # row k of G must be orthogonal to the null space of C
        scale = np.maximum((self.G**2).sum(axis=1), 1e-300)
        est = (resid**2).sum(axis=1) / scale < _EST_TOL
        x = self.G @ (Cinv @ self.b)
        P = self.G @ Cinv @ self.G.T
        return x, est, 0.5 * (P + P.T)


def batch_blup(dynamics: DynamicModel, measurements: MeasurementSeries, epoch: int, *,
               nodes: Sequence[int] | np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Batch BLUP of ``x_epoch`` from all data up to ``epoch`` (paper 003 §2.3; Henderson's mixed model).

    ``x_0`` is a fixed effect (no prior: the BLUP start), the reduced system noises ``e_t`` (``d_t = H_t e_t``)
    random effects with variance ``S̃_t``. Returns ``(x̂ (NaN where not estimable), estimable, P)`` where ``P`` is
    the prediction-error variance ``G C⁻¹ Gᵀ`` (meaningful on the estimable block). Cost grows with the epoch:
    a reference, not a filter.
    """
    _check_pair(dynamics, measurements)
    idx = measurements._nodes(None if nodes is None else np.asarray(nodes))
    measurements._epoch(epoch)
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
def kalman_filter(dynamics: DynamicModel, measurements: MeasurementSeries, *,
                  nodes: Sequence[int] | np.ndarray | None = None, max_batch_epochs: int = 500,
                  store_matrices: bool = False) -> SolverResult:
    """Covariance-form Kalman filter, three-step recursion of paper 003 §2.2 with the BLUP start of §2.3.

    Uses the stacked raw observations of ``nodes`` (default all: the central filter; ``nodes=[i]`` gives node
    ``i``'s local filter). Until the whole state is estimable the batch BLUP (:func:`batch_blup`) supplies the
    estimable entries; at the first epoch where everything is estimable it initializes ``x̂_t|t, P_t|t``
    (eq. (15)), then runs time update ``x̂⁻ = Φ x̂``, ``P⁻ = Φ P Φᵀ + S`` (eqs. (8)–(9)) and measurement update
    ``K = P⁻Aᵀ(R + A P⁻ Aᵀ)⁻¹``, ``x̂ = x̂⁻ + K (y − A x̂⁻)``, ``P = (I − KA) P⁻ (I − KA)ᵀ + K R Kᵀ``
    (eqs. (10)–(12), Joseph form), one node's observations at a time (their noises are uncorrelated, eq. (23)).
    Raises :class:`ModelError` if the state is still not estimable after
    ``max_batch_epochs`` epochs. Before the initialization every epoch re-solves the batch (O((p + Σ q_t)³)): a
    reference for moderate rank-deficient phases; the information form is the production path.
    """
    _check_pair(dynamics, measurements)
    idx = measurements._nodes(None if nodes is None else np.asarray(nodes))
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
                raise ModelError(f"state not estimable after {max_batch_epochs} epochs (entries "
                                 f"{np.flatnonzero(~ests[t - 1, 0]).tolist()[:10]} never determined)")
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
            F = dynamics.transition_at(t)
            x = F @ x
            P = F @ P @ F.T + dynamics.noise_cov_at(t)
            # node blocks are uncorrelated (eq. (23)): update with one node's rows at a time (exact, and
            # O(Σ m_i³) instead of O((Σ m_i)³))
            for blk in np.split(np.arange(A.shape[0]), np.flatnonzero(np.diff(row_node)) + 1):
                if blk.size == 0:
                    continue
                Ab, yb = A[blk], y[blk]
                S = np.eye(blk.size) + Ab @ P @ Ab.T  # Q_vv = R + A P⁻ Aᵀ (eq. (13)), R = I after whitening
                K = np.linalg.solve(S, Ab @ P).T
                x = x + K @ (yb - Ab @ x)
                IKA = np.eye(p) - K @ Ab
                P = IKA @ P @ IKA.T + K @ K.T
            P = 0.5 * (P + P.T)
        xs[t, 0] = x
        ests[t, 0] = True
        covs[t, 0] = P
    series = FilterSeries(estimates=xs, std=_std(np.nan_to_num(covs), ests), estimable=ests, nodes=np.array([-1]),
                          covariance=covs if store_matrices else None)
    return LegacyResult(
        estimates=xs[-1], converged=init_epoch >= 0, iterations=T,
        status="converged" if init_epoch >= 0 else "stopped",
        message=(f"covariance-form Kalman filter, BLUP start at epoch {init_epoch}" if init_epoch >= 0
                 else "covariance-form Kalman filter: state never fully estimable"),
        trace=TraceBuilder().build(), comm=CommTotals.empty(measurements.n_nodes),
        legacy={"series": series, "init_epoch": init_epoch, "covariance": covs[-1, 0]},
    )
