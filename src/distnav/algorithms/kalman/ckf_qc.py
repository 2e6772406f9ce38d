"""Node-local precision and innovation tests of the consensus Kalman filter (issue 12 items 3–4).

**Node-local precision.** Fig. 7 of paper 003 needs ``E_i = Σ_j l_ij² N_j`` at node ``i``, which no node holds.
Two forms run with the CKF's own messages only (no global gather):

* ``"exact"`` — every node appends to its consensus payload its row of the identity and its own normal matrix in
  its own slot (``e_j ⊗ N_j``). After ``k_n`` rounds node ``i`` holds ``l_ij`` and ``l_ij N_j`` for every ``j``, so
  ``E_i = Σ_j l_ij (l_ij N_j)`` exactly: the node-local variance *equals* the Fig. 7 value (up to rounding).
  Cost: ``n (p(p+1)/2 + 1)`` more floats in every message — for small networks (tens of nodes); O(n² p²) memory.
* ``"bound"`` — every node appends only its identity row (``n`` floats); node ``i`` then knows ``l_i`` and uses
  ``E_i ≼ (max_j l_ij) Σ_j l_ij N_j = (max_j l_ij) N_i^(k_n)`` (valid because ``l_ij ≥ 0``: each dropped term
  ``l_ij (max − l_ij) N_j`` is PSD). The Fig. 7 recursion is monotone in ``E`` (the time update is a congruence
  plus a constant, the measurement update adds ``n² E``), so the node-local ``P_i`` is never smaller than the exact
  one: never optimistic. It is loose where the rows of ``L`` are far from flat (measured in ``docs/ckf.md``).

**Innovation tests.** Before its normals enter the consensus, node ``i`` tests its whitened predicted residuals
``v = y − A x̂_i,t|t−1`` with ``D(v) = I + A P_i,t|t−1 Aᵀ`` (``P`` node-local, from above): Baarda's w-test of each
observation ``w_k = (D(v)⁻¹ v)_k / sqrt((D(v)⁻¹)_kk)`` (:func:`distnav.algorithms.statistics.w_statistics`) and the
local χ² ``vᵀ D(v)⁻¹ v``. The largest ``|w|`` above the critical value is rejected and the rest retested until
nothing is flagged; the kept rows form the node's normals. Rows touching a state entry the node cannot yet predict
(BLUP start) are not tested.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import special

from distnav.algorithms.kalman import InnovationTests
from distnav.algorithms.statistics import w_statistics
from distnav.errors import ModelError
from distnav.exchange import Exchange
from distnav.exchange.core import CommTotals
from distnav.typing import BoolArray, FloatArray, IntArray

__all__ = [
    "InnovationCollector",
    "NodeEpochTest",
    "chi2_critical",
    "innovation_test",
    "local_extra_bound",
    "local_extra_exact",
]


def local_extra_exact(L_rows: FloatArray, tagged: FloatArray) -> FloatArray:
    """``E_i = Σ_j l_ij (l_ij N_j)`` from the mixed identity rows ``(k, n)`` and tagged normals ``(k, n, t)``."""
    out: FloatArray = np.einsum("kj,kjt->kt", L_rows, tagged)
    return out


def local_extra_bound(L_rows: FloatArray, consensus_tri: FloatArray) -> FloatArray:
    """``(max_j l_ij) N_i^(k_n)`` (upper triangles), an upper bound of ``Σ_j l_ij² N_j`` for ``l_ij ≥ 0``."""
    if L_rows.size and float(L_rows.min()) < -1e-12:
        raise ModelError(
            "the node-local precision bound needs non-negative consensus weights (the product L has "
            f"an entry {float(L_rows.min()):.3g}); use local_precision='exact'"
        )
    out: FloatArray = L_rows.max(axis=1, initial=0.0)[:, None] * consensus_tri
    return out


@dataclass(frozen=True, eq=False)
class NodeEpochTest:
    """Innovation tests of one node at one epoch (rows = its whitened observations).

    w : w statistic of every row in the first test (NaN: not tested). keep : rows kept after rejection.
    removed : rejected rows in rejection order. chi2, dof : local χ² of the tested rows and their number.
    """

    w: FloatArray
    keep: BoolArray
    removed: tuple[int, ...]
    chi2: float
    dof: int


def innovation_test(
    A: FloatArray, y: FloatArray, x_pred: FloatArray, P_pred: FloatArray, est_pred: BoolArray, critical: float
) -> NodeEpochTest:
    """Iterative w-tests of one node's whitened predicted residuals (module docstring)."""
    m = A.shape[0]
    w_first = np.full(m, np.nan)
    keep = np.ones(m, bool)
    testable = np.flatnonzero(~(A[:, ~est_pred] != 0).any(axis=1)) if m else np.zeros(0, np.int64)
    if testable.size == 0:
        return NodeEpochTest(w_first, keep, (), float("nan"), 0)
    e = np.flatnonzero(est_pred)
    Ae = A[np.ix_(testable, e)]
    v = y[testable] - Ae @ x_pred[e]
    Dv = np.eye(testable.size) + Ae @ P_pred[np.ix_(e, e)] @ Ae.T
    active = np.arange(testable.size)
    removed: list[int] = []
    chi2 = float("nan")
    while active.size:
        Di = np.linalg.inv(Dv[np.ix_(active, active)])
        wv = Di @ v[active]
        w = w_statistics(wv, np.diagonal(Di))
        if not removed:
            w_first[testable] = w
            chi2 = float(v @ wv)
        absw = np.where(np.isfinite(w), np.abs(w), -1.0)
        worst = int(np.argmax(absw))
        if absw[worst] <= critical:
            break
        removed.append(int(testable[active[worst]]))
        keep[testable[active[worst]]] = False
        active = np.delete(active, worst)
    return NodeEpochTest(w_first, keep, tuple(removed), chi2, int(testable.size))


def chi2_critical(dof: IntArray, level: float) -> FloatArray:
    """Upper critical values of χ²(dof) at ``level`` (NaN where dof = 0; scipy.stats.chi2.isf's own formula, without
    importing scipy.stats: 1.3 s CPU)."""
    d = np.asarray(dof)
    out: FloatArray = np.where(d > 0, special.chdtri(np.maximum(d, 1), level), np.nan)
    return out


class InnovationCollector:
    """Gathers every epoch's :class:`NodeEpochTest` of an exchange block into whole-network arrays.

    Per epoch each block pads its nodes' rows to the network-wide maximum (one ``allreduce``) and gathers them
    with ``gather_nodes`` (monitoring/results only, like every result of a run), so the same arrays come out on
    every backend.
    """

    def __init__(self, exchange: Exchange, n_nodes: int, level: float, critical: float) -> None:
        self.ex, self.n, self.level, self.critical = exchange, n_nodes, level, critical
        self._w: list[FloatArray] = []
        self._rank: list[IntArray] = []
        self._chi2: list[FloatArray] = []
        self._dof: list[IntArray] = []

    def add(self, tests: tuple[NodeEpochTest | None, ...]) -> None:
        m_loc = max((t.w.size for t in tests if t is not None), default=0)
        m = int(self.ex.allreduce(m_loc, "max"))
        k = len(tests)
        w = np.full((k, m), np.nan)
        rank = np.full((k, m), -1, np.int64)  # order of rejection at that node-epoch, −1 = kept
        chi2 = np.full(k, np.nan)
        dof = np.zeros(k, np.int64)
        for a, t in enumerate(tests):
            if t is None:
                continue
            w[a, : t.w.size] = t.w
            for j, row in enumerate(t.removed):
                rank[a, row] = j
            chi2[a], dof[a] = t.chi2, t.dof
        self._w.append(self.ex.gather_nodes(w))
        self._rank.append(self.ex.gather_nodes(rank))
        self._chi2.append(self.ex.gather_nodes(chi2))
        self._dof.append(self.ex.gather_nodes(dof))

    def build(self) -> InnovationTests:
        epochs, nodes, rows, ws, removed_keys = [], [], [], [], []
        for t, (w, rank) in enumerate(zip(self._w, self._rank, strict=True)):
            i, k = np.nonzero(np.isfinite(w))
            epochs.append(np.full(i.size, t, np.int64))
            nodes.append(i.astype(np.int64))
            rows.append(k.astype(np.int64))
            ws.append(w[i, k])
            removed_keys.append(rank[i, k])
        epoch = np.concatenate(epochs) if epochs else np.zeros(0, np.int64)
        node = np.concatenate(nodes) if nodes else np.zeros(0, np.int64)
        row = np.concatenate(rows) if rows else np.zeros(0, np.int64)
        w_all = np.concatenate(ws) if ws else np.zeros(0)
        rank_all = np.concatenate(removed_keys) if removed_keys else np.zeros(0, np.int64)
        hit = np.flatnonzero(rank_all >= 0)
        order = hit[np.lexsort((rank_all[hit], node[hit], epoch[hit]))]
        chi2 = np.stack(self._chi2) if self._chi2 else np.zeros((0, self.n))
        dof = np.stack(self._dof) if self._dof else np.zeros((0, self.n), np.int64)
        return InnovationTests(
            node=node,
            w=w_all,
            critical_value=self.critical,
            level=self.level,
            flagged=np.abs(w_all) > self.critical,
            removed=tuple(int(j) for j in order),
            iterations=0,
            comm=CommTotals.empty(self.n),
            epoch=epoch,
            row=row,
            chi2=chi2,
            chi2_dof=dof,
            chi2_flagged=chi2 > chi2_critical(dof, self.level),
        )
