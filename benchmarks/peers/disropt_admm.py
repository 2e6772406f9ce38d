"""disropt's own ADMM on a problem given in an ``.npz`` file; launched by ``benchmarks/bench_peers.py`` with the
*peers'* Python under MPI, one rank per node (disropt runs one agent per MPI process):

    mpiexec -n N <peers-python> disropt_admm.py PROBLEM.npz ITERATIONS PENALTY

The file holds ``A`` (n, m, p), ``y`` (n, m), ``links`` (L, 2) and the centralized solution ``x_ref`` (p,). Rank
``i`` is node ``i`` with cost ``‖A_i x − y_i‖²`` (disropt ``SquaredNorm`` of an affine form; disropt's ``M @ x``
means ``Mᵀ x``, so the form is built from ``A_iᵀ`` and checked against numpy at a random point), neighbours from the
links, zero initial multipliers and z, ``disropt.algorithms.ADMM(...).run(iterations, penalty)`` — its x-update
solves a generic convex problem every iteration (cvxpy by default). Wall time of the run between two barriers
(the slowest rank), and ``max_i ‖x_i − x_ref‖ / ‖x_ref‖`` after it; rank 0 prints one JSON object.
"""

from __future__ import annotations

import json
import sys
import time
from importlib.metadata import version

import numpy as np
from mpi4py import MPI


def main(argv: list[str]) -> None:
    path, iterations, penalty = argv[0], int(argv[1]), float(argv[2])
    from disropt.agents import Agent
    from disropt.algorithms import ADMM
    from disropt.functions import SquaredNorm, Variable
    from disropt.problems import Problem

    comm = MPI.COMM_WORLD
    rank, size = comm.Get_rank(), comm.Get_size()
    data = np.load(path)
    A, y, links, x_ref = data["A"], data["y"], data["links"], data["x_ref"]
    n, _, p = A.shape
    if size != n:
        raise SystemExit(f"disropt_admm.py: launched with {size} ranks for {n} nodes (one rank per node)")
    nbrs = sorted({int(b) for a, b in links if a == rank} | {int(a) for a, b in links if b == rank})
    x = Variable(p)
    f = SquaredNorm(A[rank].T @ x - y[rank][:, None])
    probe = np.random.default_rng(rank).normal(size=(p, 1))
    want = float(np.sum((A[rank] @ probe[:, 0] - y[rank]) ** 2))
    got = float(np.asarray(f.eval(probe)).ravel()[0])
    agent = Agent(in_neighbors=nbrs, out_neighbors=nbrs)
    agent.set_problem(Problem(f))
    alg = ADMM(agent=agent, initial_lambda={j: np.zeros((p, 1)) for j in [*nbrs, rank]}, initial_z=np.zeros((p, 1)))
    comm.Barrier()
    t0 = time.perf_counter()
    alg.run(iterations=iterations, penalty=penalty)
    comm.Barrier()
    wall = time.perf_counter() - t0
    xi = np.asarray(alg.get_result()[0], dtype=float).ravel()
    xs = comm.gather(xi, root=0)
    checks = comm.gather(abs(got - want) / max(want, 1e-300), root=0)
    walls = comm.gather(wall, root=0)
    if rank == 0:
        X = np.stack(xs)  # type: ignore[arg-type]
        err = float(np.linalg.norm(X - x_ref, axis=1).max() / np.linalg.norm(x_ref))
        print(
            json.dumps(
                {
                    "package": "disropt",
                    "version": version("disropt"),
                    "python": sys.version.split()[0],
                    "numpy": np.__version__,
                    "n_nodes": n,
                    "iterations": iterations,
                    "penalty": penalty,
                    "ms_per_iteration": max(walls) / iterations * 1e3,  # type: ignore[arg-type]
                    "final_relative_error": err,
                    "cost_check": max(checks),
                }
            )
        )  # type: ignore[arg-type]


if __name__ == "__main__":
    main(sys.argv[1:])
