"""The real-data workflow of ``uwb solve`` and ``reproduce uwb-field``, in memory: geometry checks, initial
guess, a graduated robust solve, NLOS exclusion, per-anchor precision and the communication comparison.

1. :func:`prepare`: :func:`~distnav.models.uwb.geometry.check_geometry` on the problem as read; the anchors the
   ranges cannot locate (cut off, non-rigid) are dropped (reported *unsolved*), the rest gets the MDS start
   (:mod:`distnav.models.uwb.initial`) and the planar / mirror checks; a refused geometry raises ModelError.
2. :func:`solve_field`: the solver with the metres objective and a robust loss (default Cauchy at 0.3 m, LM's
   graduated start: linear first, then robust), per-link w-tests and per-anchor precision from the solver
   (:mod:`distnav.algorithms.ranging.qc`), and with ``exclude`` its iterative exclusion of the worst link while
   the network stays determined (:func:`distnav.algorithms.ranging.qc.exclude_links`). With LM in metres the
   robust fit of every link is first run from several starts (:func:`choose_start`: the lowest Cauchy cost of
   all the links wins) and the exclusions start from there; exclusions that leave a solution fitting all the
   links more than :data:`DISAGREE_RATIO` × worse are rejected (``revert``). σ admit the antenna delays the
   model does not estimate (:mod:`distnav.models.uwb.precision`, ``delay_sigma_m``). In metres with the
   Cauchy loss (``FieldOptions.nlos_aware``, the default; LM and every distributed solver but CSG) every fit uses
   the *one-sided* Cauchy loss (NLOS only lengthens a range), its scale is tightened after the choice of start
   (:func:`tighten`), the exclusions and costs work at that scale and the kept links are re-fitted at
   ``loss_scale_m`` at the end (:func:`polish_fit`). The distributed solvers take the same steps through the
   exchange (:mod:`distnav.models.uwb.field_fits`: their warm re-fits are the final distributed LM phase from the
   last solution) but not the multi-start (LM fits); network totals: the residual scatter that sets the tight
   scale, the costs of all the links (revert, per-anchor check, polish), the link tests' robust scale. Their
   re-fits after an exclusion stop early and choose the next links only where the choice is decided with a
   margin (``field_fits.REFIT_STAGES``); the last tightening fit opens the loop as such a re-fit, and where the
   polish follows, the loop ends on its decided early-stopped re-fit, else on one full fit (``TIGHTEN_OPENS_LOOP``,
   ``LOOP_ENDS_LOOSE``); every warm fit starts from the last fit's common offset and damping
   (``field_fits.CARRY_OFFSET``, ``CARRY_DAMPING``; issue 27, docs/economy_uwb.md).
3. :func:`gather_cost`: what gathering every range at one anchor over the same graph would cost instead.

The solve call goes to :func:`distnav.algorithms.ranging.csg.solve` by name, with ``objective`` passed when the solver
takes it (the metres objective of issue 13; until then the paper's squared form) — ``objective_used`` says which.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from distnav.algorithms.ranging.stop import StopRule
from distnav.algorithms.ranging.wire import comm_phases
from distnav.errors import ModelError
from distnav.models.uwb import field_fits, field_steps
from distnav.models.uwb.communication import RANGE_RECORD_BYTES, gather_cost
from distnav.models.uwb.cuts import cut_weak
from distnav.models.uwb.field_fits import TIGHT_SCALE_FLOOR_M, refit_margin_w, solve_once, tighten_scale
from distnav.models.uwb.field_options import (
    DELAY_SIGMA_M,
    FieldOptions,
    solver_kwargs,
    subset_measurements,
    supports_objective,
)
from distnav.models.uwb.field_precision import PRECISION_HOPS, PRECISION_MODES, AnchorPrecision, anchor_precision
from distnav.models.uwb.field_run import FieldFit, FieldRun, complete, ends_loose, no_worse
from distnav.models.uwb.field_steps import (
    DISAGREE_RATIO,
    MULTI_START_MAX_ANCHORS,
    POLISH_BAND,
    POLISH_RATIO,
    REFERENCE_BAND,
    START_TOLERANCES,
    all_links_cost,
    choose_start,
    exclude_worst,
    fine_margin_w,
    kept_tests,
    make_fitter,
    offset_bias_m,
    polish_fit,
    prepare,
    stage_name,
    tighten,
)
from distnav.models.uwb.geometry import GeometryReport, check_geometry
from distnav.models.uwb.local import repair_exclusions
from distnav.models.uwb.problems import RangingProblem
from distnav.models.uwb.reliability import (
    RELIABILITY_LIMIT_M,
    WEAK_RMS_M,
    ReliabilityOptions,
    check_reliability,
    undetected_nlos_covariance,
    weak_anchor_reasons,
    weak_anchors,
    with_covariance,
)
from distnav.typing import BoolArray, FloatArray

__all__ = [
    "FieldOptions",
    "FieldSolution",
    "prepare",
    "solve_field",
    "gather_cost",
    "RANGE_RECORD_BYTES",
    "supports_objective",
    "subset_measurements",
    "anchor_precision",
    "AnchorPrecision",
    "TIGHT_SCALE_FLOOR_M",
    "RELIABILITY_LIMIT_M",
    "weak_anchors",
    "PRECISION_HOPS",
    "DELAY_SIGMA_M",
    "solver_kwargs",
    # the steps (distnav.models.uwb.field_steps), re-exported where callers have always found them
    "DISAGREE_RATIO",
    "MULTI_START_MAX_ANCHORS",
    "START_TOLERANCES",
    "all_links_cost",
    "choose_start",
    "offset_bias_m",
    "tighten",
]

_solver_kwargs = solver_kwargs  # the old private name (tests)


@dataclass(frozen=True, eq=False)
class FieldSolution:
    """Everything ``uwb solve`` writes. Arrays over ``problem``'s anchors / measurements (the solvable part);
    ``geometry.unsolved`` names the anchors left out. ``w`` / ``flagged`` / ``excluded`` per measurement (``w``
    NaN where the solver gave no test); ``sigma_m`` per anchor and axis (a-posteriori; NaN where unknown)."""

    problem: RangingProblem
    geometry: GeometryReport
    positions_m: FloatArray
    sigma_m: FloatArray
    residual_m: FloatArray
    w: FloatArray
    flagged: BoolArray
    excluded: BoolArray
    result: Any
    status: str
    message: str
    objective_used: str
    iterations: int
    messages: int
    bytes: int
    critical_value: float | None
    weak: tuple[str, ...] = ()
    weak_reasons: dict[str, str] = field(default_factory=dict)  # why each weak anchor is weak (positions.csv)
    reliability: dict[str, Any] = field(default_factory=dict)  # external reliability (summary.json; reliability.py)
    covariance_m2: FloatArray | None = None  # per-anchor blocks (a-posteriori) whose diagonal gives sigma_m
    precision_kind: str | None = None  # Precision.kind of sigma_m ("centralized", "neighbourhood", …)
    precision_messages: int = 0  # of messages / bytes: those of the precision (distributed solvers)
    precision_bytes: int = 0
    mirror: dict[str, Any] | None = None  # the mirror test (mirror.py), where the known anchors are nearly collinear
    mirror_positions_m: FloatArray | None = None  # the other side's map, when the mirror test cannot choose
    comm_phases: dict[str, dict[str, int]] = field(default_factory=dict)  # messages / bytes per phase (issue 27)

    @property
    def usable(self) -> bool:
        return self.status != "diverged"


def solve_field(
    problem: RangingProblem,
    options: FieldOptions | None = None,
    *,
    geometry: GeometryReport | None = None,
    exchange: Callable[[RangingProblem], Any] | None = None,
) -> FieldSolution:
    """Solve a prepared problem (from :func:`prepare`) with QC; see the module docstring. The steps: the start and
    the tightened scale (:func:`_seed`), the exclusions (:func:`_exclusions`), their check against the robust fit of
    every link and the polish (:func:`_revert_and_polish`), precision and reliability (:func:`_precision_and_reasons`),
    the status and message (:func:`_solution`)."""
    run = _start_run(problem, options, exchange)
    _seed(run)
    fit = _exclusions(run)
    _revert_and_polish(run, fit)
    geo = geometry if geometry is not None else check_geometry(problem)
    if not fit.res.usable or not np.all(np.isfinite(fit.res.estimates)):
        return _diverged(run, fit, geo)
    return _solution(run, fit, geo)


def _start_run(
    problem: RangingProblem, options: FieldOptions | None, exchange: Callable[[RangingProblem], Any] | None
) -> FieldRun:
    opts = options or FieldOptions()
    if problem.initial_m is None:
        raise ModelError("solve_field needs a prepared problem with an initial guess (see prepare)")
    if opts.distributed_precision not in PRECISION_MODES:
        raise ModelError(
            f"distributed_precision must be one of {', '.join(PRECISION_MODES)}, got {opts.distributed_precision!r}"
        )
    objective = opts.objective if supports_objective(opts.solver) else "squared"
    note = "" if objective == opts.objective else f" ({opts.solver} has no {opts.objective} objective: squared used)"
    total: list[int] = [0, 0, 0]
    starts: list[FloatArray] = []
    carry: dict[str, Any] = {}
    fit_any = make_fitter(opts, exchange, total, starts, carry=carry)
    return FieldRun(problem, opts, opts, exchange, objective, note, fit_any, [], total, starts, carry=carry)


def _seed(run: FieldRun) -> None:
    """The start of the exclusions: LM's multi-start (metres), then with ``nlos_aware`` the first robust fit
    (distributed solvers) and the tightened one-sided loss scale, which every later fit and cost uses."""
    problem, opts, given = run.problem, run.opts, run.given
    best: FloatArray | None = None
    if (
        opts.multi_start
        and opts.solver.upper() == "LM"
        and run.objective == "metres"
        and problem.n_anchors <= MULTI_START_MAX_ANCHORS
    ):
        best, start_note = choose_start(problem, opts)
        if best is not None:
            run.starts.append(best)  # the first fit starts there, with the robust loss straight away
            run.note += start_note
    if not opts.nlos_aware:
        return
    opens: list[Any] | None = [] if field_fits.opens_loop(opts.solver, opts.exclude, given.staged_tolerances) else None
    if best is None:  # the distributed solvers (and LM without multi-start): the first robust fit, graduated
        first_fit = solve_once(
            problem,
            opts.solver,
            {**solver_kwargs(opts), "quality": opens is not None},  # it opens the loop where nothing is tightened
            opts.iterations,
            exchange=run.exchange,
            total=run.total,
            start="first",
            stage=stage_name(given, "seed"),
            carry=run.carry,
        )
        best = np.asarray(first_fit.estimates, float) if first_fit.usable else None
        opens = None if opens is None else [first_fit]
        run.mark("first_fit")
    if best is None or not np.all(np.isfinite(best)):
        return
    best, tight, _ = tighten_scale(
        problem,
        best,
        opts.solver,
        solver_kwargs(opts),
        opts.loss_scale_m,
        opts.iterations,
        field_fits.TightenShared(
            exchange=run.exchange, total=run.total, stage=stage_name(given, "seed"), carry=run.carry, results=opens
        ),
    )
    run.starts.append(best)
    run.mark("tighten")
    run.opening = field_fits.opening_fit(opens)
    run.opts = dataclasses.replace(opts, loss_scale_m=tight)
    run.fit_any = make_fitter(run.opts, run.exchange, run.total, run.starts, carry=run.carry)
    if opts.solver.upper() != "LM" and given.staged_tolerances:  # the exclusion loop's re-fits stop early
        run.loose = [
            (
                make_fitter(run.opts, run.exchange, run.total, run.starts, stage, run.carry),
                refit_margin_w(stage, opts.sigma_m),
            )
            for stage in field_fits.REFIT_STAGES  # read at run time (the benchmark's configurations)
        ]
        rung = field_steps.FINE_RUNG_FTOL_XTOL_M  # read at run time, as the switches above
        if rung is not None and run.loose:  # item 51: a 1 mm rung before the full fit
            fine = StopRule(refine_ftol=rung[0], refine_xtol_m=rung[1])
            fit_fine = make_fitter(run.opts, run.exchange, run.total, run.starts, carry=run.carry, stop=fine)
            run.loose.append((fit_fine, fine_margin_w(rung, opts.sigma_m)))
    run.note += (
        f"; one-sided Cauchy loss (ranges read long), scale tightened to {tight:.3g} m"
        if tight < given.loss_scale_m
        else "; one-sided Cauchy loss (ranges read long)"
    )


def _exclusions(run: FieldRun) -> FieldFit:
    """The exclusions tested at the robust solution (an NLOS link does not drag it; every re-fit robust too), and
    with ``repair`` the per-anchor check (:func:`_repair`); without ``exclude`` one fit of every link."""
    problem, opts = run.problem, run.opts
    if run.opening is not None and run.loose:  # the robust fit of every link: the opening (reference_ratio)
        run.no_exclusion.append(run.opening)
    else:
        run.opening = None
    confirm = not ends_loose(run)
    first = exclude_worst(problem, run.fit, opts, run.loose, run.opening, confirm) if opts.exclude else None
    if first is None:
        res = run.fit(problem)
        none = np.zeros(problem.n_meas, bool)
        if res.tests is not None and res.usable:
            fit = FieldFit(res, none, res.tests.w, res.tests.flagged, res.tests.critical_value)
        else:
            fit = FieldFit(res, none, np.full(problem.n_meas, np.nan), none.copy(), None)
        if opts.exclude and res.usable:
            run.note += f"; {opts.solver}: no per-link tests (or they failed on a re-fit): no link excluded"
            fit.untested = opts.solver.upper() == "LM"
    else:
        res, tests = first
        excluded = np.zeros(problem.n_meas, bool)
        excluded[list(tests.removed)] = True
        fit = FieldFit(
            res, excluded, tests.w, tests.flagged, float(tests.critical_value), loose=res is not run.last_full
        )
        tried: list[np.ndarray] = []  # the kept-link masks the check re-solved (REPAIR_SKIPS_REPEAT)
        for _ in range(2 if opts.repair else 0):
            if not fit.res.usable or not _repair(run, fit, tried):
                break
    if fit.crit is not None:
        fit.crit = float(fit.crit)
    run.mark("exclusions")
    return fit


def _repair(run: FieldRun, fit: FieldFit, tried: list[np.ndarray]) -> bool:
    """One round of the per-anchor check (:func:`~distnav.models.uwb.local.repair_exclusions`): re-fit without the
    links each anchor chose, test and exclude again; ``fit`` updated where the re-fit fits all the ranges no worse
    (:func:`~distnav.models.uwb.field_run.no_worse`). False when there is nothing more to do. Where the loop ended
    on an early-stopped re-fit (``field_fits.LOOP_ENDS_LOOSE``) the anchors choose at its solution: their
    thresholds (an RMS of 0.15 m, a factor 2) are far from a 1 cm step (on PLANT_HARD ``[34, 0..10]``, 19 checks:
    the same choice as at the completed fit). Its re-solve opens with the loop's first early-stopped rung from the
    current solution (``field_steps.REPAIR_OPENS_LOOSE``, ``REPAIR_STARTS_MOVED``; issue 27 items 47 and 50): the
    re-solve's tests only choose links, with that rung's margin, as the loop's re-fits do. ``tried``: the choices
    re-solved in earlier rounds; the same choice again is not re-solved (``field_steps.REPAIR_SKIPS_REPEAT``)."""
    problem, opts = run.problem, run.opts
    repaired, notes, moved = repair_exclusions(
        problem, np.asarray(fit.res.estimates, float), fit.excluded, fit.flagged, one_sided=opts.one_sided
    )
    if not notes:
        return False
    if field_steps.REPAIR_SKIPS_REPEAT and any(np.array_equal(repaired, t) for t in tried):
        run.note += "; per-anchor check: the same choice as its last round, not re-solved"
        return False
    tried.append(repaired.copy())
    kept_idx = np.flatnonzero(~repaired)
    seed = np.asarray(fit.res.estimates, float).copy()
    for k, at in moved.items() if field_steps.REPAIR_STARTS_MOVED else ():  # item 50: from the current solution
        seed[k] = at
    run.starts.append(seed)
    sub = subset_measurements(problem, ~repaired)
    opening = None
    if field_steps.REPAIR_OPENS_LOOSE and run.loose:  # item 47: the first rung (guarded as exclude_worst's fits)
        try:
            opening = run.loose[0][0](sub)
        except ModelError:
            opening = None
    if opening is not None and (opening.tests is None or not opening.usable):
        opening = None  # no tests to decide on: the loop opens with a full fit, as before
    again = exclude_worst(sub, run.fit, opts, run.loose, opening, not ends_loose(run))
    if again is None:
        run.note += "; per-anchor check: its re-fit gave no link tests, kept the first choice"
        return False
    res2, t2 = again
    if not res2.usable:
        return True
    new = FieldFit(
        res2, repaired.copy(), *kept_tests(problem.n_meas, ~repaired, t2), fit.crit, loose=res2 is not run.last_full
    )
    new.excluded[kept_idx[list(t2.removed)]] = True
    if not no_worse(run, new, fit):
        run.note += "; per-anchor check: its re-solve fitted all the ranges worse, kept the first choice"
        return False
    fit.res, fit.excluded, fit.loose, fit.w, fit.flagged = new.res, new.excluded, new.loose, new.w, new.flagged
    run.note += "; per-anchor check: " + "; ".join(notes)
    return True


def _revert_and_polish(run: FieldRun, fit: FieldFit) -> None:
    """Exclusions that raised the robust cost of all the data more than :data:`DISAGREE_RATIO` are rejected
    (``revert``); with ``nlos_aware`` and ``polish`` the kept links are re-fitted at the given loss scale where that
    fits all the links no worse than :data:`POLISH_RATIO`."""
    opts, given, first = run.opts, run.given, run.no_exclusion
    if fit.excluded.any() and first and first[0].usable and fit.res.usable and opts.revert:
        worse = run.reference_ratio(fit.res)
        if fit.loose and worse > DISAGREE_RATIO / REFERENCE_BAND:
            worse = run.reference_ratio(complete(run, fit).res)
        if worse > DISAGREE_RATIO:  # the exclusions raised the robust cost of all the data: rejected
            fit.reverted, fit.loose = worse, False
            fit.res = first[0]
            fit.excluded = np.zeros(run.problem.n_meas, bool)
            if fit.res.tests is not None:
                fit.w, fit.flagged = fit.res.tests.w, fit.res.tests.flagged
    fit.fit_scale_m = opts.loss_scale_m  # the final fit's: its w-tests, the reliability's weights, σ's variance factor
    if given.nlos_aware and given.polish and fit.res.usable and opts.loss_scale_m < given.loss_scale_m:
        polished, w2, f2 = polish_fit(
            run.problem, fit.res, fit.excluded, fit.w, fit.flagged, given, run.exchange, run.total, run.carry
        )
        ratio = run.cost_ratio(polished, fit.res)
        if fit.loose and ratio > POLISH_RATIO / POLISH_BAND:  # near the threshold: against the full fit
            ratio = run.cost_ratio(polished, complete(run, fit).res)
        if ratio <= POLISH_RATIO:
            fit.res, fit.w, fit.flagged, fit.fit_scale_m, fit.loose = polished, w2, f2, given.loss_scale_m, False
    complete(run, fit)


def _diverged(run: FieldRun, fit: FieldFit, geo: GeometryReport) -> FieldSolution:
    problem = run.problem
    nan_pos = np.full((problem.n_anchors, problem.dim), np.nan)
    return FieldSolution(
        problem=problem,
        geometry=geo,
        positions_m=nan_pos,
        sigma_m=nan_pos.copy(),
        residual_m=np.full(problem.n_meas, np.nan),
        w=fit.w,
        flagged=fit.flagged,
        excluded=fit.excluded,
        result=fit.res,
        status="diverged",
        message=f"diverged: {fit.res.message} (no positions are reported)",
        objective_used=run.objective,
        iterations=run.total[0],
        messages=run.total[1],
        bytes=run.total[2],
        critical_value=fit.crit,
    )


def _precision_and_reasons(
    run: FieldRun, fit: FieldFit, residual: FloatArray
) -> tuple[AnchorPrecision, dict[str, str], dict[str, Any]]:
    """Every anchor's σ (:func:`anchor_precision`), then why an anchor is weak: its misfit, its reliability
    (every solver, metres), a cut the exclusions made, an untested exclusion loop, exclusions the robust fit of
    every link disagrees with. Returns the precision, the reasons per anchor id and the reliability summary."""
    problem, opts, res = run.problem, run.opts, fit.res
    prec = anchor_precision(problem, res, opts, fit.excluded, run.objective, run.exchange, fit_scale_m=fit.fit_scale_m)
    run.mark("polish")
    run.total[1] += prec.messages
    run.total[2] += prec.bytes
    run.mark("precision")
    run.note += prec.note
    reasons = weak_anchor_reasons(problem, residual, fit.excluded, fit.flagged)
    reliability: dict[str, Any] = {"tested": False}
    numbers = None
    if opts.reliability_limit_m > 0 and run.objective == "metres":  # every solver (reliability.check_reliability)
        kept = subset_measurements(problem, ~fit.excluded)
        rel_weak, reliability, rel_note, numbers = check_reliability(
            kept,
            res,
            prec.sigma_m,
            ReliabilityOptions(
                opts.sigma_m,
                opts.offsets_used,
                solver_kwargs(opts).get("loss", "linear"),
                fit.fit_scale_m,
                opts.level,
                opts.offset_prior_sigma_m,
            ),
            limit_m=opts.reliability_limit_m,
            exchange=None if run.exchange is None else run.exchange(kept),
            gathered=prec.kind == "gathered",
        )
        reasons.update({k: v for k, v in rel_weak.items() if k not in reasons})
        run.note += rel_note
        run.total[1] += int(reliability.get("messages", 0))  # the anchors' reliability rounds (distributed solvers)
        run.total[2] += int(reliability.get("bytes", 0))
        run.mark("reliability")
    if opts.cut_test:  # a group of anchors the exclusions cut off: placed by fewer checks than they took (cuts.py)
        reasons.update({k: v for k, v in cut_weak(problem, fit.excluded).items() if k not in reasons})
    if numbers is not None and getattr(res, "x", None) is not None:  # LM: σ admits the NLOS links left in (issue 28)
        weak = np.isin(np.array(problem.ids), list(reasons))
        kept = subset_measurements(problem, ~fit.excluded)
        nlos = undetected_nlos_covariance(kept, numbers, -residual[fit.excluded], weak)
        prec = dataclasses.replace(prec, **with_covariance(prec.sigma_m, prec.covariance_m2, nlos))
    return prec, _whole_map_doubts(run, fit, reasons), reliability


def _whole_map_doubts(run: FieldRun, fit: FieldFit, reasons: dict[str, str]) -> dict[str, str]:
    """Every anchor weak where nothing was tested (a wrong answer would look right: docs/uwb.md, stress test) or
    where the exclusions and the robust fit of every link disagree (trust neither)."""
    every = [run.problem.ids[i] for i in np.flatnonzero(run.problem.estimated)]
    if fit.untested:
        reasons = dict.fromkeys(every, "untested: LM's normal matrix was singular in the exclusion loop")
        run.note += (
            "; LM's normal matrix was singular in the exclusion loop (no link tests, no exclusions): the "
            "positions are not determined there (a fold or a flexible part) — every anchor reported weak"
        )
    first = run.no_exclusion
    if not fit.reverted and fit.excluded.any() and first and first[0].usable:
        ratio = run.reference_ratio(fit.res)
        fit.reverted = ratio if ratio > DISAGREE_RATIO else 0.0
    if fit.reverted:
        reasons = dict.fromkeys(every, "disagree: the exclusions and the robust fit of every link disagree")
        run.note += (
            f"; the solution after the exclusions fitted all the ranges {fit.reverted:.2f} × worse (Cauchy cost) "
            "than the robust fit of every link: a folded start or a swamped exclusion — "
            + (
                "the exclusions were rejected (the robust fit of every link is reported, its flagged links "
                "named, none excluded) and "
                if run.opts.revert
                else ""
            )
            + "every anchor reported weak"
        )
    return reasons


def _solution(run: FieldRun, fit: FieldFit, geo: GeometryReport) -> FieldSolution:
    """Precision, the weak anchors and their reasons, the status and the message of a usable solution."""
    problem, res = run.problem, fit.res
    pos = np.asarray(res.estimates, float)
    residual = problem.residuals_m(pos) + offset_bias_m(problem, res)  # with the solution's offsets
    prec, reasons, reliability = _precision_and_reasons(run, fit, residual)
    weak = tuple(k for k in problem.ids if k in reasons)
    status = geo.status or (
        "weakly_determined" if weak and res.status in ("converged", "max_iterations") else res.status
    )
    msg = res.message + run.note
    if weak:
        msg = (
            f"weakly determined: anchors {', '.join(repr(k) for k in weak[:12])} still misfit their kept links "
            f"by more than {WEAK_RMS_M} m RMS (or 3 × the network's robust residual scale) after the "
            f"exclusions (too few consistent links to tell which are NLOS), keep at most one redundant link "
            f"(one NLOS link there would move them unseen), one link's undetectable bias would move them more "
            f"than {run.opts.reliability_limit_m:g} m and 3σ (external reliability), or they belong to a part placed "
            f"by fewer redundant links than the exclusions took off its cut (reasons in positions.csv) — {msg}"
        )
    if geo.status is not None:
        msg = f"{geo.status}: " + "; ".join(i.message for i in geo.issues if i.severity != "unsolved") + f" — {msg}"
    return FieldSolution(
        problem=problem,
        geometry=geo,
        positions_m=pos,
        sigma_m=prec.sigma_m,
        residual_m=residual,
        w=fit.w,
        flagged=fit.flagged,
        excluded=fit.excluded,
        result=res,
        status=status,
        message=msg,
        objective_used=run.objective,
        iterations=run.total[0],
        messages=run.total[1],
        bytes=run.total[2],
        critical_value=fit.crit,
        weak=weak,
        weak_reasons={k: reasons[k] for k in weak},
        reliability=reliability,
        covariance_m2=prec.covariance_m2,
        precision_kind=prec.kind,
        precision_messages=prec.messages,
        precision_bytes=prec.bytes,
        comm_phases=comm_phases(run.marks),
    )
