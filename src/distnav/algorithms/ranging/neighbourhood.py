"""The neighbourhood machinery of N-CSG and N-CLM (paper 002 §3.3–3.4), and the set-up shared with CSG.

Every anchor is a node of the measurement graph and talks only to the anchors it ranges with, through the
exchange (:mod:`distnav.exchange`); all arrays below are local to the exchange's block of anchors. The front doors
(:func:`~distnav.algorithms.ranging.csg.solve_ncsg`, :func:`~distnav.algorithms.ranging.csg.solve_nclm`) are in
:mod:`~distnav.algorithms.ranging.csg`; the index maps of the neighbourhood vectors (:class:`Neighbourhoods`), the
consensus round (:class:`Mixing`), the line searches
(:func:`~distnav.algorithms.ranging.neighbourhoods.armijo_details`), the local LM step (:class:`LocalLM`) and the
iteration itself (:func:`iterate_neighbourhood`).

* **N-CSG** (eqs. (14)–(18)): ``x⁽ⁱ⁾`` holds only anchor ``i`` and its neighbours; the update minimises the
  partial cost ``f⁽ⁱ⁾ = Σ_{l∈E(i)} g_l²`` (eq. (14)). In the consensus phase anchor ``j`` sends to each neighbour
  ``i`` the entries of ``u⁽ʲ⁾`` that ``i`` also holds (a message of at most ``max degree + 1`` positions: its size
  grows with the *neighbourhood*); anchor ``i`` stacks them row-wise, fills the entries a neighbour does not hold
  (non-common neighbours) with its own ``u⁽ⁱ⁾`` (eq. (18)) and mixes with row ``i`` of ``W`` (eq. (15)).
* **N-CSG + BLS** (eqs. (19)–(20)): each anchor picks its own step by backtracking from ``α₀`` until the Armijo
  condition ``f⁽ⁱ⁾(x + α d) ≤ f⁽ⁱ⁾(x) + γ α ∇f⁽ⁱ⁾ᵀ d`` holds, ``d = −G⁽ⁱ⁾ᵀ g⁽ⁱ⁾`` (the subgradient direction of
  eq. (10)) and, as in the paper, the subgradient ``G⁽ⁱ⁾ᵀ g⁽ⁱ⁾`` in the role of ``∇f⁽ⁱ⁾`` (``armijo_slope``
  selects the true gradient ``2 G⁽ⁱ⁾ᵀ g⁽ⁱ⁾`` instead), ``α ← β α``.
  **N-CSG + TBLS** (eq. (21), Truong & Nguyen 2020): start from the anchor's previous ``α``; if Armijo fails,
  shrink by ``β``; otherwise grow by ``1/β`` while Armijo holds and ``α ≤ α₀``. The line searches evaluate each
  anchor's own partial cost locally — no messages — vectorized over anchors: along ``x + α d`` every residual
  is the quartic ``(a + 2αb + α²c − d²)`` with ``a, b, c`` computed once per iteration.
* **N-CLM** (eq. (22)): the N-CSG step with the subgradient step replaced by the Levenberg–Marquardt step of
  eq. (8) on the partial cost, ``u⁽ⁱ⁾ = x⁽ⁱ⁾ − (G⁽ⁱ⁾ᵀG⁽ⁱ⁾ + λ_i D_i)⁻¹ G⁽ⁱ⁾ᵀ g⁽ⁱ⁾``; each anchor adapts its own
  ``λ_i`` from the gain ratio of its partial cost (a rejected step leaves ``x⁽ⁱ⁾`` unchanged this iteration);
  the consensus phase is that of N-CSG. ``D_i = mean(diag(G⁽ⁱ⁾ᵀG⁽ⁱ⁾))·I`` by default — a deviation from eq. (8)'s
  Fletcher scaling ``diag(G⁽ⁱ⁾ᵀG⁽ⁱ⁾)`` (``damping="fletcher"``), which stalls on the rank-deficient partial
  problems (see :func:`~distnav.algorithms.ranging.csg.solve_nclm`).

Fixed anchors take part (they measure and relay) but their coordinates, and any held coordinate, are never changed.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any, cast

import numpy as np

from distnav._settings import resolve_options
from distnav.algorithms.ranging.data import RangingData
from distnav.algorithms.ranging.neighbourhood_offsets import NeighbourhoodOffsets, loop_with_offsets
from distnav.algorithms.ranging.neighbourhoods import IterationState
from distnav.algorithms.ranging.options import NclmOptions, NcsgOptions
from distnav.algorithms.ranging.plan import plan_neighbourhood
from distnav.exchange import Exchange

__all__ = ["iterate_neighbourhood"]


def iterate_neighbourhood(
    problem: RangingData,
    *,
    method: str = "N-CSG",
    exchange: Exchange | None = None,
    options: NcsgOptions | NclmOptions | None = None,
    **changes: Any,
) -> Iterator[IterationState]:
    """Yield the state of N-CSG / N-CSG-BLS / N-CSG-TBLS / N-CLM after iterations 0, 1, …, ``iterations``.

    ``options``: an :class:`~distnav.algorithms.ranging.options.NclmOptions` for N-CLM, an
    :class:`~distnav.algorithms.ranging.options.NcsgOptions` for the N-CSG family (their defaults, the front
    doors', are those of the paper for the squared objective), with keyword ``changes`` to it (``alpha``,
    ``loss``, ...: :func:`distnav._settings.resolve_options`); the run-only fields (``stop``, ``quality``, ...) are
    not used here. ``range_offsets`` "common" / "per_anchor" (metres objective):
    :mod:`distnav.algorithms.ranging.neighbourhood_offsets`.

    See the module docstring for the equations (paper 002 eqs. (14)–(22)). ``loss="huber"|"cauchy"`` makes every
    anchor minimise the robust partial objective ``Σ_{l∈E(i)} s_l² ρ((g_l/s_l)²)`` (``s_l = 2 d_l σ``,
    ``σ = loss_scale_m``, as :func:`distnav.algorithms.ranging.lm.solve_lm`): the subgradient becomes ``G⁽ⁱ⁾ᵀW g⁽ⁱ⁾``
    with IRLS weights ``w_l = ρ'`` computed by the anchor from its own estimates, the line searches test the
    robust objective, and N-CLM solves the weighted normal equations.

    ``objective="metres"``: every anchor fits the whitened range residuals ``(‖r_i − r_j‖ − d)/σ`` of its links
    instead of ``g`` (the loss scale ``loss_scale_m`` then is in metres of range error for every link), and the
    steps ``alpha`` / ``alpha0`` are relative to each anchor's own information, ``α_i = alpha / Σ_{l∈E(i)} σ_l⁻²``
    (a gradient step of ``alpha ≤ 1`` is stable for the partial cost's Gauss–Newton curvature, whose largest
    eigenvalue is at most ``2 Σ σ_l⁻²``); ``graduated = k`` runs the first ``k`` iterations with the linear loss.
    """
    o: NcsgOptions | NclmOptions  # resolve_options refuses an options object of the other class
    if method.upper() == "N-CLM":
        o = resolve_options(NclmOptions, cast("NclmOptions | None", options), changes)
    else:
        o = resolve_options(NcsgOptions, cast("NcsgOptions | None", options), changes)
    plan, P, step = plan_neighbourhood(problem, o, method=method, exchange=exchange)
    nb = plan.nb
    mode = o.range_offsets
    if mode != "none":
        off = NeighbourhoodOffsets(nb, mode, float(o.offset_prior_sigma_m), o.initial_offset_m or 0.0)
        yield from loop_with_offsets(plan, off, P, step, np.full(nb.nl, 2.0))
        return
    diff, g = nb.geometry(P)
    yield IterationState(0, P[:, 0].copy(), step.copy(), nb.partial_cost(g))
    yield from plan.loop(P, step, np.full(nb.nl, 2.0), 1)
