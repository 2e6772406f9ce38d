"""CSV range logs and anchor-position files for UWB anchor self-localization.

* ranges: header ``a,b,range_m`` (extra columns are ignored), one row per measured range; node ids are strings;
  any number of rows per pair (both orders count as the same pair).
* positions (known / initial / truth): header ``id,x_m,y_m,z_m`` (``z_m`` may be omitted for a 2-D network).
* heights: header ``id,z_m``.

Every problem is reported as a :class:`~distnav.errors.DataFileError` naming the file and the line, except
**bad samples** of a real log (a range that is negative, zero or not finite — NaN/inf, a DW1000 clock wrap turned
into a huge value is caught by the unit check below): :func:`read_ranges` drops them, counts them per reason in
:attr:`RangeLog.dropped` and logs one warning; ``strict=True`` refuses the file at the first one instead.
:func:`check_units` catches ranges that look like millimetres, centimetres or feet (the known anchors'
distances disagree with their ranges by that factor, or without two known anchors on a link, a median range of
hundreds of metres); :func:`single_link_anchors` names anchors with a single measured partner (often an id typo,
``A1O`` for ``A10``), with the nearest-spelled other id.
:func:`combine_ranges` merges repeated ranges of a pair by their **median**, which ignores a minority of
NLOS ranges that are metres too long (a mean would be dragged by them); the median absolute deviation of
each pair is returned so a user can spot unstable links.
"""

from __future__ import annotations

import difflib
import logging
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from distnav.errors import DataFileError
from distnav.formats.text import csv_rows, plain_text

__all__ = [
    "RangeLog",
    "CombinedRanges",
    "read_ranges",
    "combine_ranges",
    "read_positions",
    "read_heights",
    "format_positions",
    "check_units",
    "single_link_anchors",
    "same_number_ids",
    "DROP_REASONS",
]

log_ = logging.getLogger(__name__)

DROP_REASONS = ("negative", "zero", "not finite", "beyond any radio range")
#: A range sample longer than this (1,000 km) is corrupt, not a unit (ranges in mm of a 300-m hall are 3·10⁵): it is
#: dropped like a negative one (1e308 went on to "weighted residual sum of squares must be finite")
MAX_SAMPLE_RANGE_M = 1e6


@dataclass(frozen=True)
class RangeLog:
    """Raw range rows: ``a[k]``, ``b[k]`` (ids), ``range_m[k]`` read from ``path`` line ``line[k]``.

    ``dropped`` counts the bad samples left out per reason (:data:`DROP_REASONS`), ``dropped_lines`` their lines.
    """

    path: Path
    a: tuple[str, ...]
    b: tuple[str, ...]
    range_m: np.ndarray
    line: np.ndarray
    dropped: Mapping[str, int] = field(default_factory=dict)
    dropped_lines: tuple[int, ...] = ()

    @property
    def n_dropped(self) -> int:
        return int(sum(self.dropped.values()))

    def drop_message(self) -> str:
        """One line saying what was dropped ("" when nothing was)."""
        if not self.n_dropped:
            return ""
        what = ", ".join(f"{v} {k}" for k, v in self.dropped.items() if v)
        shown = ", ".join(str(x) for x in self.dropped_lines[:5]) + (" …" if len(self.dropped_lines) > 5 else "")
        return (
            f"{self.path}: dropped {self.n_dropped} bad range sample(s) of {self.n_dropped + self.range_m.size} "
            f"({what}; lines {shown})"
        )

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
    raw = p.read_bytes()
    text = plain_text(
        p,
        raw,
        encoding="utf-8",
        expected="a CSV text file in UTF-8",
        undecodable="UTF-8 text: expected a CSV text file in UTF-8 (this looks like binary data, a gzip archive, or "
        "text saved as UTF-16 or in a local code page: save it as UTF-8 CSV)",
    )
    rows: list[tuple[int, list[str]]] = []
    header: list[str] | None = None
    for number, fields in csv_rows(p, text.splitlines()):
        if not fields or all(not f.strip() for f in fields) or fields[0].lstrip().startswith("#"):
            continue
        fields = [f.strip() for f in fields]
        if header is None:
            header = [f.lower() for f in fields]
            missing = [c for c in required if c not in header]
            twice = sorted({c for c in header if c and header.count(c) > 1})
            if twice:  # before: the first of the two columns was read, the other silently ignored
                raise DataFileError(f"{p}:{number}: column {', '.join(twice)} named twice in the header")
            if missing:
                raise DataFileError(
                    f"{p}:{number}: header must name the columns {','.join(required)}; missing {', '.join(missing)} "
                    f"(got {','.join(fields)})"
                )
            continue
        if [f.lower() for f in fields] == header:  # before: "range_m 'range_m' is not a number"
            raise DataFileError(f"{p}:{number}: the header line again (two files joined into one?): remove it")
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


def _sample(p: Path, number: int, field_: str) -> tuple[float, str]:
    """The range of one row and why it is bad ("" when it is a usable sample)."""
    try:
        v = float(field_)
    except ValueError:
        raise DataFileError(f"{p}:{number}: range_m {field_!r} is not a number") from None
    if not np.isfinite(v):
        return v, "not finite"
    if v < 0:
        return v, "negative"
    if v == 0:
        return v, "zero"
    if v > MAX_SAMPLE_RANGE_M:
        return v, "beyond any radio range"
    return v, ""


def read_ranges(path: str | Path, *, strict: bool = False) -> RangeLog:
    """Read a range log ``a,b,range_m`` (see the module docstring).

    A negative, zero or non-finite range is dropped and counted (one logged warning per file); with
    ``strict=True`` it is a :class:`~distnav.errors.DataFileError` naming the line. A field that is not a
    number at all, a row with the wrong number of fields, an empty id or a range of an anchor to itself are
    errors either way (the file is not a range log as described)."""
    p = Path(path)
    header, rows = _rows(p, ("a", "b", "range_m"))
    ia, ib, ir = header.index("a"), header.index("b"), header.index("range_m")
    a, b, r, ln = [], [], [], []
    dropped = dict.fromkeys(DROP_REASONS, 0)
    dropped_lines: list[int] = []
    for number, f in rows:
        if len(f) != len(header):
            raise DataFileError(f"{p}:{number}: expected {len(header)} fields ({','.join(header)}), got {len(f)}")
        if not f[ia] or not f[ib]:
            raise DataFileError(f"{p}:{number}: empty anchor id")
        if f[ia] == f[ib]:
            raise DataFileError(f"{p}:{number}: range from anchor {f[ia]!r} to itself")
        v, bad = _sample(p, number, f[ir])
        if bad:
            if strict:
                raise DataFileError(
                    f"{p}:{number}: {bad} range {f[ir]!r} between {f[ia]!r} and {f[ib]!r} "
                    f"(without --strict such samples are dropped and counted)"
                )
            dropped[bad] += 1
            dropped_lines.append(number)
            continue
        a.append(f[ia])
        b.append(f[ib])
        r.append(v)
        ln.append(number)
    if not r:
        raise DataFileError(
            f"{p}:{dropped_lines[0]}: no usable range sample ({len(dropped_lines)} bad one(s) "
            f"dropped: {', '.join(f'{v} {k}' for k, v in dropped.items() if v)})"
        )
    out = RangeLog(
        p,
        tuple(a),
        tuple(b),
        np.asarray(r, float),
        np.asarray(ln, np.int64),
        {k: v for k, v in dropped.items() if v},
        tuple(dropped_lines),
    )
    if out.n_dropped:
        log_.warning("%s", out.drop_message())
    return out


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


UNIT_FACTORS = {"millimetres": 1000.0, "centimetres": 100.0, "feet": 1.0 / 0.3048}
MAX_PLAUSIBLE_RANGE_M = 300.0
MIN_PLAUSIBLE_RANGE_M = 0.05  # anchors are mounted farther apart than 5 cm: smaller medians are kilometres
MAX_UNIT_CONTRADICTION = 3.0  # ranges vs known distances beyond 3× either way: not one unit (feet: 3.28×)


def check_units(
    comb: CombinedRanges, known_m: Mapping[str, np.ndarray], *, where: str = "ranges"
) -> tuple[str, str | None]:
    """Refuse ranges that are not in metres; returns ``(note on what was compared, warning or None)``.

    Compares the median ranges of links between two known anchors with the distance of their positions: a
    median ratio within 15 % of 1000, 100 or 3.28 means millimetres, centimetres or feet (a
    :class:`DataFileError`), and so does any ratio beyond :data:`MAX_UNIT_CONTRADICTION` (3×) either way (ranges
    in km with positions in feet: the two files contradict each other, issue 28); a ratio outside 0.5–2 but
    within that is returned as a warning (a wrong known position, or a unit we do not guess). Without such a
    link, a median range above :data:`MAX_PLAUSIBLE_RANGE_M` (UWB does not range that far) is refused as probably
    millimetres, one below :data:`MIN_PLAUSIBLE_RANGE_M` as probably kilometres."""
    ratios = []
    for (x, y), r in zip(comb.pairs, comb.range_m, strict=True):
        if x in known_m and y in known_m:
            d = float(np.linalg.norm(np.asarray(known_m[x]) - np.asarray(known_m[y])))
            if d > 0.5:
                ratios.append(float(r) / d)
    if ratios:
        q = float(np.median(ratios))
        for unit, f in UNIT_FACTORS.items():
            if abs(np.log(q / f)) < np.log(1.15):
                raise DataFileError(
                    f"{where}: the ranges look like {unit}: between known anchors they are {q:.4g}× the distance "
                    f"of the known positions (median of {len(ratios)} link(s)); convert range_m to metres"
                )
        note = f"ranges / known distances = {q:.3f} (median of {len(ratios)} link(s) between known anchors)"
        if not 1.0 / MAX_UNIT_CONTRADICTION < q < MAX_UNIT_CONTRADICTION:
            raise DataFileError(
                f"{where}: between known anchors the ranges are {q:.4g}× the distance of the known positions "
                f"(median of {len(ratios)} link(s)): ranges and known positions are not in the same unit (e.g. "
                f"ranges in km, positions in feet) or the known anchors' ids do not match the log; convert both "
                f"to metres"
            )
        if not 0.5 < q < 2.0:
            return note, (
                f"between known anchors the ranges are {q:.3g}× the distance of the known positions "
                f"(median of {len(ratios)} link(s)): check the known positions and the units of range_m"
            )
        return note, None
    med = float(np.median(comb.range_m))
    if med < MIN_PLAUSIBLE_RANGE_M:
        raise DataFileError(
            f"{where}: median range {med:.4g} m is shorter than any two UWB anchors are mounted apart; the ranges "
            f"look like kilometres (convert range_m to metres)"
        )
    if med > MAX_PLAUSIBLE_RANGE_M:
        raise DataFileError(
            f"{where}: median range {med:.4g} m is beyond UWB reach; the ranges look like "
            f"millimetres (convert range_m to metres)"
        )
    return "", None


def single_link_anchors(comb: CombinedRanges) -> list[str]:
    """Warnings for anchors with one measured partner only (often an id typo), naming the closest other id."""
    partners: dict[str, set[str]] = {}
    for x, y in comb.pairs:
        partners.setdefault(x, set()).add(y)
        partners.setdefault(y, set()).add(x)
    many = [k for k, v in partners.items() if len(v) > 1]
    out = []
    for k, v in partners.items():
        if len(v) != 1:
            continue
        near = _closest_ids(k, many)
        hint = f"; an id typo for {' or '.join(repr(x) for x in near)}?" if near else ""
        out.append(
            f"anchor {k!r} has a single measured link (to {next(iter(v))!r}): it cannot be located from ranges{hint}"
        )
    return out


_LOOKALIKE = str.maketrans({"o": "0", "l": "1", "i": "1", "s": "5", "b": "8", "z": "2"})


def same_number_ids(key: str, others: Sequence[str]) -> list[str]:
    """Ids of ``others`` that spell the same number as ``key`` another way (``08`` and ``8``, ``12.0`` and ``12``:
    a spreadsheet's or a script's formatting), none when ``key`` is not a number."""
    try:
        value = float(key)
    except ValueError:
        return []
    out = []
    for o in others:
        try:
            if o != key and float(o) == value:
                out.append(o)
        except ValueError:
            continue
    return out


def _closest_ids(key: str, others: Sequence[str]) -> list[str]:
    """Ids that spell the same number (:func:`same_number_ids`), differ from ``key`` by a look-alike character
    (O/0, l/1, ...) or else by one edit, at most 3."""
    numeric = same_number_ids(key, others)
    if numeric:
        return numeric[:3]
    norm = key.lower().translate(_LOOKALIKE)
    same = [o for o in others if o.lower().translate(_LOOKALIKE) == norm]
    if same:
        return same[:3]
    return difflib.get_close_matches(key, list(others), n=3, cutoff=0.75)


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


def format_positions(ids: Sequence[str], positions_m: np.ndarray) -> str:
    """The text of a positions file, ``id,x_m,y_m,z_m`` (without ``z_m`` for 2-D), micrometre resolution: what
    :func:`read_positions` reads back (the caller writes it, e.g. with :func:`distnav.output.atomic_write_text`)."""
    pos = np.asarray(positions_m, float)
    cols = ["x_m", "y_m", "z_m"][: pos.shape[1]]
    lines = ["id," + ",".join(cols)]
    for k, row in zip(ids, pos, strict=True):
        lines.append(k + "," + ",".join(f"{v:.6f}" for v in row))
    return "\n".join(lines) + "\n"
