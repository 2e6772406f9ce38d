"""Consensus Kalman filter (paper 003 Fig. 6) and its error-variance recursion (Fig. 7).

The recursion is validated three ways: (a) the stationary closed form ``P = α (t n N)⁻¹`` (eqs. (44)–(48)),
(b) ``k_n`` large gives the central filter, (c) Monte Carlo. Plus the paper's form of Fig. 7 coded
independently in this file, exact consensus on a complete graph, and every validation rule.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from distnav.algorithms.consensus.averaging import consensus_product, consensus_schedule
from distnav.algorithms.kalman import (
    DynamicModel,
    NormalSeries,
    ObservationSeries,
    central_filter,
    simulate_states,
)
from distnav.algorithms.kalman.ckf import (
    alpha_factor,
    ckf,
    ckf_error_variance,
    ckf_std_ratio,
    consensus_rounds,
    iterate_ckf,
)
from distnav.algorithms.kalman.ckf_options import CKFOptions, CKFRunOptions
from distnav.errors import ModelError, UsageError, WeightsError
from distnav.exchange import FaultSchedule, make_exchange
from distnav.network import builders
from distnav.network.graph import Graph, SwitchingGraph
from distnav.network.weights import ConsensusWeights


def observed_model(
    seed: int, *, n: int = 6, p: int = 4, T: int = 10, late_until: int = 3, identity_transition: bool = False
) -> tuple[DynamicModel, ObservationSeries, np.ndarray]:
    """Random model with singular system noise; entry p−1 unobserved before ``late_until``."""
    rng = np.random.default_rng(seed)
    F = None if identity_transition else np.eye(p) + 0.05 * rng.standard_normal((p, p))
    dyn = DynamicModel(p, transition=F, noise_cov=np.diag([0.2, 0.1] + [0.0] * (p - 2)))
    x = simulate_states(dyn, T, rng=rng, initial_state=rng.standard_normal(p))
    epochs = []
    for t in range(T):
        row = []
        for _ in range(n):
            m = int(rng.integers(1, 3))
            A = rng.standard_normal((m, p))
            if t < late_until:
                A[:, p - 1] = 0.0
            var = rng.uniform(0.5, 2.0, m)
            row.append((A, var, A @ x[t] + np.sqrt(var) * rng.standard_normal(m)))
        epochs.append(row)
    return dyn, ObservationSeries(p, epochs), x


def table1_product(n: int, links: list[tuple[int, int]], protocol: str, kn: int) -> np.ndarray:
    """``L = W^k_n`` from paper 003 Table 1, written here from the links (independent of the library's weights).

    For a neighbour j of i: P1 ``w_ij = 1/max_u dg_u``, P2 ``1/n``, P3 (Metropolis) ``1/(1 + max(dg_i, dg_j))``;
    the self-weight makes each row sum to 1.
    """
    adj = np.zeros((n, n), bool)
    for a, b in links:
        adj[a, b] = adj[b, a] = True
    dg = adj.sum(axis=1)
    W = np.zeros((n, n))
    for i in range(n):
        for j in np.flatnonzero(adj[i]):
            W[i, j] = {"P1": 1.0 / dg.max(), "P2": 1.0 / n, "P3": 1.0 / (1 + max(dg[i], dg[j]))}[protocol]
        W[i, i] = 1.0 - W[i].sum()
    return np.linalg.matrix_power(W, kn)


def path_links(n: int) -> list[tuple[int, int]]:
    return [(i, i + 1) for i in range(n - 1)]


def ring_links(n: int) -> list[tuple[int, int]]:
    return [(i, (i + 1) % n) for i in range(n)]


def test_table1_reference_tells_the_protocols_apart():
    # the reference above must distinguish the protocols on the graphs used here, or the tests below prove nothing
    for links in (path_links(6), ring_links(6)):
        Ls = [table1_product(6, links, pr, 3) for pr in ("P1", "P2", "P3")]
        assert not np.allclose(Ls[0], Ls[2]) and not np.allclose(Ls[1], Ls[2]) and not np.allclose(Ls[0], Ls[1])


def test_consensus_rounds_from_time_scales():
    # paper 003 §5.2: Δ = 60 s; δ = 15, 10, 5 s → k_n = 4, 6, 12
    assert [consensus_rounds(60.0, d) for d in (15.0, 10.0, 5.0)] == [4, 6, 12]
    assert consensus_rounds(1.0, 0.3) == 3
    assert consensus_rounds(60.0, 60.0) == 1
    # the messages name the arguments to change (issue 29), not only the paper's symbols
    with pytest.raises(ModelError, match="sending_interval_s = 15.0 s .δ. exceeds sampling_interval_s = 10.0 s"):
        consensus_rounds(10.0, 15.0)
    with pytest.raises(ModelError, match="sampling_interval_s .the sampling interval Δ."):
        consensus_rounds(0.0, 1.0)
    with pytest.raises(ModelError, match="sending_interval_s .the sending interval δ."):
        consensus_rounds(60.0, -5.0)


def test_alpha_factor_bounds():
    g = builders.path(7)
    sched = consensus_schedule(g, "P3")
    for kn in (0, 1, 3, 10):
        a = alpha_factor(consensus_product(sched, kn))
        assert np.all(a >= 1 - 1e-12)
    np.testing.assert_allclose(alpha_factor(consensus_product(sched, 0)), 7.0)  # L = I → α = n
    np.testing.assert_allclose(alpha_factor(np.full((5, 5), 0.2)), 1.0)  # l = e/n → α = 1 (eq. (48))
    with pytest.raises(WeightsError, match="square"):
        alpha_factor(np.ones((2, 3)))


@pytest.mark.parametrize("kn", [1, 3, 6])
def test_stationary_closed_form(kn):
    # eqs. (44)–(47): Φ = I, S = 0, N_i = N for all i → P_i,t|t = α_i (t n N)⁻¹, α_i = n Σ_j l_ij²
    n, p, T = 8, 3, 6
    rng = np.random.default_rng(kn)
    B = rng.standard_normal((5, p))
    N = B.T @ B
    ms = NormalSeries(np.broadcast_to(N, (T, n, p, p)).copy())
    g = builders.path(n)
    res = ckf(DynamicModel(p), ms, graph=g, protocol="P3", rounds=kn, store_matrices=True)
    P = res.series.covariance
    L = table1_product(n, path_links(n), "P3", kn)  # the protocol's definition, not the library's weights
    alpha = n * (L**2).sum(axis=1)
    Ninv = np.linalg.inv(N)
    for t in range(T):
        for i in range(n):
            np.testing.assert_allclose(P[t, i], alpha[i] * Ninv / ((t + 1) * n), rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(res.alpha, alpha, rtol=1e-12)
    # the nominal variance I_i⁻¹ = (t n N)⁻¹ is the central one: it understates the error by √α
    s = res.series
    np.testing.assert_allclose(
        s.std / s.nominal_std, np.broadcast_to(np.sqrt(alpha)[None, :, None], s.std.shape), rtol=1e-10
    )


@pytest.mark.parametrize("graph_kind", ["static", "switching"])
def test_many_rounds_give_the_central_filter(graph_kind):
    dyn, ms, _ = observed_model(1)
    if graph_kind == "static":
        g: Graph | SwitchingGraph = builders.ring(ms.n_nodes)
        protocol, kn = "P3", 300
    else:
        s1 = Graph.from_links(6, [(0, 1), (2, 3), (4, 5)])
        s2 = Graph.from_links(6, [(1, 2), (3, 4), (5, 0)])
        g = SwitchingGraph((s1, s2))
        protocol, kn = "P4", 300
    c = central_filter(dyn, ms).series
    r = ckf(dyn, ms, graph=g, protocol=protocol, rounds=kn)
    s = r.series
    assert np.array_equal(s.estimable, np.broadcast_to(c.estimable, s.estimable.shape))
    central = np.broadcast_to(c.estimates, s.estimates.shape)
    np.testing.assert_allclose(np.nan_to_num(s.estimates), np.nan_to_num(central), atol=1e-8)
    ratio = ckf_std_ratio(s, c)
    np.testing.assert_allclose(ratio[s.estimable], 1.0, atol=1e-8)
    np.testing.assert_allclose(s.nominal_std[s.estimable], s.std[s.estimable], rtol=1e-8)
    assert r.trace["consensus_deviation"].max() < 1e-9


def test_complete_graph_one_round_is_exact_average():
    # Protocol 2 on a complete graph: W = eeᵀ/n, so one round delivers N̄, r̄ exactly (eqs. (27)–(28))
    dyn, ms, _ = observed_model(2)
    c = central_filter(dyn, ms).series
    s = ckf(dyn, ms, graph=builders.complete(ms.n_nodes), protocol="P2", rounds=1).series
    central = np.broadcast_to(c.estimates, s.estimates.shape)
    np.testing.assert_allclose(np.nan_to_num(s.estimates), np.nan_to_num(central), atol=1e-10)
    np.testing.assert_allclose(np.nan_to_num(s.std), np.nan_to_num(np.broadcast_to(c.std, s.std.shape)), atol=1e-10)


def paper_fig7(dyn: DynamicModel, ms: NormalSeries | ObservationSeries, L: np.ndarray) -> np.ndarray:
    """Fig. 7 exactly as printed (needs I_i invertible from epoch 0): written here, independent of the library."""
    n, p = ms.n_nodes, ms.n_states
    I = np.zeros((n, p, p))
    P = np.zeros((n, p, p))
    out = []
    for t in range(ms.n_epochs):
        N, _ = ms.normals(t)
        if t == 0:
            Ipred = np.zeros((n, p, p))
            Ppred = np.zeros((n, p, p))
        else:
            F = dyn.transition_at(t)
            S = dyn.noise_cov_at(t)
            Ppred = np.stack([F @ P[i] @ F.T + S for i in range(n)])
            Ipred = np.stack([np.linalg.inv(F @ np.linalg.inv(I[i]) @ F.T + S) for i in range(n)])
        for i in range(n):
            Nk = sum(L[i, j] * N[j] for j in range(n))
            I[i] = Ipred[i] + n * Nk
            extra = n**2 * sum(L[i, j] ** 2 * N[j] for j in range(n))
            Iinv = np.linalg.inv(I[i])
            P[i] = Iinv @ (Ipred[i] @ Ppred[i] @ Ipred[i] + extra) @ Iinv
        out.append(P.copy())
    return np.stack(out)


@pytest.mark.parametrize("general_noise", [False, True])
def test_recursion_matches_paper_form_of_fig7(general_noise):
    dyn, ms, _ = observed_model(3, late_until=0)
    if general_noise:  # singular S without identity-column structure: the generic H path of the time update
        B = np.random.default_rng(9).standard_normal((ms.n_states, 2))
        dyn = DynamicModel(ms.n_states, transition=dyn.transition_at(1), noise_cov=B @ B.T * 0.1)
        assert dyn.noise_selection_at(1) is None
    else:
        assert dyn.noise_selection_at(1) is not None
    g = builders.path(ms.n_nodes)
    L = table1_product(ms.n_nodes, path_links(ms.n_nodes), "P1", 2)  # Table 1, not the library's weights
    ref = paper_fig7(dyn, ms, L)
    res = ckf(dyn, ms, graph=g, protocol="P1", rounds=2, store_matrices=True)
    np.testing.assert_allclose(res.series.covariance, ref, rtol=1e-9, atol=1e-12)
    alone = ckf_error_variance(dyn, ms, L, store_matrices=True)
    np.testing.assert_allclose(alone.covariance, ref, rtol=1e-9, atol=1e-12)


def test_standalone_recursion_equals_ckf_with_rank_deficient_start():
    dyn, ms, _ = observed_model(4, late_until=4, identity_transition=True)
    g = builders.ring(ms.n_nodes)
    r = ckf(dyn, ms, graph=g, rounds=3)
    s = r.series
    np.testing.assert_allclose(r.product, table1_product(ms.n_nodes, ring_links(ms.n_nodes), "P3", 3), atol=1e-15)
    alone = ckf_error_variance(dyn, ms, r.product)
    assert np.array_equal(alone.estimable, s.estimable)
    assert not s.estimable[:4, :, -1].any() and s.estimable[4:].all()
    np.testing.assert_allclose(np.nan_to_num(alone.std), np.nan_to_num(s.std), rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(np.nan_to_num(alone.nominal_std), np.nan_to_num(s.nominal_std), rtol=1e-10)
    c = central_filter(dyn, ms).series
    ratio = ckf_std_ratio(s, c)
    assert np.nanmin(ratio) >= 1 - 1e-9  # the CKF is never better than the central filter (eq. (48))


def test_monte_carlo_error_covariance():
    """Monte Carlo check of Fig. 7: D(x_t − x̂_i,t|t) = P_i,t|t.

    Model: 5 nodes on a path, Protocol 3, k_n = 2, p = 3, non-identity Φ, singular S (one constant entry),
    x_0 with an arbitrary non-zero mean (the BLUP start needs no prior). At epoch 0 entries 1 and 2 are observed
    only as their sum, so only entry 0 is estimable and every I_i is singular (not structurally): that epoch
    tests the information-error form of the recursion on the estimable block. 1500 realizations of system and
    measurement noise; for node i and epoch t the errors of the k estimable entries are whitened with P_i,t|t:
    z = C⁻¹ e, C Cᵀ = P (that block).
    Statistic: the likelihood-ratio test of D(z) = I with known zero mean (so bias is tested too),
    λ = R (tr S_z − ln det S_z − k), S_z = Σ z zᵀ / R, asymptotically χ² with k(k+1)/2 degrees of freedom.
    Each of the 20 (node, epoch) tests uses level 1e-4 (χ²₆ quantile 27.9, χ²₁ 15.1); the family-wise false-alarm
    rate is below 20 × 1e-4 = 2e-3 (Bonferroni). Seeded, so the outcome is reproducible. Power check in the same
    run: the nominal variance I_i⁻¹ (what a node believes, not its error variance) must be rejected for the
    path's end nodes, where α is largest (≈ 2.2).
    """
    n, p, T, R, kn = 5, 3, 6, 1500, 2
    rng = np.random.default_rng(20240601)
    F = np.array([[1.0, 0.1, 0.0], [0.0, 1.0, 0.05], [0.0, 0.0, 1.0]])
    dyn = DynamicModel(p, transition=F, noise_cov=np.diag([0.3, 0.2, 0.0]))
    designs = rng.standard_normal((T, n, 1, p))
    designs[0, :, :, 2] = designs[0, :, :, 1]  # epoch 0: entries 1 and 2 only observed as their sum
    var = rng.uniform(0.5, 2.0, (T, n, 1))
    g = builders.path(n)
    sched = consensus_schedule(g, "P3")
    x0_mean = np.array([5.0, -3.0, 2.0])
    Aw = designs / np.sqrt(var)[..., None]  # whitened designs
    Nfix = np.einsum("tnmp,tnmq->tnpq", Aw, Aw)
    errors = np.empty((R, T, n, p))
    for k in range(R):
        x = simulate_states(dyn, T, rng=rng, initial_state=x0_mean + rng.standard_normal(p))
        y = np.einsum("tnmp,tp->tnm", designs, x) + np.sqrt(var) * rng.standard_normal((T, n, 1))
        ms = NormalSeries(Nfix, np.einsum("tnmp,tnm->tnp", Aw, y / np.sqrt(var)))  # r = Aᵀ R⁻¹ y (eq. (24))
        for st in iterate_ckf(dyn, ms, rounds=kn, schedule=sched, variance=False, monitor=False):
            errors[k, st.epoch] = x[st.epoch] - st.estimates
    ms0 = ObservationSeries(p, [[(designs[t, i], var[t, i]) for i in range(n)] for t in range(T)])
    ref = ckf(dyn, ms0, schedule=sched, rounds=kn, store_matrices=True, monitor=False)
    P = ref.series.covariance
    info = ref.series.information
    est = ref.series.estimable

    def crit(k: int) -> float:
        return float(stats.chi2.ppf(1 - 1e-4, k * (k + 1) // 2))

    def lr_stat(e: np.ndarray, cov: np.ndarray) -> float:
        z = np.linalg.solve(np.linalg.cholesky(cov), e.T).T
        Sz = z.T @ z / z.shape[0]
        return float(R * (np.trace(Sz) - np.log(np.linalg.det(Sz)) - e.shape[1]))

    # epoch 0: only entry 0 estimable (I_i singular, not structurally: the eigen-decomposition path)
    assert est[0, :, 0].all() and not est[0, :, 1:].any() and est[1:].all()
    assert np.isfinite(errors[:, 1:]).all() and np.isnan(errors[:, 0, :, 1:]).all()
    for t in (0, 1, 2, 5):
        for i in range(n):
            m = est[t, i]
            lam = lr_stat(errors[:, t, i][:, m], P[t, i][np.ix_(m, m)])
            assert lam < crit(int(m.sum())), f"node {i}, epoch {t}: λ = {lam:.1f} ≥ {crit(int(m.sum())):.1f}"
    # power: the nominal I_i⁻¹ is rejected at the end nodes (α ≈ 2.2 there; λ ≈ 700–1300 in this run)
    alpha = ref.alpha
    assert alpha[0] > 2.0 and alpha[-1] > 2.0
    for i in (0, n - 1):
        assert lr_stat(errors[:, T - 1, i], np.linalg.inv(info[T - 1, i])) > crit(p)


def test_communication_totals():
    dyn, ms, _ = observed_model(5, T=4)
    g = builders.ring(ms.n_nodes)
    kn = 3
    r = ckf(dyn, ms, graph=g, rounds=kn)
    p = ms.n_states
    msgs = ms.n_epochs * kn * 2 * g.n_links
    assert r.comm.messages == msgs
    assert r.comm.rounds == ms.n_epochs * kn
    assert r.comm.bytes == msgs * (p * (p + 1) // 2 + p) * 8
    assert r.iterations == ms.n_epochs and r.rounds == kn


def test_time_scales_give_rounds():
    dyn, ms, _ = observed_model(6, T=3)
    r = ckf(dyn, ms, graph=builders.ring(ms.n_nodes), sampling_interval_s=60.0, sending_interval_s=10.0)
    assert r.rounds == 6
    assert r.comm.rounds == 3 * 6


def test_faults_use_the_product_actually_applied():
    # with dropped messages the weights move to the self-weight; the CKF carries L along in the payload,
    # so the recursion must equal Fig. 7 evaluated with the per-epoch products measured separately.
    dyn, ms, _ = observed_model(7, T=5, late_until=0)
    g = builders.ring(ms.n_nodes)
    kn = 3
    faults = FaultSchedule(drop_probability=0.3, seed=3)
    res = ckf(dyn, ms, graph=g, rounds=kn, exchange=make_exchange(g, faults=faults), store_matrices=True)
    assert res.comm.messages_dropped > 0
    # products per epoch, obtained by mixing the identity with an exchange with the same fault schedule, with
    # the P3 weights of Table 1 built here (so a wrong protocol in the library cannot agree with itself)
    ex = make_exchange(g, faults=faults)
    W3 = table1_product(ms.n_nodes, ring_links(ms.n_nodes), "P3", 1)
    mixer = ex.mixer(ConsensusWeights.from_matrix(g, W3))
    Ls = []
    for _ in range(ms.n_epochs):
        Lt = np.eye(ms.n_nodes)
        for _k in range(kn):
            Lt = mixer.apply(Lt)
        Ls.append(Lt)
    assert not np.allclose(Ls[0], Ls[1])
    # independent reference: the paper's Fig. 7 with an epoch-dependent L
    n, p = ms.n_nodes, ms.n_states
    I = np.zeros((n, p, p))
    P = np.zeros((n, p, p))
    for t in range(ms.n_epochs):
        N, _ = ms.normals(t)
        if t:
            F, S = dyn.transition_at(t), dyn.noise_cov_at(t)
            Ppred = np.stack([F @ P[i] @ F.T + S for i in range(n)])
            Ipred = np.stack([np.linalg.inv(F @ np.linalg.inv(I[i]) @ F.T + S) for i in range(n)])
        else:
            Ppred = Ipred = np.zeros((n, p, p))
        for i in range(n):
            I[i] = Ipred[i] + n * np.einsum("j,jab->ab", Ls[t][i], N)
            Iinv = np.linalg.inv(I[i])
            P[i] = Iinv @ (Ipred[i] @ Ppred[i] @ Ipred[i] + n**2 * np.einsum("j,jab->ab", Ls[t][i] ** 2, N)) @ Iinv
        np.testing.assert_allclose(res.series.covariance[t], P, rtol=1e-8, atol=1e-12)


def test_ckf_validation():
    dyn, ms, _ = observed_model(8, T=2)
    g = builders.ring(ms.n_nodes)
    with pytest.raises(ModelError, match="either rounds"):
        ckf(dyn, ms, graph=g, rounds=2, sampling_interval_s=60.0, sending_interval_s=5.0)
    with pytest.raises(ModelError, match="give rounds"):
        ckf(dyn, ms, graph=g)
    with pytest.raises(ModelError, match="non-negative integer"):
        ckf(dyn, ms, graph=g, rounds=-1)
    with pytest.raises(ModelError, match="graph has 7 nodes, the measurements 6"):
        ckf(dyn, ms, graph=builders.ring(7), rounds=1)
    with pytest.raises(ModelError, match="give a graph"):
        ckf(dyn, ms, rounds=1)
    with pytest.raises(ModelError, match="different graph"):
        ckf(dyn, ms, graph=g, rounds=1, exchange=make_exchange(builders.path(6)))
    with pytest.raises(ModelError, match="must be 6×6"):
        ckf_error_variance(dyn, ms, np.eye(5))
    with pytest.raises(ModelError, match="3 states, measurements 4"):
        ckf(DynamicModel(3), ms, graph=g, rounds=1)


def test_options_object_and_keywords_run_the_same():
    """The house style (distnav._settings): CKFOptions / CKFRunOptions, keyword changes to them, or both — the same
    filter bit for bit; unknown names and wrong objects are refused by name."""
    dyn, ms, _ = observed_model(9, T=4)
    g = builders.ring(ms.n_nodes)
    by_keywords = ckf(dyn, ms, graph=g, rounds=3, protocol="P2", store_matrices=True)
    by_object = ckf(dyn, ms, graph=g, options=CKFRunOptions(rounds=3, protocol="P2", store_matrices=True))
    mixed = ckf(dyn, ms, graph=g, options=CKFOptions(protocol="P2"), rounds=3, store_matrices=True)
    for res in (by_object, mixed):
        np.testing.assert_array_equal(res.series.estimates, by_keywords.series.estimates)
        np.testing.assert_array_equal(res.series.covariance, by_keywords.series.covariance)
    assert ckf(dyn, ms, graph=g, options=CKFOptions(rounds=3)).series.covariance is None  # keeps no matrices
    states = list(iterate_ckf(dyn, ms, graph=g, options=CKFOptions(rounds=3, protocol="P2")))
    np.testing.assert_array_equal(states[-1].estimates, by_keywords.estimates)
    with pytest.raises(UsageError, match="CKFRunOptions has no option 'round'.*did you mean 'rounds'"):
        ckf(dyn, ms, graph=g, round=3)
    with pytest.raises(UsageError, match="CKFOptions has no option 'store_matrices'"):
        next(iterate_ckf(dyn, ms, graph=g, rounds=3, store_matrices=True))
    with pytest.raises(ModelError, match="give rounds"):
        ckf(dyn, ms, graph=g, options=CKFOptions(protocol="P2"))  # a partial object: the rounds are missing
    with pytest.raises(ModelError, match="either rounds"):
        CKFOptions(rounds=2, sending_interval_s=5.0)


def test_zero_rounds_is_a_suboptimal_local_filter():
    # k_n = 0: L = I, node i uses only its own data but with weight n (Fig. 6), so its estimator is a linear
    # unbiased one of the local data: Fig. 7's P must be ≥ the optimal local filter's variance (BLUP optimality),
    # with no messages sent and α = n.
    dyn, ms, _ = observed_model(1)
    from distnav.algorithms.kalman import local_filters

    loc = local_filters(dyn, ms).series
    r = ckf(dyn, ms, graph=builders.ring(ms.n_nodes), rounds=0)
    s = r.series
    assert r.comm.messages == 0
    np.testing.assert_allclose(r.alpha, ms.n_nodes)
    assert np.array_equal(s.estimable, loc.estimable)
    m = s.estimable
    assert np.all(s.std[m] >= loc.std[m] * (1 - 1e-10))
    assert np.any(s.std[m] > loc.std[m] * 1.01)  # strictly worse somewhere: the weighting is not optimal
    assert ckf(dyn, ms, graph=builders.ring(ms.n_nodes), rounds=3, variance=False).product is None
