"""The Python examples in README.md and docs/*.md run as written."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from conftest import REPO

DOCS = [REPO / "README.md", *sorted((REPO / "docs").glob("*.md"))]


def _python_blocks(path: Path) -> list[str]:
    return re.findall(r"```python\n(.*?)```", path.read_text(encoding="utf-8"), flags=re.S)


def test_readme_has_python_example():
    assert _python_blocks(REPO / "README.md"), "README.md must show a Python example"


@pytest.mark.parametrize("path", DOCS, ids=[p.name for p in DOCS])
def test_python_examples_run(path, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # examples that write files write them here
    blocks = _python_blocks(path)
    for block in blocks:
        exec(
            compile(block, str(path), "exec", dont_inherit=True),  # run as a user would: no inherited __future__
            {"__name__": "__doc_example__"},
        )  # noqa: S102
    if any("print(" in b for b in blocks):
        assert capsys.readouterr().out.strip(), f"the examples of {path.name} print their results"
