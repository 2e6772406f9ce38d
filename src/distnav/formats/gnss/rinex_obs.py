"""A fast reader of GPS observations in RINEX 2.11 and 3.x observation files (plain, gzip, Hatanaka ``.crx``/``.d``).

Why not georinex for the observations: a full day of 30-s multi-GNSS data takes it 13–40 s on this machine and it
reports nothing while it works; this reader decompresses (``hatanaka``, C code), decodes as **latin-1** (any byte
is accepted, so a header comment with a non-ASCII byte such as 0xE4 does not abort a run) and slices only the GPS
lines and the requested observation types (≈ 2 s for the same day, most of it the Hatanaka decompression).
Progress goes to ``logging`` and to an optional callback; the reader never prints.

Layout handled (RINEX 2.11 §5.1, RINEX 3.05 §5.1): header labels in columns 61–80; RINEX 3 epoch lines ``>`` with
one line per satellite (``A1,I2.2`` + 16-character fields ``F14.3,I1,I1``); RINEX 2 epoch lines with up to 12
satellites per line (continuation lines from column 33) and ⌈types/5⌉ lines of five 16-character fields per
satellite. Event flags 2–5 are skipped together with their header records; flag 1 (power failure) epochs are kept,
flag 6 (cycle-slip records) skipped. Satellite identifiers without a system letter are GPS (RINEX 2).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from distnav.errors import DataFileError
from distnav.formats.gnss.compressed import (
    COMPRESSED_MAGIC,
    _ends_with_newline,
    _text_lines,
    read_bytes,
    read_text_file,
)
from distnav.formats.gnss.rinex_fields import epoch_time, glonass_slot_channels, parse_fields
from distnav.formats.text import text_bytes
from distnav.models.gnss.code_observations import ProgressCallback
from distnav.models.gnss.systems import SYSTEM_NAMES

__all__ = [
    "RinexHeader",
    "RawObservations",
    "SYSTEM_NAMES",
    "read_header",
    "read_lines",
    "parse_header",
    "observations_from_lines",
    "EpochSelection",
    "read_observation_types",
    "on_grid",
    "ProgressCallback",
    "read_bytes",
    "read_text_file",
    "COMPRESSED_MAGIC",
]

log = logging.getLogger(__name__)


_N_PRN = 40  # GPS PRNs 1..32 in use; room for test PRNs


@dataclass(frozen=True)
class RinexHeader:
    """What the readers need from an observation file header: ``gps_types`` (RINEX 2: all types), the RINEX 3
    types of every system, and the GLONASS frequency channels of ``GLONASS SLOT / FRQ #`` (``{"R01": 1, …}``)."""

    version: float
    file_type: str
    receiver: str
    marker: str
    position_ecef_m: np.ndarray
    gps_types: tuple[str, ...]
    time_system: str
    header_lines: int
    types_by_system: dict[str, tuple[str, ...]] = field(default_factory=dict)
    glonass_channels: dict[str, int] = field(default_factory=dict)

    def types_of(self, system: str) -> tuple[str, ...]:
        """The observation types of one system (RINEX 2: every type is shared; GPS, Galileo and GLONASS are read)."""
        if self.version < 3:
            return self.gps_types if system in RINEX2_SYSTEMS else ()
        return self.types_by_system.get(system, ())


@dataclass(frozen=True, eq=False)
class RawObservations:
    """GPS observations of the requested types: ``time`` (T,) datetime64[ns], ``svs`` (S,), ``values[type]``
    (T, S) float (NaN where blank), ``lli[type]`` (T, S) int8 loss-of-lock indicators (0 where blank)."""

    header: RinexHeader
    time: np.ndarray
    svs: tuple[str, ...]
    values: dict[str, np.ndarray]
    lli: dict[str, np.ndarray]


def read_lines(path: Path) -> list[str]:
    """The lines of an observation file (plain, compressed, Hatanaka), decoded as latin-1; read once, then give them
    to :func:`parse_header` and :func:`observations_from_lines` (Hatanaka decompression is most of a read)."""
    return _read_lines(path)


def parse_header(lines: Sequence[str], path: Path) -> RinexHeader:
    """The header of an observation file from its lines (:func:`read_lines`)."""
    return _parse_header(lines, path)


def _read_lines(path: Path) -> list[str]:
    raw = text_bytes(path, read_bytes(path))
    _ends_with_newline(path, raw)
    if b"COMPACT RINEX" in raw[:200] or b"CRINEX VERS" in raw[:200]:
        try:
            import hatanaka

            raw = hatanaka.decompress(raw)
        except ImportError:
            from distnav._optional import install_hint

            raise DataFileError(
                f"{path}: Hatanaka-compressed; install the 'hatanaka' package ({install_hint('gnss')})"
            ) from None
        except Exception:  # the hatanaka package raises its own and OS errors
            raise DataFileError(
                f"{path}: not valid Compact RINEX (Hatanaka) data: expected a .crx/.d file as written by rnx2crx"
            ) from None
        if isinstance(raw, str):
            raw = raw.encode("latin-1")
    return _text_lines(path, raw)


def _parse_header(lines: Sequence[str], path: Path) -> RinexHeader:
    version, ftype, receiver, marker, tsys = 0.0, "", "", "", "GPS"
    pos = np.full(3, np.nan)
    r2_types: list[str] = []
    r2_count = 0
    r3_types: dict[str, list[str]] = {}
    r3_sys = ""
    channels: dict[str, int] = {}
    end = -1
    for k, line in enumerate(lines):
        label = line[60:80].strip()
        if label == "END OF HEADER":
            end = k
            break
        if label == "RINEX VERSION / TYPE":
            try:
                version = float(line[:9])
            except ValueError:
                raise DataFileError(
                    f"{path}, line {k + 1}: the RINEX version (columns 1-9): expected a number such "
                    f"as 2.11 or 3.04, got {line[:9].strip()!r}"
                ) from None
            ftype = line[20:21]
        elif label == "REC # / TYPE / VERS":
            receiver = line[20:40].strip()
        elif label == "MARKER NAME":
            marker = line[:60].strip()
        elif label == "APPROX POSITION XYZ":
            try:
                pos = np.array([float(line[i : i + 14]) for i in (0, 14, 28)])
            except ValueError:
                pos = np.full(3, np.nan)
        elif label == "# / TYPES OF OBSERV":
            if line[:6].strip():
                if not line[:6].strip().isdigit():
                    raise DataFileError(
                        f"{path}, line {k + 1}: the number of observation types (columns 1-6): "
                        f"expected a whole number, got {line[:6].strip()!r}"
                    )
                r2_count = int(line[:6])
            # 9(4X,A2) in columns 7–60: the label (from column 61) is not a type
            r2_types += line[6:60].split()
        elif label == "SYS / # / OBS TYPES":
            if line[0] != " ":
                r3_sys = line[0]
                r3_types[r3_sys] = []
            r3_types.setdefault(r3_sys, []).extend(line[7 + 4 * i : 10 + 4 * i].strip() for i in range(13))
        elif label == "TIME OF FIRST OBS":
            tsys = line[48:51].strip() or "GPS"
        elif label == "GLONASS SLOT / FRQ #":
            glonass_slot_channels(line, channels)
    if end < 0:
        raise DataFileError(f"{path}: not a RINEX file (no END OF HEADER line)")
    if not version:
        raise DataFileError(f"{path}: no RINEX VERSION / TYPE line")
    types = [t for t in (r3_types.get("G", []) if version >= 3 else r2_types) if t]
    if version < 3 and r2_count and len(types) > r2_count:
        types = types[:r2_count]
    by_system = {k: tuple(t for t in v if t) for k, v in r3_types.items()} if version >= 3 else {}
    return RinexHeader(version, ftype, receiver, marker, pos, tuple(types), tsys, end + 1, by_system, channels)


def read_header(path: str | Path) -> RinexHeader:
    """The header of an observation file (see :class:`RinexHeader`)."""
    p = Path(path)
    return _parse_header(_read_lines(p), p)


def read_observation_types(
    path: str | Path,
    types: Sequence[str],
    *,
    tlim: tuple[np.datetime64, np.datetime64] | None = None,
    interval_s: float | None = None,
    progress: ProgressCallback | None = None,
    label: str | None = None,
    system: str = "G",
) -> RawObservations:
    """Read the observations of ``types`` of one satellite system (``system``: ``G`` GPS, ``E`` Galileo, ``C``
    BeiDou, ``R`` GLONASS, … — RINEX 3 only for systems other than GPS and Galileo), names as in the file: RINEX
    3 ``C1C``,
    RINEX 2 ``C1``/``P2``….

    ``tlim`` (inclusive datetime64 bounds) and ``interval_s`` (keep epochs whose time of day is a multiple) select
    epochs. Raises :class:`~distnav.errors.DataFileError` naming the file (and line) for unreadable content.
    """
    p = Path(path)
    lines = _read_lines(p)
    window = EpochSelection(tlim, interval_s)
    return observations_from_lines(p, lines, _parse_header(lines, p), types, window, progress, label, system)


@dataclass(frozen=True)
class EpochSelection:
    """The epochs read: ``tlim`` inclusive datetime64 bounds, ``interval_s`` a grid of the time of day."""

    tlim: tuple[np.datetime64, np.datetime64] | None = None
    interval_s: float | None = None


def observations_from_lines(
    p: Path,
    lines: Sequence[str],
    hdr: RinexHeader,
    types: Sequence[str],
    window: EpochSelection = EpochSelection(),
    progress: ProgressCallback | None = None,
    label: str | None = None,
    system: str = "G",
) -> RawObservations:
    """:func:`read_observation_types` on a file's lines already read (:func:`read_lines`) and its header."""
    if hdr.file_type not in ("O", ""):
        raise DataFileError(f"{p}: not a RINEX observation file (type {hdr.file_type!r})")
    columns = _type_columns(p, hdr, types, system)
    for fast in (True, False):  # anything wrong on the fast path: read line by line, which names the first problem
        scan = _Scan(p, lines, hdr, columns, system, progress if fast else None, label or p.name, fast=fast)
        scan.select(window.tlim, window.interval_s)
        try:
            scan.run()
            scan.parse_pending()
        except _Bad as exc:
            if fast:
                continue
            at = f" (epoch {str(scan.epoch)[:19]})" if scan.epoch is not None and "epoch" not in str(exc) else ""
            raise DataFileError(f"{p}, line {scan.k + 1}{at}: {exc}") from None
        break
    if progress is not None:
        progress(scan.name, 1.0)
    return scan.result(window.tlim)


def _type_columns(p: Path, hdr: RinexHeader, types: Sequence[str], system: str) -> list[int]:
    """The index of each requested type among the system's types in the header, or the error naming the missing."""
    name = SYSTEM_NAMES.get(system, system)
    if system not in RINEX2_SYSTEMS and hdr.version < 3:
        raise DataFileError(f"{p}: {name} observations are read from RINEX 3 files only (this file is RINEX 2)")
    have = hdr.types_of(system)
    missing = [t for t in types if t not in have]
    if missing:
        raise DataFileError(
            f"{p}: observation types {' '.join(missing)} not in the header ({name} types: {' '.join(have)})"
        )
    return [have.index(t) for t in types]


RINEX2_SYSTEMS = ("G", "E", "R")
"""Systems read from RINEX 2.11 files (their satellites share the file's types: ``C1``, ``C5``…)."""

_MAX_PRN = {"G": _N_PRN}  # GPS keeps its 1-39 (test PRNs above 32); other systems up to 63 (BeiDou C01-C63)
_MAX_PRN_OTHER = 64


class _Scan:
    """One pass over a file's observation records: the epochs kept and every non-blank value of the requested
    types of one system, collected as flat lists (epoch, PRN, type, value, loss-of-lock) and put into arrays once
    at the end (:meth:`result`). ``k`` (the line being read) and ``epoch`` name the place of an error
    (:class:`_Bad`). With ``fast`` the satellite lines are only collected and their fields parsed all at once by
    :func:`~distnav.formats.gnss.rinex_fields.parse_fields` (:meth:`parse_pending`; any malformed field raises
    :class:`_Bad` without a place: the caller reads line by line again, which names it)."""

    def __init__(
        self,
        path: Path,
        lines: Sequence[str],
        hdr: RinexHeader,
        columns: list[int],
        system: str,
        progress: ProgressCallback | None,
        name: str,
        *,
        fast: bool = False,
    ) -> None:
        self.path, self.lines, self.hdr, self.columns, self.system = path, lines, hdr, columns, system
        self.progress, self.name, self.fast = progress, name, fast
        self.pending: dict[tuple[int, ...], tuple[list[str], list[int], list[int]]] = {}
        self.cell_arrays: tuple[np.ndarray, ...] = ()
        self.layout: tuple[list[tuple[int, ...]], list[int]] | None = None
        self.types = [hdr.types_of(system)[c] for c in columns]
        self.n_prn = _MAX_PRN.get(system, _MAX_PRN_OTHER)
        self.k = hdr.header_lines
        self.epoch: np.datetime64 | None = None
        self.lo: Any = None
        self.hi: Any = None
        self.step_ns = 0
        self.times: list[np.datetime64] = []
        self.cells: tuple[list[int], list[int], list[int], list[float], list[int]] = ([], [], [], [], [])

    def select(self, tlim: tuple[np.datetime64, np.datetime64] | None, interval_s: float | None) -> None:
        if tlim is not None:
            self.lo, self.hi = (np.asarray(t).astype("datetime64[ns]")[()] for t in tlim)
        self.step_ns = int(round(interval_s * 1e9)) if interval_s else 0

    def run(self) -> None:
        lines, n_lines = self.lines, len(self.lines)
        epoch_record = self._rinex3_epoch if self.hdr.version >= 3 else self._rinex2_epoch
        next_report = 0.1
        while self.k < n_lines:
            if self.progress is not None and self.k / n_lines >= next_report:
                self.progress(self.name, self.k / n_lines)
                next_report += 0.1
            epoch_record(lines[self.k])

    def parse_pending(self) -> None:
        """The fields of the satellite lines collected on the fast path, as the arrays :attr:`cells` would give
        (:attr:`cell_arrays`; file order within one layout of fields, and the layouts of RINEX 2's lines hold
        different types, so a repeated satellite's last value wins as before)."""
        parts: list[tuple[np.ndarray, ...]] = []  # (the fast path leaves :attr:`cells` empty)
        for starts, (lines, epochs, prns) in self.pending.items():
            got = parse_fields(lines, starts)
            if got is None:
                raise _Bad("a malformed observation field")
            values, lli, present = got
            rows, cols = np.nonzero(present)
            parts.append((np.asarray(epochs)[rows], np.asarray(prns)[rows], cols, values[rows, cols], lli[rows, cols]))
        self.cell_arrays = tuple(np.concatenate(c) for c in zip(*parts, strict=True))
        self.pending = {}

    def _sink(self, starts: tuple[int, ...]) -> tuple[list[str], list[int], list[int]]:
        """The fast path's lists (lines, epoch rows, PRNs) of the lines with the field ``starts``."""
        got = self.pending.get(starts)
        if got is None:
            got = self.pending[starts] = ([], [], [])
        return got

    def _line(self, line: str, starts: tuple[int, ...], prn: int) -> None:
        """The values of one satellite's line(s) at the field ``starts`` (one per requested type; -1: not on
        this line) into :attr:`cells` (on the fast path: the line kept for :meth:`parse_pending`)."""
        t = len(self.times)
        if self.fast:
            got = self._sink(starts)
            got[0].append(line)
            got[1].append(t)
            got[2].append(prn)
            return
        ti, pi, ji, vi, li = self.cells
        for j, a in enumerate(starts):
            if a < 0:
                continue
            f = line[a : a + 14]
            if not f or f.isspace():
                continue
            try:
                if len(f) != 14 or f[10] != ".":
                    raise ValueError
                value = float(f)
            except ValueError:
                raise _Bad(
                    f"{self.types[j]} of {self.system}{prn:02d} (columns {a + 1}-{a + 14}): expected a number in "
                    f"F14.3 (e.g. '  22000000.123'), got {f!r}"
                ) from None
            ll = line[a + 14 : a + 15]
            if ll and ll != " " and not "0" <= ll <= "9":
                raise _Bad(
                    f"loss-of-lock indicator of {self.types[j]}, {self.system}{prn:02d} (column {a + 15}): "
                    f"expected a digit 0-7, got {ll!r}"
                )
            ti.append(t)
            pi.append(prn)
            ji.append(j)
            vi.append(value)
            li.append(ord(ll) - 48 if ll and ll != " " else 0)

    def _rinex3_epoch(self, line: str) -> None:
        """One RINEX 3 epoch (``>`` line, one line per satellite), from the line ``k``."""
        if not line.startswith(">"):
            self.k += 1
            return
        flag = _int(line[31:32] or "0", "the event flag (column 32)", "0-6")
        nsat = _int(line[32:35], "the number of satellites (columns 33-35)", "a whole number")
        if flag > 1:
            self.k += 1 + (nsat if flag in (2, 3, 4, 5, 6) else 0)
            return
        self.epoch = t = _epoch(line[2:6], line[7:9], line[10:12], line[13:15], line[16:18], line[18:29])
        start = self.k + 1
        sat_lines = self.lines[start : start + nsat]
        _complete(len(sat_lines), nsat, "satellite lines")
        self.k = start + nsat
        if not _keep(t, self.lo, self.hi, self.step_ns):
            return
        self._check_order(t, start - 1)
        system = self.system
        starts = tuple(3 + 16 * c for c in self.columns)
        sink: tuple[list[str], list[int], list[int]] | None = None  # the fast path's lists, without a call a line
        t_row = len(self.times)
        for i, sl in enumerate(sat_lines):
            self.k = start + i
            if sl[:1] != system or not sl[1:3].strip().isdigit():
                if not (sl[:1].isalpha() and sl[1:3].strip().isdigit()):
                    raise _Bad(
                        f"expected a satellite line starting with its id (e.g. G01) in columns 1-3, got {sl[:12]!r}"
                    )
                continue
            prn = _prn(sl[1:3], system, self.n_prn)
            if self.fast:
                if sink is None:
                    sink = self._sink(starts)
                sink[0].append(sl)
                sink[1].append(t_row)
                sink[2].append(prn)
                continue
            self._line(sl, starts, prn)
        self.k = start + nsat
        self.times.append(t)

    def _check_order(self, t: np.datetime64, line_index: int) -> None:
        """Epochs must follow one another (a repeated or out-of-order epoch would count its data twice or end in
        the levelling's "epoch times must be one increasing series", naming no file)."""
        if self.times and not t > self.times[-1]:
            self.k = line_index
            raise _Bad(
                f"epoch {str(t)[:19]} is not after the previous epoch {str(self.times[-1])[:19]} (a repeated or "
                f"out-of-order epoch: the file is not one time series)"
            )

    def _rinex2_layout(self, n_per_sat: int) -> tuple[list[tuple[int, ...]], list[int]]:
        """The field starts of the requested types on each of a satellite's RINEX 2 lines, and the lines that hold
        any (the same for every epoch of the file: computed once)."""
        if self.layout is None:
            cols = self.columns
            per_line = [tuple(16 * (c % 5) if c // 5 == r else -1 for c in cols) for r in range(n_per_sat)]
            self.layout = per_line, [r for r in range(n_per_sat) if any(a >= 0 for a in per_line[r])]
        return self.layout

    def _rinex2_epoch(self, line: str) -> None:
        """One RINEX 2 epoch (satellite list on the epoch line and its continuations, ⌈types/5⌉ lines per
        satellite), from the line ``k``."""
        lines, n_lines = self.lines, len(self.lines)
        if not line.strip():
            self.k += 1
            return
        k0 = self.k
        flag = _int(line[28:29] or "0", "the event flag (column 29)", "0-6")
        nsat = _int(line[29:32], "the number of satellites (columns 30-32)", "a whole number")
        if flag > 1:
            self.k += 1 + (nsat if flag in (2, 3, 4, 5, 6) else 0)
            return
        sats = [line[32 + 3 * i : 35 + 3 * i] for i in range(min(nsat, 12))]
        yy = _int(line[1:3], "the year (columns 2-3)", "two digits")
        self.epoch = t = _epoch(
            str(yy + (2000 if yy < 80 else 1900)), line[4:6], line[7:9], line[10:12], line[13:15], line[15:26]
        )
        self.k += 1
        while len(sats) < nsat:
            _complete(n_lines - self.k, 1, "satellite continuation lines")
            cont = lines[self.k]
            sats += [cont[32 + 3 * i : 35 + 3 * i] for i in range(min(nsat - len(sats), 12))]
            self.k += 1
        n_per_sat = (len(self.hdr.gps_types) + 4) // 5
        start = self.k
        block = list(lines[start : start + nsat * n_per_sat])
        if start + nsat * n_per_sat - n_lines in range(1, n_per_sat):
            block += [""] * (start + nsat * n_per_sat - n_lines)  # the last satellite's blank lines left out
        self.k = k0
        _complete(len(block), nsat * n_per_sat, "observation lines")
        self.k = start + nsat * n_per_sat
        if not _keep(t, self.lo, self.hi, self.step_ns):
            return
        self._check_order(t, k0)
        per_line, used = self._rinex2_layout(n_per_sat)
        # the fast path keeps the lines for parse_pending: appended here without a call per line
        sinks: list[tuple[list[str], list[int], list[int]]] | None = None
        t_row = len(self.times)
        for s, sv in enumerate(sats):
            if sv[:1] != self.system and not (self.system == "G" and sv[:1] == " "):
                continue
            self.k = k0  # a bad satellite list is on the epoch line (or its continuation)
            prn = _prn(sv[1:3], self.system, self.n_prn)
            if self.fast:
                if sinks is None:  # made at the first satellite kept (as the per-line path would)
                    sinks = [self._sink(per_line[r]) for r in used]
                for r, (keep_lines, keep_t, keep_prn) in zip(used, sinks, strict=True):
                    keep_lines.append(block[s * n_per_sat + r])
                    keep_t.append(t_row)
                    keep_prn.append(prn)
                continue
            for r in used:
                self.k = start + s * n_per_sat + r
                self._line(block[s * n_per_sat + r], per_line[r], prn)
        self.k = start + nsat * n_per_sat
        self.times.append(t)

    def result(self, tlim: Any) -> RawObservations:
        """The epochs kept and the satellites seen with any of the types (PRN order)."""
        p, name, types = self.path, SYSTEM_NAMES.get(self.system, self.system), self.types
        if not self.times:
            within = ""
            if tlim is not None:
                t0, t1 = (str(np.datetime64(t, "s")) for t in tlim)
                within = f" between {t0} and {t1} (GPS time; --tlim)"
            raise DataFileError(f"{p}: no {name} observation epochs{within}")
        shape = (len(self.times), self.n_prn, len(types))
        V = np.full(shape, np.nan)  # (T, PRN, types)
        L = np.zeros(shape, np.int8)
        ti, pi, ji, vi, li = self.cell_arrays or tuple(np.asarray(c) for c in self.cells)
        if ti.size:
            V[ti, pi, ji] = vi
            L[ti, pi, ji] = li
        seen = np.flatnonzero(np.isfinite(V).any(axis=(0, 2)))
        if seen.size == 0:
            raise DataFileError(f"{p}: no {name} satellites observed with {' '.join(types)}")
        svs = tuple(f"{self.system}{prn:02d}" for prn in seen.tolist())
        log.debug("%s: %d epochs, %d %s satellites, types %s", self.name, len(self.times), len(svs), name, types)
        return RawObservations(
            self.hdr,
            np.array(self.times, dtype="datetime64[ns]"),
            svs,
            {t: V[:, seen, j] for j, t in enumerate(types)},
            {t: L[:, seen, j] for j, t in enumerate(types)},
        )


class _Bad(Exception):
    """A malformed field; the reader adds the file, line and epoch."""


def _int(text: str, what: str, expected: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise _Bad(f"{what}: expected {expected}, got {text.strip()!r}") from None


def _prn(text: str, system: str = "G", n_prn: int = _N_PRN) -> int:
    try:
        prn = int(text)
    except ValueError:
        prn = -1
    if not 0 < prn < n_prn:
        raise _Bad(f"satellite number {text!r}: expected a {SYSTEM_NAMES.get(system, system)} PRN 01-{n_prn - 1}")
    return prn


def _epoch(year: str, month: str, day: str, hour: str, minute: str, second: str) -> np.datetime64:
    fields = (year, month, day, hour, minute)
    try:
        y, mo, d, h, mi = (int(f) for f in fields)
        sec = float(second)
        return epoch_time(y, mo, d, h, mi, sec)
    except ValueError:
        got = " ".join(f.strip() for f in (*fields, second))
        raise _Bad(
            f"the epoch: expected year month day hour minute second (e.g. 2024 01 10 00 00 30.0000000), got {got!r}"
        ) from None


def _complete(have: int, need: int, what: str) -> None:
    if have < need:
        raise _Bad(f"the epoch announces {need} {what}, the file ends after {have}: the file is truncated")


def on_grid(time: np.ndarray, interval_s: float) -> np.ndarray:
    """Epochs (datetime64) whose time of day is a multiple of ``interval_s``."""
    t = np.asarray(time).astype("datetime64[ns]")
    ns = (t - t.astype("datetime64[D]")).astype(np.int64)
    return np.asarray(ns % int(round(interval_s * 1e9)) == 0)


def _keep(t: np.datetime64, lo: Any, hi: Any, step_ns: int) -> bool:
    if lo is not None and t < lo:
        return False
    if hi is not None and t > hi:
        return False
    if step_ns:
        ns = int((t - t.astype("datetime64[D]")).astype(np.int64))
        return ns % step_ns == 0
    return True
