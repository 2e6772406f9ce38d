"""Which per-anchor σ the distributed solvers report in the field workflow, and what it costs (issue 13 item 3,
issue 27).

``"gathered"`` (:func:`gathered_precision`, the default up to
:data:`~distnav.algorithms.ranging.covariance.CENTRAL_MAX_ANCHORS` anchors with the metres objective): LM's
central a-posteriori covariance with the antenna delays considered
(:func:`distnav.models.uwb.precision.consider_precision`, exactly LM's σ code) at the distributed solution, computed
at one anchor that gathers what it needs over a shortest-path tree of the range graph — every kept range record
(:data:`~distnav.models.uwb.communication.RANGE_RECORD_BYTES`, held by the lower-numbered anchor of its link) and
every anchor's estimate (``dim`` floats, and its own offset with per-anchor offsets) — and sends each anchor its
own covariance block back (the packed upper triangle of its free coordinates). A **fusion centre for the σ
only**: it costs about what gathering the ranges costs (1–2 ×), where the network-wide CG of ``"central"`` cost
3,000 × that on plant-like 28-anchor halls (docs/economy_uwb.md); the positions are still the distributed
solvers'. ``"central"`` (:func:`distnav.algorithms.ranging.covariance.central_precision`): the same blocks by CG
over the exchange — messages of ``P (n_free + n)`` floats for ``≈ n_free`` rounds (the default before issue 27).
``"subnetwork"`` (:func:`distnav.algorithms.ranging.precision.neighbourhood_precision` with
:data:`PRECISION_HOPS` hops): each anchor's 2-hop sub-network from its neighbours' link records and each 2-hop
anchor's relayed once (:mod:`distnav.algorithms.ranging.subnetwork`: 28–40 × fewer bytes than the records relayed by
every neighbour before issue 27's fifth session), but 0.67–0.88 × LM's σ where the chain to the known anchors is long
(docs/uwb.md). ``"auto"`` (the
default): gathered for the metres objective up to ``CENTRAL_MAX_ANCHORS`` anchors, else the sub-network (whose
busiest anchor sends less than a gather's busiest relay on large networks); the sub-network is also the fallback
where the gathered or central solve fails (a singular normal matrix, CG not converged).
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass
from types import SimpleNamespace
from typing import Any

import numpy as np

from distnav.algorithms.ranging.covariance import (
    CENTRAL_MAX_ANCHORS,
    ECONOMY_CG_RTOL,
    ECONOMY_WIRE_DTYPE,
    CentralPrecisionOptions,
    central_precision,
)
from distnav.algorithms.ranging.losses import robust_weights
from distnav.algorithms.ranging.neighbourhood_offsets import sample_bias
from distnav.algorithms.ranging.objective import RangeObjective
from distnav.algorithms.ranging.precision import neighbourhood_precision
from distnav.algorithms.statistics import variance_factor
from distnav.errors import ModelError
from distnav.models.uwb.communication import VALUE_BYTES, gathered_up
from distnav.models.uwb.field_options import FieldOptions, solver_kwargs, subset_measurements
from distnav.models.uwb.precision import DELAY_UPPER_Z, consider_precision
from distnav.models.uwb.problems import RangingProblem
from distnav.network.gather import gather_cost
from distnav.typing import BoolArray, FloatArray

__all__ = [
    "DistributedSigma",
    "distributed_sigma",
    "gathered_precision",
    "gathered_cost",
    "PRECISION_HOPS",
    "PRECISION_MODES",
    "AnchorPrecision",
    "anchor_precision",
]

log = logging.getLogger(__name__)
PRECISION_HOPS = 2  # the sub-network σ: each anchor's 2-hop sub-network (docs/uwb.md, "Per-anchor precision")
PRECISION_MODES = ("auto", "gathered", "central", "subnetwork")


@dataclass(frozen=True, eq=False)
class DistributedSigma:
    """σ ``(n, dim)``, the a-posteriori covariance blocks (m²), the kind (``"gathered"``, ``"central"`` or
    ``"neighbourhood"``) and the cost: the exchange's messages / bytes plus, for the central σ, its network totals
    as spanning-tree reductions (:meth:`~distnav.algorithms.ranging.covariance.CentralPrecision.reduction_cost`);
    for the gathered σ the tree's messages up and down. ``bytes_sent``: per anchor, where known (the gathered σ:
    what each anchor transmits, its own data and what it relays; the sub-network σ: its exchange's counters)."""

    sigma_m: FloatArray
    covariance_m2: FloatArray
    kind: str
    messages: int
    bytes: int
    bytes_sent: FloatArray | None = None


def _consider_kwargs(model: CentralPrecisionOptions) -> dict[str, Any]:
    """The keyword arguments of :func:`~distnav.models.uwb.precision.consider_precision` (LM's σ code) for the fit
    ``model``."""
    return {
        "sigma_m": model.sigma_m,
        "offsets": model.range_offsets,
        "loss": model.loss,
        "loss_scale_m": model.loss_scale_m,
        "delay_sigma_m": model.delay_sigma_m,
        "offset_prior_sigma_m": model.offset_prior_sigma_m,
        "estimate_delays": model.estimate_delays and model.delay_sigma_m > 0,
    }


def distributed_sigma(
    kept: RangingProblem,
    res: Any,
    model: CentralPrecisionOptions,
    *,
    exchange: Any,
    objective: str,
    mode: str = "auto",
) -> DistributedSigma:
    """The distributed solvers' σ on the links ``kept`` at the solution ``res`` of the fit ``model`` (module
    docstring: the fit's range σ, loss, offsets, delays considered and ``variance_scale_m``, the scale it was
    fitted at, as :func:`~distnav.algorithms.ranging.covariance.central_precision` takes them); ``exchange``
    builds the exchange of a problem (None: in-process). Raises ModelError where none can be computed, or the
    ``mode`` forced cannot."""
    if mode not in PRECISION_MODES:
        raise ModelError(f"distributed precision must be one of {', '.join(PRECISION_MODES)}, got {mode!r}")
    if mode in ("central", "gathered") and objective != "metres":
        raise ModelError(f"distributed precision {mode!r} models the metres objective only, not {objective!r}")
    if mode == "central":
        return _central(kept, res, model, exchange)
    if mode == "gathered" or (mode == "auto" and objective == "metres" and kept.n_anchors <= CENTRAL_MAX_ANCHORS):
        gathered = gathered_precision(kept, res, model)
        if gathered is not None:
            return gathered
        if mode == "gathered":
            raise ModelError("gathered precision: the normal matrix of the kept links is singular")
        log.info("gathered precision failed (a singular normal matrix): the 2-hop sub-network σ instead")
    return _subnetwork(kept, res, model, exchange, objective)


def _central(kept: RangingProblem, res: Any, model: CentralPrecisionOptions, exchange: Any) -> DistributedSigma:
    """LM's blocks by CG over the exchange (:func:`~distnav.algorithms.ranging.covariance.central_precision`, the
    workflow's float32 directions to :data:`~distnav.algorithms.ranging.covariance.ECONOMY_CG_RTOL`)."""
    off = getattr(res, "offsets_m", None)
    out = central_precision(
        kept,
        np.asarray(res.estimates, float),
        offset_m=None if off is None else np.asarray(off, float),
        exchange=None if exchange is None else exchange(kept),
        options=model,
        delay_upper_z=DELAY_UPPER_Z,
        rtol=ECONOMY_CG_RTOL,
        wire_dtype=ECONOMY_WIRE_DTYPE,
    )
    comm = out.precision.comm
    red_msg, red_bytes = out.reduction_cost(kept.n_anchors)
    return DistributedSigma(
        np.where(kept.free, out.std(a_posteriori=True), 0.0),
        out.covariance(a_posteriori=True),
        "central",
        red_msg + (0 if comm is None else int(comm.messages)),
        red_bytes + (0 if comm is None else int(comm.bytes)),
    )


def _subnetwork(
    kept: RangingProblem, res: Any, model: CentralPrecisionOptions, exchange: Any, objective: str
) -> DistributedSigma:
    """Every anchor's :data:`PRECISION_HOPS`-hop sub-network σ (they know no offsets: the ranges less the
    solution's)."""
    off = getattr(res, "offsets_m", None)
    bias = 0.0 if off is None else _bias(kept, np.asarray(off, float))
    sub = kept.with_ranges(kept.range_m - bias) if not np.isscalar(bias) or bias != 0.0 else kept
    nb = neighbourhood_precision(
        sub,
        np.asarray(res.estimates, float),
        exchange=None if exchange is None else exchange(sub),
        objective=objective,
        sigma_m=model.sigma_m,
        loss=model.loss,
        loss_scale_m=model.loss_scale_m,
        hops=PRECISION_HOPS,
        delay_sigma_m=model.delay_sigma_m,
    )
    comm = nb.precision.comm
    return DistributedSigma(
        np.where(kept.free, nb.std(a_posteriori=True), 0.0),
        nb.covariance(a_posteriori=True),
        nb.precision.kind,
        0 if comm is None else int(comm.messages),
        0 if comm is None else int(comm.bytes),
        None if comm is None else np.asarray(comm.bytes_sent, float),
    )


def _bias(problem: RangingProblem, off: FloatArray) -> FloatArray | float:
    return sample_bias(problem.meas_a, problem.meas_b, off)


def gathered_precision(kept: RangingProblem, res: Any, model: CentralPrecisionOptions) -> DistributedSigma | None:
    """LM's σ at the distributed solution ``res`` on the links ``kept``, computed at one anchor (module docstring):
    :func:`~distnav.models.uwb.precision.consider_precision` with the variance factor σ̂² = Σ w r² / redundancy of
    the weights at ``model.variance_scale_m`` (the fit's, as :func:`~distnav.algorithms.ranging.covariance.
    central_precision`) and the normal matrix's weights at ``model.loss_scale_m``. The cost
    (:func:`gathered_cost`): the records up, the blocks down. None where the normal matrix is singular."""
    obj = RangeObjective(kept, "metres", model.sigma_m, model.range_offsets, model.offset_prior_sigma_m)
    est = np.asarray(res.estimates, float)
    off = np.zeros(obj.n_offsets)
    got = getattr(res, "offsets_m", None)
    if obj.n_offsets:  # the solver's offsets: the common one (every anchor's copy, their mean) or each anchor's own
        held = np.zeros(1) if got is None else np.asarray(got, float)
        off = np.full(1, float(np.mean(held))) if model.range_offsets == "common" else held
    if off.shape != (obj.n_offsets,) or not (np.all(np.isfinite(est)) and np.all(np.isfinite(off))):
        return None
    x = np.concatenate([kept.to_vector(est), off])
    r = obj.residual(x)
    scale = model.loss_scale_m if model.variance_scale_m is None else model.variance_scale_m
    w_vf = robust_weights(r, obj.loss_scale(scale), model.loss)[0]
    redundancy = float(r.size - obj.n_x)
    vf = variance_factor(float(np.sum(w_vf * r * r)), redundancy)
    prec = SimpleNamespace(variance_factor=1.0 if vf is None else vf, redundancy=redundancy)
    out = consider_precision(kept, SimpleNamespace(x=x, precision=prec), **_consider_kwargs(model))
    if out is None:
        return None
    sigma, blocks = out
    messages, sent = gathered_cost(kept, per_anchor_offsets=model.range_offsets == "per_anchor")
    return DistributedSigma(np.where(kept.free, sigma, 0.0), blocks, "gathered", messages, int(sent.sum()), sent)


def gathered_cost(problem: RangingProblem, *, per_anchor_offsets: bool = False) -> tuple[int, FloatArray]:
    """Messages and bytes each anchor transmits for :func:`gathered_precision` over a shortest-path tree of the
    range graph to the anchor with the fewest hop-bytes (:func:`distnav.network.gather.gather_cost`): up, every
    anchor's range records and estimate (and offset); down, every anchor's covariance block (the packed upper
    triangle of its free coordinates), each relayed by the anchors between it and the root. One message per tree
    link each way (a relay bundles its subtree's)."""
    graph, up = gathered_up(problem, per_anchor_offsets=per_anchor_offsets)
    n_free = problem.free.sum(axis=1)
    down_bytes = VALUE_BYTES * n_free * (n_free + 1) // 2
    subtree = gather_cost(graph, down_bytes, sink=up.sink).relay_bytes  # its subtree's blocks, its own included
    down = subtree - down_bytes  # a relay forwards its subtree's blocks but its own
    down[up.sink] = int(down_bytes.sum() - down_bytes[up.sink])
    sent = np.asarray(up.relay_bytes + down, float)
    return 2 * up.tree_messages, sent


@dataclass(frozen=True, eq=False)
class AnchorPrecision:
    """What :func:`anchor_precision` gives ``solve_field``: σ per anchor and axis, the covariance blocks they come
    from (a-posteriori, m²; None where unknown), the precision's kind, its messages / bytes and a note."""

    sigma_m: FloatArray
    covariance_m2: FloatArray | None
    kind: str | None
    messages: int = 0
    bytes: int = 0
    note: str = ""


def anchor_precision(
    problem: RangingProblem,
    res: Any,
    opts: FieldOptions,
    excluded: BoolArray,
    objective: str,
    exchange: Callable[[RangingProblem], Any] | None,
    *,
    fit_scale_m: float | None = None,
) -> AnchorPrecision:
    """σ of every anchor after the solve, on the links kept (``~excluded``); ``fit_scale_m``: the loss scale
    ``res`` was fitted at (its variance factor's, as LM's own; default ``opts.loss_scale_m``).

    LM: its central ``σ̂² (JᵀWJ)⁻¹`` (kind ``"centralized"``), with the antenna delays considered where
    ``opts.considers_delays`` (:mod:`distnav.models.uwb.precision`). The distributed solvers (through the
    exchange, its messages counted; ``opts.distributed_precision``, :mod:`distnav.models.uwb.field_precision`):
    by default LM's central blocks by CG (kind ``"central"``, up to 100 anchors), else every anchor's
    :data:`PRECISION_HOPS`-hop sub-network (kind ``"neighbourhood"``, its own variance factor), the delays
    considered; the solvers' own conditional
    ``N_i⁻¹`` (a lower bound) is used only if that fails, and the note says so."""
    nan_pos = np.full((problem.n_anchors, problem.dim), np.nan)
    prec = res.precision
    kept = subset_measurements(problem, ~excluded)
    if opts.solver.upper() != "LM":
        try:
            model = CentralPrecisionOptions(
                sigma_m=opts.sigma_m,
                loss=solver_kwargs(opts).get("loss", "linear"),
                loss_scale_m=opts.loss_scale_m,
                range_offsets=opts.offsets_used,
                offset_prior_sigma_m=opts.offset_prior_sigma_m,
                delay_sigma_m=opts.delay_sigma_m if opts.considers_delays and objective == "metres" else 0.0,
                estimate_delays=opts.estimate_delays,
                variance_scale_m=fit_scale_m,
            )
            out = distributed_sigma(
                kept, res, model, exchange=exchange, objective=objective, mode=opts.distributed_precision
            )
        except ModelError as err:
            note = f"; neighbourhood precision failed ({err}): σ are the conditional ones (a lower bound)"
        else:
            return AnchorPrecision(
                sigma_m=out.sigma_m,
                covariance_m2=out.covariance_m2,
                kind=out.kind,
                messages=out.messages,
                bytes=out.bytes,
            )
    else:
        note = ""
    if prec is None:
        return AnchorPrecision(sigma_m=nan_pos, covariance_m2=None, kind=None, note=note)
    vf = prec.variance_factor if prec.variance_factor is not None else 1.0
    sigma = np.where(problem.free, prec.std(a_posteriori=True), 0.0)
    cov = prec.covariance * vf
    if opts.considers_delays:
        considered = consider_precision(
            kept,
            res,
            sigma_m=opts.sigma_m,
            offsets=opts.offsets_used,
            loss=solver_kwargs(opts).get("loss", "linear"),
            loss_scale_m=opts.loss_scale_m,
            delay_sigma_m=opts.delay_sigma_m,
            estimate_delays=opts.estimate_delays,
        )
        if considered is not None:
            sigma, cov = considered  # the ellipses of the σ written, delays considered
    return AnchorPrecision(sigma_m=sigma, covariance_m2=cov, kind=prec.kind, note=note)
