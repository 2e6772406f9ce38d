"""Issue 29 item 7: the demo report's cells — numbers inside lists and dicts to 4 significant digits (the uwb-field
table printed 16-digit floats), missing values as a dash, and long unbroken names allowed to wrap."""

from __future__ import annotations

import numpy as np

from distnav.experiments.report import _CSS, _fmt


def test_numbers_in_lists_and_dicts_are_short() -> None:
    assert _fmt([0.12345678901234567, 2.0, np.float64(1 / 3)]) == "[0.1235, 2, 0.3333]"
    assert _fmt({"a": 1.23456789e-7, "b": [np.nan, 3]}) == "{a: 1.235e-07, b: [—, 3]}"
    assert _fmt(np.array([1.0, 2.5])) == "[1, 2.5]"
    assert _fmt(0.000123456) == "0.0001235" and _fmt("tests/test_x.py::test_name") == "tests/test_x.py::test_name"


def _rule(selector: str) -> str:
    return _CSS.split(selector + "{", 1)[1].split("}", 1)[0]


def test_long_names_wrap_in_table_cells() -> None:
    # every cell may break a long word that would overflow it, without shrinking short columns to a letter a line
    # (``anywhere`` on every cell let the browser squeeze "consensus" and "agree" to one letter per line: seen in
    # a headless-Chromium screenshot of the demo report); the claims table's "why" column (test names) breaks
    # anywhere, its short columns never break
    assert "overflow-wrap:break-word" in _rule("td,th")
    assert "overflow-wrap:anywhere" in _rule("table.claims td:nth-child(8)")
    assert "white-space:nowrap" in _rule("table.claims td:nth-child(-n+3),table.claims td:nth-child(7)")
