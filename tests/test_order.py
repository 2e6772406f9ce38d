"""Results in the user's order at every size (issue 30 item 4).

From ``LOCALITY_MIN_NODES`` (10⁴) nodes on, ``order="auto"`` renumbers the exchange's nodes (RCM). That order is
internal: the front doors (``average_consensus``, ``admm``, ``ckf``) use it and gather their results back into the
user's order, and an exchange made by the user (``make_exchange(graph)``) keeps the user's order unless it opts in.
Each case runs at n = 9,999 and 10,000 and is compared row by row with a reference computed in the user's order
(``order="none"``) and, where one exists, with an independent scipy product.
"""

from __future__ import annotations

import numpy as np
import pytest

from distnav.algorithms.consensus.averaging import average_consensus, iterate_average_consensus
from distnav.exchange import make_exchange
from distnav.network import builders, consensus_weights
from distnav.network.graph import Graph
from distnav.network.partition import LOCALITY_MIN_NODES

SIZES = (LOCALITY_MIN_NODES - 1, LOCALITY_MIN_NODES)
_GRAPHS: dict[int, Graph] = {}


def _graph(n: int) -> Graph:
    if n not in _GRAPHS:  # a connected random geometric graph numbered as the builder gives it (random order)
        _GRAPHS[n] = builders.connected_random_geometric(n, mean_degree=16, rng=np.random.default_rng(n))
    return _GRAPHS[n]


def test_the_threshold_is_crossed():
    """The sizes straddle the renumbering: the same call keeps the user's ids at 9,999 and reorders at 10,000."""
    below, at = (make_exchange(_graph(n), order="auto") for n in SIZES)
    assert np.array_equal(below.nodes, np.arange(SIZES[0]))
    assert not np.array_equal(at.nodes, np.arange(SIZES[1]))
    for n in SIZES:  # the default exchange never renumbers
        assert np.array_equal(make_exchange(_graph(n)).nodes, np.arange(n))


@pytest.mark.parametrize("n", SIZES)
def test_mixer_apply_on_users_rows(n):
    """``make_exchange(graph).mixer(w).apply(x)`` on an array in the user's order is ``W x`` (scipy) at both sizes;
    with the opt-in order, ``ex.local``/``ex.gather_nodes`` convert at the boundary and give the same bits."""
    g = _graph(n)
    w = consensus_weights(g, "P3")
    x = np.random.default_rng(1).normal(size=(n, 3))
    reference = w.to_sparse().tocsr() @ x  # independent: scipy's own product in the user's order
    plain = make_exchange(g).mixer(w).apply(x)
    np.testing.assert_allclose(plain, reference, rtol=1e-13, atol=1e-15)
    ex = make_exchange(g, order="auto")
    opted = ex.gather_nodes(ex.mixer(w).apply(ex.local(x)))
    assert np.array_equal(opted, plain)  # row by row, bit for bit
    forced_off = make_exchange(g, order="none").mixer(w).apply(x)
    assert np.array_equal(forced_off, plain)


@pytest.mark.parametrize("n", SIZES)
def test_average_consensus_rows(n):
    g = _graph(n)
    x = np.random.default_rng(2).normal(size=(n, 2))
    rounds = 4
    res = average_consensus(x, graph=g, rounds=rounds)  # its own exchange: locality order inside from 10⁴
    ref = average_consensus(x, graph=g, rounds=rounds, exchange=make_exchange(g, order="none"))
    assert np.array_equal(res.estimates, ref.estimates)
    assert np.array_equal(res.comm.messages_sent, ref.comm.messages_sent)
    w = consensus_weights(g, "P3").to_sparse().tocsr()
    expect = x.copy()
    for _ in range(rounds):
        expect = w @ expect
    np.testing.assert_allclose(res.estimates, expect, rtol=1e-12, atol=1e-14)
    # the iterator on its own exchange hands out rows in the user's order too
    *_, last = iterate_average_consensus(x, graph=g, rounds=rounds)
    assert np.array_equal(last.values, ref.estimates)


def _linear_problem(n: int):
    from distnav.algorithms.lsq.blue import LinearProblem

    rng = np.random.default_rng(21)
    A = rng.normal(size=(n, 2, 3))  # 2 observations of 3 parameters: every node singular alone
    truth = rng.normal(size=3)
    y = np.einsum("nmp,p->nm", A, truth) + 0.1 * rng.normal(size=(n, 2))
    return LinearProblem.from_blocks(list(A), list(y), [0.01 * np.eye(2)] * n)


@pytest.mark.parametrize("n", SIZES)
def test_admm_per_node_estimates(n):
    from distnav.algorithms.lsq.admm import admm, iterate_admm

    g = _graph(n)
    problem = _linear_problem(n)
    opts = {"constraint_nodes": "min_cover", "W": 1.0, "max_iterations": 6, "tol": 0.0}
    res = admm(problem, g, **opts)
    ref = admm(problem, g, exchange=make_exchange(g, order="none"), **opts)
    assert np.array_equal(res.estimates, ref.estimates)
    assert np.array_equal(res.comm.bytes_sent, ref.comm.bytes_sent)
    # a node's estimate depends on its own data: rows swapped would differ (no test that cannot fail)
    assert not np.array_equal(ref.estimates, ref.estimates[::-1])
    gen = iterate_admm(problem, g, constraint_nodes="min_cover", W=1.0)
    for _ in range(7):  # states 0..6
        state = next(gen)
    assert np.array_equal(state.x, ref.estimates)


@pytest.mark.parametrize("n", SIZES)
def test_ckf_rows(n):
    from distnav.algorithms.kalman import DynamicModel, NormalSeries
    from distnav.algorithms.kalman.ckf import ckf, iterate_ckf

    g = _graph(n)
    p, epochs = 2, 3
    rng = np.random.default_rng(6)
    A = rng.normal(size=(epochs, n, 2, p))
    y = rng.normal(size=(epochs, n, 2))
    normals = NormalSeries(np.einsum("tnmp,tnmq->tnpq", A, A), np.einsum("tnmp,tnm->tnp", A, y))
    dyn = DynamicModel(p, noise_cov=np.diag([0.1, 0.05]))
    kw = {"graph": g, "protocol": "P3", "rounds": 3, "variance": False}
    res = ckf(dyn, normals, **kw)
    ref = ckf(dyn, normals, exchange=make_exchange(g, order="none"), **kw)
    assert np.array_equal(res.estimates, ref.estimates)
    assert np.array_equal(res.information, ref.information)
    assert np.array_equal(res.series.nominal_std, ref.series.nominal_std)
    *_, last = iterate_ckf(dyn, normals, **kw)
    assert np.array_equal(last.estimates, ref.estimates)


def test_boundary_conversions_round_trip_and_name_bad_shapes():
    from distnav.errors import ExchangeError

    g = _graph(SIZES[1])
    ex = make_exchange(g, order="auto")
    x = np.arange(g.n_nodes * 2, dtype=float).reshape(-1, 2)
    local = ex.local(x)
    assert np.array_equal(local[:, 0] // 2, ex.nodes)  # row k of the local array is node ex.nodes[k]
    assert np.array_equal(ex.gather_nodes(local), x)
    with pytest.raises(ExchangeError, match="10000 rows"):
        ex.local(x[:-1])
    with pytest.raises(ExchangeError, match="10000 rows"):
        ex.gather_nodes(local[:-1])
    with pytest.raises(ExchangeError, match="10000 rows"):
        ex.local(np.float64(1.0))
