"""The algorithms beyond consensus as field node programs: ADMM (paper 000), the CKF (paper 003), UWB (paper 002).

``distnav node`` calls :func:`run_algorithm` with its :class:`~distnav.exchange.field.FieldExchange`; the node reads
only its own data file (:mod:`distnav.formats.field_data`) and runs **the same front door as in-process and under
MPI** (:func:`~distnav.algorithms.lsq.admm.admm`, :func:`~distnav.algorithms.kalman.ckf.iterate_ckf`) over the field
exchange. The global operations those front doors use (ADMM's rank check, stopping totals and gathered result; the
CKF's gathered estimates) travel over the network's spanning tree (:mod:`distnav.exchange.field.tree`), so no node
needs any address but its neighbours'. Without lost messages every node's numbers equal the in-process run's bit for
bit (``tests/test_field_algorithms.py``).

The UWB solvers' iterations read only an anchor's own links (paper 002 eq. (14)), but their monitoring, stopping rule,
final cost, observation tests and precision are central computations on every range (under MPI every rank holds the
whole problem). A field anchor's file holds only its own links; at start-up it gathers the other anchors' range
samples once over the spanning tree (counted on the wire), so those central computations are the in-process ones.
A deployment whose anchors must not share their ranges needs them made node-local (not done). The UWB program, and
how its anchors go on without one that dies, is :mod:`distnav.commands.field_uwb`.

Departure from the in-process defaults, stated: the CKF runs without the Fig. 7 error-variance recursion
(``variance=False``: it needs every node's normals at every node each epoch, an analysis input no node has) and
without the consensus-deviation monitor (``monitor=False``), as ``distnav gnss ionosphere`` runs it.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from distnav.errors import ExchangeError, UsageError
from distnav.exchange.field import FieldExchange, Transport
from distnav.formats.field_config import NetworkDescription
from distnav.formats.field_data import admm_node_problem, ckf_node_model, read_node_arrays

if TYPE_CHECKING:
    from distnav.commands.field_survive import Rerun

__all__ = ["NODE_ALGORITHMS", "REJOIN_ALGORITHMS", "prepare_node", "rejoin_algorithm", "run_algorithm"]

NODE_ALGORITHMS = ("admm", "ckf", "uwb")
#: node programs a restarted node can rejoin (besides consensus): they run again from the start with it
REJOIN_ALGORITHMS = ("admm", "ckf", "uwb")


def _arrays(desc: NetworkDescription, node_id: int, kind: str) -> dict[str, np.ndarray]:
    from distnav.errors import DataFileError

    entry = desc.node(node_id)
    if entry.data is None:
        raise DataFileError(f"{desc._where()}: node {node_id}: key 'data' (its .npz data file) is needed by {kind}")
    return read_node_arrays(entry.data, kind, node_id, desc.n_nodes)


def run_admm(desc: NetworkDescription, node_id: int, ex: FieldExchange) -> dict[str, Any]:
    """ADMM (paper 000 Fig. 6) on this node's observation block; its estimate, status and iterations. A node lost
    mid-run: the others go on without it (:mod:`distnav.commands.field_admm`)."""
    from distnav.commands.field_admm import run_admm_field
    from distnav.commands.field_survive import without_lost

    entry = desc.node(node_id)
    assert entry.data is not None
    arrays = _arrays(desc, node_id, "admm")
    problem = admm_node_problem(arrays, entry.data, node_id, desc.n_nodes)
    try:
        res = run_admm_field(desc.algorithm, problem, ex)
    except ExchangeError as exc:
        return without_lost(desc, ex, str(exc), _rerun(desc, node_id))
    return {
        "estimate": res.estimates[node_id],
        "status": res.status,
        "message": res.message,
        "iterations": res.iterations,
        "rounds": 2 * res.iterations + 1,
    }


def run_ckf(desc: NetworkDescription, node_id: int, ex: FieldExchange) -> dict[str, Any]:
    """The CKF (paper 003 Fig. 6) on this node's normals; its final estimate and which states it determines. A
    global check at the end (the CKF has none of its own) tells every node of a loss; then the remaining nodes agree
    on who remains and run the CKF again from the first epoch on their own normals
    (:func:`~distnav.commands.field_survive.without_lost`)."""
    from distnav.commands.field_survive import without_lost

    entry = desc.node(node_id)
    assert entry.data is not None
    try:
        out = _ckf(desc.algorithm, _arrays(desc, node_id, "ckf"), entry.data, ex)
    except ExchangeError as exc:
        return without_lost(desc, ex, str(exc), _rerun(desc, node_id))
    return out


def _rerun(desc: NetworkDescription, node_id: int) -> Rerun:
    """The run again of an ADMM, CKF or UWB node on a sub-network (without lost nodes, or with returned ones), from the
    start on its own data."""
    from distnav.commands.field_admm import admm_again
    from distnav.commands.field_uwb import uwb_again

    entry = desc.node(node_id)
    assert entry.data is not None
    path, kind = entry.data, desc.algorithm["name"]
    if kind == "uwb":
        return uwb_again(desc, node_id)
    arrays = _arrays(desc, node_id, kind)
    if kind == "admm":
        return admm_again(desc.algorithm, arrays, path)

    def ckf_on(sub: FieldExchange, alive: np.ndarray) -> dict[str, Any]:  # alive unused: every node has its own normals
        return _ckf(desc.algorithm, arrays, path, sub)

    return ckf_on


def rejoin_algorithm(desc: NetworkDescription, node_id: int, ex: FieldExchange, invited: np.ndarray) -> dict[str, Any]:
    """A restarted ADMM, CKF or UWB node, invited back by the others (``invited``: ``startup.rejoin``): it runs
    again from the start with them, on every node's data that is there (:func:`~distnav.commands.field_survive.
    without_lost`)."""
    from distnav.commands.field_survive import without_lost

    if desc.algorithm["name"] not in REJOIN_ALGORITHMS:
        raise UsageError(f"--rejoin: {desc.algorithm['name']} nodes cannot rejoin (only {REJOIN_ALGORITHMS})")
    return without_lost(desc, ex, "", _rerun(desc, node_id), invited=invited)


def _ckf(algo: dict[str, Any], arrays: dict[str, np.ndarray], path: Path, ex: FieldExchange) -> dict[str, Any]:
    """The CKF front door on this node's normals over ``ex`` (its graph's nodes), then a global check that every
    node is still there (a loss raises :class:`ExchangeError` at every node)."""
    from distnav.algorithms.kalman.ckf import iterate_ckf

    dyn, series = ckf_node_model(arrays, path, ex.me, ex.graph.n_nodes)
    last = None
    for state in iterate_ckf(
        dyn,
        series,
        graph=ex.graph,
        protocol=algo["protocol"],
        rounds=algo["rounds"],
        exchange=ex,
        variance=False,
        monitor=False,
    ):
        last = state
    assert last is not None
    ex.allreduce(0, "max")  # a node lost anywhere: the operation cannot be finished, at every node
    return {
        "estimate": last.estimates[0],
        "estimable": last.estimable[0],
        "status": "completed",
        "message": f"{series.n_epochs} epochs",
        "epochs": series.n_epochs,
        "rounds": series.n_epochs * algo["rounds"],
    }


def prepare_node(desc: NetworkDescription, node_id: int) -> None:
    """What a node program can do before the start-up barrier: import its algorithm's modules and read (and check)
    its data file. The barrier lets every node into step 0 together; a node whose imports and file read came after
    it spent the first steps' deadlines on them (``deadline_ms × miss_limit``, 6 s by default, is not long on a
    loaded or slow device) and could be declared lost. A bad data file is refused here, before this node greets."""
    import distnav.algorithms.lsq.admm  # noqa: F401  (the front doors the runners call; imported once)
    import distnav.commands.field_survive  # noqa: F401

    name = desc.algorithm["name"]
    if name == "uwb":
        import distnav.algorithms.ranging.csg  # noqa: F401  (the solvers' front door, imported in the solve)
        from distnav.commands.field_uwb import _own

        _own(desc, node_id)
    else:
        import distnav.algorithms.kalman.ckf  # noqa: F401
        import distnav.commands.field_admm  # noqa: F401

        _arrays(desc, node_id, name)


def run_algorithm(desc: NetworkDescription, node_id: int, ex: FieldExchange, transport: Transport) -> dict[str, Any]:
    """Run the description's algorithm (one of :data:`NODE_ALGORITHMS`) as node ``node_id``.

    ADMM, the CKF and UWB go on without a dead node: the remaining nodes agree on who remains and run again on their
    own data (:mod:`distnav.commands.field_admm`, :mod:`distnav.commands.field_uwb`); where they cannot (the rest may
    be split, a parameter becomes inestimable, another failure) the node ends with ``status = "stopped"``, no
    estimate, and a message naming the lost node and the reason — never an answer that looks right. (Consensus in
    flow form also finishes: the exact mean of the nodes that remain, :mod:`distnav.algorithms.consensus.flows`.)"""
    from distnav.commands.field_uwb import run_uwb

    runner = {"admm": run_admm, "ckf": run_ckf, "uwb": run_uwb}[desc.algorithm["name"]]
    try:
        out = (
            runner(desc, node_id, ex)
            if transport.invited is None
            else rejoin_algorithm(desc, node_id, ex, transport.invited)
        )
    except ExchangeError as exc:
        return _stopped(desc, ex, transport, str(exc))
    if transport.lost and "lost_nodes" not in out:  # (admm, uwb name the losses it went on without itself)
        return _stopped(desc, ex, transport, "")
    return out


def _stopped(desc: NetworkDescription, ex: FieldExchange, transport: Transport, error: str) -> dict[str, Any]:
    lost = ", ".join(f"node {k} at step {v}" for k, v in sorted(transport.lost.items()))
    why = "; ".join(t for t in (f"lost {lost}" if lost else "", error) if t)
    return {
        "estimate": None,
        "status": "stopped",
        "message": (
            f"{desc.algorithm['name']} cannot finish without every node's data: {why}; no estimate is given (a "
            "restart of the whole network without the lost node gives the answer of the rest)"
        ),
        "rounds": ex.step,
    }
