"""Which per-anchor σ the distributed solvers report in the field workflow, and what it costs (issue 13 item 3).

``"central"`` (:func:`distnav.algorithms.ranging.covariance.central_precision`): every anchor's block of LM's
central a-posteriori covariance, the antenna delays considered and estimated as LM does, by CG over the exchange —
messages of ``P (n_free + n)`` floats for ``≈ n_free`` rounds. ``"subnetwork"``
(:func:`distnav.algorithms.ranging.precision.neighbourhood_precision` with :data:`PRECISION_HOPS` hops): each
anchor's 2-hop sub-network, ``O(degree²)`` floats per link in ``3 + hops`` rounds, but 0.67–0.88 × LM's σ where the
chain to the known anchors is long (docs/uwb.md). ``"auto"`` (the default): central for the metres objective up
to :data:`~distnav.algorithms.ranging.covariance.CENTRAL_MAX_ANCHORS` anchors, else the sub-network; the
sub-network is also the fallback where the central solve fails (a singular own block, CG not converged).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Any

import numpy as np

from distnav.algorithms.ranging.covariance import (
    CENTRAL_MAX_ANCHORS,
    ECONOMY_CG_RTOL,
    ECONOMY_WIRE_DTYPE,
    central_precision,
)
from distnav.algorithms.ranging.neighbourhood_offsets import sample_bias
from distnav.algorithms.ranging.precision import neighbourhood_precision
from distnav.errors import ModelError
from distnav.models.uwb.precision import DELAY_UPPER_Z
from distnav.models.uwb.problems import RangingProblem
from distnav.typing import FloatArray

__all__ = ["DistributedSigma", "distributed_sigma", "PRECISION_HOPS", "PRECISION_MODES"]

log = logging.getLogger(__name__)
PRECISION_HOPS = 2  # the sub-network σ: each anchor's 2-hop sub-network (docs/uwb.md, "Per-anchor precision")
PRECISION_MODES = ("auto", "central", "subnetwork")


@dataclass(frozen=True, eq=False)
class DistributedSigma:
    """σ ``(n, dim)``, the a-posteriori covariance blocks (m²), the kind (``"central"`` or ``"neighbourhood"``)
    and the cost: the exchange's messages / bytes plus, for the central σ, its network totals as spanning-tree
    reductions (:meth:`~distnav.algorithms.ranging.covariance.CentralPrecision.reduction_cost`)."""

    sigma_m: FloatArray
    covariance_m2: FloatArray
    kind: str
    messages: int
    bytes: int


def distributed_sigma(
    kept: RangingProblem,
    res: Any,
    *,
    exchange: Any,
    objective: str,
    sigma_m: float,
    loss: str,
    loss_scale_m: float,
    offsets: str,
    offset_prior_sigma_m: float,
    delay_sigma_m: float,
    estimate_delays: bool,
    mode: str = "auto",
    fit_scale_m: float | None = None,
) -> DistributedSigma:
    """The distributed solvers' σ on the links ``kept`` at the solution ``res`` (module docstring); ``exchange``
    builds the exchange of a problem (None: in-process). ``delay_sigma_m`` 0: no delays considered; ``fit_scale_m``
    the loss scale ``res`` was fitted at (the central σ̂² at it, as LM's). Raises
    ModelError where neither can be computed."""
    if mode not in PRECISION_MODES:
        raise ModelError(f"distributed precision must be one of {', '.join(PRECISION_MODES)}, got {mode!r}")
    est = np.asarray(res.estimates, float)
    off = getattr(res, "offsets_m", None)
    if mode == "central" and objective != "metres":
        raise ModelError(f"distributed precision 'central' models the metres objective only, not {objective!r}")
    if mode == "central" or (mode == "auto" and objective == "metres" and kept.n_anchors <= CENTRAL_MAX_ANCHORS):
        try:
            out = central_precision(
                kept,
                est,
                offset_m=None if off is None else np.asarray(off, float),
                exchange=None if exchange is None else exchange(kept),
                sigma_m=sigma_m,
                loss=loss,
                loss_scale_m=loss_scale_m,
                range_offsets=offsets,
                offset_prior_sigma_m=offset_prior_sigma_m,
                delay_sigma_m=delay_sigma_m,
                estimate_delays=estimate_delays,
                variance_scale_m=fit_scale_m,
                delay_upper_z=DELAY_UPPER_Z,
                rtol=ECONOMY_CG_RTOL,
                wire_dtype=ECONOMY_WIRE_DTYPE,
            )
        except ModelError as err:
            if mode == "central":
                raise
            log.info("central precision failed (%s): the 2-hop sub-network σ instead", err)
        else:
            comm = out.precision.comm
            red_msg, red_bytes = out.reduction_cost(kept.n_anchors)
            return DistributedSigma(
                np.where(kept.free, out.std(a_posteriori=True), 0.0),
                out.covariance(a_posteriori=True),
                "central",
                red_msg + (0 if comm is None else int(comm.messages)),
                red_bytes + (0 if comm is None else int(comm.bytes)),
            )
    bias = 0.0 if off is None else _bias(kept, np.asarray(off, float))  # the sub-network σ know no offsets
    sub = kept.with_ranges(kept.range_m - bias) if not np.isscalar(bias) or bias != 0.0 else kept
    nb = neighbourhood_precision(
        sub,
        est,
        exchange=None if exchange is None else exchange(sub),
        objective=objective,
        sigma_m=sigma_m,
        loss=loss,
        loss_scale_m=loss_scale_m,
        hops=PRECISION_HOPS,
        delay_sigma_m=delay_sigma_m,
    )
    comm = nb.precision.comm
    return DistributedSigma(
        np.where(kept.free, nb.std(a_posteriori=True), 0.0),
        nb.covariance(a_posteriori=True),
        nb.precision.kind,
        0 if comm is None else int(comm.messages),
        0 if comm is None else int(comm.bytes),
    )


def _bias(problem: RangingProblem, off: FloatArray) -> FloatArray | float:
    return sample_bias(problem.meas_a, problem.meas_b, off)
