"""CSG (Koppanyi et al. 2018; paper 002 eqs. (10)–(12)): anchor ``i`` holds an estimate ``x⁽ⁱ⁾`` of *every* anchor.
Update phase ``u⁽ⁱ⁾ = x⁽ⁱ⁾ − α G⁽ⁱ⁾ᵀ g⁽ⁱ⁾`` where ``g⁽ⁱ⁾`` keeps only the residuals ``g_l = ‖r_a − r_b‖² − d_l²`` of
the ranges anchor ``i`` measured (eq. (10)); consensus phase ``u⁽ⁱ⁾ ← Σ_{j∈N(i)∪{i}} W_ij u⁽ʲ⁾`` repeated
``consensus_rounds`` times (eq. (11)), then ``x⁽ⁱ⁾ ← u⁽ⁱ⁾``. ``W`` is Metropolis–Hastings (eq. (12), ``"MH"``) or
Koppanyi's own variant (``"Koppanyi"``). A message is the whole vector: its size grows with the *network*.

Also here: what the family's front doors share (:func:`_cost_of`, :func:`_summarize`, :func:`_loss_scale`).
Split from ``csg.py`` (issue 25: no module over 600 lines), which re-exports :func:`iterate_csg`."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from typing import Any

import numpy as np
import scipy.sparse as sp

from distnav._settings import resolve_options
from distnav._sparse import csr_times
from distnav.algorithms.ranging.data import RangingData
from distnav.algorithms.ranging.losses import range_loss_scale
from distnav.algorithms.ranging.neighbourhoods import (
    IterationState,
    check_start,
    exchange_for,
    half_measurements,
    mixing_weights,
)
from distnav.algorithms.ranging.objective import range_sigma
from distnav.algorithms.ranging.options import CsgOptions
from distnav.exchange import Exchange

__all__ = ["iterate_csg"]


def _cost_of(problem: RangingData, objective: str, sigma: np.ndarray) -> Callable[[np.ndarray], float]:
    if objective == "metres":

        def cost(pos: np.ndarray) -> float:
            r = (problem.distances(pos) - problem.range_m) / sigma
            return float(r @ r)

        return cost
    return problem.cost


def _summarize(
    problem: RangingData,
    ex: Exchange,
    own_local: np.ndarray,
    truth: np.ndarray | None,
    est: np.ndarray,
    cost_of: Callable[[np.ndarray], float],
) -> tuple[np.ndarray, float, float]:
    """Monitoring only (gathers): all own estimates, global cost (eq. (2), or Σ e²/σ²) and RMSE (eq. (24))."""
    own = ex.gather_nodes(own_local)
    cost = cost_of(own)
    if truth is None:
        return own, cost, float("nan")
    if not est.any():
        return own, cost, 0.0
    d = own[est] - truth  # truth: the estimated anchors' true positions
    return own, cost, float(np.sqrt(np.mean(np.einsum("ij,ij->i", d, d))))


# ---------------------------------------------------------------------- CSG (full estimation vector)
def iterate_csg(
    problem: RangingData,
    *,
    exchange: Exchange | None = None,
    options: CsgOptions | None = None,
    **changes: Any,
) -> Iterator[IterationState]:
    """Yield the CSG state after iterations 0 (start), 1, …, ``iterations`` (paper 002 eqs. (10)–(12)).

    ``options`` (:class:`~distnav.algorithms.ranging.options.CsgOptions`, with keyword ``changes`` to it): the
    front door's; the run-only fields (``stop``, ``quality``, ...) are not used here.

    ``objective="metres"``: the residuals are ``(‖r_a − r_b‖ − d)/σ`` and ``α`` is relative to each anchor's
    information ``Σ_{l∈E(i)} σ_l⁻²`` (as in :func:`~distnav.algorithms.ranging.neighbourhood.iterate_neighbourhood`).
    ``range_offsets`` (metres): every anchor also holds every anchor's offset (``"per_anchor"``, prior counted
    twice in its own partial cost) or its copy of the common one, mixed in the same round (the conventions of
    :mod:`distnav.algorithms.ranging.neighbourhood_offsets`)."""
    o = resolve_options(CsgOptions, options, changes)
    init = check_start(problem, o.iterations, o.consensus_rounds, o.initial_m)
    run = _Csg(problem, exchange_for(problem, exchange), o, init)
    yield run.state(0, run.partial_cost(run.F))
    for k in range(1, o.iterations + 1):
        yield run.state(k, run.advance())


class _Csg:
    """One block's CSG iteration (:func:`iterate_csg`): the set-up, and the state ``F`` (``F[li, k]`` = anchor
    ``ex.nodes[li]``'s estimate of anchor ``k``) with the offsets ``Bo`` (every anchor's, per anchor, or its copy
    of the common one)."""

    def __init__(self, problem: RangingData, ex: Exchange, o: CsgOptions, init: np.ndarray) -> None:
        self.ex, self.consensus_rounds, self.range_offsets = ex, o.consensus_rounds, o.range_offsets
        self.alpha = alpha = o.step()
        self.metres = metres = o.objective == "metres"
        self.mixer = ex.mixer(mixing_weights(problem, o.weights))
        n, dim, nl = problem.n_anchors, problem.dim, ex.n_local
        own_idx, other, d2, samp = half_measurements(problem, ex)
        self.n, self.dim, self.nl, self.own_idx, self.d2, self.samp = n, dim, nl, own_idx, d2, samp
        self.sig = sig = range_sigma(problem, o.sigma_m)[samp]
        self.rng_m = problem.range_m[samp]
        me = ex.nodes[own_idx]
        self.F = np.broadcast_to(init, (nl, n, dim)).copy()
        self.free = np.broadcast_to(problem.free, (nl, n, dim))
        self.known = np.broadcast_to(problem.positions_m, (nl, n, dim))
        self.fl_self = fl_self = own_idx * n + me
        self.fl_other = fl_other = own_idx * n + other
        nh = own_idx.size
        self.Q = sp.csr_matrix(
            (
                np.concatenate([np.ones(nh), -np.ones(nh)]),
                (np.concatenate([fl_self, fl_other]), np.concatenate([np.arange(nh)] * 2)),
            ),
            shape=(nl * n, nh),
        )
        self.per = per = o.range_offsets == "per_anchor"
        self.prior_w = prior_w = 2.0 / o.offset_prior_sigma_m**2 if per else 0.0  # b_i² in f⁽ⁱ⁾, counted twice
        self.Bo = np.zeros((nl, n if per else 1))
        self.b_self: np.ndarray = fl_self if per else own_idx
        self.b_other: np.ndarray = fl_other if per else own_idx
        self.mine = np.arange(nl), (ex.nodes if per else np.zeros(nl, np.int64))
        self.ratio: np.ndarray | None = None
        if metres:
            info = np.bincount(own_idx, 1.0 / sig**2, minlength=nl)
            self.alpha_local = alpha / np.where(info > 0, info, 1.0)
            self.ratio = info / np.maximum(info + prior_w, 1e-300)  # offset step / position step
        else:
            self.alpha_local = np.full(nl, float(alpha))

    def bias(self) -> np.ndarray | float:
        flat_b = self.Bo.reshape(-1)
        if self.range_offsets == "none":
            return 0.0
        return np.asarray(flat_b[self.b_self] + (flat_b[self.b_other] if self.per else 0.0))

    def residual(self, diff: np.ndarray) -> np.ndarray:
        if self.metres:
            return np.asarray((np.linalg.norm(diff, axis=1) + self.bias() - self.rng_m) / self.sig)
        return np.asarray(np.einsum("ij,ij->i", diff, diff) - self.d2)

    def partial_cost(self, Fc: np.ndarray) -> np.ndarray:
        nl = self.nl
        flat = Fc.reshape(nl * self.n, self.dim)
        g = self.residual(flat[self.fl_self] - flat[self.fl_other])
        return np.asarray(np.bincount(self.own_idx, g * g, minlength=nl) + self.prior_w * self.Bo[self.mine] ** 2)

    def state(self, k: int, pc: np.ndarray) -> IterationState:
        nl, n, own_idx, samp = self.nl, self.n, self.own_idx, self.samp
        flat = self.F.reshape(nl * n, self.dim)
        own = flat[self.ex.nodes + np.arange(nl) * n].copy()
        if self.range_offsets == "none":
            return IterationState(k, own, self.alpha_local, pc, own_idx, samp, flat[self.fl_other])
        return IterationState(
            k,
            own,
            self.alpha_local,
            pc,
            own_idx,
            samp,
            flat[self.fl_other],
            self.Bo[self.mine].copy(),
            np.broadcast_to(self.bias(), own_idx.shape).copy(),
        )

    def advance(self) -> np.ndarray:
        """One iteration (eqs. (10)–(11)); the partial costs at its start."""
        nl, n, dim, F, Bo, sig = self.nl, self.n, self.dim, self.F, self.Bo, self.sig
        own_idx, mine, prior_w, free, known = self.own_idx, self.mine, self.prior_w, self.free, self.known
        flat = F.reshape(nl * n, dim)
        diff = flat[self.fl_self] - flat[self.fl_other]
        g = self.residual(diff)
        pc = np.bincount(own_idx, g * g, minlength=nl)
        pc = pc + prior_w * Bo[mine] ** 2 if prior_w else pc
        if self.metres:
            norm = np.linalg.norm(diff, axis=1)
            jr = diff / (np.where(norm > 0, norm, np.inf) * sig)[:, None]
            grad = csr_times(self.Q, g[:, None] * jr).reshape(nl, n, dim)
            U = np.where(free, F - self.alpha_local[:, None, None] * grad, known)
        else:
            grad = csr_times(self.Q, 2.0 * g[:, None] * diff).reshape(nl, n, dim)  # G⁽ⁱ⁾ᵀ g⁽ⁱ⁾, eq. (10)
            U = np.where(free, F - self.alpha * grad, known)
        if self.range_offsets == "none":
            for _ in range(self.consensus_rounds):  # eq. (11)
                U = self.mixer.apply(U)
        else:  # the offsets' gradient, step and consensus (in the same messages: n·dim + n or + 1 floats)
            assert self.ratio is not None  # offsets come with the metres objective only
            gB = (
                np.bincount(self.b_self, g / sig, minlength=Bo.size)
                + (np.bincount(self.b_other, g / sig, minlength=Bo.size) if self.per else 0.0)
            ).reshape(Bo.shape)
            gB[mine] = gB[mine] + prior_w * Bo[mine]
            V = np.concatenate([U.reshape(nl, n * dim), Bo - (self.alpha_local * self.ratio)[:, None] * gB], axis=1)
            for _ in range(self.consensus_rounds):
                V = self.mixer.apply(V)
            U, self.Bo = V[:, : n * dim].reshape(nl, n, dim), V[:, n * dim :]
        self.F = np.where(free, U, known)
        return np.asarray(pc)


def _loss_scale(problem: RangingData, objective: str, loss: str, loss_scale_m: float, sigma: np.ndarray) -> np.ndarray:
    if objective == "metres":
        return np.asarray(loss_scale_m / sigma)
    return range_loss_scale(problem, loss_scale_m) if loss != "linear" else np.ones(problem.n_meas)
