"""Bad input the first sweep (tests/test_bad_input_sweep.py) left, found by guard13's sweep (docs/bad_input.md):
absurd experiment sizes that started and ran until stopped, now refused when the options are parsed (exit code 2,
the limit and its reason in the message and in ``--help``), and what the second sweep found broken.

Each case failed on the code before its fix: the size limits parsed (and the run started), the others as noted.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import pytest

from distnav.cli import build_parser, main
from distnav.commands.gnss_common import load_edges
from distnav.errors import DataFileError
from distnav.formats.gnss.compressed import read_text_file
from distnav.formats.uwb.april import read_april
from distnav.formats.uwb.io import read_positions
from distnav.options import int_up_to

#: (command line without --out, the option, its limit): every size option of reproduce, demo, reproduce-all,
#: uwb solve and gnss codebias (gnss ionosphere --kn was bounded by the first sweep)
SIZES = [
    (["reproduce", "uwb"], "--instances", 1_000),
    (["reproduce", "uwb"], "--iterations", 20_000),
    (["reproduce", "uwb"], "--jobs", 64),
    (["reproduce", "admm"], "--jobs", 64),
    (["reproduce", "codebias"], "--epochs", 2_880),
    (["reproduce", "codebias"], "--iterations", 100_000),
    (["reproduce", "uwb-field"], "--anchors", 112),
    (["reproduce", "uwb-field"], "--instances", 100),
    (["reproduce", "uwb-field"], "--iterations", 20_000),
    (["reproduce", "ckf-ionosphere"], "--epochs", 1_440),
    (["reproduce", "ckf-ionosphere"], "--data-kn", 10_000),
    (["demo"], "--jobs", 64),
    (["reproduce-all"], "--jobs", 64),
    (["uwb", "solve", "--ranges", "r.csv", "--known", "k.csv"], "--iterations", 100_000),
    (["gnss", "codebias", "--obs", "a.21o", "--nav", "a.21n"], "--iterations", 100_000),
]


def _parse(words: list[str]) -> argparse.Namespace:
    return build_parser(words).parse_args(words)


def _words(cmd: list[str], option: str, value: int, tmp: Path) -> list[str]:
    return [*cmd, "--out", str(tmp / "out"), option, str(value)]


@pytest.mark.parametrize(("cmd", "option", "limit"), SIZES, ids=[f"{' '.join(c[:2])} {o}" for c, o, _ in SIZES])
def test_an_absurd_size_is_refused_when_parsed_naming_the_limit(
    cmd: list[str], option: str, limit: int, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Before: ``--instances 1000000000`` (and the rest) parsed, and the run started and ran until stopped."""
    with pytest.raises(SystemExit) as exc:
        _parse(_words(cmd, option, limit + 1, tmp_path))
    err = capsys.readouterr().err
    assert exc.value.code == 2
    assert f"argument {option}: at most {limit:,}, got {limit + 1} (" in err, err
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize(("cmd", "option", "limit"), SIZES, ids=[f"{' '.join(c[:2])} {o}" for c, o, _ in SIZES])
def test_the_limit_itself_parses_and_the_help_states_it(
    cmd: list[str], option: str, limit: int, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    args = _parse(_words(cmd, option, limit, tmp_path))
    assert getattr(args, option[2:].replace("-", "_")) == limit
    with pytest.raises(SystemExit):
        _parse([*cmd[:2], "--help"])
    help_text = " ".join(capsys.readouterr().out.split())
    assert f"at most {limit:,}" in help_text, help_text


def test_the_whole_line_is_refused_before_anything_runs(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Through :func:`main`: exit code 2, no traceback, nothing written."""
    with pytest.raises(SystemExit) as exc:
        main(["reproduce", "uwb", "--out", str(tmp_path / "o"), "--iterations", "1000000000"])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and "--iterations: at most 20,000, got 1000000000 (" in err
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize(
    ("text", "value"),
    [("7", 7), (" 7 ", 7), ("1_000", 1_000), ("1001", None), ("0", None), ("-3", None), ("nan", None), ("1e3", None)]
    + [("0x10", None), ("2**62", None), ("", None), ("99999999999999999999999", None)],
)
def test_a_bounded_type_gives_a_value_or_names_the_text(text: str, value: int | None) -> None:
    """What argparse hands the type: the value, or an error quoting the text as given (not reformatted)."""
    parse = int_up_to(1_000, "a reason")
    if value is not None:
        assert parse(text) == value
        return
    with pytest.raises(argparse.ArgumentTypeError) as exc:
        parse(text)
    assert repr(text) in str(exc.value) or text.strip() in str(exc.value), str(exc.value)


# ----------------------------------------------------------- one text preamble for every reader (formats/text.py)
def test_nul_bytes_are_named_with_their_line_by_every_reader(tmp_path: Path) -> None:
    """Before: the --graph reader said "binary data (NUL bytes)" without the line, the UWB CSV reader decoded
    first; now the three readers (and RINEX's) share one preamble and name the line."""
    graph = tmp_path / "g.csv"
    graph.write_bytes(b"DELF,WSRA\nWSRA,\x00EIJS\n")
    with pytest.raises(DataFileError, match=r"g\.csv, line 2: binary data \(NUL bytes\)"):
        load_edges(graph, ["DELF", "WSRA", "EIJS"])
    known = tmp_path / "known.csv"
    known.write_bytes(b"id,x_m,y_m\nA0,0,0\nA1,1\x00,0\n")
    with pytest.raises(DataFileError, match=r"known\.csv, line 3: binary data \(NUL bytes\)"):
        read_positions(known)
    log = tmp_path / "dataset9.txt"
    log.write_bytes(b"0.5 12 8\n0.5 14 8\n\x00\x01\n")
    with pytest.raises(DataFileError, match=r"dataset9\.txt, line 3: binary data \(NUL bytes\)"):
        read_april(log)
    rinex = tmp_path / "x.21o"
    rinex.write_bytes(b"     3.04           OBSERVATION DATA    M                   RINEX VERSION / TYPE\n\x00")
    with pytest.raises(DataFileError, match=r"x\.21o, line 2: binary data \(NUL bytes\)"):
        read_text_file(rinex)


def test_a_byte_order_mark_is_dropped_by_every_reader(tmp_path: Path) -> None:
    known = tmp_path / "known.csv"
    known.write_bytes(b"\xef\xbb\xbfid,x_m,y_m\nA0,0,0\nA1,1,0\n")
    assert sorted(read_positions(known)[0]) == ["A0", "A1"]
    rinex = tmp_path / "x.21o"
    rinex.write_bytes(b"\xef\xbb\xbfline one\n")
    assert read_text_file(rinex) == ["line one"]


def test_a_time_zone_in_tlim_is_refused_when_parsed(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Before: refused later, by a second check (a regex in gnss_common) beside options.iso_datetime's."""
    words = ["gnss", "codebias", "--obs", "a.21o", "--nav", "a.21n", "--out", str(tmp_path / "o")]
    with pytest.raises(SystemExit) as exc:
        _parse([*words, "--tlim", "2021-01-01T00:00Z", "2021-01-01T06:00"])
    assert exc.value.code == 2
    assert "argument --tlim: '2021-01-01T00:00Z': times are GPS time, without a time zone" in capsys.readouterr().err
    assert _parse([*words, "--tlim", "2021-01-01T00:00", "2021-01-01T06:00"]).tlim == [
        "2021-01-01T00:00",
        "2021-01-01T06:00",
    ]


# ------------------------------------------------------------------------- guard13's sweep: uwb solve / import-april
A = {"A0": (0.0, 0.0), "A1": (10.0, 0.0), "A2": (0.0, 8.0), "A3": (10.0, 8.0), "A4": (5.0, 4.0), "A5": (3.0, 6.0)}


def _uwb(tmp: Path, *, ranges_extra: str = "", header: str = "a,b,range_m") -> list[str]:
    ids = list(A)
    rows = [header]
    for i, a in enumerate(ids):
        for b in ids[i + 1 :]:
            (xa, ya), (xb, yb) = A[a], A[b]
            rows.append(f"{a},{b},{((xa - xb) ** 2 + (ya - yb) ** 2) ** 0.5:.4f}")
    (tmp / "ranges.csv").write_text("\n".join(rows) + "\n" + ranges_extra)
    (tmp / "known.csv").write_text("id,x_m,y_m\n" + "".join(f"{k},{A[k][0]},{A[k][1]}\n" for k in ("A0", "A1", "A2")))
    return ["uwb", "solve", "--ranges", str(tmp / "ranges.csv"), "--known", str(tmp / "known.csv")]


def _exit_and_error(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str]:
    try:
        code = main(argv)
    except SystemExit as exc:
        code = int(exc.code or 0)
    err = capsys.readouterr().err
    assert "Traceback" not in err
    return code, err


@pytest.mark.parametrize(
    ("extra", "expect"),
    [
        # exit 3, "no anchor's accuracy can be stated: A3, A4, A5 need more links or a known anchor"
        (["--sigma-m", "1e308"], "--sigma-m 1e+308 m: a range σ over 300 m"),
        # a traceback: OverflowError (34, 'Numerical result out of range')
        (["--delay-sigma-m", "1e308"], "--delay-sigma-m 1e+308 m: a range σ over 300 m"),
        # "input file ... lies inside the output folder ." (the empty path taken for the working folder)
        (["--out", ""], "argument --out: an empty path is not an output folder"),
    ],
)
def test_uwb_solve_absurd_values(
    extra: list[str], expect: str, tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    argv = _uwb(tmp_path)
    argv += extra if "--out" in extra else ["--out", str(tmp_path / "o"), *extra]
    code, err = _exit_and_error(argv, capsys)
    assert code == 2 and expect in err, err[-600:]


@pytest.mark.parametrize(
    ("extra", "header", "expect"),
    [
        # a traceback: _csv.Error: field larger than field limit (131072)
        ("A0,A1," + "9" * 200_000 + "\n", "a,b,range_m", "ranges.csv:17: not a CSV line (field larger than"),
        # exit 0: the first range_m column read, the other silently ignored
        ("", "a,b,range_m,range_m", "ranges.csv:1: column range_m named twice in the header"),
    ],
)
def test_uwb_csv_lines_the_csv_module_refuses(
    extra: str, header: str, expect: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    argv = _uwb(tmp_path, ranges_extra=extra, header=header)
    code, err = _exit_and_error([*argv, "--out", str(tmp_path / "o")], capsys)
    assert code == 2 and expect in err, err[-600:]


def test_a_range_of_1e308_m_is_dropped_as_a_bad_sample(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Before: "weighted residual sum of squares must be finite and ≥ 0, got nan" (exit 2, naming no line)."""
    argv = _uwb(tmp_path, ranges_extra="A0,A3,1e308\n")
    code, err = _exit_and_error([*argv, "--out", str(tmp_path / "o"), "--strict"], capsys)
    assert code == 2 and "ranges.csv:17: beyond any radio range range '1e308' between 'A0' and 'A3'" in err, err
    code, err = _exit_and_error([*argv, "--out", str(tmp_path / "o2")], capsys)
    assert code == 0 and "dropped 1 bad range sample(s) of 16 (1 beyond any radio range; lines 17)" in err, err


APRIL = "0.5312093098958 12 8 31.75 10191 15294 68 -108.34 -82.73 32.75 8484 12645 56 -111.94 -83.51 31.75\n"


@pytest.mark.parametrize(
    ("first", "expect"),
    [
        # "node ids [-9223372036854775808] are not the APRIL nodes"
        ("0.53 99999999999999999999 8", "line 1: node 99999999999999999999 is not an APRIL node [8, 12,"),
    ],
)
def test_april_log_bad_nodes_named_by_line(
    first: str, expect: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    log = tmp_path / "dataset5.txt"
    log.write_text(f"{first}\n" + APRIL * 5)
    code, err = _exit_and_error(["uwb", "import-april", str(log), "--out", str(tmp_path / "o")], capsys)
    assert code == 2 and expect in err, err[-600:]
    assert not (tmp_path / "o").exists()


# ------------------------------------------------------------------------------------ guard13's sweep: gnss options
NL = "gnss/nl_2021001_short_network_snapshot"


@pytest.mark.parametrize(
    ("extra", "expect"),
    [
        # exit 0 with "invalid value encountered in scalar divide"
        (["--sigma", "1e308"], "--sigma 1e+308: at most 100 (a zenith code σ over 100 m is no code observation)"),
        # a traceback: numpy.linalg.LinAlgError: Singular matrix
        (["--tec-rw", "1e30"], "--tec-rw 1e+30: at most 1000 ("),
    ],
)
def test_gnss_ionosphere_absurd_sigmas_refused_before_reading(
    extra: list[str], expect: str, shared_data: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    d = shared_data / NL
    argv = ["gnss", "ionosphere", "--obs", str(d / "delf0010.21o"), str(d / "wsra0010.21o")]
    argv += ["--nav", str(d / "cbw10010.21n.gz"), "--no-progress", "--out", str(tmp_path / "o"), *extra]
    code, err = _exit_and_error(argv, capsys)
    assert code == 2 and expect in err, err[-600:]
    assert not (tmp_path / "o").exists()


def test_gnss_codebias_absurd_sigma_refused_before_reading(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The files are never read (the option check comes first): placeholders do."""
    for name in ("a.21o", "a.21n"):
        (tmp_path / name).write_text("dummy\n")
    argv = ["gnss", "codebias", "--obs", str(tmp_path / "a.21o"), "--nav", str(tmp_path / "a.21n")]
    code, err = _exit_and_error([*argv, "--out", str(tmp_path / "o"), "--sigma", "1e308"], capsys)
    assert code == 2 and "--sigma 1e+308: at most 100" in err, err[-600:]


@pytest.mark.parametrize(
    ("extra", "expect"),
    [
        # exit 0: the prior of per-anchor delays given where none are estimated, silently ignored
        (["--range-offsets", "none", "--offset-prior-sigma-m", "0.5"], "--offset-prior-sigma-m 0.5 is the prior σ"),
        # exit 0: the delays σ admits are the metres objective's, silently ignored with the squared one
        (["--objective", "squared", "--delay-sigma-m", "0.2"], "it does not apply with --objective squared"),
    ],
)
def test_uwb_solve_options_that_do_not_apply_are_refused(
    extra: list[str], expect: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    code, err = _exit_and_error([*_uwb(tmp_path), "--out", str(tmp_path / "o"), *extra], capsys)
    assert code == 2 and expect in err, err[-600:]
    assert not (tmp_path / "o").exists()


def test_a_graph_file_with_a_huge_field_names_the_line(tmp_path: Path) -> None:
    """Before: a traceback (_csv.Error: field larger than field limit (131072)); the UWB CSV readers share the fix
    (formats.text.csv_rows)."""
    graph = tmp_path / "g.csv"
    graph.write_text("DELF,WSRA\n" + "X" * 200_000 + ",WSRA\n")
    with pytest.raises(DataFileError, match=r"g\.csv:2: not a CSV line \(field larger than field limit"):
        load_edges(graph, ["DELF", "WSRA"])


def test_reproduce_uwb_sizes_allowed_alone_but_not_together(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Before: each within its limit, ``--instances 1000 --iterations 20000`` (≈ 356 CPU-hours) started."""
    argv = ["reproduce", "uwb", "--out", str(tmp_path / "o"), "--instances", "1000", "--iterations", "20000"]
    code, err = _exit_and_error(argv, capsys)
    assert code == 2 and "--instances 1000 with --iterations 20,000 is ≈ 356 CPU-hours" in err, err[-600:]
    assert not (tmp_path / "o").exists()
    from distnav.experiments.uwb import check_options

    for words in (["--iterations", "20000"], ["--instances", "1000"], ["--quick", "--iterations", "20000"]):
        check_options(_parse(["reproduce", "uwb", "--out", str(tmp_path / "o"), *words]))  # each alone: allowed
