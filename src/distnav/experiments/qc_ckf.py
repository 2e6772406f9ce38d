"""The CKF half of ``reproduce qc``: local innovation tests against injected gross errors (issue 12 items 3, 4, 6).

Scenario: a connected random geometric network of 12 nodes (mean degree 4), Protocol 3, k_n = 6 consensus rounds
per epoch. State: 2 random-walk entries (σ = 0.1 per epoch) and 3 constant biases, p = 5; every node observes 4
random linear combinations per epoch (σ = U(0.5, 1.5)), 40 epochs (quick: 20). In every trial a fresh noise
realization is drawn and gross errors of ``GROSS_SIGMA`` σ are added to ``N_GROSS`` random observations (epoch ≥ 2,
so that every node can predict). Each node runs the CKF with the exact node-local precision and tests its
predicted residuals at level ``LEVEL`` before its normals enter the consensus (``ckf(..., test_level=...)``).

Reference: the central information filter fed every node's data, testing the same per-node predicted residuals
with the central prediction and its covariance (written here, on
:func:`distnav.algorithms.kalman.ckf_qc.innovation_test`
and the information kernel). Reported, distributed vs central: detection rate (injected errors rejected), false
alarms (clean observations rejected, per clean observation tested), the final distance of the estimates to the
*clean* central filter (no gross errors, no tests), and the same for the untested CKF. Also the node-local
precision: exact form vs Fig. 7 (ratio 1) and the cheap bound's ratio.

``run(ctx)`` returns the results (with a ``"headline"``) and saves ``ckf_*.png``; ``reproduce qc`` writes them.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from distnav.algorithms.consensus.averaging import consensus_schedule
from distnav.algorithms.kalman import (
    DynamicModel,
    InformationKernel,
    ObservationSeries,
    central_filter,
    pseudo_inverse_psd,
    simulate_states,
)
from distnav.algorithms.kalman.ckf import ckf
from distnav.algorithms.kalman.ckf_qc import innovation_test
from distnav.algorithms.statistics import critical_value
from distnav.experiments.common import ExperimentContext, pyplot
from distnav.network import builders
from distnav.network.graph import Graph

__all__ = ["run", "central_tested_filter"]

N_NODES = 12
N_OBS = 4
N_RW, N_BIAS = 2, 3
RW_STD = 0.1
KN = 6
LEVEL = 0.001
GROSS_SIGMA = 8.0
N_GROSS = 6
Epochs = list[list[tuple[np.ndarray, np.ndarray, np.ndarray]]]


def _model() -> DynamicModel:
    p = N_RW + N_BIAS
    return DynamicModel(p, noise_map=np.eye(p)[:, :N_RW], noise_reduced_cov=np.eye(N_RW) * RW_STD**2)


def _designs(rng: np.random.Generator, T: int) -> tuple[np.ndarray, np.ndarray]:
    p = N_RW + N_BIAS
    return rng.standard_normal((T, N_NODES, N_OBS, p)), rng.uniform(0.5, 1.5, (T, N_NODES, N_OBS))


def _epochs(A: np.ndarray, sig: np.ndarray, y: np.ndarray) -> Epochs:
    return [[(A[t, i], sig[t, i] ** 2, y[t, i]) for i in range(A.shape[1])] for t in range(A.shape[0])]


def central_tested_filter(
    dyn: DynamicModel,
    epochs: Epochs,
    level: float,
) -> tuple[np.ndarray, set[tuple[int, int, int]]]:
    """Central information filter that tests every node's predicted residuals with the central prediction.

    Returns the last-epoch estimate (p,) and the rejected observations as ``(epoch, node, row)``.
    """
    p = dyn.n_states
    ms = ObservationSeries(p, epochs)
    crit = critical_value(level)
    ker = InformationKernel(1, p, track_error=False)
    removed: set[tuple[int, int, int]] = set()
    for t in range(ms.n_epochs):
        if t:
            ker.time_update(dyn, t)
        A, y, node = ms.observations(t)
        keep = np.ones(y.size, bool)
        if t:
            inv, est = pseudo_inverse_psd(ker.I)
            x_pred = inv[0] @ ker.i[0]
            for i in range(ms.n_nodes):
                rows = np.flatnonzero(node == i)
                res = innovation_test(A[rows], y[rows], x_pred, inv[0], est[0], crit)
                keep[rows] = res.keep
                removed.update((t, i, int(r)) for r in res.removed)
        Ak, yk = A[keep], y[keep]
        ker.measurement_update((Ak.T @ Ak)[None], (Ak.T @ yk)[None])
    x, _est, _inv, _ = ker.estimates()
    return x[0], removed


def _data_with_gross_errors(
    dyn: DynamicModel, A: np.ndarray, sig: np.ndarray, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray, set[tuple[int, int, int]], np.ndarray]:
    """Simulated observations, and the same with :data:`N_GROSS` gross errors of ±:data:`GROSS_SIGMA` σ from
    epoch 2 on: ``(y_clean, y_bad, injected (epoch, node, row), their epochs)``."""
    T = A.shape[0]
    x = simulate_states(dyn, T, rng=rng, initial_state=rng.normal(0.0, 3.0, dyn.n_states))
    y_clean = np.einsum("tnmp,tp->tnm", A, x) + sig * rng.standard_normal(sig.shape)
    flat = rng.choice((T - 2) * N_NODES * N_OBS, N_GROSS, replace=False)
    t_g, i_g, k_g = np.unravel_index(flat, (T - 2, N_NODES, N_OBS))
    t_g = t_g + 2
    y_bad = y_clean.copy()
    y_bad[t_g, i_g, k_g] += GROSS_SIGMA * sig[t_g, i_g, k_g] * rng.choice([-1.0, 1.0], N_GROSS)
    injected = {(int(a), int(b), int(c)) for a, b, c in zip(t_g, i_g, k_g, strict=True)}
    return y_clean, y_bad, injected, t_g


def _ckf_runs(
    ctx: ExperimentContext, graph: Graph, dyn: DynamicModel, ms_bad: ObservationSeries, ms_clean: ObservationSeries
) -> tuple[Any, Any, Any]:
    """The CKF with local innovation tests and without them on the data with gross errors, and without them on
    the clean data (the reference of both)."""
    sched = consensus_schedule(graph, "P3")

    def run_ckf(ms: ObservationSeries, **tests: Any) -> Any:
        return ckf(
            dyn, ms, schedule=sched, rounds=KN, exchange=ctx.exchange(graph), variance=False, monitor=False, **tests
        )

    tested = run_ckf(ms_bad, local_precision="exact", test_level=LEVEL)
    return tested, run_ckf(ms_bad), run_ckf(ms_clean)


def _trial(
    ctx: ExperimentContext,
    graph: Graph,
    dyn: DynamicModel,
    A: np.ndarray,
    sig: np.ndarray,
    rng: np.random.Generator,
    *,
    trace: bool,
) -> dict[str, Any]:
    y_clean, y_bad, injected, t_g = _data_with_gross_errors(dyn, A, sig, rng)
    clean_c = central_filter(dyn, ObservationSeries(dyn.n_states, _epochs(A, sig, y_clean))).estimates[0]
    ms_bad = ObservationSeries(dyn.n_states, _epochs(A, sig, y_bad))
    tested, plain, clean_ckf = _ckf_runs(
        ctx, graph, dyn, ms_bad, ObservationSeries(dyn.n_states, _epochs(A, sig, y_clean))
    )
    xc, removed_c = central_tested_filter(dyn, _epochs(A, sig, y_bad), LEVEL)
    tests = tested.tests
    assert tests is not None
    removed_d = {(int(tests.epoch[j]), int(tests.node[j]), int(tests.row[j])) for j in tests.removed}
    n_tested = int(tests.w.size)

    def dist(est: np.ndarray) -> float:
        return float(np.max(np.linalg.norm(np.atleast_2d(est) - clean_c, axis=-1)))

    out: dict[str, Any] = {
        "injected": len(injected),
        "tested": n_tested,
        "detected_distributed": len(removed_d & injected),
        "false_distributed": len(removed_d - injected),
        "detected_central": len(removed_c & injected),
        "false_central": len(removed_c - injected),
        "distance_distributed": dist(tested.estimates),
        "distance_untested": dist(plain.estimates),
        "distance_central": dist(xc),
        "ckf_distance_distributed": float(np.linalg.norm(tested.estimates - clean_ckf.estimates, axis=1).max()),
        "ckf_distance_untested": float(np.linalg.norm(plain.estimates - clean_ckf.estimates, axis=1).max()),
    }
    if trace:
        from distnav.algorithms.kalman.gather_data import OBSERVATIONS_DATA, observation_bytes_per_node
        from distnav.algorithms.result import compare_with_gather

        out["communication_vs_gather"] = {
            "CKF with local tests": compare_with_gather(
                tested.comm, graph, observation_bytes_per_node(ms_bad), data=OBSERVATIONS_DATA
            ).as_dict()
        }
        ref = clean_ckf.series.estimates
        out["trace"] = {
            "tested": np.linalg.norm(tested.series.estimates - ref, axis=2).max(axis=1),
            "untested": np.linalg.norm(plain.series.estimates - ref, axis=2).max(axis=1),
            "gross_epochs": sorted({int(t) for t in t_g}),
        }
    return out


def _precision_check(
    ctx: ExperimentContext, graph: Graph, dyn: DynamicModel, A: np.ndarray, sig: np.ndarray
) -> dict[str, float]:
    y = np.zeros(sig.shape)
    ms = ObservationSeries(dyn.n_states, _epochs(A, sig, y))
    sched = consensus_schedule(graph, "P3")
    out: dict[str, float] = {}
    for kind in ("exact", "bound"):
        r = ckf(dyn, ms, schedule=sched, rounds=KN, exchange=ctx.exchange(graph), local_precision=kind, monitor=False)
        m = r.series.estimable
        assert r.local_std is not None and r.precision is not None and r.precision.comm is not None
        ratio = r.local_std[m] / r.series.std[m]
        out[f"{kind}_min_ratio"] = float(ratio.min())
        out[f"{kind}_max_ratio"] = float(ratio.max())
        out[f"{kind}_extra_bytes_fraction"] = r.precision.comm.bytes / r.comm.bytes
    return out


def run(ctx: ExperimentContext) -> dict[str, Any]:
    T = 20 if ctx.quick else 40
    n_trials = 20 if ctx.quick else 100
    graph = builders.connected_random_geometric(N_NODES, mean_degree=4.0, rng=ctx.rng(31))
    dyn = _model()
    A, sig = _designs(ctx.rng(32), T)
    rng = ctx.rng(33)
    trials = []
    with ctx.progress.task("qc: CKF with local innovation tests, gross errors injected", total=n_trials) as advance:
        for k in range(n_trials):
            trials.append(_trial(ctx, graph, dyn, A, sig, rng, trace=(k == 0)))
            advance(1)
        precision = _precision_check(ctx, graph, dyn, A, sig)
    inj = sum(t["injected"] for t in trials)
    clean_tested = sum(t["tested"] - t["injected"] for t in trials)

    def rate(key: str, denom: int) -> float:
        return float(sum(t[key] for t in trials)) / denom

    dist = {k: [t[f"distance_{k}"] for t in trials] for k in ("distributed", "central", "untested")}
    ckf_dist = {k: [t[f"ckf_distance_{k}"] for t in trials] for k in ("distributed", "untested")}
    results: dict[str, Any] = {
        "setup": {
            "n_nodes": N_NODES,
            "n_links": graph.n_links,
            "n_states": dyn.n_states,
            "n_obs_per_node": N_OBS,
            "n_epochs": T,
            "k_n": KN,
            "protocol": "P3",
            "level": LEVEL,
            "critical_value": critical_value(LEVEL),
            "gross_error_sigma": GROSS_SIGMA,
            "gross_errors_per_trial": N_GROSS,
            "trials": n_trials,
        },
        "detection_rate": {"distributed": rate("detected_distributed", inj), "central": rate("detected_central", inj)},
        "false_alarm_rate": {
            "distributed": rate("false_distributed", clean_tested),
            "central": rate("false_central", clean_tested),
        },
        "final_distance_to_clean_central": {
            k: {"median": float(np.median(v)), "max": float(np.max(v))} for k, v in dist.items()
        },
        "final_distance_to_clean_ckf": {
            k: {"median": float(np.median(v)), "max": float(np.max(v))} for k, v in ckf_dist.items()
        },
        "final_distance_note": "max over nodes of ‖x̂_i − x̂_clean‖ at the last epoch; clean = the same filter on the "
        "data without gross errors and without tests (the CKF with k_n = 6 is itself "
        "away from the central filter, so the clean-CKF distance isolates the gross errors)",
        "node_local_precision": precision,
    }
    results["communication_vs_gather"] = trials[0]["communication_vs_gather"]
    results["headline"] = {
        "CKF local tests: detection rate of 8σ errors": results["detection_rate"]["distributed"],
        "central tests: detection rate of 8σ errors": results["detection_rate"]["central"],
        "CKF local tests: false-alarm rate (level 0.1 %)": results["false_alarm_rate"]["distributed"],
        "central tests: false-alarm rate (level 0.1 %)": results["false_alarm_rate"]["central"],
        "median final distance to clean central, CKF with tests": results["final_distance_to_clean_central"][
            "distributed"
        ]["median"],
        "median final distance to clean central, CKF without tests": results["final_distance_to_clean_central"][
            "untested"
        ]["median"],
        "median final distance to clean central, central with tests": results["final_distance_to_clean_central"][
            "central"
        ]["median"],
        "median final distance to clean CKF, CKF with tests": results["final_distance_to_clean_ckf"]["distributed"][
            "median"
        ],
        "median final distance to clean CKF, CKF without tests": results["final_distance_to_clean_ckf"]["untested"][
            "median"
        ],
        "node-local precision exact / Fig. 7, max": precision["exact_max_ratio"],
        "node-local precision bound / Fig. 7, max (std)": precision["bound_max_ratio"],
    }
    if ctx.is_root:
        _figures(ctx, results, trials[0]["trace"], dist)
    return results


def _figures(
    ctx: ExperimentContext, results: dict[str, Any], trace: dict[str, Any], dist: dict[str, list[float]]
) -> None:
    plt = pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    ax = axes[0]
    kinds = ["distributed", "central"]
    ax.bar(np.arange(2) - 0.2, [results["detection_rate"][k] for k in kinds], 0.4, label="detection rate")
    ax.bar(np.arange(2) + 0.2, [100 * results["false_alarm_rate"][k] for k in kinds], 0.4, label="false alarms × 100")
    ax.axhline(100 * LEVEL, color="k", ls="--", lw=0.8, label="level × 100")
    ax.set_xticks(range(2), ["CKF (local tests)", "central filter"])
    ax.legend(fontsize=8)
    ax.set_title(f"{GROSS_SIGMA:g}σ gross errors, level {LEVEL:g}")
    ax = axes[1]
    ax.boxplot([dist[k] for k in ("distributed", "central", "untested")], showfliers=True)
    ax.set_xticks([1, 2, 3], ["CKF tested", "central tested", "CKF untested"])
    ax.set_yscale("log")
    ax.set_ylabel("final max_i ‖x̂_i − x̂_clean central‖ (state units, dimensionless)")
    ax.grid(alpha=0.3)
    ctx.save_figure(fig, "ckf_detection.png")
    fig, ax = plt.subplots(figsize=(6, 4))
    ep = np.arange(trace["tested"].size)
    ax.semilogy(ep, trace["untested"], label="CKF without tests")
    ax.semilogy(ep, trace["tested"], label="CKF with local tests")
    for t in trace["gross_epochs"]:
        ax.axvline(t, color="r", lw=0.6, alpha=0.5)
    ax.set_xlabel("epoch (red: a gross error injected)")
    ax.set_ylabel("max_i ‖x̂_i − x̂_i of the clean CKF‖ (state units, dimensionless)")
    ax.legend()
    ax.grid(alpha=0.3)
    ctx.save_figure(fig, "ckf_distance_trace.png")
