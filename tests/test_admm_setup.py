"""The vectorized x-update set-up (issue 17 item 3): the normal form's gains are bitwise those of the einsum form of
eq. (20); the observation form's (a Cholesky vectorized over the nodes) equal LAPACK's to rounding."""

from __future__ import annotations

import numpy as np
import pytest

from distnav.algorithms.lsq.admm import admm, iterate_admm
from distnav.algorithms.lsq.blue import LinearProblem
from distnav.algorithms.lsq.kernel import Multipliers, XUpdate
from distnav.algorithms.lsq.xupdate import SMALL_M, _diagonal_or_none
from distnav.errors import ModelError
from distnav.exchange import make_exchange
from distnav.network import builders


def _problem(rng: np.random.Generator, n: int, m: int, p: int, variances: bool) -> LinearProblem:
    A = rng.normal(size=(n, m, p)) * rng.uniform(0.01, 100.0)
    y = rng.normal(size=(n, m))
    return LinearProblem.from_stacked(A, y, rng.uniform(0.2, 5.0, size=(n, m)) if variances else None)


def _lapack_gain(prob: LinearProblem, Wm: np.ndarray, c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The second form of eq. (20) by einsum and LAPACK's inverse (the set-up before the vectorized Cholesky)."""
    Winv = np.linalg.inv(Wm)[None] / c[:, None, None]
    S = prob.R + np.einsum("nmp,npq,nkq->nmk", prob.A, Winv, prob.A)
    return np.einsum("npq,nmq->npm", Winv, prob.A) @ np.linalg.inv(S), np.linalg.cond(S)


def _assert_gain_close(G: np.ndarray, G_ref: np.ndarray, cond: np.ndarray) -> None:
    """Per node, to a few rounding errors times the condition number of ``S_i`` (both solvers are backward stable)."""
    scale = np.abs(G_ref).max(axis=(1, 2))
    err = np.abs(G - G_ref).max(axis=(1, 2))
    assert (err <= 20 * cond * np.finfo(float).eps * scale).all(), float((err / scale / cond).max())
    well = cond < 1e3  # the rule where the gains themselves are that accurate: 1e-12 relative
    assert (err[well] <= 1e-12 * scale[well]).all()


@pytest.mark.parametrize("variances", [False, True])
@pytest.mark.parametrize("W", [3.0, "diag", "full"])
@pytest.mark.parametrize(
    ("m", "p", "scale"),
    [(5, 10, 1.0), (5, 10, 30.0), (1, 3, 1.0), (3, 7, 0.01), (11, 12, 3.0), (SMALL_M + 2, SMALL_M + 4, 1.0)],
)
def test_observation_form_gain_equals_lapack(variances: bool, W: str | float, m: int, p: int, scale: float) -> None:
    rng = np.random.default_rng(11 + m)
    n = 4500 if m <= 5 else 700  # m ≤ 5: several blocks of 2048 nodes
    prob = _problem(rng, n, m, p, variances)
    prob = LinearProblem.from_stacked(prob.A * scale, prob.y, np.diagonal(prob.R, axis1=1, axis2=2).copy())
    if W == 3.0:
        Wm = 3.0 * np.eye(p)
    elif W == "diag":
        Wm = np.diag(rng.uniform(0.5, 4.0, p))
    else:
        B = rng.normal(size=(p, p))
        Wm = B @ B.T + p * np.eye(p)  # SPD, not diagonal: S_i by einsum, then the same solve
    c = rng.integers(1, 9, n).astype(float)
    G_ref, cond = _lapack_gain(prob, Wm, c)
    _assert_gain_close(XUpdate(prob, Wm, c, "observation").G, G_ref, cond)


def test_observation_form_gain_with_full_R_and_padded_rows() -> None:
    """Nodes with fewer rows (padded with identity R blocks) and correlated R_i."""
    rng = np.random.default_rng(14)
    p, n = 6, 300
    A_blocks, y_blocks, R_blocks = [], [], []
    for i in range(n):
        mi = i % 4  # 0 to 3 rows: zero-row nodes too
        A_blocks.append(rng.normal(size=(mi, p)))
        y_blocks.append(rng.normal(size=mi))
        F = rng.normal(size=(mi, mi))
        R_blocks.append(F @ F.T + mi * np.eye(mi))
    prob = LinearProblem.from_blocks(A_blocks, y_blocks, R_blocks)
    Wm = 2.0 * np.eye(p)
    c = rng.integers(1, 5, n).astype(float)
    G_ref, cond = _lapack_gain(prob, Wm, c)
    _assert_gain_close(XUpdate(prob, Wm, c, "observation").G, G_ref, cond)


def test_observation_form_gain_does_not_depend_on_the_block_split() -> None:
    """Elementwise over the nodes: the gains of any subset of nodes are bitwise those of the whole (MPI blocks)."""
    rng = np.random.default_rng(15)
    n, m, p = 5000, 5, 10
    prob = _problem(rng, n, m, p, True)
    c = rng.integers(1, 9, n).astype(float)
    G = XUpdate(prob, 3.0 * np.eye(p), c, "observation").G
    part = rng.permutation(n)[:1777]
    G_part = XUpdate(prob.subset(part), 3.0 * np.eye(p), c[part], "observation").G
    assert np.array_equal(G_part, G[part])


def test_observation_form_refuses_an_indefinite_matrix() -> None:
    rng = np.random.default_rng(16)
    prob = _problem(rng, 20, 2, 4, False)
    bad = LinearProblem(A=prob.A * 1e-3, y=prob.y, R=-np.broadcast_to(np.eye(2), (20, 2, 2)).copy(), rows=prob.rows)
    with pytest.raises(ModelError, match="not positive definite"):
        XUpdate(bad, np.eye(4), np.ones(20), "observation")


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
    first = admm(prob, g, W=5.0, max_iterations=1, tol=0.0, record_nodes=False, exchange=make_exchange(g, order=order))
    assert first.multipliers is not None
    zero = Multipliers(np.zeros_like(first.multipliers.pairs), np.zeros_like(first.multipliers.self_pairs))
    cold = iterate_admm(prob, g, W=5.0, exchange=make_exchange(g, order=order))
    warm = iterate_admm(prob, g, W=5.0, exchange=make_exchange(g, order=order), multipliers=zero)
    u_norms = []
    for _ in range(6):
        a, b = next(cold), next(warm)
        assert np.array_equal(a.x, b.x) and np.array_equal(a.z, b.z)
        assert (a.primal_residual, a.dual_residual, a.x_norm, a.z_norm, a.u_norm) == (
            b.primal_residual,
            b.dual_residual,
            b.x_norm,
            b.z_norm,
            b.u_norm,
        )
        u_norms.append(a.u_norm)
    assert max(u_norms) > 0  # the compared multiplier norms are not trivially zero
