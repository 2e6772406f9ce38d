"""Bad input nobody had tried (issue: guard12's adversarial sweep of every command): each case here broke before
its fix — a traceback, a misleading message, exit 0 on a file the next step refuses, an option silently ignored —
and now ends with exit code 2 and ``error: ...`` naming the problem, or (BOM, CRLF) reads as the clean file does.

Every bad input is built in ``tmp_path``: the UWB ones from small synthetic files, the GNSS ones from the real
files of ``../shared/data`` (read in place, copied and corrupted in ``tmp_path``; skipped with the reason where the
folder is absent). The sweep itself (about 260 cases, every command) was a script outside the repository; the
cases it found broken are these.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import pytest

from distnav.cli import main
from distnav.commands.gnss_common import load_edges

NL = "gnss/nl_2021001_short_network_snapshot"
IGS = "gnss/igs_2024010_bele_dgar"

# a small 2-D network: three known anchors, three to estimate, every pair ranged (exact distances)
ANCHORS = {"A0": (0.0, 0.0), "A1": (10.0, 0.0), "A2": (0.0, 8.0), "A3": (10.0, 8.0), "A4": (5.0, 4.0), "A5": (3.0, 6.0)}


def _uwb_files(tmp: Path) -> tuple[Path, Path]:
    ids = list(ANCHORS)
    rows = ["a,b,range_m"]
    for i, a in enumerate(ids):
        for b in ids[i + 1 :]:
            (xa, ya), (xb, yb) = ANCHORS[a], ANCHORS[b]
            rows.append(f"{a},{b},{((xa - xb) ** 2 + (ya - yb) ** 2) ** 0.5:.4f}")
    ranges, known = tmp / "ranges.csv", tmp / "known.csv"
    ranges.write_text("\n".join(rows) + "\n")
    known.write_text("id,x_m,y_m\n" + "".join(f"{k},{ANCHORS[k][0]},{ANCHORS[k][1]}\n" for k in ("A0", "A1", "A2")))
    return ranges, known


# an APRIL DW1000 log: time of propagation (µs, with the antenna delays), node a, node b, 18 diagnostics
_DIAG = "32.50 9337 14091 64 -108.14 -82.90 34.00 8214 13301 60 -107.72 -83.22 32.50 9922 14189 68 -109.10 -83.09"
APRIL_LINES = [f"0.53{k % 7}2093098958 {a} {b} {_DIAG}" for k, (a, b) in enumerate([(12, 8), (14, 8), (54, 12)] * 4)]


def _april(tmp: Path, lines: list[str], *, end: str = "\n", prefix: bytes = b"") -> Path:
    p = tmp / "dataset9.txt"
    p.write_bytes(prefix + ("\n".join(lines) + end).encode("ascii"))
    return p


def _nl(shared: Path, name: str) -> str:
    return str(shared / NL / name)


def _gnss(shared: Path, tmp: Path, *extra: str, obs: tuple[str, ...] = ()) -> list[str]:
    """``gnss ionosphere`` of two short Dutch stations (1.5 s), with ``obs`` in place of the first station."""
    files = list(obs) or [_nl(shared, "delf0010.21o")]
    return [
        "gnss",
        "ionosphere",
        "--obs",
        *files,
        _nl(shared, "wsra0010.21o"),
        "--nav",
        _nl(shared, "cbw10010.21n.gz"),
        "--no-progress",
        "--out",
        str(tmp / "out"),
        *extra,
    ]


def _rinex_with(shared: Path, tmp: Path, make: Callable[[bytes], bytes]) -> str:
    """delf0010.21o rewritten by ``make`` in ``tmp`` (same name: the station and the day come from it)."""
    raw = (shared / NL / "delf0010.21o").read_bytes()
    (tmp / "bad").mkdir(exist_ok=True)
    p = tmp / "bad" / "delf0010.21o"
    p.write_bytes(make(raw))
    return str(p)


def _codebias_json(tmp: Path, day: str, x_ns: dict[str, float]) -> Path:
    """A minimal ``codebias.json`` (the keys ``gnss compare`` reads) of station BELE tracking C1C/C2W/C5X."""
    p = tmp / "est" / "codebias.json"
    p.parent.mkdir(exist_ok=True)
    codes = {"L1": "C1C", "L2": "C2W", "L5": "C5X"}
    p.write_text(
        json.dumps(
            {
                "x_ns": x_ns,
                "codes": {"BELE": codes},
                "reference_station": "BELE",
                "coefficients": [0.2261799729067455, -1.2261799729067455, 1.0],
                "first_epoch": f"{day}T00:00:00.000000000",
                "last_epoch": f"{day}T23:59:30.000000000",
            }
        )
    )
    return p


@dataclass(frozen=True)
class Case:
    id: str
    argv: Callable[[Path, Path | None], list[str]]  # (tmp_path, shared data or None) -> command line
    expect: str  # in the error message (case-insensitive)
    shared: bool = False


def _initial_coincident(tmp: Path, _: Path | None) -> list[str]:
    ranges, known = _uwb_files(tmp)
    init = tmp / "init.csv"
    init.write_text("id,x_m,y_m\n" + "".join(f"{k},1,1\n" for k in ANCHORS))  # every anchor at one point
    return ["uwb", "solve", "--ranges", str(ranges), "--known", str(known), "--initial", str(init), "--out", "{out}"]


def _known_spelled_otherwise(tmp: Path, _: Path | None) -> list[str]:
    """Numeric ids (as in the APRIL CSVs), the log spelling anchor 8 as 08 (a spreadsheet's zero padding)."""
    ranges, known = _uwb_files(tmp)
    numbers = {"A0": "8", "A1": "12", "A2": "54", "A3": "14", "A4": "61", "A5": "81"}
    for path, log in ((ranges, True), (known, False)):
        text = path.read_text()
        for name, number in numbers.items():
            text = text.replace(name, "08" if log and number == "8" else number)
        path.write_text(text)
    return ["uwb", "solve", "--ranges", str(ranges), "--known", str(known), "--out", "{out}"]


def _header_twice(tmp: Path, _: Path | None) -> list[str]:
    ranges, known = _uwb_files(tmp)
    lines = ranges.read_text().splitlines()
    ranges.write_text("\n".join(lines[:4] + lines[:1] + lines[4:]) + "\n")
    return ["uwb", "solve", "--ranges", str(ranges), "--known", str(known), "--out", "{out}"]


def _ranges_twice(tmp: Path, _: Path | None) -> list[str]:
    ranges, known = _uwb_files(tmp)
    other = tmp / "other.csv"
    other.write_text(ranges.read_text())
    return ["uwb", "solve", "--ranges", str(ranges), "--known", str(known), "--ranges", str(other), "--out", "{out}"]


def _import(lines: list[str], *known: str, end: str = "\n") -> Callable[[Path, Path | None], list[str]]:
    def argv(tmp: Path, _: Path | None) -> list[str]:
        return ["uwb", "import-april", str(_april(tmp, lines, end=end)), *known, "--out", "{out}"]

    return argv


UWB_CASES = [
    # a traceback: "ValueError: 'list' argument must have no negative elements" (0/0 derivatives at one point)
    Case("uwb-solve-initial-all-at-one-point", _initial_coincident, "have the same initial position"),
    # "range_m 'range_m' is not a number"
    Case("uwb-solve-header-twice", _header_twice, "ranges.csv:5: the header line again"),
    # argparse kept the last --ranges: the first log was dropped without a word
    Case("uwb-solve-option-twice", _ranges_twice, "--ranges is given twice: give it once"),
    # exit 3: anchor 08 estimated as unknown, known anchor 8 ignored with a warning (a worse map)
    Case("uwb-solve-known-id-spelled-otherwise", _known_spelled_otherwise, "known anchor '8' has no range in"),
    # exit 0 and a known.csv that `uwb solve` refuses ("listed twice", "no data rows", "needs 2 fixed anchors")
    Case("uwb-import-april-known-twice", _import(APRIL_LINES, "--known", "8,8,12"), "--known names node(s) 8 twice"),
    Case("uwb-import-april-known-empty", _import(APRIL_LINES, "--known", ""), "--known must be comma-separated"),
    Case("uwb-import-april-known-one", _import(APRIL_LINES, "--known", "8"), "needs at least 2 known nodes"),
    # exit 0 with the bad line copied into ranges.csv (refused only by `uwb solve`, naming its line there)
    Case(
        "uwb-import-april-self-range",
        _import([APRIL_LINES[0], f"0.53 12 12 {_DIAG}", *APRIL_LINES[1:]]),
        "line 2: a range from node 12 to itself",
    ),
    # exit 0 with an empty ranges.csv: node 16 (the robot) has no ground truth and is left out
    Case("uwb-import-april-robot-only", _import([f"0.53 16 8 {_DIAG}", f"0.53 8 16 {_DIAG}"]), "no sample between"),
    # exit 0: a cut last line read as a (wrong) sample
    Case(
        "uwb-import-april-cut-last-line",
        _import([*APRIL_LINES[:-1], APRIL_LINES[-1][:20]], end=""),
        "line 12: the file ends inside a line",
    ),
]


def _g(*extra: str, obs: Callable[[Path, Path], str] | None = None) -> Callable[[Path, Path | None], list[str]]:
    def argv(tmp: Path, shared: Path | None) -> list[str]:
        assert shared is not None
        return _gnss(shared, tmp, *extra, obs=(obs(shared, tmp),) if obs else ())

    return argv


def _graph(text: bytes) -> Callable[[Path, Path | None], list[str]]:
    def argv(tmp: Path, shared: Path | None) -> list[str]:
        assert shared is not None
        g = tmp / "graph.csv"
        g.write_bytes(text)
        return _gnss(shared, tmp, "--graph", str(g))

    return argv


def _header_then(tail: bytes) -> Callable[[Path, Path], str]:
    def obs(shared: Path, tmp: Path) -> str:
        return _rinex_with(shared, tmp, lambda raw: raw[: raw.index(b"END OF HEADER") + 14] + tail)

    return obs


def _compare(
    day: str, *extra: str, bias: Callable[[Path, Path | None], list[str]] | None = None
) -> Callable[[Path, Path | None], list[str]]:
    def argv(tmp: Path, shared: Path | None) -> list[str]:
        est = _codebias_json(tmp, day, {"G01": 1.0, "G03": 2.0, "G08": -1.0})
        files = bias(tmp, shared) if bias else [str(tmp / "GFZ0OPSRAP_20240100000_01D_01D_DCB.BIA")]
        for f in files:
            if not Path(f).exists():
                Path(f).write_text("%=BIA 1.00\n")  # never read: the checks come first
        return ["gnss", "compare", "--estimates", str(est), "--bias", *files, "--out", "{out}", *extra]

    return argv


GNSS_CASES = [
    # "line 29: the file ends inside a line: it is truncated" for binary data / UTF-16 (NUL bytes)
    Case(
        "gnss-rinex-binary-after-header",
        _g(obs=_header_then(bytes(range(256)) * 4)),
        "binary data (NUL bytes)",
        shared=True,
    ),
    Case(
        "gnss-rinex-utf16",
        _g(obs=lambda s, t: _rinex_with(s, t, lambda raw: raw.decode("latin-1").encode("utf-16"))),
        "binary data (NUL bytes)",
        shared=True,
    ),
    # a traceback: UnicodeDecodeError
    Case("gnss-graph-binary", _graph(bytes(range(128, 256)) * 3), "is not UTF-8 text", shared=True),
    # "no links": line 1 was taken as a header because one name was unknown
    Case(
        "gnss-graph-unknown-on-line-1", _graph(b"DELF,XXXX\nDELF,WSRA\n"), "line 1: unknown station XXXX", shared=True
    ),
    # exit 0: a station that is not there (a typo) silently excluded nothing
    Case("gnss-exclude-unknown-station", _g("--exclude", "DELX"), "--exclude DELX: no such station", shared=True),
    # exit 0 with every DSB empty in dcb_final.csv: the zero mean ran over no satellite
    Case(
        "gnss-datum-satellites-none-tracked",
        _g("--datum-satellites", "G04,G31"),
        "none of them is tracked",
        shared=True,
    ),
    # exit 0 with a numpy deprecation warning and the window shifted by the zone
    Case(
        "gnss-tlim-time-zone",
        _g("--tlim", "2021-01-01T00:00+05:00", "2021-01-01T06:00+05:00"),
        "without a time zone",
        shared=True,
    ),
    # the message said "(np.datetime64('2021-01-01T05:00:00.000000000'), ...)"
    Case(
        "gnss-tlim-outside-the-data",
        _g("--tlim", "2021-01-01T05:00", "2021-01-01T06:00"),
        "between 2021-01-01T05:00:00 and 2021-01-01T06:00:00 (GPS time; --tlim)",
        shared=True,
    ),
    # exit 0 with DELF alone: argparse kept the last --obs list
    Case(
        "gnss-obs-option-twice",
        lambda t, s: _gnss(s, t, "--obs", _nl(s, "zegv0010.21o")) if s else [],
        "--obs is given twice: give it once, with all its values",
        shared=True,
    ),
    # "fewer than two satellites with 30 station-epochs or more": a 7-s grid kept one 30-s epoch in 7
    Case(
        "gnss-interval-off-the-sampling",
        _g("--interval", "7"),
        "--interval 7 s does not fit the 30-s sampling of DELF",
        shared=True,
    ),
    Case(
        "gnss-interval-beyond-the-data",
        _g("--interval", "1e9"),
        "is longer than the longest station's data (DELF: 3120 s)",
        shared=True,
    ),
    # ran for days (10⁸ consensus rounds every epoch)
    Case("gnss-kn-huge", _g("--kn", "100000000"), "--kn must lie in 0 … 10,000", shared=True),
    # exit 0: the second code of a band silently won; a code of another band used with this band's coefficient
    Case(
        "gnss-codebias-codes-band-twice",
        lambda t, s: [
            "gnss",
            "codebias",
            "--obs",
            str(t / "a.21o"),
            "--nav",
            str(t / "a.21n"),
            "--codes",
            "L1=C1C,L1=C1W",
        ],
        "--codes names L1 twice",
    ),
    Case(
        "gnss-codebias-codes-other-band",
        lambda t, s: ["gnss", "codebias", "--obs", str(t / "a.21o"), "--nav", str(t / "a.21n"), "--codes", "L1=C2W"],
        "C2W is not an L1 code",
    ),
    # compare of codebias.json: "no satellite in common" instead of the other day; --exclude ignored
    Case("gnss-compare-codebias-other-day", _compare("2021-01-01"), "a product of 2024-01-10"),
    Case(
        "gnss-compare-codebias-exclude-all",
        _compare("2024-01-10", "--exclude", "G01", "G03", "G08"),
        "--exclude leaves no satellite",
    ),
    # exit 0: --filter ignored for a codebias.json (one solution)
    Case(
        "gnss-compare-codebias-filter", _compare("2024-01-10", "--filter", "ckf:BELE"), "--filter ckf:BELE applies to"
    ),
    # exit 0: a product compared with itself, or counted twice
    Case(
        "gnss-compare-estimates-is-bias",
        lambda t, s: ["gnss", "compare", "--estimates", str(_bia(t)), "--bias", str(_bia(t))],
        "also given as --bias",
    ),
    # "epoch times must be one increasing series" from the levelling, naming no file
    Case(
        "gnss-rinex-repeated-epoch",
        _g(obs=lambda s, t: _rinex_with(s, t, _repeat_first_epoch)),
        "is not after the previous epoch 2021-01-01T00:00:00",
        shared=True,
    ),
    # exit 0 with the NaN DSB in the comparison
    Case(
        "gnss-compare-bias-sinex-nan",
        _compare("2024-01-10", bias=lambda t, s: [_cas(t, s, "nan", "CAS0OPSRAP_20240100000_01D_01D_DCB.BIA")]),
        "expected a finite number, got 'nan'",
        shared=True,
    ),
    # exit 0: a renamed product (the day only in its first line) of another day compared without a word
    Case(
        "gnss-compare-renamed-product-of-another-day",
        _compare("2024-01-10", bias=lambda t, s: [_cas(t, s, "", "mybias.bia", day="20240110000")]),
        "mybias.bia: a product of 2024-01-11",
        shared=True,
    ),
    # exit 0: the experiment run twice into one folder
    Case("demo-only-twice", lambda t, s: ["demo", "--out", "{out}", "--only", "ckf", "ckf"], "--only names ckf twice"),
    Case(
        "gnss-compare-bias-twice",
        _compare("2024-01-10", bias=lambda t, s: [str(_bia(t)), str(_bia(t))]),
        "is given twice",
    ),
]


def _repeat_first_epoch(raw: bytes) -> bytes:
    """The first epoch of a RINEX 2 file (its epoch line and observation lines) written twice."""
    start = raw.index(b"END OF HEADER") + 14
    second = raw.index(b"\n 21  1  1  0  0 30.0", start) + 1
    return raw[:second] + raw[start:second] + raw[second:]


def _cas(tmp: Path, shared: Path | None, value: str, name: str, *, day: str = "20240100000") -> str:
    """CAS's Bias-SINEX product of ../shared (``day``: 2024-01-10 or 01-11) as ``name``, its first DSB value
    replaced by ``value`` (unless empty)."""
    from distnav.formats.gnss.rinex_obs import read_bytes

    assert shared is not None
    raw = read_bytes(shared / IGS / f"CAS0OPSRAP_{day}_01D_01D_DCB.BIA.gz")
    if value:
        first = raw.index(b"\n DSB ") + 1
        line_end = raw.index(b"\n", first)
        line = raw[first:line_end]
        raw = raw[:first] + line[:70] + value.rjust(21).encode() + line[91:] + raw[line_end:]
    p = tmp / name
    p.write_bytes(raw)
    return str(p)


def _bia(tmp: Path) -> Path:
    p = tmp / "CAS0OPSRAP_20240100000_01D_01D_DCB.BIA"
    if not p.exists():
        p.write_text("%=BIA 1.00\n")
    return p


def _files(tmp: Path) -> None:
    for name in ("a.21o", "a.21n"):
        (tmp / name).write_text("dummy\n")


@pytest.mark.parametrize("case", [pytest.param(c, id=c.id) for c in UWB_CASES + GNSS_CASES])
def test_bad_input_exits_2_naming_it(
    case: Case,
    tmp_path: Path,
    request: pytest.FixtureRequest,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    shared = request.getfixturevalue("shared_data") if case.shared else None
    monkeypatch.chdir(tmp_path)
    _files(tmp_path)
    out = tmp_path / "out"
    argv = [a.replace("{out}", str(out)) for a in case.argv(tmp_path, shared)]
    try:
        code = main(argv)
    except SystemExit as exc:
        code = exc.code
    err = capsys.readouterr().err
    assert code == 2, f"exit code {code!r}; stderr: {err[-800:]}"
    assert "Traceback" not in err and "error:" in err
    assert case.expect.lower() in err.lower(), err[-800:]
    assert not list(out.rglob("*.csv")) and not list(out.rglob("*.json")), "results written for a refused input"


# ------------------------------------------------------------------ what must read as the clean file reads
def test_april_log_with_a_byte_order_mark_reads_as_without(tmp_path: Path) -> None:
    """A Windows editor's UTF-8 BOM: refused before ("byte 0xef is not plain ASCII"); now the same CSVs."""
    plain, bom = tmp_path / "plain", tmp_path / "bom"
    plain.mkdir(), bom.mkdir()
    a = _april(plain, APRIL_LINES)
    b = _april(bom, APRIL_LINES, prefix=b"\xef\xbb\xbf")
    assert main(["uwb", "import-april", str(a), "--out", str(plain / "o")]) == 0
    assert main(["uwb", "import-april", str(b), "--out", str(bom / "o")]) == 0
    for name in ("ranges.csv", "known.csv", "truth.csv"):
        assert (bom / "o" / name).read_text() == (plain / "o" / name).read_text()
    assert len((plain / "o" / "ranges.csv").read_text().splitlines()) == 1 + len(APRIL_LINES)


def test_graph_with_a_byte_order_mark_and_crlf_reads_as_without(tmp_path: Path) -> None:
    """Before: the BOM stuck to the first name ('\\ufeffDELF' unknown), so line 1 was skipped as a header and the
    graph came out disconnected."""
    stations = ["DELF", "WSRA", "EIJS"]
    plain, bom = tmp_path / "plain.csv", tmp_path / "bom.csv"
    plain.write_bytes(b"DELF,WSRA\nWSRA,EIJS\n")
    bom.write_bytes(b"\xef\xbb\xbfDELF,WSRA\r\nWSRA,EIJS\r\n")
    assert load_edges(bom, stations).links.tolist() == load_edges(plain, stations).links.tolist() == [[0, 1], [1, 2]]


def test_rinex_with_a_byte_order_mark_gives_the_same_dsbs(
    shared_data: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Before: "no RINEX VERSION / TYPE line" (the BOM shifted line 1's columns)."""
    clean = _gnss(shared_data, tmp_path / "clean")
    bom = _gnss(
        shared_data,
        tmp_path / "bom",
        obs=(_rinex_with(shared_data, tmp_path, lambda raw: b"\xef\xbb\xbf" + raw),),
    )
    assert main(clean) == 0
    assert main(bom) == 0, capsys.readouterr().err[-600:]
    assert (tmp_path / "bom/out/dcb_final.csv").read_text() == (tmp_path / "clean/out/dcb_final.csv").read_text()


def test_compare_of_codebias_leaves_out_the_excluded_satellites(
    shared_data: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """``--exclude`` was ignored for a ``codebias.json``: the excluded satellite stayed in the RMS. The reference
    is the same comparison without that satellite in the estimates at all."""
    cas = str(shared_data / IGS / "CAS0OPSRAP_20240100000_01D_01D_DCB.BIA.gz")
    x_ns = {"G01": 1.0, "G03": 2.5, "G08": -1.0, "G10": 0.3}
    full = _codebias_json(tmp_path, "2024-01-10", x_ns)
    argv = ["gnss", "compare", "--estimates", str(full), "--bias", cas]
    assert main([*argv, "--exclude", "G03", "--out", str(tmp_path / "excluded")]) == 0
    without = tmp_path / "without"
    without.mkdir()
    est = json.loads(full.read_text())
    (without / "codebias.json").write_text(json.dumps({**est, "x_ns": {k: v for k, v in x_ns.items() if k != "G03"}}))
    assert main(["gnss", "compare", "--estimates", str(without), "--bias", cas, "--out", str(tmp_path / "ref")]) == 0
    got = json.loads((tmp_path / "excluded/comparison.json").read_text())
    ref = json.loads((tmp_path / "ref/comparison.json").read_text())
    assert "G03" not in got["zero_mean"]["differences_ns"] and got["n_common"] == ref["n_common"] == 3
    assert got["zero_mean"] == ref["zero_mean"]


def test_default_graph_of_stations_at_one_point() -> None:
    """Two receivers on one monument (a zero baseline; or one file under two names): the nearest-neighbour graph
    linked a station to itself ("link #1 joins node 1 to itself; use self_loops=True")."""
    import numpy as np

    from distnav.commands.gnss_common import default_graph

    same = [3.9e6, 3.0e5, 5.0e6]
    for pos, links in (
        ([same, same, [3.9e6, 4.0e5, 5.0e6]], [[0, 1], [0, 2], [1, 2]]),
        ([[3.9e6, 4.0e5, 5.0e6], same, same], [[0, 1], [0, 2], [1, 2]]),
        ([same, same], [[0, 1]]),
    ):
        graph = default_graph(np.array(pos), ["AAAA", "BBBB", "CCCC"][: len(pos)])
        assert graph.links.tolist() == links


def test_single_link_hint_names_the_same_number_spelled_otherwise() -> None:
    """``12.0`` for ``12`` (a script's float formatting): the single-link warning named no likely typo (difflib's
    ratio 0.67 is below its cut-off)."""
    import numpy as np

    from distnav.formats.uwb.io import CombinedRanges, single_link_anchors

    pairs = (("12", "8"), ("12", "54"), ("8", "54"), ("12.0", "8"))
    comb = CombinedRanges(pairs, np.ones(4), np.ones(4, np.int64), np.zeros(4))
    (warning,) = single_link_anchors(comb)
    assert "anchor '12.0' has a single measured link" in warning and "an id typo for '12'?" in warning


def test_a_product_of_several_days_is_not_taken_for_its_first_day(
    shared_data: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A weekly, monthly or quarterly product (``DLR0MGXFIN_20240010000_03L_07D_DCB.BSX``) is valid over its span: the
    name's start day alone made `gnss compare` refuse it as "a product of 2024-01-01" against estimates of
    2024-01-10. Reference: the same file under its daily name gives the same comparison."""
    import shutil

    import numpy as np

    from distnav.formats.gnss.product_files import product_day

    assert product_day("DLR0MGXFIN_20240010000_03L_07D_DCB.BSX") is None
    assert product_day("COD0OPSFIN_20240070000_07D_01D_OSB.BIA") is None
    assert product_day("CAS0OPSRAP_20240100000_01D_01D_DCB.BIA") == np.datetime64("2024-01-10")
    assert product_day("BELE00BRA_R_20240100000_15M_01S_MO.rnx") == np.datetime64("2024-01-10")
    cas = shared_data / IGS / "CAS0OPSRAP_20240100000_01D_01D_DCB.BIA.gz"
    quarterly = tmp_path / "CAS0OPSRAP_20240010000_03L_01D_DCB.BIA.gz"
    shutil.copy(cas, quarterly)
    est = _codebias_json(tmp_path, "2024-01-10", {"G01": 1.0, "G03": 2.5, "G08": -1.0, "G10": 0.3})
    for name, product in (("daily", cas), ("quarterly", quarterly)):
        argv = ["gnss", "compare", "--estimates", str(est), "--bias", str(product), "--out", str(tmp_path / name)]
        assert main(argv) == 0, capsys.readouterr().err[-600:]
    daily = json.loads((tmp_path / "daily/comparison.json").read_text())
    other = json.loads((tmp_path / "quarterly/comparison.json").read_text())
    assert other["zero_mean"] == daily["zero_mean"] and other["n_common"] == daily["n_common"] == 4
