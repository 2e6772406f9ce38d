"""The field runtime's wire format: one message = one ZeroMQ frame, a fixed little-endian header then raw bytes.

Versioned and language-neutral (no pickle): any program that can pack a C struct can talk to a distnav node.

========  =====  ==========================================================================================
offset    type   field
========  =====  ==========================================================================================
0         4s     magic ``b"DNF1"``
4         u1     version (:data:`VERSION`)
5         u1     kind (:class:`Kind`: a consensus column, an edge value, a reduction, a gather, a hello, tree)
6         u1     dtype code (:data:`DTYPES`: 1 = float64, 2 = float32, 3 = int64, 4 = uint8)
7         u1     ndim (0…4)
8         u4     sender node id
12        u8     step (every collective call of the run is one step, counted from 0 by every node alike)
20        u8     payload length in bytes
28        ndim×u4  shape
…         bytes  payload: the array in C order, little-endian
========  =====  ==========================================================================================

:func:`decode` checks every field against what the receiver expects before the payload is used (length consistent
with dtype × shape, size limit, known kind and dtype) and raises :class:`WireError` naming the problem; the
exchange logs and counts such refusals and keeps running.
"""

from __future__ import annotations

import enum
import math
import struct
import sys
from typing import NamedTuple

import numpy as np

from distnav.errors import ExchangeError

__all__ = [
    "MAGIC",
    "VERSION",
    "DTYPES",
    "Kind",
    "Message",
    "WireError",
    "encode",
    "decode",
    "HEADER",
    "KIND_OFFSET",
    "Expected",
]

MAGIC = b"DNF1"
VERSION = 1
HEADER = struct.Struct("<4sBBBBIQQ")
KIND_OFFSET = 5  # the header's kind byte, after the 4-byte magic and the version (what a counter by kind reads)
_DIM = struct.Struct("<I")
MAX_NDIM = 4
#: dtype code → numpy dtype (little-endian on the wire whatever the host)
DTYPES: dict[int, np.dtype] = {
    1: np.dtype("<f8"),
    2: np.dtype("<f4"),
    3: np.dtype("<i8"),
    4: np.dtype("u1"),
}


class Kind(enum.IntEnum):
    """What a message carries."""

    COLUMN = 1  #: a node's value for a consensus round / broadcast (the same to every neighbour)
    EDGE = 2  #: a value for one directed edge (``Exchange.send``)
    REDUCE = 3  #: a contribution to an all-reduce (monitoring)
    GATHER = 4  #: a node's rows for gather_nodes (results)
    HELLO = 5  #: "I am up" (start-up and rejoin)
    BYE = 6  #: "I am done" (a neighbour that finished is not a lost one)
    TREE_UP = 7  #: a subtree's rows of a global operation, child → parent (:mod:`.tree`)
    TREE_DOWN = 8  #: every node's rows of a global operation, parent → child (:mod:`.tree`)
    INVITE = 9  #: to a restarted node: the step of the re-run with it, the failed step, the re-run's nodes


class WireError(ExchangeError):
    """A received message that is not a valid distnav field message."""


class Message(NamedTuple):
    """One received message (a named tuple: made once per message, cheaply)."""

    kind: Kind
    sender: int
    step: int
    array: np.ndarray


_CODE = {(dt.kind, dt.itemsize): c for c, dt in DTYPES.items()}  # (kind, itemsize) → dtype code
_NATIVE = {c: dt.newbyteorder("=") for c, dt in DTYPES.items()}  # the received array's dtype in this host's order
_LITTLE = sys.byteorder == "little"  # the wire's order: received arrays are used as they are, no byte swap
_KINDS = {int(k): k for k in Kind}
#: header and shape of an ``ndim``-dimensional array in one struct (one pack / unpack call per message)
_HEAD_SHAPE = [struct.Struct(HEADER.format + "I" * k) for k in range(MAX_NDIM + 1)]


def encode(kind: Kind, sender: int, step: int, array: np.ndarray) -> bytes:
    """One frame: header, shape, payload (C order, little-endian)."""
    a = array if type(array) is np.ndarray else np.asarray(array)
    code = _CODE.get((a.dtype.kind, a.dtype.itemsize))
    if code is None:
        raise WireError(f"cannot send dtype {a.dtype} (float64, float32, int64 or uint8 only)")
    if a.ndim > MAX_NDIM:
        raise WireError(f"cannot send an array of {a.ndim} dimensions (at most {MAX_NDIM})")
    wire = DTYPES[code]
    if a.dtype != wire or not a.flags.c_contiguous:
        a = np.ascontiguousarray(a, dtype=wire)
    payload = a.tobytes()
    head = _HEAD_SHAPE[a.ndim].pack(
        MAGIC, VERSION, int(kind), code, a.ndim, int(sender), int(step), len(payload), *a.shape
    )
    return head + payload


def decode(frame: bytes | memoryview, *, max_bytes: int) -> Message:
    """Parse and check one frame (see the module docstring); :class:`WireError` names what is wrong."""
    size = len(frame)
    if size > max_bytes:
        raise WireError(f"oversize message: {size} bytes (limit {max_bytes})")
    if size < HEADER.size:
        raise WireError(f"malformed message: {size} bytes, shorter than the {HEADER.size}-byte header")
    ndim = frame[7]  # header and shape in one unpack when ndim is valid (else the header alone, for the error)
    fields = (_HEAD_SHAPE[ndim] if ndim <= MAX_NDIM and size >= HEADER.size + 4 * ndim else HEADER).unpack_from(frame)
    magic, version, kind, code, ndim, sender, step, length = fields[:8]
    if magic != MAGIC:
        raise WireError(f"malformed message: magic {bytes(magic)!r}, expected {MAGIC!r}")
    if version != VERSION:
        raise WireError(f"message of wire version {version}; this node speaks version {VERSION}")
    kind_ = _KINDS.get(kind)
    if kind_ is None:
        raise WireError(f"malformed message: unknown kind {kind}")
    dtype = DTYPES.get(code)
    if dtype is None:
        raise WireError(f"malformed message: unknown dtype code {code}")
    if ndim > MAX_NDIM:
        raise WireError(f"malformed message: ndim {ndim} > {MAX_NDIM}")
    start = HEADER.size + ndim * 4
    if size != start + length:
        raise WireError(f"malformed message: {size} bytes, the header announces {start + length}")
    shape = fields[8:]
    count = shape[0] if ndim == 1 else math.prod(shape)
    if count * dtype.itemsize != length:
        raise WireError(f"malformed message: shape {shape} of {dtype} is not {length} bytes")
    arr = np.frombuffer(frame, dtype, count, start)  # positional: keywords cost more than the call here
    if ndim != 1:
        arr = arr.reshape(shape)
    if not _LITTLE:
        arr = arr.astype(_NATIVE[code])
    return Message(kind_, sender, step, arr)


class Expected(NamedTuple):
    """The exact header each sender's message of one step must carry, when its kind, dtype and shape are known
    (a consensus or edge round: the same as the array this node sends): ``heads`` maps the header bytes (magic,
    version, kind, dtype code, ndim, sender, step, length, shape) to the sender. A frame of ``size`` bytes whose
    first ``head_bytes`` are a key of ``heads`` passes every check of :func:`decode` (and names its sender and step)
    with one slice and one dict look-up; any other frame goes through :func:`decode` and is refused or routed as
    usual."""

    heads: dict[bytes, int]
    head_bytes: int
    size: int
    dtype: np.dtype
    items: int


def expected(kind: Kind, step: int, senders: set[int], like: np.ndarray) -> Expected | None:
    """:class:`Expected` of ``step``'s messages from ``senders`` shaped as ``like`` (None if ``like``'s dtype or
    rank cannot be sent). The headers are made of a per-sender prefix (magic … sender, made once) and this step's
    suffix (step, length, shape)."""
    code = _CODE.get((like.dtype.kind, like.dtype.itemsize))
    if code is None or like.ndim > MAX_NDIM or not _LITTLE:  # a big-endian host decodes and swaps
        return None
    dtype, ndim = DTYPES[code], like.ndim
    length = like.size * dtype.itemsize
    suffix = _TAIL[ndim].pack(step, length, *like.shape)
    prefixes = _PREFIXES.get((kind, code, ndim))
    if prefixes is None:
        prefixes = _PREFIXES[kind, code, ndim] = {}
    heads = {}
    for s in senders:
        head = prefixes.get(s)
        if head is None:
            head = prefixes[s] = _PREFIX.pack(MAGIC, VERSION, int(kind), code, ndim, s)
        heads[head + suffix] = s
    n_head = HEADER.size + 4 * ndim
    return Expected(heads, n_head, n_head + length, dtype, like.size)


_PREFIX = struct.Struct("<4sBBBBI")  # the header up to the sender (its first 12 bytes)
_TAIL = [struct.Struct("<QQ" + "I" * k) for k in range(MAX_NDIM + 1)]  # step, length, shape
_PREFIXES: dict[tuple[Kind, int, int], dict[int, bytes]] = {}  # (kind, dtype code, ndim) → sender → prefix
