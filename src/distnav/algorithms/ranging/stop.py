"""When the distributed UWB solvers stop (:class:`StopRule`; used by :mod:`distnav.algorithms.ranging.csg`
and re-exported there)."""

from __future__ import annotations

from dataclasses import dataclass

from distnav.errors import ModelError

__all__ = ["StopRule", "REFINE_FTOL", "REFINE_XTOL_M"]

REFINE_FTOL, REFINE_XTOL_M = 1e-6, 1e-4  # the final LM phase's loosest thresholds (StopRule.phase_tolerances)


@dataclass(frozen=True)
class StopRule:
    """When a distributed run stops (paper 002 §5 suggests the cost and the step size; a network-total test).

    At every monitored iteration (after the graduated linear stage): converged when, for ``patience`` checks in a
    row, the global objective changed by at most ``ftol`` (relative) since the previous check and no anchor's own
    estimate (nor its range offset) moved by more than ``xtol_m`` metres. Diverged when the cost is not finite or
    an own estimate is farther than ``divergence_factor`` × the extent of the start from its centre. The tests use
    network totals (``ex.allreduce``), like ADMM's; a deployment without them runs a fixed count (``stop=None``, the
    paper's mode).

    With the final LM phase (``refine``) the iterations only hand over a start; the phase stops by
    ``refine_ftol`` / ``refine_xtol_m``: by default ``ftol`` / ``xtol_m``, never looser than :data:`REFINE_FTOL` /
    :data:`REFINE_XTOL_M` (a loose hand-over, ``StopRule(ftol=1e-2, xtol_m=0.5)``: 36 iterations instead of 500 on
    the 32 × 32 grid of ``benchmarks/bench_uwb_scaling.py``, the same answer; docs/scale.md).
    """

    ftol: float = 1e-6
    xtol_m: float = 1e-4
    patience: int = 3
    divergence_factor: float = 100.0
    refine_ftol: float | None = None
    refine_xtol_m: float | None = None

    def __post_init__(self) -> None:
        if not (
            min(self.ftol, self.xtol_m, *self.phase_tolerances) >= 0
            and self.patience >= 1
            and self.divergence_factor > 1
        ):
            raise ModelError(f"invalid stopping rule {self}")

    @property
    def phase_tolerances(self) -> tuple[float, float]:
        """``(ftol, xtol_m)`` of the final distributed LM phase (see the class docstring)."""
        return (
            min(self.ftol, REFINE_FTOL) if self.refine_ftol is None else self.refine_ftol,
            min(self.xtol_m, REFINE_XTOL_M) if self.refine_xtol_m is None else self.refine_xtol_m,
        )
