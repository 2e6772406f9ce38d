"""The field runtime's exchange: every node its own OS process, messages over ZeroMQ (the ``field`` extra).

* :mod:`.wire` — the versioned, language-neutral message format (no pickle) and its checks;
* :mod:`.transport` — sockets, deadlines, refusals, lost peers, CURVE admission, real byte counts;
* :mod:`.startup` — the start-up hellos: the network's fingerprint checked, every node into step 0 together;
* :mod:`.exchange` — :class:`FieldExchange`, the lock-step backend the algorithms run on unchanged.

pyzmq is imported only when a transport is made, so ``import distnav.exchange.field`` works without it.
"""

from __future__ import annotations

from distnav.exchange.field.exchange import FieldExchange
from distnav.exchange.field.transport import CurveKeys, Peer, Transport, TransportOptions
from distnav.exchange.field.wire import Kind, WireError, decode, encode

__all__ = [
    "FieldExchange",
    "Transport",
    "TransportOptions",
    "Peer",
    "CurveKeys",
    "Kind",
    "WireError",
    "encode",
    "decode",
]
