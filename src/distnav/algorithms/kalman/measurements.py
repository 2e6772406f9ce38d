"""Measurements of the Kalman/CKF family: per-node, per-epoch observations and normal equations.

Node ``i`` at epoch ``t`` observes ``y_i,t = A_i,t x_t + ε_i,t``, ``D(ε_i,t) = R_i,t``, mutually uncorrelated over
nodes and epochs (paper 003 eqs. (22)–(23)). The rows of ``A_i,t`` may change from epoch to epoch (satellites rise
and set); a state entry no node observes simply has zero columns. :class:`ObservationSeries` holds
``(A_i,t, R_i,t, y_i,t)``; :class:`NormalSeries` holds the normals ``N_i,t = A_i,tᵀ R_i,t⁻¹ A_i,t`` and
``r_i,t = A_i,tᵀ R_i,t⁻¹ y_i,t`` (eq. (24)) directly; :class:`FunctionSeries` computes them on demand.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from distnav._checks import affordable_nodes, whole_number
from distnav.algorithms.kalman.dynamics import DynamicModel
from distnav.errors import ModelError
from distnav.typing import ArrayLike, FloatArray, IntArray

__all__ = [
    "FunctionSeries",
    "MeasurementSeries",
    "NodeData",
    "NodeEpoch",
    "NormalSeries",
    "ObservationSeries",
    "check_model",
    "normal_equations",
]


@dataclass(frozen=True, eq=False)
class NodeEpoch:
    """Observations of one node at one epoch: ``y = A x + ε``, ``D(ε) = R``.

    ``design`` is m×p; ``cov`` is m×m or a vector of m variances; ``obs`` has m entries (may be ``None`` for a
    variance-only analysis: ``r`` is then zero).
    """

    design: ArrayLike
    cov: ArrayLike
    obs: ArrayLike | None = None


NodeData = NodeEpoch | tuple[ArrayLike, ArrayLike] | tuple[ArrayLike, ArrayLike, ArrayLike | None] | None
"""One node's data at one epoch in an :class:`ObservationSeries`: a :class:`NodeEpoch`, ``(A, R)``, ``(A, R, y)``
or ``None`` (no data)."""


def _whiten(
    design: ArrayLike, cov: ArrayLike, obs: ArrayLike | None, p: int, where: str
) -> tuple[FloatArray, FloatArray]:
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
        Aw: FloatArray = A * s[:, None]
        yw: FloatArray = y * s
        return Aw, yw
    if R.shape != (m, m):
        raise ModelError(f"{where}: variance matrix must be {m}×{m}, got {R.shape}")
    if not np.allclose(R, R.T, rtol=0, atol=1e-12 * max(float(np.abs(R).max()), 1e-300)):
        raise ModelError(f"{where}: variance matrix is not symmetric")
    try:
        C = np.linalg.cholesky(R)
    except np.linalg.LinAlgError:
        raise ModelError(f"{where}: variance matrix is not positive definite") from None
    import scipy.linalg as sla

    Aw = sla.solve_triangular(C, A, lower=True)
    yw = sla.solve_triangular(C, y, lower=True)
    return Aw, yw


def normal_equations(
    design: ArrayLike,
    cov: ArrayLike,
    obs: ArrayLike | None = None,
) -> tuple[FloatArray, FloatArray]:
    """``N = Aᵀ R⁻¹ A`` and ``r = Aᵀ R⁻¹ y`` (paper 003 eq. (24)); ``cov`` is a matrix or a variance vector."""
    A = np.asarray(design, dtype=float)
    if A.ndim != 2:
        raise ModelError(f"design must be a matrix, got shape {A.shape}")
    Aw, yw = _whiten(A, cov, obs, A.shape[1], "normal_equations")
    N: FloatArray = Aw.T @ Aw
    r: FloatArray = Aw.T @ yw
    return N, r


class MeasurementSeries:
    """Per-node, per-epoch measurement information (the interface every filter reads).

    Subclasses provide :meth:`normals` and, when the raw observations exist, :meth:`observations`.
    ``nodes`` are global node ids, so a block of an MPI exchange asks only for its own nodes.
    """

    n_nodes: int
    n_epochs: int
    n_states: int

    def normals(self, epoch: int, nodes: IntArray | None = None) -> tuple[FloatArray, FloatArray]:
        """``(N (k×p×p), r (k×p))`` of the given nodes (default all) at ``epoch`` (eq. (24))."""
        raise NotImplementedError

    def observations(self, epoch: int, nodes: IntArray | None = None) -> tuple[FloatArray, FloatArray, IntArray]:
        """Stacked whitened ``(A, y)`` of the given nodes plus the node of each row: ``(A_w, y_w, node)``.

        Whitened means ``R = I``; only series built from raw observations have them.
        """
        raise ModelError(
            f"{type(self).__name__} holds normal equations only; the covariance-form filter needs an ObservationSeries"
        )

    def records(self, epoch: int, nodes: IntArray | None = None) -> tuple[FloatArray, FloatArray]:
        """The raw observations of the given nodes as records over a fixed set of slots (e.g. satellites):
        ``(values, weights)``, each (k × slots), weight 0 where nothing was observed. What the CKF's relay
        transport sends (:mod:`distnav.algorithms.kalman.relay`); only series whose design rows follow from
        knowledge every node holds (GNSS: orbits and station positions) have them."""
        raise ModelError(
            f"{type(self).__name__} gives no observation records; the CKF's relay transport needs them "
            f"(use transport='matrices')"
        )

    def record_slots(self, epoch: int, nodes: IntArray | None = None) -> IntArray:
        """The slot of each row of :meth:`observations` (same order): how a node leaves an observation an
        innovation test removed out of the records it sends."""
        raise ModelError(f"{type(self).__name__} gives no observation records")

    def normals_from_records(
        self, epoch: int, node: int, values: FloatArray, weights: FloatArray
    ) -> tuple[FloatArray, FloatArray]:
        """``(N (p×p), r (p,))`` of ``node`` at ``epoch`` rebuilt from its records (:meth:`records`) alone."""
        raise ModelError(f"{type(self).__name__} gives no observation records")

    def normals_from_records_of(
        self, epoch: int, nodes: IntArray, values: FloatArray, weights: FloatArray
    ) -> tuple[FloatArray, FloatArray]:
        """:meth:`normals_from_records` of several ``nodes`` (rows of ``values``, ``weights``): ``(k×p×p)``,
        ``(k×p)``; a series may do them in one batched product (the same numbers)."""
        pairs = [
            self.normals_from_records(epoch, int(j), values[a], weights[a]) for a, j in enumerate(np.asarray(nodes))
        ]
        return np.stack([N for N, _ in pairs]), np.stack([r for _, r in pairs])

    def node_ids(self, nodes: ArrayLike | None = None) -> IntArray:
        """The selected global node ids as an int64 vector (default all), validated against ``n_nodes``."""
        if nodes is None:
            return np.arange(self.n_nodes)
        given = np.asarray(nodes)
        if given.dtype == np.int64 and given.ndim == 1 and given.size:  # the common case, checked cheaply
            if given.min() < 0 or given.max() >= self.n_nodes:
                raise ModelError(f"node ids must lie in 0..{self.n_nodes - 1}, got {given.min()}..{given.max()}")
            return given
        if given.ndim > 1:
            raise ModelError(f"node ids must be a single id or a 1-D list of ids, got shape {given.shape}")
        if given.size and not np.issubdtype(given.dtype, np.integer):
            raise ModelError(f"node ids must be integers, got dtype {given.dtype}")
        idx = np.atleast_1d(given.astype(np.int64))
        if idx.size and (idx.min() < 0 or idx.max() >= self.n_nodes):
            raise ModelError(f"node ids must lie in 0..{self.n_nodes - 1}, got {idx.min()}..{idx.max()}")
        return idx

    def check_epoch(self, epoch: int) -> int:
        """``epoch`` as an int, or a :class:`ModelError` when it lies outside ``0..n_epochs − 1``."""
        if not 0 <= epoch < self.n_epochs:
            raise ModelError(f"epoch {epoch} outside 0..{self.n_epochs - 1}")
        return int(epoch)

    # the names subclasses have used
    _nodes = node_ids
    _epoch = check_epoch


class ObservationSeries(MeasurementSeries):
    """``(A_i,t, R_i,t, y_i,t)`` for every epoch ``t`` and node ``i``: ``epochs[t][i]`` is a :class:`NodeEpoch`,
    a tuple ``(A, R)`` / ``(A, R, y)``, or ``None`` (no data). The number of rows may vary freely.

    Validated once at construction; errors name the epoch and node.
    """

    def __init__(self, n_states: int, epochs: Sequence[Sequence[NodeData]]) -> None:
        p = whole_number(n_states, "n_states", minimum=1, error=ModelError)
        affordable_nodes(p * p, f"n_states={p:,}: a p×p matrix", error=ModelError, items="entries", hint="")
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
                    raise ModelError(
                        f"epoch {t}, node {i}: expected NodeEpoch, (A, R[, y]) or None, got {type(item).__name__}"
                    )
                Aw, yw = _whiten(A, R, y, p, f"epoch {t}, node {i}")
                Ar.append(Aw)
                yr.append(yw)
            self._A.append(Ar)
            self._y.append(yr)

    def normals(self, epoch: int, nodes: IntArray | None = None) -> tuple[FloatArray, FloatArray]:
        t = self.check_epoch(epoch)
        idx = self.node_ids(nodes)
        p = self.n_states
        N = np.zeros((idx.size, p, p))
        r = np.zeros((idx.size, p))
        for k, i in enumerate(idx):
            A = self._A[t][i]
            if A.shape[0]:
                N[k] = A.T @ A
                r[k] = A.T @ self._y[t][i]
        return N, r

    def observations(self, epoch: int, nodes: IntArray | None = None) -> tuple[FloatArray, FloatArray, IntArray]:
        t = self.check_epoch(epoch)
        idx = self.node_ids(nodes)
        A = [self._A[t][i] for i in idx]
        y = [self._y[t][i] for i in idx]
        node = (
            np.concatenate([np.full(a.shape[0], i, np.int64) for a, i in zip(A, idx, strict=True)])
            if idx.size
            else np.zeros(0, np.int64)
        )
        return (
            np.concatenate(A, axis=0) if A else np.zeros((0, self.n_states)),
            np.concatenate(y) if y else np.zeros(0),
            node,
        )


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

    def normals(self, epoch: int, nodes: IntArray | None = None) -> tuple[FloatArray, FloatArray]:
        t = self.check_epoch(epoch)
        if nodes is None:
            return self._N[t], self._r[t]
        idx = self.node_ids(nodes)
        return self._N[t, idx], self._r[t, idx]


class FunctionSeries(MeasurementSeries):
    """Normals computed on demand by ``fn(epoch, nodes) -> (N (k×p×p), r (k×p))`` (large runs, streaming data)."""

    def __init__(
        self, n_nodes: int, n_epochs: int, n_states: int, fn: Callable[[int, np.ndarray], tuple[np.ndarray, np.ndarray]]
    ) -> None:
        if min(n_nodes, n_epochs, n_states) < 1:
            raise ModelError("n_nodes, n_epochs and n_states must be ≥ 1")
        self.n_nodes, self.n_epochs, self.n_states = int(n_nodes), int(n_epochs), int(n_states)
        self._fn = fn

    def normals(self, epoch: int, nodes: IntArray | None = None) -> tuple[FloatArray, FloatArray]:
        t = self.check_epoch(epoch)
        idx = self.node_ids(nodes)
        N, r = self._fn(t, idx)
        p = self.n_states
        if np.shape(N) != (idx.size, p, p) or np.shape(r) != (idx.size, p):
            raise ModelError(
                f"epoch {t}: fn returned shapes {np.shape(N)}, {np.shape(r)}; expected "
                f"{(idx.size, p, p)}, {(idx.size, p)}"
            )
        return np.asarray(N, float), np.asarray(r, float)


def check_model(dynamics: DynamicModel, measurements: MeasurementSeries) -> None:
    """Raise :class:`ModelError` unless the dynamic model and the measurements agree (states, epochs)."""
    if dynamics.n_states != measurements.n_states:
        raise ModelError(f"dynamic model has {dynamics.n_states} states, measurements {measurements.n_states}")
    dynamics.check_epochs(measurements.n_epochs)
