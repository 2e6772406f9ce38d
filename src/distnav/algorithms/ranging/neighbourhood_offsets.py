"""Range-bias calibration in the neighbourhood solvers (N-CSG, N-CSG + BLS / TBLS, N-CLM; issue 13 item 5).

The link model of the metres objective gains a bias: ``e_l = ‖r_a − r_b‖ + b_l − d_l`` (whitened by σ_l), with

* ``"per_anchor"``: ``b_l = b_a + b_b``, every anchor's antenna delay ``b_i`` with the prior ``N(0, σ_b²)`` (the
  convention of LM's ``range_offsets="per_anchor"``, :mod:`distnav.algorithms.ranging.objective`). Anchor ``i``
  holds, next to its neighbourhood positions, an estimate of the offsets of itself and of its neighbours (one
  more float per slot of the neighbourhood vector; a message carries ``K·(dim + 1)`` floats instead of
  ``K·dim``) and mixes them with the positions in the same consensus round (eqs. (15), (18));
* ``"common"``: one offset ``c`` every range carries. Every anchor holds its own copy ``c_i`` and uses it on its
  links; the copies are mixed by average consensus (row ``i`` of ``W``) in the same messages as the positions —
  **one** more float per message (the sender's ``c_j``), no extra round.

Anchor ``i``'s partial cost (eq. (14)) becomes ``f⁽ⁱ⁾ = Σ_{l∈E(i)} ρ(e_l²) + 2 b_i²/σ_b²``: every range is in two
partial costs and every prior in one, so the prior is counted twice to keep ``Σ_i f⁽ⁱ⁾ = 2F`` (``F`` the
centralized objective LM minimises) and the consensus fixed point that of LM. Fixed anchors estimate their
offsets too (their coordinates stay fixed). The gradient steps of N-CSG scale the offset step by
``Σσ⁻² / (Σσ⁻² + 2σ_b⁻²)`` (the prior's curvature); the Armijo tests (eqs. (19)–(21)) and N-CLM's gain ratio
(eq. (22)) evaluate the partial cost with the offsets moved along their step; N-CLM's local LM has one more
parameter per slot (the own block is ``(dim + 1)²``, the neighbour blocks stay rank one: the row of a range
w.r.t. a neighbour is ``[−u, 1]/σ``, ``[−u, 0]/σ`` for the common offset, which lives in the own block only).

Precision (what each anchor computes from its own links, neighbours held): ``σ(b_i)`` from the inverse of its
``(free coordinates, b_i)`` information with the prior; the common offset's information is ``½ Σ_i`` of every
anchor's information on ``c`` with its own coordinates eliminated (a network total, like the variance factor:
results only). Both are *conditional*, hence optimistic (docs/uwb.md, "Range offsets").
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import TYPE_CHECKING

import numpy as np

from distnav._blas import single_threaded_blas
from distnav._sparse import csr_times
from distnav.algorithms.ranging.data import RangingData
from distnav.algorithms.ranging.losses import loss_terms
from distnav.algorithms.ranging.neighbourhoods import ArmijoTest, IterationState, Mixing, Neighbourhoods
from distnav.algorithms.ranging.qc import free_block_inverses
from distnav.exchange import Exchange

if TYPE_CHECKING:
    from distnav.algorithms.ranging.local_lm import LocalLM
    from distnav.algorithms.ranging.plan import NeighbourhoodPlan

__all__ = [
    "NeighbourhoodOffsets",
    "loop_with_offsets",
    "offset_precision",
    "sample_bias",
]


class NeighbourhoodOffsets:
    """The offsets every anchor of one block holds, ``B (n_local, K)`` in the slots of its neighbourhood vector."""

    def __init__(self, nb: Neighbourhoods, mode: str, prior_sigma_m: float, start_m: float = 0.0) -> None:
        self.nb, self.mode, self.start_m = nb, mode, start_m  # start_m: the common offset's (a warm re-fit's)
        self.per_anchor = mode == "per_anchor"
        self.prior_w = 2.0 / prior_sigma_m**2 if self.per_anchor else 0.0  # weight of b_i² in f⁽ⁱ⁾ (see above)
        self.flat_self = nb.h_own * nb.K
        self.flat_other = nb.h_own * nb.K + nb.h_slot
        self.free = nb.valid if self.per_anchor else nb.valid & (np.arange(nb.K) == 0)[None, :]
        info = np.bincount(nb.h_own, 1.0 / nb.h_sigma**2, minlength=nb.nl)
        self.step_ratio = info / np.maximum(info + self.prior_w, 1e-300)  # offset step / position step

    def initial(self) -> np.ndarray:
        B = np.zeros((self.nb.nl, self.nb.K))
        if not self.per_anchor:
            B[:, 0] = self.start_m
        return B

    def half(self, B: np.ndarray) -> np.ndarray:
        """``b_l`` of every half-measurement as its holder sees it."""
        flat = B.reshape(-1)
        return np.asarray(flat[self.flat_self] + flat[self.flat_other] if self.per_anchor else flat[self.flat_self])

    def prior(self, B: np.ndarray) -> np.ndarray:
        return np.asarray(self.prior_w * B[:, 0] ** 2)

    def residual(self, sq_norm: np.ndarray, bias: np.ndarray) -> np.ndarray:
        nb = self.nb
        return np.asarray((np.sqrt(np.maximum(sq_norm, 0.0)) + bias - nb.h_range) / nb.h_sigma)

    def gradient(self, gw: np.ndarray, B: np.ndarray) -> np.ndarray:
        """``Jᵀ W r`` w.r.t. the offsets (½ ∇f⁽ⁱ⁾), ``gw = w r`` per half-measurement; the prior's ``2 b_i/σ_b²``."""
        nb = self.nb
        v = gw / nb.h_sigma
        size = nb.nl * nb.K
        g = np.bincount(self.flat_self, v, minlength=size)
        if self.per_anchor:
            g = g + np.bincount(self.flat_other, v, minlength=size)
        g = np.asarray(g, float).reshape(nb.nl, nb.K)
        g[:, 0] = g[:, 0] + self.prior_w * B[:, 0]
        return np.where(self.free, g, 0.0)


class OffsetArmijoTest(ArmijoTest):
    """:class:`~distnav.algorithms.ranging.neighbourhoods.ArmijoTest` with the offsets moving along ``α·dB`` too."""

    def __init__(
        self,
        off: NeighbourhoodOffsets,
        diff: np.ndarray,
        d: np.ndarray,
        B: np.ndarray,
        dB: np.ndarray,
        gB: np.ndarray,
        f0: np.ndarray,
        gamma: float,
        slope_factor: float,
    ) -> None:
        nb = off.nb
        flat = d.reshape(-1, nb.dim)
        dd = flat[nb.h_flat_self] - flat[nb.h_flat_other]
        self.nb, self.off, self.f0, self.gamma = nb, off, f0, gamma
        self.n2 = np.einsum("ij,ij->i", diff, diff)
        self.b = 2.0 * np.einsum("ij,ij->i", diff, dd)
        self.c = np.einsum("ij,ij->i", dd, dd)
        self.bias, self.dbias = off.half(B), off.half(dB)
        self.B, self.dB = B, dB
        self.slope = -slope_factor * (np.einsum("ijk,ijk->i", d, d) - np.einsum("ij,ij->i", dB, gB))
        self.moving = self.slope < 0

    def __call__(self, alpha: np.ndarray) -> np.ndarray:
        nb, off = self.nb, self.off
        al = alpha[nb.h_own]
        r = off.residual(self.n2 + al * (self.b + al * self.c), self.bias + al * self.dbias)
        fa = np.bincount(nb.h_own, nb.terms(r), minlength=nb.nl) + off.prior(self.B + alpha[:, None] * self.dB)
        return np.asarray(fa <= self.f0 + self.gamma * alpha * self.slope)


def mix_with_offsets(
    mix: Mixing, U: np.ndarray, B: np.ndarray, off: NeighbourhoodOffsets
) -> tuple[np.ndarray, np.ndarray]:
    """One consensus round (eqs. (15), (18)) of the positions and the offsets in the same messages."""
    nb, ex = mix.nb, mix.ex
    K, dim = nb.K, nb.dim
    if off.per_anchor:  # every slot carries (position, offset): K·(dim + 1) floats
        ext = np.concatenate([U, B[:, :, None]], axis=2)
        msg = np.zeros((nb.n_out * K, dim + 1))
        msg[nb.msg_flat] = ext.reshape(-1, dim + 1)[nb.msg_src]
        inbox = ex.send(msg.reshape(nb.n_out, K, dim + 1))
        fill = mix.fill_w if inbox.delivered.all() else mix._fill_weights(inbox.delivered)
        vals = inbox.values.reshape(nb.n_in, K * (dim + 1))
        mixed = fill[:, :, None] * ext + csr_times(mix.S, vals).reshape(ext.shape)
        return np.where(nb.free_slot, mixed[:, :, :dim], nb.known_slot), np.where(off.free, mixed[:, :, dim], 0.0)
    msg = np.zeros((nb.n_out * K, dim))  # the positions as in Mixing.apply, plus the sender's copy of c
    msg[nb.msg_flat] = U.reshape(-1, dim)[nb.msg_src]
    inbox = ex.send(np.concatenate([msg.reshape(nb.n_out, K * dim), B[ex.out_src, :1]], axis=1))
    fill = mix.fill_w if inbox.delivered.all() else mix._fill_weights(inbox.delivered)
    vals = inbox.values
    mixed = fill[:, :, None] * U + csr_times(mix.S, vals[:, : K * dim]).reshape(U.shape)
    c = fill[:, 0] * B[:, 0] + csr_times(mix.S, vals[:, K * dim :])[:, 0]  # every neighbour holds slot 0's node
    return np.where(nb.free_slot, mixed, nb.known_slot), np.where(nb.valid, c[:, None], 0.0)


def _linearize(
    plan: NeighbourhoodPlan, off: NeighbourhoodOffsets, P: np.ndarray, B: np.ndarray, k: int
) -> tuple[np.ndarray, ...]:
    """``(diff, r, bias, w, f⁽ⁱ⁾, ½∇_P f⁽ⁱ⁾, ½∇_B f⁽ⁱ⁾)`` at the start of iteration ``k``."""
    nb = plan.nb
    nb.loss = "linear" if k <= plan.graduated else plan.loss
    flat = P.reshape(-1, nb.dim)
    diff = flat[nb.h_flat_self] - flat[nb.h_flat_other]
    bias = off.half(B)
    r = off.residual(np.einsum("ij,ij->i", diff, diff), bias)
    w, terms = nb.rho(r)
    f0 = np.bincount(nb.h_own, terms, minlength=nb.nl) + off.prior(B)
    linear = nb.loss == "linear"
    gP = nb.gradient(diff, r, None if linear else w)
    gB = off.gradient(r if linear else w * r, B)
    return diff, r, bias, w, f0, gP, gB


def _lm_step(
    lm: LocalLM,
    off: NeighbourhoodOffsets,
    P: np.ndarray,
    B: np.ndarray,
    diff: np.ndarray,
    r: np.ndarray,
    bias: np.ndarray,
    f0: np.ndarray,
    gP: np.ndarray,
    gB: np.ndarray,
    lam: np.ndarray,
    nu: np.ndarray,
    wt: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:meth:`LocalLM.step` with one more parameter per slot (module docstring)."""
    nb = lm.nb
    nl, d = nb.nl, nb.dim
    D = d + 1
    robust = nb.loss != "linear"
    c = np.bincount(lm.inv, 1.0 / nb.h_sigma**2 * (wt if robust else 1.0), minlength=lm.count.size)
    norm = np.linalg.norm(diff[lm.first], axis=1)
    v = diff[lm.first] / np.where(norm > 0, norm, np.inf)[:, None]
    ones = np.ones((v.shape[0], 1))
    a = np.concatenate([v * lm.fo[lm.ls_own], ones], axis=1)  # own row (free coordinates, offset)
    nvec = np.concatenate([-v * lm.fs, ones if off.per_anchor else 0.0 * ones], axis=1)  # neighbour row
    fs_ext = np.concatenate([lm.fs, np.full((v.shape[0], 1), off.per_anchor)], axis=1)
    fo_ext = np.concatenate([lm.fo, np.ones((nl, 1), bool)], axis=1)
    A0 = csr_times(lm.O, (c[:, None, None] * a[:, :, None] * a[:, None, :]).reshape(-1, D * D)).reshape(nl, D, D)
    A0[:, d, d] += off.prior_w
    dA = np.einsum("kii->ki", A0) * fo_ext
    dB = c[:, None] * nvec * nvec
    if lm.damping == "fletcher":
        floor = 1e-12 * np.maximum(dA.max(axis=1), 1e-300)
        sA = np.maximum(dA, floor[:, None])
        sB = np.maximum(dB, floor[lm.ls_own][:, None])
    else:
        n_free = fo_ext.sum(axis=1) + np.asarray(lm.O @ fs_ext.sum(axis=1).astype(float))
        mean = np.maximum((dA.sum(axis=1) + csr_times(lm.O, dB.sum(axis=1))) / np.maximum(n_free, 1), 1e-300)
        sA = np.broadcast_to(mean[:, None], dA.shape)
        sB = np.broadcast_to(mean[lm.ls_own][:, None], dB.shape)
    t = np.where(fs_ext, lam[lm.ls_own][:, None] * sB, 1.0)
    tn = nvec / t
    q = np.einsum("ij,ij->i", nvec, tn)
    den = 1.0 + c * q
    b0 = -np.concatenate([gP[:, 0, :], gB[:, :1]], axis=1)
    bs = -np.concatenate([gP[lm.ls_own, lm.ls_slot, :], gB[lm.ls_own, lm.ls_slot][:, None]], axis=1)
    mo = fo_ext[:, :, None] & fo_ext[:, None, :]
    Am = A0 * mo + np.eye(D) * np.where(fo_ext, lam[:, None] * sA, 1.0)[:, :, None]
    coef = c * c * q / den
    S = Am - csr_times(lm.O, (coef[:, None, None] * a[:, :, None] * a[:, None, :]).reshape(-1, D * D)).reshape(nl, D, D)
    r0 = b0 - csr_times(lm.O, (c * np.einsum("ij,ij->i", tn, bs) / den)[:, None] * a)
    with single_threaded_blas():
        d0 = np.linalg.solve(S, r0[:, :, None])[:, :, 0]
    x = bs - (c * np.einsum("ij,ij->i", a, d0[lm.ls_own]))[:, None] * nvec
    ds = x / t - (c * np.einsum("ij,ij->i", tn, x) / den)[:, None] * tn
    delta = np.zeros((nl, nb.K, D))
    delta[:, 0, :] = d0
    delta[lm.ls_own, lm.ls_slot, :] = ds
    dP = np.where(nb.free_slot, delta[:, :, :d], 0.0)
    dBo = np.where(off.free, delta[:, :, d], 0.0)
    flat = dP.reshape(-1, d)
    dd = flat[nb.h_flat_self] - flat[nb.h_flat_other]
    dbias = off.half(dBo)
    lin = r + np.einsum("ij,ij->i", nb.jrows(diff), dd) + dbias / nb.h_sigma
    r_new = off.residual(np.einsum("ij,ij->i", diff + dd, diff + dd), bias + dbias)
    prior0, prior1 = off.prior(B), off.prior(B + dBo)
    f_new = np.bincount(nb.h_own, nb.terms(r_new), minlength=nl) + prior1
    if robust:
        pred = np.bincount(nb.h_own, wt * (r * r - lin * lin), minlength=nl) + prior0 - prior1
    else:
        pred = f0 - np.bincount(nb.h_own, lin * lin, minlength=nl) - prior1
    acc, new_lam, new_nu = lm.gain_update(f0, f_new, pred, lam, nu)
    return (P + np.where(acc[:, None, None], dP, 0.0), B + np.where(acc[:, None], dBo, 0.0), new_lam, new_nu)


def loop_with_offsets(
    plan: NeighbourhoodPlan, off: NeighbourhoodOffsets, P: np.ndarray, step: np.ndarray, nu: np.ndarray
) -> Iterator[IterationState]:
    """Iterations 0, 1, …, ``plan.iterations`` of the plan's method with the offsets estimated too."""
    nb, method = plan.nb, plan.method
    B = off.initial()

    def state(k: int, step: np.ndarray, f0: np.ndarray) -> IterationState:
        return IterationState(
            k,
            P[:, 0].copy(),
            step.copy(),
            f0,
            nb.h_own,
            nb.h_samp,
            P.reshape(-1, nb.dim)[nb.h_flat_other],
            B[:, 0].copy(),
            off.half(B),
        )

    yield state(0, step, _linearize(plan, off, P, B, 0)[4])
    for k in range(1, plan.iterations + 1):
        diff, r, bias, w, f0, gP, gB = _linearize(plan, off, P, B, k)
        if method == "N-CLM":
            assert plan.lm is not None
            U, V, step, nu = _lm_step(plan.lm, off, P, B, diff, r, bias, f0, gP, gB, step, nu, w)
        else:
            if method != "N-CSG":
                dB = -off.step_ratio[:, None] * gB
                test = OffsetArmijoTest(off, diff, -gP, B, dB, gB, f0, plan.line.gamma, plan.line.slope_factor)
                start = plan.bls_start() if method == "N-CSG-BLS" else step
                step = plan.search(diff, r, gP, f0, start, method == "N-CSG-TBLS", reuse=test)[0]
            U = P - step[:, None, None] * gP
            V = B - (step * off.step_ratio)[:, None] * gB
        for _ in range(plan.consensus_rounds):
            U, V = mix_with_offsets(plan.mix, U, V, off)
        P, B = U, V
        yield state(k, step, f0)


def sample_bias(meas_a: np.ndarray, meas_b: np.ndarray, offsets_m: np.ndarray | None) -> np.ndarray | float:
    """``b_l`` of every sample from reported offsets (one common, or one per anchor; None: 0)."""
    if offsets_m is None:
        return 0.0
    if offsets_m.size == 1:
        return float(offsets_m[0])
    return np.asarray(offsets_m[meas_a] + offsets_m[meas_b])


def offset_precision(
    problem: RangingData,
    ex: Exchange,
    st: IterationState,
    mode: str,
    prior_sigma_m: float,
    loss: str,
    sigma: np.ndarray,
    scale: np.ndarray,
    variance_factor: float | None,
) -> tuple[np.ndarray, np.ndarray]:
    """``(offsets, σ)`` reported by the anchors at the state ``st`` (module docstring): per anchor, or one common
    (the mean of the anchors' copies); ``sigma`` / ``scale``: every sample's range σ and loss scale."""
    assert st.half_owner is not None and st.half_other_m is not None and st.offset_m is not None
    assert st.half_sample is not None and st.half_offset_m is not None
    owner, samp, nl = st.half_owner, st.half_sample, ex.n_local
    dim = st.own_m.shape[1]
    sigma_half, free_own = sigma[samp], problem.free[ex.nodes[owner]]
    diff = st.own_m[owner] - st.half_other_m
    norm = np.linalg.norm(diff, axis=1)
    r = (norm + st.half_offset_m - problem.range_m[samp]) / sigma_half
    weight = loss_terms(r, scale[samp], loss)[0]  # the final IRLS weights
    j = np.concatenate(
        [diff / (np.where(norm > 0, norm, np.inf) * sigma_half)[:, None] * free_own, (1.0 / sigma_half)[:, None]],
        axis=1,
    )
    info = np.zeros((nl, dim + 1, dim + 1))
    np.add.at(info, owner, weight[:, None, None] * j[:, :, None] * j[:, None, :])
    per_anchor = mode == "per_anchor"
    if per_anchor:
        info[:, dim, dim] += 1.0 / prior_sigma_m**2
    free = np.zeros((nl, dim + 1), bool)
    free[owner, :dim] = free_own
    free[:, dim] = True
    var = free_block_inverses(info, free)[:, dim, dim]
    s2 = variance_factor if variance_factor else 1.0
    if per_anchor:
        return ex.gather_nodes(st.offset_m), np.sqrt(np.maximum(ex.gather_nodes(var), 0.0) * s2)
    with np.errstate(divide="ignore"):
        eliminated = np.where(np.isfinite(var) & (var > 0), 1.0 / var, 0.0)
    total = float(ex.allreduce(float(eliminated.sum()), "sum")) / 2.0  # every range in two anchors' information
    mean = float(ex.allreduce(float(st.offset_m.sum()), "sum")) / max(float(ex.allreduce(nl, "sum")), 1.0)
    return np.array([mean]), np.array([np.sqrt(s2 / total) if total > 0 else np.nan])
