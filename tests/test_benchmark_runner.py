"""The benchmark runner's table (``benchmarks/run.py``) and the peers' availability check (``bench_peers.py``).

No benchmark is run here: the table is built from hand-written result rows, and the peers' check is given
interpreters that cannot import the peers (the project's own Python has neither decent-bench nor disropt)."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

import pytest

BENCH = Path(__file__).resolve().parents[1] / "benchmarks"


def _load(name: str) -> ModuleType:
    sys.path.insert(0, str(BENCH))
    try:
        spec = importlib.util.spec_from_file_location(f"_bench_{name}", BENCH / f"{name}.py")
        assert spec and spec.loader
        mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)
        return mod
    finally:
        sys.path.remove(str(BENCH))


def _table_row(md: str, start: str) -> list[str]:
    line = next(x for x in md.splitlines() if x.startswith(f"| {start}"))
    return [c.strip() for c in line.strip("|").split("|")]


def test_rows_in_the_older_keys_show_their_figures() -> None:
    run = _load("run")
    payload = {
        "time": "T",
        "numpy": "2",
        "python": "3",
        "rows": [
            {
                "name": "n=200: per-pair",
                "seconds": 1e-4,
                "ms_per_iteration": 0.104,
                "reference_seconds": 9.8e-5,
                "reference": "centralized BLUE solve",
                "ratio": 1.06,
                "goal": "≤ 0.5 ms",
                "meets_goal": True,
            },
            {"name": "CKF paper workload", "n_nodes": 13, "seconds": 2.75, "reference_seconds": 72.3, "ratio": 0.038},
            {"name": "ADMM under MPI", "n_nodes": 99_856, "ranks": 2, "ms_per_iteration": 765.0},
            {
                "name": "new style",
                "n_nodes": 10,
                "distnav_ms": 2.0,
                "floor_ms": 1.0,
                "floor": "bare",
                "ratio_min": 1.5,
                "ratio_median": 2.0,
            },
            {
                "name": "vs a slow peer",
                "distnav_ms": 0.1,
                "floor_ms": 50.0,
                "ratio_min": 0.0008,
                "ratio_median": 0.0023,
            },
        ],
    }
    md = run.markdown({"demo": payload})
    # columns: workload, size, distnav, floor, floor is, ratio, goal, met, set-up, exponent
    assert _table_row(md, "n=200: per-pair")[2:6] == ["0.104 ms", "9.8e-05 s", "centralized BLUE solve", "1.06×"]
    assert _table_row(md, "CKF paper workload")[2:4] == ["2.75 s", "72.3 s"]
    assert _table_row(md, "ADMM under MPI")[2] == "765 ms"
    assert _table_row(md, "new style")[2:6] == ["2 ms", "1 ms", "bare", "1.50–2.00×"]
    assert _table_row(md, "vs a slow peer")[5] == "0.0008–0.0023×"


def test_scaling_exponent_reads_the_older_keys_too() -> None:
    run = _load("run")
    rows = [
        {"name": "w", "n_nodes": 100, "seconds": 1.0},
        {"name": "w", "n_nodes": 10_000, "seconds": 100.0},
        {"name": "v", "n_nodes": 100, "distnav_ms": 1.0},
        {"name": "v", "n_nodes": 10_000, "distnav_ms": 10.0},
    ]
    k = run._exponents(rows)
    assert k[("w", None)] == pytest.approx(1.0)
    assert k[("v", None)] == pytest.approx(0.5)


def test_peers_missing_are_named(tmp_path: Path) -> None:
    peers = _load("bench_peers")
    assert "not installed" in (peers.peer_missing(None, "decent-bench") or "")
    gone = tmp_path / "no-python"
    assert f"{gone} does not exist" in (peers.peer_missing(str(gone), "disropt") or "")
    # the project's own interpreter exists but has neither peer
    why = peers.peer_missing(sys.executable, "decent-bench") or ""
    assert why.startswith("not installed") and "cannot import decent_bench" in why


def test_recorded_peer_row_is_labelled() -> None:
    """Without the peers' Python the row quotes the recorded figures, says so, and gives no goal verdict (the
    recorded error is not of this run)."""
    peers = _load("bench_peers")
    row = peers.decent_bench_row(True, None)
    assert row["peer_status"] == "recorded" and "RECORDED" in row["floor"] and "not installed" in row["note"]
    assert row["floor_ms"] == 49.5 and row["ratio_median"] == pytest.approx(row["distnav_ms"] / 49.5)
    assert row["meets_goal"] is None and row["peer_error_after_iterations"] is None
