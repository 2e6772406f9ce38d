"""Corrupted input files through every reader and the CLI (issue 15 item 4): each ends in a project error that names
the file and, where it can be known, the line and what was expected — never a quoted numpy/georinex/codec/gzip
message, never a traceback, never a silently accepted truncated file.

Seeds: small valid files written here (RINEX 2.11 / 3.04 observations, Bias-SINEX, IONEX DCB block, UWB range and
position CSVs, an APRIL log) and the heads of three real files read in place from ``../shared/data`` (RINEX 2 and 3
navigation, SP3; those cases skip without the data). Each seed is corrupted in the generic ways (empty, cut in
half, cut mid-line, binary junk, junk after the header, NUL bytes, UTF-16, a broken or fake gzip) and the
format's own (a bad number in a known line, shifted columns, a missing header label, a record cut short).
"""

from __future__ import annotations

import gzip
import re
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from distnav.errors import DistnavError
from test_gnss_bias_sinex import IONEX  # the DCB block of an IONEX header (G01, G32, R01; ALBH, ALIC)

# what a message must never contain: the text of the library (or builtin) exception it came from
LIBRARY_TEXT = re.compile(
    r"could not convert|invalid literal|index out of range|out of bounds|Errno|codec can't|can't decode|"
    r"gzipped file|end-of-stream|Compressed file|georinex|xarray|pandas|numpy|ValueError|IndexError|KeyError|"
    r"TypeError|EOFError|OSError|BadGzipFile|UnicodeDecodeError|Traceback|unconverted data|does not match format|"
    r"line contains NUL|not enough values|too many values|has no attribute|object is not|NoneType|"
    r"Expecting|codec|hatanaka\.",
    re.IGNORECASE,
)

# ---------------------------------------------------------------------------------------------------- seeds
R2_OBS = """\
     2.11           OBSERVATION DATA    G (GPS)             RINEX VERSION / TYPE
DGAR                                                        MARKER NAME
5101              SEPT POLARX5        5.5.0                 REC # / TYPE / VERS
  1916240.0000  6006997.0000  -801083.0000                  APPROX POSITION XYZ
     7    C1    P1    P2    L1    L2    S1    S2            # / TYPES OF OBSERV
  2024     1    10     0     0    0.0000000     GPS         TIME OF FIRST OBS
                                                            END OF HEADER
 24  1 10  0  0  0.0000000  0  2G01G02
  22000000.123    22000000.456    22000002.789   115610000.123 7  90084000.456 7
        45.000          40.000
  23000000.123    23000000.456    23000002.789   120865000.123 7  94180000.456 7
        44.000          39.000
 24  1 10  0  0 30.0000000  0  2G01G02
  22000100.123    22000100.456    22000102.789   115610525.123 7  90084409.456 7
        45.000          40.000
  23000100.123    23000100.456    23000102.789   120865525.123 7  94180409.456 7
        44.000          39.000
"""
R2_OBS_DATA_LINE = 9  # the first observation line (1-based)

R3_OBS = """\
     3.04           OBSERVATION DATA    G                   RINEX VERSION / TYPE
BELE                                                        MARKER NAME
3001              TRIMBLE ALLOY       5.45                  REC # / TYPE / VERS
  4229012.0000 -4770778.0000 -1113150.0000                  APPROX POSITION XYZ
G    4 C1C L1C C2W L2W                                      SYS / # / OBS TYPES
  2024     1    10     0     0    0.0000000     GPS         TIME OF FIRST OBS
                                                            END OF HEADER
> 2024 01 10 00 00  0.0000000  0  2
G01  22000000.123   115610000.123 7  22000002.789    90084000.456 7
G02  23000000.123   120865000.123 7  23000002.789    94180000.456 7
> 2024 01 10 00 00 30.0000000  0  2
G01  22000100.123   115610525.123 7  22000102.789    90084409.456 7
G02  23000100.123   120865525.123 7  23000102.789    94180409.456 7
"""
R3_OBS_DATA_LINE = 9

IONEX_DATA_LINE = 4

RANGES = "a,b,range_m\nA1,A2,5.012\nA1,A3,7.250\nA2,A3,4.100\nA3,A4,6.000\nA1,A4,8.020\n"
POSITIONS = "id,x_m,y_m,z_m\nA1,0.0,0.0,1.5\nA2,5.0,0.0,1.5\nA3,2.5,4.0,1.5\n"
APRIL = (
    "0.5312093098958 12 8 32.50 9337 14091 64 -108.14 -82.90\n"
    "0.5313971103766 12 8 32.50 10129 14323 60 -108.21 -83.05\n"
    "0.5313032101362 14 61 32.50 8723 12860 72 -107.19 -83.36\n"
    "0.5313971103766 54 8 32.50 9253 14379 60 -110.07 -82.86\n"
)


def _bias_sinex() -> str:
    from distnav.formats.gnss.bias_sinex import BiasSinexHeader, write_bias_sinex

    text = write_bias_sinex(
        None,
        obs1="C1C",
        obs2="C2W",
        start="2024-01-10",
        end="2024-01-11",
        satellites={"G01": (1.25, 0.01), "G02": (-2.5, 0.02)},
        stations={"DGAR": (10.5, 0.1)},
        header=BiasSinexHeader(created="2024-01-12"),
    )
    assert isinstance(text, str)
    return text


def _shared_head(
    shared: Path, rel: str, *, lines: int | None = None, until: Callable[[list[str]], int] | None = None
) -> str:
    p = shared / rel
    raw = gzip.decompress(p.read_bytes()) if p.name.endswith(".gz") else p.read_bytes()
    text = raw.decode("latin-1").splitlines()
    n = until(text) if until is not None else (lines or len(text))
    return "\n".join(text[:n]) + "\n"


def _nav3_seed(shared: Path | None) -> str:
    """The header and the first three healthy GPS records of the IGS merged RINEX 3 navigation file."""
    assert shared is not None
    text = _shared_head(shared, "gnss/igs_2024010_bele_dgar/BRDC00IGS_R_20240100000_01D_MN.rnx.gz").splitlines()
    end = next(k for k, line in enumerate(text) if "END OF HEADER" in line)
    starts = [
        k
        for k in range(end + 1, len(text))
        if text[k].startswith("G") and float(text[k + 6][23:42].replace("D", "E")) == 0.0
    ][:3]  # healthy ones
    return "\n".join(text[: end + 1] + [line for k in starts for line in text[k : k + 8]]) + "\n"


def _sp3_head(text: list[str]) -> int:
    epochs = [k for k, line in enumerate(text) if line.startswith("*  ")]
    return epochs[3]  # header + three epochs


# ------------------------------------------------------------------------------------------------- readers
def _read_r2(p: Path) -> Any:
    from distnav.formats.gnss.rinex import read_code_observations

    return read_code_observations(p, bands=(1, 2))


def _read_nav(p: Path) -> Any:
    from distnav.formats.gnss.rinex import read_navigation

    return read_navigation(p)


def _read_sp3(p: Path) -> Any:
    from distnav.formats.gnss.rinex import read_sp3

    return read_sp3(p)


def _read_bia(p: Path) -> Any:
    from distnav.formats.gnss.bias_sinex import read_bias_sinex

    return read_bias_sinex(p)


def _read_ionex(p: Path) -> Any:
    from distnav.formats.gnss.bias_sinex import read_ionex_dcb

    return read_ionex_dcb(p)


def _read_ranges(p: Path) -> Any:
    from distnav.formats.uwb.io import read_ranges

    return read_ranges(p)


def _read_positions(p: Path) -> Any:
    from distnav.formats.uwb.io import read_positions

    return read_positions(p)


def _read_april(p: Path) -> Any:
    from distnav.formats.uwb.april import read_april

    return read_april(p)


@dataclass(frozen=True)
class Format:
    name: str
    suffix: str
    read: Callable[[Path], Any]
    seed: Callable[[Path | None], str]  # argument: the shared data folder (None for the hand-written seeds)
    shared: bool = False
    # format-specific corruptions: id -> (old, new, the 1-based line the message must name or None)
    edits: tuple[tuple[str, str, str, int | None], ...] = ()
    header_end: str | None = None  # the line after which the data begin (for "junk after the header")


def _line(text: str, number: int) -> str:
    return text.splitlines()[number - 1]


FORMATS: tuple[Format, ...] = (
    Format(
        "rinex2-obs",
        ".24o",
        _read_r2,
        lambda _: R2_OBS,
        header_end="END OF HEADER",
        edits=(
            ("bad-number", "22000000.123    22000000.456", "2200x000.123    22000000.456", R2_OBS_DATA_LINE),
            ("bad-epoch-second", " 0 30.0000000  0  2G01G02", " 0 3x.0000000  0  2G01G02", 13),
            ("bad-satellite-count", "0.0000000  0  2G01G02", "0.0000000  0  xG01G02", 8),
            ("bad-prn", "  2G01G02\n  22000000", "  2GxxG02\n  22000000", 8),
            ("shifted-columns", " 24  1 10  0  0 30.0000000", "    24  1 10  0  0 30.0000000", 13),
            ("bad-version", "     2.11           OBSERVATION", "     2.x1           OBSERVATION", 1),
            ("no-types", "     7    C1    P1    P2    L1    L2    S1    S2            # / TYPES OF OBSERV\n", "", None),
            ("bad-types-count", "     7    C1    P1", "    xx    C1    P1", 5),
            ("bad-lli", "  22000000.123    22000000.456", "  22000000.123x   22000000.456", R2_OBS_DATA_LINE),
            (
                "truncated-epoch",
                "        45.000          40.000\n  23000100.123    23000100.456    23000102.789   "
                "120865525.123 7  94180409.456 7\n        44.000          39.000\n",
                "        45.000          40.000\n",
                13,
            ),
            ("nav-type", "OBSERVATION DATA    G (GPS)", "NAVIGATION DATA     G (GPS)", None),
        ),
    ),
    Format(
        "rinex3-obs",
        ".rnx",
        _read_r2,
        lambda _: R3_OBS,
        header_end="END OF HEADER",
        edits=(
            ("bad-number", "G01  22000000.123   115610000.123", "G01  2200x000.123   115610000.123", R3_OBS_DATA_LINE),
            ("bad-epoch-year", "> 2024 01 10 00 00 30.0", "> 20x4 01 10 00 00 30.0", 11),
            ("bad-month", "> 2024 01 10 00 00 30.0", "> 2024 13 10 00 00 30.0", 11),
            ("bad-satellite-count", "30.0000000  0  2", "30.0000000  0  x", 11),
            ("bad-prn", "G02  23000100.123", "Gx2  23000100.123", 13),
            ("shifted-columns", "G01  22000100.123", "   G01  22000100.123", 12),
            ("no-gps-types", "G    4 C1C L1C C2W L2W  ", "E    4 C1C L1C C2W L2W  ", None),
            ("bad-version", "     3.04           OBSERVATION", "     3.x4           OBSERVATION", 1),
            (
                "no-end-of-header",
                "                                                            END OF HEADER\n",
                "",
                None,
            ),
        ),
    ),
    Format(
        "rinex2-nav",
        ".21n",
        _read_nav,
        lambda s: _shared_head(s, "gnss/nl_2021001_short_network_snapshot/cbw10010.21n.gz", lines=8 + 3 * 8),
        shared=True,
        header_end="END OF HEADER",
        edits=(
            ("bad-number", "5.200000000000D+01-7.362500000000D+01", "5.200000000000D+01-7.36x500000000D+01", 10),
            ("bad-epoch", " 1 21  1  1  2  0  0.0", " 1 21 1x  1  2  0  0.0", 9),
            ("bad-prn", " 1 21  1  1  2  0  0.0", "xx 21  1  1  2  0  0.0", 9),
            (
                "shifted-columns",
                "    5.200000000000D+01-7.362500000000D+01",
                "       5.200000000000D+01-7.362500000000D+01",
                10,
            ),
            ("bad-version", "     2.11           N: GPS NAV DATA", "     x.11           N: GPS NAV DATA", 1),
            ("obs-type", "     2.11           N: GPS NAV DATA", "     2.11           O: GPS NAV DATA", None),
        ),
    ),
    Format(
        "rinex3-nav",
        ".rnx",
        _read_nav,
        lambda s: _nav3_seed(s),
        shared=True,
        header_end="END OF HEADER",
        edits=(("bad-version", "     3.04           N: GNSS", "     3.x4           N: GNSS", 1),),
    ),
    Format(
        "sp3",
        ".sp3",
        _read_sp3,
        lambda s: (
            _shared_head(
                s, "gnss/esbc_2020177_single_station_L5_sp3/GRG0MGXFIN_20201770000_01D_15M_ORB.SP3.gz", until=_sp3_head
            )
            + "EOF\n"
        ),
        shared=True,
        header_end="/* CCCCCCCCCCCCCCCCCCCCCCCCCCCCCCCCCCCCCCCCCCCCCCCCCCCCCCCCC",
        edits=(
            ("bad-number", "PE01 -11562.163582", "PE01 -11x62.163582", 24),
            ("bad-epoch", "*  2020  6 25  0  0  0.00000000", "*  2020 x6 25  0  0  0.00000000", 23),
            ("bad-first-line", "#cP2020  6 25", "#cPxx20  6 25", 1),
            ("shifted-columns", "PE01 -11562.163582", "PE01    -11562.163582", 24),
        ),
    ),
    Format(
        "bias-sinex",
        ".BIA",
        _read_bia,
        lambda _: _bias_sinex(),
        header_end="*BIAS SVN_",
        edits=(
            ("bad-number", "1.2500      0.0100", "1.2x00      0.0100", None),
            ("bad-std", "1.2500      0.0100", "1.2500      0.0x00", None),
            ("extra-field", " DSB  G    G01", " DSB  G    G01 X", None),
            ("shifted-columns", " DSB  G    G02", "    DSB  G    G02", None),
            ("bad-kind", " DSB  G    G02", " XYZ  G    G02", None),
            ("no-end-of-block", "-BIAS/SOLUTION\n%=ENDBIA\n", "", None),
            ("bad-first-line", "%=BIA 1.00", "%=XYZ 1.00", 1),
        ),
    ),
    Format(
        "ionex-dcb",
        ".24i",
        _read_ionex,
        lambda _: IONEX,
        header_end="START OF AUX DATA",
        edits=(
            ("bad-number", "-7.722     0.020", "-7.7x2     0.020", IONEX_DATA_LINE),
            ("bad-rms", "-7.722     0.020", "-7.722     0.0x0", IONEX_DATA_LINE),
            ("missing-rms", "   G01    -7.722     0.020     ", "   G01    -7.722               ", IONEX_DATA_LINE),
            ("bad-prn", "   G32    -4.401", "   Gxx    -4.401", 5),
            ("bad-station-bias", "21.005     0.071", "21.0x5     0.071", 9),
            (
                "no-end-of-aux",
                "DIFFERENTIAL CODE BIASES                                    END OF AUX DATA\n",
                "",
                None,
            ),
            ("no-block", "DIFFERENTIAL CODE BIASES                                    START OF AUX DATA\n", "", None),
        ),
    ),
    Format(
        "uwb-ranges",
        ".csv",
        _read_ranges,
        lambda _: RANGES,
        header_end="a,b,range_m",
        edits=(
            ("bad-number", "A1,A3,7.250", "A1,A3,7.2x0", 3),
            ("extra-field", "A1,A3,7.250", "A1,A3,7.250,9", 3),
            ("missing-field", "A1,A3,7.250", "A1,7.250", 3),
            ("no-header", "a,b,range_m\n", "", 1),
            ("wrong-header", "a,b,range_m", "from,to,range", 1),
            ("semicolons", "A1,A2,5.012", "A1;A2;5.012", 2),
            ("self-range", "A1,A3,7.250", "A1,A1,7.250", 3),
        ),
    ),
    Format(
        "uwb-positions",
        ".csv",
        _read_positions,
        lambda _: POSITIONS,
        header_end="id,x_m,y_m,z_m",
        edits=(
            ("bad-number", "A2,5.0,0.0,1.5", "A2,5.0,0.x,1.5", 3),
            ("nan", "A2,5.0,0.0,1.5", "A2,5.0,nan,1.5", 3),
            ("missing-field", "A2,5.0,0.0,1.5", "A2,5.0,1.5", 3),
            ("duplicate", "A3,2.5,4.0,1.5", "A2,2.5,4.0,1.5", 4),
            ("wrong-header", "id,x_m,y_m,z_m", "id,x,y,z", 1),
        ),
    ),
    Format(
        "april-log",
        ".txt",
        _read_april,
        lambda _: APRIL,
        edits=(
            ("bad-number", "0.5313971103766 12 8", "0.53139x1103766 12 8", 2),
            ("bad-node", "0.5313032101362 14 61", "0.5313032101362 14 6x", 3),
            ("missing-columns", "0.5313971103766 54 8 32.50 9253 14379 60 -110.07 -82.86", "0.5313971103766 54", 4),
            ("unknown-node", "0.5313032101362 14 61", "0.5313032101362 14 99", None),
        ),
    ),
)


# ------------------------------------------------------------------------------------------------ mutations
def _generic(text: str, header_end: str | None) -> dict[str, tuple[bytes, str, int | None]]:
    """id -> (file bytes, file-name suffix to add, line the message must name or None)."""
    raw = text.encode("latin-1")
    lines = text.splitlines(keepends=True)
    rng = np.random.default_rng(15)
    junk = rng.integers(0, 256, 600, dtype=np.uint8).tobytes()
    cut_mid = "".join(lines[:-1]) + lines[-1][: len(lines[-1]) // 2]
    out = {
        "empty": (b"", "", None),
        "half": (raw[: len(raw) // 2], "", None),
        "cut-mid-line": (cut_mid.encode("latin-1"), "", None),
        "binary-junk": (junk, "", None),
        "nul-bytes": (raw[: len(raw) // 2] + b"\x00" * 40 + raw[len(raw) // 2 :], "", None),
        "utf16": (text.encode("utf-16"), "", None),
        "gzip-truncated": (gzip.compress(raw)[: len(gzip.compress(raw)) // 2], ".gz", None),
        "fake-gzip": (b"\x1f\x8b" + raw[2:], ".gz", None),
    }
    if header_end is not None:
        k = next(i for i, line in enumerate(lines) if header_end in line)
        out["junk-after-header"] = ("".join(lines[: k + 1]).encode("latin-1") + junk, "", None)
        out["header-only"] = ("".join(lines[: k + 1]).encode("latin-1"), "", None)
    return out


@dataclass(frozen=True)
class Case:
    id: str
    fmt: Format
    kind: str  # "generic" or "edit"
    key: str


GENERIC = ("empty", "half", "cut-mid-line", "binary-junk", "nul-bytes", "utf16", "gzip-truncated", "fake-gzip")
# A CSV or whitespace log has no end marker and no fixed columns: cut in half, or cut inside its last line, it is
# still a well-formed (shorter) file, so those two corruptions are not expected to be refused there.
NO_END_MARKER = ("uwb-ranges", "uwb-positions", "april-log")
CASES = [
    Case(f"{f.name}-{g}", f, "generic", g)
    for f in FORMATS
    for g in GENERIC + (("junk-after-header", "header-only") if f.header_end else ())
    if not (f.name in NO_END_MARKER and g in ("half", "cut-mid-line"))
]
CASES += [Case(f"{f.name}-{e[0]}", f, "edit", e[0]) for f in FORMATS for e in f.edits]

# the readers whose messages are another helper's: marked strictly, the mark comes off when the owner's fix lands


def _materialize(case: Case, tmp: Path, shared: Path | None) -> tuple[Path, int | None]:
    text = case.fmt.seed(shared)
    if case.kind == "generic":
        data, extra, line = _generic(text, case.fmt.header_end)[case.key]
    else:
        _, old, new, line = next(e for e in case.fmt.edits if e[0] == case.key)
        assert old in text, f"{case.id}: the seed does not contain {old!r}"
        data, extra = text.replace(old, new, 1).encode("latin-1"), ""
    p = tmp / f"corrupt-{case.key}{case.fmt.suffix}{extra}"
    p.write_bytes(data)
    return p, line


def _check_message(case: Case, msg: str, path: Path, line: int | None) -> None:
    assert path.name in msg, f"{case.id}: the file is not named: {msg}"
    assert not LIBRARY_TEXT.search(msg), f"{case.id}: library text in the message: {msg}"
    if line is not None:
        assert re.search(rf"(line |:){line}\b", msg), f"{case.id}: line {line} is not named: {msg}"


def _params() -> list[Any]:
    return [pytest.param(c, id=c.id) for c in CASES]


@pytest.fixture
def shared_or_none(request: pytest.FixtureRequest) -> Path | None:
    case: Case = request.getfixturevalue("case")
    if not case.fmt.shared:
        return None
    shared: Path = request.getfixturevalue("shared_data")
    return shared


@pytest.mark.parametrize("case", _params())
def test_corrupted_file_gives_a_project_error(case: Case, tmp_path: Path, shared_or_none: Path | None) -> None:
    path, line = _materialize(case, tmp_path, shared_or_none)
    with pytest.raises(DistnavError) as info:
        case.fmt.read(path)
    _check_message(case, str(info.value), path, line)


def test_seeds_are_valid(tmp_path: Path, request: pytest.FixtureRequest) -> None:
    """Every seed reads without error, so each corruption is what the reader refuses."""
    for f in FORMATS:
        shared = request.getfixturevalue("shared_data") if f.shared else None
        p = tmp_path / f"seed-{f.name}{f.suffix}"
        p.write_text(f.seed(shared), encoding="latin-1")
        f.read(p)


def test_enough_cases() -> None:
    assert len(CASES) >= 100, len(CASES)


# ------------------------------------------------------------------------------------------------------ CLI
def _cli_cases(tmp: Path, shared: Path | None) -> list[tuple[str, list[str], Path]]:
    """(id, argv, the corrupted file) through the commands that read each format."""
    from distnav.formats.gnss.bias_sinex import BiasSinexHeader, write_bias_sinex

    good_bia = tmp / "good.bia"
    write_bias_sinex(
        good_bia,
        obs1="C1C",
        obs2="C2W",
        start="2024-01-10",
        end="2024-01-11",
        satellites={"G01": (1.0, 0.1)},
        stations={},
        header=BiasSinexHeader(created="2024-01-12"),
    )
    known = tmp / "known.csv"
    known.write_text(POSITIONS)
    ranges = tmp / "ranges.csv"
    ranges.write_text(RANGES)
    out = str(tmp / "out")
    picks = {
        "uwb-ranges": ("bad-number", "nul-bytes", "binary-junk", "utf16", "missing-field"),
        "uwb-positions": ("bad-number", "nan", "binary-junk"),
        "bias-sinex": ("bad-number", "no-end-of-block", "fake-gzip", "binary-junk"),
        "ionex-dcb": ("bad-number", "gzip-truncated"),
        "rinex2-obs": ("bad-number", "cut-mid-line", "binary-junk"),
        "rinex3-obs": ("bad-number", "utf16", "bad-prn", "gzip-truncated"),
    }
    cases = []
    for f in FORMATS:
        for key in picks.get(f.name, ()):
            case = next(c for c in CASES if c.fmt is f and c.key == key)
            sub = tmp / case.id
            sub.mkdir()
            p, _ = _materialize(case, sub, shared)
            argv = {
                "uwb-ranges": ["uwb", "solve", "--ranges", str(p), "--known", str(known), "--out", out],
                "uwb-positions": ["uwb", "solve", "--ranges", str(ranges), "--known", str(p), "--out", out],
                "april-log": ["uwb", "import-april", str(p), "--out", out],
                "bias-sinex": ["gnss", "compare", "--estimates", str(good_bia), "--bias", str(p), "--out", out],
                "ionex-dcb": ["gnss", "compare", "--estimates", str(good_bia), "--bias", str(p), "--out", out],
                "rinex2-obs": ["gnss", "codebias", "--obs", str(p), str(p), "--nav", str(p), "--out", out],
                "rinex3-obs": ["gnss", "codebias", "--obs", str(p), str(p), "--nav", str(p), "--out", out],
            }[f.name]
            cases.append((case.id, argv, p))
    return cases


def test_cli_reports_corrupted_files(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """The commands end with ``error: <file>...`` and exit code 2, no traceback, no output written."""
    from distnav.cli import main

    monkeypatch.chdir(tmp_path)
    cases = _cli_cases(tmp_path, None)
    assert len(cases) >= 20
    failures = []
    for cid, argv, path in cases:
        try:
            code = main(argv)
        except SystemExit as exc:
            code = exc.code
        err = capsys.readouterr().err
        problems = []
        if code != 2:
            problems.append(f"exit code {code!r}")
        if "Traceback" in err or "error:" not in err:
            problems.append("no 'error:' line")
        if path.name not in err:
            problems.append("file not named")
        if LIBRARY_TEXT.search(err):
            problems.append("library text")
        if (tmp_path / "out").exists() and any((tmp_path / "out").iterdir()):
            problems.append("output written")
        if problems:
            failures.append(f"{cid}: {', '.join(problems)}: {err.strip()[-300:]}")
    assert not failures, "\n".join(failures)
