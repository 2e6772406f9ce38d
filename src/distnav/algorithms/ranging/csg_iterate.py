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
    iterations, consensus_rounds, objective = o.iterations, o.consensus_rounds, o.objective
    range_offsets, offset_prior_sigma_m, alpha = o.range_offsets, o.offset_prior_sigma_m, o.step()
    init = check_start(problem, iterations, consensus_rounds, o.initial_m)
    metres = objective == "metres"
    ex = exchange_for(problem, exchange)
    mixer = ex.mixer(mixing_weights(problem, o.weights))
    n, dim, nl = problem.n_anchors, problem.dim, ex.n_local
    own_idx, other, d2, samp = half_measurements(problem, ex)
    sig = range_sigma(problem, o.sigma_m)[samp]
    rng_m = problem.range_m[samp]
    me = ex.nodes[own_idx]
    # full vectors: F[li, k] = anchor ex.nodes[li]'s estimate of anchor k
    F = np.broadcast_to(init, (nl, n, dim)).copy()
    free = np.broadcast_to(problem.free, (nl, n, dim))
    known = np.broadcast_to(problem.positions_m, (nl, n, dim))
    fl_self = own_idx * n + me
    fl_other = own_idx * n + other
    nh = own_idx.size
    Q = sp.csr_matrix(
        (
            np.concatenate([np.ones(nh), -np.ones(nh)]),
            (np.concatenate([fl_self, fl_other]), np.concatenate([np.arange(nh)] * 2)),
        ),
        shape=(nl * n, nh),
    )
    per = range_offsets == "per_anchor"
    prior_w = 2.0 / offset_prior_sigma_m**2 if per else 0.0  # b_i² in f⁽ⁱ⁾, counted twice (see above)
    Bo = np.zeros((nl, n if per else 1))  # every anchor's offsets (per anchor) or its copy of the common one
    b_self, b_other = (fl_self, fl_other) if per else (own_idx, own_idx)
    mine = np.arange(nl), (ex.nodes if per else np.zeros(nl, np.int64))
    if metres:
        info = np.bincount(own_idx, 1.0 / sig**2, minlength=nl)
        alpha_local = alpha / np.where(info > 0, info, 1.0)
        ratio = info / np.maximum(info + prior_w, 1e-300)  # offset step / position step
    else:
        alpha_local = np.full(nl, float(alpha))

    def bias() -> np.ndarray | float:
        flat_b = Bo.reshape(-1)
        return 0.0 if range_offsets == "none" else np.asarray(flat_b[b_self] + (flat_b[b_other] if per else 0.0))

    def residual(diff: np.ndarray) -> np.ndarray:
        if metres:
            return np.asarray((np.linalg.norm(diff, axis=1) + bias() - rng_m) / sig)
        return np.asarray(np.einsum("ij,ij->i", diff, diff) - d2)

    def partial_cost(Fc: np.ndarray) -> np.ndarray:
        flat = Fc.reshape(nl * n, dim)
        g = residual(flat[fl_self] - flat[fl_other])
        return np.asarray(np.bincount(own_idx, g * g, minlength=nl) + prior_w * Bo[mine] ** 2)

    def state(k: int, pc: np.ndarray) -> IterationState:
        flat = F.reshape(nl * n, dim)
        own = flat[ex.nodes + np.arange(nl) * n].copy()
        if range_offsets == "none":
            return IterationState(k, own, alpha_local, pc, own_idx, samp, flat[fl_other])
        return IterationState(
            k,
            own,
            alpha_local,
            pc,
            own_idx,
            samp,
            flat[fl_other],
            Bo[mine].copy(),
            np.broadcast_to(bias(), own_idx.shape).copy(),
        )

    yield state(0, partial_cost(F))
    for k in range(1, iterations + 1):
        flat = F.reshape(nl * n, dim)
        diff = flat[fl_self] - flat[fl_other]
        g = residual(diff)
        pc = np.bincount(own_idx, g * g, minlength=nl)
        pc = pc + prior_w * Bo[mine] ** 2 if prior_w else pc
        if metres:
            norm = np.linalg.norm(diff, axis=1)
            jr = diff / (np.where(norm > 0, norm, np.inf) * sig)[:, None]
            grad = csr_times(Q, g[:, None] * jr).reshape(nl, n, dim)
            U = np.where(free, F - alpha_local[:, None, None] * grad, known)
        else:
            grad = csr_times(Q, 2.0 * g[:, None] * diff).reshape(nl, n, dim)  # G⁽ⁱ⁾ᵀ g⁽ⁱ⁾, eq. (10)
            U = np.where(free, F - alpha * grad, known)
        if range_offsets == "none":
            for _ in range(consensus_rounds):  # eq. (11)
                U = mixer.apply(U)
        else:  # the offsets' gradient, step and consensus (in the same messages: n·dim + n or + 1 floats)
            gB = (
                np.bincount(b_self, g / sig, minlength=Bo.size)
                + (np.bincount(b_other, g / sig, minlength=Bo.size) if per else 0.0)
            ).reshape(Bo.shape)
            gB[mine] = gB[mine] + prior_w * Bo[mine]
            V = np.concatenate([U.reshape(nl, n * dim), Bo - (alpha_local * ratio)[:, None] * gB], axis=1)
            for _ in range(consensus_rounds):
                V = mixer.apply(V)
            U, Bo = V[:, : n * dim].reshape(nl, n, dim), V[:, n * dim :]
        F = np.where(free, U, known)
        yield state(k, pc)


def _loss_scale(problem: RangingData, objective: str, loss: str, loss_scale_m: float, sigma: np.ndarray) -> np.ndarray:
    if objective == "metres":
        return np.asarray(loss_scale_m / sigma)
    return range_loss_scale(problem, loss_scale_m) if loss != "linear" else np.ones(problem.n_meas)
