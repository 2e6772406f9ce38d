"""Reproduction of paper 000 §3–4, Figs. 3–5 (and the ρ study of §5.2 on a random network).

* (a) Figs. 3–4: a 2-node problem with a scalar parameter (so ``[x_1, x_2]`` is 2-D): the method of multipliers
  (eqs. (13)–(15)) versus ADMM with one consensus state (eq. (16)) from ``z⁰ = 3`` and ``z⁰ = −7``, 8 iterations,
  ``u⁰ = 0``, with the dual function ``g(u)`` (eq. (10)) along each run. The paper's data are not given; ours:
  ``a = (1, 2)``, ``R = I``, ``y = (−1, 4)``, ``W = 1`` (``x̂ = 1.4``).
* (b) Fig. 5: the 9-node graph (reconstructed from the text: ``N_1 = {1, 2}``, ``N_3 = {2, 3, 5, 6, 7, 8}``, ``C =
  {1, 3, 4, 6, 9}`` covers every link and ``{1, 3, 4, 9}`` leaves (5, 6), (6, 7) unused), ADMM of Fig. 6 with both
  sets on random problems whose ``N_i`` are all singular: convergence of ``max_i ‖x_i − x̂‖/‖x̂‖``.
* (c) ``W = ρI`` sweep on a random geometric network (all-nodes and minimum-cover ``C``), per-node curves as in
  Fig. 9, and the initial-value comparison of Fig. 10 (zero versus a previous experiment's solution).
* (d) §4.3 on a nonlinear model: range positioning of two targets, the linearized variant and the nonlinear
  x-update (eq. (23)) against centralized Gauss–Newton.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
from typing import Any

import numpy as np

from distnav.algorithms.lsq.admm import AdmmResult, admm
from distnav.algorithms.lsq.blue import LinearProblem, blue, method_of_multipliers, single_consensus_admm
from distnav.algorithms.lsq.nonlinear import admm_linearized, admm_nonlinear, gauss_newton, range_positioning_problem
from distnav.exchange import Exchange, make_exchange
from distnav.experiments.admm_checks import fig5_conditions, fig6_as_printed
from distnav.experiments.admm_figures import figures
from distnav.experiments.common import ExperimentContext, add_jobs_argument, parallel_map
from distnav.network import builders
from distnav.network.constraint_nodes import ConstraintNodes, choose_constraint_nodes
from distnav.network.graph import Graph

NAME = "admm"
TITLE = "Distributed least squares by ADMM with constraint nodes (paper 000 Figs. 3-5, 9-10)"

# Fig. 5, 1-based as in the paper
FIG5_LINKS = ((1, 2), (2, 3), (3, 5), (3, 6), (3, 7), (3, 8), (5, 6), (6, 7), (4, 5), (4, 8), (7, 9), (8, 9))
FIG5_POSITIONS = (
    (0.0, 2.0),
    (1.0, 2.2),
    (2.0, 1.6),
    (4.0, 0.0),
    (3.0, 0.6),
    (3.2, 1.8),
    (3.0, 2.8),
    (2.6, -0.2),
    (4.2, 2.0),
)
C_FULL = (1, 3, 4, 6, 9)
C_REDUCED = (1, 3, 4, 9)
TWO_NODE: dict[str, Any] = {"a": (1.0, 2.0), "R": (1.0, 1.0), "y": (-1.0, 4.0), "W": 1.0}
ITERATIONS_2D = 8


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_jobs_argument(parser)


@dataclass(frozen=True)
class _Run:
    """One ADMM run of a study (Fig. 5 draws, the ρ sweep): what a worker process needs to run it."""

    problem: LinearProblem
    graph: Graph
    constraint_nodes: ConstraintNodes
    rho: float
    max_iterations: int
    reference: np.ndarray
    monitor_every: int = 1


def _iterations_of(run: _Run, exchange: Callable[[Graph], Exchange] | None = None) -> int | None:
    """Iterations of Fig. 6 until ``max_i ‖x_i − x̂‖/‖x̂‖ ≤ 1e-6`` (None if never within ``max_iterations``; the
    residuals are not monitored: only the distance to x̂ stops the run)."""
    make = exchange or (lambda graph: make_exchange(graph))
    res = admm(
        run.problem,
        run.graph,
        constraint_nodes=run.constraint_nodes,
        W=run.rho,
        max_iterations=run.max_iterations,
        tol=0.0,
        reference=run.reference,
        stop_at_reference=1e-6,
        record_nodes=False,
        exchange=make(run.graph),
        monitor_every=run.monitor_every,
    )
    return _iters(res)


def iterations_to_1e6(
    ctx: ExperimentContext,
    problem: LinearProblem,
    x_hat: np.ndarray,
    g: Graph,
    C: ConstraintNodes,
    rho: float,
    max_iterations: int,
) -> int:
    """Iterations of Fig. 6 until ``max_i ‖x_i − x̂‖/‖x̂‖ ≤ 1e-6`` (``max_iterations`` if never)."""
    v = _iterations_of(_Run(problem, g, C, rho, max_iterations, x_hat, monitor_every=0), ctx.exchange)
    return max_iterations if v is None else v


def _study(ctx: ExperimentContext, runs: list[_Run], advance: Callable[[int], None]) -> list[int | None]:
    """:func:`_iterations_of` of every run, in worker processes (``--jobs``) or, under MPI, here in step."""
    jobs = ctx.workers()
    fn = _iterations_of if jobs > 1 else partial(_iterations_of, exchange=ctx.exchange)
    return parallel_map(fn, runs, jobs, advance)


def fig5_graph() -> Graph:
    """The 9-node graph of paper 000 Fig. 5 (node names 1..9, ids 0..8)."""
    return Graph.from_links(
        9,
        [(a - 1, b - 1) for a, b in FIG5_LINKS],
        names=[str(k) for k in range(1, 10)],
        positions=np.array(FIG5_POSITIONS),
    )


def two_node_problem() -> LinearProblem:
    a, R, y = (tuple(float(v) for v in TWO_NODE[k]) for k in ("a", "R", "y"))
    return LinearProblem.from_blocks(
        [np.array([[a[0]]]), np.array([[a[1]]])],
        [np.array([y[0]]), np.array([y[1]])],
        [np.array([[R[0]]]), np.array([[R[1]]])],
    )


def random_problem(rng: np.random.Generator, n: int, m: int, p: int, sigma: float = 0.1) -> LinearProblem:
    """``m < p`` rows per node (every ``N_i`` singular), standard-normal design, noise σ, unit weights (``R_i = I``:
    ordinary least squares, so ``ρ`` is measured against ``N_i = A_iᵀA_i``), rank(A) = p."""
    A = rng.normal(size=(n, m, p))
    y = np.einsum("nmp,p->nm", A, rng.normal(size=p)) + sigma * rng.normal(size=(n, m))
    return LinearProblem.from_stacked(A, y)


def _iters(res: AdmmResult, level: str = "1e-06") -> int | None:
    v = res.iterations_to[level]
    return None if v is None else int(v)


# ----------------------------------------------------------------------------------------------- (a)
def part_a() -> dict[str, Any]:
    prob = two_node_problem()
    W = TWO_NODE["W"]
    sol = blue(prob, W=W)
    mom = method_of_multipliers(prob, W=W, iterations=ITERATIONS_2D)
    runs = {"method_of_multipliers": mom}
    for z0 in (3.0, -7.0):
        runs[f"admm_z0={z0:g}"] = single_consensus_admm(prob, W=W, iterations=ITERATIONS_2D, z0=z0)
    out: dict[str, Any] = {
        "x_hat": float(sol.x[0]),
        "optimal_value": sol.cost,
        "u_hat": sol.multipliers[:, 0].tolist() if sol.multipliers is not None else None,
    }
    for name, r in runs.items():
        g = np.concatenate([[r.dual_value_initial], r.trace["dual_value"]])
        out[name] = {
            "x": r.trace["x"][:, :, 0].tolist(),
            "z": r.trace["z"][:, 0].tolist(),
            "u": r.trace["u"][:, :, 0].tolist(),
            "dual_value": g.tolist(),
            "dual_increasing": bool(np.all(np.diff(g) >= -1e-12)),
            "final_error": float(np.abs(r.trace["x"][-1, :, 0] - sol.x[0]).max()),
        }
    return out


# ----------------------------------------------------------------------------------------------- (b)
def fig5_sets(g: Graph) -> dict[str, ConstraintNodes]:
    """The constraint-node sets of the Fig. 5 study: the paper's two and all nodes."""
    return {
        "C_full": choose_constraint_nodes(g, [k - 1 for k in C_FULL]),
        "C_reduced": choose_constraint_nodes(g, [k - 1 for k in C_REDUCED]),
        "C_all": choose_constraint_nodes(g, "all"),
    }


def fig5_problems(ctx: ExperimentContext, draws: int) -> tuple[list[LinearProblem], list[np.ndarray]]:
    """The seeded random problems of the Fig. 5 study (``p = 4``, ``m_i = 2``) and their BLUEs."""
    rng = ctx.rng(11)
    problems = [random_problem(rng, 9, 2, 4) for _ in range(draws)]
    return problems, [blue(pr).x for pr in problems]


def part_b(
    ctx: ExperimentContext, draws: int, iterations: int, rho: float, rho_grid: tuple[float, ...]
) -> dict[str, Any]:
    from distnav.algorithms.lsq.gather_data import GATHER_DATA, node_data_bytes
    from distnav.algorithms.result import compare_with_gather

    g = fig5_graph()
    sets = fig5_sets(g)
    problems, refs = fig5_problems(ctx, draws)
    curves: dict[str, Any] = {}
    finals: dict[str, float] = {}
    comm: dict[str, Any] = {}
    vs_gather: dict[str, Any] = {}
    first: dict[str, int | None] = {}
    for key, C in sets.items():  # the primary runs: first problem, ρ = rho, full length
        res = admm(
            problems[0],
            g,
            constraint_nodes=C,
            W=rho,
            max_iterations=iterations,
            tol=0.0,
            reference=refs[0],
            exchange=ctx.exchange(g),
        )
        curves[key] = res.trace["relative_max_distance"]
        finals[key] = float(res.trace["relative_max_distance"][-1])
        first[key] = _iters(res)
        comm[key] = {**res.comm.as_dict(), "messages_per_iteration": int(res.comm.messages_per_round[1:3].sum())}
        vs_gather[f"Fig. 5, {key}"] = compare_with_gather(
            res.comm, g, node_data_bytes(problems[0]), data=f"each node's data ({GATHER_DATA})"
        ).as_dict()
    # the study: every problem, every ρ of the grid, iterations to 1e-6
    table: dict[str, dict[str, list[int]]] = {f"{r:g}": {k: [] for k in sets} for r in rho_grid}
    cells = [
        (f"{r:g}", key, _Run(pr, g, C, r, iterations * 3, xh, monitor_every=0))
        for pr, xh in zip(problems, refs, strict=True)
        for r in rho_grid
        for key, C in sets.items()
    ]
    with ctx.progress.task(
        f"admm: Fig. 5 graph, {draws} problems × {len(rho_grid)} ρ × {len(sets)} constraint sets", total=len(cells)
    ) as adv:
        its = _study(ctx, [c[2] for c in cells], adv)
    for (label, key, run), v in zip(cells, its, strict=True):
        table[label][key].append(run.max_iterations if v is None else v)
    study: dict[str, dict[str, Any]] = {}
    for label, row in table.items():
        full, red = np.array(row["C_full"]), np.array(row["C_reduced"])
        study[label] = {
            "median_iterations_to_1e-6": {k: float(np.median(v)) for k, v in row.items()},
            "reduced_slower_than_full": int((red > full).sum()),
            "reduced_faster_than_full": int((red < full).sum()),
        }
    best = {k: min(float(v["median_iterations_to_1e-6"][k]) for v in study.values()) for k in sets}
    return {
        "rho": rho,
        "draws": draws,
        "rho_grid": list(rho_grid),
        **{key: {"iterations_to_1e-6": first[key], **sets[key].summary(), "communication": comm[key]} for key in sets},
        "rho_study": study,
        "best_median_over_rho": best,
        "min_cover": choose_constraint_nodes(g, "min_cover").summary(),
        "_curves": curves,
        "_finals": finals,
        "_vs_gather": vs_gather,
        "_graph": g,
        "_sets": sets,
    }


# ----------------------------------------------------------------------------------------------- (c)
def part_c(ctx: ExperimentContext, n: int, rhos: np.ndarray, iterations: int) -> dict[str, Any]:
    """(c): the ``W = ρI`` sweep on an ``n``-node random geometric network (all nodes and minimum-cover ``C``),
    per-node curves around the best ρ (Fig. 9), zero against a previous experiment's start (Fig. 10, §4.3), and
    a final run to tol 1e-12 at the best ρ."""
    rng = ctx.rng(21)
    g = builders.connected_random_geometric(n, mean_degree=6, rng=rng)
    prob = random_problem(rng, n, 3, 6)
    xh = blue(prob).x
    sets = {"all": choose_constraint_nodes(g, "all"), "min_cover": choose_constraint_nodes(g, "min_cover")}
    sweep = _rho_sweep(ctx, prob, g, sets, xh, rhos, iterations)
    arr = np.array([np.inf if v is None else v for v in sweep["min_cover"]], float)
    best = float(rhos[int(np.argmin(arr))])
    run_c = partial(_admm_c, ctx, prob, g, sets["min_cover"], xh, iterations)
    # Fig. 9: per-node curves for three ρ around the best; Fig. 10: zero vs previous-experiment initial values
    show = [best] if ctx.quick else sorted({best / 10, best, best * 10})
    curves = {f"{rho:.3g}": run_c(rho).trace["distance_to_reference"] for rho in show}
    # a previous experiment: same nodes and parameters, fresh noise (σ = 0.1); its BLUE starts this run (§4.3)
    y_prev = np.einsum("nmp,p->nm", prob.A, xh) + 0.1 * rng.normal(size=prob.y.shape)
    x_prev = blue(LinearProblem.from_stacked(prob.A, y_prev, prob.R)).x
    init_runs = {}
    for label, init in {"zero": "zero", "previous": x_prev}.items():
        res = run_c(best, init=init, record_nodes=False)
        init_runs[label] = {
            "iterations_to_1e-6": _iters(res),
            "iterations_to_1e-8": _iters(res, "1e-08"),
            "initial_relative_distance": float(res.trace["relative_max_distance"][0]),
            "final_relative_distance": float(res.trace["relative_max_distance"][-1]),
        }
    final = run_c(best, tol=1e-12, record_nodes=False)
    return {
        "n_nodes": n,
        "n_links": g.n_links,
        "p": 6,
        "m_i": 3,
        "rho": rhos.tolist(),
        "iterations_to_1e-6": sweep,
        "best_rho_min_cover": best,
        "constraint_nodes": {k: {"n": c.size, "method": c.method, "optimal": c.optimal} for k, c in sets.items()},
        "initial_values": init_runs,
        "final_run": {
            "rho": best,
            **final.summary(),
            "relative_max_distance": float(final.trace["relative_max_distance"][-1]),
        },
        "_curves": curves,
    }


def _rho_sweep(
    ctx: ExperimentContext,
    prob: LinearProblem,
    g: Graph,
    sets: dict[str, ConstraintNodes],
    xh: np.ndarray,
    rhos: np.ndarray,
    iterations: int,
) -> dict[str, list[int | None]]:
    """Iterations to 1e-6 for every ρ and constraint-node set (in parallel with ``--jobs``)."""
    sweep: dict[str, list[int | None]] = {k: [] for k in sets}
    # monitor_every=0: with tol=0 the residuals never stop a run (only the distance to x̂ does), so not computing
    # them leaves every count unchanged
    cells = [
        (key, _Run(prob, g, C, float(rho), iterations, xh, monitor_every=0)) for rho in rhos for key, C in sets.items()
    ]
    with ctx.progress.task(f"admm: ρ sweep on a {g.n_nodes}-node random network", total=len(cells)) as adv:
        its = _study(ctx, [c[1] for c in cells], adv)
    for (key, _), v in zip(cells, its, strict=True):
        sweep[key].append(v)
    return sweep


def _admm_c(
    ctx: ExperimentContext,
    prob: LinearProblem,
    g: Graph,
    C: ConstraintNodes,
    xh: np.ndarray,
    iterations: int,
    rho: float,
    *,
    init: Any = "zero",
    tol: float = 0.0,
    record_nodes: bool = True,
) -> AdmmResult:
    """One ADMM run of part (c) with the minimum-cover constraint nodes, tracked against x̂."""
    return admm(
        prob,
        g,
        constraint_nodes=C,
        W=rho,
        init=init,
        max_iterations=iterations,
        tol=tol,
        reference=xh,
        record_nodes=record_nodes,
        exchange=ctx.exchange(g),
    )


# ----------------------------------------------------------------------------------------------- (d)
def part_d(ctx: ExperimentContext, rho: float = 3.0) -> dict[str, Any]:
    """§4.3 on a nonlinear model: 20 nodes range two 2-D targets (m_i = 2 < p = 4), σ = 0.5 m; the linearized
    variant and the nonlinear x-update (eq. 23) against centralized Gauss–Newton, all from the same start."""
    rng = ctx.rng(31)
    g = builders.connected_random_geometric(20, mean_degree=5, rng=rng, size=100.0)
    targets = np.array([[30.0, 60.0], [70.0, 25.0]])
    assert g.positions is not None
    prob = range_positioning_problem(g.positions, targets, sigma_m=0.5, rng=rng)
    x0 = targets.ravel() + rng.uniform(-5, 5, 4)
    gn = gauss_newton(prob, x0)
    xg = gn.estimates[0]
    C = choose_constraint_nodes(g, "min_cover")
    with ctx.progress.task("admm: nonlinear range positioning (linearized and eq. 23)"):
        lin = admm_linearized(
            prob, g, x0, constraint_nodes=C, W=rho, reference=xg, inner_tol=1e-10, exchange=ctx.exchange(g)
        )
        nl = admm_nonlinear(
            prob,
            g,
            x0,
            constraint_nodes=C,
            W=rho,
            reference=xg,
            max_iterations=3000,
            tol=1e-10,
            exchange=ctx.exchange(g),
        )
    return {
        "n_nodes": g.n_nodes,
        "targets_m": targets.tolist(),
        "sigma_m": 0.5,
        "rho": rho,
        "x0": x0.tolist(),
        "gauss_newton": {
            "x": xg.tolist(),
            "iterations": gn.iterations,
            "error_vs_truth_m": float(np.abs(xg - targets.ravel()).max()),
        },
        "linearized": {
            "outer_iterations": lin.iterations,
            "admm_iterations": lin.inner_iterations_total,
            "max_deviation_from_gauss_newton_m": float(np.abs(lin.estimates - xg).max()),
            "messages": lin.comm.messages,
        },
        "nonlinear_eq23": {
            "iterations": nl.iterations,
            "converged": nl.converged,
            "max_deviation_from_gauss_newton_m": float(np.abs(nl.estimates - xg).max()),
            "messages": nl.comm.messages,
        },
        "_graph": g,
        "_lin": lin,
        "_nl": nl,
        "_xg": xg,
    }


# ----------------------------------------------------------------------------------------------- run
def run(ctx: ExperimentContext) -> dict[str, Any]:
    quick = ctx.quick
    a = part_a()
    b = part_b(
        ctx,
        draws=3 if quick else 40,
        iterations=400 if quick else 1000,
        rho=1.0,
        rho_grid=(0.3, 1.0, 3.0) if quick else (0.3, 1.0, 3.0, 10.0),
    )
    rhos = np.array([0.3, 1.0, 3.0, 10.0]) if quick else np.geomspace(0.1, 30, 11)
    c = part_c(ctx, n=20 if quick else 100, rhos=rhos, iterations=600 if quick else 5000)
    d = part_d(ctx)
    final_dev = b["_finals"]["C_full"]
    results: dict[str, Any] = {
        "fig3_4": a,
        "fig5": {k: v for k, v in b.items() if not k.startswith("_")},
        "rho_sweep": {k: v for k, v in c.items() if not k.startswith("_")},
        "nonlinear": {k: v for k, v in d.items() if not k.startswith("_")},
        "final_max_deviation": final_dev,
        "final_max_deviation_reduced": b["_finals"]["C_reduced"],
        "communication_vs_gather": b["_vs_gather"],
        "fig5_conditions_18": fig5_conditions(b["_graph"], b["_sets"], b["_finals"]),
        "fig6_as_printed": fig6_as_printed(
            ctx, b["_graph"], b["_sets"]["C_full"], fig5_problems(ctx, 1)[0][0], 1.0, 400 if quick else 2000
        ),
        "headline": {
            "Fig. 5, C={1,3,4,6,9}: iterations to 1e-6": b["C_full"]["iterations_to_1e-6"],
            "Fig. 5, C={1,3,4,9}: iterations to 1e-6": b["C_reduced"]["iterations_to_1e-6"],
            **{
                f"Fig. 5, ρ={r}: reduced C slower than full in draws (of {b['draws']})": v["reduced_slower_than_full"]
                for r, v in b["rho_study"].items()
            },
            "Fig. 5: final max_i ‖x_i − x̂‖/‖x̂‖ (C full)": final_dev,
            "2-node: method of multipliers g(u) increasing": a["method_of_multipliers"]["dual_increasing"],
            "2-node: ADMM z0=−7 g(u) increasing": a["admm_z0=-7"]["dual_increasing"],
            f"{c['n_nodes']}-node net: best ρ (min cover)": c["best_rho_min_cover"],
            f"{c['n_nodes']}-node net: iterations to 1e-6 at best ρ (min cover)": min(
                v for v in c["iterations_to_1e-6"]["min_cover"] if v is not None
            ),
            f"{c['n_nodes']}-node net: final relative deviation (tol 1e-12)": c["final_run"]["relative_max_distance"],
            "ranges: linearized ADMM − Gauss-Newton [m]": d["linearized"]["max_deviation_from_gauss_newton_m"],
            "ranges: nonlinear x-update (eq. 23) − Gauss-Newton [m]": d["nonlinear_eq23"][
                "max_deviation_from_gauss_newton_m"
            ],
        },
    }
    ctx.write_json("results.json", results)
    if ctx.is_root:
        figures(ctx, a, b, c, d, problem=two_node_problem(), two_node=TWO_NODE, iterations_2d=ITERATIONS_2D)
    return results
