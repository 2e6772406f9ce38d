"""N-CSG-BLS and N-CSG-TBLS (paper 002 eqs. (19)–(21)) run side by side, computing what they share once.

On paper 002's problems the two line searches give the same steps in every iteration, so the two runs are the
same, bit for bit, and running them separately costs twice. :func:`iterate_line_search_pair` runs them in lockstep
and does the shared work (geometry, gradient, the BLS search, the consensus round) once while it is *provably*
the same for both:

* BLS tests ``α₀, βα₀, β²α₀, …`` and stops at the first step ``α_B`` where Armijo holds, so every grid step above
  ``α_B`` fails. TBLS starts from its previous step ``α_T``, itself a step of the same grid (``α₀`` or an earlier
  ``α_B``, reached by the same multiplications). If ``α_T ≥ α_B`` and Armijo holds at ``α_B``, TBLS shrinks through
  failing grid steps to ``α_B`` and its first growth trial ``α_B/β`` is a failing grid step too (or above ``α₀``),
  so it returns ``α_B`` (anchors without a descent direction keep their own previous step and do not move).
  With ``β`` a power of two, ``α/β`` and ``βα`` are exact, so "the same grid step" is bit-identical.
* Otherwise (an anchor whose TBLS step is below BLS's, climbing) TBLS runs its own search, reusing BLS's
  tests (every step at or above BLS's result is known) and evaluating only the steps below it. If the two
  updated vectors agree bit for bit the run stays shared, else it splits into two independent runs from there.

The messages are sent over both exchanges, so each run's communication counts are its own. Sharing needs
in-process exchanges without faults (under MPI each block would have to agree on the split); otherwise the
pair runs as two independent iterations.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Iterator
from dataclasses import replace

import numpy as np

from distnav.algorithms.ranging.data import RangingData
from distnav.algorithms.ranging.neighbourhoods import ArmijoTest, IterationState, Mixing
from distnav.algorithms.ranging.options import NcsgOptions
from distnav.algorithms.ranging.plan import NeighbourhoodPlan, plan_neighbourhood
from distnav.errors import ModelError
from distnav.exchange import Exchange

__all__ = ["iterate_line_search_pair"]


def _shareable(ex_b: Exchange, ex_t: Exchange, beta: float) -> bool:
    def plain(ex: Exchange) -> bool:
        return ex.backend == "inprocess" and not ex.faults.active and ex.n_local == ex.n_nodes

    same_order = (
        np.array_equal(ex_b.nodes, ex_t.nodes)
        and np.array_equal(ex_b.out_edges, ex_t.out_edges)
        and np.array_equal(ex_b.in_edges, ex_t.in_edges)
    )
    return plain(ex_b) and plain(ex_t) and same_order and math.frexp(beta)[0] == 0.5


def _bits_equal(a: np.ndarray, b: np.ndarray) -> bool:
    return a.shape == b.shape and bool(np.array_equal(a.view(np.uint64), b.view(np.uint64)))


class _Runs:
    """Two state iterators fed from one lockstep generator while the runs are shared, each from its own loop after
    the split: a run advances only when its consumer asks (a run that stopped sends no more messages)."""

    def __init__(self) -> None:
        self.shared: Iterator[tuple[IterationState, IterationState]] = iter(())
        self.split: tuple[Iterator[IterationState], Iterator[IterationState]] | None = None
        self.buffer: tuple[deque[IterationState], deque[IterationState]] = (deque(), deque())

    def run(self, which: int) -> Iterator[IterationState]:
        while True:
            if self.buffer[which]:
                yield self.buffer[which].popleft()
            elif self.split is not None:
                yield from self.split[which]
                return
            else:
                pair = next(self.shared, None)
                if pair is not None:
                    self.buffer[1 - which].append(pair[1 - which])
                    yield pair[which]
                elif self.split is None:
                    return


def iterate_line_search_pair(
    problem: RangingData, options: NcsgOptions, *, exchanges: tuple[Exchange, Exchange]
) -> tuple[Iterator[IterationState], Iterator[IterationState]]:
    """The BLS and the TBLS states after iterations 0, 1, …, ``iterations``: the same states as
    ``iterate_neighbourhood(problem, method="N-CSG-BLS", exchange=exchanges[0], options=options)`` and
    ``…"N-CSG-TBLS", exchange=exchanges[1]…`` (see the module docstring). The two iterators may be consumed in any
    order (the states one is ahead by are buffered)."""
    ex_b, ex_t = exchanges
    if ex_b is ex_t:
        raise ModelError("the BLS and TBLS runs need an exchange each (their messages are counted separately)")
    plan_b, P, step_b = plan_neighbourhood(problem, options, method="N-CSG-BLS", exchange=ex_b)
    plan_t, _, step_t = plan_neighbourhood(problem, options, method="N-CSG-TBLS", exchange=ex_t)
    runs = _Runs()
    runs.shared = _lockstep(runs, plan_b, plan_t, P, step_b, step_t, _shareable(ex_b, ex_t, plan_b.line.beta))
    return runs.run(0), runs.run(1)


def _lockstep(
    runs: _Runs,
    plan_b: NeighbourhoodPlan,
    plan_t: NeighbourhoodPlan,
    P: np.ndarray,
    step_b: np.ndarray,
    step_t: np.ndarray,
    shareable: bool,
) -> Iterator[tuple[IterationState, IterationState]]:
    nb = plan_b.nb
    diff, g = nb.geometry(P)
    f0 = nb.partial_cost(g)
    yield IterationState(0, P[:, 0].copy(), step_b.copy(), f0), IterationState(0, P[:, 0].copy(), step_t.copy(), f0)
    nu = np.full(nb.nl, 2.0)
    if not shareable or plan_b.consensus_rounds != 1:
        runs.split = plan_b.loop(P, step_b, nu, 1), plan_t.loop(P, step_t, nu.copy(), 1)
        return
    shared_t = replace(plan_t, nb=nb, mix=Mixing(nb, plan_t.mix.ex, plan_t.weights))  # one set of index maps
    ex_t = plan_t.mix.ex
    for k in range(1, plan_b.iterations + 1):
        diff, g, _, f0, grad = plan_b.linearize(P, k)
        test = ArmijoTest(nb, diff, -grad, f0, plan_b.line.gamma, plan_b.line.slope_factor)
        bls = plan_b.search(diff, g, grad, f0, plan_b.bls_start(), False, reuse=test)
        step_b = bls[0]
        step_t = plan_b.search(diff, g, grad, f0, step_t, True, known=bls, reuse=test)[0]
        U_b = P - step_b[:, None, None] * grad
        U_t = P - step_t[:, None, None] * grad
        if not _bits_equal(U_b, U_t):  # the searches disagreed: two runs from here on
            P_b, P_t = plan_b.mix.apply(U_b), shared_t.mix.apply(U_t)
            runs.split = plan_b.loop(P_b, step_b, nu, k + 1), shared_t.loop(P_t, step_t, nu.copy(), k + 1)
            yield plan_b.state(k, P_b, step_b, f0), shared_t.state(k, P_t, step_t, f0)
            return
        P = plan_b.mix.apply(U_b, echo=ex_t)
        st_b = plan_b.state(k, P, step_b, f0)
        yield (
            st_b,
            IterationState(k, st_b.own_m, step_t.copy(), f0, st_b.half_owner, st_b.half_sample, st_b.half_other_m),
        )
