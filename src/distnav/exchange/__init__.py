"""Directed-edge message passing: in-process (vectorized) and MPI backends with one interface."""

from __future__ import annotations

from distnav.errors import ExchangeError
from distnav.exchange.base import CommTotals, Exchange, Inbox, Mixer
from distnav.exchange.faults import FaultSchedule
from distnav.exchange.inprocess import InProcessExchange
from distnav.network.graph import Graph
from distnav.network.graph_part import GraphPart

__all__ = ["Exchange", "Inbox", "Mixer", "CommTotals", "FaultSchedule", "InProcessExchange", "make_exchange"]


def make_exchange(
    graph: Graph | GraphPart, *, backend: str = "inprocess", faults: FaultSchedule | None = None, **options: object
) -> Exchange:
    """Create an exchange for ``graph``: ``backend="inprocess"`` (default) or ``"mpi"`` (needs the mpi extra
    and a launch under ``mpiexec -n N python -m mpi4py``). ``order=`` (both backends) picks the local node order
    (:func:`distnav.network.partition.locality_order`): in-process the default ``"none"`` keeps the user's order at
    every size (local arrays are the user's arrays), ``"auto"`` opts in to the locality order from 10⁴ nodes on
    (then convert with ``ex.local`` / ``ex.gather_nodes``); under MPI local arrays are always a block's rows (in the
    order of ``ex.nodes``, ``"auto"`` by default) and go through ``ex.local`` / ``ex.gather_nodes`` anyway. MPI
    also takes ``partition=``, and instead of the whole graph this rank's
    :class:`~distnav.network.graph_part.GraphPart` (``partition=`` then names the partition the parts were built
    from: an owner array, a partition file or ``"block"``). See docs/scale.md, "Results in your order".

    Examples
    --------
    One message round on a 4-node ring: every node sends its value to both neighbours and sums what arrives; the
    exchange counts the messages.

    >>> import numpy as np
    >>> from distnav.exchange import make_exchange
    >>> from distnav.network import builders
    >>> ex = make_exchange(builders.ring(4))
    >>> inbox = ex.broadcast(np.array([1.0, 2.0, 3.0, 4.0]))
    >>> inbox.sum().tolist(), ex.comm_totals().messages
    ([6.0, 4.0, 6.0, 4.0], 8)
    """
    if backend == "inprocess":
        if not isinstance(graph, Graph):
            raise ExchangeError("the in-process exchange needs the whole graph, not a graph part")
        order = options.get("order", "none")  # other options (partition=, comm=) mean nothing in-process
        return InProcessExchange(graph, faults, order=order)  # type: ignore[arg-type]
    if backend == "mpi":
        from distnav.exchange.mpi import MPIExchange  # lazy: mpi4py is an optional extra

        return MPIExchange(graph, faults, **options)  # type: ignore[arg-type]
    if backend == "field":  # this thread's node of a field network (distnav.exchange.field.session)
        from distnav.exchange.field.session import session_exchange

        return session_exchange(graph, faults, **options)  # type: ignore[arg-type]
    raise ExchangeError(f"unknown exchange backend {backend!r}; choose 'inprocess', 'mpi' or 'field'")
