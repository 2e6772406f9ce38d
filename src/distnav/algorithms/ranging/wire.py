"""What the distributed UWB phases put on the wire (issue 27): only what the receiver cannot already know.

The final distributed LM phase (:mod:`~distnav.algorithms.ranging.refine`) and the central σ
(:mod:`~distnav.algorithms.ranging.covariance`) exchange two kinds of rows with their neighbours:

* **the anchors' parameters** (coordinates and, per anchor, the range offset) — a row of ``P`` floats;
* **CG vectors** (a search direction for ``k`` right-hand sides) — a row of ``P·k`` floats, zero at every
  parameter that is not free (a fixed anchor's coordinates, a surveyed height held): the products multiply the
  neighbour's entries by its Jacobian rows, which are zero there.

What a receiver already knows is the problem's structure — which anchors are fixed and which coordinates are held,
the same on every anchor (:class:`~distnav.algorithms.ranging.data.RangingData`, set up once with the ranges) —
and what it received before. So :class:`Wire`

1. sends a CG vector's row only from an anchor with a free parameter, and only its **free columns** (the
   union over the network, so every message of a round has one size: ``P_free·k`` floats; with surveyed heights
   ``P_free = 2`` of ``P = 3``). The receiver fills zeros; the products are unchanged bit for bit (a zero Jacobian
   entry times a zero is the zero it was times the sent value);
2. sends the parameters in full **once** (:meth:`Wire.parameters` first call), then only the free columns from
   anchors with a free parameter: the held and fixed values never change (an LM step is zero there), the receiver
   keeps the first message's;
3. optionally sends the CG vectors as **float32** (:data:`CG_WIRE_DTYPE` in the LM phase): CG there is an inexact
   inner solve with the forcing term ``CG_RTOL = 0.1``; a relative rounding of 6e-8 on the neighbours' entries of a
   direction changes the step by far less than the forcing term allows, and the fixed point is set by the gradient,
   which every anchor computes from the parameters (float64). The sender's own rows stay float64.

Measured (``benchmarks/bench_uwb_economy.py``, plant-like 28-anchor hall ``[78, 0]``): see docs/economy_uwb.md.
"""

from __future__ import annotations

import numpy as np

from distnav.algorithms.ranging.data import RangingData
from distnav.errors import ModelError
from distnav.exchange import Exchange

__all__ = ["Wire", "CG_WIRE_DTYPE", "PLAIN", "comm_mark", "comm_phases"]

CG_WIRE_DTYPE = np.float32  # the LM phase's CG directions on the wire (module docstring, item 3)
PLAIN = False  # True: every row in full, float64, from every anchor (as before issue 27; bench_uwb_economy's "before")


class Wire:
    """The packed rounds of one exchange block (module docstring). ``owner`` / ``other``: every half-measurement's
    local holder and the other end's global id; ``extra``: parameter columns beyond ``dim`` that every anchor
    estimates (a per-anchor range offset)."""

    def __init__(self, problem: RangingData, ex: Exchange, owner: np.ndarray, other: np.ndarray, extra: int) -> None:
        self.ex, self.n = ex, problem.n_anchors
        self.owner, self.other = owner, other
        free = np.concatenate([problem.free, np.ones((problem.n_anchors, extra), bool)], axis=1)
        self.P = free.shape[1]
        self.cols = np.flatnonzero(np.any(free, axis=0))  # the free columns of the network (every round's size)
        talks: np.ndarray = np.asarray(np.any(free, axis=1))  # anchors with a free parameter (others: rows constant)
        active = np.ones(ex.n_edges, bool)
        active[ex.out_edges] = talks[ex.nodes[ex.out_src]]
        active[ex.in_edges] = talks[ex.in_src]
        self.active = active
        self.talks_other = talks[other]  # per half-measurement: the other end sends
        self._pos: np.ndarray | None = None
        self._params: np.ndarray | None = None  # the last parameters received, per half-measurement

    def _positions(self, box_dst: np.ndarray, box_src: np.ndarray) -> np.ndarray:
        if self._pos is None:
            key = box_dst * self.n + box_src
            order = np.argsort(key, kind="stable")
            want = self.owner * self.n + self.other
            pos = order[np.minimum(np.searchsorted(key[order], want), max(order.size - 1, 0))]
            if order.size == 0 or not np.all(key[pos] == want):
                raise ModelError("a ranged pair is not an edge of the exchange's graph")
            self._pos = pos
        return self._pos

    def _round(self, rows: np.ndarray, active: np.ndarray | None, need: np.ndarray | None) -> np.ndarray:
        """One broadcast of ``rows`` ``(n_local, m)``; each half-measurement's other end's row (``need``: the
        half-measurements whose sender sent; a lost one of them is an error)."""
        box = self.ex.broadcast(rows, active=active)
        pos = self._positions(box.dst, box.src)
        ok = box.delivered[pos] if need is None else box.delivered[pos] | ~need
        if not np.all(ok):
            raise ModelError("refinement: a neighbour's message was lost (it needs every link each round)")
        return np.asarray(box.values[pos])

    def parameters(self, values: np.ndarray) -> np.ndarray:
        """Each half-measurement's other end's parameter row of ``values`` ``(n_local, P)``: the whole row the first
        time, the free columns from anchors with a free parameter after that (the rest as first received)."""
        if PLAIN:
            return self._round(values, None, None)
        if self._params is None:
            self._params = self._round(values, None, None).copy()
            return self._params.copy()
        got = self._round(np.ascontiguousarray(values[:, self.cols]), self.active, self.talks_other)
        out = self._params
        out[np.ix_(self.talks_other, self.cols)] = got[self.talks_other]
        return out.copy()

    def vectors(self, v: np.ndarray, dtype: type[np.floating] = np.float64) -> np.ndarray:
        """Each half-measurement's other end's rows of the CG vector ``v`` ``(n_local, P, k)`` (zero at parameters
        that are not free): the free columns only, from anchors with a free parameter, as ``dtype``; zeros
        elsewhere."""
        nl, P, k = v.shape
        if PLAIN:
            return self._round(v.reshape(nl, P * k), None, None).reshape(-1, P, k)
        sent = np.ascontiguousarray(v[:, self.cols, :], dtype=dtype).reshape(nl, self.cols.size * k)
        got = self._round(sent, self.active, self.talks_other).reshape(-1, self.cols.size, k)
        out = np.zeros((got.shape[0], P, k))
        out[:, self.cols, :] = got
        out[~self.talks_other] = 0.0
        return out


def comm_mark(ex: Exchange) -> tuple[int, int]:
    """The exchange's network totals so far, (messages, bytes): a phase boundary for :func:`comm_phases`
    (monitoring, as the result's ``comm``)."""
    c = ex.comm_totals()
    return c.messages, c.bytes


def comm_phases(marks: dict[str, tuple[int, int]]) -> dict[str, dict[str, int]]:
    """Messages and bytes of each phase from the totals at its end (``marks`` in phase order, from 0)."""
    out, last = {}, (0, 0)
    for name, (m, b) in marks.items():
        out[name] = {"messages": m - last[0], "bytes": b - last[1]}
        last = (m, b)
    return out
