"""decent-bench's own ADMM on a problem given in an ``.npz`` file; run by ``benchmarks/bench_peers.py`` with the
*peers'* Python (decent-bench 0.3.0 needs Python ≥ 3.13; it is never imported by distnav or its tests).

    <peers-python> decent_bench_admm.py PROBLEM.npz ITERATIONS REPEATS PENALTY [PENALTY ...]

The file holds ``A`` (n, m, p), ``y`` (n, m), ``links`` (L, 2) and the centralized solution ``x_ref`` (p,). Every
node's cost is decent-bench's ``LinearRegressionCost`` of its own m rows, ``(1/2m)‖A_i x − y_i‖²``; with the same
m at every node the sum's minimizer is the unweighted least-squares solution, i.e. ``x_ref`` (checked here with
``numpy.linalg.lstsq`` and printed as ``x_ref_check``). The algorithm is ``decent_bench.algorithms.p2p.ADMM``
(defaults: relaxation 0.5, zero initial states) run through its public ``Algorithm.run`` on a ``P2PNetwork`` of the
same links, one agent per node, numpy backend, CPU, snapshots only at the last iteration. For each penalty:
``REPEATS`` fresh runs of ``ITERATIONS`` iterations, wall time per iteration of each run (set-up apart), and the
error ``max_i ‖x_i − x_ref‖ / ‖x_ref‖`` after the run. Prints one JSON object.
"""

from __future__ import annotations

import json
import sys
import time
from importlib.metadata import version

import networkx as nx
import numpy as np
from decent_array import interoperability as iop
from decent_array.types import Devices, Frameworks


def main(argv: list[str]) -> None:
    path, iterations, repeats = argv[0], int(argv[1]), int(argv[2])
    penalties = [float(v) for v in argv[3:]]
    iop.set_backend(Frameworks.NUMPY, Devices.CPU)
    from decent_bench.agents import Agent
    from decent_bench.algorithms.p2p import ADMM
    from decent_bench.costs import LinearRegressionCost
    from decent_bench.networks import P2PNetwork

    data = np.load(path)
    A, y, links, x_ref = data["A"], data["y"], data["links"], data["x_ref"]
    n, m, _ = A.shape
    check = np.linalg.lstsq(A.reshape(n * m, -1), y.reshape(-1), rcond=None)[0]
    graph: nx.Graph = nx.Graph()
    graph.add_nodes_from(range(n))
    graph.add_edges_from(map(tuple, links.tolist()))

    def network() -> tuple[P2PNetwork, list[Agent]]:
        agents = [
            Agent(
                LinearRegressionCost([(iop.from_numpy(A[i, k]), iop.from_numpy(y[i, k : k + 1])) for k in range(m)]),
                state_snapshot_period=iterations,
            )
            for i in range(n)
        ]
        return P2PNetwork(graph, agents), agents

    runs = []
    for penalty in penalties:
        for _ in range(repeats):
            t0 = time.perf_counter()
            net, agents = network()
            t1 = time.perf_counter()
            ADMM(penalty=penalty).run(net, iterations)
            t2 = time.perf_counter()
            x = np.stack([iop.to_numpy(a.x) for a in agents])
            err = float(np.linalg.norm(x - x_ref, axis=1).max() / np.linalg.norm(x_ref))
            runs.append(
                {
                    "penalty": penalty,
                    "setup_s": t1 - t0,
                    "ms_per_iteration": (t2 - t1) / iterations * 1e3,
                    "final_relative_error": err,
                }
            )
    print(
        json.dumps(
            {
                "package": "decent-bench",
                "version": version("decent-bench"),
                "python": sys.version.split()[0],
                "numpy": np.__version__,
                "n_nodes": n,
                "iterations": iterations,
                "x_ref_check": float(np.abs(check - x_ref).max() / np.abs(x_ref).max()),
                "runs": runs,
            }
        )
    )


if __name__ == "__main__":
    main(sys.argv[1:])
