"""Reading RINEX observation (2.11 / 3.x, Hatanaka and gzip too), navigation and SP3 files.

:func:`read_code_observations` picks, per GPS band, the first code observation type present in the file from a
preference list and returns a :class:`CodeObservations` (pseudo-ranges in metres, NaN where missing):

* L1: ``C1C``, ``C1W`` (RINEX 2: ``C1`` → C1C, ``P1`` → C1W)
* L2: ``C2W``, ``C2L``, ``C2X``, ``C2S`` (RINEX 2: ``P2`` → C2W, ``C2`` → the receiver's L2C code)
* L5: ``C5Q``, ``C5X``, ``C5I`` (RINEX 2: ``C5`` → C5Q or C5X depending on the receiver)

RINEX 2 does not say which tracking mode ``C2``/``C5`` are; :data:`RINEX2_RECEIVER_ATTRIBUTES` maps the receiver
make to the RINEX 3 attribute (Septentrio: L2C = C2L, L5 = C5Q — as CAS lists DGAR's receiver DSB as C1C−C5Q;
Trimble: C2X, C5X), and the choice is recorded in ``CodeObservations.notes``.

Observation files are read by :mod:`distnav.formats.gnss.rinex_obs` (own reader, latin-1, ≈ 2 s per full day of
30-s data, progress callback), navigation files by :mod:`distnav.formats.gnss.rinex_nav` (own reader, one pass),
SP3 files by georinex.
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from distnav._optional import require
from distnav.errors import DataFileError
from distnav.formats.gnss.rinex_nav import _ints, check_navigation_file, read_ephemerides
from distnav.formats.gnss.rinex_obs import (
    COMPRESSED_MAGIC,
    SYSTEM_NAMES,
    EpochSelection,
    ProgressCallback,
    observations_from_lines,
    parse_header,
    read_bytes,
    read_lines,
    read_text_file,
)
from distnav.models.gnss.code_observations import CodeObservations
from distnav.models.gnss.orbits import BroadcastOrbit, SP3Orbit

__all__ = [
    "CodeObservations",
    "read_code_observations",
    "read_stations",
    "read_navigation",
    "read_sp3",
    "check_navigation_file",
    "check_sp3_file",
    "CODE_PREFERENCE",
    "SYSTEM_CODE_PREFERENCE",
    "RINEX2_RECEIVER_ATTRIBUTES",
    "RINEX2_GALILEO_ATTRIBUTES",
    "RINEX2_GLONASS_TYPES",
]

CODE_PREFERENCE: dict[int, tuple[str, ...]] = {
    1: ("C1C", "C1W"),
    2: ("C2W", "C2L", "C2X", "C2S"),
    5: ("C5Q", "C5X", "C5I"),
}
"""Default RINEX 3 code preference per GPS band (first present wins)."""

SYSTEM_CODE_PREFERENCE: dict[str, dict[int, tuple[str, ...]]] = {
    "G": CODE_PREFERENCE,
    "E": {1: ("C1C", "C1X"), 5: ("C5Q", "C5X"), 7: ("C7Q", "C7X"), 8: ("C8Q", "C8X"), 6: ("C6C", "C6X")},
    "C": {2: ("C2I", "C2X"), 6: ("C6I", "C6X"), 7: ("C7I", "C7X")},
    "R": {1: ("C1C", "C1P"), 2: ("C2C", "C2P")},
}
"""Default RINEX 3 code preference per system and band (Galileo pilot Q before data+pilot X, as CAS's C1C−C5Q;
BeiDou B1I/B3I/B2I; GLONASS C/A before P)."""

_RINEX2_FIXED = {"C1": "C1C", "P1": "C1W", "P2": "C2W"}
RINEX2_RECEIVER_ATTRIBUTES: dict[str, dict[str, str]] = {
    "SEPT": {"C2": "C2L", "C5": "C5Q"},
    "TRIMBLE": {"C2": "C2X", "C5": "C5X"},
    "JAVAD": {"C2": "C2X", "C5": "C5X"},
    "TPS": {"C2": "C2X", "C5": "C5X"},
    "LEICA": {"C2": "C2S", "C5": "C5Q"},
}
"""RINEX 2 ``C2``/``C5`` → RINEX 3 code by receiver make (substring of the receiver type, upper case)."""
_RINEX2_DEFAULT = {"C2": "C2X", "C5": "C5X"}


def _georinex() -> Any:
    return require("georinex", "gnss")


def _rinex2_attribute_map(receiver: str) -> tuple[dict[str, str], str]:
    rx = receiver.upper()
    for key, mapping in RINEX2_RECEIVER_ATTRIBUTES.items():
        if key in rx:
            return {**_RINEX2_FIXED, **mapping}, key
    return {**_RINEX2_FIXED, **_RINEX2_DEFAULT}, ""


def _station_name(marker: str, path: Path) -> str:
    """The 4-character site code: first four letters of the file name (RINEX 2 ``dgar0100.24o`` and RINEX 3
    ``BELE00BRA_R_...`` alike), else of the marker name."""
    stem = path.name[:4]
    if len(stem) == 4 and stem.isalnum():
        return stem.upper()
    name = marker.strip() or "RCVR"
    return name.split()[0][:4].upper()


def _phase_type(band: int, code: str, file_code: str, types: Sequence[str], rinex3: bool) -> str | None:
    """The carrier-phase type that goes with a code: the same tracking mode if recorded (L1C with C1C), else any
    phase of the band (the phase bias of another mode is constant and goes into the arc offset of levelling)."""
    if not rinex3:
        return f"L{band}" if f"L{band}" in types else None
    same = "L" + code[1:]
    if same in types:
        return same
    return next((t for t in types if t.startswith(f"L{band}")), None)


def _to_datetime64(t: Any) -> np.datetime64:
    try:
        return np.datetime64(t, "ns")
    except ValueError:
        raise DataFileError(f"time {t!r} is not an ISO date/time (e.g. 2024-01-10T06:00)") from None


def read_code_observations(
    path: str | Path,
    *,
    bands: Sequence[int] = (1, 2, 5),
    codes: Mapping[int, str] | None = None,
    tlim: tuple[Any, Any] | None = None,
    interval_s: float | None = None,
    phases: bool = False,
    progress: ProgressCallback | None = None,
    system: str = "G",
    channels: Mapping[str, int] | None = None,
) -> CodeObservations:
    """Read the code observations of one system (``system``: ``G`` GPS, ``E`` Galileo, ``C`` BeiDou — RINEX 3
    only for the others) of one RINEX 2.11/3.x observation file (``.o``, ``.d``, ``.crx``, ``.gz``).

    ``codes`` forces the RINEX 3 code of a band (e.g. ``{1: "C1W"}``); otherwise the system's preference list
    (:data:`SYSTEM_CODE_PREFERENCE`) decides. ``tlim=(start, stop)`` reads a time window (ISO strings or
    datetimes, inclusive), ``interval_s`` keeps only epochs on that grid. ``phases=True`` also reads a carrier
    phase per band (``phase_m``, metres, and the loss-of-lock indicators ``lli``; a band without phase is left out
    of ``phase_m``). ``progress(label, fraction)`` is called while reading (see
    :mod:`distnav.formats.gnss.rinex_obs`, the reader). ``channels``: GLONASS FDMA channels where the header has
    none (RINEX 2; e.g. :meth:`~distnav.models.gnss.glonass.GlonassOrbit.channels` of the navigation file). Raises
    :class:`~distnav.errors.DataFileError` naming the file for an unreadable file, a file without data of the
    system, or a band with none of the accepted codes.
    """
    p = Path(path)
    lines = read_lines(p)
    hdr = parse_header(lines, p)
    if hdr.file_type not in ("O", ""):
        raise DataFileError(f"{p}: not a RINEX observation file (type {hdr.file_type!r})")
    if system not in SYSTEM_CODE_PREFERENCE:
        raise DataFileError(f"system {system!r}: expected one of {' '.join(SYSTEM_CODE_PREFERENCE)}")
    types = list(hdr.types_of(system))
    if not types:
        raise DataFileError(f"{p}: no {SYSTEM_NAMES[system]} observation types in the header")
    forced = dict(codes or {})
    if hdr.version >= 3:
        chosen = _rinex3_codes(p, types, bands, forced, system)
        file_types, notes = dict(chosen), list[str]()
    else:
        chosen, file_types, notes = _rinex2_codes(p, types, bands, forced, hdr.receiver, system)
    phase_types: dict[int, str] = {}
    for b in bands if phases else ():
        ph = _phase_type(b, chosen[b], file_types[b], types, hdr.version >= 3)
        if ph is not None:
            phase_types[b] = ph
    window = None if tlim is None else (_to_datetime64(tlim[0]), _to_datetime64(tlim[1]))
    wanted = sorted(set(file_types.values()) | set(phase_types.values()))
    station = _station_name(hdr.marker, p)
    raw = observations_from_lines(p, lines, hdr, wanted, EpochSelection(window, interval_s), progress, station, system)
    ranges = _ranges_m(raw.values, file_types)
    channel = {**(channels or {}), **hdr.glonass_channels}
    phase_m, lli = _phases_m(raw, phase_types, ranges, system, channel)
    return CodeObservations(
        station=station,
        path=p,
        time=raw.time,
        svs=raw.svs,
        codes=chosen,
        range_m=ranges,
        position_ecef_m=hdr.position_ecef_m,
        receiver=hdr.receiver,
        rinex_version=hdr.version,
        notes=tuple(notes),
        phase_m=phase_m,
        lli=lli,
        phase_types={b: t for b, t in phase_types.items()},
        time_system=hdr.time_system,
        channels={sv: k for sv, k in channel.items() if sv in raw.svs and system == "R"},
    )


def _rinex3_codes(
    p: Path, types: Sequence[str], bands: Sequence[int], forced: Mapping[int, str], system: str
) -> dict[int, str]:
    """The code read per band of a RINEX 3 file: the forced one or the first of the preference list present."""
    chosen: dict[int, str] = {}
    for b in bands:
        prefs = (forced[b],) if b in forced else SYSTEM_CODE_PREFERENCE[system].get(b, ())
        hit = next((c for c in prefs if c in types), None)
        if hit is None:
            raise DataFileError(
                f"{p}: no L{b} code observation ({'/'.join(prefs)}) for {SYSTEM_NAMES[system]}; "
                f"types present: {' '.join(t for t in types if t.startswith('C'))}"
            )
        chosen[b] = hit
    return chosen


def _rinex2_codes(
    p: Path, types: Sequence[str], bands: Sequence[int], forced: Mapping[int, str], receiver: str, system: str = "G"
) -> tuple[dict[int, str], dict[int, str], list[str]]:
    """The RINEX 3 code and the RINEX 2 type read per band of a RINEX 2 file, and the notes on the types whose
    tracking mode the receiver make decides (GPS ``C2``/``C5``: :data:`RINEX2_RECEIVER_ATTRIBUTES`; Galileo:
    :data:`RINEX2_GALILEO_ATTRIBUTES`)."""
    if system == "R":
        amap, make = dict(RINEX2_GLONASS_TYPES), ""
    else:
        amap, make = _rinex2_attribute_map(receiver) if system == "G" else _rinex2_galileo_map(receiver)
    inverse: dict[str, list[str]] = {}
    for r2, r3 in amap.items():
        inverse.setdefault(r3, []).append(r2)
    chosen: dict[int, str] = {}
    file_types: dict[int, str] = {}
    notes: list[str] = []
    for b in bands:
        prefs = (forced[b],) if b in forced else SYSTEM_CODE_PREFERENCE[system].get(b, ())
        pair = next(((c3, r2) for c3 in prefs for r2 in inverse.get(c3, []) if r2 in types), None)
        if pair is None:
            r2_names = [r2 for c3 in prefs for r2 in inverse.get(c3, [])]
            raise DataFileError(
                f"{p}: no L{b} code observation ({'/'.join(r2_names) or '/'.join(prefs)}) in this RINEX 2 "
                f"file; types present: {' '.join(types)}"
            )
        chosen[b], file_types[b] = pair
        if (system == "G" and pair[1] in ("C2", "C5")) or system == "E":
            notes.append(
                f"RINEX 2 {pair[1]} read as {pair[0]} "
                f"({'receiver ' + make if make else 'unknown receiver make: default'})"
            )
    return chosen, file_types, notes


RINEX2_GALILEO_ATTRIBUTES: dict[str, str] = {"SEPT": "CQQQ", "LEICA": "CQQQ", "TRIMBLE": "XXXX", "JAVAD": "XXXX"}
"""Galileo in RINEX 2.11 (``C1 C5 C7 C8``): the RINEX 3 attributes of E1, E5a, E5b, E5 by receiver make
(Septentrio tracks the pilots: C1C C5Q C7Q C8Q, as CAS lists DGAR's receiver DSB C1C−C5Q; Trimble data+pilot X);
an unknown make gets X."""


RINEX2_GLONASS_TYPES: dict[str, str] = {"C1": "C1C", "P1": "C1P", "C2": "C2C", "P2": "C2P"}
"""GLONASS in RINEX 2.11: C/A and P code on G1 and G2 (RINEX 2.11 §5.1; no tracking-mode ambiguity)."""


def _rinex2_galileo_map(receiver: str) -> tuple[dict[str, str], str]:
    rx = receiver.upper()
    make = next((k for k in RINEX2_GALILEO_ATTRIBUTES if k in rx), "")
    attributes = RINEX2_GALILEO_ATTRIBUTES.get(make, "XXXX")
    return {f"C{b}": f"C{b}{a}" for b, a in zip("1578", attributes, strict=True)}, make


def _ranges_m(values: Mapping[str, np.ndarray], file_types: Mapping[int, str]) -> dict[int, np.ndarray]:
    """The pseudo-ranges per band; blanks, zeros and values outside 10,000–50,000 km (garbage) are NaN."""
    ranges: dict[int, np.ndarray] = {}
    for b, name in file_types.items():
        arr = values[name].copy()
        with np.errstate(invalid="ignore"):
            arr[(arr < 1.0e7) | (arr > 5.0e7)] = np.nan  # blanks / zeros / garbage are not ranges
        ranges[b] = arr
    return ranges


def _phases_m(
    raw: Any,
    phase_types: Mapping[int, str],
    ranges: Mapping[int, np.ndarray],
    system: str,
    channels: Mapping[str, int],
) -> tuple[dict[int, np.ndarray], dict[int, np.ndarray]]:
    """The carrier phases per band in metres (cycles × the band's wavelength; NaN where the code is missing) and
    their loss-of-lock indicators."""
    from distnav.models.gnss.constants import C_M_S
    from distnav.models.gnss.systems import carrier_frequencies_hz

    phase_m: dict[int, np.ndarray] = {}
    lli: dict[int, np.ndarray] = {}
    for b, name in phase_types.items():
        arr = raw.values[name] * (C_M_S / carrier_frequencies_hz(system, b, raw.svs, channels))
        arr[~np.isfinite(ranges[b]) | (raw.values[name] == 0.0)] = np.nan
        phase_m[b] = arr
        lli[b] = raw.lli[name]
    return phase_m, lli


def check_sp3_file(path: str | Path) -> None:
    """The format checks of an SP3 file before georinex reads it (see :func:`check_navigation_file`): the first
    line (``#a``–``#d``, the start epoch), every epoch line and position record, and the closing ``EOF``."""
    p = Path(path)
    lines = read_text_file(p, whole_lines=True)
    first = lines[0] if lines else ""
    if first[:2] not in ("#a", "#b", "#c", "#d"):
        raise DataFileError(
            f"{p}, line 1: expected an SP3 file starting with '#a', '#b', '#c' or '#d', got {first[:20]!r}"
        )
    _ints(p, 1, first, [(3, 7), (8, 10), (11, 13)], "the start date", "year month day as in '#dP2020  6 25'")
    epochs = 0
    for no, line in enumerate(lines, start=1):
        if line.startswith("*"):
            epochs += 1
            _ints(
                p,
                no,
                line,
                [(3, 7), (8, 10), (11, 13), (14, 16), (17, 19)],
                "the epoch",
                "year month day hour minute as in '*  2020  6 25  0  0  0.00000000'",
            )
        elif line.startswith("P"):
            for a in (4, 18, 32):
                f = line[a : a + 14]
                try:
                    float(f)
                except ValueError:
                    raise DataFileError(
                        f"{p}, line {no}: columns {a + 1}-{a + 14} of {line[1:4]}: expected a "
                        f"coordinate in km such as ' -11562.163582', got {f.strip()!r}"
                    ) from None
    if not epochs:
        raise DataFileError(f"{p}: no epoch lines ('*  YYYY MM DD ...'): not an SP3 orbit file")
    if lines[-1].strip() != "EOF":
        raise DataFileError(f"{p}, line {len(lines)}: the file does not end with 'EOF': it is truncated")


def read_navigation(
    path: str | Path, *, max_age_s: float = 2 * 3600.0, systems: Sequence[str] = ("G",)
) -> BroadcastOrbit:
    """Broadcast ephemerides of the ``systems`` (GPS by default; ``E`` Galileo and ``C`` BeiDou from a RINEX 3
    mixed file such as BRDC00IGS_R_…_MN.rnx) of a RINEX 2 or 3 navigation file (gzip too;
    :mod:`distnav.formats.gnss.rinex_nav`). ``max_age_s`` bounds |t − toe| (the ±2 h fit interval by default)."""
    p = Path(path)
    columns = read_ephemerides(p, systems=systems)
    if not columns:
        names = "/".join(SYSTEM_NAMES.get(s, s) for s in systems)
        raise DataFileError(f"{p}: no {names} navigation records")
    return BroadcastOrbit.from_records(columns, max_age_s=max_age_s, source=str(p))


def read_sp3(paths: str | Path | Sequence[str | Path], *, order: int = 9, system: str = "G") -> SP3Orbit:
    """The orbits of one system (GPS by default; ``E`` Galileo, ``C`` BeiDou of a multi-GNSS product) of one or
    more SP3 files (consecutive days are concatenated), Lagrange-interpolated."""
    items = [paths] if isinstance(paths, (str, Path)) else list(paths)
    gr = _georinex()
    datasets = []
    for item in items:
        p = Path(item)
        check_sp3_file(p)
        with p.open("rb") as fh:
            magic = fh.read(4)
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                if magic.startswith(COMPRESSED_MAGIC):  # .Z / bzip2 / zip: georinex needs unlzw3 for .Z
                    import io

                    from georinex.sp3 import load_sp3

                    ds = load_sp3(io.StringIO(read_bytes(p).decode("latin-1")), None)
                else:
                    ds = gr.load(p)
        except Exception:  # georinex's messages quote Python internals; the checks above found nothing specific
            raise DataFileError(
                f"{p}: could not be read as SP3 orbits although its epochs and records look "
                f"well-formed (expected SP3-c/d position records)"
            ) from None
        if ds is None or "position" not in getattr(ds, "data_vars", {}):
            raise DataFileError(f"{p}: not an SP3 orbit file")
        datasets.append(ds)
    return SP3Orbit.from_datasets(datasets, system=system, order=order, source=", ".join(str(i) for i in items))


def _first_code_as_band_1(o: CodeObservations, first: int) -> CodeObservations:
    """The first code under key 1 (the models' first signal), whatever its RINEX band (BeiDou B1I is band 2);
    ``codes[1]`` keeps its real name, so its frequency stays known (:meth:`CodeObservations.frequencies_hz`)."""
    if first == 1:
        return o

    def rekey(d: Mapping[int, Any]) -> dict[int, Any]:
        return {(1 if b == first else b): v for b, v in d.items()}

    return replace(
        o,
        codes=rekey(o.codes),
        range_m=rekey(o.range_m),
        phase_m=rekey(o.phase_m),
        lli=rekey(o.lli),
        phase_types=rekey(o.phase_types),
    )


def read_stations(
    paths: Sequence[str | Path],
    *,
    l1_code: str,
    l2_code: str,
    tlim: tuple[str, str] | None = None,
    interval_s: float | None = None,
    phases: bool = False,
    progress: ProgressCallback | None = None,
    l1_fallback: str | None = None,
    system: str = "G",
    channels: Mapping[str, int] | None = None,
) -> list[CodeObservations]:
    """Read the first and second codes (bands from the codes: ``C5X`` → L5, ``C2I`` → BeiDou B1I) of one system
    (``system``: ``G`` GPS, ``E`` Galileo, ``C`` BeiDou, ``R`` GLONASS; RINEX 2.11 mixed files for Galileo and
    GLONASS too) of every station, the first code under key 1 whatever its band; a file without ``l1_code`` is
    read with ``l1_fallback`` when given (a mixed C1W / C1C-only network). ``channels``: GLONASS FDMA channels
    for files whose header has none."""
    if not paths:
        raise DataFileError("no observation file given")
    band, first = int(l2_code[1]), int(l1_code[1])
    codes = {first: l1_code.upper(), band: l2_code.upper()}
    bands = (first, band)

    common: dict[str, Any] = {"bands": bands, "tlim": tlim, "interval_s": interval_s, "phases": phases}
    common.update(progress=progress, system=system, channels=channels)

    def read(p: str | Path) -> CodeObservations:
        try:
            return read_code_observations(p, codes=codes, **common)
        except DataFileError as exc:
            if l1_fallback is None or "no L1 code observation" not in str(exc):
                raise
        return read_code_observations(p, codes={**codes, first: l1_fallback.upper()}, **common)

    def read_any_mode(p: str | Path) -> CodeObservations:
        """Galileo: a station without the named code of a band is read with its own (C1C/C5Q for C1X/C5X)."""
        try:
            return read(p)
        except DataFileError as exc:
            if system == "G" or "code observation" not in str(exc):
                raise
        o = read_code_observations(p, **common)
        note = (
            f"codes {o.codes[first]}/{o.codes[band]} (no {codes[first]}/{codes[band]}): its receiver DSB is of its "
            "own pair"
        )
        return replace(o, notes=(*o.notes, note))

    obs = [_first_code_as_band_1(read_any_mode(p), first) for p in paths]
    stations = [o.station for o in obs]
    dup = sorted({s for s in stations if stations.count(s) > 1})
    if dup:
        twice = ", ".join(str(o.path) for o in obs if o.station == dup[0])
        raise DataFileError(f"station {dup[0]} is given twice ({twice})")
    for o in obs:
        pos = o.position_ecef_m
        if not (np.all(np.isfinite(pos)) and np.linalg.norm(pos) > 6.0e6):
            raise DataFileError(f"{o.path}: no usable APPROX POSITION XYZ in the header ({pos.tolist()})")
    return obs
