"""The Fig. 6 kernel of ADMM with constraint nodes (paper 000 §4) on one exchange block.

:class:`XUpdate` is the linear x-update (eqs. (20)/(21)); :class:`AdmmState` what an iteration yields; the private
``_Kernel`` runs the iterations as message rounds with per-pair messages exactly as Fig. 6 and holds the last value
received on every edge when messages are lost (aggregated messages: :mod:`distnav.algorithms.lsq.aggregated`). The
x-update lives in :mod:`distnav.algorithms.lsq.xupdate` (re-exported here). The front doors are
:func:`distnav.algorithms.lsq.admm.admm` and :func:`~distnav.algorithms.lsq.admm.iterate_admm`; the module docstring of
:mod:`distnav.algorithms.lsq.admm` describes the iteration and the weighting of the x-update.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from distnav._optional import scipy_sparse as sp
from distnav.algorithms.lsq.delta_codec import DeltaCodec
from distnav.algorithms.lsq.xupdate import XUpdate, XUpdateMethod
from distnav.errors import ModelError
from distnav.exchange import Exchange
from distnav.network.constraint_nodes import ConstraintNodes

if TYPE_CHECKING:
    from distnav.exchange.route import Route

__all__ = ["AdmmState", "Multipliers", "XUpdate", "XUpdateMethod"]


# ----------------------------------------------------------------------------------------------- kernel
@dataclass(frozen=True, eq=False)
class Multipliers:
    """The scaled multipliers of one exchange block after a per-pair run: ``pairs`` ``u_{i,s}`` (one row per pair
    ``s ≠ i``, in the kernel's pair order) and ``self_pairs`` ``u_{s,s}`` (zero rows off ``C``). Block-local state:
    valid only for the same exchange block, constraint nodes and parameter count."""

    pairs: np.ndarray
    self_pairs: np.ndarray

    def copy(self) -> Multipliers:
        return Multipliers(self.pairs.copy(), self.self_pairs.copy())


@dataclass(frozen=True, eq=False)
class AdmmState:
    """After iteration ``k`` (``k = 0``: the initial values) of Fig. 6, for this exchange block.

    ``x`` ``(n_local, p)`` local states; ``z`` ``(n_local, p)`` consensus states (rows of non-constraint nodes are 0);
    ``primal_residual`` ``sqrt(Σ_pairs ‖x_i − z_s‖²)``; ``dual_residual`` ``sqrt(Σ_pairs ‖W(z_s^[k] − z_s^[k−1])‖²)``;
    ``x_norm``, ``z_norm``: pair norms ``sqrt(Σ_pairs ‖·‖²)``; ``u_norm``: ``sqrt(Σ_i ‖W Σ_s u_{i,s}‖²)`` (at the
    solution ``W Σ_s û_{i,s} = r_i − N_i x̂``, eq. (9)), for relative stopping. Residuals and norms
    are network totals (``ex.allreduce``: monitoring only).
    """

    iteration: int
    x: np.ndarray
    z: np.ndarray
    primal_residual: float
    dual_residual: float
    x_norm: float
    z_norm: float
    u_norm: float


def _per_node(value: Any, n: int, p: int, what: str) -> np.ndarray:
    arr = np.asarray(value, dtype=float)
    if arr.ndim == 0:
        arr = np.full(p, float(arr))
    if arr.shape == (p,):
        return np.broadcast_to(arr, (n, p)).copy()
    if arr.shape == (n, p):
        return arr.copy()
    raise ModelError(f"{what} must be a scalar, a length-{p} vector or an ({n}, {p}) array, got shape {arr.shape}")


class _Kernel:
    """Fig. 6 on one exchange block; ``x_update`` maps ``(l, x_prev)`` to the new ``x`` for the block.

    ``z_weight`` (global, one per node, or None): the z-update of constraint node ``s`` becomes the weighted mean
    ``Σ_{i∈N_s} w_i z_{i,s} / Σ_{i∈N_s} w_i`` instead of the plain one; with ``w_i = 1/c_i`` it is the z-update of
    the Lagrangian with pair weights ``W/c_i`` (``x_weight="fig6-zweighted"``, per-pair messages only). The weights
    are structural (the constraint neighbours' ``c_i``), known from the graph like the pairs themselves.
    """

    def __init__(
        self,
        ex: Exchange,
        C: ConstraintNodes,
        W: np.ndarray,
        p: int,
        x_update: Callable[[np.ndarray, np.ndarray], np.ndarray],
        z_weight: np.ndarray | None = None,
    ) -> None:
        g = ex.graph
        self.ex = ex
        self.W = W
        self.w_scale = float(np.linalg.eigvalsh(W).max())
        self.p = p
        self.x_update = x_update
        inC = C.mask
        self.inC_global = inC
        nodes = ex.nodes
        nl = ex.n_local
        self.inC_loc = inC[nodes]
        real = g.src != g.dst
        self.to_c = inC[g.dst] & real
        self.from_c = inC[g.src] & real
        # pairs (i, s), s ≠ i: one per in-edge s→i with s ∈ C (z_s arrives there); u_{i,s} lives here at node i.
        # Per-pair arrays hold one row per pair in this order (in-edge order: grouped by receiver, senders
        # ascending), and the two message rounds are prepared routes on these compact arrays. The masks are the
        # graph's per-edge ones read at the block's edges (no per-edge sender/receiver ids needed).
        self.z_route = ex.route(self.from_c)  # step 2: z_s to the pairs (i, s), on in-edge rows ascending
        self.ip = self.z_route.in_rows
        self.pair_dst = ex.in_dst[self.ip]
        n_pairs = self.ip.size
        self.count = np.bincount(self.pair_dst, minlength=nl) + self.inC_loc  # c_i = |N_i ∩ C|
        # outgoing z_{i,s} on edges i→s, s ∈ C: the pair's row is that of the reverse in-edge s→i
        op = np.flatnonzero(self.to_c[ex.out_edges])
        idx = _index_dtype(n_pairs)  # set-up temporaries in int32 where they fit (half the memory to touch)
        lookup = np.full(g.n_edges, -1, dtype=idx)
        lookup[ex.in_edges[self.ip]] = np.arange(n_pairs, dtype=idx)
        op_pair = lookup[g.reverse_edge[ex.out_edges[op]]]
        del lookup
        if op.size != n_pairs or (op_pair < 0).any():  # pragma: no cover - guaranteed by symmetric graphs
            raise ModelError("pair edges are not symmetric in this exchange block")
        send_rows = np.empty(n_pairs, dtype=np.int64)
        send_rows[op_pair] = op  # the out-edge row of each pair, in pair order: z_{i,s} is sent as it is computed
        self.x_route = ex.route(self.to_c, out_rows=send_rows)  # step 1: z_{i,s} to the constraint nodes
        # one array of ones serves as the data of both 0/1 summing matrices (never written)
        ones = np.ones(max(n_pairs, self.x_route.in_rows.size))
        ones.setflags(write=False)
        self.S_pairs = _rows_in_order(self.pair_dst, nl, ones=ones)
        self._u: tuple[np.ndarray, np.ndarray] | None = None
        # at constraint node s: z_{i,s} arrives on in-edges i→s (rows of x_route.in_rows); each row of the z-update
        # sums them in in-edge order (senders ascending), whatever order the route returns them in
        recv_rows = self.x_route.in_rows
        self.recv_dst = ex.in_dst[recv_rows]
        if recv_rows is send_rows:  # in-process: received in pair order; ascending rows are the op order
            by_edge = op_pair
        elif recv_rows.size < 2 or bool((recv_rows[1:] > recv_rows[:-1]).all()):
            by_edge = np.arange(recv_rows.size)
        else:  # routes return ascending rows or the caller's order; anything else is sorted
            by_edge = np.argsort(recv_rows, kind="stable")
        self.S_c = _rows_in_order(self.recv_dst[by_edge], nl, by_edge, ones=ones)
        self.size_s = (np.bincount(self.recv_dst, minlength=nl) + 1).astype(float)  # |N_s|
        self.w_iso = float(W[0, 0]) if np.array_equal(W, W[0, 0] * np.eye(p)) else None
        self.size_c = self.size_s * self.inC_loc
        self.count_f = self.count.astype(float)
        self.z_weight: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        if z_weight is not None:
            w_in = z_weight[ex.in_src[recv_rows]]  # on the rows z_{i,s} arrives on (i→s, s ∈ C)
            w_self = z_weight[nodes] * self.inC_loc
            total = self.S_c @ w_in + w_self
            inv_total = np.divide(1.0, total, out=np.zeros_like(total), where=self.inC_loc)
            self.z_weight = (w_in[:, None], w_self[:, None], inv_total[:, None])

    def run(
        self,
        x0: np.ndarray,
        z0: np.ndarray,
        monitor_every: int = 1,
        u0: Multipliers | None = None,
        *,
        bits: int | None = None,
    ) -> Iterator[AdmmState]:
        """Fig. 6 with per-pair messages from ``x0``, ``z0`` and multipliers ``u0`` (default ``u^[−1] = 0``, §4.3);
        :attr:`multipliers` follows the run (a warm start of a changed problem continues from them). ``bits``:
        every message after the first of each stream as ``bits``-bit deltas with error feedback
        (:mod:`~distnav.algorithms.lsq.delta_codec`; no fault schedule)."""
        cm = self.inC_loc[:, None].astype(float)  # 1 on constraint-node rows
        inv_count = 1.0 / self.count[:, None]
        inv_size = cm / self.size_s[:, None]
        x = x0.copy()
        z = z0 * cm
        # Per-pair state is compact (one row per pair); the routes deliver straight into it. Without faults every
        # message on a route arrives and the received array *is* the held value; with faults a preallocated held
        # buffer takes the delivered rows in place. Sums run over the same entries in the same order as over the
        # full in-edge arrays of before (bitwise equal). Three pair-sized arrays (u, z_buf, x_p) serve as the
        # four of the iteration's pair values: x_p holds x_i, then x_i − z_s, then u_{i,s} + x_i − z_s (a monitored
        # state forms the next u there, and the u-update swaps it in) or z_s − u_{i,s}; z_buf holds z_s and, between
        # its last read and the next broadcast, z_{i,s} = x_i + u_{i,s} (same values, one 100 MB array less at 10⁵
        # nodes for the first iteration to fault in).
        n_pairs = self.ip.size
        u, u_self = self._u = self._initial_multipliers(u0, x)
        faulty = self.ex.faults.active
        x_p = _take(x, self.pair_dst)  # x_i on every pair row: computed once per x-update, used twice
        # until z_s arrives, a node assumes its own x_i^[0]; until z_{i,s} arrives, s assumes its own z_s^[0]
        held_z = x_p.copy() if faulty else None
        held_c = _take(z, self.recv_dst) if faulty else None
        z_buf = np.empty((n_pairs, self.p))
        coded = _CodedRoutes(self.x_route, self.z_route, bits) if bits is not None else None
        # initialization round: constraint nodes send z_s^[0] to their neighbours
        z_recv = self._broadcast_z(coded, held_z, z, z_buf)
        # x_p is not read again before the next x-update overwrites it, so the pair residuals x_i − z_s take its
        # buffer (one pair-sized array less to allocate and touch)
        diff = np.subtract(x_p, z_recv, out=x_p)
        diff_self = (x - z) * cm
        pre_added = u0 is not None  # the state formed u + (x_i − z_s) in diff's buffer (a cold start: u = 0)
        yield self._state(0, x, z, diff, diff_self, np.zeros_like(z), u, u_self, add_in_place=pre_added)
        k = 0
        while True:
            k += 1
            # step 1: u-update, l, x-update, send z_{i,s} = x_i + u_{i,s} to constraint neighbours
            if pre_added:  # u + (x_i − z_s), formed by the monitored state: the u-update, bitwise
                u, x_p = x_p, u
                self._u = (u, u_self)
            else:
                u += diff
            u_self += diff_self
            np.subtract(z_recv, u, out=x_p)  # x_p is free until the x-update
            l = self.S_pairs @ x_p
            l += z
            l -= u_self
            l *= inv_count
            x = self.x_update(l, x)
            _take(x, self.pair_dst, out=x_p)
            # z_buf is free between the last read of z_s (above) and the broadcast below
            np.add(x_p, u, out=z_buf)
            zin_c = coded.send_x(z_buf) if coded is not None else _held(held_c, *self.x_route.send(z_buf))
            # step 2: z-update at constraint nodes, broadcast z_s
            z_new = self._z_update(zin_c, x, u_self, inv_size)
            dz = z_new - z
            z = z_new
            z_recv = self._broadcast_z(coded, held_z, z, z_buf)
            diff = np.subtract(x_p, z_recv, out=x_p)
            np.subtract(x, z, out=diff_self)
            diff_self *= cm
            pre_added = bool(monitor_every) and k % monitor_every == 0
            if pre_added:
                yield self._state(k, x, z, diff, diff_self, dz, u, u_self, add_in_place=True)
            else:
                yield AdmmState(k, x, z, np.nan, np.nan, np.nan, np.nan, np.nan)

    def _initial_multipliers(self, u0: Multipliers | None, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``u_{i,s}`` (pair order) and ``u_{s,s}``: zero (``u^[−1] = 0``, §4.3) or copied from ``u0``."""
        u = np.zeros((self.ip.size, self.p))
        u_self = np.zeros_like(x)  # u_{s,s}; zero on rows of non-constraint nodes, and stays so
        if u0 is not None:
            if u0.pairs.shape != u.shape or u0.self_pairs.shape != u_self.shape:
                raise ModelError(
                    "the multipliers to continue from belong to another exchange block, constraint-"
                    "node set or parameter count"
                )
            u[:] = u0.pairs
            u_self[:] = u0.self_pairs
        return u, u_self

    def _broadcast_z(
        self, coded: _CodedRoutes | None, held_z: np.ndarray | None, z: np.ndarray, z_buf: np.ndarray
    ) -> np.ndarray:
        """Constraint nodes send ``z_s`` to their neighbours; ``z_s`` on every pair row (held where lost)."""
        if coded is not None:
            return coded.broadcast_z(z)
        return _held(held_z, *self.z_route.broadcast(z, out=z_buf))

    def _z_update(self, zin_c: np.ndarray, x: np.ndarray, u_self: np.ndarray, inv_size: np.ndarray) -> np.ndarray:
        """Fig. 6 step 2 at the constraint nodes: the (weighted) mean of the received ``z_{i,s}`` and ``x_s +
        u_{s,s}``."""
        if self.z_weight is None:
            z_new: np.ndarray = self.S_c @ zin_c
            z_new += x
            z_new += u_self
            z_new *= inv_size
            return z_new
        w_in, w_self, inv_total = self.z_weight
        z_new = self.S_c @ (zin_c * w_in)
        z_new += (x + u_self) * w_self
        z_new *= inv_total
        return z_new

    @property
    def multipliers(self) -> Multipliers | None:
        """This block's ``u_{i,s}`` (pair order) and ``u_{s,s}`` now (None before :meth:`run` started)."""
        if self._u is None:
            return None
        u, u_self = self._u
        return Multipliers(u.copy(), u_self.copy())

    def _dual_sq(self, dz: np.ndarray) -> float:
        return _dual_sq(dz, self.size_c, self.W, self.w_iso, self.w_scale)

    def _times_W(self, a: np.ndarray) -> np.ndarray:
        return _times_W(a, self.W, self.w_iso)

    def _state(
        self,
        k: int,
        x: np.ndarray,
        z: np.ndarray,
        diff_pair: np.ndarray,
        diff_self: np.ndarray,
        dz: np.ndarray,
        u: np.ndarray,
        u_self: np.ndarray,
        add_in_place: bool,
    ) -> AdmmState:
        """The monitored state. ``add_in_place``: ``u + diff_pair`` is formed in ``diff_pair``'s buffer (the run's
        next u-update takes it from there); else ``u`` is all zero (the first state of a cold start: ``0 + d`` is
        ``d`` bitwise but for the sign of a zero, which the sum into rows, started at +0, and the square both drop)
        and ``diff_pair`` is used as it is. The residual sums are taken before it is overwritten."""
        primal_sq = np.einsum("ij,ij->", diff_pair, diff_pair) + np.einsum("ij,ij->", diff_self, diff_self)
        u_next = np.add(u, diff_pair, out=diff_pair) if add_in_place else diff_pair
        # einsum, not BLAS: tiny BLAS calls are slow when the BLAS thread pool is contended
        sums = np.array(
            [
                primal_sq,
                self._dual_sq(dz),
                np.einsum("i,ij,ij->", self.count_f, x, x),
                np.einsum("i,ij,ij->", self.size_c, z, z),
                _sq_rows(self._times_W(self.S_pairs @ u_next + u_self + diff_self)),
            ]
        )
        tot = np.sqrt(np.asarray(self.ex.allreduce(sums, "sum")))
        return AdmmState(k, x, z, float(tot[0]), float(tot[1]), float(tot[2]), float(tot[3]), float(tot[4]))


def _dual_sq(dz: np.ndarray, size_c: np.ndarray, W: np.ndarray, w_iso: float | None, w_scale: float) -> float:
    """``Σ_pairs ‖W (z_s^[k] − z_s^[k−1])‖²`` (every constraint node ``s`` is in ``|N_s|`` pairs: ``size_c``)."""
    if w_iso is not None:
        return float(w_scale**2 * np.einsum("i,ij,ij->", size_c, dz, dz))
    Wdz = _times_W(dz, W, w_iso)
    return float(np.einsum("i,ij,ij->", size_c, Wdz, Wdz))


def _times_W(a: np.ndarray, W: np.ndarray, w_iso: float | None) -> np.ndarray:
    return a * w_iso if w_iso is not None else np.einsum("ij,jk->ik", a, W)


def _index_dtype(size: int) -> type[np.signedinteger[Any]]:
    return np.int32 if size < 2**31 - 1 else np.int64


def _rows_in_order(
    rows: np.ndarray, n_rows: int, columns: np.ndarray | None = None, ones: np.ndarray | None = None
) -> sp.csr_matrix:
    """0/1 CSR matrix ``(n_rows, len(rows))`` summing entry ``q`` (column ``columns[q]``, default ``q``) into row
    ``rows[q]``; ``rows`` ascending. Each row keeps its entries in the given order, and a product sums them in it.
    ``ones``: a read-only array of at least ``len(rows)`` ones to take the data from (shared, not copied)."""
    idx = _index_dtype(rows.size)
    cols = np.arange(rows.size, dtype=idx) if columns is None else np.asarray(columns, idx)
    ptr = np.zeros(n_rows + 1, dtype=np.int64)
    np.cumsum(np.bincount(rows, minlength=n_rows), out=ptr[1:])
    data = np.ones(rows.size) if ones is None else ones[: rows.size]
    return sp.csr_matrix((data, cols, ptr.astype(idx)), shape=(n_rows, rows.size))


def _held(held: np.ndarray | None, values: np.ndarray, delivered: np.ndarray) -> np.ndarray:
    """The value held on every in-edge after a round: without faults (``held`` None) the inbox itself; else the
    delivered rows copied into ``held`` in place (a lost message keeps the previous value)."""
    if held is None:
        return values
    np.copyto(held, values, where=delivered[:, None])
    return held


def _take(a: np.ndarray, index: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """Rows ``a[index]`` (into ``out`` when given). ``mode="clip"`` (the indices are always valid here) lets numpy
    write straight into ``out``; the default ``mode="raise"`` goes through a temporary copy, ~5× slower."""
    return np.take(a, index, axis=0, out=out, mode="clip")


def _sq_rows(a: np.ndarray) -> float:
    return float(np.einsum("ij,ij->", a, a))


class _CodedRoutes:
    """The two message rounds of a per-pair run with coded messages (:mod:`~distnav.algorithms.lsq.delta_codec`):
    each stream's first message in full, then ``bits``-bit deltas; returns the receivers' reconstructions."""

    def __init__(self, x_route: Route, z_route: Route, bits: int) -> None:
        self.x_route, self.z_route = x_route, z_route
        self.tx_x, self.rx_x = DeltaCodec(bits), DeltaCodec(bits)
        self.tx_z, self.rx_z = DeltaCodec(bits), DeltaCodec(bits)

    def send_x(self, values: np.ndarray) -> np.ndarray:
        return _coded_round(self.tx_x, self.rx_x, values, lambda v: self.x_route.send(v)[0])

    def broadcast_z(self, values: np.ndarray) -> np.ndarray:
        return _coded_round(self.tx_z, self.rx_z, values, lambda v: self.z_route.broadcast(v)[0])


def _coded_round(
    tx: DeltaCodec, rx: DeltaCodec, values: np.ndarray, transmit: Callable[[np.ndarray], np.ndarray]
) -> np.ndarray:
    """One round of a coded stream: the first message in full, then the coded delta; the receivers' copy."""
    if not tx.started:
        tx.start(values)
        rx.start(transmit(values))
    else:
        rx.decode(transmit(tx.encode(values)))
    assert rx.reference is not None
    return rx.reference
