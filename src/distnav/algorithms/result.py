"""The result type shared by every distnav solver family."""

from __future__ import annotations

import warnings
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, fields
from typing import TYPE_CHECKING, Any, Literal, get_args

import numpy as np

from distnav.exchange.core import CommTotals
from distnav.typing import ArrayLike

if TYPE_CHECKING:
    from distnav.exchange.base import Exchange
    from distnav.network.gather import GatherCost
    from distnav.network.graph import Graph

__all__ = [
    "CommComparison",
    "compare_with_gather",
    "format_bytes",
    "format_count",
    "format_ratio",
    "ObservationTests",
    "Precision",
    "SOLVER_STATUSES",
    "SolverResult",
    "SolverStatus",
    "stopping_fields",
    "Trace",
    "TraceBuilder",
]


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

    @classmethod
    def gathered(
        cls,
        ex: Exchange,
        blocks: np.ndarray,
        before: CommTotals,
        *,
        variance_factor: float | None,
        redundancy: float,
        kind: Literal["exact", "bound", "conditional", "neighbourhood", "central"],
        iterations: int,
    ) -> Precision:
        """A distributed precision: every node's covariance block (``blocks``, the exchange's local rows) gathered
        for the result, and what the exchange ``ex`` cost since the snapshot ``before``."""
        return cls(
            covariance=ex.gather_nodes(blocks),
            variance_factor=variance_factor,
            redundancy=redundancy,
            kind=kind,
            iterations=iterations,
            comm=ex.comm_totals().since(before),
        )

    def std(self, *, a_posteriori: bool = False) -> np.ndarray:
        """Standard deviations ``(n_nodes, p)`` from the covariance diagonal (a-posteriori: × σ̂)."""
        diag: np.ndarray = np.sqrt(np.maximum(np.diagonal(self.covariance, axis1=-2, axis2=-1), 0.0))
        if a_posteriori and self.variance_factor is not None:
            diag = diag * np.sqrt(self.variance_factor)
        return diag

    def summary(self) -> dict[str, Any]:
        plain = {name: getattr(self, name) for name in ("variance_factor", "redundancy", "kind", "iterations")}
        return {**plain, "communication": None if self.comm is None else self.comm.as_dict()}


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
        plain = {name: getattr(self, name) for name in ("converged", "iterations", "status", "message")}
        return {**plain, "communication": self.comm.as_dict()}


def stopping_fields(
    converged: bool, iterations: int, message: str, trace: TraceBuilder, comm: CommTotals
) -> dict[str, Any]:
    """The :class:`SolverResult` fields but ``estimates`` of a run that stops at its tolerance (status
    ``converged``) or else at its iteration limit (``max_iterations``), its trace built."""
    status: SolverStatus = "converged" if converged else "max_iterations"
    return {
        "converged": converged,
        "iterations": iterations,
        "status": status,
        "message": message,
        "trace": trace.build(),
        "comm": comm,
    }


def format_bytes(n_bytes: float) -> str:
    """Bytes in decimal units, three significant digits: ``'41.2 MB'``, ``'2.9 kB'``, ``'512 B'``."""
    value = float(n_bytes)
    for unit in ("B", "kB", "MB", "GB"):
        if abs(value) < 1000 or unit == "GB":
            return f"{value:.0f} {unit}" if unit == "B" else f"{value:.3g} {unit}"
        value /= 1000
    return f"{value:.3g} TB"  # pragma: no cover - unreachable: the loop returns at GB


def format_count(count: float) -> str:
    """A count for a console line: ``'9,870'``, ``'326 k'``, ``'4.24 M'``."""
    c = float(count)
    if abs(c) < 10_000:
        return f"{c:,.0f}"
    if abs(c) < 1e6:
        return f"{c / 1e3:.3g} k"
    return f"{c / 1e6:.3g} M"


def format_ratio(ratio: float) -> str:
    """``'14,000×'`` (three significant digits above 100), ``'3.2×'``, ``'0.41×'``."""
    if not np.isfinite(ratio):
        return "∞×"
    if ratio >= 100:
        return f"{float(f'{ratio:.3g}'):,.0f}×"
    return f"{ratio:.0f}×" if ratio >= 10 else f"{ratio:.2g}×"


@dataclass(frozen=True, eq=False)
class CommComparison:
    """A distributed run's communication beside what a fusion centre would cost on the same graph (issue 27).

    ``bytes_sent``/``messages_sent`` are per node (``None`` when the run kept totals only); ``gather`` is
    :func:`distnav.network.gather.gather_cost` of the same data (``data``: what each node holds that a fusion
    centre needs, in words) gathered at one sink by multi-hop relaying. The ratios compare the total bytes with the
    gather's total hop-bytes, and the busiest node's bytes with the gather's busiest relay.
    """

    total_bytes: int
    total_messages: int
    rounds: int | None
    bytes_sent: np.ndarray | None
    messages_sent: np.ndarray | None
    gather: GatherCost
    data: str
    node_label: str = "node"
    node_names: tuple[str, ...] | None = None

    @property
    def ratio_bytes(self) -> float:
        """Total bytes sent ÷ the gather's total hop-bytes."""
        hop = self.gather.total_hop_bytes
        return self.total_bytes / hop if hop else float("inf")

    @property
    def ratio_busiest_node(self) -> float | None:
        """The busiest node's bytes ÷ the gather's busiest relay's bytes (``None`` without per-node counts)."""
        if self.bytes_sent is None or not self.bytes_sent.size:
            return None
        relay = self.gather.busiest_relay_bytes
        return float(self.bytes_sent.max()) / relay if relay else float("inf")

    def _name(self, node: int) -> str:
        return self.node_names[node] if self.node_names is not None and 0 <= node < len(self.node_names) else str(node)

    def as_dict(self) -> dict[str, Any]:
        per_node: dict[str, Any] = {}
        for key, arr in (("bytes", self.bytes_sent), ("messages", self.messages_sent)):
            if arr is not None and arr.size:
                per_node[f"{key}_per_node_max"] = int(arr.max())
                per_node[f"{key}_per_node_median"] = float(np.median(arr))
        return {
            "distributed": {
                "bytes": self.total_bytes,
                "messages": self.total_messages,
                "rounds": self.rounds,
                **per_node,
            },
            "gather": {
                **self.gather.as_dict(),
                "sink_name": self._name(self.gather.sink),
                "data": self.data,
            },
            "ratio_bytes": self.ratio_bytes,
            "ratio_busiest_node": self.ratio_busiest_node,
            "line": self.line(),
        }

    def line(self) -> str:
        """One console line: what the run sent, what gathering the data would cost, the ratio."""
        label = self.node_label
        sent = f"sent {format_bytes(self.total_bytes)} in {format_count(self.total_messages)} messages"
        if self.bytes_sent is not None and self.bytes_sent.size:
            sent += (
                f" (per {label} max {format_bytes(self.bytes_sent.max())}, "
                f"median {format_bytes(float(np.median(self.bytes_sent)))})"
            )
        g = self.gather
        if self.total_bytes == 0 and g.total_hop_bytes == 0:
            return f"{sent}; gathering would cost nothing either: the data are already at one {label}"
        hops = f"{format_count(g.messages)} relay hop{'' if g.messages == 1 else 's'}"
        return (
            f"{sent}; gathering {self.data} at {label} {self._name(g.sink)} would cost "
            f"{format_bytes(g.total_hop_bytes)} over {hops} "
            f"(busiest relay {format_bytes(g.busiest_relay_bytes)}): {format_ratio(self.ratio_bytes)} the bytes"
        )


def compare_with_gather(
    comm: CommTotals | tuple[int, int],
    graph: Graph,
    data_bytes_per_node: ArrayLike,
    *,
    data: str,
    node_label: str = "node",
    node_names: Sequence[object] | None = None,
    sink: int | None = None,
) -> CommComparison:
    """The :class:`CommComparison` of a run: ``comm`` its :class:`CommTotals` (or ``(bytes, messages)`` totals
    when per-node counts were not kept), ``graph`` the communication graph, ``data_bytes_per_node`` the bytes of
    the data each node holds (what a fusion centre would need; ``data`` says what it is)."""
    from distnav.network.gather import gather_cost  # scipy's csgraph: imported on use (the MPI path stays light)

    gather = gather_cost(graph, data_bytes_per_node, sink=sink)
    names = None if node_names is None else tuple(str(v) for v in node_names)
    if isinstance(comm, CommTotals):
        return CommComparison(
            total_bytes=comm.bytes,
            total_messages=comm.messages,
            rounds=comm.rounds,
            bytes_sent=np.asarray(comm.bytes_sent),
            messages_sent=np.asarray(comm.messages_sent),
            gather=gather,
            data=data,
            node_label=node_label,
            node_names=names,
        )
    total_bytes, total_messages = comm
    return CommComparison(int(total_bytes), int(total_messages), None, None, None, gather, data, node_label, names)
