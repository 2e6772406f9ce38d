"""scripts/compare_results.py: identical trees pass, any changed byte outside wall-clock timings fails."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

from conftest import REPO

_spec = importlib.util.spec_from_file_location("compare_results", REPO / "scripts" / "compare_results.py")
assert _spec is not None and _spec.loader is not None
compare_results = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(compare_results)


def _write(root: Path, name: str, data: object) -> None:
    (root / name).mkdir(parents=True)
    (root / name / "results.json").write_text(json.dumps(data, indent=2) + "\n", encoding="utf-8")


def _trees(tmp_path: Path, b_admm: object, b_uwb: object) -> tuple[Path, Path]:
    a, b = tmp_path / "a", tmp_path / "b"
    _write(a, "admm", {"x": [1.0, 0.1], "n": 3})
    _write(a, "uwb", {"rmse_m": 0.5, "solver_seconds": {"LM": 0.7}})
    _write(b, "admm", b_admm)
    _write(b, "uwb", b_uwb)
    return a, b


def test_identical_and_timings_only(tmp_path: Path, capsys) -> None:
    a, b = _trees(tmp_path, {"x": [1.0, 0.1], "n": 3}, {"rmse_m": 0.5, "solver_seconds": {"LM": 1.9}})
    assert compare_results.main([str(a), str(b)]) == 0
    out = capsys.readouterr().out
    assert "identical  admm" in out and "except wall-clock" in out and "solver_seconds" in out
    assert compare_results.main([str(a), str(b), "--volatile"]) == 1  # every byte: the timing differs


def test_cpu_timings_are_volatile_too(tmp_path: Path) -> None:
    a, b = tmp_path / "a", tmp_path / "b"
    _write(a, "uwb-field", {"rmse_m": 0.5, "runs": [{"cpu_s": 0.33, "cpu_s_per_solve": 0.1, "wall_s": 1.0}]})
    _write(b, "uwb-field", {"rmse_m": 0.5, "runs": [{"cpu_s": 0.49, "cpu_s_per_solve": 0.2, "wall_s": 2.0}]})
    assert compare_results.main([str(a), str(b)]) == 0
    assert compare_results.main([str(a), str(b), "--volatile"]) == 1


def test_last_digit_differs(tmp_path: Path, capsys) -> None:
    a, b = _trees(tmp_path, {"x": [1.0, 0.1 + 2**-55], "n": 3}, {"rmse_m": 0.5, "solver_seconds": {"LM": 0.7}})
    assert 0.1 + 2**-55 != 0.1
    assert compare_results.main([str(a), str(b)]) == 1
    assert "DIFFERENT  admm: $.x[1]" in capsys.readouterr().out


def test_value_beside_timings_differs(tmp_path: Path, capsys) -> None:
    a, b = _trees(tmp_path, {"x": [1.0, 0.1], "n": 3}, {"rmse_m": 0.51, "solver_seconds": {"LM": 0.7}})
    assert compare_results.main([str(a), str(b)]) == 1
    assert "DIFFERENT  uwb: $.rmse_m" in capsys.readouterr().out


def test_missing_experiment(tmp_path: Path, capsys) -> None:
    a, b = _trees(tmp_path, {"x": [1.0, 0.1], "n": 3}, {"rmse_m": 0.5, "solver_seconds": {"LM": 0.7}})
    _write(a, "ckf", {})
    assert compare_results.main([str(a), str(b)]) == 1
    assert "ckf: results.json missing in B" in capsys.readouterr().out
