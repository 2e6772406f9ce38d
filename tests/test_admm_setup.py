"""The vectorized x-update set-up (issue 17 item 3) gives bitwise the gains of the einsum forms of eq. (20)."""

from __future__ import annotations

import numpy as np
import pytest

from distnav.algorithms.admm_kernel import XUpdate, _diagonal_or_none
from distnav.algorithms.lsq import LinearProblem


def _problem(rng: np.random.Generator, n: int, m: int, p: int, variances: bool) -> LinearProblem:
    A = rng.normal(size=(n, m, p)) * rng.uniform(0.01, 100.0)
    y = rng.normal(size=(n, m))
    return LinearProblem.from_stacked(A, y, rng.uniform(0.2, 5.0, size=(n, m)) if variances else None)


@pytest.mark.parametrize("variances", [False, True])
@pytest.mark.parametrize("W", [3.0, "diag"])
def test_observation_form_gain_is_bitwise_the_einsum_form(variances: bool, W: object) -> None:
    rng = np.random.default_rng(11)
    n, m, p = 4500, 5, 10  # several blocks of 2048 nodes
    prob = _problem(rng, n, m, p, variances)
    Wm = 3.0 * np.eye(p) if W == 3.0 else np.diag(rng.uniform(0.5, 4.0, p))
    c = rng.integers(1, 9, n).astype(float)
    Winv = np.linalg.inv(Wm)[None] / c[:, None, None]
    S = prob.R + np.einsum("nmp,npq,nkq->nmk", prob.A, Winv, prob.A)
    G_ref = np.einsum("npq,nmq->npm", Winv, prob.A) @ np.linalg.inv(S)
    G = XUpdate(prob, Wm, c, "observation").G
    assert np.array_equal(G, G_ref)


@pytest.mark.parametrize("variances", [False, True])
def test_normal_form_gain_is_bitwise_the_einsum_form(variances: bool) -> None:
    rng = np.random.default_rng(12)
    n, m, p = 300, 8, 4
    prob = _problem(rng, n, m, p, variances)
    Wm = 2.0 * np.eye(p)
    c = rng.integers(1, 6, n).astype(float)
    N_i, _ = prob.normal_equations
    G_ref = np.linalg.solve(N_i + c[:, None, None] * Wm[None], np.einsum("nmp,nmk->npk", prob.A, prob.R_inv))
    assert np.array_equal(XUpdate(prob, Wm, c, "normal").G, G_ref)


def test_full_weight_matrix_keeps_the_general_form() -> None:
    rng = np.random.default_rng(13)
    n, m, p = 50, 3, 6
    prob = _problem(rng, n, m, p, False)
    B = rng.normal(size=(p, p))
    Wm = B @ B.T + p * np.eye(p)  # SPD, not diagonal
    c = np.ones(n)
    Winv = np.linalg.inv(Wm)[None] / c[:, None, None]
    S = prob.R + np.einsum("nmp,npq,nkq->nmk", prob.A, Winv, prob.A)
    G_ref = np.einsum("npq,nmq->npm", Winv, prob.A) @ np.linalg.inv(S)
    assert np.array_equal(XUpdate(prob, Wm, c, "observation").G, G_ref)


def test_diagonal_detection() -> None:
    rng = np.random.default_rng(14)
    for k in (1, 2, 3, 5):
        M = np.zeros((4, k, k))
        M[:, range(k), range(k)] = rng.normal(size=(4, k))
        d = _diagonal_or_none(M)
        assert d is not None and np.array_equal(d, M[:, range(k), range(k)])
        for i in range(k):
            for j in range(k):
                if i != j:
                    M2 = M.copy()
                    M2[2, i, j] = 1e-300
                    assert _diagonal_or_none(M2) is None
