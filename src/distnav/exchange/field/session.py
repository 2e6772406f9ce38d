"""``make_exchange(graph, backend="field")``: the field exchange of the node this thread (or process) runs.

A node program sets its session once (:func:`field_session`: its node id and its started :class:`Transport`), and
from then on any code that builds its exchange with ``make_exchange(graph, backend=backend)`` — every algorithm's
front door, every MPI test case — runs over the network as that node, unchanged. Several nodes can run in one process
as threads (each with its own session and transport, e.g. over ``inproc://`` addresses sharing one ZeroMQ context):
that is how the tests run the MPI cases on the field exchange.
"""

from __future__ import annotations

import threading
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass

from distnav.errors import ExchangeError
from distnav.exchange.faults import FaultSchedule
from distnav.exchange.field.exchange import FieldExchange
from distnav.exchange.field.transport import Transport
from distnav.network.graph import Graph

__all__ = ["field_session", "session_exchange"]


@dataclass(frozen=True)
class _Session:
    node: int
    transport: Transport


_LOCAL = threading.local()


@contextmanager
def field_session(node: int, transport: Transport) -> Iterator[None]:
    """Within this block, ``make_exchange(..., backend="field")`` on this thread is node ``node`` over ``transport``."""
    previous = getattr(_LOCAL, "session", None)
    _LOCAL.session = _Session(int(node), transport)
    try:
        yield
    finally:
        _LOCAL.session = previous


def session_exchange(graph: Graph, faults: FaultSchedule | None = None, **options: object) -> FieldExchange:
    """The field exchange of this thread's session (see the module docstring)."""
    session: _Session | None = getattr(_LOCAL, "session", None)
    if session is None:
        raise ExchangeError(
            "backend 'field' needs a node session: run `distnav node` (or wrap the code in "
            "distnav.exchange.field.session.field_session(node, transport))"
        )
    if not isinstance(graph, Graph):
        raise ExchangeError("the field exchange needs the whole graph (every node reads the network description)")
    unknown = set(options) - {"order", "partition"}  # MPI's layout options mean nothing for one node per process
    if unknown:
        raise ExchangeError(f"the field exchange takes no options {sorted(unknown)}")
    return FieldExchange(graph, session.node, session.transport, faults)
