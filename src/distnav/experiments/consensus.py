"""Reproduction of paper 003 §3, Figs. 2–4: average-consensus protocols on 20-node networks.

* network (a): a static 20-node network with 49 links (the 49 shortest pairs of 20 random points,
  redrawn until connected);
* network (b): a switching 20-node network of 4 sessions with 7, 6, 8, 7 links, every node with at most one
  neighbour per session (random matchings of nearby pairs), union connected;
* twenty values with average exactly 5; Protocols 1–3 on (a), Protocol 4 on (b), 30 iterations;
* ``λ_{n−1}`` of P1–P3 (eq. (38)); probability (40) versus q for k_n = 10, 20, 30 by Monte Carlo.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from distnav.algorithms.consensus import (
    average_consensus,
    consensus_probability,
    consensus_product,
    consensus_schedule,
)
from distnav.errors import GraphError
from distnav.experiments.common import ExperimentContext, pyplot
from distnav.network.graph import Graph, SwitchingGraph

NAME = "consensus"
TITLE = "Average consensus protocols 1-4 (paper 003 Figs. 2-4)"

N_NODES = 20
STATIC_LINKS = 49
SESSION_LINKS = (7, 6, 8, 7)
ITERATIONS = 30
KN_VALUES = (10, 20, 30)
PAPER_SLEM = {"P1": 0.92, "P2": 0.97, "P3": 0.91}


def static_network(rng: np.random.Generator, n_nodes: int = N_NODES, n_links: int = STATIC_LINKS,
                   max_tries: int = 200) -> Graph:
    """``n_nodes`` uniform points in a 100 m square linked by their ``n_links`` shortest pairs, connected."""
    for _ in range(max_tries):
        pos = rng.uniform(0, 100, size=(n_nodes, 2))
        a, b = np.triu_indices(n_nodes, 1)
        d = np.linalg.norm(pos[a] - pos[b], axis=1)
        keep = np.argsort(d)[:n_links]
        g = Graph.from_links(n_nodes, np.stack([a[keep], b[keep]], 1), positions=pos)
        if g.is_connected:
            return g
    raise GraphError(f"no connected {n_nodes}-node network with {n_links} links in {max_tries} draws")


def switching_network(rng: np.random.Generator, n_nodes: int = N_NODES,
                      session_links: tuple[int, ...] = SESSION_LINKS, max_tries: int = 2000) -> SwitchingGraph:
    """Sessions that are matchings (each node ≤ 1 neighbour, Protocol 4) of nearby pairs; union connected."""
    for _ in range(max_tries):
        pos = rng.uniform(0, 100, size=(n_nodes, 2))
        a, b = np.triu_indices(n_nodes, 1)
        d = np.linalg.norm(pos[a] - pos[b], axis=1)
        near = np.argsort(d)[: 4 * n_nodes]
        sessions = []
        used: set[tuple[int, int]] = set()
        for count in session_links:
            busy: set[int] = set()
            links: list[tuple[int, int]] = []
            for e in rng.permutation(near):
                i, j = int(a[e]), int(b[e])
                if i in busy or j in busy or (i, j) in used:
                    continue
                links.append((i, j))
                busy |= {i, j}
                if len(links) == count:
                    break
            if len(links) < count:
                break
            used |= set(links)
            sessions.append(Graph.from_links(n_nodes, links, positions=pos))
        if len(sessions) == len(session_links):
            try:
                return SwitchingGraph(tuple(sessions))
            except GraphError:
                continue
    raise GraphError("could not draw a connected switching network; try another seed")


def twenty_values(rng: np.random.Generator, n_nodes: int = N_NODES, average: float = 5.0) -> np.ndarray:
    v = rng.normal(average, 2.0, size=n_nodes)
    return v - v.mean() + average


def run(ctx: ExperimentContext) -> dict[str, Any]:
    rng_net = ctx.rng(1)
    g_static = static_network(rng_net)
    g_switch = switching_network(rng_net)
    values = twenty_values(ctx.rng(2))
    samples = 20_000 if ctx.quick else 100_000
    q = np.round(np.linspace(0.0, 1.0, 41), 6)

    runs: dict[str, Any] = {}
    slem: dict[str, float] = {}
    probability: dict[str, dict[str, list[float]]] = {}
    schedules: dict[str, tuple[Graph | SwitchingGraph, Any]] = {
        p: (g_static, consensus_schedule(g_static, p)) for p in ("P1", "P2", "P3")
    }
    schedules["P4"] = (g_switch, consensus_schedule(g_switch, "P4"))
    with ctx.progress.task("consensus: protocols P1-P4, 30 iterations + Monte Carlo", total=4) as advance:
        for p, (graph, sched) in schedules.items():
            ex = ctx.exchange(sched.graph)
            res = average_consensus(values, graph=graph, protocol=p, rounds=ITERATIONS, exchange=ex,
                                    record_values=True)
            runs[p] = res
            if p != "P4":
                slem[p] = sched.weights[0].slem
            probability[p] = {
                str(kn): consensus_probability(consensus_product(sched, kn), q, samples=samples,
                                               rng=ctx.rng(10 + kn)).tolist()
                for kn in KN_VALUES
            }
            advance(1)

    final_dev = {p: float(r.trace["max_abs_deviation"][-1]) for p, r in runs.items()}
    iq = int(np.argmin(np.abs(q - 0.2)))
    results: dict[str, Any] = {
        "network": {
            "static": {"n_nodes": g_static.n_nodes, "n_links": g_static.n_links,
                       "links": g_static.links.tolist()},
            "switching": {"n_nodes": g_switch.n_nodes,
                          "links_per_session": [s.n_links for s in g_switch.sessions],
                          "sessions": [s.links.tolist() for s in g_switch.sessions]},
        },
        "values": values.tolist(),
        "average": float(values.mean()),
        "slem": slem,
        "paper_slem": PAPER_SLEM,
        "final_max_abs_deviation": final_dev,
        "max_abs_deviation": {p: r.trace["max_abs_deviation"].tolist() for p, r in runs.items()},
        "probability": {**probability, "q": q.tolist()},
        "q": q.tolist(),
        "monte_carlo_samples": samples,
        "communication": {p: r.comm.as_dict() for p, r in runs.items()},
        "headline": {
            **{f"λ_(n-1) {p} (paper {PAPER_SLEM[p]})": v for p, v in slem.items()},
            **{f"max |r_i − r̄| after 30 it., {p}": v for p, v in final_dev.items()},
            **{f"P(max dev ≤ 0.2σ), k_n=10, {p}": probability[p]["10"][iq] for p in probability},
        },
    }
    ctx.write_json("results.json", results)
    if ctx.is_root:
        _figures(ctx, g_static, g_switch, runs, probability, q)
    return results


def _figures(ctx: ExperimentContext, g_static: Graph, g_switch: SwitchingGraph, runs: dict[str, Any],
             probability: dict[str, dict[str, list[float]]], q: np.ndarray) -> None:
    plt = pyplot()
    # Fig. 2: the two networks
    fig, axes = plt.subplots(1, 2, figsize=(10, 4.5))
    pos = g_static.positions
    assert pos is not None
    for i, j in g_static.links:
        axes[0].plot(pos[[i, j], 0], pos[[i, j], 1], "-", color="0.5", lw=1)
    axes[0].plot(pos[:, 0], pos[:, 1], "o", color="tab:blue")
    for k in range(g_static.n_nodes):
        axes[0].annotate(str(k + 1), pos[k], fontsize=7, xytext=(3, 3), textcoords="offset points")
    axes[0].set_title(f"(a) static, {g_static.n_links} links")
    colours = ["tab:red", "gold", "tab:green", "tab:blue"]
    pos2 = g_switch.sessions[0].positions
    assert pos2 is not None
    for s, (sg, c) in enumerate(zip(g_switch.sessions, colours, strict=False)):
        for n_, (i, j) in enumerate(sg.links):
            axes[1].plot(pos2[[i, j], 0], pos2[[i, j], 1], "-", color=c, lw=2,
                         label=f"session {s + 1} ({sg.n_links} links)" if n_ == 0 else None)
    axes[1].plot(pos2[:, 0], pos2[:, 1], "o", color="k")
    axes[1].legend(fontsize=7)
    axes[1].set_title("(b) switching, 4 sessions")
    for ax in axes:
        ax.set_aspect("equal")
        ax.set_xlabel("x [m]")
    ctx.save_figure(fig, "fig2_networks.png")
    # Fig. 3: iterated values
    fig, axes = plt.subplots(2, 2, figsize=(10, 7), sharex=True, sharey=True)
    for ax, (p, res) in zip(axes.ravel(), runs.items(), strict=False):
        vals = res.trace["values"]
        ax.plot(np.arange(vals.shape[0]), vals, lw=0.8)
        ax.axhline(5.0, color="k", ls="--", lw=0.8)
        ax.set_title(f"Protocol {p[1]} ({'network (b)' if p == 'P4' else 'network (a)'})")
        ax.set_xlabel("iteration k")
        ax.set_ylabel("r_i^(k)")
    ctx.save_figure(fig, "fig3_iterations.png")
    # Fig. 4: probability vs q
    fig, axes = plt.subplots(1, 3, figsize=(13, 4), sharey=True)
    for ax, kn in zip(axes, KN_VALUES, strict=True):
        for p in probability:
            ax.plot(q, probability[p][str(kn)], label=f"P.{p[1]}")
        ax.set_title(f"k_n = {kn}")
        ax.set_xlabel("q")
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("P(max_i |r_i^(k_n) − r̄| ≤ qσ)")
    axes[0].legend()
    ctx.save_figure(fig, "fig4_probability.png")
