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
   :class:`~distnav.exchange.field.survivors.SubnetTransport`); another loss starts the next attempt;
5. take back a lost node whose process was restarted (``--rejoin``): after the run, one global OR tells every
   remaining node whether such a node greeted a neighbour (:attr:`Transport.greeted`); its neighbours readmit it and
   invite it (:attr:`Kind.INVITE`: the new run's first step, the failed step, the run's nodes), and every node, it
   too (``without_lost(..., invited=...)``), runs the :data:`Rerun` again from the start on that network. A rejoin
   costs a re-run; ``status`` ``<status>_with_rejoined_nodes`` when every lost node is back, ``rejoined_nodes``.

``status`` is the new run's with ``_without_lost_nodes``; ``lost_nodes`` names every lost node with the step of the
failed operation, ``remaining_nodes`` and ``restarted_at_step`` say who went on and from where. The node stops
(``status = "stopped"``, no estimate, the reason named) on a possible split, a remaining network that is not
connected, a third failure with every node alive (:data:`MAX_STALLS`: before that the nodes run again with every
node, ``status`` ``<status>_run_again``, ``stalled_at_steps``), or data that no longer determine the parameters
(ModelError). The families' departures (the restart discards the iterations made before the loss) are in
:mod:`distnav.commands.field_admm` and :mod:`distnav.commands.field_uwb`.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from distnav.errors import ExchangeError, ModelError
from distnav.exchange.field import FieldExchange, Kind
from distnav.exchange.field.survivors import (
    SubnetTransport,
    agree_on_survivors,
    agreement_window_s,
    beyond_reach,
    subnetwork,
)
from distnav.exchange.field.transport import StepTransport
from distnav.formats.field_config import NetworkDescription
from distnav.network.graph import Graph

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


def without_lost(
    desc: NetworkDescription, ex: FieldExchange, error: str, rerun: Rerun, *, invited: np.ndarray | None = None
) -> dict[str, Any]:
    """Agree on the remaining nodes and run again on their data (module docstring); a lost node that greets its
    neighbours again before that run ends is invited back and the nodes run once more with it (:func:`_invite`).
    ``invited``: this node is such a returning one (the invitation, ``startup.rejoin``). At most a few passes
    per node of the network (each pass loses or regains one at least)."""
    graph, base, name = ex.graph, ex.transport, desc.algorithm["name"]
    window = agreement_window_s(graph, base.options.deadline_s)
    dead: dict[int, int] = {}
    back: dict[int, int] = {}
    failed, attempt, start = ex.step - 1, 1, None
    stalls: list[int] = []  # failed steps with every node alive (a node stalled past the deadlines): run again
    if invited is not None:  # [first step of the run with this node, the failed step, the run's nodes]
        failed, attempt = int(invited[1]), int(invited[0]) // ATTEMPT_STEPS + 1
        start = (np.asarray(invited[2:]) > 0, int(invited[0]))
        dead = {int(k): failed for k in np.flatnonzero(~start[0])}
        back = {ex.me: start[1]}
    for _ in range(2 * desc.n_nodes + 2):
        if start is None:
            alive, failed, step = agree_on_survivors(
                base, graph, attempt * ATTEMPT_STEPS, window_s=window, failed_step=failed, dead=set(dead)
            )
            attempt += 1
            why = _lost_now(graph, alive, dead, failed, error, stalls)
            if why:
                return _stopped(name, ex, dead, why)
        else:
            (alive, step), start = start, None
        sub = _sub_exchange(ex, alive, step)
        if sub is None:
            return _stopped(name, ex, dead, "the remaining nodes are not one connected network")
        try:
            check_agreement(sub, alive, failed)
            out = rerun(sub, alive)
            returned = _returned(sub, base, dead, graph.n_nodes)
        except ExchangeError as exc:
            failed, error = sub.step - 1, str(exc)
            continue
        except ModelError as exc:
            return _stopped(name, ex, dead, f"the remaining nodes' data do not determine the parameters: {exc}")
        if returned:
            start = _invite(base, alive, returned, failed, (attempt - 1) * ATTEMPT_STEPS + ATTEMPT_STEPS // 2)
            back.update({d: start[1] for d in returned})
            dead = {d: s for d, s in dead.items() if d not in returned}
            continue
        return _finished(out, name, dead, back, alive, step, stalls) | {"rounds": sub.step}
    return _stopped(name, ex, dead, error)


#: runs again after a failure with every node alive before a node stops (a node that keeps stalling, or a failure
#: that is not a stall, would otherwise cost a run each time)
MAX_STALLS = 2


def _lost_now(graph: Graph, alive: np.ndarray, dead: dict[int, int], failed: int, error: str, stalls: list[int]) -> str:
    """Record the nodes the agreement found newly lost in ``dead``; the reason to stop, if any (a possible split:
    :func:`~distnav.exchange.field.survivors.beyond_reach`, or more than :data:`MAX_STALLS` failures with every node
    alive). A failure with every node alive (a node stopped longer than the deadlines, then going on: the others
    left the operation without it) is a stall: noted in ``stalls``, and the nodes run again with every node."""
    newly = sorted(set(np.flatnonzero(~alive).tolist()) - set(dead))
    if not newly:
        if len(stalls) < MAX_STALLS:
            stalls.append(failed)
            return ""
        return f"a global operation failed at steps {[*stalls, failed]} with every node alive ({error})"
    unseen = beyond_reach(graph, alive, newly)
    dead.update({k: failed for k in newly if k not in unseen})
    return f"{_UNSEEN} {unseen}" if unseen else ""


def _returned(sub: FieldExchange, base: StepTransport, dead: dict[int, int], n: int) -> list[int]:
    """The lost nodes whose restarted process greeted a remaining neighbour (:attr:`Transport.greeted`: the hello
    of a restarted process, not the start-up's), as every remaining node learns them (a global OR over the
    remaining nodes)."""
    mine = np.zeros(n, np.int64)
    mine[[d for d in dead if d in base.greeted]] = 1
    return np.flatnonzero(np.asarray(sub.allreduce(mine, "max")) > 0).tolist()


def _invite(
    base: StepTransport, alive: np.ndarray, returned: list[int], failed: int, step: int
) -> tuple[np.ndarray, int]:
    """Invite the returned nodes to a run from ``step`` with every remaining node and them: each remaining neighbour
    of one sends it ``[step, failed, the run's nodes]`` (:attr:`Kind.INVITE`); the same nodes and step here."""
    everyone = alive.copy()
    everyone[returned] = True
    invitation = np.r_[step, failed, everyone.astype(np.int64)].astype(np.int64)
    for d in returned:
        base.greeted.pop(d, None)  # a later loss of it needs a new restart
        if d in base.peers:
            base.readmit(d, step)
            base.post(d, Kind.INVITE, step, invitation)
    return everyone, step


def _finished(
    out: dict[str, Any],
    name: str,
    dead: dict[int, int],
    back: dict[int, int],
    alive: np.ndarray,
    step: int,
    stalls: list[int],
) -> dict[str, Any]:
    """The run's result with who was lost (and is still), who came back and from which step they ran together."""
    lost = ", ".join(f"node {d} (at step {s})" for d, s in sorted(dead.items()))
    rejoined = ", ".join(f"node {d}" for d in sorted(back))
    out["stalled_at_steps"] = list(stalls)
    if not dead and not back:  # only stalls: every node alive throughout
        out["status"] = f"{out['status']}_run_again"
        done = f"a global operation failed at steps {stalls} with every node alive (a node stalled past the deadlines)"
        out["message"] = (
            f"{done}; the {int(alive.sum())} nodes ran {name} again on all data from step {step} ({out['message']})"
        )
        out["rejoined_nodes"] = {}
        return out | _lost_fields(dead, alive, step)
    if dead:
        out["status"] = f"{out['status']}_without_lost_nodes"
        done = f"lost {lost}; the {int(alive.sum())} remaining nodes agreed on it and ran {name} again on their own "
    else:
        out["status"] = f"{out['status']}_with_rejoined_nodes"
        done = f"every lost node came back ({rejoined}); the {int(alive.sum())} nodes ran {name} again on all "
    if back and dead:
        done += f"(with {rejoined}, back after a loss) "
    out["message"] = f"{done}data from step {step} ({out['message']})"
    out["rejoined_nodes"] = {str(d): s for d, s in sorted(back.items())}
    return out | _lost_fields(dead, alive, step)


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
