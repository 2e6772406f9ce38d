"""``distnav --version`` and ``--help`` answer from the top-level table without importing the commands, the
experiments, numpy or scipy (issue 29 item 6; the time itself is measured in benchmarks/bench_cli_startup.py), and
the table says what the full parser says."""

from __future__ import annotations

import argparse
import json
import subprocess
import sys

import pytest

from distnav import __version__
from distnav.cli import build_parser, build_top_level_parser, main

HEAVY = ("numpy", "scipy", "matplotlib", "distnav.commands", "distnav.experiments.common", "distnav.exchange")


def test_top_level_help_is_the_full_parsers() -> None:
    light = build_top_level_parser()
    assert light is not None, "a module of COMMAND_MODULES has no line in TOP_LEVEL_HELP / COMMAND_NAMES"
    assert light.format_help() == build_parser().format_help()


@pytest.mark.parametrize("flag", ["--version", "--help"])
def test_version_and_help_import_nothing_heavy(flag: str) -> None:
    code = (
        "import json, sys\n"
        "from distnav.cli import main\n"
        "try:\n"
        f"    main([{flag!r}])\n"
        "except SystemExit:\n"
        "    pass\n"
        f"print(json.dumps([m for m in {HEAVY!r} if m in sys.modules]), file=sys.stderr)\n"
    )
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert json.loads(run.stderr.strip().splitlines()[-1]) == []
    assert (f"distnav {__version__}" if flag == "--version" else "reproduce-all") in run.stdout


@pytest.mark.parametrize("argv", [[], ["--frobnicate"], ["-h"], ["--version"], ["--version", "--help"]])
def test_without_a_command_the_answer_is_the_full_parsers(argv: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as full:
        build_parser().parse_args(argv)
    expected = capsys.readouterr()
    with pytest.raises(SystemExit) as light:
        main(argv)
    assert light.value.code == full.value.code and capsys.readouterr() == expected


def _subparsers(parser: argparse.ArgumentParser, path: tuple[str, ...] = ()) -> dict[tuple[str, ...], str]:
    """Every (sub)command path of ``parser`` and its help text."""
    found = {path: parser.format_help()}
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                found.update(_subparsers(sub, (*path, name)))
    return found


def test_a_named_command_is_built_as_in_the_full_parser() -> None:
    """Issue 32 item 7: ``build_parser(words)`` builds only the named command; each command path's help (its
    options, types, defaults) is the full parser's, and so is every top-level line."""
    full = _subparsers(build_parser())
    commands = {path[:2] if path[0] == "reproduce" else path[:1] for path in full if path}
    assert len(commands) >= 14  # demo, reproduce + 8 experiments, uwb, gnss, reproduce-all, node, field
    for command in commands:
        light = _subparsers(build_parser([*command, "--help"]))
        assert light[()] == full[()]
        built = {p: h for p, h in light.items() if p[: len(command)] == command}
        assert built == {p: h for p, h in full.items() if p[: len(command)] == command}, command


@pytest.mark.parametrize(
    ("argv", "imported", "not_imported"),
    [
        (
            ["gnss", "codebias", "--help"],
            "distnav.commands.gnss",
            ("distnav.experiments.consensus", "distnav.experiments.common", "distnav.commands.uwb", "matplotlib"),
        ),
        (
            ["reproduce", "consensus", "--help"],
            "distnav.experiments.consensus",
            ("distnav.experiments.admm", "distnav.experiments.uwb", "distnav.commands.gnss", "distnav.commands.uwb"),
        ),
        (
            ["reproduce-all", "--help"],
            "distnav.commands.reproduce_all",
            ("distnav.experiments.common", "distnav.commands.gnss"),
        ),
    ],
)
def test_a_command_imports_only_its_own_modules(argv: list[str], imported: str, not_imported: tuple[str, ...]) -> None:
    code = (
        "import json, sys\n"
        "from distnav.cli import main\n"
        "try:\n"
        f"    main({argv!r})\n"
        "except SystemExit:\n"
        "    pass\n"
        f"print(json.dumps([m for m in {(imported, *not_imported)!r} if m in sys.modules]), file=sys.stderr)\n"
    )
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert json.loads(run.stderr.strip().splitlines()[-1]) == [imported], run.stderr[-2000:]
    assert "usage: distnav " + " ".join(argv[:-1]) in run.stdout
