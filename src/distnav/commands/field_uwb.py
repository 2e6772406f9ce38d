"""The UWB solvers of paper 002 as a field anchor's program, going on without an anchor that dies mid-run.

An anchor's file holds only its own range samples (every sample of a link it is an end of) and the anchor table
(:mod:`distnav.formats.field_data`). The solvers' iterations read only an anchor's own links (paper 002 eq. (14)),
but their monitoring, stopping rule, final cost, observation tests and precision are central computations on every
range, so at start-up each anchor gathers the others' samples over the spanning tree (counted on the wire) and then
runs the same :func:`~distnav.algorithms.ranging.csg.solve` as in-process and under MPI on the field exchange.

**A dead anchor.** The solvers' network totals are global operations: one that lacks an anchor raises
:class:`~distnav.errors.ExchangeError` at every anchor, in the same step (:mod:`distnav.exchange.field.tree`). The
anchors that remain then

1. agree on who remains (:func:`~distnav.exchange.field.survivors.agree_on_survivors`: flooding over their own
   links, with absolute round deadlines that cover the skew with which they left the failed operation);
2. check the agreement: every anchor's view of the remaining anchors and of the failed step, gathered over the
   remaining anchors' spanning tree, must be the same (otherwise the anchor stops, ``status = "stopped"``);
3. gather the remaining anchors' samples of the links between remaining anchors (the dead anchor's links are
   dropped; the samples are renumbered in their original order, the anchors in ascending id order) and solve again
   on that reduced problem, **from the initial guess of the files** (the survey's), with the same solver and
   settings, over a :class:`~distnav.exchange.field.survivors.SubnetTransport`.

So the answer is exactly the in-process solve of the remaining data (the same solver from the same start), and with
the ``metres`` objective (whose final distributed LM phase has LM's fixed point, :mod:`~distnav.algorithms.ranging.
refine`) it is LM's solution of the remaining data to well under a millimetre on a well-connected hall
(``tests/test_field_uwb_lost.py``). Departure, stated: the restart discards the iterations made before the loss
(they were made with the dead anchor's ranges, so they are not iterations of the reduced problem). The node's
``status`` is the reduced solve's with ``_without_lost_nodes``; ``lost_nodes`` names every lost anchor with the step
of the failed operation (at every remaining anchor, not only the dead one's neighbours). If another anchor dies
during the second solve the anchors agree again; a failure with nobody lost, or a remaining network that is not
connected, stops the anchor with the reason.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from distnav.commands.field_survive import Rerun, without_lost
from distnav.errors import DataFileError, ExchangeError
from distnav.exchange.field import FieldExchange
from distnav.formats.field_config import NetworkDescription
from distnav.formats.field_data import read_node_arrays, uwb_samples_problem

__all__ = ["run_uwb", "uwb_again"]

_TABLE = ("ids", "positions_m", "free", "initial_m", "truth_m")  # the anchor table's per-anchor arrays


def run_uwb(desc: NetworkDescription, node_id: int, ex: FieldExchange) -> dict[str, Any]:
    """A UWB solver (paper 002; N-CLM by default) as anchor ``node_id``: its own position estimate and the status
    (on the remaining anchors when one died: module docstring)."""
    arrays, own, path = _own(desc, node_id)
    try:
        problem = uwb_samples_problem(arrays, _gathered(ex, own), path)
        res = _solve(problem, desc.algorithm, ex)
    except ExchangeError as exc:
        return without_lost(desc, ex, str(exc), _uwb_again(desc, arrays, own, path))
    return {
        "estimate": res.estimates[node_id],
        "status": res.status,
        "message": res.message,
        "iterations": res.iterations,
        "rounds": res.iterations,
        "samples_gathered_at_start": int(problem.n_meas),
    }


def uwb_again(desc: NetworkDescription, node_id: int) -> Rerun:
    """The UWB :data:`Rerun` of anchor ``node_id`` from its file: a restarted anchor's solve with the others
    (:func:`~distnav.commands.field_algorithms.rejoin_algorithm`)."""
    return _uwb_again(desc, *_own(desc, node_id))


def _own(desc: NetworkDescription, node_id: int) -> tuple[dict[str, np.ndarray], np.ndarray, Path]:
    """This anchor's file: its arrays, its own sample rows ``[index, a, b, range_m]`` and the file's path."""
    entry = desc.node(node_id)
    if entry.data is None:
        raise DataFileError(f"{desc._where()}: node {node_id}: key 'data' (its .npz data file) is needed by uwb")
    arrays = read_node_arrays(entry.data, "uwb", node_id, desc.n_nodes)
    own = np.asarray(arrays["samples"], float)
    if own.ndim != 2 or own.shape[1] != 4:
        raise DataFileError(f"{entry.data}: node {node_id}: samples must be rows [index, a, b, range_m]")
    return arrays, own, entry.data


def _gathered(ex: FieldExchange, own: np.ndarray) -> np.ndarray:
    """Every anchor's sample rows at every anchor (over the spanning tree; the padding rows dropped)."""
    width = int(ex.allreduce(own.shape[0], "max"))
    padded = np.full((1, width, 4), -1.0)
    padded[0, : own.shape[0]] = own
    rows = ex.gather_nodes(padded).reshape(-1, 4)
    return rows[rows[:, 0] >= 0]


def _solve(problem: Any, algo: dict[str, Any], ex: FieldExchange) -> Any:
    from distnav.algorithms.ranging.csg import solve

    extra = {} if algo.get("objective", "squared") == "squared" else {"objective": algo["objective"]}
    return solve(problem, algo["solver"], iterations=algo["iterations"], exchange=ex, **extra)


def _reduced(arrays: dict[str, np.ndarray], rows: np.ndarray, alive: np.ndarray) -> tuple[dict[str, Any], np.ndarray]:
    """The anchor table of the remaining anchors and ``rows`` (original numbering, links between remaining anchors
    only) renumbered: samples by rank of their original index, anchors in ascending id order."""
    keep = np.flatnonzero(alive)
    new = np.full(alive.size, -1, np.int64)
    new[keep] = np.arange(keep.size)
    index = np.unique(rows[:, 0].astype(np.int64))
    out = rows.copy()
    out[:, 0] = np.searchsorted(index, rows[:, 0].astype(np.int64))
    out[:, 1] = new[rows[:, 1].astype(np.int64)]
    out[:, 2] = new[rows[:, 2].astype(np.int64)]
    table: dict[str, Any] = dict(arrays)
    for key in _TABLE:
        if key in arrays:
            table[key] = np.asarray(arrays[key])[keep]
    table["n_samples"] = np.array(index.size, np.int64)
    return table, out


def _between(own: np.ndarray, alive: np.ndarray) -> np.ndarray:
    a, b = own[:, 1].astype(np.int64), own[:, 2].astype(np.int64)
    return np.asarray(own[alive[a] & alive[b]])


def _uwb_again(desc: NetworkDescription, arrays: dict[str, np.ndarray], own: np.ndarray, path: Path) -> Rerun:
    """The solve again on the remaining anchors' data (module docstring, step 3), the UWB :data:`Rerun` of
    :func:`~distnav.commands.field_survive.without_lost`."""

    def rerun(sub: FieldExchange, alive: np.ndarray) -> dict[str, Any]:
        table, rows = _reduced(arrays, _gathered(sub, _between(own, alive)), alive)
        problem = uwb_samples_problem(table, rows, path)
        res = _solve(problem, desc.algorithm, sub)
        return {
            "estimate": res.estimates[sub.me],
            "status": res.status,
            "message": res.message,
            "iterations": res.iterations,
            "samples_of_remaining": int(problem.n_meas),
        }

    return rerun
