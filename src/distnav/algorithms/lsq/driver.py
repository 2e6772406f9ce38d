"""Setting up and driving a Fig. 6 run: the options shared by every ADMM front door, written once, and the result.

:class:`AdmmOptions` is the frozen options object of the kernel that :func:`~distnav.algorithms.lsq.admm.iterate_admm`,
:func:`~distnav.algorithms.lsq.admm.admm` and the QC runs accept (``options=`` and/or keyword changes, validated once
when it is built; :class:`AdmmRunOptions` adds :func:`~distnav.algorithms.lsq.admm.admm`'s stopping rule);
:func:`prepare` checks them against the problem and graph and builds the kernel's state generator; :func:`drive`
runs a generator to the stopping rule and returns an :class:`AdmmResult`.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from typing import Any, Literal, Protocol, get_args

import numpy as np

from distnav._checks import check_field_types, real_number, whole_number
from distnav._settings import option_names
from distnav.algorithms.lsq.aggregated import _AggregatedKernel, rounds_on_graph
from distnav.algorithms.lsq.blue import LinearProblem, inestimable_directions, weight_matrix
from distnav.algorithms.lsq.kernel import AdmmState, Multipliers, XUpdate, XUpdateMethod, _Kernel, _per_node
from distnav.algorithms.lsq.xupdate import InLocalOrder, _diagonal_or_none, in_local_order
from distnav.algorithms.result import ObservationTests, Precision, SolverResult, SolverStatus, TraceBuilder
from distnav.errors import ModelError
from distnav.exchange import Exchange, make_exchange
from distnav.network.constraint_nodes import ConstraintNodes, ConstraintNodeSpec, choose_constraint_nodes
from distnav.network.graph import Graph
from distnav.typing import ArrayLike, FloatArray

__all__ = [
    "AdmmOptions",
    "AdmmResult",
    "AdmmRunOptions",
    "ConstraintOptions",
    "MessageMode",
    "PreparedRun",
    "Stopping",
    "StoppingRule",
    "XWeight",
    "drive",
    "prepare",
    "run_options",
]

XWeight = Literal["lagrangian", "fig6", "fig6-zweighted"]
MessageMode = Literal["pairs", "aggregated", "ternary"]
#: Bits per entry of the coded deltas of ``messages="ternary"`` (:mod:`~distnav.algorithms.lsq.delta_codec`).
TERNARY_BITS = 2
X_WEIGHTS: tuple[str, ...] = get_args(XWeight)
THRESHOLDS = (1e-4, 1e-6, 1e-8)


@dataclass(frozen=True, eq=False, kw_only=True)
class ConstraintOptions:
    """The two settings every ADMM options object starts with (default in brackets).

    Fields
    ------
    constraint_nodes : [``"min_cover"``] ``"min_cover"``, ``"all"``, node ids or a
        :class:`~distnav.network.constraint_nodes.ConstraintNodes` (the set ``C``).
    W : [1.0] ``ρ`` or an SPD ``(p, p)`` matrix (checked against ``p`` when the run is set up).
    """

    constraint_nodes: ConstraintNodeSpec = "min_cover"
    W: ArrayLike = 1.0


@dataclass(frozen=True, eq=False, kw_only=True)
class AdmmOptions(ConstraintOptions):
    """Options of the Fig. 6 kernel (paper 000 §4), validated once; taken by
    :func:`~distnav.algorithms.lsq.admm.iterate_admm` as ``options=`` and/or keyword changes (house style:
    :mod:`distnav._settings`): ``constraint_nodes`` and ``W`` of :class:`ConstraintOptions`, and (default in brackets)

    Fields
    ------
    x_update : [``"auto"``] see :class:`~distnav.algorithms.lsq.kernel.XUpdate`.
    x_weight : [``"lagrangian"``] ``"lagrangian"``, ``"fig6"`` or ``"fig6-zweighted"`` (module docstring of
        :mod:`distnav.algorithms.lsq.admm`).
    messages : [``"pairs"``] ``"pairs"``, ``"aggregated"`` or ``"ternary"`` (per-pair messages as 2-bit deltas with
        error feedback after the first, :mod:`~distnav.algorithms.lsq.delta_codec`; no fault schedule).
    init : [``"zero"``] ``"zero"``, a ``(p,)`` vector, an ``(n, p)`` array or a previous
        :class:`~distnav.algorithms.result.SolverResult` (§4.3).
    z0 : [None] ``z_s^[0]`` when it differs from the initial ``x_i^[0]``.
    monitor_every : [1] residuals every that many iterations (0 = never).
    multipliers : [None: ``u^[−1] = 0``] a previous per-pair run's :attr:`AdmmResult.multipliers` (same exchange
        and constraint nodes) to continue from — a warm start of a changed problem (data snooping).
    """

    x_update: XUpdateMethod = "auto"
    x_weight: XWeight = "lagrangian"
    messages: MessageMode = "pairs"
    init: Any = "zero"
    z0: Any = None
    monitor_every: int = 1
    multipliers: Multipliers | None = None

    def __post_init__(self) -> None:
        check_field_types(self, error=ModelError)  # types first, naming the field (issue 29)
        if self.messages not in ("pairs", "aggregated", "ternary"):
            raise ModelError(f"messages must be 'pairs', 'aggregated' or 'ternary', got {self.messages!r}")
        if self.monitor_every < 0:
            raise ModelError(f"monitor_every must be ≥ 0, got {self.monitor_every}")
        if self.x_weight not in X_WEIGHTS:
            raise ModelError(f"x_weight must be {', '.join(repr(w) for w in X_WEIGHTS)}, got {self.x_weight!r}")


@dataclass(frozen=True, eq=False, kw_only=True)
class AdmmRunOptions(AdmmOptions):
    """:class:`AdmmOptions` plus the stopping rule of :func:`~distnav.algorithms.lsq.admm.admm` (default in brackets).

    Fields
    ------
    max_iterations : [1000] at most that many iterations.
    tol : [1e-10] relative tolerance of the residual test (Boyd et al. 2011 §3.3).
    atol : [0.0] absolute tolerance of the residual test, in the units of ``x``.
    stop_at_reference : [None] stop when ``max_i ‖x_i − x̂‖/‖x̂‖`` is at or below it (experiments).
    record_nodes : [True] trace every node's distance to the reference.
    """

    max_iterations: int = 1000
    tol: float = 1e-10
    atol: float = 0.0
    stop_at_reference: float | None = None
    record_nodes: bool = True

    def __post_init__(self) -> None:
        super().__post_init__()
        check_stopping(self.max_iterations, self.tol, self.atol)


def run_options(options: AdmmOptions | None) -> AdmmRunOptions | None:
    """``options`` as an :class:`AdmmRunOptions` (a kernel-only :class:`AdmmOptions` gets the default stopping
    rule), so one kernel options object serves :func:`~distnav.algorithms.lsq.admm.iterate_admm` and
    :func:`~distnav.algorithms.lsq.admm.admm` alike."""
    if options is None or isinstance(options, AdmmRunOptions):
        return options
    if not isinstance(options, AdmmOptions):
        return options  # refused by name in resolve_options
    return AdmmRunOptions(**{name: getattr(options, name) for name in option_names(AdmmOptions)})


@dataclass(frozen=True, eq=False, kw_only=True)
class AdmmResult(SolverResult):
    """Outcome of :func:`~distnav.algorithms.lsq.admm.admm` (and :func:`~distnav.algorithms.lsq.admm.admm_nonlinear`).

    Attributes (beyond :class:`~distnav.algorithms.result.SolverResult`)
    ----------
    z : ``(|C|, p)`` consensus state of every constraint node, in the order of ``constraint_nodes.nodes``.
    z_nodes : ``(n, p)`` the same per node (zero rows off ``C``); a warm start reads it (§4.3).
    constraint_nodes : the set ``C`` used.
    iterations_to : first iteration with ``max_i ‖x_i − x̂‖/‖x̂‖`` at or below ``"0.0001"``, ``"1e-06"``,
        ``"1e-08"`` (None if never reached or no reference was given).
    pairs : number of pairs ``(i, s)``, ``s ∈ N_i ∩ C`` (including ``s = i``).
    x_update : the x-update method run (``"normal"``, ``"observation"``, ``"cholesky"`` or the nonlinear one).
    x_weight : the weighting of the x-update (``"lagrangian"``, ``"fig6"``, ``"fig6-zweighted"``).
    messages : ``"pairs"`` or ``"aggregated"``.
    precision : the covariance blocks and variance factor when computed (:mod:`distnav.algorithms.lsq.qc`).
    tests : the observation tests when data snooping ran (:mod:`distnav.algorithms.lsq.qc`).
    multipliers : this exchange block's final ``u_{i,s}`` (per-pair runs; None for aggregated messages), for a
        warm start that keeps them (option ``multipliers``).
    """

    z: FloatArray
    z_nodes: FloatArray
    constraint_nodes: ConstraintNodes
    iterations_to: Mapping[str, int | None]
    pairs: int
    x_update: str
    x_weight: str
    messages: str
    precision: Precision | None = None
    tests: ObservationTests | None = None
    multipliers: Multipliers | None = None


@dataclass(frozen=True, eq=False)
class PreparedRun:
    """A validated Fig. 6 run: the state generator of this exchange block and what it was built from."""

    states: Iterator[AdmmState]
    exchange: Exchange
    constraint_nodes: ConstraintNodes
    p: int
    x_update: str
    x_weight: str
    messages: str
    kernel: _Kernel | None = None


def constraint_nodes_for(graph: Graph, constraint_nodes: Any) -> ConstraintNodes:
    """``C`` from a choice (``"min_cover"``, ``"all"``, ids) or a given set checked against ``graph``."""
    if isinstance(constraint_nodes, ConstraintNodes):
        if constraint_nodes.graph.n_nodes != graph.n_nodes or constraint_nodes.graph.n_edges != graph.n_edges:
            raise ModelError("the constraint nodes were chosen on a different graph")
        return constraint_nodes
    return choose_constraint_nodes(graph, constraint_nodes)


def initial_values(init: Any, z0: Any, n: int, p: int) -> tuple[FloatArray, FloatArray]:
    """``x_i^[0]`` and ``z_s^[0]`` (per node) from ``init`` (``"zero"``, a vector, an ``(n, p)`` array, or a previous
    :class:`~distnav.algorithms.result.SolverResult`, whose ``z_nodes`` it continues from) and ``z0``."""
    if isinstance(init, SolverResult):
        x0 = _per_node(init.estimates, n, p, "the previous solution's estimates")
        prev_z = init.z_nodes if isinstance(init, AdmmResult) else None
        z_default = x0 if prev_z is None else _per_node(prev_z, n, p, "the previous solution's z")
    elif isinstance(init, str):
        if init != "zero":
            raise ModelError(
                f"init must be 'zero', a vector, a per-node array or a previous SolverResult, got {init!r}"
            )
        x0 = np.zeros((n, p))
        z_default = x0
    else:
        x0 = _per_node(init, n, p, "init")
        z_default = x0
    z = z_default.copy() if z0 is None else _per_node(z0, n, p, "z0")
    if not (np.all(np.isfinite(x0)) and np.all(np.isfinite(z))):
        raise ModelError("initial values x0/z0 have non-finite entries")
    return x0, z


def check_stopping(max_iterations: int, tol: float, atol: float) -> None:
    """Refuse by name a stopping rule that is not a whole ``max_iterations ≥ 0`` and real tolerances ≥ 0 (not a
    string, None, a fraction, a bool or a complex number)."""
    whole_number(max_iterations, "max_iterations", minimum=0, error=ModelError)
    # below 1e100: a larger tolerance means no test at all, and its product with √(P p) overflows (issue 29)
    real_number(tol, "tol (relative tolerance)", minimum=0.0, below=1e100, error=ModelError)
    real_number(atol, "atol (absolute tolerance)", minimum=0.0, below=1e100, error=ModelError)


def _check_estimable(problem: LinearProblem, local: LinearProblem, ex: Exchange, need_blocks: bool) -> None:
    """Refuse a problem whose ``N = Σ N_i`` is singular (paper 000, eq. (2)), as :func:`~distnav.algorithms.lsq.blue`
    does: ADMM would converge and report the initial value for an inestimable direction. ``N`` is a network sum of
    ``p × p`` blocks (``ex.allreduce``, a set-up check like the stopping rule's totals). With ``R_i`` diagonal and the
    per-node ``N_i`` not needed otherwise (the observation-form x-update), the block's sum is one ``(p × m n)`` product
    instead of ``n`` whitened ``N_i`` (only this rank test reads it)."""
    r_diag = None if need_blocks else _diagonal_or_none(local.R)
    if r_diag is None:
        N_local = local.normal_equations[0].sum(axis=0)
    else:
        p = local.n_params
        A = local.A.reshape(-1, p)
        # R = I (the common case): A/1 is A bitwise, so the same product without the whitened copy
        Aw = A if bool((r_diag == 1.0).all()) else A / r_diag.reshape(-1, 1)
        N_local = Aw.T @ A
    N = np.asarray(ex.allreduce(N_local, "sum"), dtype=float)
    text = inestimable_directions(N, problem.param_label)
    if text is not None:
        raise ModelError(f"{text}; ADMM would converge and return the initial value for these directions")


def prepare(problem: LinearProblem, graph: Graph, exchange: Exchange | None, options: AdmmOptions) -> PreparedRun:
    """Build the Fig. 6 state generator for this exchange block from validated options."""
    messages, monitor_every, x_weight = options.messages, options.monitor_every, options.x_weight
    if problem.n_nodes != graph.n_nodes:
        raise ModelError(f"the problem has {problem.n_nodes} nodes, the graph {graph.n_nodes}")
    p = problem.n_params
    Wm = weight_matrix(options.W, p)
    C = constraint_nodes_for(graph, options.constraint_nodes)
    ex = exchange if exchange is not None else make_exchange(graph)
    if ex.graph.n_edges != graph.n_edges or ex.graph.n_nodes != graph.n_nodes:
        raise ModelError("the exchange was built on a different graph")
    x0, zz0 = initial_values(options.init, options.z0, graph.n_nodes, p)
    count = C.per_node_count.astype(float)
    c_weight = count if x_weight == "lagrangian" else np.ones_like(count)
    xu, local = _x_update(problem, ex, Wm, c_weight, options.x_update)
    if messages == "aggregated" and ex.faults.active:
        raise ModelError(
            "messages='aggregated' keeps multiplier sums that lost messages corrupt for good (the run "
            "converges to a wrong point); use messages='pairs' with a fault schedule"
        )
    if messages == "aggregated" and x_weight == "fig6-zweighted":
        raise ModelError("x_weight='fig6-zweighted' weights the z-update per pair: use messages='pairs'")
    _check_estimable(problem, local, ex, need_blocks=xu.method != "observation")
    u0 = options.multipliers
    if messages == "ternary" and ex.faults.active:
        raise ModelError(
            "messages='ternary' sends deltas against a copy both ends keep: a lost message desynchronizes them "
            "for good; use messages='pairs' with a fault schedule"
        )
    kernel: _Kernel | None = None
    if messages in ("pairs", "ternary"):
        z_weight = 1.0 / C.per_node_count.astype(float) if x_weight == "fig6-zweighted" else None
        kernel = _Kernel(ex, C, Wm, p, xu, z_weight=z_weight)
        bits = TERNARY_BITS if messages == "ternary" else None
        states = kernel.run(x0[ex.nodes], zz0[ex.nodes], monitor_every, u0=u0, bits=bits)
    else:
        if u0 is not None:
            raise ModelError("multipliers can only be continued with messages='pairs'")
        x_loc, z_loc = x0[ex.nodes], zz0[ex.nodes]
        del x0, zz0  # the kernel takes the block's rows over: no whole-size copy stays
        states = _AggregatedKernel(ex, rounds_on_graph(ex, C), Wm, p, xu).run(x_loc, z_loc, monitor_every)
    return PreparedRun(
        states=states,
        exchange=ex,
        constraint_nodes=C,
        p=p,
        x_update=xu.method,
        x_weight=x_weight,
        messages=messages,
        kernel=kernel,
    )


def _x_update(
    problem: LinearProblem, ex: Exchange, W: np.ndarray, c: np.ndarray, method: XUpdateMethod
) -> tuple[XUpdate | InLocalOrder, LinearProblem]:
    """The block's x-update (``c``: every node's ``c_i`` weight) and the problem rows it reads. A block holding every
    node (in-process) keeps the caller's problem in the caller's order — no permuted copy of ``A``, ``y``, ``R`` —
    and the x-update moves ``l`` and ``x`` between the orders (:func:`~distnav.algorithms.lsq.xupdate.in_local_order`:
    per-node arithmetic, so bitwise the same ``x``); a block of some nodes (MPI) holds its own rows."""
    if ex.n_local == problem.n_nodes:
        # the same arrays under a fresh cache: what the set-up derives (N_i, R_i⁻¹) goes with the run, not onto the
        # caller's object
        mine = dataclasses.replace(problem, _cache={})
        return in_local_order(XUpdate(mine, W, c, method), ex.nodes), mine
    local = problem.subset(ex.nodes)
    return XUpdate(local, W, c[ex.nodes], method), local


class StoppingRule(Protocol):
    """What :func:`drive` reads of an options object: ``max_iterations``, ``tol`` and ``atol`` (checked by
    :func:`check_stopping` when the object was built)."""

    @property
    def max_iterations(self) -> int: ...

    @property
    def tol(self) -> float: ...

    @property
    def atol(self) -> float: ...


@dataclass(frozen=True, kw_only=True)
class Stopping:
    """A stopping rule on its own (for runs whose options name it otherwise, e.g. the inner runs of
    :func:`~distnav.algorithms.lsq.nonlinear.admm_linearized`)."""

    max_iterations: int
    tol: float
    atol: float

    def __post_init__(self) -> None:
        check_stopping(self.max_iterations, self.tol, self.atol)


def drive(
    run: PreparedRun,
    stop: StoppingRule,
    *,
    reference: np.ndarray | None = None,
    stop_at_reference: float | None = None,
    record_nodes: bool = False,
) -> AdmmResult:
    """Run a prepared state generator to the stopping rule ``stop`` of :func:`~distnav.algorithms.lsq.admm.admm`,
    tracing as it goes (without a ``reference``: the residuals only)."""
    max_iterations, tol, atol = stop.max_iterations, stop.tol, stop.atol
    gen, C, p = run.states, run.constraint_nodes, run.p
    track = _ReferenceTrace(run.exchange, reference, p, record_nodes)
    n_pairs = int(C.per_node_count.sum())
    abs_term = atol * np.sqrt(n_pairs * p)
    state: AdmmState | None = None
    status: SolverStatus = "max_iterations"
    for state in gen:
        track.tb.add(primal_residual=state.primal_residual, dual_residual=state.dual_residual)
        rel = track.add(state)
        if state.iteration > 0:
            ok_pri = state.primal_residual <= abs_term + tol * max(state.x_norm, state.z_norm)
            ok_dual = state.dual_residual <= abs_term + tol * state.u_norm
            at_reference = stop_at_reference is not None and rel is not None and rel <= stop_at_reference
            if (ok_pri and ok_dual) or at_reference:
                status = "converged"
                break
        if state.iteration >= max_iterations:
            break
    close = getattr(gen, "close", None)
    if close is not None:
        close()
    assert state is not None
    return _admm_result(run, state, status, track, n_pairs)


class _ReferenceTrace:
    """The trace of a run and, with a reference ``x̂``, each iteration's distance to it and the first iteration
    below each of :data:`THRESHOLDS` (relative)."""

    def __init__(self, ex: Exchange, reference: np.ndarray | None, p: int, record_nodes: bool) -> None:
        self.ex, self.record_nodes, self.tb = ex, record_nodes, TraceBuilder()
        self.ref: np.ndarray | None = None
        if reference is not None:
            self.ref = np.asarray(reference, dtype=float)
            if self.ref.shape != (p,):
                raise ModelError(f"reference must be a length-{p} vector (x̂), got shape {self.ref.shape}")
        norm = float(np.linalg.norm(self.ref)) if self.ref is not None else 1.0
        self.ref_norm = norm if norm > 0 else 1.0
        self.reached: dict[str, int | None] = {f"{t:g}": None for t in THRESHOLDS}

    def add(self, state: AdmmState) -> float | None:
        """Trace the distance of ``state`` to the reference; return the relative maximum (None without one)."""
        if self.ref is None:
            return None
        dist_local = np.linalg.norm(state.x - self.ref[None, :], axis=1)
        dmax = float(self.ex.allreduce(float(dist_local.max()) if dist_local.size else 0.0, "max"))
        rel = dmax / self.ref_norm
        self.tb.add(max_distance_to_reference=dmax, relative_max_distance=rel)
        if self.record_nodes:
            self.tb.add(distance_to_reference=self.ex.gather_nodes(dist_local))
        for t in THRESHOLDS:
            if self.reached[f"{t:g}"] is None and rel <= t:
                self.reached[f"{t:g}"] = state.iteration
        return rel


def _admm_result(
    run: PreparedRun, state: AdmmState, status: SolverStatus, track: _ReferenceTrace, n_pairs: int
) -> AdmmResult:
    """The :class:`AdmmResult` of a finished run: every node's ``x_i`` and ``z`` gathered, the message counts."""
    ex, C = run.exchange, run.constraint_nodes
    u = getattr(run.kernel, "multipliers", None) if run.kernel is not None else None
    x_all = ex.gather_nodes(state.x)
    z_all = ex.gather_nodes(state.z)
    msg = (
        f"{state.iteration} iterations, primal residual {state.primal_residual:.3g}, "
        f"dual residual {state.dual_residual:.3g}"
    )
    if track.ref is not None:
        worst = float(np.max(np.linalg.norm(x_all - track.ref, axis=1))) / track.ref_norm
        msg += f", max_i ‖x_i − x̂‖/‖x̂‖ = {worst:.3g}"
    return AdmmResult(
        estimates=x_all,
        converged=status == "converged",
        iterations=state.iteration,
        status=status,
        message=msg,
        trace=track.tb.build(),
        comm=ex.comm_totals(),
        z=z_all[C.nodes],
        z_nodes=z_all,
        constraint_nodes=C,
        iterations_to=track.reached,
        pairs=n_pairs,
        x_update=run.x_update,
        x_weight=run.x_weight,
        messages=run.messages,
        multipliers=None if u is None else u.copy(),
    )
