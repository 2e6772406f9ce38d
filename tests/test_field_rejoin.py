"""A restarted ADMM or CKF node process rejoins (issue 26 item 4): a node killed mid-run is started again with the
same description (``field launch`` restarts it with ``--rejoin``); the others, which went on without it, invite it
back and every node runs again from the start with it. The answer is that of all the data: ADMM within 1e-6 of the
centralized BLUE, the CKF bit for bit the in-process CKF. Separate node processes on loopback, bounded in time,
cleaned up by ``launch``."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("zmq")
pytest.importorskip("tomli_w")

from distnav.algorithms.lsq.blue import blue  # noqa: E402
from distnav.commands.field import launch  # noqa: E402
from distnav.commands.field_processes import LoopbackOptions  # noqa: E402
from distnav.commands.field_scenarios import ckf_scenario, codebias_scenario, write_scenario  # noqa: E402
from distnav.exchange import make_exchange  # noqa: E402


def _restarting(net: Path, victim: int, step: int) -> None:
    """The description's crash entry of ``victim`` with a restart 0.5 s after it exits (``field launch`` restarts it
    with ``--rejoin``)."""
    text = net.read_text()
    entry = f"{{ node = {victim}, round = {step} }}"
    assert entry in text
    net.write_text(text.replace(entry, f"{{ node = {victim}, round = {step}, restart_after_s = 0.5 }}"))


def _check_rejoined(summary: dict, victim: int, n: int, status: str) -> list[dict]:  # type: ignore[type-arg]
    assert summary["rejoined"] == [victim], summary
    assert summary["finished"] == list(range(n)) and summary["failed"] == [] and summary["stopped"] == [], summary
    nodes = [summary["nodes"][str(i)] for i in range(n)]
    assert all(r["status"] == status for r in nodes), [r["status"] for r in nodes]
    starts = {r["rejoined_nodes"][str(victim)] for r in nodes}
    assert len(starts) == 1  # every node, the returned one too, ran again from the same step
    assert nodes[victim]["rejoined_at_step"] == starts.pop()
    assert all(r["lost_nodes"] == {} for r in nodes)
    return nodes


def test_a_restarted_admm_node_rejoins_and_the_answer_is_the_blue_of_all_the_data(tmp_path: Path) -> None:
    sc = codebias_scenario(10, seed=1, epochs=10)
    assert sc.problem is not None
    victim = 9
    net = write_scenario(tmp_path / "net", sc, LoopbackOptions(deadline_ms=2000, crash={victim: 30}))
    _restarting(net, victim, 30)
    summary = launch(net, tmp_path / "run", timeout_s=400, quiet=True)
    nodes = _check_rejoined(summary, victim, 10, "converged_with_rejoined_nodes")
    field = np.array([r["estimate"] for r in nodes], dtype=float)
    ref = blue(sc.problem).x
    assert np.abs(field - ref).max() <= 1e-6  # the centralized solution of all the data, the returned node's too
    rest = [i for i in range(10) if i != victim]
    A = [sc.problem.A[i, : sc.problem.rows[i]] for i in rest]
    y = [sc.problem.y[i, : sc.problem.rows[i]] for i in rest]
    R = [sc.problem.R[i, : sc.problem.rows[i], : sc.problem.rows[i]] for i in rest]
    without = blue(type(sc.problem).from_blocks(A, y, R)).x
    assert np.abs(without - ref).max() > 1e-4  # its data mattered: the answer without it would fail the check


def test_a_restarted_ckf_node_rejoins_and_equals_the_inprocess_ckf(tmp_path: Path) -> None:
    from distnav.algorithms.kalman.ckf import iterate_ckf

    sc = ckf_scenario(10, seed=2, epochs=12)
    assert sc.dynamics is not None and sc.series is not None
    victim = 7
    net = write_scenario(tmp_path / "net", sc, LoopbackOptions(deadline_ms=2000, crash={victim: 30}))
    _restarting(net, victim, 30)
    summary = launch(net, tmp_path / "run", timeout_s=400, quiet=True)
    nodes = _check_rejoined(summary, victim, 10, "completed_with_rejoined_nodes")
    options = {"protocol": "P3", "rounds": 4, "variance": False, "monitor": False}
    states = iterate_ckf(sc.dynamics, sc.series, graph=sc.graph, exchange=make_exchange(sc.graph), **options)
    ref = np.asarray(list(states)[-1].estimates)
    field = np.array([r["estimate"] for r in nodes], dtype=float)
    assert np.isfinite(ref).any()
    assert np.array_equal(field, ref, equal_nan=True), np.nanmax(np.abs(field - ref))


def test_a_restarted_uwb_anchor_rejoins_and_equals_the_inprocess_solve(tmp_path: Path) -> None:
    """N-CLM (metres objective) on a well-connected hall of 10 anchor processes; a free anchor is killed at step 30
    and restarted: every anchor ends bit for bit with N-CLM in-process on all the data, within 1 mm of LM on it."""
    from distnav.algorithms.ranging.csg import solve
    from distnav.commands.field_scenarios import hall_scenario

    sc = hall_scenario(10, seed=5, iterations=300, objective="metres", hall={"link_loss": 0.0, "range_limit_m": 40.0})
    p = sc.ranging
    assert p is not None
    victim = int(np.flatnonzero(p.free.any(axis=1))[-1])
    net = write_scenario(tmp_path / "net", sc, LoopbackOptions(deadline_ms=2000, crash={victim: 30}))
    _restarting(net, victim, 30)
    summary = launch(net, tmp_path / "run", timeout_s=400, quiet=True)
    nodes = _check_rejoined(summary, victim, 10, "converged_with_rejoined_nodes")
    field = np.array([r["estimate"] for r in nodes], dtype=float)
    inproc = solve(p, "N-CLM", iterations=300, objective="metres", exchange=make_exchange(p.graph))
    np.testing.assert_array_equal(field, inproc.estimates)
    lm = solve(p, "LM", iterations=500, objective="metres")
    assert np.abs(field - lm.estimates).max() <= 1e-3


def test_a_restarted_node_that_no_one_takes_back_stops_with_the_reason(tmp_path: Path) -> None:
    """An ADMM node started with ``--rejoin`` when the others are gone (they finished without it): no invitation
    within ``start_timeout_s``, so it writes its results file with ``status = "stopped"``, no estimate and the
    reason, and exits with the stopped code (3)."""
    import json

    from distnav.cli import main

    sc = codebias_scenario(3, seed=1, epochs=4)
    net = write_scenario(tmp_path / "net", sc, LoopbackOptions(deadline_ms=500))
    text = net.read_text()
    assert "start_timeout_s = 60" in text
    net.write_text(text.replace("start_timeout_s = 60", "start_timeout_s = 1"))
    out = tmp_path / "run"
    out.mkdir()
    code = main(["node", "--config", str(net), "--id", "0", "--out", str(out), "--rejoin"])
    assert code == 3
    r = json.loads((out / "node-0.json").read_text())
    assert r["status"] == "stopped" and r["estimate"] is None
    assert "did not take it back" in r["message"] and "no neighbour invited it back within 1" in r["message"]
