"""``distnav --version`` and ``--help`` answer from the top-level table without importing the commands, the
experiments, numpy or scipy (issue 29 item 6; the time itself is measured in benchmarks/bench_cli_startup.py), and
the table says what the full parser says."""

from __future__ import annotations

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
