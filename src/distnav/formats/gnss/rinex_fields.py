"""The ``F14.3,I1`` observation fields of many RINEX satellite lines at once (the fast path of ``rinex_obs``).

The observation reader (:mod:`distnav.formats.gnss.rinex_obs`) walks the epochs line by line but leaves the fields
of the satellite lines to :func:`parse_fields`: the lines are padded to one width, viewed as a byte matrix and
every requested field is cut, checked and converted for all lines in a few array operations (the same
``F14.3`` value as Python's ``float``, the loss-of-lock digit after it). Any field that the line-by-line reader
would reject (not blank and not a number with its decimal point in column 11 of the field, a loss-of-lock
character other than a digit or blank, a field cut short by the end of the line, characters outside latin-1)
makes :func:`parse_fields` return ``None``: the reader then reads the file line by line again and reports the
problem with its line and epoch as before. RINEX 2.11 §5.1 / RINEX 3.05 §5.1 for the layout.

Also two field readers of the observation reader's: :func:`epoch_time` (an epoch line's time) and
:func:`glonass_slot_channels` (a ``GLONASS SLOT / FRQ #`` header line).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from distnav.typing import BoolArray, FloatArray

__all__ = ["parse_fields"]

_SPACE, _DOT, _ZERO, _NINE = ord(" "), ord("."), ord("0"), ord("9")


def parse_fields(lines: Sequence[str], starts: Sequence[int]) -> tuple[FloatArray, np.ndarray, BoolArray] | None:
    """Values ``(n, J)`` [as in the file], loss-of-lock indicators ``(n, J)`` (int8, 0 for blank) and ``present``
    ``(n, J)`` (the field is not blank) of the fields starting at the 0-based columns ``starts`` (−1: the type is
    not on these lines) of ``lines``; ``None`` when a field is malformed (the caller reads line by line instead).

    A blank field (only spaces, or past the end of the line) is not present, as in the line-by-line reader."""
    n, J = len(lines), len(starts)
    values = np.full((n, J), np.nan)
    lli = np.zeros((n, J), np.int8)
    present = np.zeros((n, J), bool)
    used = [j for j, a in enumerate(starts) if a >= 0]
    if n == 0 or not used:
        return values, lli, present
    width = max(starts[j] for j in used) + 15
    try:
        buf = "".join([line[:width].ljust(width) for line in lines]).encode("latin-1")
    except UnicodeEncodeError:
        return None
    chars = np.frombuffer(buf, np.uint8).reshape(n, width)
    length = np.fromiter(map(len, lines), np.int64, n)
    for j in used:
        a = starts[j]
        field = chars[:, a : a + 14]
        here = ~(field == _SPACE).all(axis=1)
        if not here.any():
            continue
        good = (field[:, 10] == _DOT) & (length >= a + 14)
        flag = chars[:, a + 14]
        digit = (flag >= _ZERO) & (flag <= _NINE)
        if (here & ~(good & ((flag == _SPACE) | digit))).any():
            return None
        text = np.ascontiguousarray(field[here]).view("S14").reshape(-1)
        try:
            values[here, j] = text.astype(np.float64)
        except ValueError:
            return None
        lli[:, j] = np.where(here & digit, flag.astype(np.int16) - _ZERO, 0).astype(np.int8)
        present[:, j] = here
    return values, lli, present


def glonass_slot_channels(line: str, out: dict[str, int]) -> None:
    """The ``Rnn k`` pairs (up to 8 per line, columns 5-60) of a ``GLONASS SLOT / FRQ #`` line; a malformed pair
    is left out (the channel then comes from the navigation file)."""
    for i in range(8):
        sv, k = line[4 + 7 * i : 7 + 7 * i], line[8 + 7 * i : 10 + 7 * i]
        if sv[:1] == "R" and sv[1:3].strip().isdigit():
            try:
                out[f"R{int(sv[1:3]):02d}"] = int(k)
            except ValueError:
                continue


_HOURS: dict[tuple[int, int, int, int], int] = {}


def epoch_time(y: int, mo: int, d: int, h: int, mi: int, sec: float) -> np.datetime64:
    """The epoch in ns: the hour parsed (and so checked) by numpy once per hour and remembered, the minute checked
    here, then whole nanoseconds added — the same datetime64 as parsing every epoch's minute (issue 32: 6 µs of
    string parsing per epoch)."""
    key = (y, mo, d, h)
    hour_ns = _HOURS.get(key)
    if hour_ns is None:
        hour_ns = int(np.datetime64(f"{y:04d}-{mo:02d}-{d:02d}T{h:02d}", "ns").astype(np.int64))
        if len(_HOURS) > 4096:
            _HOURS.clear()
        _HOURS[key] = hour_ns
    if not 0 <= mi <= 59:
        raise ValueError(f"minute {mi}")
    return np.datetime64(hour_ns + mi * 60_000_000_000 + int(round(sec * 1e9)), "ns")
