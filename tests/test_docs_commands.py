"""Every ``distnav`` command the README and docs/*.md show names a command and options that exist.

The shell blocks and the inline commands of the pages are read as a user would copy them: the words up to the
first option must be a path of sub-commands of the CLI's parser (``uwb solve``, ``reproduce uwb-field``, …), and
every ``--option`` must be one of that sub-command's options. Running them is too slow for the suite (the real
data take minutes); this catches the drift that costs a user most: a renamed command, an option that no longer
exists (the examples' outputs are checked by tests/test_readme.py; the figures by re-running them, docs/claims.md).
"""

from __future__ import annotations

import argparse
import re
from pathlib import Path

import pytest

from conftest import REPO
from distnav.cli import build_parser

DOCS = [REPO / "README.md", *sorted((REPO / "docs").glob("*.md"))]
_FENCE = re.compile(r"^```(\w*)\n(.*?)^```", flags=re.S | re.M)
_INLINE = re.compile(r"`(?:[^`\n]*?-m )?(distnav [^`\n]+)`")  # also `mpiexec … python -m mpi4py -m distnav …`
_PLACEHOLDER = re.compile(r"^(\.\.\.|…|[A-Z_]+|<\S+>|\S*\|\S*)$")  # DIR, NAME, <verb>, ..., a|b: filled in by a user


def _shell_commands(text: str) -> list[tuple[str, bool]]:
    """The ``distnav …`` commands of the page's shell and plain blocks (continuation lines joined, comments cut)
    and of its inline code, each with whether it is meant to run as shown (a block's line, or inline code that
    gives options: ``distnav gnss codebias`` in a sentence names the command); ``mpiexec … -m distnav …`` counts
    from ``distnav``."""
    found = []
    for lang, body in _FENCE.findall(text):
        if lang not in ("", "bash", "sh", "console"):
            continue
        body = re.sub(r"\n\s+(?=[\[-])", " ", body.replace("\\\n", " "))  # a synopsis's indented lines go on
        for line in body.splitlines():
            line = line.split(" #", 1)[0].strip()
            m = re.search(r"(?:^|-m )(distnav\s.*)$", line)
            if m:
                found.append((m.group(1), True))
    found += [(cmd, " -" in cmd) for cmd in _INLINE.findall(text)]
    return found


def _subparsers(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser] | None:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return dict(action.choices)
    return None


def command_problem(parser: argparse.ArgumentParser, command: str, *, complete: bool = True) -> str | None:
    """Why ``command`` would not parse as far as names go (an unknown sub-command or option; with ``complete``, a
    required option left out unless the command elides with ``...``), else None."""
    words = command.replace("[", " ").replace("]", " ").split()[1:]
    path = ["distnav"]
    while words and (choices := _subparsers(parser)) is not None:
        word = words[0]
        if _PLACEHOLDER.match(word):
            return None  # "reproduce NAME --out DIR": the options depend on the name filled in
        if word.startswith("-"):
            break
        if word not in choices:
            return f"{' '.join(path)}: no sub-command {word!r} (has {', '.join(sorted(choices))})"
        parser, path, words = choices[word], [*path, word], words[1:]
    known = {s for a in parser._actions for s in a.option_strings}
    unknown = [w.split("=")[0] for w in words if w.startswith("--") and w.split("=")[0] not in known]
    if unknown:
        return f"{' '.join(path)}: no option {', '.join(unknown)}"
    given = {w.split("=")[0] for w in words}
    required = [a.option_strings[0] for a in parser._actions if a.required and a.option_strings]
    missing = [o for o in required if o not in given]
    elided = "..." in command or "…" in command or "--help" in given or "-h" in given or not complete
    return f"{' '.join(path)}: without {', '.join(missing)} (required)" if missing and not elided else None


def test_the_check_can_fail():
    parser = build_parser()
    assert command_problem(parser, "distnav uwb solve --ranges r.csv --known k.csv --out o") is None
    assert command_problem(parser, "distnav reproduce uwb --quick --out DIR [--instances N]") is None
    assert command_problem(parser, "distnav reproduce NAME --quick") is None  # options of a placeholder: unknown
    assert "no option --no-such" in command_problem(parser, "distnav uwb solve --no-such 1")
    assert "no sub-command 'qc-ckf'" in command_problem(parser, "distnav reproduce qc-ckf --out x")
    assert "no sub-command 'solvee'" in command_problem(parser, "distnav uwb solvee --out x")
    assert "without --out (required)" in command_problem(parser, "distnav reproduce ckf --quick")
    assert command_problem(parser, "distnav reproduce ckf --quick ...") is None  # the rest elided on purpose
    assert _shell_commands("```\nmpiexec -n 4 python -m mpi4py -m distnav reproduce ckf \\\n  --quick # c\n```") == [
        ("distnav reproduce ckf    --quick", True)
    ]
    assert _shell_commands("`distnav reproduce ckf` runs, `distnav reproduce ckf --quick` too") == [
        ("distnav reproduce ckf", False),
        ("distnav reproduce ckf --quick", True),
    ]


@pytest.mark.parametrize("path", DOCS, ids=[p.name for p in DOCS])
def test_every_documented_command_names_existing_commands_and_options(path: Path):
    parser = build_parser()
    problems = [
        f"{cmd!r}: {why}"
        for cmd, complete in _shell_commands(path.read_text(encoding="utf-8"))
        if (why := command_problem(parser, cmd, complete=complete))
    ]
    assert not problems, f"{path.name}:\n" + "\n".join(problems)


def test_the_uwb_solve_synopsis_lists_every_option():
    """docs/uwb.md's synopsis of ``uwb solve`` is a user's list of what the command takes: every option, no more
    (it lacked --estimate-offset-prior, --reliability-limit-m and --no-refine until the docs12 pass)."""
    text = (REPO / "docs" / "uwb.md").read_text(encoding="utf-8")
    synopsis = next(body for _, body in _FENCE.findall(text) if body.startswith("distnav uwb solve --ranges"))
    solve = _subparsers(_subparsers(build_parser())["uwb"])["solve"]
    options = {s for a in solve._actions for s in a.option_strings if s.startswith("--") and s != "--help"}
    shown = set(re.findall(r"--[a-z0-9-]+", synopsis))
    assert options - shown == set(), "missing from the synopsis"
    assert shown - options == set(), "not options of uwb solve"
