"""``distnav node --config NET --id ID``: one node of a field network as its own program.

The node reads the description, loads only its own data file, binds its address, greets its neighbours, runs the
algorithm over a :class:`~distnav.exchange.field.FieldExchange` (the same node code as in-process and under MPI) and
writes ``node-ID.json`` (its estimate, status, rounds, the peers it lost and when, real wire bytes and refusals) and
``node-ID.log`` into ``--out``.
"""

from __future__ import annotations

import gc
import itertools
import logging
import os
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from distnav._optional import require
from distnav.algorithms.consensus.averaging import iterate_average_consensus
from distnav.algorithms.consensus.flows import iterate_flow_consensus
from distnav.commands.field_algorithms import REJOIN_ALGORITHMS
from distnav.errors import DataFileError, ExchangeError, UsageError
from distnav.exchange import FaultSchedule
from distnav.exchange.field import CurveKeys, FieldExchange, Transport
from distnav.exchange.field.startup import StartCheck, Startup, eccentricity, handshake
from distnav.exchange.field.startup import rejoin as join_running
from distnav.formats.field_config import NetworkDescription, read_node_values
from distnav.output import atomic_write_json

__all__ = ["CRASH_EXIT", "STOPPED_EXIT", "load_keys", "run_node", "node_values"]

#: Exit code of a node that crashes on purpose (``[faults] crash`` in the description).
CRASH_EXIT = 70
#: Exit code of a node that stopped without an answer (a lost node its algorithm cannot do without), having written
#: its node-ID.json with ``status = "stopped"`` and the reason.
STOPPED_EXIT = 3
LOG = logging.getLogger("distnav.field")


def load_keys(desc: NetworkDescription, node_id: int) -> CurveKeys | None:
    """This node's CURVE key pair from its secret key file (None without CURVE); the public half must be the one
    the description lists."""
    if desc.security != "curve":
        return None
    entry = desc.node(node_id)
    if entry.secret_key is None:
        raise DataFileError(f"{desc._where()}: node {node_id}: key 'secret_key' is needed with security = \"curve\"")
    auth = require("zmq.auth", "field")
    try:
        public, secret = auth.load_certificate(str(entry.secret_key))
    except (OSError, ValueError) as exc:
        raise DataFileError(f"{entry.secret_key}: node {node_id}: cannot read the secret key ({exc})") from None
    if secret is None:
        raise DataFileError(f"{entry.secret_key}: node {node_id}: holds no secret key (a public key file?)")
    if entry.public_key is not None and public.decode() != entry.public_key:
        raise DataFileError(
            f"{entry.secret_key}: node {node_id}: this key pair's public key is not the one the description lists"
        )
    return CurveKeys(public=public, secret=secret)


def node_values(desc: NetworkDescription, node_id: int) -> np.ndarray:
    """A consensus node's values (its data file, :func:`read_node_values`)."""
    entry = desc.node(node_id)
    if entry.data is None:
        raise DataFileError(f"{desc._where()}: node {node_id}: key 'data' (its data file) is needed by consensus")
    return read_node_values(entry.data, node_id)


def run_node(desc: NetworkDescription, node_id: int, out_dir: Path, *, rejoin: bool = False) -> int:
    """Run node ``node_id`` to the end (see the module docstring); returns the exit code. ``rejoin``: a restarted
    node joining a running network (from its initial data, at the step its neighbours are at; no crash again)."""
    entry = desc.node(node_id)
    consensus = desc.algorithm["name"] in ("consensus", "consensus_flows")
    values = node_values(desc, node_id) if consensus else None
    keys = load_keys(desc, node_id)
    if rejoin and not consensus and desc.algorithm["name"] not in REJOIN_ALGORITHMS:
        raise UsageError(f"--rejoin: {desc.algorithm['name']} nodes cannot rejoin a running network (not done)")
    transport = Transport(node_id, entry.address, desc.peers(node_id), options=desc.transport_options(), keys=keys)
    transport.readmit_on_hello = consensus  # ADMM, CKF, UWB: a returning node is invited to a re-run (field_survive)
    t0 = time.monotonic()
    try:
        schedule = FaultSchedule(drop_probability=desc.drop_probability, seed=desc.drop_seed)
        crash_step = None if (consensus or rejoin) else desc.crash.get(node_id)
        ex = (
            FieldExchange(desc.graph(), node_id, transport, schedule, direct=False)
            if crash_step is None
            else _CrashingExchange(desc.graph(), node_id, transport, schedule, crash_step=crash_step)
        )
        joined, late = _join(transport, consensus) if rejoin else (0, None)
        mid_run = joined is not None and rejoin  # False: a normal start (the others were still starting)
        first = joined if joined is not None else 0
        if mid_run and consensus:
            ex.start_at(first)
            LOG.warning("node %d: rejoining at step %d", node_id, first)
        # a consensus node is ready before it greets: weights, checks and mixers built (no message), so the first
        # round does not wait for this node's set-up, and the rounds are timed alone
        states = _consensus_states(desc, node_id, ex, values, first) if values is not None else None
        gc.freeze()  # the set-up's objects (modules, description, weights) out of the collector's passes
        start = Startup([]) if mid_run else _start(desc, node_id, transport, values)
        missing = start.missing
        t_start, cpu_start = time.monotonic(), time.process_time()
        outcome: dict[str, Any]
        if late is not None:  # a node program back after the others finished: no answer, the reason
            outcome = {"estimate": None, "status": "stopped", "message": late, "rounds": 0}
        elif states is not None:
            assert values is not None
            crash_round = None if rejoin else desc.crash.get(node_id)
            outcome = _run_consensus(states, values, node_id, int(desc.algorithm["rounds"]), first, crash_round)
            outcome |= _farewell(transport, ex.step)
        else:
            from distnav.commands.field_algorithms import run_algorithm

            outcome = run_algorithm(desc, node_id, ex, transport)
        elapsed, cpu = time.monotonic() - t_start, time.process_time() - cpu_start
        ex._flush()  # this node's model counters (comm_totals would gather over the network)
        rounds = int(outcome.pop("rounds"))
        status = outcome.pop("status", "completed")
        agreed = outcome.pop("lost_nodes", None)  # losses the node program agreed on with the others (uwb)
        lost = agreed if agreed is not None else {str(k): v for k, v in sorted(transport.lost.items())}
        if agreed is None and transport.lost and status != "stopped":
            status = f"{status}_with_lost_neighbours"
        if outcome.get("dropped_by"):  # its neighbours went on without it (:func:`_farewell`)
            status = f"{status}_dropped_by_neighbours"
        result = {
            "node": node_id,
            "algorithm": desc.algorithm["name"],
            **outcome,
            "rounds": rounds,
            "steps": ex.step,
            "status": status,
            "lost_nodes": lost,
            "readmitted_nodes": {str(k): v for k, v in sorted(transport.readmitted.items())},
            "missing_at_start": missing,
            "refused_at_start": {str(k): v for k, v in sorted(start.strangers.items())},
            "rejoined_at_step": first if mid_run else None,
            "restarted_during_startup": rejoin and not mid_run,
            "wire": transport.wire_counts(),
            "wire_bytes_by_kind": transport.bytes_by_kind(),
            "model_bytes_sent": int(ex.bytes_sent.sum()),
            "messages_received_model": int(ex.messages_received.sum()),
            "refused": transport.refusal_counts(),
            "seconds": elapsed,
            "cpu_seconds": cpu,
            "seconds_total": time.monotonic() - t0,
            "rounds_per_second": rounds / elapsed if elapsed > 0 else None,
        }
        atomic_write_json(out_dir / f"node-{node_id}.json", result)
        LOG.info("node %d: %d rounds in %.2f s, lost %s", node_id, rounds, elapsed, sorted(transport.lost))
        return STOPPED_EXIT if status == "stopped" else 0
    finally:
        transport.close()


def _start(desc: NetworkDescription, node_id: int, transport: Transport, values: np.ndarray | None) -> Startup:
    """The start-up handshake (:mod:`distnav.exchange.field.startup`: this network's fingerprint, a consensus node's
    number of values, into step 0 with the whole network). A node that heard none of its neighbours takes part in
    no run: :class:`ExchangeError` (exit code 2) with the reason, and no ``node-ID.json`` (a second start of a node
    that already finished writes nothing over its result). ADMM, CKF and UWB nodes import their modules and read
    their data file first (:func:`~distnav.commands.field_algorithms.prepare_node`), as a consensus node has built its
    states: the barrier lets the network into step 0 together, so nothing slow may come after it."""
    if values is None:
        from distnav.commands.field_algorithms import prepare_node

        prepare_node(desc, node_id)
    depth = eccentricity(desc.graph(), node_id)
    check = StartCheck(desc.fingerprint(), 0 if values is None else values.size, depth)
    start = handshake(transport, check=check)
    if start.missing:
        LOG.warning("node %d: no hello from neighbours %s within %.0f s", node_id, start.missing, desc.start_timeout_s)
    if start.latest_step >= desc.miss_limit:  # they began without it, and have taken it for lost
        raise ExchangeError(
            f"node {node_id}: its neighbours are already at step {start.latest_step}: it started after the others "
            f"began (more than start_timeout_s = {desc.start_timeout_s:g} s after them?); start it with --rejoin"
        )
    if transport.peers and len(start.missing) + len(start.strangers) == len(transport.peers):
        reasons: dict[str, list[int]] = {}
        for k, v in sorted(start.strangers.items()):
            reasons.setdefault(v, []).append(k)
        why = "; ".join(f"neighbours {ids}: {v}" for v, ids in reasons.items())
        if why:
            raise ExchangeError(f"node {node_id}: refused by the start-up check: {why}")
        curve = " With CURVE: is this node's key pair the one its neighbours' description lists?"
        raise ExchangeError(
            f"node {node_id}: none of its neighbours {sorted(transport.peers)} answered within "
            f"{desc.start_timeout_s:g} s (are they started, with this description, and their addresses reachable from "
            "here? a node started after the others finished has no run to join)." + (curve if transport.curve else "")
        )
    if values is not None:  # consensus: a neighbour known absent is not waited for (it is readmitted if it comes)
        for p in start.missing:
            transport.lost.setdefault(p, 0)
    LOG.info(
        "node %d: started after %.1f s (neighbours missing %s, refused %s)",
        node_id,
        start.seconds,
        start.missing,
        sorted(start.strangers),
    )
    return start


def _farewell(transport: Transport, step: int) -> dict[str, Any]:
    """A consensus node's last word: a bye to every neighbour saying whether (at which step, else -1) this node
    declared it lost, and the byes that came from the neighbours by now (:meth:`Transport.farewell`). A node stopped
    (SIGSTOP) past the deadlines and then resumed ran on its neighbours' queued messages and could not tell that they
    had dropped it: their answer and its own no longer hold its data. The byes of neighbours that finished before it
    are there when it ends (``dropped_by``, ``status`` ``..._dropped_by_neighbours``)."""
    return {"dropped_by": transport.farewell(step)}


def _join(transport: Transport, consensus: bool) -> tuple[int | None, str | None]:
    """A restarted node's way back: a consensus node at the step its neighbours are at; an ADMM, CKF or UWB node
    when the others invite it to run again with them (:func:`~distnav.commands.field_survive.without_lost`), or, if
    none does within ``start_timeout_s`` (they finished without it), the reason it stops. None: the others are still
    in their start-up (:func:`~distnav.exchange.field.startup.rejoin`), and the node starts with them from step 0."""
    try:
        return join_running(transport, invitation=not consensus), None
    except ExchangeError as exc:
        if consensus:
            raise
        return 0, f"restarted, but the others did not take it back (they finished without it?): {exc}"


class _CrashingExchange(FieldExchange):
    """A field exchange whose process exits on purpose when it reaches step ``crash_step`` (``[faults] crash`` of an
    algorithm node: its "round" is the exchange's step, every message round or global operation one step)."""

    def __init__(self, *args: Any, crash_step: int) -> None:
        super().__init__(*args, direct=False)
        self._crash_step = int(crash_step)

    def _next_step(self) -> int:
        if self.step == self._crash_step:
            LOG.warning("node %d: crashing on purpose at step %d ([faults] crash)", self.me, self.step)
            logging.shutdown()
            os._exit(CRASH_EXIT)
        return super()._next_step()


def _consensus_states(
    desc: NetworkDescription, node_id: int, ex: FieldExchange, values: np.ndarray, first: int
) -> Iterator[Any]:
    """Average consensus or its flow form from round ``first`` on, its set-up done (the initial state taken)."""
    algo = desc.algorithm
    rounds = int(algo["rounds"]) - first
    full = np.zeros((desc.n_nodes, values.size))
    full[node_id] = values  # the other rows are placeholders: only this node's row is read (ex.local)
    states: Iterator[Any]
    if algo["name"] == "consensus":
        states = iterate_average_consensus(full, graph=ex.graph, protocol=algo["protocol"], rounds=rounds, exchange=ex)
    else:
        states = iterate_flow_consensus(
            full, graph=ex.graph, protocol=algo["protocol"], rounds=rounds, exchange=ex, patience=algo["patience"]
        )
    first_state = next(states)  # builds the weights and mixers; no message yet
    return itertools.chain([first_state], states)


def _run_consensus(
    states: Iterator[Any], values: np.ndarray, node_id: int, rounds: int, first: int, crash_round: int | None
) -> dict[str, Any]:
    """Run the consensus rounds; exits the process at round ``crash_round`` (``[faults] crash``)."""
    last = None
    for state in states:
        last = state
        if crash_round is not None and state.round + first == crash_round:
            LOG.warning("node %d: crashing on purpose at round %d ([faults] crash)", node_id, crash_round)
            logging.shutdown()
            os._exit(CRASH_EXIT)
    assert last is not None
    return {"estimate": last.values[0], "initial": values, "rounds": rounds}


def check_node_id(desc: NetworkDescription, node_id: int) -> None:
    if not 0 <= node_id < desc.n_nodes:
        raise UsageError(f"--id {node_id}: the description has nodes 0..{desc.n_nodes - 1}")
