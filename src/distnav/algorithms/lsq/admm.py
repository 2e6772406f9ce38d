"""Distributed least squares by ADMM with constraint nodes (paper 000 §4, Fig. 6), linearized and nonlinear variants.

Every node ``i`` holds its data ``(A_i, y_i, R_i)`` and a local state ``x_i``; every constraint node ``s ∈ C``
(:mod:`distnav.network.constraint_nodes`) holds a consensus state ``z_s``; every pair ``(i, s)`` with ``s ∈ N_i ∩ C``
holds a scaled multiplier ``u_{i,s}`` at node ``i``. One iteration ``k`` of Fig. 6 is:

* step 1, every node ``i`` — u-update ``u_{i,s} += x_i^[k−1] − z_s^[k−1]``; ``l_i = mean_s (z_s − u_{i,s})``;
  x-update ``x_i^[k] = l_i + G_i (y_i − A_i l_i)`` (eq. (20) or Cholesky solves of eq. (21)); then **a message
  round on the pair edges i→s**: ``z_{i,s} = x_i^[k] + u_{i,s}`` to each constraint neighbour (``ex.send`` with
  ``active`` = edges into ``C``);
* step 2, every constraint node ``s`` — ``z_s^[k] = mean_{i∈N_s} z_{i,s}``, then **a broadcast round** of ``z_s``
  to its neighbours (``ex.broadcast`` with ``active`` = edges out of ``C``).

So an iteration is two message rounds; the initialization is one more (the ``z_s^[0]`` broadcast). Nodes talk
only through the exchange on local block arrays, so the same code runs under MPI. A lost message is replaced by
the last value received on that edge (a constraint node starts from its own ``z_s^[0]``, a node from its own
``x_i^[0]``), so runs with a :class:`~distnav.exchange.FaultSchedule` go on and are reproducible by its seed.

**Weighting of the x-update.** The augmented Lagrangian (19) has one penalty ``½‖x_i − (z_s − u_{i,s})‖²_W`` per
pair, so minimizing it over ``x_i`` gives ``x_i = (N_i + c_i W)⁻¹ (r_i + c_i W l_i)`` with ``c_i = |N_i ∩ C|``, i.e.
eqs. (20)/(21) with ``W`` replaced by ``W_i = c_i W``. This is the default (``x_weight="lagrangian"``). Fig. 6 as
printed uses ``G_i = (N_i + W)⁻¹…`` with the *mean* ``l_i``; with the plain-mean z-update that pair of updates is not
the ADMM of any single Lagrangian, and its fixed point satisfies ``N x* − r = −W Σ_i mean_s u_{i,s}``, which is zero
only when every ``c_i`` is equal (e.g. the single-consensus case (16)). ``x_weight="fig6"`` runs it verbatim: it
converges, but to a point that differs from the BLUE on irregular graphs (tests/test_admm.py shows both facts).
The printed x-update can also be kept and the *z-update* repaired instead: weighting each ``z_{i,s}`` by ``1/c_i``,
``z_s = Σ_{i∈N_s} z_{i,s}/c_i / Σ_{i∈N_s} 1/c_i``, makes the pair (printed x-update, weighted z-update) the ADMM
of the Lagrangian with pair weights ``W/c_i``, whose fixed point is the BLUE (``x_weight="fig6-zweighted"``,
per-pair messages; the weights are the constraint neighbours' ``c_i``, known from the graph).

**Cost per iteration** (in-process, batched over nodes): one batched ``(p × m)`` gain product (or two batched
triangular solves), three segment sums over pairs, two message rounds. No Python loop over nodes.

:func:`admm_linearized` (paper 000 §4.3, the linearized case) and :func:`admm_nonlinear` (eq. (23)) handle
nonlinear models ``y_i = F_i(x) + e_i`` given as a :class:`NonlinearProblem`; :func:`gauss_newton` is the centralized
reference (all in :mod:`distnav.algorithms.lsq.nonlinear`, re-exported here). The kernel is
:mod:`distnav.algorithms.lsq.kernel`; the options, their validation and the stopping rule are
:mod:`distnav.algorithms.lsq.driver`.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import numpy as np

from distnav._settings import resolve_options, runs
from distnav.algorithms.lsq.blue import LinearProblem
from distnav.algorithms.lsq.driver import (
    AdmmOptions,
    AdmmResult,
    AdmmRunOptions,
    MessageMode,
    XWeight,
    drive,
    prepare,
    run_options,
)
from distnav.algorithms.lsq.kernel import AdmmState, XUpdate, XUpdateMethod
from distnav.errors import ModelError
from distnav.exchange import Exchange, FaultSchedule, make_exchange
from distnav.network.graph import Graph


def __getattr__(name: str) -> Any:
    """The nonlinear variants (the names of :data:`distnav.algorithms.lsq.nonlinear.__all__`), re-exported from
    :mod:`distnav.algorithms.lsq.nonlinear` on first use (PEP 562): an MPI job of the linear kernel does not import
    them at start-up (so they are not in this module's ``__all__``)."""
    if not name.startswith("_"):
        from distnav.algorithms.lsq import nonlinear as module

        if name in module.__all__:
            return getattr(module, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = [
    "AdmmOptions",
    "AdmmResult",
    "AdmmRunOptions",
    "AdmmState",
    "MessageMode",
    "XUpdateMethod",
    "XWeight",
    "iterate_admm",
    "admm",
    "XUpdate",
]


def iterate_admm(
    problem: LinearProblem,
    graph: Graph,
    *,
    exchange: Exchange | None = None,
    options: AdmmOptions | None = None,
    **changes: Any,
) -> Iterator[AdmmState]:
    """Yield the ADMM state of Fig. 6 (paper 000) after iterations ``0, 1, 2, …`` (endless: stop it yourself).

    Options: one :class:`~distnav.algorithms.lsq.driver.AdmmOptions` (``options=``) and/or keyword changes to it
    (a name that is not one of its fields is refused), validated before the first iteration:
    ``constraint_nodes``: ``"min_cover"`` (default), ``"all"``, node ids, or a
    :class:`~distnav.network.constraint_nodes.ConstraintNodes`. ``W``: ``ρ`` (default 1) or an SPD ``(p, p)``
    matrix. ``x_update``: see :class:`XUpdate`. ``x_weight``: ``"lagrangian"`` (default), ``"fig6"`` or
    ``"fig6-zweighted"`` (module docstring). ``init``: ``"zero"``, a ``(p,)`` vector, an ``(n, p)`` array, or a
    previous :class:`~distnav.algorithms.result.SolverResult` (§4.3: ``x_i^[0] = z_s^[0]`` from an earlier run);
    ``z0`` overrides ``z_s^[0]``. Multipliers start at ``u^[−1] = 0`` (§4.3, eq. (22)). States hold this exchange
    block's rows.

    ``messages="pairs"`` sends ``z_{i,s} = x_i + u_{i,s}`` on each pair edge exactly as Fig. 6;
    ``messages="aggregated"`` broadcasts ``x_i`` to the constraint neighbours and keeps multiplier *sums* (node
    ``U_i = Σ_s u_{i,s}``, constraint node ``V_s = Σ_i u_{i,s}``): the same iterates without faults, the same number of
    messages, but no per-pair state — several times faster on large networks. It refuses a fault schedule: a lost
    message corrupts the sums for good, while the per-pair form (holding the last value received) still converges
    to the BLUE. ``monitor_every``: compute the residuals (network totals, monitoring only) every that many
    iterations; the others yield NaN residuals (0 = never).

    Raises :class:`~distnav.errors.ModelError` for a problem whose ``Σ N_i`` is singular (as
    :func:`~distnav.algorithms.lsq.blue` does), naming the inestimable directions.
    """
    return prepare(problem, graph, exchange, resolve_options(AdmmOptions, options, changes)).states


@runs(iterate_admm, adds=("reference", "faults"))
def admm(
    problem: LinearProblem,
    graph: Graph,
    *,
    reference: np.ndarray | None = None,
    exchange: Exchange | None = None,
    faults: FaultSchedule | None = None,
    options: AdmmOptions | None = None,
    **changes: Any,
) -> AdmmResult:
    """Distributed least squares by ADMM with constraint nodes (paper 000, Fig. 6); options
    :class:`~distnav.algorithms.lsq.driver.AdmmRunOptions`: those of :func:`iterate_admm` plus the stopping rule
    ``max_iterations`` [1000], ``tol`` [1e-10], ``atol`` [0.0], ``stop_at_reference`` [None] and ``record_nodes``
    [True] (``options=`` one object — an :class:`~distnav.algorithms.lsq.driver.AdmmOptions` gets the default stopping
    rule — and/or keyword changes to it).

    Stops after ``max_iterations`` or when ``primal ≤ atol·√(P p) + tol·max(‖x‖, ‖z‖)`` and
    ``dual ≤ atol·√(P p) + tol·‖W U‖`` (pair norms, ``P`` pairs, ``U_i = Σ_s u_{i,s}``; after Boyd et al. 2011
    §3.3), or — for experiments —
    when ``max_i ‖x_i − x̂‖/‖x̂‖ ≤ stop_at_reference``. The stopping test uses network totals
    (``ex.allreduce``); a deployment would run a fixed count instead. With ``monitor_every = k`` the residuals (and
    so the tolerance test) are computed every ``k``-th iteration only (NaN in the trace otherwise) — cheaper on
    large networks; 0 disables the tolerance test.

    Trace (leading axis = iteration ``0..k``): ``primal_residual``, ``dual_residual``; with ``reference`` (x̂)
    ``max_distance_to_reference`` and ``relative_max_distance`` (``max_i ‖x_i − x̂‖/‖x̂‖``) and, with
    ``record_nodes``, ``distance_to_reference`` (``k × n``: ``‖x_i^[k] − x̂‖`` per node). The result
    (:class:`~distnav.algorithms.lsq.driver.AdmmResult`) has ``z`` (per constraint node), ``z_nodes`` (per node,
    zero rows off ``C``), ``constraint_nodes``, ``x_update``, ``x_weight``, ``messages``, ``pairs`` and
    ``iterations_to`` (first iteration with relative distance ≤ 1e-4, 1e-6, 1e-8 when a reference is given).
    Every per-node result is in the user's node order at every size: without ``exchange`` the run keeps the
    locality order (``order="auto"``) inside and gathers back; pass ``make_exchange(graph, order="auto")`` for the
    same speed with your own exchange (docs/scale.md).

    Examples
    --------
    The three nodes of :func:`~distnav.algorithms.lsq.blue.blue`'s example on a path ``0 – 1 – 2``: every node ends
    with the BLUE ``(1.1, 2.1)`` by messages to its neighbours only:

    >>> import numpy as np
    >>> from distnav.algorithms.lsq.admm import admm
    >>> from distnav.algorithms.lsq.blue import LinearProblem
    >>> from distnav.network import builders
    >>> A = [np.array([[1.0, 0.0]]), np.array([[0.0, 1.0]]), np.array([[1.0, 1.0]])]
    >>> y = [np.array([1.0]), np.array([2.0]), np.array([3.3])]
    >>> res = admm(LinearProblem.from_blocks(A, y), builders.path(3), max_iterations=2000, tol=1e-12)
    >>> res.converged, res.estimates.round(6).tolist()
    (True, [[1.1, 2.1], [1.1, 2.1], [1.1, 2.1]])
    """
    o = resolve_options(AdmmRunOptions, run_options(options), changes)
    if o.max_iterations == 0 and (o.init is None or isinstance(o.init, str)):
        raise ModelError(
            "max_iterations=0 from a cold start returns the initial values, not a solution: give "
            "max_iterations ≥ 1, or init= a previous result or values to evaluate them"
        )
    if exchange is not None and faults is not None:
        raise ModelError("pass faults either to the exchange or to admm(), not both")
    ex = exchange if exchange is not None else make_exchange(graph, faults=faults, order="auto")  # gathered below
    run = prepare(problem, graph, ex, o)
    return drive(run, o, reference=reference, stop_at_reference=o.stop_at_reference, record_nodes=o.record_nodes)
