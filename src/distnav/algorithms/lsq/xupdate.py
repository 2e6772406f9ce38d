"""The linear x-update of ADMM with constraint nodes (paper 000 §4, Fig. 6, eqs. (20)/(21)), prepared once per block.

:class:`XUpdate` holds the per-node gains. The observation form's ``G_i = W_i⁻¹A_iᵀ (R_i + A_i W_i⁻¹ A_iᵀ)⁻¹``
(:func:`observation_gain`) is solved by a Cholesky factorization vectorized over the nodes when ``m_i`` is small
(:data:`SMALL_M`): the ``m × m`` matrices of 10⁵ nodes are factored by a few hundred numpy operations on node-long
vectors instead of 10⁵ LAPACK calls. The gains equal those of LAPACK's ``inv`` to rounding (≈ 1e-15 relative,
growing with the condition number of ``S_i``; tests/test_admm_setup.py), not bitwise; every node's arithmetic is
elementwise over the node axis, so they do not depend on how the nodes are split into ranks or blocks (the MPI and
in-process backends stay bitwise equal). Split from :mod:`distnav.algorithms.lsq.kernel`, which re-exports it.
"""

from __future__ import annotations

from typing import Any, Literal

import numpy as np

from distnav.algorithms.lsq.blue import LinearProblem
from distnav.errors import ModelError

__all__ = ["SMALL_M", "InLocalOrder", "XUpdate", "XUpdateMethod", "in_local_order", "observation_gain"]

XUpdateMethod = Literal["auto", "normal", "observation", "cholesky"]

#: Up to this many rows per node the observation-form gains are solved by the node-vectorized Cholesky
#: (:func:`_cholesky_solve_block`); above it by LAPACK (``np.linalg.solve``, one call per node), which is then faster
#: (2 × 10⁴ nodes, p = m + 5, CPU: m = 5 0.015 vs 0.036 s, 8 0.038 vs 0.052 s, 12 0.105 vs 0.092 s, 16 0.20 vs 0.16 s).
SMALL_M = 10

#: Nodes per block of an x-update call (its temporaries: a block's residuals and products, not the network's).
CALL_BLOCK = 2048

_BLOCK = 2048  # nodes per node-last block (a block's (p, m, k) arrays stay in cache)


class XUpdate:
    """The linear x-update of Fig. 6 for a block of nodes, prepared once.

    ``method``: ``"normal"`` — ``G_i = (N_i + W_i)⁻¹ A_iᵀR_i⁻¹`` (first form of eq. (20), a ``p × p`` inverse);
    ``"observation"`` — ``G_i = W_i⁻¹ A_iᵀ (R_i + A_i W_i⁻¹ A_iᵀ)⁻¹`` (second form, an ``m_i × m_i`` inverse);
    ``"cholesky"`` — ``N_i + W_i = L Lᵀ`` factored once, ``δ`` from eq. (21) by forward and backward substitution
    (vectorized over nodes, looping over the ``p`` rows only); ``"auto"`` — the first form when ``p ≤ m``, else the
    second (paper 000 §4.3). ``W_i = c_i W`` (see the module docstring).
    """

    def __init__(self, problem: LinearProblem, W: np.ndarray, c: np.ndarray, method: XUpdateMethod = "auto") -> None:
        if method not in ("auto", "normal", "observation", "cholesky"):
            raise ModelError(
                f"unknown x-update method {method!r}; choose 'auto', 'normal', 'observation' or 'cholesky'"
            )
        if method == "auto":
            method = "normal" if problem.n_params <= problem.max_rows else "observation"
        self.method = method
        self.A = np.ascontiguousarray(problem.A)
        self.y = np.ascontiguousarray(problem.y)
        n, m, p = self.A.shape
        if method == "normal":
            N_i, _ = problem.normal_equations
            R_inv = problem.R_inv
            r_diag = _diagonal_or_none(R_inv)
            if r_diag is None:
                AtRi = np.einsum("nmp,nmk->npk", problem.A, R_inv)
            else:  # the same products without the zero terms (bitwise equal, see _diagonal_or_none)
                AtRi = np.swapaxes(problem.A * r_diag[:, :, None], 1, 2)
            self.G = np.linalg.solve(N_i + c[:, None, None] * W[None], AtRi)  # (n, p, m): W_i = c_i W
        elif method == "observation":
            self.G = observation_gain(problem, W, c)
        else:
            N_i, r_i = problem.normal_equations
            self.L = np.linalg.cholesky(N_i + c[:, None, None] * W[None])
            self.N = N_i
            self.r = r_i

    def __call__(self, l: np.ndarray, x_prev: np.ndarray | None = None) -> np.ndarray:
        """``x_i = l_i + G_i (y_i − A_i l_i)`` for every node of the block, :data:`CALL_BLOCK` nodes at a time (the
        temporaries of a block, not of the network; every node's arithmetic is the same)."""
        out = np.empty(l.shape)
        for a in range(0, l.shape[0], CALL_BLOCK):
            b = min(a + CALL_BLOCK, l.shape[0])
            out[a:b] = self.rows(l[a:b], a, b)
        return out

    def rows(self, l: np.ndarray, a: int, b: int) -> np.ndarray:
        """The x-update of nodes ``a:b`` from their ``l`` (rows ``a:b``)."""
        if self.method == "cholesky":
            rhs = self.r[a:b] - (self.N[a:b] @ l[..., None])[..., 0]  # A_iᵀR_i⁻¹(y_i − A_i l_i), eq. (21)
            x: np.ndarray = l + _cholesky_solve(self.L[a:b], rhs)
            return x
        res = self.y[a:b] - (self.A[a:b] @ l[..., None])[..., 0]
        x = l + (self.G[a:b] @ res[..., None])[..., 0]
        return x


class InLocalOrder:
    """An :class:`XUpdate` prepared on the caller's whole problem in the caller's node order, called with a block's
    rows in its own order ``nodes`` (a permutation of every node: an in-process exchange in a locality order).

    ``l`` is moved to the caller's order, updated, and ``x`` moved back (a gather and a scatter of ``n × p`` floats
    per call, :data:`CALL_BLOCK` nodes at a time)
    instead of a permuted copy of the problem's ``A``, ``y``, ``R`` and the gains in the block's order (≈ 1 kB per
    node at ``p`` = 10, ``m`` = 5). The x-update is per node, so ``x`` is bitwise that of an :class:`XUpdate` on the
    permuted copy."""

    def __init__(self, xu: XUpdate, nodes: np.ndarray) -> None:
        self.xu = xu
        self.method = xu.method
        self.nodes = np.asarray(nodes, dtype=np.intp)
        idx: type[np.signedinteger[Any]] = np.int32 if self.nodes.size < 2**31 - 1 else np.intp  # 32 bits if they fit
        position = np.empty(self.nodes.size, dtype=idx)
        position[self.nodes] = np.arange(self.nodes.size, dtype=idx)
        self.position = position  # the block's row of each node

    def __call__(self, l: np.ndarray, x_prev: np.ndarray | None = None) -> np.ndarray:
        out = np.empty(l.shape)
        for a in range(0, l.shape[0], CALL_BLOCK):
            b = min(a + CALL_BLOCK, l.shape[0])
            rows = self.position[a:b]  # the block's rows of the caller's nodes a:b
            out[rows] = self.xu.rows(np.take(l, rows, axis=0), a, b)
        return out


def in_local_order(xu: XUpdate, nodes: np.ndarray) -> XUpdate | InLocalOrder:
    """``xu`` (on every node, the caller's order) for a block whose rows are ``nodes``: itself when ``nodes`` is the
    caller's order, else an :class:`InLocalOrder` around it."""
    nodes = np.asarray(nodes)
    if bool((nodes == np.arange(nodes.size)).all()):
        return xu
    return InLocalOrder(xu, nodes)


def observation_gain(problem: LinearProblem, W: np.ndarray, c: np.ndarray) -> np.ndarray:
    """The gains ``G_i = W_i⁻¹A_iᵀ S_i⁻¹`` ``(n, p, m)``, ``S_i = R_i + A_i W_i⁻¹ A_iᵀ``, ``W_i = c_i W`` (second form
    of eq. (20)), computed as ``(S_i⁻¹ B_i)ᵀ`` with ``B_i = A_i W_i⁻¹`` (``S_i`` and ``W_i`` symmetric).

    ``W⁻¹`` diagonal (``W = ρI`` or a diagonal ``W``) and ``m ≤`` :data:`SMALL_M`: one pass over blocks of nodes
    turned node-last (:func:`_diagonal_w_gain`); a full ``W``: ``S_i`` by einsum, then the same Cholesky
    (:func:`_spd_solve_nodes_last`); ``m >`` :data:`SMALL_M`: LAPACK."""
    A = np.ascontiguousarray(problem.A)
    n, m, p = A.shape
    Winv1 = np.linalg.inv(W)
    w_diag = _diagonal_or_none(Winv1[None])
    if w_diag is not None and m <= SMALL_M:
        return _diagonal_w_gain(A, problem.R, w_diag[0][None, :] / c[:, None])
    if w_diag is None:
        Winv = Winv1[None] / c[:, None, None]
        S = problem.R + np.einsum("nmp,npq,nkq->nmk", A, Winv, A)
        B = np.einsum("npq,nmq->nmp", Winv, A)  # A_i W_i⁻¹
    else:
        B = A * (w_diag[0][None, :] / c[:, None])[:, None, :]
        S = problem.R + np.einsum("nmp,nkp->nmk", B, A)
    if m > SMALL_M:
        G: np.ndarray = np.swapaxes(np.linalg.solve(S, B), 1, 2)
        return G
    return _spd_solve_nodes_last(S, B)


def _diagonal_w_gain(A: np.ndarray, R: np.ndarray, w: np.ndarray, block: int = _BLOCK) -> np.ndarray:
    """:func:`observation_gain` for ``W_i⁻¹ = diag(w_i)`` (``w`` ``(n, p)``): per block of nodes, node-last,
    ``B = A_i diag(w_i)``, ``S_i = R_i + Σ_j B[:, j] A[:, j]ᵀ`` (term by term in ``j`` over the node axis), then the
    Cholesky solve in place. Neither ``S`` nor ``B`` is formed for all nodes at once."""
    n, m, p = A.shape
    out = np.empty((n, p, m))
    k_max = min(block, n)
    acc = np.empty((m, m, k_max))
    prod = np.empty_like(acc)
    work = _Work(m, p, k_max)
    for a in range(0, n, block):
        k = min(block, n - a)
        Ab = np.ascontiguousarray(A[a : a + k].transpose(2, 1, 0))  # (p, m, k)
        Bb = Ab * np.ascontiguousarray(w[a : a + k].T)[:, None, :]  # (p, m, k): A_i W_i⁻¹, transposed
        L, pr = acc[:, :, :k], prod[:, :, :k]
        np.copyto(L, R[a : a + k].transpose(1, 2, 0))
        for j in range(p):
            np.multiply(Bb[j][:, None, :], Ab[j][None, :, :], out=pr)
            L += pr
        Y = np.ascontiguousarray(Bb.transpose(1, 0, 2))  # (m, p, k)
        _cholesky_solve_block(L, Y, work, k)
        out[a : a + k] = Y.transpose(2, 1, 0)
    return out


def _spd_solve_nodes_last(S: np.ndarray, B: np.ndarray, block: int = _BLOCK) -> np.ndarray:
    """``(S_i⁻¹ B_i)ᵀ`` ``(n, p, m)`` for a stack of SPD ``S`` ``(n, m, m)`` and ``B`` ``(n, m, p)``, a block of
    nodes at a time turned node-last (:func:`_cholesky_solve_block`)."""
    n, m, p = B.shape
    out = np.empty((n, p, m))
    work = _Work(m, p, min(block, n))
    for a in range(0, n, block):
        k = min(block, n - a)
        L = np.ascontiguousarray(S[a : a + k].transpose(1, 2, 0))  # (m, m, k)
        Y = np.ascontiguousarray(B[a : a + k].transpose(1, 2, 0))  # (m, p, k)
        _cholesky_solve_block(L, Y, work, k)
        out[a : a + k] = Y.transpose(2, 1, 0)
    return out


class _Work:
    """Scratch vectors of a node-last Cholesky solve (reused over the blocks)."""

    def __init__(self, m: int, p: int, k: int) -> None:
        self.inv_d = np.empty((m, k))
        self.t = np.empty(k)
        self.tp = np.empty((p, k))


def _cholesky_solve_block(L: np.ndarray, Y: np.ndarray, work: _Work, k: int) -> None:
    """In place, for ``k`` nodes node-last: the lower triangle of ``L`` ``(m, m, k)`` (SPD matrices) becomes their
    Cholesky factors (``S = L Lᵀ``), and ``Y`` ``(m, p, k)`` becomes ``S⁻¹ Y`` (``L V = Y`` forward, then ``Lᵀ D = V``
    backward). The loops run over ``m`` only; every operation is over the node axis. A matrix that is not positive
    definite (a pivot ≤ 0 or NaN) is refused."""
    m = L.shape[0]
    d, t, tp = work.inv_d[:, :k], work.t[:k], work.tp[:, :k]
    for j in range(m):
        for q in range(j):
            np.multiply(L[j, q], L[j, q], out=t)
            L[j, j] -= t
        if not bool((L[j, j] > 0).all()):
            raise ModelError(
                "the observation-form x-update matrix R_i + A_i W_i⁻¹ A_iᵀ is not positive definite at "
                "some node (check R_i)"
            )
        np.sqrt(L[j, j], out=L[j, j])
        np.divide(1.0, L[j, j], out=d[j])
        for i in range(j + 1, m):
            for q in range(j):
                np.multiply(L[i, q], L[j, q], out=t)
                L[i, j] -= t
            L[i, j] *= d[j]
    for i in range(m):  # L V = Y
        for q in range(i):
            np.multiply(Y[q], L[i, q], out=tp)
            Y[i] -= tp
        Y[i] *= d[i]
    for i in range(m - 1, -1, -1):  # Lᵀ D = V
        for q in range(i + 1, m):
            np.multiply(Y[q], L[q, i], out=tp)
            Y[i] -= tp
        Y[i] *= d[i]


def _diagonal_or_none(M: np.ndarray) -> np.ndarray | None:
    """The diagonals ``(n, k)`` of a stack ``(n, k, k)`` whose off-diagonal entries are all exactly zero, else None.

    Then every product with an off-diagonal entry in an einsum over ``M`` is ±0 and adding it leaves the (finite)
    running sum unchanged, so the sums without those terms are bitwise those of the einsum (tests/test_admm_setup.py
    checks the normal form's gains against the einsum form bitwise)."""
    k = M.shape[-1]
    d = np.diagonal(M, axis1=-2, axis2=-1)
    off = M.reshape(M.shape[0], -1)[:, :-1].reshape(M.shape[0], k - 1, k + 1)[:, :, 1:]  # entries off the diagonal
    return np.ascontiguousarray(d) if not off.any() else None


def _cholesky_solve(L: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Solve ``L Lᵀ δ = b`` for a stack of lower-triangular ``L`` ``(n, p, p)``: forward then backward substitution."""
    p = L.shape[-1]
    w = np.empty_like(b)
    for j in range(p):
        w[:, j] = (b[:, j] - np.einsum("nk,nk->n", L[:, j, :j], w[:, :j])) / L[:, j, j]
    d = np.empty_like(b)
    for j in range(p - 1, -1, -1):
        d[:, j] = (w[:, j] - np.einsum("nk,nk->n", L[:, j + 1 :, j], d[:, j + 1 :])) / L[:, j, j]
    return d
