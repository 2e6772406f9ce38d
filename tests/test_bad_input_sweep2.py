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
