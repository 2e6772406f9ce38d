"""The stored paper-like consensus network: reproducible from its search, and its numbers as the paper states."""

from __future__ import annotations

import numpy as np

from distnav.experiments.consensus_network import (
    PAPER_LIKE,
    build,
    candidate,
    paper_like_networks,
    relabel_like_paper,
    search,
)


def test_stored_network_is_the_searched_candidate():
    info = PAPER_LIKE["search"]
    static, switching, _ = build(info["seed"], info["index"])
    assert static.links.tolist() == PAPER_LIKE["links"]
    assert [s.links.tolist() for s in switching.sessions] == PAPER_LIKE["sessions"]
    assert np.allclose(static.positions, PAPER_LIKE["positions_m"], atol=5e-4)


def test_search_accepts_the_stored_candidate_and_rejects_its_neighbours():
    index = PAPER_LIKE["search"]["index"]
    rep = search(0, 1, start=index)
    assert rep.matched == [index] and rep.best == index
    rep = search(0, 200, start=index + 1)  # the next 200 draws: none matches (the next match is 67420)
    assert rep.examined == 200 and rep.matched == [] and rep.slem_matched < 10
    assert 0 < PAPER_LIKE["search"]["matched"] <= PAPER_LIKE["search"]["slem_matched"] / 100


def test_paper_like_network_shapes_and_node_facts():
    static, switching = paper_like_networks()
    assert static.n_nodes == 20 and static.n_links == 49 and static.is_connected
    assert [s.n_links for s in switching.sessions] == [7, 6, 8, 7]
    assert all(s.degrees.max() <= 1 for s in switching.sessions) and switching.union.is_connected
    # paper 003 §3.1-3.2 (1-based): node 2's neighbours are 1, 3, 4, 5; node 1 has 4, node 14 has 7 neighbours
    assert sorted((static.neighbors(1) + 1).tolist()) == [1, 3, 4, 5]
    assert static.degrees[0] == 4 and static.degrees[13] == 7


def test_relabelling_needs_the_paper_degrees():
    ring = np.array([(i, (i + 1) % 20) for i in range(20)])  # every degree 2: no labelling like the paper's
    assert relabel_like_paper(ring) is None
    _, links = candidate(0, PAPER_LIKE["search"]["index"])
    perm = relabel_like_paper(links)
    assert perm is not None and sorted(perm.tolist()) == list(range(20))
    new = np.empty(20, dtype=int)
    new[perm] = np.arange(20)
    relabelled = {tuple(sorted(e)) for e in new[links].tolist()}
    assert {j for i, j in relabelled if i == 1} | {i for i, j in relabelled if j == 1} == {0, 2, 3, 4}
