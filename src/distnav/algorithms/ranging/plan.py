"""The set-up of one neighbourhood solver (N-CSG, N-CSG-BLS, N-CSG-TBLS, N-CLM; paper 002 eqs. (14)–(22)):
options checked once (:func:`plan_neighbourhood`) into a :class:`NeighbourhoodPlan` that runs the iterations."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from distnav.algorithms.ranging.data import RangingData
from distnav.algorithms.ranging.local_lm import LocalLM
from distnav.algorithms.ranging.neighbourhoods import (
    ArmijoTest,
    IterationState,
    LineSearch,
    Mixing,
    Neighbourhoods,
    armijo_details,
    check_start,
    exchange_for,
    mixing_weights,
)
from distnav.algorithms.ranging.options import NclmOptions, NcsgOptions
from distnav.errors import ModelError
from distnav.exchange import Exchange
from distnav.network.weights import ConsensusWeights

METHODS = ("N-CSG", "N-CSG-BLS", "N-CSG-TBLS", "N-CLM")


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
    line: LineSearch
    loss: str
    graduated: int
    consensus_rounds: int
    lm: LocalLM | None

    def bls_start(self) -> np.ndarray:
        """BLS's start in every iteration: ``α₀`` (per anchor for metres)."""
        nb = self.nb
        alpha0_i = self.line.alpha0
        return np.full(nb.nl, float(alpha0_i)) if not nb.metres else np.asarray(alpha0_i, float).copy()

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
        return armijo_details(self.nb, diff, g, -grad, f0, start, self.line, two_way, known, reuse)

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


def plan_neighbourhood(
    problem: RangingData,
    options: NcsgOptions | NclmOptions,
    *,
    method: str = "N-CSG",
    exchange: Exchange | None = None,
) -> tuple[NeighbourhoodPlan, np.ndarray, np.ndarray]:
    """Set up the loop of :func:`~distnav.algorithms.ranging.neighbourhood.iterate_neighbourhood` for ``method``
    (N-CLM takes :class:`NclmOptions`, the N-CSG family :class:`NcsgOptions`): ``(plan, P₀, step₀)``."""
    method = method.upper()
    if method not in METHODS:
        raise ModelError(f"unknown neighbourhood method {method!r}")
    wanted = NclmOptions if method == "N-CLM" else NcsgOptions
    if not isinstance(options, wanted):
        raise ModelError(f"{method} takes {wanted.__name__}, got {type(options).__name__}")
    o = options
    init = check_start(problem, o.iterations, o.consensus_rounds, o.initial_m)
    ex = exchange_for(problem, exchange)
    nb = Neighbourhoods(problem, ex, o.loss, o.loss_scale_m, o.objective, o.sigma_m)
    w = mixing_weights(problem, o.weights)
    search = o if isinstance(o, NcsgOptions) else NcsgOptions()  # N-CLM: the defaults, never used
    alpha, alpha0 = search.steps()
    alpha_i, alpha0_i = _relative_steps(nb, alpha, alpha0)
    slope = 2.0 if search.armijo_slope == "gradient" else 1.0
    plan = NeighbourhoodPlan(
        nb,
        Mixing(nb, ex, w),
        w,
        method,
        o.iterations,
        alpha,
        alpha_i,
        LineSearch(alpha0_i, search.beta, search.gamma, search.max_backtracks, slope),
        o.loss,
        o.graduated_iterations(),
        o.consensus_rounds,
        LocalLM(nb, o.damping, o.lambda_min) if isinstance(o, NclmOptions) else None,
    )
    if method == "N-CSG":
        step = np.full(nb.nl, float(alpha)) if not nb.metres else np.asarray(alpha_i, float).copy()
    elif isinstance(o, NclmOptions):
        step = np.full(nb.nl, float(o.lambda0))
    else:
        step = plan.bls_start()
    return plan, nb.initial(init), step


def _relative_steps(nb: Neighbourhoods, alpha: float, alpha0: float) -> tuple[float | np.ndarray, float | np.ndarray]:
    """``(alpha, alpha0)`` per anchor: relative to each anchor's information ``Σ σ⁻²`` for metres (1 for an anchor
    without links), else as given."""
    if not nb.metres:
        return alpha, alpha0
    info = np.bincount(nb.h_own, 1.0 / nb.h_sigma**2, minlength=nb.nl)
    unit = 1.0 / np.where(info > 0, info, 1.0)
    return alpha * unit, alpha0 * unit
