"""A final refinement phase of the distributed UWB solvers: distributed Levenberg–Marquardt with a conjugate-gradient
inner solve, every product through the exchange (issue 13 item 3).

Why: N-CLM and N-CSG-TBLS are consensus methods whose rate is set by the network's slowest mode. On plant-like
halls with the known anchors in a corner that mode is a swing of the far part of the network about the known
corner; after 500 iterations per fit their worst coordinate was a median 1.8–5.1 σ (up to 13.5 σ, 2.6 m) from LM's
solution on the same links, and N-CLM was still 0.99 m RMS from it after 5000 iterations (docs/uwb.md,
"Distributed solvers vs LM"). Conjugate gradients solve the Gauss–Newton system ``(N + μD) δ = −g`` of the
*whole* network in at most as many iterations as it has unknowns (about 50 on a 28-anchor hall with heights held)
whatever its conditioning — with the forcing term :data:`CG_RTOL` far fewer, 8–17 per round there — and each
iteration needs only the neighbours' values:

* a **matrix–vector product** ``(N v)_i = Σ_{l∈E(i)} w_l a_l (a_lᵀ v_i + c_lᵀ v_j + e_l v_c)`` — anchor ``i``'s
  link rows ``a_l`` (its own parameters), ``c_l`` (the neighbour's) and ``e_l`` (a common offset), the IRLS weights
  ``w_l = ρ'(r_l²)`` of the loss — is one broadcast of ``v`` (``P`` floats per link: the coordinates and, with
  per-anchor offsets, the offset);
* the **scalars** of CG (two dot products), the cost of a trial step, the common offset's row and the step's
  largest move are network totals, as the solvers' :class:`~distnav.algorithms.ranging.csg.StopRule` uses: each is a
  sum over the anchors assembled in the anchors' order (``gather_nodes``, so that in-process and MPI agree bit
  for bit; a deployment would run a spanning-tree reduction, ``2(n − 1)`` messages of the reduced floats). They
  are counted in :attr:`Refinement.reduced` (:class:`~distnav.algorithms.ranging.wire.Reductions`), their bytes
  (:func:`~distnav.algorithms.ranging.wire.reduction_cost`) in the solver result's ``settings["refine"]``
  and in ``uwb solve``'s totals (issue 27: before, only the broadcasts were counted — at two reductions of two
  floats per CG iteration the reductions send about twice the bytes of the float16 broadcasts on a 28-anchor hall).

The outer loop is Levenberg–Marquardt (Madsen, Nielsen & Tingleff 2004, §3.2: Marquardt's diagonal damping
``μ·diag(N)``, μ ÷ 3 after an accepted step, × 4 after a rejected one) on the objective LM minimises, ``F = Σ_l
ρ(r_l²) + Σ_i b_i²/σ_b²`` (:func:`~distnav.algorithms.ranging.losses.loss_terms`;
the metres residual ``r_l = (‖x_a − x_b‖ +
b_l − d_l)/σ_l``), preconditioned by each anchor's own damped block (block Jacobi, local). Its fixed point is
LM's (IRLS weights: the stationary point of the robust objective). It stops ``converged`` when an accepted step
moved no parameter by more than ``xtol_m`` and changed ``F`` by at most ``ftol`` (relative) — the solvers'
stopping thresholds — and says ``max_iterations`` after ``max_rounds`` outer rounds. Where the IRLS weights make the
tail linear (the largest move shrinking by a steady ratio ρ: 0.75 a round on a weakly determined part of a plant-like
hall), one trial jumps by the rest of the steps' geometric series (Aitken's idea; :data:`EXTRAPOLATE`, issue 27): a
trial like any other, counted as a round, kept only where it lowers ``F``; the stop is tested on plain steps only.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

import numpy as np

from distnav._settings import resolve_options
from distnav.algorithms.ranging import wire
from distnav.algorithms.ranging.data import RangingData
from distnav.algorithms.ranging.inner import (
    CG_RTOL,
    Delegated,
    Forcing,
    Links,
    NormalSystem,
    block_preconditioner,
    edge_round,
    hand_over,
    held_by_all,
    pcg,
    sit_out_plan,
)
from distnav.algorithms.ranging.losses import loss_terms
from distnav.algorithms.ranging.neighbourhoods import IterationState, half_measurements
from distnav.errors import ModelError
from distnav.exchange import Exchange

__all__ = [
    "Refinement",
    "RefineOptions",
    "refine",
    "refine_state",
    "MAX_ROUNDS",
    "Links",
    "NormalSystem",
    "pcg",
    "jacobian_rows",
    "block_preconditioner",
    "CG_RTOL",
]

MAX_ROUNDS = 60  # outer LM rounds; plant-like halls: a median 4–6 after the exclusions, 16–36 with NLOS links kept
MU0 = 1e-3  # initial Marquardt damping (relative to diag N)
#: the LM phase's CG stops on the preconditioned residual ``rᵀz`` (no reduction of ``rᵀr``; :func:`pcg`, issue 27)
PRECONDITIONED_STOP = True
#: a round's own network totals — the common offset's gradient and curvature, a trial's largest move — as the CG
#: scalars (float32) on the wire; the objective, which decides acceptance, stays float64 (issue 27)
ROUND_SCALARS = True
#: after three accepted steps whose largest moves shrank by ratios ``ρ`` within 10 % of each other, in [0.2, 0.97],
#: one trial of ``ρ/(1 − ρ)`` × the last step, kept where it lowers ``F`` (module docstring; None: off)
EXTRAPOLATE: tuple[float, float, float] | None = (0.2, 0.97, 0.1)  # ρ's range, its largest relative change
#: a fit's first evaluation reduces the objective only: the largest move of its zero step is 0, which every anchor
#: knows (issue 27, seventh session; False: a zero column reduced with the objective, as before)
FIRST_MOVE_KNOWN = True
#: a trial's objective and largest move go up the reduction tree to its root only, which decides (accept, stop,
#: extrapolate) and sends every anchor its decision: 1 B down (and the jump factor with an extrapolation) instead of
#: the totals; a fit's first objective goes up only (issue 27, seventh session; False: all-reductions, as before)
ROOT_DECIDES = True
#: an extrapolated trial's step not sent: every receiver scales the last step it holds by the jump factor, which the
#: root's decision carries (``Wire.scaled``, the same rows bit for bit; issue 27, seventh session)
SCALED_TRIAL_KNOWN = True
#: the common offset's start not reduced where every anchor's copy is the one the options give (``offset_start_m``:
#: a fit's LM phase from the solver's start, which every anchor holds; issue 27, seventh session)
OFFSET_START_HELD = True
#: the anchors without a free parameter sit the phase out (``inner.sit_out_plan``): no message to them, the
#: reduction tree over the others; their terms evaluated at the other end of each link (issue 27, eighth session)
SIT_OUT = True


@dataclass(frozen=True, eq=False)
class Refinement:
    """The refined state of one exchange block: own estimates ``(n_local, dim)``, own offsets (per anchor, or
    every anchor's copy of the common one; None without offsets), the neighbours' estimates and offsets per
    half-measurement (as :class:`~distnav.algorithms.ranging.neighbourhoods.IterationState`), the objective ``F``, the
    status, outer rounds (accepted or not), CG iterations and network reductions (with their floats per anchor,
    summed: the cost, :func:`~distnav.algorithms.ranging.wire.reduction_cost`)."""

    own_m: np.ndarray
    offset_m: np.ndarray | None
    half_other_m: np.ndarray
    half_offset_m: np.ndarray | None
    objective: float
    status: str
    rounds: int
    cg_iterations: int
    reduced: wire.Reductions
    mu: float = MU0  # the Marquardt damping at the end (a warm re-fit may start from it: RefineOptions.mu0)


@dataclass(frozen=True, kw_only=True)
class RefineOptions:
    """The settings of :func:`refine`, as the solver's: ``sigma`` / ``scale`` (every sample's range σ, metres, and
    whitened loss scale), ``loss``, ``range_offsets`` (``"none"``, ``"common"``, ``"per_anchor"``) and
    ``offset_prior_sigma_m`` (metres), the stopping thresholds ``ftol`` (relative) and ``xtol_m`` (metres),
    ``max_rounds`` (:data:`MAX_ROUNDS`) outer rounds, ``mu0`` (:data:`MU0`) the initial damping, ``held_m``
    what the receivers hold from the last fit (:class:`~distnav.algorithms.ranging.wire.Wire`, item 6) and
    ``offset_start_m`` the common offset every anchor's copy holds at the start, metres (None: not known; then
    the start is their network mean, one reduction; :data:`OFFSET_START_HELD`); ``forcing`` the adaptive forcing
    term of the phase's inner solves (:class:`~distnav.algorithms.ranging.inner.Forcing`'s fields; None: every CG
    run to ``CG_RTOL``; a workflow's fits get it by their stage, ``field_fits.STAGE_FORCING``)."""

    sigma: np.ndarray
    scale: np.ndarray
    loss: str
    range_offsets: str
    offset_prior_sigma_m: float
    ftol: float
    xtol_m: float
    max_rounds: int = MAX_ROUNDS
    mu0: float = MU0
    held_m: np.ndarray | None = None
    offset_start_m: float | None = None
    forcing: tuple[float, ...] | None = None


@dataclass(frozen=True, eq=False)
class _Linearization:
    """One outer round's Jacobian rows (``a``, ``cn``, ``e``), IRLS weights ``w``, gradient ``g`` (and the common
    offset's ``gc``, curvature ``dc``), the normal matrix's diagonal and every anchor's own block."""

    a: np.ndarray
    cn: np.ndarray
    e: np.ndarray
    w: np.ndarray
    g: np.ndarray
    gc: float
    dc: float
    diag: np.ndarray
    own_block: np.ndarray


class _Refiner:
    """The fixed parts of one refinement (the block's links, weights, free parameters) and its steps."""

    def __init__(self, problem: RangingData, ex: Exchange, o: RefineOptions, offset_m: np.ndarray | None) -> None:
        self.o = o
        self.per, self.common = o.range_offsets == "per_anchor", o.range_offsets == "common"
        self.n, self.nl, self.dim = problem.n_anchors, ex.n_local, problem.dim
        dim = self.dim
        self.P = dim + (1 if self.per else 0)
        every = np.ones((self.n, self.P), bool)
        every[:, :dim] = problem.free
        plan = None
        if SIT_OUT and not wire.PLAIN and wire.KNOWN_FROM_PROBLEM:  # Wire sends no known coordinate: a plan may apply
            plan = sit_out_plan(problem, every)
        warm = SIT_OUT and o.held_m is not None  # a warm fit: the silent anchors may have sat the last one out
        held_m, self.mu0, self.offset_m = o.held_m, o.mu0, offset_m
        if plan is None and warm:
            self.offset_m, self.mu0 = self._hand_over(problem, ex, every, offset_m)
        self.start_held = self._start_held(ex, self.offset_m)
        if self.common and not self.start_held and plan is not None:  # every copy in the start's mean (refine)
            plan = None
            if warm:
                self.offset_m, self.mu0 = self._hand_over(problem, ex, every, offset_m)
        if plan is None and held_m is not None and SIT_OUT:
            held_m = held_by_all(problem, held_m, every)
        self.links = links = Links(
            problem, ex, per_anchor_offsets=self.per, known_from_problem=True, held_m=held_m, sit_out=plan
        )
        self.owner, self.other, self.samp = links.owner, links.other, links.samp
        self.sig, self.sc, self.rng_m = o.sigma[self.samp], o.scale[self.samp], problem.range_m[self.samp]
        self.free = every[ex.nodes]
        self.n_free = int(problem.free.sum()) + (self.n if self.per else 0)  # the network's free parameters
        self.known_m = problem.positions_m[ex.nodes]
        self.free_nb = np.ones((self.samp.size, self.P), bool)
        self.free_nb[:, :dim] = problem.free[self.other]
        self.wire_dtype = wire.cg_wire_dtype(problem.n_anchors)
        self.dot_dtype = wire.cg_dot_dtype(problem.n_anchors)  # CG's reduced dot products (fifth session)
        self.prior = 1.0 / o.offset_prior_sigma_m**2 if self.per else 0.0
        self.steps = wire.STEPS and not wire.PLAIN  # trials travel as steps (wire, item 5)
        # the products' held exponents per link, kept from one CG run to the next of the fit (wire.HELD_ACROSS_RUNS)
        self.held: list[np.ndarray] = []
        # the adaptive forcing term of the fit's CG runs (None: every run to CG_RTOL)
        self.forcing = Forcing.of(o.forcing) if o.forcing is not None and not wire.PLAIN else None
        self.kk = None if plan is None else Delegated(problem, ex, plan, o.sigma, o.scale, o.loss, self.common)
        self.omega: np.ndarray | None = None
        if plan is not None:  # 0 at an owner that sits out, 2 where the other end does (the same term there)
            listens = plan.listens
            self.omega = np.where(listens[ex.nodes[self.owner]], np.where(listens[self.other], 1.0, 2.0), 0.0)

    def _start_held(self, ex: Exchange, offset_m: np.ndarray | None) -> bool:
        """Whether every copy of the common offset is the start the options give (:data:`OFFSET_START_HELD`: then
        not reduced): a check (monitoring, no bytes)."""
        held = self.o.offset_start_m
        if not self.common or offset_m is None or held is None or not OFFSET_START_HELD or wire.PLAIN:
            return False
        differs = not np.all(np.asarray(offset_m, float) == held)
        return bool(ex.allreduce(float(differs), "max") == 0)

    def _hand_over(
        self, problem: RangingData, ex: Exchange, every: np.ndarray, offset_m: np.ndarray | None
    ) -> tuple[np.ndarray | None, float]:
        """A warm fit where the plan does not apply: the anchors without a free parameter may have sat the last fit
        out and hold neither the common offset (their copies) nor the damping: one message of both (8 B each) from
        a neighbour (:func:`~distnav.algorithms.ranging.inner.hand_over`); their copies and μ as received.

        Charged on every such warm fit, also where no anchor sat the last fit out, and why that is right: whether
        the last fit's plan applied depends on *its* links and offset copies (:func:`~distnav.algorithms.ranging.
        inner.sit_out_plan`, :meth:`_start_held`), which this phase does not hold — it holds the last fit's
        coordinates only (``held_m``). An anchor that cannot tell whether its known neighbours hold ``c`` and μ must
        send them, or the phase's result would hang on values they may lack; skipping the message would need the
        last fit's plan passed with ``held_m`` through the front door. The price is 16 B to each known anchor once
        per fit where the plan does not apply now; in the 1,252 fits counted on 100 PLANT_HARD and 12 plant-like
        workflows the plan applied in every fit (docs/economy_uwb.md item 37), so it was never sent there."""
        silent = ~np.any(every, axis=1)
        if not silent.any():
            return offset_m, self.o.mu0
        common = self.common and offset_m is not None
        rows = np.c_[np.full(self.nl, self.o.mu0), np.asarray(offset_m, float) if common else np.zeros((self.nl, 0))]
        got = hand_over(problem, ex, silent, rows)
        mine = silent[ex.nodes]
        mu0 = float(got[mine, 0].max(initial=self.o.mu0))  # the same value everywhere (a check: the senders' μ)
        return (got[:, 1].copy() if common else offset_m), mu0

    def start(self, own_m: np.ndarray, offset_m: np.ndarray | None) -> tuple[np.ndarray, float, int]:
        """The start ``(x, c)`` and CG's iteration limit (one reduction: the common offset's mean; the number of
        unknowns is the problem's structure, which every anchor holds: no message, issue 27 fifth session)."""
        dim, links = self.dim, self.links
        x = np.zeros((self.nl, self.P))
        x[:, :dim] = np.where(self.free[:, :dim], own_m, self.known_m)  # known coordinates as the problem's (wire)
        if self.per:
            assert offset_m is not None
            x[:, dim] = offset_m
        common = self.common and offset_m is not None
        c = 0.0
        if common and self.start_held:
            held = float(self.o.offset_start_m or 0.0)
            c = float(np.sum(np.full(self.n, held))) / self.n  # the mean of n equal copies, as the reduction's
        elif common:  # their network mean (no plan here: every anchor's copy is in it)
            c = float(links.total(np.asarray(offset_m, float))) / self.n
        n_unknowns = self.n_free + (1 if self.common else 0)
        return x, c, min(n_unknowns + 10, 2000)

    def evaluate(
        self,
        xv: np.ndarray,
        cv: float,
        step: np.ndarray,
        base: np.ndarray | None = None,
        *,
        move: bool = True,
        scaled: float | None = None,
    ) -> tuple[np.ndarray, float, np.ndarray, float]:
        """Neighbour rows, F, the per-half residuals at ``(xv, cv)`` and the largest move of ``step`` (one
        broadcast and one reduction; ``base``: the neighbour rows ``step`` moved from, then only the step travels,
        :meth:`~distnav.algorithms.ranging.wire.Wire.stepped`; ``move`` False: its largest move is not needed, an
        extrapolated trial's, and not reduced with :data:`ROOT_DECIDES`; ``scaled``: ``step`` is this factor times
        the last step sent, which the receivers scale themselves, :data:`SCALED_TRIAL_KNOWN`)."""
        dim, owner, per = self.dim, self.owner, self.per
        if base is None or not self.steps:
            nb = self.links.neighbours(xv)
        elif scaled is not None and SCALED_TRIAL_KNOWN and ROOT_DECIDES:  # the factor travels with the decision
            nb = self.links.wire.scaled(base, scaled)
        else:
            nb = self.links.wire.stepped(base, step)
        diff = xv[owner, :dim] - nb[:, :dim]
        bias = (xv[owner, dim] + nb[:, dim]) if per else cv
        r = (np.linalg.norm(diff, axis=1) + bias - self.rng_m) / self.sig
        if self.omega is None:
            terms = loss_terms(r, self.sc, self.o.loss)[1]
            f_node = 0.5 * np.bincount(owner, terms, minlength=self.nl) + (self.prior * xv[:, dim] ** 2 if per else 0.0)
        else:  # an owner that sits out: its terms are the other end's (omega); the delegated samples' terms
            r = np.where(self.omega > 0, r, 0.0)
            terms = loss_terms(r, self.sc, self.o.loss)[1]
            assert self.kk is not None
            r_kk, f_kk = self.kk.terms(cv)
            f_node = 0.5 * np.bincount(owner, terms * self.omega, minlength=self.nl) + f_kk
            r = np.r_[r, r_kk]  # carried to the linearization
        small = wire.CG_SCALAR_DTYPE if ROUND_SCALARS and not wire.PLAIN else np.float64
        root = ROOT_DECIDES and not wire.PLAIN
        down = (0 if base is None else 1) if root else None  # the first objective: nothing to decide yet
        if (base is None and FIRST_MOVE_KNOWN or not move and root) and not wire.PLAIN:  # F alone
            only = self.links.gathered(np.c_[f_node], small, exact_columns=1, down_bytes=down)
            return nb, float(np.sum(only[:, 0])), r, 0.0
        moves = np.max(np.abs(step), axis=1, initial=0.0)
        both = self.links.gathered(np.c_[f_node, moves], small, exact_columns=1, down_bytes=down)
        return nb, float(np.sum(both[:, 0])), r, float(np.max(both[:, 1], initial=0.0))

    def linearize(self, x: np.ndarray, nb: np.ndarray, r: np.ndarray) -> _Linearization:
        """The outer round's linearization at ``x`` (the common offset's rows: one reduction)."""
        dim, nl, owner, per, prior = self.dim, self.nl, self.owner, self.per, self.prior
        if self.forcing is not None:
            self.forcing.linearized()
        r, r_kk = r[: self.owner.size], r[self.owner.size :]  # the delegated samples' residuals after the halves'
        a, cn, e = jacobian_rows(x, nb, owner, self.sig, dim, per, self.common, self.free, self.free_nb)
        w = loss_terms(r, self.sc, self.o.loss)[0]
        g = _rows(owner, (w * r)[:, None] * a, nl)
        if per:
            g[:, dim] += prior * x[:, dim]
        gc = dc = 0.0
        if self.common:  # the common offset's gradient and curvature: one reduction
            if self.omega is None:
                shares = (
                    0.5
                    * np.c_[np.bincount(owner, w * r * e, minlength=nl), np.bincount(owner, w * e * e, minlength=nl)]
                )
            else:  # an owner that sits out: its rows are the other end's (omega); the delegated samples' rows
                we = w * e * self.omega
                shares = 0.5 * np.c_[np.bincount(owner, we * r, minlength=nl), np.bincount(owner, we * e, minlength=nl)]
                assert self.kk is not None
                shares += self.kk.row(r_kk)
            small = wire.CG_SCALAR_DTYPE if ROUND_SCALARS and not wire.PLAIN else np.float64
            gc, dc = (float(t) for t in self.links.total(shares, small))
        diag = _rows(owner, w[:, None] * a * a, nl) + (np.c_[np.zeros((nl, dim)), np.full(nl, prior)] if per else 0.0)
        block = np.einsum("h,ha,hb->hab", w, a, a)
        own_block = np.zeros((nl, self.P, self.P))
        np.add.at(own_block, owner, block)
        if per:
            own_block[:, dim, dim] += prior
        return _Linearization(a, cn, e, w, g, gc, dc, diag, own_block)

    def step(self, lin: _Linearization, mu: float, cg_max: int) -> tuple[np.ndarray, float, int]:
        """The damped Gauss–Newton step ``(dx, dc)`` by preconditioned CG, and its CG iterations."""
        free, common = self.free, self.common
        damp = mu * np.maximum(lin.diag, 1e-12)
        damp_c = mu * max(lin.dc, 1e-12)
        pre_inv = block_preconditioner(lin.own_block, damp, free)
        system = NormalSystem(
            self.links,
            self.owner,
            lin.a,
            lin.cn,
            lin.e,
            lin.w,
            damp,
            damp_c,
            self.prior,
            free,
            common,
            self.wire_dtype,
            self.sig,
            held=self.held if wire.HELD_ACROSS_RUNS else [],
            omega=self.omega,
            kk_curv=None if self.kk is None else self.kk.curvature(),
        )
        dxk, dck, its = pcg(
            system,
            -np.where(free, lin.g, 0.0)[:, :, None],
            np.array([-lin.gc]),
            pre_inv,
            lin.dc + damp_c if common else 1.0,
            self.links,
            cg_max,
            scalar_dtype=self.dot_dtype,
            preconditioned_stop=PRECONDITIONED_STOP and not wire.PLAIN,
            forcing=self.forcing,
        )
        return dxk[:, :, 0], float(dck[0]), its

    def extrapolate(
        self,
        x: np.ndarray,
        c: float,
        nb: np.ndarray,
        r: np.ndarray,
        F: float,
        last: tuple[np.ndarray, float],
        tail: list[float],
    ) -> tuple[np.ndarray, float, np.ndarray, np.ndarray, float]:
        """One trial of the rest of the geometric series of the steps (:data:`EXTRAPOLATE`): ``ρ/(1 − ρ)`` × the last
        step from ``(x, c)`` (one reduction, as any trial; the step is broadcast only without
        :data:`SCALED_TRIAL_KNOWN`), kept where it lowers ``F``; the tail restarts either way."""
        jump = tail[-1] / tail[-2] / (1.0 - tail[-1] / tail[-2])
        tail.clear()
        dx = self.links.wire.rounded(last[0] * jump) if self.steps else last[0] * jump
        dcv = last[1] * jump
        nb_new, F_new, r_new, _ = self.evaluate(x + dx, c + dcv, dx, nb, move=False, scaled=jump)
        if np.isfinite(F_new) and F_new < F:
            return x + dx, c + dcv, nb_new, r_new, F_new
        return x, c, nb, r, F

    def result(
        self, x: np.ndarray, c: float, nb: np.ndarray, F: float, status: str, rounds: int, cg_total: int
    ) -> Refinement:
        dim, links = self.dim, self.links
        offsets = half_off = None
        if self.per:
            offsets = x[:, dim].copy()
            half_off = x[self.owner, dim] + nb[:, dim]
        elif self.common:
            offsets = np.full(self.nl, c)
            half_off = np.full(self.samp.size, c)
        other_m = nb[:, :dim].copy()
        if self.omega is not None:  # the halves of an anchor that sat out, as their other ends hold them: tested
            sat = self.omega == 0  # there (a deployment's delegate; here read uncounted, as a gather of the result)
            other_m[sat] = np.asarray(links.ex.gather_nodes(x[:, :dim]))[self.other[sat]]
        return Refinement(
            own_m=x[:, :dim].copy(),
            offset_m=offsets,
            half_other_m=other_m,
            half_offset_m=half_off,
            objective=F,
            status=status,
            rounds=rounds,
            cg_iterations=cg_total,
            reduced=links.counted(),
        )


def refine(
    problem: RangingData,
    ex: Exchange,
    own_m: np.ndarray,
    offset_m: np.ndarray | None,
    *,
    options: RefineOptions | None = None,
    **changes: Any,
) -> Refinement:
    """Refine the block's own estimates (and offsets) to the network's least-squares solution (module docstring).

    ``options``: :class:`RefineOptions` (with keyword ``changes`` to it: :func:`distnav._settings.resolve_options`),
    as the solver's; ``offset_m``: the block's own offsets (``range_offsets="per_anchor"``) or its copies of the
    common one (their network mean is the start)."""
    o = resolve_options(RefineOptions, options, changes)
    run = _Refiner(problem, ex, o, offset_m)
    x, c, cg_max = run.start(own_m, run.offset_m)
    nb, F, r, _ = run.evaluate(x, c, np.zeros_like(x))
    mu = run.mu0
    status, rounds, cg_total = "max_iterations", 0, 0
    tail: list[float] = []  # the largest moves of the last accepted plain steps (EXTRAPOLATE)
    with np.errstate(invalid="ignore", divide="ignore"):
        while rounds < o.max_rounds:
            rounds += 1
            lin = run.linearize(x, nb, r)
            while True:  # inner: solve the damped system, try the step
                dx, dcv, its = run.step(lin, mu, cg_max)
                cg_total += its
                dx = run.links.wire.rounded(dx) if run.steps else dx  # moved by the step its neighbours receive
                x_new, c_new = x + dx, c + dcv
                nb_new, F_new, r_new, moved = run.evaluate(x_new, c_new, dx, nb)
                moved = max(moved, abs(dcv))
                if np.isfinite(F_new) and F_new <= F:
                    change = F - F_new
                    x, c, nb, r = x_new, c_new, nb_new, r_new
                    F_old, F = F, F_new
                    mu = max(mu / 3.0, 1e-12)
                    if change <= o.ftol * max(abs(F_old), 1e-300) and moved <= o.xtol_m:
                        if run.forcing is None or run.forcing.settled():  # a loose solve's short step: one more
                            status = "converged"  # round to CG_RTOL (inner.Forcing.settled)
                    elif _steady(tail, moved) and rounds < o.max_rounds:  # one more trial: counted as a round
                        rounds += 1
                        if ROOT_DECIDES and not wire.PLAIN:  # the root's decision carries the jump factor
                            run.links.decide(8)
                        x, c, nb, r, F = run.extrapolate(x, c, nb, r, F, (dx, dcv), tail)
                    break
                if moved <= o.xtol_m * 1e-3 and mu <= 1.0:  # a nearly undamped GN step of < 0.1 µm: F is at its
                    status = "converged"  # minimum up to rounding (the step no longer lowers it)
                    break
                mu *= 4.0
                if mu > 1e12:  # stalled: no decrease along ever shorter steps, status stays max_iterations
                    break
                rounds += 1
                if rounds >= o.max_rounds:
                    break
            if status == "converged":
                break
    return dataclasses.replace(run.result(x, c, nb, F, status, rounds, cg_total), mu=mu)


def rows_for_local_tests(problem: RangingData, ex: Exchange, ref: Refinement) -> None:
    """Where the anchors without a free parameter sat the phase out (``ref.reduced.tree_nodes``): one round in
    which each of them receives from every neighbour that took part its final coordinates and, with a common
    offset, that offset (8 B a value) — what such an anchor needs to test its links with its own scale
    (``test_scale="local"``: the local QC tests each link at its lower-indexed anchor). Counted only: the values
    are the halves :func:`refine` gives them, bit for bit (checked); a lost one is a ModelError naming the anchor."""
    if not ref.reduced.tree_nodes:
        return
    listens = np.any(problem.free, axis=1)
    rows = ref.own_m if ref.offset_m is None else np.c_[ref.own_m, ref.offset_m]  # a plan: no per-anchor offsets
    out_on = listens[ex.nodes[ex.out_src]] & ~listens[ex.out_dst]
    in_on = listens[ex.in_src] & ~listens[ex.nodes[ex.in_dst]]
    values, lost = edge_round(ex, rows, out_on, in_on)
    if lost.any():
        anchor = problem.ids[ex.nodes[ex.in_dst[lost][0]]]
        raise ModelError(f"refinement: anchor {anchor} did not receive its neighbours' final rows (lost)")
    owner, other, _, _ = half_measurements(problem, ex)
    got = {(int(ex.in_dst[e]), int(ex.in_src[e])): values[e] for e in np.flatnonzero(in_on)}
    for h in np.flatnonzero(~listens[ex.nodes[owner]] & listens[other]):
        row = got[(int(owner[h]), int(other[h]))]
        same = np.array_equal(row[: problem.dim], ref.half_other_m[h])
        if ref.half_offset_m is not None:
            same = same and row[problem.dim] == ref.half_offset_m[h]
        assert same, "the halves refine() gives a known anchor are its neighbours' final rows"


def _steady(tail: list[float], moved: float) -> bool:
    """Record an accepted plain step's largest move; whether the last three shrank by a steady ratio in the range
    of :data:`EXTRAPOLATE`."""
    tail.append(moved)
    if EXTRAPOLATE is None or len(tail) < 3:
        return False
    lo, hi, change = EXTRAPOLATE
    r1, r2 = tail[-2] / max(tail[-3], 1e-300), tail[-1] / max(tail[-2], 1e-300)
    return lo <= r2 <= hi and abs(r2 - r1) <= change * max(r1, r2)


def _rows(owner: np.ndarray, values: np.ndarray, nl: int) -> np.ndarray:
    """Σ over each anchor's half-measurements of ``values`` ``(h, P)`` → ``(n_local, P)``."""
    out = np.zeros((nl, values.shape[1]))
    np.add.at(out, owner, values)
    return out


def jacobian_rows(
    x: np.ndarray,
    nb: np.ndarray,
    owner: np.ndarray,
    sig: np.ndarray,
    dim: int,
    per: bool,
    common: bool,
    free: np.ndarray,
    free_nb: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every half-measurement's whitened Jacobian rows at ``x`` (own rows ``(n_local, P)``) and its neighbours'
    rows ``nb``: ``a`` (own parameters), ``cn`` (the other end's) and ``e`` (the common offset; zeros without)."""
    diff = x[owner, :dim] - nb[:, :dim]
    dist = np.linalg.norm(diff, axis=1)
    u = diff / (np.where(dist > 0, dist, np.inf) * sig)[:, None]
    a = np.zeros((sig.size, x.shape[1]))
    a[:, :dim] = u
    cn = -a
    if per:
        a[:, dim] = cn[:, dim] = 1.0 / sig
    a *= free[owner]
    cn *= free_nb
    e = 1.0 / sig if common else np.zeros(sig.size)
    return a, cn, e


def refine_state(
    problem: RangingData,
    ex: Exchange,
    st: IterationState,
    *,
    options: RefineOptions | None = None,
    **changes: Any,
) -> tuple[IterationState, Refinement]:
    """:func:`refine` from a solver's last state; the refined state (same iteration count, the neighbours' refined
    estimates and offsets on every half-measurement, for the local QC) and the refinement's record."""
    ref = refine(problem, ex, st.own_m, st.offset_m, options=resolve_options(RefineOptions, options, changes))
    owner, _, _, samp = half_measurements(problem, ex)
    out = IterationState(
        st.iteration,
        ref.own_m,
        st.step_size,
        st.partial_cost,
        owner,
        samp,
        ref.half_other_m,
        ref.offset_m,
        ref.half_offset_m,
    )
    return out, ref
