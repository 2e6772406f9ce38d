"""The Python examples in README.md run as written."""

from __future__ import annotations

import re

from conftest import REPO


def _python_blocks() -> list[str]:
    text = (REPO / "README.md").read_text(encoding="utf-8")
    return re.findall(r"```python\n(.*?)```", text, flags=re.S)


def test_readme_has_python_example():
    assert _python_blocks(), "README.md must show a Python example"


def test_readme_python_examples_run(capsys):
    for block in _python_blocks():
        exec(compile(block, "README.md", "exec"), {})  # noqa: S102 - the README's own example
    assert capsys.readouterr().out.strip(), "the README example prints its result"
