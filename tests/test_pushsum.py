"""Running-sum push-sum (algorithms/consensus/pushsum.py): exact average under asynchrony and loss, the mass
invariant, and equality with ordinary synchronous push-sum."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from distnav.algorithms.consensus.pushsum import Clock, iterate_push_sum, mass_in_flight, push_sum
from distnav.errors import WeightsError
from distnav.exchange import FaultSchedule, make_exchange
from distnav.network import builders


def _network(n: int = 24, seed: int = 1):  # type: ignore[no-untyped-def]
    return builders.connected_random_geometric(n, mean_degree=5, rng=np.random.default_rng(seed))


@pytest.mark.parametrize("loss", [0.1, 0.3])
def test_exact_average_under_asynchrony_and_loss(loss: float) -> None:
    g = _network()
    x = np.random.default_rng(2).normal(3.0, 2.0, size=(g.n_nodes, 3))
    rates = np.random.default_rng(3).uniform(0.2, 1.0, g.n_nodes)
    ex = make_exchange(g, faults=FaultSchedule(drop_probability=loss, seed=4))
    res = push_sum(x, graph=g, ticks=20_000, clock=Clock(rates, seed=5), exchange=ex)
    assert res.status == "converged", res.message
    dropped = res.comm.messages_dropped / res.comm.messages
    assert abs(dropped - loss) < 0.03  # the losses really happened
    np.testing.assert_allclose(res.estimates, np.broadcast_to(np.mean(x, axis=0), x.shape), atol=1e-8)
    assert res.mass_error < 1e-12


def test_slow_node_ticks_less_and_the_answer_is_still_exact() -> None:
    g = _network(16, seed=7)
    x = np.arange(16.0) ** 2
    rates = np.full(16, 0.9)
    rates[5] = 0.3
    ex = make_exchange(g, faults=FaultSchedule(drop_probability=0.2, seed=1))
    res = push_sum(x, graph=g, ticks=20_000, clock=Clock(rates, seed=2), exchange=ex)
    assert res.status == "converged", res.message
    per_tick = res.ticks_per_node / res.iterations
    assert abs(per_tick[5] - 0.3) < 0.05 and np.all(np.abs(np.delete(per_tick, 5) - 0.9) < 0.05)
    np.testing.assert_allclose(res.estimates[:, 0], np.mean(x), rtol=1e-9)


def test_mass_is_conserved_at_every_tick_with_losses() -> None:
    g = _network(12, seed=3)
    x = np.random.default_rng(8).normal(size=g.n_nodes)
    ex = make_exchange(g, faults=FaultSchedule(drop_probability=0.3, seed=2))
    total = np.array([x.sum(), g.n_nodes])
    in_flight_seen = 0.0
    for state in iterate_push_sum(x, graph=g, ticks=300, clock=Clock(0.5, seed=1), exchange=ex):
        flight = mass_in_flight(state, ex)
        in_flight_seen = max(in_flight_seen, float(np.abs(flight).max()))
        np.testing.assert_allclose(
            state.mass.sum(axis=0) + flight, total, rtol=0, atol=1e-12 * (1 + float(np.abs(total).max()))
        )
        assert np.all(state.mass[:, -1] > 0)  # the weights z stay positive: the ratio is always defined
    assert in_flight_seen > 1e-3  # messages were lost, so the in-flight term was needed for the balance


def test_plain_push_sum_would_be_biased_by_the_same_losses() -> None:
    """Contrast (an independent naive implementation): pushing shares instead of running sums loses the mass of a
    lost message, and its ratio misses the average by far more than the running-sum result does."""
    g = _network(12, seed=3)
    x = np.random.default_rng(8).normal(size=g.n_nodes)
    faults = FaultSchedule(drop_probability=0.3, seed=2)
    y, z = x.copy(), np.ones(g.n_nodes)
    deg = g.degrees.astype(float)
    for k in range(2000):
        ok = faults.delivered(k, g.src, g.dst, np.arange(g.n_edges))
        sy, sz = y / (deg + 1), z / (deg + 1)
        y = sy + np.bincount(g.dst[ok], weights=sy[g.src[ok]], minlength=g.n_nodes)
        z = sz + np.bincount(g.dst[ok], weights=sz[g.src[ok]], minlength=g.n_nodes)
    naive_error = float(np.abs(y / z - x.mean()).max())
    res = push_sum(x, graph=g, ticks=2000, exchange=make_exchange(g, faults=faults))
    assert naive_error > 1e-4
    assert float(np.abs(res.estimates[:, 0] - x.mean()).max()) < 1e-9


def test_synchronous_lossless_equals_ordinary_push_sum() -> None:
    g = _network(15, seed=4)
    x = np.random.default_rng(9).normal(size=g.n_nodes)
    n = g.n_nodes
    a = np.zeros((n, n))  # column-stochastic: node i keeps 1/(D_i+1), gives 1/(D_i+1) to each neighbour
    for i in range(n):
        nb = g.neighbors(i, include_self=True)
        a[nb, i] = 1.0 / len(nb)
    y, z = x.copy(), np.ones(n)
    for state in iterate_push_sum(x, graph=g, ticks=600):
        if state.tick:
            y, z = a @ y, a @ z
        assert state.acted.all() or state.tick == 0
        np.testing.assert_allclose(state.mass[:, 0], y, rtol=1e-12, atol=1e-13)
        np.testing.assert_allclose(state.mass[:, 1], z, rtol=1e-12)
    assert np.abs(y / z - x.mean()).max() < 1e-6


def test_ticks_budget_reports_max_iterations() -> None:
    g = builders.path(10)
    res = push_sum(np.arange(10.0), graph=g, ticks=5, clock=Clock(0.5))
    assert res.status == "max_iterations" and not res.converged and res.iterations == 5


def test_payload_of_any_shape_and_user_order() -> None:
    g = _network(10, seed=5)
    x = np.random.default_rng(1).normal(size=(10, 2, 2))
    res = push_sum(
        x, graph=g, ticks=5000, clock=Clock(0.7), exchange=make_exchange(g, order=np.arange(10)[::-1].copy())
    )
    assert res.status == "converged", res.message
    np.testing.assert_allclose(res.estimates, np.broadcast_to(x.reshape(10, 4).mean(axis=0), (10, 4)), atol=1e-9)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"clock": Clock(np.r_[np.ones(3), 0.0, np.ones(4)])}, "node 3"),
        ({"clock": Clock(1.5)}, "node 0"),
        ({"values": np.r_[np.ones(6), np.nan, 1.0]}, r"nodes \[6\]"),
        ({"values": np.ones(7)}, "one row per node"),
        ({"ticks": -1}, "ticks"),
        ({"tol": 0.0}, "tol"),
    ],
)
def test_bad_input_is_named(kwargs: dict[str, object], match: str) -> None:
    args: dict[str, object] = {"values": np.arange(8.0), "graph": builders.ring(8), "ticks": 10, **kwargs}
    with pytest.raises(WeightsError, match=match):
        push_sum(**args)  # type: ignore[arg-type]


_MPI_SCRIPT = """
import sys
from pathlib import Path

import numpy as np
from distnav.algorithms.consensus.pushsum import Clock, push_sum
from distnav.exchange import FaultSchedule, make_exchange
from distnav.network import builders

g = builders.connected_random_geometric(12, mean_degree=4, rng=np.random.default_rng(6))
x = np.random.default_rng(7).normal(size=(12, 2))
ex = make_exchange(g, backend=sys.argv[1], faults=FaultSchedule(drop_probability=0.2, seed=8))
res = push_sum(x, graph=g, ticks=300, clock=Clock(np.linspace(0.3, 1.0, 12), seed=9), exchange=ex)
if ex.is_root:
    np.save(sys.argv[2], np.concatenate([res.estimates.ravel(), [res.iterations, res.comm.messages]]))
"""


@pytest.mark.mpi
def test_mpi_run_equals_the_inprocess_run(tmp_path: Path) -> None:
    """The same asynchronous run on 3 MPI ranks and in-process: bit for bit (who ticks and which messages drop are
    pure functions of seeds, so every block agrees without messages)."""
    import os
    import shutil
    import subprocess
    import sys

    pytest.importorskip("mpi4py")
    local = Path(sys.executable).parent / "mpiexec"
    exe = str(local) if local.exists() else shutil.which("mpiexec")
    assert exe is not None, "mpi4py is installed but no mpiexec was found"
    script = tmp_path / "run.py"
    script.write_text(_MPI_SCRIPT)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in sys.path if p)}
    for backend, cmd in (
        ("inprocess", [sys.executable, str(script)]),
        ("mpi", [exe, "-n", "3", sys.executable, "-m", "mpi4py", str(script)]),
    ):
        proc = subprocess.run(
            [*cmd, backend, str(tmp_path / f"{backend}.npy")],
            stdin=subprocess.DEVNULL,
            capture_output=True,
            text=True,
            timeout=240,
            env=env,
        )
        assert proc.returncode == 0, proc.stderr[-3000:]
    a, b = np.load(tmp_path / "inprocess.npy"), np.load(tmp_path / "mpi.npy")
    assert np.array_equal(a, b), np.abs(a - b).max()


def test_information_fusion_by_async_push_sum_equals_centralized_lsq() -> None:
    """The CKF's consensus step done by push-sum (docs/field_async.md): every node averages its information
    contribution (Hᵢᵀ Rᵢ⁻¹ Hᵢ, Hᵢᵀ Rᵢ⁻¹ yᵢ) asynchronously under 20 % loss and solves with the averages (n cancels):
    every node then holds the centralized least-squares solution (numpy lstsq as the reference)."""
    rng = np.random.default_rng(21)
    g = _network(16, seed=6)
    p = 3
    h = rng.normal(size=(16, 2, p))  # two observations per node
    sigma = rng.uniform(0.5, 2.0, size=(16, 2))
    y = h @ np.array([1.0, -2.0, 0.5]) + sigma * rng.normal(size=(16, 2))
    w = 1.0 / sigma**2
    info_m = np.einsum("nkp,nk,nkq->npq", h, w, h)
    info_v = np.einsum("nkp,nk,nk->np", h, w, y)
    payload = np.concatenate([info_v, info_m.reshape(16, -1)], axis=1)
    ex = make_exchange(g, faults=FaultSchedule(drop_probability=0.2, seed=3))
    res = push_sum(payload, graph=g, ticks=20_000, clock=Clock(rng.uniform(0.3, 1.0, 16), seed=4), exchange=ex)
    assert res.status == "converged", res.message
    x_nodes = np.array([np.linalg.solve(r[p:].reshape(p, p), r[:p]) for r in res.estimates])
    a = (h * np.sqrt(w)[..., None]).reshape(-1, p)
    x_ref = np.linalg.lstsq(a, (y * np.sqrt(w)).ravel(), rcond=None)[0]
    np.testing.assert_allclose(x_nodes, np.broadcast_to(x_ref, (16, p)), atol=1e-8)


@pytest.mark.parametrize("ticks", [2.5, "3", True, -1])
def test_iterator_names_a_bad_tick_count(ticks: object) -> None:
    """The generator checks ``ticks`` itself (it used to leave 2.5 to ``range``: a bare TypeError)."""
    states = iterate_push_sum(np.arange(4.0), graph=builders.ring(4), ticks=ticks)  # type: ignore[arg-type]
    with pytest.raises(WeightsError, match="ticks must be"):
        next(states)
