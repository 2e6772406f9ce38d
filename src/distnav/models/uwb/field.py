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
   ``loss_scale_m`` at the end (:func:`_polish`). The distributed solvers take the same steps through the
   exchange (:mod:`distnav.models.uwb.field_fits`: their warm re-fits are the final distributed LM phase from the
   last solution) but not the multi-start (LM fits); network totals: the residual scatter that sets the tight
   scale, the costs of all the links (revert, per-anchor check, polish), the link tests' robust scale.
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

from distnav._blas import single_threaded_blas
from distnav.algorithms.ranging import csg
from distnav.algorithms.ranging.neighbourhood_offsets import sample_bias
from distnav.algorithms.ranging.qc import exclude_links
from distnav.algorithms.ranging.wire import comm_phases
from distnav.errors import ModelError
from distnav.models.uwb.communication import RANGE_RECORD_BYTES, gather_cost
from distnav.models.uwb.cuts import cut_weak
from distnav.models.uwb.field_fits import TIGHT_SCALE_FLOOR_M, solve_once, tighten_scale
from distnav.models.uwb.field_options import (
    DELAY_SIGMA_M,
    FieldOptions,
    solver_kwargs,
    subset_measurements,
    supports_objective,
)
from distnav.models.uwb.field_precision import PRECISION_HOPS, PRECISION_MODES, AnchorPrecision, anchor_precision
from distnav.models.uwb.geometry import GeometryReport, check_geometry
from distnav.models.uwb.initial import candidate_starts, mds_initial_guess
from distnav.models.uwb.local import repair_exclusions
from distnav.models.uwb.problems import RangingProblem
from distnav.models.uwb.reliability import (
    RELIABILITY_LIMIT_M,
    WEAK_RMS_M,
    ReliabilityOptions,
    check_reliability,
    weak_anchor_reasons,
    weak_anchors,
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
]

_solver_kwargs = solver_kwargs  # the old private name (tests)

DISAGREE_RATIO = 1.5  # on 24 simulated halls: ≤ 1.37 where the exclusions were right, 1.80 on the folded one
START_TOLERANCES = {"ftol": 1e-6, "xtol": 1e-6}  # choose_start compares basins; the chosen one is refined
MULTI_START_MAX_ANCHORS = 200  # larger networks: the prepared start only (each extra start is a full LM fit)
SAME_START_M = 0.3  # RMS distance under which two starts are taken to lead to the same basin
POLISH_RATIO = 1.01  # 24 halls: ≤ 1.004 where the polish helped; 1.05 and 1.44 where it pulled a weak anchor back


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


def prepare(
    problem: RangingProblem,
    *,
    initial_m: FloatArray | None = None,
    allow_planar_3d: bool = False,
    rng: np.random.Generator | None = None,
) -> tuple[RangingProblem, GeometryReport]:
    """Geometry checks, the determined part, its initial guess (see the module docstring)."""
    first = check_geometry(problem, allow_planar_3d=allow_planar_3d, rng=rng)
    if not (first.solvable & problem.estimated).any():
        raise ModelError("nothing to solve: " + ("; ".join(first.messages()) or "no estimated anchor"))
    sub = problem.subset(first.solvable)
    if initial_m is not None:
        init = np.asarray(initial_m, float)[first.solvable]
    else:
        with single_threaded_blas():  # dense n × n SVD / products: one BLAS thread is 4× cheaper in CPU on 2 cores
            init = mds_initial_guess(sub)
    sub = sub.with_initial(init)
    second = check_geometry(sub, allow_planar_3d=allow_planar_3d, rng=rng)
    carried = tuple(i for i in first.issues if i.severity == "unsolved")
    report = GeometryReport(
        ids=problem.ids,
        solvable=first.solvable,
        issues=carried + second.issues,
        planarity_known=second.planarity_known,
        planarity_network=second.planarity_network,
        notes=first.notes + second.notes,
        planar_fit_ratio=second.planar_fit_ratio,
    )
    report.raise_if_refused()
    return sub, report


def choose_start(problem: RangingProblem, opts: FieldOptions) -> tuple[FloatArray | None, str]:
    """The robust fit of every link (LM, graduated: linear then the robust loss) from the prepared start and from
    each of :func:`~distnav.models.uwb.initial.candidate_starts`; returns the solution with the lowest objective
    of the fit itself over every link (for the Cauchy loss the order of :func:`all_links_cost`; None if no fit was
    usable) and a note naming the start it came from when that was not
    the prepared one. The exclusions then start from there. Why: on simulated plant-like halls with the known
    anchors in a corner the MDS/SMACOF start can be folded (2 m off) and the first robust fit keeps the fold; the
    careful fit's classical-MDS start, a leave-one-out alignment or one weak anchor mirrored finds a lower cost."""
    kw = solver_kwargs(opts)
    kw["quality"] = False
    kw.update({k: v for k, v in START_TOLERANCES.items() if k not in kw})
    assert problem.initial_m is not None
    best: tuple[float, str, FloatArray] | None = None
    tried: list[FloatArray] = []
    est = problem.estimated
    for name, start in [("prepared", problem.initial_m), *candidate_starts(problem)]:
        if any(np.sqrt(np.mean(np.sum((start[est] - t[est]) ** 2, axis=1))) < SAME_START_M for t in tried):
            continue  # as good as tried: it lands in the same basin
        tried.append(start)
        r = csg.solve(problem.with_initial(start), "LM", iterations=opts.iterations, **kw)
        if not (r.usable and np.all(np.isfinite(r.estimates))):
            continue
        cost = float(r.objective)  # the fit's own (robust) objective over every link
        if best is None or cost < best[0] - 1e-9 * max(1.0, abs(best[0])):
            best = (cost, name, np.asarray(r.estimates, float))
    if best is None:
        return None, ""
    note = (
        ""
        if best[1] == "prepared"
        else (
            f"; multi-start: the {best[1]} start of {len(tried)} gave the lowest "
            f"robust cost of all the links ({best[0]:.4g})"
        )
    )
    return best[2], note


def tighten(problem: RangingProblem, start_m: FloatArray, opts: FieldOptions) -> tuple[FloatArray, float, int]:
    """The one-sided fit of every link (LM here; the distributed solvers: ``field_fits.tighten_scale`` through the
    exchange), its loss scale halved from ``opts.loss_scale_m`` (each LM fit from the last
    solution) down to :data:`TIGHT_SCALE_FLOOR_M` or 3 × the robust scatter of the residuals, whichever is larger.
    Returns ``(positions, final scale, fits)``.

    Why: at 0.3 m the one-sided Cauchy loss lets a folded or swamped solution keep links measured 0.2–0.5 m long
    at little cost; at 3 × the scatter (5 cm on simulated halls) a LOS link that misfits costs what its Gaussian
    likelihood says, an NLOS link little more than a constant. On 6 simulated halls whose robust fit at 0.3 m was
    wrong (2 halls with an anchor 0.9–3.4 m off, a folded plant-like hall at 2.44 m), the tightened one-sided fit
    of every link, no link excluded, came within 1.0–1.4 × the oracle on four (the folded hall 0.35 m, oracle
    0.26 m); the two it did not fix have an anchor with one redundant link and one NLOS link among them."""
    return tighten_scale(problem, start_m, opts.solver, solver_kwargs(opts), opts.loss_scale_m, opts.iterations)


def _stage(opts: FieldOptions, stage: str) -> str | None:
    """The stage tolerances of a distributed fit (:data:`~distnav.models.uwb.field_fits.STAGE_TOLERANCES`), unless
    ``opts.staged_tolerances`` is off (every fit to the solver's own)."""
    return stage if opts.staged_tolerances else None


def _fitter(
    opts: FieldOptions, exchange: Callable[[RangingProblem], Any] | None, comm: list[int], last: list[FloatArray]
) -> Callable[[Any], Any]:
    key = opts.solver.upper()
    kw = solver_kwargs(opts)
    warm_refits = key == "LM" or opts.nlos_aware  # the distributed solvers' re-fits: graduated unless nlos_aware

    def fit(sub: Any) -> Any:
        if last:  # a re-fit after an exclusion starts from the last solution, robust loss straight away
            sub = sub.with_initial(last[-1])
        r = solve_once(
            sub,
            key,
            kw,
            opts.iterations,
            exchange=exchange,
            total=comm,
            warm=bool(last) and warm_refits,
        )
        if r.usable and np.all(np.isfinite(r.estimates)):
            last.append(np.asarray(r.estimates, float))
        return r

    return fit


def offset_bias_m(problem: RangingProblem, res: Any) -> FloatArray | float:
    """What the solution's range offsets add to every modelled range (``b`` common, or ``b_a + b_b`` per anchor;
    0 without offsets): the residual of a link is ``problem.residuals_m(positions) + offset_bias_m(...)``."""
    off = getattr(res, "offsets_m", None)
    return sample_bias(problem.meas_a, problem.meas_b, None if off is None else np.asarray(off, float))


def all_links_cost(problem: RangingProblem, res: Any, opts: FieldOptions) -> float:
    """Σ log(1 + (e/s)²) over *every* link, excluded ones too (e in metres with the solution's range offsets,
    s = ``loss_scale_m``): the Cauchy cost of all the data, the same yardstick for two solutions that excluded
    different links. A per-anchor repair is kept only if it lowers it (it must explain the ranges better, NLOS
    ones included at their bounded cost)."""
    e = problem.residuals_m(np.asarray(res.estimates, float)) + offset_bias_m(problem, res)
    z = (e / opts.loss_scale_m) ** 2
    if opts.nlos_aware:  # one-sided: a range read short costs its square, one read long the Cauchy cost
        return float(np.sum(np.where(e < 0, np.log1p(z), z)))
    return float(np.sum(np.log1p(z)))


def _polish(
    problem: RangingProblem,
    res: Any,
    excluded: BoolArray,
    w: FloatArray,
    flagged: BoolArray,
    opts: FieldOptions,
    exchange: Callable[[RangingProblem], Any] | None = None,
    total: list[int] | None = None,
) -> tuple[Any, FloatArray, BoolArray]:
    """The kept links re-fitted at the given loss scale (one-sided, from the tightened solution), with its tests
    and precision: once the NLOS links are out, the tight scale only down-weights LOS links a little (their σ and
    the positions are those of the usual robust fit). Returns the result, ``w`` and ``flagged`` over every
    measurement; the input ones if the re-fit failed. The caller keeps it only if it raises the one-sided cost of
    all the links at the tight scale by at most :data:`POLISH_RATIO` (a weak anchor pulled back into the basin the
    tight scale left: on 24 halls 1.05 and 1.44 × there, ≤ 1.004 × where the polish helped)."""
    keep = ~np.asarray(excluded, bool)
    r = solve_once(
        subset_measurements(problem, keep).with_initial(np.asarray(res.estimates, float)),
        opts.solver,
        solver_kwargs(opts),
        opts.iterations,
        exchange=exchange,
        total=total,
        warm=True,
    )
    if not (r.usable and np.all(np.isfinite(r.estimates)) and r.tests is not None):
        return res, w, flagged
    w2 = np.full(problem.n_meas, np.nan)
    w2[keep] = r.tests.w
    f2 = np.zeros(problem.n_meas, bool)
    f2[keep] = r.tests.flagged
    return r, w2, f2


def _exclude(problem: RangingProblem, fit: Callable[[Any], Any], opts: FieldOptions) -> tuple[Any, Any] | None:
    """csg's exclusion loop; None when a re-fit returns no tests (e.g. its normal matrix became singular)."""
    try:
        per_round = opts.exclusions_per_round
        if per_round is not None:  # 3 on a 28-anchor plant; grows with the network (1000 anchors: 250 per re-fit)
            per_round = max(per_round, problem.n_anchors // 4)
        res, _, tests = exclude_links(
            problem, fit, max_exclusions=opts.max_exclusions, one_sided=opts.one_sided, per_round=per_round
        )
    except ModelError:
        return None
    return res, tests


def solve_field(
    problem: RangingProblem,
    options: FieldOptions | None = None,
    *,
    geometry: GeometryReport | None = None,
    exchange: Callable[[RangingProblem], Any] | None = None,
) -> FieldSolution:
    """Solve a prepared problem (from :func:`prepare`) with QC; see the module docstring."""
    opts = options or FieldOptions()
    given = opts
    if problem.initial_m is None:
        raise ModelError("solve_field needs a prepared problem with an initial guess (see prepare)")
    if opts.distributed_precision not in PRECISION_MODES:
        raise ModelError(
            f"distributed_precision must be one of {', '.join(PRECISION_MODES)}, got {opts.distributed_precision!r}"
        )
    objective = opts.objective if supports_objective(opts.solver) else "squared"
    note = "" if objective == opts.objective else f" ({opts.solver} has no {opts.objective} objective: squared used)"
    total = [0, 0, 0]
    marks: dict[str, tuple[int, int]] = {}  # phase -> (messages, bytes) at its end: FieldSolution.comm_phases
    starts: list[FloatArray] = []
    fit_any = _fitter(opts, exchange, total, starts)
    no_exclusion: list[Any] = []  # the first robust fit, on every link

    def fit(sub: Any) -> Any:
        r = fit_any(sub)
        if not no_exclusion:
            no_exclusion.append(r)
        return r

    best: FloatArray | None = None
    if (
        opts.multi_start
        and opts.solver.upper() == "LM"
        and objective == "metres"
        and problem.n_anchors <= MULTI_START_MAX_ANCHORS
    ):
        best, start_note = choose_start(problem, opts)
        if best is not None:
            starts.append(best)  # the first fit starts there, with the robust loss straight away
            note += start_note
    if opts.nlos_aware:  # the one-sided loss tightened; every later fit and cost at that scale
        if best is None:  # the distributed solvers (and LM without multi-start): the first robust fit, graduated
            first_fit = solve_once(
                problem,
                opts.solver,
                {**solver_kwargs(opts), "quality": False},
                opts.iterations,
                exchange=exchange,
                total=total,
                first=True,
                stage=_stage(given, "seed"),
            )
            best = np.asarray(first_fit.estimates, float) if first_fit.usable else None
            marks["first_fit"] = (total[1], total[2])
        if best is not None and np.all(np.isfinite(best)):
            best, tight, _ = tighten_scale(
                problem,
                best,
                opts.solver,
                solver_kwargs(opts),
                opts.loss_scale_m,
                opts.iterations,
                exchange=exchange,
                total=total,
                stage=_stage(given, "seed"),
            )
            starts.append(best)
            marks["tighten"] = (total[1], total[2])
            opts = dataclasses.replace(opts, loss_scale_m=tight)
            fit_any = _fitter(opts, exchange, total, starts)
            note += (
                f"; one-sided Cauchy loss (ranges read long), scale tightened to {tight:.3g} m"
                if tight < given.loss_scale_m
                else "; one-sided Cauchy loss (ranges read long)"
            )
    excluded = np.zeros(problem.n_meas, bool)
    untested = False  # LM's exclusion loop got no link tests (a singular normal matrix): no QC, nothing determined
    # exclusions tested at the robust solution (an NLOS link does not drag it); every re-fit robust too
    first = _exclude(problem, fit, opts) if opts.exclude else None
    if first is not None:
        res, tests = first
        excluded[list(tests.removed)] = True
        w, flagged, crit = tests.w, tests.flagged, float(tests.critical_value)
        for _ in range(2 if opts.repair else 0):
            if not res.usable:
                break
            repaired, notes, moved = repair_exclusions(
                problem, np.asarray(res.estimates, float), excluded, flagged, one_sided=opts.one_sided
            )
            if not notes:
                break
            if notes:  # re-fit without the links each anchor chose, then test (and exclude) again
                kept_idx = np.flatnonzero(~repaired)
                seed = np.asarray(res.estimates, float).copy()
                for k, at in moved.items():  # each changed anchor starts where its own links put it
                    seed[k] = at
                starts.append(seed)
                again = _exclude(subset_measurements(problem, ~repaired), fit, opts)
                if again is None:
                    note += "; per-anchor check: its re-fit gave no link tests, kept the first choice"
                    break
                res2, t2 = again
                if res2.usable and all_links_cost(problem, res2, opts) > all_links_cost(problem, res, opts):
                    note += "; per-anchor check: its re-solve fitted all the ranges worse, kept the first choice"
                    break
                if res2.usable:
                    res, excluded = res2, repaired
                    excluded[kept_idx[list(t2.removed)]] = True
                    w = np.full(problem.n_meas, np.nan)
                    w[kept_idx] = t2.w
                    flagged = np.zeros(problem.n_meas, bool)
                    flagged[kept_idx] = t2.flagged
                    note += "; per-anchor check: " + "; ".join(notes)
    else:
        res = fit(problem)
        if res.tests is not None and res.usable:
            w, flagged, crit = res.tests.w, res.tests.flagged, float(res.tests.critical_value)
        else:
            w, flagged, crit = np.full(problem.n_meas, np.nan), np.zeros(problem.n_meas, bool), None
        if opts.exclude and res.usable:
            note += f"; {opts.solver}: no per-link tests (or they failed on a re-fit): no link excluded"
            untested = opts.solver.upper() == "LM"
    marks["exclusions"] = (total[1], total[2])
    reverted = 0.0
    if excluded.any() and no_exclusion and no_exclusion[0].usable and res.usable and opts.revert:
        worse = all_links_cost(problem, res, opts) / max(all_links_cost(problem, no_exclusion[0], opts), 1e-12)
        if worse > DISAGREE_RATIO:  # the exclusions raised the robust cost of all the data: rejected
            reverted = worse
            res = no_exclusion[0]
            excluded = np.zeros(problem.n_meas, bool)
            if res.tests is not None:
                w, flagged = res.tests.w, res.tests.flagged
    fit_scale_m = opts.loss_scale_m  # the loss scale of the final fit (its w-tests, the reliability test's weights,
    # the distributed σ's variance factor as LM's own)
    if given.nlos_aware and given.polish and res.usable and opts.loss_scale_m < given.loss_scale_m:
        polished, w2, f2 = _polish(problem, res, excluded, w, flagged, given, exchange, total)
        ratio = all_links_cost(problem, polished, opts) / max(all_links_cost(problem, res, opts), 1e-12)
        if ratio <= POLISH_RATIO:
            res, w, flagged, fit_scale_m = polished, w2, f2, given.loss_scale_m
    geo = geometry if geometry is not None else check_geometry(problem)
    nan_pos = np.full((problem.n_anchors, problem.dim), np.nan)
    if not res.usable or not np.all(np.isfinite(res.estimates)):
        return FieldSolution(
            problem=problem,
            geometry=geo,
            positions_m=nan_pos,
            sigma_m=nan_pos.copy(),
            residual_m=np.full(problem.n_meas, np.nan),
            w=w,
            flagged=flagged,
            excluded=excluded,
            result=res,
            status="diverged",
            message=f"diverged: {res.message} (no positions are reported)",
            objective_used=objective,
            iterations=total[0],
            messages=total[1],
            bytes=total[2],
            critical_value=crit,
        )
    pos = np.asarray(res.estimates, float)
    prec_out = anchor_precision(problem, res, opts, excluded, objective, exchange, fit_scale_m=fit_scale_m)
    sigma = prec_out.sigma_m
    marks["polish"] = (total[1], total[2])
    total[1] += prec_out.messages
    total[2] += prec_out.bytes
    marks["precision"] = (total[1], total[2])
    note += prec_out.note
    residual = problem.residuals_m(pos) + offset_bias_m(problem, res)  # with the solution's offsets
    reasons = weak_anchor_reasons(problem, residual, excluded, flagged)
    reliability: dict[str, Any] = {"tested": False}
    if opts.reliability_limit_m > 0 and objective == "metres":  # every solver (reliability.check_reliability)
        kept = subset_measurements(problem, ~excluded)
        rel_weak, reliability, rel_note = check_reliability(
            kept,
            res,
            sigma,
            ReliabilityOptions(
                opts.sigma_m,
                opts.offsets_used,
                solver_kwargs(opts).get("loss", "linear"),
                fit_scale_m,
                opts.level,
                opts.offset_prior_sigma_m,
            ),
            limit_m=opts.reliability_limit_m,
            exchange=None if exchange is None else exchange(kept),
        )
        reasons.update({k: v for k, v in rel_weak.items() if k not in reasons})
        note += rel_note
        total[1] += int(reliability.get("messages", 0))  # the anchors' reliability rounds (distributed solvers)
        total[2] += int(reliability.get("bytes", 0))
        marks["reliability"] = (total[1], total[2])
    if opts.cut_test:  # a group of anchors the exclusions cut off: placed by fewer checks than they took (cuts.py)
        reasons.update({k: v for k, v in cut_weak(problem, excluded).items() if k not in reasons})
    every = [problem.ids[i] for i in np.flatnonzero(problem.estimated)]
    if untested:  # nothing was tested, nothing excluded: a wrong answer would look right (docs/uwb.md, stress test)
        reasons = dict.fromkeys(every, "untested: LM's normal matrix was singular in the exclusion loop")
        note += (
            "; LM's normal matrix was singular in the exclusion loop (no link tests, no exclusions): the "
            "positions are not determined there (a fold or a flexible part) — every anchor reported weak"
        )
    if not reverted and excluded.any() and no_exclusion and no_exclusion[0].usable:
        reverted = all_links_cost(problem, res, opts) / max(all_links_cost(problem, no_exclusion[0], opts), 1e-12)
        reverted = reverted if reverted > DISAGREE_RATIO else 0.0
    if reverted:  # the exclusions and the robust fit of all links disagree: trust neither
        reasons = dict.fromkeys(every, "disagree: the exclusions and the robust fit of every link disagree")
        note += (
            f"; the solution after the exclusions fitted all the ranges {reverted:.2f} × worse (Cauchy cost) "
            "than the robust fit of every link: a folded start or a swamped exclusion — "
            + (
                "the exclusions were rejected (the robust fit of every link is reported, its flagged links "
                "named, none excluded) and "
                if opts.revert
                else ""
            )
            + "every anchor reported weak"
        )
    weak = tuple(k for k in problem.ids if k in reasons)
    status = geo.status or (
        "weakly_determined" if weak and res.status in ("converged", "max_iterations") else res.status
    )
    msg = res.message + note
    if weak:
        msg = (
            f"weakly determined: anchors {', '.join(repr(k) for k in weak[:12])} still misfit their kept links "
            f"by more than {WEAK_RMS_M} m RMS (or 3 × the network's robust residual scale) after the "
            f"exclusions (too few consistent links to tell which are NLOS), keep at most one redundant link "
            f"(one NLOS link there would move them unseen), one link's undetectable bias would move them more "
            f"than {opts.reliability_limit_m:g} m and 3σ (external reliability), or they belong to a part placed "
            f"by fewer redundant links than the exclusions took off its cut (reasons in positions.csv) — {msg}"
        )
    if geo.status is not None:
        msg = f"{geo.status}: " + "; ".join(i.message for i in geo.issues if i.severity != "unsolved") + f" — {msg}"
    return FieldSolution(
        problem=problem,
        geometry=geo,
        positions_m=pos,
        sigma_m=sigma,
        residual_m=residual,
        w=w,
        flagged=flagged,
        excluded=excluded,
        result=res,
        status=status,
        message=msg,
        objective_used=objective,
        iterations=total[0],
        messages=total[1],
        bytes=total[2],
        critical_value=crit,
        weak=weak,
        weak_reasons={k: reasons[k] for k in weak},
        reliability=reliability,
        covariance_m2=prec_out.covariance_m2,
        precision_kind=prec_out.kind,
        precision_messages=prec_out.messages,
        precision_bytes=prec_out.bytes,
        comm_phases=comm_phases(marks),
    )
