"""A node's start-up: hellos until its neighbours have answered, checked against this node's network, then into step
0 together with the whole network.

Two things went wrong without it (found by starting node programs in a random order, and with another network's
description or a cut data file):

* **a node started alone.** A node whose neighbours had all answered went into its rounds while a neighbour still
  waited for a node of its own that had not started yet; it passed its first steps' deadlines without a message
  (or, with a short deadline, declared every neighbour lost), its neighbours used its messages and it did not use
  theirs, and plain consensus ended, every node "completed", 1.5 away from the mean of data of size 1. Now every
  hello carries the sender's *level*: -1 while it waits for its own neighbours' hellos (at most ``start_timeout_s``),
  then ``1 + min`` of its answered neighbours' levels (0 when it has none), capped at ``levels``. A node at level
  ``k`` knows that every node within ``k`` hops has heard its neighbours, so at ``levels = n - 1`` (a network
  description's nodes) the whole connected network has, and the nodes enter step 0 within a few message latencies
  of each other. A level change is sent at once (not at the 0.5 s repeat), so the rise to ``n - 1`` costs ``n - 1``
  message latencies. Bounded: a node waits at most ``2 × start_timeout_s`` in all (a neighbour that answered and then
  died holds the levels back until then; it is lost in the run as any dead node);
* **a stranger taken for a neighbour.** Without CURVE anything on a neighbour's port was believed: a node of another
  network's description on the same ports ran with this one (its data in this network's answer, every status
  "completed"), and a node whose data file had lost values sent messages of the wrong length, refused every round
  but never counted as missing. Now the hello carries the network's fingerprint
  (:meth:`~distnav.formats.field_config.NetworkDescription.fingerprint`) and the number of values of this node's
  step messages where the algorithm knows it (consensus: the data's length); a hello that differs is refused
  (``another_network``, the reason logged once), and the sender is a *stranger*: lost from step 0 and every
  later message of it refused (:attr:`Transport.strangers`). So is a peer whose step messages come before any hello
  of it (a neighbour's hellos precede its step messages on their one connection): a run already going on without
  this node, or another network's.

The hello (kind ``HELLO``, step 0) carries int64 ``[level, fingerprint, values]``; a restarted process's hello is one
byte (uint8), as before.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from distnav.exchange.field.transport import Transport
from distnav.exchange.field.wire import Kind, WireError, decode, encode

__all__ = ["StartCheck", "Startup", "handshake"]

LOG = logging.getLogger("distnav.field")
_REPEAT_S = 0.5  # a hello is repeated this often (and at once when the level changes)


@dataclass(frozen=True)
class StartCheck:
    """What a hello must agree on, and how far the start waits.

    network_id : the network's fingerprint (0: not checked). values : the number of values of this node's step
    messages (0: not checked). levels : the start-up barrier's depth (``n - 1`` for a description of ``n`` nodes;
    0: start as soon as the neighbours have answered).
    """

    network_id: int = 0
    values: int = 0
    levels: int = 0


@dataclass
class Startup:
    """How the start went: the neighbours that never answered, and the strangers (neighbour → why refused)."""

    missing: list[int]
    strangers: dict[int, str] = field(default_factory=dict)
    seconds: float = 0.0
    #: the latest step of a neighbour's message that came during the start (-1: none; a node that comes after the
    #: others began sees their steps)
    latest_step: int = -1


def handshake(transport: Transport, peers: list[int] | None = None, check: StartCheck | None = None) -> Startup:
    """Greet ``peers`` (default: every peer of ``transport``) and wait as the module docstring says; returns who
    never answered and who was refused. Step messages that arrive meanwhile are kept for their step."""
    chk = check if check is not None else StartCheck()
    targets = sorted(transport.peers) if peers is None else sorted(peers)
    t0 = time.monotonic()
    end_answers, end_all = t0 + transport.options.start_timeout_s, t0 + 2 * transport.options.start_timeout_s
    levels: dict[int, int] = {}  # neighbour → its latest level (-1: still waiting for its own neighbours)
    strangers: dict[int, str] = {}
    level, sent, next_send = -1, -2, 0.0
    while True:
        now = time.monotonic()
        answered = [p for p in targets if p in levels]
        if level < 0 and (len(answered) + len(strangers) >= len(targets) or now >= end_answers):
            level = 0  # this node has heard its neighbours (or has waited for them long enough)
        if level >= 0:
            level = min(chk.levels, 1 + min((levels[p] for p in answered), default=chk.levels))
        if level >= chk.levels or now >= end_all:
            break
        if now >= next_send or level != sent:
            _greet(transport, targets, level, chk)
            sent, next_send = level, now + _REPEAT_S
        if transport.pull.poll(50):
            for frame in transport._frames():
                _hear(transport, frame, chk, levels, strangers)
    _greet(transport, targets, chk.levels, chk)  # neighbours still rising see this node at the top
    transport.strangers.update(strangers)
    for p in strangers:
        transport.lost.setdefault(p, 0)
    missing = [p for p in targets if p not in levels and p not in strangers]
    latest = max(transport._held, default=-1)
    for held in transport._held.values():  # a stranger's step messages are never used
        for p in strangers:
            held.pop(p, None)
    return Startup(missing, strangers, time.monotonic() - t0, latest)


def _greet(transport: Transport, targets: list[int], level: int, chk: StartCheck) -> None:
    frame = encode(Kind.HELLO, transport.me, 0, np.array([level, chk.network_id, chk.values], np.int64))
    zmq = transport._zmq
    for p in targets:
        try:
            transport.push[p].send(frame, zmq.NOBLOCK)
        except zmq.Again:
            continue
        transport.bytes_sent += len(frame)
        transport.frames_sent += 1


def _hear(transport: Transport, frame: Any, chk: StartCheck, levels: dict[int, int], strangers: dict[int, str]) -> None:
    """One frame received during the start: a hello (its level noted, or its sender refused as a stranger), or a step
    message of a neighbour already in its rounds (kept; that neighbour is at the top level)."""
    try:
        msg = decode(frame.buffer if transport.curve else frame, max_bytes=transport.options.max_message_bytes)
    except WireError as exc:
        transport._refuse("malformed", str(exc))
        return
    sender = msg.sender
    if sender not in transport.peers:
        transport._refuse("unknown_sender", f"message from node {sender}, not a peer of node {transport.me}")
        return
    if sender in strangers:
        transport.refused["another_network"] += 1
        return
    if msg.kind != Kind.HELLO:  # a neighbour's hellos come before its step messages (one ordered connection)
        transport._held.setdefault(msg.step, {})[sender] = msg
        if sender in levels:
            levels[sender] = chk.levels  # in its rounds: at the top
            return
        strangers[sender] = _UNGREETED
        transport._refuse("another_network", f"node {transport.me}: refused node {sender}: {_UNGREETED}")
        return
    a = msg.array
    if a.dtype == np.uint8 and a.size == 1:  # a restarted process's hello: not a start-up
        return
    why = _difference(a, chk)
    if why is not None:
        strangers[sender] = why
        transport._refuse("another_network", f"node {transport.me}: refused node {sender}'s hello: {why}")
        return
    levels[sender] = max(levels.get(sender, -1), int(a[0]))


_UNGREETED = (
    "it sent step messages before any start-up hello of this network (a run that began without this node: start it "
    "with --rejoin; or another network on these ports)"
)


def _difference(a: np.ndarray, chk: StartCheck) -> str | None:
    """Why a start-up hello's payload does not belong to this node's network (None: it does)."""
    if a.dtype != np.int64 or a.size != 3:
        return f"a start-up hello of another format ({a.dtype}, {a.size} values: another distnav version?)"
    _, network_id, values = (int(v) for v in a)
    if chk.network_id and network_id != chk.network_id:
        return (
            f"it runs another network description (fingerprint {network_id & 0xFFFFFFFF:08x}, this node's "
            f"{chk.network_id & 0xFFFFFFFF:08x}): a different file, or another network on these ports"
        )
    if chk.values and values and values != chk.values:
        return f"its messages carry {values} values, this node's {chk.values} (a data file with values missing?)"
    return None
