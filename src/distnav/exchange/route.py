"""Prepared message rounds over a fixed set of edges, on compact arrays (:meth:`Exchange.route`).

A :class:`Route` is built once for an ``active`` edge mask (e.g. the pair edges of ADMM with constraint nodes)
and then carries one round per call, like :meth:`Exchange.broadcast` / :meth:`Exchange.send`, but on arrays that
hold *only the route's rows* in an order the caller chose at set-up:

* :meth:`Route.broadcast` — each local node's row goes along its active outgoing edges; returns one row per
  route in-edge (``in_rows`` order: positions in :attr:`Exchange.in_edges`);
* :meth:`Route.send` — one row per route out-edge (``out_rows`` order: positions in :attr:`Exchange.out_edges`);
  returns one row per route in-edge in the order of :attr:`Route.in_rows`.

Both return ``(values, delivered)``: ``delivered`` says which rows arrived (a read-only all-true mask without
faults); under faults the rows that did not arrive hold zeros, as in an :class:`~distnav.exchange.base.Inbox`.
Messages are counted and faults drawn exactly as by ``broadcast``/``send`` with the same ``active`` mask (same
counts, same dropped messages), so a route changes no result, only what the round costs: no full-length gather,
no masking of inactive rows, no per-round mask slicing. In-process, where a message on out-edge row ``r`` arrives
on in-edge row ``r``, a send moves nothing: it returns the sent array itself (or, with faults, a copy with the
lost rows zeroed), and :attr:`Route.in_rows` follows the caller's ``out_rows``.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from distnav.errors import ExchangeError

if TYPE_CHECKING:
    from distnav.exchange.core import ExchangeCore

__all__ = ["Route"]


def _rows_or_default(rows: np.ndarray | None, mask: np.ndarray, what: str) -> np.ndarray:
    """``rows`` checked to list every active row exactly once (in any order), or the active rows ascending."""
    n_active = int(np.count_nonzero(mask))
    if rows is None:
        return np.flatnonzero(mask)
    rows = np.asarray(rows, dtype=np.int64)
    ok = rows.shape == (n_active,) and (rows.size == 0 or (0 <= int(rows.min()) and int(rows.max()) < mask.size))
    if ok:  # as many rows as active ones, all active, as many distinct ones: a permutation (linear, no sort)
        seen = np.zeros(mask.size, bool)
        seen[rows] = True
        ok = bool(mask[rows].all()) and int(np.count_nonzero(seen)) == n_active
    if not ok:
        raise ExchangeError(
            f"route {what} must list each of the {n_active} active {what.split('_')[0]}-edge "
            f"rows of this block once, got {rows.size} rows"
        )
    return rows


class Route:
    """A prepared round over the edges of ``active`` (a mask over the graph's directed edges); see the module
    docstring. ``in_rows``/``out_rows``: the order of the compact arrays (default: ascending edge rows)."""

    def __init__(
        self,
        exchange: ExchangeCore,
        active: np.ndarray,
        *,
        in_rows: np.ndarray | None = None,
        out_rows: np.ndarray | None = None,
    ) -> None:
        ex = exchange
        self.exchange = ex
        self.active = np.asarray(active, bool)
        if ex._moves_rows_in_place and ex.out_edges is ex.in_edges:  # in-process: one edge order, one mask
            if self.active.shape != (ex.n_edges,):
                raise ExchangeError(
                    f"active must be a mask over the {ex.n_edges} directed edges, got {self.active.shape}"
                )
            self._act_in = self.active[ex.in_edges] & ex._real_in
            self._act_out = self._act_in
        else:
            self._act_out, self._act_in = ex._active_slices(self.active)
        self.out_rows = _rows_or_default(out_rows, self._act_out, "out_rows")
        self._in_place = ex._moves_rows_in_place and in_rows is None and out_rows is not None
        if self._in_place:  # in-process: the message on out-edge row r arrives on in-edge row r
            self.in_rows = self.out_rows
            if not np.array_equal(self._act_in, self._act_out):  # pragma: no cover - same edges in-process
                raise ExchangeError("in-process route with different incoming and outgoing edges")
        elif in_rows is None and out_rows is None and self._act_in is self._act_out:
            self.in_rows = self.out_rows  # in-process: the same rows ascending (one array, not two equal ones)
        else:
            self.in_rows = _rows_or_default(in_rows, self._act_in, "in_rows")
        self._gather = np.ascontiguousarray(ex.in_src_col[self.in_rows])
        self._sent = np.bincount(ex.out_src[self._act_out], minlength=ex.n_local)
        self._recv = np.bincount(ex.in_dst[self._act_in], minlength=ex.n_local)
        self._sent_total = int(self._sent.sum())
        self._all = np.ones(self.in_rows.size, bool)
        self._all.setflags(write=False)
        self._out_buffers: dict[tuple[int, str], np.ndarray] = {}

    @property
    def dst(self) -> np.ndarray:
        """Local receiver of each route in-edge (``in_rows`` order)."""
        return np.asarray(self.exchange.in_dst[self.in_rows])

    @property
    def src(self) -> np.ndarray:
        """Global sender id of each route in-edge (``in_rows`` order)."""
        return np.asarray(self.exchange.in_src[self.in_rows])

    def _count(self, msg_bytes: int) -> np.ndarray:
        """Count the round (as ``broadcast``/``send`` with this mask do) and return the compact delivered mask."""
        ex = self.exchange
        if not ex.faults.active:
            ex._account(self._sent, self._recv, msg_bytes, self._sent_total)
            return self._all
        delivered = ex._fault_plan.delivered(ex.round_index) & self._act_in
        sent, total = ex._sent_counts(self._act_out, cache=True)
        ex._account_faulty(sent, total, delivered, msg_bytes)
        return np.asarray(delivered[self.in_rows])

    def broadcast(self, node_values: np.ndarray, *, out: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Each local node's row along its route edges → ``(values, delivered)`` per route in-edge; ``out``: an
        array of shape ``(len(in_rows), ...)`` to write into (reused round after round by the caller)."""
        ex = self.exchange
        x = np.asarray(node_values)
        if x.ndim == 0 or x.shape[0] != ex.n_local:
            raise ExchangeError(f"broadcast needs {ex.n_local} local rows, got array of shape {x.shape}")
        tail = x.shape[1:]
        flat = x.reshape(x.shape[0], math.prod(tail))
        cols = ex._columns(flat, self.active)
        if out is not None and (
            out.shape != (self.in_rows.size, *tail) or out.dtype != cols.dtype or not out.flags.c_contiguous
        ):
            raise ExchangeError(
                f"out must be a contiguous {cols.dtype} array of shape "
                f"{(self.in_rows.size, *tail)}, got {out.dtype} {out.shape}"
            )
        flat_out = None if out is None else out.reshape(self.in_rows.size, flat.shape[1])
        values = np.take(cols, self._gather, axis=0, out=flat_out, mode="clip")  # indices valid by construction
        ok = self._count(flat.shape[1] * flat.itemsize)
        if ok is not self._all:
            values[~ok] = 0
        return values.reshape((self.in_rows.size, *tail)), ok

    def send(self, edge_values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """One row per route out-edge (``out_rows`` order) → ``(values, delivered)`` per route in-edge
        (:attr:`in_rows` order). In-process without faults ``values`` is ``edge_values`` itself."""
        ex = self.exchange
        x = np.asarray(edge_values)
        if x.ndim == 0 or x.shape[0] != self.out_rows.size:
            raise ExchangeError(
                f"route send needs one row per route out-edge ({self.out_rows.size}), got array of shape {x.shape}"
            )
        tail = x.shape[1:]
        flat = x.reshape(x.shape[0], math.prod(tail))
        if self._in_place:
            values = flat
        else:
            key = (flat.shape[1], flat.dtype.str)
            full = self._out_buffers.get(key)
            if full is None:  # rows off the route stay zero
                full = self._out_buffers[key] = np.zeros((ex.out_edges.size, flat.shape[1]), flat.dtype)
            full[self.out_rows] = flat
            values = np.take(ex._move_edges(full, self.active), self.in_rows, axis=0, mode="clip")
        ok = self._count(flat.shape[1] * flat.itemsize)
        if ok is not self._all:
            if self._in_place:  # never zero the caller's array
                values = values.copy()
            values[~ok] = 0
        return values.reshape((self.in_rows.size, *tail)), ok
