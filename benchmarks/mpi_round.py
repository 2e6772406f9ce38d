"""Launched by bench_mpi.py under mpiexec: distnav's MPI exchange (halo transport) and a full consensus round
vs a bare Neighbor_allgather of the same boundary payload on the same rank graph.

    mpiexec -n R python -m mpi4py benchmarks/mpi_round.py N_NODES PAYLOAD ROUNDS
Prints one JSON line on rank 0.
"""

from __future__ import annotations

import json
import sys
import time

import numpy as np
from mpi4py import MPI

from distnav.exchange.mpi import MPIExchange
from distnav.network import builders, consensus_weights

n, payload, rounds = int(sys.argv[1]), int(sys.argv[2]), int(sys.argv[3])
comm = MPI.COMM_WORLD
t0 = time.perf_counter()
g = builders.random_geometric(n, np.sqrt(8 / (np.pi * n)), rng=np.random.default_rng(0))
ex = MPIExchange(g)
setup = time.perf_counter() - t0
mixer = ex.mixer(consensus_weights(g, "P3"))
x = np.random.default_rng(1).normal(size=(ex.n_local, payload))


def timed(fn) -> float:
    best = float("inf")
    for _ in range(3):
        comm.Barrier()
        t = time.perf_counter()
        for _ in range(rounds):
            fn()
        comm.Barrier()
        best = min(best, (time.perf_counter() - t) / rounds)
    return comm.allreduce(best, op=MPI.MAX)


state = {"x": x}


def distnav_round() -> None:
    state["x"] = mixer.apply(state["x"])


halo_send = np.random.default_rng(2).normal(size=(int(ex._node_send_counts.max(initial=0)), payload))
nbrs = ex.neighbour_ranks.size
halo_recv = np.empty((nbrs, *halo_send.shape))


def bare_round() -> None:
    if nbrs:
        ex.dist_comm.Neighbor_allgather(halo_send, halo_recv)


flat = np.ascontiguousarray(x)


def distnav_exchange() -> None:
    ex._columns(flat, None)  # the transport alone: halo values of this block's neighbours


ours = timed(distnav_round)
transport = timed(distnav_exchange)
bare = timed(bare_round)
cut = comm.allreduce(ex.n_cut_edges, op=MPI.SUM)
if comm.Get_rank() == 0:
    print(json.dumps({"ranks": comm.Get_size(), "n_nodes": n, "payload_floats": payload,
                      "distnav_exchange_ms": transport * 1e3, "bare_neighbor_allgather_ms": bare * 1e3,
                      "ratio": transport / bare if bare > 0 else None,
                      "consensus_round_ms": ours * 1e3, "rounds_per_s": 1.0 / ours,
                      "cut_edges_fraction": cut / g.n_edges, "setup_s": setup}))
