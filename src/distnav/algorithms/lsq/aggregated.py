"""Fig. 6 of paper 000 with aggregated messages (``messages="aggregated"``) on one exchange block: no per-pair state.

Node ``i`` broadcasts ``x_i`` to its constraint neighbours instead of ``z_{i,s} = x_i + u_{i,s}`` per pair, and keeps
only ``U_i = Σ_s u_{i,s}``; constraint node ``s`` keeps ``V_s = Σ_{i∈N_s} u_{i,s}``. Since
``Σ_i z_{i,s} = Σ_i x_i + V_s``, the iterates equal those of the per-pair form in exact arithmetic (and ``V_s = 0``
after the first iteration, Boyd et al. 2011 §7.1). Every round's receiver needs only the *sum* of its messages, so
each round is a fused mixer round (``ex.mixer`` with 0/1 weights: one sparse product); the form refuses a fault
schedule (:func:`~distnav.algorithms.lsq.driver.prepare`), since a lost message corrupts the sums for good.

**Memory** (issue 30). A block holds, per node, the x-update's gains and ``p``-wide state vectors, and per edge
into or out of ``C`` one entry of the two mixers' matrices — nothing per pair of width ``p``. The mixers' edge
weights are one read-only broadcast 1.0 (the active masks zero the rest); once built, each mixer drops what only a
fault round reads (fault schedules are refused) and the two share one array of ones and their message counts
(:func:`_lean`). An iteration holds five ``p``-wide arrays across it and one more at a time: the elementwise
updates of ``U`` and ``V`` run a chunk of rows at a time, and the monitored iterations form the pair residuals
``‖x_i − z_s‖`` from the columns the x-round's transport fills (the block's own values and its halo), a chunk of
pairs at a time in the free ``z^[k] − z^[k−1]`` buffer, instead of a full-length inbox of ``p`` floats per in-edge.
Every element's operations, and every sum's terms and order, are those of one pass (the iterates and residuals are
bitwise those of the unchunked form).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator

import numpy as np

from distnav.algorithms.lsq.kernel import AdmmState, _dual_sq, _times_W
from distnav.exchange import Exchange
from distnav.exchange.mixer import Mixer
from distnav.network.constraint_nodes import ConstraintNodes
from distnav.network.weights import ConsensusWeights

__all__: list[str] = []

_XUpdateFn = Callable[[np.ndarray, np.ndarray], np.ndarray]

#: Pairs per chunk of a monitored iteration's residual (a few MB of ``p``-wide temporaries).
_PAIR_CHUNK = 1 << 16


class _Rounds:
    """The two message rounds of the aggregated form on one block and what they are summed by: ``mix_x`` (``x_i``
    into the constraint nodes, self-weight 1 there), ``mix_z`` (``z_s`` out of them), every local node's ``inC``,
    ``count`` ``c_i = |N_i ∩ C|`` (``i`` itself counted when ``i ∈ C``) and ``size`` ``|N_s| + 1``."""

    def __init__(self, mix_x: Mixer, mix_z: Mixer, inC: np.ndarray, count: np.ndarray, size: np.ndarray) -> None:
        self.mix_x, self.mix_z, self.inC, self.count, self.size = mix_x, mix_z, inC, count, size


def rounds_on_graph(ex: Exchange, C: ConstraintNodes) -> _Rounds:
    """:class:`_Rounds` of an exchange on the whole graph (in-process, or MPI with the graph on every rank)."""
    g = ex.graph
    inC = C.mask
    # the same 0/1 weights as before (1 on the active edges, the self-weight 1 at constraint nodes) without an
    # edge-sized float array per mixer: the inactive edges' weights are zeroed by the masks. One mixer at a time,
    # each made lean (:func:`_lean`) before the next is built
    ones = np.broadcast_to(np.float64(1.0), (g.n_edges,))
    inC_f = inC.astype(float)
    to_c = inC[g.dst] & (g.src != g.dst)  # i→s, s ∈ C: the x-round
    mix_x = _lean(ex.mixer(ConsensusWeights(g, ones, inC_f, name="sum into C"), active=to_c))
    del to_c
    from_c = inC[g.src] & (g.src != g.dst)  # s→i, s ∈ C: the z-round
    mix_z = _lean(ex.mixer(ConsensusWeights(g, ones, inC_f, name="sum from C"), active=from_c), mix_x)
    del from_c
    return _Rounds(mix_x, mix_z, inC[ex.nodes], C.per_node_count[ex.nodes], _sizes(ex))


def _lean(mix: Mixer, other: Mixer | None = None) -> Mixer:
    """``mix`` without what only a fault round reads (fault schedules are refused), and, with ``other`` (the
    round's other 0/1 mixer), one array of ones for both: :meth:`Mixer.drop_fault_state`, :meth:`Mixer.share_with`."""
    mix.drop_fault_state()
    if other is not None:
        mix.share_with(other)
        other.share_with(mix)
    return mix


def rounds_on_part(ex: Exchange, inC_part: np.ndarray) -> _Rounds:
    """:class:`_Rounds` of an exchange built from a graph part, ``inC_part`` the constraint nodes among the part's
    nodes (part order): the halo's membership comes by one transport of the block's own (a set-up round, not
    counted), and the rounds' masks are over the block's own edge rows — no array over the whole network."""
    part = ex.part
    assert part is not None
    rows = ex.part_rows()  # (made once: on a part in its own order the identity is made when asked)
    node_pos = rows[1]
    inC = np.asarray(inC_part, bool)[node_pos]
    inC_col = np.array(ex.node_columns(inC.astype(float)[:, None])[:, 0] > 0.5)  # [local | halo]
    # a part without self-loops (the builders' default) has no in- or out-edge to leave out of a round
    loops = part.self_loops
    x_in = inC[ex.in_dst]
    z_in = inC_col[ex.in_src_col]
    if loops:
        real_in = ex.in_src_col != ex.local_col[ex.in_dst]
        x_in &= real_in
        z_in &= real_in
        del real_in
    # the sent counts without the out-edge tables (every link runs both ways): a node sends into C on as many links
    # as it receives on from C (the z-round's received counts), a constraint node out of C on all its real links
    from_c = np.bincount(ex.in_dst[z_in], minlength=ex.n_local)
    degree = part.degree[node_pos]  # (a part's degrees leave the self-loop out)
    # 0/1 weights on the part (one broadcast 1.0, zeroed off the masks); the masks are over the block's own edge
    # rows, which Exchange.mixer (a mask over the whole graph's edges) does not take: the mixer is made directly
    ones = np.broadcast_to(np.float64(1.0), (part.n_local_edges,))
    self_w = np.asarray(inC_part, float)
    mix_x = Mixer(ex, ones, self_w, (x_in, None), rows=rows, sent_counts=from_c)
    del x_in
    mix_z = Mixer(ex, ones, self_w, (z_in, None), rows=rows, sent_counts=np.where(inC, degree, 0).astype(np.int64))
    del z_in
    count = from_c + inC  # c_i: constraint senders (and i ∈ C)
    size = degree + 1.0  # |N_s| + 1
    return _Rounds(mix_x, mix_z, inC, count.astype(np.int64), size)


def _sizes(ex: Exchange) -> np.ndarray:
    """``|N_s| + 1`` of every local node (its real in-edges and itself)."""
    sender_is_self = ex.in_src_col == ex.local_col[ex.in_dst]
    return (np.bincount(ex.in_dst, weights=~sender_is_self, minlength=ex.n_local) + 1).astype(float)


class _AggregatedKernel:
    """Fig. 6 with aggregated messages on one exchange block (fault-free); ``x_update`` maps ``(l, x_prev)`` to the
    new ``x`` for the block."""

    def __init__(self, ex: Exchange, rounds: _Rounds, W: np.ndarray, p: int, x_update: _XUpdateFn) -> None:
        self.ex, self.W, self.p, self.x_update = ex, W, p, x_update
        self.w_scale = float(np.linalg.eigvalsh(W).max())
        self.w_iso = float(W[0, 0]) if np.array_equal(W, W[0, 0] * np.eye(p)) else None
        self.mix_x, self.mix_z = rounds.mix_x, rounds.mix_z
        _lean(self.mix_x)
        _lean(self.mix_z, self.mix_x)  # (made lean already on a whole graph: then a no-op)
        self.inC_loc = rounds.inC
        self.size_s = rounds.size
        self.count_f = rounds.count.astype(float)  # c_i (the same values as the integer counts)

    def run(self, x0: np.ndarray, z0: np.ndarray, monitor_every: int) -> Iterator[AdmmState]:
        """The iterations from ``x0``, ``z0`` (``u^[−1] = 0``, §4.3).

        Five ``p``-wide arrays live across an iteration (``x``, ``z``, ``U``, ``V``, ``zsum``) and one more at a time
        (the new ``x`` or ``z``, ``l``, ``xsum`` — turned into ``z^[k] − z^[k−1]`` on a monitored iteration, released
        before the z-round on the others; a caller holding the last state keeps its ``x`` and ``z`` too): the
        elementwise updates of ``U`` and ``V`` run a chunk of rows at a time (:func:`_rowwise`), which leaves every
        element's operations, and so its bits, as in one pass."""
        cm = self.inC_loc[:, None]  # a 0/1 factor: bool, cast to 0.0/1.0 by each product (the same bits)
        cnt = self.count_f[:, None]  # (1 / c and [s ∈ C] / |N_s| are made when used: the same values)
        size = self.size_s[:, None]
        x = x0  # the caller's fresh rows (the driver's copies): taken over, not copied again
        z = z0 * cm
        del x0, z0
        # initialization rounds: z_s^[0] from constraint nodes, x_i^[0] to constraint nodes
        zsum = self.mix_z.apply(z)
        xsum = self.mix_x.apply(x)
        U = np.zeros_like(x)
        V = np.empty_like(x)
        _rowwise(_v_first, V, xsum, size, z, cm)  # Σ_i u^[0]_{i,s} with u^[−1] = 0
        xsum[...] = 0.0  # dz of state 0
        yield self._state(0, x, z, xsum, U, cnt, zsum)
        del xsum
        k = 0
        while True:
            k += 1
            monitored = bool(monitor_every) and k % monitor_every == 0
            _rowwise(_u_step, U, cnt, x, zsum)  # U += cnt x − zsum: Σ_s of the u-updates
            l = np.subtract(zsum, U)
            l *= 1.0 / cnt  # l = (zsum − U) / c
            del zsum  # the next one comes with z_new
            x = self.x_update(l, x)
            del l
            xsum = self.mix_x.apply(x)
            z_new = np.add(xsum, V)  # a fresh array: a yielded state's x and z are never written again
            z_new *= cm / size  # z_new = (xsum + V) / |N_s| at constraint nodes
            _rowwise(_v_step, V, xsum, size, z_new, cm)  # V += (xsum − |N_s| z_new) at constraint nodes
            # z^[k] − z^[k−1] only where the residuals are formed: an unmonitored iteration lets the x-sum's buffer
            # go before the z-round's product (one p-wide array less at its peak)
            dz = np.subtract(z_new, z, out=xsum) if monitored else None
            del xsum
            z = z_new
            del z_new
            zsum = self.mix_z.apply(z)
            if dz is not None:
                yield self._state(k, x, z, dz, U, cnt, zsum)
            else:
                yield AdmmState(k, x, z, np.nan, np.nan, np.nan, np.nan, np.nan)
            del dz

    def _pair_sq(self, x: np.ndarray, z: np.ndarray, scratch: np.ndarray) -> float:
        """``Σ_{s∈C} Σ_{i∈N_s, i≠s} ‖x_i − z_s‖²`` on this block, from the x-round's columns (the block's own ``x``
        and its halo: what the constraint nodes received), a chunk of in-edges at a time — at most
        :data:`_PAIR_CHUNK` and at most the block's node count, so each chunk's differences fit in the rows of
        ``scratch`` (a free ``(n_local, p)`` buffer) and the temporaries scale with the block, not with a fixed
        chunk (a 10⁴-node block's peak was a 65,536-pair chunk's). The chunk's sums are added in chunk order, so the
        monitored residuals' last bits depend on the chunk size (the iterates do not)."""
        ex = self.ex
        cols = ex.node_columns(x)  # the values the x-round delivers (monitoring: read again, counted once)
        total = 0.0
        step = max(min(_PAIR_CHUNK, scratch.shape[0]), 1)  # in-edges per chunk: its pairs fit in the scratch rows
        for a in range(0, ex.in_dst.size, step):
            dst, src_col = ex.in_dst[a : a + step], ex.in_src_col[a : a + step]
            pair = self.inC_loc[dst] & (src_col != ex.local_col[dst])  # i→s, s ∈ C, i ≠ s
            src_p, dst_p = src_col[pair], dst[pair]
            if src_p.size <= scratch.shape[0]:
                d = np.take(cols, src_p, axis=0, out=scratch[: src_p.size], mode="clip")  # (valid indices)
            else:
                d = np.take(cols, src_p, axis=0)
            for c in range(0, dst_p.size, _ROW_CHUNK):  # elementwise: z's rows taken a sub-chunk at a time
                d[c : c + _ROW_CHUNK] -= np.take(z, dst_p[c : c + _ROW_CHUNK], axis=0)
            total += float(np.einsum("ij,ij->", d, d))
        return total

    def _state(
        self, k: int, x: np.ndarray, z: np.ndarray, dz: np.ndarray, U: np.ndarray, cnt: np.ndarray, zsum: np.ndarray
    ) -> AdmmState:
        """The monitored state. ``dz`` (``z^[k] − z^[k−1]``) is the scratch buffer of the other sums once the dual
        one is taken: ``U + c x − zsum`` (the next ``U``), then ``(x − z)`` at the constraint nodes."""
        size_c = self.size_s * self.inC_loc  # |N_s| + 1 at constraint nodes, 0 elsewhere (made when monitored)
        dual_sq = _dual_sq(dz, size_c, self.W, self.w_iso, self.w_scale)
        U_next = _u_next(U, cnt, x, zsum, out=dz)
        if self.w_iso is not None:
            WU = np.multiply(U_next, self.w_iso, out=U_next)
        else:
            WU = _times_W(U_next, self.W, self.w_iso)
        u_sq = np.einsum("ij,ij->", WU, WU)
        del WU, U_next
        ds = np.subtract(x, z, out=dz)
        ds *= self.inC_loc[:, None]
        self_sq = np.einsum("ij,ij->", ds, ds)
        del ds
        sums = np.array(
            [
                self._pair_sq(x, z, dz) + self_sq,
                dual_sq,
                np.einsum("i,ij,ij->", self.count_f, x, x),
                np.einsum("i,ij,ij->", size_c, z, z),
                u_sq,
            ]
        )
        tot = np.sqrt(np.asarray(self.ex.allreduce(sums, "sum")))
        return AdmmState(k, x, z, float(tot[0]), float(tot[1]), float(tot[2]), float(tot[3]), float(tot[4]))


def _u_next(U: np.ndarray, cnt: np.ndarray, x: np.ndarray, zsum: np.ndarray, *, out: np.ndarray) -> np.ndarray:
    """``U + c x − zsum`` (the next ``U``, for the dual norm) in ``out``, evaluated as ``(U + c x) − zsum``."""
    np.multiply(cnt, x, out=out)
    np.add(U, out, out=out)
    out -= zsum
    return out


#: Rows per chunk of an elementwise update (:func:`_rowwise`: its temporaries are a chunk's, not the block's).
_ROW_CHUNK = 2048


def _rowwise(step: Callable[..., None], target: np.ndarray, *args: np.ndarray) -> None:
    """``step(target[a:b], *(arg[a:b] for arg in args))`` over chunks of :data:`_ROW_CHUNK` rows: an elementwise
    update whose temporaries are a chunk's. Each element sees the same operations as in one pass (bitwise)."""
    for a in range(0, target.shape[0], _ROW_CHUNK):
        b = a + _ROW_CHUNK
        step(target[a:b], *(arg[a:b] for arg in args))


def _u_step(U: np.ndarray, cnt: np.ndarray, x: np.ndarray, zsum: np.ndarray) -> None:
    """``U += (c x − zsum)`` in place."""
    t = np.multiply(cnt, x)
    t -= zsum
    U += t


def _v_first(V: np.ndarray, xsum: np.ndarray, size: np.ndarray, z: np.ndarray, cm: np.ndarray) -> None:
    """``V = (xsum − |N_s| z) · [s ∈ C]`` (state 0, ``u^[−1] = 0``) in place."""
    t = size * z
    np.subtract(xsum, t, out=t)
    np.multiply(t, cm, out=V)


def _v_step(V: np.ndarray, xsum: np.ndarray, size: np.ndarray, z_new: np.ndarray, cm: np.ndarray) -> None:
    """``V += (xsum − |N_s| z_new) · [s ∈ C]`` in place."""
    t = np.multiply(size, z_new)
    np.subtract(xsum, t, out=t)
    t *= cm
    V += t
