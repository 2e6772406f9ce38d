"""ADMM with ternary messages (issue 27 item 2): deltas with error feedback reach the BLUE for far fewer bytes."""

from __future__ import annotations

import numpy as np
import pytest

from distnav.algorithms.lsq.admm import admm
from distnav.algorithms.lsq.blue import LinearProblem, blue
from distnav.algorithms.lsq.delta_codec import DeltaCodec, payload_bytes
from distnav.errors import ModelError
from distnav.exchange import FaultSchedule, make_exchange
from distnav.network import builders


@pytest.mark.parametrize("bits", [2, 3, 8])
def test_codec_keeps_both_ends_equal_and_carries_the_rest_forward(bits: int) -> None:
    rng = np.random.default_rng(1)
    tx, rx = DeltaCodec(bits), DeltaCodec(bits)
    v = rng.normal(size=(5, 7))
    tx.start(v)
    rx.start(v)
    target = rng.normal(size=(5, 7))
    errors = []
    for _ in range(60):  # a constant target: error feedback drives the copy to it
        msg = tx.encode(target)
        assert msg.dtype == np.uint8 and msg.shape == (5, payload_bytes(7, bits))
        got = rx.decode(msg)
        assert np.array_equal(got, tx.reference)  # bit for bit the sender's copy
        errors.append(float(np.abs(got - target).max()))
    assert errors[-1] < 1e-12 * max(errors[0], 1.0) or errors[-1] == 0.0
    assert payload_bytes(12, 2) == 7 and payload_bytes(12, 8) == 16


def _problem(n: int, p: int, rng: np.random.Generator) -> LinearProblem:
    A = rng.normal(size=(n, 3, p))
    y = np.einsum("nmp,p->nm", A, rng.normal(size=p)) + 0.1 * rng.normal(size=(n, 3))
    return LinearProblem.from_blocks(list(A), list(y), [0.01 * np.eye(3)] * n)


def test_ternary_reaches_the_blue_for_far_fewer_bytes() -> None:
    rng = np.random.default_rng(3)
    g = builders.connected_random_geometric(30, mean_degree=5, rng=rng)
    problem = _problem(30, 12, rng)
    x_hat = blue(problem).x  # the centralized reference
    runs = {
        m: admm(problem, g, W=300.0, messages=m, max_iterations=800, tol=0.0, reference=x_hat, record_nodes=False)
        for m in ("pairs", "ternary")
    }
    for res in runs.values():
        assert np.abs(res.estimates - x_hat).max() <= 1e-6 * np.abs(x_hat).max()
    k = {m: r.iterations_to["1e-06"] for m, r in runs.items()}
    assert k["pairs"] is not None and k["ternary"] is not None
    to_tol = {
        m: int(np.asarray(r.comm.bytes_per_round)[: k[m] * (r.comm.rounds // r.iterations)].sum())
        for m, r in runs.items()
    }
    # 12 float64 (96 B) against 3 B of codes + a 4-byte scale: 13.7× per message; 411 iterations against 335
    assert to_tol["pairs"] >= 10 * to_tol["ternary"]
    assert runs["ternary"].comm.messages == runs["pairs"].comm.messages


def test_ternary_refuses_a_fault_schedule() -> None:
    rng = np.random.default_rng(4)
    g = builders.ring(6)
    ex = make_exchange(g, faults=FaultSchedule(drop_probability=0.1, seed=1))
    with pytest.raises(ModelError, match="ternary"):
        admm(_problem(6, 4, rng), g, messages="ternary", max_iterations=5, exchange=ex)
