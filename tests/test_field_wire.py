"""The field wire format and the transport's refusals (unknown sender or key, malformed, oversize, replay): each
refused, logged and counted while the node keeps receiving. One process, real sockets on loopback."""

from __future__ import annotations

import struct
import time

import numpy as np
import pytest

zmq = pytest.importorskip("zmq")

from distnav.commands.field_processes import free_loopback_ports  # noqa: E402
from distnav.exchange.field import CurveKeys, Kind, Peer, Transport, TransportOptions, WireError  # noqa: E402
from distnav.exchange.field.wire import HEADER, decode, encode  # noqa: E402


def test_round_trip_every_dtype_and_shape() -> None:
    for arr in (np.arange(6.0).reshape(2, 3), np.float32([1.5, -2]), np.int64([[7]]), np.uint8([]), np.float64(3.0)):
        msg = decode(encode(Kind.EDGE, 5, 123456789012, arr), max_bytes=1 << 20)
        assert (msg.kind, msg.sender, msg.step) == (Kind.EDGE, 5, 123456789012)
        assert msg.array.dtype == arr.dtype and msg.array.shape == np.shape(arr)
        np.testing.assert_array_equal(msg.array, arr)


def test_header_is_little_endian_and_documented() -> None:
    frame = encode(Kind.COLUMN, 2, 7, np.array([1.0, 2.0]))
    assert frame[:4] == b"DNF1" and frame[4] == 1 and frame[5] == Kind.COLUMN and frame[6] == 1 and frame[7] == 1
    assert struct.unpack_from("<IQQ", frame, 8) == (2, 7, 16)
    assert struct.unpack_from("<I", frame, HEADER.size) == (2,)
    assert np.frombuffer(frame[HEADER.size + 4 :], "<f8").tolist() == [1.0, 2.0]


@pytest.mark.parametrize(
    ("frame", "match"),
    [
        (b"short", "shorter than"),
        (b"XXXX" + encode(Kind.EDGE, 0, 0, np.zeros(2))[4:], "magic"),
        (encode(Kind.EDGE, 0, 0, np.zeros(2))[:-3], "announces"),
        (encode(Kind.EDGE, 0, 0, np.zeros(2))[:4] + b"\x09" + encode(Kind.EDGE, 0, 0, np.zeros(2))[5:], "version 9"),
        (encode(Kind.EDGE, 0, 0, np.zeros(2))[:5] + b"\x63" + encode(Kind.EDGE, 0, 0, np.zeros(2))[6:], "kind 99"),
        (encode(Kind.EDGE, 0, 0, np.zeros(2))[:6] + b"\x63" + encode(Kind.EDGE, 0, 0, np.zeros(2))[7:], "dtype code"),
        (encode(Kind.EDGE, 0, 0, np.zeros(1 << 12)), "oversize"),
    ],
)
def test_decode_refuses(frame: bytes, match: str) -> None:
    with pytest.raises(WireError, match=match):
        decode(frame, max_bytes=1 << 12)


def test_encode_refuses_objects_and_complex() -> None:
    with pytest.raises(WireError, match="dtype"):
        encode(Kind.EDGE, 0, 0, np.array([1 + 2j]))
    with pytest.raises(WireError, match="dtype"):
        encode(Kind.EDGE, 0, 0, np.array(["a"], dtype=object))


def _pair(keys: tuple[CurveKeys, CurveKeys] | None = None, max_bytes: int = 1 << 16) -> tuple[Transport, int, int]:
    p0, p1 = free_loopback_ports(2)
    a0, a1 = f"tcp://127.0.0.1:{p0}", f"tcp://127.0.0.1:{p1}"
    opts = TransportOptions(deadline_s=0.5, max_message_bytes=max_bytes)
    pub1 = keys[1].public if keys else None
    t0 = Transport(0, a0, [Peer(1, a1, pub1)], options=opts, keys=keys[0] if keys else None)
    return t0, p0, p1


def _raw_push(port: int, keys: CurveKeys | None = None, server: bytes | None = None) -> object:
    s = zmq.Context.instance().socket(zmq.PUSH)
    s.linger = 0
    if keys is not None:
        s.curve_secretkey, s.curve_publickey, s.curve_serverkey = keys.secret, keys.public, server
    s.connect(f"tcp://127.0.0.1:{port}")
    return s


@pytest.mark.parametrize("like", [None, np.zeros(1)], ids=["decode", "expected_header"])
def test_refusals_are_counted_and_the_node_keeps_running(
    caplog: pytest.LogCaptureFixture, like: np.ndarray | None
) -> None:
    """Every refusal, with the receiver's general checks and with its expected-header path (``like``: a round whose
    dtype and shape are known), which must refuse the same frames."""
    t0, p0, _ = _pair()
    push = _raw_push(p0)
    try:
        push.send(b"garbage")  # malformed
        push.send(encode(Kind.COLUMN, 9, 0, np.zeros(1)))  # unknown sender
        push.send(encode(Kind.COLUMN, 1, 0, np.zeros(1 << 14)))  # oversize (128 kB > 64 kB)
        push.send(encode(Kind.COLUMN, 1, 0, np.array([7.0])) + b"x")  # the expected header, one byte too many
        push.send(encode(Kind.COLUMN, 1, 0, np.array([4.0])))  # the good one
        got = t0.collect(Kind.COLUMN, 0, [1], like=like)
        assert got[1].tolist() == [4.0]
        push.send(encode(Kind.COLUMN, 1, 0, np.array([5.0])))  # replay of step 0
        push.send(encode(Kind.COLUMN, 1, 1, np.array([6.0])))
        got = t0.collect(Kind.COLUMN, 1, [1], like=like)
        assert got[1].tolist() == [6.0]  # the replay did not replace it
        push.send(encode(Kind.COLUMN, 1, 1, np.array([8.0])))  # replay of the step just taken
        push.send(encode(Kind.EDGE, 1, 2, np.array([9.0])))  # another kind than the step's
        assert t0.collect(Kind.COLUMN, 2, [1], like=like, deadline_s=0.3) == {}
        counts = t0.refusal_counts()
        want = {"malformed": 2, "unknown_sender": 1, "oversize": 1, "replay": 2, "out_of_sequence": 1}
        assert counts == want, counts
        assert "replay of step 0 from node 1" in caplog.text
        assert "41 bytes, the header announces 40" in caplog.text
    finally:
        push.close()
        t0.close()


@pytest.mark.parametrize("like", [None, np.zeros(1)], ids=["decode", "expected_header"])
def test_a_second_message_of_a_step_is_a_replay_whatever_its_shape(like: np.ndarray | None) -> None:
    """A sender's first message of a step is the one taken (here of another shape: the exchange refuses it as
    malformed); a second one of the same step, even with the expected header, is a replay on both paths."""
    p0, p1, p2 = free_loopback_ports(3)
    peers = [Peer(1, f"tcp://127.0.0.1:{p1}"), Peer(2, f"tcp://127.0.0.1:{p2}")]
    t0 = Transport(0, f"tcp://127.0.0.1:{p0}", peers, options=TransportOptions(deadline_s=0.5))
    push = _raw_push(p0)
    try:
        push.send(encode(Kind.COLUMN, 1, 0, np.array([1.0, 2.0])))
        push.send(encode(Kind.COLUMN, 1, 0, np.array([3.0])))  # while node 2's is still awaited
        push.send(encode(Kind.COLUMN, 2, 0, np.array([4.0])))
        got = t0.collect(Kind.COLUMN, 0, [1, 2], like=like)
        assert got[1].tolist() == [1.0, 2.0] and got[2].tolist() == [4.0]
        assert t0.refusal_counts() == {"replay": 1}
    finally:
        push.close()
        t0.close()


def test_a_missing_message_is_lost_after_the_deadline_and_a_silent_peer_declared_lost() -> None:
    t0, _, _ = _pair()
    try:
        for step in range(3):
            assert t0.collect(Kind.COLUMN, step, [1], deadline_s=0.05) == {}
        assert t0.lost == {1: 2}  # miss_limit 3: declared at the third silent step
    finally:
        t0.close()


def test_curve_refuses_unknown_keys_and_forged_senders() -> None:
    k0, k1, stranger = (CurveKeys(*zmq.curve_keypair()) for _ in range(3))
    t0, p0, _ = _pair((k0, k1))
    good, bad = _raw_push(p0, k1, k0.public), _raw_push(p0, stranger, k0.public)
    try:
        bad.send(encode(Kind.COLUMN, 1, 0, np.array([9.0])))  # claims node 1 under an unknown key
        good.send(encode(Kind.COLUMN, 1, 0, np.array([1.0])))
        got = t0.collect(Kind.COLUMN, 0, [1])
        assert got[1].tolist() == [1.0]
        for _ in range(100):  # the ZAP handshake of the stranger runs on its own: wait for its verdict
            if t0.refusal_counts().get("unknown_key", 0):
                break
            time.sleep(0.05)
        assert t0.refusal_counts().get("unknown_key", 0) >= 1
        # a key we know, but it claims to be another node: the sender id must match the key's owner
        t0.peers[2] = Peer(2, "tcp://127.0.0.1:1")
        t0._last_step[2] = -1
        good.send(encode(Kind.COLUMN, 2, 1, np.array([2.0])))
        good.send(encode(Kind.COLUMN, 1, 1, np.array([3.0])))
        got = t0.collect(Kind.COLUMN, 1, [1])
        assert got[1].tolist() == [3.0]
        assert t0.refusal_counts().get("forged_sender") == 1
    finally:
        good.close()
        bad.close()
        t0.close()


def test_the_kind_offset_is_where_encode_puts_the_kind() -> None:
    """The transport counts bytes by kind from one header byte (``wire.KIND_OFFSET``): it must be the kind's."""
    from distnav.exchange.field.wire import KIND_OFFSET, Kind, encode

    for kind in Kind:
        assert encode(kind, 3, 7, np.ones(2))[KIND_OFFSET] == int(kind)
