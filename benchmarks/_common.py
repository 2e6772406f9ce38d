"""Shared helpers for the benchmark scripts: timing, JSON output, a printed table.

Every ``benchmarks/bench_<area>.py`` defines ``run(quick: bool) -> list[dict]`` (one row per measurement with
at least ``name``; usually ``seconds``, ``reference_seconds``, ``ratio``, ``goal`` and ``meets_goal``) and ends with
``if __name__ == "__main__": main_for(__file__, run)``. ``benchmarks/run.py`` runs them all.
Figures are ratios measured in one run: the machines are shared and noisy.
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

RESULTS = Path(__file__).resolve().parent / "results"


def best_time(fn: Callable[[], Any], *, repeat: int = 5, number: int = 1) -> float:
    """Best of ``repeat`` timings of ``number`` calls, in seconds per call."""
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        for _ in range(number):
            fn()
        best = min(best, (time.perf_counter() - t0) / number)
    return best


def paired_times(fns: dict[str, Callable[[], Any]], *, repeat: int = 5, number: int = 1) -> dict[str, np.ndarray]:
    """Seconds per call of each function, measured *interleaved* (one batch of each per repeat), so a noisy
    neighbour on the shared machine slows every candidate of a repeat alike. Returns ``repeat`` timings each."""
    out: dict[str, list[float]] = {k: [] for k in fns}
    for _ in range(repeat):
        for name, fn in fns.items():
            t0 = time.perf_counter()
            for _ in range(number):
                fn()
            out[name].append((time.perf_counter() - t0) / number)
    return {k: np.asarray(v) for k, v in out.items()}


def ratio_stats(ours: np.ndarray, floor: np.ndarray) -> dict[str, float]:
    """Per-repeat ratios of two paired timings: their minimum and median (the figure quoted as min–median)."""
    r = np.asarray(ours) / np.asarray(floor)
    return {"ratio_min": float(r.min()), "ratio_median": float(np.median(r))}


def _fmt(v: Any) -> str:
    if isinstance(v, float):
        return f"{v:.4g}"
    return str(v)


def print_table(title: str, rows: list[dict[str, Any]]) -> None:
    if not rows:
        return
    cols: list[str] = []
    for r in rows:
        for k in r:
            if k not in cols:
                cols.append(k)
    width = {c: max(len(c), *(len(_fmt(r.get(c, ""))) for r in rows)) for c in cols}
    print(f"\n## {title}")
    print("  ".join(c.ljust(width[c]) for c in cols))
    for r in rows:
        print("  ".join(_fmt(r.get(c, "")).ljust(width[c]) for c in cols))


def write_json(area: str, rows: list[dict[str, Any]]) -> Path:
    RESULTS.mkdir(parents=True, exist_ok=True)
    path = RESULTS / f"{area}.json"
    payload = {
        "area": area,
        "python": sys.version.split()[0],
        "numpy": np.__version__,
        "machine": platform.machine(),
        "time": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "rows": rows,
    }
    path.write_text(json.dumps(payload, indent=2, default=float) + "\n")
    return path


def main_for(file: str, run: Callable[[bool], list[dict[str, Any]]]) -> None:
    area = Path(file).stem.removeprefix("bench_")
    ap = argparse.ArgumentParser(description=f"distnav benchmark: {area}")
    ap.add_argument("--quick", action="store_true", help="small sizes only (seconds)")
    args = ap.parse_args()
    rows = run(args.quick)
    print_table(area, rows)
    print(f"\nwritten {write_json(area, rows)}")
