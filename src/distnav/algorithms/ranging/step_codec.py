"""The LM phase's trial steps on the wire (issue 27, seventh session; split from
:mod:`~distnav.algorithms.ranging.wire`, item 8 of its docstring): a float32 step's entries on the exponents
their columns carried in the sender's last step, which every receiver holds — the same values bit for bit."""

from __future__ import annotations

import numpy as np

from distnav.errors import ModelError

__all__ = ["STEP_WINDOW", "pack_steps", "unpack_steps"]

STEP_WINDOW = 7  # an entry's exponent within this of its column's held one travels as 4 bits (pack_steps)
_STEP_BITS = 28  # sign, 4-bit exponent difference, 23-bit mantissa


def pack_steps(rows: np.ndarray, held: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """float32 rows ``(n, m)`` on the exponents ``held`` ``(n, m)`` of each row's last step (0: none held), as
    bytes ``(n, 4m + 1)`` with each message's size and the exponents held after it (item 8 of the module
    docstring). A row whose every entry is zero or a normal float32 within :data:`STEP_WINDOW` binades of its held
    exponent travels as one 28-bit word an entry (sign, the difference + 8 in 4 bits — 0 for a zero —, the
    mantissa), ``ceil(28m/8)`` bytes; any other row as its plain float32 bytes (``4m``). The last byte says which
    (on the wire the message's size does)."""
    r = np.ascontiguousarray(rows, np.float32)
    n, m = r.shape
    bits = r.view(np.uint32).astype(np.int64)
    exp, mant, sign = (bits >> 23) & 0xFF, bits & 0x7FFFFF, bits >> 31
    zero = (exp == 0) & (mant == 0)
    near = (exp > 0) & (exp < 255) & (held > 0) & (np.abs(exp - held) <= STEP_WINDOW)
    coded = np.all(zero | near, axis=1)
    out = np.zeros((n, 4 * m + 1), np.uint8)
    out[:, : 4 * m] = r.view(np.uint8).reshape(n, 4 * m)
    words = (sign << 27) | (np.where(zero, 0, exp - held + 8) << 23) | mant
    wbits = ((words[:, :, None] >> np.arange(_STEP_BITS - 1, -1, -1)) & 1).astype(np.uint8).reshape(n, -1)
    size = -(-_STEP_BITS * m // 8)
    out[coded, :size] = np.packbits(wbits[coded], axis=1)
    out[coded, size : 4 * m] = 0
    out[:, 4 * m] = coded
    return out, np.where(coded, size, 4 * m).astype(np.int64), np.where(zero, held, exp)


def unpack_steps(packed: np.ndarray, held: np.ndarray, m: int) -> tuple[np.ndarray, np.ndarray]:
    """The float64 values of :func:`pack_steps`'s rows ``(n, 4m + 1)`` decoded on the exponents ``held``
    ``(n, m)`` the receiver holds from each sender's last step, and the exponents it holds after them."""
    b = np.ascontiguousarray(packed, np.uint8)
    n = b.shape[0]
    if b.ndim != 2 or b.shape[1] != 4 * m + 1:
        raise ModelError(f"a packed step must have {4 * m + 1} bytes, got shape {b.shape}")
    plain = np.ascontiguousarray(b[:, : 4 * m]).view(np.float32).reshape(n, m)
    size = -(-_STEP_BITS * m // 8)
    wbits = np.unpackbits(b[:, :size], axis=1)[:, : _STEP_BITS * m].reshape(n, m, _STEP_BITS).astype(np.int64)
    words = np.sum(wbits << np.arange(_STEP_BITS - 1, -1, -1), axis=2)
    code, mant, sign = (words >> 23) & 0xF, words & 0x7FFFFF, words >> 27
    exp = np.where(code == 0, 0, held + code - 8)
    decoded = ((sign << 31) | (exp << 23) | mant).astype(np.uint32).view(np.float32)
    values = np.where((b[:, 4 * m] == 1)[:, None], decoded, plain)
    vbits = values.view(np.uint32).astype(np.int64)
    vexp = (vbits >> 23) & 0xFF
    vzero = (vexp == 0) & ((vbits & 0x7FFFFF) == 0)
    return values.astype(float), np.where(vzero, held, vexp)
