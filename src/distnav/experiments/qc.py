"""Reproduction ``qc``: distributed precision and data snooping (issue 12; paper 000 §6's open questions).

Paper 000 ends (§6) asking how to compute the precision of the solution and how to validate it in a distributed
manner. This run answers it on the 110-station code-bias network of ``reproduce codebias`` (explicit observation
equations (24)/(26), correlated differenced observations; 2 epochs, 8 gross errors; ``--quick``: 1 epoch, 3
errors): gross errors of ±6σ are injected into observation rows, and distributed data snooping
(:func:`distnav.algorithms.lsq.qc.admm_data_snooping`: ADMM estimate, distributed covariance, local w-tests,
removal of the worst, warm-started re-convergence) is compared with centralized iterative data snooping
(:func:`distnav.algorithms.statistics.data_snooping`) on the same data: detections, false alarms, the distance of
the final solution to the clean centralized one, the messages it costs. The CKF half (local innovation tests) is
``experiments/qc_ckf.py`` when present. :func:`gross_error_problem` is the small simulated network shared by the
tests and ``benchmarks/bench_qc.py``.
"""

from __future__ import annotations

import importlib
import importlib.util
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.linalg import block_diag

from distnav.algorithms.lsq.blue import LinearProblem, blue
from distnav.algorithms.lsq.qc import admm_data_snooping
from distnav.algorithms.statistics import data_snooping
from distnav.experiments.codebias import _simulate, constellation, synthetic_igs_network
from distnav.experiments.common import ExperimentContext, pyplot
from distnav.models.gnss.constants import NS_TO_M
from distnav.network import builders
from distnav.network.graph import Graph


@dataclass(frozen=True, eq=False)
class GrossErrorProblem:
    """A simulated network: ``graph``, the data with gross errors (``problem``) and without (``clean``), the flat
    indices of the corrupted observations (``outliers``, node-major) and the truth ``x``."""

    graph: Graph
    problem: LinearProblem
    clean: LinearProblem
    outliers: np.ndarray
    x: np.ndarray


def gross_error_problem(
    rng: np.random.Generator,
    *,
    n: int = 20,
    m: int = 3,
    p: int = 6,
    n_outliers: int = 2,
    size_sigma: float = 6.0,
    mean_degree: float = 5.0,
) -> GrossErrorProblem:
    """``m < p`` rows per node (every ``N_i`` singular), standard-normal design, σ_j ~ U(0.5, 2) per observation
    (diagonal ``R_i``), and ``n_outliers`` observations shifted by ``± size_sigma·σ_j``."""
    g = builders.connected_random_geometric(n, mean_degree=mean_degree, rng=rng)
    A = rng.normal(size=(n, m, p))
    x = rng.normal(size=p)
    sigma = rng.uniform(0.5, 2.0, size=(n, m))
    y = np.einsum("nmp,p->nm", A, x) + sigma * rng.normal(size=(n, m))
    bad = np.sort(rng.choice(n * m, n_outliers, replace=False))
    y_bad = y.copy().ravel()
    y_bad[bad] += size_sigma * sigma.ravel()[bad] * rng.choice([-1.0, 1.0], n_outliers)
    return GrossErrorProblem(
        graph=g,
        problem=LinearProblem.from_stacked(A, y_bad.reshape(n, m), sigma**2),
        clean=LinearProblem.from_stacked(A, y, sigma**2),
        outliers=bad,
        x=x,
    )


# ----------------------------------------------------------------------------------------------- reproduction
NAME = "qc"
TITLE = "Distributed precision and data snooping: ADMM on the code-bias network with gross errors (issue 12)"

#: Captions for the demo report (the CKF half's figures come from ``qc_ckf``).
FIGURE_CAPTIONS = {
    "fig_qc_snooping.png": "Left: |w| of every observation of the code-bias network in the first distributed solution, "
    "the injected 6σ errors (circles), what distributed data snooping removed (crosses) and the "
    "critical value. Right: largest distance of any node's estimate to the clean centralized "
    "solution without snooping, after distributed and after centralized snooping (log scale).",
    "ckf_detection.png": "CKF half: detection and false-alarm rates of the nodes' local innovation tests against a "
    "central tested filter (left), and the final distance to the clean central filter of the "
    "tested CKF, the tested central filter and the untested CKF (right).",
    "ckf_distance_trace.png": "CKF half: per epoch, the largest distance of a node's estimate to the clean CKF, with "
    "and without local tests; red lines mark epochs with an injected gross error.",
}
LEVEL = 0.001
GROSS_SIGMA = 6.0
RHO_PER_EPOCH = 0.5


def codebias_qc_problem(ctx: ExperimentContext, epochs: int, n_errors: int) -> dict[str, Any]:
    """The 110-station code-bias network of ``reproduce codebias`` with its explicit observation equations (eqs.
    (24)/(26): differenced code observables, correlated ``R_i`` per epoch), and ``n_errors`` rows shifted by
    ``±6σ`` of the row (non-pivot differences change exactly one row)."""
    net = synthetic_igs_network(ctx.rng(1))
    orbit, svs, t0, orbit_text = constellation(None, None)
    sat = ctx.rng(2).normal(0.0, 3.0 * NS_TO_M, size=(len(svs), 3))
    rx = ctx.rng(4).normal(0.0, 5.0 * NS_TO_M, size=(net.graph.n_nodes, 3))
    data = _simulate(net, orbit, svs, t0, epochs, ctx.rng(3), sat, rx)  # the sessions of `reproduce codebias`
    data = data.estimable_subset()
    data.check()
    blocks = [data.node_system(i) for i in range(data.n_stations)]
    clean = LinearProblem.from_blocks(
        [b[0] for b in blocks],
        [b[2] for b in blocks],
        [b[1] for b in blocks],
        parameter_names=data.svs,
        node_names=data.stations,
    )
    rows = clean.rows
    offsets = np.concatenate([[0], np.cumsum(rows)])
    rng = ctx.rng(6)
    bad = np.sort(rng.choice(int(rows.sum()), n_errors, replace=False))
    y = clean.y.copy()
    for k in bad:
        i = int(np.searchsorted(offsets, k, side="right") - 1)
        j = int(k - offsets[i])
        y[i, j] += GROSS_SIGMA * np.sqrt(clean.R[i, j, j]) * rng.choice([-1.0, 1.0])
    problem = LinearProblem.from_blocks(
        [b[0] for b in blocks],
        [y[i, : rows[i]] for i in range(len(blocks))],
        [b[1] for b in blocks],
        parameter_names=data.svs,
        node_names=data.stations,
    )
    return {
        "graph": net.graph,
        "problem": problem,
        "clean": clean,
        "outliers": bad,
        "epochs": data.n_epochs,
        "satellites": list(data.svs),
        "constellation": orbit_text,
    }


def _stacked(problem: LinearProblem) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(A, y, R)`` of all real rows, node-major (``R`` block diagonal)."""
    keep = np.concatenate([i * problem.max_rows + np.arange(problem.rows[i]) for i in range(problem.n_nodes)])
    R = block_diag(*[problem.R[i, : problem.rows[i], : problem.rows[i]] for i in range(problem.n_nodes)])
    return problem.A.reshape(-1, problem.n_params)[keep], problem.y.ravel()[keep], R


def run(ctx: ExperimentContext) -> dict[str, Any]:
    from distnav.algorithms.lsq.gather_data import node_data_bytes
    from distnav.algorithms.result import compare_with_gather

    epochs, n_errors = (1, 3) if ctx.quick else (2, 8)
    with ctx.progress.task(f"qc: simulate the 110-station code-bias network, {epochs} epoch(s), {n_errors} errors"):
        case = codebias_qc_problem(ctx, epochs, n_errors)
    g: Graph = case["graph"]
    prob: LinearProblem = case["problem"]
    bad = set(case["outliers"].tolist())
    x_clean = blue(case["clean"]).x
    x_raw = blue(prob).x
    W = RHO_PER_EPOCH * case["epochs"]  # ρ against one epoch's information, as in `reproduce codebias`
    res, ref, A, R = _snooping(ctx, prob, g, W)
    assert res.tests is not None and res.precision is not None and res.tests.comm is not None
    removed = set(res.tests.removed)
    blue_cov = np.linalg.inv(A.T @ np.linalg.solve(R, A))
    dist = {
        "no_snooping": float(np.abs(x_raw - x_clean).max()),
        "distributed": float(np.abs(res.estimates - x_clean[None]).max()),
        "centralized": float(np.abs(ref.x - x_clean).max()),
    }
    results: dict[str, Any] = {
        "network": {
            "n_nodes": g.n_nodes,
            "n_links": g.n_links,
            "observations": int(prob.rows.sum()),
            "epochs": case["epochs"],
            "satellites": case["satellites"],
            "constellation": case["constellation"],
        },
        "level": LEVEL,
        "critical_value": res.tests.critical_value,
        "gross_error_sigma": GROSS_SIGMA,
        "rho": W,
        "injected": sorted(bad),
        "distributed": {
            **_removals(res.tests.removed, bad),
            "variance_factor": res.precision.variance_factor,
            "redundancy": res.precision.redundancy,
            "extra_iterations": res.tests.iterations,
            "extra_messages": res.tests.comm.messages,
            "iterations_last_solution": res.iterations,
            "messages_total": res.comm.messages,
        },
        "communication_vs_gather": {
            "distributed data snooping": compare_with_gather(
                res.comm,
                g,
                node_data_bytes(prob, normals=False),
                data="each station's observations (data snooping tests them)",
                node_label="station",
            ).as_dict()
        },
        "centralized": {
            **_removals(ref.removed, bad),
            "variance_factor": ref.variance_factor,
            "redundancy": ref.redundancy,
        },
        "same_removals": res.tests.removed == ref.removed,
        "max_abs_w_difference": float(np.nanmax(np.abs(res.tests.w - ref.w))),
        "covariance_relative_error_vs_final_centralized": float(
            np.abs(res.precision.covariance - ref.covariance[None]).max() / np.abs(ref.covariance).max()
        ),
        "max_distance_to_clean_centralized_m": dist,
        "sigma_clean_centralized_m": np.sqrt(np.diag(blue_cov)).tolist(),
    }
    ckf_part = _ckf_half(ctx)
    if ckf_part is not None:
        results["ckf"] = ckf_part
    results["headline"] = _headline(results, res, ref, bad, removed, dist)
    if ckf_part is not None:
        results["headline"].update({f"CKF: {k}": v for k, v in ckf_part.get("headline", {}).items()})
    else:
        results["headline"]["CKF half"] = "not run (experiments/qc_ckf.py absent)"
    ctx.write_json("results.json", results)
    if ctx.is_root:
        _figures(ctx, prob, res, ref, bad, dist)
    return results


def _snooping(
    ctx: ExperimentContext, prob: LinearProblem, g: Graph, W: float
) -> tuple[Any, Any, np.ndarray, np.ndarray]:
    """Distributed data snooping by ADMM and the centralized reference on the stacked rows ``(A, R)``."""
    with ctx.progress.task("qc: distributed data snooping (ADMM estimate, precision, w-tests, removals)"):
        res = admm_data_snooping(prob, g, W=W, level=LEVEL, tol=1e-10, max_iterations=20000, exchange=ctx.exchange(g))
    with ctx.progress.task("qc: centralized data snooping (the reference)"):
        A, y, R = _stacked(prob)
        ref = data_snooping(A, y, R, level=LEVEL)
    return res, ref, A, R


def _removals(removed: Any, bad: set[int]) -> dict[str, Any]:
    """What a data snooping removed, how many of the injected errors that finds and how many false alarms."""
    return {"removed": list(removed), "detected": len(set(removed) & bad), "false_alarms": len(set(removed) - bad)}


def _headline(
    results: dict[str, Any], res: Any, ref: Any, bad: set[int], removed: set[int], dist: dict[str, float]
) -> dict[str, Any]:
    return {
        "gross errors injected / detected (distributed)": f"{len(bad)} / {len(removed & bad)}",
        "false alarms (distributed / centralized)": (
            f"{results['distributed']['false_alarms']} / {results['centralized']['false_alarms']}"
        ),
        "same removals as centralized data snooping": results["same_removals"],
        "max |w| distributed − centralized": results["max_abs_w_difference"],
        "distance to clean solution [m]: none / distributed / centralized": (
            f"{dist['no_snooping']:.3g} / {dist['distributed']:.3g} / {dist['centralized']:.3g}"
        ),
        "σ̂² (distributed / centralized)": f"{res.precision.variance_factor:.6g} / {ref.variance_factor:.6g}",
        "extra iterations / messages after the first solution": f"{res.tests.iterations} / {res.tests.comm.messages}",
    }


def _ckf_half(ctx: ExperimentContext) -> dict[str, Any] | None:
    """The consensus-Kalman-filter half (local innovation tests), written by the Kalman work in
    ``experiments/qc_ckf.py``; HOOK: skipped while that module does not exist."""
    if importlib.util.find_spec("distnav.experiments.qc_ckf") is None:
        return None
    mod = importlib.import_module("distnav.experiments.qc_ckf")
    out: dict[str, Any] = mod.run(ctx)
    return out


def _figures(
    ctx: ExperimentContext, prob: LinearProblem, res: Any, ref: Any, bad: set[int], dist: dict[str, float]
) -> None:
    plt = pyplot()
    A, y, R = _stacked(prob)
    first = data_snooping(A, y, R, level=LEVEL, max_removals=0)  # the w of the first solution
    fig, axes = plt.subplots(1, 2, figsize=(13, 4.5))
    idx = np.arange(first.w.size)
    axes[0].plot(idx, np.abs(first.w), ".", ms=3, color="0.5", label="|w|, first solution (all observations)")
    inj = np.array(sorted(bad))
    axes[0].plot(inj, np.abs(first.w[inj]), "o", mfc="none", color="tab:red", ms=8, label="injected 6σ errors")
    rem = np.array(res.tests.removed, dtype=int)
    if rem.size:
        axes[0].plot(rem, np.abs(first.w[rem]), "x", color="k", ms=7, label="removed (distributed)")
    axes[0].axhline(
        res.tests.critical_value,
        color="tab:blue",
        ls="--",
        lw=1,
        label=f"critical value {res.tests.critical_value:.2f} (level {LEVEL:g})",
    )
    axes[0].set_xlabel("observation (node-major)")
    axes[0].set_ylabel("|w|")
    axes[0].legend(fontsize=7)
    axes[0].set_title("w-tests of the code-bias network")
    labels = ["no snooping", "distributed", "centralized"]
    vals = [dist["no_snooping"], dist["distributed"], dist["centralized"]]
    axes[1].bar(labels, vals, color=["tab:gray", "tab:red", "tab:blue"])
    axes[1].set_yscale("log")
    axes[1].set_ylabel("max |x − x̂_clean| [m]")
    axes[1].set_title("distance to the clean centralized solution")
    ctx.save_figure(fig, "fig_qc_snooping.png")
