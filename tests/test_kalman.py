"""Kalman filter (covariance form), information filter and batch BLUP — paper 003 §2.

References are independent of the code under test: the covariance form (three-step recursion) against the
information form (Fig. 1), both against the batch mixed-model BLUP, ``numpy.linalg.pinv`` for the
pseudo-inverse, and paper facts (local-to-central ratio √n at the start, §5.3).
"""

from __future__ import annotations

import numpy as np
import pytest

from distnav.algorithms.kalman import (
    DynamicModel,
    FunctionSeries,
    NodeEpoch,
    NormalSeries,
    ObservationSeries,
    batch_blup,
    central_filter,
    exact_average_filters,
    information_filter,
    kalman_filter,
    local_filters,
    noise_factor,
    normal_equations,
    pseudo_inverse_psd,
    simulate_states,
    std_ratio,
)
from distnav.errors import ModelError


def random_model(
    seed: int,
    *,
    p: int = 5,
    n: int = 4,
    T: int = 14,
    late_entry: int | None = 4,
    late_until: int = 6,
    general_noise: bool = False,
    identity_transition: bool = False,
) -> tuple[DynamicModel, ObservationSeries]:
    """A random linear model: singular system noise, one state entry unobserved before ``late_until``,
    varying numbers of observations, some nodes without data, full and diagonal R."""
    rng = np.random.default_rng(seed)
    if general_noise:  # singular, non-diagonal S: factored by eigen-decomposition
        B = rng.standard_normal((p, 2))
        S = B @ B.T
    else:  # entries 0..1 random walk, the rest constant: eq. (20) representation
        S = np.diag([0.3, 0.2] + [0.0] * (p - 2))
    F = None if identity_transition else np.eye(p) + 0.05 * rng.standard_normal((p, p))
    dyn = DynamicModel(p, transition=F, noise_cov=S)
    x = simulate_states(dyn, T, rng=rng, initial_state=rng.standard_normal(p))
    epochs = []
    for t in range(T):
        row: list[object] = []
        for i in range(n):
            if (t + i) % 5 == 3:
                row.append(None)
                continue
            m = int(rng.integers(1, 4))
            A = rng.standard_normal((m, p))
            if late_entry is not None and t < late_until:
                A[:, late_entry] = 0.0
            if i % 2:
                C = rng.standard_normal((m, m))
                R = C @ C.T + m * np.eye(m)
            else:
                R = rng.uniform(0.5, 2.0, m)
            Rm = R if np.ndim(R) == 2 else np.diag(R)
            y = A @ x[t] + np.linalg.cholesky(Rm) @ rng.standard_normal(m)
            row.append(NodeEpoch(A, R, y) if i % 3 == 0 else (A, R, y))
        epochs.append(row)
    return dyn, ObservationSeries(p, epochs)


def _assert_series_equal(a, b, tol=1e-10):
    assert np.array_equal(a.estimable, b.estimable)
    assert np.array_equal(np.isnan(a.estimates), np.isnan(b.estimates))
    np.testing.assert_allclose(np.nan_to_num(a.estimates), np.nan_to_num(b.estimates), atol=tol, rtol=0)
    np.testing.assert_allclose(np.nan_to_num(a.std), np.nan_to_num(b.std), atol=tol, rtol=tol)


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("general_noise", [False, True])
def test_information_form_equals_covariance_form(seed, general_noise):
    dyn, ms = random_model(seed, general_noise=general_noise)
    info = central_filter(dyn, ms, store_matrices=True)
    cov = kalman_filter(dyn, ms, store_matrices=True)
    si, sc = info.series, cov.series
    _assert_series_equal(si, sc)
    init = cov.init_epoch
    assert init >= 0
    # full error-variance matrices after the BLUP initialization
    np.testing.assert_allclose(si.covariance[init:], sc.covariance[init:], atol=1e-10, rtol=1e-9)


def test_rank_deficient_early_epochs_are_reported_as_nan():
    # identity transition: the late entry carries no information at all before epoch 6
    dyn, ms = random_model(5, identity_transition=True, late_entry=4, late_until=6)
    res = central_filter(dyn, ms)
    s = res.series
    assert not s.estimable[:6, 0, 4].any()
    assert np.isnan(s.estimates[:6, 0, 4]).all() and np.isnan(s.std[:6, 0, 4]).all()
    assert s.estimable[6:, 0].all()
    assert s.estimable[1:6, 0, :4].all()  # the others are estimable from epoch 1 on (enough rows)
    cov = kalman_filter(dyn, ms)
    assert cov.init_epoch == 6
    _assert_series_equal(s, cov.series)


@pytest.mark.parametrize("epoch", [0, 2, 5, 9, 13])
def test_information_filter_equals_batch_blup(epoch):
    dyn, ms = random_model(3, identity_transition=True)
    s = central_filter(dyn, ms, store_matrices=True).series
    x, est, P = batch_blup(dyn, ms, epoch)
    assert np.array_equal(est, s.estimable[epoch, 0])
    np.testing.assert_allclose(x[est], s.estimates[epoch, 0, est], atol=1e-10)
    np.testing.assert_allclose(P[np.ix_(est, est)], s.covariance[epoch, 0][np.ix_(est, est)], atol=1e-10)


def test_exact_average_filters_reproduce_central():
    dyn, ms = random_model(7)
    c = central_filter(dyn, ms).series
    e = exact_average_filters(dyn, ms).series
    assert e.estimates.shape == (ms.n_epochs, ms.n_nodes, ms.n_states)
    for i in range(ms.n_nodes):
        assert np.array_equal(e.estimable[:, i], c.estimable[:, 0])
        np.testing.assert_allclose(
            np.nan_to_num(e.estimates[:, i]), np.nan_to_num(c.estimates[:, 0]), atol=1e-10, rtol=0
        )
        np.testing.assert_allclose(np.nan_to_num(e.std[:, i]), np.nan_to_num(c.std[:, 0]), atol=1e-10)


def test_local_filters_equal_single_node_covariance_form():
    dyn, ms = random_model(11, n=3, T=20, late_entry=None)
    loc = local_filters(dyn, ms).series
    for i in range(ms.n_nodes):
        ref = kalman_filter(dyn, ms, nodes=[i]).series
        assert np.array_equal(loc.estimable[:, i], ref.estimable[:, 0])
        np.testing.assert_allclose(np.nan_to_num(loc.estimates[:, i]), np.nan_to_num(ref.estimates[:, 0]), atol=1e-9)
        np.testing.assert_allclose(np.nan_to_num(loc.std[:, i]), np.nan_to_num(ref.std[:, 0]), atol=1e-9)


def test_local_to_central_ratio_is_sqrt_n_at_start():
    # paper 003 §5.3: equally precise receivers → local/central std = √n at the initialization
    n, p, T = 13, 3, 5
    rng = np.random.default_rng(0)
    A = rng.standard_normal((T, 4, p))
    N = np.einsum("tmp,tmq->tpq", A, A)
    Ns = np.broadcast_to(N[:, None], (T, n, p, p)).copy()
    ms = NormalSeries(Ns)
    dyn = DynamicModel.random_walk([0.1, 0.1, 0.0])
    c = central_filter(dyn, ms).series
    loc = local_filters(dyn, ms).series
    ratio = std_ratio(loc, c)
    assert ratio.shape == (T, n, p)
    np.testing.assert_allclose(ratio[0], np.sqrt(n), rtol=1e-12)
    assert np.all(ratio[1:] > 1.0)  # the central filter stays more precise


def test_noise_factor_representations():
    S = np.diag([2.0, 0.0, 3.0])
    H, St = noise_factor(S)
    np.testing.assert_array_equal(H, np.eye(3)[:, [0, 2]])  # eq. (20): identity columns
    np.testing.assert_array_equal(St, np.diag([2.0, 3.0]))
    B = np.array([[1.0, 0.0], [1.0, 1.0], [0.0, 2.0]])
    S2 = B @ B.T  # singular, no zero rows
    H2, St2 = noise_factor(S2)
    assert H2.shape == (3, 2)
    np.testing.assert_allclose(H2 @ St2 @ H2.T, S2, atol=1e-12)
    H0, S0 = noise_factor(np.zeros((2, 2)))
    assert H0.shape == (2, 0) and S0.shape == (0, 0)


def test_noise_map_equals_noise_cov():
    dyn1, ms = random_model(4, general_noise=False)
    S = dyn1.noise_cov_at(1)
    F = dyn1.transition_at(1)
    H = np.array([[1.0, 0.0], [0.0, 1.0], [0.0, 0.0], [0.0, 0.0], [0.0, 0.0]])
    dyn2 = DynamicModel(5, transition=F, noise_map=H, noise_reduced_cov=S[:2, :2])
    a = central_filter(dyn1, ms).series
    b = central_filter(dyn2, ms).series
    _assert_series_equal(a, b, tol=1e-12)


def test_per_epoch_dynamics_and_static_state():
    rng = np.random.default_rng(2)
    T, p = 6, 2
    Fs = np.stack([np.eye(p) + 0.1 * rng.standard_normal((p, p)) for _ in range(T)])
    Ss = [np.diag([0.1 * (t + 1), 0.0]) for t in range(T)]
    dyn = DynamicModel(p, transition=Fs, noise_cov=Ss)
    epochs = [[(rng.standard_normal((2, p)), np.ones(2), rng.standard_normal(2))] for _ in range(T)]
    ms = ObservationSeries(p, epochs)
    _assert_series_equal(central_filter(dyn, ms).series, kalman_filter(dyn, ms).series)
    # no system noise: the filter is recursive least squares = the batch solution of all data
    static = DynamicModel(p)
    s = central_filter(static, ms).series
    A = np.concatenate([e[0][0] for e in epochs])
    y = np.concatenate([e[0][2] for e in epochs])
    np.testing.assert_allclose(s.estimates[-1, 0], np.linalg.lstsq(A, y, rcond=None)[0], atol=1e-12)


def test_pseudo_inverse_matches_numpy():
    rng = np.random.default_rng(3)
    mats = []
    for rank in (5, 3, 0, 4):
        B = rng.standard_normal((5, rank))
        mats.append(B @ B.T)
    Z = mats[1].copy()
    Z[2, :] = 0.0
    Z[:, 2] = 0.0
    mats.append(Z)
    info = np.stack(mats)
    inv, est = pseudo_inverse_psd(info)
    for k in range(info.shape[0]):
        pinv = np.linalg.pinv(info[k], rcond=1e-10, hermitian=True)
        proj = np.eye(5) - pinv @ info[k]
        np.testing.assert_array_equal(est[k], np.diag(proj) < 1e-8)
        # a generalized inverse, equal to the pseudo-inverse on the estimable block
        np.testing.assert_allclose(info[k] @ inv[k] @ info[k], info[k], atol=1e-8)
        np.testing.assert_allclose(inv[k][np.ix_(est[k], est[k])], pinv[np.ix_(est[k], est[k])], atol=1e-8)
    np.testing.assert_allclose(inv[0], np.linalg.inv(info[0]), rtol=1e-8)
    assert est[0].all() and not est[2].any() and est[4].sum() == 0


def test_estimability_does_not_depend_on_units():
    # entries in wildly different units (1e-6 and 1e6): rank-deficient in entries 2-3 only
    rng = np.random.default_rng(5)
    A = rng.standard_normal((6, 4))
    A[:, 3] = A[:, 2]  # entries 2 and 3 only estimable as a sum
    D = np.diag([1e-6, 1e6, 1.0, 1.0])
    info = (D @ A.T @ A @ D)[None]
    inv, est = pseudo_inverse_psd(info)
    np.testing.assert_array_equal(est[0], [True, True, False, False])
    Dinv = np.linalg.inv(D)
    unscaled = A.T @ A
    ref = Dinv[:2, :2] @ np.linalg.pinv(unscaled, hermitian=True)[:2, :2] @ Dinv[:2, :2]
    np.testing.assert_allclose(inv[0][:2, :2], ref, rtol=1e-8)


def test_normal_equations_full_and_diagonal():
    rng = np.random.default_rng(4)
    A = rng.standard_normal((4, 3))
    y = rng.standard_normal(4)
    var = np.array([1.0, 2.0, 0.5, 4.0])
    N, r = normal_equations(A, var, y)
    np.testing.assert_allclose(N, A.T @ np.diag(1 / var) @ A)
    np.testing.assert_allclose(r, A.T @ (y / var))
    C = rng.standard_normal((4, 4))
    R = C @ C.T + np.eye(4)
    N2, r2 = normal_equations(A, R, y)
    np.testing.assert_allclose(N2, A.T @ np.linalg.solve(R, A))
    np.testing.assert_allclose(r2, A.T @ np.linalg.solve(R, y))


def test_function_series_and_node_subsets():
    dyn, ms = random_model(8)
    fs = FunctionSeries(ms.n_nodes, ms.n_epochs, ms.n_states, lambda t, nodes: ms.normals(t, nodes))
    _assert_series_equal(central_filter(dyn, ms).series, central_filter(dyn, fs).series, 0)
    sub = central_filter(dyn, ms, nodes=[0, 2]).series
    ref = kalman_filter(dyn, ms, nodes=[0, 2]).series
    _assert_series_equal(sub, ref)


# ------------------------------------------------------------------------------------------- validation
def test_dynamic_model_validation():
    with pytest.raises(ModelError, match="n_states"):
        DynamicModel(0)
    with pytest.raises(ModelError, match="must be 2×2"):
        DynamicModel(2, transition=np.eye(3))
    with pytest.raises(ModelError, match="singular"):
        DynamicModel(2, transition=np.zeros((2, 2)))
    with pytest.raises(ModelError, match="not finite"):
        DynamicModel(2, transition=np.array([[1.0, np.nan], [0.0, 1.0]]))
    with pytest.raises(ModelError, match="either noise_cov"):
        DynamicModel(2, noise_cov=np.eye(2), noise_map=np.eye(2), noise_reduced_cov=np.eye(2))
    with pytest.raises(ModelError, match="together"):
        DynamicModel(2, noise_map=np.eye(2))
    with pytest.raises(ModelError, match="not symmetric"):
        DynamicModel(2, noise_cov=np.array([[1.0, 0.5], [0.0, 1.0]]))
    with pytest.raises(ModelError, match="positive semi-definite"):
        DynamicModel(2, noise_cov=np.diag([1.0, -1.0]))
    with pytest.raises(ModelError, match="must be 2×2"):
        DynamicModel(2, noise_cov=np.eye(3))
    with pytest.raises(ModelError, match="full column rank"):
        DynamicModel(2, noise_map=np.ones((2, 2)), noise_reduced_cov=np.eye(2))
    with pytest.raises(ModelError, match="not positive definite"):
        DynamicModel(2, noise_map=np.eye(2), noise_reduced_cov=np.diag([1.0, 0.0]))
    with pytest.raises(ModelError, match="2×2 to match"):
        DynamicModel(2, noise_map=np.eye(2), noise_reduced_cov=np.eye(1))
    with pytest.raises(ModelError, match="must have 2 rows"):
        DynamicModel(2, noise_map=np.eye(3), noise_reduced_cov=np.eye(3))
    with pytest.raises(ModelError, match="both be constant"):
        DynamicModel(2, noise_map=np.eye(2), noise_reduced_cov=[np.eye(2)] * 3)
    with pytest.raises(ModelError, match="at epoch 1"):
        DynamicModel(2, noise_cov=[np.eye(2), np.diag([1.0, -2.0])])
    with pytest.raises(ModelError, match="non-negative"):
        DynamicModel.random_walk([1.0, -1.0])
    short = DynamicModel(2, transition=[np.eye(2)] * 2)
    ms = NormalSeries(np.zeros((4, 1, 2, 2)))
    with pytest.raises(ModelError, match="transition given for 2 epochs"):
        central_filter(short, ms)
    with pytest.raises(ModelError, match="2 states"):
        central_filter(DynamicModel(2), NormalSeries(np.zeros((2, 1, 3, 3))))


def test_node_ids_refuse_arrays_they_would_have_reshaped():
    ms = NormalSeries(np.zeros((4, 3, 2, 2)))
    assert ms.node_ids(1).tolist() == [1] and ms.node_ids([2, 0]).tolist() == [2, 0]
    assert ms.node_ids(np.array([], dtype=np.int64)).size == 0
    with pytest.raises(ModelError, match=r"1-D list of ids, got shape \(1, 2\)"):
        ms.node_ids([[0, 1]])
    with pytest.raises(ModelError, match="node ids must be integers, got dtype float64"):
        ms.node_ids([0.5])
    with pytest.raises(ModelError, match=r"must lie in 0..2"):
        ms.node_ids([3])


def test_observation_series_validation():
    A = np.ones((2, 3))
    with pytest.raises(ModelError, match="epoch 1, node 1: design must be m×3"):
        ObservationSeries(3, [[(A, np.ones(2)), None], [None, (np.ones((2, 2)), np.ones(2))]])
    with pytest.raises(ModelError, match="epoch 0, node 0: 2 design rows but observations"):
        ObservationSeries(3, [[(A, np.ones(2), np.ones(3))]])
    with pytest.raises(ModelError, match="epoch 0, node 0: variances must be positive"):
        ObservationSeries(3, [[(A, np.array([1.0, 0.0]))]])
    with pytest.raises(ModelError, match="2 observations but 3 variances"):
        ObservationSeries(3, [[(A, np.ones(3))]])
    with pytest.raises(ModelError, match="not positive definite"):
        ObservationSeries(3, [[(A, np.array([[1.0, 2.0], [2.0, 1.0]]))]])
    with pytest.raises(ModelError, match="not symmetric"):
        ObservationSeries(3, [[(A, np.array([[1.0, 0.5], [0.0, 1.0]]))]])
    with pytest.raises(ModelError, match="must be 2×2"):
        ObservationSeries(3, [[(A, np.eye(3))]])
    with pytest.raises(ModelError, match="not finite"):
        ObservationSeries(3, [[(A, np.ones(2), np.array([1.0, np.inf]))]])
    with pytest.raises(ModelError, match="expected NodeEpoch"):
        ObservationSeries(3, [["junk"]])
    with pytest.raises(ModelError, match="epoch 1 lists 1 nodes"):
        ObservationSeries(3, [[None, None], [None]])
    with pytest.raises(ModelError, match="at least one epoch"):
        ObservationSeries(3, [])
    with pytest.raises(ModelError, match="no nodes"):
        ObservationSeries(3, [[]])
    ms = ObservationSeries(3, [[(A, np.ones(2))]])
    with pytest.raises(ModelError, match="epoch 3 outside"):
        ms.normals(3)
    with pytest.raises(ModelError, match="node ids"):
        ms.normals(0, np.array([1]))


def test_normal_series_validation():
    with pytest.raises(ModelError, match="shape"):
        NormalSeries(np.zeros((2, 2, 2)))
    with pytest.raises(ModelError, match="right-hand sides"):
        NormalSeries(np.zeros((2, 1, 2, 2)), np.zeros((2, 2, 2)))
    N = np.zeros((2, 3, 2, 2))
    N[1, 2] = [[1.0, 0.5], [0.0, 1.0]]
    with pytest.raises(ModelError, match="epoch 1, node 2: normal matrix is not symmetric"):
        NormalSeries(N)
    N = np.zeros((2, 3, 2, 2))
    N[0, 1] = np.diag([1.0, -1.0])
    with pytest.raises(ModelError, match="epoch 0, node 1: .*negative diagonal"):
        NormalSeries(N)
    N = np.zeros((2, 3, 2, 2))
    N[1, 0, 0, 0] = np.nan
    with pytest.raises(ModelError, match="epoch 1, node 0: normals not finite"):
        NormalSeries(N)
    fs = FunctionSeries(2, 3, 2, lambda t, nodes: (np.zeros((1, 2, 2)), np.zeros((1, 2))))
    with pytest.raises(ModelError, match="epoch 0: fn returned shapes"):
        fs.normals(0)
    with pytest.raises(ModelError, match="≥ 1"):
        FunctionSeries(0, 3, 2, lambda t, nodes: (None, None))


def test_filter_entry_point_validation():
    dyn, ms = random_model(0)
    with pytest.raises(ModelError, match="mode must be one of"):
        information_filter(dyn, ms, mode="fusion")
    with pytest.raises(ModelError, match="no nodes selected"):
        central_filter(dyn, ms, nodes=[])
    with pytest.raises(ModelError, match="needs an ObservationSeries"):
        kalman_filter(DynamicModel(2), NormalSeries(np.zeros((3, 1, 2, 2))))
    with pytest.raises(ModelError, match="not estimable after 2 epochs"):
        kalman_filter(
            DynamicModel(2), ObservationSeries(2, [[(np.array([[1.0, 0.0]]), np.ones(1))]] * 5), max_batch_epochs=2
        )
    c = central_filter(dyn, ms).series
    short = local_filters(dyn, ObservationSeries(ms.n_states, [[None] * 2] * 3)).series
    with pytest.raises(ModelError, match="do not match"):
        std_ratio(short, c)
    loc = local_filters(dyn, ms).series
    with pytest.raises(ModelError, match="one row or"):
        std_ratio(c, loc)


def test_long_gnss_like_run_stays_equal_to_covariance_form():
    # GNSS-like scales (paper 003 §5): random-walk TEC-like entries with tiny system noise, constant biases
    # that set during the run, 300 epochs: the two forms must not drift apart numerically.
    rng = np.random.default_rng(0)
    n, nb, T = 4, 12, 300
    p = 3 + nb
    dyn = DynamicModel(p, noise_map=np.eye(p)[:, :3], noise_reduced_cov=np.diag([1e-6, 2.5e-5, 2.5e-5]))
    set_epoch = rng.integers(100, T + 1, nb)
    epochs = []
    for t in range(T):
        sats = np.flatnonzero(t < set_epoch)
        row = []
        for _ in range(n):
            A = np.zeros((sats.size, p))
            A[:, 0] = rng.uniform(1, 3, sats.size)
            A[:, 1:3] = rng.normal(0, 0.05, (sats.size, 2))
            A[np.arange(sats.size), 3 + sats] = 2.85
            var = rng.uniform(0.4, 2.0, sats.size) ** 2
            row.append((A, var, rng.standard_normal(sats.size)) if sats.size else None)
        epochs.append(row)
    ms = ObservationSeries(p, epochs)
    info = central_filter(dyn, ms).series
    cov = kalman_filter(dyn, ms).series
    assert np.array_equal(info.estimable, cov.estimable) and info.estimable[1:].all()
    m = info.estimable
    assert np.max(np.abs(info.estimates - cov.estimates)[m] / info.std[m]) < 1e-9
    assert np.max(np.abs(info.std / cov.std - 1)[m]) < 1e-9


def test_remaining_validation_rules():
    with pytest.raises(ModelError, match="must be square"):
        noise_factor(np.ones((2, 3)))
    with pytest.raises(ModelError, match="at epoch 4 is not finite"):
        noise_factor(np.array([[np.nan, 0.0], [0.0, 1.0]]), epoch=4)
    with pytest.raises(ModelError, match="empty sequence"):
        DynamicModel(2, transition=[])
    with pytest.raises(ModelError, match="must be a matrix, a 3-D array"):
        DynamicModel(2, transition=np.ones(2))
    with pytest.raises(ModelError, match="factor is not finite"):
        DynamicModel(2, noise_map=np.array([[1.0], [np.inf]]), noise_reduced_cov=np.eye(1))
    with pytest.raises(ModelError, match="noise_reduced_cov is not symmetric"):
        DynamicModel(2, noise_map=np.eye(2), noise_reduced_cov=np.array([[1.0, 0.5], [0.0, 1.0]]))
    dyn = DynamicModel(2, noise_cov=[np.eye(2)] * 3)
    with pytest.raises(ModelError, match="given for 3 epochs, epoch 5 requested"):
        dyn.noise_factor_at(5)
    with pytest.raises(ModelError, match="system noise given for 3 epochs, the measurements have 4"):
        central_filter(dyn, NormalSeries(np.zeros((4, 1, 2, 2))))
    with pytest.raises(ModelError, match="design must be a matrix"):
        normal_equations(np.ones(3), np.ones(3))
    with pytest.raises(ModelError, match="n_states must be ≥ 1"):
        ObservationSeries(0, [[None]])
