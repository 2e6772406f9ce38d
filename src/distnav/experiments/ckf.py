"""Consensus Kalman filter on a generic 20-node network (paper 003 §4, Figs. 6–7, eqs. (44)–(48)).

A 20-node network (the static network (a) of the consensus experiment: the 49 shortest pairs of 20 random
points) tracks a state of ``3`` random-walk entries and ``9`` constant biases. Every node observes, at every
epoch, one row per *visible* bias it can see: ``y = a_rwᵀ x_rw + b_s + ε`` with node- and epoch-specific random
coefficients ``a_rw`` and variance; biases rise and set over the session (so an entry is unobserved for a while)
and each node sees only ~70 % of them (partial observation). The CKF (Fig. 6, Protocol 3) runs with
``k_n = 1, 4, 12``; its error variances come from the recursion of Fig. 7 and are compared with the central
(network) filter and the single-node (local) filters, as the paper does in Figs. 11–12.

Also: the α factor ``n Σ_j l_ij²`` (eq. (46)) per node for a range of ``k_n`` and a check of the stationary closed
form ``P_i,t|t = α_i (t n N)⁻¹`` (eq. (47)) on the same network; and one realization with data, to confirm that
the actual CKF errors are consistent with the Fig. 7 standard deviations; and the CKF with k_n = 4 when 10 % of
the consensus messages are lost.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from distnav.algorithms.consensus.averaging import consensus_product, consensus_schedule
from distnav.algorithms.kalman import (
    DynamicModel,
    FunctionSeries,
    NormalSeries,
    central_filter,
    local_filters,
    simulate_states,
    std_ratio,
)
from distnav.algorithms.kalman.ckf import alpha_factor, ckf, ckf_error_variance, ckf_std_ratio
from distnav.exchange import FaultSchedule
from distnav.experiments.common import ExperimentContext, pyplot
from distnav.experiments.consensus import static_network
from distnav.network import builders
from distnav.network.graph import Graph

NAME = "ckf"
TITLE = "Consensus Kalman filter and its error-variance recursion (paper 003 §4, Figs. 6-7)"

KN_VALUES = (1, 4, 12)
ALPHA_KN = (0, 1, 2, 4, 6, 8, 12, 20, 30, 50)
PROTOCOL = "P3"
DROP_PROBABILITY = 0.1
DROP_KN = 4


def synthetic_model(
    *,
    n_nodes: int,
    n_epochs: int,
    n_random_walk: int,
    n_biases: int,
    seed: int,
    see_probability: float = 1.0,
    rw_std: float = 0.1,
    noise_std: float = 1.0,
    late_fraction: float = 0.3,
) -> tuple[DynamicModel, FunctionSeries, np.ndarray]:
    """A GNSS-like linear network model: ``n_random_walk`` random-walk entries common to all nodes plus
    ``n_biases`` constant biases that rise and set (visible windows), each seen by a node with
    ``see_probability``. Row of node i for bias s at epoch t: ``[a_rw, e_s]`` with ``a_rw ~ U(0.5, 1.5)`` for the
    first random-walk entry and ``N(0, 0.3²)`` for the others, variance ``noise_std² · U(1, 4)``.

    The system noise is singular (``H`` = the random-walk columns, eq. (20)). Normals are generated on demand
    from ``(seed, epoch)`` (memory-light; the same numbers for any node subset). Returns
    ``(dynamics, measurements, truth (T×p))``.
    """
    p = n_random_walk + n_biases
    rng = np.random.default_rng([seed, 0])
    dyn = DynamicModel(p, noise_map=np.eye(p)[:, :n_random_walk], noise_reduced_cov=np.eye(n_random_walk) * rw_std**2)
    truth = simulate_states(dyn, n_epochs, rng=rng, initial_state=rng.normal(0.0, 3.0, p))
    rise = np.zeros(n_biases, np.int64)
    n_late = int(round(n_biases / 3))
    rise[:n_late] = rng.integers(1, max(2, int(late_fraction * n_epochs)), n_late)
    set_ = np.full(n_biases, n_epochs)
    n_set = int(round(n_biases / 3))
    set_[n_late : n_late + n_set] = rng.integers(int(0.6 * n_epochs), n_epochs + 1, n_set)
    sees = rng.random((n_nodes, n_biases)) < see_probability
    sees[np.arange(n_biases) % n_nodes, np.arange(n_biases)] = True  # every bias seen by someone

    def fn(t: int, nodes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        g = np.random.default_rng([seed, 1, t])
        a = np.empty((n_nodes, n_biases, n_random_walk))
        a[..., 0] = g.uniform(0.5, 1.5, (n_nodes, n_biases))
        a[..., 1:] = g.normal(0.0, 0.3, (n_nodes, n_biases, n_random_walk - 1))
        sig = noise_std * np.sqrt(g.uniform(1.0, 4.0, (n_nodes, n_biases)))
        eps = g.standard_normal((n_nodes, n_biases)) * sig
        a, sig, eps = a[nodes], sig[nodes], eps[nodes]
        vis = ((rise <= t) & (t < set_))[None, :] & sees[nodes]
        A = np.zeros((nodes.size, n_biases, p))
        A[..., :n_random_walk] = a
        A[:, np.arange(n_biases), n_random_walk + np.arange(n_biases)] = 1.0
        y = A @ truth[t] + eps
        w = np.where(vis, 1.0 / sig, 0.0)
        Aw = A * w[..., None]
        AwT = np.swapaxes(Aw, 1, 2)
        return AwT @ Aw, (AwT @ (y * w)[..., None])[..., 0]

    return dyn, FunctionSeries(n_nodes, n_epochs, p, fn), truth


def stationary_check(graph: Graph, kn: int, *, n_states: int = 3, n_epochs: int = 5) -> float:
    """Largest |P_i,t|t / P_t|t − α_i| (relative) for Φ = I, S = 0, equal N (paper 003 eq. (47))."""
    n = graph.n_nodes
    B = np.random.default_rng(0).standard_normal((4, n_states))
    N = B.T @ B
    ms = NormalSeries(np.broadcast_to(N, (n_epochs, n, n_states, n_states)).copy())
    L = consensus_product(consensus_schedule(graph, PROTOCOL), kn)
    s = ckf_error_variance(DynamicModel(n_states), ms, L)
    central = np.sqrt(np.diag(np.linalg.inv(N)))[None, None, :] / np.sqrt(n * np.arange(1, n_epochs + 1))[:, None, None]
    ratio2 = (s.std / central) ** 2
    a = alpha_factor(L)[None, :, None]
    return float(np.abs(ratio2 / a - 1.0).max())


def exact_average_check(ctx: ExperimentContext, dyn: Any, ms: Any, central: Any, n: int) -> dict[str, float]:
    """Paper 003 §4 (after eq. (28)): with exact averages every node's CKF delivers the central filter. Exact
    averages in one round: Protocol 2 on the complete graph (``w_ij = 1/n`` for every pair and the node itself).
    Returns the largest difference of any node's estimates to the central filter's (relative to the largest
    central estimate) and the largest ``|σ_CKF/σ_central − 1|`` (Fig. 7 recursion), estimable parameters only."""
    g = builders.complete(n)
    r = ckf(dyn, ms, schedule=consensus_schedule(g, "P2"), rounds=1, exchange=ctx.exchange(g))
    est = np.abs(r.series.estimates - central.estimates)
    return {
        "max_relative_estimate_difference": float(np.nanmax(est) / np.nanmax(np.abs(central.estimates))),
        "max_std_ratio_minus_1": float(np.nanmax(np.abs(ckf_std_ratio(r.series, central) - 1.0))),
    }


def run(ctx: ExperimentContext) -> dict[str, Any]:
    from distnav.algorithms.kalman.gather_data import NORMALS_DATA, normal_bytes_per_node
    from distnav.algorithms.result import compare_with_gather

    n_epochs = 40 if ctx.quick else 240
    graph = static_network(ctx.rng(1))
    n = graph.n_nodes
    dyn, ms, truth = synthetic_model(
        n_nodes=n,
        n_epochs=n_epochs,
        n_random_walk=3,
        n_biases=9,
        seed=int(ctx.rng(2).integers(2**31)),
        see_probability=0.7,
    )
    sched = consensus_schedule(graph, PROTOCOL)
    central, local, runs, lossy = _filters(ctx, dyn, ms, graph, sched)
    cs = central.series
    gathered = normal_bytes_per_node(ms)
    ls = local.series
    ratios = {kn: ckf_std_ratio(r.series, cs) for kn, r in runs.items()}
    local_ratio = std_ratio(ls, cs)

    alpha = _alpha(graph, sched)
    std_ratio_final = {str(kn): _final_max(ratios[kn]) for kn in KN_VALUES}
    consistency = _consistency(truth, cs, runs)
    lossy_ratio = ckf_std_ratio(lossy.series, cs)
    drops_result = {
        "k_n": DROP_KN,
        "drop_probability": DROP_PROBABILITY,
        "std_ratio_final": _final_max(lossy_ratio),
        "messages_dropped": lossy.comm.messages_dropped,
        "messages": lossy.comm.messages,
    }
    exact = exact_average_check(ctx, dyn, ms, central.series, n)
    not_estimable = {str(kn): int((~r.series.estimable[-1]).sum()) for kn, r in runs.items()}
    degrees = graph.degrees
    results: dict[str, Any] = {
        "network": {"n_nodes": n, "n_links": graph.n_links, "links": graph.links.tolist(), "degrees": degrees.tolist()},
        "model": {
            "n_states": ms.n_states,
            "n_random_walk": 3,
            "n_biases": 9,
            "n_epochs": n_epochs,
            "protocol": PROTOCOL,
            "see_probability": 0.7,
        },
        "alpha": alpha,
        "std_ratio_final": std_ratio_final,
        "std_ratio_final_note": "largest CKF/central std ratio over nodes and estimable parameters at the last epoch",
        "std_ratio_final_per_node": {str(kn): np.nanmax(ratios[kn][-1], axis=1).tolist() for kn in KN_VALUES},
        "local_to_central_final": {
            "max": _final_max(local_ratio),
            "per_node": np.nanmax(local_ratio[-1], axis=1).tolist(),
        },
        "rms_standardized_error": consistency,
        "not_estimable_final": not_estimable,
        "communication": {str(kn): r.comm.as_dict() for kn, r in runs.items()},
        "communication_vs_gather": {
            str(kn): compare_with_gather(r.comm, graph, gathered, data=NORMALS_DATA).as_dict() for kn, r in runs.items()
        },
        "message_drops": drops_result,
        "exact_average_vs_central": exact,
        "headline": _headline(
            std_ratio_final, _final_max(local_ratio), drops_result, alpha, consistency, not_estimable
        ),
    }
    ctx.write_json("results.json", results)
    if ctx.is_root:
        _figures(ctx, graph, ratios, local_ratio, alpha, degrees, results)
    return results


def _filters(
    ctx: ExperimentContext, dyn: Any, ms: Any, graph: Graph, sched: Any
) -> tuple[Any, Any, dict[int, Any], Any]:
    """The central and local filters, the CKF for every k_n, and the CKF with 10 % of its messages lost."""
    runs: dict[int, Any] = {}
    with ctx.progress.task("ckf: central, local and CKF filters", total=len(KN_VALUES) + 3) as advance:
        central = central_filter(dyn, ms)
        advance(1)
        local = local_filters(dyn, ms)
        advance(1)
        for kn in KN_VALUES:
            runs[kn] = ckf(dyn, ms, schedule=sched, rounds=kn, exchange=ctx.exchange(graph))
            advance(1)
        # robustness: 10 % of the messages lost (their weight moves to the receiver's self-weight); the CKF
        # carries the rows of the product actually applied, so Fig. 7 stays exact
        drops = FaultSchedule(drop_probability=DROP_PROBABILITY, seed=7)
        lossy = ckf(dyn, ms, schedule=sched, rounds=DROP_KN, exchange=ctx.exchange(graph, faults=drops))
        advance(1)
    return central, local, runs, lossy


def _alpha(graph: Graph, sched: Any) -> dict[str, Any]:
    """α of eq. (46) per node for every k_n of :data:`ALPHA_KN`, and the stationary closed form's error (eq. (47))."""
    alpha_rows = [alpha_factor(consensus_product(sched, kn)) for kn in ALPHA_KN]
    return {
        "kn": list(ALPHA_KN),
        "max_over_nodes": [float(a.max()) for a in alpha_rows],
        "mean_over_nodes": [float(a.mean()) for a in alpha_rows],
        "min_over_nodes": [float(a.min()) for a in alpha_rows],
        "per_node": {str(kn): a.tolist() for kn, a in zip(ALPHA_KN, alpha_rows, strict=True)},
        "stationary_closed_form_max_rel_error": {str(kn): stationary_check(graph, kn) for kn in KN_VALUES},
    }


def _final_max(r: np.ndarray) -> float:
    return float(np.nanmax(r[-1]))


def _consistency(truth: np.ndarray, cs: Any, runs: dict[int, Any]) -> dict[str, float]:
    """Consistency of one realization: the RMS of the standardized errors of the central and CKF estimates with
    their Fig. 7 std."""
    zc = (truth[:, None, :] - cs.estimates) / cs.std
    consistency = {"central": float(np.sqrt(np.nanmean(zc**2)))}
    for kn, r in runs.items():
        s = r.series
        z = (truth[:, None, :] - s.estimates) / s.std
        consistency[str(kn)] = float(np.sqrt(np.nanmean(z**2)))
    return consistency


def _headline(
    std_ratio_final: dict[str, float],
    local_final: float,
    drops_result: dict[str, Any],
    alpha: dict[str, Any],
    consistency: dict[str, float],
    not_estimable: dict[str, int],
) -> dict[str, Any]:
    return {
        **{f"max CKF/central std ratio, last epoch, k_n={kn}": std_ratio_final[str(kn)] for kn in KN_VALUES},
        "max local/central std ratio, last epoch": local_final,
        f"max CKF/central std ratio, k_n={DROP_KN}, {DROP_PROBABILITY:.0%} messages lost": drops_result[
            "std_ratio_final"
        ],
        **{f"α max over nodes, k_n={kn}": alpha["max_over_nodes"][ALPHA_KN.index(kn)] for kn in KN_VALUES},
        "eq. (47) closed form, max rel. error": max(alpha["stationary_closed_form_max_rel_error"].values()),
        "RMS (x−x̂)/σ of one realization, central": consistency["central"],
        "RMS (x−x̂)/σ of one realization, CKF k_n=4": consistency["4"],
        **{f"node-parameters not estimable at the end, k_n={kn}": not_estimable[str(kn)] for kn in KN_VALUES},
    }


def _figures(
    ctx: ExperimentContext,
    graph: Graph,
    ratios: dict[int, np.ndarray],
    local_ratio: np.ndarray,
    alpha: dict[str, Any],
    degrees: np.ndarray,
    results: dict[str, Any],
) -> None:
    plt = pyplot()
    T = local_ratio.shape[0]
    ep = np.arange(1, T + 1)
    # Fig. A: std ratios over time (first random-walk entry, every node), local vs CKF k_n
    fig, axes = plt.subplots(1, len(KN_VALUES) + 1, figsize=(16, 4), sharey=True)
    panels = [("local (single node)", local_ratio)] + [(f"CKF k_n = {kn}", ratios[kn]) for kn in KN_VALUES]
    cmap = plt.get_cmap("viridis")
    dmax = max(int(degrees.max()), 1)
    for ax, (title, r) in zip(axes, panels, strict=True):
        for i in range(r.shape[1]):
            ax.plot(ep, r[:, i, 0], lw=0.8, color=cmap(degrees[i] / dmax))
        ax.axhline(1.0, color="k", ls="--", lw=0.8)
        ax.set_title(title)
        ax.set_xlabel("epoch")
        ax.set_yscale("log")
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("std ratio to central (random-walk entry 1)")
    fig.suptitle("one line per node; colour = node degree (dark = few neighbours, yellow = many)", fontsize=9)
    ctx.save_figure(fig, "std_ratio_time.png")
    # Fig. B: final ratio per node vs degree
    fig, ax = plt.subplots(figsize=(6, 4))
    for kn in KN_VALUES:
        ax.plot(degrees, results["std_ratio_final_per_node"][str(kn)], "o", label=f"CKF k_n={kn}")
    ax.plot(degrees, results["local_to_central_final"]["per_node"], "x", color="0.4", label="local")
    _save_panel(ctx, fig, ax, "node degree", "max std ratio to central, last epoch", "std_ratio_vs_degree.png")
    # Fig. C: α table
    fig, ax = plt.subplots(figsize=(6, 4))
    kns = np.asarray(alpha["kn"])
    ax.plot(kns, alpha["max_over_nodes"], "o-", label="max over nodes")
    ax.plot(kns, alpha["mean_over_nodes"], "s-", label="mean")
    ax.plot(kns, alpha["min_over_nodes"], "^-", label="min")
    ax.axhline(1.0, color="k", ls="--", lw=0.8)
    _save_panel(ctx, fig, ax, "consensus rounds k_n", "α = n Σ_j l_ij²  (eq. 46)", "alpha.png")


def _save_panel(ctx: ExperimentContext, fig: Any, ax: Any, xlabel: str, ylabel: str, name: str) -> None:
    """Finish a one-panel figure (log y axis, labels, legend, grid) and save it as ``name``."""
    ax.set_yscale("log")
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.legend()
    ax.grid(alpha=0.3)
    ctx.save_figure(fig, name)
