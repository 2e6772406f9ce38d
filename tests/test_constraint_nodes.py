"""Constraint nodes: conditions (18) of paper 000, vertex covers, unused links (Fig. 5)."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from distnav.errors import GraphError
from distnav.network import builders
from distnav.network.constraint_nodes import (
    check_conditions,
    choose_constraint_nodes,
    minimum_vertex_cover,
    unused_links,
    validate_constraint_nodes,
)
from distnav.network.graph import Graph

# the 9-node graph of paper 000 Fig. 5, 1-based as in the paper (a reconstruction consistent with the text:
# N_1 = {1, 2}, N_3 = {2, 3, 5, 6, 7, 8}, {1,3,4,6,9} covers every link, {1,3,4,9} leaves (5,6) and (6,7) unused)
FIG5 = [(1, 2), (2, 3), (3, 5), (3, 6), (3, 7), (3, 8), (5, 6), (6, 7), (4, 5), (4, 8), (7, 9), (8, 9)]


def fig5() -> Graph:
    return Graph.from_links(9, [(a - 1, b - 1) for a, b in FIG5], names=[str(k) for k in range(1, 10)])


def ids(*one_based: int) -> list[int]:
    return [k - 1 for k in one_based]


def test_fig5_neighbourhoods_as_stated_in_the_paper():
    g = fig5()
    assert g.neighbors(0, include_self=True).tolist() == ids(1, 2)
    assert g.neighbors(2, include_self=True).tolist() == ids(2, 3, 5, 6, 7, 8)


def test_fig5_full_set_uses_every_link_and_reduced_set_leaves_two_unused():
    g = fig5()
    full = choose_constraint_nodes(g, ids(1, 3, 4, 6, 9))
    assert full.unused_links.shape == (0, 2)
    reduced = choose_constraint_nodes(g, ids(1, 3, 4, 9))  # still satisfies (18), as the paper says
    assert sorted(map(tuple, (reduced.unused_links + 1).tolist())) == [(5, 6), (6, 7)]
    assert reduced.summary()["n_unused_links"] == 2


def test_conditions_reject_uncovered_node_with_its_name():
    g = builders.path(6)  # 0-1-2-3-4-5
    with pytest.raises(GraphError, match=r"\(18\)-1: nodes 2 have no constraint node"):
        validate_constraint_nodes(g, [0, 4])
    rep = check_conditions(g, [0, 4])
    assert rep.uncovered == (2,) and not rep.ok


def test_conditions_reject_disjoint_groups():
    g = builders.path(6)
    # N_1 = {0,1,2} and N_4 = {3,4,5} cover all nodes but never overlap: x_0..x_2 and x_3..x_5 decouple
    with pytest.raises(GraphError, match=r"\(18\)-2: the constraint nodes split into 2 groups.*\{1\}; \{4\}"):
        validate_constraint_nodes(g, [1, 4])
    # adding node 2 bridges them (N_2 = {1,2,3} meets both)
    assert validate_constraint_nodes(g, [1, 2, 4]).tolist() == [1, 2, 4]


def test_literal_reading_of_condition_2_rejects_all_nodes_on_a_long_path():
    g = builders.path(8)
    assert check_conditions(g, range(8)).ok  # the paper's "trivial choice" C = {1..n}
    rep = check_conditions(g, range(8), literal=True)
    assert not rep.ok and (0, 7) in rep.unbridged_pairs
    with pytest.raises(GraphError, match=r"literal\): no single constraint node bridges the pairs \(0, 5\)"):
        validate_constraint_nodes(g, range(8), literal=True)
    # on a short path the literal reading holds too
    assert check_conditions(builders.path(5), range(5), literal=True).ok


def test_star_with_only_the_hub():
    g = builders.star(6)
    assert validate_constraint_nodes(g, [0]).tolist() == [0]
    with pytest.raises(GraphError, match="nodes 2, 3, 4, 5 have no constraint node"):
        validate_constraint_nodes(g, [1])


@pytest.mark.parametrize(
    ("nodes", "pattern"),
    [
        ([], "is empty"),
        ([0, 0, 2], "node 0 is listed twice"),
        ([0, 9], "constraint node 9 is outside 0..5"),
        ([-1], "outside"),
        ([0.5], "integer node ids"),
        (np.array([True, False]), "mask needs 6 entries"),
    ],
)
def test_invalid_node_sets(nodes, pattern):
    with pytest.raises(GraphError, match=pattern):
        validate_constraint_nodes(builders.path(6), nodes)


def test_choice_errors():
    g = builders.path(4)
    with pytest.raises(GraphError, match="unknown constraint-node choice"):
        choose_constraint_nodes(g, "every")
    with pytest.raises(GraphError, match="unknown vertex-cover method"):
        minimum_vertex_cover(g, method="greedy")  # type: ignore[arg-type]
    disconnected = Graph.from_links(4, [(0, 1), (2, 3)])
    with pytest.raises(GraphError, match="not connected: nodes 2, 3"):
        choose_constraint_nodes(disconnected, "all")


def brute_force_cover_size(g: Graph) -> int:
    links = g.links.tolist()
    for k in range(g.n_nodes + 1):
        for sub in itertools.combinations(range(g.n_nodes), k):
            s = set(sub)
            if all(a in s or b in s for a, b in links):
                return k
    raise AssertionError


@pytest.mark.parametrize("seed", range(6))
def test_exact_cover_is_minimum_and_approximation_within_bound(seed):
    rng = np.random.default_rng(seed)
    g = builders.connected_random_geometric(11, mean_degree=4, rng=rng)
    best = brute_force_cover_size(g)
    exact = choose_constraint_nodes(g, "min_cover", method="exact")
    assert exact.optimal and exact.size == best
    approx = choose_constraint_nodes(g, "min_cover", method="approx")
    assert approx.optimal is False
    assert approx.lower_bound is not None and approx.lower_bound <= best <= approx.size <= 2 * approx.lower_bound
    for c in (exact, approx):  # every link covered, and (18) holds (validated inside choose_constraint_nodes)
        assert unused_links(g, c.nodes).shape == (0, 2)


def test_min_cover_of_simple_graphs():
    assert choose_constraint_nodes(builders.star(7)).nodes.tolist() == [0]
    assert choose_constraint_nodes(builders.path(7)).size == 3
    assert choose_constraint_nodes(builders.complete(5)).size == 4
    assert choose_constraint_nodes(Graph.from_links(1, [])).nodes.tolist() == [0]
    assert choose_constraint_nodes(builders.ring(9), method="approx").size <= 2 * 4  # OPT(ring 9) = 5, |M| = 4


def test_all_and_per_node_counts():
    g = fig5()
    c = choose_constraint_nodes(g, "all")
    assert c.size == 9 and c.method == "all nodes"
    np.testing.assert_array_equal(c.per_node_count, g.degrees + 1)
    r = choose_constraint_nodes(g, ids(1, 3, 4, 9))
    # node 6 (id 5) sees constraint node 3 only; node 8 (id 7) sees 3, 4 and 9
    assert r.per_node_count[5] == 1 and r.per_node_count[7] == 3


def test_exact_cover_time_limit_raises_or_falls_back():
    g = builders.connected_random_geometric(60, mean_degree=8, rng=np.random.default_rng(0))
    with pytest.raises(GraphError, match="did not finish in 1e-09 s"):
        minimum_vertex_cover(g, method="exact", time_limit_s=1e-9)
    nodes, optimal, lower, used = minimum_vertex_cover(g, method="auto", time_limit_s=1e-9)
    assert not optimal and used.startswith("2-approximation") and lower <= nodes.size <= 2 * lower


def _sequential_matching(g):
    """The one-link-at-a-time greedy matching (lowest-degree endpoints first), written as a plain loop."""
    deg = g.degrees
    links = g.links
    order = np.lexsort((np.maximum(deg[links[:, 0]], deg[links[:, 1]]), deg[links[:, 0]] + deg[links[:, 1]]))
    used, out = set(), []
    for a, b in links[order].tolist():
        if a not in used and b not in used:
            used |= {a, b}
            out.append((a, b))
    return out


def _sequential_prune(g, chosen):
    chosen = set(chosen)
    for v in sorted(chosen, key=lambda k: (g.degrees[k], k)):
        nb = g.neighbors(v).tolist()
        if nb and all(u in chosen for u in nb):
            chosen.discard(v)
    return sorted(chosen)


@pytest.mark.parametrize(("tail", "chunk"), [(0, 1 << 16), (50, 1 << 16), (0, 997), (50, 7)])
def test_vectorized_greedy_passes_equal_the_sequential_ones(monkeypatch, tail, chunk):
    import distnav.network.constraint_nodes as cn

    monkeypatch.setattr(cn, "_SEQUENTIAL_TAIL", tail)
    monkeypatch.setattr(cn, "_SEQUENTIAL_TAIL_LINKS", tail)
    monkeypatch.setattr(cn, "_MATCH_CHUNK", chunk)  # links matched per chunk (≈ 13,500 links here)
    g = builders.connected_random_geometric(3000, mean_degree=9, rng=np.random.default_rng(5))
    ref = _sequential_matching(g)
    got = cn._maximal_matching(g)
    assert sorted(map(tuple, got.tolist())) == sorted(ref)
    chosen = np.zeros(g.n_nodes, bool)
    chosen[np.asarray(ref).ravel()] = True
    assert np.flatnonzero(cn._prune(g, chosen)).tolist() == _sequential_prune(g, np.flatnonzero(chosen).tolist())


def test_approximation_reports_the_lp_bound():
    from distnav.network.constraint_nodes import lp_lower_bound

    # odd ring: LP optimum n/2 → bound ⌈n/2⌉ = OPT; a star: LP = 1 = OPT
    assert lp_lower_bound(builders.ring(9)) == 5 and lp_lower_bound(builders.star(6)) == 1
    g = builders.connected_random_geometric(1000, mean_degree=8, rng=np.random.default_rng(0))
    c = choose_constraint_nodes(g, "min_cover")  # beyond exact_max_nodes: the approximation
    assert c.optimal is False and c.method.startswith("2-approximation")
    assert c.lower_bound >= g.n_nodes // 2 and c.ratio_bound is not None and 1 <= c.ratio_bound <= 2
    assert unused_links(g, c.nodes).shape == (0, 2)


@pytest.mark.parametrize("n, degree, seed", [(20, 8, 0), (57, 8, 1), (200, 8, 2), (1001, 8, 3), (1001, 12, 4)])
def test_matching_bound_is_below_the_lp_bound_and_equal_when_it_says_so(n, degree, seed):
    """The linear-time bound (greedy matching + triangle augmentations in the double cover) against the exact LP
    bound of scipy's Hopcroft–Karp matching: never above it, and equal where it claims to be the LP bound."""
    from distnav.network.constraint_nodes import _maximal_matching, lp_lower_bound, matching_lower_bound

    g = builders.connected_random_geometric(n, mean_degree=degree, rng=np.random.default_rng(seed))
    matching = _maximal_matching(g)
    bound, is_lp = matching_lower_bound(g, matching)
    lp = lp_lower_bound(g)
    assert matching.shape[0] <= bound <= lp
    assert is_lp == (bound == -(-n // 2)) and (not is_lp or bound == lp)


def test_the_cover_states_which_lower_bound_it_reports(monkeypatch):
    from distnav.network import constraint_nodes as cn

    g = builders.ring(41)  # no triangles: the matching bound stays at |M| + 0 < ⌈n/2⌉
    assert cn.matching_lower_bound(g, cn._maximal_matching(g))[1] is False
    assert minimum_vertex_cover(g, method="approx")[3].endswith("lower bound: LP relaxation")
    monkeypatch.setattr(cn, "LP_BOUND_MAX_LINKS", 10)  # too large for the exact LP: the cheaper bound, said so
    nodes, optimal, lower, used = minimum_vertex_cover(g, method="approx")
    assert used.endswith("the LP relaxation not computed: too large)") and lower == 20 <= nodes.size


def test_overlap_groups_equal_those_of_the_neighbourhood_product():
    """(18)-2 groups via the linear bipartite construction = components of A[C] A[:, C] (the definition)."""
    from scipy.sparse.csgraph import connected_components

    g = builders.connected_random_geometric(200, mean_degree=9, rng=np.random.default_rng(3))
    A = g.adjacency(include_self=True)
    for seed in range(5):
        C = np.sort(np.random.default_rng(seed).choice(200, size=25, replace=False))
        _, lab = connected_components(A[C] @ A[:, C], directed=False)
        want = sorted(tuple(int(s) for s in C[lab == k]) for k in np.unique(lab))
        assert sorted(check_conditions(g, C).groups) == want
