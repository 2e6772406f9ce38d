"""The real-data workflow of ``uwb solve`` and ``reproduce uwb-field``, in memory: geometry checks, initial
guess, a graduated robust solve, NLOS exclusion, per-anchor precision and the communication comparison.

1. :func:`prepare`: :func:`~distnav.models.uwb.geometry.check_geometry` on the problem as read; the anchors the
   ranges cannot locate (cut off, non-rigid) are dropped (reported *unsolved*), the rest gets the MDS start
   (:mod:`distnav.models.uwb.initial`) and the planar / mirror checks; a refused geometry raises ModelError.
2. :func:`solve_field`: a robust solve (``loss``, default Cauchy, which finds the NLOS links' basin) and then,
   with ``exclude``, :func:`~distnav.models.uwb.qc.exclude_links` with the plain (linear) loss, each re-solve
   started from the last estimate (the graduated start of issue 13: robust first, then least squares on the links
   that pass their tests). Precision: :func:`~distnav.models.uwb.qc.anchor_covariance` on the kept links.
3. :func:`gather_cost`: what gathering every range at one anchor over the same graph would cost instead.

The solve call goes to :func:`distnav.algorithms.csg.solve` by name, with ``objective`` passed when the solver
takes it (the metres objective of issue 13; until then the paper's squared form) — ``objective_used`` says which.
"""

from __future__ import annotations

import inspect
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import shortest_path

from distnav.algorithms import csg
from distnav.errors import ModelError
from distnav.models.uwb.geometry import GeometryReport, check_geometry
from distnav.models.uwb.initial import mds_initial_guess
from distnav.models.uwb.problems import RangingProblem
from distnav.models.uwb.qc import LinkQC, anchor_covariance, exclude_links, link_tests, with_measurements
from distnav.typing import BoolArray, FloatArray, IntArray

__all__ = ["FieldOptions", "FieldSolution", "prepare", "solve_field", "gather_cost", "RANGE_RECORD_BYTES",
           "supports_objective"]

RANGE_RECORD_BYTES = 16  # two int32 anchor ids + one float64 range
POSITION_BYTES = 8


@dataclass(frozen=True)
class FieldOptions:
    solver: str = "LM"
    objective: str = "metres"
    loss: str = "cauchy"
    loss_scale_m: float = 0.3
    iterations: int = 500
    exclude: bool = True
    level: float = 0.001
    max_exclusions: int | None = None
    allow_planar_3d: bool = False
    solver_options: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True, eq=False)
class FieldSolution:
    """Everything ``uwb solve`` writes. Arrays over ``problem``'s anchors / measurements (the solvable part);
    ``geometry.unsolved`` names the anchors left out."""

    problem: RangingProblem
    geometry: GeometryReport
    positions_m: FloatArray
    covariance_m2: FloatArray | None
    tests: LinkQC
    excluded: BoolArray
    kept_flagged: IntArray
    result: Any
    status: str
    message: str
    objective_used: str
    iterations: int
    messages: int
    bytes: int
    rounds: int

    @property
    def sigma_m(self) -> FloatArray | None:
        if self.covariance_m2 is None:
            return None
        out: FloatArray = np.sqrt(np.maximum(np.diagonal(self.covariance_m2, axis1=1, axis2=2), 0.0))
        return out


def supports_objective(solver: str) -> bool:
    """Whether the solver front door takes ``objective=`` (the metres objective of issue 13)."""
    key = solver.upper()
    fn: Callable[..., Any] = csg.solve_lm if key == "LM" else (csg.solve_csg if key == "CSG" else
                                                               csg.solve_nclm if key == "N-CLM" else csg.solve_ncsg)
    return "objective" in inspect.signature(fn).parameters


def prepare(problem: RangingProblem, *, initial_m: FloatArray | None = None, allow_planar_3d: bool = False,
            rng: np.random.Generator | None = None) -> tuple[RangingProblem, GeometryReport]:
    """Geometry checks, the determined part, its initial guess (see the module docstring)."""
    first = check_geometry(problem, allow_planar_3d=allow_planar_3d, rng=rng)
    if not (first.solvable & problem.estimated).any():
        raise ModelError("nothing to solve: " + ("; ".join(first.messages()) or "no estimated anchor"))
    sub = problem.subset(first.solvable)
    if initial_m is not None:
        init = np.asarray(initial_m, float)[first.solvable]
    else:
        init = mds_initial_guess(sub)
    sub = sub.with_initial(init)
    second = check_geometry(sub, allow_planar_3d=allow_planar_3d, rng=rng)
    carried = tuple(i for i in first.issues if i.severity == "unsolved")
    report = GeometryReport(ids=problem.ids, solvable=first.solvable, issues=carried + second.issues,
                            planarity_known=second.planarity_known, planarity_network=second.planarity_network,
                            notes=first.notes + second.notes)
    report.raise_if_refused()
    return sub, report


def _solve_once(problem: RangingProblem, opts: FieldOptions, loss: str, initial_m: FloatArray,
                exchange: Callable[[RangingProblem], Any] | None, objective: str | None) -> Any:
    kw: dict[str, Any] = dict(opts.solver_options)
    key = opts.solver.upper()
    if key != "CSG":
        kw.update(loss=loss, loss_scale_m=opts.loss_scale_m)
    if objective is not None:
        kw["objective"] = objective
    if key != "LM" and exchange is not None:
        kw["exchange"] = exchange(problem)
    return csg.solve(problem.with_initial(initial_m), key, iterations=opts.iterations, **kw)


def solve_field(problem: RangingProblem, options: FieldOptions | None = None, *,
                geometry: GeometryReport | None = None,
                exchange: Callable[[RangingProblem], Any] | None = None) -> FieldSolution:
    """Solve a prepared problem (from :func:`prepare`) with QC; see the module docstring."""
    opts = options or FieldOptions()
    if problem.initial_m is None:
        raise ModelError("solve_field needs a prepared problem with an initial guess (see prepare)")
    has_obj = supports_objective(opts.solver)
    objective = opts.objective if has_obj else "squared"
    obj_arg = opts.objective if has_obj else None
    if not has_obj and opts.objective != "squared":
        note = " (the metres objective is not available in this version's solvers: squared form used)"
    else:
        note = ""
    first_loss = opts.loss if opts.solver.upper() != "CSG" else "linear"
    res = _solve_once(problem, opts, first_loss, problem.initial_m, exchange, obj_arg)
    total = [int(res.iterations), int(res.comm.messages), int(res.comm.bytes)]
    if res.status == "diverged" or not np.all(np.isfinite(res.estimates)):
        return _diverged(problem, geometry, res, objective, total)
    pos = np.asarray(res.estimates, float)
    excluded = np.zeros(problem.n_meas, bool)
    kept_flagged = np.zeros(0, np.int64)
    rounds = 0
    if opts.exclude:

        def resolve_with(loss: str) -> Callable[[RangingProblem, FloatArray], tuple[FloatArray, Any, int]]:
            def resolve(sub: RangingProblem, start: FloatArray) -> tuple[FloatArray, Any, int]:
                r = _solve_once(sub, opts, loss, start, exchange, obj_arg)
                total[1] += int(r.comm.messages)
                total[2] += int(r.comm.bytes)
                return np.asarray(r.estimates, float), r, int(r.iterations)
            return resolve

        # exclusions tested at the robust solution (NLOS links stand out, they do not drag it), each re-solve
        # robust too; then the plain least-squares solve on the links kept (the graduated start's last stage)
        out = exclude_links(problem, pos, resolve_with(first_loss), objective=objective, level=opts.level,
                            max_exclusions=opts.max_exclusions)
        total[0] += out.solver_iterations
        excluded[out.excluded] = True
        kept_flagged = out.kept_flagged
        rounds = out.rounds
        pos, res, k = resolve_with("linear")(with_measurements(problem, ~excluded), out.positions_m)
        total[0] += k
        if res.status == "diverged" or not np.all(np.isfinite(pos)):
            return _diverged(problem, geometry, res, objective, total)
        tests = link_tests(problem, pos, objective=objective, level=opts.level, active=~excluded)
    else:
        tests = link_tests(problem, pos, objective=objective, level=opts.level)
    cov: FloatArray | None
    try:
        cov = anchor_covariance(problem, pos, objective=objective, active=~excluded)
    except ModelError:
        cov = None
    geo = geometry if geometry is not None else check_geometry(problem)
    status = geo.status or res.status
    msg = res.message + note
    if geo.status is not None:
        msg = f"{geo.status}: " + "; ".join(i.message for i in geo.issues if i.severity != "unsolved") + f" — {msg}"
    return FieldSolution(problem=problem, geometry=geo, positions_m=pos, covariance_m2=cov, tests=tests,
                         excluded=excluded, kept_flagged=kept_flagged, result=res, status=status, message=msg,
                         objective_used=objective, iterations=total[0], messages=total[1], bytes=total[2],
                         rounds=rounds)


def _diverged(problem: RangingProblem, geometry: GeometryReport | None, res: Any, objective: str,
              total: list[int]) -> FieldSolution:
    nan = np.full(problem.n_meas, np.nan)
    tests = LinkQC(residual_m=nan, w=nan, q_ll=nan, scale_m=float("nan"), variance_factor_m2=None, redundancy=0,
                   critical_value=float("nan"), level=float("nan"), active=np.ones(problem.n_meas, bool))
    return FieldSolution(problem=problem, geometry=geometry or check_geometry(problem),
                         positions_m=np.full((problem.n_anchors, problem.dim), np.nan), covariance_m2=None,
                         tests=tests, excluded=np.zeros(problem.n_meas, bool), kept_flagged=np.zeros(0, np.int64),
                         result=res, status="diverged",
                         message=f"diverged: {res.message} (no positions are reported)", objective_used=objective,
                         iterations=total[0], messages=total[1], bytes=total[2], rounds=0)


def gather_cost(problem: RangingProblem) -> dict[str, Any]:
    """Messages and bytes to gather every range at one anchor over the range graph and send the positions back.

    Convergecast along a shortest-path tree to the anchor that minimizes the bytes: every link's record
    (:data:`RANGE_RECORD_BYTES`) travels from the nearer of its two anchors one hop per tree edge, one message
    per tree edge carries a subtree's records; the estimated positions (``dim × 8`` B each) go back the same way.
    """
    lk = problem.links
    n = problem.n_anchors
    g = csr_matrix((np.ones(2 * lk.shape[0]), (np.concatenate([lk[:, 0], lk[:, 1]]),
                                                 np.concatenate([lk[:, 1], lk[:, 0]]))), shape=(n, n))
    hops = shortest_path(g, directed=False, unweighted=True)
    if not np.all(np.isfinite(hops)):
        raise ModelError("the range graph is not connected: no single anchor can gather every range")
    own = np.minimum(hops[:, lk[:, 0]], hops[:, lk[:, 1]])  # sink × link: hops of the link's record
    up = own.sum(axis=1) * RANGE_RECORD_BYTES
    down = hops[:, problem.estimated].sum(axis=1) * problem.dim * POSITION_BYTES
    total = up + down
    sink = int(np.argmin(total))
    return {"sink": problem.ids[sink], "messages": int(2 * (n - 1)), "bytes": int(total[sink]),
            "bytes_ranges": int(up[sink]), "bytes_positions": int(down[sink]),
            "record_bytes": RANGE_RECORD_BYTES, "links": int(lk.shape[0]),
            "max_hops": int(hops[sink].max())}


def subset_measurements(problem: RangingProblem, keep: BoolArray) -> RangingProblem:
    """Alias of :func:`distnav.models.uwb.qc.with_measurements` (the oracle drops the NLOS links by truth)."""
    return with_measurements(problem, keep)
