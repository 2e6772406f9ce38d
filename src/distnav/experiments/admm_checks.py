"""Quantities of ``reproduce admm`` that only the claims table reads (issue 31): conditions (18) of paper 000 for the
Fig. 5 constraint-node sets, and Fig. 6's x-update as printed against the Lagrangian's on an irregular and a
regular graph (docs/admm.md). Kept beside :mod:`distnav.experiments.admm` so that module stays one reproduction."""

from __future__ import annotations

from typing import Any

import numpy as np

from distnav.algorithms.lsq.admm import admm
from distnav.algorithms.lsq.blue import LinearProblem, blue
from distnav.experiments.common import ExperimentContext
from distnav.network import builders
from distnav.network.constraint_nodes import ConstraintNodes, check_conditions, choose_constraint_nodes
from distnav.network.graph import Graph

__all__ = ["fig5_conditions", "fig6_as_printed"]


def fig5_conditions(graph: Graph, sets: dict[str, ConstraintNodes], finals: dict[str, float]) -> dict[str, Any]:
    """Per constraint-node set: whether conditions (18) hold (:func:`check_conditions`, paper 000 §3.2), the links
    no constraint node serves, and the final ``max_i ‖x_i − x̂‖/‖x̂‖`` of its run (convergence to the BLUE)."""
    out: dict[str, Any] = {}
    for key, C in sets.items():
        report = check_conditions(graph, C.nodes)
        out[key] = {
            "nodes_1_based": [int(i) + 1 for i in C.nodes],
            "conditions_18_hold": report.ok,
            "unused_links_1_based": [[int(a) + 1, int(b) + 1] for a, b in C.summary()["unused_links"]],
            "final_relative_distance_to_blue": float(finals[key]),
        }
    return out


def fig6_as_printed(
    ctx: ExperimentContext, graph: Graph, C: ConstraintNodes, problem: LinearProblem, rho: float, iterations: int
) -> dict[str, Any]:
    """Final ``max_i ‖x_i − x̂‖/‖x̂‖`` of Fig. 6 as printed (``x_weight="fig6"``: the plain mean of the constraint
    states) and of the Lagrangian's weighting, on the Fig. 5 graph (unequal numbers of constraint nodes ``c_i``)
    and on a 9-node ring with every node a constraint node (every ``c_i = 3``), same data."""
    ring = builders.ring(graph.n_nodes)
    all_ring = choose_constraint_nodes(ring, "all")
    ref = blue(problem).x
    out: dict[str, Any] = {"rho": rho, "iterations": iterations}
    for label, g, cn in (("fig5_graph", graph, C), ("regular_ring", ring, all_ring)):
        for weight in ("fig6", "lagrangian"):
            res = admm(
                problem,
                g,
                constraint_nodes=cn,
                W=rho,
                x_weight=weight,
                max_iterations=iterations,
                tol=0.0,
                reference=ref,
                exchange=ctx.exchange(g),
            )
            out[f"{label}_{weight}"] = float(np.asarray(res.trace["relative_max_distance"])[-1])
    closed = graph.adjacency(include_self=True).tocsr()
    out["fig5_graph_c_i"] = [int(v) for v in np.asarray(closed[:, C.nodes].sum(axis=1)).ravel()]
    return out
