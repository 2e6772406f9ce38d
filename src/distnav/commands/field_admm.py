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
operation failed with every node alive a third time (the first two are stalls: the nodes run again with every node,
``status`` ``<status>_run_again``). The field CKF and the UWB anchors use the same
:func:`~distnav.commands.field_survive.without_lost` with their own
:data:`Rerun` (:func:`distnav.commands.field_algorithms.run_ckf`).

**A split network.** The agreement (flooding) cannot tell a dead node from a live one cut off behind the dead: on
a path ``0 – … – 7`` without node 5, nodes ``0..4`` never hear of 6 and 7, and each side would take the other for
dead and solve apart. So a node not among the remaining ones counts as lost only if a remaining node is its
neighbour (saw it silent); any other one — a live node beyond a cut, or a dead node whose neighbours all died — stops
the node, naming it. (Found by ``tests/test_field_admm_lost.py``'s path test: without this check nodes ``0..4``
finished with an answer of their own half.)
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from distnav.commands.field_survive import Rerun
from distnav.exchange.field import FieldExchange
from distnav.formats.field_data import admm_node_problem

__all__ = ["admm_again", "run_admm_field"]


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


def admm_again(algo: dict[str, Any], arrays: dict[str, np.ndarray], path: Path) -> Rerun:
    """ADMM on the remaining nodes' rows, without the parameters none of them observes (module docstring)."""

    def rerun(sub: FieldExchange, alive: np.ndarray) -> dict[str, Any]:  # alive unused: every node has its own rows
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
