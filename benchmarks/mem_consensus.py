"""Peak memory of a consensus run at scale, distnav against bare numpy/scipy arrays (one process per mode).

    python benchmarks/mem_consensus.py {distnav,bare} N_NODES PAYLOAD ROUNDS [DROP]
    python benchmarks/mem_consensus.py partition N_NODES RANKS OWNER.npy
    mpiexec -n RANKS python -m mpi4py benchmarks/mem_consensus.py {mpi-part,mpi-whole} N PAYLOAD ROUNDS DROP OWNER.npy

``partition`` writes a partition file once (nodes cut into equal chunks along a Hilbert curve through the
builder's positions: no graph is built). ``mpi-part``: each rank builds only its part of the graph
(:func:`~distnav.network.builders.random_geometric_part`) for the nodes the file gives it, the exchange reads the
same file; ``mpi-whole``: each rank builds the whole graph (the way before parts). Rank 0 prints every rank's
peak memory per stage, the part's bytes and its owned nodes and links.

Both modes draw the same random geometric graph (mean degree ≈ 8, the same seed), Metropolis–Hastings weights,
nodes renumbered by reverse Cuthill–McKee, and run ``ROUNDS`` consensus rounds on ``PAYLOAD`` floats per node.
``distnav``: :class:`~distnav.network.graph.Graph` from the builder, ``consensus_weights``, the in-process exchange
and its mixer (with a fault schedule dropping ``DROP`` of the messages when given). ``bare``, written without
distnav: the k-d tree's link pairs, the weights and one scipy CSR matrix, RCM-renumbered, the rounds as CSR
products (with drops: the bare drop round of bench_consensus, masked data and lost weight to the diagonal).
Prints one JSON line: peak resident memory (``VmHWM``) after the imports, after the graph, after the set-up
and at the end, in MB. ``bench_consensus`` launches it (a fresh process per measurement).
"""

from __future__ import annotations

import json
import resource
import sys
import time

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import reverse_cuthill_mckee
from scipy.spatial import cKDTree


def rss_mb() -> float:
    """Peak resident memory of this process so far: ``VmHWM`` (Linux; reset by exec, unlike ``ru_maxrss``, which a
    child started from a large parent inherits), else ``ru_maxrss``."""
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / 1024.0  # kB
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # Linux: kilobytes


def bare(n: int, payload: int, rounds: int, drop: float) -> dict[str, float]:
    mem = {"import_mb": rss_mb()}
    rng = np.random.default_rng(0)
    pos = rng.uniform(0.0, 1.0, size=(n, 2))
    pairs = cKDTree(pos).query_pairs(float(np.sqrt(8 / (np.pi * n))), output_type="ndarray")
    del pos
    mem["graph_mb"] = rss_mb()
    deg = np.bincount(pairs.ravel(), minlength=n)
    w = 1.0 / (1.0 + np.maximum(deg[pairs[:, 0]], deg[pairs[:, 1]]))
    self_w = 1.0 - np.bincount(pairs.ravel(), weights=np.repeat(w, 2), minlength=n)
    i, j = pairs[:, 0], pairs[:, 1]
    W = sp.csr_matrix(
        (np.concatenate([w, w, self_w]), (np.concatenate([i, j, np.arange(n)]), np.concatenate([j, i, np.arange(n)]))),
        shape=(n, n),
    )
    del pairs, i, j, w, self_w, deg
    perm = reverse_cuthill_mckee(W, symmetric_mode=True)
    W = W[perm][:, perm].tocsr()
    x = np.random.default_rng(1).normal(size=(n, payload) if payload > 1 else n)[perm]
    if drop:
        rows = np.repeat(np.arange(n), np.diff(W.indptr))
        diag = rows == W.indices
        diag_pos, off_pos, off_rows = np.flatnonzero(diag), np.flatnonzero(~diag), rows[~diag]
        base = W.data.copy()
        del rows, diag
    mem["setup_mb"] = rss_mb()
    drops = np.random.default_rng(2)
    for _ in range(rounds):
        if drop:
            lost = drops.random(off_pos.size) < drop
            data = base.copy()
            data[off_pos[lost]] = 0.0
            data[diag_pos] += np.bincount(off_rows[lost], weights=base[off_pos[lost]], minlength=n)
            W.data = data
        x = W @ x
    mem["end_mb"] = rss_mb()
    return mem


def distnav(n: int, payload: int, rounds: int, drop: float) -> dict[str, float]:
    from distnav.exchange import FaultSchedule, make_exchange
    from distnav.network import builders, consensus_weights

    mem = {"import_mb": rss_mb()}
    g = builders.random_geometric(n, np.sqrt(8 / (np.pi * n)), rng=np.random.default_rng(0))
    mem["graph_mb"] = rss_mb()
    w = consensus_weights(g, "MH")
    ex = make_exchange(g, faults=FaultSchedule(drop_probability=drop, seed=1) if drop else None, order="auto")
    mixer = ex.mixer(w)
    x = ex.local(np.random.default_rng(1).normal(size=(n, payload) if payload > 1 else n))
    mem["setup_mb"] = rss_mb()
    for _ in range(rounds):
        x = mixer.apply(x)
    mem["end_mb"] = rss_mb()
    return mem


def write_owner(n: int, ranks: int, path: str) -> None:
    from distnav.formats.partition import write_partition
    from distnav.network.partition import space_filling_order

    pos = np.random.default_rng(0).uniform(0.0, 1.0, size=(n, 2))  # the builder's draw (seed 0, unit square)
    owner = np.empty(n, np.int64)
    owner[space_filling_order(pos)] = (np.arange(n) * ranks) // n
    write_partition(path, owner)


def mpi_run(n: int, payload: int, rounds: int, drop: float, path: str, whole: bool) -> None:
    from mpi4py import MPI

    from distnav.exchange import FaultSchedule, make_exchange
    from distnav.network import builders, consensus_weights

    comm = MPI.COMM_WORLD
    rank, size = comm.Get_rank(), comm.Get_size()
    mem = {"import_mb": rss_mb()}
    t0 = time.process_time()
    radius, rng = float(np.sqrt(8 / (np.pi * n))), np.random.default_rng(0)
    faults = FaultSchedule(drop_probability=drop, seed=1) if drop else None
    info: dict[str, float] = {}
    if whole:
        g = builders.random_geometric(n, radius, rng=rng)
        mem["graph_mb"] = rss_mb()
        w = consensus_weights(g, "MH")
        ex = make_exchange(g, backend="mpi", faults=faults, partition=path)
    else:
        from distnav.network.partition import read_partition
        from distnav.network.weights import part_weights

        owner = read_partition(path, n, size)
        part = builders.random_geometric_part(n, radius, rng=rng, nodes=np.flatnonzero(owner == rank))
        del owner
        mem["graph_mb"] = rss_mb()
        info = {
            "part_mb": part.nbytes / 2**20,
            "owned_nodes": part.n_local,
            "in_edges": part.n_local_edges,
            "halo_nodes": int(part.halo.size),
        }
        ex = make_exchange(part, backend="mpi", faults=faults, partition=path)
        w = part_weights(part, "MH")  # type: ignore[assignment]
    mixer = ex.mixer(w)
    x = ex.local(np.random.default_rng(1).normal(size=(n, payload) if payload > 1 else n))
    mem["setup_mb"] = rss_mb()
    setup_cpu = time.process_time() - t0
    for _ in range(rounds):
        x = mixer.apply(x)
    mem["end_mb"] = rss_mb()
    rows = comm.gather({"rank": rank, **mem, **info, "setup_cpu_s": setup_cpu}, root=0)
    if rank == 0:
        print(
            json.dumps(
                {
                    "mode": "mpi-whole" if whole else "mpi-part",
                    "n_nodes": n,
                    "ranks": size,
                    "payload_floats": payload,
                    "rounds": rounds,
                    "drop": drop,
                    "per_rank": rows,
                    "max_end_mb": max(r["end_mb"] for r in rows),
                }
            )
        )


def main() -> None:
    if sys.argv[1] == "partition":
        write_owner(int(sys.argv[2]), int(sys.argv[3]), sys.argv[4])
        return
    if sys.argv[1] in ("mpi-part", "mpi-whole"):
        mpi_run(
            int(sys.argv[2]),
            int(sys.argv[3]),
            int(sys.argv[4]),
            float(sys.argv[5]),
            sys.argv[6],
            sys.argv[1] == "mpi-whole",
        )
        return
    mode, n, payload, rounds = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4])
    drop = float(sys.argv[5]) if len(sys.argv) > 5 else 0.0
    t0 = time.perf_counter()
    mem = {"distnav": distnav, "bare": bare}[mode](n, payload, rounds, drop)
    print(
        json.dumps(
            {
                "mode": mode,
                "n_nodes": n,
                "payload_floats": payload,
                "rounds": rounds,
                "drop": drop,
                "seconds": time.perf_counter() - t0,
                **mem,
            }
        )
    )


if __name__ == "__main__":
    main()
