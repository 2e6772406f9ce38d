"""The MPI cases (tests/mpi/cases.py) on the field exchange: every node a thread with its own transport and session,
talking through ZeroMQ (``inproc://``: the same wire format, checks and lock-step code as over TCP). Node results must
equal the in-process run bit for bit (the keys test_mpi.py compares bitwise), monitoring sums to rounding.

A case builds its exchange with ``make_exchange(g, backend="field")``: the same node code as in-process and MPI.
"""

from __future__ import annotations

import sys
import threading
import time
import uuid
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

zmq = pytest.importorskip("zmq")

from distnav.exchange.field import Peer, Transport, TransportOptions  # noqa: E402
from distnav.exchange.field.session import field_session  # noqa: E402
from distnav.exchange.field.startup import handshake  # noqa: E402

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE / "mpi"))
from cases import CASES  # noqa: E402

from test_mpi import BITWISE  # noqa: E402

# the cases with few global operations (each is 60 × 59 messages on 60 threads): seconds; consensus_static and
# consensus_with_faults (a reduction per round) are in benchmarks/bench_field.py's equality table
FAST = ["raw_send_and_broadcast", "route_send_and_broadcast"]


def run_on_threads(
    fn: Callable[[str], dict[str, np.ndarray]], n_nodes: int, timeout_s: float = 300, graph: Any = None
) -> list[Any]:
    """Run ``fn("field")`` as ``n_nodes`` nodes, one thread each; returns each node's result (or its exception).
    With ``graph`` each node knows only its neighbours' addresses (global operations then go over the spanning tree,
    as in a field node run from a description); without, every other node's."""
    ctx = zmq.Context()
    ctx.set(zmq.MAX_SOCKETS, 4 * n_nodes * n_nodes + 64)
    tag = uuid.uuid4().hex
    addr = [f"inproc://field-{tag}-{i}" for i in range(n_nodes)]
    results: list[Any] = [None] * n_nodes
    opts = TransportOptions(deadline_s=60.0, start_timeout_s=60.0)

    def node(i: int) -> None:
        known = range(n_nodes) if graph is None else graph.neighbors(i).tolist()
        peers = [Peer(j, addr[j]) for j in known if j != i]
        tr = Transport(i, addr[i], peers, options=opts, context=ctx)
        try:
            handshake(tr)
            with field_session(i, tr):
                results[i] = fn("field")
        except BaseException as exc:  # reported by the caller
            results[i] = exc
        finally:
            tr.close()

    threads = [threading.Thread(target=node, args=(i,), daemon=True) for i in range(n_nodes)]
    for t in threads:
        t.start()
    end = time.monotonic() + timeout_s
    for t in threads:
        t.join(max(0.0, end - time.monotonic()))
    alive = [i for i, t in enumerate(threads) if t.is_alive()]
    if not alive:
        ctx.term()
    assert not alive, f"nodes {alive} still running after {timeout_s} s"
    return results


def _n_nodes(fn: Callable[[str], dict[str, np.ndarray]]) -> int:
    from cases import _graph

    return _graph().n_nodes


@pytest.mark.parametrize("name", FAST)
def test_field_equals_inprocess(name: str) -> None:
    ref = CASES[name]("inprocess")
    _compare(name, ref, run_on_threads(CASES[name], _n_nodes(CASES[name])))


def _compare(name: str, ref: dict[str, np.ndarray], results: list[Any]) -> None:
    errors = [r for r in results if isinstance(r, BaseException)]
    assert not errors, repr(errors[0])
    for node, got_all in enumerate(results):
        for key, value in ref.items():
            got = got_all[key]
            assert np.shape(got) == np.shape(value), f"{name}/{key}"
            if key in BITWISE:
                assert np.array_equal(got, value), f"node {node}: {name}/{key}: max diff {np.max(np.abs(got - value))}"
            else:
                np.testing.assert_allclose(got, value, rtol=1e-12, atol=1e-14, err_msg=f"node {node}: {name}/{key}")


def _ckf_graph() -> Any:
    from distnav.network import builders

    return builders.connected_random_geometric(12, mean_degree=4, rng=np.random.default_rng(5))


def test_neighbours_only_global_operations_go_over_the_spanning_tree() -> None:
    """The CKF case (a gather and three reductions every epoch) with each node knowing only its neighbours: every
    global operation travels over the spanning tree, and every node's result is the in-process one."""
    name = "ckf_random_walk"
    g = _ckf_graph()
    ref = CASES[name]("inprocess")
    _compare(name, ref, run_on_threads(CASES[name], g.n_nodes, timeout_s=120, graph=g))
