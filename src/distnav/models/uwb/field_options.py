"""The options of ``uwb solve``'s workflow (:func:`distnav.models.uwb.field.solve_field`) and what they resolve to:
the solver front door's keyword arguments and whether it takes the metres objective; split out of
:mod:`distnav.models.uwb.field` (issue 25: modules ≤ 600 lines) with :func:`subset_measurements`."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from distnav._settings import option_names
from distnav.algorithms.ranging import csg
from distnav.algorithms.ranging.lm import LMSolveOptions
from distnav.errors import ModelError
from distnav.models.uwb.problems import RangingProblem
from distnav.models.uwb.reliability import RELIABILITY_LIMIT_M
from distnav.typing import BoolArray

__all__ = ["FieldOptions", "DELAY_SIGMA_M", "supports_objective", "solver_kwargs", "subset_measurements"]

DELAY_SIGMA_M = 0.015  # Monte Carlo over 4 × 100 simulated halls (docs/uwb.md, "Precision")


@dataclass(frozen=True)
class FieldOptions:
    """How :func:`solve_field` solves (defaults: LM, objective in metres, Cauchy loss at 0.3 m, exclusions)."""

    solver: str = "LM"
    objective: str = "metres"
    loss: str = "cauchy"
    loss_scale_m: float = 0.3
    sigma_m: float = 0.1
    iterations: int = 500
    exclude: bool = True
    level: float = 0.001
    max_exclusions: int | None = None
    range_offsets: str = "auto"
    offset_prior_sigma_m: float = 0.1
    allow_planar_3d: bool = False
    repair: bool = True
    one_sided: bool = True
    exclusions_per_round: int | None = 3  # at least; n_anchors // 4 on larger networks
    multi_start: bool = True  # LM with the metres objective: choose_start before the exclusions
    revert: bool = True  # exclusions that raise the all-links robust cost > DISAGREE_RATIO × are rejected
    delay_sigma_m: float = DELAY_SIGMA_M  # antenna delays considered in σ (models/uwb/precision.py); 0: off
    nlos_loss: bool = True  # metres with the Cauchy loss: one-sided ("cauchy_long"), tightened (nlos_aware)
    polish: bool = True  # with nlos_aware: the kept links re-fitted at loss_scale_m at the end (_polish)
    estimate_delays: bool = True  # σ: delay_sigma_m is a floor, larger delays the residuals show are used
    reliability_limit_m: float = RELIABILITY_LIMIT_M  # LM: weak if one undetected link moves it more (reliability.py)
    cut_test: bool = True  # weak: a part whose excluded cut links exceed the cut's redundancy (cuts.py)
    distributed_precision: str = "auto"  # distributed σ: gathered / central / subnetwork / auto (field_precision.py)
    staged_tolerances: bool = True  # distributed fits that seed the next stop early (field_fits.STAGE_TOLERANCES)

    @property
    def considers_delays(self) -> bool:
        """Whether σ admit the per-anchor delays: the metres objective, delays not estimated (``range_offsets``
        none or common), ``delay_sigma_m`` > 0 — LM by :mod:`distnav.models.uwb.precision`, the distributed solvers
        (metres) by :mod:`distnav.models.uwb.field_precision` (central blocks through the exchange, or each
        anchor's 2-hop sub-network)."""
        return (
            self.delay_sigma_m > 0
            and self.objective == "metres"
            and supports_objective(self.solver)
            and self.offsets_used in ("none", "common")
        )

    solver_options: dict[str, Any] = field(default_factory=dict)

    @property
    def nlos_aware(self) -> bool:
        """Whether the solve uses the one-sided loss: ``nlos_loss``, the metres objective, the Cauchy loss and a
        solver that has a robust loss — LM and every distributed solver but CSG (the same steps for all; the
        distributed ones through the exchange, :mod:`distnav.models.uwb.field_fits`).
        Then every fit uses ``"cauchy_long"`` (:func:`distnav.algorithms.ranging.losses.loss_terms`: Cauchy for
        ranges read
        long, linear for ranges read short: NLOS only lengthens a range), and after the choice of start its scale
        is tightened from ``loss_scale_m`` by halves down to :data:`TIGHT_SCALE_FLOOR_M` or 3 × the robust scatter
        of the residuals (:func:`tighten`); the exclusions, the per-anchor check and the revert then work at that
        scale, and :func:`all_links_cost` is the one-sided cost at it."""
        return (
            self.nlos_loss
            and self.solver.upper() != "CSG"
            and self.objective == "metres"
            and self.loss == "cauchy"
            and supports_objective(self.solver)
        )

    @property
    def offsets_used(self) -> str:
        """``range_offsets`` resolved: ``"auto"`` is a common range offset with the metres objective (every solver)
        and none with the squared one. LM: on simulated halls with per-node antenna delays it brings the 2σ
        coverage of LM's σ from 0.72–0.94 to 0.83–0.97 and lowers the RMSE a little. The distributed solvers
        (docs/uwb.md, "Range offsets"): on plant-like halls whose ranges carry a 0.3 m common offset it halves
        their RMSE and removes most false exclusions; without one it costs them 5–10 % RMSE (noisy, 3 halls);
        on the APRIL lab logs it helps N-CLM on both (0.326 → 0.244, 0.342 → 0.253 m, docs/uwb.md)."""
        if self.range_offsets != "auto":
            return self.range_offsets
        return "common" if self.objective == "metres" else "none"


def supports_objective(solver: str) -> bool:
    """Whether the solver front door takes ``objective=`` (the metres objective of issue 13)."""
    key = solver.upper()
    options = (
        LMSolveOptions
        if key == "LM"
        else (csg.CsgOptions if key == "CSG" else csg.NclmOptions if key == "N-CLM" else csg.NcsgOptions)
    )
    return "objective" in option_names(options)


def solver_kwargs(opts: FieldOptions) -> dict[str, Any]:
    """The solver front door's keyword arguments for ``opts`` (loss, objective, σ, offsets, test level)."""
    key = opts.solver.upper()
    kw: dict[str, Any] = dict(opts.solver_options)
    if key != "CSG":
        kw.update(loss="cauchy_long" if opts.nlos_aware else opts.loss, loss_scale_m=opts.loss_scale_m)
    if supports_objective(key):
        kw.update(objective=opts.objective)
        if opts.objective == "metres":
            kw.update(sigma_m=opts.sigma_m)
            if opts.offsets_used != "none":  # LM and every distributed solver (neighbourhood_offsets)
                kw.update(range_offsets=opts.offsets_used, offset_prior_sigma_m=opts.offset_prior_sigma_m)
        kw.update(test_level=opts.level)
    if opts.offsets_used != "none" and opts.objective != "metres":
        raise ModelError(f"range offsets are estimated with the metres objective, not with {opts.objective!r}")
    return kw


def subset_measurements(problem: RangingProblem, keep: BoolArray) -> RangingProblem:
    """The same problem with only the measurements where ``keep`` is True (the oracle drops NLOS links)."""
    k = np.asarray(keep, bool)
    return dataclasses.replace(problem, meas_a=problem.meas_a[k], meas_b=problem.meas_b[k], range_m=problem.range_m[k])
