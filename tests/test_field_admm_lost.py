"""An ADMM node process killed mid-run (issue 26 item 4): the others agree on it, run ADMM again on their own data
and finish; every remaining node names the lost node and the step, and its answer is the centralized BLUE (paper 000
eq. (4), :func:`~distnav.algorithms.lsq.blue.blue`) of the remaining nodes' data to 1e-6. Separate node processes on
loopback, bounded in time, cleaned up by ``launch``."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("zmq")
pytest.importorskip("tomli_w")

from conftest import assert_lost_named_everywhere
from distnav.algorithms.lsq.blue import LinearProblem, blue  # noqa: E402
from distnav.commands.field import launch  # noqa: E402
from distnav.commands.field_processes import LoopbackOptions  # noqa: E402
from distnav.commands.field_scenarios import codebias_scenario, write_scenario  # noqa: E402
from distnav.network import builders  # noqa: E402
from distnav.network.graph import Graph  # noqa: E402


def _remaining_blue(problem: LinearProblem, rest: list[int]) -> np.ndarray:
    """The BLUE of the remaining nodes' blocks (built here from the full problem's arrays, not the nodes' files)."""
    A = [problem.A[i, : problem.rows[i]] for i in rest]
    y = [problem.y[i, : problem.rows[i]] for i in rest]
    R = [problem.R[i, : problem.rows[i], : problem.rows[i]] for i in rest]
    return blue(LinearProblem.from_blocks(A, y, R)).x


def _with_a_parameter_of_one_node(problem: LinearProblem, node: int) -> LinearProblem:
    """The problem with one more parameter, "G99", observed only by the first row of ``node`` (a satellite only it
    tracked): determined with every node, inestimable without that one."""
    A = np.concatenate([problem.A, np.zeros((*problem.A.shape[:2], 1))], axis=2)
    A[node, 0, -1] = 1.0
    assert problem.parameter_names is not None
    return LinearProblem(
        A=A, y=problem.y, R=problem.R, rows=problem.rows, parameter_names=(*problem.parameter_names, "G99")
    )


def test_admm_nodes_go_on_without_a_killed_node(tmp_path: Path) -> None:
    sc = codebias_scenario(10, seed=1, epochs=10)
    assert sc.problem is not None
    sc = type(sc)(sc.graph, sc.kind, sc.algorithm, problem=_with_a_parameter_of_one_node(sc.problem, 9))
    assert sc.problem is not None
    victim, rest = 9, list(range(9))
    keep = np.arange(10) != 9
    links = [(a, b) for a, b in np.asarray(sc.graph.links).reshape(-1, 2).tolist() if keep[a] and keep[b]]
    assert Graph.from_links(9, links).is_connected  # the rest stays one network
    net = write_scenario(tmp_path / "net", sc, LoopbackOptions(deadline_ms=2000, crash={victim: 30}))
    summary = launch(net, tmp_path / "run", timeout_s=300, quiet=True)
    nodes = assert_lost_named_everywhere(summary, victim, rest, after_step=30)
    assert all(r["status"] == "converged_without_lost_nodes" and r["remaining_nodes"] == rest for r in nodes)
    assert all(f"node {victim} (at step" in r["message"] for r in nodes)

    field = np.array([r["estimate"] for r in nodes], dtype=float)
    assert all(r["dropped_parameters"] == ["G99"] for r in nodes)  # seen only by the dead node: named, no number
    assert np.isnan(field[:, -1]).all() and np.isfinite(field[:, :-1]).all()
    p = sc.problem.n_params - 1
    without = LinearProblem(A=sc.problem.A[:, :, :p], y=sc.problem.y, R=sc.problem.R, rows=sc.problem.rows)
    ref = _remaining_blue(without, rest)
    assert np.abs(field[:, :-1] - ref).max() <= 1e-6  # issue 26: the centralized solution of the data that remained
    full = blue(sc.problem).x[:p]
    assert np.abs(full - ref).max() > 1e-4  # the dead node's data mattered: not the answer of all the data


def test_admm_stops_and_says_why_when_the_rest_is_disconnected(tmp_path: Path) -> None:
    """On a path 0 – … – 7 node 5 dies at step 30: the remaining nodes are two networks, so no node presents an
    answer; every remaining node stops and names the lost node and why."""
    sc = codebias_scenario(8, seed=1, epochs=10)
    sc = type(sc)(builders.path(8), sc.kind, sc.algorithm, problem=sc.problem)
    # 1 s deadlines (as the ADMM stall test's): on this path the agreement's window is 17 deadlines
    net = write_scenario(tmp_path / "net", sc, LoopbackOptions(deadline_ms=1000, crash={5: 30}))
    summary = launch(net, tmp_path / "run", timeout_s=300, quiet=True)
    assert summary["crashed_on_purpose"] == [5]
    assert summary["finished"] == [] and summary["failed"] == [], summary
    assert sorted(summary["stopped"]) == [0, 1, 2, 3, 4, 6, 7]
    for r in summary["nodes"].values():
        assert r["status"] == "stopped" and r["estimate"] is None
        assert "nodes [5]" in r["message"] and "may be split" in r["message"], r["message"]
        assert list(r["lost_nodes"]) == ["5"]  # the nodes beyond it are named as out of reach, not as lost
    assert "[6, 7]" in summary["nodes"]["4"]["message"] and "[0, 1, 2, 3, 4]" in summary["nodes"]["6"]["message"]


def test_admm_stops_naming_the_direction_the_remaining_data_leave_open(tmp_path: Path) -> None:
    """Two more parameters, G98 and G99: node 0 observes their sum, node 9 G98 alone. With node 9 dead, both are
    still observed but only as a sum: ADMM's rank check names the inestimable direction and every remaining node
    stops with it, no number."""
    sc = codebias_scenario(10, seed=1, epochs=10)
    problem = sc.problem
    assert problem is not None and problem.parameter_names is not None
    A = np.concatenate([problem.A, np.zeros((*problem.A.shape[:2], 2))], axis=2)
    A[0, 0, -2:] = 1.0
    A[9, 0, -2] = 1.0
    names = (*problem.parameter_names, "G98", "G99")
    extended = LinearProblem(A=A, y=problem.y, R=problem.R, rows=problem.rows, parameter_names=names)
    blue(extended)  # all the data determine every parameter
    sc = type(sc)(sc.graph, sc.kind, sc.algorithm, problem=extended)
    net = write_scenario(tmp_path / "net", sc, LoopbackOptions(deadline_ms=2000, crash={9: 30}))
    summary = launch(net, tmp_path / "run", timeout_s=300, quiet=True)
    assert summary["crashed_on_purpose"] == [9] and summary["finished"] == [], summary
    assert sorted(summary["stopped"]) == list(range(9)), summary
    for i in range(9):
        r = summary["nodes"][str(i)]
        assert r["status"] == "stopped" and r["estimate"] is None and list(r["lost_nodes"]) == ["9"]
        assert "do not determine" in r["message"] and "G98" in r["message"] and "G99" in r["message"], r["message"]
