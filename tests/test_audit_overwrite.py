"""Issue 29 item 1: no command writes over any of its inputs or over a file it did not create.

Every command with ``--out`` is given (a) an input file inside its output folder, (b) its output folder being an
input folder (directly and through a symbolic link), and (c) an existing output folder holding a file distnav did
not write: each is refused before any work (exit 2, ``error: ...`` naming the file), and the file is unchanged.
A re-run into a folder distnav wrote is allowed, and the issue's own case (``uwb solve --ranges OUT/links.csv
--out OUT``) is run for real.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import pytest

from distnav.cli import build_parser, main
from distnav.options import OUTPUT_MANIFEST, check_output_spares, input_paths
from test_bad_input_audit import _options, _subparsers

#: command → its argv with ``{a}`` / ``{b}`` for two input files (commands without inputs have none)
COMMANDS: dict[tuple[str, ...], tuple[str, ...]] = {
    ("demo",): ("demo", "--only", "consensus"),
    ("reproduce-all",): ("reproduce-all", "--only", "consensus", "--quick"),
    ("uwb", "solve"): ("uwb", "solve", "--ranges", "{a}", "--known", "{b}"),
    ("uwb", "import-april"): ("uwb", "import-april", "{a}"),
    ("gnss", "codebias"): ("gnss", "codebias", "--obs", "{a}", "--nav", "{b}"),
    ("gnss", "compare"): ("gnss", "compare", "--estimates", "{a}", "--bias", "{b}"),
    ("gnss", "ionosphere"): ("gnss", "ionosphere", "--obs", "{a}", "--nav", "{b}"),
    ("field", "launch"): ("field", "launch", "--config", "{a}"),
    ("field", "keys"): ("field", "keys", "--config", "{a}"),
    ("field", "demo"): ("field", "demo", "--nodes", "4"),
}
#: one node of a field network: its ``--out`` is shared with the machine's other nodes (and their description), so
#: it refuses only an input that is one of its own files (options.check_node_outputs)
NODE_COMMANDS: dict[tuple[str, ...], tuple[str, ...]] = {
    ("node",): ("node", "--config", "{a}", "--id", "0"),
    ("field", "demo-uwb-node"): ("field", "demo-uwb-node", "--config", "{a}", "--id", "0"),
    ("field", "pushsum-node"): ("field", "pushsum-node", "--config", "{a}", "--id", "0"),
}
#: commands whose ``--out`` is a new file, not a folder: they refuse any existing file (tests/test_field_init.py)
FILE_OUTPUT = {("field", "init")}


def _writing_commands() -> list[tuple[str, ...]]:
    """Every command (``reproduce NAME`` counted as one) that has an ``--out`` option."""
    found = set()
    for path, parser in _subparsers(build_parser()):
        leaf = not any(isinstance(a, argparse._SubParsersAction) for a in parser._actions)
        if path and leaf and any("--out" in a.option_strings for a in _options(parser)):
            found.add(("reproduce",) if path[0] == "reproduce" else path)
    return sorted(found)


def _argv(command: tuple[str, ...], a: Path, b: Path, out: Path) -> list[str]:
    argv = ("reproduce", "consensus", "--quick") if command == ("reproduce",) else COMMANDS[command]
    return [s.format(a=a, b=b) for s in argv] + ["--out", str(out)]


def test_every_writing_command_is_covered() -> None:
    covered = COMMANDS.keys() | NODE_COMMANDS.keys() | FILE_OUTPUT | {("reproduce",)}
    missing = [c for c in _writing_commands() if c not in covered]
    assert not missing, f"commands with --out and no overwrite case here: {missing}"


@pytest.mark.parametrize("command", list(NODE_COMMANDS), ids=["-".join(c) for c in NODE_COMMANDS])
def test_a_node_refuses_an_input_that_is_its_own_output(command, tmp_path, capsys) -> None:
    out = tmp_path / "OUT"
    out.mkdir()
    own = out / "node-0.json"
    own.write_text("[network]\n")
    argv = [s.format(a=own) for s in NODE_COMMANDS[command]] + ["--out", str(out)]
    _refused(argv, capsys, "is the file this node writes", "node-0.json")
    assert own.read_text() == "[network]\n"


def _inputs(folder: Path) -> tuple[Path, Path]:
    folder.mkdir(parents=True, exist_ok=True)
    a, b = folder / "links.csv", folder / "known.csv"
    a.write_text("a,b,range_m\n1,2,3.0\n")
    b.write_text("id,x_m,y_m,z_m\n1,0,0,0\n")
    return a, b


def _refused(argv: list[str], capsys: pytest.CaptureFixture[str], *words: str) -> str:
    assert main(argv) == 2, argv
    err = capsys.readouterr().err
    assert err.startswith("error: ") and "Traceback" not in err
    for word in words:
        assert word in err, err
    return err


WITH_INPUTS = [c for c in COMMANDS if "{a}" in COMMANDS[c]]


@pytest.mark.parametrize("command", WITH_INPUTS, ids=["-".join(c) for c in WITH_INPUTS])
def test_input_inside_the_output_folder_is_refused(command, tmp_path, capsys) -> None:
    out = tmp_path / "OUT"
    a, b = _inputs(out)
    before = a.read_bytes(), b.read_bytes()
    _refused(_argv(command, a, b, out), capsys, "lies inside the output folder", "links.csv")
    assert (a.read_bytes(), b.read_bytes()) == before
    assert sorted(p.name for p in out.iterdir()) == ["known.csv", "links.csv"]  # nothing written, no manifest


@pytest.mark.parametrize("command", WITH_INPUTS, ids=["-".join(c) for c in WITH_INPUTS])
def test_output_folder_that_is_an_input_folder_is_refused(command, tmp_path, capsys) -> None:
    data = tmp_path / "data"
    a, b = _inputs(data)
    (tmp_path / "link").symlink_to(data)
    _refused(_argv(command, a, b, tmp_path / "link"), capsys, "lies inside the output folder")
    _refused(_argv(command, a, b, tmp_path / "data" / ".." / "data"), capsys, "lies inside the output folder")
    nested = tmp_path / "outer"
    a2, b2 = _inputs(nested / "in")
    _refused(_argv(command, a2, b2, nested), capsys, "lies inside the output folder")


@pytest.mark.parametrize("command", [*COMMANDS, ("reproduce",)], ids=["-".join(c) for c in [*COMMANDS, ("reproduce",)]])
def test_foreign_file_in_the_output_folder_is_refused(command, tmp_path, capsys) -> None:
    a, b = _inputs(tmp_path / "in")
    out = tmp_path / "out"
    (out / "sub").mkdir(parents=True)
    mine = out / "sub" / "notes.txt"
    mine.write_text("my own notes\n")
    _refused(_argv(command, a, b, out), capsys, "did not write", "sub/notes.txt")
    assert mine.read_text() == "my own notes\n" and not (out / OUTPUT_MANIFEST).exists()


def test_rerun_into_its_own_folder_is_allowed_and_a_new_foreign_file_is_not(tmp_path, capsys) -> None:
    out = tmp_path / "run"
    argv = ["reproduce", "consensus", "--quick", "--no-progress", "--out", str(out)]
    assert main(argv) == 0
    listed = (out / OUTPUT_MANIFEST).read_text().splitlines()
    assert "results.json" in listed and "fig2_networks.png" in listed
    assert main(argv) == 0  # the same folder again: every file in it is distnav's
    (out / "results-by-hand.json").write_text("{}")
    _refused(argv, capsys, "results-by-hand.json")


def test_the_issue_case_uwb_solve_over_its_own_links(tmp_path, capsys) -> None:
    """Issue 29: ``uwb solve --ranges OUT/links.csv ... --out OUT`` overwrote its input with its output, exit 0."""
    first = tmp_path / "OUT"
    ranges = tmp_path / "ranges.csv"
    known = tmp_path / "known.csv"
    coords = {1: (0.0, 0.0), 2: (10.0, 0.0), 3: (0.0, 10.0), 4: (10.0, 10.0), 5: (4.0, 6.0)}
    rows = ["a,b,range_m"] + [
        f"{i},{j},{((coords[i][0] - coords[j][0]) ** 2 + (coords[i][1] - coords[j][1]) ** 2) ** 0.5:.4f}"
        for i in coords
        for j in coords
        if i < j
    ]
    ranges.write_text("\n".join(rows) + "\n")
    known.write_text("id,x_m,y_m\n" + "".join(f"{i},{x},{y}\n" for i, (x, y) in list(coords.items())[:3]))
    assert main(["uwb", "solve", "--ranges", str(ranges), "--known", str(known), "--out", str(first)]) == 0
    capsys.readouterr()
    links = first / "links.csv"
    before = links.read_bytes()
    _refused(
        ["uwb", "solve", "--ranges", str(links), "--known", str(known), "--out", str(first)],
        capsys,
        f"input file {links.resolve()} lies inside the output folder",
    )
    assert links.read_bytes() == before


def test_input_paths_and_the_rule(tmp_path) -> None:
    a, _ = _inputs(tmp_path / "x")
    assert input_paths(["nope", 3, None, [str(a), ("8,12",)]]) == [a.resolve()]
    check_output_spares(tmp_path / "elsewhere", [a])  # a new folder beside the input: fine
    check_output_spares(tmp_path / "x" / "sub", [a])  # a new folder below the input's folder: fine
    with pytest.raises(Exception, match="lies inside"):
        check_output_spares(tmp_path, [a])
