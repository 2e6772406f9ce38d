"""Messages as quantized deltas with error feedback (issue 27 item 2: ADMM's ``messages="ternary"``).

The sender and the receiver of a stream of vectors ``v^[k]`` (one per message row) keep the same reconstruction
``r``. A message carries, per row, ``q = clip(rint((v − r)/s · L), −L, L)`` in ``b`` bits per entry
(``L = 2^(b−1) − 1``; ``b = 2``: ternary codes −1, 0, +1) and the row's scale ``s = max|v − r|`` as a float32; both
sides then set ``r ← r + q · s/L`` with the same float64 arithmetic, so the receiver's copy equals the sender's
bit for bit and the part of ``v − r`` a code could not carry is carried by the next message (error feedback): as
the iteration converges the deltas, and with them the quantization error, shrink to zero, so the run still
reaches the exact fixed point (measured on the code-bias network: 463 iterations to 1e-6 with ternary codes
against 472 in float64, docs/economy.md). The first message of a stream is sent in full (float64).

Needs every message to arrive (a lost message desynchronizes the two copies for good): no fault schedule.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["DeltaCodec", "payload_bytes"]

SCALE_BYTES = 4  # float32


def payload_bytes(width: int, bits: int) -> int:
    """Bytes of one coded message row of ``width`` entries: packed codes and a float32 scale."""
    return math.ceil(width * bits / 8) + SCALE_BYTES


class DeltaCodec:
    """One end of a coded stream of ``(rows, width)`` float64 arrays (module docstring)."""

    def __init__(self, bits: int) -> None:
        if not 2 <= bits <= 8:
            raise ValueError(f"bits must be in 2..8, got {bits}")
        self.bits = bits
        self.levels = 2 ** (bits - 1) - 1
        self.reference: np.ndarray | None = None

    @property
    def started(self) -> bool:
        return self.reference is not None

    def start(self, values: np.ndarray) -> None:
        """The first message, sent in full: both ends take it as their reconstruction."""
        self.reference = np.array(values, dtype=float, copy=True)

    def encode(self, values: np.ndarray) -> np.ndarray:
        """The coded message (uint8, ``(rows, payload_bytes)``) of ``values``; updates this end's reconstruction."""
        ref = self.reference
        assert ref is not None
        d = np.asarray(values, float) - ref
        scale32 = np.abs(d).max(axis=1).astype(np.float32)
        step = self._step(scale32)
        with np.errstate(invalid="ignore", divide="ignore"):
            q = np.where(step[:, None] > 0, np.rint(d / np.where(step > 0, step, 1.0)[:, None]), 0.0)
        np.clip(q, -self.levels, self.levels, out=q)
        ref += q * step[:, None]
        codes = (q + self.levels).astype(np.uint8)
        planes = ((codes[..., None] >> np.arange(self.bits, dtype=np.uint8)) & 1).astype(np.uint8)
        packed = np.packbits(planes.reshape(codes.shape[0], -1), axis=1, bitorder="little")
        return np.concatenate([packed, scale32.reshape(-1, 1).view(np.uint8)], axis=1)

    def decode(self, payload: np.ndarray) -> np.ndarray:
        """Apply a received message to this end's reconstruction and return it (do not modify it)."""
        ref = self.reference
        assert ref is not None
        rows, width = ref.shape
        body = np.ascontiguousarray(payload[:, :-SCALE_BYTES])
        scale32 = np.ascontiguousarray(payload[:, -SCALE_BYTES:]).view(np.float32)[:, 0]
        bits = np.unpackbits(body, axis=1, count=width * self.bits, bitorder="little").reshape(rows, width, self.bits)
        codes = (bits.astype(np.int64) << np.arange(self.bits)).sum(axis=2)
        q = (codes - self.levels).astype(float)
        ref += q * self._step(scale32)[:, None]
        return ref

    def _step(self, scale32: np.ndarray) -> np.ndarray:
        step: np.ndarray = scale32.astype(np.float64) / self.levels
        return step
