"""The demo report's field section: present exactly when DIR/field/results.json exists, verdicts shown as written."""

from __future__ import annotations

import json
from pathlib import Path

from distnav.experiments.report import write_report


def test_field_section_only_with_results(tmp_path: Path) -> None:
    write_report(tmp_path, [])
    assert "Field runtime" not in (tmp_path / "REPORT.md").read_text()
    (tmp_path / "field").mkdir()
    results = {
        "nodes": 8,
        "headline": {"consensus clean: max |field - in-process|": 0.0, "wire bytes, all runs": 1234},
        "verdicts": {"clean run bitwise equal to in-process": True, "async push-sum within 1e-6 of the mean": False},
    }
    (tmp_path / "field" / "results.json").write_text(json.dumps(results))
    write_report(tmp_path, [])
    md = (tmp_path / "REPORT.md").read_text()
    assert "## Field runtime: 8 node processes on loopback" in md
    assert "| consensus clean: max \\|field - in-process\\| | 0 |" in md
    assert "| clean run bitwise equal to in-process | ok |" in md
    assert "| async push-sum within 1e-6 of the mean | FAIL |" in md
    assert "href='field/results.json'" in (tmp_path / "index.html").read_text()
