"""Distributed anchor self-localization (paper 002 §3.2–3.4): CSG, N-CSG (+ BLS / TBLS line search), N-CLM.

Every anchor is a node of the measurement graph and talks only to the anchors it ranges with, through the
exchange (:mod:`distnav.exchange`); all arrays below are local to the exchange's block of anchors.

* **CSG** (eqs. (10)–(12), :mod:`~distnav.algorithms.ranging.csg_iterate`): every anchor holds every anchor.
* **N-CSG** (eqs. (14)–(18)), **+ BLS / TBLS** (eqs. (19)–(21)), **N-CLM** (eq. (22)): every anchor holds itself and
  its neighbours (:mod:`distnav.algorithms.ranging.neighbourhood`). Here: the front doors (:func:`solve_csg`,
  :func:`solve_ncsg`, :func:`solve_nclm`, :func:`solve`), which return a
  :class:`~distnav.algorithms.ranging.data.RangingResult` (``"max_iterations"``, or ``"diverged"`` on a blow-up).

Fixed anchors take part (they measure and relay) but their coordinates, and any held coordinate, are never changed.
Range offsets (``range_offsets``, metres objective): :mod:`distnav.algorithms.ranging.neighbourhood_offsets`.
Paper defaults: 500 iterations, ``α = 1e-3``, ``α₀ = 1e-2``, ``β = γ = 1/2``, one consensus round.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any, cast

import numpy as np

from distnav._checks import whole_number
from distnav._settings import resolve_options
from distnav.algorithms.ranging.csg_iterate import _cost_of, _loss_scale, _summarize, iterate_csg
from distnav.algorithms.ranging.data import RangingData, RangingResult
from distnav.algorithms.ranging.line_search_pair import iterate_line_search_pair
from distnav.algorithms.ranging.lm import solve_lm
from distnav.algorithms.ranging.losses import loss_terms
from distnav.algorithms.ranging.neighbourhood import iterate_neighbourhood
from distnav.algorithms.ranging.neighbourhood_offsets import offset_precision, sample_bias
from distnav.algorithms.ranging.neighbourhoods import (
    IterationState,
    exchange_for,
)
from distnav.algorithms.ranging.objective import range_sigma
from distnav.algorithms.ranging.options import CsgOptions, NclmOptions, NcsgOptions, NeighbourhoodOptions, RunOptions
from distnav.algorithms.ranging.qc import distributed_quality
from distnav.algorithms.ranging.refine import MU0, refine_state, rows_for_local_tests
from distnav.algorithms.ranging.stop import StopRule
from distnav.algorithms.ranging.wire import comm_mark, comm_phases, network_marks, reductions_cost
from distnav.algorithms.result import SolverStatus, Trace
from distnav.errors import ModelError
from distnav.exchange import Exchange

__all__ = [
    "PAPER_MODE",
    "SOLVERS",
    "StopRule",
    "CsgOptions",
    "NcsgOptions",
    "NclmOptions",
    "DISTRIBUTED_SOLVERS",
    "IterationState",
    "iterate_csg",
    "iterate_neighbourhood",
    "solve_csg",
    "solve_ncsg",
    "solve_nclm",
    "solve_line_search_pair",
    "solve",
]

SOLVERS = ("LM", "CSG", "N-CSG", "N-CSG-BLS", "N-CSG-TBLS", "N-CLM")
DISTRIBUTED_SOLVERS = SOLVERS[1:]


PAPER_MODE: dict[str, Any] = {"stop": None, "quality": False}
"""Options that make a distributed solver run as in paper 002: a fixed iteration count, no QC."""


# ---------------------------------------------------------------------- run-to-end front doors
@dataclass(frozen=True)
class _Setup:
    """What :func:`_run` reads: a front door's options and its loss (CSG has none: the linear loss, the scale
    0.3 m of the neighbourhood solvers' default for its metres quality control, no graduated phase)."""

    o: RunOptions
    loss: str = "linear"
    loss_scale_m: float = 0.3
    graduated: int = 0

    @staticmethod
    def of(o: RunOptions) -> _Setup:
        if isinstance(o, NeighbourhoodOptions):
            return _Setup(o, o.loss, o.loss_scale_m, o.graduated_iterations())
        return _Setup(o)


class _Watch:
    """The monitoring of one run (see :func:`_run`): the trace's rows, the anchors' gathered estimates, and the
    divergence and stopping tests of the stopping rule against the previous monitored iteration."""

    def __init__(
        self,
        problem: RangingData,
        ex: Exchange,
        cost_of: Callable[[np.ndarray], float],
        seen: dict[int, tuple[np.ndarray, np.ndarray, float, float]] | None,
    ) -> None:
        self.problem, self.ex, self.cost_of, self.seen = problem, ex, cost_of, seen
        truth = problem.truth_m
        self.est = problem.estimated
        self.truth_est = None if truth is None else truth[self.est]
        self.rm: list[float] = []
        self.cost: list[float] = []
        self.pcost: list[float] = []
        self.step: list[float] = []
        self.count = max(int(ex.allreduce(ex.n_local, "sum")), 1)
        self.own: np.ndarray | None = None
        self.prev_local: np.ndarray | None = None
        self.prev_off: np.ndarray | None = None
        self.prev_pcost = float("nan")
        self.centre, self.extent = np.zeros(problem.dim), 1.0
        self.calm = 0

    def skip(self) -> None:
        """An unmonitored iteration: NaN rows."""
        nan = float("nan")
        for rows in (self.rm, self.cost, self.pcost, self.step):
            rows.append(nan)

    def record(self, st: IterationState) -> float:
        """Gather and sum iteration ``st`` (or reuse the monitoring of the same ``own_m``); its global cost."""
        ex, seen = self.ex, self.seen
        hit = seen.get(id(st.own_m)) if seen is not None else None
        if hit is not None and hit[0] is st.own_m:
            own, c, r = hit[1].copy(), hit[2], hit[3]  # a result of its own
        else:
            own, c, r = _summarize(self.problem, ex, st.own_m, self.truth_est, self.est, self.cost_of)
            if seen is not None:
                seen[id(st.own_m)] = (st.own_m, own, c, r)  # st.own_m kept alive: its id stays unique
        self.own = own
        self.rm.append(r)
        self.cost.append(c)
        self.pcost.append(float(ex.allreduce(float(st.partial_cost.sum()), "sum")))
        self.step.append(float(ex.allreduce(float(st.step_size.sum()), "sum")) / self.count)
        if st.iteration == 0:
            self.centre = own.mean(axis=0)
            self.extent = max(float(np.max(np.linalg.norm(own - self.centre, axis=1), initial=0.0)), 1.0)
        return c

    def verdict(self, st: IterationState, stop: StopRule, graduated: int) -> tuple[SolverStatus, str] | None:
        """``("diverged" | "converged", why)`` when the stopping rule ends the run at ``st``, else None."""
        assert self.own is not None
        far = float(np.max(np.linalg.norm(self.own - self.centre, axis=1), initial=0.0))
        if far > stop.divergence_factor * self.extent:
            return "diverged", f"an estimate left the network ({far:.3g} m from its centre)"
        pcost = self.pcost
        if self.prev_local is not None and st.iteration > graduated + 1:  # vs the previous monitored iteration
            local_move = np.linalg.norm(st.own_m - self.prev_local, axis=1)
            if st.offset_m is not None and self.prev_off is not None:  # the offsets must have settled too
                local_move = np.maximum(local_move, np.abs(st.offset_m - self.prev_off))
            moved = float(self.ex.allreduce(float(local_move.max(initial=0.0)), "max"))
            change = abs(pcost[-1] - self.prev_pcost)
            small = change <= stop.ftol * max(abs(pcost[-1]), 1e-9 * abs(pcost[0]), 1e-300) and moved <= stop.xtol_m
            self.calm = self.calm + 1 if small else 0
            if self.calm >= stop.patience:
                return "converged", (
                    f"objective change ≤ {stop.ftol:g} (relative) and steps ≤ {stop.xtol_m:g} m "
                    f"for {stop.patience} checks"
                )
        self.prev_local, self.prev_pcost, self.prev_off = st.own_m, pcost[-1], st.offset_m
        return None


@dataclass
class _Outcome:
    """Where a run ended and what its result says: the last state, the gathered estimates, the status and why,
    the final cost, the settings listed and the bytes of each phase so far."""

    last: IterationState
    own: np.ndarray
    status: SolverStatus
    why: str
    final_cost: float
    settings: dict[str, Any]
    marks: dict[str, tuple[int, int]]

    def note(self, text: str) -> None:
        self.why = (self.why + "; " if self.why else "") + text


def _iterate(
    states: Iterator[IterationState], watch: _Watch, iterations: int, setup: _Setup
) -> tuple[IterationState, SolverStatus, str]:
    """Run the state generator until the stopping rule or the budget: ``(last state, status, why)``."""
    monitor_every, stop = setup.o.monitor_every, setup.o.stop
    last: IterationState | None = None
    status: SolverStatus = "max_iterations"
    why = ""
    with np.errstate(over="ignore", invalid="ignore"):
        for st in states:
            last = st
            k = st.iteration
            if not (k == 0 or k == iterations or (monitor_every and k % monitor_every == 0)):
                watch.skip()
                continue
            c = watch.record(st)
            if not np.isfinite(c):  # the estimates blew up (e.g. a fixed α too large for the geometry)
                status, why = "diverged", "the cost is not finite"
                break
            if stop is None:
                continue
            ended = watch.verdict(st, stop, setup.graduated)
            if ended is not None:
                status, why = ended
                break
    assert last is not None
    return last, status, why


def _start_offset(o: RunOptions, last: IterationState) -> float | None:
    """The common offset every anchor's copy holds when the LM phase starts from the solver's start (no iteration:
    the neighbourhood solvers start every copy at ``initial_offset_m``), else None (refine.OFFSET_START_HELD)."""
    if isinstance(o, NeighbourhoodOptions) and o.range_offsets == "common" and last.iteration == 0:
        return float(o.initial_offset_m or 0.0)
    return None


def _refine_phase(
    problem: RangingData, ex: Exchange, setup: _Setup, sigma: np.ndarray, scale: np.ndarray, out: _Outcome
) -> None:
    """A final LM phase through the exchange (:mod:`distnav.algorithms.ranging.refine`), recorded in ``out``."""
    rule = setup.o.stop or StopRule()
    try:
        refined = refine_state(
            problem,
            ex,
            out.last,
            sigma=sigma,
            scale=scale,
            loss=setup.loss,
            range_offsets=setup.o.range_offsets,
            offset_prior_sigma_m=setup.o.offset_prior_sigma_m,
            ftol=rule.phase_tolerances[0],
            xtol_m=rule.phase_tolerances[1],
            mu0=MU0 if setup.o.refine_mu0 is None else setup.o.refine_mu0,
            held_m=setup.o.refine_held_m,
            forcing=setup.o.refine_forcing,
            offset_start_m=_start_offset(setup.o, out.last),
        )
        if setup.o.quality and setup.o.test_scale == "local":  # a known anchor's own scale (refine, SIT_OUT)
            rows_for_local_tests(problem, ex, refined[1])
    except ModelError as err:  # e.g. a lost message: the refinement needs every link each round
        out.note(f"no distributed LM phase ({err})")
        return
    out.last, ref = refined
    if out.status == "max_iterations":
        out.note(f"the {out.last.iteration} iterations ran out")
    out.own, out.status = ex.gather_nodes(out.last.own_m), cast(SolverStatus, ref.status)
    out.note(
        f"then distributed LM: {ref.status.replace('_', ' ')} after "
        f"{ref.rounds} rounds, {ref.cg_iterations} CG iterations"
    )
    out.marks["refine"] = comm_mark(ex)
    cost = reductions_cost(problem.n_anchors, ref.reduced)
    out.settings = {
        **out.settings,
        "refine": {
            "rounds": ref.rounds,
            "cg_iterations": ref.cg_iterations,
            "reductions": ref.reduced.count,
            "tree_nodes": ref.reduced.tree_nodes,  # 0: every anchor (refine.SIT_OUT: the ones with a free parameter)
            **dict(zip(("reduction_messages", "reduction_bytes"), cost, strict=True)),
            "status": ref.status,
            "mu": ref.mu,
        },
    }


def _run(
    problem: RangingData,
    states: Iterator[IterationState],
    ex: Exchange,
    name: str,
    iterations: int,
    settings: dict[str, Any],
    setup: _Setup,
    seen: dict[int, tuple[np.ndarray, np.ndarray, float, float]] | None = None,
) -> RangingResult:
    """Drive a state generator until the stopping rule or the budget, monitoring every ``monitor_every``-th
    iteration (and the first and last). ``seen``: the monitoring of states whose ``own_m`` another run shares
    (the same array object: :func:`solve_line_search_pair`), filled by the first run and reused by the second.

    Monitoring gathers every anchor's own estimate (``ex.gather_nodes``) and sums the partial costs and steps
    (``ex.allreduce``): network-wide collectives a deployment would not run each iteration. Unmonitored rows of the
    trace are NaN; a blow-up (non-finite cost) is detected at the next monitored iteration and ends the run as
    ``"diverged"`` (estimates NaN). ``monitor_every=0`` monitors the start and the end only. Then the final LM
    phase (:func:`_refine_phase`) and the quality control (:func:`_quality_phase`).
    """
    o = setup.o
    sigma = range_sigma(problem, o.sigma_m)
    cost_of = _cost_of(problem, o.objective, sigma)
    watch = _Watch(problem, ex, cost_of, seen)
    last, status, why = _iterate(states, watch, iterations, setup)
    assert watch.own is not None
    key = "lambda" if name == "N-CLM" else "step_size"
    trace = Trace(
        {
            "rmse_m": np.asarray(watch.rm),
            "cost": np.asarray(watch.cost),
            "partial_cost": np.asarray(watch.pcost),
            key: np.asarray(watch.step),
        }
    )
    scale = _loss_scale(problem, o.objective, setup.loss, setup.loss_scale_m, sigma)
    marks = {"iterations": comm_mark(ex)}  # the bytes of each phase (issue 27): settings["comm_phases"]
    out = _Outcome(last, watch.own, status, why, watch.cost[-1], settings, marks)
    if o.refines and status != "diverged":  # a final LM phase through the exchange (ranging_refine)
        _refine_phase(problem, ex, setup, sigma, scale, out)
        if "refine" in out.marks:
            out.final_cost = cost_of(out.own)
    offsets, offsets_std, objective, precision, tests = _quality_phase(problem, ex, setup, sigma, scale, out)
    out.marks["quality"] = comm_mark(ex)
    tail = f" ({out.why})" if out.why else ""
    status, last, final_cost = out.status, out.last, out.final_cost
    return RangingResult(
        estimates=out.own,
        converged=status == "converged",
        iterations=last.iteration,
        status=status,
        message=f"{name}: {status.replace('_', ' ')} after {last.iteration} iterations{tail}, cost {final_cost:.6g}"
        + (f", RMSE {watch.rm[-1]:.3f} m" if problem.truth_m is not None and status != "diverged" else ""),
        trace=trace,
        comm=ex.comm_totals(),
        solver=name,
        cost=final_cost,
        objective=objective,
        loss=setup.loss,
        settings={**out.settings, "comm_phases": comm_phases(network_marks(ex, out.marks))},
        objective_kind=o.objective,
        precision=precision,
        tests=tests,
        offsets_m=offsets,
        offsets_std_m=offsets_std,
    )


def _quality_phase(
    problem: RangingData, ex: Exchange, setup: _Setup, sigma: np.ndarray, scale: np.ndarray, out: _Outcome
) -> tuple[np.ndarray | None, np.ndarray | None, float, Any, Any]:
    """The offsets and their σ, the robust objective, and (``quality``) the precision and w-tests at the end of a
    run: ``(offsets, offsets_std, objective, precision, tests)``; a diverged run's estimates become NaN."""
    o, last, own = setup.o, out.last, out.own
    offsets = offsets_std = None
    off_args = (o.range_offsets, o.offset_prior_sigma_m, setup.loss, sigma, scale)
    if last.offset_m is not None and out.status != "diverged":
        offsets, offsets_std = offset_precision(problem, ex, last, *off_args, None)
    bias = sample_bias(problem.meas_a, problem.meas_b, offsets)
    with np.errstate(over="ignore", invalid="ignore"):
        res_final = (
            (problem.distances(own) + bias - problem.range_m) / sigma
            if o.objective == "metres"
            else problem.residuals(own)
        )
        if offsets is not None:
            out.final_cost = float(res_final @ res_final)
        objective = (
            out.final_cost if setup.loss == "linear" else float(np.sum(loss_terms(res_final, scale, setup.loss)[1]))
        )
    precision = tests = None
    if out.status == "diverged":
        out.own = np.full_like(own, np.nan)  # never present a blown-up iterate as a result
    elif o.quality and last.half_owner is not None:
        precision, tests = distributed_quality(
            problem,
            ex,
            last,
            sigma,
            scale,
            objective=o.objective,
            loss=setup.loss,
            test_scale=o.test_scale,
            test_level=o.test_level,
        )
        if offsets is not None:
            offsets, offsets_std = offset_precision(problem, ex, last, *off_args, precision.variance_factor)
    return offsets, offsets_std, objective, precision, tests


def solve_csg(
    problem: RangingData,
    *,
    exchange: Exchange | None = None,
    options: CsgOptions | None = None,
    **changes: Any,
) -> RangingResult:
    """CSG (paper 002 eqs. (10)–(12)); trace: ``rmse_m``, ``cost`` (global f at the anchors' own estimates),
    ``partial_cost`` (Σ_i f⁽ⁱ⁾(x⁽ⁱ⁾)), ``step_size``; row 0 is the start.

    ``options``: a :class:`~distnav.algorithms.ranging.options.CsgOptions` (its fields, defaults and units), with
    keyword ``changes`` to it (``solve_csg(p, iterations=200)``; :func:`distnav._settings.resolve_options`).
    ``alpha`` defaults to the paper's 1e-3 (squared; a fixed step that diverges on long links — the run then
    ends ``"diverged"``) and to 0.8 for ``objective="metres"`` (relative to each anchor's information: below the
    stability bound 1 of the Gauss–Newton curvature).
    CSG has no robust loss (Koppanyi's algorithm; the neighbourhood solvers do). ``stop``: the stopping rule
    (:class:`StopRule`; ``None`` runs all ``iterations`` as in the paper). ``quality`` adds the conditional
    per-anchor covariance and the w-tests of every anchor's own links (:mod:`distnav.algorithms.ranging.qc`).
    ``monitor_every = k`` gathers the estimates for the trace (and the stopping and divergence tests) only every
    ``k``-th iteration (NaN rows otherwise; 0: start and end only); see :func:`_run`."""
    o = resolve_options(CsgOptions, options, changes)
    ex = exchange_for(problem, exchange)
    states = iterate_csg(problem, exchange=ex, options=o)
    settings = {"alpha": o.step(), "consensus_rounds": o.consensus_rounds}
    return _run(problem, states, ex, "CSG", o.iterations, settings, _Setup.of(o))


def solve_ncsg(
    problem: RangingData,
    *,
    line_search: str | None = None,
    exchange: Exchange | None = None,
    options: NcsgOptions | None = None,
    **changes: Any,
) -> RangingResult:
    """N-CSG (eqs. (14)–(18)); ``line_search="BLS"`` (eqs. (19)–(20)) or ``"TBLS"`` (eq. (21)).

    ``options``: a :class:`~distnav.algorithms.ranging.options.NcsgOptions` (its fields, defaults and units), with
    keyword ``changes`` to it. Trace, ``stop``, ``quality`` and ``monitor_every`` as :func:`solve_csg`;
    ``step_size`` is the mean ``α`` over anchors (paper 002 Fig. 6). Steps: squared ``alpha = 1e-3``,
    ``alpha0 = 1e-2`` (the paper's), metres ``alpha = 0.8``, ``alpha0 = 2`` (the Armijo test keeps it safe; 4
    oscillates) relative to each anchor's information (see
    :func:`~distnav.algorithms.ranging.neighbourhood.iterate_neighbourhood`). ``graduated``: iterations
    with the linear loss before the robust one (default: a quarter of ``iterations`` for metres with a robust loss,
    else 0). ``range_offsets`` ``"common"`` / ``"per_anchor"`` (metres; prior σ ``offset_prior_sigma_m``):
    range offsets estimated with the positions (:mod:`distnav.algorithms.ranging.neighbourhood_offsets`).
    ``armijo_slope="subgradient"`` (default, the papers README's eq. (19): ``d = −∇f``, "the subgradient") puts
    the subgradient ``G⁽ⁱ⁾ᵀg⁽ⁱ⁾`` of eq. (10) in place of ``∇f⁽ⁱ⁾`` in the Armijo test, i.e. requires
    ``f⁽ⁱ⁾(x + αd) ≤ f⁽ⁱ⁾(x) − γα‖d‖²``; this reproduces the paper's Fig. 6 step sizes (≈1.2e-3 on RC/RM).
    ``"gradient"`` uses the true slope ``∇f⁽ⁱ⁾ᵀd = −2‖d‖²`` of ``f⁽ⁱ⁾ = Σ g²`` (a stricter test: steps ≈ 0.7×).

    Examples
    --------
    >>> import numpy as np
    >>> from distnav.algorithms.ranging.csg import NcsgOptions, solve_ncsg
    >>> from distnav.models.uwb.problems import generate_problem
    >>> p = generate_problem("GC", np.random.default_rng(1), n_anchors=16, dim=2)
    >>> o = NcsgOptions(objective="metres", sigma_m=0.15, iterations=200)
    >>> res = solve_ncsg(p, line_search="TBLS", options=o)
    >>> res.status, res.iterations
    ('converged', 200)
    >>> same = solve_ncsg(p, line_search="TBLS", objective="metres", sigma_m=0.15, iterations=200)
    >>> bool(np.array_equal(res.estimates, same.estimates))
    True
    >>> solve_ncsg(p, alpha=-1.0)
    Traceback (most recent call last):
        ...
    distnav.errors.ModelError: alpha must be positive, got -1.0
    """
    if line_search is None:
        method = "N-CSG"
    elif str(line_search).upper() in ("BLS", "TBLS"):
        method = f"N-CSG-{str(line_search).upper()}"
    else:
        raise ModelError(f"line_search must be None, 'BLS' or 'TBLS', got {line_search!r}")
    o = resolve_options(NcsgOptions, options, changes)
    ex = exchange_for(problem, exchange)
    states = iterate_neighbourhood(problem, method=method, exchange=ex, options=o)
    return _run(problem, states, ex, method, o.iterations, _ncsg_settings(o), _Setup.of(o))


def _ncsg_settings(o: NcsgOptions) -> dict[str, Any]:
    """The settings an N-CSG family result lists."""
    a, a0 = o.steps()
    return {
        "alpha": a,
        "alpha0": a0,
        "beta": o.beta,
        "gamma": o.gamma,
        "consensus_rounds": o.consensus_rounds,
        "armijo_slope": o.armijo_slope,
        "loss": o.loss,
    }


def solve_line_search_pair(
    problem: RangingData,
    *,
    exchanges: tuple[Exchange, Exchange] | None = None,
    options: NcsgOptions | None = None,
    **changes: Any,
) -> tuple[RangingResult, RangingResult]:
    """N-CSG-BLS and N-CSG-TBLS: the results of ``solve_ncsg(problem, line_search="BLS", exchange=exchanges[0],
    options=options, **changes)`` and of ``line_search="TBLS"`` on ``exchanges[1]``, computing the work the two
    runs provably share once (:mod:`distnav.algorithms.ranging.line_search_pair`)."""
    if "line_search" in changes or "exchange" in changes:
        raise ModelError(
            "solve_line_search_pair runs BLS and TBLS: pass exchanges=(bls, tbls), not line_search or exchange"
        )
    o = resolve_options(NcsgOptions, options, changes)
    if o.range_offsets != "none":
        raise ModelError("solve_line_search_pair has no range offsets: run solve_ncsg for BLS and TBLS")
    pair = exchanges or (exchange_for(problem, None), exchange_for(problem, None))
    ex_b, ex_t = exchange_for(problem, pair[0]), exchange_for(problem, pair[1])
    bls_states, tbls_states = iterate_line_search_pair(problem, o, exchanges=(ex_b, ex_t))
    seen: dict[int, tuple[np.ndarray, np.ndarray, float, float]] = {}
    setup, settings, its = _Setup.of(o), _ncsg_settings(o), o.iterations
    res_b = _run(problem, bls_states, ex_b, "N-CSG-BLS", its, settings, setup, seen)
    return res_b, _run(problem, tbls_states, ex_t, "N-CSG-TBLS", its, settings, setup, seen)


def solve_nclm(
    problem: RangingData,
    *,
    exchange: Exchange | None = None,
    options: NclmOptions | None = None,
    **changes: Any,
) -> RangingResult:
    """N-CLM (eq. (22)); ``options`` (a :class:`~distnav.algorithms.ranging.options.NclmOptions`, with keyword
    ``changes`` to it), trace, ``objective``, ``graduated``, ``stop``, ``quality``, ``monitor_every`` and
    ``range_offsets`` as :func:`solve_ncsg`, with the mean ``lambda`` instead of ``step_size``.

    ``damping="fletcher"`` is eq. (22) read literally with eq. (8)'s ``λ diag(G⁽ⁱ⁾ᵀG⁽ⁱ⁾)``. On the partial cost
    this stalls: anchor ``i`` has ``d_i`` ranges but ``(d_i + 1)·dim`` unknowns, and a neighbour's coordinates
    carry the curvature of one range only, so Fletcher's scaling lets every anchor drag each neighbour to fit
    that one range; after mixing the network wanders (10×10 grid, 2-D, noise 0.15 m: RMSE 3.1 m after 300
    iterations, vs 0.26 m for N-CSG-BLS). The default ``"levenberg"`` damps isotropically with
    ``λ_i · mean(diag(G⁽ⁱ⁾ᵀG⁽ⁱ⁾)) · I`` (scale-free like Fletcher's, but equal for own and neighbour
    coordinates), which reaches 0.26 m on the same problem.

    ``lambda_min`` (default 0.1) floors each anchor's ``λ_i``: with ``λ_i → 0`` an anchor's step fits its own,
    underdetermined, ranges exactly and the network drifts when the ranges disagree (one anchor pair 3 m NLOS:
    RMSE 3.15 m with the floor 1e-9, 0.30 m with 0.1 and a Cauchy loss; RM with heights held: 0.78 → 0.51 m).
    """
    o = resolve_options(NclmOptions, options, changes)
    ex = exchange_for(problem, exchange)
    states = iterate_neighbourhood(problem, method="N-CLM", exchange=ex, options=o)
    settings = {"lambda0": o.lambda0, "consensus_rounds": o.consensus_rounds, "damping": o.damping, "loss": o.loss}
    return _run(problem, states, ex, "N-CLM", o.iterations, settings, _Setup.of(o))


def solve(
    problem: RangingData, solver: str, *, iterations: int = 500, exchange: Exchange | None = None, **options: Any
) -> RangingResult:
    """Run one of :data:`SOLVERS` by name with paper defaults (``options`` go to the solver's front door)."""
    iterations = whole_number(iterations, "iterations", error=ModelError)
    key = str(solver).upper()
    if key == "LM":
        return solve_lm(problem, max_iterations=iterations, **options)
    if key == "CSG":
        return solve_csg(problem, iterations=iterations, exchange=exchange, **options)
    if key == "N-CSG":
        return solve_ncsg(problem, iterations=iterations, exchange=exchange, **options)
    if key in ("N-CSG-BLS", "N-CSG-TBLS"):
        return solve_ncsg(
            problem, line_search=key.rsplit("-", 1)[1], iterations=iterations, exchange=exchange, **options
        )
    if key == "N-CLM":
        return solve_nclm(problem, iterations=iterations, exchange=exchange, **options)
    raise ModelError(f"unknown solver {solver!r}; choose one of {', '.join(SOLVERS)}")
