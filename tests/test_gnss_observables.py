"""Observables of paper 000 §5.1: combinations (24)-(26), S-basis, weighting, variance propagation."""

from __future__ import annotations

import numpy as np
import pytest

from distnav.errors import ModelError
from distnav.models.gnss.observables import (
    between_satellite_operator,
    codebias_coefficients,
    codebias_observable,
    combination_covariance,
    combination_matrix,
    elevation_sigma,
    euler_goad_sigma,
    geometry_free,
    ionosphere_free,
    mu_coefficients,
    sbasis_design,
    sine_sigma,
)

MU = mu_coefficients((1, 2, 5))


def test_combinations_remove_what_they_should(rng: np.random.Generator) -> None:
    rho = rng.uniform(2e7, 2.6e7, 50)
    iono = rng.uniform(0, 40, 50)
    y1, y2, y3 = (rho + m * iono for m in MU)
    assert np.allclose(ionosphere_free(y1, y2), rho, rtol=0, atol=1e-6)
    assert np.allclose(geometry_free(y1, y2), iono, rtol=0, atol=1e-6)
    assert np.allclose(codebias_observable(y1, y2, y3), 0.0, atol=1e-6)
    # eq. (25) as printed has μ₂ȳ₁ − μ₁ȳ₁ (typo): that would not remove the ionosphere
    typo = (MU[1] * y1 - MU[0] * y1) / (MU[1] - MU[0])
    assert not np.allclose(typo, rho, rtol=0, atol=1.0)


def test_codebias_coefficients_hand_values() -> None:
    c = codebias_coefficients()
    m1, m2, m3 = 1.0, (154 / 120) ** 2, (154 / 115) ** 2
    assert c == pytest.approx([(m3 - m2) / (m2 - m1), (m1 - m3) / (m2 - m1), 1.0], rel=1e-12)
    assert c.sum() == pytest.approx(0.0, abs=1e-12)
    assert c @ MU == pytest.approx(0.0, abs=1e-12)
    assert c[0] == pytest.approx(0.22618, abs=1e-5) and c[1] == pytest.approx(-1.22618, abs=1e-5)
    # the observable equals the linear form with these coefficients on arbitrary inputs
    y = np.array([[1.0, 2.0, 7.0], [-3.0, 0.5, 2.0]])
    assert np.allclose(codebias_observable(*y.T), y @ c)


def test_variance_propagation_monte_carlo(rng: np.random.Generator) -> None:
    """Full covariance of [IF, GF, y] (correlated) against a Monte Carlo sample."""
    sig = np.array([0.2, 0.25, 0.3])
    q = np.diag(sig**2)
    C = combination_matrix()
    Q = combination_covariance(C, q)
    assert np.allclose(Q, Q.T)
    assert abs(Q[0, 1]) > 0.1 * np.sqrt(Q[0, 0] * Q[1, 1])  # IF and GF are correlated
    e = rng.normal(size=(200_000, 3)) * sig
    samples = np.stack(
        [ionosphere_free(e[:, 0], e[:, 1]), geometry_free(e[:, 0], e[:, 1]), codebias_observable(*e.T)], axis=1
    )
    emp = np.cov(samples.T)
    assert np.allclose(emp, Q, rtol=0.02, atol=2e-4)
    # vector-of-variances input and stacked input give the same
    assert np.allclose(combination_covariance(C, sig**2), Q)
    assert combination_covariance(C, np.stack([q, 2 * q])).shape == (2, 3, 3)
    with pytest.raises(ModelError, match="does not match"):
        combination_covariance(C, np.ones(4))


def test_between_satellite_operator_eq26() -> None:
    assert np.array_equal(between_satellite_operator(3).T, [[-1, 1, 0], [-1, 0, 1]])
    assert np.array_equal(between_satellite_operator(4).T, [[-1, 1, 0, 0], [-1, 0, 1, 0], [-1, 0, 0, 1]])
    d = between_satellite_operator(5)
    assert np.allclose(np.ones(5) @ d, 0.0)  # receiver terms cancel
    with pytest.raises(ModelError, match="at least one satellite"):
        between_satellite_operator(0)


def test_sbasis_design() -> None:
    a1 = sbasis_design([0, 2, 3], 5, reference_receiver=True)
    assert np.array_equal(a1, np.eye(5)[[0, 2, 3]])
    ai = sbasis_design([1, 2, 4], 5, reference_receiver=False)
    assert np.array_equal(ai, [[0, -1, 1, 0, 0], [0, -1, 0, 0, 1]])
    with pytest.raises(ModelError, match="out of range"):
        sbasis_design([0, 5], 5, reference_receiver=True)


def test_elevation_weighting_hand_values() -> None:
    s0 = 0.2
    assert euler_goad_sigma(np.deg2rad(10.0), s0) == pytest.approx(s0 * (1 + 10 * np.exp(-1)), rel=1e-12)
    assert euler_goad_sigma(np.pi / 2, s0) == pytest.approx(s0 * (1 + 10 * np.exp(-9)), rel=1e-12)
    assert sine_sigma(np.deg2rad(30.0), s0) == pytest.approx(0.4, rel=1e-12)
    assert elevation_sigma(np.deg2rad(30.0), s0, "sin") == pytest.approx(0.4)
    assert elevation_sigma(np.array([0.3, 1.0]), s0, "constant").tolist() == [0.2, 0.2]
    with pytest.raises(ModelError, match="unknown elevation weighting"):
        elevation_sigma(0.5, s0, "cosine")
