"""ADMM field nodes going on without a node that dies mid-run (issue 26 item 4), as the UWB anchors do.

ADMM (paper 000 Fig. 6) has no answer without every node's data while the dead node is in the problem: its rank
check, stopping totals and gathered result are global operations (:mod:`distnav.exchange.field.tree`), and one that
lacks a node raises :class:`~distnav.errors.ExchangeError` at every node. The nodes that remain then, as
:mod:`distnav.commands.field_uwb` does,

1. agree on who remains (:func:`~distnav.exchange.field.survivors.agree_on_survivors`) and check the agreement over
   the remaining nodes' spanning tree (every node's view of the remaining nodes and the failed step equal);
2. drop the parameters that no remaining node's rows observe (a network OR of each node's non-zero columns, eq. (1)'s
   ``A_i``): e.g. the code bias of a satellite only the dead station tracked. They are reported by
   name in ``dropped_parameters`` and given as NaN in the estimate, never as a number;
3. run ADMM again **from the start** (``x = 0``, ``u = 0``, §4.3) with the same settings on the sub-network the
   remaining nodes induce, each with only its own rows, over a
   :class:`~distnav.exchange.field.survivors.SubnetTransport`.

So the answer converges to the centralized BLUE (eq. (4)) of the remaining nodes' data (``tests/
test_field_admm_lost.py``). Departure, stated: the iterations before the loss are discarded (they hold the dead
node's data in the multipliers). ``status`` is the new run's with ``_without_lost_nodes``; ``lost_nodes`` names
every lost node with the step of the failed operation. The node stops (``status = "stopped"``, no estimate, the
reason named) when the remaining network may be split (below), when the remaining data leave a direction inestimable
(ADMM's rank check names the direction), or when a global
operation failed with every node alive. The field CKF uses the same :func:`without_lost` with its own
:data:`Rerun` (:func:`distnav.commands.field_algorithms.run_ckf`).

**A split network.** The agreement (flooding) cannot tell a dead node from a live one cut off behind the dead: on
a path ``0 – … – 7`` without node 5, nodes ``0..4`` never hear of 6 and 7, and each side would take the other for
dead and solve apart. So a node not among the remaining ones counts as lost only if a remaining node is its
neighbour (saw it silent); any other one — a live node beyond a cut, or a dead node whose neighbours all died — stops
the node, naming it. (Found by ``tests/test_field_admm_lost.py``'s path test: without this check nodes ``0..4``
finished with an answer of their own half.)
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
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
from distnav.formats.field_data import admm_node_problem

__all__ = ["Rerun", "admm_again", "run_admm_field", "without_lost"]

_UNSEEN = (
    "the remaining network may be split: no remaining node is a neighbour of (so none saw die) the nodes that are "
    "neither remaining nor seen dead, which may be alive on the other side of the lost nodes:"
)


def run_admm_field(algo: dict[str, Any], problem: Any, ex: FieldExchange) -> Any:
    """The ADMM front door with the description's settings on this exchange."""
    from distnav.algorithms.lsq.admm import admm

    return admm(
        problem,
        ex.graph,
        constraint_nodes=algo["constraint_nodes"],
        W=algo["rho"],
        max_iterations=algo["max_iterations"],
        tol=algo["tol"],
        messages=algo["messages"],
        record_nodes=False,
        exchange=ex,
    )


def _used_columns(sub: FieldExchange, arrays: dict[str, np.ndarray]) -> np.ndarray:
    """Which parameters any remaining node's rows observe (a network OR over the sub-network)."""
    A = np.asarray(arrays["A"], float)[: int(arrays["rows"])]
    mine = np.any(A != 0, axis=0).astype(np.int64)
    return np.asarray(sub.allreduce(mine, "max")) > 0


def _columns(arrays: dict[str, np.ndarray], used: np.ndarray) -> dict[str, np.ndarray]:
    out = dict(arrays)
    out["A"] = np.asarray(arrays["A"])[:, used]
    if "parameter_names" in arrays:
        out["parameter_names"] = np.asarray(arrays["parameter_names"])[used]
    return out


def _names(arrays: dict[str, np.ndarray], which: np.ndarray) -> list[str]:
    names = arrays.get("parameter_names")
    return [str(names[k]) if names is not None else f"x[{k}]" for k in np.flatnonzero(which)]


#: a node program's new run on the remaining nodes: its result fields (``status`` and ``message`` of that run) from
#: its exchange on the sub-network; it raises ExchangeError (another loss) or ModelError (no answer: stop)
Rerun = Callable[[FieldExchange], dict[str, Any]]


def admm_again(algo: dict[str, Any], arrays: dict[str, np.ndarray], path: Path) -> Rerun:
    """ADMM on the remaining nodes' rows, without the parameters none of them observes (module docstring)."""

    def rerun(sub: FieldExchange) -> dict[str, Any]:
        used = _used_columns(sub, arrays)
        problem = admm_node_problem(_columns(arrays, used), path, sub.me, sub.graph.n_nodes)
        res = run_admm_field(algo, problem, sub)
        estimate = np.full(used.size, np.nan)
        estimate[used] = res.estimates[sub.me]
        dropped = _names(arrays, ~used)
        return {
            "estimate": estimate,
            "status": res.status,
            "message": f"parameters no remaining node observes (NaN): {dropped or 'none'}; {res.message}",
            "iterations": res.iterations,
            "dropped_parameters": dropped,
        }

    return rerun


def without_lost(desc: NetworkDescription, ex: FieldExchange, error: str, rerun: Rerun) -> dict[str, Any]:
    """Agree on the remaining nodes and run again on their data (module docstring); at most one pass per node of
    the network (each pass loses at least one)."""
    from distnav.commands.field_uwb import _ATTEMPT_STEPS, _check_agreement

    graph, base, name = ex.graph, ex.transport, desc.algorithm["name"]
    window = agreement_window_s(graph, base.options.deadline_s)
    dead: dict[int, int] = {}
    failed = ex.step - 1
    for attempt in range(1, desc.n_nodes + 1):
        alive, failed, step = agree_on_survivors(
            base, graph, attempt * _ATTEMPT_STEPS, window_s=window, failed_step=failed, dead=set(dead)
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
            _check_agreement(sub, alive, failed)
            out = rerun(sub)
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
