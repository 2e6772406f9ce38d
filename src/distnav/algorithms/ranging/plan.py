"""The set-up of one neighbourhood solver (N-CSG, N-CSG-BLS, N-CSG-TBLS, N-CLM; paper 002 eqs. (14)–(22)):
options checked once (:func:`plan_neighbourhood`) into a :class:`NeighbourhoodPlan` that runs the iterations."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from distnav.algorithms.ranging.data import RangingData
from distnav.algorithms.ranging.local_lm import LocalLM
from distnav.algorithms.ranging.losses import LOSSES
from distnav.algorithms.ranging.neighbourhoods import (
    ArmijoTest,
    IterationState,
    Mixing,
    Neighbourhoods,
    armijo_details,
    check_start,
    exchange_for,
    mixing_weights,
)
from distnav.errors import ModelError
from distnav.exchange import Exchange
from distnav.network.weights import ConsensusWeights

OFFSET_MODES = ("none", "common", "per_anchor")


def check_offsets(range_offsets: str, offset_prior_sigma_m: float, objective: str) -> None:
    if range_offsets not in OFFSET_MODES:
        raise ModelError(f"range offsets must be one of {', '.join(OFFSET_MODES)}, got {range_offsets!r}")
    if range_offsets != "none" and objective != "metres":
        raise ModelError("range offsets are estimated with objective='metres' only")
    if range_offsets == "per_anchor" and not offset_prior_sigma_m > 0:
        raise ModelError(f"offset_prior_sigma_m must be positive, got {offset_prior_sigma_m}")


@dataclass
class NeighbourhoodPlan:
    """Everything the iteration loop of one neighbourhood solver needs besides its state (set up once)."""

    nb: Neighbourhoods
    mix: Mixing
    weights: ConsensusWeights
    method: str
    iterations: int
    alpha: float
    alpha_i: float | np.ndarray
    alpha0_i: float | np.ndarray
    beta: float
    gamma: float
    max_backtracks: int
    slope_factor: float
    loss: str
    graduated: int
    consensus_rounds: int
    lm: LocalLM | None

    def bls_start(self) -> np.ndarray:
        """BLS's start in every iteration: ``α₀`` (per anchor for metres)."""
        nb = self.nb
        return np.full(nb.nl, float(self.alpha0_i)) if not nb.metres else np.asarray(self.alpha0_i, float).copy()

    def linearize(self, P: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``(diff, g, IRLS weights, f⁽ⁱ⁾(x⁽ⁱ⁾), G⁽ⁱ⁾ᵀ g⁽ⁱ⁾)`` at the start of iteration ``k``."""
        nb = self.nb
        nb.loss = "linear" if k <= self.graduated else self.loss
        diff, g = nb.geometry(P)
        w, terms = nb.rho(g)
        f0 = np.bincount(nb.h_own, terms, minlength=nb.nl)
        grad = nb.gradient(diff, g, None if nb.loss == "linear" else w)
        return diff, g, w, f0, grad

    def search(
        self,
        diff: np.ndarray,
        g: np.ndarray,
        grad: np.ndarray,
        f0: np.ndarray,
        start: np.ndarray,
        two_way: bool,
        known: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
        reuse: ArmijoTest | None = None,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return armijo_details(
            self.nb,
            diff,
            g,
            -grad,
            f0,
            start,
            self.alpha0_i,
            self.beta,
            self.gamma,
            two_way,
            self.max_backtracks,
            self.slope_factor,
            known,
            reuse,
        )

    def state(self, k: int, P: np.ndarray, step: np.ndarray, f0: np.ndarray) -> IterationState:
        nb = self.nb
        return IterationState(
            k, P[:, 0].copy(), step.copy(), f0, nb.h_own, nb.h_samp, P.reshape(-1)[nb.e_other].reshape(-1, nb.dim)
        )

    def loop(self, P: np.ndarray, step: np.ndarray, nu: np.ndarray, first: int) -> Iterator[IterationState]:
        """Iterations ``first``, …, ``iterations`` from the state ``(P, step, nu)`` (eqs. (14)–(22))."""
        nb, method = self.nb, self.method
        for k in range(first, self.iterations + 1):
            diff, g, w, f0, grad = self.linearize(P, k)
            if method == "N-CSG":
                U = P - self.alpha * grad if not nb.metres else P - step[:, None, None] * grad
            elif method == "N-CLM":
                assert self.lm is not None
                U, step, nu = self.lm.step(P, diff, g, f0, grad, step, nu, w)
            else:
                start = self.bls_start() if method == "N-CSG-BLS" else step
                step = self.search(diff, g, grad, f0, start, method == "N-CSG-TBLS")[0]
                U = P - step[:, None, None] * grad
            for _ in range(self.consensus_rounds):
                U = self.mix.apply(U)
            P = U
            yield self.state(k, P, step, f0)


def _check_choices(loss: str, armijo_slope: str, damping: str, objective: str, beta: float, gamma: float) -> None:
    """Refuse by name a loss, Armijo slope, damping or objective :func:`plan_neighbourhood` does not know, and line
    search factors outside (0, 1)."""
    if loss not in LOSSES:
        raise ModelError(f"unknown loss {loss!r}; choose one of {', '.join(LOSSES)}")
    if armijo_slope not in ("gradient", "subgradient"):
        raise ModelError(f"armijo_slope must be 'gradient' or 'subgradient', got {armijo_slope!r}")
    if damping not in ("levenberg", "fletcher"):
        raise ModelError(f"damping must be 'levenberg' or 'fletcher', got {damping!r}")
    if not (0 < beta < 1 and 0 < gamma < 1):
        raise ModelError(f"beta and gamma must lie in (0, 1), got beta={beta}, gamma={gamma}")
    if objective not in ("squared", "metres"):
        raise ModelError(f"objective must be 'squared' or 'metres', got {objective!r}")


def plan_neighbourhood(
    problem: RangingData,
    *,
    method: str = "N-CSG",
    exchange: Exchange | None = None,
    iterations: int = 500,
    alpha: float = 1e-3,
    alpha0: float = 1e-2,
    beta: float = 0.5,
    gamma: float = 0.5,
    lambda0: float = 1e-3,
    consensus_rounds: int = 1,
    weights: str | ConsensusWeights = "MH",
    initial_m: np.ndarray | None = None,
    max_backtracks: int = 40,
    damping: str = "levenberg",
    armijo_slope: str = "subgradient",
    loss: str = "linear",
    loss_scale_m: float = 0.3,
    lambda_min: float = 0.1,
    objective: str = "squared",
    sigma_m: float | np.ndarray = 1.0,
    graduated: int = 0,
    range_offsets: str = "none",
    offset_prior_sigma_m: float = 0.1,
) -> tuple[NeighbourhoodPlan, np.ndarray, np.ndarray]:
    """Check the options of :func:`iterate_neighbourhood` and set up its loop: ``(plan, P₀, step₀)``."""
    method = method.upper()
    if method not in ("N-CSG", "N-CSG-BLS", "N-CSG-TBLS", "N-CLM"):
        raise ModelError(f"unknown neighbourhood method {method!r}")
    init = check_start(problem, iterations, consensus_rounds, initial_m)
    if not (alpha > 0 and alpha0 > 0 and lambda0 > 0 and lambda_min > 0):
        raise ModelError("alpha, alpha0, lambda0 and lambda_min must be positive")
    _check_choices(loss, armijo_slope, damping, objective, beta, gamma)
    if graduated < 0:
        raise ModelError(f"graduated must be ≥ 0 iterations, got {graduated}")
    check_offsets(range_offsets, offset_prior_sigma_m, objective)
    ex = exchange_for(problem, exchange)
    nb = Neighbourhoods(problem, ex, loss, loss_scale_m, objective, sigma_m)
    w = mixing_weights(problem, weights)
    nl = nb.nl
    if nb.metres:  # steps relative to each anchor's information Σ σ⁻² (1 for an anchor without links)
        info = np.bincount(nb.h_own, 1.0 / nb.h_sigma**2, minlength=nl)
        unit = 1.0 / np.where(info > 0, info, 1.0)
        alpha_i: float | np.ndarray = alpha * unit
        alpha0_i: float | np.ndarray = alpha0 * unit
    else:
        alpha_i, alpha0_i = alpha, alpha0
    plan = NeighbourhoodPlan(
        nb,
        Mixing(nb, ex, w),
        w,
        method,
        iterations,
        alpha,
        alpha_i,
        alpha0_i,
        beta,
        gamma,
        max_backtracks,
        2.0 if armijo_slope == "gradient" else 1.0,
        loss,
        graduated,
        consensus_rounds,
        LocalLM(nb, damping, lambda_min) if method == "N-CLM" else None,
    )
    if method == "N-CSG":
        step = np.full(nl, float(alpha)) if not nb.metres else np.asarray(alpha_i, float).copy()
    elif method == "N-CLM":
        step = np.full(nl, float(lambda0))
    else:
        step = plan.bls_start()
    return plan, nb.initial(init), step
