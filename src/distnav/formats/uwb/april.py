"""The APRIL lab DW1000 range logs (``../shared/data/uwb/april-dw1000-8node``, read in place): conversion to the
texts of the CSV files ``uwb solve`` reads (``uwb import-april`` writes them).

The logs hold one double-sided two-way-ranging exchange per line, whitespace separated: the raw time of
propagation in **microseconds including the antenna delays**, the two node ids, then DW1000 diagnostics (see the
folder's PROVENANCE.md). The range is ``d = (t − (δ_a + δ_b)/2) · c`` with ``c = 299.792458 m/µs`` and the
lab's hand-calibrated delays :data:`MANUAL_DELAYS_US` (or one default delay, 0.516 µs, for every node: the
uncalibrated case a common range offset absorbs). Clock-wrap garbage comes out as large negative ranges; they
are kept in ``ranges.csv`` so that ``uwb solve`` drops and counts them as it would in any real log. Ground truth
is 2-D, in feet (converted to metres); node 16 (the robot) has none and is left out.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from distnav.errors import DataFileError
from distnav.formats.text import plain_text

__all__ = ["C_M_PER_US", "MANUAL_DELAYS_US", "DEFAULT_DELAY_US", "TRUTH_FT", "read_april", "april_csv_texts"]

C_M_PER_US = 299.792458
DEFAULT_DELAY_US = 0.516
MANUAL_DELAYS_US = {
    8: 0.515375,
    12: 0.515547,
    14: 0.515818,
    16: 0.515717,
    54: 0.515316,
    61: 0.515541,
    81: 0.515397,
    87: 0.515345,
}
TRUTH_FT = {
    8: (0.0, 0.0),
    12: (15.0, 1.0),
    14: (2.0, 9.0),
    54: (20.0, 3.0),
    61: (10.0, 0.0),
    81: (17.0, 7.0),
    87: (8.0, 8.0),
}
FT_M = 0.3048


def read_april(path: str | Path, *, delays: str = "manual") -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(a, b, range_m)`` of every sample of one APRIL log (``delays`` = ``"manual"`` or ``"default"``)."""
    p = Path(path)
    if not p.is_file():
        raise DataFileError(f"{p}: file not found")
    if delays not in ("manual", "default"):
        raise DataFileError(f"delays must be 'manual' or 'default', got {delays!r}")
    rows = _parse_log(p)
    a, b = rows[:, 1].astype(np.int64), rows[:, 2].astype(np.int64)
    if delays == "manual":
        da = np.array([MANUAL_DELAYS_US[int(k)] for k in a])
        db = np.array([MANUAL_DELAYS_US[int(k)] for k in b])
    else:
        da = db = np.full(a.size, DEFAULT_DELAY_US)
    return a, b, (rows[:, 0] - 0.5 * (da + db)) * C_M_PER_US


def april_csv_texts(path: str | Path, *, known: list[int], delays: str = "manual") -> dict[str, str]:
    """The texts of ``ranges.csv``, ``known.csv`` (the ``known`` nodes' true positions) and ``truth.csv`` (2-D,
    metres) for one APRIL log, by file stem (``uwb import-april`` writes them)."""
    for k in known:
        if k not in TRUTH_FT:
            raise DataFileError(f"known node {k} has no ground truth; choose from {sorted(TRUTH_FT)}")
    a, b, r = read_april(path, delays=delays)
    keep = np.isin(a, list(TRUTH_FT)) & np.isin(b, list(TRUTH_FT))  # node 16: no truth, left out
    if not keep.any():
        raise DataFileError(
            f"{path}: no sample between two nodes with ground truth {sorted(TRUTH_FT)} (node 16, the robot, has none)"
        )
    lines = ["a,b,range_m"] + [f"{x},{y},{v:.6f}" for x, y, v in zip(a[keep], b[keep], r[keep], strict=True)]

    def table(nodes: list[int]) -> str:
        return "id,x_m,y_m\n" + "".join(f"{k},{TRUTH_FT[k][0] * FT_M:.4f},{TRUTH_FT[k][1] * FT_M:.4f}\n" for k in nodes)

    return {"ranges": "\n".join(lines) + "\n", "known": table(sorted(known)), "truth": table(sorted(TRUTH_FT))}


def _parse_log(p: Path) -> np.ndarray:
    """``(n, 3)`` array of time of propagation (µs), node a, node b, checked line by line; a
    :class:`DataFileError` names the line and what was expected."""
    raw = p.read_bytes()
    if raw[:2] == b"\x1f\x8b":
        raise DataFileError(f"{p}: a gzip archive: expected the APRIL range log as plain text (gunzip it first)")
    text = plain_text(
        p,
        raw,
        encoding="ascii",
        expected="an APRIL range log (text)",
        undecodable="plain ASCII text: expected an APRIL range log (whitespace-separated numbers)",
    )
    _check_last_line(p, text)
    out: list[tuple[float, float, float]] = []
    for number, text_line in enumerate(text.splitlines(), start=1):
        fields = text_line.split()
        if not fields:
            continue
        if len(fields) < 3:
            raise DataFileError(
                f"{p}, line {number}: {len(fields)} field(s): expected at least 3 (time of "
                f"propagation in µs, node a, node b)"
            )
        try:
            t_us = float(fields[0])
        except ValueError:
            raise DataFileError(f"{p}, line {number}: time of propagation {fields[0]!r} is not a number") from None
        if not (fields[1].isdigit() and fields[2].isdigit()):
            raise DataFileError(f"{p}, line {number}: node ids {fields[1]!r} {fields[2]!r}: expected two whole numbers")
        strangers = [f for f in fields[1:3] if int(f) not in MANUAL_DELAYS_US]
        if strangers:  # named here, as written (a 20-digit id was reported as -9223372036854775808)
            raise DataFileError(
                f"{p}, line {number}: node {', '.join(strangers)} is not an APRIL node {sorted(MANUAL_DELAYS_US)}"
            )
        if int(fields[1]) == int(fields[2]):
            raise DataFileError(f"{p}, line {number}: a range from node {fields[1]} to itself")
        out.append((t_us, float(fields[1]), float(fields[2])))
    if not out:
        raise DataFileError(f"{p}: no samples (an empty APRIL range log)")
    return np.array(out)


def _check_last_line(p: Path, text: str) -> None:
    """A log whose last line has no newline and fewer fields than the line before was cut while it was written
    or copied: its last number may be cut too (``0.53`` of ``0.5313…``), a silently wrong range."""
    if not text or text.endswith(("\n", "\r")):
        return
    lines = [line for line in text.splitlines() if line.strip()]
    if len(lines) >= 2 and len(lines[-1].split()) < len(lines[-2].split()):
        raise DataFileError(
            f"{p}, line {text.count(chr(10)) + 1}: the file ends inside a line ({len(lines[-1].split())} fields, the "
            f"line before has {len(lines[-2].split())}; no final newline): it is truncated"
        )
