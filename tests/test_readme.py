"""The Python examples in README.md and docs/*.md run as written, and print what the page says they print.

A ``python`` block that prints is followed by an ``output`` block: what it printed when the page was written. The
test runs every block (in the page's order, one namespace per page) and compares: the words exactly, the numbers to
2 % (numbers of magnitude below 1e-6 — round-off residuals such as ``1e-12`` — only to a factor of 10, as they
depend on the BLAS). So no figure in an example's output can be contradicted by a run without the suite failing.
"""

from __future__ import annotations

import contextlib
import io
import math
import re
from pathlib import Path

import pytest

from conftest import REPO

DOCS = [REPO / "README.md", *sorted((REPO / "docs").glob("*.md"))]
_BLOCK = re.compile(r"```python\n(.*?)```(?:\s*```output\n(.*?)```)?", flags=re.S)
_NUMBER = re.compile(r"[-+]?(?:\d+\.\d*|\.\d+|\d+)(?:[eE][-+]?\d+)?|\bnan\b")


def _python_blocks(path: Path) -> list[tuple[str, str | None]]:
    """``(code, printed output or None)`` of every ``python`` block of ``path``."""
    return [(m.group(1), m.group(2)) for m in _BLOCK.finditer(path.read_text(encoding="utf-8"))]


def _numbers_agree(got: str, want: str) -> bool:
    if got == want:
        return True
    try:
        a, b = float(got), float(want)
    except ValueError:
        return False
    if math.isnan(a) or math.isnan(b):
        return False
    if abs(b) < 1e-6:
        return abs(a) <= 10 * abs(b) and (abs(b) == 0 or abs(a) >= abs(b) / 10)
    return math.isclose(a, b, rel_tol=0.02)


def output_mismatch(got: str, want: str) -> str | None:
    """Why the printed ``got`` differs from the page's ``want`` (None when they agree)."""
    got_lines, want_lines = got.strip().splitlines(), want.strip().splitlines()
    if len(got_lines) != len(want_lines):
        return f"{len(got_lines)} lines printed, the page shows {len(want_lines)}:\n{got}"
    for g, w in zip(got_lines, want_lines, strict=True):
        g_words, w_words = _NUMBER.split(g.strip()), _NUMBER.split(w.strip())
        g_nums, w_nums = _NUMBER.findall(g.strip()), _NUMBER.findall(w.strip())
        if [s.split() for s in g_words] != [s.split() for s in w_words] or len(g_nums) != len(w_nums):
            return f"printed {g!r}, the page shows {w!r}"
        for a, b in zip(g_nums, w_nums, strict=True):
            if not _numbers_agree(a, b):
                return f"printed {a} where the page shows {b}: {g!r} vs {w!r}"
    return None


def test_readme_has_python_example():
    assert _python_blocks(REPO / "README.md"), "README.md must show a Python example"


def test_output_comparison_can_fail():
    assert output_mismatch("converged: 2e-10 °C, 360000 messages", "converged: 2e-10 °C, 360000 messages") is None
    assert output_mismatch("converged: 3e-10 °C, 360000", "converged: 2e-10 °C, 360000") is None  # round-off
    assert output_mismatch("max_iterations: 3e-02 °C, 36000", "converged: 2e-10 °C, 360000")
    assert output_mismatch("converged: 3e-02 °C, 360000", "converged: 2e-10 °C, 360000")
    assert output_mismatch("converged: 2e-10 °C, 36000", "converged: 2e-10 °C, 360000")
    assert output_mismatch("0.84 ns", "0.88 ns") and output_mismatch("a\nb", "a")


@pytest.mark.parametrize("path", DOCS, ids=[p.name for p in DOCS])
def test_python_examples_run_and_print_what_the_page_says(path, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # examples that write files write them here
    namespace = {"__name__": "__doc_example__"}
    for code, shown in _python_blocks(path):
        printed = io.StringIO()
        with contextlib.redirect_stdout(printed):
            exec(  # noqa: S102 - run as a user would: no inherited __future__
                compile(code, str(path), "exec", dont_inherit=True), namespace
            )
        first = code.strip().splitlines()[0]
        if "print(" in code:
            assert shown is not None, f"{path.name}: the example starting {first!r} prints but shows no output block"
            problem = output_mismatch(printed.getvalue(), shown)
            assert problem is None, f"{path.name}, example starting {first!r}: {problem}"
