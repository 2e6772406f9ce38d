"""The steps of :func:`~distnav.models.uwb.field.solve_field` below the workflow itself: the choice of start
(:func:`choose_start`), the tightened loss scale (:func:`tighten`), a fit by name through the exchange
(:func:`make_fitter`), the robust cost of every link (:func:`all_links_cost`), the exclusion loop
(:func:`exclude_worst`) and the polish of the kept links (:func:`polish_fit`); the module docstring of
:mod:`distnav.models.uwb.field` says how they fit together.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from distnav._blas import single_threaded_blas
from distnav.algorithms.ranging import csg
from distnav.algorithms.ranging.neighbourhood_offsets import sample_bias
from distnav.algorithms.ranging.qc import SCALE_FLOOR, exclude_links
from distnav.algorithms.ranging.stop import StopRule
from distnav.errors import ModelError
from distnav.models.uwb.field_fits import solve_once, tighten_scale
from distnav.models.uwb.field_options import FieldOptions, solver_kwargs, subset_measurements
from distnav.models.uwb.geometry import GeometryReport, check_geometry
from distnav.models.uwb.initial import candidate_starts, mds_initial_guess
from distnav.models.uwb.problems import RangingProblem
from distnav.typing import BoolArray, FloatArray

__all__ = [
    "DISAGREE_RATIO",
    "MULTI_START_MAX_ANCHORS",
    "POLISH_BAND",
    "POLISH_RATIO",
    "REFERENCE_BAND",
    "SAME_START_M",
    "START_TOLERANCES",
    "all_links_cost",
    "choose_start",
    "exclude_worst",
    "kept_tests",
    "make_fitter",
    "offset_bias_m",
    "polish_fit",
    "prepare",
    "stage_name",
    "tighten",
]

DISAGREE_RATIO = 1.5  # on 24 simulated halls: ≤ 1.37 where the exclusions were right, 1.80 on the folded one
START_TOLERANCES = {"ftol": 1e-6, "xtol": 1e-6}  # choose_start compares basins; the chosen one is refined
MULTI_START_MAX_ANCHORS = 200  # larger networks: the prepared start only (each extra start is a full LM fit)
SAME_START_M = 0.3  # RMS distance under which two starts are taken to lead to the same basin
#: the all-links cost ratio to an early-stopped robust fit of every link within this factor of DISAGREE_RATIO (or
#: above) is decided against that fit continued to the solver's tolerances (``field_run.FieldRun.reference_ratio``)
REFERENCE_BAND = 1.25
#: the polish's cost ratio to an early-stopped end of the exclusion loop above POLISH_RATIO / this is decided against
#: that end continued to the solver's tolerances (``field_run.complete``)
POLISH_BAND = 1.002
POLISH_RATIO = 1.01  # 24 halls: ≤ 1.004 where the polish helped; 1.05 and 1.44 where it pulled a weak anchor back
#: the per-anchor check's re-solve opens its exclusion loop with an early-stopped re-fit of the changed links (the
#: loop's first rung, its choice taken where decided with that rung's margin) instead of a fit at the solver's
#: tolerances (issue 27, eighth session, docs/economy_uwb.md item 47); False: a full fit first, as before
REPAIR_OPENS_LOOSE = True
#: the check's re-solve starts from the current solution, the changed anchors where they are (issue 27, eighth session,
#: item 50); True: each changed anchor starts where its own chosen links put it (``local.repair_exclusions``'s
#: positions), as before — 100 PLANT_HARD halls: the same links and status either way, 2.2 % fewer bytes from here
REPAIR_STARTS_MOVED = False
#: the check's second round is not re-solved where its anchors choose exactly the links its first round re-solved
#: (the same mask of kept links): it would re-fit the same sub-network and test the same links again from the first
#: round's answer (issue 27, tenth session, docs/economy_uwb.md item 59: at 1,000 and 3,000 anchors the second round
#: repeated the first's sub-network and ended on the same links). False: that round re-solved, as before
REPAIR_SKIPS_REPEAT = True
#: (ftol, xtol_m) of a last early-stopped rung of the exclusion loop, after ``field_fits.REFIT_STAGES``' and before
#: the fit at the solver's tolerances: a choice the 3 mm rung leaves open goes to a fit of that rung (margin
#: :func:`fine_margin_w`) first (issue 27, eighth session, item 51). None (the default): straight to the full fit.
#: ``(1e-4, 1e-3)``, a 1 mm rung: 100 PLANT_HARD 32.11 -> 31.11 MB, the same links and status, but the plant-like
#: ``[78, 0]`` middle 227.1 -> 247.9 kB (docs/economy_uwb.md item 51: off, the pages' figures unchanged)
FINE_RUNG_FTOL_XTOL_M: tuple[float, float] | None = None


def prepare(
    problem: RangingProblem,
    *,
    initial_m: FloatArray | None = None,
    allow_planar_3d: bool = False,
    rng: np.random.Generator | None = None,
) -> tuple[RangingProblem, GeometryReport]:
    """Geometry checks, the determined part, its initial guess (see :mod:`distnav.models.uwb.field`'s docstring)."""
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


def stage_name(opts: FieldOptions, stage: str) -> str | None:
    """The stage tolerances of a distributed fit (:data:`~distnav.models.uwb.field_fits.STAGE_TOLERANCES`), unless
    ``opts.staged_tolerances`` is off (every fit to the solver's own)."""
    return stage if opts.staged_tolerances else None


def make_fitter(
    opts: FieldOptions,
    exchange: Callable[[RangingProblem], Any] | None,
    comm: list[int],
    last: list[FloatArray],
    stage: str | None = None,
    carry: dict[str, Any] | None = None,
    stop: StopRule | None = None,
) -> Callable[[Any], Any]:
    """A fit by name of a (sub)problem from the last usable solution in ``last`` (appended to it), its messages
    added to ``comm``; ``stage``: a distributed solver's LM phase stops at that stage's tolerances
    (:data:`~distnav.models.uwb.field_fits.STAGE_TOLERANCES`); ``carry``: the common offset handed from fit to fit
    (:func:`~distnav.models.uwb.field_fits.solve_once`); ``stop``: a distributed solver's own StopRule (no stage:
    the :data:`FINE_RUNG_FTOL_XTOL_M`)."""
    key = opts.solver.upper()
    kw = solver_kwargs(opts) if stop is None else {**solver_kwargs(opts), "stop": stop}
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
            start="warm" if last and warm_refits else "cold",
            stage=stage,
            carry=carry,
        )
        if r.usable and np.all(np.isfinite(r.estimates)):
            last.append(np.asarray(r.estimates, float))
        return r

    return fit


def fine_margin_w(rung: tuple[float, float], sigma_m: float) -> float:
    """The |w| margin of a rung ``(ftol, xtol_m)`` such as :data:`FINE_RUNG_FTOL_XTOL_M` (as
    ``field_fits.refit_margin_w``: both ends of a link off by its step tolerance)."""
    return 2.0 * rung[1] / (sigma_m * SCALE_FLOOR)


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


def polish_fit(
    problem: RangingProblem,
    res: Any,
    excluded: BoolArray,
    w: FloatArray,
    flagged: BoolArray,
    opts: FieldOptions,
    exchange: Callable[[RangingProblem], Any] | None = None,
    total: list[int] | None = None,
    carry: dict[str, Any] | None = None,
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
        start="warm",
        carry=carry,
    )
    if not (r.usable and np.all(np.isfinite(r.estimates)) and r.tests is not None):
        return res, w, flagged
    return (r, *kept_tests(problem.n_meas, keep, r.tests))


def kept_tests(n_meas: int, keep: BoolArray, tests: Any) -> tuple[FloatArray, BoolArray]:
    """``w`` and ``flagged`` over every measurement from the tests of a fit of the ``keep`` ones (NaN / False at
    the others)."""
    w = np.full(n_meas, np.nan)
    w[keep] = tests.w
    flagged = np.zeros(n_meas, bool)
    flagged[keep] = tests.flagged
    return w, flagged


def exclude_worst(
    problem: RangingProblem,
    fit: Callable[[Any], Any],
    opts: FieldOptions,
    loose: Sequence[tuple[Callable[[Any], Any], float]] = (),
    opening: Any = None,
    confirm: bool = True,
) -> tuple[Any, Any] | None:
    """csg's exclusion loop; None when a re-fit returns no tests (e.g. its normal matrix became singular).
    ``loose``: the re-fits after an exclusion stop early and decide only with a margin
    (:data:`~distnav.models.uwb.field_fits.REFIT_MARGIN_W`), one ``fit`` at the end
    (:func:`~distnav.algorithms.ranging.qc.exclude_links`); ``opening``: the loop starts from that early-stopped
    fit of ``problem`` (the last tightening fit, :data:`~distnav.models.uwb.field_fits.TIGHTEN_OPENS_LOOP`);
    ``confirm`` False: the loop may end on a decided loose re-fit
    (:data:`~distnav.models.uwb.field_fits.LOOP_ENDS_LOOSE`)."""
    try:
        per_round = opts.exclusions_per_round
        if per_round is not None:  # 3 on a 28-anchor plant; grows with the network (1000 anchors: 250 per re-fit)
            per_round = max(per_round, problem.n_anchors // 4)
        res, _, tests = exclude_links(
            problem,
            fit,
            max_exclusions=opts.max_exclusions,
            one_sided=opts.one_sided,
            per_round=per_round,
            loose=loose,
            opening=opening,
            confirm=confirm,
        )
    except ModelError:
        return None
    return res, tests
