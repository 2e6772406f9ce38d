"""The shared result types: a fixed status set, usability, the deprecated extras view."""

from __future__ import annotations

import numpy as np
import pytest

from distnav.algorithms.consensus.averaging import ConsensusResult, average_consensus
from distnav.algorithms.result import SOLVER_STATUSES, Precision, SolverResult, Trace, TraceBuilder, stopping_fields
from distnav.exchange.core import CommTotals
from distnav.network import builders


def test_unknown_status_is_refused_and_usable_follows_status() -> None:
    res = average_consensus(np.arange(5.0), graph=builders.ring(5), rounds=3)
    assert isinstance(res, ConsensusResult) and res.usable
    kw = {
        "estimates": res.estimates,
        "converged": False,
        "iterations": 1,
        "message": "",
        "trace": Trace(),
        "comm": res.comm,
    }
    with pytest.raises(ValueError, match="unknown solver status"):
        SolverResult(status="done", **kw)  # type: ignore[arg-type]
    assert {"converged", "max_iterations", "stopped", "diverged", "ambiguous", "weakly_determined"} == set(
        SOLVER_STATUSES
    )
    assert not SolverResult(status="diverged", **kw).usable
    assert not SolverResult(status="ambiguous", **kw).usable


def test_extras_is_a_deprecated_view_of_the_typed_fields() -> None:
    res = average_consensus(np.arange(5.0), graph=builders.ring(5), rounds=3)
    with pytest.warns(DeprecationWarning):
        assert res.extras["average"] is res.average


def test_precision_std_scales_with_the_variance_factor() -> None:
    cov = np.array([[[4.0, 0.0], [0.0, 9.0]]])
    p = Precision(covariance=cov, variance_factor=4.0, redundancy=3, kind="centralized")
    np.testing.assert_allclose(p.std(), [[2.0, 3.0]])
    np.testing.assert_allclose(p.std(a_posteriori=True), [[4.0, 6.0]])


def test_gathered_precision_holds_every_block_and_only_the_messages_since_the_snapshot() -> None:
    from distnav.exchange import make_exchange

    ex = make_exchange(builders.ring(4))
    ex.broadcast(np.zeros((4, 1)))  # before the snapshot: not the precision's cost
    before = ex.comm_totals().snapshot()
    ex.broadcast(np.zeros((4, 1)))  # one round on a 4-ring: every node to both neighbours, 8 messages
    blocks = np.arange(4.0).reshape(4, 1, 1)
    p = Precision.gathered(ex, blocks, before, variance_factor=2.0, redundancy=3.0, kind="exact", iterations=1)
    assert p.covariance.tolist() == [[[0.0]], [[1.0]], [[2.0]], [[3.0]]]
    assert (p.variance_factor, p.redundancy, p.kind, p.iterations) == (2.0, 3.0, "exact", 1)
    assert p.comm is not None and (p.comm.rounds, p.comm.messages) == (1, 8)
    assert ex.comm_totals().messages == 16


def test_stopping_fields_name_the_status_by_the_tolerance():
    """A run that met its tolerance ends ``converged``, else ``max_iterations``; the trace is built, the rest kept."""
    tb = TraceBuilder()
    tb.add(step=1.0)
    tb.add(step=0.5)
    comm = CommTotals.empty(3)
    met = SolverResult(estimates=np.zeros((3, 1)), **stopping_fields(True, 2, "two steps", tb, comm))
    not_met = SolverResult(estimates=np.zeros((3, 1)), **stopping_fields(False, 2, "two steps", tb, comm))
    assert (met.status, met.converged, met.iterations, met.message) == ("converged", True, 2, "two steps")
    assert (not_met.status, not_met.converged) == ("max_iterations", False)
    assert met.trace["step"].tolist() == [1.0, 0.5] and met.comm is comm
