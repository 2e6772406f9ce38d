"""The k-hop sub-network covariance of :mod:`distnav.algorithms.ranging.precision` (its module docstring gives the
formula, ``Q_SS = N_SS⁻¹ + N_SS⁻¹ N_SR (⊕_v Σ_v) N_RS N_SS⁻¹``): the messages that bring every anchor the link
records of its ``hops``-hop neighbourhood, and the dense solve of each anchor's ball.

**What travels** (issue 27; each message counted at the bytes its content needs, ``Exchange.send(message_bytes=…)``,
the rows themselves a fixed-width container padded to the largest degree):

* the anchors' blocks ``Σ`` (:func:`_send_blocks`): packed, the upper triangle of the free coordinates (3 values in
  a 3-D hall with heights held, not ``dim²`` = 9);
* round 1: every *free* anchor's record — its id and, per link, the other end's id, the free coordinates of the
  unit direction ``u``, ``c``, ``Σ w r²``, the sample count and the other end's packed block — to its neighbours
  (a known anchor's record is never used: it sends none);
* round 2 (``hops = 2``): a relay ``i`` sends its neighbour ``j`` the record of a neighbour ``k`` only if ``j``
  lacks it (``k`` is not ``j`` nor ``j``'s neighbour, both free) and ``i`` is the one common neighbour of ``j`` and
  ``k`` that the least hash of ``(i, j, k)`` designates (:func:`_relay_plan`): each 2-hop anchor's record reaches
  ``j`` once, not once per common neighbour, and nothing comes back that ``j`` already holds. One message per
  relayed record. A relayed record carries the other end's block only for links whose end ``v`` may be in ``j``'s
  ring: not where the relay knows ``j`` holds ``v``'s record (:func:`_ring_links`; 12–13 % fewer bytes);
* the record values in :data:`RECORD_DTYPE` (float32): they set ``N_SS`` and the ring's blocks, whose float32
  rounding (6e-8 relative) moves σ by at most 3e-8 relative on the halls of 100–1,000 anchors (docs/economy_uwb.md);
  ids and sample counts as int32 (:data:`ID_BYTES`). The 1-hop block rounds of
  :mod:`~distnav.algorithms.ranging.precision` are packed the same way and stay float64.

Under message loss a record lost on its one designated path is not made up by another relay (before, every common
neighbour relayed it): that anchor's ball lacks the record's anchor, which then counts in its ring — and where the
relay left that anchor's block out, the receiver has no block for it and falls back to its conditional σ.

Before issue 27's fifth session every anchor broadcast ``[id, K × 16 floats]`` (``K`` the largest degree) and, in
round 2, relayed all ``K`` rows it had received to every neighbour: 44 MB on a hall of 100 anchors. Now each anchor
gets the same ball, the same σ up to the float32 rounding, for 28–40 × fewer bytes on halls of 100–1,000 anchors.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg as sla

from distnav.algorithms.ranging.data import RangingData
from distnav.exchange import Exchange, Inbox

VARIANCE_FLOOR = 1.0 / 16.0
MIN_NOISE_SHARE = 0.1  # as distnav.models.uwb.precision: the noise keeps at least this share of σ̂²
RECORD_DTYPE: type = np.float32  # the values of the link records and of the blocks they carry, on the wire
ID_BYTES = 4  # an anchor id or a sample count on the wire (int32)


def _send_blocks(
    ex: Exchange, blocks: np.ndarray, free: np.ndarray, dtype: type = np.float64
) -> tuple[np.ndarray, Inbox]:
    """Every local anchor's symmetric ``dim × dim`` block to each neighbour, packed: the upper triangle of its free
    coordinates, ``nf (nf + 1) / 2`` values of ``dtype`` (the receiver knows the free masks and mirrors it; zeros
    elsewhere, as :func:`~distnav.algorithms.ranging.qc.free_block_inverses` leaves them).
    ``(the blocks as sent — upper triangle mirrored —, the inbox: one flattened block per in-edge)``."""
    nl = blocks.shape[0]
    sym = np.triu(blocks) + np.swapaxes(np.triu(blocks, 1), 1, 2)
    with np.errstate(over="ignore"):  # beyond float32's range (a nearly singular anchor's block): inf
        sym = sym.astype(dtype).astype(float)
    nf = free.sum(axis=1)
    size = (np.dtype(dtype).itemsize * nf * (nf + 1) // 2).astype(np.int64)
    return sym, ex.send(sym.reshape(nl, -1)[ex.out_src], message_bytes=size[ex.out_src])


def _subnetwork(
    problem: RangingData,
    ex: Exchange,
    hops: int,
    cov: np.ndarray,
    cond: np.ndarray,
    pos: np.ndarray,
    n_in: int,
    j_own: np.ndarray,
    w: np.ndarray,
    r: np.ndarray,
    free: np.ndarray,
    delay_sigma_m: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray | None]:
    """The k-hop sub-network covariance and variance factor of every local anchor (module docstring).

    Link record of in-edge (i ← v), held by i: ``[v, u (dim), c, Σ w r², samples, Σ_v (dim²)]`` with ``c u uᵀ``
    the link's information (``u`` the unit direction of the own-end Jacobian row, ``c = Σ_s w_s ‖j_s‖²``). One
    message of the final ``Σ`` on every link (packed, :func:`_send_blocks`; the records carry the neighbours'
    blocks), then round 1: every free anchor sends ``[id, its records]`` to its neighbours, round 2 (``hops = 2``):
    each anchor relays to a neighbour ``j`` the records of its own neighbours that ``j`` does not hold, each
    2-hop anchor's record once per neighbourhood (:func:`_relay_plan`). The records travel in a fixed-width
    container (padded to the largest degree); each message counts what its content needs (:func:`_record_bytes`).
    ``(n_in, …)`` arrays follow the in-edges of ``ex``."""
    dim, nl = problem.dim, ex.n_local
    k_max = int(problem.graph.degrees.max(initial=0))
    nb = _send_blocks(ex, cov, free, RECORD_DTYPE)[1]  # every anchor's final Σ to its neighbours
    norm2 = np.einsum("hd,hd->h", j_own, j_own)
    u_in = np.zeros((n_in, dim))
    nz = norm2 > 0
    u_in[pos[nz]] = j_own[nz] / np.sqrt(norm2[nz])[:, None]  # same direction for every sample of a pair
    link = np.concatenate(
        [
            nb.src[:, None].astype(float),
            u_in,
            np.bincount(pos, w * norm2, minlength=n_in)[:, None],
            np.bincount(pos, w * r * r, minlength=n_in)[:, None],
            np.bincount(pos, minlength=n_in).astype(float)[:, None],
            np.where(nb.delivered[:, None], nb.values, np.nan),
        ],
        axis=1,
    )
    fl = np.r_[1 : 3 + dim, 4 + dim : link.shape[1]]  # the values (not the ids, not the sample count)
    with np.errstate(over="ignore"):  # as the wire carries them (inf beyond float32's range)
        link[:, fl] = link[:, fl].astype(RECORD_DTYPE).astype(float)
    width = link.shape[1]
    rows = np.full((nl, 1 + k_max * width), -1.0)
    rows[:, 0] = ex.nodes
    starts = np.flatnonzero(np.r_[True, nb.dst[1:] != nb.dst[:-1]]) if n_in else np.zeros(0, np.int64)
    slot = np.arange(n_in) - np.repeat(starts, np.diff(np.r_[starts, n_in]))  # in-edges grouped by receiver
    flat = rows[:, 1:].reshape(nl, k_max, width)
    flat[nb.dst, slot] = link
    rows[:, 1:] = flat.reshape(nl, -1)
    known: list[list[np.ndarray]] = [[rows[li]] for li in range(nl)]
    g = problem.graph
    sender_free = np.asarray(problem.free.any(axis=1), bool)[g.src] & (g.src != g.dst)  # only theirs are used
    out_rows = rows[ex.out_src]
    first = ex.send(out_rows, active=sender_free, message_bytes=_record_bytes(out_rows, problem.free, k_max))
    del out_rows
    for e in np.flatnonzero(first.delivered & np.asarray(problem.free.any(axis=1), bool)[first.src]):
        known[first.dst[e]].append(first.values[e])
    if hops == 2:
        edge, rank, out_e, in_e, mine = _relay_plan(problem, ex)
        ids = first.values[in_e[:, None], 1 + np.arange(k_max) * width].astype(np.int64)
        drop = ~_ring_links(problem, ex.nodes[ex.out_src[out_e]], ex.out_dst[out_e], ids)
        for t in range(int(rank.max(initial=-1)) + 1):  # one message per relayed record
            act = np.zeros(ex.n_edges, bool)  # the same mask in every block
            act[edge[rank == t]] = True
            sel = rank[mine] == t
            box = np.zeros((ex.out_edges.size, rows.shape[1]))
            recs = np.where(first.delivered[in_e[sel], None], first.values[in_e[sel]], -1.0)
            recs[:, 1:].reshape(-1, k_max, width)[:, :, 4 + dim :][drop[sel]] = np.nan  # blocks the receiver ignores
            box[out_e[sel]] = recs
            second = ex.send(box, active=act, message_bytes=_record_bytes(box, problem.free, k_max))
            del box
            for e in np.flatnonzero(second.delivered & act[second.edges]):
                known[second.dst[e]].append(second.values[e])
    return _solve_balls(problem, ex, known, (k_max, width), cov, cond, free, delay_sigma_m)


def _solve_balls(
    problem: RangingData,
    ex: Exchange,
    known: list[list[np.ndarray]],
    shape: tuple[int, int],
    cov: np.ndarray,
    cond: np.ndarray,
    free: np.ndarray,
    delay_sigma_m: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray | None]:
    """:func:`_solve_ball` for every free local anchor from the records it holds."""
    nl = ex.n_local
    out = cov.copy()
    vf = np.full(nl, np.nan)
    delay = np.zeros_like(cov) if delay_sigma_m > 0 else None
    noise = np.full(nl, np.nan) if delay_sigma_m > 0 else None
    for li in np.flatnonzero(free.any(axis=1)):
        ball = _solve_ball(problem, int(ex.nodes[li]), known[li], *shape, cond[li], problem.n_anchors, delay_sigma_m)
        out[li], vf[li] = ball[0], ball[1]
        if delay is not None and noise is not None:
            delay[li], noise[li] = ball[2], ball[3]
    return out, vf, delay, noise


def _record_bytes(rows: np.ndarray, free: np.ndarray, k_max: int) -> np.ndarray:
    """The bytes each record row of :func:`_subnetwork` needs on the wire (0 for a row of −1s): the anchor's id
    (:data:`ID_BYTES`) and per link the other end's id, ``u``'s free coordinates (the owner's free mask; the
    others are 0), ``c``, ``Σ w r²`` (:data:`RECORD_DTYPE` each), the sample count (:data:`ID_BYTES`) and
    the other end's block packed (:func:`_send_blocks`; nothing for a known anchor, nor where the block is NaN:
    not sent, :func:`_ring_links`)."""
    owner = rows[:, 0].astype(np.int64)
    ids = rows[:, 1:].reshape(rows.shape[0], k_max, -1)[:, :, 0].astype(np.int64)
    nf = free.sum(axis=1)
    valid = ids >= 0
    nf_v = np.where(valid, nf[np.maximum(ids, 0)], 0)
    nf_own = np.where(owner >= 0, nf[np.maximum(owner, 0)], 0)
    block = ~np.isnan(rows[:, 1:].reshape(rows.shape[0], k_max, -1)[:, :, -1])  # not sent where NaN
    packed = np.where(block, nf_v * (nf_v + 1) // 2, 0)
    per_link = 2 * ID_BYTES + np.dtype(RECORD_DTYPE).itemsize * (nf_own[:, None] + 2 + packed)
    size = np.where(owner >= 0, ID_BYTES + np.sum(np.where(valid, per_link, 0), axis=1), 0)
    return np.asarray(size, np.int64)


def _directed_links(problem: RangingData) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Every directed link ``node · n + neighbour`` sorted, the neighbours in that order, and each node's first
    position and count in it."""
    n = problem.n_anchors
    lk = problem.graph.links
    lk = lk[lk[:, 0] != lk[:, 1]]
    key = np.unique(np.concatenate([lk[:, 0] * n + lk[:, 1], lk[:, 1] * n + lk[:, 0]]))
    deg = np.bincount(key // n, minlength=n)
    return key, key % n, np.r_[0, np.cumsum(deg)[:-1]], deg


def _neighbours(start: np.ndarray, deg: np.ndarray, nbr: np.ndarray, of: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(position in of, neighbour)`` of every neighbour of every node of ``of``."""
    d = deg[of]
    at = np.arange(int(d.sum())) - np.repeat(np.cumsum(d) - d, d)
    return np.repeat(np.arange(of.size), d), nbr[np.repeat(start[of], d) + at]


def _ring_links(problem: RangingData, relay: np.ndarray, to: np.ndarray, ids: np.ndarray) -> np.ndarray:
    """Which links ``(k, v)`` of the records relayed ``relay → to`` (``ids``: ``v`` per slot, −1 for none) carry
    ``v``'s block: not where the relay ``c`` knows that the receiver ``j`` holds ``v``'s record — ``v`` is ``c``,
    ``j``, a neighbour of either or of one of their common neighbours ``m`` (``c`` has every such ``m``'s link list
    from round 1): then ``v`` is in ``j``'s ball, never in its ring, where alone a block is read."""
    n = problem.n_anchors
    key, nbr, start, deg = _directed_links(problem)

    def linked(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        ab = a * n + b
        return np.asarray(key[np.minimum(np.searchsorted(key, ab), key.size - 1)] == ab)

    pair, row_pair = np.unique(relay * n + to, return_inverse=True)
    pc, pj = pair // n, pair % n
    at, m = _neighbours(start, deg, nbr, pc)  # the relay's neighbours m, those of the receiver too
    common = linked(pj[at], m)
    at_m, v_m = _neighbours(start, deg, nbr, m[common])
    held = np.unique(at[common][at_m] * n + v_m)  # (pair, a neighbour of a common neighbour)
    v = np.maximum(ids, 0)
    c, j = relay[:, None], to[:, None]
    known = (v == c) | (v == j) | linked(c, v) | linked(j, v)
    tk = row_pair.reshape(-1, 1) * n + v
    known |= held[np.minimum(np.searchsorted(held, tk), max(held.size - 1, 0))] == tk if held.size else False
    return np.asarray((ids >= 0) & ~known)


def _relay_plan(
    problem: RangingData, ex: Exchange
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Round 2 of :func:`_subnetwork`: which records each local out-edge ``i → j`` relays — those of ``i``'s
    neighbours ``k`` with ``k ≠ j``, ``k`` not ``j``'s neighbour (``j`` holds its record from round 1), both
    free, and ``i`` the designated relay of ``(j, k)``: among their common neighbours the one of the least hash of
    ``(i, j, k)`` (every common neighbour knows ``j``'s and ``k``'s links from their round-1 records, so all agree
    without a message; a hash, not the least id, spreads the relaying). Every relayed record of the network:
    ``(its edge, its rank t on that edge — it travels in the t-th message —, for the records this block relays:
    the out-edge row and the in-edge row at the sender holding k's record, the mask of those)``."""
    n = problem.n_anchors
    key, nbr, start, deg = _directed_links(problem)  # every directed link, sorted by (node, neighbour)
    pairs = deg * deg
    c = np.repeat(np.arange(n), pairs)  # every relay c and ordered pair (j, k) of its neighbours
    at = np.arange(int(pairs.sum())) - np.repeat(np.cumsum(pairs) - pairs, pairs)
    dc = deg[c]
    j, k = nbr[start[c] + at // dc], nbr[start[c] + at % dc]
    fr = np.asarray(problem.free.any(axis=1), bool)
    jk = j * n + k
    hit = np.minimum(np.searchsorted(key, jk), key.size - 1)
    keep = (j != k) & fr[j] & fr[k] & (key[hit] != jk)
    c, j, k, jk = c[keep], j[keep], k[keep], jk[keep]
    h = (c.astype(np.uint64) + np.uint64(1)) * np.uint64(0x9E3779B97F4A7C15)
    h ^= (jk.astype(np.uint64) + np.uint64(1)) * np.uint64(0xC2B2AE3D27D4EB4F)
    h ^= h >> np.uint64(29)
    order = np.lexsort((c, h, jk))
    first = order[np.r_[True, jk[order][1:] != jk[order][:-1]]] if order.size else order
    c, j, k = c[first], j[first], k[first]
    edge = problem.graph.edge_index(c, j)
    order = np.lexsort((k, edge))
    c, k, edge = c[order], k[order], edge[order]
    rank = np.arange(edge.size) - np.searchsorted(edge, edge)  # the t-th record relayed on its edge
    local = np.full(n, -1, np.int64)
    local[ex.nodes] = np.arange(ex.n_local)
    mine = local[c] >= 0
    out_pos = np.full(ex.n_edges, -1, np.int64)
    out_pos[ex.out_edges] = np.arange(ex.out_edges.size)
    in_key = ex.nodes[ex.in_dst] * n + ex.in_src
    i_sort = np.argsort(in_key, kind="stable")
    in_e = i_sort[np.searchsorted(in_key[i_sort], c[mine] * n + k[mine])]
    return edge, rank, out_pos[edge[mine]], in_e, mine


def _ball_columns(
    free: np.ndarray, records: list[np.ndarray], k_max: int, width: int, n: int
) -> tuple[dict[int, np.ndarray], list[int], np.ndarray, int]:
    """The anchors whose link records an anchor holds (the ball, free ones: ``{anchor: its records}`` and in
    order) and the column of every free coordinate of the ball ``(n, dim)`` (−1 elsewhere), with their count."""
    recs: dict[int, np.ndarray] = {}
    for row in records:
        k = int(row[0])
        if k >= 0 and k not in recs and free[k].any():
            recs[k] = row[1:].reshape(k_max, width)
    ball = sorted(recs)
    col = np.full((n, free.shape[1]), -1, np.int64)
    cnt = 0
    for k in ball:
        f = np.flatnonzero(free[k])
        col[k, f] = cnt + np.arange(f.size)
        cnt += f.size
    return recs, ball, col, cnt


def _with_ring(
    q: np.ndarray,
    x: np.ndarray,
    ring: dict[int, list[tuple[int, np.ndarray]]],
    sigma_ring: dict[int, np.ndarray],
    col: np.ndarray,
    free: np.ndarray,
) -> np.ndarray | None:
    """``q + N_SS⁻¹ N_SR (⊕_v Σ_v) N_RS N_SS⁻¹`` for the rows ``x`` of ``N_SS⁻¹``: the ring anchors behind the
    ball's links considered with their blocks ``Σ_v``; None where a block is not finite."""
    cnt, dim = x.shape[1], free.shape[1]
    for v, parts in ring.items():
        m_v = np.zeros((cnt, dim))  # N_SR column block of v: −c u_u u_vᵀ over its ball partners
        for u, info in parts:
            cu = col[u][free[u]]
            m_v[cu] -= info[free[u]] * free[v]
        xm = x @ m_v
        sig = sigma_ring[v]
        if not np.all(np.isfinite(sig)):
            return None
        q += xm @ sig @ xm.T
    return q


def _solve_ball(
    problem: RangingData,
    me: int,
    records: list[np.ndarray],
    k_max: int,
    width: int,
    cond: np.ndarray,
    n: int,
    delay_sigma_m: float = 0.0,
) -> tuple[np.ndarray, float, np.ndarray, float]:
    """Anchor ``me``'s block of ``Q_SS = N_SS⁻¹ + N_SS⁻¹ N_SR (⊕_v Σ_v) N_RS N_SS⁻¹`` over the anchors whose link
    records it holds (``S``, free ones), the ring ``R`` behind their links considered with its blocks ``Σ_v``,
    and the variance factor of the sub-network's links (shares as the local one); with ``delay_sigma_m`` the
    delays' covariance ``σ_δ² B_i B_iᵀ`` (``B = N_SS⁻¹ G_S``) and the noise factor less the delays' share. Falls
    back to ``cond`` (no delay term) where the sub-network's normal matrix is singular."""
    dim = problem.dim
    free = problem.free
    recs, ball, col, cnt = _ball_columns(free, records, k_max, width, n)
    nss = np.zeros((cnt, cnt))
    ring: dict[int, list[tuple[int, np.ndarray]]] = {}  # ring anchor -> (ball anchor, its O_uv)
    g_cols: dict[int, np.ndarray] = {}  # ∂(JᵀW r)/∂δ_k over the ball's coordinates: c u at both ends' delays
    trace_g = 0.0
    sigma_ring: dict[int, np.ndarray] = {}
    wssr = share_sum = 0.0
    for u in ball:
        lk = recs[u]
        lk = lk[lk[:, 0] >= 0]
        cu = col[u][free[u]]
        for row in lk:
            v = int(row[0])
            d_u = row[1 : 1 + dim] * free[u]
            c = float(row[1 + dim])
            info = c * np.outer(d_u, row[1 : 1 + dim])  # c u uᵀ, rows of u's free coordinates
            nss[np.ix_(cu, cu)] += info[np.ix_(free[u], free[u])]
            if not free[v].any():
                sh = 1.0
            elif v in recs:
                sh = 0.5  # counted from both ends
                cv = col[v][free[v]]
                nss[np.ix_(cu, cv)] -= info[np.ix_(free[u], free[v])]
            else:
                sh = 0.5
                ring.setdefault(v, []).append((u, info))
                sigma_ring.setdefault(v, row[4 + dim :].reshape(dim, dim))
            wssr += sh * float(row[2 + dim])
            share_sum += sh * float(row[3 + dim])
            if delay_sigma_m > 0:
                g = np.zeros(cnt)
                g[cu] = c * row[1 : 1 + dim][free[u]]
                for k in (u, v):
                    g_cols[k] = g_cols[k] + g if k in g_cols else g.copy()
                trace_g += sh * 2.0 * c
    red = share_sum - cnt
    vf = max(wssr / red, VARIANCE_FLOOR) if red > 0 else 1.0
    nss = 0.5 * (nss + nss.T)
    mine = col[me][free[me]]
    zero = np.zeros((dim, dim))
    try:
        fac = sla.cho_factor(nss, check_finite=True)
    except (np.linalg.LinAlgError, ValueError):
        return cond, vf, zero, vf
    rhs = np.zeros((cnt, mine.size))
    rhs[mine, np.arange(mine.size)] = 1.0
    x = sla.cho_solve(fac, rhs).T  # rows of N_SS⁻¹ for my coordinates
    q = _with_ring(x[:, mine].copy(), x, ring, sigma_ring, col, free)
    if q is None:  # a ring anchor without a finite block
        return cond, vf, zero, vf
    f = free[me]
    out = zero.copy()
    out[np.ix_(f, f)] = 0.5 * (q + q.T)
    if delay_sigma_m <= 0 or not g_cols:
        return out, vf, zero, vf
    g_s = np.column_stack([g_cols[k] for k in sorted(g_cols)])
    b = sla.cho_solve(fac, g_s)  # N_SS⁻¹ G_S: the ball's coordinates moved by each delay
    delay = zero.copy()
    b_me = b[mine]
    delay[np.ix_(f, f)] = delay_sigma_m**2 * (b_me @ b_me.T)
    share = delay_sigma_m**2 * (trace_g - float(np.sum(g_s * b))) / red if red > 0 else 0.0
    return out, vf, delay, max(vf - share, MIN_NOISE_SHARE * vf)
