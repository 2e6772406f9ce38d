"""Going on without a dead node, for every field node program (ADMM, the CKF, the UWB solvers): the remaining nodes
agree on who they are, check the agreement, and run again on their own data through a :data:`Rerun` of the family.

1. agree on who remains (:func:`~distnav.exchange.field.survivors.agree_on_survivors`: flooding over their own
   links, with absolute round deadlines that cover the skew with which they left the failed operation), in steps
   fixed per attempt (:data:`ATTEMPT_STEPS`) so that nodes which noticed the loss in different steps still agree;
2. refuse a possible split: a missing node counts as lost only if a remaining neighbour saw it silent
   (:func:`~distnav.exchange.field.survivors.beyond_reach`); any other one may be alive behind a cut, and the node
   stops naming it instead of solving apart;
3. check the agreement (:func:`check_agreement`: every node's view of the remaining nodes and of the failed step,
   gathered over the remaining nodes' spanning tree, must be equal);
4. run the family's :data:`Rerun` on the sub-network the remaining nodes induce (a
   :class:`~distnav.exchange.field.survivors.SubnetTransport`); another loss starts the next attempt.

``status`` is the new run's with ``_without_lost_nodes``; ``lost_nodes`` names every lost node with the step of the
failed operation, ``remaining_nodes`` and ``restarted_at_step`` say who went on and from where. The node stops
(``status = "stopped"``, no estimate, the reason named) on a possible split, a remaining network that is not
connected, a failure with every node alive, or data that no longer determine the parameters (ModelError). The
families' departures (the restart discards the iterations made before the loss) are in
:mod:`distnav.commands.field_admm` and :mod:`distnav.commands.field_uwb`.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from distnav.errors import ExchangeError, ModelError
from distnav.exchange.field import FieldExchange
from distnav.exchange.field.survivors import (
    SubnetTransport,
    agree_on_survivors,
    agreement_window_s,
    beyond_reach,
    subnetwork,
)
from distnav.formats.field_config import NetworkDescription

__all__ = ["ATTEMPT_STEPS", "Rerun", "check_agreement", "without_lost"]

#: the agreement after the k-th loss runs from step k × this (far beyond any run's steps; the wire's step is a u64),
#: so that anchors which noticed the loss in different steps still agree in the same steps
ATTEMPT_STEPS = 1 << 40

_UNSEEN = (
    "the remaining network may be split: no remaining node is a neighbour of (so none saw die) the nodes that are "
    "neither remaining nor seen dead, which may be alive on the other side of the lost nodes:"
)

#: a node program's new run on the remaining nodes: its result fields (``status`` and ``message`` of that run) from
#: its exchange on the sub-network and the mask of the remaining nodes (original ids); it raises ExchangeError
#: (another loss) or ModelError (no answer: stop)
Rerun = Callable[[FieldExchange, np.ndarray], dict[str, Any]]


def without_lost(desc: NetworkDescription, ex: FieldExchange, error: str, rerun: Rerun) -> dict[str, Any]:
    """Agree on the remaining nodes and run again on their data (module docstring); at most one pass per node of
    the network (each pass loses at least one)."""
    graph, base, name = ex.graph, ex.transport, desc.algorithm["name"]
    window = agreement_window_s(graph, base.options.deadline_s)
    dead: dict[int, int] = {}
    failed = ex.step - 1
    for attempt in range(1, desc.n_nodes + 1):
        alive, failed, step = agree_on_survivors(
            base, graph, attempt * ATTEMPT_STEPS, window_s=window, failed_step=failed, dead=set(dead)
        )
        newly = sorted(set(np.flatnonzero(~alive).tolist()) - set(dead))
        if not newly:
            return _stopped(
                name, ex, dead, f"a global operation failed at step {failed} with every node alive ({error})"
            )
        unseen = beyond_reach(graph, alive, newly)
        dead.update({k: failed for k in newly if k not in unseen})
        if unseen:
            return _stopped(name, ex, dead, f"{_UNSEEN} {unseen}")
        sub = _sub_exchange(ex, alive, step)
        if sub is None:
            return _stopped(name, ex, dead, "the remaining nodes are not one connected network")
        try:
            check_agreement(sub, alive, failed)
            out = rerun(sub, alive)
        except ExchangeError as exc:
            failed, error = sub.step - 1, str(exc)
            continue
        except ModelError as exc:
            return _stopped(name, ex, dead, f"the remaining nodes' data do not determine the parameters: {exc}")
        lost = ", ".join(f"node {d} (at step {s})" for d, s in sorted(dead.items()))
        out["status"] = f"{out['status']}_without_lost_nodes"
        out["message"] = (
            f"lost {lost}; the {int(alive.sum())} remaining nodes agreed on it and ran {name} again on their own "
            f"data from step {step} ({out['message']})"
        )
        out["rounds"] = sub.step
        return out | _lost_fields(dead, alive, step)
    return _stopped(name, ex, dead, error)


def _sub_exchange(ex: FieldExchange, alive: np.ndarray, step: int) -> FieldExchange | None:
    """This node's exchange on the sub-network of ``alive`` from ``step`` on (None: that is not connected)."""
    graph = subnetwork(ex.graph, alive)
    if not graph.is_connected:
        return None
    link = SubnetTransport(ex.transport, alive)
    sub = FieldExchange(graph, link.me, link, ex.faults, direct=False)
    sub.step = step
    return sub


def _lost_fields(dead: dict[int, int], alive: np.ndarray, step: int) -> dict[str, Any]:
    """Who was lost (node → step of the failed operation), who remains, and where the new run began."""
    lost = {str(d): s for d, s in sorted(dead.items())}
    return {"lost_nodes": lost, "remaining_nodes": np.flatnonzero(alive).tolist(), "restarted_at_step": step}


def _stopped(name: str, ex: FieldExchange, dead: dict[int, int], why: str) -> dict[str, Any]:
    """No estimate: the reason, and the nodes seen lost (node → step)."""
    text = f"{name} cannot go on without the lost nodes {sorted(dead)}: {why}; no estimate is given"
    lost = {str(d): s for d, s in sorted(dead.items())}
    return dict(estimate=None, status="stopped", message=text, rounds=ex.step, lost_nodes=lost)


def check_agreement(sub: FieldExchange, alive: np.ndarray, failed: int) -> None:
    """Every remaining node's view (which nodes remain, the failed step) must be this node's."""
    mine = np.r_[float(failed), alive.astype(float)][None]
    views = sub.gather_nodes(mine)
    if not np.array_equal(views, np.repeat(mine, views.shape[0], axis=0)):
        raise ExchangeError(f"the remaining nodes disagree on who remains: views {views.tolist()}")
