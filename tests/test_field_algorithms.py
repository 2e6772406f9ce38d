"""ADMM (paper 000's code-bias network), the CKF (paper 003's generic network) and N-CLM (paper 002, a simulated
hall) as separate node processes, each holding only its own data file, against the same front door run in-process:
every node's numbers bit for bit."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("zmq")
pytest.importorskip("tomli_w")

from distnav.commands.field import launch  # noqa: E402
from distnav.commands.field_processes import LoopbackOptions  # noqa: E402
from distnav.commands.field_scenarios import ckf_scenario, codebias_scenario, hall_scenario, write_scenario  # noqa: E402
from distnav.errors import DataFileError  # noqa: E402
from distnav.exchange import make_exchange  # noqa: E402
from distnav.formats.field_data import read_node_arrays  # noqa: E402


def _launch(tmp_path: Path, scenario, timeout_s: float = 240) -> dict:  # type: ignore[no-untyped-def]
    net = write_scenario(tmp_path / "net", scenario, LoopbackOptions(deadline_ms=30000))
    summary = launch(net, tmp_path / "run", timeout_s=timeout_s, quiet=True)
    n = scenario.graph.n_nodes
    assert summary["finished"] == list(range(n)), summary["failed"]
    assert summary["refused"] == 0 and summary["lost_nodes"] == []
    return summary


def test_admm_codebias_nodes_equal_inprocess(tmp_path: Path) -> None:
    from distnav.algorithms.lsq.admm import admm
    from distnav.algorithms.lsq.blue import blue

    sc = codebias_scenario(8, seed=1, epochs=10)
    sc = type(sc)(sc.graph, sc.kind, {**sc.algorithm, "max_iterations": 60}, problem=sc.problem)
    assert sc.problem is not None
    summary = _launch(tmp_path, sc)
    ref = admm(
        sc.problem, sc.graph, W=0.5, max_iterations=60, tol=1e-10, record_nodes=False, exchange=make_exchange(sc.graph)
    )
    field = np.array([summary["nodes"][str(i)]["estimate"] for i in range(8)])
    assert np.array_equal(field, ref.estimates), np.abs(field - ref.estimates).max()
    node0 = summary["nodes"]["0"]
    assert node0["status"] == ref.status and node0["iterations"] == ref.iterations
    # and the run is the network's least-squares problem: 60 iterations bring it near the BLUE of all the data
    assert np.abs(field - blue(sc.problem).x).max() < 0.5


def _ckf_inprocess(sc) -> np.ndarray:  # type: ignore[no-untyped-def]
    """The reference: the CKF front door in-process, P3, k_n = 4, no variance recursion, no monitor."""
    from distnav.algorithms.kalman.ckf import iterate_ckf

    options = {"protocol": "P3", "rounds": 4, "variance": False, "monitor": False}
    states = list(iterate_ckf(sc.dynamics, sc.series, graph=sc.graph, exchange=make_exchange(sc.graph), **options))
    return np.asarray(states[-1].estimates)


def test_ckf_nodes_equal_inprocess(tmp_path: Path) -> None:
    sc = ckf_scenario(10, seed=2, epochs=12)
    assert sc.dynamics is not None and sc.series is not None
    summary = _launch(tmp_path, sc)
    ref = _ckf_inprocess(sc)
    field = np.array([summary["nodes"][str(i)]["estimate"] for i in range(10)], dtype=float)
    assert np.isfinite(ref).any()
    assert np.array_equal(field, ref, equal_nan=True), np.nanmax(np.abs(field - ref))


def test_gnss_ckf_on_the_nl_network_equals_inprocess(shared_data: Path, tmp_path: Path) -> None:
    """The CKF of ``distnav gnss ionosphere`` on the five Dutch stations (109 epochs, 18 states), one process per
    station holding only its own normals: every station's final estimate bitwise the in-process one."""
    from distnav.commands.field_scenarios import rinex_ckf_scenario

    nl = shared_data / "gnss" / "nl_2021001_short_network_snapshot"
    files = [nl / f for f in ("delf0010.21o", "eijs0010.21d", "wsra0010.21o", "zegv0010.21o", "rovn0010.21o")]
    sc = rinex_ckf_scenario(files, nl / "cbw10010.21n.gz")
    assert sc.dynamics is not None and sc.series is not None and sc.graph.n_nodes == 5
    summary = _launch(tmp_path, sc)
    ref = _ckf_inprocess(sc)
    field = np.array([summary["nodes"][str(i)]["estimate"] for i in range(5)], dtype=float)
    assert np.isfinite(ref).sum() >= 5 * 10  # most of the 18 states determined at the end of the session
    assert np.array_equal(field, ref, equal_nan=True), np.nanmax(np.abs(field - ref))


def test_uwb_nclm_hall_anchors_equal_inprocess(tmp_path: Path) -> None:
    from distnav.algorithms.ranging.csg import solve_nclm

    sc = hall_scenario(12, seed=4, iterations=40)
    assert sc.ranging is not None
    summary = _launch(tmp_path, sc)
    ref = solve_nclm(sc.ranging, iterations=40, exchange=make_exchange(sc.graph))
    field = np.array([summary["nodes"][str(i)]["estimate"] for i in range(12)])
    assert np.array_equal(field, ref.estimates), np.abs(field - ref.estimates).max()
    assert summary["nodes"]["3"]["status"] == ref.status
    # each file held only its anchor's links: the samples of anchor 3 are those with 3 at one end
    own = read_node_arrays(tmp_path / "net" / "data" / "node-3.npz", "uwb", 3, 12)["samples"]
    ends = (sc.ranging.meas_a == 3) | (sc.ranging.meas_b == 3)
    assert own.shape[0] == int(ends.sum()) < sc.ranging.n_meas


def test_a_node_file_of_another_node_is_refused(tmp_path: Path) -> None:
    sc = codebias_scenario(4, seed=3, epochs=4)
    write_scenario(tmp_path / "net", sc)
    f = tmp_path / "net" / "data" / "node-2.npz"
    assert read_node_arrays(f, "admm", 2, 4)["A"].shape[1] == sc.problem.n_params  # type: ignore[union-attr]
    with pytest.raises(DataFileError, match="file of node 2 of a 4-node network, not of node 1"):
        read_node_arrays(f, "admm", 1, 4)
    with pytest.raises(DataFileError, match="holds 'admm' data, the algorithm needs 'ckf'"):
        read_node_arrays(f, "ckf", 2, 4)
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"not a zip")
    with pytest.raises(DataFileError, match="not a node data file"):
        read_node_arrays(bad, "admm", 0, 4)


@pytest.mark.parametrize(
    ("table", "match"),
    [
        ({"name": "admm", "rho": 0}, "key 'rho' must be > 0"),
        ({"name": "admm", "rounds": 5}, "keys \\['rounds'\\] mean nothing to 'admm'"),
        ({"name": "ckf", "protocol": "XX"}, "key 'protocol' must be one of P1"),
        ({"name": "uwb", "solver": "LM"}, "key 'solver' must be one of"),
        ({"name": "uwb", "iterations": 0}, "key 'iterations' must be >= 1"),
    ],
)
def test_algorithm_settings_are_checked(table: dict, match: str) -> None:  # type: ignore[type-arg]
    from distnav.formats.field_config import parse_description

    raw = {"algorithm": table, "node": [{"id": 0, "address": "tcp://127.0.0.1:5000", "neighbours": []}]}
    with pytest.raises(DataFileError, match=match):
        parse_description(raw)


def test_algorithm_defaults_are_filled() -> None:
    from distnav.formats.field_config import parse_description

    raw = {"algorithm": {"name": "admm"}, "node": [{"id": 0, "address": "tcp://127.0.0.1:5000", "neighbours": []}]}
    algo = parse_description(raw).algorithm
    assert algo == {
        "name": "admm",
        "rho": 1.0,
        "max_iterations": 1000,
        "tol": 1e-10,
        "constraint_nodes": "min_cover",
        "messages": "pairs",
    }


def test_ckf_nodes_go_on_without_a_killed_node(tmp_path: Path) -> None:
    """A CKF node process exits at step 30 of 48: every other node learns of it at the end (a global check), they
    agree on who remains and run the CKF again on their own normals; every remaining node names the lost node and
    the step, and its estimate is bit for bit the in-process CKF of the remaining nodes' normals on their graph."""
    from distnav.algorithms.kalman.ckf import iterate_ckf
    from distnav.algorithms.kalman.measurements import NormalSeries
    from distnav.exchange.field.survivors import subnetwork

    sc = ckf_scenario(10, seed=2, epochs=12)
    assert sc.dynamics is not None and sc.series is not None
    victim, rest = 7, [i for i in range(10) if i != 7]
    alive = np.arange(10) != victim
    sub = subnetwork(sc.graph, alive)
    assert sub.is_connected
    net = write_scenario(tmp_path / "net", sc, LoopbackOptions(deadline_ms=2000, crash={victim: 30}))
    summary = launch(net, tmp_path / "run", timeout_s=300, quiet=True)
    assert summary["crashed_on_purpose"] == [victim], summary
    assert summary["finished"] == rest and summary["stopped"] == [] and summary["failed"] == [], summary
    nodes = [summary["nodes"][str(i)] for i in rest]
    assert all(list(r["lost_nodes"]) == [str(victim)] for r in nodes)
    assert len({r["lost_nodes"][str(victim)] for r in nodes}) == 1
    assert all(r["status"] == "completed_without_lost_nodes" for r in nodes)

    normals = [sc.series.normals(t) for t in range(sc.series.n_epochs)]
    series = NormalSeries(np.stack([n[0][alive] for n in normals]), np.stack([n[1][alive] for n in normals]))
    options = {"protocol": "P3", "rounds": 4, "variance": False, "monitor": False}
    ref = np.asarray(
        list(iterate_ckf(sc.dynamics, series, graph=sub, exchange=make_exchange(sub), **options))[-1].estimates
    )
    field = np.array([r["estimate"] for r in nodes], dtype=float)
    assert np.isfinite(ref).any()
    assert np.array_equal(field, ref, equal_nan=True), np.nanmax(np.abs(field - ref))
    full = _ckf_inprocess(sc)[rest]
    assert not np.allclose(full, ref, equal_nan=True)  # the dead node's normals mattered
