"""Consensus weights (paper 003 Table 1, paper 002 eq. (12)), average consensus, product matrix, measures."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from distnav.algorithms.consensus.averaging import (
    ConsensusWarning,
    average_consensus,
    consensus_probability,
    consensus_product,
    consensus_schedule,
    iterate_average_consensus,
)
from distnav.errors import WeightsError
from distnav.network import (
    ConsensusWeights,
    Graph,
    SwitchingGraph,
    builders,
    check_weights,
    consensus_weights,
)


@st.composite
def random_graphs(draw, connected: bool | None = True):
    n = draw(st.integers(2, 12))
    pairs = [(i, j) for i in range(n) for j in range(i + 1, n)]
    chosen = draw(st.lists(st.sampled_from(pairs), unique=True, max_size=len(pairs)))
    if connected:
        chosen = sorted(set(chosen) | {(i, i + 1) for i in range(n - 1)})
    return Graph.from_links(n, chosen)


@settings(max_examples=60, deadline=None)
@given(random_graphs(), st.sampled_from(["P1", "P2", "P3", "MH", "Koppanyi"]))
def test_weights_doubly_stochastic_and_respect_graph(g, protocol):
    w = consensus_weights(g, protocol)
    dense = w.to_dense()
    assert np.allclose(dense.sum(axis=0), 1) and np.allclose(dense.sum(axis=1), 1)
    assert (dense >= -1e-15).all()
    adj = g.adjacency().toarray() + np.eye(g.n_nodes)
    assert np.all(dense[adj == 0] == 0)
    assert np.allclose(dense, dense.T)
    rep = check_weights(w)
    assert rep.ok and rep.row_stochastic and rep.column_stochastic and rep.symmetric


@settings(max_examples=60, deadline=None)
@given(random_graphs(connected=None), st.sampled_from(["P2", "P3", "MH", "Koppanyi"]))
def test_slem_below_one_iff_connected(g, protocol):
    # positive self-weights for P2/P3/MH everywhere; Koppanyi can have zero self-weight, so use the spectrum
    w = consensus_weights(g, protocol)
    slem = np.sort(np.abs(np.linalg.eigvals(w.to_dense())))[-2] if g.n_nodes > 1 else 0.0
    if protocol in {"P2", "P3", "MH"}:
        assert (slem < 1 - 1e-9) == g.is_connected
    elif not g.is_connected:
        assert slem > 1 - 1e-9


@settings(max_examples=40, deadline=None)
@given(random_graphs(), st.sampled_from(["P1", "P2", "P3"]), st.integers(0, 25), st.integers(0, 2**31))
def test_consensus_preserves_average(g, protocol, rounds, seed):
    warnings.simplefilter("ignore", ConsensusWarning)  # P1 on a 2-node graph oscillates but keeps the mean
    vals = np.random.default_rng(seed).normal(size=(g.n_nodes, 3))
    res = average_consensus(vals, graph=g, protocol=protocol, rounds=rounds)
    assert np.allclose(res.estimates.mean(axis=0), vals.mean(axis=0), atol=1e-12)
    assert np.array_equal(res.average, vals.mean(axis=0))  # typed field: the reference the trace measures against


def test_table1_values_on_hand_graph():
    # path 0-1-2-3 plus link 1-3: degrees 1, 3, 2, 2
    g = Graph.from_links(4, [(0, 1), (1, 2), (2, 3), (1, 3)])
    p1 = consensus_weights(g, "P1").to_dense()
    assert p1[0, 1] == pytest.approx(1 / 3) and p1[1, 1] == pytest.approx(0.0) and p1[0, 0] == pytest.approx(2 / 3)
    p2 = consensus_weights(g, 2).to_dense()
    assert p2[2, 3] == pytest.approx(1 / 4) and p2[1, 1] == pytest.approx(1 / 4)
    p3 = consensus_weights(g, "P3").to_dense()
    assert p3[0, 1] == pytest.approx(1 / 4)  # 1/(1+max(1,3))
    assert p3[2, 3] == pytest.approx(1 / 3)  # 1/(1+max(2,2))
    assert p3[0, 0] == pytest.approx(3 / 4)
    kop = consensus_weights(g, "Koppanyi").to_dense()
    assert kop[0, 1] == pytest.approx(1 / 3)  # min(1/1, 1/3)
    assert kop[0, 0] == pytest.approx(2 / 3)  # max(0, 1/1 - 1/3)
    assert kop[1, 1] == pytest.approx(0.0)
    assert np.allclose(kop.sum(axis=1), 1)
    m = Graph.from_links(4, [(0, 1), (2, 3)])
    p4 = consensus_weights(m, "P4").to_dense()
    assert np.allclose(p4, np.kron(np.eye(2), np.full((2, 2), 0.5)))


def test_protocol1_zero_self_weight_reported_not_changed():
    g = Graph.from_links(4, [(0, 1), (1, 2), (2, 3), (1, 3)])
    w = consensus_weights(g, "P1")
    assert w.self_weight[1] == 0.0
    rep = check_weights(w)
    assert rep.guaranteed and not rep.positive_diagonal
    assert "self-weight is zero at node(s) 1" in rep.message and "still converges" in rep.message


def test_protocol1_on_regular_bipartite_not_guaranteed():
    # a 4-cycle is 2-regular bipartite: P1 gives every self-weight 0 and eigenvalue -1
    w = consensus_weights(builders.ring(4), "P1")
    rep = check_weights(w)
    assert rep.ok and not rep.guaranteed
    assert "NOT guaranteed" in rep.message
    with pytest.warns(ConsensusWarning, match="NOT guaranteed"):
        res = average_consensus(np.arange(4.0), graph=builders.ring(4), protocol="P1", rounds=11)
    assert np.allclose(res.estimates, [2, 1, 2, 1])  # odd rounds: oscillates between neighbours' means, never averages


def test_weight_validation_errors():
    g = builders.path(3)
    with pytest.raises(WeightsError, match="at most one neighbour"):
        consensus_weights(g, "P4")
    with pytest.raises(WeightsError, match="unknown consensus protocol"):
        consensus_weights(g, "P9")
    with pytest.raises(WeightsError, match="protocol must be 1, 2, 3 or 4"):
        from distnav.network.weights import protocol_weights

        protocol_weights(g, 7)
    bad = ConsensusWeights.from_matrix(g, np.array([[0.5, 0.6, 0], [0.6, 0.4, 0], [0, 0, 1.0]]))
    rep = check_weights(bad)
    assert not rep.ok and "row 0 sums to 1.1" in rep.message
    with pytest.raises(WeightsError, match="row 0 sums"):
        check_weights(bad, raise_on_error=True)
    neg = ConsensusWeights.from_matrix(g, np.array([[1.2, -0.2, 0], [-0.2, 1.0, 0.2], [0, 0.2, 0.8]]))
    assert "negative" in check_weights(neg).message
    with pytest.raises(WeightsError, match=r"W\[0, 2\].*not linked"):
        ConsensusWeights.from_matrix(g, np.array([[0.5, 0.25, 0.25], [0.25, 0.75, 0], [0.25, 0, 0.75]]))
    with pytest.raises(WeightsError, match="3×3"):
        ConsensusWeights.from_matrix(g, np.eye(2))
    with pytest.raises(WeightsError, match="edge_weight must have shape"):
        ConsensusWeights(g, np.zeros(3), np.ones(3))
    with pytest.raises(WeightsError, match="finite"):
        ConsensusWeights(g, np.full(4, np.nan), np.ones(3))
    disconnected = Graph.from_links(3, [(0, 1)])
    assert "not connected" in check_weights(consensus_weights(disconnected, "P3")).message
    nonsym = ConsensusWeights.from_matrix(g, np.array([[0.5, 0.5, 0], [0.25, 0.5, 0.25], [0, 0.25, 0.75]]))
    assert "column 0 sums" in check_weights(nonsym).message


def test_consensus_input_errors():
    g = builders.ring(5)
    with pytest.raises(WeightsError, match="one row per node"):
        average_consensus(np.zeros(4), graph=g, rounds=3)
    with pytest.raises(WeightsError, match="not finite"):
        average_consensus(np.array([0, 1, np.inf, 0, 0.0]), graph=g, rounds=3)
    with pytest.raises(WeightsError, match="rounds must be"):
        list(iterate_average_consensus(np.zeros(5), graph=g, rounds=-1))
    with pytest.raises(WeightsError, match="2 weight matrices for 1 sessions"):
        consensus_schedule(g, [consensus_weights(g, "P3")] * 2)


def test_consensus_on_matrices_equals_dense_product():
    g = builders.connected_random_geometric(15, mean_degree=4, rng=np.random.default_rng(4))
    mats = np.random.default_rng(5).normal(size=(15, 3, 3))
    res = average_consensus(mats, graph=g, protocol="P3", rounds=7)
    L = consensus_product(consensus_schedule(g, "P3"), 7)
    assert np.allclose(res.estimates, np.einsum("ij,jkl->ikl", L, mats), atol=1e-13)


def test_switching_graph_protocol4_converges_and_product_matches():
    sessions = (
        Graph.from_links(6, [(0, 1), (2, 3), (4, 5)]),
        Graph.from_links(6, [(1, 2), (3, 4)]),
        Graph.from_links(6, [(5, 0)]),
    )
    sw = SwitchingGraph(sessions)
    vals = np.arange(6.0)
    res = average_consensus(vals, graph=sw, protocol="P4", rounds=120)
    assert np.allclose(res.estimates, 2.5, atol=1e-8)
    sched = consensus_schedule(sw, "P4")
    L = consensus_product(sched, 5)
    res5 = average_consensus(vals, graph=sw, protocol="P4", rounds=5)
    assert np.allclose(res5.estimates, L @ vals, atol=1e-13)
    # only the active session's links carry messages: 6+4+2 directed messages per cycle of 3 rounds
    assert res5.comm.messages_per_round.tolist() == [6, 4, 2, 6, 4]


def test_probability_measure_closed_form_on_complete_graph():
    # P2 on a complete graph averages exactly in one round: deviation 0, probability 1 for every q ≥ 0
    g = builders.complete(8)
    L = consensus_product(consensus_schedule(g, "P2"), 1)
    p = consensus_probability(L, [0.0, 0.1], samples=1000, rng=np.random.default_rng(0))
    assert np.allclose(p, 1.0)


def test_probability_measure_against_independent_reference():
    # With L = I (no consensus), r_i - r̄ = (I - J) r; check P(max|.| <= q) against a plain loop estimate
    n = 5
    rng = np.random.default_rng(7)
    q = np.array([0.5, 1.0, 2.0])
    p = consensus_probability(np.eye(n), q, samples=40_000, rng=np.random.default_rng(8))
    r = rng.standard_normal((40_000, n))
    dev = np.abs(r - r.mean(axis=1, keepdims=True)).max(axis=1)
    ref = np.array([(dev <= qq).mean() for qq in q])
    assert np.allclose(p, ref, atol=0.012)  # two independent 40k-sample estimates: 3σ ≈ 0.011


def test_slem_of_paper_like_networks_ordering():
    # P3 (Metropolis) ≤ P1 ≤ P2 is typical; we only assert P2 is the slowest as the paper found
    g = builders.connected_random_geometric(20, mean_degree=4.9, rng=np.random.default_rng(11))
    s = {p: consensus_weights(g, p).slem for p in ("P1", "P2", "P3")}
    assert s["P2"] > s["P1"] and s["P2"] > s["P3"]
