"""Distributed least squares by ADMM with constraint nodes (paper 000 §4, Fig. 6), linearized and nonlinear variants.

Every node ``i`` holds its data ``(A_i, y_i, R_i)`` and a local state ``x_i``; every constraint node ``s ∈ C``
(:mod:`distnav.network.constraint_nodes`) holds a consensus state ``z_s``; every pair ``(i, s)`` with ``s ∈ N_i ∩ C``
holds a scaled multiplier ``u_{i,s}`` at node ``i``. One iteration ``k`` of Fig. 6 is:

* step 1, every node ``i`` — u-update ``u_{i,s} += x_i^[k−1] − z_s^[k−1]``; ``l_i = mean_s (z_s − u_{i,s})``;
  x-update ``x_i^[k] = l_i + G_i (y_i − A_i l_i)`` (eq. (20) or Cholesky solves of eq. (21)); then **a message
  round on the pair edges i→s**: ``z_{i,s} = x_i^[k] + u_{i,s}`` to each constraint neighbour (``ex.send`` with
  ``active`` = edges into ``C``);
* step 2, every constraint node ``s`` — ``z_s^[k] = mean_{i∈N_s} z_{i,s}``, then **a broadcast round** of ``z_s``
  to its neighbours (``ex.broadcast`` with ``active`` = edges out of ``C``).

So an iteration is two message rounds; the initialization is one more (the ``z_s^[0]`` broadcast). Nodes talk
only through the exchange on local block arrays, so the same code runs under MPI. A lost message is replaced by
the last value received on that edge (a constraint node starts from its own ``z_s^[0]``, a node from its own
``x_i^[0]``), so runs with a :class:`~distnav.exchange.FaultSchedule` go on and are reproducible by its seed.

**Weighting of the x-update.** The augmented Lagrangian (19) has one penalty ``½‖x_i − (z_s − u_{i,s})‖²_W`` per
pair, so minimizing it over ``x_i`` gives ``x_i = (N_i + c_i W)⁻¹ (r_i + c_i W l_i)`` with ``c_i = |N_i ∩ C|``, i.e.
eqs. (20)/(21) with ``W`` replaced by ``W_i = c_i W``. This is the default (``x_weight="lagrangian"``). Fig. 6 as
printed uses ``G_i = (N_i + W)⁻¹…`` with the *mean* ``l_i``; with the plain-mean z-update that pair of updates is not
the ADMM of any single Lagrangian, and its fixed point satisfies ``N x* − r = −W Σ_i mean_s u_{i,s}``, which is zero
only when every ``c_i`` is equal (e.g. the single-consensus case (16)). ``x_weight="fig6"`` runs it verbatim: it
converges, but to a point that differs from the BLUE on irregular graphs (tests/test_admm.py shows both facts).

**Cost per iteration** (in-process, batched over nodes): one batched ``(p × m)`` gain product (or two batched
triangular solves), three segment sums over pairs, two message rounds. No Python loop over nodes.

:func:`admm_linearized` (paper 000 §4.3, the linearized case) and :func:`admm_nonlinear` (eq. (23)) handle
nonlinear models ``y_i = F_i(x) + e_i`` given as a :class:`NonlinearProblem`; :func:`gauss_newton` is the centralized
reference.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
import scipy.sparse as sp

from distnav.algorithms.lsq import LinearProblem, weight_matrix
from distnav.algorithms.result import LegacyResult, SolverResult, SolverStatus, TraceBuilder
from distnav.errors import ModelError
from distnav.exchange import Exchange, FaultSchedule, make_exchange
from distnav.exchange.base import CommTotals
from distnav.network.constraint_nodes import ConstraintNodes, choose_constraint_nodes
from distnav.network.graph import Graph

__all__ = [
    "AdmmState",
    "iterate_admm",
    "admm",
    "XUpdate",
    "NonlinearProblem",
    "RangeModel",
    "range_positioning_problem",
    "gauss_newton",
    "admm_linearized",
    "admm_nonlinear",
]

XUpdateMethod = Literal["auto", "normal", "observation", "cholesky"]


# ----------------------------------------------------------------------------------------------- x-update
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
            raise ModelError(f"unknown x-update method {method!r}; choose 'auto', 'normal', 'observation' or "
                             f"'cholesky'")
        if method == "auto":
            method = "normal" if problem.n_params <= problem.max_rows else "observation"
        self.method = method
        self.A = np.ascontiguousarray(problem.A)
        self.y = np.ascontiguousarray(problem.y)
        n, m, p = self.A.shape
        Wi = c[:, None, None] * W[None]  # (n, p, p)
        if method == "normal":
            N_i, _ = problem.normal_equations
            AtRi = np.einsum("nmp,nmk->npk", problem.A, problem.R_inv)
            self.G = np.linalg.solve(N_i + Wi, AtRi)  # (n, p, m)
        elif method == "observation":
            Winv = np.linalg.inv(W)[None] / c[:, None, None]
            S = problem.R + np.einsum("nmp,npq,nkq->nmk", problem.A, Winv, problem.A)
            self.G = np.einsum("npq,nmq->npm", Winv, problem.A) @ np.linalg.inv(S)
        else:
            N_i, r_i = problem.normal_equations
            self.L = np.linalg.cholesky(N_i + Wi)
            self.N = N_i
            self.r = r_i

    def __call__(self, l: np.ndarray, x_prev: np.ndarray | None = None) -> np.ndarray:
        """``x_i = l_i + G_i (y_i − A_i l_i)`` for every node of the block."""
        if self.method == "cholesky":
            rhs = self.r - (self.N @ l[..., None])[..., 0]  # A_iᵀR_i⁻¹(y_i − A_i l_i), eq. (21)
            return l + _cholesky_solve(self.L, rhs)
        res = self.y - (self.A @ l[..., None])[..., 0]
        return l + (self.G @ res[..., None])[..., 0]


def _cholesky_solve(L: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Solve ``L Lᵀ δ = b`` for a stack of lower-triangular ``L`` ``(n, p, p)``: forward then backward substitution."""
    p = L.shape[-1]
    w = np.empty_like(b)
    for j in range(p):
        w[:, j] = (b[:, j] - np.einsum("nk,nk->n", L[:, j, :j], w[:, :j])) / L[:, j, j]
    d = np.empty_like(b)
    for j in range(p - 1, -1, -1):
        d[:, j] = (w[:, j] - np.einsum("nk,nk->n", L[:, j + 1:, j], d[:, j + 1:])) / L[:, j, j]
    return d


# ----------------------------------------------------------------------------------------------- kernel
@dataclass(frozen=True, eq=False)
class AdmmState:
    """After iteration ``k`` (``k = 0``: the initial values) of Fig. 6, for this exchange block.

    ``x`` ``(n_local, p)`` local states; ``z`` ``(n_local, p)`` consensus states (rows of non-constraint nodes are 0);
    ``primal_residual`` ``sqrt(Σ_pairs ‖x_i − z_s‖²)``; ``dual_residual`` ``sqrt(Σ_pairs ‖W(z_s^[k] − z_s^[k−1])‖²)``;
    ``x_norm``, ``z_norm``: pair norms ``sqrt(Σ_pairs ‖·‖²)``; ``u_norm``: ``sqrt(Σ_i ‖W Σ_s u_{i,s}‖²)`` (at the
    solution ``W Σ_s û_{i,s} = r_i − N_i x̂``, eq. (9)), for relative stopping. Residuals and norms
    are network totals (``ex.allreduce``: monitoring only).
    """

    iteration: int
    x: np.ndarray
    z: np.ndarray
    primal_residual: float
    dual_residual: float
    x_norm: float
    z_norm: float
    u_norm: float


def _per_node(value: Any, n: int, p: int, what: str) -> np.ndarray:
    arr = np.asarray(value, dtype=float)
    if arr.ndim == 0:
        arr = np.full(p, float(arr))
    if arr.shape == (p,):
        return np.broadcast_to(arr, (n, p)).copy()
    if arr.shape == (n, p):
        return arr.copy()
    raise ModelError(f"{what} must be a scalar, a length-{p} vector or an ({n}, {p}) array, got shape {arr.shape}")


class _Kernel:
    """Fig. 6 on one exchange block; ``x_update`` maps ``(l, x_prev)`` to the new ``x`` for the block."""

    def __init__(self, ex: Exchange, C: ConstraintNodes, W: np.ndarray, p: int,
                 x_update: Callable[[np.ndarray, np.ndarray], np.ndarray]) -> None:
        g = ex.graph
        self.ex = ex
        self.W = W
        self.w_scale = float(np.linalg.eigvalsh(W).max())
        self.p = p
        self.x_update = x_update
        inC = C.mask
        self.inC_global = inC
        nodes = ex.nodes
        nl = ex.n_local
        self.inC_loc = inC[nodes]
        self.c_rows = np.flatnonzero(self.inC_loc)
        real = g.src != g.dst
        self.to_c = inC[g.dst] & real
        self.from_c = inC[g.src] & real
        real_in = ex.in_src != nodes[ex.in_dst]
        real_out = ex.out_dst != nodes[ex.out_src]
        # pairs (i, s), s ≠ i: one per in-edge s→i with s ∈ C (z_s arrives there); u_{i,s} lives here at node i
        self.ip = np.flatnonzero(inC[ex.in_src] & real_in)
        self.pair_dst = ex.in_dst[self.ip]
        n_pairs = self.ip.size
        self.S_pairs = _segment_matrix(self.pair_dst, nl)
        self.count = np.bincount(self.pair_dst, minlength=nl) + self.inC_loc  # c_i = |N_i ∩ C|
        # outgoing z_{i,s} on edges i→s, s ∈ C: the multiplier of the pair is stored at the reverse in-edge s→i
        self.op = np.flatnonzero(inC[ex.out_dst] & real_out)
        lookup = np.full(g.n_edges, -1, dtype=np.int64)
        lookup[ex.in_edges[self.ip]] = np.arange(n_pairs)
        self.op_pair = lookup[g.reverse_edge[ex.out_edges[self.op]]]
        if (self.op_pair < 0).any():  # pragma: no cover - guaranteed by symmetric graphs
            raise ModelError("pair edges are not symmetric in this exchange block")
        self.op_src = ex.out_src[self.op]
        # at constraint node s: z_{i,s} arrives on in-edges i→s
        self.ic = np.flatnonzero(self.inC_loc[ex.in_dst] & real_in)
        n_ic = self.ic.size
        self.S_c = _segment_matrix(ex.in_dst[self.ic], nl)
        self.size_s = (np.bincount(ex.in_dst[self.ic], minlength=nl) + 1).astype(float)  # |N_s|
        n_in = ex.in_edges.size
        self.S_pairs_all = sp.csr_matrix((np.ones(n_pairs), (self.pair_dst, self.ip)), shape=(nl, n_in))
        self.S_c_all = sp.csr_matrix((np.ones(n_ic), (ex.in_dst[self.ic], self.ic)), shape=(nl, n_in))
        self.out_buf = np.zeros((ex.out_edges.size, p))
        self.w_iso = float(W[0, 0]) if np.array_equal(W, W[0, 0] * np.eye(p)) else None
        self.size_c = self.size_s * self.inC_loc
        self.count_f = self.count.astype(float)

    def run(self, x0: np.ndarray, z0: np.ndarray, monitor_every: int = 1) -> Iterator[AdmmState]:
        ex = self.ex
        cm = self.inC_loc[:, None].astype(float)  # 1 on constraint-node rows
        inv_count = 1.0 / self.count[:, None]
        inv_size = cm / self.size_s[:, None]
        x = x0.copy()
        z = z0 * cm
        u_pair = np.zeros((self.ip.size, self.p))
        u_self = np.zeros_like(x)  # u_{s,s}; zero on rows of non-constraint nodes, and stays so
        # initialization round: constraint nodes send z_s^[0] to their neighbours
        inbox = ex.broadcast(z, active=self.from_c)
        z_recv = x[self.pair_dst]  # until z_s arrives, a node assumes its own x_i^[0]
        self._hold(z_recv, inbox.values, inbox.delivered, self.ip)
        zin_c = z[ex.in_dst[self.ic]]  # until z_{i,s} arrives, s assumes its own z_s^[0]
        diff_pair = x[self.pair_dst] - z_recv
        diff_self = (x - z) * cm
        yield self._state(0, x, z, diff_pair, diff_self, np.zeros_like(z), u_pair, u_self)
        k = 0
        buf = self.out_buf
        # work arrays reused every iteration (large networks: no fresh allocation per round)
        tmp = np.empty_like(u_pair)
        g_x = np.empty((self.op.size, self.p))
        g_u = np.empty_like(g_x)
        while True:
            k += 1
            # step 1: u-update, l, x-update, send z_{i,s} = x_i + u_{i,s} to constraint neighbours
            u_pair += diff_pair
            u_self += diff_self
            np.subtract(z_recv, u_pair, out=tmp)
            l = self.S_pairs @ tmp
            l += z
            l -= u_self
            l *= inv_count
            x = self.x_update(l, x)
            np.take(x, self.op_src, axis=0, out=g_x)
            np.take(u_pair, self.op_pair, axis=0, out=g_u)
            g_x += g_u
            buf[self.op] = g_x
            inbox = ex.send(buf, active=self.to_c)
            self._hold(zin_c, inbox.values, inbox.delivered, self.ic)
            # step 2: z-update at constraint nodes, broadcast z_s
            z_new = self.S_c @ zin_c
            z_new += x
            z_new += u_self
            z_new *= inv_size
            dz = z_new - z
            z = z_new
            inbox = ex.broadcast(z, active=self.from_c)
            self._hold(z_recv, inbox.values, inbox.delivered, self.ip)
            np.take(x, self.pair_dst, axis=0, out=diff_pair)
            diff_pair -= z_recv
            diff_self = (x - z) * cm
            if monitor_every and k % monitor_every == 0:
                yield self._state(k, x, z, diff_pair, diff_self, dz, u_pair, u_self)
            else:
                yield AdmmState(k, x, z, np.nan, np.nan, np.nan, np.nan, np.nan)

    def run_aggregated(self, x0: np.ndarray, z0: np.ndarray, monitor_every: int) -> Iterator[AdmmState]:
        """Fig. 6 with aggregated messages: node ``i`` broadcasts ``x_i`` to its constraint neighbours instead of
        ``z_{i,s} = x_i + u_{i,s}`` per pair, and keeps only ``U_i = Σ_s u_{i,s}``; constraint node ``s`` keeps
        ``V_s = Σ_{i∈N_s} u_{i,s}``. Since ``Σ_i z_{i,s} = Σ_i x_i + V_s``, the iterates equal those of
        :meth:`run` in exact arithmetic (and ``V_s = 0`` after the first iteration, Boyd et al. 2011 §7.1).

        Without faults a round whose receiver only needs the *sum* of its messages is a fused mixer round
        (``ex.mixer`` with 0/1 weights: one sparse product); monitored iterations send the x-round as a broadcast
        so each constraint node can form its exact pair residuals ``‖x_i − z_s‖``.
        """
        from distnav.network.weights import ConsensusWeights

        ex = self.ex
        g = ex.graph
        fused = not ex.faults.active
        if fused:
            inC_f = self.inC_global.astype(float)
            mix_x = ex.mixer(ConsensusWeights(g, self.to_c.astype(float), inC_f, name="sum into C"), active=self.to_c)
            mix_z = ex.mixer(ConsensusWeights(g, self.from_c.astype(float), inC_f, name="sum from C"),
                             active=self.from_c)
        cm = self.inC_loc[:, None].astype(float)
        inv_count = 1.0 / self.count[:, None]
        inv_size = cm / self.size_s[:, None]
        cnt = self.count[:, None].astype(float)
        size = self.size_s[:, None]
        x = x0.copy()
        z = z0 * cm
        held_x = _Held(ex.in_edges.size, self.p)
        held_z = _Held(ex.in_edges.size, self.p)

        def x_round(x: np.ndarray, monitored: bool, fill: np.ndarray | None) -> tuple[np.ndarray, np.ndarray | None]:
            if fused and not monitored:
                return mix_x.apply(x), None
            inbox = ex.broadcast(x, active=self.to_c)
            vals = held_x.update(inbox.values, inbox.delivered, self.ic, fill=fill)
            out = self.S_c_all @ vals
            out += x * cm
            return out, vals

        def z_round(z: np.ndarray, fill: np.ndarray | None) -> np.ndarray:
            if fused:
                return mix_z.apply(z)
            inbox = ex.broadcast(z, active=self.from_c)
            vals = held_z.update(inbox.values, inbox.delivered, self.ip, fill=fill)
            out = self.S_pairs_all @ vals
            out += z
            return out

        # initialization rounds: z_s^[0] from constraint nodes, x_i^[0] to constraint nodes
        zsum = z_round(z, fill=x[ex.in_dst])
        xsum, xvals = x_round(x, True, fill=z[ex.in_dst])
        U = np.zeros_like(x)
        V = (xsum - size * z) * cm  # Σ_i u^[0]_{i,s} with u^[−1] = 0
        yield self._state_agg(0, x, z, xvals, np.zeros_like(z), U + cnt * x - zsum)
        k = 0
        while True:
            k += 1
            monitored = bool(monitor_every) and k % monitor_every == 0
            U += cnt * x - zsum  # Σ_s of the u-updates
            l = (zsum - U) * inv_count
            x = self.x_update(l, x)
            xsum, xvals = x_round(x, monitored, None)
            z_new = (xsum + V) * inv_size
            V += (xsum - size * z_new) * cm
            dz = z_new - z
            z = z_new
            zsum = z_round(z, None)
            if monitored:
                yield self._state_agg(k, x, z, xvals, dz, U + cnt * x - zsum)
            else:
                yield AdmmState(k, x, z, np.nan, np.nan, np.nan, np.nan, np.nan)

    def _state_agg(self, k: int, x: np.ndarray, z: np.ndarray, xvals: np.ndarray | None, dz: np.ndarray,
                   U_next: np.ndarray) -> AdmmState:
        assert xvals is not None
        d = xvals[self.ic] - z[self.ex.in_dst[self.ic]]  # at constraint node s: x_i − z_s for i ∈ N_s
        ds = (x - z) * self.inC_loc[:, None]
        WU = self._times_W(U_next)
        sums = np.array([
            np.einsum("ij,ij->", d, d) + np.einsum("ij,ij->", ds, ds),
            self.w_scale ** 2 * np.einsum("i,ij,ij->", self.size_c, dz, dz),
            np.einsum("i,ij,ij->", self.count_f, x, x),
            np.einsum("i,ij,ij->", self.size_c, z, z),
            np.einsum("ij,ij->", WU, WU),
        ])
        tot = np.sqrt(np.asarray(self.ex.allreduce(sums, "sum")))
        return AdmmState(k, x, z, float(tot[0]), float(tot[1]), float(tot[2]), float(tot[3]), float(tot[4]))

    def _times_W(self, a: np.ndarray) -> np.ndarray:
        return a * self.w_iso if self.w_iso is not None else np.einsum("ij,jk->ik", a, self.W)

    def _hold(self, target: np.ndarray, values: np.ndarray, delivered: np.ndarray, pos: np.ndarray) -> None:
        if not self.ex.faults.active:  # every message on an active edge arrives
            np.take(values, pos, axis=0, out=target)
            return
        ok = delivered[pos]
        if ok.all():
            np.take(values, pos, axis=0, out=target)
        else:
            target[ok] = values[pos[ok]]

    def _state(self, k: int, x: np.ndarray, z: np.ndarray, diff_pair: np.ndarray, diff_self: np.ndarray,
               dz: np.ndarray, u_pair: np.ndarray, u_self: np.ndarray) -> AdmmState:
        # einsum, not BLAS: tiny BLAS calls are slow when the BLAS thread pool is contended
        sums = np.array([
            np.einsum("ij,ij->", diff_pair, diff_pair) + np.einsum("ij,ij->", diff_self, diff_self),
            self.w_scale ** 2 * np.einsum("i,ij,ij->", self.size_c, dz, dz),
            np.einsum("i,ij,ij->", self.count_f, x, x),
            np.einsum("i,ij,ij->", self.size_c, z, z),
            _sq_rows(self._times_W(self.S_pairs @ (u_pair + diff_pair) + u_self + diff_self)),
        ])
        tot = np.sqrt(np.asarray(self.ex.allreduce(sums, "sum")))
        return AdmmState(k, x, z, float(tot[0]), float(tot[1]), float(tot[2]), float(tot[3]), float(tot[4]))


def _segment_matrix(receiver: np.ndarray, n_rows: int) -> sp.csr_matrix:
    """0/1 CSR matrix summing values (one per entry of ``receiver``) into their receiver's row."""
    k = receiver.size
    return sp.csr_matrix((np.ones(k), (receiver, np.arange(k))), shape=(n_rows, k))


def _sq_rows(a: np.ndarray) -> float:
    return float(np.einsum("ij,ij->", a, a))


class _Held:
    """Last value received on each incoming edge: a dropped message is replaced by the previous one.

    Without drops the inbox array is used as is (no copy); the first drop switches to a private copy.
    """

    def __init__(self, n_in: int, p: int) -> None:
        self.prev: np.ndarray | None = None
        self.own = False
        self.shape = (n_in, p)

    def update(self, values: np.ndarray, delivered: np.ndarray, pos: np.ndarray,
               fill: np.ndarray | None) -> np.ndarray:
        ok = delivered[pos]
        if not self.own and ok.all():
            self.prev = values
            return values
        if not self.own:
            base = self.prev if self.prev is not None else (fill if fill is not None else np.zeros(self.shape))
            self.prev = np.array(base, dtype=float)
            self.own = True
        assert self.prev is not None
        keep = pos[ok]
        self.prev[keep] = values[keep]
        return self.prev


# ----------------------------------------------------------------------------------------------- front doors
def _constraint_nodes(graph: Graph, constraint_nodes: Any) -> ConstraintNodes:
    if isinstance(constraint_nodes, ConstraintNodes):
        if constraint_nodes.graph.n_nodes != graph.n_nodes or constraint_nodes.graph.n_edges != graph.n_edges:
            raise ModelError("the constraint nodes were chosen on a different graph")
        return constraint_nodes
    return choose_constraint_nodes(graph, constraint_nodes)


def _initial(init: Any, z0: Any, n: int, p: int) -> tuple[np.ndarray, np.ndarray]:
    if isinstance(init, SolverResult):
        x0 = _per_node(init.estimates, n, p, "the previous solution's estimates")
        prev_z = init.extras.get("z_nodes")
        z_default = x0 if prev_z is None else _per_node(prev_z, n, p, "the previous solution's z")
    elif isinstance(init, str):
        if init != "zero":
            raise ModelError(f"init must be 'zero', a vector, a per-node array or a previous SolverResult, "
                             f"got {init!r}")
        x0 = np.zeros((n, p))
        z_default = x0
    else:
        x0 = _per_node(init, n, p, "init")
        z_default = x0
    z = z_default.copy() if z0 is None else _per_node(z0, n, p, "z0")
    if not (np.all(np.isfinite(x0)) and np.all(np.isfinite(z))):
        raise ModelError("initial values x0/z0 have non-finite entries")
    return x0, z


def iterate_admm(
    problem: LinearProblem,
    graph: Graph,
    *,
    constraint_nodes: Any = "min_cover",
    W: Any = 1.0,
    x_update: XUpdateMethod = "auto",
    x_weight: Literal["lagrangian", "fig6"] = "lagrangian",
    messages: Literal["pairs", "aggregated"] = "pairs",
    init: Any = "zero",
    z0: Any = None,
    exchange: Exchange | None = None,
    monitor_every: int = 1,
) -> Iterator[AdmmState]:
    """Yield the ADMM state of Fig. 6 (paper 000) after iterations ``0, 1, 2, …`` (endless: stop it yourself).

    ``constraint_nodes``: ``"min_cover"`` (default), ``"all"``, node ids, or a
    :class:`~distnav.network.constraint_nodes.ConstraintNodes`. ``W``: ``ρ`` or an SPD ``(p, p)`` matrix.
    ``x_update``: see :class:`XUpdate`. ``init``: ``"zero"``, a ``(p,)`` vector, an ``(n, p)`` array, or a previous
    :class:`SolverResult` (§4.3: ``x_i^[0] = z_s^[0]`` from an earlier run); ``z0`` overrides ``z_s^[0]``.
    Multipliers start at ``u^[−1] = 0`` (§4.3, eq. (22)). States hold this exchange block's rows.

    ``messages="pairs"`` sends ``z_{i,s} = x_i + u_{i,s}`` on each pair edge exactly as Fig. 6;
    ``messages="aggregated"`` broadcasts ``x_i`` to the constraint neighbours and keeps multiplier *sums* (node
    ``U_i = Σ_s u_{i,s}``, constraint node ``V_s = Σ_i u_{i,s}``): the same iterates without faults, the same number of
    messages, but no per-pair state — several times faster on large networks. It refuses a fault schedule: a lost
    message corrupts the sums for good, while the per-pair form (holding the last value received) still converges
    to the BLUE. ``monitor_every``: compute the residuals (network totals, monitoring only) every that many
    iterations; the others yield NaN residuals (0 = never).
    """
    if messages not in ("pairs", "aggregated"):
        raise ModelError(f"messages must be 'pairs' or 'aggregated', got {messages!r}")
    if monitor_every < 0:
        raise ModelError(f"monitor_every must be ≥ 0, got {monitor_every}")
    if problem.n_nodes != graph.n_nodes:
        raise ModelError(f"the problem has {problem.n_nodes} nodes, the graph {graph.n_nodes}")
    if x_weight not in ("lagrangian", "fig6"):
        raise ModelError(f"x_weight must be 'lagrangian' or 'fig6', got {x_weight!r}")
    p = problem.n_params
    Wm = weight_matrix(W, p)
    C = _constraint_nodes(graph, constraint_nodes)
    ex = exchange if exchange is not None else make_exchange(graph)
    if ex.graph.n_edges != graph.n_edges or ex.graph.n_nodes != graph.n_nodes:
        raise ModelError("the exchange was built on a different graph")
    x0, zz0 = _initial(init, z0, graph.n_nodes, p)
    local = problem.subset(ex.nodes)
    count = C.per_node_count[ex.nodes].astype(float)
    c_weight = count if x_weight == "lagrangian" else np.ones_like(count)
    xu = XUpdate(local, Wm, c_weight, x_update)
    if messages == "aggregated" and ex.faults.active:
        raise ModelError("messages='aggregated' keeps multiplier sums that lost messages corrupt for good (the run "
                         "converges to a wrong point); use messages='pairs' with a fault schedule")
    kernel = _Kernel(ex, C, Wm, p, xu)
    if messages == "pairs":
        yield from kernel.run(x0[ex.nodes], zz0[ex.nodes], monitor_every)
    else:
        yield from kernel.run_aggregated(x0[ex.nodes], zz0[ex.nodes], monitor_every)


def admm(
    problem: LinearProblem,
    graph: Graph,
    *,
    constraint_nodes: Any = "min_cover",
    W: Any = 1.0,
    x_update: XUpdateMethod = "auto",
    x_weight: Literal["lagrangian", "fig6"] = "lagrangian",
    messages: Literal["pairs", "aggregated"] = "pairs",
    init: Any = "zero",
    z0: Any = None,
    max_iterations: int = 1000,
    tol: float = 1e-10,
    atol: float = 0.0,
    reference: np.ndarray | None = None,
    stop_at_reference: float | None = None,
    record_nodes: bool = True,
    monitor_every: int = 1,
    exchange: Exchange | None = None,
    faults: FaultSchedule | None = None,
) -> SolverResult:
    """Distributed least squares by ADMM with constraint nodes (paper 000, Fig. 6); see :func:`iterate_admm`.

    Stops after ``max_iterations`` or when ``primal ≤ atol·√(P p) + tol·max(‖x‖, ‖z‖)`` and
    ``dual ≤ atol·√(P p) + tol·‖W U‖`` (pair norms, ``P`` pairs, ``U_i = Σ_s u_{i,s}``; after Boyd et al. 2011
    §3.3), or — for experiments —
    when ``max_i ‖x_i − x̂‖/‖x̂‖ ≤ stop_at_reference``. The stopping test uses network totals
    (``ex.allreduce``); a deployment would run a fixed count instead. With ``monitor_every = k`` the residuals (and
    so the tolerance test) are computed every ``k``-th iteration only (NaN in the trace otherwise) — cheaper on
    large networks; 0 disables the tolerance test.

    Trace (leading axis = iteration ``0..k``): ``primal_residual``, ``dual_residual``; with ``reference`` (x̂)
    ``max_distance_to_reference`` and ``relative_max_distance`` (``max_i ‖x_i − x̂‖/‖x̂‖``) and, with
    ``record_nodes``, ``distance_to_reference`` (``k × n``: ``‖x_i^[k] − x̂‖`` per node). ``extras``: ``z`` (per
    constraint node), ``z_nodes`` (per node, zero rows off ``C``), ``constraint_nodes``, ``x_update`` method,
    ``iterations_to`` (first iteration with relative distance ≤ 1e-4, 1e-6, 1e-8 when a reference is given).
    """
    _check_stopping(max_iterations, tol, atol)
    if exchange is not None and faults is not None:
        raise ModelError("pass faults either to the exchange or to admm(), not both")
    ex = exchange if exchange is not None else make_exchange(graph, faults=faults)
    C = _constraint_nodes(graph, constraint_nodes)
    p = problem.n_params
    gen = iterate_admm(problem, graph, constraint_nodes=C, W=W, x_update=x_update, x_weight=x_weight,
                       messages=messages, init=init, z0=z0, exchange=ex, monitor_every=monitor_every)
    x_method = x_update
    if x_update == "auto":
        x_method = "normal" if p <= problem.max_rows else "observation"
    return _drive(gen, ex, C, p, max_iterations=max_iterations, tol=tol, atol=atol, reference=reference,
                  stop_at_reference=stop_at_reference, record_nodes=record_nodes,
                  extras={"x_update": x_method, "x_weight": x_weight, "messages": messages})


def _check_stopping(max_iterations: int, tol: float, atol: float) -> None:
    if max_iterations < 0:
        raise ModelError(f"max_iterations must be ≥ 0, got {max_iterations}")
    if tol < 0 or atol < 0:
        raise ModelError(f"tolerances must be ≥ 0, got tol={tol}, atol={atol}")


def _drive(gen: Iterator[AdmmState], ex: Exchange, C: ConstraintNodes, p: int, *, max_iterations: int, tol: float,
           atol: float, reference: np.ndarray | None, stop_at_reference: float | None, record_nodes: bool,
           extras: dict[str, Any]) -> SolverResult:
    """Run an ADMM state generator to the stopping rule of :func:`admm`, tracing as it goes."""
    ref = None
    if reference is not None:
        ref = np.asarray(reference, dtype=float)
        if ref.shape != (p,):
            raise ModelError(f"reference must be a length-{p} vector (x̂), got shape {ref.shape}")
    ref_norm = float(np.linalg.norm(ref)) if ref is not None else 1.0
    ref_norm = ref_norm if ref_norm > 0 else 1.0
    tb = TraceBuilder()
    n_pairs = int(C.per_node_count.sum())
    abs_term = atol * np.sqrt(n_pairs * p)
    thresholds = (1e-4, 1e-6, 1e-8)
    reached: dict[str, int | None] = {f"{t:g}": None for t in thresholds}
    state: AdmmState | None = None
    status: SolverStatus = "max_iterations"
    converged = False
    for state in gen:
        tb.add(primal_residual=state.primal_residual, dual_residual=state.dual_residual)
        rel = None
        if ref is not None:
            dist_local = np.linalg.norm(state.x - ref[None, :], axis=1)
            dmax = float(ex.allreduce(float(dist_local.max()) if dist_local.size else 0.0, "max"))
            rel = dmax / ref_norm
            tb.add(max_distance_to_reference=dmax, relative_max_distance=rel)
            if record_nodes:
                tb.add(distance_to_reference=ex.gather_nodes(dist_local))
            for t in thresholds:
                if reached[f"{t:g}"] is None and rel <= t:
                    reached[f"{t:g}"] = state.iteration
        if state.iteration > 0:
            ok_pri = state.primal_residual <= abs_term + tol * max(state.x_norm, state.z_norm)
            ok_dual = state.dual_residual <= abs_term + tol * state.u_norm
            if ok_pri and ok_dual:
                status, converged = "converged", True
                break
            if stop_at_reference is not None and rel is not None and rel <= stop_at_reference:
                status, converged = "converged", True
                break
        if state.iteration >= max_iterations:
            break
    close = getattr(gen, "close", None)
    if close is not None:
        close()
    assert state is not None
    x_all = ex.gather_nodes(state.x)
    z_all = ex.gather_nodes(state.z)
    msg = (f"{state.iteration} iterations, primal residual {state.primal_residual:.3g}, "
           f"dual residual {state.dual_residual:.3g}")
    if ref is not None:
        msg += f", max_i ‖x_i − x̂‖/‖x̂‖ = {float(np.max(np.linalg.norm(x_all - ref, axis=1))) / ref_norm:.3g}"
    return LegacyResult(
        estimates=x_all, converged=converged, iterations=state.iteration, status=status, message=msg,
        trace=tb.build(), comm=ex.comm_totals(),
        legacy={"z": z_all[C.nodes], "z_nodes": z_all, "constraint_nodes": C, "iterations_to": reached,
                "pairs": n_pairs, **extras},
    )


# ----------------------------------------------------------------------------------------------- nonlinear models
class RangeModel:
    """Ranges from every node (known position ``a_i``) to ``T`` targets with unknown positions: ``x`` stacks the
    targets' coordinates (``p = T·d``), node ``i`` observes ``‖x_t − a_i‖`` for every target ``t`` (``m_i = T``).

    With ``d ≥ 2`` each ``N_i`` has rank ≤ ``T < p``: no node can position the targets alone.
    """

    def __init__(self, node_positions_m: np.ndarray, n_targets: int) -> None:
        pos = np.asarray(node_positions_m, dtype=float)
        if pos.ndim != 2:
            raise ModelError(f"node positions must be (n_nodes, dim), got shape {pos.shape}")
        if n_targets < 1:
            raise ModelError(f"n_targets must be ≥ 1, got {n_targets}")
        self.positions_m = pos
        self.n_targets = int(n_targets)
        self.dim = pos.shape[1]
        self.n_params = self.n_targets * self.dim

    def predict(self, x: np.ndarray, nodes: np.ndarray) -> np.ndarray:
        """Ranges ``(len(nodes), T)`` from each listed node to the targets in its own ``x`` row ``(len(nodes), p)``."""
        d = x.reshape(x.shape[0], self.n_targets, self.dim) - self.positions_m[nodes][:, None, :]
        return np.sqrt(np.einsum("ntd,ntd->nt", d, d))

    def jacobian(self, x: np.ndarray, nodes: np.ndarray) -> np.ndarray:
        """``∂ range / ∂ x`` ``(len(nodes), T, p)``: unit vectors from node to target, in the target's columns."""
        n = x.shape[0]
        d = x.reshape(n, self.n_targets, self.dim) - self.positions_m[nodes][:, None, :]
        rng = np.sqrt(np.einsum("ntd,ntd->nt", d, d))
        if np.any(rng == 0):
            raise ModelError("a target estimate coincides with a node position: the range Jacobian is undefined")
        J = np.zeros((n, self.n_targets, self.n_params))
        for t in range(self.n_targets):
            J[:, t, t * self.dim:(t + 1) * self.dim] = d[:, t, :] / rng[:, t, None]
        return J


@dataclass(frozen=True, eq=False)
class NonlinearProblem:
    """``y_i = F_i(x) + e_i``, ``C(e_i) = R_i`` per node (paper 000 §4.3 with nonlinear maps ``A_i(x)``).

    ``model`` provides ``predict(x_rows, nodes)`` ``(k, m)`` and ``jacobian(x_rows, nodes)`` ``(k, m, p)``, where row
    ``j`` is evaluated for node ``nodes[j]`` at its own ``x_rows[j]`` (nodes use only their own data).
    ``y`` ``(n, m)`` and ``R`` ``(n, m, m)``.
    """

    model: Any
    y: np.ndarray
    R: np.ndarray

    def __post_init__(self) -> None:
        y = np.asarray(self.y, dtype=float)
        R = np.asarray(self.R, dtype=float)
        if y.ndim != 2 or R.shape != (y.shape[0], y.shape[1], y.shape[1]):
            raise ModelError(f"y must be (n, m) and R (n, m, m); got {y.shape} and {R.shape}")
        bad = ~np.isfinite(y).all(axis=1)
        if bad.any():
            raise ModelError(f"node {int(np.argmax(bad))}: observations are not finite")
        try:
            np.linalg.cholesky(R)
        except np.linalg.LinAlgError:
            i = int(np.argmin([np.linalg.eigvalsh(r).min() for r in R]))
            raise ModelError(f"node {i}: R_i is not positive definite") from None
        object.__setattr__(self, "y", y)
        object.__setattr__(self, "R", R)

    @property
    def n_nodes(self) -> int:
        return int(self.y.shape[0])

    @property
    def n_params(self) -> int:
        return int(self.model.n_params)

    def linearize(self, x_approx: np.ndarray) -> LinearProblem:
        """Increments at each node's approximate value ``x_i^o`` (§4.3): ``Δy_i = y_i − F_i(x_i^o)``,
        ``A_i = ∂F_i(x_i^o)``; ``x_approx`` is ``(p,)`` (common) or ``(n, p)``."""
        n = self.n_nodes
        xo = _per_node(x_approx, n, self.n_params, "x_approx")
        nodes = np.arange(n)
        return LinearProblem.from_stacked(self.model.jacobian(xo, nodes), self.y - self.model.predict(xo, nodes),
                                          self.R)

    def cost(self, x: np.ndarray) -> float:
        """``Σ_i ½‖y_i − F_i(x)‖²_{R_i⁻¹}`` at a common ``x``."""
        n = self.n_nodes
        e = self.y - self.model.predict(np.broadcast_to(np.asarray(x, float), (n, self.n_params)), np.arange(n))
        return float(0.5 * np.einsum("nm,nmk,nk->", e, np.linalg.inv(self.R), e))


def range_positioning_problem(node_positions_m: np.ndarray, targets_m: np.ndarray, *, sigma_m: float,
                              rng: np.random.Generator) -> NonlinearProblem:
    """Every node measures its range to every target with noise ``N(0, σ²)``: a :class:`NonlinearProblem` on a
    :class:`RangeModel` (``targets_m`` is ``(T, d)``; the true ``x`` is ``targets_m.ravel()``)."""
    tg = np.atleast_2d(np.asarray(targets_m, dtype=float))
    if sigma_m <= 0:
        raise ModelError(f"sigma_m must be > 0, got {sigma_m}")
    model = RangeModel(node_positions_m, tg.shape[0])
    n = model.positions_m.shape[0]
    if tg.shape[1] != model.dim:
        raise ModelError(f"targets have {tg.shape[1]} coordinates, nodes have {model.dim}")
    truth = np.broadcast_to(tg.ravel(), (n, model.n_params))
    y = model.predict(truth, np.arange(n)) + sigma_m * rng.standard_normal((n, tg.shape[0]))
    R = np.broadcast_to(sigma_m ** 2 * np.eye(tg.shape[0]), (n, tg.shape[0], tg.shape[0])).copy()
    return NonlinearProblem(model, y, R)


def gauss_newton(problem: NonlinearProblem, x0: np.ndarray, *, max_iterations: int = 50,
                 tol: float = 1e-12) -> SolverResult:
    """Centralized Gauss–Newton on ``Σ_i ½‖y_i − F_i(x)‖²_{R_i⁻¹}`` (the fusion-centre reference, Teunissen 1990):
    ``x ← x + (Σ J_iᵀR_i⁻¹J_i)⁻¹ Σ J_iᵀR_i⁻¹(y_i − F_i(x))`` until ``‖Δx‖ ≤ tol·(1 + ‖x‖)``."""
    p = problem.n_params
    x = np.asarray(x0, dtype=float).copy()
    if x.shape != (p,):
        raise ModelError(f"x0 must be a length-{p} vector, got shape {x.shape}")
    n = problem.n_nodes
    nodes = np.arange(n)
    Rinv = np.linalg.inv(problem.R)
    tb = TraceBuilder()
    converged = False
    k = 0
    while k < max_iterations:
        k += 1
        xs = np.broadcast_to(x, (n, p))
        J = problem.model.jacobian(xs, nodes)
        e = problem.y - problem.model.predict(xs, nodes)
        JtRi = np.einsum("nmp,nmk->npk", J, Rinv)
        N = np.einsum("npk,nkq->pq", JtRi, J)
        g = np.einsum("npk,nk->p", JtRi, e)
        dx = np.linalg.solve(N, g)
        x = x + dx
        tb.add(step_norm=float(np.linalg.norm(dx)), cost=problem.cost(x))
        if np.linalg.norm(dx) <= tol * (1 + np.linalg.norm(x)):
            converged = True
            break
    return LegacyResult(estimates=x[None, :], converged=converged, iterations=k,
                        status="converged" if converged else "max_iterations",
                        message=f"Gauss-Newton: {k} iterations, cost {problem.cost(x):.6g}", trace=tb.build(),
                        comm=CommTotals.empty(n))


def admm_linearized(problem: NonlinearProblem, graph: Graph, x_approx: np.ndarray, *,
                    constraint_nodes: Any = "min_cover", W: Any = 1.0, outer_iterations: int = 10,
                    inner_max_iterations: int = 2000, inner_tol: float = 1e-12, inner_atol: float = 1e-12,
                    tol: float = 1e-10,
                    reference: np.ndarray | None = None, messages: Literal["pairs", "aggregated"] = "pairs",
                    exchange: Exchange | None = None) -> SolverResult:
    """The linearized case of paper 000 §4.3: all nodes start from the same approximate value ``x^o``, linearize
    their models there, run Fig. 6 on the increments from ``Δx_i^[0] = z_s^[0] = 0`` until it converges, then set
    ``x_i^o ← x_i^o + Δx_i``; repeated until ``max_i ‖Δx_i‖ ≤ tol·(1 + ‖x^o‖)`` or ``outer_iterations``.

    Each node keeps its own ``x_i^o``; they stay identical up to the inner tolerance (the paper's requirement of
    identical approximate values), so ``inner_tol`` should be tight; ``inner_atol`` (absolute, in the units of ``x``)
    ends the inner runs of the last steps, whose increments are tiny. Trace per outer iteration: ``max_step``,
    ``inner_iterations``, ``spread`` (``max_i ‖x_i^o − mean‖``) and with ``reference`` ``max_distance_to_reference``.
    """
    p = problem.n_params
    ex = exchange if exchange is not None else make_exchange(graph)
    C = _constraint_nodes(graph, constraint_nodes)
    xo = _per_node(x_approx, problem.n_nodes, p, "x_approx")
    tb = TraceBuilder()
    converged = False
    total_inner = 0
    t = 0
    while t < outer_iterations:
        t += 1
        inner = admm(problem.linearize(xo), graph, constraint_nodes=C, W=W, init="zero",
                     max_iterations=inner_max_iterations, tol=inner_tol, atol=inner_atol, exchange=ex,
                     messages=messages,
                     record_nodes=False)
        dx = inner.estimates
        xo = xo + dx
        total_inner += inner.iterations
        step = float(np.linalg.norm(dx, axis=1).max())
        tb.add(max_step=step, inner_iterations=inner.iterations,
               spread=float(np.linalg.norm(xo - xo.mean(axis=0), axis=1).max()))
        if reference is not None:
            tb.add(max_distance_to_reference=float(np.linalg.norm(xo - np.asarray(reference)[None, :], axis=1).max()))
        if step <= tol * (1 + float(np.linalg.norm(xo.mean(axis=0)))):
            converged = True
            break
    return LegacyResult(estimates=xo, converged=converged, iterations=t,
                        status="converged" if converged else "max_iterations",
                        message=f"linearized ADMM: {t} outer iterations, {total_inner} ADMM iterations in all",
                        trace=tb.build(), comm=ex.comm_totals(),
                        legacy={"inner_iterations_total": total_inner, "constraint_nodes": C})


class _NonlinearXUpdate:
    """Eq. (23): ``x_i = argmin ‖y_i − F_i(x)‖²_{R_i⁻¹} + c_i‖l_i − x‖²_W`` by ``steps`` regularized Gauss–Newton steps
    from the previous ``x_i`` (batched over the block's nodes)."""

    def __init__(self, problem: NonlinearProblem, nodes: np.ndarray, W: np.ndarray, c: np.ndarray, steps: int) -> None:
        self.model = problem.model
        self.nodes = nodes
        self.y = problem.y[nodes]
        self.Rinv = np.linalg.inv(problem.R[nodes])
        self.Wc = c[:, None, None] * W[None]
        self.steps = steps

    def __call__(self, l: np.ndarray, x_prev: np.ndarray) -> np.ndarray:
        x = x_prev
        for _ in range(self.steps):
            J = self.model.jacobian(x, self.nodes)
            e = self.y - self.model.predict(x, self.nodes)
            JtRi = np.einsum("nmp,nmk->npk", J, self.Rinv)
            H = JtRi @ J + self.Wc
            g = np.einsum("npk,nk->np", JtRi, e) + (self.Wc @ (l - x)[..., None])[..., 0]
            x = x + np.linalg.solve(H, g[..., None])[..., 0]
        return x


def admm_nonlinear(problem: NonlinearProblem, graph: Graph, x0: np.ndarray, *, constraint_nodes: Any = "min_cover",
                   W: Any = 1.0, gn_steps: int = 2, max_iterations: int = 2000, tol: float = 1e-10,
                   atol: float = 0.0, reference: np.ndarray | None = None, record_nodes: bool = True,
                   exchange: Exchange | None = None) -> SolverResult:
    """ADMM with constraint nodes and the nonlinear x-update of paper 000 eq. (23): each node solves its regularized
    nonlinear least-squares problem (``gn_steps`` Gauss–Newton steps warm-started at its previous ``x_i`` per
    iteration; exact at convergence). ``x0``: common ``(p,)`` or per-node ``(n, p)`` start (also ``z_s^[0]``).
    Same stopping and trace as :func:`admm`."""
    _check_stopping(max_iterations, tol, atol)
    if gn_steps < 1:
        raise ModelError(f"gn_steps must be ≥ 1, got {gn_steps}")
    p = problem.n_params
    Wm = weight_matrix(W, p)
    ex = exchange if exchange is not None else make_exchange(graph)
    C = _constraint_nodes(graph, constraint_nodes)
    x_init, z_init = _initial(x0, None, problem.n_nodes, p)
    count = C.per_node_count[ex.nodes].astype(float)
    xu = _NonlinearXUpdate(problem, ex.nodes, Wm, count, gn_steps)
    kernel = _Kernel(ex, C, Wm, p, xu)
    gen = kernel.run(x_init[ex.nodes], z_init[ex.nodes])
    return _drive(gen, ex, C, p, max_iterations=max_iterations, tol=tol, atol=atol, reference=reference,
                  stop_at_reference=None, record_nodes=record_nodes,
                  extras={"x_update": f"nonlinear (eq. 23, {gn_steps} Gauss-Newton steps)"})
