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
3. optionally sends the CG vectors in fewer bits: float32, or **float16 with a shared exponent per row**
   (:func:`pack_half`: every entry as a float16 of the row scaled by a power of two, ``2·m + 1`` bytes for ``m``
   entries — a block floating point, so that a direction of 1e-9 m keeps its 11 significant bits where a bare
   float16 would flush it to zero; :data:`CG_WIRE_DTYPE` in the LM phase, issue 27). CG there is an inexact inner
   solve with the forcing term ``CG_RTOL = 0.1``; a relative rounding of 5e-4 (6e-8 in float32) of the largest
   entry of a neighbour's row of a direction changes the step by far less than the forcing term allows, and the
   fixed point is set by the gradient, which every anchor computes from the parameters (float64). The sender's
   own rows stay float64. No error feedback: every CG direction is a new vector, no rounding error carries over.
   Measured on 12 plant-like halls in ``uwb solve``'s workflow (docs/economy_uwb.md): float32 → float16 with the
   exponent, 1.5–1.7 × fewer bytes, positions within 0.03 mm, the same links excluded;
4. in the LM phase sends, instead of a CG direction's row, **each neighbour's product itself**
   (:meth:`Wire.projected`, :data:`PROJECTED`): the matrix–vector product needs on a link only ``c_lᵀ v_j``, the
   other end's Jacobian row times its row of ``v``, and that end has the row (the pair's unit vector, both ends
   know both positions, and the offset's ``1``): it sends ``σ_l · a_lᵀ v_j`` of its first sample of the pair, the
   receiver divides by its own sample's σ. ``k`` values per link (one exponent byte with them in float16) where a
   row was ``k`` per free column: 3 B instead of 5 per link and CG iteration with heights held;
5. sends a trial's parameters, after the first, as the **LM step from the last accepted parameters**
   (:meth:`Wire.stepped`, :data:`STEPS`), its free columns in float32 (8 B where the float64 columns were 16;
   :data:`STEP_DTYPE`): the receiver knows the accepted ones (acceptance is decided on a network total)
   and the sender moves by the rounded step (:meth:`Wire.rounded`), so both ends hold the same parameters bit
   for bit — a step rounded to 24 bits is another inexact LM step (CG's forcing term is 0.1); the objective,
   the gradient and so the fixed point are evaluated at parameters every end agrees on;
7. sends CG's reduced dot products (float16, :data:`CG_DOT_DTYPE`) after a CG run's first reduction **on the
   exponent each slot carried last** (:data:`HELD_DOTS`, :func:`held_scalars`): 2 B a value instead of 3 where it
   lies in float16's normal range on it — the same 11 bits, so the same values bit for bit; the products' held
   exponents (4., :data:`HELD_EXPONENT`) are kept from one CG run to the next of a fit (:data:`HELD_ACROSS_RUNS`);
8. sends a trial's float32 step (5.) after a fit's first **on the exponents its entries carried last**
   (:data:`STEP_HELD`, :func:`pack_steps`): sign, 23-bit mantissa and a 4-bit difference from the exponent of the
   column in the sender's last step, which every receiver holds (7 B for two free columns instead of 8; outside
   that window and a fit's first as plain float32): the same values bit for bit (issue 27, seventh session);
9. sends nothing for an extrapolated trial (``refine.EXTRAPOLATE``): its step is a shared factor times the last
   step, which every receiver holds (:meth:`Wire.scaled`).

Measured (``benchmarks/bench_uwb_economy.py``, plant-like 28-anchor hall ``[78, 0]``): see docs/economy_uwb.md.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from distnav.algorithms.ranging.data import RangingData
from distnav.algorithms.ranging.step_codec import pack_steps, unpack_steps
from distnav.errors import ModelError
from distnav.exchange import Exchange

__all__ = [
    "Wire",
    "RANGE_RECORD_BYTES",
    "CG_WIRE_DTYPE",
    "PLAIN",
    "comm_mark",
    "comm_phases",
    "network_marks",
    "pack_half",
    "unpack_half",
    "reduction_cost",
    "Reductions",
    "reductions_cost",
    "CG_SCALAR_DTYPE",
    "HALF_MAX_ANCHORS",
    "cg_wire_dtype",
    "CG_DOT_DTYPE",
    "cg_dot_dtype",
    "pack_scalars",
    "unpack_scalars",
    "PROJECTED",
    "STEPS",
    "STEP_DTYPE",
    "KNOWN_FROM_PROBLEM",
    "HELD_EXPONENT",
    "HELD_FROM_LAST_FIT",
    "HELD_DOTS",
    "HELD_ACROSS_RUNS",
    "HeldScalars",
    "held_scalars",
    "STEP_HELD",
    "pack_steps",
    "unpack_steps",
]

CG_WIRE_DTYPE: type[np.floating] = np.float16  # the LM phase's CG directions: float16 + exponent (item 3)
CG_SCALAR_DTYPE: type[np.floating] = np.float32  # the LM phase's CG dot products on the wire (item 4)
#: CG's own network totals in the LM phase (each anchor's share of ``pᵀq``, ``rᵀz`` and the common offset's row):
#: float16 with an exponent per value, 3 B (:func:`pack_scalars`, issue 27 fifth session) up to
#: :data:`HALF_MAX_ANCHORS` anchors; :data:`CG_SCALAR_DTYPE` above, or where this is not float16
#: (:func:`cg_dot_dtype`)
CG_DOT_DTYPE: type[np.floating] = np.float16
#: above this many anchors the LM phase's directions travel as float32 even where CG_WIRE_DTYPE is float16: one
#: warm fit (bench_uwb_economy.py) took 596 CG iterations at 1,000 anchors in float16 (712 in float32), but
#: 2,630 at 3,000 (1,177) and 2,049 at 10⁴ (993) — CG's rounding noise grows with the network
HALF_MAX_ANCHORS = 1000
#: one range record as it travels whole (two int32 anchor ids + one float64 range): the gather's unit, and a
#: delegated sample's record in the LM phase (``inner.Delegated``, issue 27 item 37)
RANGE_RECORD_BYTES = 16


def cg_wire_dtype(n_anchors: int) -> type[np.floating]:
    """The LM phase's CG directions on the wire for a network of ``n_anchors``: :data:`CG_WIRE_DTYPE`, float32
    instead of float16 above :data:`HALF_MAX_ANCHORS` anchors."""
    if CG_WIRE_DTYPE == np.float16 and n_anchors > HALF_MAX_ANCHORS:
        return np.float32
    return CG_WIRE_DTYPE


def cg_dot_dtype(n_anchors: int) -> type[np.floating]:
    """The type of CG's reduced dot products in the LM phase of a network of ``n_anchors`` (:data:`CG_DOT_DTYPE`).

    Why float16 (issue 27, fifth session): CG's two reductions per iteration (3 floats: ``pᵀq``, the common
    offset's share, ``rᵀz``) sent more bytes than its products on the links (on the 28-anchor hall 648 B against
    489 B per iteration in float32). An anchor's share rounded to 11 significant bits (its own exponent: 3 B)
    changes CG's step lengths ``α`` and ``β`` by a relative 2⁻¹¹ of the terms' magnitudes at most: another
    inexact inner solve within the forcing term 0.1, as the float16 directions (module docstring, item 3); the
    gradient, the objective and so the fixed point stay float64/float32. Measured on 12 plant-like halls: 1.11 ×
    fewer bytes, positions within 0.1 mm, the same links excluded (docs/economy_uwb.md). As the directions, only
    up to :data:`HALF_MAX_ANCHORS` anchors (CG's rounding noise grows with the network). The simulation rounds
    every anchor's share and sums them in float64; a tree that re-rounds each partial sum on the way up adds one
    rounding per level (4 levels on the hall)."""
    if CG_DOT_DTYPE == np.float16 and n_anchors <= HALF_MAX_ANCHORS:
        return np.float16
    return CG_SCALAR_DTYPE


#: the LM phase's matrix–vector products: each anchor sends each neighbour its own product with the link's Jacobian
#: row, ``k`` values per link (:meth:`Wire.projected`, item 4), not its row of the CG direction (False: as before)
PROJECTED = True
#: after the first, the LM phase's trial parameters travel as the step from the last accepted ones, float16 with
#: the shared exponent (:meth:`Wire.stepped`, item 5); False: the free columns in float64 (as before)
STEPS = True
#: the steps' type on the wire: float32 (8 B per link with heights held). float16 with the shared exponent (5 B)
#: left the phase "converged" 1–20 mm from LM on a 16 × 16 grid (tests/test_csg_handover.py): the rounding of
#: 2⁻¹¹ stirs the slow modes, which the step-size test of the stop does not see
STEP_DTYPE: type[np.floating] = np.float32
#: the LM phase's projected products after a CG run's first iteration: float16 on the exponent that the run's first
#: message on the link carried, 2 B a value instead of 3 (:meth:`Wire.projected`, issue 27 fifth session)
HELD_EXPONENT = True
#: the first parameters of a phase travel as the later ones (the free columns, from anchors with a free parameter):
#: every receiver takes a fixed anchor's coordinates and the held ones from the problem (``positions_m``: set up
#: once with the ranges, the same on every anchor; the solvers hold those coordinates at exactly these values),
#: not from the message (issue 27, fifth session: a fit's first broadcast 16 B per link instead of 24, none from
#: a fixed anchor); False: the whole row, float64, from every anchor (as before)
KNOWN_FROM_PROBLEM = True
#: a warm fit's first parameters are not sent from an anchor whose receivers hold them from the last fit
#: (``Wire(held_m=...)``, item 6 of the module docstring); False: sent as :data:`KNOWN_FROM_PROBLEM` says
HELD_FROM_LAST_FIT = True
#: CG's reduced dot products (float16, :data:`CG_DOT_DTYPE`) after a CG run's first reduction: each value on the
#: exponent its slot carried last (per anchor's share and for the total), 2 B instead of 3 where every share and the
#: total lie in its window (:func:`held_scalars`; issue 27, seventh session) — the same values bit for bit
HELD_DOTS = True
#: the held exponents of the LM phase's products (:data:`HELD_EXPONENT`) kept from one CG run to the next within a
#: fit (both ends of every link know where a run ends), so a run's first product needs no new exponent either where
#: it lies in the window (issue 27, seventh session; False: every run starts with new exponents, as before). Not for
#: the dot products: kept across runs they cost more (on 12 plant-like workflows 1.28 → 1.36 MB of reductions:
#: one share outside its window sends the value at 3 B in every message, and the shares' scale jumps between runs)
HELD_ACROSS_RUNS = True
#: a trial's float32 step after a fit's first on the exponents its entries carried in the sender's last step
#: (:func:`pack_steps`, item 8): 7 B for two free columns instead of 8, bit for bit; False: plain float32
STEP_HELD = True
PLAIN = False  # True: every row in full, float64, from every anchor (as before issue 27; bench_uwb_economy's "before")


class Wire:
    """The packed rounds of one exchange block (module docstring). ``owner`` / ``other``: every half-measurement's
    local holder and the other end's global id; ``extra``: parameter columns beyond ``dim`` that every anchor
    estimates (a per-anchor range offset); ``held_m`` ``(n, dim)``: per anchor, the coordinates every one of its
    ranged neighbours holds bit for bit from the last fit (NaN: not held) — its start must be these where they are
    given (a ModelError otherwise), and its first parameters are then not sent (item 6; with ``known_from_problem``
    and no ``extra`` column only)."""

    def __init__(
        self,
        problem: RangingData,
        ex: Exchange,
        owner: np.ndarray,
        other: np.ndarray,
        extra: int,
        *,
        known_from_problem: bool = False,
        held_m: np.ndarray | None = None,
        listens: np.ndarray | None = None,
    ) -> None:
        self.ex, self.n = ex, problem.n_anchors
        self.known_from_problem = known_from_problem  # :data:`KNOWN_FROM_PROBLEM` (the LM phase's: refine.py)
        self.owner, self.other = owner, other
        free = np.concatenate([problem.free, np.ones((problem.n_anchors, extra), bool)], axis=1)
        self.P = free.shape[1]
        self.cols = np.flatnonzero(np.any(free, axis=0))  # the free columns of the network (every round's size)
        talks: np.ndarray = np.asarray(np.any(free, axis=1))  # anchors with a free parameter (others: rows constant)
        active = np.ones(ex.n_edges, bool)
        active[ex.out_edges] = talks[ex.nodes[ex.out_src]]
        active[ex.in_edges] = talks[ex.in_src]
        if listens is not None:  # no message to an anchor that sits the phase out (inner.sit_out_plan, item 37)
            active[ex.out_edges] &= listens[ex.out_dst]
            active[ex.in_edges] &= listens[ex.nodes[ex.in_dst]]
        self.active = active
        self.talks_other = talks[other]  # per half-measurement: the other end sends
        #: per half-measurement: a message arrives (its other end sends, its owner takes part)
        self.need = self.talks_other if listens is None else self.talks_other & listens[ex.nodes[owner]]
        self._talks = talks
        self._problem = problem  # the other ends' known coordinates, read at a first broadcast (known_from_problem)
        self._pos: np.ndarray | None = None
        self._params: np.ndarray | None = None  # the last parameters received, per half-measurement
        self._held: np.ndarray | None = None  # per anchor, its coordinates its receivers hold (item 6), else None
        if held_m is not None and HELD_FROM_LAST_FIT and known_from_problem and extra == 0:
            held = np.asarray(held_m, float)
            if held.shape != (problem.n_anchors, problem.dim):
                raise ModelError(f"held_m must have shape ({problem.n_anchors}, {problem.dim}), got {held.shape}")
            self._held = held
        self._rep: tuple[np.ndarray, np.ndarray] | None = None  # per out-edge: a half-measurement, the edge's mask
        self._step_sent: np.ndarray | None = None  # the exponents of this block's last step, per column (item 8)
        self._step_got: np.ndarray | None = None  # the same of every other end's last step, per half-measurement
        self._last_got: np.ndarray | None = None  # every other end's last step received (item 9)

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
        time (with ``known_from_problem``, :data:`KNOWN_FROM_PROBLEM`, only the free columns from anchors with a free
        parameter, the known coordinates from the problem: ``values`` must hold them there, as the LM phase does),
        the free columns from anchors with a free parameter after that (the rest as first received)."""
        if PLAIN:
            return self._round(values, None, None)
        if self._params is None and not (KNOWN_FROM_PROBLEM and self.known_from_problem):
            self._params = self._round(values, None, None).copy()
            return self._params.copy()
        active, need, send = self.active, self.need, True
        if self._params is None:  # the other end's known coordinates (the problem's: fixed, held), zeros elsewhere
            self._params = np.zeros((self.other.size, self.P))
            self._params[:, : self._problem.dim] = self._problem.positions_m[self.other]
            if self._held is not None:
                active, need, send = self._held_start(values)
        out = self._params
        if send:  # not when no anchor of the network sends (every block knows: no round at all)
            got = self._round(np.ascontiguousarray(values[:, self.cols]), active, need)
            out[np.ix_(need, self.cols)] = got[need]
        return out.copy()

    def _held_start(self, values: np.ndarray) -> tuple[np.ndarray, np.ndarray, bool]:
        """A warm fit's first broadcast with :attr:`_held` (item 6): the receivers' rows of the anchors whose start
        they hold filled from it; the edges that still carry a message, the half-measurements that need one and
        whether any anchor of the network sends."""
        assert self._held is not None
        ex, cols = self.ex, self.cols
        held = np.all(np.isfinite(self._held[:, cols]), axis=1)
        own = held[ex.nodes]
        differs = not np.array_equal(values[own][:, cols], self._held[ex.nodes[own]][:, cols])
        if ex.allreduce(float(differs), "max") > 0:  # every block refuses together (a check: monitoring, no bytes)
            raise ModelError("a warm fit's start differs from the parameters its receivers hold (held_m)")
        from_held = self.talks_other & held[self.other]
        assert self._params is not None
        self._params[np.ix_(from_held, cols)] = self._held[self.other[from_held]][:, cols]
        active = self.active.copy()
        active[ex.out_edges] &= ~held[ex.nodes[ex.out_src]]
        active[ex.in_edges] &= ~held[ex.in_src]
        return active, self.need & ~held[self.other], bool(np.any(self._talks & ~held))

    def rounded(self, step: np.ndarray) -> np.ndarray:
        """An LM step ``(n_local, P)`` as :meth:`stepped` delivers it: its free columns as :data:`STEP_DTYPE` (the
        sender moves by this step, so that both ends hold the same parameters bit for bit; item 5)."""
        out = np.zeros_like(step)
        out[:, self.cols] = self.rounded_columns(step[:, self.cols])
        return out

    def rounded_columns(self, columns: np.ndarray) -> np.ndarray:
        """The free columns of a step ``(rows, m)`` rounded as :data:`STEP_DTYPE` (float64 values)."""
        return _decode(_encode(columns, STEP_DTYPE), self.cols.size)

    def stepped(self, base: np.ndarray, step: np.ndarray) -> np.ndarray:
        """Each half-measurement's other end's parameters moved from ``base`` (per half-measurement, as both ends
        hold them) by its :meth:`rounded` ``step``: the free columns as :data:`STEP_DTYPE`, from anchors with a
        free parameter (item 5)."""
        if STEP_HELD and STEP_DTYPE == np.float32:
            got = self._held_step(step[:, self.cols])
        else:
            got = _decode(self._round(_encode(step[:, self.cols], STEP_DTYPE), self.active, self.need), self.cols.size)
        self._last_got = got
        out = np.array(base, float)
        out[np.ix_(self.talks_other, self.cols)] += got[self.talks_other]
        return out

    def scaled(self, base: np.ndarray, factor: float) -> np.ndarray:
        """:meth:`stepped` by :meth:`rounded` ``factor`` × the last step every receiver holds from each sender (an
        extrapolated trial, ``refine.EXTRAPOLATE``; ``factor`` from a decision all anchors share): no message, the
        same rows bit for bit as the senders' own rounding of ``factor`` × their last step (item 9)."""
        if self._last_got is None:
            raise ModelError("no step to scale: no trial was sent")
        got = self.rounded_columns(self._last_got * factor)
        out = np.array(base, float)
        out[np.ix_(self.talks_other, self.cols)] += got[self.talks_other]
        return out

    def _held_step(self, step: np.ndarray) -> np.ndarray:
        """Every half-measurement's other end's ``step`` ``(n_local, m)`` in float32, sent as :func:`pack_steps` on
        the exponents of the sender's last step (item 8): one message per active directed edge, 7 B or 8 B with two
        columns. The receiver decodes on the exponents it holds from that sender's last step."""
        m, ex = step.shape[1], self.ex
        if self._step_sent is None:
            self._step_sent = np.zeros((ex.n_local, m), np.int64)
            self._step_got = np.zeros((self.other.size, m), np.int64)
        assert self._step_got is not None
        packed, sizes, self._step_sent = pack_steps(step.astype(np.float32), self._step_sent)
        box = ex.send(packed[ex.out_src], active=self.active, message_bytes=sizes[ex.out_src])
        pos = self._positions(box.dst, box.src)
        if not np.all(box.delivered[pos] | ~self.need):
            raise ModelError("refinement: a neighbour's message was lost (it needs every link each round)")
        got = np.zeros((self.other.size, m))
        talk = self.need
        values, self._step_got[talk] = unpack_steps(np.asarray(box.values)[pos[talk]], self._step_got[talk], m)
        got[talk] = values
        return got

    def vectors(self, v: np.ndarray, dtype: type[np.floating] = np.float64) -> np.ndarray:
        """Each half-measurement's other end's rows of the CG vector ``v`` ``(n_local, P, k)`` (zero at parameters
        that are not free): the free columns only, from anchors with a free parameter, as ``dtype``; zeros
        elsewhere."""
        nl, P, k = v.shape
        if PLAIN:
            return self._round(v.reshape(nl, P * k), None, None).reshape(-1, P, k)
        m = self.cols.size * k
        if dtype == np.float16:  # a shared exponent per row (module docstring, item 3)
            sent = pack_half(v[:, self.cols, :].reshape(nl, m))
            got = unpack_half(self._round(sent, self.active, self.need), m).reshape(-1, self.cols.size, k)
        else:
            sent = np.ascontiguousarray(v[:, self.cols, :], dtype=dtype).reshape(nl, m)
            got = self._round(sent, self.active, self.need).reshape(-1, self.cols.size, k)
        out = np.zeros((got.shape[0], P, k))
        out[:, self.cols, :] = got
        out[~self.need] = 0.0
        return out

    def _edges(self) -> tuple[np.ndarray, np.ndarray]:
        """Per outgoing edge, one half-measurement of its sender to its receiver (the first), and the mask of
        the directed edges that carry a projected row: a ranged pair whose sender talks (either end knows it)."""
        if self._rep is None:
            ex, n = self.ex, self.n
            key = self.owner * n + self.other
            order = np.argsort(key, kind="stable")
            sk = key[order]

            def find(want: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
                at = np.minimum(np.searchsorted(sk, want), max(order.size - 1, 0))
                return (order[at] if order.size else np.zeros(want.size, np.int64)), (
                    sk[at] == want if order.size else np.zeros(want.size, bool)
                )

            rep, has_out = find(ex.out_src * n + ex.out_dst)
            has_in = find(ex.in_dst * n + ex.in_src)[1]
            active = self.active.copy()
            active[ex.out_edges[~has_out]] = False
            active[ex.in_edges[~has_in]] = False
            self._rep = (rep, active)
        return self._rep

    def projected(
        self, own: np.ndarray, dtype: type[np.floating] = np.float64, held: list[np.ndarray] | None = None
    ) -> np.ndarray:
        """Each half-measurement's other end's value of ``own`` ``(h, k)`` — a value per half-measurement that its
        owner computed for the pair (the first of the pair's samples; item 4 of the module docstring) —, zero
        where the other end has no free parameter: one message per directed edge of a ranged pair from an anchor
        with a free parameter, ``k`` values as ``dtype`` (float16: :func:`pack_half`, ``2k + 1`` bytes).

        ``held`` (float16 only; :data:`HELD_EXPONENT`): a CG run's state, empty at its start: each link's last
        exponent sent, which both ends keep. A message whose row float16 holds to 11 bits on that exponent is
        ``2k`` bytes, the others carry a new one (``2k + 1``; the first of the run on every link) —
        :func:`_on_held_exponent`."""
        rep, active = self._edges()
        k = own.shape[1]
        rows = np.asarray(own, float)[rep] if own.shape[0] else np.zeros((rep.size, k))
        if dtype == np.float16 and held is not None:
            packed, sizes = _on_held_exponent(rows, held)
            box = self.ex.send(packed, active=active, message_bytes=sizes)
            values = unpack_half(box.values, k)
        elif dtype == np.float16:
            box = self.ex.send(pack_half(rows), active=active)
            values = unpack_half(box.values, k)
        else:
            box = self.ex.send(np.ascontiguousarray(rows, dtype=dtype), active=active)
            values = np.asarray(box.values, float)
        pos = self._positions(box.dst, box.src)
        if not np.all(box.delivered[pos] | ~self.need):
            raise ModelError("refinement: a neighbour's message was lost (it needs every link each round)")
        got = np.asarray(values[pos])
        got[~self.need] = 0.0
        return got


def _exponents(packed: np.ndarray, k: int) -> np.ndarray:
    """The exponent byte of every row of :func:`pack_half`'s ``(n, 2k + 1)`` bytes, as integers."""
    return np.ascontiguousarray(packed[:, 2 * k], dtype=np.uint8).view(np.int8).astype(np.int64)


#: the binades around a link's held exponent in which its row travels on it (:func:`_on_held_exponent`): float16's
#: normal range, so that the row's largest entry keeps 11 significant bits
HELD_BELOW, HELD_ABOVE = 13, 15


def _on_held_exponent(rows: np.ndarray, held: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Rows ``(n, k)`` as :func:`pack_half`'s bytes and each message's size (:meth:`Wire.projected`): a row whose
    largest entry lies within float16's normal range on the link's held exponent ``e`` (``held[0]``; its own
    exponent from ``e − 13`` to ``e + 15``, or a zero row) travels as float16 of ``row · 2⁻ᵉ``, ``2k`` bytes —
    the receiver holds ``e``; the container carries it for the simulation —, any other row (every row when
    ``held`` is empty: a CG run's first round) as :func:`pack_half` with its own exponent, ``2k + 1`` bytes, which
    both ends then hold. Why the window: in a large network a CG direction spreads from the anchors the gradient
    is on, and a link's product can grow 10⁶-fold within a run (1,000 anchors: 2²³), beyond any fixed exponent."""
    rows = np.asarray(rows, float)
    k = rows.shape[1]
    fresh = pack_half(rows)
    own = _exponents(fresh, k)
    if not held:
        held[:] = [own]
        return fresh, np.full(rows.shape[0], 2 * k + 1, np.int64)
    e = held[0]
    zero = np.max(np.abs(rows), axis=1, initial=0.0) == 0.0
    keep = zero | ((own >= e - HELD_BELOW) & (own <= e + HELD_ABOVE))
    out = fresh.copy()
    on_e = np.ldexp(rows[keep], -e[keep, None]).astype(HALF)
    out[keep, : 2 * k] = np.ascontiguousarray(on_e).view(np.uint8).reshape(-1, 2 * k)
    out[keep, 2 * k] = e[keep].astype(np.int8).view(np.uint8)
    held[0] = np.where(keep, e, own)
    return out, np.where(keep, 2 * k, 2 * k + 1).astype(np.int64)


@dataclass
class HeldScalars:
    """One CG run's held exponents of one reduction's values (:data:`HELD_DOTS`): every anchor's share's and the
    network total's (empty at the run's start; :func:`held_scalars` fills and updates them)."""

    shares: list[np.ndarray] = field(default_factory=list)
    total: list[np.ndarray] = field(default_factory=list)


def held_scalars(values: np.ndarray, held: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """``values`` ``(n, f)`` as :func:`pack_scalars` rounds them — float16 of each value scaled by a power of two,
    11 significant bits — and per value whether it travelled on its slot's held exponent (2 B) or carried a new one
    (3 B; every value of a run's first reduction): :func:`_on_held_exponent` with one value per row. A value whose
    own exponent lies within the window (``e − 13`` … ``e + 15`` of the held ``e``) is a normal float16 on ``e``,
    so it keeps the same 11 bits: the returned values equal :func:`pack_scalars`'s bit for bit either way."""
    v = np.asarray(values, float)
    packed, sizes = _on_held_exponent(v.reshape(-1, 1), held)
    return unpack_half(packed, 1).reshape(v.shape), (sizes == 2).reshape(v.shape)


def _encode(rows: np.ndarray, dtype: type[np.floating]) -> np.ndarray:
    """Rows ``(n, m)`` on the wire as ``dtype`` (float16: :func:`pack_half`)."""
    return pack_half(rows) if dtype == np.float16 else np.ascontiguousarray(rows, dtype=dtype)


def _decode(sent: np.ndarray, m: int) -> np.ndarray:
    """The float64 rows of :func:`_encode`'s ``(n, m)``."""
    return unpack_half(sent, m) if sent.dtype == np.uint8 else np.asarray(sent, float)


HALF = np.dtype("<f2")  # little-endian on the wire whatever the host (the field runtime's convention)


def pack_half(rows: np.ndarray) -> np.ndarray:
    """Rows ``(n, m)`` as bytes ``(n, 2m + 1)``: each row scaled by ``2⁻ᵉ`` (``e`` the exponent of its largest
    magnitude, so the largest scaled entry lies in [0.5, 1)) as little-endian float16, then ``e`` as one int8.
    A zero (or non-finite) row's exponent is 0; rows whose largest entry is below ``2⁻¹²⁷`` travel as zeros."""
    r = np.asarray(rows, float)
    top = np.max(np.abs(r), axis=1, initial=0.0)
    e = np.where(np.isfinite(top) & (top > 0), np.frexp(np.where(np.isfinite(top), top, 1.0))[1], 0)
    tiny = e < -127
    e = np.clip(e, -127, 127)
    scaled = np.where(tiny[:, None], 0.0, np.ldexp(r, -e[:, None]))
    half = np.ascontiguousarray(scaled.astype(HALF)).view(np.uint8).reshape(r.shape[0], 2 * r.shape[1])
    return np.concatenate([half, e.astype(np.int8).view(np.uint8)[:, None]], axis=1)


def unpack_half(packed: np.ndarray, m: int) -> np.ndarray:
    """The float64 rows ``(n, m)`` of :func:`pack_half`'s bytes ``(n, 2m + 1)``."""
    b = np.ascontiguousarray(packed, dtype=np.uint8)
    if b.ndim != 2 or b.shape[1] != 2 * m + 1:
        raise ModelError(f"a packed float16 row must have {2 * m + 1} bytes, got shape {b.shape}")
    vals = np.ascontiguousarray(b[:, : 2 * m]).view(HALF).astype(float)
    e = b[:, 2 * m].view(np.int8).astype(int)
    return np.asarray(np.ldexp(vals, e[:, None]))


def pack_scalars(values: np.ndarray) -> np.ndarray:
    """Every value of ``values`` as 3 bytes (:func:`pack_half` of a one-entry row: float16 of the value scaled to
    [0.5, 1), then its exponent), shape ``(values.size, 3)``."""
    return pack_half(np.asarray(values, float).reshape(-1, 1))


def unpack_scalars(packed: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    """The float64 values of :func:`pack_scalars`'s bytes, in ``shape``."""
    return unpack_half(packed, 1).reshape(shape)


@dataclass(frozen=True)
class Reductions:
    """The network totals a solver took as all-reductions: how many (``count``) and their size per anchor summed
    over them, in floats and in bytes (float64, or fewer bytes where a float32 wire carried them); their cost as
    spanning-tree messages: :func:`reduction_cost`."""

    count: int = 0
    floats: int = 0
    bytes: int = 0
    #: of them, totals decided at the tree's root (``refine.ROOT_DECIDES``): how many, their tree directions (1 or 2)
    #: and bytes per tree edge (the values up, the decision down), summed — not in ``bytes``
    decided: int = 0
    decided_directions: int = 0
    decided_bytes: int = 0
    #: the anchors of the spanning tree (0: every anchor; fewer where the anchors without a free parameter sit the
    #: phase out, ``inner.sit_out_plan``, item 37)
    tree_nodes: int = 0


def reductions_cost(n_anchors: int, reduced: Reductions) -> tuple[int, int]:
    """Messages and bytes of ``reduced`` over a spanning tree: :func:`reduction_cost` of its all-reductions, and
    ``n − 1`` messages per direction of every decided one (its bytes per tree edge on each of the ``n − 1`` edges);
    ``n`` the tree's anchors (``reduced.tree_nodes``, else ``n_anchors``)."""
    n_anchors = reduced.tree_nodes or n_anchors
    m, b = reduction_cost(n_anchors, reduced.count - reduced.decided, reduced.bytes)
    edges = max(n_anchors - 1, 0)
    return m + reduced.decided_directions * edges, b + reduced.decided_bytes * edges


def reduction_cost(n_anchors: int, reductions: int, reduced_bytes: int) -> tuple[int, int]:
    """Messages and bytes of ``reductions`` network totals as spanning-tree all-reductions (up to a root and back
    down: ``2(n − 1)`` messages each, every message carrying the reduced values): ``reduced_bytes`` is their size
    summed over the reductions (per anchor). The exchange computes these totals by gathering every anchor's row
    (``gather_nodes``, so that in-process and MPI agree bit for bit); a deployment sends this."""
    per = 2 * max(n_anchors - 1, 0)
    return reductions * per, reduced_bytes * per


def comm_mark(ex: Exchange) -> tuple[int, int]:
    """This block's own totals so far, (messages, bytes): a phase boundary for :func:`comm_phases` (monitoring, as
    the result's ``comm``), taken without a message; :func:`network_marks` sums the marks over the blocks once."""
    return ex.local_totals()


def network_marks(ex: Exchange, marks: dict[str, tuple[int, int]]) -> dict[str, tuple[int, int]]:
    """The network's totals at each of :func:`comm_mark`'s marks: one all-reduction of every mark at the end (each
    block counts what its own nodes sent, so the sum over the blocks is the network total at the mark) where a
    network total at every mark cost the field's nodes a gather of every counter each time."""
    flat = np.asarray([v for mark in marks.values() for v in mark], np.int64)
    total = np.asarray(ex.allreduce(flat, "sum"), np.int64)
    return {name: (int(total[2 * i]), int(total[2 * i + 1])) for i, name in enumerate(marks)}


def comm_phases(marks: dict[str, tuple[int, int]]) -> dict[str, dict[str, int]]:
    """Messages and bytes of each phase from the totals at its end (``marks`` in phase order, from 0)."""
    out, last = {}, (0, 0)
    for name, (m, b) in marks.items():
        out[name] = {"messages": m - last[0], "bytes": b - last[1]}
        last = (m, b)
    return out
