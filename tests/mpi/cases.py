"""Algorithm runs that must give the same numbers in-process and under MPI.

Each case is ``f(backend: str) -> dict[str, np.ndarray]``; ``run_cases.py`` runs them under ``mpiexec`` and
``tests/test_mpi.py`` compares with the in-process run. Add a case for every distributed algorithm.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import partial
from typing import Any

import numpy as np

from distnav.algorithms.consensus.averaging import average_consensus
from distnav.exchange import FaultSchedule, make_exchange
from distnav.network import Graph, SwitchingGraph, builders, consensus_weights

CASES: dict[str, Callable[[str], dict[str, np.ndarray]]] = {}


def case(fn: Callable[[str], dict[str, np.ndarray]]) -> Callable[[str], dict[str, np.ndarray]]:
    CASES[fn.__name__] = fn
    return fn


def _graph() -> Graph:
    return builders.connected_random_geometric(60, mean_degree=6, rng=np.random.default_rng(1))


@case
def consensus_static(backend: str) -> dict[str, np.ndarray]:
    g = _graph()
    vals = np.random.default_rng(2).normal(size=(60, 2, 2))
    res = average_consensus(vals, graph=g, protocol="P3", rounds=25, exchange=make_exchange(g, backend=backend))
    return {
        "estimates": res.estimates,
        "trace": res.trace["max_abs_deviation"],
        "sent": res.comm.messages_sent,
        "bytes": res.comm.bytes_sent,
    }


@case
def consensus_with_faults(backend: str, order: str = "auto") -> dict[str, np.ndarray]:
    g = _graph()
    faults = FaultSchedule(
        drop_probability=0.2,
        failed_links=((int(g.links[0, 0]), int(g.links[0, 1]), 3),),
        silent_nodes=((5, 10),),
        seed=4,
    )
    vals = np.random.default_rng(3).normal(size=60)
    ex = make_exchange(g, backend=backend, faults=faults, order=order)
    res = average_consensus(vals, graph=g, protocol="MH", rounds=20, exchange=ex)
    return {
        "estimates": res.estimates,
        "sent": res.comm.messages_sent,
        "received": res.comm.messages_received,
        "per_round": res.comm.messages_per_round,
    }


@case
def consensus_switching(backend: str) -> dict[str, np.ndarray]:
    sessions = (
        Graph.from_links(8, [(0, 1), (2, 3), (4, 5), (6, 7)]),
        Graph.from_links(8, [(1, 2), (3, 4), (5, 6)]),
        Graph.from_links(8, [(7, 0)]),
    )
    sw = SwitchingGraph(sessions)
    ex = make_exchange(sw.union, backend=backend)
    res = average_consensus(np.arange(8.0), graph=sw, protocol="P4", rounds=13, exchange=ex)
    return {"estimates": res.estimates, "per_round": res.comm.messages_per_round}


@case
def raw_send_and_broadcast(backend: str, order: str = "auto") -> dict[str, np.ndarray]:
    g = _graph()
    ex = make_exchange(g, backend=backend, faults=FaultSchedule(drop_probability=0.3, seed=8), order=order)
    # each out-edge carries (src id, dst id, edge id): the receiver checks it got the right message
    vals = np.stack([g.src[ex.out_edges], g.dst[ex.out_edges], ex.out_edges], axis=1).astype(float)
    inbox = ex.send(vals)
    ok = inbox.delivered
    assert np.array_equal(inbox.values[ok], np.stack([inbox.src, ex.nodes[inbox.dst], inbox.edges], 1)[ok])
    b = ex.broadcast(ex.local(np.arange(60.0) ** 2))
    w = consensus_weights(g, "P3")
    mixed = ex.mixer(w).apply(ex.local(np.arange(60.0)))
    return {
        "edge_sum": ex.gather_nodes(inbox.sum()),
        "count": ex.gather_nodes(inbox.count()),
        "bcast_sum": ex.gather_nodes(b.sum()),
        "mixed": ex.gather_nodes(mixed),
        "sent": ex.comm_totals().messages_sent,
    }


@case
def route_send_and_broadcast(backend: str) -> dict[str, np.ndarray]:
    """Prepared routes (compact rounds over an edge subset) carry the right messages across ranks, with drops."""
    g = _graph()
    ex = make_exchange(g, backend=backend, faults=FaultSchedule(drop_probability=0.3, seed=8))
    active = (g.src + 2 * g.dst) % 3 != 0
    send_rows = np.flatnonzero(active[ex.out_edges])[::-1].copy()
    snd, bro = ex.route(active, out_rows=send_rows), ex.route(active)
    vals, ok = snd.send(
        np.stack([g.src[ex.out_edges], g.dst[ex.out_edges], ex.out_edges], axis=1)[send_rows].astype(float)
    )
    rows = snd.in_rows
    assert np.array_equal(vals[ok], np.stack([snd.src, ex.nodes[snd.dst], ex.in_edges[rows]], 1)[ok])
    assert not vals[~ok].any()
    bv, bok = bro.broadcast(ex.local(np.arange(60.0) ** 2))
    assert np.array_equal(bv[bok], (bro.src**2.0)[bok])
    per_node = np.bincount(bro.dst[bok], weights=bv[bok], minlength=ex.n_local)  # integer values: exact in any order
    return {
        "bcast_sum": ex.gather_nodes(per_node),
        "count": ex.gather_nodes(np.bincount(snd.dst[ok], minlength=ex.n_local)),
        "sent": ex.comm_totals().messages_sent,
        "received": ex.comm_totals().messages_received,
    }


def _linear_problem(n: int, p: int = 4, m: int = 2):
    from distnav.algorithms.lsq.blue import LinearProblem

    rng = np.random.default_rng(21)
    A = rng.normal(size=(n, m, p))  # m < p: every N_i singular
    x = rng.normal(size=p)
    y = np.einsum("nmp,p->nm", A, x) + 0.1 * rng.normal(size=(n, m))
    return LinearProblem.from_blocks(list(A), list(y), [0.01 * np.eye(m)] * n)


@case
def admm_constraint_nodes(backend: str, order: str = "auto") -> dict[str, np.ndarray]:
    from distnav.algorithms.lsq.admm import admm

    g = _graph()
    problem = _linear_problem(g.n_nodes)
    ex = make_exchange(g, backend=backend, order=order)
    res = admm(problem, g, constraint_nodes="min_cover", W=1.0, max_iterations=40, tol=0.0, exchange=ex)
    return {
        "estimates": res.estimates,
        "sent": res.comm.messages_sent,
        "bytes": res.comm.bytes_sent,
        "primal": res.trace["primal_residual"],
    }


@case
def admm_with_drops(backend: str, order: str = "auto") -> dict[str, np.ndarray]:
    from distnav.algorithms.lsq.admm import admm

    g = _graph()
    problem = _linear_problem(g.n_nodes)
    ex = make_exchange(g, backend=backend, faults=FaultSchedule(drop_probability=0.1, seed=3), order=order)
    res = admm(problem, g, constraint_nodes="all", W=1.0, max_iterations=25, tol=0.0, exchange=ex)
    return {"estimates": res.estimates, "received": res.comm.messages_received}


@case
def ckf_random_walk(backend: str) -> dict[str, np.ndarray]:
    from distnav.algorithms.kalman import DynamicModel, NormalSeries
    from distnav.algorithms.kalman.ckf import ckf

    g = builders.connected_random_geometric(12, mean_degree=4, rng=np.random.default_rng(5))
    n, p, T = g.n_nodes, 3, 6
    rng = np.random.default_rng(6)
    A = rng.normal(size=(T, n, 2, p))
    y = rng.normal(size=(T, n, 2))
    N = np.einsum("tnmp,tnmq->tnpq", A, A)
    r = np.einsum("tnmp,tnm->tnp", A, y)
    dyn = DynamicModel(p, noise_cov=np.diag([0.1, 0.05, 0.0]))
    res = ckf(dyn, NormalSeries(N, r), graph=g, protocol="P3", rounds=4, exchange=make_exchange(g, backend=backend))
    series = res.series
    return {"estimates": res.estimates, "std": series.std, "sent": res.comm.messages_sent}


def _relay_series(seed: int, n: int, outlier: bool = False) -> Any:
    from distnav.models.gnss.gfbias import BiasGeometryFreeSeries, BiasStateLayout

    S, T = 6, 5
    rng = np.random.default_rng(seed)
    lay = BiasStateLayout(tuple(f"G{k:02d}" for k in range(S)), tuple(f"R{i}" for i in range(n)), reference="R0")
    tracked = rng.random((T, n, S)) > 0.3
    obs = (0.3 if outlier else 1.0) * rng.standard_normal((T, n, S))
    if outlier:
        obs[3, 4, np.flatnonzero(tracked[3, 4])[0]] += 40.0  # node 4 must reject it at epoch 3
    return BiasGeometryFreeSeries(
        lay,
        rng.standard_normal((T, n, S, 3)),
        rng.uniform(0.2, 0.4 if outlier else 1.0, (T, n, S)),
        obs_m=obs,
        tracked=tracked,
        groups=np.zeros(n, np.int64),
    )


@case
def ckf_relay_transport(backend: str) -> dict[str, np.ndarray]:
    from distnav.algorithms.kalman import DynamicModel
    from distnav.algorithms.kalman.ckf import ckf

    g = builders.connected_random_geometric(12, mean_degree=4, rng=np.random.default_rng(5))
    ser = _relay_series(8, g.n_nodes)
    dyn = DynamicModel(ser.n_states, noise_cov=0.01 * np.eye(ser.n_states))
    ex = make_exchange(g, backend=backend)
    res = ckf(dyn, ser, graph=g, protocol="P3", rounds=3, transport="relay", exchange=ex)
    return {"estimates": res.series.estimates, "std": res.series.std, "bytes": res.comm.bytes_sent}


@case
def ckf_relay_with_innovation_tests(backend: str) -> dict[str, np.ndarray]:
    from distnav.algorithms.kalman import DynamicModel
    from distnav.algorithms.kalman.ckf import ckf

    g = builders.connected_random_geometric(12, mean_degree=4, rng=np.random.default_rng(5))
    ser = _relay_series(9, g.n_nodes, outlier=True)
    dyn = DynamicModel(ser.n_states, noise_cov=0.01 * np.eye(ser.n_states))
    ex = make_exchange(g, backend=backend)
    res = ckf(dyn, ser, graph=g, rounds=3, transport="relay", exchange=ex, local_precision="exact", test_level=0.001)
    assert res.tests is not None and res.local_std is not None
    return {
        "estimates": res.series.estimates,
        "local_std": res.local_std,
        "removed": np.asarray(res.tests.removed),
        "bytes": res.comm.bytes_sent,
    }


@case
def ckf_local_precision_and_tests(backend: str) -> dict[str, np.ndarray]:
    from distnav.algorithms.kalman import DynamicModel, ObservationSeries
    from distnav.algorithms.kalman.ckf import ckf

    g = builders.connected_random_geometric(12, mean_degree=4, rng=np.random.default_rng(5))
    n, p, T = g.n_nodes, 3, 6
    rng = np.random.default_rng(7)
    epochs = []
    for t in range(T):
        row = []
        for i in range(n):
            A = rng.normal(size=(3, p))
            y = rng.normal(size=3)
            if (t, i) == (4, 5):
                y[0] += 50.0  # a gross error the node must reject
            row.append((A, np.ones(3), y))
        epochs.append(row)
    dyn = DynamicModel(p, noise_cov=np.diag([0.1, 0.05, 0.0]))
    res = ckf(
        dyn,
        ObservationSeries(p, epochs),
        graph=g,
        protocol="P3",
        rounds=4,
        local_precision="exact",
        test_level=0.001,
        exchange=make_exchange(g, backend=backend),
    )
    assert res.tests is not None and res.local_std is not None
    return {
        "estimates": res.estimates,
        "local_std": res.local_std,
        "w": res.tests.w,
        "removed": np.array(res.tests.removed),
        "sent": res.comm.bytes_sent,
    }


def _admm_messages(backend: str, messages: str, W: float, iterations: int) -> dict[str, np.ndarray]:
    from distnav.algorithms.lsq.admm import admm

    g = _graph()
    problem = _linear_problem(g.n_nodes)
    ex = make_exchange(g, backend=backend)
    res = admm(
        problem,
        g,
        constraint_nodes="min_cover",
        W=W,
        messages=messages,
        max_iterations=iterations,
        tol=0.0,
        exchange=ex,
    )
    return {"estimates": res.estimates, "sent": res.comm.messages_sent, "bytes": res.comm.bytes_sent}


@case
def admm_aggregated_messages(backend: str) -> dict[str, np.ndarray]:
    return _admm_messages(backend, "aggregated", 2.0, 30)


@case
def admm_ternary_messages(backend: str) -> dict[str, np.ndarray]:
    return _admm_messages(backend, "ternary", 1.0, 40)


@case
def admm_precision_and_snooping(backend: str) -> dict[str, np.ndarray]:
    from distnav.algorithms.lsq.qc import admm_data_snooping
    from distnav.experiments.qc import gross_error_problem

    pb = gross_error_problem(np.random.default_rng([12, 0]))
    res = admm_data_snooping(pb.problem, pb.graph, W=3.0, tol=1e-11, exchange=make_exchange(pb.graph, backend=backend))
    assert res.precision is not None and res.tests is not None and res.precision.variance_factor is not None
    return {
        "estimates": res.estimates,
        "covariance": res.precision.covariance,
        "w": res.tests.w,
        "removed": np.array(res.tests.removed),
        "variance_factor": np.array(res.precision.variance_factor),
        "sent": res.comm.messages_sent,
    }


def _uwb_problem():
    from distnav.models.uwb.problems import generate_problem

    return generate_problem("RC", np.random.default_rng(31), n_anchors=40, dim=2)


@case
def ncsg_tbls(backend: str) -> dict[str, np.ndarray]:
    from distnav.algorithms.ranging.csg import solve_ncsg

    problem = _uwb_problem()
    res = solve_ncsg(problem, line_search="TBLS", iterations=30, exchange=make_exchange(problem.graph, backend=backend))
    return {
        "estimates": res.estimates,
        "sent": res.comm.messages_sent,
        "bytes": res.comm.bytes_sent,
        "cost": res.trace["cost"],
    }


@case
def csg_and_nclm(backend: str) -> dict[str, np.ndarray]:
    from distnav.algorithms.ranging.csg import solve_csg, solve_nclm

    problem = _uwb_problem()
    csg = solve_csg(problem, iterations=20, exchange=make_exchange(problem.graph, backend=backend), alpha=1e-4)
    nclm = solve_nclm(problem, iterations=10, exchange=make_exchange(problem.graph, backend=backend))
    return {
        "estimates": np.concatenate([csg.estimates.ravel(), nclm.estimates.ravel()]),
        "sent": csg.comm.messages_sent + nclm.comm.messages_sent,
    }


@case
def ncsg_tbls_with_drops(backend: str, order: str = "auto") -> dict[str, np.ndarray]:
    from distnav.algorithms.ranging.csg import solve
    from distnav.models.uwb.problems import generate_problem

    problem = generate_problem("RM", np.random.default_rng(3), n_anchors=40)
    ex = make_exchange(problem.graph, backend=backend, faults=FaultSchedule(drop_probability=0.1, seed=2), order=order)
    res = solve(problem, "N-CSG-TBLS", iterations=30, exchange=ex, monitor_every=7)  # gathers at 0, 7, …, 28, 30
    return {
        "estimates": res.estimates,
        "bytes": res.comm.bytes_sent,
        "received": res.comm.messages_received,
        "cost": res.trace["cost"],
    }


@case
def ncsg_metres_with_local_qc(backend: str) -> dict[str, np.ndarray]:
    from distnav.algorithms.ranging.csg import solve_ncsg

    problem = _uwb_problem()
    res = solve_ncsg(
        problem,
        line_search="TBLS",
        iterations=40,
        objective="metres",
        sigma_m=0.15,
        loss="cauchy",
        exchange=make_exchange(problem.graph, backend=backend),
    )
    return {
        "estimates": res.estimates,
        "w": np.nan_to_num(res.tests.w, nan=-99.0),
        "covariance": res.precision.covariance,
    }


# the same runs with the exchange's nodes renumbered by reverse Cuthill–McKee (issue 17 item 0): on the small graphs
# above "auto" keeps the user's order, so these exercise the locality order on both backends
for _fn in (
    consensus_with_faults,
    raw_send_and_broadcast,
    admm_constraint_nodes,
    admm_with_drops,
    ncsg_tbls_with_drops,
):
    CASES[f"{_fn.__name__}_rcm"] = partial(_fn, order="rcm")


@case
def transport_options(backend: str) -> dict[str, np.ndarray]:
    """The non-persistent transport, and a partition read from a file (in-process ignores both)."""
    import os
    import tempfile

    from distnav.formats.partition import write_partition
    from distnav.network.partition import partition_nodes

    g = _graph()
    faults = FaultSchedule(drop_probability=0.2, seed=6)
    plain = make_exchange(g, backend=backend, faults=faults, persistent=False)
    vals = np.random.default_rng(9).normal(size=(60, 3))
    res = average_consensus(vals, graph=g, protocol="MH", rounds=15, exchange=plain)
    owner = partition_nodes(g, 4, "block")[::-1].copy()  # any valid owner array: here blocks in reverse
    with tempfile.TemporaryDirectory() as tmp:
        path = write_partition(os.path.join(tmp, "owner.txt"), owner)
        ex = make_exchange(g, backend=backend, faults=faults, partition=path)
        inbox = ex.send(np.stack([g.src[ex.out_edges], ex.out_edges], axis=1).astype(float))
    return {
        "estimates": res.estimates,
        "received": res.comm.messages_received,
        "edge_sum": ex.gather_nodes(inbox.sum()),
        "count": ex.gather_nodes(inbox.count()),
    }


@case
def consensus_on_graph_parts(backend: str) -> dict[str, np.ndarray]:
    """MPI: each rank builds only its part of a random geometric graph (``random_geometric_part``) from a partition
    file (strips of the unit square, not a partition distnav computes); in-process: the whole graph. Drops, a
    silent node, raw broadcast/send rounds: the same numbers."""
    import os
    import tempfile

    from distnav.formats.partition import write_partition
    from distnav.network.graph_part import GraphPart
    from distnav.network.weights import part_weights

    n, radius = 3000, float(np.sqrt(8 / (np.pi * 3000)))
    faults = FaultSchedule(drop_probability=0.15, silent_nodes=((17, 4),), seed=6)
    x0 = np.random.default_rng(4).normal(size=(n, 2))
    if backend == "mpi":
        from mpi4py import MPI

        comm = MPI.COMM_WORLD
        rank, size = comm.Get_rank(), comm.Get_size()
        x_pos = np.random.default_rng(0).uniform(0.0, 1.0, size=(n, 2))[:, 0]  # the builder's first draw
        owner = np.minimum((x_pos * size).astype(np.int64), size - 1)
        tmp = comm.bcast(tempfile.mkdtemp() if rank == 0 else None)
        path = os.path.join(tmp, "owner.npy")
        if rank == 0:
            write_partition(path, owner)
        comm.Barrier()
        part: GraphPart = builders.random_geometric_part(
            n, radius, rng=np.random.default_rng(0), nodes=np.flatnonzero(owner == rank)
        )
        ex = make_exchange(part, backend="mpi", faults=faults, partition=path)
        mixer = ex.mixer(part_weights(part, "MH"))
        comm.Barrier()
        if rank == 0:
            os.remove(path)
            os.rmdir(tmp)
    else:
        g = builders.random_geometric(n, radius, rng=np.random.default_rng(0))
        ex = make_exchange(g, faults=faults)
        mixer = ex.mixer(consensus_weights(g, "MH"))
    x = ex.local(x0)
    for _ in range(15):
        x = mixer.apply(x)
    bcast = ex.broadcast(ex.local(x0[:, 0])).sum()
    edge = ex.send(ex.out_edges.astype(float)).sum()
    comm_totals = ex.comm_totals()
    return {
        "estimates": ex.gather_nodes(x),
        "bcast_sum": ex.gather_nodes(bcast),
        "edge_sum": ex.gather_nodes(edge),
        "sent": comm_totals.messages_sent,
        "received": comm_totals.messages_received,
        "per_round": comm_totals.messages_per_round,
    }


@case
def consensus_on_tiled_parts(backend: str) -> dict[str, np.ndarray]:
    """MPI: each rank builds only its part of a tiled random geometric graph (no array over the whole network),
    the partition held as node ranges; in-process: the whole tiled graph. Drops and a silent node: the same
    numbers."""
    from distnav.network.part_builders import (
        radius_for_mean_degree,
        tiled_random_geometric,
        tiled_random_geometric_part,
    )
    from distnav.network.partition import block_ranges
    from distnav.network.weights import part_weights

    n = 5000
    radius = radius_for_mean_degree(n, 8)
    faults = FaultSchedule(drop_probability=0.1, silent_nodes=((4321, 3),), seed=9)
    x0 = np.random.default_rng(5).normal(size=n)
    if backend == "mpi":
        from mpi4py import MPI

        comm = MPI.COMM_WORLD
        ranges = block_ranges(n, comm.Get_size())
        part = tiled_random_geometric_part(
            n, radius, seed=7, nodes=ranges.nodes_of(comm.Get_rank()), tile_nodes=128, comm=comm
        )
        ex = make_exchange(part, backend="mpi", faults=faults, partition=ranges)
        mixer = ex.mixer(part_weights(part, "MH"))
    else:
        g = tiled_random_geometric(n, radius, seed=7, tile_nodes=128)
        ex = make_exchange(g, faults=faults)
        mixer = ex.mixer(consensus_weights(g, "MH"))
    x = ex.local(x0)
    for _ in range(12):
        x = mixer.apply(x)
    totals = ex.comm_totals()
    return {
        "estimates": ex.gather_nodes(x),
        "received": totals.messages_received,
        "per_round": totals.messages_per_round,
    }


@case
def ncsg_neighbourhood_precision(backend: str) -> dict[str, np.ndarray]:
    """The node-local "neighbourhood" precision (block broadcasts) at an N-CSG-TBLS solution."""
    from distnav.algorithms.ranging.csg import solve_ncsg
    from distnav.algorithms.ranging.precision import neighbourhood_precision

    problem = _uwb_problem()
    res = solve_ncsg(
        problem,
        line_search="TBLS",
        iterations=40,
        objective="metres",
        sigma_m=0.15,
        quality=False,
        exchange=make_exchange(problem.graph, backend=backend),
    )
    out = neighbourhood_precision(
        problem,
        res.estimates,
        exchange=make_exchange(problem.graph, backend=backend),
        objective="metres",
        sigma_m=0.15,
        rounds=6,
    )
    ball = neighbourhood_precision(
        problem,
        res.estimates,
        exchange=make_exchange(problem.graph, backend=backend),
        objective="metres",
        sigma_m=0.15,
        rounds=6,
        hops=2,
        delay_sigma_m=0.015,
    )
    assert out.precision.comm is not None and ball.precision.comm is not None
    return {
        "covariance": out.precision.covariance,
        "conditional": out.conditional,
        "variance_factor_nodes": np.nan_to_num(out.variance_factor_nodes, nan=-1.0),
        "bytes": out.precision.comm.bytes_sent,
        "subnetwork_covariance": ball.covariance(a_posteriori=True),
        "subnetwork_factor": np.nan_to_num(ball.variance_factor_nodes, nan=-1.0),
        "subnetwork_bytes": ball.precision.comm.bytes_sent,
    }


@case
def range_offsets_distributed(backend: str) -> dict[str, np.ndarray]:
    """Range offsets (issue 13 item 5): per-anchor by N-CLM and N-CSG-TBLS with drops, common by CSG."""
    import dataclasses

    from distnav.algorithms.ranging.csg import solve

    problem = _uwb_problem()
    delays = np.random.default_rng(8).normal(0.0, 0.05, problem.n_anchors)
    problem = dataclasses.replace(
        problem, range_m=problem.range_m + 0.2 + delays[problem.meas_a] + delays[problem.meas_b]
    )
    node: list[np.ndarray] = []  # per-anchor results: bit for bit
    total: list[np.ndarray] = []  # the common offset and every σ use network sums (allreduce): equal to rounding
    sent: list[np.ndarray] = []
    for solver, mode, faults in (
        ("N-CLM", "per_anchor", None),
        ("N-CSG-TBLS", "per_anchor", 0.1),
        ("N-CSG-TBLS", "common", None),
        ("CSG", "common", None),
    ):
        ex = make_exchange(
            problem.graph,
            backend=backend,
            faults=None if faults is None else FaultSchedule(drop_probability=faults, seed=5),
        )
        robust = {} if solver == "CSG" else {"loss": "cauchy"}
        res = solve(
            problem,
            solver,
            iterations=25,
            exchange=ex,
            objective="metres",
            sigma_m=0.15,
            **robust,
            range_offsets=mode,
            offset_prior_sigma_m=0.1,
        )
        node.append(res.estimates.ravel())
        (node if mode == "per_anchor" else total).append(res.offsets_m)
        total.append(np.nan_to_num(res.offsets_std_m, posinf=-1.0))  # σ: × the variance factor (a network sum)
        sent.append(res.comm.bytes_sent)
    return {"estimates": np.concatenate(node), "offsets": np.concatenate(total), "bytes": np.concatenate(sent)}


@case
def distributed_lm_refinement(backend: str) -> dict[str, np.ndarray]:
    """The final distributed LM phase (ranging_refine: CG through broadcasts, network totals in the anchors' order)
    after 15 iterations of N-CLM (common offset) and N-CSG-TBLS (per-anchor offsets), Cauchy loss, metres."""
    import dataclasses

    from distnav.algorithms.ranging.csg import solve

    problem = _uwb_problem()
    delays = np.random.default_rng(9).normal(0.0, 0.05, problem.n_anchors)
    problem = dataclasses.replace(
        problem, range_m=problem.range_m + 0.2 + delays[problem.meas_a] + delays[problem.meas_b]
    )
    est: list[np.ndarray] = []
    sent: list[np.ndarray] = []
    rounds: list[float] = []
    for solver, mode in (("N-CLM", "common"), ("N-CSG-TBLS", "per_anchor")):
        res = solve(
            problem,
            solver,
            iterations=15,
            exchange=make_exchange(problem.graph, backend=backend),
            objective="metres",
            sigma_m=0.15,
            loss="cauchy",
            range_offsets=mode,
            offset_prior_sigma_m=0.1,
        )
        assert "refine" in res.settings, res.message
        est.append(res.estimates.ravel())
        sent.append(res.comm.messages_sent)
        rounds += [res.settings["refine"]["rounds"], res.settings["refine"]["cg_iterations"]]
    return {"estimates": np.concatenate(est), "sent": np.concatenate(sent), "count": np.asarray(rounds)}


@case
def uwb_field_workflow_distributed(backend: str) -> dict[str, np.ndarray]:
    """``uwb solve``'s workflow with N-CLM (issue 13): one-sided loss tightened through distributed fits, warm
    re-fits by the distributed LM phase, link tests with the network robust scale, exclusions, polish, 2-hop σ."""
    from distnav.experiments.uwb_field import hall_problem
    from distnav.models.uwb.field import FieldOptions, prepare, solve_field
    from distnav.models.uwb.hall import PLANT_LIKE, HallConfig, simulate_hall

    h = simulate_hall(np.random.default_rng([0, 1201]), HallConfig().with_(n_anchors=16, known="corner", **PLANT_LIKE))
    sub, geo = prepare(hall_problem(h)[0])
    sol = solve_field(
        sub,
        FieldOptions(solver="N-CLM", iterations=60),
        geometry=geo,
        exchange=lambda p: make_exchange(p.graph, backend=backend),
    )
    return {
        "positions": sol.positions_m,
        "sigma": sol.sigma_m,
        "w": np.nan_to_num(sol.w, nan=-99.0),
        "excluded": sol.excluded.astype(float),
        "messages": np.asarray([sol.messages, sol.bytes], float),
    }


@case
def central_precision_distributed(backend: str) -> dict[str, np.ndarray]:
    """LM's central blocks through the exchange (uwb19): multi-column CG, delays considered and estimated from
    the residuals (the n × n reduction), one-sided Cauchy, common offset, on a 16-anchor plant-like hall."""
    from distnav.algorithms.ranging.covariance import central_precision
    from distnav.algorithms.ranging.lm import solve_lm
    from distnav.experiments.uwb_field import hall_problem
    from distnav.models.uwb.field import prepare
    from distnav.models.uwb.hall import PLANT_LIKE, HallConfig, simulate_hall

    h = simulate_hall(np.random.default_rng([0, 1201]), HallConfig().with_(n_anchors=16, known="corner", **PLANT_LIKE))
    sub, _ = prepare(hall_problem(h)[0])
    lm = solve_lm(sub, objective="metres", sigma_m=0.1, range_offsets="common", loss="cauchy_long", loss_scale_m=0.1)
    out = central_precision(
        sub,
        lm.estimates,
        offset_m=lm.offsets_m,
        exchange=make_exchange(sub.graph, backend=backend),
        sigma_m=0.1,
        loss="cauchy_long",
        loss_scale_m=0.1,
        range_offsets="common",
        delay_sigma_m=0.005,
        estimate_delays=True,
        variance_scale_m=0.3,
        delay_upper_z=1.645,
    )
    assert out.precision.comm is not None
    return {
        "estimates": out.covariance(a_posteriori=True).ravel(),
        "sent": out.precision.comm.messages_sent,
        "count": np.asarray([out.cg_iterations, out.reduced.count, out.reduced.floats]),
    }


@case
def local_reliability_distributed(backend: str) -> dict[str, np.ndarray]:
    """Issue 28 item 5: every anchor's redundancy numbers, MDB and worst shift from its 2-hop neighbourhood's link
    records, flooded through the exchange (one-sided Cauchy, common offset) on a 40-anchor random network."""
    from distnav.algorithms.ranging.reliability import ReliabilityOptions, local_reliability

    problem = _uwb_problem()
    assert problem.truth_m is not None
    est = problem.truth_m + np.where(problem.free, np.random.default_rng(5).normal(0.0, 0.05, problem.truth_m.shape), 0)
    opts = ReliabilityOptions(sigma_m=0.1, offsets="common", loss="cauchy_long", loss_scale_m=0.3)
    rel = local_reliability(
        problem, est, opts, offsets_m=np.array([0.02]), hops=2, exchange=make_exchange(problem.graph, backend=backend)
    )
    return {
        "estimates": np.nan_to_num(np.concatenate([rel.r, rel.mdb_m, rel.shift_m]), nan=-1.0),  # NaN: not owned
        "count": np.concatenate([rel.worst_link, rel.subnetwork_anchors]),
        "bytes": np.asarray(rel.comm.bytes_sent),
        "sent": np.asarray(rel.comm.messages_sent),
    }
