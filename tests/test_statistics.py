"""w-tests, variance factor and centralized data snooping against independent computations."""

from __future__ import annotations

import numpy as np
import pytest

from distnav.algorithms.kalman.ckf_qc import chi2_critical
from distnav.algorithms.statistics import (
    critical_value,
    data_snooping,
    variance_factor,
    variance_factor_test,
    w_statistics,
)
from distnav.errors import ModelError


def _problem(rng: np.random.Generator, m: int = 30, p: int = 4) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    A = rng.normal(size=(m, p))
    sigma = rng.uniform(0.5, 2.0, size=m)
    y = A @ rng.normal(size=p) + rng.normal(size=m) * sigma
    return A, y, sigma**2


def test_critical_value_is_the_two_sided_normal_quantile() -> None:
    assert critical_value(0.001) == pytest.approx(3.2905, abs=1e-4)
    assert critical_value(0.05) == pytest.approx(1.95996, abs=1e-5)
    with pytest.raises(ModelError):
        critical_value(0.0)


@pytest.mark.parametrize("level", [1e-6, 0.001, 0.01, 0.05, 0.3])
def test_quantiles_equal_scipy_stats(level: float) -> None:
    """The quantiles come from scipy.special (importing scipy.stats costs ~1.3 s CPU per run): the same values as
    scipy.stats's distributions, to the last bit."""
    from scipy import stats

    assert critical_value(level) == float(stats.norm.isf(level / 2.0))
    for r in (1, 2, 7.5, 40, 1000, 60_000):
        _, (lo, hi), _ = variance_factor_test(float(r), r, level)
        assert lo == float(stats.chi2.ppf(level / 2.0, r) / r)
        assert hi == float(stats.chi2.isf(level / 2.0, r) / r)
    dof = np.array([0, 1, 3, 40, 900])
    got = chi2_critical(dof, level)
    assert np.isnan(got[0])
    np.testing.assert_array_equal(got[1:], stats.chi2.isf(level, dof[1:]))


def test_w_equals_the_deletion_residual_over_its_standard_deviation() -> None:
    """Independent form (uncorrelated observations): w_i = (y_i − a_i x̂₍ᵢ₎) / sqrt(σ_i² + a_i Q₍ᵢ₎ a_iᵀ),
    with x̂₍ᵢ₎ the BLUE without observation i."""
    rng = np.random.default_rng(3)
    A, y, var = _problem(rng)
    out = data_snooping(A, y, var, level=1e-12)  # nothing removed at this level
    assert out.removed == ()
    for i in range(len(y)):
        keep = np.arange(len(y)) != i
        Wk = np.diag(1.0 / var[keep])
        Q = np.linalg.inv(A[keep].T @ Wk @ A[keep])
        xi = Q @ A[keep].T @ Wk @ y[keep]
        ref = (y[i] - A[i] @ xi) / np.sqrt(var[i] + A[i] @ Q @ A[i])
        assert out.w[i] == pytest.approx(ref, rel=1e-9)


def test_w_is_standard_normal_and_variance_factor_unbiased_by_monte_carlo() -> None:
    rng = np.random.default_rng(7)
    A = rng.normal(size=(12, 3))
    var = rng.uniform(0.5, 2.0, size=12)
    ws, s2 = [], []
    for _ in range(3000):
        y = A @ np.ones(3) + rng.normal(size=12) * np.sqrt(var)
        out = data_snooping(A, y, var, level=1e-15)
        ws.append(out.w)
        s2.append(out.variance_factor)
    w = np.array(ws)
    assert abs(w.mean()) < 0.03
    assert w.std(axis=0) == pytest.approx(np.ones(12), abs=0.05)
    assert np.mean(s2) == pytest.approx(1.0, abs=0.03)


def test_snooping_removes_the_gross_error_and_only_it() -> None:
    rng = np.random.default_rng(11)
    A, y, var = _problem(rng, m=40)
    y[17] += 12.0 * np.sqrt(var[17])
    out = data_snooping(A, y, var, level=0.001)
    assert out.removed == (17,)
    assert np.isnan(out.w[17]) and not out.flagged.any()
    assert out.redundancy == 40 - 1 - 4


def test_correlated_observations_use_the_weighted_form() -> None:
    """With a full R the w-test is (R⁻¹ê)_i / sqrt((R⁻¹Q_êR⁻¹)_ii); whitening gives a different statistic, so check
    the defining property instead: under H0 it is N(0, 1) (Monte Carlo)."""
    rng = np.random.default_rng(5)
    A = rng.normal(size=(8, 2))
    L = rng.normal(size=(8, 8)) * 0.3 + np.eye(8)
    R = L @ L.T
    ws = []
    for _ in range(3000):
        y = A @ np.ones(2) + L @ rng.normal(size=8)
        ws.append(data_snooping(A, y, R, level=1e-15).w)
    assert np.std(ws, axis=0) == pytest.approx(np.ones(8), abs=0.06)


def test_rank_deficient_design_gives_finite_statistics_and_redundancy_from_the_rank() -> None:
    rng = np.random.default_rng(2)
    A = rng.normal(size=(10, 3))
    A = np.column_stack([A, A[:, 0] + A[:, 1]])  # rank 3 with 4 columns
    y = rng.normal(size=10)
    out = data_snooping(A, y, np.ones(10), level=1e-12)
    assert out.redundancy == 7 and np.isfinite(out.w).all()


def test_variance_factor_and_its_test() -> None:
    assert variance_factor(10.0, 5) == 2.0
    assert variance_factor(1.0, 0) is None
    s2, (lo, hi), ok = variance_factor_test(100.0, 100, 0.05)
    assert ok and lo < 1.0 < hi
    assert not variance_factor_test(200.0, 100, 0.05)[2]
    with pytest.raises(ModelError):
        w_statistics(np.ones(3), np.ones(2))
