"""Asynchronous push-sum at one field node: its own timer, no rounds, no barrier (issue 26 item 5).

``distnav field pushsum-node --config NET --id ID --out DIR [--period-ms P] [--duration-s D]`` runs
node ``ID`` of a network description (:mod:`distnav.formats.field_config`): it reads only its own data file, binds
its address, greets its neighbours, then every ``P`` ms of its own clock pushes its running sum to its neighbours
and, between ticks, uses whatever running sums have arrived (:func:`~distnav.algorithms.consensus.pushsum.
run_push_sum_node`). Nodes may tick at different rates; a lost or late message costs nothing (running sums). After
``D`` seconds it writes ``node-ID.json``: its estimate of the network average, its ticks, the messages it refused
and the real bytes on the wire.

The messages are the field transport's frames (:mod:`distnav.exchange.field.wire`, kind ``COLUMN``, the step field
carrying the sender's own tick count), checked by the transport on arrival (sender, size, format, CURVE key).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import Any

import numpy as np

from distnav.algorithms.consensus.pushsum import NodeOutcome, run_push_sum_node
from distnav.errors import UsageError
from distnav.exchange.faults import uniform_hash
from distnav.exchange.field import Kind, Transport
from distnav.exchange.field.startup import StartCheck, eccentricity, handshake
from distnav.formats.field_config import NetworkDescription, read_description, read_node_values
from distnav.options import existing_file, node_output_files, nonnegative_int, output_folder, positive_float
from distnav.output import atomic_write_json

__all__ = ["TransportLink", "add_node_arguments", "open_node", "run_async_node", "register"]


class TransportLink:
    """A :class:`~distnav.algorithms.consensus.pushsum.PushSumLink` over the field transport.

    With ``drop_probability`` > 0 (the description's ``[faults]``, for tests and demos) the receiver drops each
    arrived message with that probability, decided by ``uniform_hash(seed, tick, sender)``: lost messages in the
    field, on top of whatever the network loses. ``dropped`` counts them."""

    def __init__(
        self, transport: Transport, neighbours: list[int], *, drop_probability: float = 0.0, seed: int = 0
    ) -> None:
        self.transport = transport
        self.neighbours = neighbours
        self.drop_probability = float(drop_probability)
        self.seed = int(seed) * 1_000_003 + transport.me  # a different draw at every receiver
        self.dropped = 0

    def post(self, tick: int, running_sum: np.ndarray) -> None:
        for peer in self.neighbours:
            self.transport.post(peer, Kind.COLUMN, tick, running_sum)

    def drain(self, timeout_s: float) -> list[tuple[int, int, np.ndarray]]:
        msgs = [m for m in self.transport.receive_any(timeout_s) if m.kind == Kind.COLUMN]
        if self.drop_probability > 0 and msgs:
            u = [float(uniform_hash(self.seed, m.step, np.array([m.sender]))[0]) for m in msgs]
            kept = [m for m, x in zip(msgs, u, strict=True) if x >= self.drop_probability]
            self.dropped += len(msgs) - len(kept)
            msgs = kept
        return [(m.sender, m.step, np.asarray(m.array, dtype=float)) for m in msgs]


def run_async_node(
    desc: NetworkDescription, node_id: int, out_dir: Path, *, period_s: float, duration_s: float
) -> NodeOutcome:
    """Run node ``node_id`` (module docstring) and write ``out_dir/node-ID.json``."""
    from distnav.commands.field_node import load_keys

    entry = desc.node(node_id)
    if entry.data is None:
        raise UsageError(f"{desc._where()}: node {node_id}: key 'data' (its value file) is needed by push-sum")
    value = read_node_values(entry.data, node_id)
    neighbours = sorted(entry.neighbours)
    transport = Transport(
        node_id, entry.address, desc.peers(node_id), options=desc.transport_options(), keys=load_keys(desc, node_id)
    )
    try:
        check = StartCheck(desc.fingerprint(), value.size, eccentricity(desc.graph(), node_id))
        missing = handshake(transport, check=check).missing
        t0 = time.monotonic()
        link = TransportLink(transport, neighbours, drop_probability=desc.drop_probability, seed=desc.drop_seed)
        outcome = run_push_sum_node(
            value,
            out_degree=len(neighbours),
            in_neighbours=neighbours,
            link=link,
            period_s=period_s,
            duration_s=duration_s,
        )
        elapsed = time.monotonic() - t0
        atomic_write_json(
            out_dir / f"node-{node_id}.json",
            {
                "node": node_id,
                "algorithm": "pushsum",
                "estimate": outcome.ratio,
                "initial": value,
                "weight": float(outcome.mass[-1]),
                "ticks": outcome.ticks,
                "period_s": period_s,
                "seconds": elapsed,
                "last_tick_from": {str(k): v for k, v in sorted(outcome.last_tick_from.items())},
                "not_used": outcome.refused,
                "dropped_on_purpose": link.dropped,
                "refused": transport.refusal_counts(),
                "missing_at_start": missing,
                "wire": transport.wire_counts(),
                "wire_bytes_by_kind": transport.bytes_by_kind(),
            },
        )
        return outcome
    finally:
        transport.close()


def add_node_arguments(p: argparse.ArgumentParser) -> None:
    """``--config``, ``--id`` and ``--out`` of a node program started by a field command."""
    p.add_argument("--config", type=existing_file, required=True, help="the network description (TOML)")
    p.add_argument("--id", type=nonnegative_int, required=True, help="this node's id")
    p.add_argument("--out", type=output_folder, required=True, help="folder for node-ID.json and node-ID.log")


def open_node(args: argparse.Namespace) -> NetworkDescription:
    """The description of a node program's ``--config``, its ``--id`` checked, its log opened in ``--out``."""
    from distnav.commands.field_processes import setup_node_log

    desc = read_description(args.config)
    if not 0 <= args.id < desc.n_nodes:
        raise UsageError(f"--id {args.id}: the description has nodes 0..{desc.n_nodes - 1}")
    args.out.mkdir(parents=True, exist_ok=True)
    setup_node_log(args.out, args.id)
    return desc


def add_node_program(
    field_sub: Any, name: str, help_text: str, func: Any, options: list[tuple[str, Any, Any, str]]
) -> None:
    """A ``distnav field NAME`` node program: ``--config/--id/--out`` and ``options`` (flag, type, default, help)."""
    p = field_sub.add_parser(name, help=help_text)
    add_node_arguments(p)
    for flag, kind, default, text in options:
        p.add_argument(flag, type=kind, default=default, help=text)
    p.set_defaults(func=func, node_files=node_output_files)


def register(field_sub: Any) -> None:
    """Add ``pushsum-node`` to the ``distnav field`` sub-commands."""
    text = "run one node of an asynchronous push-sum network (own timer)"
    add_node_program(field_sub, "pushsum-node", text, _handler, _PUSHSUM_OPTIONS)


_PUSHSUM_OPTIONS = [
    ("--period-ms", positive_float, 10.0, "tick period of this node (default 10)"),
    ("--duration-s", positive_float, 5.0, "how long the node ticks (default 5)"),
]


def _handler(args: argparse.Namespace) -> int:
    desc = open_node(args)
    run_async_node(desc, args.id, args.out, period_s=args.period_ms / 1000.0, duration_s=args.duration_s)
    return 0
