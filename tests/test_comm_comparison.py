"""The communication comparison of issue 27: a distributed run's bytes beside a fusion centre's multi-hop gather."""

from __future__ import annotations

import numpy as np
import pytest

from distnav.algorithms.consensus.averaging import average_consensus
from distnav.algorithms.result import compare_with_gather, format_bytes, format_count, format_ratio
from distnav.errors import GraphError
from distnav.exchange.core import CommTotals
from distnav.network import builders


def _totals(bytes_sent: list[int], messages_sent: list[int], rounds: int) -> CommTotals:
    b, m = np.array(bytes_sent, np.int64), np.array(messages_sent, np.int64)
    return CommTotals(rounds, m, b, m.copy(), b.copy(), np.zeros(rounds, np.int64), np.zeros(rounds, np.int64))


def test_comparison_on_a_path_by_hand() -> None:
    # path 0-1-2-3, 10 B at every node, gathered at node 0: hops 0,1,2,3 -> 60 hop-bytes, 6 relay hops;
    # node 1 transmits its own 10 B and the 20 B of nodes 2 and 3 -> busiest relay 30 B
    cmp = compare_with_gather(
        _totals([100, 200, 300, 400], [1, 2, 3, 4], 5),
        builders.path(4),
        [10, 10, 10, 10],
        data="the test records",
        node_label="anchor",
        node_names=["A", "B", "C", "D"],
        sink=0,
    )
    d = cmp.as_dict()
    assert d["distributed"] == {
        "bytes": 1000,
        "messages": 10,
        "rounds": 5,
        "bytes_per_node_max": 400,
        "bytes_per_node_median": 250.0,
        "messages_per_node_max": 4,
        "messages_per_node_median": 2.5,
    }
    g = d["gather"]
    assert (g["total_hop_bytes"], g["messages"], g["busiest_relay_bytes"], g["sink_name"]) == (60, 6, 30, "A")
    assert d["ratio_bytes"] == pytest.approx(1000 / 60) and d["ratio_busiest_node"] == pytest.approx(400 / 30)
    assert cmp.line() == (
        "sent 1 kB in 10 messages (per anchor max 400 B, median 250 B); gathering the test records at anchor A "
        "would cost 60 B over 6 relay hops (busiest relay 30 B): 17× the bytes"
    )


def test_comparison_of_a_real_consensus_run_counts_what_the_exchange_counted() -> None:
    g = builders.ring(8)
    res = average_consensus(np.arange(8.0), graph=g, protocol="P3", rounds=12)
    cmp = compare_with_gather(res.comm, g, np.full(8, 8), data="one float each")
    # a ring: every node sends 8 B to both neighbours every round
    assert cmp.total_bytes == 12 * 16 * 8 and cmp.total_messages == 12 * 16
    assert np.array_equal(cmp.bytes_sent, np.full(8, 12 * 2 * 8))
    # gathering 8 B from each of 8 ring nodes: hops 1,1,2,2,3,3,4 from any sink -> 16 hops, 128 hop-bytes
    assert cmp.gather.messages == 16 and cmp.gather.total_hop_bytes == 128
    assert cmp.ratio_bytes == pytest.approx(1536 / 128)


def test_totals_only_comparison_has_no_per_node_figures() -> None:
    cmp = compare_with_gather((5_000_000, 42_000), builders.star(5), [0, 12, 12, 12, 12], data="ranges")
    assert cmp.gather.sink == 0 and cmp.gather.total_hop_bytes == 48
    assert cmp.ratio_busiest_node is None and "per node" not in cmp.line()
    assert cmp.line().startswith("sent 5 MB in 42 k messages; gathering ranges at node 0 would cost 48 B")
    assert "bytes_per_node_max" not in cmp.as_dict()["distributed"]


def test_bad_data_sizes_are_named() -> None:
    with pytest.raises(GraphError, match="one entry per node"):
        compare_with_gather((1, 1), builders.path(3), [1, 2], data="x")


@pytest.mark.parametrize(
    ("value", "text"),
    [(512, "512 B"), (2900, "2.9 kB"), (41_234_567, "41.2 MB"), (3.3e12, "3.3e+03 GB")],
)
def test_format_bytes(value: float, text: str) -> None:
    assert format_bytes(value) == text


def test_format_count_and_ratio() -> None:
    assert [format_count(v) for v in (9870, 326_123, 4_240_000)] == ["9,870", "326 k", "4.24 M"]
    assert [format_ratio(v) for v in (14_213.4, 42.4, 3.24, 0.41, float("inf"))] == [
        "14,200×",
        "42×",
        "3.2×",
        "0.41×",
        "∞×",
    ]
