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
  ``k`` knows that every node within ``k`` hops has heard its neighbours, so at ``levels`` = its
  :func:`eccentricity` in the graph of who greets whom (at most ``n - 1``, the depth used before; 1 where every
  node greets every other) the whole connected network has, and the nodes enter step 0 within a few message
  latencies of each other. A level change is sent at once to every neighbour, so the rise costs ``levels`` message
  latencies; a hello is repeated (0.5 s, then 1, 2, 4 s) only to a neighbour that has not answered (a hello to a node
  not yet started waits in its queue and arrives when it starts), and answered at once (at most every 0.5 s) to one
  whose hello says it still waits or that restarted. Bounded: a node waits at most ``2 × start_timeout_s`` in all (a
  neighbour that answered and then died holds the levels back until then; it is lost in the run as any dead node);
* **a rejoin during the start-up.** A node killed while the network was still starting and restarted with
  ``--rejoin`` greeted with its one-byte hello, which the barrier ignored: it exited 2 ("no neighbour answered")
  and the others waited ``2 × start_timeout_s`` and ran without its data. Now the barrier answers it (and waits
  for its new process: its old level is void), :func:`rejoin` sees start-up hellos and no step message, and the
  node starts as the others do, from step 0;
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

The hello (kind ``HELLO``, step 0) carries int64 ``[level, fingerprint, values, depth]``; a restarted process's hello
is one byte (uint8), as before.

Three start-up races (review13), each fixed here:

* **a dead neighbour lengthens the distances.** With a node that never started, the live nodes' distances can
  exceed the full graph's eccentricity, and a node left its barrier before a live neighbour (ring of 6, node 3 dead,
  node 2 late: node 4 out at 3.1 s, node 5 at 4.5 s). A node that reaches level 0 by timing out on a neighbour takes
  ``StartCheck.levels_if_missing`` (``n - 1``) as its depth and carries it in every hello; every node takes the
  largest depth it hears (the depth travels in the same hellos as the levels it must hold back);
* **a top-level hello read as "still starting".** :func:`rejoin` returned None 0.5 s after a neighbour's *last*
  hello (at its top level) when its first step message came later; the node then ran :func:`handshake`, which took
  that neighbour's step messages for a stranger's. Now only a hello below its sender's depth starts the 0.5 s wait;
* **a node back mid-run held a neighbour in its barrier.** Its one-byte hello reset its level there; :func:`announce`
  (one hello at its top level, sent first on the mid-run path) sets it again.

Every hello sent, :func:`rejoin`'s too, is counted in the transport's byte totals
(:meth:`Transport.bytes_by_kind` ``hello``).
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from distnav.errors import ExchangeError
from distnav.exchange.field.transport import Transport
from distnav.exchange.field.wire import Kind, WireError, decode
from distnav.network.graph import Graph

__all__ = ["StartCheck", "Startup", "announce", "eccentricity", "handshake", "rejoin"]

LOG = logging.getLogger("distnav.field")
_REPEAT_S = 0.5  # the first repeat of a hello to a neighbour that has not answered (a level change goes at once)
_REPEAT_MAX_S = 4.0  # the longest wait between two repeats to it
_RUNNING = 2**31  # the level of a neighbour whose step messages came: in its rounds, above every depth


@dataclass(frozen=True)
class StartCheck:
    """What a hello must agree on, and how far the start waits.

    network_id : the network's fingerprint (0: not checked). values : the number of values of this node's step
    messages (0: not checked). levels : the start-up barrier's depth: this node's :func:`eccentricity` in the graph of
    who greets whom (every node within that many hops is every node; ``n - 1`` is always enough; 0: start as soon as
    the neighbours have answered). levels_if_missing : the depth once a neighbour never answered (``n - 1``; 0: keep
    ``levels``): without it, distances in the graph of the nodes that did start can exceed the eccentricity.
    """

    network_id: int = 0
    values: int = 0
    levels: int = 0
    levels_if_missing: int = 0


@dataclass
class Startup:
    """How the start went: the neighbours that never answered, and the strangers (neighbour → why refused)."""

    missing: list[int]
    strangers: dict[int, str] = field(default_factory=dict)
    seconds: float = 0.0
    #: the latest step of a neighbour's message that came during the start (-1: none; a node that comes after the
    #: others began sees their steps)
    latest_step: int = -1


def eccentricity(graph: Graph, node: int) -> int:
    """The most hops from ``node`` to a node of its connected part of ``graph`` (breadth-first): the start-up depth
    at which ``node`` knows that every node it can reach has heard its neighbours (:class:`StartCheck`)."""
    seen, frontier, hops = {node}, [node], 0
    while True:
        nxt = [int(j) for i in frontier for j in graph.neighbors(i) if int(j) not in seen]
        if not nxt:
            return hops
        seen.update(nxt)
        frontier, hops = list(dict.fromkeys(nxt)), hops + 1


def handshake(transport: Transport, peers: list[int] | None = None, check: StartCheck | None = None) -> Startup:
    """Greet ``peers`` (default: every peer of ``transport``) and wait as the module docstring says; returns who
    never answered and who was refused. Step messages that arrive meanwhile are kept for their step."""
    chk = check if check is not None else StartCheck()
    targets = sorted(transport.peers) if peers is None else sorted(peers)
    t0 = time.monotonic()
    end_answers, end_all = t0 + transport.options.start_timeout_s, t0 + 2 * transport.options.start_timeout_s
    heard = _Heard(depth=chk.levels)
    hellos = _Hellos(transport, chk, targets)
    level, sent = -1, -2
    while True:
        now = time.monotonic()
        answered = [p for p in targets if p in heard.levels]
        if level < 0 and (len(set(answered) | set(heard.strangers)) >= len(targets) or now >= end_answers):
            level = 0  # this node has heard its neighbours (or has waited for them long enough)
            if len(answered) < len(targets):  # one never answered: the graph of who started is not the full one
                heard.depth = max(heard.depth, chk.levels_if_missing)
        if level >= 0:
            level = min(heard.depth, 1 + min((heard.levels[p] for p in answered), default=heard.depth))
        if level >= heard.depth or now >= end_all:
            break
        if level != sent or hellos.depth != heard.depth:  # a new level (or depth) goes to every neighbour at once
            hellos.depth, sent = heard.depth, level
            hellos.send(targets, level, now)
        else:  # repeated only to the neighbours that have not answered yet, less and less often
            hellos.repeat([p for p in targets if p not in heard.levels and p not in heard.strangers], level, now)
        if transport.pull.poll(50):
            for frame in transport._frames():
                asker = _hear(transport, frame, chk, heard)
                if asker >= 0:
                    hellos.answer(asker, level)
    hellos.depth = heard.depth
    hellos.send(targets, heard.depth, time.monotonic())  # neighbours still rising see this node at the top
    strangers = heard.strangers
    transport.strangers.update(strangers)
    for p in strangers:
        transport.lost.setdefault(p, 0)
    missing = [p for p in targets if p not in heard.levels and p not in strangers]
    latest = max(transport._held, default=-1)
    for held in transport._held.values():  # a stranger's step messages are never used
        for p in strangers:
            held.pop(p, None)
    return Startup(missing, strangers, time.monotonic() - t0, latest)


def announce(transport: Transport, check: StartCheck) -> None:
    """One start-up hello at this node's top level to every neighbour (the highest depth it could have, ``n - 1``
    where ``check.levels_if_missing`` says so; its depth field ``check.levels``): a restarted node that rejoins a
    running network sends it first, so that a neighbour still in its start-up barrier (the restart's one-byte hello
    set its level back to -1) does not wait ``2 × start_timeout_s`` for it."""
    hellos = _Hellos(transport, check, sorted(transport.peers))
    hellos.send(sorted(transport.peers), max(check.levels, check.levels_if_missing), time.monotonic())


@dataclass
class _Heard:
    """What a node in its start-up has heard: its neighbours' levels (-1: still waiting for their own neighbours),
    the strangers (neighbour → why refused), and the barrier's depth (the largest its own and its hellos' carried)."""

    depth: int
    levels: dict[int, int] = field(default_factory=dict)
    strangers: dict[int, str] = field(default_factory=dict)


class _Hellos:
    """The start-up hellos a node sends: every level change to every neighbour; a repeat only to a neighbour that has
    not answered, after 0.5 s, then 1, 2, 4 s (a hello to a node not yet started waits in its queue and arrives when
    it starts; the repeats are for a process that took it and died); an answer, at most one per 0.5 s, to a neighbour
    that asks for one (its hello says it still waits, or it is a restarted process)."""

    def __init__(self, transport: Transport, chk: StartCheck, targets: list[int]) -> None:
        self.transport, self.chk, self.depth = transport, chk, chk.levels
        self.last = dict.fromkeys(targets, -math.inf)  # neighbour → when the latest hello to it was sent
        self.gap = dict.fromkeys(targets, _REPEAT_S)  # neighbour → the wait before its next repeat

    def send(self, peers: list[int], level: int, now: float) -> None:
        array = np.array([level, self.chk.network_id, self.chk.values, self.depth], np.int64)
        self.transport.post_many(peers, Kind.HELLO, 0, array)
        for p in peers:
            self.last[p] = now

    def repeat(self, peers: list[int], level: int, now: float) -> None:
        due = [p for p in peers if now >= self.last[p] + self.gap[p]]
        if due:
            self.send(due, level, now)
            for p in due:
                self.gap[p] = min(2 * self.gap[p], _REPEAT_MAX_S)

    def answer(self, peer: int, level: int) -> None:
        now = time.monotonic()
        if peer in self.last and now >= self.last[peer] + _REPEAT_S:  # a peer outside ``peers`` is not greeted
            self.send([peer], level, now)


def _hear(transport: Transport, frame: Any, chk: StartCheck, heard: _Heard) -> int:
    """One frame received during the start: a hello (its level and depth noted, or its sender refused as a stranger),
    or a step message of a neighbour already in its rounds (kept; that neighbour is at the top level). Returns the
    neighbour that asks for this node's hello (-1: none): one whose hello says it still waits for its neighbours, or a
    restarted process (its one-byte hello: its old level no longer holds, it waits again)."""
    levels, strangers = heard.levels, heard.strangers
    try:
        msg = decode(frame.buffer if transport.curve else frame, max_bytes=transport.options.max_message_bytes)
    except WireError as exc:
        transport._refuse("malformed", str(exc))
        return -1
    sender = msg.sender
    if sender not in transport.peers:
        transport._refuse("unknown_sender", f"message from node {sender}, not a peer of node {transport.me}")
        return -1
    if sender in strangers:
        transport.refused["another_network"] += 1
        return -1
    if msg.kind != Kind.HELLO:  # a neighbour's hellos come before its step messages (one ordered connection)
        transport._held.setdefault(msg.step, {})[sender] = msg
        if sender in levels:
            levels[sender] = _RUNNING  # in its rounds: at the top
            return -1
        strangers[sender] = _UNGREETED
        transport._refuse("another_network", f"node {transport.me}: refused node {sender}: {_UNGREETED}")
        return -1
    a = msg.array
    if a.dtype == np.uint8 and a.size == 1:  # a restarted process (--rejoin) while this node is still starting
        if sender in levels:
            levels[sender] = -1  # its old process's level is void: the barrier waits for the new one
        return sender
    why = _difference(a, chk)
    if why is not None:
        levels.pop(sender, None)  # an answer, then a refused hello: a stranger only (counted once)
        strangers[sender] = why
        transport._refuse("another_network", f"node {transport.me}: refused node {sender}'s hello: {why}")
        return -1
    levels[sender] = max(levels.get(sender, -1), int(a[0]))
    heard.depth = max(heard.depth, int(a[3]))  # a node that missed a neighbour: every node waits n - 1 levels
    return sender if int(a[0]) < 0 else -1


def rejoin(transport: Transport, *, invitation: bool = False) -> int | None:
    """Rejoin a running network (a restarted node): greet the neighbours (one-byte hellos) until one of them sends a
    step message, and return the latest step seen (the step to run next); messages of earlier steps are dropped.
    ``invitation``: wait instead for a neighbour's :attr:`Kind.INVITE` (node programs that run again from the start
    with a returning node), keep its array in :attr:`Transport.invited` and return its step; the messages of later
    steps are kept for them. None: the neighbours are still in their start-up (a start-up hello below its sender's
    top level came, no hello at a sender's top, and no step message within 0.5 s after it): the network has not begun,
    and the node starts as any other (:func:`handshake`, from step 0), its data in the answer. A hello at its
    sender's top level (level = depth, the last one it sends on leaving its barrier) means the sender runs: its
    first step message may come seconds later (an ADMM or UWB node's local work), and is waited for."""
    end = time.monotonic() + transport.options.start_timeout_s
    hello, next_send, seen, running = np.ones(1, np.uint8), 0.0, -1, False
    rising: dict[int, float] = {}  # neighbour → when its latest start-up hello, below its top, came (inf: at its top)
    while time.monotonic() < end:  # until a step message, then half a second more (queued old steps first)
        if time.monotonic() >= next_send:
            transport.post_many(sorted(transport.push), Kind.HELLO, 0, hello)  # counted as every frame sent
            next_send = time.monotonic() + 0.2
        if transport.pull.poll(50):
            for frame in transport._frames():
                msg = transport._checked(frame) if invitation else transport._checked_hello(frame)
                if msg is None or msg.kind == Kind.BYE:  # a bye: that run is over
                    continue
                if msg.kind == Kind.HELLO:
                    _note_rising(rising, msg.sender, msg.array)
                    continue
                running = True
                if not invitation:
                    seen = max(seen, msg.step)
                elif msg.kind == Kind.INVITE:
                    transport.invited, seen, end = msg.array, msg.step, 0.0
                else:
                    transport._held.setdefault(msg.step, {})[msg.sender] = msg
        if not running and _starting(rising) and time.monotonic() >= min(rising.values()) + _REPEAT_S:
            return None
        if seen >= 0:
            end = min(end, time.monotonic() + 0.5) if end - time.monotonic() > 0.5 else end
            if time.monotonic() >= end:
                break
    if seen < 0:
        what = "invited it back" if invitation else "answered"
        raise ExchangeError(f"node {transport.me}: no neighbour {what} within {transport.options.start_timeout_s} s")
    for k in [k for k in transport._held if k < seen]:
        del transport._held[k]
    return seen


def _note_rising(rising: dict[int, float], sender: int, a: np.ndarray) -> None:
    """A start-up hello heard by :func:`rejoin`: below its sender's top level (still in its barrier), noted with its
    time; at the top (leaving its barrier, into its rounds), noted as ``inf``."""
    if a.dtype != np.int64 or a.size != 4:
        return
    if int(a[0]) < int(a[3]):
        if rising.get(sender, math.inf) == math.inf:
            rising[sender] = time.monotonic()
    else:
        rising[sender] = math.inf


def _starting(rising: dict[int, float]) -> bool:
    """The network has not begun: a neighbour is in its barrier and none has left it (a neighbour at its top runs,
    though another still rises: its step messages would come to :func:`handshake` from a sender that never greeted
    there, refused as another network's)."""
    return bool(rising) and math.inf not in rising.values()


_UNGREETED = (
    "it sent step messages before any start-up hello of this network (a run that began without this node: start it "
    "with --rejoin; or another network on these ports)"
)


def _difference(a: np.ndarray, chk: StartCheck) -> str | None:
    """Why a start-up hello's payload does not belong to this node's network (None: it does)."""
    if a.dtype != np.int64 or a.size != 4:
        return f"a start-up hello of another format ({a.dtype}, {a.size} values: another distnav version?)"
    _, network_id, values, _ = (int(v) for v in a)
    if chk.network_id and network_id != chk.network_id:
        return (
            f"it runs another network description (fingerprint {network_id & 0xFFFFFFFF:08x}, this node's "
            f"{chk.network_id & 0xFFFFFFFF:08x}): a different file, or another network on these ports"
        )
    if chk.values and values and values != chk.values:
        return f"its messages carry {values} values, this node's {chk.values} (a data file with values missing?)"
    return None
