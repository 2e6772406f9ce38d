"""Node programs started the way a tester starts them (docs/field.md, "What a node does when ..."): in a random
order with delays, on a port another process holds, with another network's description or a data file that lost
values. Each test starts its own `distnav node` processes on loopback, bounds them in time and kills their process
groups in a `finally`, also when an assertion fails."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

pytest.importorskip("zmq")

import zmq  # noqa: E402

from distnav.algorithms.consensus.averaging import iterate_average_consensus  # noqa: E402
from distnav.commands.field_processes import LoopbackOptions, write_loopback_network  # noqa: E402
from distnav.exchange.field import Kind, Peer, Transport, TransportOptions, encode  # noqa: E402
from distnav.exchange.field.startup import StartCheck, announce, eccentricity, handshake, rejoin  # noqa: E402
from distnav.network.graph import Graph  # noqa: E402

N = 6
#: a ring in which every node also links to the node two along: any one node can go and the others stay connected
LINKS = sorted({(min(i, j), max(i, j)) for i in range(N) for j in ((i + 1) % N, (i + 2) % N)})


def _start(net: Path, node: int, out: Path, *extra: str) -> subprocess.Popen[bytes]:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in sys.path if p)}
    cmd = [sys.executable, "-m", "distnav", "node", "--config", str(net), "--id", str(node), "--out", str(out), *extra]
    err = open(out / f"stderr-{node}-{time.monotonic_ns()}.txt", "wb")  # noqa: SIM115 - closed after the run
    return subprocess.Popen(cmd, env=env, stdout=err, stderr=err, start_new_session=True)


def _finish(procs: dict[int, subprocess.Popen[bytes]], timeout_s: float) -> dict[int, int | None]:
    """Wait for every process at most ``timeout_s`` in all; the exit codes (None: killed at the timeout)."""
    end = time.monotonic() + timeout_s
    codes: dict[int, int | None] = {}
    for k, p in procs.items():
        try:
            codes[k] = p.wait(timeout=max(0.1, end - time.monotonic()))
        except subprocess.TimeoutExpired:
            codes[k] = None
    return codes


def _kill_all(procs: dict[int, subprocess.Popen[bytes]]) -> None:
    for p in procs.values():
        if p.poll() is None:
            try:
                os.killpg(p.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            p.wait(timeout=10)


def _run_alone(net: Path, node: int, out: Path) -> tuple[int | None, str]:
    """One node process, bounded (60 s): its exit code and what it printed."""
    procs = {node: _start(net, node, out)}
    try:
        codes = _finish(procs, 60)
    finally:
        _kill_all(procs)
    return codes[node], _stderr(out)


def _stderr(out: Path) -> str:
    return "\n".join(f.read_text(errors="replace") for f in sorted(out.glob("stderr-*.txt")))


def _network(tmp_path: Path, values: np.ndarray, opts: LoopbackOptions) -> tuple[Path, Path]:
    """The loopback description of LINKS with ``values`` and its (made) output folder."""
    net = write_loopback_network(tmp_path / "net", LINKS, values, opts)
    out = tmp_path / "run"
    out.mkdir()
    return net, out


def _wait_until_started(out: Path, n_nodes: int, timeout_s: float) -> None:
    """Until ``n_nodes`` node programs have said they started (their "started after" line), at most ``timeout_s``."""
    end = time.monotonic() + timeout_s
    while _stderr(out).count("started after") < n_nodes:
        assert time.monotonic() < end, f"the nodes did not start within {timeout_s} s:\n{_stderr(out)}"
        time.sleep(0.2)


def test_nodes_started_in_a_random_order_with_delays_run_bitwise_the_inprocess_rounds(tmp_path: Path) -> None:
    """Before the start-up barrier a node whose neighbours had all answered went into its rounds while a neighbour
    still waited for a node not yet started: its first steps passed without messages and plain consensus ended,
    every node "completed" and nothing refused but "late", far from the mean. Now the nodes enter step 0 together."""
    values = np.random.default_rng(3).normal(size=(N, 3))
    algo = {"name": "consensus", "rounds": 40, "protocol": "MH", "patience": 20}
    opts = LoopbackOptions(algorithm=algo, deadline_ms=2000, start_timeout_s=30)
    net = write_loopback_network(tmp_path / "net", LINKS, values, opts)
    out = tmp_path / "run"
    out.mkdir()
    procs: dict[int, subprocess.Popen[bytes]] = {}
    try:  # node 2 comes 6 s after the others: node 5, not its neighbour, has heard all of its own neighbours by then
        for node, pause_s in ((3, 0.3), (0, 0.3), (5, 0.3), (1, 0.3), (4, 6.0), (2, 0.0)):
            procs[node] = _start(net, node, out)
            time.sleep(pause_s)
        codes = _finish(procs, 120)
    finally:
        _kill_all(procs)
    assert all(c == 0 for c in codes.values()), (codes, _stderr(out)[-3000:])
    res = [json.loads((out / f"node-{i}.json").read_text()) for i in range(N)]
    field = np.array([r["estimate"] for r in res])
    ref = list(iterate_average_consensus(values, graph=Graph.from_links(N, LINKS), protocol="MH", rounds=40))[-1]
    assert np.array_equal(field, ref.values), np.abs(field - ref.values).max()
    assert all(r["status"] == "completed" and not r["refused"] and not r["lost_nodes"] for r in res)


def test_a_port_in_use_is_a_clear_error_with_exit_code_2(tmp_path: Path) -> None:
    values = np.zeros((N, 1))
    net = write_loopback_network(tmp_path / "net", LINKS, values, LoopbackOptions(start_timeout_s=5))
    address = [ln for ln in net.read_text().splitlines() if ln.startswith("address")][2].split('"')[1]
    port = int(address.rsplit(":", 1)[1])
    out = tmp_path / "run"
    out.mkdir()
    with socket.socket() as holder:
        holder.bind(("127.0.0.1", port))
        holder.listen()
        code, err = _run_alone(net, 2, out)
    assert code == 2, err
    assert f"error: node 2: cannot listen on its address {address} (Address already in use)" in err, err
    assert "Traceback" not in err and not (out / "node-2.json").exists()


def test_a_node_that_hears_no_neighbour_exits_2_and_writes_no_result(tmp_path: Path) -> None:
    """Before, a node started alone (its neighbours not started, or finished long ago: a second start of a node)
    ran every round on its own data and wrote ``completed_with_lost_neighbours`` with exit code 0 over the file of
    the first start."""
    net = write_loopback_network(tmp_path / "net", LINKS, np.ones((N, 2)), LoopbackOptions(start_timeout_s=2))
    out = tmp_path / "run"
    out.mkdir()
    code, err = _run_alone(net, 0, out)
    assert code == 2, err
    assert "error: node 0: none of its neighbours [1, 2, 4, 5] answered within 2 s" in err, err
    assert not (out / "node-0.json").exists()


def test_a_node_of_another_network_or_with_a_cut_data_file_is_refused_at_start(tmp_path: Path) -> None:
    """Node 3 started with another network's description (same ports and links, another name) and, in a second
    network, node 3's data file cut (2 values where the others have 3). Before, both were taken for node 3 (its
    data in the others' answer, or every round refused while it never counted as missing), every node "completed".
    Now node 3 exits with code 2 naming the reason, and the others run without it: flow consensus gives the exact
    mean of their data."""
    values = np.random.default_rng(5).normal(size=(N, 3))
    algo = {"name": "consensus_flows", "rounds": 150, "protocol": "MH", "patience": 5}
    opts = LoopbackOptions(algorithm=algo, deadline_ms=1000, start_timeout_s=20)
    net = write_loopback_network(tmp_path / "net", LINKS, values, opts)
    other = tmp_path / "other" / "network.toml"
    other.parent.mkdir()
    other.write_text(net.read_text().replace('name = "network"', 'name = "other"').replace("data/", "../net/data/"))
    cut = tmp_path / "cut" / "network.toml"
    (cut.parent / "data").mkdir(parents=True)
    for i in range(N):
        v = values[i, :2] if i == 3 else values[i]
        (cut.parent / "data" / f"node-{i}.txt").write_text(" ".join(repr(float(x)) for x in v) + "\n")
    cut.write_text(net.read_text())
    for name, odd, why in (
        ("other", other, "it runs another network description"),
        ("cut", cut, "its messages carry 3 values, this node's 2"),
    ):
        main_net = net if name == "other" else cut
        out = tmp_path / f"run-{name}"
        out.mkdir()
        procs: dict[int, subprocess.Popen[bytes]] = {}
        try:
            for i in range(N):
                procs[i] = _start(odd if i == 3 else main_net, i, out)
            codes = _finish(procs, 150)
        finally:
            _kill_all(procs)
        err = _stderr(out)
        assert codes == {i: 2 if i == 3 else 0 for i in range(N)}, (name, codes, err[-3000:])
        assert f"error: node 3: refused by the start-up check: neighbours [1, 2, 4, 5]: {why}" in err, err
        res = {i: json.loads((out / f"node-{i}.json").read_text()) for i in range(N) if i != 3}
        for i in (1, 2, 4, 5):
            assert res[i]["lost_nodes"] == {"3": 0} and "3" in res[i]["refused_at_start"], res[i]
        keep = [i for i in range(N) if i != 3]
        field = np.array([res[i]["estimate"] for i in keep])
        assert np.abs(field - values[keep].mean(axis=0)).max() <= 1e-6, (name, field, values[keep].mean(axis=0))


def test_an_admm_node_stopped_past_the_deadlines_then_resumed_leaves_the_blue_of_all_the_data(tmp_path: Path) -> None:
    """SIGSTOP of one of 6 ADMM node processes mid-run for 6 s (deadline 1 s), then SIGCONT: a global operation
    fails at every node with every node alive. Before, every node stopped without an answer (exit code 3); now they
    agree that every node is alive, run ADMM again with every node and end within 1e-6 of the centralized BLUE."""
    from distnav.algorithms.lsq.blue import blue
    from distnav.commands.field_scenarios import codebias_scenario, write_scenario

    sc = codebias_scenario(6, seed=2, epochs=8)
    assert sc.problem is not None
    net = write_scenario(tmp_path / "net", sc, LoopbackOptions(deadline_ms=1000, start_timeout_s=60))
    text = net.read_text()
    assert "max_iterations = " in text
    net.write_text(text.replace("tol = 1e-10", "tol = 1e-12"))
    out = tmp_path / "run"
    out.mkdir()
    victim = 4
    procs: dict[int, subprocess.Popen[bytes]] = {}
    try:
        procs = {i: _start(net, i, out) for i in range(6)}
        log = out / f"node-{victim}.log"
        end = time.monotonic() + 120
        while time.monotonic() < end and not (log.exists() and "started after" in log.read_text()):
            time.sleep(0.05)
        time.sleep(1.0)  # into its rounds
        assert procs[victim].poll() is None, _stderr(out)
        os.kill(procs[victim].pid, signal.SIGSTOP)
        time.sleep(6.0)
        os.kill(procs[victim].pid, signal.SIGCONT)
        codes = _finish(procs, 300)
    finally:
        _kill_all(procs)
    assert all(c == 0 for c in codes.values()), (codes, _stderr(out)[-3000:])
    res = [json.loads((out / f"node-{i}.json").read_text()) for i in range(6)]
    assert all(r["status"].endswith("_run_again") and r["stalled_at_steps"] for r in res), [r["message"] for r in res]
    assert len({tuple(r["stalled_at_steps"]) for r in res}) == 1 and all(r["lost_nodes"] == {} for r in res)
    field = np.array([r["estimate"] for r in res], dtype=float)
    assert np.abs(field - blue(sc.problem).x).max() <= 1e-6


def _processes_with(text: str) -> list[int]:
    """The ids of the processes whose command line holds ``text`` (a test's own unique path)."""
    pids = []
    for d in Path("/proc").iterdir():
        try:
            if d.name.isdigit() and text in (d / "cmdline").read_bytes().decode(errors="replace"):
                pids.append(int(d.name))
        except OSError:
            continue
    return pids


@pytest.mark.skipif(not Path("/proc").is_dir(), reason="finds the node processes through /proc")
def test_a_terminated_launcher_leaves_no_node_process_behind(tmp_path: Path) -> None:
    """SIGTERM to `distnav field launch` (a `kill`, a batch system's stop): before, the launcher died at once and its
    node processes, each in its own session, ran on; now it kills them, says so and exits 130."""
    algo = {"name": "consensus", "rounds": 10**7, "protocol": "MH", "patience": 20}
    net = write_loopback_network(tmp_path / "net", LINKS, np.ones((N, 1)), LoopbackOptions(algorithm=algo))
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in sys.path if p)}
    cmd = [sys.executable, "-m", "distnav", "field", "launch", "--config", str(net), "--out", str(tmp_path / "run")]
    launcher = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        end = time.monotonic() + 120
        logs = [tmp_path / "run" / f"node-{i}.log" for i in range(N)]
        while time.monotonic() < end and not all(f.exists() and "started after" in f.read_text() for f in logs):
            time.sleep(0.1)
        assert len(_processes_with(str(net))) == N + 1  # the launcher and its nodes, in their rounds
        launcher.send_signal(signal.SIGTERM)
        _, err = launcher.communicate(timeout=60)
        time.sleep(0.5)
        left = _processes_with(str(net))
    finally:
        if launcher.poll() is None:
            launcher.kill()
            launcher.wait()
        for pid in _processes_with(str(net)):
            os.kill(pid, signal.SIGKILL)
    assert launcher.returncode == 130 and b"interrupted: every node process stopped" in err, err
    assert left == []


def test_a_node_started_after_the_others_began_exits_2_naming_rejoin(tmp_path: Path) -> None:
    """Node 3 started 2 s after the others had begun their rounds (their start timeout 2 s): before, it ran from step
    0 while its neighbours were hundreds of steps ahead; now it exits 2 and says to start it with --rejoin."""
    algo = {"name": "consensus_flows", "rounds": 10**6, "protocol": "MH", "patience": 5}
    opts = LoopbackOptions(algorithm=algo, deadline_ms=1000, start_timeout_s=2)
    net = write_loopback_network(tmp_path / "net", LINKS, np.ones((N, 1)), opts)
    out = tmp_path / "run"
    out.mkdir()
    procs: dict[int, subprocess.Popen[bytes]] = {}
    try:
        procs = {i: _start(net, i, out) for i in range(N) if i != 3}
        _wait_until_started(out, N - 1, 120.0)  # their imports may take seconds on a loaded machine
        time.sleep(2.0)  # and into their rounds
        late = _start(net, 3, out)
        procs[3] = late
        code = _finish({3: late}, 60)[3]
        assert all(p.poll() is None for k, p in procs.items() if k != 3)  # the others still in their rounds
    finally:
        _kill_all(procs)
    err = _stderr(out)
    assert code == 2, err
    assert "error: node 3: its neighbours are already at step" in err and "start it with --rejoin" in err, err
    assert not (out / "node-3.json").exists()


def test_a_consensus_node_stopped_past_the_deadlines_learns_that_its_neighbours_dropped_it(tmp_path: Path) -> None:
    """SIGSTOP of node 3 (flow consensus) mid-run for longer than the rest of the run, then SIGCONT: its neighbours
    declare it lost and end with the exact mean of their own data while it is stopped. Before, node 3 then ran on
    their queued messages and ended ``completed``, nothing said (its data in no one's answer); now their byes tell
    it (``dropped_by``, ``..._dropped_by_neighbours``). (Resumed while they still run, it is readmitted and every
    node ends with the mean of all the data: the flows' design.)"""
    values = np.random.default_rng(8).normal(size=(N, 2))
    algo = {"name": "consensus_flows", "rounds": 2000, "protocol": "MH", "patience": 5}
    net = write_loopback_network(tmp_path / "net", LINKS, values, LoopbackOptions(algorithm=algo, deadline_ms=500))
    out = tmp_path / "run"
    out.mkdir()
    procs: dict[int, subprocess.Popen[bytes]] = {}
    try:
        procs = {i: _start(net, i, out) for i in range(N)}
        log = out / "node-3.log"
        end = time.monotonic() + 120
        while time.monotonic() < end and not (log.exists() and "started after" in log.read_text()):
            time.sleep(0.05)
        time.sleep(0.5)
        assert procs[3].poll() is None, _stderr(out)
        os.kill(procs[3].pid, signal.SIGSTOP)
        others = {i: p for i, p in procs.items() if i != 3}
        _finish(others, 120)  # they finish without it
        os.kill(procs[3].pid, signal.SIGCONT)
        codes = _finish(procs, 240)
    finally:
        _kill_all(procs)
    assert all(c == 0 for c in codes.values()), (codes, _stderr(out)[-3000:])
    res = {i: json.loads((out / f"node-{i}.json").read_text()) for i in range(N)}
    keep = [i for i in range(N) if i != 3]
    assert all("3" in res[i]["lost_nodes"] for i in (1, 2, 4, 5)), {i: res[i]["lost_nodes"] for i in keep}
    field = np.array([res[i]["estimate"] for i in keep])
    assert np.abs(field - values[keep].mean(axis=0)).max() <= 1e-6
    assert res[3]["status"].endswith("_dropped_by_neighbours"), res[3]["status"]
    assert sorted(res[3]["dropped_by"]) == ["1", "2", "4", "5"], res[3]["dropped_by"]
    assert all(not res[i]["dropped_by"] for i in keep)


def test_a_node_killed_during_the_start_up_and_restarted_with_rejoin_starts_with_the_others(tmp_path: Path) -> None:
    """Node 3 killed while the network is still starting (node 0 not started yet), then restarted with --rejoin.
    Before, its one-byte hello was ignored by the start-up barrier: it exited 2 ("no neighbour answered") and the
    others waited 2 x start_timeout_s and ended without its data. Now its neighbours answer it with their start-up
    hello, it starts as the others do (from step 0, ``restarted_during_startup``) and every node ends bit for bit with
    the in-process rounds of all the data."""
    values = np.random.default_rng(5).normal(size=(N, 2))
    algo = {"name": "consensus", "rounds": 40, "protocol": "MH", "patience": 20}
    net, out = _network(tmp_path, values, LoopbackOptions(algorithm=algo, start_timeout_s=30))  # 8 s: CI load
    procs = {i: _start(net, i, out) for i in range(1, N)}
    try:
        end = time.monotonic() + 60
        while time.monotonic() < end and not (out / "node-3.log").exists():
            time.sleep(0.05)
        time.sleep(1.0)  # into its start-up hellos; the barrier cannot end: node 0 is not started
        os.killpg(procs[3].pid, signal.SIGKILL)
        procs[3].wait(timeout=10)
        procs[3] = _start(net, 3, out, "--rejoin")
        time.sleep(1.0)
        procs[0] = _start(net, 0, out)
        codes = _finish(procs, 120)
    finally:
        _kill_all(procs)
    assert all(c == 0 for c in codes.values()), (codes, _stderr(out)[-3000:])
    res = [json.loads((out / f"node-{i}.json").read_text()) for i in range(N)]
    assert res[3]["restarted_during_startup"] is True and res[3]["rejoined_at_step"] is None
    assert all(r["status"] == "completed" and not r["lost_nodes"] and not r["missing_at_start"] for r in res)
    field = np.array([r["estimate"] for r in res])
    ref = list(iterate_average_consensus(values, graph=Graph.from_links(N, LINKS), protocol="MH", rounds=40))[-1]
    assert np.array_equal(field, ref.values), np.abs(field - ref.values).max()


def test_the_start_up_depth_is_the_eccentricity_of_the_greeting_graph() -> None:
    """The barrier's depth is each node's eccentricity (was n - 1 for every node): checked against scipy's
    breadth-first distances on a path, a ring, LINKS and a random geometric graph."""
    from scipy.sparse.csgraph import shortest_path

    from distnav.network import builders

    path = Graph.from_links(7, [(i, i + 1) for i in range(6)])
    ring = Graph.from_links(9, [(i, (i + 1) % 9) for i in range(9)])
    rgg = builders.connected_random_geometric(30, mean_degree=4, rng=np.random.default_rng(2))
    for g in (path, ring, Graph.from_links(N, LINKS), rgg):
        hops = shortest_path(g.adjacency(), unweighted=True, directed=False)
        assert [eccentricity(g, i) for i in range(g.n_nodes)] == [int(h.max()) for h in hops]
    assert [eccentricity(path, i) for i in (0, 3)] == [6, 3]


def test_start_up_hellos_are_repeated_only_to_a_neighbour_that_has_not_answered() -> None:
    """Four nodes that all greet each other (threads, inproc), node 3 started 3 s after the others. Before, every
    node repeated its hello to every neighbour every 0.5 s until the whole network was up, and its level rose to
    n - 1 = 3 (a hello per level change and neighbour): node 0 sent 28 hellos, node 3 15. Now the depth is 1 (every
    node one hop away), the answered neighbours get only the level changes, and the repeats to node 3 go at 0.5, 1,
    2 s: node 0 sent 12, node 3 6 (bounds 20 and 12)."""
    import uuid

    ctx = zmq.Context()
    addr = [f"inproc://hello-{uuid.uuid4().hex}-{i}" for i in range(4)]
    sent: dict[int, dict[str, int]] = {}
    missing: dict[int, list[int]] = {}

    def node(i: int) -> None:
        peers = [Peer(j, addr[j]) for j in range(4) if j != i]
        tr = Transport(i, addr[i], peers, options=TransportOptions(start_timeout_s=20.0), context=ctx)
        try:
            missing[i] = handshake(tr, check=StartCheck(levels=1)).missing
            sent[i] = tr.bytes_by_kind()
        finally:
            tr.close()

    threads = [threading.Thread(target=node, args=(i,), daemon=True) for i in range(4)]
    for t in threads[:3]:
        t.start()
    time.sleep(3.0)
    threads[3].start()
    for t in threads:
        t.join(60)
    assert not any(t.is_alive() for t in threads)
    ctx.term()
    assert missing == {i: [] for i in range(4)}
    hello_frame_bytes = 28 + 4 + 4 * 8  # header, one dimension, four int64 (wire.py)
    frames = {i: sent[i]["hello"] // hello_frame_bytes for i in range(4)}
    assert all(sent[i]["hello"] % hello_frame_bytes == 0 for i in range(4))
    assert frames[0] <= 20 and frames[3] <= 12, frames


def _sockets(n: int) -> tuple[Any, list[str]]:
    import uuid

    tag = uuid.uuid4().hex
    return zmq.Context(), [f"inproc://raw-{tag}-{i}" for i in range(n)]


def _drain(sock: Any) -> list[bytes]:
    frames = []
    while sock.poll(200):
        frames.append(sock.recv())
    return frames


def test_rejoin_hellos_are_counted_as_the_bytes_that_reached_the_peer() -> None:
    """A restarted node that nobody answers (start_timeout_s 1 s): every one-byte hello it sent reached its peer's
    socket, and its byte totals are exactly what that socket received. Before, ``join`` counted none of them."""

    from distnav.errors import ExchangeError

    ctx, addr = _sockets(2)
    peer = ctx.socket(zmq.PULL)
    peer.bind(addr[1])
    tr = Transport(0, addr[0], [Peer(1, addr[1])], options=TransportOptions(start_timeout_s=1.0), context=ctx)
    try:
        with pytest.raises(ExchangeError, match="no neighbour answered"):
            rejoin(tr)
        got = _drain(peer)
        assert len(got) >= 3 and tr.frames_sent == len(got)
        assert tr.bytes_sent == sum(len(f) for f in got) == len(got) * (28 + 4 + 1)  # header, one dimension, 1 byte
        assert tr.bytes_by_kind() == {"hello": tr.bytes_sent}
    finally:
        tr.close()
        peer.close()
        ctx.term()


def _rejoin_hearing(sends: list[tuple[float, bytes]], start_timeout_s: float) -> tuple[int | None, float, int]:
    """Node 0 restarted (:func:`rejoin`, consensus) while neighbours 1 and 2 send ``sends`` (each after its wait, in
    s; node 2 never binds, what it is sent waits): what rejoin returned, after how many seconds, how many refused."""
    ctx, addr = _sockets(3)
    peer_in, peer_out = ctx.socket(zmq.PULL), ctx.socket(zmq.PUSH)
    peer_in.bind(addr[1])
    peers = [Peer(1, addr[1]), Peer(2, addr[2])]
    tr = Transport(0, addr[0], peers, options=TransportOptions(start_timeout_s=start_timeout_s), context=ctx)

    def neighbour() -> None:
        for wait_s, frame in sends:
            time.sleep(wait_s)
            peer_out.send(frame)

    thread = threading.Thread(target=neighbour, daemon=True)
    try:
        peer_out.connect(addr[0])
        t0 = time.monotonic()
        thread.start()
        got = rejoin(tr)
        return got, time.monotonic() - t0, sum(tr.refused.values())
    finally:
        if thread.ident is not None:
            thread.join(5)
        tr.close()
        peer_in.close()
        peer_out.close(linger=0)
        ctx.term()


def test_a_rejoin_that_hears_start_up_hellos_starts_normally() -> None:
    """A neighbour still in its start-up (four int64, below its top level, and no step message follows):
    :func:`rejoin` returns None at once (the node then starts as the others do) instead of waiting for a step."""
    got, seconds, _ = _rejoin_hearing([(0.0, encode(Kind.HELLO, 1, 0, np.array([-1, 0, 0, 1], np.int64)))], 20.0)
    assert got is None
    assert seconds < 5.0  # half a second after the start-up hello, not the 20 s start timeout


def test_a_neighbour_that_answered_and_was_refused_counts_once() -> None:
    """Neighbour 1 sends a hello of this network, then one of another network (refused: a stranger); neighbour 2
    never answers. Before, neighbour 1 counted as answered and as refused: "every neighbour heard" at once, and its
    stale level -1 held the barrier until 2 x start_timeout_s (3 s). Now it counts once, as a stranger: the node
    waits for neighbour 2 until start_timeout_s (1.5 s) and then starts, 2 missing and 1 refused."""
    ctx, addr = _sockets(3)
    sinks = [ctx.socket(zmq.PULL) for _ in range(2)]
    for s, a in zip(sinks, addr[1:], strict=True):
        s.bind(a)
    peers = [Peer(1, addr[1]), Peer(2, addr[2])]
    tr = Transport(0, addr[0], peers, options=TransportOptions(start_timeout_s=1.5), context=ctx)
    out = ctx.socket(zmq.PUSH)
    try:
        out.connect(addr[0])
        out.send(encode(Kind.HELLO, 1, 0, np.array([-1, 77, 0, 1], np.int64)))
        out.send(encode(Kind.HELLO, 1, 0, np.array([-1, 78, 0, 1], np.int64)))  # another network's fingerprint
        start = handshake(tr, check=StartCheck(network_id=77, levels=1))
        assert list(start.strangers) == [1] and start.missing == [2]
        assert 1.4 <= start.seconds < 2.6, start.seconds
    finally:
        tr.close()
        for s in sinks:
            s.close()
        out.close(linger=0)
        ctx.term()


def _leave_times(n: int, links: list[tuple[int, int]], delays: dict[int, float], timeout_s: float) -> dict[int, float]:
    """Threads (inproc) that run :func:`handshake` on the graph ``links``, node i started ``delays[i]`` s late (a
    node not in ``delays`` never starts); when each left its barrier, in seconds from the first start."""
    g = Graph.from_links(n, links)
    ctx, addr = _sockets(n)
    t0, ends = time.monotonic(), {}

    def node(i: int) -> None:
        time.sleep(delays[i])
        peers = [Peer(int(j), addr[int(j)]) for j in sorted(g.neighbors(i))]
        tr = Transport(i, addr[i], peers, options=TransportOptions(start_timeout_s=timeout_s), context=ctx)
        try:
            handshake(tr, check=StartCheck(levels=eccentricity(g, i), levels_if_missing=n - 1))
            ends[i] = time.monotonic() - t0
        finally:
            tr.close()

    threads = [threading.Thread(target=node, args=(i,), daemon=True) for i in delays]
    for t in threads:
        t.start()
    for t in threads:
        t.join(6 * timeout_s + max(delays.values()))
    assert not any(t.is_alive() for t in threads)
    ctx.term()
    return ends


def test_a_node_that_never_started_holds_every_barrier_until_the_network_can_have_heard_it() -> None:
    """Ring of 6, node 3 never starts, node 2 starts 1.5 s late, start_timeout_s 3 s (review13, finding 2). With the
    depth = the full ring's eccentricity (3), node 4 left its barrier at 3.1 s and its only live neighbour 5 at 4.5 s
    (with 1 s deadlines node 4 declares 5 lost). Now node 4 timed out on node 3, so it waits n - 1 = 5 levels and its
    hellos carry that depth to the others: every node leaves when node 2 has timed out on node 3 (4.5 s), together."""
    ends = _leave_times(6, [(i, (i + 1) % 6) for i in range(6)], {0: 0.0, 1: 0.0, 2: 1.5, 4: 0.0, 5: 0.0}, 3.0)
    assert sorted(ends) == [0, 1, 2, 4, 5]
    assert min(ends.values()) >= 4.3, ends
    assert max(ends.values()) - min(ends.values()) < 0.5, ends


def test_a_rejoin_that_hears_a_top_level_hello_waits_for_the_first_step_message() -> None:
    """Neighbour 1's last start-up hello is at its top level (level = depth: it leaves its barrier), neighbour 2's is
    below it, and 1's first step message comes 0.8 s later (an ADMM round's local work). Before, :func:`rejoin`
    returned None 0.5 s after the hello (review13, finding 1): the node ran the start-up, and node 1's step messages,
    from a sender that never greeted there, made it a stranger ("another network"). Now it waits and rejoins at 1's
    step (a neighbour at its top: the network runs, though another still rises)."""
    hellos = [encode(Kind.HELLO, i, 0, np.array([level, 0, 0, 2], np.int64)) for i, level in ((1, 2), (2, 1))]
    sends = [(0.0, hellos[0]), (0.0, hellos[1]), (0.8, encode(Kind.COLUMN, 1, 3, np.zeros(2)))]
    got, _, refused = _rejoin_hearing(sends, 10.0)
    assert got == 3 and refused == 0


def test_a_node_back_mid_run_announces_its_top_level_to_a_neighbour_still_in_its_barrier() -> None:
    """Node 0 is in its barrier (depth 1, start_timeout_s 3 s); neighbour 2 is at its top; neighbour 1 greeted, was
    restarted (its one-byte hello: level -1 again) and takes the mid-run path (review13, finding 3). Before, it sent
    no start-up hello there and node 0 waited 2 x start_timeout_s (6 s). Now its :func:`announce` (one hello at its
    top level) lets node 0 leave at once."""
    ctx, addr = _sockets(3)
    sink, out = ctx.socket(zmq.PULL), ctx.socket(zmq.PUSH)
    sink.bind(addr[2])
    opts = TransportOptions(start_timeout_s=3.0)
    tr = Transport(0, addr[0], [Peer(1, addr[1]), Peer(2, addr[2])], options=opts, context=ctx)
    back = Transport(1, addr[1], [Peer(0, addr[0])], options=opts, context=ctx)
    try:
        out.connect(addr[0])
        out.send(encode(Kind.HELLO, 2, 0, np.array([1, 0, 0, 1], np.int64)))
        back.post_many([0], Kind.HELLO, 0, np.array([0, 0, 0, 1], np.int64))
        back.post_many([0], Kind.HELLO, 0, np.ones(1, np.uint8))  # restarted: its old level is void
        announce(back, StartCheck(levels=1))
        start = handshake(tr, check=StartCheck(levels=1))
        assert start.missing == [] and start.seconds < 1.5, start.seconds
    finally:
        for t in (tr, back):
            t.close()
        sink.close()
        out.close(linger=0)
        ctx.term()
