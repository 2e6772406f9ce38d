"""N-CSG-BLS and N-CSG-TBLS run side by side (distnav.algorithms.ranging.line_search_pair) give, bit for bit, the
results of the two separate runs: estimates, every trace row, status, message and message counts."""

from __future__ import annotations

import numpy as np
import pytest

from distnav.algorithms.ranging.csg import PAPER_MODE, StopRule, solve, solve_line_search_pair
from distnav.errors import ModelError
from distnav.exchange import make_exchange
from distnav.models.uwb.problems import generate_problem


def _same(a, b):
    assert a.solver == b.solver and a.status == b.status and a.message == b.message
    assert np.array_equal(np.asarray(a.estimates), np.asarray(b.estimates), equal_nan=True)
    assert a.trace.keys() == b.trace.keys()
    for key in a.trace.keys():
        assert np.array_equal(a.trace[key], b.trace[key], equal_nan=True), key
    assert a.comm.messages == b.comm.messages and a.comm.bytes == b.comm.bytes and a.comm.rounds == b.comm.rounds
    assert np.array_equal(a.comm.messages_received, b.comm.messages_received)


def _check(problem, iterations, **options):
    bls = solve(problem, "N-CSG-BLS", iterations=iterations, **options)
    tbls = solve(problem, "N-CSG-TBLS", iterations=iterations, **options)
    pb, pt = solve_line_search_pair(problem, iterations=iterations, **options)
    _same(bls, pb)
    _same(tbls, pt)
    return bls, tbls


@pytest.fixture(scope="module")
def grid():
    return generate_problem("GC", np.random.default_rng(5))


def test_pair_equals_the_separate_runs_on_a_paper_problem(grid):
    bls, tbls = _check(grid, 80, **PAPER_MODE)
    assert np.array_equal(bls.estimates, tbls.estimates)  # the shared path: the two runs are one


def test_pair_equals_the_separate_runs_when_the_searches_split():
    """γ = 1e-4 on a far-started 2-D ladder: TBLS stops below a gap BLS jumps over (tests/test_claims.py), so the
    pair must leave the shared path and still give both runs exactly."""
    ladder = generate_problem("LC", np.random.default_rng(2), n_anchors=20, dim=2, init_halfwidth_m=30.0)
    bls, tbls = _check(ladder, 30, gamma=1e-4, **PAPER_MODE)
    assert np.abs(bls.estimates - tbls.estimates).max() > 0.5


@pytest.mark.parametrize(
    "options",
    [
        {"beta": 0.3},  # not a power of two: no sharing, two independent runs
        {"armijo_slope": "gradient"},
        {"objective": "metres", "sigma_m": 0.15, "loss": "cauchy"},
        {"stop": None},  # with the QC of the final state
    ],
)
def test_pair_equals_the_separate_runs_with_other_options(grid, options):
    _check(grid, 40, **{"quality": False, **options})


def test_pair_runs_on_after_one_run_stopped():
    """A stopping rule ends the two (split) runs at different iterations: BLS first (the TBLS run goes on alone
    from the buffered states) and TBLS first."""
    ladder = generate_problem("LC", np.random.default_rng(2), n_anchors=20, dim=2, init_halfwidth_m=30.0)
    for ftol, bls_first in ((0.03, True), (0.01, False)):
        bls, tbls = _check(ladder, 300, gamma=1e-4, quality=False, stop=StopRule(ftol=ftol, xtol_m=100.0, patience=2))
        assert (bls.iterations < tbls.iterations) == bls_first and bls.iterations != tbls.iterations


def test_pair_validation(grid):
    ex = make_exchange(grid.graph)
    with pytest.raises(ModelError, match="exchange each"):
        solve_line_search_pair(grid, iterations=2, exchanges=(ex, ex))
    with pytest.raises(ModelError, match="line_search"):
        solve_line_search_pair(grid, iterations=2, line_search="BLS")
    with pytest.raises(ModelError):
        solve_line_search_pair(grid, iterations=2, beta=1.5)
