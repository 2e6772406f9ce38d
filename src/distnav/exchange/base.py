"""The exchange of one block of nodes: :class:`ExchangeCore` (message rounds, accounting, faults) with the two
prepared kinds of round, :meth:`Exchange.route` and :meth:`Exchange.mixer`.

:mod:`~distnav.exchange.core` holds the rounds themselves; :mod:`~distnav.exchange.mixer` and
:mod:`~distnav.exchange.route` build on it, and this module ties them together, so no module of the exchange imports
one above it. Backends (in-process, MPI, field) subclass :class:`Exchange`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from distnav.errors import ExchangeError
from distnav.exchange.core import CommTotals, ExchangeCore, Inbox, incoming_edges
from distnav.exchange.mixer import Mixer
from distnav.exchange.route import Route
from distnav.network.graph_part import GraphPart

if TYPE_CHECKING:
    from distnav.network.weights import ConsensusWeights, PartWeights

__all__ = ["Exchange", "Inbox", "Mixer", "Route", "CommTotals", "incoming_edges"]


class Exchange(ExchangeCore):
    """One block of nodes' view of the network (see :class:`~distnav.exchange.core.ExchangeCore`), with the
    prepared rounds over fixed edge sets and the prepared consensus round."""

    def route(
        self, active: np.ndarray, *, in_rows: np.ndarray | None = None, out_rows: np.ndarray | None = None
    ) -> Route:
        """Prepare rounds over the edges of ``active`` on compact arrays (:class:`~distnav.exchange.route.Route`):
        the same messages, counts and faults as :meth:`broadcast`/:meth:`send` with that mask, without the
        full-length arrays."""
        return Route(self, active, in_rows=in_rows, out_rows=out_rows)

    def mixer(self, weights: ConsensusWeights | PartWeights, *, active: np.ndarray | None = None) -> Mixer:
        """Prepare consensus rounds with a :class:`~distnav.network.weights.ConsensusWeights` on this graph (or,
        on an exchange built from a graph part, :class:`~distnav.network.weights.PartWeights` of that part).

        For a switching graph pass the session's weights expressed on the union graph and its edge mask.
        """
        if weights.graph.n_edges != self.n_edges or weights.graph.n_nodes != self.n_nodes:
            raise ExchangeError("weights are defined on a different graph than this exchange")
        if isinstance(weights.graph, GraphPart) and weights.graph is not self.part:
            raise ExchangeError("weights on a graph part must be made on this exchange's own part")
        rows = self.part_rows() if isinstance(weights.graph, GraphPart) else None
        return Mixer(self, weights.edge_weight, weights.self_weight, active, rows=rows)
