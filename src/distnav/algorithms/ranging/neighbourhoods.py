"""The shared machinery of the neighbourhood solvers N-CSG and N-CLM (paper 002 §3.3–3.4) and of CSG: the
iteration state, the index maps of the neighbourhood vectors (:class:`Neighbourhoods`), the consensus round
(:class:`Mixing`) and the per-anchor line searches (:func:`armijo_details`). The bottom of the neighbourhood
rooms: :mod:`~distnav.algorithms.ranging.local_lm`, :mod:`~distnav.algorithms.ranging.plan` and
:mod:`~distnav.algorithms.ranging.neighbourhood` build on it. See :mod:`distnav.algorithms.ranging.neighbourhood`
for the equations."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from distnav._checks import whole_number
from distnav._sparse import csr_times
from distnav.algorithms.ranging.data import RangingData
from distnav.algorithms.ranging.losses import loss_terms, range_loss_scale
from distnav.algorithms.ranging.objective import range_sigma
from distnav.errors import ModelError
from distnav.exchange import Exchange, make_exchange
from distnav.network.weights import ConsensusWeights, consensus_weights
from distnav.typing import ArrayLike


@dataclass(frozen=True, eq=False)
class IterationState:
    """State of a distributed solver after ``iteration`` iterations (this block's anchors only).

    ``own_m``: each local anchor's estimate of itself ``(n_local, dim)``; ``step_size``: the ``α`` (or, for N-CLM,
    ``λ``) each local anchor used; ``partial_cost``: ``f⁽ⁱ⁾(x⁽ⁱ⁾)`` of every local anchor before the update.
    ``half_owner`` / ``half_sample`` / ``half_other_m``: for every range sample an anchor of this block holds, the
    holder (local index), the sample and the holder's estimate of the other end (for local precision and tests).
    ``offset_m``: each local anchor's own range offset (its copy of the common one), ``half_offset_m``: the bias
    ``b_l`` the holder puts on each half-measurement (None without offsets; :mod:`.neighbourhood_offsets`).
    """

    iteration: int
    own_m: np.ndarray
    step_size: np.ndarray
    partial_cost: np.ndarray
    half_owner: np.ndarray | None = None
    half_sample: np.ndarray | None = None
    half_other_m: np.ndarray | None = None
    offset_m: np.ndarray | None = None
    half_offset_m: np.ndarray | None = None


# ---------------------------------------------------------------------- checks and set-up
def check_start(
    problem: RangingData, iterations: int, consensus_rounds: int, initial_m: ArrayLike | None
) -> np.ndarray:
    whole_number(iterations, "iterations", error=ModelError, allow_float=False)
    whole_number(consensus_rounds, "consensus_rounds", minimum=1, error=ModelError, allow_float=False)
    init = problem.initial_m if initial_m is None else np.asarray(initial_m, float)
    if init is None:
        raise ModelError("the solver needs an initial guess (problem.initial_m or initial_m=)")
    init = np.asarray(init, float)
    if init.shape != (problem.n_anchors, problem.dim) or not np.all(np.isfinite(init)):
        raise ModelError(f"initial guess must be finite with shape ({problem.n_anchors}, {problem.dim})")
    return np.where(problem.free, init, problem.positions_m)


def checked_estimates(problem: RangingData, estimates_m: np.ndarray) -> np.ndarray:
    """``estimates_m`` as floats of shape ``(n_anchors, dim)`` (ModelError otherwise)."""
    est = np.asarray(estimates_m, float)
    if est.shape != (problem.n_anchors, problem.dim):
        raise ModelError(f"estimates must have shape ({problem.n_anchors}, {problem.dim}), got {est.shape}")
    return est


def exchange_for(problem: RangingData, exchange: Exchange | None) -> Exchange:
    g = problem.graph
    ex = exchange if exchange is not None else make_exchange(g)
    if (
        ex.graph.n_nodes != g.n_nodes
        or ex.graph.n_edges != g.n_edges
        or not (np.array_equal(ex.graph.src, g.src) and np.array_equal(ex.graph.dst, g.dst))
    ):
        raise ModelError("the exchange must be built on the problem's measurement graph (problem.graph)")
    return ex


def mixing_weights(problem: RangingData, weights: str | ConsensusWeights) -> ConsensusWeights:
    if isinstance(weights, ConsensusWeights):
        if weights.graph.n_edges != problem.graph.n_edges:
            raise ModelError("consensus weights are defined on another graph than the measurement graph")
        return weights
    key = str(weights).strip().lower()
    if key not in ("mh", "metropolis", "metropolis-hastings", "koppanyi"):
        raise ModelError(f"weights must be 'MH' (paper 002 eq. (12)) or 'Koppanyi', got {weights!r}")
    return consensus_weights(problem.graph, "Koppanyi" if key == "koppanyi" else "MH")


def half_measurements(problem: RangingData, ex: Exchange) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Every range sample seen from each of its two local anchors: (owner local idx, other global id, d², sample)."""
    n = problem.n_anchors
    local_of = np.full(n, -1, np.int64)
    local_of[ex.nodes] = np.arange(ex.n_local)
    a, b = problem.meas_a, problem.meas_b
    own = np.concatenate([a, b])
    other = np.concatenate([b, a])
    samp = np.concatenate([np.arange(a.size)] * 2)
    keep = local_of[own] >= 0
    d2 = problem.range_sq[samp[keep]]
    return local_of[own[keep]], other[keep], d2, samp[keep]


# ---------------------------------------------------------------------- neighbourhoods (N-CSG, N-CLM)
class Neighbourhoods:
    """Index maps of the neighbourhood estimation vectors on one exchange block.

    Anchor ``i``'s vector has ``K = max degree + 1`` slots (padded): slot 0 is ``i``, slots ``1..d_i`` its
    neighbours in ascending id order. Built from the graph's topology only (what anchors learn from their
    neighbours' neighbour lists when the network is set up).
    """

    def __init__(
        self,
        problem: RangingData,
        ex: Exchange,
        loss: str = "linear",
        loss_scale_m: float = 0.3,
        objective: str = "squared",
        sigma_m: float | np.ndarray = 1.0,
    ) -> None:
        g = problem.graph
        self.n, self.dim = g.n_nodes, problem.dim
        self.K = int(g.degrees.max(initial=0)) + 1
        self.nl = ex.n_local
        self._key_sorted = g.dst * self.n + g.src  # graph edges are sorted by (dst, src)
        self._in_ptr = g.in_ptr
        self._slots(problem, ex)
        self._half_links(problem, ex, loss, loss_scale_m, objective, sigma_m)
        self._messages(ex)

    def _is_edge(self, src: np.ndarray, dst: np.ndarray) -> np.ndarray:
        key_sorted = self._key_sorted
        want = dst * self.n + src
        pos = np.minimum(np.searchsorted(key_sorted, want), key_sorted.size - 1)
        return (key_sorted[pos] == want) if key_sorted.size else np.zeros(want.shape, bool)

    def position(self, holder: np.ndarray, k: np.ndarray) -> np.ndarray:
        """Slot of node k in holder's vector (k must be holder or a neighbour)."""
        e = np.searchsorted(self._key_sorted, holder * self.n + k)
        return np.asarray(np.where(k == holder, 0, e - self._in_ptr[holder] + 1))

    def _slots(self, problem: RangingData, ex: Exchange) -> None:
        """Which node every slot of every local vector holds (slot 0: the node itself, then its neighbours in
        ascending id order; -1 padding), and the free / known values per slot."""
        g, nl = problem.graph, self.nl
        deg = g.degrees[ex.nodes]
        slot_node = np.full((nl, self.K), -1, np.int64)
        slot_node[:, 0] = ex.nodes
        # neighbours of local node li = src of the graph's in-edges of ex.nodes[li] (sorted by src)
        starts = g.in_ptr[ex.nodes]
        rows = np.repeat(np.arange(nl), deg)
        offs = np.arange(rows.size) - np.repeat(np.cumsum(deg) - deg, deg)
        slot_node[rows, offs + 1] = g.src[starts[rows] + offs]
        self.slot_node = slot_node
        self.valid = slot_node >= 0
        safe = np.where(self.valid, slot_node, 0)
        self.free_slot = problem.free[safe] & self.valid[:, :, None]
        self.known_slot = np.where(self.valid[:, :, None], problem.positions_m[safe], 0.0)

    def _half_links(
        self,
        problem: RangingData,
        ex: Exchange,
        loss: str,
        loss_scale_m: float,
        objective: str,
        sigma_m: float | np.ndarray,
    ) -> None:
        """The half-measurements: owner local idx, slot of the other end in the owner's vector, range, σ, loss
        scale, and the sparse map ``Q`` from slot differences to half-measurements."""
        own_idx, other, d2, samp = half_measurements(problem, ex)
        self.h_own, self.h_d2, self.h_samp = own_idx, d2, samp
        self.loss = loss
        self.metres = objective == "metres"
        self.h_range = problem.range_m[samp]
        self.h_sigma = range_sigma(problem, sigma_m)[samp]
        if self.metres:
            if not loss_scale_m > 0:
                raise ModelError(f"loss_scale_m must be positive, got {loss_scale_m}")
            self.h_scale = loss_scale_m / self.h_sigma
        else:
            self.h_scale = range_loss_scale(problem, loss_scale_m)[samp] if loss != "linear" else np.ones(samp.size)
        self.h_slot = self.position(ex.nodes[own_idx], other)
        self.h_flat_self = own_idx * self.K
        self.h_flat_other = own_idx * self.K + self.h_slot
        # the same rows as flat element indices (a 1-D gather copies the same values, ~4× faster on short rows)
        self.e_self = (self.h_flat_self[:, None] * self.dim + np.arange(self.dim)).ravel()
        self.e_other = (self.h_flat_other[:, None] * self.dim + np.arange(self.dim)).ravel()
        nh = own_idx.size
        self.Q = sp.csr_matrix(
            (
                np.concatenate([np.ones(nh), -np.ones(nh)]),
                (np.concatenate([self.h_flat_self, self.h_flat_other]), np.concatenate([np.arange(nh)] * 2)),
            ),
            shape=(self.nl * self.K, nh),
        )

    def _messages(self, ex: Exchange) -> None:
        """Where every sent slot lands in the receiver's vector, and which receiver slots each sender holds."""
        slot_node = self.slot_node
        # outgoing messages: sender slot s of node k goes to receiver i at position(i, k) when k ∈ N(i) ∪ {i}
        oe = np.arange(ex.out_edges.size)
        send_local = ex.out_src
        recv = ex.out_dst
        e_rep = np.repeat(oe, self.K)
        s_rep = np.tile(np.arange(self.K), oe.size)
        k_node = slot_node[send_local[e_rep], s_rep]
        r_node = recv[e_rep]
        ok = (k_node >= 0) & ((k_node == r_node) | self._is_edge(np.maximum(k_node, 0), r_node))
        self.msg_flat = e_rep[ok] * self.K + self.position(r_node[ok], k_node[ok])
        self.msg_src = send_local[e_rep[ok]] * self.K + s_rep[ok]
        self.n_out = oe.size
        # incoming: which positions of the receiver's vector the sender holds (static "has" mask)
        ie = np.arange(ex.in_edges.size)
        i_rep = np.repeat(ie, self.K)
        p_rep = np.tile(np.arange(self.K), ie.size)
        kk = slot_node[ex.in_dst[i_rep], p_rep]
        snd = ex.in_src[i_rep]
        has = (kk >= 0) & ((kk == snd) | self._is_edge(np.maximum(kk, 0), snd))
        self.has = has.reshape(ie.size, self.K)
        self.in_dst = ex.in_dst
        self.n_in = ie.size

    def initial(self, init: np.ndarray) -> np.ndarray:
        safe = np.where(self.valid, self.slot_node, 0)
        return np.where(self.valid[:, :, None], init[safe], 0.0)

    def geometry(self, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(r_own − r_other, residual)`` of every half-measurement: ``g = ‖·‖² − d²`` (squared) or the whitened
        ``(‖·‖ − d)/σ`` (metres)."""
        diff = self.differences(P)
        return diff, self.residual_of(np.einsum("ij,ij->i", diff, diff))

    def differences(self, P: np.ndarray) -> np.ndarray:
        """``P[own] − P[other]`` of every half-measurement, ``(halves, dim)``, for a slot-layout array ``P``."""
        flat = P.reshape(-1)
        return np.asarray(flat[self.e_self] - flat[self.e_other]).reshape(-1, self.dim)

    def residual_of(self, sq_norm: np.ndarray) -> np.ndarray:
        """The residual from ``‖r_own − r_other‖²``."""
        if self.metres:
            return np.asarray((np.sqrt(np.maximum(sq_norm, 0.0)) - self.h_range) / self.h_sigma)
        return np.asarray(sq_norm - self.h_d2)

    def jrows(self, diff: np.ndarray) -> np.ndarray:
        """``∂residual/∂r_own`` per half-measurement: ``2(r_own − r_other)`` or ``u/σ`` (``u`` the unit vector)."""
        if not self.metres:
            return 2.0 * diff
        norm = np.linalg.norm(diff, axis=1)
        return np.asarray(diff / (np.where(norm > 0, norm, np.inf) * self.h_sigma)[:, None])

    def rho(self, g: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Per half-measurement IRLS weight ``ρ'((g/s)²)`` and objective term ``s² ρ((g/s)²)`` (linear: 1, g²)."""
        return loss_terms(g, self.h_scale, self.loss)

    def terms(self, g: np.ndarray) -> np.ndarray:
        """The objective terms of :meth:`rho` alone (linear: ``g²``, without the weights)."""
        return np.asarray(g * g) if self.loss == "linear" else self.rho(g)[1]

    def partial_cost(self, g: np.ndarray) -> np.ndarray:
        """``f⁽ⁱ⁾ = Σ_{l∈E(i)} g_l²`` (eq. (14)); with a robust loss ``Σ s_l² ρ((g_l/s_l)²)``."""
        return np.bincount(self.h_own, self.terms(g), minlength=self.nl)

    def gradient(self, diff: np.ndarray, g: np.ndarray, w: np.ndarray | None = None) -> np.ndarray:
        """``G⁽ⁱ⁾ᵀ g⁽ⁱ⁾`` per anchor in slot layout (zero on fixed/held/padding slots), eq. (10) restricted;
        with IRLS weights ``w``: ``G⁽ⁱ⁾ᵀ W g⁽ⁱ⁾`` (half the gradient of the robust partial objective)."""
        gw = g if w is None else w * g
        if self.metres:
            grad = csr_times(self.Q, gw[:, None] * self.jrows(diff)).reshape(self.nl, self.K, self.dim)
        else:
            grad = csr_times(self.Q, 2.0 * gw[:, None] * diff).reshape(self.nl, self.K, self.dim)
        return np.where(self.free_slot, grad, 0.0)


class Mixing:
    """The N-CSG consensus round (eqs. (15), (18)) on an exchange.

    Row ``i`` of ``W`` mixes ``i``'s own vector with the rows received from its neighbours; an entry a neighbour
    does not hold is filled with ``i``'s own entry (eq. (18)). Filling is linear, so the fill-in weight of every
    slot, ``Σ_{j: j lacks slot p} W_ij``, is folded into the self-weight per slot (recomputed only when a
    message is lost).
    """

    def __init__(self, nb: Neighbourhoods, ex: Exchange, w: ConsensusWeights) -> None:
        self.nb, self.ex = nb, ex
        self.self_w = w.self_weight[ex.nodes]
        ew_in = w.edge_weight[ex.in_edges]
        self.ew_in = ew_in
        self.S = sp.csr_matrix((ew_in, (ex.in_dst, np.arange(ex.in_edges.size))), shape=(ex.n_local, ex.in_edges.size))
        self.fill_w = self._fill_weights(np.ones(ex.in_edges.size, bool))
        self._msg = np.zeros((nb.n_out * nb.K, nb.dim))  # the entries outside msg_flat stay zero
        # msg_flat / msg_src as element indices of the flat arrays: a 1-D copy, ~4× faster than one of rows
        self._msg_e = (nb.msg_flat[:, None] * nb.dim + np.arange(nb.dim)).ravel()
        self._src_e = (nb.msg_src[:, None] * nb.dim + np.arange(nb.dim)).ravel()

    def _fill_weights(self, delivered: np.ndarray) -> np.ndarray:
        nb = self.nb
        lack = (~(nb.has & delivered[:, None])).astype(float)
        return np.asarray(self.self_w[:, None] + np.asarray(self.S @ lack))  # (n_local, K)

    def apply(self, U: np.ndarray, echo: Exchange | None = None) -> np.ndarray:
        """One consensus round; ``echo``: an in-process exchange without faults that sends the same messages
        too (it only counts them: a second solver whose state is, bit for bit, this one's)."""
        nb, ex = self.nb, self.ex
        K, dim = nb.K, nb.dim
        msg = self._msg  # consumed by the round below before the next one overwrites it
        msg.reshape(-1)[self._msg_e] = U.reshape(-1)[self._src_e]  # msg[msg_flat] = U's rows msg_src
        inbox = ex.send(msg.reshape(nb.n_out, K, dim))
        if echo is not None:
            echo.send(msg.reshape(nb.n_out, K, dim))
        fill = self.fill_w if inbox.delivered.all() else self._fill_weights(inbox.delivered)
        vals = inbox.values.reshape(nb.n_in, K * dim)  # entries not held (or lost) arrive as zeros
        mixed = fill[:, :, None] * U + csr_times(self.S, vals).reshape(U.shape)  # eqs. (15), (18)
        return np.where(nb.free_slot, mixed, nb.known_slot)


class ArmijoTest:
    """The Armijo test of every anchor along ``x + α d`` (eqs. (19)–(21)): every residual is the quartic
    ``a + 2αb + α²c − d²`` in ``α`` with ``a, b, c`` computed once per iteration."""

    def __init__(
        self, nb: Neighbourhoods, diff: np.ndarray, d: np.ndarray, f0: np.ndarray, gamma: float, slope_factor: float
    ) -> None:
        dd = nb.differences(d)
        self.nb, self.f0, self.gamma = nb, f0, gamma
        self.a = np.einsum("ij,ij->i", diff, diff) - nb.h_d2
        self.b = 2.0 * np.einsum("ij,ij->i", diff, dd)
        self.c = np.einsum("ij,ij->i", dd, dd)
        # ∇f⁽ⁱ⁾ᵀd with ∇f⁽ⁱ⁾ = 2 G⁽ⁱ⁾ᵀg⁽ⁱ⁾ = −2d (slope_factor 2); "subgradient": G⁽ⁱ⁾ᵀg⁽ⁱ⁾ in its place (factor 1)
        self.slope = -slope_factor * np.einsum("ijk,ijk->i", d, d)
        self.moving = self.slope < 0
        self.n2 = self.a + nb.h_d2  # ‖r_own − r_other‖² (metres)

    def __call__(self, alpha: np.ndarray) -> np.ndarray:
        nb = self.nb
        al = alpha[nb.h_own]
        r = nb.residual_of(self.n2 + al * (self.b + al * self.c)) if nb.metres else self.a + al * (self.b + al * self.c)
        fa = np.bincount(nb.h_own, nb.terms(r), minlength=nb.nl)
        return np.asarray(fa <= self.f0 + self.gamma * alpha * self.slope)


@dataclass(frozen=True)
class LineSearch:
    """The settings of the per-anchor line searches (eqs. (19)–(21)): the largest step ``alpha0`` (per anchor for
    the metres objective), the backtracking factor ``beta``, the Armijo constant ``gamma``, the trial steps per
    search ``max_backtracks`` and the slope factor (2: the true gradient ``2 G⁽ⁱ⁾ᵀg⁽ⁱ⁾``; 1: the paper's
    subgradient ``G⁽ⁱ⁾ᵀg⁽ⁱ⁾``)."""

    alpha0: float | np.ndarray
    beta: float
    gamma: float
    max_backtracks: int
    slope_factor: float = 2.0


def armijo_details(
    nb: Neighbourhoods,
    diff: np.ndarray,
    g: np.ndarray,
    d: np.ndarray,
    f0: np.ndarray,
    alpha_start: np.ndarray,
    rule: LineSearch,
    two_way: bool,
    known: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
    reuse: ArmijoTest | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-anchor step sizes by BLS (eqs. (19)–(20)) or TBLS (``two_way``, eq. (21)), vectorized over the block's
    anchors: ``(steps, ok, moving)``, with whether the Armijo condition holds at the returned step and which
    anchors have a descent direction (the others keep ``alpha_start``).

    ``known``: a BLS search's ``(steps, ok, moving)`` at the same point with the same ``α₀`` and a power-of-two
    ``β``: it tested every grid step from ``α₀`` down to its result, all failing but the result, so a test at a
    step ≥ the result needs no evaluation (every anchor's test depends on its own step only; the steps are exact
    grid values). A test is evaluated only when some moving anchor's step is below BLS's result. ``reuse``: the
    :class:`ArmijoTest` of the same point (computed once for both searches)."""
    test = ArmijoTest(nb, diff, d, f0, rule.gamma, rule.slope_factor) if reuse is None else reuse
    moving = test.moving
    beta, alpha0, max_backtracks = rule.beta, rule.alpha0, rule.max_backtracks

    def armijo(alpha: np.ndarray) -> np.ndarray:
        if known is not None and np.all((alpha >= known[0]) | ~moving):
            return np.asarray(known[1] & (alpha == known[0]))
        return test(alpha)

    alpha = alpha_start.copy()
    ok = armijo(alpha)
    todo = moving & ~ok
    for _ in range(max_backtracks):  # shrink until Armijo holds
        if not todo.any():
            break
        alpha[todo] *= beta
        ok = armijo(alpha)
        todo = moving & ~ok
    if two_way:  # grow while Armijo holds and α ≤ α₀
        grow = moving & ok & (alpha / beta <= alpha0 * (1 + 1e-12))
        for _ in range(max_backtracks):
            if not grow.any():
                break
            trial = np.where(grow, alpha / beta, alpha)
            ok_t = armijo(trial)
            step_up = grow & ok_t
            alpha = np.where(step_up, trial, alpha)
            grow = step_up & (alpha / beta <= alpha0 * (1 + 1e-12))
            ok = ok | step_up
    return np.where(moving, alpha, alpha_start), ok, moving
