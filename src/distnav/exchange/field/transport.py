"""The field runtime's transport: ZeroMQ sockets between node processes, with deadlines, checks and real byte counts.

Each node binds one ``PULL`` socket on its own address and connects one ``PUSH`` socket to every peer it talks to.
A *step* is one collective call of the run (a consensus round, an edge round, a reduction, a gather); every node
counts steps alike, so a message is identified by ``(sender, step)``. :meth:`Transport.collect` waits for one
message per expected sender of a step until the deadline; a message that misses it is lost (the exchange's
``delivered`` mask shows it). A message of a future step is kept for later (a faster neighbour); one of a past step
is refused: as a *replay* when that sender's step was already accepted, else as *late*.

Refusals (unknown sender or key, malformed, oversize, replayed, late, out of sequence) are logged and counted in
:attr:`Transport.refused`; the node keeps running. With CURVE (:class:`CurveKeys`) the ZAP handler admits only the
public keys of the description, and a message's claimed sender must be the owner of the key it arrived under.

A peer that sends nothing for ``miss_limit`` consecutive steps is declared lost (a late message proves its sender
alive and restarts the count: a node that waited for a dead neighbour delays its own messages, and its neighbours
must not take it for dead) (:attr:`Transport.lost`, with the
step): with a deadline ``d`` a dead neighbour is noticed within ``miss_limit × d`` seconds of its last message, and
the transport stops waiting for it. A lost peer whose messages arrive again (a restarted node) is readmitted.
"""

from __future__ import annotations

import heapq
import logging
import time
from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from distnav._optional import require
from distnav.errors import ExchangeError
from distnav.exchange.field.wire import KIND_OFFSET, Kind, Message, WireError, decode, encode, expected

__all__ = ["CurveKeys", "Peer", "StepTransport", "Transport", "TransportOptions"]

LOG = logging.getLogger("distnav.field")
#: the senders a step waits for; an array shaped and typed as the step's messages are expected (or None)
Senders = list[int] | np.ndarray
Like = np.ndarray | None
#: longest single blocking receive (ms): a step waits in slices of this, re-checking the clock between them
_SLICE_MS = 100

#: The wire counters every transport keeps (attributes of the same names) and reports in :meth:`wire_counts`.
WIRE_COUNTERS = ("bytes_sent", "bytes_received", "frames_sent", "frames_received", "send_failures")


def _zmq() -> Any:
    return require("zmq", "field")


@dataclass(frozen=True)
class Peer:
    """Another node process: its node id, ``tcp://host:port`` and (with CURVE) its Z85 public key."""

    node: int
    address: str
    public_key: bytes | None = None


@dataclass(frozen=True)
class CurveKeys:
    """This node's CURVE key pair (Z85, as written by ``zmq.curve_keypair``)."""

    public: bytes
    secret: bytes


@dataclass(frozen=True)
class TransportOptions:
    """Timing and limits of a node's transport (documented defaults; validated once).

    deadline_s : how long a step waits for its messages before the missing ones count as lost.
    miss_limit : consecutive steps without a message after which a peer is declared lost.
    start_timeout_s : how long the start-up handshake waits for every peer's hello.
    max_message_bytes : larger frames are refused unread.
    latency_max_s : tests and benchmarks: every received message is held back a further Uniform(0, latency_max_s)
        seconds (drawn from ``latency_seed``) before the step may use it, as if the network had delayed it.
    """

    deadline_s: float = 2.0
    miss_limit: int = 3
    start_timeout_s: float = 60.0
    max_message_bytes: int = 16 * 1024 * 1024
    latency_max_s: float = 0.0
    latency_seed: int = 0

    def __post_init__(self) -> None:
        if not self.latency_max_s >= 0:
            raise ExchangeError(f"latency_max_s must be >= 0, got {self.latency_max_s}")
        if not self.deadline_s > 0:
            raise ExchangeError(f"deadline_s must be > 0, got {self.deadline_s}")
        if self.miss_limit < 1:
            raise ExchangeError(f"miss_limit must be >= 1, got {self.miss_limit}")
        if not self.start_timeout_s > 0:
            raise ExchangeError(f"start_timeout_s must be > 0, got {self.start_timeout_s}")
        if self.max_message_bytes < 64:
            raise ExchangeError(f"max_message_bytes must be >= 64, got {self.max_message_bytes}")


class StepTransport(Protocol):
    """What the field exchange and the spanning-tree operations need of a node's transport: :class:`Transport`, or a
    view of it on the nodes that remain after a loss (:class:`~distnav.exchange.field.survivors.SubnetTransport`)."""

    me: int
    peers: dict[int, Peer]
    options: TransportOptions

    @property
    def lost(self) -> dict[int, int]: ...

    @property
    def heard(self) -> dict[int, int]: ...

    @property
    def greeted(self) -> dict[int, int]: ...

    def post(self, peer: int, kind: Kind, step: int, array: np.ndarray) -> None: ...

    def readmit(self, peer: int, step: int) -> None: ...

    def post_many(self, peers: list[int], kind: Kind, step: int, array: np.ndarray) -> None: ...

    def collect(
        self, kind: Kind, step: int, senders: Senders, *, deadline_s: float | None = None, like: Like = None
    ) -> dict[int, np.ndarray]: ...

    def _refuse(self, reason: str, text: str) -> Message | None: ...


@dataclass
class _Admission:
    """ZAP credentials check: only the listed public keys connect; refusals are logged and counted."""

    allowed: dict[bytes, int]
    refused: Counter[str] = field(default_factory=Counter)

    def callback(self, domain: str, key: bytes) -> bool:
        zmq = _zmq()
        z85 = zmq.utils.z85.encode(key) if len(key) == 32 else key
        if z85 in self.allowed:
            return True
        self.refused["unknown_key"] += 1
        LOG.warning("refused a connection from unknown CURVE key %s", z85.decode(errors="replace"))
        return False


class Transport:
    """One node's sockets (see the module docstring)."""

    def __init__(
        self,
        me: int,
        address: str,
        peers: list[Peer],
        *,
        options: TransportOptions | None = None,
        keys: CurveKeys | None = None,
        context: Any = None,
    ) -> None:
        zmq = _zmq()
        self._zmq = zmq
        self.me = int(me)
        self.options = options if options is not None else TransportOptions()
        self.peers = {p.node: p for p in peers}
        if self.me in self.peers:
            raise ExchangeError(f"node {me} lists itself as a peer")
        self.curve = keys is not None
        if self.curve and any(p.public_key is None for p in peers):
            missing = sorted(p.node for p in peers if p.public_key is None)
            raise ExchangeError(f"CURVE needs every peer's public key; missing for nodes {missing}")
        self._owns_context = context is None  # threads of one process may share one (inproc:// addresses)
        self.ctx = zmq.Context() if context is None else context
        self.refused: Counter[str] = Counter()
        self._auth: Any = None
        self._admission: _Admission | None = None
        self._key_owner: dict[str, int] = {}
        self.pull = self.ctx.socket(zmq.PULL)
        self.pull.linger = 0
        if keys is not None:
            from zmq.auth.thread import ThreadAuthenticator

            allowed = {p.public_key: p.node for p in peers if p.public_key is not None}
            self._key_owner = {k.decode(): n for k, n in allowed.items()}
            self._admission = _Admission(allowed)
            self._auth = ThreadAuthenticator(self.ctx, log=LOG.getChild("zap"))
            self._auth.start()
            self._auth.configure_curve_callback(domain="*", credentials_provider=self._admission)
            self.pull.curve_secretkey = keys.secret
            self.pull.curve_publickey = keys.public
            self.pull.curve_server = True
        try:
            self.pull.bind(address)
        except zmq.ZMQError as exc:
            self._close_sockets()
            raise ExchangeError(_bind_failure(self.me, address, exc)) from None
        self._rcvtimeo = -1  # the PULL socket's receive timeout (ms) as last set (:meth:`_recv_within`)
        self.push: dict[int, Any] = {}
        for p in peers:
            s = self.ctx.socket(zmq.PUSH)
            s.linger = 2000  # queued messages still leave after close (a node that finished)
            s.sndhwm = 10_000
            if keys is not None:
                s.curve_secretkey = keys.secret
                s.curve_publickey = keys.public
                s.curve_serverkey = p.public_key
            s.connect(p.address)
            self.push[p.node] = s
        self._held: dict[int, dict[int, Message]] = {}  # step → sender → message (arrived early)
        self._last_step = dict.fromkeys(self.peers, -1)
        self._missed = dict.fromkeys(self.peers, 0)
        self.lost: dict[int, int] = {}  # peer → step at which it was declared lost
        self.readmitted: dict[int, int] = {}
        self.heard = dict.fromkeys(self.peers, 0)  # checked messages per peer (any step or kind): signs of life
        self.greeted: dict[int, int] = {}  # peer → the step at which its latest hello during the run came
        self.strangers: dict[int, str] = {}  # peer → why its start-up hello was refused (:mod:`.startup`)
        self.invited: np.ndarray | None = None  # the invitation a restarted node was given (:func:`.startup.rejoin`)
        #: a lost peer's hello readmits it at once (consensus); False: a node program that takes a returning node
        #: back by running again with it (ADMM, the CKF) waits for it only from that run on
        self.readmit_on_hello = True
        self.bytes_sent = 0
        self.bytes_received = 0
        self.frames_sent = 0
        self.frames_received = 0
        self.send_failures = 0
        self._kind_bytes: Counter[int] = Counter()  # wire kind → bytes sent (:meth:`bytes_by_kind`)
        self._delayed: list[tuple[float, int, Message]] = []  # (release time, arrival number, message)
        self._latency = np.random.default_rng(self.options.latency_seed + 7919 * self.me)

    # ------------------------------------------------------------- sending
    def post(self, peer: int, kind: Kind, step: int, array: np.ndarray) -> None:
        """Queue one message to ``peer`` without blocking (a full queue to a dead peer drops it, counted)."""
        self._send(peer, encode(kind, self.me, step, array))

    def post_many(self, peers: list[int], kind: Kind, step: int, array: np.ndarray) -> None:
        """:meth:`post` of the same message to every peer of ``peers``, encoded once."""
        frame = encode(kind, self.me, step, array)
        push, again, flags, copy, sent = self.push, self._zmq.Again, self._zmq.NOBLOCK, len(frame) < 65536, 0
        for peer in peers:  # _send inlined: a consensus round sends one frame per neighbour
            try:
                push[peer].send(frame, flags, copy)  # positional: cheaper than keywords per frame
            except again:
                self.send_failures += 1
                continue
            sent += 1
        self.bytes_sent += sent * len(frame)
        self.frames_sent += sent
        self._kind_bytes[kind] += sent * len(frame)

    def _send(self, peer: int, frame: bytes) -> None:
        try:
            self.push[peer].send(frame, self._zmq.NOBLOCK, len(frame) < 65536)
        except self._zmq.Again:
            self.send_failures += 1
            return
        self.bytes_sent += len(frame)
        self.frames_sent += 1
        self._kind_bytes[frame[KIND_OFFSET]] += len(frame)

    # ------------------------------------------------------------- receiving
    def collect(
        self, kind: Kind, step: int, senders: Senders, *, deadline_s: float | None = None, like: Like = None
    ) -> dict[int, np.ndarray]:
        """The arrays of ``step`` from ``senders`` that arrive before the deadline (peers declared lost are not
        waited for, but still accepted if they arrive).

        Frames are taken one at a time with a blocking receive (no poll call, no exception per empty socket), at
        most :data:`_SLICE_MS` at a time or up to the deadline or the next delayed message's release; at the deadline
        whatever has already arrived is still taken. ``like``: the messages are expected with this array's dtype and
        shape (a consensus or edge round), and a frame that carries exactly the expected header is accepted after
        one comparison (:func:`~.wire.expected`; :meth:`_collect_expected`)."""
        got: dict[int, np.ndarray] = {}
        held = self._held.pop(step, None)
        if held:
            for msg in held.values():
                self._accept(msg, kind, step, got)
        lost = self.lost
        waiting = {int(s) for s in senders if s not in got and s not in lost}
        if not waiting and (lost or self._delayed):  # nobody to wait for: still read a lost peer's return
            self._drain(kind, step, got)
            self._release(kind, step, got)
        end = time.monotonic() + (self.options.deadline_s if deadline_s is None else deadline_s)
        if waiting and like is not None and not self.curve and not self._delayed and not self.options.latency_max_s:
            self._collect_expected(kind, step, waiting, like, got, end)
        while waiting:
            now = time.monotonic()
            if self._delayed:
                self._release(kind, step, got)
                waiting.difference_update(got)
                if not waiting:
                    break
            if now >= end:
                self._drain(kind, step, got)  # what arrived by the deadline still counts
                break
            until = min(end, self._delayed[0][0]) if self._delayed else end
            frame = self._recv_within(until - now)
            if frame is not None:
                sender = self._take(frame, kind, step, got)
                if sender in got:
                    waiting.discard(sender)
        self._note_missing(senders, got, step)
        return got

    def _collect_expected(
        self, kind: Kind, step: int, waiting: set[int], like: np.ndarray, got: dict[int, np.ndarray], end: float
    ) -> None:
        """:meth:`collect`'s loop for messages of a known header: a frame whose header is the one expected of a
        sender still awaited (kind, step, sender, dtype, shape, length, version: every check of
        :func:`~.wire.decode`; not a replay, as that sender's message of this step has not come yet) and whose size
        is the expected one is taken as an array at once; any other frame is checked and routed as usual
        (:meth:`_take`). Returns when every sender's message is in, or at the deadline (what has arrived by then is
        taken by :meth:`collect`)."""
        exp = expected(kind, step, waiting, like)
        if exp is None or exp.size > self.options.max_message_bytes:
            return
        heads, n_head, size, dtype, count = exp
        shape = like.shape if like.ndim != 1 else None
        last, heard, pull, again, monotonic = self._last_step, self.heard, self.pull, self._zmq.Again, time.monotonic
        while waiting:
            left = end - monotonic()
            if left <= 0:
                return
            ms = min(_SLICE_MS, int(left * 1000) + 1)
            if ms != self._rcvtimeo:
                pull.setsockopt(self._zmq.RCVTIMEO, ms)
                self._rcvtimeo = ms
            try:
                frame = pull.recv(0, True)
            except again:
                continue
            self.frames_received += 1
            self.bytes_received += len(frame)
            sender = heads.pop(frame[:n_head], -1) if len(frame) == size else -1
            if sender not in waiting:  # not the expected header (a replay, another step or kind, malformed, ...)
                sender = self._take(frame, kind, step, got)
                if sender in got:
                    waiting.discard(sender)
                continue
            heard[sender] += 1
            last[sender] = step
            arr = np.frombuffer(frame, dtype, count, n_head)  # positional: keywords cost more than the call
            got[sender] = arr if shape is None else arr.reshape(shape)
            waiting.discard(sender)

    def _recv_within(self, seconds: float) -> Any:
        """One frame, waiting at most ``seconds`` (None when none came); the socket's receive timeout is changed only
        when less than one slice is left, so a step usually costs no socket option call."""
        ms = min(_SLICE_MS, int(seconds * 1000) + 1)
        if ms != self._rcvtimeo:
            self.pull.setsockopt(self._zmq.RCVTIMEO, ms)
            self._rcvtimeo = ms
        try:
            frame = self.pull.recv(0, not self.curve)
        except self._zmq.Again:
            return None
        self.frames_received += 1
        self.bytes_received += len(frame)
        return frame

    def _frames(self) -> Iterator[Any]:
        """Every frame waiting on the socket now (counted as received bytes)."""
        zmq = self._zmq
        while True:
            try:
                frame = self.pull.recv(zmq.NOBLOCK, not self.curve)
            except zmq.Again:
                return
            self.frames_received += 1
            self.bytes_received += len(frame)
            yield frame

    def receive_any(self, timeout_s: float) -> list[Message]:
        """Every message that has arrived, waiting at most ``timeout_s`` for the first: checked (sender, size,
        format, CURVE key; refusals counted) but not matched to a step — for nodes that run without steps (the
        asynchronous mode, :mod:`distnav.commands.field_async`)."""
        out: list[Message] = []
        if not self.pull.poll(max(0, int(timeout_s * 1000))):
            return out
        for frame in self._frames():
            msg = self._checked(frame)
            if msg is not None and msg.kind != Kind.HELLO:
                out.append(msg)
        return out

    def _drain(self, kind: Kind, step: int, got: dict[int, np.ndarray]) -> None:
        for frame in self._frames():
            self._take(frame, kind, step, got)

    def _take(self, frame: Any, kind: Kind, step: int, got: dict[int, np.ndarray]) -> int:
        """Check one received frame and hand it on (to ``got``, the held messages of a later step, or the delayed
        ones); returns its sender (-1 when refused)."""
        msg = self._checked(frame)
        if msg is None:
            return -1
        if msg.kind == Kind.HELLO:  # a restarted process's hello is one byte (a start-up one: :mod:`.startup`)
            self._hello(msg.sender, step, restarted=msg.array.dtype == np.uint8 and msg.array.size == 1)
            return -1
        if self.options.latency_max_s > 0:  # injected latency: usable only from its release time on
            delay = float(self._latency.uniform(0.0, self.options.latency_max_s))
            heapq.heappush(self._delayed, (time.monotonic() + delay, self.frames_received, msg))
            return -1
        sender = msg.sender
        if msg.step == step and msg.kind == kind and sender not in self.lost:  # the usual case, :meth:`_accept`'s
            self._last_step[sender] = step
            got[sender] = msg.array
            return sender
        self._route(msg, kind, step, got)
        return sender

    def _release(self, kind: Kind, step: int, got: dict[int, np.ndarray]) -> None:
        """Hand on the delayed messages whose release time has come (injected latency only)."""
        now = time.monotonic()
        while self._delayed and self._delayed[0][0] <= now:
            self._route(heapq.heappop(self._delayed)[2], kind, step, got)

    def _route(self, msg: Message, kind: Kind, step: int, got: dict[int, np.ndarray]) -> None:
        if msg.step > step:
            self._held.setdefault(msg.step, {})[msg.sender] = msg
        else:
            self._accept(msg, kind, step, got)

    def _hello(self, sender: int, step: int, *, restarted: bool) -> None:
        """A hello during the run: a repeated one of the start-up, or a restarted peer (lost, or its process new)
        asking to rejoin: readmitted, its steps counted afresh, waited for again from the next step on (and noted in
        :attr:`greeted`, for node programs that take a returning node back by running again with it)."""
        if restarted:  # a restarted process's hello (one byte; the start-up's is empty)
            self.greeted[sender] = step
        if sender in self.lost and self.readmit_on_hello:
            self.readmit(sender, step)

    def readmit(self, peer: int, step: int) -> None:
        """Take a restarted peer back: no longer lost, its steps counted afresh, waited for from ``step`` on."""
        self.lost.pop(peer, None)
        self.readmitted[peer] = step
        self._last_step[peer] = -1
        self._missed[peer] = 0
        LOG.warning("node %d: node %d rejoins at step %d", self.me, peer, step)

    def farewell(self, step: int) -> dict[str, int]:
        """Send a bye to every neighbour (the step at which this node declared it lost, else -1) and return the
        neighbours whose byes by now say they dropped this node (neighbour → step); one not yet finished is not
        waited for. A node stopped past the deadlines and resumed cannot tell otherwise that its answer lacks them."""
        for p in self.peers:
            self.post(p, Kind.BYE, step, np.array([self.lost.get(p, -1)], np.int64))
        byes = {s: m for held in self._held.values() for s, m in held.items() if m.kind == Kind.BYE}
        for frame in self._frames():
            msg = self._checked(frame)
            if msg is not None and msg.kind == Kind.BYE:
                byes[msg.sender] = msg
        return {str(s): int(m.array[0]) for s, m in sorted(byes.items()) if m.array.size == 1 and m.array[0] >= 0}

    def _checked(self, frame: Any) -> Message | None:
        try:
            msg = decode(frame.buffer if self.curve else frame, max_bytes=self.options.max_message_bytes)
        except WireError as exc:
            reason = "oversize" if str(exc).startswith("oversize") else "malformed"
            return self._refuse(reason, str(exc))
        if msg.sender not in self.peers:
            return self._refuse("unknown_sender", f"message from node {msg.sender}, not a peer of node {self.me}")
        if msg.sender in self.strangers:  # refused at start-up (another network, :mod:`.startup`): counted only
            self.refused["another_network"] += 1
            return None
        if msg.kind == Kind.HELLO:
            return msg
        if self.curve:
            owner = self._key_owner.get(frame.get("User-Id"))
            if owner != msg.sender:
                return self._refuse(
                    "forged_sender", f"message claims node {msg.sender} but came under the key of node {owner}"
                )
        self.heard[msg.sender] += 1  # a checked message of its own: its sender is alive, whatever its step or kind
        if msg.step <= self._last_step[msg.sender]:
            return self._refuse(
                "replay", f"replay of step {msg.step} from node {msg.sender} (already at {self._last_step[msg.sender]})"
            )
        return msg

    def _accept(self, msg: Message, kind: Kind, step: int, got: dict[int, np.ndarray]) -> None:
        if msg.step < step:  # lost for its step, but its sender is alive: no step towards declaring it lost
            self._missed[msg.sender] = -1
            self._refuse("late", f"late message of step {msg.step} from node {msg.sender} (now at step {step})")
            return
        if msg.kind != kind:
            self._refuse(
                "out_of_sequence", f"node {msg.sender} sent {msg.kind.name} at step {step}, expected {kind.name}"
            )
            return
        self._last_step[msg.sender] = msg.step
        if msg.sender in self.lost:
            self.readmitted[msg.sender] = step
            del self.lost[msg.sender]
            LOG.warning("node %d: node %d is back at step %d", self.me, msg.sender, step)
        got[msg.sender] = msg.array

    def _note_missing(self, want: list[int] | np.ndarray, got: dict[int, np.ndarray], step: int) -> None:
        for s in map(int, want):
            if s in got:
                self._missed[s] = 0
                continue
            self._missed[s] += 1
            if s not in self.lost and self._missed[s] >= self.options.miss_limit:
                self.lost[s] = step
                LOG.warning(
                    "node %d: node %d lost at step %d (%d steps without a message)", self.me, s, step, self._missed[s]
                )

    def _refuse(self, reason: str, text: str) -> Message | None:
        """Count and log a refused message; returns None (what the checks hand on instead of the message)."""
        self.refused[reason] += 1
        LOG.warning("node %d refused a message: %s", self.me, text)
        return None

    # ------------------------------------------------------------- start-up, shutdown
    def _checked_hello(self, frame: Any) -> Message | None:
        try:
            msg = decode(frame.buffer if self.curve else frame, max_bytes=self.options.max_message_bytes)
        except WireError as exc:
            return self._refuse("malformed", str(exc))
        if msg.sender not in self.peers:
            return self._refuse("unknown_sender", f"hello from node {msg.sender}, not a peer of node {self.me}")
        if msg.kind != Kind.HELLO:  # a fast peer already in step 0: keep it
            self._held.setdefault(msg.step, {})[msg.sender] = msg
            return msg
        return msg

    def wire_counts(self) -> dict[str, int]:
        """Real bytes and frames this node put on and took off the wire, and the sends that could not be queued."""
        return {name: int(getattr(self, name)) for name in WIRE_COUNTERS}

    def bytes_by_kind(self) -> dict[str, int]:
        """:attr:`bytes_sent` by wire kind (``hello``, ``column``, ``edge``, ...)."""
        return {Kind(k).name.lower(): int(v) for k, v in sorted(self._kind_bytes.items())}

    @property
    def refusals(self) -> int:
        total = sum(self.refused.values())
        return total + (sum(self._admission.refused.values()) if self._admission is not None else 0)

    def refusal_counts(self) -> dict[str, int]:
        out = dict(self.refused)
        if self._admission is not None:
            out.update(self._admission.refused)
        return out

    def close(self) -> None:
        for s in self.push.values():
            s.close()
        self._close_sockets()

    def _close_sockets(self) -> None:
        self.pull.close()
        if self._auth is not None:
            self._auth.stop()
        if self._owns_context:
            self.ctx.term()


def _bind_failure(me: int, address: str, exc: Any) -> str:
    """Why node ``me`` cannot listen on its own address, and the likely cause."""
    text = f"node {me}: cannot listen on its address {address} ({exc.strerror.split(' (addr=')[0]})"
    if "in use" in exc.strerror:
        return f"{text}: another process holds that port (node {me} started twice, or another program)"
    if "assign" in exc.strerror:
        return f"{text}: this host does not have that address (is node {me} of the description on another host?)"
    return text
