"""Launched by bench_mpi.py under mpiexec: distnav's MPI exchange against bare mpi4py kernels of the same work.

    mpiexec -n R python -m mpi4py benchmarks/mpi_round.py N_NODES PAYLOAD ROUNDS

* transport: ``ex.halo`` (the halo of every neighbour rank into the column buffer: a persistent
  ``Neighbor_alltoallv_init`` request where the MPI library has it) against a bare ``Neighbor_alltoallv`` of the
  same counts on the same distributed-graph communicator, buffers preallocated, written here without distnav;
* full consensus round: ``Mixer.apply`` against that bare collective plus one scipy CSR product of this rank's
  block of ``W`` (built here from the exchange's index arrays);
* peak memory per rank (``ru_maxrss``) after import, after the graph, after the exchange + mixer set-up, and at
  the end, with this rank's node, link and halo counts (for the bytes-per-node / per-link fit in docs/scale.md).
Timings are interleaved batches (min and median of the per-batch ratios). Prints one JSON line on rank 0.
"""

from __future__ import annotations

import json
import resource
import sys
import time

import numpy as np
import scipy.sparse as sp
from mpi4py import MPI

from distnav.exchange.mpi import MPIExchange
from distnav.network import builders, consensus_weights


def rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # Linux: kilobytes


n, payload, rounds = int(sys.argv[1]), int(sys.argv[2]), int(sys.argv[3])
comm = MPI.COMM_WORLD
mem = {"import_mb": rss_mb()}
t0 = time.perf_counter()
g = builders.random_geometric(n, np.sqrt(8 / (np.pi * n)), rng=np.random.default_rng(0))
graph_s = time.perf_counter() - t0
mem["graph_mb"] = rss_mb()
t0 = time.perf_counter()
ex = MPIExchange(g)
w = consensus_weights(g, "P3")
mixer = ex.mixer(w)
comm.Barrier()
setup = time.perf_counter() - t0
mem["setup_mb"] = rss_mb()
x = np.random.default_rng(1).normal(size=(ex.n_local, payload))

# ---- bare kernels, written without distnav (only its index arrays are read)
nbr = ex.neighbour_ranks.size
sc, rc = ex._node_send_counts * payload, ex._node_recv_counts * payload


def displs(c: np.ndarray) -> list[int]:
    return np.concatenate([[0], np.cumsum(c)[:-1]]).astype(int).tolist() if c.size else []


bare_send = np.empty((int(ex._node_send_counts.sum()), payload))
bare_recv = np.empty((int(ex._node_recv_counts.sum()), payload))
send_spec = [bare_send, (sc.tolist(), displs(sc))]
recv_spec = [bare_recv, (rc.tolist(), displs(rc))]
W_block = sp.csr_matrix(
    (
        np.concatenate([w.edge_weight[ex.in_edges], w.self_weight[ex.nodes]]),
        (np.concatenate([ex.in_dst, np.arange(ex.n_local)]), np.concatenate([ex.in_src_col, ex.local_col])),
    ),
    shape=(ex.n_local, ex.n_columns),
)
bare_cols = np.empty((ex.n_columns, payload))


def bare_transport() -> None:
    if nbr:
        np.take(x, ex._send_node_idx, axis=0, out=bare_send)
        ex.dist_comm.Neighbor_alltoallv(send_spec, recv_spec)


def bare_round() -> None:
    bare_transport()
    bare_cols[: ex.n_local] = x
    bare_cols[ex.n_local :] = bare_recv
    W_block @ bare_cols


def distnav_transport() -> None:
    ex.halo(x)  # the boundary values sent and the halo received, as the bare collective does


def distnav_round() -> None:
    mixer.apply(x)


def paired(fns: dict, repeat: int = 5) -> dict[str, np.ndarray]:
    out: dict[str, list[float]] = {k: [] for k in fns}
    for _ in range(repeat):
        for k, fn in fns.items():
            comm.Barrier()
            t = time.perf_counter()
            for _ in range(rounds):
                fn()
            comm.Barrier()
            out[k].append(comm.allreduce((time.perf_counter() - t) / rounds, op=MPI.MAX))
    return {k: np.asarray(v) for k, v in out.items()}


t = paired(
    {"transport": distnav_transport, "bare_transport": bare_transport, "round": distnav_round, "bare_round": bare_round}
)
mem["end_mb"] = rss_mb()
tr = t["transport"] / t["bare_transport"]
rr = t["round"] / t["bare_round"]
cut = comm.allreduce(ex.n_cut_edges, op=MPI.SUM)
per_rank = comm.gather({**mem, "n_local": ex.n_local, "in_edges": int(ex.in_edges.size), "halo": ex.n_halo}, root=0)
if comm.Get_rank() == 0:
    print(
        json.dumps(
            {
                "ranks": comm.Get_size(),
                "n_nodes": n,
                "n_edges": g.n_edges,
                "payload_floats": payload,
                "persistent": ex.persistent,
                "transport_ms": float(np.median(t["transport"])) * 1e3,
                "bare_alltoallv_ms": float(np.median(t["bare_transport"])) * 1e3,
                "transport_ratio_min": float(tr.min()),
                "transport_ratio_median": float(np.median(tr)),
                "round_ms": float(np.median(t["round"])) * 1e3,
                "bare_round_ms": float(np.median(t["bare_round"])) * 1e3,
                "round_ratio_min": float(rr.min()),
                "round_ratio_median": float(np.median(rr)),
                "cut_edges_fraction": cut / g.n_edges,
                "graph_s": graph_s,
                "setup_s": setup,
                "per_rank": per_rank,
            }
        )
    )
