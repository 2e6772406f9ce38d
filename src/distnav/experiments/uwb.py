"""Reproduction of paper 002 §4–5: UWB anchor self-localization, Figs. 3–6 and Table 1.

Problems GC, GO, GM, LC, LO, LM, RC, RM (class G: 10 m grid with 8-neighbourhood; L: two-row ladder, degree ≤ 5;
R: random, links up to 18 m; 100 anchors of which 3 fixed in a corner (C), opposite corners (O) or the middle
(M)); ranging noise N(0, 0.15² m²); initial guess truth + U(−5, 5) m per coordinate (eq. (23)); anchors in a
horizontal plane, solved in 3-D. Solvers LM, CSG, N-CSG, N-CSG-BLS, N-CSG-TBLS, N-CLM with the paper's settings
(500 iterations, α = 1e-3, α₀ = 1e-2, β = γ = 1/2, one consensus round, Metropolis–Hastings weights).

Per iteration and problem × solver: the mean RMSE over instances (eqs. (24)–(25)) and the mean RMS cost
``ρ = sqrt(f(x_k)/m)`` (the RMS of the residuals ``g_l`` of eq. (6), m²; ``f`` evaluated at every anchor's own
estimate, so every solver is scored on the same function), the mean BLS/TBLS step size (Fig. 6), example
N-CSG-TBLS solutions (Fig. 5) and the Table 1 analogue (final values; messages and bytes per instance).
``--instances N`` sets the instances per problem (paper: 50 for G and L, 100 for R); ``--quick`` runs one
instance of 60 iterations. ``--start horizontal`` perturbs the initial guess in x and y only and starts every
height at the truth (the paper's measured class is described at one height; a planar truth is a saddle point of
the 3-D cost, docs/uwb.md); the default run's ``results.json`` has no ``start`` setting. The instances run in
``--jobs`` worker processes (default: the available cores; every instance seeds its own draws and the sums run
in instance order, so the results are the same for any ``--jobs``). A run whose estimates blow up (CSG and
N-CSG with the fixed α = 1e-3 can, on class R) is counted in ``diverged`` and left out of the means.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from dataclasses import dataclass
from functools import cache, partial
from typing import Any

import numpy as np

from distnav.algorithms.ranging.csg import PAPER_MODE, SOLVERS, solve, solve_line_search_pair
from distnav.algorithms.ranging.data import RangingResult
from distnav.algorithms.result import compare_with_gather
from distnav.errors import UsageError
from distnav.exchange import Exchange, make_exchange
from distnav.experiments.common import ExperimentContext, add_jobs_argument, parallel_map, pyplot
from distnav.models.uwb.communication import RANGES_DATA, range_bytes_per_anchor
from distnav.models.uwb.problems import PAPER_PROBLEMS, RangingProblem, generate_layout, generate_problem
from distnav.network.graph import Graph
from distnav.options import add_size_option, int_up_to

NAME = "uwb"
TITLE = "UWB anchor self-localization: LM, CSG, N-CSG (+BLS/TBLS), N-CLM (paper 002 Figs. 3-6, Table 1)"

PAPER_INSTANCES = {"G": 50, "L": 50, "R": 100}
PAPER_ITERATIONS = 500
QUICK_ITERATIONS = 60
PAPER_TBLS_FINAL_STEP = {"N-CSG-BLS": 1.2e-3, "N-CSG-TBLS": 1.3e-3}
STARTS = ("paper", "horizontal")
#: Size limits of ``--instances`` / ``--iterations``, from the measured cost (docs/uwb.md: 6 solvers × 500 iterations
#: on one instance of each of the 8 problems ≈ 32 CPU-s, linear in both): refused at parse time above them.
INSTANCES = int_up_to(1_000, "one instance of the 8 problems is ≈ 32 CPU-s at 500 iterations: 1,000 are ≈ 9 CPU-hours")
ITERATIONS = int_up_to(
    20_000, "≈ 0.064 CPU-s per iteration of the 8 problems: the paper's instances at 20,000 are ≈ 14 CPU-hours"
)


#: The most CPU time ``--instances`` and ``--iterations`` may ask for together (each is bounded alone as well)
MAX_CPU_HOURS = 24.0
SET_CPU_S = 32.0  # one instance of the 8 problems at PAPER_ITERATIONS (docs/uwb.md)


def check_options(args: argparse.Namespace) -> None:
    """Refuse (:class:`UsageError`, before any work) sizes that together ask for more than :data:`MAX_CPU_HOURS`
    (``--instances 1000 --iterations 20000``: each within its limit, ≈ 356 CPU-hours together)."""
    paper_sets = sum(PAPER_INSTANCES[name[0]] for name in PAPER_PROBLEMS) / len(PAPER_PROBLEMS)  # 50/50/100: 62.5
    sets = args.instances or (1 if args.quick else paper_sets)
    iterations = args.iterations or (QUICK_ITERATIONS if args.quick else PAPER_ITERATIONS)
    hours = sets * SET_CPU_S * iterations / PAPER_ITERATIONS / 3600.0
    if hours > MAX_CPU_HOURS:
        raise UsageError(
            f"--instances {args.instances or 'the paper’s'} with --iterations {iterations:,} is ≈ {hours:,.0f} "
            f"CPU-hours (one instance of the 8 problems ≈ {SET_CPU_S:g} CPU-s at {PAPER_ITERATIONS} iterations): at "
            f"most {MAX_CPU_HOURS:g} together"
        )


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_size_option(
        parser,
        "--instances",
        INSTANCES,
        default=None,
        help="instances per problem (default: the paper's 50 for G and L, 100 for R; --quick: 1)",
    )
    add_size_option(
        parser,
        "--iterations",
        ITERATIONS,
        default=None,
        help=f"iterations of every solver (default {PAPER_ITERATIONS}; --quick: {QUICK_ITERATIONS})",
    )
    parser.add_argument(
        "--armijo-slope",
        choices=["gradient", "subgradient"],
        default="subgradient",
        help="slope in the BLS/TBLS Armijo test: the subgradient Gᵀg as in the paper (default) "
        "or the true gradient 2Gᵀg of f",
    )
    parser.add_argument(
        "--hold-heights",
        action="store_true",
        help="hold every estimated anchor's height at its true value (solve x, y only)",
    )
    parser.add_argument(
        "--start",
        choices=list(STARTS),
        default="paper",
        help="initial guess: truth + U(-5, 5) m in every coordinate (paper: eq. (23), default) or "
        "in x and y only, the heights started at the truth (horizontal)",
    )
    add_jobs_argument(parser)


def _errors(problem: RangingProblem, est: np.ndarray) -> tuple[float, float]:
    assert problem.truth_m is not None
    e = (est - problem.truth_m)[problem.estimated]
    return float(np.sqrt(np.mean(np.sum(e[:, :2] ** 2, axis=1)))), float(np.sqrt(np.mean(e[:, 2:] ** 2)))


@dataclass(frozen=True)
class _Task:
    """One instance of one problem: everything a worker process needs to run the six solvers on it."""

    seed: int
    problem_index: int
    name: str
    instance: int
    iterations: int
    armijo_slope: str
    hold_heights: bool
    start: str


@cache
def _layout(cls: str) -> tuple[np.ndarray, np.ndarray] | None:
    """The fixed G / L placement (the paper keeps it over the instances); None for R (drawn per instance)."""
    return generate_layout(cls) if cls in "GL" else None


def instance_problem(
    name: str, rng: np.random.Generator, *, hold_heights: bool = False, start: str = "paper"
) -> RangingProblem:
    """The reproduction's instance of problem ``name``: :func:`generate_problem` with the fixed G / L placement;
    ``start="horizontal"`` keeps its initial guess's horizontal perturbation and starts every height at the
    truth (the random draws are the same, so the two starts are paired instance by instance)."""
    if start not in STARTS:
        raise UsageError(f"--start must be one of {', '.join(STARTS)}, got {start!r}")
    problem = generate_problem(name, rng, layout=_layout(name[0]), hold_heights=hold_heights)
    if start == "horizontal":
        assert problem.initial_m is not None and problem.truth_m is not None
        init = problem.initial_m.copy()
        init[:, 2:] = problem.truth_m[:, 2:]
        problem = problem.with_initial(init)
    return problem


def _run_instance(task: _Task, exchange: Callable[[Graph], Exchange] | None = None) -> dict[str, Any]:
    """The six solvers on one instance (in a worker process, or in the main one with ``ctx.exchange``)."""
    make = exchange or (lambda graph: make_exchange(graph))
    rng = np.random.default_rng([task.seed, 1000 * (task.problem_index + 1) + task.instance])  # = ctx.rng(...)
    problem = instance_problem(task.name, rng, hold_heights=task.hold_heights, start=task.start)
    m, its = problem.n_meas, task.iterations
    out: dict[str, Any] = {"runs": {}, "example": None}
    line_searches: dict[str, RangingResult] = {}
    for s in SOLVERS:
        t0 = time.perf_counter()
        if s == "LM":
            res = solve(problem, s, iterations=its, pad_trace=True)
        elif s in line_searches:
            res = line_searches[s]
        elif "LS" in s:  # the paper's mode: a fixed iteration count, no QC; BLS and TBLS share what they can
            pair = solve_line_search_pair(
                problem,
                iterations=its,
                armijo_slope=task.armijo_slope,
                exchanges=(make(problem.graph), make(problem.graph)),
                **PAPER_MODE,
            )
            res, line_searches["N-CSG-TBLS"] = pair
        else:
            res = solve(problem, s, iterations=its, exchange=make(problem.graph), **PAPER_MODE)
        run: dict[str, Any] = {
            "seconds": time.perf_counter() - t0,
            "messages": res.comm.messages,
            "bytes": res.comm.bytes,
            "diverged": False,
        }
        out["runs"][s] = run
        if res.status == "diverged" or not np.all(np.isfinite(res.trace["rmse_m"])):
            run["diverged"] = True
            continue
        run["rmse"] = res.trace["rmse_m"][: its + 1]
        run["cost"] = np.sqrt(res.trace["cost"][: its + 1] / m)
        if "LS" in s:
            run["step"] = res.trace["step_size"][: its + 1]
        run["xy"], run["z"] = _errors(problem, res.estimates)
        if task.instance == 0 and s == "N-CSG-TBLS" and task.name in ("GO", "LC", "RM"):
            out["example"] = {
                "truth": problem.truth_m,
                "initial": problem.initial_m,
                "estimate": res.estimates,
                "fixed": problem.fixed,
                "links": problem.links,
            }
        if task.instance == 0 and s in ("N-CLM", "N-CSG-TBLS") and task.name in ("GO", "LC", "RM"):
            out.setdefault("vs_gather", {})[s] = compare_with_gather(
                res.comm, problem.graph, range_bytes_per_anchor(problem), data=RANGES_DATA, node_label="anchor"
            ).as_dict()
    return out


def run(ctx: ExperimentContext) -> dict[str, Any]:
    opt_inst = ctx.option("instances", None, minimum=1)
    iterations = int(ctx.option("iterations", QUICK_ITERATIONS if ctx.quick else PAPER_ITERATIONS, minimum=1))
    armijo_slope = str(ctx.options.get("armijo_slope") or "subgradient")
    hold_heights = bool(ctx.options.get("hold_heights", False))
    start = str(ctx.options.get("start") or "paper")
    if start not in STARTS:
        raise UsageError(f"--start must be one of {', '.join(STARTS)}, got {start!r}")
    n_inst = {c: (int(opt_inst) if opt_inst is not None else (1 if ctx.quick else PAPER_INSTANCES[c])) for c in "GLR"}
    tasks = [
        _Task(ctx.seed, pi, name, inst, iterations, armijo_slope, hold_heights, start)
        for pi, name in enumerate(PAPER_PROBLEMS)
        for inst in range(n_inst[name[0]])
    ]
    runs = _run_tasks(ctx, tasks)
    curves: dict[str, dict[str, dict[str, np.ndarray]]] = {}
    table: list[dict[str, Any]] = []
    examples: dict[str, Any] = {}
    vs_gather: dict[str, Any] = {}
    timing: dict[str, float] = {s: 0.0 for s in SOLVERS}
    for name in PAPER_PROBLEMS:
        done = [r for t, r in zip(tasks, runs, strict=True) if t.name == name]
        acc = _accumulate(done, timing)
        for one in done:
            if one["example"] is not None:
                examples[name] = one["example"]
            for s, v in one.get("vs_gather", {}).items():
                vs_gather[f"{name}, {s}, instance 0"] = v
        curves[name] = {}
        for s in SOLVERS:
            curves[name][s], row = _mean_curves(acc[s], iterations)
            table.append(
                {
                    "problem": name,
                    "solver": s,
                    **row,
                    "instances": n_inst[name[0]],
                    "diverged": acc[s]["diverged"],
                    "iterations": iterations,
                }
            )
    results: dict[str, Any] = {
        "communication_vs_gather": vs_gather,
        "settings": _settings(iterations, n_inst, armijo_slope, hold_heights, start),
        "table": table,
        "curves": {p: {s: {k: v.tolist() for k, v in d.items()} for s, d in sv.items()} for p, sv in curves.items()},
        "paper_claims": {
            "LM lowest cost": "LM reaches the lowest cost on every problem (Table 1)",
            "distributed lower RMSE": "LM RMSE stagnates above 1 m; distributed solvers mostly below 0.6 m",
            "ladder hardest": "class L has the highest errors for every solver",
            "step size": "mean BLS/TBLS α rises to about 1.2e-3 / 1.3e-3 (RC, RM; Fig. 6)",
        },
        "solver_seconds": timing,
    }
    results["checks"] = _checks(table, curves)
    results["headline"] = _headline(table, curves, results["checks"])
    ctx.write_json("results.json", results)
    ctx.write_text("table.csv", _table_csv(table))
    ctx.write_text("table.md", _table_md(table))
    if ctx.is_root:
        _figures(ctx, curves, examples)
    return results


def _run_tasks(ctx: ExperimentContext, tasks: list[_Task]) -> list[dict[str, Any]]:
    """Every instance's solver runs, in ``--jobs`` processes (or in-process on the context's backend)."""
    jobs = ctx.workers()
    parallel = jobs > 1
    workers = min(jobs, len(tasks)) if parallel else 1
    with ctx.progress.task(
        f"uwb: {len(tasks)} instances of {len(PAPER_PROBLEMS)} problems × {len(SOLVERS)} "
        f"solvers, {workers} process(es)",
        total=len(tasks),
    ) as advance:
        if parallel:
            return parallel_map(_run_instance, tasks, jobs, advance)
        return parallel_map(partial(_run_instance, exchange=ctx.exchange), tasks, 1, advance)


def _accumulate(done: list[dict[str, Any]], timing: dict[str, float]) -> dict[str, dict[str, Any]]:
    """One problem's instances collected per solver (the runs that did not blow up; ``diverged`` counts the
    others), adding each solver's seconds to ``timing``."""
    acc: dict[str, dict[str, Any]] = {
        s: {"rmse": [], "cost": [], "step": [], "msg": [], "bytes": [], "xy": [], "z": [], "diverged": 0}
        for s in SOLVERS
    }
    for one in done:  # in instance order: the means are the serial loop's sums
        for s, r in one["runs"].items():
            a = acc[s]
            timing[s] += r["seconds"]
            a["msg"].append(r["messages"])
            a["bytes"].append(r["bytes"])
            if r["diverged"]:
                a["diverged"] += 1
                continue
            for key in ("rmse", "cost", "xy", "z") + (("step",) if "step" in r else ()):
                a[key].append(r[key])
    return acc


def _mean_curves(a: dict[str, Any], iterations: int) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """A solver's mean curves over the instances (eq. (25)) and its row of the table (final mean and median
    RMSE and cost, messages, bytes, horizontal and vertical RMSE)."""
    nanrow = [np.full(iterations + 1, np.nan)]
    rm = np.mean(a["rmse"] or nanrow, axis=0)  # eq. (25), over the runs that did not blow up
    rc = np.mean(a["cost"] or nanrow, axis=0)
    curve = {"rmse_m": rm, "rms_cost": rc}
    if a["step"]:
        curve["step_size"] = np.mean(a["step"], axis=0)
    finals = np.array([r[-1] for r in a["rmse"]]) if a["rmse"] else np.full(1, np.nan)
    finals_c = np.array([c[-1] for c in a["cost"]]) if a["cost"] else np.full(1, np.nan)
    row = {
        "rmse_m": float(rm[-1]),
        "rms_cost": float(rc[-1]),
        "rmse_m_median": float(np.median(finals)),
        "rms_cost_median": float(np.median(finals_c)),
        "messages": int(round(float(np.mean(a["msg"])))),
        "bytes": int(round(float(np.mean(a["bytes"])))),
        "rmse_xy_m": float(np.mean(a["xy"])) if a["xy"] else float("nan"),
        "rmse_z_m": float(np.mean(a["z"])) if a["z"] else float("nan"),
    }
    return curve, row


def _settings(
    iterations: int, n_inst: dict[str, int], armijo_slope: str, hold_heights: bool, start: str
) -> dict[str, Any]:
    return {
        "iterations": iterations,
        "instances": n_inst,
        "alpha": 1e-3,
        "alpha0": 1e-2,
        "beta": 0.5,
        "gamma": 0.5,
        "armijo_slope": armijo_slope,
        "hold_heights": hold_heights,
        "consensus_rounds": 1,
        "weights": "MH",
        "sigma_m": 0.15,
        "init_halfwidth_m": 5.0,
        "dim": 3,
        "anchors": 100,
        "fixed": 3,
        **({"start": start} if start != "paper" else {}),
    }


def _final(table: list[dict[str, Any]], problem: str, solver: str, key: str) -> float:
    return next(float(r[key]) for r in table if r["problem"] == problem and r["solver"] == solver)


def _checks(table: list[dict[str, Any]], curves: dict[str, Any]) -> dict[str, Any]:
    """The paper's qualitative claims evaluated on distnav's numbers (see docs/uwb.md)."""
    dist = [s for s in SOLVERS if s != "LM"]
    lm_lowest = [
        p
        for p in PAPER_PROBLEMS
        if all(not _final(table, p, "LM", "rms_cost") > _final(table, p, s, "rms_cost") for s in dist)
    ]
    lm_lowest_median = [
        p
        for p in PAPER_PROBLEMS
        if all(not _final(table, p, "LM", "rms_cost_median") > _final(table, p, s, "rms_cost_median") for s in dist)
    ]
    dist_better = {
        p: [s for s in dist if _final(table, p, s, "rmse_m") < _final(table, p, "LM", "rmse_m")] for p in PAPER_PROBLEMS
    }
    by_class = {
        c: float(np.nanmean([_final(table, p, s, "rmse_m") for p in PAPER_PROBLEMS if p[0] == c for s in dist]))
        for c in "GLR"
    }
    ls = ("N-CSG-BLS", "N-CSG-TBLS")
    by_class_ls = {
        c: float(np.nanmean([_final(table, p, s, "rmse_m") for p in PAPER_PROBLEMS if p[0] == c for s in ls]))
        for c in "GLR"
    }
    step = {s: {p: float(curves[p][s]["step_size"][-1]) for p in ("RC", "RM")} for s in ls}
    return {
        "problems_where_LM_has_lowest_cost": lm_lowest,
        "problems_where_LM_has_lowest_median_cost": lm_lowest_median,
        "distributed_solvers_with_lower_RMSE_than_LM": dist_better,
        "mean_distributed_RMSE_by_class_m": by_class,
        "hardest_class": max(by_class, key=lambda c: by_class[c]),
        "mean_line_search_RMSE_by_class_m": by_class_ls,
        "hardest_class_line_search": max(by_class_ls, key=lambda c: by_class_ls[c]),
        "final_mean_step_size": step,
    }


def _headline(table: list[dict[str, Any]], curves: dict[str, Any], checks: dict[str, Any]) -> dict[str, Any]:
    h: dict[str, Any] = {}
    its = table[0]["iterations"] if table else 0
    for p in ("GC", "LC", "RC"):
        for s in ("LM", "N-CSG-TBLS"):
            h[f"{p} RMSE {s} after {its} it. [m]"] = _final(table, p, s, "rmse_m")
    h["problems where LM has the lowest mean cost (paper: all 8)"] = len(checks["problems_where_LM_has_lowest_cost"])
    h["problems where LM has the lowest median cost"] = len(checks["problems_where_LM_has_lowest_median_cost"])
    h["problems where N-CSG-TBLS beats LM in RMSE (paper: all)"] = sum(
        "N-CSG-TBLS" in v for v in checks["distributed_solvers_with_lower_RMSE_than_LM"].values()
    )
    h["hardest class, all distributed solvers (paper: L)"] = checks["hardest_class"]
    h["hardest class, N-CSG-BLS/TBLS (paper: L)"] = checks["hardest_class_line_search"]
    for s, v in checks["final_mean_step_size"].items():
        h[f"{s} mean α at the end, RC (paper ≈{PAPER_TBLS_FINAL_STEP[s]:.1e})"] = v["RC"]
    h["bytes per message, CSG"] = _final(table, "GC", "CSG", "bytes") / max(_final(table, "GC", "CSG", "messages"), 1)
    h["bytes per message, N-CSG"] = _final(table, "GC", "N-CSG", "bytes") / max(
        _final(table, "GC", "N-CSG", "messages"), 1
    )
    return h


def _table_csv(table: list[dict[str, Any]]) -> str:
    cols = [
        "problem",
        "solver",
        "rmse_m",
        "rms_cost",
        "rmse_m_median",
        "rms_cost_median",
        "messages",
        "bytes",
        "rmse_xy_m",
        "rmse_z_m",
        "instances",
        "diverged",
        "iterations",
    ]
    lines = [",".join(cols)]
    for r in table:
        lines.append(",".join(f"{r[c]:.6g}" if isinstance(r[c], float) else str(r[c]) for c in cols))
    return "\n".join(lines) + "\n"


def _table_md(table: list[dict[str, Any]]) -> str:
    def block(cell: Callable[[str, str], str]) -> list[str]:
        head = ["| problem | " + " | ".join(SOLVERS) + " |", "|---|" + "---|" * len(SOLVERS)]
        return head + [f"| {p} | " + " | ".join(cell(p, s) for s in SOLVERS) + " |" for p in PAPER_PROBLEMS]

    out = ["# Table 1 analogue (paper 002): final mean RMSE [m] / RMS cost [m²]", ""]
    out += block(lambda p, s: f"{_final(table, p, s, 'rmse_m'):.3f} / {_final(table, p, s, 'rms_cost'):.3g}")
    out += ["", "Messages / bytes per instance:", ""]
    out += block(lambda p, s: f"{int(_final(table, p, s, 'messages'))} / {int(_final(table, p, s, 'bytes'))}")
    return "\n".join(out) + "\n"


STYLE = {
    "LM": ("k", "-"),
    "CSG": ("tab:gray", "--"),
    "N-CSG": ("tab:blue", "-"),
    "N-CSG-BLS": ("tab:orange", "-"),
    "N-CSG-TBLS": ("tab:green", "--"),
    "N-CLM": ("tab:red", ":"),
}


def _sparse_log_ticks(ax: Any) -> None:
    """At most ~5 labelled ticks per axis of a Fig. 3/4 panel: on a log axis spanning less than a decade matplotlib
    labels every minor tick, and the 8 small panels' labels ran into each other."""
    from matplotlib import ticker

    ax.yaxis.set_major_locator(ticker.LogLocator(base=10, subs=(1.0, 2.0, 5.0), numticks=6))
    ax.yaxis.set_major_formatter(ticker.FuncFormatter(lambda y, _: f"{y:g}"))
    ax.yaxis.set_minor_formatter(ticker.NullFormatter())
    ax.xaxis.set_major_locator(ticker.MaxNLocator(4, integer=True))


def _figures(ctx: ExperimentContext, curves: dict[str, Any], examples: dict[str, Any]) -> None:
    plt = pyplot()
    for key, fname, label in (
        ("rmse_m", "fig3_rmse.png", "mean RMSE [m]"),
        ("rms_cost", "fig4_cost.png", "mean RMS cost [m²]"),
    ):
        fig, axes = plt.subplots(2, 4, figsize=(16, 7), sharex=True)
        for ax, p in zip(axes.ravel(), PAPER_PROBLEMS, strict=True):
            for s in SOLVERS:
                c, ls = STYLE[s]
                ax.semilogy(np.asarray(curves[p][s][key]), color=c, ls=ls, lw=1.2, label=s)
            ax.set_title(p)
            ax.grid(alpha=0.3)
            ax.set_xlabel("iteration")
            _sparse_log_ticks(ax)
        axes[0, 0].set_ylabel(label)
        axes[1, 0].set_ylabel(label)
        axes[0, 0].legend(fontsize=7)
        ctx.save_figure(fig, fname)
    if examples:
        fig, axes = plt.subplots(
            2, len(examples), figsize=(6 * len(examples), 8), squeeze=False, gridspec_kw={"height_ratios": [3, 1]}
        )
        for col, (p, ex) in enumerate(examples.items()):
            ax, axz = axes[0, col], axes[1, col]
            t, e, f = ex["truth"], ex["estimate"], ex["fixed"]
            lk = ex["links"]
            seg = np.full((lk.shape[0], 3, 2), np.nan)  # one NaN-separated polyline: fast to draw
            seg[:, 0], seg[:, 1] = t[lk[:, 0], :2], t[lk[:, 1], :2]
            ax.plot(seg[:, :, 0].ravel(), seg[:, :, 1].ravel(), "-", color="0.85", lw=0.5)
            ax.plot(ex["initial"][:, 0], ex["initial"][:, 1], ".", color="0.6", ms=3, label="initial guess")
            ax.plot(t[:, 0], t[:, 1], "x", color="tab:green", label="truth")
            ax.plot(e[:, 0], e[:, 1], "o", mfc="none", color="tab:blue", ms=5, label="N-CSG-TBLS")
            ax.plot(t[f, 0], t[f, 1], "^", color="k", ms=8, label="fixed")
            ax.set_title(f"{p} (first instance): x–y")
            if p[0] != "L":
                ax.set_aspect("equal")
            axz.plot(t[:, 0], t[:, 2], "x", color="tab:green")
            axz.plot(e[:, 0], e[:, 2], "o", mfc="none", color="tab:blue", ms=4)
            axz.set_xlabel("x [m]")
            axz.set_ylabel("z [m]")
            axz.set_title("heights: the plane's mirror ambiguity", fontsize=9)
        axes[0, 0].legend(fontsize=7)
        ctx.save_figure(fig, "fig5_examples.png")
    fig, axes = plt.subplots(1, 2, figsize=(11, 4), sharey=True)
    for ax, p in zip(axes, ("RC", "RM"), strict=True):
        for s in ("N-CSG-BLS", "N-CSG-TBLS"):
            c, ls = STYLE[s]
            ax.plot(np.asarray(curves[p][s]["step_size"])[1:], color=c, ls=ls, label=s)
        ax.axhline(1e-3, color="k", ls=":", lw=1, label="N-CSG α = 1e-3")
        ax.set_title(f"{p}: mean step size α")
        ax.set_xlabel("iteration")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    ctx.save_figure(fig, "fig6_step_size.png")
