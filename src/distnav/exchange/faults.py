"""Seeded fault schedules: dropped messages, failed links, silent nodes.

Whether the message on directed edge ``e`` in round ``k`` is dropped is a pure function of
``(seed, k, e)`` (a SplitMix64 hash), not of a random stream. So every backend — the in-process
block or any partition over MPI ranks — drops exactly the same messages, whichever subset of
edges it evaluates and in whatever order.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np

from distnav._checks import check_field_types
from distnav.errors import ExchangeError

__all__ = ["FaultPlan", "FaultSchedule", "uniform_hash"]

#: Per-edge senders or receivers (global ids), or a callable making them only when a plan needs them.
Endpoints = np.ndarray | Callable[[], np.ndarray]

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
        check_field_types(self, error=ExchangeError)  # types first, naming the field (issue 29)
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


class FaultPlan:
    """A :class:`FaultSchedule` compiled once for one block's edges, so a fault round costs a few array passes.

    * drops: the same SplitMix64 hash as :func:`uniform_hash` (the same messages drop on every backend), computed
      in place on cache-sized chunks and for several rounds at once when the block is small; ``u ≥ p`` is
      decided in integers (``z ≥ ⌈p·2⁵³⌉·2¹¹``, exact, no float conversion);
    * failed links and silent senders: folded into one per-edge "dead from round" array (``min`` over every fault
      that silences the edge), so a round compares one integer array instead of looping over the faults; made only
      when the schedule has such faults (the senders and receivers are read only then: pass callables to have
      them made on demand, and ``is_self``, the self-loop mask, so a drop-only plan never needs them).

    ``delivered(k)`` equals ``schedule.delivered(k, src, dst, edges)`` bit for bit (tested).
    """

    _CHUNK = 1 << 15  # uint64 elements per pass: 256 KB stays in cache

    def __init__(
        self,
        schedule: FaultSchedule,
        src: Endpoints,
        dst: Endpoints,
        edge_ids: np.ndarray,
        *,
        is_self: np.ndarray | None = None,
    ) -> None:
        self.schedule = schedule
        self.n_edges = int(np.shape(edge_ids)[0])
        # the edge ids as given (int32 in-process), turned into uint64 a chunk at a time by the draw: no
        # edge-sized copy. Senders and receivers (arrays, or callables making them) are read only for failed links
        # and silent nodes, or to find self-loops when ``is_self`` is not given: a drop-only plan holds no
        # per-edge array but the optional self-loop mask and one round's decisions.
        self._edges = np.ascontiguousarray(edge_ids)
        need_ends = bool(schedule.failed_links or schedule.silent_nodes) or is_self is None
        src_a = np.asarray(src() if callable(src) else src) if need_ends else None
        dst_a = np.asarray(dst() if callable(dst) else dst) if need_ends else None
        is_self = np.asarray(src_a == dst_a if is_self is None else is_self, bool)
        self._has_self = bool(is_self.any())
        self._self = is_self if self._has_self else None
        p = float(schedule.drop_probability)
        self._drops = p > 0
        self._threshold = np.uint64(math.ceil(p * 2.0**53) << 11) if self._drops else np.uint64(0)
        never = np.iinfo(np.int64).max
        self._dead_from: np.ndarray | None = None
        self._first_dead = never
        if src_a is not None and dst_a is not None and (schedule.failed_links or schedule.silent_nodes):
            dead = np.full(self.n_edges, never, np.int64)
            for i, j, r in schedule.failed_links:  # set-up only: a few faults, each one vectorized pass
                hit = ((src_a == i) & (dst_a == j)) | ((src_a == j) & (dst_a == i))
                np.minimum(dead, np.where(hit, r, never), out=dead)
            for node, r in schedule.silent_nodes:
                np.minimum(dead, np.where(src_a == node, r, never), out=dead)
            if self._self is not None:
                dead[self._self] = never  # a node's message to itself never leaves the device
            self._dead_from = dead
            self._first_dead = int(dead.min()) if dead.size else never
        del src_a, dst_a
        self._ones: np.ndarray | None = None
        rows = max(1, min(64, self._CHUNK // max(self.n_edges, 1)))
        self._rows = rows
        self._block_start = -1
        self._block = np.zeros((0, self.n_edges), bool)
        # silent senders of the block's outgoing edges: per number of silencings already begun, cached
        self._silent_rounds = np.array(sorted({r for _, r in schedule.silent_nodes}), dtype=np.int64)

    # ----------------------------------------------------------------- drops
    def _keys(self, first: int, count: int) -> np.ndarray:
        seed = self.schedule.seed
        with np.errstate(over="ignore"):
            base = np.uint64(seed & 0xFFFFFFFFFFFFFFFF) * np.uint64(1_000_003)
            rounds = np.arange(first, first + count, dtype=np.uint64)
            keys: np.ndarray = _splitmix64(base + rounds)
        return keys

    def _draw(self, first: int) -> None:
        """Drop decisions of rounds ``first … first + rows − 1`` for every edge of the block."""
        rows = self._rows
        keys = self._keys(first, rows)[:, None]
        out = np.empty((rows, self.n_edges), bool)
        step = max(1, self._CHUNK // rows)
        z = np.empty((rows, min(step, self.n_edges)), np.uint64)
        t = np.empty_like(z)
        s30, s27, s31 = np.uint64(30), np.uint64(27), np.uint64(31)
        for a in range(0, self.n_edges, step):
            b = min(a + step, self.n_edges)
            zz, tt = z[:, : b - a], t[:, : b - a]
            np.copyto(zz, self._edges[a:b][None, :], casting="unsafe")  # ids ≥ 0: the same uint64 values
            np.bitwise_xor(zz, keys, out=zz)
            np.add(zz, _GOLDEN, out=zz)
            np.right_shift(zz, s30, out=tt)
            np.bitwise_xor(zz, tt, out=zz)
            np.multiply(zz, _M1, out=zz)
            np.right_shift(zz, s27, out=tt)
            np.bitwise_xor(zz, tt, out=zz)
            np.multiply(zz, _M2, out=zz)
            np.right_shift(zz, s31, out=tt)
            np.bitwise_xor(zz, tt, out=zz)
            np.greater_equal(zz, self._threshold, out=out[:, a:b])
        self._block_start = first
        self._block = out

    def delivered(self, round_index: int) -> np.ndarray:
        """Boolean mask over the block's edges: does each message arrive in this round? (Do not modify it.)"""
        ok: np.ndarray
        if self._drops:
            k = round_index - self._block_start
            if self._block_start < 0 or not 0 <= k < self._rows:
                self._draw(round_index)
                k = 0
            ok = self._block[k]
        else:
            if self._ones is None:
                self._ones = np.ones(self.n_edges, bool)
                self._ones.setflags(write=False)
            ok = self._ones
        if self._dead_from is not None and round_index >= self._first_dead:
            ok = ok & (round_index < self._dead_from)
        if self._self is not None and self._drops:
            ok = ok | self._self
        return ok

    # ----------------------------------------------------------------- for a compiled round
    @property
    def drop_threshold(self) -> int:
        """``⌈p·2⁵³⌉·2¹¹``: a message is delivered when its hash ``z`` (as in :func:`uniform_hash`, before the
        shift to a float) is at least this (0 without drops)."""
        return int(self._threshold)

    @property
    def edge_ids(self) -> np.ndarray:
        """The block's edge ids the drops are hashed from (as given, not copied)."""
        return self._edges

    @property
    def first_dead(self) -> int:
        """The first round in which a failed link or a silent sender kills a message (the largest int64 if none)."""
        return self._first_dead

    def dead_from(self, round_index: int) -> np.ndarray | None:
        """Per edge, the first round from which a failed link or a silent sender kills its message, when one such
        fault has begun by ``round_index``; else None."""
        return self._dead_from if round_index >= self._first_dead else None

    # ----------------------------------------------------------------- silent senders
    def silent_stage(self, round_index: int) -> int:
        """How many distinct silencing rounds have begun: the sent counts change only when this does."""
        return int(np.searchsorted(self._silent_rounds, round_index, side="right"))
