"""Readers of published code-bias products: Bias-SINEX (``.BIA``/``.BSX``, gzip too) and the differential
code-bias block of IONEX files (between ``START OF AUX DATA`` and ``END OF AUX DATA``).

Bias-SINEX 1.00 ``+BIAS/SOLUTION`` lines have fixed columns (``*BIAS SVN_ PRN STATION__ OBS1 OBS2 BIAS_START____
BIAS_END______ UNIT __ESTIMATED_VALUE____ _STD_DEV___``); a satellite line has the PRN and no station, a station
line a system letter in SVN and PRN and the station name. The reader takes the fixed columns and checks them
against the whitespace tokens (10 for a satellite line, 11 for a station line), so a malformed line is reported
with its file and line number. The GFZ product carries a non-ASCII byte in its header: files are decoded as
latin-1, which accepts any byte.

Sign convention (Bias-SINEX): a DSB ``OBS1−OBS2`` is the bias of OBS1 minus the bias of OBS2, both biases adding
to the observations of receiver *and* satellite. :func:`resolve_dsb` chains DSBs (``C1C−C2W = (C1C−C1W) +
(C1W−C2W)``), taking as many terms as possible from the first product given.
"""

from __future__ import annotations

import gzip
import itertools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from distnav._checks import real_number
from distnav.errors import DataFileError, ModelError

__all__ = [
    "BiasRecord",
    "BiasProduct",
    "read_bias_sinex",
    "IonexDCB",
    "read_ionex_dcb",
    "resolve_dsb",
    "sinex_time",
    "session_length",
    "write_bias_sinex",
    "BiasSinexHeader",
]


def _read_text_lines(path: Path) -> list[str]:
    from distnav.formats.gnss.rinex_obs import read_text_file  # gzip, .Z, bzip2, zip by content

    return read_text_file(path, whole_lines=True)


_COLUMNS = (
    "the fixed columns of '*BIAS SVN_ PRN STATION__ OBS1 OBS2 BIAS_START____ BIAS_END______ UNIT "
    "__ESTIMATED_VALUE____ _STD_DEV___'"
)


@dataclass(frozen=True)
class BiasRecord:
    """One ``+BIAS/SOLUTION`` line. ``prn`` is ``""`` for a station bias, ``station`` ``""`` for a satellite."""

    kind: str
    svn: str
    prn: str
    station: str
    obs1: str
    obs2: str
    start: str
    end: str
    unit: str
    value: float
    std: float
    line: int

    @property
    def system(self) -> str:
        return (self.prn or self.svn)[:1]


@dataclass(frozen=True)
class BiasProduct:
    """The bias records of one Bias-SINEX file, with look-ups by satellite or station."""

    path: Path
    agency: str
    records: tuple[BiasRecord, ...]
    _sat: dict[tuple[str, str, str], BiasRecord] = field(default_factory=dict, repr=False, compare=False)
    _sta: dict[tuple[str, str, str, str], BiasRecord] = field(default_factory=dict, repr=False, compare=False)

    def __post_init__(self) -> None:
        for r in self.records:
            if r.kind != "DSB":
                continue
            if r.prn and not r.station:
                self._sat.setdefault((r.prn, r.obs1, r.obs2), r)
            elif r.station:
                self._sta.setdefault((r.station[:4].upper(), r.system, r.obs1, r.obs2), r)

    @property
    def name(self) -> str:
        return self.agency or self.path.name[:3]

    def satellites(self, system: str = "G") -> tuple[str, ...]:
        return tuple(sorted({k[0] for k in self._sat if k[0].startswith(system)}))

    def satellite_pairs(self, prn: str) -> list[tuple[str, str, float]]:
        """All DSBs ``(obs1, obs2, value_ns)`` given for a satellite."""
        return [(o1, o2, _ns(r)) for (p, o1, o2), r in self._sat.items() if p == prn]

    def station_pairs(self, station: str, system: str = "G") -> list[tuple[str, str, float]]:
        st = station[:4].upper()
        return [(o1, o2, _ns(r)) for (s, sy, o1, o2), r in self._sta.items() if s == st and sy == system]

    def satellite_dsb_ns(self, prn: str, obs1: str, obs2: str) -> float | None:
        """DSB ``obs1 − obs2`` of a satellite in ns, reversing the sign of a stored ``obs2 − obs1``; None if absent."""
        r = self._sat.get((prn, obs1, obs2))
        if r is not None:
            return _ns(r)
        r = self._sat.get((prn, obs2, obs1))
        return -_ns(r) if r is not None else None

    def station_dsb_ns(self, station: str, obs1: str, obs2: str, system: str = "G") -> float | None:
        st = station[:4].upper()
        r = self._sta.get((st, system, obs1, obs2))
        if r is not None:
            return _ns(r)
        r = self._sta.get((st, system, obs2, obs1))
        return -_ns(r) if r is not None else None


def _ns(r: BiasRecord) -> float:
    if r.unit.lower() != "ns":
        raise ModelError(f"bias of {r.prn or r.station} {r.obs1}-{r.obs2} (line {r.line}) is in {r.unit!r}, not ns")
    return r.value


def read_bias_sinex(path: str | Path) -> BiasProduct:
    """Read a Bias-SINEX file (plain or gzip). Raises :class:`~distnav.errors.DataFileError` with the line number
    for a malformed ``+BIAS/SOLUTION`` line, or when the file has no such block."""
    p = Path(path)
    lines = _read_text_lines(p)
    if not lines or not lines[0].startswith("%=BIA"):
        raise DataFileError(
            f"{p}, line 1: not a Bias-SINEX file: expected a first line starting with '%=BIA', got "
            f"{(lines[0] if lines else '')[:20]!r}"
        )
    head = lines[0].split()
    agency = head[2] if len(head) > 2 else ""
    records: list[BiasRecord] = []
    inside = False
    seen_block = False
    opened = 0
    for no, line in enumerate(lines, start=1):
        if line.startswith("+BIAS/SOLUTION"):
            inside, seen_block, opened = True, True, no
            continue
        if line.startswith("-BIAS/SOLUTION"):
            inside = False
            continue
        if not inside or line.startswith("*") or not line.strip():
            continue
        tokens = line.split()
        kind = line[1:5].strip()
        svn = line[6:10].strip()
        prn = line[11:14].strip()
        station = line[15:24].strip()
        obs1 = line[25:29].strip()
        obs2 = line[30:34].strip()
        start = line[35:49].strip()
        end = line[50:64].strip()
        unit = line[65:69].strip()
        value = _number(p, no, line, 70, 91, "the estimated value")
        std = _number(p, no, line, 92, 103, "the standard deviation") if line[92:103].strip() else float("nan")
        expected = 11 if station else 10
        if not obs2:
            expected -= 1  # OSB lines have no second observation code
        if kind not in ("DSB", "OSB", "ISB") or tokens[0] != kind:
            raise DataFileError(
                f"{p}, line {no}: malformed +BIAS/SOLUTION line: expected DSB, OSB or ISB in "
                f"columns 2-4 ({_COLUMNS}), got {line.strip()[:40]!r}"
            )
        if len(tokens) != expected:
            raise DataFileError(
                f"{p}, line {no}: malformed +BIAS/SOLUTION line: {len(tokens)} fields where a "
                f"{'station' if station else 'satellite'} line has {expected} ({_COLUMNS}): "
                f"{line.strip()!r}"
            )
        records.append(
            BiasRecord(kind, svn, prn if len(prn) == 3 else "", station, obs1, obs2, start, end, unit, value, std, no)
        )
    if not seen_block:
        raise DataFileError(f"{p}: no +BIAS/SOLUTION block")
    if inside:
        raise DataFileError(
            f"{p}, line {len(lines)}: the +BIAS/SOLUTION block of line {opened} is not closed by "
            f"-BIAS/SOLUTION: the file is truncated"
        )
    return BiasProduct(path=p, agency=agency, records=tuple(records))


def _number(p: Path, no: int, line: str, a: int, b: int, what: str) -> float:
    try:
        value = float(line[a:b])
    except ValueError:
        value = math.nan
    if not math.isfinite(value):  # float() reads "nan" and "inf", which no product holds
        raise DataFileError(
            f"{p}, line {no}: malformed +BIAS/SOLUTION line: {what} (columns {a + 1}-{b}): expected "
            f"a finite number, got {line[a:b].strip()!r}"
        )
    return value


@dataclass(frozen=True)
class IonexDCB:
    """The DCB block of an IONEX file: satellite ``{prn: (bias_ns, rms_ns)}`` and station
    ``{(system, site): (bias_ns, rms_ns)}``; ``reference`` the ``Reference observables`` comments if any."""

    path: Path
    satellite: dict[str, tuple[float, float]]
    station: dict[tuple[str, str], tuple[float, float]]
    reference: dict[str, str]


def read_ionex_dcb(path: str | Path) -> IonexDCB:
    """Read the ``DIFFERENTIAL CODE BIASES`` block (``PRN / BIAS / RMS`` and ``STATION / BIAS / RMS`` lines)
    of an IONEX file header (plain or gzip). Satellite ids without a system letter are read as GPS."""
    p = Path(path)
    lines = _read_text_lines(p)
    sat: dict[str, tuple[float, float]] = {}
    sta: dict[tuple[str, str], tuple[float, float]] = {}
    ref: dict[str, str] = {}
    inside = False
    found = 0
    for no, line in enumerate(lines, start=1):
        label = line[60:].strip()
        if label == "START OF AUX DATA" and "DIFFERENTIAL CODE BIASES" in line[:60]:
            inside, found = True, no
            continue
        if label == "END OF AUX DATA":
            inside = False
            continue
        if label == "END OF HEADER":
            break
        if not inside:
            continue
        content = line[:60]
        try:
            if label == "PRN / BIAS / RMS":
                tok = content.split()
                if len(tok) != 3 or not (tok[0].isdigit() or (tok[0][:1].isalpha() and tok[0][1:].isdigit())):
                    raise ValueError
                prn = tok[0] if tok[0][:1].isalpha() else f"G{int(tok[0]):02d}"
                sat[prn] = (float(tok[-2]), float(tok[-1]))
            elif label == "STATION / BIAS / RMS":
                system = content[3:4].strip() or "G"
                site = content[6:10].strip().upper()
                tok = content[10:].split()
                if len(tok) < 2 or not site:
                    raise ValueError
                sta[(system, site)] = (float(tok[-2]), float(tok[-1]))
            elif label == "COMMENT" and content.startswith("Reference observables"):
                key, _, obs = content.partition(":")
                ref[key.replace("Reference observables for", "").strip()] = obs.strip()
        except (ValueError, IndexError):
            example = (
                "'   G01    -7.722     0.020' (satellite, bias ns, rms ns)"
                if label == "PRN / BIAS / RMS"
                else "'   G  ALIC    21.005     0.071' (system, station, bias ns, rms ns)"
            )
            raise DataFileError(
                f"{p}, line {no}: malformed IONEX DCB line: expected {example} in columns 1-60, "
                f"got {content.rstrip()!r}"
            ) from None
    if not found:
        raise DataFileError(f"{p}: no 'DIFFERENTIAL CODE BIASES / START OF AUX DATA' block in the IONEX header")
    if inside:
        raise DataFileError(
            f"{p}, line {len(lines)}: the DCB block of line {found} is not closed by "
            f"'END OF AUX DATA' before the end of the header: the file is truncated or malformed"
        )
    return IonexDCB(path=p, satellite=sat, station=sta, reference=ref)


def resolve_dsb(
    products: Sequence[BiasProduct],
    obs1: str,
    obs2: str,
    *,
    prn: str | None = None,
    station: str | None = None,
    system: str = "G",
) -> tuple[float, list[str]]:
    """The DSB ``obs1 − obs2`` [ns] of a satellite (``prn``) or station, chained through the DSBs of the products.

    Among all chains ``obs1 → … → obs2`` (a path in the graph of available code pairs), the one with the fewest
    DSBs from products other than the first is taken, then one that uses the first product at all, then the
    shortest. So with ``[GFZ, CAS]`` a C1C−C2W satellite DSB is formed as CAS C1C−C1W + GFZ C1W−C2W.
    Returns the value and the chain as text (e.g. ``["CAS C1C-C1W", "GFZ C1W-C2W"]``).
    Raises :class:`~distnav.errors.ModelError` when no chain exists.
    """
    if (prn is None) == (station is None):
        raise ModelError("resolve_dsb needs exactly one of prn= or station=")
    if obs1 == obs2:
        return 0.0, []
    edges: dict[frozenset[str], list[tuple[int, str, str, float]]] = {}
    for rank, prod in enumerate(products):
        pairs = prod.satellite_pairs(prn) if prn is not None else prod.station_pairs(station or "", system)
        for o1, o2, v in pairs:
            edges.setdefault(frozenset((o1, o2)), []).append((rank, o1, o2, v))
    nodes = sorted({c for k in edges for c in k})
    if obs1 not in nodes or obs2 not in nodes:
        what = prn if prn is not None else station
        raise ModelError(f"no {obs1}-{obs2} DSB for {what} in {', '.join(p.name for p in products)}")
    best: tuple[tuple[int, int, int], float, list[str]] | None = None
    middle = [c for c in nodes if c not in (obs1, obs2)]
    for length in range(0, min(len(middle), 4) + 1):
        for mids in itertools.permutations(middle, length):
            path = [obs1, *mids, obs2]
            options = [edges.get(frozenset((a, b))) for a, b in itertools.pairwise(path)]
            if any(o is None for o in options):
                continue
            value = 0.0
            chain: list[str] = []
            n_other = n_first = 0
            for (a, b), opts in zip(itertools.pairwise(path), options, strict=True):
                assert opts is not None
                rank, o1, o2, v = min(opts, key=lambda e: e[0])
                value += v if (o1, o2) == (a, b) else -v
                chain.append(f"{products[rank].name} {o1}-{o2}")
                n_first += rank == 0
                n_other += rank != 0
            key = (n_other, -int(n_first > 0), len(path))
            if best is None or key < best[0]:
                best = (key, value, chain)
    if best is None:
        what = prn if prn is not None else station
        raise ModelError(f"no chain of DSBs gives {obs1}-{obs2} for {what} in {', '.join(p.name for p in products)}")
    return best[1], best[2]


def sinex_time(t: object) -> str:
    """``YYYY:DDD:SSSSS`` (SINEX epoch) of a datetime64 / ISO string."""
    import numpy as np

    ts = np.asarray(t).astype("datetime64[s]")[()]
    day = ts.astype("datetime64[D]")
    year = int(str(day)[:4])
    doy = int((day - np.datetime64(f"{year}-01-01", "D")).astype(int)) + 1
    sec = int((ts - day).astype(int))
    return f"{year:04d}:{doy:03d}:{sec:05d}"


def _solution_line(
    svn: str, prn: str, station: str, obs1: str, obs2: str, start: str, end: str, value: float, std: float
) -> str:
    return f" DSB  {svn:<4} {prn:<3} {station:<9} {obs1:<4} {obs2:<4} {start} {end} ns   {value:21.4f} {std:11.4f}"


def session_length(seconds: float) -> str:
    """A session's length in words for the header: ``daily``, ``5-day``, ``6-hour``, ``90-minute``."""
    if seconds > 0 and seconds % 86400 == 0:
        days = int(seconds // 86400)
        return "daily" if days == 1 else f"{days}-day"
    if seconds > 0 and seconds % 3600 == 0:
        return f"{int(seconds // 3600)}-hour"
    return f"{seconds / 60:g}-minute"


def _comment_lines(comments: Sequence[str]) -> list[str]:
    """Comments wrapped at word boundaries to the 80 columns of a SINEX line (continuations indented)."""
    import textwrap

    out: list[str] = []
    for c in comments:
        out += textwrap.wrap(c, width=79, initial_indent=" ", subsequent_indent="   ", break_long_words=True) or [" "]
    return out


@dataclass(frozen=True, kw_only=True)
class BiasSinexHeader:
    """What a written Bias-SINEX file says about itself: the ``agency`` code (3 characters), the time it was
    ``created`` (default now), the ``FILE/REFERENCE`` ``description``, the ``OBSERVATION_SAMPLING`` [s], the
    ``FILE/COMMENT`` lines (wrapped at word boundaries) and the ``datum`` stated on the ``OUTPUT`` line."""

    agency: str = "DNV"
    created: object = None
    description: str = ""
    sampling_s: float = 30.0
    comments: Sequence[str] = ()
    datum: str = "zero-mean satellite datum"

    def __post_init__(self) -> None:
        if not (isinstance(self.agency, str) and 1 <= len(self.agency) <= 3 and self.agency.isascii()):
            raise DataFileError(f"a Bias-SINEX agency is 1 to 3 ASCII characters, got {self.agency!r}")
        if isinstance(self.comments, str):
            raise DataFileError("comments must be a list of lines, got one string")
        real_number(self.sampling_s, "sampling_s", positive=True, unit="s", error=DataFileError)


def write_bias_sinex(
    path: str | Path | None,
    *,
    obs1: str,
    obs2: str,
    start: object,
    end: object,
    satellites: Mapping[str, tuple[float, float]],
    stations: Mapping[str, tuple[float, float]],
    station_codes: Mapping[str, tuple[str, str]] | None = None,
    svns: Mapping[str, str] | None = None,
    header: BiasSinexHeader | None = None,
) -> Path | str:
    """Write satellite and station DSBs ``obs1 − obs2`` [ns] with σ as a Bias-SINEX 1.00 file (gzip if the name
    ends in ``.gz``): header line, ``FILE/REFERENCE``, ``FILE/COMMENT``, ``BIAS/DESCRIPTION`` (relative biases,
    GPS time) and ``BIAS/SOLUTION`` in the fixed columns of the format (those :func:`read_bias_sinex` reads).
    A bias without a value or a σ (not estimated) is left out and named in a comment — never written with σ = 0.
    ``svns``: each satellite's SVN (``G01`` → ``G063``, e.g. from a reference product: the SVN field is
    ``ANNN``); a satellite without one gets the system letter and a comment says so. Station biases carry the
    system letter in the SVN and PRN fields (as CAS and DLR write them). ``header``: :class:`BiasSinexHeader`; its
    ``OUTPUT`` line states the session length (:func:`session_length`) and the datum. ``path=None`` returns the
    text instead (for an atomic write by the caller). ``station_codes``: a station's own code pair where it
    differs from the satellites' (C1C receivers corrected to C1W)."""
    import numpy as np

    h = header if header is not None else BiasSinexHeader()
    t0, t1 = sinex_time(start), sinex_time(end)
    t_end, t_start = (np.asarray(x).astype("datetime64[s]")[()] for x in (end, start))
    spacing = int(round(float((t_end - t_start).astype(int))))
    sv_ids = svns or {}
    rows = _solution_rows((obs1, obs2), (t0, t1), (satellites, stations), station_codes or {}, sv_ids)
    notes = list(h.comments) + _omission_notes(satellites, stations, sv_ids)
    text = "\n".join(_file_lines(h, t0, t1, spacing, rows, notes)) + "\n"
    if path is None:
        return text
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    data = text.encode("ascii", errors="replace")
    p.write_bytes(gzip.compress(data) if p.name.lower().endswith(".gz") else data)
    return p


def _known(v: float, sd: float) -> bool:
    import math

    return math.isfinite(v) and math.isfinite(sd)


_Biases = Mapping[str, tuple[float, float]]
_Codes = Mapping[str, tuple[str, str]]
_Ids = Mapping[str, str]


def _solution_rows(
    pair: tuple[str, str], span: tuple[str, str], biases: tuple[_Biases, _Biases], own: _Codes, sv_ids: _Ids
) -> list[str]:
    """The ``BIAS/SOLUTION`` lines: satellites (SVN from ``sv_ids`` or the system letter), then stations on their
    ``own`` code pair where given; biases without a value or σ are left out. ``pair`` (obs1, obs2), ``span``
    (t0, t1), ``biases`` (satellites, stations)."""
    (obs1, obs2), (t0, t1), (satellites, stations) = pair, span, biases
    rows = [
        _solution_line(sv_ids.get(prn, prn[:1]), prn, "", obs1, obs2, t0, t1, v, sd)
        for prn, (v, sd) in sorted(satellites.items())
        if _known(v, sd)
    ]
    system = next(iter(sorted(satellites)), "G")[:1]  # a station's DSB belongs to the satellites' system
    rows += [
        _solution_line(system, system, sta.upper(), *own.get(sta, (obs1, obs2)), t0, t1, v, sd)
        for sta, (v, sd) in sorted(stations.items())
        if _known(v, sd)
    ]
    return rows


def _omission_notes(
    satellites: Mapping[str, tuple[float, float]],
    stations: Mapping[str, tuple[float, float]],
    sv_ids: Mapping[str, str],
) -> list[str]:
    """Comments naming the biases left out (no value or σ) and the satellites written without an SVN."""
    notes = []
    left_out = [k for k, (v, sd) in sorted({**satellites, **stations}.items()) if not _known(v, sd)]
    if left_out:
        notes.append(f"not estimated (left out, no value or sigma): {' '.join(left_out)}")
    no_svn = [prn for prn, (v, sd) in sorted(satellites.items()) if _known(v, sd) and prn not in sv_ids]
    if no_svn:
        notes.append(f"SVN unknown (no reference product gave it; SVN field = system letter): {' '.join(no_svn)}")
    return notes


def _file_lines(h: BiasSinexHeader, t0: str, t1: str, spacing: int, rows: list[str], notes: list[str]) -> list[str]:
    """Every line of the file, its blocks in the order of the format."""
    import numpy as np

    made = sinex_time(h.created if h.created is not None else np.datetime64("now", "s"))
    bar = "*" + "-" * 79
    return [
        f"%=BIA 1.00 {h.agency:<3} {made} {h.agency:<3} {t0} {t1} R {len(rows):08d}",
        bar,
        "+FILE/REFERENCE",
        "*INFO_TYPE_________ INFO" + "_" * 56,
        f" DESCRIPTION        {h.description or 'distnav geometry-free code DCBs (receivers and satellites)'}"[:80],
        f" OUTPUT             {session_length(spacing)} DSBs of satellites and receivers, {h.datum}"[:80],
        " SOFTWARE           distnav",
        "-FILE/REFERENCE",
        bar,
        "+FILE/COMMENT",
        *_comment_lines(notes),
        "-FILE/COMMENT",
        bar,
        "+BIAS/DESCRIPTION",
        "*KEYWORD________________________________ VALUE(S)" + "_" * 31,
        f" OBSERVATION_SAMPLING                    {int(round(h.sampling_s))}",
        f" PARAMETER_SPACING                       {spacing}",
        " DETERMINATION_METHOD                    INTER-FREQUENCY_BIAS_ESTIMATION",
        " BIAS_MODE                               RELATIVE",
        " TIME_SYSTEM                             G",
        "-BIAS/DESCRIPTION",
        bar,
        "+BIAS/SOLUTION",
        "*BIAS SVN_ PRN STATION__ OBS1 OBS2 BIAS_START____ BIAS_END______ UNIT __ESTIMATED_VALUE____ _STD_DEV___",
        *rows,
        "-BIAS/SOLUTION",
        "%=ENDBIA",
    ]
