"""The result type shared by every distnav solver family."""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from distnav.exchange.base import CommTotals

__all__ = ["SolverResult", "Trace"]


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


@dataclass(frozen=True, eq=False)
class SolverResult:
    """Outcome of a distributed (or reference) solver; the same fields for every family.

    Attributes
    ----------
    estimates : per-node estimates, leading axis = node (for centralized solvers one row).
    converged : whether the stopping tolerance was met.
    iterations : iterations (or consensus rounds, or epochs) performed.
    status : ``"converged"``, ``"max_iterations"`` or ``"stopped"``.
    message : a human-readable account of how the run ended.
    trace : per-iteration arrays (:class:`Trace`).
    comm : communication totals (:class:`~distnav.exchange.base.CommTotals`).
    extras : solver-specific outputs (e.g. ``z`` of ADMM, information matrices of the CKF).
    """

    estimates: np.ndarray
    converged: bool
    iterations: int
    status: str
    message: str
    trace: Trace
    comm: CommTotals
    extras: Mapping[str, Any] = field(default_factory=dict)

    def summary(self) -> dict[str, Any]:
        """JSON-friendly summary (no large arrays)."""
        return {
            "converged": self.converged,
            "iterations": self.iterations,
            "status": self.status,
            "message": self.message,
            "communication": self.comm.as_dict(),
        }
