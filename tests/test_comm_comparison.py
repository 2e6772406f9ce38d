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


def test_node_data_bytes_takes_the_smaller_of_observations_and_normals() -> None:
    from distnav.algorithms.lsq.blue import LinearProblem
    from distnav.algorithms.lsq.gather_data import node_data_bytes

    # node 0: 2 rows touching 1 of 3 unknowns, diagonal R: observations 2·8 + 2·8 + 2·12 = 56 B,
    # normals (1 + 1)·8 + 4 = 20 B -> 20. Node 1: 1 row touching all 3: observations 8 + 8 + 3·12 = 52 B,
    # normals (6 + 3)·8 + 3·4 = 84 B -> 52. Node 2: 2 rows on 2 unknowns, full R: observations
    # 2·8 + 3·8 + 4·12 = 88 B, normals (3 + 2)·8 + 2·4 = 48 B -> 48.
    prob = LinearProblem.from_blocks(
        [np.array([[1.0, 0, 0], [2.0, 0, 0]]), np.array([[1.0, 1.0, 1.0]]), np.array([[1.0, 2.0, 0], [3.0, 1, 0]])],
        [np.zeros(2), np.zeros(1), np.zeros(2)],
        [np.ones(2), 1.0, np.array([[2.0, 0.5], [0.5, 2.0]])],
    )
    assert node_data_bytes(prob).tolist() == [20, 52, 48]


def test_normal_bytes_per_node_counts_the_observed_states_of_each_epoch() -> None:
    from distnav.algorithms.kalman.gather_data import normal_bytes_per_node
    from distnav.algorithms.kalman.measurements import NormalSeries

    # 2 epochs, 2 nodes, 3 states. Node 0 observes states {0, 1} then {0}; node 1 nothing then {0, 1, 2}.
    N = np.zeros((2, 2, 3, 3))
    N[0, 0, :2, :2] = [[2.0, 1.0], [1.0, 2.0]]
    N[1, 0, 0, 0] = 1.0
    N[1, 1] = np.eye(3)
    # q = 2: (3 + 2)·8 + 2·4 = 48 B; q = 1: (1 + 1)·8 + 4 = 20 B; q = 3: (6 + 3)·8 + 3·4 = 84 B
    assert normal_bytes_per_node(NormalSeries(N)).tolist() == [48 + 20, 84]


def test_report_lists_the_communication_lines() -> None:
    from distnav.experiments.report import communication_lines

    assert communication_lines({"communication_vs_gather": {"P1": {"line": "sent 1 kB"}}}) == ["P1: sent 1 kB"]
    assert communication_lines({"headline": {}}) == [] and communication_lines(None) == []


def test_record_and_observation_bytes_per_node() -> None:
    from distnav.algorithms.kalman.gather_data import observation_bytes_per_node, record_bytes_per_node
    from distnav.algorithms.kalman.measurements import ObservationSeries

    tracked = np.zeros((3, 2, 4), bool)  # 3 epochs, 2 nodes, 4 satellites
    tracked[:, 0, :2] = True  # node 0: 6 observations
    tracked[1, 1, 3] = True  # node 1: 1
    assert record_bytes_per_node(tracked).tolist() == [6 * 20, 20]
    # one epoch, node 0 two rows (one and two non-zero design entries), node 1 no data:
    # rows of 16 B (value, σ) + 12 B per non-zero entry -> 28 + 40
    series = ObservationSeries(2, [[(np.array([[1.0, 0.0], [1.0, 2.0]]), np.eye(2), np.zeros(2)), None]])
    assert observation_bytes_per_node(series).tolist() == [68, 0]


def test_one_node_run_says_nothing_was_needed_not_an_infinite_ratio() -> None:
    """A one-station network (gnss ionosphere on one receiver) sends nothing and gathering costs nothing: the line
    says so instead of '∞× the bytes'."""
    cmp = compare_with_gather((0, 0), builders.path(1), [240], data="every epoch's observations", node_label="station")
    assert cmp.total_bytes == 0 and cmp.gather.total_hop_bytes == 0
    assert "∞" not in cmp.line()
    assert cmp.line() == (
        "sent 0 B in 0 messages; gathering would cost nothing either: the data are already at one station"
    )
