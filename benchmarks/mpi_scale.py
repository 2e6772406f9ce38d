"""One consensus (or ADMM) job on graph parts, measured per rank (launched by ``bench_scale.py`` under ``mpiexec``).

    mpiexec -n R python -m mpi4py benchmarks/mpi_scale.py N_NODES ROUNDS REPEATS
    mpiexec -n R python -m mpi4py benchmarks/mpi_scale.py admm N_NODES ITERATIONS REPEATS [ORDER]

``admm`` (:func:`admm_main`): ADMM with aggregated messages on the parts
(:func:`~distnav.algorithms.lsq.on_part.iterate_admm_on_part`) of an 8-neighbour grid of ``≈ N_NODES`` nodes (ADMM
needs a connected graph; the tiled geometric graph at mean degree 8 leaves ≈ n·e⁻⁸ nodes alone), p = 10 and 5 rows
per node drawn by each rank for its own nodes; per rank the set-up CPU seconds (part; ADMM: constraint nodes,
rounds, gains, state 0), ``VmHWM`` after the part and the problem, after the set-up and after the iterations, and
the iteration against its floor: two products of a 0/1 CSR matrix of the rank's rows (``p`` columns, written from
the part) and the batched x-update products, timed after the run. ``ORDER`` is the exchange's local order
(default ``"none"``: the grid's row-major ids are already local, and the exchange then shares the part's edge
arrays instead of holding a permuted copy; ``"auto"``: reverse Cuthill–McKee of the part).
"""

from __future__ import annotations

import json
import os
import sys
import time
from typing import Any

import numpy as np
import scipy.sparse as sp
from mpi4py import MPI
from scipy.sparse.csgraph import reverse_cuthill_mckee

from distnav.exchange import make_exchange
from distnav.network.graph_part import GraphPart
from distnav.network.part_builders import grid_part, radius_for_mean_degree, tiled_random_geometric_part
from distnav.network.partition import block_ranges
from distnav.network.weights import PartWeights, part_weights

#: The ``admm`` job's glibc ``M_MMAP_THRESHOLD`` (bytes; ``DISTNAV_MMAP_THRESHOLD``, 0: glibc's default, which
#: raises the threshold up to 32 MB after the first large free, so freed set-up temporaries stay in the heap).
MMAP_THRESHOLD = 256 * 1024


def return_freed_blocks(threshold: int) -> int:
    """Every allocation of at least ``threshold`` bytes gets its own mapping, returned to the system when freed
    (glibc ``mallopt(M_MMAP_THRESHOLD)``; as ``MALLOC_MMAP_THRESHOLD_=threshold`` in the environment). Returns the
    threshold set, 0 where not set (``threshold`` 0, or no glibc)."""
    if threshold <= 0:
        return 0
    import ctypes
    import ctypes.util

    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        return threshold if libc.mallopt(-3, threshold) == 1 else 0  # M_MMAP_THRESHOLD = -3
    except (OSError, AttributeError):  # pragma: no cover - not glibc
        return 0


def vm_hwm_mb() -> float:
    with open("/proc/self/status") as fh:
        for line in fh:
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024.0
    return float("nan")


def floor_matrix(part: GraphPart, w: PartWeights) -> sp.csr_matrix:
    """``W``'s rows of this rank over ``[owned | halo]`` columns, owned nodes in scipy's RCM order."""
    n_own = part.n_local
    dst = np.repeat(np.arange(n_own), np.diff(part.in_ptr))
    k, own = part.owned_positions(part.src)
    col = np.where(own, k, n_own + np.searchsorted(part.halo, part.src))
    inner = sp.csr_matrix((np.ones(int(own.sum())), (dst[own], k[own])), shape=(n_own, n_own))
    perm = np.asarray(reverse_cuthill_mckee(inner, symmetric_mode=True), np.int64)
    new = np.empty(n_own, np.int64)
    new[perm] = np.arange(n_own)
    col = np.where(own, new[np.minimum(col, n_own - 1)], col)
    rows = np.concatenate([new[dst], new])
    cols = np.concatenate([col, new])
    data = np.concatenate([w.edge_weight, w.self_weight])
    return sp.csr_matrix((data, (rows, cols)), shape=(n_own, n_own + part.halo.size))


def ping_pong(comm: Any, nbytes: int, reps: int) -> float:
    """Seconds for one message of ``nbytes`` from rank 0 to rank 1 (half a round trip, best of ``reps``)."""
    buf = np.zeros(max(nbytes, 1), np.uint8)
    best = float("inf")
    for _ in range(reps):
        comm.Barrier()
        t0 = time.perf_counter()
        if comm.Get_rank() == 0:
            comm.Send(buf, dest=1)
            comm.Recv(buf, source=1)
        elif comm.Get_rank() == 1:
            comm.Recv(buf, source=0)
            comm.Send(buf, dest=0)
        best = min(best, (time.perf_counter() - t0) / 2)
    return best


def main() -> None:
    n, rounds, repeats = int(sys.argv[1]), int(sys.argv[2]), int(sys.argv[3])
    comm = MPI.COMM_WORLD
    rank, size = comm.Get_rank(), comm.Get_size()
    row: dict[str, Any] = {"rank": rank, "import_mb": vm_hwm_mb()}
    ranges = block_ranges(n, size)
    t = time.process_time()
    part = tiled_random_geometric_part(n, radius_for_mean_degree(n, 8), seed=1, nodes=ranges.nodes_of(rank), comm=comm)
    row["part_s"] = time.process_time() - t
    row["part_mb"] = vm_hwm_mb()
    t = time.process_time()
    weights = part_weights(part, "MH")
    row["weights_s"] = time.process_time() - t
    t = time.process_time()
    ex = make_exchange(part, backend="mpi", partition=ranges)
    row["exchange_s"] = time.process_time() - t
    t = time.process_time()
    mixer = ex.mixer(weights)
    row["mixer_s"] = time.process_time() - t
    row["setup_s"] = row["part_s"] + row["weights_s"] + row["exchange_s"] + row["mixer_s"]
    row["setup_mb"] = vm_hwm_mb()
    floor = floor_matrix(part, weights)
    x = ex.nodes.astype(float) / n
    cols = np.random.default_rng(rank).random(floor.shape[1])
    ours, bare, halo = [], [], []
    for _ in range(repeats):
        comm.Barrier()
        t0 = time.perf_counter()
        for _ in range(rounds):
            x = mixer.apply(x)
        ours.append((time.perf_counter() - t0) / rounds)
        t0 = time.perf_counter()
        for _ in range(rounds):
            y = floor @ cols
        bare.append((time.perf_counter() - t0) / rounds)
        del y
        comm.Barrier()
        t0 = time.perf_counter()
        for _ in range(rounds):
            ex.halo(x[:, None])
        halo.append((time.perf_counter() - t0) / rounds)
    ratio = np.asarray(ours) / np.asarray(bare)
    row.update(
        owned=part.n_local,
        in_edges=part.n_local_edges,
        halo_nodes=int(ex.n_halo),
        neighbour_ranks=int(ex.neighbour_ranks.size),
        halo_bytes_per_round=int(ex.n_halo) * 8,
        sent_bytes_per_round=int(ex._send_node_idx.size) * 8,
        round_ms=float(np.median(ours)) * 1e3,
        floor_ms=float(np.median(bare)) * 1e3,
        halo_ms=float(np.median(halo)) * 1e3,
        ratio_min=float(ratio.min()),
        ratio_median=float(np.median(ratio)),
        end_mb=vm_hwm_mb(),
    )
    if size > 1:  # ranks 0 and 1 measure; the others wait at the barriers
        latency, big = ping_pong(comm, 8, 200), ping_pong(comm, 1 << 23, 10)
        if rank == 0:
            row["latency_s"], row["bandwidth_Bps"] = latency, (1 << 23) / big
    rows = comm.gather(row)
    if rank == 0:
        print(json.dumps({"n_nodes": n, "n_edges": part.n_edges, "ranks": size, "rounds": rounds, "per_rank": rows}))


def admm_main() -> None:
    """The ``admm`` job (module docstring): rank 0 prints one JSON line with every rank's row."""
    from distnav.algorithms.lsq.blue import LinearProblem
    from distnav.algorithms.lsq.on_part import iterate_admm_on_part

    n, iterations, repeats = int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4])
    order = sys.argv[5] if len(sys.argv) > 5 else "none"
    p, m = 10, 5
    comm = MPI.COMM_WORLD
    rank, size = comm.Get_rank(), comm.Get_size()
    threshold = int(os.environ.get("DISTNAV_MMAP_THRESHOLD", MMAP_THRESHOLD))
    row: dict[str, Any] = {"rank": rank, "import_mb": vm_hwm_mb(), "mmap_threshold": return_freed_blocks(threshold)}
    side = int(round(np.sqrt(n)))  # an 8-neighbour grid: connected (a tiled geometric graph has lone nodes)
    n = side * side
    ranges = block_ranges(n, size)
    t = time.process_time()
    part = grid_part(side, side, ranges.nodes_of(rank), neighbourhood=8)
    row["part_s"] = time.process_time() - t
    ex = make_exchange(part, backend="mpi", partition=ranges, order=order)
    row["order"] = order
    row["exchange_s"] = time.process_time() - t - row["part_s"]
    rng = np.random.default_rng([7, rank])  # this rank's nodes' data, drawn here
    A = rng.standard_normal((part.n_local, m, p))
    y = A @ rng.standard_normal(p) + 0.1 * rng.standard_normal((part.n_local, m))
    problem = LinearProblem.from_stacked(A, y)
    row["part_mb"] = vm_hwm_mb()
    t = time.process_time()
    states = iterate_admm_on_part(problem, ex, W=5.0, messages="aggregated", monitor_every=0)
    next(states)
    row["admm_setup_s"] = time.process_time() - t
    row["setup_s"] = row["part_s"] + row["exchange_s"] + row["admm_setup_s"]
    row["setup_mb"] = vm_hwm_mb()
    ours = []
    for _ in range(repeats):
        comm.Barrier()
        t0 = time.perf_counter()
        for _ in range(iterations):
            st = next(states)
        ours.append((time.perf_counter() - t0) / iterations)
    row["iterations_mb"] = vm_hwm_mb()
    row["problem_mb"] = (A.nbytes + y.nbytes) / 2**20  # the caller's data (A, y), in the peak above
    x_last = st.x.copy()
    del st, states, problem  # the solver's arrays go before the checks' and the floor's are made (the job's)
    row.update(_admm_check(ex, A, y, x_last, comm))
    ex.free()
    bare = _admm_floor(part, A, x_last, iterations, repeats, comm)
    ratio = np.asarray(ours) / np.asarray(bare)
    row.update(
        owned=part.n_local,
        in_edges=part.n_local_edges,
        iteration_ms=float(np.median(ours)) * 1e3,
        floor_ms=float(np.median(bare)) * 1e3,
        ratio_min=float(ratio.min()),
        ratio_median=float(np.median(ratio)),
        end_mb=vm_hwm_mb(),
    )
    rows = comm.gather(row)
    if rank == 0:
        print(
            json.dumps(
                {"n_nodes": n, "n_edges": part.n_edges, "ranks": size, "iterations": iterations, "per_rank": rows}
            )
        )


def _admm_check(ex: Any, A: np.ndarray, y: np.ndarray, x: np.ndarray, comm: Any) -> dict[str, float]:
    """What the job can check of its result without the whole network: the centralized least-squares solution
    ``x̂ = (Σ A_iᵀA_i)⁻¹ Σ A_iᵀy_i`` (``R = I``; the network sums by allreduce: ``p × p`` numbers) and the distance of
    every node's ``x_i`` from it, and the consensus disagreement ``max ‖x_i − x_j‖∞`` over the links (the halo
    read once, a chunk of in-edges at a time). Both are network maxima (the same on every rank)."""
    p = A.shape[2]
    flat = A.reshape(-1, p)
    N = np.asarray(ex.allreduce(flat.T @ flat, "sum"))
    b = np.asarray(ex.allreduce(flat.T @ y.reshape(-1), "sum"))
    x_hat = np.linalg.solve(N, b)
    cols = ex.node_columns(x)  # [local | halo], the local rows in the exchange's order (as x)
    link = 0.0
    for a in range(0, ex.in_dst.size, 1 << 18):
        d = cols[ex.in_src_col[a : a + (1 << 18)]] - x[ex.in_dst[a : a + (1 << 18)]]
        link = max(link, float(np.abs(d).max(initial=0.0)))
    del cols
    return {
        "max_err_vs_central": float(ex.allreduce(float(np.abs(x - x_hat).max(initial=0.0)), "max")),
        "max_link_disagreement": float(ex.allreduce(link, "max")),
        "central_norm": float(np.abs(x_hat).max()),
    }


def _admm_floor(part: GraphPart, A: np.ndarray, x: np.ndarray, iterations: int, repeats: int, comm: Any) -> list[float]:
    """Seconds per bare iteration of this rank: two products of a 0/1 CSR matrix of its rows over ``[owned | halo]``
    columns with ``p`` columns of values, and the x-update's two batched products (``A l`` and ``Aᵀ r``, standing in
    for ``G r``: the same shapes), made after the run (not in its memory)."""
    n_own, p = part.n_local, A.shape[2]
    w = PartWeights(part, np.ones(part.n_local_edges), np.ones(n_own))
    S = floor_matrix(part, w)
    cols = np.random.default_rng(1).random((S.shape[1], p))
    At = np.ascontiguousarray(A.transpose(0, 2, 1))
    l = x.copy()
    out = []
    for _ in range(repeats):
        comm.Barrier()
        t0 = time.perf_counter()
        for _ in range(iterations):
            xs = S @ cols
            zs = S @ cols
            res = (A @ l[..., None])[..., 0]
            l = l + (At @ res[..., None])[..., 0] * 1e-3
            del xs, zs
        out.append((time.perf_counter() - t0) / iterations)
    return out


if __name__ == "__main__":
    if sys.argv[1] == "admm":
        admm_main()
    else:
        main()
