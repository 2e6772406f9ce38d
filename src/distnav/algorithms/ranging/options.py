"""The settings of the distributed ranging front doors (paper 002 §3.2–3.4), in the house style of
:mod:`distnav._settings`: one frozen options object per front door, validated once, with documented defaults.

:class:`RunOptions` holds what CSG, N-CSG and N-CLM share: over
:class:`~distnav.algorithms.ranging.objective.FitOptions` (what LM shares too: start, objective, range offsets,
quality control) the budget, consensus, stopping rule and final LM phase. :class:`CsgOptions` adds CSG's step,
:class:`NeighbourhoodOptions` the robust loss of the neighbourhood solvers, and :class:`NcsgOptions` /
:class:`NclmOptions` their line search or damping. The same object drives a front door
(:func:`~distnav.algorithms.ranging.csg.solve_ncsg`) and its iteration
(:func:`~distnav.algorithms.ranging.neighbourhood.iterate_neighbourhood`), which ignores the run-only fields
(``monitor_every``, ``stop``, ``quality``, ``test_level``, ``test_scale``, ``refine``).

Values are checked in ``__post_init__`` and refused with :class:`~distnav.errors.ModelError` naming the field (the
family's error since before the options objects; a name that is not a field is refused by
:func:`~distnav._settings.resolve_options` with :class:`~distnav.errors.UsageError`). Checks that need
the problem (``iterations``, ``consensus_rounds``, ``weights``, ``initial_m``, ``sigma_m``) stay where the
problem is known.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from distnav._checks import check_field_types
from distnav.algorithms.ranging.losses import LOSSES
from distnav.algorithms.ranging.objective import FitOptions
from distnav.algorithms.ranging.qc import DISTRIBUTED_TEST_SCALES
from distnav.algorithms.ranging.stop import StopRule
from distnav.errors import ModelError
from distnav.network.weights import ConsensusWeights

__all__ = [
    "CsgOptions",
    "NclmOptions",
    "NcsgOptions",
    "NeighbourhoodOptions",
    "RunOptions",
]


def _positive(**values: float | None) -> None:
    """Refuse, by name, a value that is given (not None) and not positive."""
    for name, value in values.items():
        if value is not None and not value > 0:
            raise ModelError(f"{name} must be positive, got {value}")


def _forcing(terms: tuple[float, ...] | None) -> None:
    """Refuse a forcing term that is not ``(γ, α, η₀, η_min, η_max[, stop_η])`` with every η in (0, 1),
    ``η_min ≤ η_max``, γ and α positive (:class:`~distnav.algorithms.ranging.inner.Forcing`)."""
    if terms is None:
        return
    if len(terms) not in (5, 6):
        raise ModelError(f"refine_forcing must be (gamma, alpha, eta0, eta_min, eta_max[, stop_eta]), got {terms!r}")
    gamma, alpha, *etas = (float(t) for t in terms)
    _positive(refine_forcing_gamma=gamma, refine_forcing_alpha=alpha)
    if not all(0 < e <= 1 for e in etas) or etas[1] > etas[2]:
        raise ModelError(f"refine_forcing's η values must lie in (0, 1] with eta_min ≤ eta_max, got {terms!r}")


@dataclass(frozen=True, kw_only=True)
class RunOptions(FitOptions):
    """:class:`~distnav.algorithms.ranging.objective.FitOptions` and what every distributed ranging front door adds
    (CSG, N-CSG, N-CLM).

    - ``iterations`` (500, the paper's): the iteration budget.
    - ``consensus_rounds`` (1): consensus rounds per iteration (eq. (11) / (15)).
    - ``weights`` (``"MH"``, eq. (12); or ``"Koppanyi"``, or a :class:`ConsensusWeights`): the mixing weights.
    - ``monitor_every`` (1): gather the estimates for the trace and the stopping tests every k-th iteration
      (0: start and end only).
    - ``stop`` (``StopRule()``; None runs all ``iterations`` as the paper): the stopping rule.
    - ``refine`` (None: with the metres objective and a stopping rule): a final distributed LM phase.
    - ``refine_mu0`` (None: ``refine.MU0``): that phase's initial Marquardt damping (a warm re-fit: the last fit's
      final one, ``settings["refine"]["mu"]``, issue 27).
    - ``refine_held_m`` (None; an ``(n_anchors, dim)`` array): per anchor, the coordinates every one of its ranged
      neighbours holds bit for bit from the last fit's LM phase (NaN: not held); that phase's start must equal
      them there and sends nothing from those anchors (a warm re-fit: ``field_fits.CARRY_HELD``; issue 27,
      :class:`~distnav.algorithms.ranging.wire.Wire` item 6).
    - ``refine_forcing`` (None: every inner solve to ``inner.CG_RTOL``): that phase's adaptive forcing term
      ``(γ, α, η₀, η_min, η_max)``, optionally with the loosest η whose step may stop it
      (:class:`~distnav.algorithms.ranging.inner.Forcing`; a workflow's fits by their stage:
      ``field_fits.STAGE_FORCING`` over ``field_fits.FORCING_STAGES``, issue 27).
    - ``test_scale`` also ``"local"`` (each anchor's own scale) beside the centralized scales.

    ``range_offsets="common_delays"`` (LM's) is refused by name: the neighbourhood solvers' offsets
    (:mod:`~distnav.algorithms.ranging.neighbourhood_offsets`) hold a common offset or per-anchor delays, not both.
    """

    iterations: int = 500
    consensus_rounds: int = 1
    weights: str | ConsensusWeights = "MH"
    monitor_every: int = 1
    stop: StopRule | None = StopRule()
    refine: bool | None = None
    refine_mu0: float | None = None
    refine_held_m: np.ndarray | None = None
    refine_forcing: tuple[float, ...] | None = None

    def __post_init__(self) -> None:
        check_field_types(self, error=ModelError)  # types first, naming the field (issue 29)
        _positive(refine_mu0=self.refine_mu0)
        _forcing(self.refine_forcing)
        if self.monitor_every < 0:
            raise ModelError(f"monitor_every must be ≥ 0, got {self.monitor_every}")
        if self.test_scale not in DISTRIBUTED_TEST_SCALES:
            raise ModelError(f"test_scale must be one of {', '.join(DISTRIBUTED_TEST_SCALES)}, got {self.test_scale!r}")
        super().__post_init__()
        if self.range_offsets == "common_delays":
            raise ModelError(
                "range_offsets='common_delays' (a common offset plus per-anchor delays about it) is LM's only: the "
                "distributed solvers (CSG, N-CSG, N-CLM) estimate 'common' or 'per_anchor' offsets"
            )

    @property
    def refines(self) -> bool:
        """Whether a final distributed LM phase runs (:mod:`distnav.algorithms.ranging.refine`): ``refine``, by
        default with the metres objective and a stopping rule (never in the paper's mode)."""
        return bool(self.refine) if self.refine is not None else self.objective == "metres" and self.stop is not None


@dataclass(frozen=True, kw_only=True)
class CsgOptions(RunOptions):
    """:class:`RunOptions` and CSG's step ``alpha`` (eq. (10); None: the paper's 1e-3 for the squared objective,
    0.8 relative to each anchor's information for metres). CSG has no robust loss (Koppanyi's algorithm)."""

    alpha: float | None = None

    def __post_init__(self) -> None:
        super().__post_init__()
        _positive(alpha=self.alpha)

    def step(self) -> float:
        """``alpha``, or its default for the objective."""
        return (1e-3 if self.objective == "squared" else 0.8) if self.alpha is None else self.alpha


@dataclass(frozen=True, kw_only=True)
class NeighbourhoodOptions(RunOptions):
    """:class:`RunOptions` and the robust loss of the neighbourhood solvers (N-CSG, N-CLM).

    - ``loss`` (``"linear"``; ``"huber"``, ``"soft_l1"``, ``"cauchy"``, ...): the robust loss of the partial costs.
    - ``loss_scale_m`` (0.3): the range error where the loss bends, metres.
    - ``graduated`` (None: a quarter of ``iterations`` for metres with a robust loss, else 0): iterations with the
      linear loss before the robust one.
    - ``initial_offset_m`` (None: 0): the common range offset's start, metres (``range_offsets="common"``; a warm
      re-fit carries the last fit's, which every anchor holds: issue 27).
    """

    loss: str = "linear"
    loss_scale_m: float = 0.3
    graduated: int | None = None
    initial_offset_m: float | None = None

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.loss not in LOSSES:
            raise ModelError(f"unknown loss {self.loss!r}; choose one of {', '.join(LOSSES)}")
        if self.graduated is not None and self.graduated < 0:
            raise ModelError(f"graduated must be ≥ 0 iterations, got {self.graduated}")
        if self.initial_offset_m is not None and self.range_offsets != "common":
            raise ModelError(
                f"initial_offset_m is the common offset's start, not for range_offsets={self.range_offsets!r}"
            )

    def graduated_iterations(self) -> int:
        """``graduated``, or its default."""
        if self.graduated is not None:
            return int(self.graduated)
        return self.iterations // 4 if self.objective == "metres" and self.loss != "linear" else 0


@dataclass(frozen=True, kw_only=True)
class NcsgOptions(NeighbourhoodOptions):
    """:class:`NeighbourhoodOptions` and N-CSG's steps and line search (eqs. (14)–(21)).

    - ``alpha`` (None: 1e-3 squared, 0.8 metres, relative to each anchor's information): N-CSG's fixed step.
    - ``alpha0`` (None: 1e-2 squared, the paper's; 2 metres): the line searches' largest step.
    - ``beta`` (1/2), ``gamma`` (1/2): the backtracking factor and the Armijo constant, both in (0, 1).
    - ``max_backtracks`` (40): the line searches' trial steps per iteration.
    - ``armijo_slope`` (``"subgradient"``, the paper's; or ``"gradient"``): the slope in the Armijo test.
    """

    alpha: float | None = None
    alpha0: float | None = None
    beta: float = 0.5
    gamma: float = 0.5
    max_backtracks: int = 40
    armijo_slope: str = "subgradient"

    def __post_init__(self) -> None:
        super().__post_init__()
        _positive(alpha=self.alpha, alpha0=self.alpha0)
        if self.armijo_slope not in ("gradient", "subgradient"):
            raise ModelError(f"armijo_slope must be 'gradient' or 'subgradient', got {self.armijo_slope!r}")
        if not (0 < self.beta < 1 and 0 < self.gamma < 1):
            raise ModelError(f"beta and gamma must lie in (0, 1), got beta={self.beta}, gamma={self.gamma}")

    def steps(self) -> tuple[float, float]:
        """``(alpha, alpha0)``, or their defaults for the objective."""
        squared = self.objective == "squared"
        a = (1e-3 if squared else 0.8) if self.alpha is None else self.alpha
        a0 = (1e-2 if squared else 2.0) if self.alpha0 is None else self.alpha0
        return a, a0


@dataclass(frozen=True, kw_only=True)
class NclmOptions(NeighbourhoodOptions):
    """:class:`NeighbourhoodOptions` and N-CLM's damping (eq. (22)).

    - ``lambda0`` (1e-3): every anchor's initial ``λ_i``.
    - ``damping`` (``"levenberg"``: ``λ_i · mean(diag(G⁽ⁱ⁾ᵀG⁽ⁱ⁾)) · I``; or ``"fletcher"``, eq. (8) literally).
    - ``lambda_min`` (0.1): the floor of every ``λ_i``.
    """

    lambda0: float = 1e-3
    damping: str = "levenberg"
    lambda_min: float = 0.1

    def __post_init__(self) -> None:
        super().__post_init__()
        _positive(lambda0=self.lambda0, lambda_min=self.lambda_min)
        if self.damping not in ("levenberg", "fletcher"):
            raise ModelError(f"damping must be 'levenberg' or 'fletcher', got {self.damping!r}")
