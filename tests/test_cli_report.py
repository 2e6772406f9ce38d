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


def test_the_report_explains_every_verdict_and_every_solver_status() -> None:
    from distnav.algorithms.result import SOLVER_STATUSES
    from distnav.experiments.claims import VERDICTS
    from distnav.experiments.report import STATUS_MEANINGS, VERDICT_MEANINGS, legend_lines

    assert tuple(STATUS_MEANINGS) == SOLVER_STATUSES  # a new status needs its meaning here
    assert tuple(VERDICT_MEANINGS) == VERDICTS
    assert len(legend_lines()) == len(SOLVER_STATUSES) + len(VERDICTS)


def test_uwb_field_rows_give_statuses_and_bytes_beside_the_gather() -> None:
    from distnav.experiments.report import table_lines

    rows = [
        {"scenario": "plant", "placement": "middle", "solver": "LM", "instances": 2, "statuses": {"converged": 2}}
        | {"messages": 0.0, "bytes": 0.0, "gather_bytes": 3000.0},  # LM sends nothing: no communication line
        {"scenario": "plant", "placement": "middle", "solver": "N-CLM", "instances": 2}
        | {"statuses": {"weakly_determined": 1, "converged": 1}, "messages": 36805.0}
        | {"bytes": 127443.0, "gather_bytes": 3048.0},
    ]
    statuses, comm = table_lines({"table": rows})
    assert statuses == [
        "plant middle LM: converged 2 (of 2 halls)",
        "plant middle N-CLM: weakly_determined 1, converged 1 (of 2 halls)",
    ]
    assert comm == [
        "plant middle N-CLM: sent 127.4 kB in 36,805 messages per solve (mean); gathering the ranges at one anchor "
        "and sending the positions back would cost 3.05 kB: 42× the bytes"  # 127443 / 3048 = 41.8
    ]
    assert table_lines({"headline": {}}) == ([], []) and table_lines([1, 2]) == ([], [])
