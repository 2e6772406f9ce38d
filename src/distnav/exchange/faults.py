"""Seeded fault schedules: dropped messages, failed links, silent nodes.

Whether the message on directed edge ``e`` in round ``k`` is dropped is a pure function of
``(seed, k, e)`` (a SplitMix64 hash), not of a random stream. So every backend — the in-process
block or any partition over MPI ranks — drops exactly the same messages, whichever subset of
edges it evaluates and in whatever order.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np

from distnav.errors import ExchangeError

__all__ = ["FaultSchedule", "uniform_hash"]

_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)


def _splitmix64(x: Any) -> Any:
    with np.errstate(over="ignore"):
        z = x + _GOLDEN
        z = (z ^ (z >> np.uint64(30))) * _M1
        z = (z ^ (z >> np.uint64(27))) * _M2
        return z ^ (z >> np.uint64(31))


def uniform_hash(seed: int, round_index: int, edge_ids: np.ndarray) -> np.ndarray:
    """Uniform(0, 1) numbers that depend only on ``(seed, round_index, edge_id)``."""
    with np.errstate(over="ignore"):
        key = _splitmix64(np.uint64(seed & 0xFFFFFFFFFFFFFFFF) * np.uint64(1_000_003) + np.uint64(round_index))
        z = _splitmix64(np.asarray(edge_ids, dtype=np.uint64) ^ key)
    out: np.ndarray = (z >> np.uint64(11)).astype(np.float64) * (1.0 / 9007199254740992.0)
    return out


@dataclass(frozen=True)
class FaultSchedule:
    """Faults injected into message rounds, reproducible by ``seed``.

    Parameters
    ----------
    drop_probability : each message is lost independently with this probability.
    failed_links : ``(i, j, from_round)``: the link i–j carries nothing in either direction from that round on.
    silent_nodes : ``(node, from_round)``: the node sends nothing from that round on (it still receives).
    seed : selects the drop pattern.

    Rounds are counted from 0 by the exchange, one per message round.
    """

    drop_probability: float = 0.0
    failed_links: tuple[tuple[int, int, int], ...] = ()
    silent_nodes: tuple[tuple[int, int], ...] = ()
    seed: int = 0

    def __post_init__(self) -> None:
        if not 0.0 <= float(self.drop_probability) < 1.0:
            raise ExchangeError(f"drop_probability must be in [0, 1), got {self.drop_probability}")
        object.__setattr__(self, "failed_links", tuple(tuple(int(v) for v in t) for t in self.failed_links))
        object.__setattr__(self, "silent_nodes", tuple(tuple(int(v) for v in t) for t in self.silent_nodes))
        for t in self.failed_links:
            if len(t) != 3 or t[2] < 0:
                raise ExchangeError(f"failed link {t} must be (i, j, from_round ≥ 0)")
        for s in self.silent_nodes:
            if len(s) != 2 or s[1] < 0:
                raise ExchangeError(f"silent node {s} must be (node, from_round ≥ 0)")

    @property
    def active(self) -> bool:
        return self.drop_probability > 0 or bool(self.failed_links) or bool(self.silent_nodes)

    def validate_for(self, n_nodes: int, links: Iterable[tuple[int, int]] | None = None) -> None:
        """Raise if a node id is out of range or a failed link is not a link of the graph."""
        for i, j, _ in self.failed_links:
            if not (0 <= i < n_nodes and 0 <= j < n_nodes):
                raise ExchangeError(f"failed link ({i}, {j}) names a node outside 0..{n_nodes - 1}")
        for node, _ in self.silent_nodes:
            if not 0 <= node < n_nodes:
                raise ExchangeError(f"silent node {node} is outside 0..{n_nodes - 1}")
        if links is not None:
            have = {(min(a, b), max(a, b)) for a, b in links}
            for i, j, _ in self.failed_links:
                if (min(i, j), max(i, j)) not in have:
                    raise ExchangeError(f"failed link ({i}, {j}) is not a link of the graph")

    def silent_mask(self, round_index: int, nodes: np.ndarray) -> np.ndarray:
        """True where a node (global id) is silent in this round."""
        out = np.zeros(np.shape(nodes), bool)
        for node, r in self.silent_nodes:
            if round_index >= r:
                out |= nodes == node
        return out

    def delivered(self, round_index: int, src: np.ndarray, dst: np.ndarray, edge_ids: np.ndarray) -> np.ndarray:
        """Boolean mask: does the message on each edge (global ids) reach its receiver in this round?"""
        ok = np.ones(np.shape(edge_ids), bool)
        if self.drop_probability > 0:
            ok &= uniform_hash(self.seed, round_index, edge_ids) >= self.drop_probability
        for i, j, r in self.failed_links:
            if round_index >= r:
                ok &= ~(((src == i) & (dst == j)) | ((src == j) & (dst == i)))
        if self.silent_nodes:
            ok &= ~self.silent_mask(round_index, src)
        ok |= src == dst  # a node's message to itself never leaves the device
        return ok
