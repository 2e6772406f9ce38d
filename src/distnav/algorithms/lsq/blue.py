"""Least squares over a network of nodes: the centralized BLUE and the two reference solvers of paper 000 §3.

Every node ``i`` holds ``y_i = A_i x + e_i`` with ``C(e_i) = R_i`` (paper 000, eq. (1)). This module gives

* :class:`LinearProblem` — the per-node blocks ``(A_i, y_i, R_i)`` (any number of rows per node, full ``R_i``),
  stacked and zero-padded so every computation is batched over nodes;
* :func:`blue` — the centralized solution ``N x̂ = r`` with ``N = Σ N_i``, ``r = Σ r_i`` (eq. (4)), after a
  rank check of ``A`` (eq. (2)) that names the inestimable parameter directions (a null-space basis);
* :func:`method_of_multipliers` (eqs. (13)–(15)) and :func:`single_consensus_admm` (eq. (16)) — the
  iterative schemes of paper 000 §3, with the dual function ``g(u)`` of eq. (10) (:func:`dual_function`).
  **Both need a fusion centre**: (15) needs every node's data for ``z^[k]``, and (16) averages over all nodes.
  They are reference solvers for the 2-node illustration (Figs. 3–4); the distributed algorithm, with
  constraint nodes and message rounds, is :func:`distnav.algorithms.lsq.admm.admm` (Fig. 6).

Conventions: ``f_i(x) = ½‖y_i − A_i x‖²_{R_i⁻¹}`` (eq. (3)); multipliers ``u_i`` are the *scaled* ones of eq. (8)
(the penalty is ``½‖x_i − (z − u_i)‖²_W``), so ``W û_i = r_i − N_i x̂`` at the solution (eq. (9)).
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any

import numpy as np

from distnav._checks import real_array, real_number, whole_number
from distnav._settings import runs
from distnav.algorithms.lsq.conditions import inestimable_directions, null_space_directions, weight_matrix
from distnav.algorithms.result import SolverResult, TraceBuilder
from distnav.errors import ModelError
from distnav.exchange.core import CommTotals
from distnav.typing import ArrayLike, FloatArray

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


# ----------------------------------------------------------------------------------------------- problem
def _node(names: Sequence[str] | None, i: int) -> str:
    return f"node {names[i]}" if names is not None else f"node {i}"


def _as_R(Ri: ArrayLike | None, m: int, i: int, names: Sequence[str] | None) -> np.ndarray:
    if Ri is None:
        return np.eye(m)
    R = np.asarray(Ri, dtype=float)
    if R.ndim == 0:
        R = np.full(m, float(R))
    if R.ndim == 1:
        if R.shape != (m,):
            raise ModelError(f"{_node(names, i)}: variances R_i have {R.shape[0]} entries for {m} observations")
        if not np.all(np.isfinite(R)) or np.any(R <= 0):
            raise ModelError(f"{_node(names, i)}: variances R_i must be finite and > 0, got {R}")
        return np.diag(R)
    if R.shape != (m, m):
        raise ModelError(f"{_node(names, i)}: R_i must be ({m}, {m}) for {m} observations, got {R.shape}")
    return R


@dataclass(frozen=True, eq=False)
class LinearProblem:
    """Per-node linear observation equations ``y_i = A_i x + e_i``, ``C(e_i) = R_i`` (paper 000, eq. (1)).

    Stored stacked over nodes and zero-padded to the largest row count ``m``: ``A`` is ``(n, m, p)``, ``y`` is
    ``(n, m)``, ``R`` is ``(n, m, m)`` with an identity block on padded rows (padded rows have ``A = 0``, ``y = 0``
    and so contribute nothing). ``rows[i]`` is the true ``m_i``. Build with :meth:`from_blocks` (lists of
    per-node arrays) or :meth:`from_stacked` (equal row counts, fast for large networks).
    """

    A: np.ndarray
    y: np.ndarray
    R: np.ndarray
    rows: np.ndarray
    parameter_names: tuple[str, ...] | None = None
    node_names: tuple[str, ...] | None = None
    _cache: dict[str, Any] = field(default_factory=dict, repr=False, compare=False)

    # -------------------------------------------------------------- construction
    @classmethod
    def from_blocks(
        cls,
        A: Sequence[ArrayLike],
        y: Sequence[ArrayLike],
        R: Sequence[ArrayLike] | None = None,
        *,
        parameter_names: Sequence[str] | None = None,
        node_names: Sequence[str] | None = None,
    ) -> LinearProblem:
        """Build from per-node ``A_i`` (``m_i × p``), ``y_i`` (``m_i``) and ``R_i`` (``m_i × m_i`` full,
        ``m_i`` variances, a scalar variance, or None for identity). A node may have zero rows."""
        n = len(A)
        names = None if node_names is None else tuple(str(s) for s in node_names)
        if n == 0:
            raise ModelError("a problem needs at least one node")
        if len(y) != n:
            raise ModelError(f"got {n} design matrices but {len(y)} observation vectors")
        if R is not None and len(R) != n:
            raise ModelError(f"got {n} design matrices but {len(R)} variance matrices")
        if names is not None and len(names) != n:
            raise ModelError(f"got {len(names)} node names for {n} nodes")
        blocks = []
        p = None
        for i in range(n):
            Ai = real_array(A[i], f"{_node(names, i)}: A_i entries", error=ModelError)
            if Ai.ndim != 2:
                raise ModelError(f"{_node(names, i)}: A_i must be a 2-D (m_i, p) array, got shape {Ai.shape}")
            if p is None:
                p = Ai.shape[1]
            if Ai.shape[1] != p:
                raise ModelError(f"{_node(names, i)}: A_i has {Ai.shape[1]} columns, node 0 has {p}")
            yi = real_array(y[i], f"{_node(names, i)}: y_i entries", error=ModelError)
            if yi.shape != (Ai.shape[0],):
                raise ModelError(f"{_node(names, i)}: y_i has shape {yi.shape}, A_i has {Ai.shape[0]} rows")
            blocks.append((Ai, yi, _as_R(None if R is None else R[i], Ai.shape[0], i, names)))
        assert p is not None
        if p < 1:
            raise ModelError("the parameter vector x must have at least one entry (p ≥ 1)")
        m = max(max(b[0].shape[0] for b in blocks), 1)
        A_s = np.zeros((n, m, p))
        y_s = np.zeros((n, m))
        R_s = np.broadcast_to(np.eye(m), (n, m, m)).copy()
        rows = np.zeros(n, dtype=np.int64)
        for i, (Ai, yi, Ri) in enumerate(blocks):
            mi = Ai.shape[0]
            A_s[i, :mi], y_s[i, :mi], R_s[i, :mi, :mi], rows[i] = Ai, yi, Ri, mi
        return cls._validated(A_s, y_s, R_s, rows, parameter_names, names)

    @classmethod
    def from_stacked(
        cls,
        A: np.ndarray,
        y: np.ndarray,
        R: np.ndarray | None = None,
        *,
        parameter_names: Sequence[str] | None = None,
        node_names: Sequence[str] | None = None,
    ) -> LinearProblem:
        """Build from stacked arrays with the same row count ``m`` at every node: ``A (n, m, p)``, ``y (n, m)``,
        ``R`` ``(n, m, m)`` full, ``(n, m)`` variances, or None (identity)."""
        A_s = real_array(A, "stacked A entries", error=ModelError)
        y_s = real_array(y, "stacked y entries", error=ModelError)
        if A_s.ndim != 3:
            raise ModelError(f"stacked A must have shape (n_nodes, m, p), got {A_s.shape}")
        n, m, _p = A_s.shape
        if y_s.shape != (n, m):
            raise ModelError(f"stacked y must have shape ({n}, {m}), got {y_s.shape}")
        if R is None:  # one read-only identity block seen by every node (no n × m × m copy: 200 B per node at m = 5)
            R_s = np.broadcast_to(np.eye(m), (n, m, m))
        else:
            R_s = real_array(R, "stacked R entries", error=ModelError)
            if R_s.shape == (n, m):
                if not np.all(np.isfinite(R_s)) or np.any(R_s <= 0):
                    bad = int(np.flatnonzero(~(np.isfinite(R_s) & (R_s > 0)).all(axis=1))[0])
                    raise ModelError(f"{_node(node_names, bad)}: variances must be finite and > 0")
                R_s = R_s[:, :, None] * np.eye(m)
            elif R_s.shape != (n, m, m):
                raise ModelError(f"stacked R must have shape ({n}, {m}, {m}) or ({n}, {m}), got {R_s.shape}")
        names = None if node_names is None else tuple(str(s) for s in node_names)
        return cls._validated(A_s, y_s, R_s, np.full(n, m, dtype=np.int64), parameter_names, names)

    @classmethod
    def _validated(
        cls,
        A: np.ndarray,
        y: np.ndarray,
        R: np.ndarray,
        rows: np.ndarray,
        parameter_names: Sequence[str] | None,
        names: tuple[str, ...] | None,
    ) -> LinearProblem:
        n, m, p = A.shape
        for what, arr in (("A_i", A), ("y_i", y), ("R_i", R)):
            finite = np.isfinite(arr.reshape(n, -1)).all(axis=1)
            if not finite.all():
                raise ModelError(f"{_node(names, int(np.argmin(finite)))}: {what} has non-finite entries")
        asym = np.abs(R - np.swapaxes(R, 1, 2)).reshape(n, -1).max(axis=1)
        scale = np.abs(R).reshape(n, -1).max(axis=1)
        bad = asym > 1e-10 * np.maximum(scale, 1e-300)
        if bad.any():
            i = int(np.argmax(bad))
            raise ModelError(f"{_node(names, i)}: R_i is not symmetric (max |R − Rᵀ| = {asym[i]:.3g})")
        try:
            np.linalg.cholesky(R)
        except np.linalg.LinAlgError:
            for i in range(n):  # only on failure: find and name the offending node
                if np.linalg.eigvalsh(R[i]).min() <= 0:
                    raise ModelError(
                        f"{_node(names, i)}: R_i is not positive definite "
                        f"(smallest eigenvalue {np.linalg.eigvalsh(R[i]).min():.3g})"
                    ) from None
            raise
        pn = None
        if parameter_names is not None:
            pn = tuple(str(s) for s in parameter_names)
            if len(pn) != p:
                raise ModelError(f"got {len(pn)} parameter names for p = {p} parameters")
        for arr in (A, y, R):
            arr.setflags(write=False)
        return cls(A=A, y=y, R=R, rows=rows, parameter_names=pn, node_names=names)

    # -------------------------------------------------------------- facts
    @property
    def n_nodes(self) -> int:
        return int(self.A.shape[0])

    @property
    def n_params(self) -> int:
        return int(self.A.shape[2])

    @property
    def max_rows(self) -> int:
        return int(self.A.shape[1])

    def node_label(self, i: int) -> str:
        return _node(self.node_names, i)

    def param_label(self, k: int) -> str:
        return self.parameter_names[k] if self.parameter_names is not None else f"x[{k}]"

    @cached_property
    def R_inv(self) -> np.ndarray:
        """``R_i⁻¹`` for every node, ``(n, m, m)``."""
        return np.linalg.inv(self.R)

    @cached_property
    def normal_equations(self) -> tuple[np.ndarray, np.ndarray]:
        """Per-node ``N_i = A_iᵀR_i⁻¹A_i`` ``(n, p, p)`` and ``r_i = A_iᵀR_i⁻¹y_i`` ``(n, p)`` (paper 000, eq. (4))."""
        L = np.linalg.cholesky(self.R)
        Aw = np.linalg.solve(L, self.A)
        yw = np.linalg.solve(L, self.y[..., None])[..., 0]
        N = np.einsum("nmp,nmq->npq", Aw, Aw)
        r = np.einsum("nmp,nm->np", Aw, yw)
        return N, r

    def cost(self, x: np.ndarray) -> np.ndarray:
        """``f_i(x_i) = ½‖y_i − A_i x_i‖²_{R_i⁻¹}`` per node, for ``x`` of shape ``(p,)`` or ``(n, p)``."""
        xx = np.broadcast_to(np.asarray(x, float), (self.n_nodes, self.n_params))
        e = self.y - np.einsum("nmp,np->nm", self.A, xx)
        cost: np.ndarray = 0.5 * np.einsum("nm,nmk,nk->n", e, self.R_inv, e)
        return cost

    def subset(self, nodes: np.ndarray) -> LinearProblem:
        """The blocks of the given nodes (e.g. an exchange block's ``ex.nodes``)."""
        idx = np.asarray(nodes, dtype=np.int64)
        names = None if self.node_names is None else tuple(self.node_names[i] for i in idx)
        return LinearProblem(
            A=self.A[idx],
            y=self.y[idx],
            R=self.R[idx],
            rows=self.rows[idx],
            parameter_names=self.parameter_names,
            node_names=names,
        )


@dataclass(frozen=True, eq=False)
class BlueSolution:
    """The centralized least-squares solution (paper 000, eqs. (3)–(4)).

    ``x`` is the BLUE ``x̂``, ``covariance = N⁻¹``, ``normal_matrix = N = Σ N_i``, ``rhs = r = Σ r_i``,
    ``cost = Σ f_i(x̂)`` (the optimal value of eq. (12)), ``multipliers`` the ``û_i`` of eq. (9) for ``W`` when
    requested.
    """

    x: np.ndarray
    covariance: np.ndarray
    normal_matrix: np.ndarray
    rhs: np.ndarray
    cost: float
    multipliers: np.ndarray | None = None


def blue(problem: LinearProblem, *, rcond: float = 1e-10, W: ArrayLike | None = None) -> BlueSolution:
    """Centralized BLUE from the per-node normal equations: ``N x̂ = r``, ``N = Σ N_i``, ``r = Σ r_i``
    (paper 000, eq. (4)). This is what a fusion centre computes.

    Raises :class:`~distnav.errors.ModelError` when ``rank(A) < p`` (eq. (2) fails), naming a basis of the
    inestimable directions (e.g. ``x[0] − x[1]``). With ``W`` also returns ``û_i = W⁻¹(r_i − N_i x̂)`` (eq. (9)).

    Examples
    --------
    Three nodes with one observation each of ``x = (x₀, x₁)``: ``x₀``, ``x₁`` and ``x₀ + x₁``. No node alone can
    solve for ``x``; the BLUE is ordinary least squares on the stacked rows (``R_i = I``):

    >>> import numpy as np
    >>> from distnav.algorithms.lsq.blue import LinearProblem, blue
    >>> A = [np.array([[1.0, 0.0]]), np.array([[0.0, 1.0]]), np.array([[1.0, 1.0]])]
    >>> y = [np.array([1.0]), np.array([2.0]), np.array([3.3])]
    >>> sol = blue(LinearProblem.from_blocks(A, y))
    >>> sol.x.round(6)
    array([1.1, 2.1])
    >>> bool(np.allclose(sol.x, np.linalg.lstsq(np.vstack(A), np.concatenate(y), rcond=None)[0]))
    True
    """
    rcond = real_number(rcond, "rcond", minimum=0.0, below=1.0, error=ModelError)
    N_i, r_i = problem.normal_equations
    N = N_i.sum(axis=0)
    r = r_i.sum(axis=0)
    text = inestimable_directions(N, problem.param_label, rcond=rcond)
    if text is not None:
        raise ModelError(text)
    L = np.linalg.cholesky(N)
    x = np.linalg.solve(L.T, np.linalg.solve(L, r))
    Linv = np.linalg.inv(L)
    cov = Linv.T @ Linv
    u = None
    if W is not None:
        Wm = weight_matrix(W, problem.n_params)
        u = np.linalg.solve(Wm, (r_i - N_i @ x).T).T
    return BlueSolution(x=x, covariance=cov, normal_matrix=N, rhs=r, cost=float(problem.cost(x).sum()), multipliers=u)


# ----------------------------------------------------------------------------------------------- §3 reference
def _gain(problem: LinearProblem, Wm: np.ndarray) -> np.ndarray:
    """``G_i = (N_i + W)⁻¹ A_iᵀ R_i⁻¹`` (paper 000, eq. (15)), ``(n, p, m)``."""
    N_i, _ = problem.normal_equations
    AtRi = np.einsum("nmp,nmk->npk", problem.A, problem.R_inv)
    return np.linalg.solve(N_i + Wm, AtRi)


def _x_of(problem: LinearProblem, G: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``x_i = v_i + G_i (y_i − A_i v_i)`` for ``v_i = z − u_i`` (paper 000, eqs. (15)–(16))."""
    res = problem.y - np.einsum("nmp,np->nm", problem.A, v)
    x: np.ndarray = v + np.einsum("npm,nm->np", G, res)
    return x


def multiplier_step(problem: LinearProblem, u: np.ndarray, W: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """Minimize ``L_W`` jointly over ``x_1..x_n, z`` for given multipliers ``u`` (paper 000, eq. (15)).

    ``z = (Σ H_i)⁻¹ Σ h_i`` with ``H_i = A_iᵀ(R_i + A_iW⁻¹A_iᵀ)⁻¹A_i``,
    ``h_i = A_iᵀ(R_i + A_iW⁻¹A_iᵀ)⁻¹(y_i + A_i u_i)``;
    then ``x_i = z − u_i + G_i(y_i − A_i[z − u_i])``. Needs every node's data: a fusion-centre step.
    """
    Wm = weight_matrix(W, problem.n_params)
    u = _check_u(problem, u)
    Winv = np.linalg.inv(Wm)
    S = problem.R + np.einsum("nmp,pq,nkq->nmk", problem.A, Winv, problem.A)
    Q = np.linalg.inv(S)
    AtQ = np.einsum("nmp,nmk->npk", problem.A, Q)
    H = np.einsum("npk,nkq->pq", AtQ, problem.A)
    h = np.einsum("npk,nk->p", AtQ, problem.y + np.einsum("nmp,np->nm", problem.A, u))
    try:
        z = np.linalg.solve(H, h)
    except np.linalg.LinAlgError:
        raise ModelError("Σ H_i is singular: rank(A) < p (paper 000, eq. (2)); run blue() for the directions") from None
    x = _x_of(problem, _gain(problem, Wm), z[None, :] - u)
    return x, z


def _check_u(problem: LinearProblem, u: ArrayLike) -> np.ndarray:
    arr = np.asarray(u, dtype=float)
    shape = (problem.n_nodes, problem.n_params)
    if arr.shape != shape:
        raise ModelError(f"multipliers u must have shape {shape} (one u_i per node), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ModelError("multipliers u have non-finite entries")
    return arr


def dual_function(problem: LinearProblem, u: np.ndarray, W: ArrayLike) -> float:
    """The dual function ``g(u) = min_{x_i, z} L_W`` (paper 000, eq. (10)):
    ``Σ f_i(x̂_i(u)) + ½‖x̂_i(u) − (ẑ(u) − u_i)‖²_W − ½‖u_i‖²_W``, a lower bound of ``Σ f_i(x̂)`` (eq. (11))."""
    Wm = weight_matrix(W, problem.n_params)
    u = _check_u(problem, u)
    x, z = multiplier_step(problem, u, Wm)
    d = x - (z[None, :] - u)
    return float(
        problem.cost(x).sum() + 0.5 * np.einsum("np,pq,nq->", d, Wm, d) - 0.5 * np.einsum("np,pq,nq->", u, Wm, u)
    )


@dataclass(frozen=True, eq=False)
class MultiplierState:
    """Iterate ``k`` of the §3 schemes: ``x[i] = x_i^[k]``, ``z = z^[k]``, ``u[i] = u_i^[k]`` (after the update)."""

    iteration: int
    x: np.ndarray
    z: np.ndarray
    u: np.ndarray


def _init_u(problem: LinearProblem, u0: ArrayLike | None) -> np.ndarray:
    if u0 is None:
        return np.zeros((problem.n_nodes, problem.n_params))
    return _check_u(problem, u0).copy()


def iterate_method_of_multipliers(
    problem: LinearProblem, *, W: ArrayLike, iterations: int, u0: ArrayLike | None = None
) -> Iterator[MultiplierState]:
    """The method of multipliers (paper 000, eq. (13)): step 1 solves ``∂_{x_i}L_W = 0, ∂_zL_W = 0`` jointly
    (eq. (15)), step 2 moves ``u`` along the ascent direction ``d_i = x_i − z`` (eq. (14)).
    Needs a fusion centre (``z^[k]`` uses all nodes' data). Yields states ``k = 1..iterations``."""
    Wm = weight_matrix(W, problem.n_params)
    iterations = whole_number(iterations, "iterations", error=ModelError)
    u = _init_u(problem, u0)
    for k in range(1, iterations + 1):
        x, z = multiplier_step(problem, u, Wm)
        u = u + (x - z[None, :])
        yield MultiplierState(k, x, z, u)


def iterate_single_consensus_admm(
    problem: LinearProblem, *, W: ArrayLike, iterations: int, z0: ArrayLike, u0: ArrayLike | None = None
) -> Iterator[MultiplierState]:
    """ADMM with one consensus state (paper 000, eq. (16)):
    ``x_i^[k] = z^[k−1] − u_i^[k−1] + G_i(y_i − A_i[z^[k−1] − u_i^[k−1]])``, ``z^[k] = (1/n) Σ (x_i^[k] + u_i^[k−1])``,
    ``u_i^[k] = u_i^[k−1] + x_i^[k] − z^[k]``. The average over all nodes needs a fusion centre.
    Yields states ``k = 1..iterations``."""
    p = problem.n_params
    Wm = weight_matrix(W, p)
    iterations = whole_number(iterations, "iterations", error=ModelError)
    z = np.broadcast_to(np.asarray(z0, dtype=float), (p,)).copy() if np.ndim(z0) <= 1 else None
    if z is None or not np.all(np.isfinite(z)):
        raise ModelError(f"z0 must be a scalar or a length-{p} vector of finite values, got {z0!r}")
    u = _init_u(problem, u0)
    G = _gain(problem, Wm)
    for k in range(1, iterations + 1):
        x = _x_of(problem, G, z[None, :] - u)
        z = (x + u).mean(axis=0)
        u = u + (x - z[None, :])
        yield MultiplierState(k, x, z, u)


@dataclass(frozen=True, eq=False, kw_only=True)
class MultiplierResult(SolverResult):
    """Outcome of the §3 reference solvers (:func:`method_of_multipliers`, :func:`single_consensus_admm`).

    ``z``: the last ``z^[k]`` (None after 0 iterations); ``u``: the last multipliers ``(n, p)`` (``u^[0]`` after 0
    iterations); ``dual_value_initial``: ``g(u^[0])`` (eq. (10)), the start of the trace's ``dual_value``.
    """

    z: FloatArray | None
    u: FloatArray
    dual_value_initial: float


def _run(
    problem: LinearProblem,
    states: Iterator[MultiplierState],
    W: ArrayLike,
    u0: ArrayLike | None,
    reference: np.ndarray | None,
    name: str,
) -> MultiplierResult:
    Wm = weight_matrix(W, problem.n_params)
    tb = TraceBuilder()
    u_start = _init_u(problem, u0)
    dual0 = dual_function(problem, u_start, Wm)
    last: MultiplierState | None = None
    for st in states:
        tb.add(
            x=st.x,
            z=st.z,
            u=st.u,
            dual_value=dual_function(problem, st.u, Wm),
            primal_residual=float(np.linalg.norm(st.x - st.z[None, :])),
        )
        if reference is not None:
            tb.add(distance_to_reference=np.linalg.norm(st.x - reference[None, :], axis=1))
        last = st
    trace = tb.build()
    if last is None:
        x_final = np.zeros((problem.n_nodes, problem.n_params))
        k = 0
    else:
        x_final, k = last.x, last.iteration
    return MultiplierResult(
        estimates=x_final,
        converged=False,
        iterations=k,
        status="max_iterations",
        message=f"{name}: {k} iterations (reference solver: needs a fusion centre)",
        trace=trace,
        comm=CommTotals.empty(problem.n_nodes),
        z=None if last is None else last.z,
        u=u_start if last is None else last.u,
        dual_value_initial=dual0,
    )


@runs(iterate_method_of_multipliers, adds=("reference",))
def method_of_multipliers(
    problem: LinearProblem,
    *,
    W: ArrayLike,
    iterations: int,
    u0: ArrayLike | None = None,
    reference: np.ndarray | None = None,
) -> MultiplierResult:
    """Run :func:`iterate_method_of_multipliers`; the trace holds ``x`` (k × n × p), ``z``, ``u``, ``dual_value``
    ``g(u^[k])`` (eq. (10)) and, with ``reference``, ``distance_to_reference``. ``dual_value_initial`` is
    ``g(u^[0])``. Reference solver: it needs a fusion centre (no communication is modelled).

    Examples
    --------
    >>> import numpy as np
    >>> from distnav.algorithms.lsq.blue import LinearProblem, method_of_multipliers
    >>> A = [np.array([[1.0, 0.0]]), np.array([[0.0, 1.0]]), np.array([[1.0, 1.0]])]
    >>> problem = LinearProblem.from_blocks(A, [np.array([1.0]), np.array([2.0]), np.array([3.3])])
    >>> method_of_multipliers(problem, W=1.0, iterations=200).estimates.round(6).tolist()  # the BLUE at every node
    [[1.1, 2.1], [1.1, 2.1], [1.1, 2.1]]
    """
    states = iterate_method_of_multipliers(problem, W=W, iterations=iterations, u0=u0)
    return _run(problem, states, W, u0, reference, "method of multipliers")


@runs(iterate_single_consensus_admm, adds=("reference",))
def single_consensus_admm(
    problem: LinearProblem,
    *,
    W: ArrayLike,
    iterations: int,
    z0: ArrayLike,
    u0: ArrayLike | None = None,
    reference: np.ndarray | None = None,
) -> MultiplierResult:
    """Run :func:`iterate_single_consensus_admm` (eq. (16)); same trace as :func:`method_of_multipliers`.
    Reference solver: the z-average needs a fusion centre."""
    states = iterate_single_consensus_admm(problem, W=W, iterations=iterations, z0=z0, u0=u0)
    return _run(problem, states, W, u0, reference, "ADMM with one consensus state")
