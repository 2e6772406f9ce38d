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

import gzip
import io
import logging
import zipfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from distnav.errors import DataFileError
from distnav.models.gnss.code_observations import ProgressCallback

__all__ = [
    "RinexHeader",
    "RawObservations",
    "read_header",
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
    """What the readers need from an observation file header."""

    version: float
    file_type: str
    receiver: str
    marker: str
    position_ecef_m: np.ndarray
    gps_types: tuple[str, ...]
    time_system: str
    header_lines: int


@dataclass(frozen=True, eq=False)
class RawObservations:
    """GPS observations of the requested types: ``time`` (T,) datetime64[ns], ``svs`` (S,), ``values[type]``
    (T, S) float (NaN where blank), ``lli[type]`` (T, S) int8 loss-of-lock indicators (0 where blank)."""

    header: RinexHeader
    time: np.ndarray
    svs: tuple[str, ...]
    values: dict[str, np.ndarray]
    lli: dict[str, np.ndarray]


COMPRESSED_MAGIC = (b"\x1f\x9d", b"BZh", b"PK\x03\x04")  # Unix compress (.Z), bzip2, zip


def _unix_decompress(raw: bytes, path: Path) -> bytes:
    try:
        import ncompress  # installed with hatanaka (the gnss extra)
    except ImportError:
        from distnav._optional import install_hint

        raise DataFileError(
            f"{path}: Unix-compressed (.Z); install the 'ncompress' package ({install_hint('gnss')})"
        ) from None
    out: bytes = ncompress.decompress(raw)
    return out


def _decompress(path: Path, raw: bytes) -> bytes:
    """``raw`` decompressed by content (gzip, Unix compress, bzip2, zip; unchanged when none of them);
    :class:`DataFileError` naming the file and the format when the compressed data are broken."""
    if raw[:2] == b"\x1f\x8b":
        try:
            raw = gzip.decompress(raw)
        except EOFError:
            raise DataFileError(f"{path}: the gzip data end early (the file is truncated; download it again)") from None
        except OSError:  # gzip.BadGzipFile and zlib errors
            raise DataFileError(
                f"{path}: starts like gzip but is not valid gzip data (expected a .gz file written by gzip)"
            ) from None
    if raw.startswith(COMPRESSED_MAGIC):
        kind = "Unix compress (.Z)" if raw[:2] == b"\x1f\x9d" else "bzip2" if raw[:3] == b"BZh" else "zip"
        try:
            if raw[:2] == b"\x1f\x9d":
                raw = _unix_decompress(raw, path)
            elif raw[:3] == b"BZh":
                import bz2

                raw = bz2.decompress(raw)
            else:
                with zipfile.ZipFile(io.BytesIO(raw)) as z:
                    names = z.namelist()
                    if len(names) != 1:
                        raise DataFileError(f"{path}: a zip archive of {len(names)} files (one expected)")
                    raw = z.read(names[0])
        except (OSError, ValueError, EOFError, zipfile.BadZipFile):
            raise DataFileError(
                f"{path}: starts like {kind} data but could not be decompressed (truncated or "
                f"not {kind}; download it again)"
            ) from None
    return raw


def read_bytes(path: Path) -> bytes:
    """A file's bytes, decompressed by content: gzip, Unix compress (``.Z``, older IGS archives), bzip2, zip (Hatanaka
    compression is left to the caller)."""
    if not path.exists():
        raise DataFileError(f"{path}: file not found")
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise DataFileError(f"{path}: cannot read the file ({exc.strerror or 'read error'})") from None
    return _decompress(path, raw)


def _text_lines(path: Path, raw: bytes) -> list[str]:
    nul = raw.find(b"\x00")
    if nul >= 0:
        line = raw.count(b"\n", 0, nul) + 1
        raise DataFileError(
            f"{path}, line {line}: binary data (NUL bytes): expected a plain ASCII text file "
            f"(not UTF-16, not a binary format)"
        )
    return raw.decode("latin-1").splitlines()


def read_text_file(path: Path, *, whole_lines: bool = False) -> list[str]:
    """The lines of a plain or compressed (:func:`read_bytes`) text file, decoded as latin-1 (any byte is accepted);
    broken compressed data and a file with NUL bytes (binary data, UTF-16) are refused naming the file (and line).
    ``whole_lines``: a file that ends inside a line (no final newline: a cut download) is refused too."""
    raw = read_bytes(path)
    if whole_lines:
        _ends_with_newline(path, raw)
    return _text_lines(path, raw)


def _ends_with_newline(path: Path, raw: bytes) -> None:
    if raw and not raw.endswith(b"\n"):  # records are lines: a cut download ends inside one
        last = raw.count(b"\n") + 1
        raise DataFileError(f"{path}, line {last}: the file ends inside a line (no final newline): it is truncated")


def _read_lines(path: Path) -> list[str]:
    raw = read_bytes(path)
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
    if end < 0:
        raise DataFileError(f"{path}: not a RINEX file (no END OF HEADER line)")
    if not version:
        raise DataFileError(f"{path}: no RINEX VERSION / TYPE line")
    types = [t for t in (r3_types.get("G", []) if version >= 3 else r2_types) if t]
    if version < 3 and r2_count and len(types) > r2_count:
        types = types[:r2_count]
    return RinexHeader(version, ftype, receiver, marker, pos, tuple(types), tsys, end + 1)


def read_header(path: str | Path) -> RinexHeader:
    """The header of an observation file (see :class:`RinexHeader`)."""
    p = Path(path)
    return _parse_header(_read_lines(p), p)


def _epoch_time(y: int, mo: int, d: int, h: int, mi: int, sec: float) -> np.datetime64:
    base = np.datetime64(f"{y:04d}-{mo:02d}-{d:02d}T{h:02d}:{mi:02d}", "ns")
    return base + np.timedelta64(int(round(sec * 1e9)), "ns")


def read_observation_types(
    path: str | Path,
    types: Sequence[str],
    *,
    tlim: tuple[np.datetime64, np.datetime64] | None = None,
    interval_s: float | None = None,
    progress: ProgressCallback | None = None,
    label: str | None = None,
) -> RawObservations:
    """Read the GPS observations of ``types`` (names as in the file: RINEX 3 ``C1C``, RINEX 2 ``C1``/``P2``…).

    ``tlim`` (inclusive datetime64 bounds) and ``interval_s`` (keep epochs whose time of day is a multiple) select
    epochs. Raises :class:`~distnav.errors.DataFileError` naming the file (and line) for unreadable content.
    """
    p = Path(path)
    lines = _read_lines(p)
    hdr = _parse_header(lines, p)
    if hdr.file_type not in ("O", ""):
        raise DataFileError(f"{p}: not a RINEX observation file (type {hdr.file_type!r})")
    missing = [t for t in types if t not in hdr.gps_types]
    if missing:
        raise DataFileError(
            f"{p}: observation types {' '.join(missing)} not in the header (GPS types: {' '.join(hdr.gps_types)})"
        )
    idx = [hdr.gps_types.index(t) for t in types]
    name = label or p.name
    lo = hi = None
    if tlim is not None:
        lo, hi = (np.asarray(t).astype("datetime64[ns]")[()] for t in tlim)
    step_ns = int(round(interval_s * 1e9)) if interval_s else 0
    times: list[np.datetime64] = []
    rows: list[np.ndarray] = []
    lrows: list[np.ndarray] = []
    nt = len(types)
    n_lines = len(lines)
    next_report = 0.1
    k = hdr.header_lines
    rinex3 = hdr.version >= 3
    n_per_sat = (len(hdr.gps_types) + 4) // 5
    epoch: np.datetime64 | None = None
    try:
        while k < n_lines:
            if progress is not None and k / n_lines >= next_report:
                progress(name, k / n_lines)
                next_report += 0.1
            line = lines[k]
            if rinex3:
                if not line.startswith(">"):
                    k += 1
                    continue
                flag = _int(line[31:32] or "0", "the event flag (column 32)", "0-6")
                nsat = _int(line[32:35], "the number of satellites (columns 33-35)", "a whole number")
                if flag > 1:
                    k += 1 + (nsat if flag in (2, 3, 4, 5, 6) else 0)
                    continue
                epoch = t = _epoch(line[2:6], line[7:9], line[10:12], line[13:15], line[16:18], line[18:29])
                sat_lines = lines[k + 1 : k + 1 + nsat]
                _complete(len(sat_lines), nsat, "satellite lines")
                start = k + 1
                k += 1 + nsat
                if not _keep(t, lo, hi, step_ns):
                    continue
                vals = np.full((_N_PRN, nt), np.nan)
                lli = np.zeros((_N_PRN, nt), np.int8)
                for i, sl in enumerate(sat_lines):
                    k = start + i
                    if not (sl[:1].isalpha() and sl[1:3].strip().isdigit()):
                        raise _Bad(
                            f"expected a satellite line starting with its id (e.g. G01) in columns 1-3, got {sl[:12]!r}"
                        )
                    if sl[:1] != "G":
                        continue
                    prn = _prn(sl[1:3])
                    for j, c in enumerate(idx):
                        _value(sl, 3 + 16 * c, vals, lli, prn, j, types[j])
                k = start + nsat
            else:
                if not line.strip():
                    k += 1
                    continue
                k0 = k
                flag = _int(line[28:29] or "0", "the event flag (column 29)", "0-6")
                nsat = _int(line[29:32], "the number of satellites (columns 30-32)", "a whole number")
                if flag > 1:
                    k += 1 + (nsat if flag in (2, 3, 4, 5, 6) else 0)
                    continue
                sats = [line[32 + 3 * i : 35 + 3 * i] for i in range(min(nsat, 12))]
                yy = _int(line[1:3], "the year (columns 2-3)", "two digits")
                epoch = t = _epoch(
                    str(yy + (2000 if yy < 80 else 1900)), line[4:6], line[7:9], line[10:12], line[13:15], line[15:26]
                )
                k += 1
                while len(sats) < nsat:
                    _complete(n_lines - k, 1, "satellite continuation lines")
                    cont = lines[k]
                    sats += [cont[32 + 3 * i : 35 + 3 * i] for i in range(min(nsat - len(sats), 12))]
                    k += 1
                block = lines[k : k + nsat * n_per_sat]
                if k + nsat * n_per_sat - n_lines in range(1, n_per_sat):
                    block += [""] * (k + nsat * n_per_sat - n_lines)  # the last satellite's blank lines left out
                start, k = k, k0
                _complete(len(block), nsat * n_per_sat, "observation lines")
                k = start + nsat * n_per_sat
                if not _keep(t, lo, hi, step_ns):
                    continue
                vals = np.full((_N_PRN, nt), np.nan)
                lli = np.zeros((_N_PRN, nt), np.int8)
                for s, sv in enumerate(sats):
                    if sv[:1] not in ("G", " "):
                        continue
                    k = k0  # a bad satellite list is on the epoch line (or its continuation)
                    prn = _prn(sv[1:3])
                    for j, c in enumerate(idx):
                        k = start + s * n_per_sat + c // 5
                        _value(block[s * n_per_sat + c // 5], 16 * (c % 5), vals, lli, prn, j, types[j])
                k = start + nsat * n_per_sat
            times.append(t)
            rows.append(vals)
            lrows.append(lli)
    except _Bad as exc:
        at = f" (epoch {str(epoch)[:19]})" if epoch is not None and "epoch" not in str(exc) else ""
        raise DataFileError(f"{p}, line {k + 1}{at}: {exc}") from None
    if progress is not None:
        progress(name, 1.0)
    if not times:
        raise DataFileError(f"{p}: no GPS observation epochs" + (f" in {tlim}" if tlim is not None else ""))
    V = np.stack(rows)  # (T, PRN, types)
    L = np.stack(lrows)
    seen = np.flatnonzero(np.isfinite(V).any(axis=(0, 2)))
    if seen.size == 0:
        raise DataFileError(f"{p}: no GPS satellites observed with {' '.join(types)}")
    svs = tuple(f"G{prn:02d}" for prn in seen.tolist())
    log.debug("%s: %d epochs, %d GPS satellites, types %s", name, len(times), len(svs), types)
    return RawObservations(
        hdr,
        np.array(times, dtype="datetime64[ns]"),
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


def _prn(text: str) -> int:
    try:
        prn = int(text)
    except ValueError:
        prn = -1
    if not 0 < prn < _N_PRN:
        raise _Bad(f"satellite number {text!r}: expected a GPS PRN 01-{_N_PRN - 1}")
    return prn


def _epoch(year: str, month: str, day: str, hour: str, minute: str, second: str) -> np.datetime64:
    fields = (year, month, day, hour, minute)
    try:
        y, mo, d, h, mi = (int(f) for f in fields)
        sec = float(second)
        return _epoch_time(y, mo, d, h, mi, sec)
    except ValueError:
        got = " ".join(f.strip() for f in (*fields, second))
        raise _Bad(
            f"the epoch: expected year month day hour minute second (e.g. 2024 01 10 00 00 30.0000000), got {got!r}"
        ) from None


def _complete(have: int, need: int, what: str) -> None:
    if have < need:
        raise _Bad(f"the epoch announces {need} {what}, the file ends after {have}: the file is truncated")


def _value(line: str, start: int, vals: np.ndarray, lli: np.ndarray, prn: int, j: int, obs_type: str) -> None:
    """One F14.3 observation (columns ``start``+1..+14) and its loss-of-lock digit into ``vals``/``lli``."""
    f = line[start : start + 14]
    if not f.strip():
        return
    ok = len(f) == 14 and f[10] == "."
    try:
        value = float(f) if ok else 0.0
    except ValueError:
        ok = False
    if not ok:
        raise _Bad(
            f"{obs_type} of G{prn:02d} (columns {start + 1}-{start + 14}): expected a number in F14.3 "
            f"(e.g. '  22000000.123'), got {f!r}"
        )
    vals[prn, j] = value
    ll = line[start + 14 : start + 15]
    if ll.strip():
        if not ll.isdigit():
            raise _Bad(
                f"loss-of-lock indicator of {obs_type}, G{prn:02d} (column {start + 15}): expected a digit "
                f"0-7, got {ll!r}"
            )
        lli[prn, j] = int(ll)


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
