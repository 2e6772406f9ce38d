"""The result type shared by every distnav solver family."""

from __future__ import annotations

import warnings
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, fields
from typing import Any, Literal, get_args

import numpy as np

from distnav.exchange.core import CommTotals

__all__ = ["ObservationTests", "Precision", "SOLVER_STATUSES", "SolverResult", "SolverStatus", "Trace", "TraceBuilder"]


class Trace(Mapping[str, np.ndarray]):
    """Per-iteration arrays of a run, keyed by name (leading axis = iteration).

    Common keys: ``distance_to_reference`` (iterations × nodes, ‖x_i^[k] − x̂‖ when x̂ is known),
    ``max_distance_to_reference``, ``primal_residual``, ``dual_residual``, ``cost``, ``step_size``,
    ``max_abs_deviation`` (consensus), ``rmse_m`` (UWB).
    """

    def __init__(self, data: Mapping[str, Any] | None = None) -> None:
        self._data: dict[str, np.ndarray] = {k: np.asarray(v) for k, v in (data or {}).items()}

    def __getitem__(self, key: str) -> np.ndarray:
        try:
            return self._data[key]
        except KeyError:
            raise KeyError(f"trace has no {key!r}; available: {', '.join(self._data) or 'none'}") from None

    def __iter__(self) -> Iterator[str]:
        return iter(self._data)

    def __len__(self) -> int:
        return len(self._data)

    def __repr__(self) -> str:
        return "Trace(" + ", ".join(f"{k}: {v.shape}" for k, v in self._data.items()) + ")"


class TraceBuilder:
    """Collects per-iteration values; :meth:`build` stacks them into a :class:`Trace`."""

    def __init__(self) -> None:
        self._rows: dict[str, list[Any]] = {}

    def add(self, **values: Any) -> None:
        for k, v in values.items():
            self._rows.setdefault(k, []).append(np.asarray(v))

    def build(self) -> Trace:
        return Trace({k: np.stack(v) if v else np.zeros(0) for k, v in self._rows.items()})


SolverStatus = Literal["converged", "max_iterations", "stopped", "diverged", "ambiguous", "weakly_determined"]
"""How a run ended. ``converged``: the stopping rule was met. ``max_iterations``: the budget ran out before it.
``stopped``: a filter ran out of epochs before every state was estimable (or a user stopped a generator).
``diverged``: the iterates blew up or the cost rose without bound; the estimates are not usable.
``ambiguous``: the data admit more than one solution (e.g. a mirror image); the estimates are one of them.
``weakly_determined``: converged, but some parameters are barely constrained (see the message)."""

SOLVER_STATUSES: tuple[str, ...] = get_args(SolverStatus)
USABLE_STATUSES: frozenset[str] = frozenset({"converged", "max_iterations", "stopped", "weakly_determined"})


@dataclass(frozen=True, eq=False)
class Precision:
    """What each node knows about the precision of its own estimate.

    Attributes
    ----------
    covariance : ``(n_nodes, p, p)`` covariance block of every node's estimate, scaled by the a-priori variance
        factor (σ² = 1); multiply by :attr:`variance_factor` for the a-posteriori covariance.
    variance_factor : a-posteriori variance factor σ̂² = êᵀR⁻¹ê / redundancy, or ``None`` where the redundancy is 0.
    redundancy : number of observations minus the number of estimable parameters (m − rank A).
    kind : ``"exact"`` (equal to the centralized value up to the stopping tolerance), ``"bound"`` (a stated upper
        bound, never optimistic), ``"centralized"`` (computed at one place) or ``"conditional"`` (each node's
        covariance with its neighbours held at their estimates: a lower bound, optimistic, and said so) or
        ``"neighbourhood"`` (each node's covariance with its neighbours' errors propagated through its links from
        their own blocks, :mod:`distnav.algorithms.ranging.precision`: an approximation, neither bound).
    iterations : message rounds or iterations spent on the precision (beyond those of the estimate).
    comm : the messages and bytes they cost (``None`` for centralized values).
    """

    covariance: np.ndarray
    variance_factor: float | None
    redundancy: float
    kind: Literal["exact", "bound", "centralized", "conditional", "neighbourhood", "central"]
    iterations: int = 0
    comm: CommTotals | None = None

    def std(self, *, a_posteriori: bool = False) -> np.ndarray:
        """Standard deviations ``(n_nodes, p)`` from the covariance diagonal (a-posteriori: × σ̂)."""
        diag: np.ndarray = np.sqrt(np.maximum(np.diagonal(self.covariance, axis1=-2, axis2=-1), 0.0))
        if a_posteriori and self.variance_factor is not None:
            diag = diag * np.sqrt(self.variance_factor)
        return diag

    def summary(self) -> dict[str, Any]:
        return {
            "variance_factor": self.variance_factor,
            "redundancy": self.redundancy,
            "kind": self.kind,
            "iterations": self.iterations,
            "communication": None if self.comm is None else self.comm.as_dict(),
        }


@dataclass(frozen=True, eq=False)
class ObservationTests:
    """Test statistics of the observations, each computed by the node that holds the observation.

    Attributes
    ----------
    node : owning node of each observation (``(m,)``).
    w : w-test statistic of each observation (standardized residual, N(0, 1) under H0); NaN where the residual
        variance is zero (an observation no other can check).
    critical_value : |w| above which an observation is flagged, for :attr:`level`.
    level : the false-alarm probability of one test (two-sided).
    flagged : ``(m,)`` observations above the critical value in the final solution.
    removed : indices of the observations removed, in the order they were removed (iterative data snooping).
    iterations : extra solver iterations spent on re-convergence after removals.
    comm : the extra messages and bytes that cost (``None`` for centralized tests).
    """

    node: np.ndarray
    w: np.ndarray
    critical_value: float
    level: float
    flagged: np.ndarray
    removed: tuple[int, ...] = ()
    iterations: int = 0
    comm: CommTotals | None = None

    def summary(self) -> dict[str, Any]:
        return {
            "level": self.level,
            "critical_value": self.critical_value,
            "flagged": int(np.count_nonzero(self.flagged)),
            "removed": list(self.removed),
            "iterations": self.iterations,
            "communication": None if self.comm is None else self.comm.as_dict(),
        }


_BASE_FIELDS = ("estimates", "converged", "iterations", "status", "message", "trace", "comm")


@dataclass(frozen=True, eq=False)
class SolverResult:
    """Outcome of a distributed (or reference) solver; the same fields for every family.

    Each family returns a subclass with typed, named fields for what is particular to it (ADMM's ``z`` and
    constraint nodes, a filter's ``series``, precision and test statistics); this base holds what all share.

    Attributes
    ----------
    estimates : per-node estimates, leading axis = node (for centralized solvers one row).
    converged : whether the stopping tolerance was met.
    iterations : iterations (or consensus rounds, or epochs) performed.
    status : one of :data:`SolverStatus`; checked on construction.
    message : a human-readable account of how the run ended.
    trace : per-iteration arrays (:class:`Trace`).
    comm : communication totals (:class:`~distnav.exchange.base.CommTotals`).
    """

    estimates: np.ndarray
    converged: bool
    iterations: int
    status: SolverStatus
    message: str
    trace: Trace
    comm: CommTotals

    def __post_init__(self) -> None:
        if self.status not in SOLVER_STATUSES:
            raise ValueError(f"unknown solver status {self.status!r}; expected one of {', '.join(SOLVER_STATUSES)}")

    @property
    def usable(self) -> bool:
        """Whether the estimates are worth using (not diverged, not ambiguous)."""
        return self.status in USABLE_STATUSES

    @property
    def extras(self) -> Mapping[str, Any]:
        """Deprecated: the family-specific fields by name. Read the typed attributes instead."""
        warnings.warn(
            f"SolverResult.extras is deprecated: read the typed fields of the result ({type(self).__name__}) instead",
            DeprecationWarning,
            stacklevel=2,
        )
        return {f.name: getattr(self, f.name) for f in fields(self) if f.name not in _BASE_FIELDS}

    def summary(self) -> dict[str, Any]:
        """JSON-friendly summary (no large arrays)."""
        return {
            "converged": self.converged,
            "iterations": self.iterations,
            "status": self.status,
            "message": self.message,
            "communication": self.comm.as_dict(),
        }
