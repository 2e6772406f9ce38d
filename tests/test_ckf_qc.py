"""CKF node-local precision and local innovation tests (issue 12 items 3–4).

References, all independent of the node-local code: the Fig. 7 recursion with the global gather (itself checked
against the paper's printed form and Monte Carlo in test_ckf.py), Monte Carlo of the actual CKF errors, a CKF run
on data with the bad observation deleted by hand, and the binomial law of the false alarms.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from distnav.algorithms.consensus.averaging import consensus_schedule
from distnav.algorithms.kalman import DynamicModel, NormalSeries, ObservationSeries, simulate_states
from distnav.algorithms.kalman.ckf import ckf, iterate_ckf
from distnav.errors import ModelError
from distnav.exchange import FaultSchedule, make_exchange
from distnav.network import builders


def raw_data(
    seed: int,
    *,
    n: int = 6,
    p: int = 4,
    T: int = 10,
    m: int = 3,
    late_until: int = 2,
) -> tuple[DynamicModel, list[list[tuple[np.ndarray, np.ndarray, np.ndarray]]], np.ndarray]:
    """Random model with singular system noise, ``m`` observations per node and epoch, entry p−1 unobserved
    before ``late_until`` (the BLUP start with singular information)."""
    rng = np.random.default_rng(seed)
    F = np.eye(p) + 0.05 * rng.standard_normal((p, p))
    dyn = DynamicModel(p, transition=F, noise_cov=np.diag([0.2, 0.1] + [0.0] * (p - 2)))
    x = simulate_states(dyn, T, rng=rng, initial_state=rng.standard_normal(p))
    epochs = []
    for t in range(T):
        row = []
        for _ in range(n):
            A = rng.standard_normal((m, p))
            if t < late_until:
                A[:, p - 1] = 0.0
            var = rng.uniform(0.5, 2.0, m)
            row.append((A, var, A @ x[t] + np.sqrt(var) * rng.standard_normal(m)))
        epochs.append(row)
    return dyn, epochs, x


def series_of(epochs: list[list[tuple[np.ndarray, np.ndarray, np.ndarray]]], p: int) -> ObservationSeries:
    return ObservationSeries(p, epochs)


@pytest.mark.parametrize("graph_kind", ["path", "ring_with_drops"])
def test_exact_local_precision_equals_fig7(graph_kind):
    dyn, epochs, _ = raw_data(1)
    ms = series_of(epochs, 4)
    n = ms.n_nodes
    if graph_kind == "path":
        g = builders.path(n)
        ex = make_exchange(g)
    else:  # with drops the product differs per epoch; the local form must follow the product actually applied
        g = builders.ring(n)
        ex = make_exchange(g, faults=FaultSchedule(drop_probability=0.3, seed=4))
    res = ckf(dyn, ms, graph=g, rounds=3, exchange=ex, local_precision="exact", store_matrices=True)
    if graph_kind != "path":
        assert res.comm.messages_dropped > 0
    m = res.series.estimable
    assert not m[0, :, -1].any() and m[-1].all()  # the BLUP start phase is covered
    np.testing.assert_allclose(res.local_std[m], res.series.std[m], rtol=1e-8)
    assert np.isnan(res.local_std[~m]).all()
    assert res.precision is not None and res.precision.kind == "exact"
    np.testing.assert_allclose(res.precision.covariance, res.series.covariance[-1], rtol=1e-8, atol=1e-12)
    # the estimates do not depend on the precision bookkeeping
    plain = ckf(dyn, ms, graph=g, rounds=3, exchange=make_exchange(g, faults=ex.faults))
    np.testing.assert_allclose(
        np.nan_to_num(res.series.estimates), np.nan_to_num(plain.series.estimates), rtol=1e-12, atol=1e-12
    )


def test_local_precision_costs_bytes_not_messages():
    dyn, epochs, _ = raw_data(2, T=4)
    ms = series_of(epochs, 4)
    n, p, kn = ms.n_nodes, ms.n_states, 3
    g = builders.ring(n)
    plain = ckf(dyn, ms, graph=g, rounds=kn)
    n_tri = p * (p + 1) // 2
    msgs = ms.n_epochs * kn * 2 * g.n_links
    for kind, extra in (("exact", n * (n_tri + 1)), ("bound", n)):
        r = ckf(dyn, ms, graph=g, rounds=kn, local_precision=kind)
        assert r.comm.messages == plain.comm.messages == msgs
        assert r.comm.bytes == msgs * (n_tri + p + extra) * 8
        assert r.precision is not None and r.precision.comm is not None
        assert r.precision.comm.bytes == msgs * extra * 8 and r.precision.comm.messages == 0


def test_bound_is_never_optimistic_and_is_a_bound_not_the_value():
    dyn, epochs, _ = raw_data(3, T=12)
    ms = series_of(epochs, 4)
    for g, kn in ((builders.path(ms.n_nodes), 2), (builders.ring(ms.n_nodes), 6)):
        res = ckf(dyn, ms, graph=g, rounds=kn, local_precision="bound")
        m = res.series.estimable
        ratio = res.local_std[m] / res.series.std[m]
        assert ratio.min() >= 1 - 1e-9
        assert ratio.max() > 1.01  # it is an upper bound, not the exact value
    with pytest.raises(ModelError, match="local_precision must be"):
        ckf(dyn, ms, graph=g, rounds=1, local_precision="approximate")  # type: ignore[arg-type]


def test_local_precision_against_monte_carlo():
    """Empirical error variances of the actual CKF (600 runs) against the node-local ones.

    Per (node, entry) at the last epoch, R·s²/σ² is χ²_R under "σ² is the error variance": for the exact form
    every ratio must lie inside the two-sided 1e-4 quantiles (Bonferroni over the 24 checks: family-wise
    false-alarm < 3e-3); for the bound only the upper side is required (s² ≤ σ²_bound up to sampling).
    """
    n, p, T, R, kn = 6, 4, 8, 600, 2
    dyn, epochs, _ = raw_data(4, n=n, p=p, T=T)
    g = builders.path(n)
    sched = consensus_schedule(g, "P3")
    ref_ms = series_of(epochs, p)
    exact = ckf(dyn, ref_ms, schedule=sched, rounds=kn, local_precision="exact", monitor=False)
    bound = ckf(dyn, ref_ms, schedule=sched, rounds=kn, local_precision="bound", monitor=False)
    rng = np.random.default_rng(99)
    err = np.empty((R, n, p))
    for k in range(R):
        x = simulate_states(dyn, T, rng=rng, initial_state=rng.standard_normal(p) * 3)
        eps = [
            [(A, var, A @ x[t] + np.sqrt(var) * rng.standard_normal(var.size)) for (A, var, _y) in row]
            for t, row in enumerate(epochs)
        ]
        *_, last = iterate_ckf(dyn, series_of(eps, p), rounds=kn, schedule=sched, variance=False, monitor=False)
        err[k] = x[T - 1] - last.estimates
    s2 = (err**2).mean(axis=0)
    lo, hi = stats.chi2.ppf([1e-4 / 2, 1 - 1e-4 / 2], R) / R
    r_exact = s2 / exact.local_std[-1] ** 2
    assert np.all((r_exact > lo) & (r_exact < hi)), r_exact
    r_bound = s2 / bound.local_std[-1] ** 2
    assert np.all(r_bound < hi), r_bound


def test_perth_exact_local_precision_meets_the_target():
    """Issue 12 target: within 1.2× of Fig. 7 for k_n ≥ 6 on the Perth network, never optimistic (exact: 1×)."""
    from distnav.experiments.ckf_ionosphere import perth_network, perth_scenario

    _geo, _layout, series, dyn = perth_scenario(40)
    g = perth_network()
    for kn in (6, 12):
        res = ckf(dyn, series, graph=g, protocol="P3", rounds=kn, local_precision="exact", monitor=False)
        m = res.series.estimable
        ratio = res.local_std[m] / res.series.std[m]
        assert ratio.max() <= 1.2 and ratio.min() >= 1 - 1e-6, (ratio.min(), ratio.max())


# ----------------------------------------------------------------------------------------------- innovation tests
def test_gross_error_rejected_by_its_node_and_estimate_stays_clean():
    dyn, epochs, _ = raw_data(5, T=10)
    p, node, epoch, row = 4, 2, 6, 1
    g = builders.ring(6)
    kw = dict(graph=g, rounds=4, local_precision="exact", test_level=0.001)
    clean = ckf(dyn, series_of(epochs, p), **kw)
    assert clean.tests is not None and clean.tests.n_removed == 0  # no false alarm in this seeded run
    A, var, y = epochs[epoch][node]
    bad = [list(r) for r in epochs]
    y_bad = y.copy()
    y_bad[row] += 40.0 * np.sqrt(var[row])  # a 40σ gross error
    bad[epoch][node] = (A, var, y_bad)
    res = ckf(dyn, series_of(bad, p), **kw)
    t = res.tests
    assert t is not None and t.n_removed == 1
    j = t.removed[0]
    assert (t.epoch[j], t.node[j], t.row[j]) == (epoch, node, row)
    assert abs(t.w[j]) > t.critical_value and t.flagged[j]
    assert t.chi2_flagged[epoch, node]
    # reference: the same data with that observation deleted by hand, no tests
    keep = np.arange(len(y)) != row
    deleted = [list(r) for r in epochs]
    deleted[epoch][node] = (A[keep], var[keep], y[keep])
    ref = ckf(dyn, series_of(deleted, p), graph=g, rounds=4)
    np.testing.assert_allclose(res.estimates, ref.estimates, rtol=1e-12, atol=1e-12)
    # without the tests the gross error spreads through the consensus to every node
    naive = ckf(dyn, series_of(bad, p), graph=g, rounds=4)
    dev_naive = np.abs(naive.estimates - clean.estimates).max()
    dev_tested = np.abs(res.estimates - clean.estimates).max()
    assert dev_naive > 10 * dev_tested, (dev_naive, dev_tested)


def test_tests_need_local_precision_and_a_valid_level():
    dyn, epochs, _ = raw_data(6, T=3)
    ms = series_of(epochs, 4)
    g = builders.ring(6)
    with pytest.raises(ModelError, match="need the node-local precision"):
        ckf(dyn, ms, graph=g, rounds=2, test_level=0.01)
    with pytest.raises(ModelError, match="test level"):
        ckf(dyn, ms, graph=g, rounds=2, local_precision="exact", test_level=1.5)
    N = np.stack([ms.normals(t)[0] for t in range(ms.n_epochs)])
    with pytest.raises(ModelError, match="need the raw observations; NormalSeries"):
        ckf(dyn, NormalSeries(N), graph=g, rounds=2, local_precision="exact", test_level=0.01)


@pytest.mark.parametrize("kind", ["exact", "bound"])
def test_false_alarm_rate_matches_the_level(kind):
    """Clean data, level 2 %: the first-test w statistics flag a fraction of the tested observations that matches
    the level (exact precision: two-sided binomial 1e-4 interval) or stays below it (bound: conservative)."""
    level, R = 0.02, 60
    dyn, epochs, _ = raw_data(7, T=12, late_until=0)
    g = builders.ring(6)
    rng = np.random.default_rng(7)
    flagged = tested = 0
    chi_flag = chi_n = 0
    for _ in range(R):
        x = simulate_states(dyn, len(epochs), rng=rng, initial_state=rng.standard_normal(4))
        eps = [
            [(A, var, A @ x[t] + np.sqrt(var) * rng.standard_normal(var.size)) for (A, var, _y) in row]
            for t, row in enumerate(epochs)
        ]
        res = ckf(dyn, series_of(eps, 4), graph=g, rounds=4, local_precision=kind, test_level=level, monitor=False)
        assert res.tests is not None
        flagged += int(res.tests.flagged.sum())
        tested += res.tests.w.size
        ok = res.tests.chi2_dof > 0
        chi_flag += int(res.tests.chi2_flagged[ok].sum())
        chi_n += int(ok.sum())
    assert tested == R * 11 * 6 * 3  # every observation after epoch 0 is tested
    lo, hi = stats.binom.ppf([5e-5, 1 - 5e-5], tested, level)
    clo, chi = stats.binom.ppf([5e-5, 1 - 5e-5], chi_n, level)
    if kind == "exact":
        assert lo <= flagged <= hi, (flagged, tested)
        assert clo <= chi_flag <= chi, (chi_flag, chi_n)
    else:
        assert flagged <= hi and chi_flag <= chi
