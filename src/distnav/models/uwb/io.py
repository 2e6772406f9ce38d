"""CSV range logs and anchor-position files for UWB anchor self-localization.

* ranges: header ``a,b,range_m`` (extra columns are ignored), one row per measured range; node ids are strings;
  any number of rows per pair (both orders count as the same pair).
* positions (known / initial / truth): header ``id,x_m,y_m,z_m`` (``z_m`` may be omitted for a 2-D network).
* heights: header ``id,z_m``.

Every problem is reported as a :class:`~distnav.errors.DataFileError` naming the file and the line.
:func:`combine_ranges` merges repeated ranges of a pair by their **median**, which ignores a minority of
NLOS ranges that are metres too long (a mean would be dragged by them); the median absolute deviation of
each pair is returned so a user can spot unstable links.
"""

from __future__ import annotations

import csv
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from distnav.errors import DataFileError

__all__ = ["RangeLog", "CombinedRanges", "read_ranges", "combine_ranges", "read_positions", "read_heights",
           "write_positions"]


@dataclass(frozen=True)
class RangeLog:
    """Raw range rows: ``a[k]``, ``b[k]`` (ids), ``range_m[k]`` read from ``path`` line ``line[k]``."""

    path: Path
    a: tuple[str, ...]
    b: tuple[str, ...]
    range_m: np.ndarray
    line: np.ndarray

    @property
    def ids(self) -> list[str]:
        """Anchor ids in order of first appearance."""
        seen: dict[str, None] = {}
        for x, y in zip(self.a, self.b, strict=True):
            seen.setdefault(x, None)
            seen.setdefault(y, None)
        return list(seen)


@dataclass(frozen=True)
class CombinedRanges:
    """One range per unordered pair: the median of its samples, the sample count and the MAD (m)."""

    pairs: tuple[tuple[str, str], ...]
    range_m: np.ndarray
    count: np.ndarray
    mad_m: np.ndarray


def _rows(path: Path, required: Sequence[str]) -> tuple[list[str], list[tuple[int, list[str]]]]:
    p = Path(path)
    if not p.is_file():
        raise DataFileError(f"{p}: file not found")
    try:
        text = p.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError as exc:
        raise DataFileError(f"{p}: not a UTF-8 text file ({exc})") from None
    lines = text.splitlines()
    rows: list[tuple[int, list[str]]] = []
    header: list[str] | None = None
    for number, fields in enumerate(csv.reader(lines), start=1):
        if not fields or all(not f.strip() for f in fields) or fields[0].lstrip().startswith("#"):
            continue
        fields = [f.strip() for f in fields]
        if header is None:
            header = [f.lower() for f in fields]
            missing = [c for c in required if c not in header]
            if missing:
                raise DataFileError(
                    f"{p}:{number}: header must name the columns {','.join(required)}; missing {', '.join(missing)} "
                    f"(got {','.join(fields)})")
            continue
        rows.append((number, fields))
    if header is None:
        raise DataFileError(f"{p}: empty file (expected a header {','.join(required)})")
    if not rows:
        raise DataFileError(f"{p}: no data rows after the header")
    return header, rows


def _float(p: Path, number: int, field: str, what: str) -> float:
    try:
        v = float(field)
    except ValueError:
        raise DataFileError(f"{p}:{number}: {what} {field!r} is not a number") from None
    if not np.isfinite(v):
        raise DataFileError(f"{p}:{number}: {what} {field!r} is not finite")
    return v


def read_ranges(path: str | Path) -> RangeLog:
    """Read a range log ``a,b,range_m`` (see the module docstring)."""
    p = Path(path)
    header, rows = _rows(p, ("a", "b", "range_m"))
    ia, ib, ir = header.index("a"), header.index("b"), header.index("range_m")
    a, b, r, ln = [], [], [], []
    for number, f in rows:
        if len(f) != len(header):
            raise DataFileError(f"{p}:{number}: expected {len(header)} fields ({','.join(header)}), got {len(f)}")
        if not f[ia] or not f[ib]:
            raise DataFileError(f"{p}:{number}: empty anchor id")
        if f[ia] == f[ib]:
            raise DataFileError(f"{p}:{number}: range from anchor {f[ia]!r} to itself")
        v = _float(p, number, f[ir], "range_m")
        if v < 0:
            raise DataFileError(f"{p}:{number}: negative range {v} m between {f[ia]!r} and {f[ib]!r}")
        a.append(f[ia])
        b.append(f[ib])
        r.append(v)
        ln.append(number)
    return RangeLog(p, tuple(a), tuple(b), np.asarray(r, float), np.asarray(ln, np.int64))


def combine_ranges(log: RangeLog) -> CombinedRanges:
    """One range per unordered pair: the **median** of its samples (robust to a minority of NLOS ranges)."""
    groups: dict[tuple[str, str], list[float]] = {}
    for x, y, v in zip(log.a, log.b, log.range_m, strict=True):
        key = (x, y) if x <= y else (y, x)
        groups.setdefault(key, []).append(float(v))
    pairs = tuple(groups)
    med = np.array([np.median(groups[k]) for k in pairs])
    cnt = np.array([len(groups[k]) for k in pairs], np.int64)
    mad = np.array([np.median(np.abs(np.asarray(groups[k]) - m)) for k, m in zip(pairs, med, strict=True)])
    return CombinedRanges(pairs, med, cnt, mad)


def read_positions(path: str | Path) -> tuple[dict[str, np.ndarray], int]:
    """Read ``id,x_m,y_m[,z_m]``; returns ``({id: position}, dim)``."""
    p = Path(path)
    header, rows = _rows(p, ("id", "x_m", "y_m"))
    cols = ["x_m", "y_m"] + (["z_m"] if "z_m" in header else [])
    idx = [header.index(c) for c in cols]
    iid = header.index("id")
    out: dict[str, np.ndarray] = {}
    for number, f in rows:
        if len(f) != len(header):
            raise DataFileError(f"{p}:{number}: expected {len(header)} fields ({','.join(header)}), got {len(f)}")
        key = f[iid]
        if not key:
            raise DataFileError(f"{p}:{number}: empty anchor id")
        if key in out:
            raise DataFileError(f"{p}:{number}: anchor {key!r} is listed twice")
        out[key] = np.array([_float(p, number, f[i], c) for i, c in zip(idx, cols, strict=True)])
    return out, len(cols)


def read_heights(path: str | Path) -> tuple[dict[str, float], dict[str, int]]:
    """Read ``id,z_m``; returns ``({id: z_m}, {id: line})`` (the lines let callers name a bad id's line)."""
    p = Path(path)
    header, rows = _rows(p, ("id", "z_m"))
    iid, iz = header.index("id"), header.index("z_m")
    out: dict[str, float] = {}
    lines: dict[str, int] = {}
    for number, f in rows:
        if len(f) != len(header):
            raise DataFileError(f"{p}:{number}: expected {len(header)} fields ({','.join(header)}), got {len(f)}")
        if f[iid] in out:
            raise DataFileError(f"{p}:{number}: anchor {f[iid]!r} is listed twice")
        if not f[iid]:
            raise DataFileError(f"{p}:{number}: empty anchor id")
        out[f[iid]] = _float(p, number, f[iz], "z_m")
        lines[f[iid]] = number
    return out, lines


def write_positions(path: str | Path, ids: Sequence[str], positions_m: np.ndarray) -> None:
    """Write ``id,x_m,y_m,z_m`` (without ``z_m`` for 2-D), micrometre resolution, via a temporary file + rename."""
    pos = np.asarray(positions_m, float)
    cols = ["x_m", "y_m", "z_m"][: pos.shape[1]]
    lines = ["id," + ",".join(cols)]
    for k, row in zip(ids, pos, strict=True):
        lines.append(k + "," + ",".join(f"{v:.6f}" for v in row))
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    tmp = p.with_name(f".{p.name}.tmp")
    tmp.write_text("\n".join(lines) + "\n", encoding="utf-8")
    os.replace(tmp, p)
