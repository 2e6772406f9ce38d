"""ADMM's memory per node (issue 30: ≤ 1.5 kB per node): both message forms against the bare kernels' arrays.

What one ADMM run allocates at its peak, per node: ``tracemalloc`` around the constraint-node cover, the exchange
(in the locality order, as ``admm()`` makes it), the set-up (checks, x-update gains, routes or mixers), the first
state and three iterations (monitored every iteration: the residual sums are part of the run). Inputs are not
counted: the graph (its ``links`` made before, as a builder's graph holds them) and the problem ``(A, y, R)``.
The per-pair form's three pair arrays of ``p`` floats (the Fig. 6 state ``u_{i,s}`` and the two pair values the
iteration reads, ``pairs_state_b_per_node``) are its floor by construction; the aggregated form has no pair state.

Floor in the same run: the bare numpy/scipy kernels of the same iterations (``BareAggregatedKernel`` of
``bench_admm_aggregated``, ``BarePairKernel`` of ``bench_admm``: CSR adjacency or pair index arrays, the gains, the
state; no exchange, no cover, no residuals), their construction and three steps traced the same way, on the same
graph and cover. n = 10⁴, 10⁵ (10⁴ with ``--quick``), ``bench_setup``'s problem: connected random geometric graphs
of mean degree 15, p = 10, m_i = 5, ρ = 1. tracemalloc counts bytes, not time: the figures do not move with the
machine's load.
"""

from __future__ import annotations

import sys
import tracemalloc
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import main_for  # noqa: E402
from bench_admm import BarePairKernel  # noqa: E402
from bench_admm_aggregated import BareAggregatedKernel  # noqa: E402
from bench_setup import _case  # noqa: E402
from distnav.algorithms.lsq.admm import iterate_admm  # noqa: E402
from distnav.algorithms.lsq.blue import LinearProblem  # noqa: E402
from distnav.exchange import make_exchange  # noqa: E402
from distnav.network.constraint_nodes import ConstraintNodes, choose_constraint_nodes  # noqa: E402
from distnav.network.graph import Graph  # noqa: E402

GOAL_B = 1500.0  # bytes per node
ITERATIONS = 3


def _fresh(g: Graph) -> None:
    """Drop the graph's cached arrays but its links (so the cover, RCM and the edge maps are counted every run)."""
    links = g.links
    g._cache.clear()
    g.__dict__["links"] = links


def distnav_bytes(g: Graph, prob: LinearProblem, messages: str) -> dict[str, float]:
    """Peak and held bytes of one run (cover, exchange, set-up, state 0, :data:`ITERATIONS` iterations)."""
    _fresh(g)
    tracemalloc.start()
    base = tracemalloc.get_traced_memory()[0]
    C = choose_constraint_nodes(g, "min_cover")
    ex = make_exchange(g, order="auto")
    gen = iterate_admm(prob, g, constraint_nodes=C, W=1.0, exchange=ex, messages=messages)  # type: ignore[arg-type]
    next(gen)
    setup_peak = tracemalloc.get_traced_memory()[1] - base
    for _ in range(ITERATIONS):
        next(gen)
    held, peak = (v - base for v in tracemalloc.get_traced_memory())
    tracemalloc.stop()
    gen.close()
    return {"peak": float(peak), "setup_peak": float(setup_peak), "held": float(held)}


def bare_bytes(prob: LinearProblem, g: Graph, C: ConstraintNodes, kernel: Any) -> float:
    """Peak bytes of a bare kernel's construction and :data:`ITERATIONS` steps."""
    tracemalloc.start()
    base = tracemalloc.get_traced_memory()[0]
    bare = kernel(prob, g, C, 1.0)
    for _ in range(ITERATIONS):
        bare.step()
    peak = tracemalloc.get_traced_memory()[1] - base
    tracemalloc.stop()
    del bare
    return float(peak)


def run(quick: bool) -> list[dict[str, Any]]:
    rows: list[dict[str, Any]] = []
    for n in (10_000,) if quick else (10_000, 100_000):
        g, _, prob = _case(n)
        C = choose_constraint_nodes(g, "min_cover")
        pairs = int(C.per_node_count.sum()) - C.size  # (i, s) with s ≠ i: one per edge s → i, s ∈ C
        for messages, kernel in (("aggregated", BareAggregatedKernel), ("pairs", BarePairKernel)):
            ours = distnav_bytes(g, prob, messages)
            bare = bare_bytes(prob, g, C, kernel)
            per_node = ours["peak"] / n
            rows.append(
                {
                    "name": f"ADMM memory per node, {'aggregated' if messages == 'aggregated' else 'per-pair'} "
                    "messages (cover + exchange + set-up + 3 iterations, traced peak)",
                    "n_nodes": n,
                    "n_links": g.n_links,
                    "pairs": pairs,
                    "distnav_mb": ours["peak"] / 1e6,
                    "bare_mb": bare / 1e6,
                    "floor": "bare numpy/scipy kernel of the same iteration (construction + 3 steps, traced peak)",
                    "ratio": ours["peak"] / bare,
                    "peak_b_per_node": per_node,
                    "setup_peak_b_per_node": ours["setup_peak"] / n,
                    "held_b_per_node": ours["held"] / n,
                    "bare_b_per_node": bare / n,
                    "pairs_state_b_per_node": 3 * pairs * prob.n_params * 8 / n if messages == "pairs" else 0.0,
                    "goal": f"≤ {GOAL_B:g} B per node",
                    "meets_goal": bool(per_node <= GOAL_B),
                }
            )
    return rows


if __name__ == "__main__":
    main_for(__file__, run)
