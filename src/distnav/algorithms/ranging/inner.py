"""The inner solve of the final distributed LM phase (:mod:`~distnav.algorithms.ranging.refine`) and of the central σ
(:mod:`~distnav.algorithms.ranging.covariance`): the block's links and network totals (:class:`Links`), the damped
normal matrix applied through the exchange (:class:`NormalSystem`), each anchor's own block as preconditioner
(:func:`block_preconditioner`) and preconditioned conjugate gradients over them (:func:`pcg`, Saad 2003, Alg. 9.1).

Split from :mod:`~distnav.algorithms.ranging.refine` (issue 27, seventh session); what each piece puts on the wire:
:mod:`~distnav.algorithms.ranging.wire` (CG's reduced dot products on their held exponents: :meth:`Links.held_total`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from distnav._settings import resolve_options
from distnav.algorithms.ranging import wire
from distnav.algorithms.ranging.data import RangingData
from distnav.algorithms.ranging.losses import loss_terms
from distnav.algorithms.ranging.neighbourhoods import half_measurements
from distnav.algorithms.ranging.wire import Wire
from distnav.errors import ModelError
from distnav.exchange import Exchange

__all__ = [
    "CG_RTOL",
    "CGOptions",
    "FORCING_TRIED",
    "STOP_ETA",
    "Forcing",
    "Links",
    "NormalSystem",
    "Delegated",
    "SitOut",
    "held_by_all",
    "sit_out_plan",
    "block_preconditioner",
    "edge_round",
    "hand_over",
    "pcg",
]

CG_RTOL = 0.1  # forcing term of the inexact inner solve (Dembo, Eisenstat & Steihaug 1982); docs/uwb.md
#: the LM phase's adaptive forcing term (Eisenstat & Walker 1996, choice 2; :class:`Forcing`) measured in issue 27
#: (γ 0.9, α (1 + √5)/2, η₀ 0.5, η in [0.1, 0.9]), the best of nine on the 12 plant-like halls; a workflow's fits
#: get it by their stage (``field_fits.STAGE_FORCING`` over ``field_fits.FORCING_STAGES``, through
#: ``RunOptions.refine_forcing``; without it every CG run to :data:`CG_RTOL`). In every early-stopped fit (stages
#: "seed", "refit", "rung") with a stop only on a step solved to CG_RTOL (:data:`STOP_ETA`), not kept
#: (docs/economy_uwb.md item 33): its savings (1.17 × on the 12 halls) came from stopping on short inexact steps, and
#: on 100 PLANT_HARD halls it changes the links of one; the default runs it in the exclusion loop's re-fits and rungs
#: only, with a stop on any step (item 36)
FORCING_TRIED = (0.9, 1.618, 0.5, 0.1, 0.9)
#: the loosest forcing term whose step may stop the LM phase (:meth:`Forcing.settled`)
STOP_ETA = CG_RTOL


@dataclass
class Forcing:
    """The forcing term ``η_k`` of one LM phase's inexact inner solves (Eisenstat & Walker 1996, choice 2):
    ``η_k = γ (‖g_k‖/‖g_{k−1}‖)^α``, safeguarded by ``max(η_k, γ η_{k−1}^α)`` where ``γ η_{k−1}^α > 0.1`` (their
    safeguard) and kept in ``[η_min, η_max]``; ``η₀`` for the first round. Departures: ``‖g‖`` is the
    preconditioned gradient norm ``√(gᵀM⁻¹g)`` — CG's first ``rᵀz`` (:func:`pcg`), which every anchor holds bit
    for bit, so the term costs no message (the preconditioner moves with the damping μ, a heuristic as the paper's
    norm); a rejected trial's retry on the same linearization keeps the round's η; a step solved looser than
    :data:`STOP_ETA` (or ``stop_eta`` where given) does not stop the phase (:meth:`settled`). The default's use:
    the exclusion loop's re-fits and rungs only (``field_fits.STAGE_FORCING``, with ``stop_eta`` 0.9: issue 27,
    docs/economy_uwb.md item 36). Measured with :data:`FORCING_TRIED` (its floor the
    fixed :data:`CG_RTOL`: near the solution no tighter than before) in every early-stopped fit
    (``field_fits.FORCING_STAGES`` = ("seed", "refit", "rung")): not the default (docs/economy_uwb.md item 33)."""

    gamma: float
    alpha: float
    eta0: float
    eta_min: float
    eta_max: float
    stop_eta: float | None = None  # the loosest η whose step may stop the phase (None: STOP_ETA)
    norm: float | None = None  # the last linearization's ‖g‖
    eta: float | None = None  # the current round's η (None: a new linearization, set by the next CG run)
    eta_last: float | None = None  # the last round's η
    tight: bool = False  # from now on η = CG_RTOL at most (settled)

    @classmethod
    def of(cls, terms: tuple[float, ...]) -> Forcing:
        """The term from ``(γ, α, η₀, η_min, η_max[, stop_η])`` (``RunOptions.refine_forcing``)."""
        gamma, alpha, eta0, eta_min, eta_max = terms[:5]
        return cls(gamma, alpha, eta0, eta_min, eta_max, terms[5] if len(terms) > 5 else None)

    def linearized(self) -> None:
        """A new outer round (its η follows from its first CG run's ‖g‖)."""
        self.eta = None

    def rtol(self, norm: float) -> float:
        """The round's η, given its gradient's norm (the first CG run of the round sets it)."""
        if self.eta is not None:
            return self.eta
        if self.norm is None or not self.norm > 0:
            eta = self.eta0
        else:
            eta = self.gamma * (norm / self.norm) ** self.alpha
            last = self.gamma * (self.eta0 if self.eta_last is None else self.eta_last) ** self.alpha
            if last > 0.1:  # the safeguard: no sudden tightening
                eta = max(eta, last)
        top = min(self.eta_max, CG_RTOL) if self.tight else self.eta_max
        self.eta = self.eta_last = float(min(max(eta, self.eta_min), top))
        self.norm = norm
        return self.eta

    def settled(self) -> bool:
        """Whether a step that passed the stopping test may stop the phase: only if its inner solve ran to at most
        :data:`CG_RTOL` — a looser one's step is shorter than the Newton step, so its length understates the
        distance to the solution (on the folded plant corner #0 the loop's 1 cm re-fits stopped early enough to
        exclude a link LM keeps). Else the rest of the phase runs at most to CG_RTOL (one more round at least)."""
        if self.eta is None or self.eta <= (STOP_ETA if self.stop_eta is None else self.stop_eta):
            return True
        self.tight = True
        return False


@dataclass(frozen=True, eq=False)
class SitOut:
    """The anchors without a free parameter that sit an LM phase out (:func:`sit_out_plan`, issue 27 item 37):
    ``listens`` per anchor (False: sits out), and the samples whose two ends both sit out, each given to a
    delegate — an anchor that takes part and ranges with one of its ends (``kk_samples``, ``kk_delegate``, and
    ``kk_sender``, the end that hands it the sample's record)."""

    listens: np.ndarray
    kk_samples: np.ndarray
    kk_delegate: np.ndarray
    kk_sender: np.ndarray


def sit_out_plan(problem: RangingData, free: np.ndarray) -> SitOut | None:
    """Which anchors may sit out an LM phase (issue 27, eighth session, item 37): those without a free parameter
    (``free`` ``(n, P)``, the phase's, offsets included), where the anchors with one form a connected range graph
    (the reduction tree runs over them alone) and every sample between two anchors that sit out has a delegate (the
    lowest-numbered anchor that takes part and ranges with its first end, else with its second). An anchor that sits
    out needs nothing during the phase: its coordinates are the problem's, every term of a link to an anchor that
    takes part is the same number at the other end (the residual is symmetric), and a sample between two such anchors
    depends on the common offset only — the delegate evaluates it from the sample's record. None: nobody sits out.
    Every anchor computes the plan from the problem's structure (no message)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    talks = np.asarray(np.any(free, axis=1))
    n, a, b = problem.n_anchors, np.asarray(problem.meas_a), np.asarray(problem.meas_b)
    if talks.all() or not talks.any():
        return None
    both = talks[a] & talks[b]
    graph = coo_matrix((np.ones(int(both.sum())), (a[both], b[both])), shape=(n, n))
    labels = connected_components(graph, directed=False)[1]
    if np.unique(labels[talks]).size != 1:
        return None
    kk = np.flatnonzero(~talks[a] & ~talks[b])
    delegate, sender = np.full(kk.size, -1), np.full(kk.size, -1)
    for i, s in enumerate(kk):
        for end in (a[s], b[s]):
            nb = np.r_[b[a == end], a[b == end]]
            nb = nb[talks[nb]]
            if nb.size:
                delegate[i], sender[i] = int(nb.min()), int(end)
                break
    if (delegate < 0).any():
        return None
    return SitOut(talks, kk, delegate, sender)


class Delegated:
    """The samples between two anchors that sit the phase out (``inner.SitOut``) that this block's anchors evaluate
    as their delegates: both ends' coordinates are the problem's, so a sample's residual depends on the common offset
    only; each counts for both its halves. Their records reach the delegates once per phase: one message from the
    end that ranges with the delegate, 16 B a sample (``wire.RANGE_RECORD_BYTES``, as the gather's); a lost record
    is an error (a ModelError naming the sample's anchors), as a lost message of the phase is (``Wire``)."""

    def __init__(
        self,
        problem: RangingData,
        ex: Exchange,
        plan: SitOut,
        sigma: np.ndarray,
        scale: np.ndarray,
        loss: str,
        common: bool,
    ) -> None:
        local_of = np.full(problem.n_anchors, -1)
        local_of[ex.nodes] = np.arange(ex.n_local)
        mine = local_of[plan.kk_delegate] >= 0
        s = plan.kk_samples[mine]
        self.at, self.nl, self.loss = local_of[plan.kk_delegate[mine]], ex.n_local, loss
        a, b = problem.meas_a[s], problem.meas_b[s]
        self.dist_m = np.linalg.norm(problem.positions_m[a] - problem.positions_m[b], axis=1)
        self.range_m, self.sig, self.sc = problem.range_m[s], sigma[s], scale[s]
        self.common = common
        self.e = 1.0 / self.sig if self.common else np.zeros(s.size)
        self.w = np.zeros(s.size)
        if plan.kk_samples.size:  # the records, in one round every block takes part in
            _send_records(problem, ex, plan)

    def terms(self, c: float) -> tuple[np.ndarray, np.ndarray]:
        """The samples' residuals at the common offset ``c`` and each delegate's share of the objective."""
        r = (self.dist_m + (c if self.common else 0.0) - self.range_m) / self.sig
        return r, np.bincount(self.at, loss_terms(r, self.sc, self.loss)[1], minlength=self.nl)

    def row(self, r: np.ndarray) -> np.ndarray:
        """Each delegate's share of the common offset's gradient and curvature at the residuals ``r``."""
        self.w = loss_terms(r, self.sc, self.loss)[0]
        we = self.w * self.e
        at, nl = self.at, self.nl
        return np.asarray(np.c_[np.bincount(at, we * r, minlength=nl), np.bincount(at, we * self.e, minlength=nl)])

    def curvature(self) -> np.ndarray:
        """Each delegate's ``Σ w e²`` at the last linearization (the common offset's row of a CG product)."""
        return np.bincount(self.at, self.w * self.e * self.e, minlength=self.nl)


def held_by_all(problem: RangingData, held_m: np.ndarray, free: np.ndarray) -> np.ndarray:
    """``held_m`` where every receiver of an anchor may hold its row: an anchor without a free parameter may have
    sat the last fit out (``refine.SIT_OUT``) and hold none, so the anchors that range with one send their first row
    (NaN: not held) — conservative where it took part in the last fit."""
    silent = ~np.any(free, axis=1)
    if not silent.any():
        return held_m
    a, b = np.asarray(problem.meas_a), np.asarray(problem.meas_b)
    near = np.zeros(problem.n_anchors, bool)
    near[a[silent[b]]] = True
    near[b[silent[a]]] = True
    out = np.array(held_m, float)
    out[near] = np.nan
    return out


def edge_round(
    ex: Exchange,
    rows: np.ndarray,
    out_on: np.ndarray,
    in_on: np.ndarray,
    message_bytes: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """One round of messages on some directed links only (the item-37 rounds: records, the hand-over, the final
    rows): ``rows`` ``(n_local, k)`` sent from each block anchor on its outgoing links where ``out_on`` (the receiver
    side marks the same links ``in_on``); ``message_bytes`` as :meth:`Exchange.send`'s. Returns the received row of
    every incoming link and the incoming links whose message was lost (``in_on`` and not delivered)."""
    active = np.zeros(ex.n_edges, bool)
    active[ex.out_edges] = out_on
    active[ex.in_edges] = in_on
    box = ex.send(np.asarray(rows, float)[ex.out_src], active=active, message_bytes=message_bytes)
    return np.asarray(box.values), in_on & ~np.asarray(box.delivered, bool)


def _send_records(problem: RangingData, ex: Exchange, plan: SitOut) -> None:
    """One round: from each sender to its delegate the range records it hands over, 16 B a sample
    (:class:`Delegated`); a ModelError names a sample whose record a delegate of this block did not receive."""
    n = problem.n_anchors
    keys, count = np.unique(plan.kk_sender * n + plan.kk_delegate, return_counts=True)

    def lookup(key: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        at = np.minimum(np.searchsorted(keys, key), keys.size - 1)
        return keys[at] == key, count[at]

    hit_out, n_out = lookup(ex.nodes[ex.out_src] * n + ex.out_dst)
    hit_in, _ = lookup(ex.in_src * n + ex.nodes[ex.in_dst])
    sizes = np.where(hit_out, wire.RANGE_RECORD_BYTES * n_out, 0).astype(np.int64)
    _, lost = edge_round(ex, np.zeros((ex.n_local, 1)), hit_out, hit_in, sizes)
    if lost.any():
        key = ex.in_src[lost][0] * n + ex.nodes[ex.in_dst[lost][0]]
        s = plan.kk_samples[np.flatnonzero(plan.kk_sender * n + plan.kk_delegate == key)[0]]
        a, b = problem.ids[problem.meas_a[s]], problem.ids[problem.meas_b[s]]
        raise ModelError(
            f"refinement: the record of the sample {a}-{b} (delegated to {problem.ids[key % n]}) was lost "
            "(a delegate needs every record of the phase)"
        )


def hand_over(problem: RangingData, ex: Exchange, silent: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """One round: each anchor of ``silent`` receives its lowest-indexed neighbour's row of ``rows`` ``(n_local, k)``
    (k floats, 8 B each; that neighbour not silent) — a warm fit's start after a fit it may have sat out
    (``refine.SIT_OUT``): the common offset and the damping, which it does not hold. ``rows`` with the received
    ones at this block's silent anchors; a lost message is a ModelError naming the anchor."""
    n, vals = problem.n_anchors, np.asarray(rows, float)
    a, b = np.asarray(problem.meas_a), np.asarray(problem.meas_b)
    giver = np.full(n, n)
    for s, t in ((a, b), (b, a)):  # the lowest-indexed neighbour of each silent anchor that is not silent
        pick = silent[t] & ~silent[s]
        np.minimum.at(giver, t[pick], s[pick])
    to = silent & (giver < n)
    out_hit = to[ex.out_dst] & (giver[ex.out_dst] == ex.nodes[ex.out_src])
    in_hit = to[ex.nodes[ex.in_dst]] & (giver[ex.nodes[ex.in_dst]] == ex.in_src)
    values, lost = edge_round(ex, vals, out_hit, in_hit)
    if lost.any():
        anchor = ex.nodes[ex.in_dst[lost][0]]
        raise ModelError(f"refinement: anchor {problem.ids[anchor]} did not receive the fit's start (lost)")
    out = vals.copy()
    out[ex.in_dst[in_hit]] = values[in_hit]
    return out


class Links:
    """The half-measurements of one block, their neighbour rows in a broadcast (``wire_options``: Wire's), totals;
    ``sit_out`` (:class:`SitOut`): the anchors that sit the phase out receive nothing and are not in the reduction
    tree."""

    def __init__(
        self,
        problem: RangingData,
        ex: Exchange,
        *,
        per_anchor_offsets: bool = False,
        sit_out: SitOut | None = None,
        **wire_options: Any,
    ) -> None:
        self.ex, self.n = ex, problem.n_anchors
        self.owner, self.other, _, self.samp = half_measurements(problem, ex)
        self.reductions = 0
        self.reduced_floats = 0  # per anchor, over every reduction (their cost as spanning-tree messages)
        self.reduced_bytes = 0  # the same in bytes (float64, or float32 for the LM phase's CG scalars)
        self.decided = [0, 0, 0]  # totals decided at the tree's root: count, directions, bytes per edge (Reductions)
        self.sit_out = sit_out
        listens = None if sit_out is None else sit_out.listens
        self.wire = Wire(problem, ex, self.owner, self.other, int(per_anchor_offsets), listens=listens, **wire_options)

    def counted(self) -> wire.Reductions:
        """The reductions counted so far."""
        tree = 0 if self.sit_out is None else int(self.sit_out.listens.sum())
        count, directions, down = self.decided
        return wire.Reductions(self.reductions, self.reduced_floats, self.reduced_bytes, count, directions, down, tree)

    def neighbours(self, values: np.ndarray) -> np.ndarray:
        """Each half-measurement's other end's parameter row of ``values`` ``(n_local, P)`` (one broadcast; after
        the first, only what can change: :meth:`~distnav.algorithms.ranging.wire.Wire.parameters`)."""
        return self.wire.parameters(values)

    def vectors(self, v: np.ndarray, dtype: type[np.floating] = np.float64) -> np.ndarray:
        """Each half-measurement's other end's rows of a CG vector ``(n_local, P, k)`` (one broadcast of the free
        columns: :meth:`~distnav.algorithms.ranging.wire.Wire.vectors`)."""
        return self.wire.vectors(v, dtype)

    def total(
        self, per_node: np.ndarray, dtype: type[np.floating] = np.float64, held: wire.HeldScalars | None = None
    ) -> np.ndarray:
        """Network sum of a per-anchor array ``(n_local, ...)``, in the anchors' order (the same bits everywhere);
        ``dtype`` float32: every anchor's share is rounded to float32 on the wire (summed in float64); ``held``
        (float16 ``(n_local, f)`` only, :data:`~distnav.algorithms.ranging.wire.HELD_DOTS`): a CG run's held
        exponents of this reduction, :meth:`held_total`."""
        if held is not None and dtype == np.float16 and wire.HELD_DOTS and not wire.PLAIN:
            return self.held_total(per_node, held)
        return np.asarray(np.sum(self.gathered(per_node, dtype), axis=0))

    def held_total(self, per_node: np.ndarray, held: wire.HeldScalars) -> np.ndarray:
        """Network sum of ``per_node`` ``(n_local, f)``, every share rounded as float16 (the values of
        :meth:`gathered` with float16, bit for bit) on its held exponent
        (:func:`~distnav.algorithms.ranging.wire.held_scalars`). Counted per value: 2 B where every anchor's share
        and the total lie in their held windows, else 3 B (every message of the spanning tree at that size; the
        tree's partial sums are not simulated, as the rounding is not)."""
        rows, on_held = wire.held_scalars(per_node, held.shares)
        f = rows.shape[1]
        got = np.asarray(self.ex.gather_nodes(np.c_[rows, on_held]))  # the flags ride along (for the count only)
        out = np.asarray(np.sum(got[:, :f], axis=0))
        total_on = wire.held_scalars(out.reshape(1, -1), held.total)[1][0]
        self.reductions += 1
        self.reduced_floats += f
        flags = got[:, f:] > 0
        if self.sit_out is not None:  # an anchor that sits out sends no share (its row here is zeros)
            flags |= ~self.sit_out.listens[:, None]
        self.reduced_bytes += int(np.sum(np.where(np.all(flags, axis=0) & total_on, 2, 3)))
        return out

    def gathered(
        self,
        per_node: np.ndarray,
        dtype: type[np.floating] = np.float64,
        *,
        exact_columns: int = 0,
        down_bytes: int | None = None,
    ) -> np.ndarray:
        """Every anchor's row of ``per_node`` (a reduction's worth of data: sums and maxima taken from it), as
        ``dtype`` on the wire (returned as float64) but for its first ``exact_columns`` columns (float64: an
        objective that decides acceptance). ``down_bytes`` (None: an all-reduction): the totals go up the tree to
        its root only, which decides for every anchor and sends ``down_bytes`` down (0: nothing; :meth:`decide`
        adds to it) — counted as such; every anchor's copy here takes the same decision from the same values."""
        floats = int(np.prod(per_node.shape[1:], dtype=np.int64))
        size = 3 if dtype == np.float16 else np.dtype(dtype).itemsize  # float16: with its exponent (wire.pack_scalars)
        up = exact_columns * 8 + (floats - exact_columns) * size
        self.reductions += 1
        self.reduced_floats += floats
        if down_bytes is None:
            self.reduced_bytes += up
        else:
            self.decided[0] += 1
            self.decided[1] += 1 + (down_bytes > 0)
            self.decided[2] += up + down_bytes
        if dtype == np.float64:
            return np.asarray(self.ex.gather_nodes(per_node))
        if dtype == np.float16:
            rows = wire.unpack_scalars(wire.pack_scalars(per_node), per_node.shape)
        else:
            rows = np.asarray(per_node, dtype).astype(np.float64)
        if exact_columns:
            rows[:, :exact_columns] = per_node[:, :exact_columns]
        return np.asarray(self.ex.gather_nodes(rows))

    def decide(self, extra_bytes: int) -> None:
        """``extra_bytes`` more in the last decided total's message down (a number the root sends with its
        decision, :meth:`gathered`)."""
        self.decided[2] += extra_bytes


def block_preconditioner(own_block: np.ndarray, damp: np.ndarray, free: np.ndarray) -> np.ndarray:
    """The inverse of every anchor's own (damped) block over its free parameters (identity at fixed ones)."""
    P = free.shape[1]
    pre = (own_block + damp[:, :, None] * np.eye(P)) * (free[:, :, None] & free[:, None, :])
    idx = np.nonzero(~free)
    pre[idx[0], idx[1], idx[1]] = 1.0
    return np.asarray(np.linalg.inv(pre))


@dataclass(frozen=True, eq=False)
class NormalSystem:
    """The (damped) normal matrix of one linearization, applied through the exchange (module docstring); shared
    by :func:`refine` and :func:`distnav.algorithms.ranging.covariance.central_precision`."""

    links: Links
    owner: np.ndarray
    a: np.ndarray  # (h, P) ∂r/∂(own parameters) of every half-measurement
    cn: np.ndarray  # (h, P) ∂r/∂(the other end's parameters)
    e: np.ndarray  # (h,) ∂r/∂(common offset), zeros without one
    w: np.ndarray  # (h,) IRLS weights
    damp: np.ndarray  # (n_local, P) μ·diag N
    damp_c: float
    prior: float  # 1/σ_b² on per-anchor offsets (0 otherwise)
    free: np.ndarray  # (n_local, P)
    common: bool
    wire_dtype: type[np.floating] = np.float64  # the CG vectors on the wire (ranging.wire: float16 in the LM phase)
    sigma: np.ndarray | None = None  # (h,) every half-measurement's range σ: the products travel projected
    held: list[np.ndarray] = field(default_factory=list)  # the CG run's exponents per link (wire.HELD_EXPONENT)
    #: the held exponents of :func:`pcg`'s two reductions (``pᵀq`` with the common offset's row, ``rᵀz``;
    #: wire.HELD_DOTS), fresh for every system
    held_dots: tuple[wire.HeldScalars, wire.HeldScalars] = field(
        default_factory=lambda: (wire.HeldScalars(), wire.HeldScalars())
    )
    #: with anchors sitting out (:class:`SitOut`): each half-measurement's weight in the common offset's row (0 at an
    #: owner that sits out, 2 where the other end sits out, else 1), and per anchor the curvature ``Σ w e²`` of the
    #: samples it evaluates for two anchors that sit out
    omega: np.ndarray | None = None
    kk_curv: np.ndarray | None = None

    def matvec(self, v: np.ndarray, vc: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(N + μD) V`` on the block's rows for ``k`` columns at once (``v`` ``(n_local, P, k)``, ``vc`` the
        common offset's row ``(k,)``; one broadcast of ``P·k`` floats per link), and each anchor's share of the
        common offset's row ``(n_local, k)`` (summed over the network by the caller, together with its dot
        products: one reduction per CG iteration less)."""
        nl, P, k = v.shape
        own = np.einsum("hp,hpk->hk", self.a, v[self.owner])
        if (
            self.sigma is not None and wire.PROJECTED and not wire.PLAIN
        ):  # the neighbour's product itself: k values per link
            held = self.held if wire.HELD_EXPONENT else None
            other = self.links.wire.projected(own * self.sigma[:, None], self.wire_dtype, held) / self.sigma[:, None]
        else:
            other = np.einsum("hp,hpk->hk", self.cn, self.links.vectors(v, self.wire_dtype))
        jv = own + other + self.e[:, None] * vc[None, :]
        wjv = self.w[:, None] * jv
        out = np.zeros_like(v)
        np.add.at(out, self.owner, wjv[:, None, :] * self.a[:, :, None])
        out += self.damp[:, :, None] * v
        if self.prior:
            out[:, -1] += self.prior * v[:, -1]
        half = np.zeros((nl, k))
        if self.omega is None:
            np.add.at(half, self.owner, 0.5 * wjv * self.e[:, None])
        else:
            np.add.at(half, self.owner, 0.5 * wjv * (self.e * self.omega)[:, None])
        if self.kk_curv is not None:
            half += self.kk_curv[:, None] * vc[None, :]
        return np.where(self.free[:, :, None], out, 0.0), half


@dataclass(frozen=True, kw_only=True)
class CGOptions:
    """The settings of one :func:`pcg` run, checked once (defaults in brackets): ``rtol`` [:data:`CG_RTOL`] the
    residual's reduction that stops it (≥ 0); ``scalar_dtype`` [float64] the dot products on the wire (float16,
    float32 or float64); ``preconditioned_stop`` [False] the stop in the preconditioner's norm ``rᵀz``;
    ``forcing`` [None] the LM phase's adaptive forcing term (:class:`Forcing`: it replaces ``rtol``)."""

    rtol: float = CG_RTOL
    scalar_dtype: type[np.floating] = np.float64
    preconditioned_stop: bool = False
    forcing: Forcing | None = None

    def __post_init__(self) -> None:
        if not (np.isfinite(self.rtol) and self.rtol >= 0):
            raise ModelError(f"pcg: rtol must be a finite number ≥ 0, got {self.rtol!r}")
        if self.scalar_dtype not in (np.float16, np.float32, np.float64):
            raise ModelError(f"pcg: scalar_dtype must be float16, float32 or float64, got {self.scalar_dtype!r}")


def pcg(
    system: NormalSystem,
    b: np.ndarray,
    bc: np.ndarray,
    pre_inv: np.ndarray,
    pre_c: float,
    links: Links,
    max_its: int,
    *,
    options: CGOptions | None = None,
    **changes: Any,
) -> tuple[np.ndarray, np.ndarray, int]:
    """Preconditioned conjugate gradients (Saad 2003, Alg. 9.1) on the block's rows ``(n_local, P, k)`` for ``k``
    right-hand sides at once (independent CG recurrences sharing every broadcast and reduction) and the common
    parameter's row ``bc`` ``(k,)`` (zeros without one); the dot products are network totals. It stops when every
    column's residual is below ``rtol`` of its start — in the preconditioner's norm ``rᵀM⁻¹r`` with
    ``preconditioned_stop`` (the LM phase, issue 27: that norm is CG's ``rᵀz``, which the iteration reduces anyway,
    so the residual's own norm ``rᵀr`` needs no reduction of its own) —, or one column's curvature ``pᵀNp`` is not
    positive. Per iteration two reductions: ``pᵀq`` with the common offset's row of ``q`` (only with a common offset),
    then ``rᵀz``; with float16 ``scalar_dtype`` each value after a run's first travels on its slot's held exponent
    (:data:`~distnav.algorithms.ranging.wire.HELD_DOTS`, issue 27, seventh session). ``options``
    (:class:`CGOptions`, or its fields as keywords): ``rtol``, ``scalar_dtype``, ``preconditioned_stop`` and
    ``forcing`` (``rtol`` is then the round's adaptive forcing term: :class:`Forcing`, from the first ``rᵀz``)."""
    o = resolve_options(CGOptions, options, changes)
    rtol, scalar_dtype, preconditioned_stop, forcing = o.rtol, o.scalar_dtype, o.preconditioned_stop, o.forcing
    k = b.shape[2]
    x = np.zeros_like(b)
    xc = np.zeros(k)
    res, rc = b.copy(), np.asarray(bc, float).copy()

    held_pq, held_rz = system.held_dots  # the held exponents of the reductions (wire.HELD_DOTS)

    def dots(u: np.ndarray, v: np.ndarray, extra: np.ndarray, held: wire.HeldScalars | None = None) -> np.ndarray:
        both = np.concatenate([np.einsum("nak,nak->nk", u, v), extra], axis=1)
        return np.asarray(links.total(both, scalar_dtype, held))

    def residual_dots(r: np.ndarray, zv: np.ndarray, r_c: np.ndarray, z_c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``rᵀz`` and the residual norm the stop compares (``rᵀz`` itself with ``preconditioned_stop``)."""
        if preconditioned_stop:
            rz_ = dots(r, zv, np.zeros((r.shape[0], 0)), held_rz) + r_c * z_c
            return rz_, rz_
        tt = dots(r, zv, np.einsum("nak,nak->nk", r, r))
        return tt[:k] + r_c * z_c, tt[k:] + r_c * r_c

    z = np.einsum("nab,nbk->nak", pre_inv, res)
    zc = rc / pre_c
    rz, rr0 = residual_dots(res, z, rc, zc)
    if forcing is not None:  # the round's η from its gradient's norm (Forcing: no message)
        rtol = forcing.rtol(float(np.sqrt(np.max(rr0))))
    p, pc = z.copy(), zc.copy()
    its = 0
    live = rr0 > 0.0
    if not live.any():
        return x, xc, 0
    while its < max_its:
        its += 1
        q, q_share = system.matvec(p, pc)  # the common offset's row only with one (issue 27, seventh session)
        t = dots(p, q, q_share if system.common else q_share[:, :0], held_pq)
        qc = t[k:] + system.damp_c * pc if system.common else np.zeros(k)
        pq = t[:k] + pc * qc
        if not np.all(pq[live] > 0):
            break
        alpha = np.where(live, rz / np.where(live, pq, 1.0), 0.0)
        x += alpha * p
        xc += alpha * pc
        res -= alpha * q
        rc -= alpha * qc
        z = np.einsum("nab,nbk->nak", pre_inv, res)
        zc = rc / pre_c
        rz_new, rr = residual_dots(res, z, rc, zc)
        live &= rr > rtol**2 * rr0
        if not live.any():
            break
        beta = np.where(live, rz_new / np.where(live, rz, 1.0), 0.0)
        p = z + beta * p
        pc = zc + beta * pc
        rz = rz_new
    return x, xc, its
