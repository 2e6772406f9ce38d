"""Global (centralized) nonlinear least squares: Levenberg–Marquardt with Fletcher's scaling (paper 002 eq. (8)).

:func:`levenberg_marquardt` is generic: it minimises ``Σ_l ρ_l(g_l(x))`` for a residual function ``g`` with a
(sparse or dense) Jacobian ``G``. The update of paper 002 eq. (8),

    x_{k+1} = x_k − (GᵀG + λ_k diag(GᵀG))⁻¹ Gᵀ g,

uses Fletcher's (1971) scaling (the damping is proportional to the diagonal of ``GᵀG``, so every coordinate is
damped by its own sensitivity). ``λ`` follows the gain ratio ``ρ = actual / predicted`` reduction (Nielsen's
rule: on success ``λ ← λ·max(1/3, 1 − (2ρ − 1)³)``, on failure ``λ ← λ·ν``, ``ν ← 2ν``). One *iteration* is one
trial step (one linear solve); a rejected step leaves ``x`` unchanged.

Robust losses (``"huber"``, ``"cauchy"``) are handled by iteratively reweighted least squares inside LM: at the
current point every residual gets the weight ``w_l = ρ'((g_l/s_l)²)``, the step minimises ``Σ w_l (g_l + G_l δ)²``,
and acceptance is judged on the robust objective ``F = Σ s_l² ρ((g_l/s_l)²)`` (scipy's convention:
Huber ``ρ(z) = z`` for ``z ≤ 1`` else ``2√z − 1``; Cauchy ``ρ(z) = ln(1 + z)``). The gradients of the weighted
model and of ``F`` agree, so the fixed points are those of ``F``.

:func:`solve_lm` applies it to a UWB ranging problem (:class:`~distnav.algorithms.ranging.data.RangingData`, which
:class:`distnav.models.uwb.problems.RangingProblem` extends) and returns a
:class:`~distnav.algorithms.ranging.data.RangingResult`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.sparse as sp

from distnav._blas import single_threaded_blas
from distnav._checks import check_field_types, whole_number
from distnav._settings import resolve_options
from distnav.algorithms.ranging.damped import DampedSolver as _DampedSolver
from distnav.algorithms.ranging.data import RangingData, RangingResult
from distnav.algorithms.ranging.losses import LOSSES, robust_weights
from distnav.algorithms.ranging.objective import DELAY_MODES, FitOptions, RangeObjective
from distnav.algorithms.result import Trace
from distnav.errors import ModelError
from distnav.exchange.core import CommTotals

__all__ = [
    "single_threaded_blas",
    "levenberg_marquardt",
    "LMOptions",
    "LMSolveOptions",
    "LMResult",
    "solve_lm",
    "estimate_prior_sigma",
    "prior_variance_ratio",
]

PRIOR_ITERATIONS = 6  # variance-component re-fits at most (Förstner's iteration)
PRIOR_TOLERANCE = 0.02  # ... until σ_b changes by less than this share
PRIOR_BOUNDS_M = (0.002, 1.0)  # σ_b is kept within these (metres): a prior of 0 or ∞ has no variance component
PRIOR_MAX_UNKNOWNS = 1500  # the estimate inverts the dense normal matrix: above this the given prior is kept


@dataclass(frozen=True, kw_only=True)
class LMOptions:
    """The stopping tests and initial damping of :func:`levenberg_marquardt` (see its docstring).

    - ``max_iterations`` (500): trial steps (linear solves), ≥ 0.
    - ``ftol`` (1e-12): the relative reduction, actual and predicted, below which an accepted step stops.
    - ``xtol`` (1e-12): the step, relative to ``‖x‖ + xtol``, below which LM stops.
    - ``gtol`` (1e-12): MINPACK's gradient cosine below which LM stops.
    - ``lambda0`` (1e-3): the initial damping ``λ`` of eq. (8).
    """

    max_iterations: int = 500
    ftol: float = 1e-12
    xtol: float = 1e-12
    gtol: float = 1e-12
    lambda0: float = 1e-3

    def __post_init__(self) -> None:
        check_field_types(self, error=ModelError)  # types first, naming the field (issue 29)
        if self.max_iterations < 0:
            raise ModelError(f"max_iterations must be ≥ 0, got {self.max_iterations}")

    def tolerances(self) -> dict[str, float]:
        """The initial damping and the stopping tolerances, as ``RangingResult.settings`` lists them."""
        return {"lambda0": self.lambda0, "ftol": self.ftol, "xtol": self.xtol, "gtol": self.gtol}


@dataclass(frozen=True, kw_only=True)
class LMSolveOptions(LMOptions, FitOptions):
    """:class:`LMOptions`, the fit the ranging front doors share
    (:class:`~distnav.algorithms.ranging.objective.FitOptions`: ``initial_m``, ``objective``, ``sigma_m``,
    ``range_offsets``, ``offset_prior_sigma_m``, ``quality``, ``test_level``, ``test_scale``) and what
    :func:`solve_lm` adds:

    - ``loss`` (``"linear"``; ``"huber"``, ``"soft_l1"``, ``"cauchy"``, ...) and ``loss_scale_m`` (0.3, metres):
      the robust loss and the range error where it bends.
    - ``pad_trace`` (False): extend the trace to ``max_iterations`` rows by repeating the final state.
    - ``graduated`` (None: on for metres): fit the linear loss first, then the robust one from there.
    - ``estimate_offset_prior`` (False): with per-anchor delays (``"per_anchor"``, ``"common_delays"``), estimate
      their prior σ from the residuals (:func:`estimate_prior_sigma`, Förstner's variance components), starting
      from ``offset_prior_sigma_m``.
    """

    loss: str = "linear"
    loss_scale_m: float = 0.3
    pad_trace: bool = False
    graduated: bool | None = None
    estimate_offset_prior: bool = False

    def __post_init__(self) -> None:
        LMOptions.__post_init__(self)
        FitOptions.__post_init__(self)
        _check_lm(self.loss, self.max_iterations)
        if self.estimate_offset_prior and self.range_offsets not in DELAY_MODES:
            raise ModelError(
                f"estimate_offset_prior estimates the per-anchor delays' prior σ: range_offsets must be one of "
                f"{', '.join(DELAY_MODES)}, got {self.range_offsets!r}"
            )


@dataclass(frozen=True)
class LMResult:
    """Outcome of :func:`levenberg_marquardt` (``cost`` is ``Σ g²``; ``objective`` the robust ``F``)."""

    x: np.ndarray
    cost: float
    objective: float
    iterations: int
    converged: bool
    message: str
    trace: dict[str, np.ndarray]


@single_threaded_blas()
def levenberg_marquardt(
    fun: Callable[[np.ndarray], np.ndarray],
    jac: Callable[[np.ndarray], np.ndarray | sp.spmatrix | sp.sparray],
    x0: np.ndarray,
    *,
    loss: str = "linear",
    loss_scale: np.ndarray | float = 1.0,
    callback: Callable[[int, np.ndarray], None] | None = None,
    dense_limit: int = 200,
    options: LMOptions | None = None,
    **changes: Any,
) -> LMResult:
    """Minimise ``Σ ρ(g(x))`` by Levenberg–Marquardt with Fletcher scaling (paper 002 eq. (8)); see module docstring.

    Stops when an accepted step reduces the objective by less than ``ftol`` (relative, actual and predicted),
    when the step is below ``xtol·(‖x‖ + xtol)``, when ``max |Gᵀg| / (‖G_col‖ ‖g‖) ≤ gtol`` (MINPACK's cosine
    test), or after ``max_iterations`` trial steps (``options``: :class:`LMOptions`, with keyword ``changes``).
    ``callback(k, x)`` is called after every iteration. Runs with OpenBLAS on one thread (:func:`single_threaded_blas`).
    """
    c = resolve_options(LMOptions, options, changes)
    max_iterations, xtol, lambda0 = c.max_iterations, c.xtol, c.lambda0
    _check_lm(loss, max_iterations)
    x = np.array(x0, dtype=float)
    g = np.asarray(fun(x), float)
    w, obj = robust_weights(g, loss_scale, loss)
    lam, nu = float(lambda0), 2.0
    tb: dict[str, list[float]] = {"cost": [], "objective": [], "step_norm": [], "lambda": [], "accepted": []}

    def normal(jm: Any, w_: np.ndarray, g_: np.ndarray) -> tuple[Any, np.ndarray]:
        return solver.normal(jm, None if loss == "linear" else w_, g_)

    J: Any = jac(x)  # dense or any scipy sparse format: used through its array interface
    solver = _DampedSolver(J, dense_limit)
    A, grad = normal(J, w, g)
    converged = x.size == 0
    message, k = ("nothing to estimate" if converged else f"stopped after {max_iterations} iterations"), 0
    for k in range(1, max_iterations + 1):
        if converged:
            k -= 1
            break
        delta = solver.solve(A, -grad, lam)
        if delta is None:
            lam *= nu
            nu *= 2.0
            _record(tb, g, obj, 0.0, lam, False)
            continue
        pred = _predicted_reduction(J, delta, w, g)
        x_new = x + delta
        g_new = np.asarray(fun(x_new), float)
        w_new, obj_new = robust_weights(g_new, loss_scale, loss)
        actual = obj - obj_new
        rho = actual / pred if pred > 0 else -1.0
        step = float(np.linalg.norm(delta))
        accepted = rho > 0 and np.isfinite(obj_new)
        if accepted:
            x, g, w, obj_old, obj = x_new, g_new, w_new, obj, obj_new
            lam *= max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3)
            nu = 2.0
            J = jac(x)
            A, grad = normal(J, w, g)
            converged, message = _stopped(c, (actual, pred, obj_old), step, x, g, J, grad, message)
        else:
            lam *= nu
            nu *= 2.0
            if step <= xtol * (xtol + float(np.linalg.norm(x))):
                converged, message = True, f"step below xtol={xtol:g} (rejected)"
        _record(tb, g, obj, step if accepted else 0.0, lam, accepted)
        if callback is not None:
            callback(k, x)
    else:
        k = max_iterations
    return LMResult(
        x=x,
        cost=float(g @ g),
        objective=obj,
        iterations=k,
        converged=converged,
        message=message,
        trace={key: np.asarray(v) for key, v in tb.items()},
    )


def _check_lm(loss: str, max_iterations: int) -> None:
    if loss not in LOSSES:
        raise ModelError(f"unknown loss {loss!r}; choose one of {', '.join(LOSSES)}")
    whole_number(max_iterations, "max_iterations", error=ModelError, allow_float=False)


def _predicted_reduction(J: Any, delta: np.ndarray, w: np.ndarray, g: np.ndarray) -> float:
    """The reduction of the (IRLS-weighted) objective the linear model predicts for the step ``delta``."""
    jd = np.asarray(J @ delta).ravel()
    return float(np.sum(w * g * g) - np.sum(w * (g + jd) ** 2))


def _record(tb: dict[str, list[float]], g: np.ndarray, obj: float, step: float, lam: float, accepted: bool) -> None:
    """One row of :func:`levenberg_marquardt`'s trace."""
    tb["cost"].append(float(g @ g))
    tb["objective"].append(obj)
    tb["step_norm"].append(step)
    tb["lambda"].append(lam)
    tb["accepted"].append(1.0 if accepted else 0.0)


def _stopped(
    c: LMOptions,
    reduction: tuple[float, float, float],
    step: float,
    x: np.ndarray,
    g: np.ndarray,
    J: Any,
    grad: np.ndarray,
    message: str,
) -> tuple[bool, str]:
    """The stopping tests after an accepted step (``reduction``: actual, predicted, the objective before): relative
    reduction (``ftol``), step (``xtol``), zero residual, MINPACK's gradient cosine (``gtol``); ``(stop, why)``."""
    actual, pred, obj_old = reduction
    if actual <= c.ftol * obj_old and pred <= c.ftol * obj_old:
        return True, f"relative reduction below ftol={c.ftol:g}"
    if step <= c.xtol * (c.xtol + float(np.linalg.norm(x))):
        return True, f"step below xtol={c.xtol:g}"
    gnorm = float(np.linalg.norm(g))
    if gnorm == 0.0:
        return True, "zero residual"
    if sp.issparse(J):
        jc = J.tocsr()
        colnorm = np.sqrt(np.bincount(jc.indices, jc.data**2, minlength=x.size))
    else:
        colnorm = np.linalg.norm(J, axis=0)
    cos = np.abs(grad) / np.maximum(colnorm * gnorm, 1e-300)
    if float(cos.max(initial=0.0)) <= c.gtol:
        return True, f"gradient below gtol={c.gtol:g}"
    return False, message


def _stages_trace(
    stages: list[LMResult], start: tuple[float, float], c: LMOptions, rmse: list[float] | None, pad: bool
) -> Trace:
    """:func:`solve_lm`'s trace: row 0 the start (``start``: cost and robust objective), then every stage's rows;
    ``pad`` repeats the final state up to ``max_iterations`` rows."""
    cost = np.concatenate([[start[0]]] + [st.trace["cost"] for st in stages])
    objective_tr = np.concatenate([[start[1]]] + [st.trace["objective"] for st in stages])
    step = np.concatenate([[0.0]] + [st.trace["step_norm"] for st in stages])
    lam = np.concatenate([[c.lambda0]] + [st.trace["lambda"] for st in stages])
    rmse_tr = np.asarray(rmse) if rmse is not None else np.full(cost.size, np.nan)
    if pad and cost.size < c.max_iterations + 1:
        n = c.max_iterations + 1 - cost.size
        cost = np.concatenate([cost, np.full(n, cost[-1])])
        objective_tr = np.concatenate([objective_tr, np.full(n, objective_tr[-1])])
        step = np.concatenate([step, np.zeros(n)])
        lam = np.concatenate([lam, np.full(n, lam[-1])])
        rmse_tr = np.concatenate([rmse_tr, np.full(n, rmse_tr[-1])])
    return Trace({"cost": cost, "objective": objective_tr, "rmse_m": rmse_tr, "step_size": step, "lambda": lam})


def _lm_quality(
    obj: Any, x: np.ndarray, scale: np.ndarray | float, loss: str, level: float, test_scale: str
) -> tuple[Any, Any, np.ndarray | None]:
    """Precision, w-tests (:func:`~distnav.algorithms.ranging.qc.centralized_quality`) and the σ of the offsets
    reported (:meth:`RangeObjective.anchor_offsets`; with ``"common_delays"`` the common offset's σ first, then
    the anchors' totals) of the solution ``x`` of the objective ``obj`` with the loss's final weights."""
    from distnav.algorithms.ranging.qc import centralized_quality

    problem = obj.problem
    r = obj.residual(x)
    w = robust_weights(r, scale, loss)[0]
    precision, tests, Q = centralized_quality(
        problem, obj.jacobian(x), r, w, problem.n_meas, level=level, scale=test_scale
    )
    off_std = None
    if Q is not None and obj.n_offsets:
        s2 = precision.variance_factor if precision is not None and precision.variance_factor else 1.0
        off_std = np.sqrt(np.diag(Q)[problem.n_free :] * s2)
        if obj.offsets == "common_delays":  # the common offset's σ (settings["common_offset_std_m"]), then the
            T = obj.anchor_offsets_map()  # σ of the offsets reported: every anchor's total delay c/2 + b_i
            q_off = Q[problem.n_free :, problem.n_free :]
            off_std = np.concatenate([off_std[:1], np.sqrt(np.einsum("ij,jk,ik->i", T, q_off, T) * s2)])
    return precision, tests, off_std


def _initial(problem: RangingData, initial_m: np.ndarray | None) -> np.ndarray:
    init = problem.initial_m if initial_m is None else np.asarray(initial_m, float)
    if init is None:
        raise ModelError("global LM needs an initial guess (problem.initial_m or initial_m=)")
    return np.asarray(init)


def _rmse_of(obj: Any, x: np.ndarray) -> float:
    """RMSE (paper 002 eq. (24)) of the estimated anchors of the free vector ``x`` (NaN without the truth)."""
    problem = obj.problem
    truth, est = problem.truth_m, problem.estimated
    if truth is None:
        return float("nan")
    d = obj.split(x)[0][est] - truth[est]
    return float(np.sqrt(np.mean(np.einsum("ij,ij->i", d, d)))) if est.any() else 0.0


def prior_variance_ratio(obj: RangeObjective, x: np.ndarray, scale: np.ndarray | float, loss: str) -> float | None:
    """``ŝ_b² / ŝ_r²``: the variance factor of the delays' prior rows over that of the range rows at the solution
    ``x`` (Förstner 1979, *Ein Verfahren zur Schätzung von Varianz- und Kovarianzkomponenten*, AVN 86: each group's
    ``ŝ_k² = vₖᵀ Wₖ vₖ / r_k`` with its redundancy ``r_k = n_k − tr(Q Nₖ)``, ``Q = N⁻¹``, ``N = Σ Nₖ``; the range
    rows with the robust loss's final IRLS weights). None when the normal matrix is singular, a group has no
    redundancy left or there are more than :data:`PRIOR_MAX_UNKNOWNS` unknowns."""
    if obj.n_x > PRIOR_MAX_UNKNOWNS:
        return None
    J = sp.csr_matrix(obj.jacobian(x))
    r = obj.residual(x)
    m = obj.problem.n_meas
    w = robust_weights(r, scale, loss)[0] if loss != "linear" else np.ones_like(r)
    Jr, Jb = J[:m], J[m:]
    Nr = np.asarray((Jr.T @ sp.diags(w[:m]) @ Jr).toarray())
    Nb = np.asarray((Jb.T @ Jb).toarray())
    try:
        Q = np.linalg.inv(Nr + Nb)
    except np.linalg.LinAlgError:
        return None
    red_r, red_b = m - float(np.sum(Q * Nr)), obj.n_prior - float(np.sum(Q * Nb))
    if not (red_r > 0.5 and red_b > 0.05):
        return None
    return float((r[m:] @ r[m:] / red_b) / (np.sum(w[:m] * r[:m] ** 2) / red_r))


def estimate_prior_sigma(
    obj: RangeObjective, res: LMResult, fit: Callable[[RangeObjective, np.ndarray], LMResult], scale: Any, loss: str
) -> tuple[RangeObjective, LMResult, list[LMResult]]:
    """The per-anchor delays' prior σ_b estimated from the residuals: Förstner's iteration
    σ_b ← σ_b · √(ŝ_b² / ŝ_r²) (:func:`prior_variance_ratio`) with a re-fit ``fit(objective, start)`` after each
    update, until σ_b changes by less than :data:`PRIOR_TOLERANCE` or after :data:`PRIOR_ITERATIONS` re-fits;
    σ_b within :data:`PRIOR_BOUNDS_M`. Returns the final objective (its ``offset_prior_sigma_m``: the estimate),
    fit and the re-fits made."""
    refits: list[LMResult] = []
    for _ in range(PRIOR_ITERATIONS):
        ratio = prior_variance_ratio(obj, res.x, scale, loss)
        if ratio is None:
            break
        old = obj.offset_prior_sigma_m
        new = float(np.clip(old * np.sqrt(ratio), *PRIOR_BOUNDS_M))
        if abs(new / old - 1.0) < PRIOR_TOLERANCE:
            break
        obj = RangeObjective(obj.problem, obj.kind, obj.sigma_m, obj.offsets, new)
        res = fit(obj, res.x)
        refits.append(res)
    return obj, res, refits


def _lm_settings(
    c: LMSolveOptions, obj: RangeObjective, off: np.ndarray, off_std: np.ndarray | None, *, graduated: bool
) -> tuple[dict[str, Any], np.ndarray | None]:
    """:func:`solve_lm`'s ``settings`` and the offsets' σ it reports: with ``"common_delays"`` the common offset
    ``c`` and its σ go to the settings and ``off_std`` keeps the anchors' totals only."""
    settings: dict[str, Any] = {
        **c.tolerances(),
        "sigma_m": c.sigma_m,
        "range_offsets": c.range_offsets,
        "graduated": graduated,
    }
    if c.range_offsets == "common_delays" or c.estimate_offset_prior:  # the prior used: given, or estimated
        settings.update(offset_prior_sigma_m=obj.offset_prior_sigma_m, offset_prior_estimated=c.estimate_offset_prior)
    if c.range_offsets == "common_delays":  # offsets_m: every anchor's total delay; the common offset c here
        settings.update(common_offset_m=float(off[0]))
        settings["common_offset_std_m"] = None if off_std is None else float(off_std[0])
        off_std = None if off_std is None else off_std[1:]
    return settings, off_std


def solve_lm(problem: RangingData, *, options: LMSolveOptions | None = None, **changes: Any) -> RangingResult:
    """Global LM (paper 002 eq. (8), Fletcher scaling) on a ranging problem; returns a :class:`RangingResult`.

    ``estimates`` are the ``(n, dim)`` anchor positions. Trace (one row per iteration, plus row 0 = start):
    ``cost`` (``f`` of eq. (2)), ``objective`` (robust ``F``), ``rmse_m`` (eq. (24), when the truth is known),
    ``step_size`` (‖δ‖, 0 for a rejected step), ``lambda``. With ``pad_trace`` the trace is extended to
    ``max_iterations`` rows by repeating the final state (for averaging runs that stopped early).
    ``loss`` = ``"huber"``/``"soft_l1"``/``"cauchy"`` down-weights ranges off by more than about ``loss_scale_m``.
    No messages are counted: gathering the ranges at a centre is not modelled (``comm`` is empty).

    ``objective="metres"`` fits ``e = ‖r_a − r_b‖ − d`` with weight ``1/sigma_m²`` instead of paper 002's squared
    form (:mod:`distnav.algorithms.ranging.objective`); ``graduated`` (default: on for metres) first fits the linear
    loss, then the robust one from there. ``range_offsets="common"|"per_anchor"`` (metres only) estimates a common
    range offset or per-anchor antenna delays (prior σ ``offset_prior_sigma_m``) jointly with the positions;
    ``"common_delays"`` both, the delays about the common offset (``offsets_m``: every anchor's total delay
    ``c/2 + b_i``, so a range reads ``δ_a + δ_b`` long; ``settings["common_offset_m"]`` the common ``c``; ``x``
    holds ``[coordinates, c, b_1 … b_n]``).
    ``quality`` adds the per-anchor covariance (``precision``) and per-sample w-tests (``tests``) at the solution
    (:func:`distnav.algorithms.ranging.qc.centralized_quality`; ``test_level``, ``test_scale``).
    ``options``: an :class:`LMSolveOptions` (its fields, defaults and units; its :class:`LMOptions` part,
    ``max_iterations``, ``ftol``, ``xtol``, ``gtol``, ``lambda0``, goes to :func:`levenberg_marquardt`), with
    keyword ``changes`` to it (:func:`distnav._settings.resolve_options`).
    """
    c = resolve_options(LMSolveOptions, options, changes)
    loss, objective, sigma_m, range_offsets = c.loss, c.objective, c.sigma_m, c.range_offsets
    obj = RangeObjective(problem, objective, sigma_m, range_offsets, c.offset_prior_sigma_m)
    x0 = obj.x0(_initial(problem, c.initial_m))
    scale = obj.loss_scale(c.loss_scale_m) if loss != "linear" else 1.0
    rm: list[float] | None = [_rmse_of(obj, x0)] if problem.truth_m is not None else None
    callback = (lambda k, x: rm.append(_rmse_of(obj, x))) if rm is not None else None
    stages = []
    x_start = x0
    if (objective == "metres" if c.graduated is None else c.graduated) and loss != "linear":
        stages.append(levenberg_marquardt(obj.residual, obj.jacobian, x0, callback=callback, options=c))
        x_start = stages[0].x
    res = levenberg_marquardt(
        obj.residual, obj.jacobian, x_start, loss=loss, loss_scale=scale, callback=callback, options=c
    )
    stages.append(res)
    if c.estimate_offset_prior:  # σ_b from the residuals: re-fits with the robust loss from the last solution

        def refit(o: RangeObjective, x: np.ndarray) -> LMResult:
            return levenberg_marquardt(
                o.residual, o.jacobian, x, loss=loss, loss_scale=scale, callback=callback, options=c
            )

        obj, res, refits = estimate_prior_sigma(obj, res, refit, scale, loss)
        stages += refits
    g0 = obj.residual(x0)
    start = (float(g0 @ g0), robust_weights(g0, scale, loss)[1])
    trace = _stages_trace(stages, start, c, rm, c.pad_trace)
    pos, off = obj.split(res.x)
    precision = tests = off_std = None
    if c.quality:
        precision, tests, off_std = _lm_quality(obj, res.x, scale, loss, c.test_level, c.test_scale)
    settings, off_std = _lm_settings(c, obj, off, off_std, graduated=len(stages) > 1)
    return RangingResult(
        estimates=pos,
        converged=res.converged,
        iterations=sum(st.iterations for st in stages),
        status="converged" if res.converged else "max_iterations",
        message=f"LM: {res.message}; cost {res.cost:.6g}",
        trace=trace,
        comm=CommTotals.empty(problem.n_anchors),
        solver="LM",
        cost=res.cost,
        objective=res.objective,
        loss=loss,
        x=res.x,
        settings=settings,
        objective_kind=objective,
        precision=precision,
        tests=tests,
        offsets_m=obj.anchor_offsets(off) if obj.n_offsets else None,
        offsets_std_m=off_std,
    )
