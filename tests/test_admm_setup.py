"""The vectorized x-update set-up (issue 17 item 3) gives bitwise the gains of the einsum forms of eq. (20)."""

from __future__ import annotations

import numpy as np
import pytest

from distnav.algorithms.admm import admm, iterate_admm
from distnav.algorithms.admm_kernel import Multipliers, XUpdate, _diagonal_or_none
from distnav.algorithms.lsq import LinearProblem
from distnav.exchange import make_exchange
from distnav.network import builders


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


@pytest.mark.parametrize("order", ["none", "rcm"])
def test_cold_start_states_equal_those_from_explicit_zero_multipliers(order: str) -> None:
    """The first state of a cold start skips ``u + (x − z)`` (u is all zero) and later states write it into a
    scratch buffer shared with the sent messages; starting from explicit zero multipliers takes the general path
    from the first state on. Every state, residual and norm must agree bit for bit."""
    rng = np.random.default_rng(21)
    g = builders.connected_random_geometric(300, mean_degree=7, rng=rng)
    prob = _problem(rng, g.n_nodes, 4, 3, True)
    first = admm(prob, g, W=5.0, max_iterations=1, tol=0.0, record_nodes=False,
                 exchange=make_exchange(g, order=order))
    assert first.multipliers is not None
    zero = Multipliers(np.zeros_like(first.multipliers.pairs), np.zeros_like(first.multipliers.self_pairs))
    cold = iterate_admm(prob, g, W=5.0, exchange=make_exchange(g, order=order))
    warm = iterate_admm(prob, g, W=5.0, exchange=make_exchange(g, order=order), multipliers=zero)
    u_norms = []
    for _ in range(6):
        a, b = next(cold), next(warm)
        assert np.array_equal(a.x, b.x) and np.array_equal(a.z, b.z)
        assert (a.primal_residual, a.dual_residual, a.x_norm, a.z_norm, a.u_norm) == \
            (b.primal_residual, b.dual_residual, b.x_norm, b.z_norm, b.u_norm)
        u_norms.append(a.u_norm)
    assert max(u_norms) > 0  # the compared multiplier norms are not trivially zero
