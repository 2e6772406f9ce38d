"""In-process exchange: message rounds, accounting by hand, fault injection reproducible by seed."""

from __future__ import annotations

import numpy as np
import pytest

from distnav.errors import ExchangeError
from distnav.exchange import FaultSchedule, make_exchange
from distnav.exchange.faults import uniform_hash
from distnav.network import Graph, builders, consensus_weights


def star4() -> Graph:
    # node 0 is the hub of 1, 2, 3
    return builders.star(4)


def test_broadcast_delivers_sender_values_and_sums():
    g = star4()
    ex = make_exchange(g)
    inbox = ex.broadcast(np.array([10.0, 1.0, 2.0, 3.0]))
    assert inbox.delivered.all()
    assert np.array_equal(inbox.values, np.array([10.0, 1.0, 2.0, 3.0])[g.src])
    assert inbox.sum().tolist() == [6.0, 10.0, 10.0, 10.0]
    assert inbox.count().tolist() == [3, 1, 1, 1]
    w = np.arange(g.n_edges, dtype=float)
    assert np.allclose(inbox.sum(w), np.bincount(g.dst, weights=w * inbox.values, minlength=4))


def test_accounting_by_hand_on_star():
    g = star4()
    ex = make_exchange(g)
    ex.broadcast(np.zeros((4, 3)))  # 3 floats = 24 bytes per message
    ex.send(np.ones((g.n_edges, 2), dtype=np.float32))  # 8 bytes per message
    tot = ex.comm_totals()
    assert tot.rounds == 2
    # hub sends 3 messages per round, each leaf 1
    assert tot.messages_sent.tolist() == [6, 2, 2, 2]
    assert tot.bytes_sent.tolist() == [3 * 24 + 3 * 8, 24 + 8, 24 + 8, 24 + 8]
    assert tot.messages_received.tolist() == [6, 2, 2, 2]
    assert tot.messages_per_round.tolist() == [6, 6]
    assert tot.bytes_per_round.tolist() == [6 * 24, 6 * 8]
    assert tot.as_dict()["messages"] == 12 and tot.messages_dropped == 0


def test_active_mask_counts_only_active_edges():
    g = builders.path(3)
    ex = make_exchange(g)
    active = np.zeros(g.n_edges, bool)
    active[g.edge_index(0, 1)] = True  # only 0 → 1
    inbox = ex.broadcast(np.array([5.0, 6.0, 7.0]), active=active)
    assert inbox.delivered.sum() == 1
    assert inbox.sum().tolist() == [0.0, 5.0, 0.0]
    assert ex.comm_totals().messages_sent.tolist() == [1, 0, 0]
    with pytest.raises(ExchangeError, match="mask over the 4 directed edges"):
        ex.broadcast(np.zeros(3), active=np.ones(3, bool))


def test_dropped_message_is_visible_not_silent_zero():
    g = builders.complete(6)
    ex = make_exchange(g, faults=FaultSchedule(drop_probability=0.5, seed=3))
    inbox = ex.broadcast(np.ones(6))
    assert 0 < inbox.delivered.sum() < g.n_edges
    assert np.all(inbox.values[~inbox.delivered] == 0)
    assert np.array_equal(inbox.sum(), inbox.count().astype(float))
    tot = ex.comm_totals()
    assert tot.messages == g.n_edges  # drops are sent but not received
    assert tot.messages_received.sum() == inbox.delivered.sum()
    assert tot.messages_dropped == g.n_edges - inbox.delivered.sum()


def test_faults_reproducible_by_seed_and_differ_between_seeds():
    g = builders.connected_random_geometric(50, mean_degree=6, rng=np.random.default_rng(0))

    def masks(seed: int) -> np.ndarray:
        ex = make_exchange(g, faults=FaultSchedule(drop_probability=0.3, seed=seed))
        return np.stack([ex.broadcast(np.zeros(50)).delivered for _ in range(5)])

    a, b, c = masks(1), masks(1), masks(2)
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)
    assert not np.array_equal(a[0], a[1])  # a fresh draw every round
    assert abs(1 - a.mean() - 0.3) < 0.05


def test_uniform_hash_is_uniform_and_subset_consistent():
    u = uniform_hash(7, 3, np.arange(100_000))
    assert abs(u.mean() - 0.5) < 0.01 and u.min() >= 0 and u.max() < 1
    sub = np.array([5, 99, 12345])
    assert np.array_equal(uniform_hash(7, 3, sub), u[sub])


def test_failed_link_and_silent_node():
    g = builders.path(4)
    faults = FaultSchedule(failed_links=((1, 2, 1),), silent_nodes=((3, 2),))
    ex = make_exchange(g, faults=faults)
    r0 = ex.broadcast(np.arange(4.0))
    assert r0.delivered.all()
    r1 = ex.broadcast(np.arange(4.0))
    cut = np.isin(np.arange(g.n_edges), g.edge_index([1, 2], [2, 1]))
    assert np.array_equal(r1.delivered, ~cut)
    r2 = ex.broadcast(np.arange(4.0))
    from3 = g.src == 3
    assert np.array_equal(r2.delivered, ~cut & ~from3)
    tot = ex.comm_totals()
    assert tot.messages_sent.tolist() == [3, 6, 6, 2]  # node 3 silent in round 2 sends nothing


def test_mixer_with_drops_moves_lost_weight_to_self():
    g = builders.ring(6)
    w = consensus_weights(g, "P3")
    ex = make_exchange(g, faults=FaultSchedule(drop_probability=0.4, seed=5))
    x = np.random.default_rng(1).normal(size=(6, 2))
    got = ex.mixer(w).apply(x)
    # recompute the same round by hand from the same seeded drop pattern
    ok = FaultSchedule(drop_probability=0.4, seed=5).delivered(0, g.src, g.dst, np.arange(g.n_edges))
    dense = w.to_dense()
    ref = np.empty_like(x)
    for i in range(6):
        acc = dense[i, i] * x[i]
        for e in np.flatnonzero(g.dst == i):
            j = g.src[e]
            acc = acc + dense[i, j] * (x[j] if ok[e] else x[i])
        ref[i] = acc
    assert np.allclose(got, ref, atol=1e-14)
    # rows still sum to one: a constant stays constant under drops
    assert np.allclose(ex.mixer(w).apply(np.full((6, 1), 3.0)), 3.0)


def test_mixer_fault_free_equals_dense_product():
    g = builders.connected_random_geometric(40, mean_degree=6, rng=np.random.default_rng(2))
    w = consensus_weights(g, "MH")
    ex = make_exchange(g)
    x = np.random.default_rng(3).normal(size=(40, 2, 2))
    assert np.allclose(ex.mixer(w).apply(x), np.einsum("ij,jkl->ikl", w.to_dense(), x), atol=1e-14)


def test_exchange_input_errors():
    g = builders.path(3)
    ex = make_exchange(g)
    with pytest.raises(ExchangeError, match="broadcast needs 3 local rows"):
        ex.broadcast(np.zeros(4))
    with pytest.raises(ExchangeError, match="one row per outgoing edge"):
        ex.send(np.zeros(3))
    with pytest.raises(ExchangeError, match="mixer needs 3 local rows"):
        ex.mixer(consensus_weights(g, "P3")).apply(np.zeros(2))
    with pytest.raises(ExchangeError, match="different graph"):
        ex.mixer(consensus_weights(builders.path(4), "P3"))
    with pytest.raises(ExchangeError, match="per-node array with 3 rows"):
        ex.local(np.zeros(5))
    with pytest.raises(ValueError, match="unknown exchange backend"):
        make_exchange(g, backend="carrier-pigeon")


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"drop_probability": 1.0}, r"drop_probability must be in \[0, 1\)"),
        ({"drop_probability": -0.1}, "drop_probability"),
        ({"failed_links": ((0, 1),)}, "must be"),
        ({"silent_nodes": ((0, -1),)}, "must be"),
    ],
)
def test_fault_schedule_validation(kwargs, match):
    with pytest.raises(ExchangeError, match=match):
        FaultSchedule(**kwargs)


def test_fault_schedule_checked_against_graph():
    g = builders.path(3)
    with pytest.raises(ExchangeError, match=r"failed link \(0, 2\) is not a link"):
        make_exchange(g, faults=FaultSchedule(failed_links=((0, 2, 0),)))
    with pytest.raises(ExchangeError, match="silent node 7 is outside"):
        make_exchange(g, faults=FaultSchedule(silent_nodes=((7, 0),)))
    with pytest.raises(ExchangeError, match="names a node outside"):
        make_exchange(g, faults=FaultSchedule(failed_links=((0, 9, 0),)))


def test_reset_accounting_restarts_fault_rounds():
    g = builders.complete(5)
    ex = make_exchange(g, faults=FaultSchedule(drop_probability=0.5, seed=9))
    first = ex.broadcast(np.zeros(5)).delivered
    ex.reset_accounting()
    assert ex.comm_totals().rounds == 0
    assert np.array_equal(ex.broadcast(np.zeros(5)).delivered, first)


def test_graph_without_links_rounds_are_empty_not_errors():
    from distnav.network import Graph

    g = Graph.from_links(1, [])
    ex = make_exchange(g)
    inbox = ex.send(np.zeros((0, 3)))
    assert inbox.values.shape == (0, 3) and inbox.sum().shape == (1, 3)
    assert ex.broadcast(np.ones((1, 2))).sum().tolist() == [[0.0, 0.0]]
    assert ex.comm_totals().messages == 0


@pytest.mark.parametrize(
    "name",
    [
        "consensus_with_faults",
        "raw_send_and_broadcast",
        "admm_constraint_nodes",
        "admm_with_drops",
        "ncsg_tbls_with_drops",
    ],
)
def test_locality_order_changes_no_result(name):
    """Renumbering the exchange's nodes (RCM) is invisible: node results bit for bit, results in the user's ids."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parent / "mpi"))
    from cases import CASES

    plain, ordered = CASES[name]("inprocess"), CASES[f"{name}_rcm"]("inprocess")
    assert plain.keys() == ordered.keys()
    for key, value in plain.items():
        if key in {"primal", "trace", "cost"}:  # network-wide sums, added in another order
            np.testing.assert_allclose(ordered[key], value, rtol=1e-12, atol=1e-14, err_msg=key)
        else:
            assert np.array_equal(ordered[key], value), f"{name}/{key}"


def test_locality_order_is_a_renumbering():
    from distnav.exchange import InProcessExchange
    from distnav.network.partition import locality_order, rcm_order, space_filling_order

    g = builders.connected_random_geometric(300, mean_degree=10, rng=np.random.default_rng(4))
    ex = InProcessExchange(g, order="rcm")
    assert np.array_equal(ex.nodes, rcm_order(g)) and not np.array_equal(ex.nodes, np.arange(300))
    assert np.array_equal(np.sort(ex.in_edges), np.arange(g.n_edges))
    assert np.array_equal(ex.nodes[ex.in_dst], g.dst[ex.in_edges]) and np.array_equal(ex.in_src, g.src[ex.in_edges])
    assert np.all(np.diff(ex.in_dst) >= 0)
    x = np.arange(300.0)
    assert np.array_equal(ex.gather_nodes(ex.local(x)), x)
    # RCM shrinks the bandwidth of the local adjacency: neighbours sit near each other in memory
    assert np.abs(ex.in_dst - ex.in_src_col).max() < 0.3 * np.abs(g.dst - g.src).max()
    assert locality_order(g, "auto") is None  # small graphs keep the user's ids
    hil = space_filling_order(g.positions)
    assert np.array_equal(np.sort(hil), np.arange(300))
    with pytest.raises(ExchangeError, match="permutation"):
        InProcessExchange(g, order=np.zeros(300, int))
    with pytest.raises(ExchangeError, match="unknown node order"):
        InProcessExchange(g, order="metis")
    with pytest.raises(ExchangeError, match="needs node positions"):
        InProcessExchange(builders.path(4), order="hilbert")


def test_fault_plan_drops_exactly_the_scheduled_messages():
    """The compiled plan (bulk hash, integer threshold, folded link/silent faults) equals FaultSchedule.delivered."""
    from distnav.exchange.faults import FaultPlan

    g = builders.random_geometric(2000, 0.04, rng=np.random.default_rng(0), self_loops=True)
    link = g.links[0]
    schedules = [
        FaultSchedule(drop_probability=0.1, seed=3),
        FaultSchedule(
            drop_probability=0.37,
            seed=2**63 + 5,
            failed_links=((int(link[0]), int(link[1]), 3),),
            silent_nodes=((5, 2), (7, 9)),
        ),
        FaultSchedule(failed_links=((int(g.links[3, 0]), int(g.links[3, 1]), 1),), silent_nodes=((5, 0),)),
    ]
    edges = np.random.default_rng(1).permutation(g.n_edges)[: g.n_edges // 2]  # any subset, any order
    for fs in schedules:
        plan = FaultPlan(fs, g.src[edges], g.dst[edges], edges)
        for k in [*range(150), 3, 1000, 2]:
            assert np.array_equal(plan.delivered(k), fs.delivered(k, g.src[edges], g.dst[edges], edges)), k


def test_drop_only_fault_plan_reads_no_endpoints_and_holds_no_per_edge_fault_arrays():
    """A drop-only plan given the self-loop mask never asks for senders or receivers (at 10⁶ nodes they are two
    64-bit edge arrays) and keeps the edge ids as given (no uint64 copy), yet drops what the schedule drops."""
    from distnav.exchange.faults import FaultPlan

    g = builders.random_geometric(1500, 0.05, rng=np.random.default_rng(4), self_loops=True)
    edges = np.arange(g.n_edges, dtype=np.int32)

    def unread() -> np.ndarray:
        raise AssertionError("a drop-only plan must not read the endpoints")

    fs = FaultSchedule(drop_probability=0.2, seed=9)
    plan = FaultPlan(fs, unread, unread, edges, is_self=g.src == g.dst)
    assert plan._dead_from is None and plan._edges is edges
    for k in (0, 1, 77, 5):
        assert np.array_equal(plan.delivered(k), fs.delivered(k, g.src, g.dst, edges)), k
    with pytest.raises(AssertionError, match="endpoints"):  # failed links do need them
        FaultPlan(
            FaultSchedule(failed_links=((int(g.links[0, 0]), int(g.links[0, 1]), 1),)),
            unread,
            unread,
            edges,
            is_self=g.src == g.dst,
        )


def test_fault_mixer_restores_its_weights_after_every_round():
    """Fault rounds zero the lost entries of the held edge matrix for one product only: the matrix holds the
    in-edge weights again afterwards, and a round equals the dense masked product (lost weight to the diagonal)."""
    g = builders.connected_random_geometric(80, mean_degree=6, rng=np.random.default_rng(3))
    w = consensus_weights(g, "MH")
    fs = FaultSchedule(drop_probability=0.3, seed=4)
    ex = make_exchange(g, faults=fs)
    mixer = ex.mixer(w)
    held = mixer._w_masked.data.copy()
    assert mixer._w_full is None  # the fault-free fused block is not built under faults
    x = np.random.default_rng(5).normal(size=80)
    for k in range(6):
        ok = fs.delivered(k, g.src, g.dst, np.arange(g.n_edges))
        dense = np.zeros((80, 80))
        np.add.at(dense, (g.dst[ok], g.src[ok]), w.edge_weight[ok])
        dense[np.arange(80), np.arange(80)] += 1.0 - dense.sum(axis=1)
        x_new = mixer.apply(x)
        assert np.allclose(x_new, dense @ x, rtol=1e-13, atol=1e-15), k
        assert np.array_equal(mixer._w_masked.data, held), k
        x = x_new


def test_mixer_fault_rounds_by_hand_with_every_kind_of_fault():
    g = builders.connected_random_geometric(50, mean_degree=6, rng=np.random.default_rng(7))
    w = consensus_weights(g, "MH")
    a, b = (int(v) for v in g.links[4])
    fs = FaultSchedule(drop_probability=0.25, failed_links=((a, b, 2),), silent_nodes=((9, 3),), seed=11)
    ex = make_exchange(g, faults=fs)
    mixer = ex.mixer(w)
    x = np.random.default_rng(8).normal(size=(50, 3))
    ref = x.copy()
    dense = w.to_dense()
    sent = np.zeros(50, int)
    recv = np.zeros(50, int)
    e_all = np.arange(g.n_edges)
    for k in range(12):
        x = mixer.apply(x)
        ok = fs.delivered(k, g.src, g.dst, e_all)
        new = np.empty_like(ref)
        for i in range(50):
            acc = dense[i, i] * ref[i]
            for e in np.flatnonzero(g.dst == i):
                acc = acc + dense[i, g.src[e]] * (ref[g.src[e]] if ok[e] else ref[i])
            new[i] = acc
        ref = new
        talking = ~((g.src == 9) & (k >= 3))
        np.add.at(sent, g.src[talking], 1)
        np.add.at(recv, g.dst[ok], 1)
    np.testing.assert_allclose(x, ref, rtol=1e-13, atol=1e-14)
    tot = ex.comm_totals()
    assert tot.messages_sent.tolist() == sent.tolist()
    assert tot.messages_received.tolist() == recv.tolist()
    assert tot.bytes_received.tolist() == (recv * 24).tolist()


@pytest.mark.parametrize("order", ["none", "rcm"])
def test_route_rounds_equal_masked_rounds(order):
    """A prepared route carries the same messages as broadcast/send with the same mask: same values on the route's
    rows (in the order asked for), same deliveries and dropped messages, same counts."""
    g = builders.connected_random_geometric(40, mean_degree=5, rng=np.random.default_rng(4))
    active = np.random.default_rng(5).random(g.n_edges) < 0.6
    faults = FaultSchedule(
        drop_probability=0.25, failed_links=((int(g.src[3]), int(g.dst[3]), 2),), silent_nodes=((7, 3),), seed=11
    )
    for fs in (None, faults):
        plain, prepared = (make_exchange(g, faults=fs, order=order) for _ in range(2))
        in_rows = np.flatnonzero(active[prepared.in_edges])[::-1].copy()  # any order of the active in-edges
        out_rows = np.random.default_rng(6).permutation(np.flatnonzero(active[prepared.out_edges]))
        bro = prepared.route(active, in_rows=in_rows)
        snd = prepared.route(active, out_rows=out_rows)
        for k in range(6):
            x = np.random.default_rng(k).normal(size=(g.n_nodes, 2))
            ib = plain.broadcast(plain.local(x), active=active)
            vb, okb = bro.broadcast(prepared.local(x))
            assert np.array_equal(okb, ib.delivered[in_rows]) and np.array_equal(vb, ib.values[in_rows])
            edge_vals = np.stack([g.src[plain.out_edges], plain.out_edges + 0.5 * k], axis=1)
            ie = plain.send(edge_vals, active=active)
            vs, oks = snd.send(edge_vals[out_rows])
            assert np.array_equal(oks, ie.delivered[snd.in_rows]) and np.array_equal(vs, ie.values[snd.in_rows])
            assert np.array_equal(snd.src, g.src[plain.in_edges[snd.in_rows]])
        if fs is not None:
            assert not okb.all()  # the fault schedule did drop route messages
        a, b = plain.comm_totals(), prepared.comm_totals()
        for name in ("messages_sent", "bytes_sent", "messages_received", "bytes_received", "messages_per_round"):
            assert np.array_equal(getattr(a, name), getattr(b, name)), name


def test_route_rows_checked():
    g = star4()
    ex = make_exchange(g)
    active = g.src == 0  # hub → leaves
    with pytest.raises(ExchangeError, match="in_rows must list each of the 3 active in-edge rows"):
        ex.route(active, in_rows=np.array([0, 0, 1]))
    with pytest.raises(ExchangeError, match="out_rows must list each of the 3 active out-edge rows"):
        ex.route(active, out_rows=np.array([0, 1]))
    r = ex.route(active)
    with pytest.raises(ExchangeError, match="one row per route out-edge"):
        r.send(np.zeros((g.n_edges, 1)))
    with pytest.raises(ExchangeError, match="out must be a contiguous"):
        r.broadcast(np.zeros((4, 2)), out=np.zeros((3, 3)))


def test_mixer_block_with_dropped_entries_equals_the_dense_weights(monkeypatch):
    """The CSR block compacted in place (chunks of a few entries here) holds exactly the non-zero weights: inactive
    edges and zero self-weights left out, each row by ascending sender, the row pointers counting what was kept."""
    import distnav.exchange.mixer as mixer_mod

    monkeypatch.setattr(mixer_mod, "_CSR_CHUNK", 7)
    g = builders.connected_random_geometric(60, mean_degree=6, rng=np.random.default_rng(4))
    rng = np.random.default_rng(5)
    w = consensus_weights(g, "MH")
    active = rng.random(g.n_edges) < 0.6
    self_w = np.where(rng.random(g.n_nodes) < 0.3, 0.0, w.self_weight)
    for order in ("none", "rcm"):
        ex = make_exchange(g, order=order)
        m = mixer_mod.Mixer(ex, w.edge_weight, self_w, active)
        dense = np.zeros((g.n_nodes, g.n_nodes))
        dense[g.dst[active], g.src[active]] = w.edge_weight[active]
        dense[np.arange(g.n_nodes), np.arange(g.n_nodes)] += self_w
        local = dense[np.ix_(ex.nodes, ex.nodes)]  # rows and columns in the exchange's order
        blk = m._w_full
        assert blk is not None and blk.nnz == np.count_nonzero(local)
        assert np.array_equal(blk.toarray(), local)
        for r in range(g.n_nodes):  # each row's entries by ascending global sender id
            senders = ex.nodes[blk.indices[blk.indptr[r] : blk.indptr[r + 1]]]
            assert np.all(np.diff(senders) > 0)


def test_mixer_sharing_and_dropped_fault_state_leave_rounds_and_counts_unchanged():
    """Two 0/1 mixers (a round into a node set and its reverse) share one array of ones and their counts after
    ``share_with``; without their fault state their rounds, and the messages counted, are bitwise those of fresh
    mixers. A mixer under a fault schedule keeps its fault state."""
    from distnav.exchange.mixer import Mixer

    g = builders.connected_random_geometric(80, mean_degree=7, rng=np.random.default_rng(6))
    inC = np.random.default_rng(7).random(g.n_nodes) < 0.7
    ones = np.ones(g.n_edges)
    into = inC[g.dst] & (g.src != g.dst)
    out_of = inC[g.src] & (g.src != g.dst)
    x = np.random.default_rng(8).normal(size=(g.n_nodes, 3))
    ex_ref, ex = make_exchange(g, order="rcm"), make_exchange(g, order="rcm")
    refs = [Mixer(ex_ref, ones, inC.astype(float), a) for a in (into, out_of)]
    a, b = (Mixer(ex, ones, inC.astype(float), m) for m in (into, out_of))
    for m in (a, b):
        m.drop_fault_state()
    a.share_with(b)
    b.share_with(a)
    small, big = sorted((a._w_full, b._w_full), key=lambda blk: blk.nnz)
    assert np.shares_memory(small.data, big.data)
    assert a._sent_counts is b._recv_counts and a._recv_counts is b._sent_counts
    for ref, m in ((refs[0], a), (refs[1], b), (refs[0], a)):
        assert np.array_equal(ref.apply(x), m.apply(x))
    assert np.array_equal(ex_ref.messages_sent, ex.messages_sent)
    assert np.array_equal(ex_ref.messages_received, ex.messages_received)
    ex_f = make_exchange(g, faults=FaultSchedule(drop_probability=0.1, seed=1))
    f = Mixer(ex_f, ones, inC.astype(float), into)
    f.drop_fault_state()
    assert f._act_in.shape == (ex_f.in_dst.size,)
