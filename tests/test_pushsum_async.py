"""One push-sum node per thread on its own timer (run_push_sum_node): no barrier, different rates, lost and
reordered messages; the ratio reaches the numpy mean of the initial values."""

from __future__ import annotations

import queue
import threading

import numpy as np
import pytest

from distnav.algorithms.consensus.pushsum import NodeOutcome, run_push_sum_node
from distnav.errors import WeightsError
from distnav.network import builders


class _QueueLink:
    """In-memory link: every node has an inbox queue; a post is lost with probability ``loss``."""

    def __init__(self, me: int, outs: list[int], boxes: list[queue.Queue], loss: float, seed: int) -> None:
        self.me, self.outs, self.boxes, self.loss = me, outs, boxes, loss
        self.rng = np.random.default_rng(seed)
        self.posted = 0
        self.lost = 0

    def post(self, tick: int, running_sum: np.ndarray) -> None:
        for j in self.outs:
            self.posted += 1
            if self.rng.random() < self.loss:
                self.lost += 1
                continue
            self.boxes[j].put((self.me, tick, running_sum))

    def drain(self, timeout_s: float) -> list[tuple[int, int, np.ndarray]]:
        box = self.boxes[self.me]
        try:
            out = [box.get(timeout=timeout_s) if timeout_s > 0 else box.get_nowait()]
        except queue.Empty:
            return []
        while True:
            try:
                out.append(box.get_nowait())
            except queue.Empty:
                return out[::-1] if len(out) > 2 else out  # reordered now and then: stale ones must be skipped


@pytest.mark.parametrize("loss", [0.0, 0.2])
def test_threads_on_their_own_timers_reach_the_mean(loss: float) -> None:
    g = builders.connected_random_geometric(8, mean_degree=4, rng=np.random.default_rng(3))
    x = np.random.default_rng(4).normal(5.0, 3.0, size=(8, 2))
    boxes: list[queue.Queue] = [queue.Queue() for _ in range(8)]
    links = [_QueueLink(i, g.neighbors(i).tolist(), boxes, loss, seed=i) for i in range(8)]
    out: dict[int, NodeOutcome] = {}

    def node(i: int) -> None:
        period = 0.012 if i == 2 else 0.002  # node 2 ticks 6x slower (a margin on a loaded machine)
        out[i] = run_push_sum_node(
            x[i],
            out_degree=len(links[i].outs),
            in_neighbours=links[i].outs,
            link=links[i],
            period_s=period,
            duration_s=2.0,
        )

    threads = [threading.Thread(target=node, args=(i,)) for i in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=30)
    assert len(out) == 8
    ratios = np.array([out[i].ratio for i in range(8)])
    np.testing.assert_allclose(ratios, np.broadcast_to(x.mean(axis=0), (8, 2)), atol=1e-6)
    assert out[2].ticks < 0.6 * np.median([out[i].ticks for i in range(8)])
    if loss:
        assert sum(lk.lost for lk in links) > 0.1 * sum(lk.posted for lk in links)


def test_messages_from_strangers_and_wrong_shapes_are_refused() -> None:
    class Scripted:
        def __init__(self) -> None:
            self.script = [
                (9, 1, np.ones(2)),
                (1, 1, np.ones(3)),
                (1, 2, np.array([0.5, 0.5])),
                (1, 1, np.array([9.0, 9.0])),
            ]  # stranger, wrong shape, good, stale

        def post(self, tick: int, running_sum: np.ndarray) -> None:
            return None

        def drain(self, timeout_s: float) -> list[tuple[int, int, np.ndarray]]:
            got, self.script = self.script, []
            return got

    res = run_push_sum_node(
        np.array([1.0]), out_degree=1, in_neighbours=[1], link=Scripted(), period_s=10.0, duration_s=0.05
    )
    assert res.refused == {"stale": 1, "shape": 1, "not_a_neighbour": 1}
    assert res.last_tick_from == {1: 2}
    np.testing.assert_allclose(res.mass, [0.5 + 0.5, 0.5 + 0.5])  # own half kept + the neighbour's running sum


def test_bad_timer_is_refused() -> None:
    with pytest.raises(WeightsError, match="period_s"):
        run_push_sum_node(np.zeros(1), out_degree=1, in_neighbours=[1], link=None, period_s=0, duration_s=1)  # type: ignore[arg-type]
