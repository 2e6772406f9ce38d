"""Distributed precision and data snooping (issue 12) against the centralized references."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import block_diag

from distnav.algorithms.lsq.admm import admm
from distnav.algorithms.lsq.blue import LinearProblem, blue
from distnav.algorithms.lsq.qc import (
    PrecisionOptions,
    SnoopingOptions,
    admm_data_snooping,
    admm_precision,
    remove_observation,
)
from distnav.algorithms.statistics import data_snooping
from distnav.errors import ModelError, UsageError
from distnav.exchange import FaultSchedule
from distnav.experiments.qc import gross_error_problem
from distnav.network import builders


@pytest.fixture(scope="module")
def net():
    """24 nodes, 3 rows each, p = 6 (every N_i singular), full R_i."""
    rng = np.random.default_rng(7)
    g = builders.connected_random_geometric(24, mean_degree=5, rng=rng)
    A = rng.normal(size=(24, 3, 6))
    y = np.einsum("nmp,p->nm", A, rng.normal(size=6)) + 0.3 * rng.normal(size=(24, 3))
    M = rng.normal(size=(24, 3, 3))
    prob = LinearProblem.from_stacked(A, y, 0.1 * (M @ M.transpose(0, 2, 1)) + 0.05 * np.eye(3))
    assert all(np.linalg.matrix_rank(N) < 6 for N in prob.normal_equations[0])
    return g, prob, blue(prob)


def _sigma2_hat(prob, x):
    """Centralized σ̂² = êᵀR⁻¹ê / (m − p) from the stacked data (independent of the per-node code)."""
    A = prob.A.reshape(-1, prob.n_params)
    R = block_diag(*prob.R)
    e = prob.y.ravel() - A @ x
    return float(e @ np.linalg.solve(R, e)) / (A.shape[0] - prob.n_params)


def test_precision_equals_the_centralized_inverse_and_variance_factor(net):
    g, prob, b = net
    est = admm(prob, g, W=20.0, max_iterations=5000, tol=1e-12)
    run = admm_precision(prob, g, est.estimates, W=20.0, reference_covariance=b.covariance)
    P = run.precision
    ref = np.linalg.inv(prob.A.reshape(-1, 6).T @ np.linalg.solve(block_diag(*prob.R), prob.A.reshape(-1, 6)))
    rel = np.abs(P.covariance - ref[None]).max() / np.abs(ref).max()
    assert rel < 1e-8 and P.covariance.shape == (24, 6, 6)
    s2 = _sigma2_hat(prob, b.x)
    assert P.variance_factor == pytest.approx(s2, rel=1e-8)
    np.testing.assert_allclose(run.variance_factor_nodes, s2, rtol=1e-8)
    assert P.redundancy == 24 * 3 - 6 and P.kind == "exact"
    assert P.iterations == run.covariance_run.iterations + run.sums_run.iterations > 0
    assert P.comm is not None and P.comm.messages > 0
    # every message of the covariance run carries p² = 36 numbers
    per_round = run.covariance_run.comm.messages_per_round[-1]
    assert run.covariance_run.comm.bytes_per_round[-1] == per_round * 36 * 8


def test_precision_with_message_drops(net):
    g, prob, b = net
    faults = FaultSchedule(drop_probability=0.2, seed=9)
    est = admm(prob, g, W=20.0, max_iterations=8000, tol=1e-12, faults=faults)
    run = admm_precision(prob, g, est.estimates, W=20.0, faults=faults, max_iterations=8000)
    assert run.precision.comm is not None and run.precision.comm.messages_dropped > 0.15 * run.precision.comm.messages
    assert np.abs(run.precision.covariance - b.covariance).max() / np.abs(b.covariance).max() < 1e-8
    assert run.precision.variance_factor == pytest.approx(_sigma2_hat(prob, b.x), rel=1e-8)


def test_precision_validation(net):
    g, prob, _ = net
    with pytest.raises(ModelError, match="estimates must be"):
        admm_precision(prob, g, np.zeros((3, 6)))
    with pytest.raises(ModelError, match="active must be"):
        admm_precision(prob, g, np.zeros((24, 6)), active=np.ones((24, 2), bool))
    with pytest.raises(ModelError, match=r"reference_covariance must be \(6, 6\), got shape \(36,\)"):
        admm_precision(prob, g, np.zeros((24, 6)), reference_covariance=np.eye(6).ravel())
    with pytest.raises(ModelError, match="either to the exchange"):
        admm_precision(prob, g, np.zeros((24, 6)), faults=FaultSchedule(), exchange="x")  # type: ignore[arg-type]


def test_removed_observation_contributes_nothing(net):
    _, prob, _ = net
    red = remove_observation(prob, 5, 1)
    keep = [k for k in range(prob.n_nodes * 3) if k != 5 * 3 + 1]
    A = prob.A.reshape(-1, 6)[keep]
    R = block_diag(*prob.R)[np.ix_(keep, keep)]
    x = np.linalg.solve(A.T @ np.linalg.solve(R, A), A.T @ np.linalg.solve(R, prob.y.ravel()[keep]))
    np.testing.assert_allclose(blue(red).x, x, rtol=1e-10, atol=1e-12)


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_distributed_snooping_equals_centralized(seed):
    case = gross_error_problem(np.random.default_rng([12, seed]))
    prob = case.problem
    res = admm_data_snooping(prob, case.graph, W=3.0, level=0.001, tol=1e-11)
    ref = data_snooping(prob.A.reshape(-1, 6), prob.y.ravel(), block_diag(*prob.R), level=0.001)
    assert res.tests is not None and res.precision is not None
    assert res.tests.removed == ref.removed
    assert len(ref.removed) >= 1
    np.testing.assert_allclose(res.tests.w, ref.w, rtol=1e-7, atol=1e-7)
    assert not res.tests.flagged.any() and not ref.flagged.any()
    np.testing.assert_allclose(res.estimates, np.broadcast_to(ref.x, res.estimates.shape), rtol=1e-8, atol=1e-9)
    assert res.precision.variance_factor == pytest.approx(ref.variance_factor, rel=1e-7)
    assert res.precision.redundancy == ref.redundancy
    assert res.tests.iterations > 0 and res.tests.comm is not None and res.tests.comm.messages > 0
    assert res.tests.critical_value == pytest.approx(3.2905, abs=1e-4)


def test_snooping_without_gross_errors_removes_nothing_and_max_removals():
    case = gross_error_problem(np.random.default_rng(5), n_outliers=0)
    res = admm_data_snooping(case.problem, case.graph, W=3.0, tol=1e-11, level=1e-6)
    ref = data_snooping(case.problem.A.reshape(-1, 6), case.problem.y.ravel(), block_diag(*case.problem.R), level=1e-6)
    assert res.tests.removed == ref.removed == ()
    assert res.tests.iterations == 0
    bad = gross_error_problem(np.random.default_rng([12, 0]))
    one = admm_data_snooping(bad.problem, bad.graph, W=3.0, tol=1e-11, max_removals=1)
    assert len(one.tests.removed) == 1 and one.tests.flagged.any()


def test_options_objects_and_keywords_run_the_same(net):
    """PrecisionOptions and SnoopingOptions in the house style (distnav._settings): the object, keyword changes or
    both give bit-identical runs; unknown names and bad values are refused by name."""
    g, prob, _ = net
    est = admm(prob, g, W=20.0, max_iterations=300, tol=0.0)
    by_keywords = admm_precision(prob, g, est.estimates, W=20.0, max_iterations=200)
    by_object = admm_precision(prob, g, est.estimates, options=PrecisionOptions(W=20.0, max_iterations=200))
    mixed = admm_precision(prob, g, est.estimates, options=PrecisionOptions(W=20.0), max_iterations=200)
    for run in (by_object, mixed):
        np.testing.assert_array_equal(run.precision.covariance, by_keywords.precision.covariance)
    case = gross_error_problem(np.random.default_rng([12, 0]))
    first = admm_data_snooping(case.problem, case.graph, W=3.0, tol=1e-11, max_removals=1)
    again = admm_data_snooping(case.problem, case.graph, options=SnoopingOptions(W=3.0, tol=1e-11), max_removals=1)
    assert again.tests.removed == first.tests.removed
    np.testing.assert_array_equal(again.estimates, first.estimates)
    with pytest.raises(UsageError, match="PrecisionOptions has no option 'max_iteration'.*'max_iterations'"):
        admm_precision(prob, g, est.estimates, max_iteration=3)
    with pytest.raises(UsageError, match="SnoopingOptions has no option 'levels'"):
        admm_data_snooping(case.problem, case.graph, levels=0.01)
    with pytest.raises(ModelError, match="tol \\(relative tolerance\\) must be 0 or more"):
        SnoopingOptions(tol=-1.0)
