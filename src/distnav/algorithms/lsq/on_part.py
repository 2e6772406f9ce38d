"""ADMM with constraint nodes (paper 000 Fig. 6, aggregated messages) on a graph part: nothing of the whole network.

Under MPI every rank builds only its part of the graph (:mod:`distnav.network.part_builders`, an exchange made
from it with node ranges) and holds only its nodes' data; :func:`iterate_admm_on_part` then sets ADMM up from the
part alone, as consensus on parts does: the constraint nodes by :func:`~distnav.network.constraint_nodes.part_cover`
(each rank for its nodes; the halo's membership by one transport), ``c_i`` and ``|N_s|`` from the part's edges, the
two rounds as mixers with masks over the rank's own edges, the x-update on the rank's rows. No array over the whole
network is made, so a rank's memory is proportional to its nodes and edges (issue 30).

The iteration is :mod:`distnav.algorithms.lsq.aggregated`'s (``messages="aggregated"``): with the same constraint
nodes it is bitwise the in-process run on the whole graph (every row sums its terms in global sender order on every
backend, and the x-update is per node). **Departures from** :func:`~distnav.algorithms.lsq.admm.iterate_admm`:
``constraint_nodes="min_cover"`` means the part rule (every node but the local minima of a hash of the ids: a vertex
cover of the whole graph, the same on every split, larger than the whole-graph 2-approximation), or a mask over the
part's nodes; only ``messages="aggregated"`` (the default here; the per-pair form's pair tables pair each edge with
its reverse through the whole graph's edge ids — not built on parts), no fault schedule, ``init`` ``"zero"`` or a
``(p,)`` vector, no ``z0`` or ``multipliers``; a node without neighbours is refused by id (ADMM needs a connected
graph).
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import numpy as np

from distnav._settings import resolve_options
from distnav.algorithms.lsq.aggregated import _AggregatedKernel, rounds_on_part
from distnav.algorithms.lsq.blue import LinearProblem, weight_matrix
from distnav.algorithms.lsq.driver import AdmmOptions, _check_estimable
from distnav.algorithms.lsq.kernel import AdmmState, XUpdate
from distnav.algorithms.lsq.xupdate import in_local_order
from distnav.errors import ModelError
from distnav.exchange import Exchange
from distnav.network.constraint_nodes import part_cover
from distnav.network.graph_part import GraphPart

__all__ = ["iterate_admm_on_part"]


def iterate_admm_on_part(
    problem: LinearProblem, exchange: Exchange, *, options: AdmmOptions | None = None, **changes: Any
) -> Iterator[AdmmState]:
    """Yield the ADMM states of this rank's nodes after iterations ``0, 1, 2, …`` (endless: stop it yourself).

    ``problem``: the rows of the part's nodes, in ``exchange.part.nodes`` order (ascending ids); ``exchange``: made
    from the rank's :class:`~distnav.network.graph_part.GraphPart` (``make_exchange(part, backend="mpi",
    partition=ranges)``). Options as :func:`~distnav.algorithms.lsq.admm.iterate_admm` with the departures of the
    module docstring; states hold the rank's rows in ``exchange.nodes`` order, residuals are network totals.
    """
    if options is None:  # the only form built on parts is the default here
        changes.setdefault("messages", "aggregated")
    o = resolve_options(AdmmOptions, options, changes)
    ex = exchange
    part = ex.part
    if part is None:
        raise ModelError("iterate_admm_on_part needs an exchange built from a graph part; on a graph use iterate_admm")
    if problem.n_nodes != part.n_local:
        raise ModelError(
            f"the problem has {problem.n_nodes} nodes, this rank's part {part.n_local}: give the rows of the "
            "part's nodes (ascending ids)"
        )
    if o.messages != "aggregated":
        raise ModelError("on a graph part only messages='aggregated' is built (no per-pair tables on parts)")
    if ex.faults.active:
        raise ModelError("messages='aggregated' keeps multiplier sums that lost messages corrupt: no fault schedule")
    if o.x_weight == "fig6-zweighted":
        raise ModelError("x_weight='fig6-zweighted' weights the z-update per pair: not with aggregated messages")
    if o.z0 is not None or o.multipliers is not None:
        raise ModelError("z0 and multipliers are not taken on a graph part (start from init)")
    p = problem.n_params
    Wm = weight_matrix(o.W, p)
    rounds = rounds_on_part(ex, _part_constraint_nodes(o.constraint_nodes, part))
    alone = np.flatnonzero(rounds.count == 0)
    if alone.size:  # no constraint node in its neighbourhood: only a node without neighbours (the graph is split)
        raise ModelError(
            f"node {int(ex.nodes[alone[0]])} has no neighbour ({alone.size} such nodes on this rank): ADMM needs a "
            "connected graph"
        )
    node_pos = ex.part_rows()[1]  # the part position of each local row
    c = np.empty(part.n_local)
    c[node_pos] = rounds.count if o.x_weight == "lagrangian" else 1.0
    xu = in_local_order(XUpdate(problem, Wm, c, o.x_update), node_pos)
    _check_estimable(problem, problem, ex, need_blocks=xu.method != "observation")
    x0 = _initial(o.init, part.n_local, p)
    return _AggregatedKernel(ex, rounds, Wm, p, xu).run(x0, x0.copy(), o.monitor_every)


def _part_constraint_nodes(spec: Any, part: GraphPart) -> np.ndarray:
    """The constraint nodes among the part's nodes: the part rule for ``"min_cover"``, or a boolean mask."""
    if isinstance(spec, str) and spec == "min_cover":
        return part_cover(part)
    n = part.n_local
    mask = np.asarray(spec)
    if mask.dtype != bool or mask.shape != (n,):
        raise ModelError(
            f"constraint_nodes on a graph part: 'min_cover' or a boolean mask over the part's {n} nodes, got "
            f"{spec!r:.60}"
        )
    return mask


def _initial(init: Any, n: int, p: int) -> np.ndarray:
    """``x_i^[0] = z_s^[0]`` on the rank's rows: zero or one ``(p,)`` vector for every node."""
    if isinstance(init, str) and init == "zero":
        return np.zeros((n, p))
    arr = np.asarray(init, dtype=float)
    if arr.shape != (p,) or not np.all(np.isfinite(arr)):
        raise ModelError(f"init on a graph part must be 'zero' or a finite length-{p} vector, got {init!r:.60}")
    return np.repeat(arr[None, :], n, axis=0)
