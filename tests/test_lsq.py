"""Centralized BLUE, rank check, method of multipliers and single-consensus ADMM (paper 000 §2–3)."""

from __future__ import annotations

import numpy as np
import pytest

from distnav.algorithms.lsq.blue import (
    LinearProblem,
    blue,
    dual_function,
    iterate_method_of_multipliers,
    iterate_single_consensus_admm,
    method_of_multipliers,
    multiplier_step,
    null_space_directions,
    single_consensus_admm,
    weight_matrix,
)
from distnav.errors import ModelError


def random_spd(rng: np.random.Generator, m: int) -> np.ndarray:
    M = rng.normal(size=(m, m))
    return M @ M.T + 0.5 * np.eye(m)


def random_blocks(rng: np.random.Generator, rows: list[int], p: int):
    A = [rng.normal(size=(m, p)) for m in rows]
    y = [rng.normal(size=m) for m in rows]
    R = [random_spd(rng, m) for m in rows]
    return A, y, R


def test_blue_equals_whitened_lstsq_with_full_R_and_uneven_rows(rng):
    rows = [2, 3, 0, 1, 4, 2]
    p = 5
    A, y, R = random_blocks(rng, rows, p)
    prob = LinearProblem.from_blocks(A, y, R)
    sol = blue(prob)
    # independent reference: whiten each block with its own Cholesky factor, stack, numpy lstsq
    Aw = np.vstack([np.linalg.solve(np.linalg.cholesky(Ri), Ai) for Ai, Ri in zip(A, R, strict=True) if Ai.size])
    yw = np.concatenate([np.linalg.solve(np.linalg.cholesky(Ri), yi) for yi, Ri in zip(y, R, strict=True) if yi.size])
    ref = np.linalg.lstsq(Aw, yw, rcond=None)[0]
    np.testing.assert_allclose(sol.x, ref, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(sol.covariance, np.linalg.inv(Aw.T @ Aw), rtol=1e-9, atol=1e-12)
    assert sol.cost == pytest.approx(0.5 * float(np.sum((yw - Aw @ ref) ** 2)), rel=1e-10)
    assert prob.rows.tolist() == rows


def test_variances_vector_equals_diagonal_matrix(rng):
    A, y, _ = random_blocks(rng, [3, 3, 3], 4)
    var = [rng.uniform(0.5, 2.0, 3) for _ in range(3)]
    a = blue(LinearProblem.from_blocks(A, y, var)).x
    b = blue(LinearProblem.from_blocks(A, y, [np.diag(v) for v in var])).x
    np.testing.assert_allclose(a, b, rtol=1e-12)
    c = blue(LinearProblem.from_stacked(np.stack(A), np.stack(y), np.stack(var))).x
    np.testing.assert_allclose(a, c, rtol=1e-12)


def test_rank_deficiency_names_inestimable_directions(rng):
    n, m, p = 5, 2, 4
    A = rng.normal(size=(n, m, p))
    A[:, :, 1] = A[:, :, 0]  # x0 and x1 only seen as their sum
    A[:, :, 3] = 0.0  # x3 never observed
    prob = LinearProblem.from_stacked(A, rng.normal(size=(n, m)), parameter_names=["a", "b", "c", "d"])
    with pytest.raises(ModelError, match=r"rank\(A\) = 2 < p = 4") as exc:
        blue(prob)
    msg = str(exc.value)
    assert "d" in msg and "a − b" in msg
    basis = null_space_directions(sum(prob.normal_equations[0]))
    assert basis.shape == (4, 2)
    # the basis spans exactly {e_3, e_0 − e_1}
    for v in (np.array([0, 0, 0, 1.0]), np.array([1.0, -1.0, 0, 0]) / np.sqrt(2)):
        assert np.linalg.norm(basis @ (basis.T @ v) - v) < 1e-10


def test_a_column_of_rounding_is_no_information(rng):
    """Found in the field (issue 26): a parameter seen only through rounding-level entries of A (1e-16 beside
    order-one ones, as a reparametrization leaves them) was Jacobi-scaled up to order one and passed the rank
    check; the BLUE then returned values near 1e13. numpy's SVD rank of the stacked rows is the reference."""
    n, m, p = 6, 3, 4
    A = rng.normal(size=(n, m, p))
    A[:, :, 2] = rng.normal(size=(n, m)) * 1e-16  # rounding, not an observation
    assert np.linalg.matrix_rank(A.reshape(n * m, p)) == 3
    prob = LinearProblem.from_stacked(A, rng.normal(size=(n, m)))
    with pytest.raises(ModelError, match=r"rank\(A\) = 3 < p = 4 .*inestimable directions: x\[2\]"):
        blue(prob)


def test_rank_check_is_unit_free(rng):
    """A parameter in tiny units (column scaled by 1e-6) is still estimable."""
    n, m, p = 6, 2, 3
    A = rng.normal(size=(n, m, p))
    A[:, :, 2] *= 1e-6
    sol = blue(LinearProblem.from_stacked(A, rng.normal(size=(n, m))))
    assert np.all(np.isfinite(sol.x))


@pytest.mark.parametrize(
    ("kwargs", "pattern"),
    [
        (dict(A=[], y=[]), "at least one node"),
        (dict(A=[np.ones((2, 3))], y=[np.ones(2), np.ones(2)]), "2 observation vectors"),
        (dict(A=[np.ones((2, 3))], y=[np.ones(2)], R=[np.eye(2), np.eye(2)]), "2 variance matrices"),
        (dict(A=[np.ones(3)], y=[np.ones(1)]), "node 0: A_i must be a 2-D"),
        (dict(A=[np.ones((2, 3)), np.ones((2, 4))], y=[np.ones(2), np.ones(2)]), "node 1: A_i has 4 columns"),
        (dict(A=[np.ones((2, 3))], y=[np.ones(3)]), "node 0: y_i has shape"),
        (dict(A=[np.ones((2, 3))], y=[np.ones(2)], R=[np.ones(3)]), "node 0: variances R_i have 3 entries"),
        (dict(A=[np.ones((2, 3))], y=[np.ones(2)], R=[np.array([1.0, -1.0])]), "node 0: variances R_i must be"),
        (dict(A=[np.ones((2, 3))], y=[np.ones(2)], R=[np.eye(3)]), r"node 0: R_i must be \(2, 2\)"),
        (dict(A=[np.ones((2, 3))], y=[np.ones(2)], R=[np.array([[1.0, 0.5], [0.0, 1.0]])]), "not symmetric"),
        (
            dict(A=[np.ones((2, 3))], y=[np.ones(2)], R=[np.array([[1.0, 2.0], [2.0, 1.0]])]),
            "node 0: R_i is not positive definite",
        ),
        (dict(A=[np.ones((2, 3))], y=[np.array([1.0, np.nan])]), "node 0: y_i has non-finite"),
        (dict(A=[np.ones((2, 3))], y=[np.ones(2)], parameter_names=["a"]), "1 parameter names for p = 3"),
        (dict(A=[np.ones((2, 3))], y=[np.ones(2)], node_names=["a", "b"]), "2 node names for 1 nodes"),
    ],
)
def test_from_blocks_validation(kwargs, pattern):
    with pytest.raises(ModelError, match=pattern):
        LinearProblem.from_blocks(**kwargs)


def test_validation_names_the_node_by_name():
    R_bad = np.array([[1.0, 2.0], [2.0, 1.0]])
    with pytest.raises(ModelError, match="node station-B: R_i is not positive definite"):
        LinearProblem.from_blocks(
            [np.ones((2, 2))] * 2, [np.ones(2)] * 2, [np.eye(2), R_bad], node_names=["station-A", "station-B"]
        )


def test_from_stacked_validation():
    with pytest.raises(ModelError, match="shape \\(n_nodes, m, p\\)"):
        LinearProblem.from_stacked(np.ones((2, 3)), np.ones((2, 3)))
    with pytest.raises(ModelError, match="stacked y must have shape"):
        LinearProblem.from_stacked(np.ones((2, 3, 4)), np.ones((2, 4)))
    with pytest.raises(ModelError, match="stacked R must have shape"):
        LinearProblem.from_stacked(np.ones((2, 3, 4)), np.ones((2, 3)), np.ones((2, 3, 2)))
    with pytest.raises(ModelError, match="node 1: variances must be finite and > 0"):
        LinearProblem.from_stacked(np.ones((2, 3, 4)), np.ones((2, 3)), np.array([[1.0] * 3, [1.0, 0.0, 1.0]]))


def test_weight_matrix_validation():
    np.testing.assert_array_equal(weight_matrix(2.0, 3), 2.0 * np.eye(3))
    for bad, pattern in [
        (0.0, "must be finite and > 0"),
        (np.inf, "must be finite"),
        (np.ones((2, 2)), "shape"),
        (np.array([[1.0, 1.0], [0.0, 1.0], [0.0, 0.0]]), "shape"),
        (np.array([[1.0, 0.3, 0], [0.0, 1.0, 0], [0, 0, 1]]), "not symmetric"),
        (np.diag([1.0, -1.0, 1.0]), "not positive definite"),
        (np.diag([1.0, np.nan, 1.0]), "non-finite"),
    ]:
        with pytest.raises(ModelError, match=pattern):
            weight_matrix(bad, 3)


# ------------------------------------------------------------------------------------------ the 2-node example
def two_node_problem() -> LinearProblem:
    """x scalar, a_1 = a_2 = 1, R_1 = R_2 = 1, y = (0, 4): x̂ = 2, Σ f_i(x̂) = 4."""
    return LinearProblem.from_blocks([np.ones((1, 1))] * 2, [np.array([0.0]), np.array([4.0])])


def test_method_of_multipliers_matches_hand_computation():
    # with W = 1: G_i = 1/2, H_i = 1/2, h_i = (y_i + u_i)/2, so z = Σ(y_i + u_i)/2 = 2 (Σu stays 0) and
    # x_i = (z − u_i) + (y_i − z + u_i)/2;  u_i += x_i − z.
    # k=1: u=0 → x=(1,3), u=(−1,1); k=2: x=(1.5,2.5), u=(−1.5,1.5); k=3: x=(1.75,2.25).
    prob = two_node_problem()
    res = method_of_multipliers(prob, W=1.0, iterations=3, reference=np.array([2.0]))
    x = res.trace["x"][:, :, 0]
    np.testing.assert_allclose(x, [[1.0, 3.0], [1.5, 2.5], [1.75, 2.25]], atol=1e-14)
    np.testing.assert_allclose(res.trace["z"][:, 0], [2.0, 2.0, 2.0], atol=1e-14)
    np.testing.assert_allclose(res.trace["u"][:, :, 0], [[-1, 1], [-1.5, 1.5], [-1.75, 1.75]], atol=1e-14)
    # g(0): x = (1, 3), z = 2: f = ½·1² + ½·1² = 1; ½(x_i − z)² = ½ + ½ = 1: g = 2
    assert res.dual_value_initial == pytest.approx(2.0, abs=1e-14)
    # u = (−1, 1): x = (1.5, 2.5), z = 2: f = ½·1.5² + ½·1.5² = 2.25; ½(x_i − z + u_i)² = ½·1.5² each = 2.25;
    # −½u_i² = −1 in all: g = 3.5
    assert res.trace["dual_value"][0] == pytest.approx(3.5, abs=1e-14)
    assert np.all(np.diff(res.trace["dual_value"]) > 0)  # an ascent method (eq. (14))
    assert np.all(res.trace["dual_value"] < 4.0)  # lower bound, eq. (11)


def test_single_consensus_admm_matches_hand_computation():
    # z0 = 3, u = 0: x = (3 + (0−3)/2, 3 + (4−3)/2) = (1.5, 3.5); z = 2.5; u = (−1, 1)
    # k=2: x1 = 3.5 + (0−3.5)/2 = 1.75, x2 = 1.5 + (4−1.5)/2 = 2.75; z = mean(0.75, 3.75) = 2.25; u = (−1.5, 1.5)
    res = single_consensus_admm(two_node_problem(), W=1.0, iterations=2, z0=3.0)
    np.testing.assert_allclose(res.trace["x"][:, :, 0], [[1.5, 3.5], [1.75, 2.75]], atol=1e-14)
    np.testing.assert_allclose(res.trace["z"][:, 0], [2.5, 2.25], atol=1e-14)
    np.testing.assert_allclose(res.trace["u"][:, :, 0], [[-1.0, 1.0], [-1.5, 1.5]], atol=1e-14)


def test_dual_function_bounds_and_maximum(rng):
    """g(u) ≤ Σ f_i(x̂) for any u (eq. (11)); g(û) = Σ f_i(x̂) at û of eq. (9) (eq. (12))."""
    A, y, R = random_blocks(rng, [2, 2, 3, 1], 3)
    prob = LinearProblem.from_blocks(A, y, R)
    W = np.diag([0.5, 1.0, 2.0])
    sol = blue(prob, W=W)
    assert sol.multipliers is not None
    for _ in range(5):
        assert dual_function(prob, rng.normal(size=(4, 3)), W) <= sol.cost + 1e-10
    assert dual_function(prob, sol.multipliers, W) == pytest.approx(sol.cost, rel=1e-10)
    x, z = multiplier_step(prob, sol.multipliers, W)
    np.testing.assert_allclose(z, sol.x, rtol=1e-10)
    np.testing.assert_allclose(x, np.broadcast_to(sol.x, x.shape), rtol=1e-10)


def test_reference_solvers_converge_to_blue_with_singular_N_i(rng):
    n, m, p = 8, 2, 4
    prob = LinearProblem.from_stacked(rng.normal(size=(n, m, p)), rng.normal(size=(n, m)))
    assert all(np.linalg.matrix_rank(N) < p for N in prob.normal_equations[0])
    xh = blue(prob).x
    mm = method_of_multipliers(prob, W=1.0, iterations=300)
    ad = single_consensus_admm(prob, W=1.0, iterations=600, z0=0.0)
    np.testing.assert_allclose(mm.estimates, np.broadcast_to(xh, (n, p)), rtol=1e-8, atol=1e-10)
    np.testing.assert_allclose(ad.estimates, np.broadcast_to(xh, (n, p)), rtol=1e-8, atol=1e-10)


def test_reference_solver_validation(rng):
    prob = two_node_problem()
    with pytest.raises(ModelError, match="iterations must be ≥ 0"):
        method_of_multipliers(prob, W=1.0, iterations=-1)
    with pytest.raises(ModelError, match="iterations must be ≥ 0"):
        single_consensus_admm(prob, W=1.0, iterations=-1, z0=0.0)
    for bad in (2.5, "3", True):  # the generators check the count themselves (2.5 was a bare TypeError of range)
        with pytest.raises(ModelError, match="iterations must be a whole number"):
            single_consensus_admm(prob, W=1.0, iterations=bad, z0=0.0)  # type: ignore[arg-type]
        with pytest.raises(ModelError, match="iterations must be a whole number"):
            next(iterate_method_of_multipliers(prob, W=1.0, iterations=bad))  # type: ignore[arg-type]
        with pytest.raises(ModelError, match="iterations must be a whole number"):
            next(iterate_single_consensus_admm(prob, W=1.0, iterations=bad, z0=0.0))  # type: ignore[arg-type]
    with pytest.raises(ModelError, match="multipliers u must have shape"):
        dual_function(prob, np.zeros(3), 1.0)
    with pytest.raises(ModelError, match="multipliers u have non-finite"):
        dual_function(prob, np.array([[np.nan], [0.0]]), 1.0)
    with pytest.raises(ModelError, match="z0 must be"):
        single_consensus_admm(prob, W=1.0, iterations=1, z0=np.zeros((2, 2)))
    deficient = LinearProblem.from_stacked(np.zeros((2, 1, 2)) + np.array([1.0, 0.0]), np.ones((2, 1)))
    with pytest.raises(ModelError, match="Σ H_i is singular"):
        multiplier_step(deficient, np.zeros((2, 2)), 1.0)
