"""UWB N-CSG-TBLS / N-CLM per iteration from 10² to 10⁴ anchors (issue 17's UWB row: linear in the anchors).

The grid layout "G" of ``bench_uwb``'s large-grid row (side × side anchors, 3-D, three fixed anchors, ranges with
σ = 0.15 m, a start within ±5 m), side = 10, 32, 100 (10, 32 with ``--quick``); the paper's settings (a fixed count of
20 iterations, no quality control). Per solver and size: CPU milliseconds of this process per iteration (best
of 2 runs; the shown figure, as the machine is shared: wall time there mostly measures the queue for a core), the
wall milliseconds beside it, microseconds (CPU) per anchor-iteration, and the log-log slope of the time per
iteration over the anchor count from the smallest to the largest grid (the table's ``time ∝ n^k``). There is no
bare floor for these solvers: the goal is the scaling itself, k ≤ 1.15 (linear; the issue's figures: 3.7–5.6 /
6.2–9.3 µs per anchor-iteration). One more row: N-CSG-TBLS with its default stopping rule (``StopRule()``) against
the paper's fixed 500 iterations on the 32 × 32 grid (the issue's "far fewer iterations"): iterations, CPU time
and final RMSE of both.
"""

from __future__ import annotations

import math
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import main_for  # noqa: E402
from distnav.algorithms.csg import PAPER_MODE, solve  # noqa: E402
from distnav.models.uwb.problems import build_problem, generate_layout  # noqa: E402

ITERATIONS = 20
GOAL_K = 1.15


def grid_problem(side: int, rng: np.random.Generator) -> Any:
    pos, links = generate_layout("G", n_anchors=side * side)
    truth = np.column_stack([pos, np.zeros(side * side)])
    d = np.linalg.norm(truth[links[:, 0]] - truth[links[:, 1]], axis=1) + rng.normal(0, 0.15, links.shape[0])
    ids = [str(i) for i in range(side * side)]
    return build_problem(ids, links, d, fixed={ids[i]: truth[i] for i in (0, 1, side)}, dim=3,
                         initial_m=truth + rng.uniform(-5, 5, truth.shape), truth_m=truth)


def run(quick: bool) -> list[dict[str, Any]]:
    rows: list[dict[str, Any]] = []
    sides = (10, 32) if quick else (10, 32, 100)
    for solver in ("N-CSG-TBLS", "N-CLM"):
        series = []
        for side in sides:
            q = grid_problem(side, np.random.default_rng(0))
            n = side * side
            best_w = best_c = math.inf
            for _ in range(2):
                c0, w0 = time.process_time(), time.perf_counter()
                res = solve(q, solver, iterations=ITERATIONS, **PAPER_MODE)
                best_w = min(best_w, time.perf_counter() - w0)
                best_c = min(best_c, time.process_time() - c0)
            ms = best_c / ITERATIONS * 1e3
            series.append((n, ms))
            rows.append({"name": f"UWB {solver} iteration (grid, paper settings)", "n_nodes": n,
                         "distnav_ms": ms, "clock": "CPU ms", "wall_ms_per_iteration": best_w / ITERATIONS * 1e3,
                         "us_per_anchor_iteration": ms * 1e3 / n, "iterations": ITERATIONS,
                         "final_rmse_m": float(res.trace["rmse_m"][-1]),
                         "note": f"CPU; {ms * 1e3 / n:.2g} µs per anchor-iteration; wall "
                                                                       f"{best_w / ITERATIONS * 1e3:.3g} ms"})
        (n0, t0), (n1, t1) = series[0], series[-1]
        k = math.log(t1 / t0) / math.log(n1 / n0)
        rows[-1].update({"scaling_exponent": k, "goal": f"linear: time ∝ n^k, k ≤ {GOAL_K}",
                         "meets_goal": bool(k <= GOAL_K)})
    rows.append(stopping_row(32))  # 1,024 anchors: the 10⁴ grid would add a minute for the same answer
    return rows


def stopping_row(side: int, fixed: int = 500) -> dict[str, Any]:
    """N-CSG-TBLS with its default stopping rule (``StopRule()``, up to ``fixed`` iterations) against the paper's
    fixed count of ``fixed`` iterations on the same grid: iterations, CPU seconds and the final RMSE of each."""
    q = grid_problem(side, np.random.default_rng(0))
    out = {}
    for label, opts in (("stop", {"quality": False}), ("fixed", PAPER_MODE)):
        c0 = time.process_time()
        res = solve(q, "N-CSG-TBLS", iterations=fixed, **opts)
        out[label] = (time.process_time() - c0, res.iterations, float(res.trace["rmse_m"][-1]), res.status)
    (t_s, it_s, rmse_s, status), (t_f, it_f, rmse_f, _) = out["stop"], out["fixed"]
    return {"name": "UWB N-CSG-TBLS, default stopping rule vs the paper's fixed count", "n_nodes": side * side,
            "distnav_s": t_s, "floor_s": t_f, "floor": f"the same solver, the paper's fixed {fixed} iterations",
            "ratio": t_s / t_f, "clock": "CPU s", "iterations_stopped": it_s, "iterations_fixed": it_f,
            "rmse_m_stopped": rmse_s, "rmse_m_fixed": rmse_f, "status_stopped": status,
            "goal": "far fewer iterations, RMSE within 1 mm of the fixed count",
            "meets_goal": bool(it_s <= it_f // 2 and rmse_s <= rmse_f + 1e-3),
            "note": f"CPU; stopped after {it_s} iterations ({status}), RMSE {rmse_s:.4g} m against {rmse_f:.4g} m "
                    f"after {it_f}"}


if __name__ == "__main__":
    main_for(__file__, run)
