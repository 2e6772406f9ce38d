"""Distributed precision and data snooping for ADMM least squares (issue 12 targets).

Workloads:
* precision: 24-node random geometric networks, m_i = 3 < p = 6 (every N_i singular), σ_j ~ U(0.5, 2), ρ = 3,
  minimum-cover C, 5 seeded problems (2 with --quick). Iterations of the estimate to max_i ‖x_i − x̂‖/‖x̂‖ ≤ 1e-6
  against iterations of the covariance run to max_i ‖Q_i − N⁻¹‖_F/‖N⁻¹‖_F ≤ 1e-6 (target ≤ 2×); the error of σ̂²
  at the stopping tolerance 1e-12. Same-run floor: the centralized N⁻¹ (numpy inverse of the summed normals).
* data snooping: 100 seeded problems (10 with --quick) of 20 nodes, 2 observations shifted by ±6σ each, level
  0.1 %: the removals of the distributed procedure against `statistics.data_snooping` on the stacked data (target:
  the same on every problem), power (injected errors removed, target ≥ 80 %), false removals, extra iterations and
  messages after the first solution. Same-run floor: the centralized `data_snooping` time.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
from scipy.linalg import block_diag

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import best_time, main_for  # noqa: E402
from distnav.algorithms.lsq.admm import admm  # noqa: E402
from distnav.algorithms.lsq.blue import blue  # noqa: E402
from distnav.algorithms.lsq.qc import admm_data_snooping, admm_precision  # noqa: E402
from distnav.algorithms.statistics import data_snooping  # noqa: E402
from distnav.experiments.qc import gross_error_problem  # noqa: E402

RHO = 3.0


def precision_rows(quick: bool) -> list[dict[str, Any]]:
    rows = []
    for seed in range(2 if quick else 5):
        pb = gross_error_problem(np.random.default_rng([40, seed]), n=24, n_outliers=0)
        prob, g = pb.clean, pb.graph
        b = blue(prob)
        t_floor = best_time(lambda: np.linalg.inv(prob.normal_equations[0].sum(axis=0)), repeat=5)  # noqa: B023
        t0 = time.perf_counter()
        est = admm(prob, g, W=RHO, max_iterations=5000, tol=1e-12, reference=b.x, record_nodes=False)
        t_est = time.perf_counter() - t0
        t0 = time.perf_counter()
        run = admm_precision(prob, g, est.estimates, W=RHO, reference_covariance=b.covariance)
        t_prec = time.perf_counter() - t0
        A = prob.A.reshape(-1, prob.n_params)
        e = prob.y.ravel() - A @ b.x
        s2 = float(e @ np.linalg.solve(block_diag(*prob.R), e)) / (A.shape[0] - prob.n_params)
        it_est = est.iterations_to["1e-06"]
        it_cov = run.covariance_run.iterations_to["1e-06"]
        ratio = None if it_est is None or it_cov is None else it_cov / it_est
        P = run.precision
        rows.append(
            {
                "name": f"precision, 24 nodes, p=6, m_i=3, seed {seed}",
                "seconds": t_prec,
                "reference_seconds": t_floor,
                "reference": "centralized numpy inverse of N (same run)",
                "ratio": t_prec / t_floor,
                "estimate_seconds": t_est,
                "estimate_iterations_to_1e-6": it_est,
                "covariance_iterations_to_1e-6": it_cov,
                "covariance_over_estimate_iterations": ratio,
                "covariance_final_relative_error": float(
                    np.abs(P.covariance - b.covariance).max() / np.abs(b.covariance).max()
                ),
                "variance_factor_relative_error": abs(float(P.variance_factor or np.nan) / s2 - 1),
                "sums_run_iterations": run.sums_run.iterations,
                "precision_messages": P.comm.messages if P.comm else None,
                "estimate_messages": est.comm.messages,
                "goal": "covariance to 1e-6 within 2× the estimate's iterations",
                "meets_goal": bool(ratio is not None and ratio <= 2.0),
            }
        )
    return rows


def snooping_rows(quick: bool) -> list[dict[str, Any]]:
    draws = 10 if quick else 100
    same = detected = injected = false_removed = 0
    extra_its: list[int] = []
    extra_msgs: list[int] = []
    first_msgs: list[int] = []
    t_dist = t_cent = 0.0
    for seed in range(draws):
        pb = gross_error_problem(np.random.default_rng([41, seed]))
        prob = pb.problem
        t0 = time.perf_counter()
        res = admm_data_snooping(prob, pb.graph, W=RHO, level=0.001, tol=1e-11)
        t_dist += time.perf_counter() - t0
        t0 = time.perf_counter()
        ref = data_snooping(prob.A.reshape(-1, prob.n_params), prob.y.ravel(), block_diag(*prob.R), level=0.001)
        t_cent += time.perf_counter() - t0
        assert res.tests is not None and res.tests.comm is not None
        same += res.tests.removed == ref.removed
        injected += pb.outliers.size
        detected += len(set(res.tests.removed) & set(pb.outliers.tolist()))
        false_removed += len(set(res.tests.removed) - set(pb.outliers.tolist()))
        extra_its.append(res.tests.iterations)
        extra_msgs.append(res.tests.comm.messages)
        first_msgs.append(res.comm.messages - res.tests.comm.messages)
    power = detected / injected
    return [
        {
            "name": f"data snooping, {draws} problems of 20 nodes, 2 gross errors of 6σ, level 0.1 %",
            "seconds": t_dist / draws,
            "reference_seconds": t_cent / draws,
            "reference": "centralized statistics.data_snooping (same run)",
            "ratio": t_dist / t_cent,
            "same_removals_as_centralized": same,
            "problems": draws,
            "power": power,
            "false_removals": false_removed,
            "median_extra_iterations": float(np.median(extra_its)),
            "median_extra_messages": float(np.median(extra_msgs)),
            "median_messages_first_solution": float(np.median(first_msgs)),
            "goal": "same removals on every problem; power ≥ 80 %",
            "meets_goal": bool(same == draws and power >= 0.8),
        }
    ]


def run(quick: bool) -> list[dict[str, Any]]:
    return precision_rows(quick) + snooping_rows(quick)


if __name__ == "__main__":
    main_for(__file__, run)
