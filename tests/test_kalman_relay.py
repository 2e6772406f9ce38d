"""The CKF's relay transport (issue 27): the routing plan by hand, the bytes by hand, the records rebuilding the
normals, and the filter equal to the matrix transport's (the paper's consensus rounds) on the same data."""

from __future__ import annotations

import numpy as np
import pytest

from distnav.algorithms.kalman import DynamicModel, NormalSeries
from distnav.algorithms.kalman.ckf import ckf
from distnav.algorithms.kalman.relay import (
    COUNT_BYTES,
    MAX_RELAY_NODES,
    RECORD_BYTES,
    matrix_bytes,
    relay_bytes,
    relay_plan,
    relay_records,
)
from distnav.errors import ModelError
from distnav.exchange import FaultSchedule, make_exchange
from distnav.models.gnss.gfbias import BiasGeometryFreeSeries, BiasStateLayout
from distnav.network import Graph, builders


def _path(n: int) -> Graph:
    return Graph.from_links(n, [(i, i + 1) for i in range(n - 1)])


def _series(seed: int, n: int, T: int = 6, S: int = 7) -> BiasGeometryFreeSeries:
    rng = np.random.default_rng(seed)
    lay = BiasStateLayout(
        tuple(f"G{k:02d}" for k in range(S)), tuple(f"R{i}" for i in range(n)), n_ionospheres=1, reference="R0"
    )
    coef = rng.standard_normal((T, n, S, 3))
    sig = rng.uniform(0.2, 1.0, (T, n, S))
    tracked = rng.random((T, n, S)) > 0.35
    obs = rng.standard_normal((T, n, S))
    return BiasGeometryFreeSeries(lay, coef, sig, obs_m=obs, tracked=tracked, groups=np.zeros(n, np.int64))


def test_plan_on_a_path_by_hand() -> None:
    g = _path(4)
    plan = relay_plan(g, 2)
    e = g.edge_index
    assert plan.hops.tolist() == [[0, 1, 2, 3], [1, 0, 1, 2], [2, 1, 0, 1], [3, 2, 1, 0]]  # 3 = beyond 2 hops
    round1 = {(int(e(i, j)[0]), i) for i, j in [(0, 1), (1, 0), (1, 2), (2, 1), (2, 3), (3, 2)]}
    round2 = {(int(e(1, 2)[0]), 0), (int(e(2, 1)[0]), 3), (int(e(1, 0)[0]), 2), (int(e(2, 3)[0]), 1)}
    assert set(plan.carried[0]) == round1
    assert set(plan.carried[1]) == round2


def test_parent_is_the_lowest_neighbour_one_hop_nearer() -> None:
    # a square 0-1-3-2-0: node 3 hears of 0 from 1 (the lower of its two neighbours at one hop from 0), not 2
    g = Graph.from_links(4, [(0, 1), (0, 2), (1, 3), (2, 3)])
    plan = relay_plan(g, 2)
    into3 = [(e, o) for e, o in plan.carried[1] if int(g.dst[e]) == 3]
    assert into3 == [(int(g.edge_index(1, 3)[0]), 0)]


def test_records_and_bytes_by_hand() -> None:
    g = _path(3)
    ex = make_exchange(g)
    vals = np.array([[1.0, 2.0, 3.0], [4.0, 5.0, 6.0], [7.0, 8.0, 9.0]])
    wts = np.array([[1.0, 0.0, 2.0], [0.0, 0.0, 3.0], [1.0, 1.0, 1.0]])  # 2, 1 and 3 records
    known = relay_records(ex, relay_plan(g, 2), vals, wts)
    assert sorted(known[0]) == [0, 1, 2] and sorted(known[1]) == [0, 1, 2] and sorted(known[2]) == [0, 1, 2]
    for node in range(3):
        for origin in range(3):
            got_v, got_w = known[node][origin]
            np.testing.assert_array_equal(got_w, wts[origin])
            np.testing.assert_array_equal(got_v[wts[origin] > 0], vals[origin][wts[origin] > 0])
    m = [2, 1, 3]
    # round 1: 0→1 (m0), 1→0 (m1), 1→2 (m1), 2→1 (m2); round 2: 1→2 relays 0, 1→0 relays 2
    crossings = [m[0], m[1], m[1], m[2], m[0], m[2]]
    expected = sum(COUNT_BYTES + RECORD_BYTES * c for c in crossings)
    comm = ex.comm_totals()
    assert comm.bytes == expected
    assert comm.messages == 6
    assert comm.bytes_sent.tolist() == [
        COUNT_BYTES + RECORD_BYTES * m[0],
        4 * COUNT_BYTES + RECORD_BYTES * (2 * m[1] + m[0] + m[2]),  # four messages
        COUNT_BYTES + RECORD_BYTES * m[2],
    ]
    assert comm.bytes_received.sum() == expected


def test_records_rebuild_the_normals() -> None:
    ser = _series(3, 4)
    for t in range(ser.n_epochs):
        N, r = ser.normals(t)
        vals, wts = ser.records(t)
        for j in range(ser.n_nodes):
            Nj, rj = ser.normals_from_records(t, j, vals[j], wts[j])
            np.testing.assert_allclose(Nj, N[j], rtol=1e-13, atol=1e-13)
            np.testing.assert_allclose(rj, r[j], rtol=1e-13, atol=1e-13)
    # the values come from the record: a changed record changes r
    vals, wts = ser.records(0)
    k = int(np.flatnonzero(wts[1] > 0)[0])
    vals[1, k] += 1.0
    _, r_changed = ser.normals_from_records(0, 1, vals[1], wts[1])
    assert not np.allclose(r_changed, ser.normals(0)[1][1])


@pytest.mark.parametrize("kn", [1, 2, 4])
def test_relay_ckf_equals_matrix_ckf(kn: int) -> None:
    g = builders.connected_random_geometric(9, mean_degree=3, rng=np.random.default_rng(4))
    ser = _series(5, g.n_nodes)
    dyn = DynamicModel(ser.n_states, noise_cov=0.01 * np.eye(ser.n_states))
    runs = {
        mode: ckf(dyn, ser, graph=g, protocol="P3", rounds=kn, transport=mode, exchange=make_exchange(g))
        for mode in ("matrices", "relay")
    }
    mat, rel = runs["matrices"], runs["relay"]
    np.testing.assert_array_equal(rel.series.estimable, mat.series.estimable)
    est = mat.series.estimable
    np.testing.assert_allclose(rel.series.estimates[est], mat.series.estimates[est], rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(rel.series.std[est], mat.series.std[est], rtol=1e-9, atol=1e-12)
    # bytes: every record crosses one link into each node within kn hops of its origin, plus a count per origin
    plan = relay_plan(g, kn)
    per_epoch = [(ser.records(t)[1] > 0).sum(axis=1) for t in range(ser.n_epochs)]
    expected = sum(
        COUNT_BYTES + RECORD_BYTES * int(m[o]) for m in per_epoch for pairs in plan.carried for _, o in pairs
    )
    assert rel.comm.bytes == expected
    assert rel.comm.bytes < mat.comm.bytes


def test_relay_refusals() -> None:
    g = _path(4)
    ser = _series(6, 4)
    dyn = DynamicModel(ser.n_states, noise_cov=0.01 * np.eye(ser.n_states))
    faulty = make_exchange(g, faults=FaultSchedule(drop_probability=0.1, seed=1))
    with pytest.raises(ModelError, match="fault"):
        ckf(dyn, ser, graph=g, rounds=2, transport="relay", exchange=faulty)
    with pytest.raises(ModelError, match="transport must be"):
        ckf(dyn, ser, graph=g, rounds=2, transport="pigeons")  # type: ignore[arg-type]
    normals = NormalSeries(*(np.stack(a) for a in zip(*(ser.normals(t) for t in range(ser.n_epochs)), strict=True)))
    with pytest.raises(ModelError, match="no observation records"):
        ckf(dyn, normals, graph=g, rounds=2, transport="relay")


def test_byte_estimates_equal_what_the_transports_send() -> None:
    g = builders.connected_random_geometric(7, mean_degree=3, rng=np.random.default_rng(9))
    ser = _series(10, g.n_nodes, T=4)
    dyn = DynamicModel(ser.n_states, noise_cov=0.01 * np.eye(ser.n_states))
    records = np.stack([(ser.records(t)[1] > 0).sum(axis=1) for t in range(ser.n_epochs)])
    for mode, predicted in (
        ("relay", relay_bytes(relay_plan(g, 3), records)),
        ("matrices", matrix_bytes(g, 3, ser.n_states, ser.n_epochs)),
    ):
        res = ckf(dyn, ser, graph=g, rounds=3, transport=mode, variance=False, monitor=False)  # type: ignore[arg-type]
        assert res.comm.bytes == predicted, mode


def test_relay_on_field_nodes_equals_inprocess() -> None:
    """The MPI case on the field exchange (12 node threads over ZeroMQ): estimates and bytes bit for bit."""
    pytest.importorskip("zmq")
    import sys
    from pathlib import Path

    here = Path(__file__).resolve().parent
    sys.path.insert(0, str(here / "mpi"))
    sys.path.insert(0, str(here))
    from cases import CASES

    from test_field_cases import run_on_threads

    case = CASES["ckf_relay_transport"]
    ref = case("inprocess")
    results = run_on_threads(case, 12, timeout_s=400)
    errors = [r for r in results if isinstance(r, BaseException)]
    assert not errors, repr(errors[0])
    for got in results:
        assert np.array_equal(got["estimates"], ref["estimates"], equal_nan=True)
        assert np.array_equal(got["bytes"], ref["bytes"])
        np.testing.assert_allclose(got["std"], ref["std"], rtol=1e-12, atol=1e-13)


def test_relay_plan_refuses_networks_beyond_its_limit() -> None:
    with pytest.raises(ModelError, match="transport='matrices'"):
        relay_plan(_path(MAX_RELAY_NODES + 1), 1)


@pytest.mark.parametrize("kind", ["exact", "bound"])
def test_relay_with_local_precision_and_innovation_tests_equals_matrices(kind: str) -> None:
    g = builders.connected_random_geometric(8, mean_degree=3, rng=np.random.default_rng(11))
    rng = np.random.default_rng(12)
    T, n, S = 7, g.n_nodes, 8
    lay = BiasStateLayout(tuple(f"G{k:02d}" for k in range(S)), tuple(f"R{i}" for i in range(n)), reference="R0")
    coef = rng.standard_normal((T, n, S, 3))
    sig = rng.uniform(0.2, 0.4, (T, n, S))
    tracked = rng.random((T, n, S)) > 0.2
    obs = 0.3 * rng.standard_normal((T, n, S))
    obs[5, 3, np.flatnonzero(tracked[5, 3])[1]] += 40.0  # a gross error node 3 must reject at epoch 5
    ser = BiasGeometryFreeSeries(lay, coef, sig, obs_m=obs, tracked=tracked, groups=np.zeros(n, np.int64))
    dyn = DynamicModel(ser.n_states, noise_cov=0.01 * np.eye(ser.n_states))
    runs = {
        mode: ckf(dyn, ser, graph=g, rounds=3, transport=mode, local_precision=kind, test_level=0.001)  # type: ignore[arg-type]
        for mode in ("matrices", "relay")
    }
    mat, rel = runs["matrices"], runs["relay"]
    assert mat.tests is not None and rel.tests is not None
    assert mat.tests.n_removed > 0  # the outlier was found
    assert rel.tests.removed == mat.tests.removed
    np.testing.assert_array_equal(rel.tests.epoch, mat.tests.epoch)
    est = mat.series.estimable
    np.testing.assert_array_equal(rel.series.estimable, est)
    np.testing.assert_allclose(rel.series.estimates[est], mat.series.estimates[est], rtol=1e-9, atol=1e-9)
    assert mat.local_std is not None and rel.local_std is not None
    np.testing.assert_allclose(rel.local_std[est], mat.local_std[est], rtol=1e-9, atol=1e-12)
    assert rel.precision is not None and rel.precision.comm is not None
    assert rel.precision.comm.bytes == 0  # static rows of L and records sent anyway: nothing extra
    assert rel.comm.bytes < mat.comm.bytes
