"""Reliability (redundancy numbers, MDB, worst undetected shift) from each anchor's neighbourhood
(:func:`distnav.algorithms.ranging.reliability.local_reliability`, issue 28 item 5) against the central computation
(:func:`~distnav.algorithms.ranging.reliability.external_reliability`, itself tested against re-fits in
tests/test_reliability.py), the k-hop balls against networkx, and the flooding's bytes counted by hand."""

from __future__ import annotations

import networkx as nx
import numpy as np
import pytest

from distnav.algorithms.ranging.reliability import ReliabilityOptions, external_reliability, local_reliability
from distnav.errors import ModelError
from distnav.exchange import make_exchange
from distnav.models.uwb.problems import build_problem


def _ladder(columns: int = 9, seed: int = 0, nlos: bool = False):
    """2-D ladder: two rows 6 m apart, columns 5 m apart, every pair within 12 m ranged; the first column's two
    anchors and one in the middle known. Returns the problem and noisy "estimates" (the truth + 5 cm) at which the
    numbers are linearized (the same point for both computations)."""
    rng = np.random.default_rng(seed)
    pos = np.array([[5.0 * c, 6.0 * r] for c in range(columns) for r in range(2)])
    ids = [f"A{k:02d}" for k in range(pos.shape[0])]
    links = [
        (ids[i], ids[j])
        for i in range(len(ids))
        for j in range(i + 1, len(ids))
        if np.linalg.norm(pos[i] - pos[j]) < 12.0
    ]
    d = np.array([np.linalg.norm(pos[ids.index(a)] - pos[ids.index(b)]) for a, b in links])
    ranges = d + rng.normal(0.0, 0.05, d.size) + 0.12
    if nlos:
        ranges[3] += 1.5
    known = {ids[0]: pos[0], ids[1]: pos[1], ids[columns]: pos[columns]}
    p = build_problem(ids, links, ranges, fixed=known, dim=2, truth_m=pos)
    est = pos + np.where(p.free, rng.normal(0.0, 0.05, pos.shape), 0.0)
    return p, est


def _central(p, est, opts, off):
    x = np.concatenate([p.to_vector(est), np.atleast_1d(off) if off is not None else []])
    return external_reliability(p, x, opts)


@pytest.mark.parametrize(
    ("offsets", "loss"), [("none", "linear"), ("common", "cauchy_long"), ("per_anchor", "cauchy"), ("common", "huber")]
)
def test_equals_the_central_numbers_where_the_neighbourhood_spans_the_network(offsets, loss):
    p, est = _ladder(nlos=True)
    off = {"none": None, "common": np.array([0.1]), "per_anchor": np.full(p.n_anchors, 0.05)}[offsets]
    opts = ReliabilityOptions(sigma_m=0.05, offsets=offsets, loss=loss, loss_scale_m=0.2)
    ref = _central(p, est, opts, off)
    assert ref is not None
    loc = local_reliability(p, est, opts, offsets_m=off, hops=p.n_anchors)
    np.testing.assert_allclose(loc.r, ref.r, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(loc.q, ref.q, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(loc.mdb_m, ref.mdb_m, rtol=1e-9)
    np.testing.assert_allclose(loc.shift_m, ref.shift_m, rtol=1e-9, atol=1e-12)
    assert np.array_equal(loc.worst_link[p.estimated], ref.worst_link[p.estimated])
    assert np.allclose(loc.scale[p.estimated], ref.scale)
    assert loc.subnetwork_anchors[p.estimated].min() == p.estimated.sum()


def test_small_neighbourhoods_are_the_k_hop_balls_and_optimistic():
    """With ``hops`` = 1 every anchor solves for the estimated anchors within one hop (networkx's BFS) with the
    ring held: its own links' redundancy numbers are at least the central ones (the held ring can only add
    information: ``N_SS⁻¹ ≤ Q_SS``), the difference the docs report."""
    p, est = _ladder()
    opts = ReliabilityOptions(sigma_m=0.05)
    ref = _central(p, est, opts, None)
    g = nx.Graph(p.links.tolist())
    for hops in (1, 2):
        loc = local_reliability(p, est, opts, hops=hops)
        for i in np.flatnonzero(p.estimated):
            ball = nx.single_source_shortest_path_length(g, int(i), cutoff=hops)
            assert loc.subnetwork_anchors[i] == sum(bool(p.estimated[k]) for k in ball), (hops, i)
        assert np.all(loc.r >= ref.r - 1e-12)
        assert np.max(loc.r - ref.r) > 1e-3  # it does differ on a ladder 8 hops long
        assert loc.rounds == hops + 1


def test_the_flooding_bytes_counted_by_hand():
    """A path A–B–C–D (3 links, 6 directed edges, 2-D): one broadcast of the estimates (2 floats), then round 1
    sends every anchor's own records (at most 2: K = 2), round 2 the one record each learned (K = 1); a record is
    4 + 2·2 = 8 floats."""
    pos = np.array([[0.0, 0.0], [5.0, 0.5], [10.0, 0.0], [15.0, 0.5]])
    ids = ["A", "B", "C", "D"]
    links = [("A", "B"), ("B", "C"), ("C", "D")]
    d = np.linalg.norm(pos[[0, 1, 2]] - pos[[1, 2, 3]], axis=1)
    p = build_problem(ids, links, d, fixed={"A": pos[0], "D": pos[3]}, dim=2, truth_m=pos, check_determined=False)
    ex1 = make_exchange(p.graph)
    one = local_reliability(p, pos, ReliabilityOptions(), hops=1, exchange=ex1)
    assert one.comm.bytes == 8 * (6 * 2 + 6 * 2 * 8)
    two = local_reliability(p, pos, ReliabilityOptions(), hops=2, exchange=make_exchange(p.graph))
    assert two.comm.bytes == 8 * (6 * 2 + 6 * 2 * 8 + 6 * 1 * 8)
    assert two.comm.messages == 3 * 6


def test_rejects_bad_options_and_offsets():
    p, est = _ladder()
    with pytest.raises(ModelError, match="sigma_m"):
        ReliabilityOptions(sigma_m=0.0)
    with pytest.raises(ModelError, match="offsets"):
        ReliabilityOptions(offsets="both")
    with pytest.raises(ModelError, match="hops"):
        local_reliability(p, est, ReliabilityOptions(), hops=0)
    with pytest.raises(ModelError, match="need 1 finite offset"):
        local_reliability(p, est, ReliabilityOptions(offsets="common"), offsets_m=None)
