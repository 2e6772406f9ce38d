"""Node processes on loopback: `distnav field launch` equals the in-process run bit for bit, and a node killed
mid-run leaves the others with the exact mean of the remaining data. Each test starts its own processes (bounded by
the launcher's timeout, process groups killed in the launcher's `finally`)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("zmq")

from distnav.algorithms.consensus.averaging import iterate_average_consensus  # noqa: E402
from distnav.algorithms.consensus.flows import iterate_flow_consensus  # noqa: E402
from distnav.cli import main  # noqa: E402
from distnav.commands.field import launch  # noqa: E402
from distnav.commands.field_processes import LoopbackOptions, write_loopback_network  # noqa: E402
from distnav.network import builders  # noqa: E402


def _graph(n: int, seed: int = 1, degree: float = 4):  # type: ignore[no-untyped-def]
    return builders.connected_random_geometric(n, mean_degree=degree, rng=np.random.default_rng(seed))


def _victim(g) -> int:  # type: ignore[no-untyped-def]
    """The best-connected node whose loss leaves the others connected (else no method could reach their mean)."""
    import networkx as nx

    G = nx.Graph([tuple(map(int, link)) for link in g.links])
    ok = [v for v in range(g.n_nodes) if nx.is_connected(G.subgraph(set(range(g.n_nodes)) - {v}))]
    return max(ok, key=lambda v: (g.degrees[v], v))


def _last(states):  # type: ignore[no-untyped-def]
    return list(states)[-1].values


def test_consensus_on_node_processes_is_bitwise_the_inprocess_run(tmp_path: Path) -> None:
    g = _graph(6)
    values = np.random.default_rng(2).normal(size=(6, 3))
    algo = {"name": "consensus", "rounds": 60, "protocol": "MH", "patience": 20}
    net = write_loopback_network(tmp_path / "net", g.links, values, LoopbackOptions(algorithm=algo, deadline_ms=20000))
    summary = launch(net, tmp_path / "run", timeout_s=240, quiet=True)
    assert summary["finished"] == list(range(6)), summary["failed"]
    field = np.array([summary["nodes"][str(i)]["estimate"] for i in range(6)])
    ref = _last(iterate_average_consensus(values, graph=g, protocol="MH", rounds=60))
    assert np.array_equal(field, ref), np.abs(field - ref).max()
    assert summary["refused"] == 0 and summary["lost_nodes"] == []
    # real bytes on the wire: at least the payload the exchange's model counts, plus the 32-byte headers
    for i in range(6):
        r = summary["nodes"][str(i)]
        assert r["wire"]["bytes_sent"] >= r["model_bytes_sent"] + 32 * 60 * g.degrees[i]
    # beside the fusion centre: the same wire bytes, and a gather of the node files as they lie on disk
    vs = summary["vs_gather"]
    assert vs["distributed"]["bytes"] == summary["wire_bytes"]
    files = sorted((tmp_path / "net").rglob("node-*.txt"))
    assert len(files) == 6 and vs["gather"]["data_bytes"] == sum(f.stat().st_size for f in files)
    assert vs["ratio_bytes"] == pytest.approx(summary["wire_bytes"] / vs["gather"]["total_hop_bytes"])


def _crash_network(tmp_path: Path, rounds: int, width: int, seed: int, deadline_ms: float, latency_max_ms: float = 0.0):  # type: ignore[no-untyped-def]
    """8 nodes running consensus_flows; the best-connected node whose loss leaves the rest connected crashes at round
    20. Returns (graph, that node, the data, the description's path)."""
    g = _graph(8, seed=3, degree=5)
    dead = _victim(g)
    values = np.random.default_rng(seed).normal(size=(8, width))
    algo = {"name": "consensus_flows", "rounds": rounds, "protocol": "MH", "patience": 5}
    net = write_loopback_network(
        tmp_path / "net",
        g.links,
        values,
        LoopbackOptions(algorithm=algo, crash={dead: 20}, deadline_ms=deadline_ms, latency_max_ms=latency_max_ms),
    )
    return g, dead, values, net


def test_a_node_killed_at_round_20_leaves_the_mean_of_the_remaining_data(tmp_path: Path) -> None:
    g, dead, values, net = _crash_network(tmp_path, 400, 2, 4, 1500)
    summary = launch(net, tmp_path / "run", timeout_s=240, quiet=True)
    assert summary["crashed_on_purpose"] == [dead] and not summary["failed"], summary["failed"]
    assert summary["finished"] == [i for i in range(8) if i != dead]
    assert summary["lost_nodes"] == [dead]
    keep = np.arange(8) != dead
    field = np.array([summary["nodes"][str(i)]["estimate"] for i in summary["finished"]])
    assert np.abs(field - values[keep].mean(axis=0)).max() <= 1e-6  # numpy's mean: the independent reference
    for i in g.neighbors(dead):  # every neighbour of the dead node names it, with the step
        lost = summary["nodes"][str(int(i))]["lost_nodes"]
        assert list(lost) == [str(dead)] and 20 <= lost[str(dead)] <= 23
    # the same algorithm in-process, the node silent from round 20: the same survivors' mean
    from distnav.exchange import FaultSchedule, make_exchange

    ex = make_exchange(g, faults=FaultSchedule(silent_nodes=((dead, 20),)))
    ref = _last(iterate_flow_consensus(values, graph=g, protocol="MH", rounds=400, exchange=ex, patience=5))
    assert np.abs(ref[keep] - values[keep].mean(axis=0)).max() <= 1e-6


def test_bad_descriptions_exit_2_naming_node_and_key(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    net = write_loopback_network(tmp_path / "net", [(0, 1), (1, 2)], np.zeros((3, 1)))
    text = net.read_text()
    bad = tmp_path / "bad.toml"
    bad.write_text(text.replace("neighbours = [\n    1,\n]", "neighbours = [\n    2,\n]", 1))
    assert main(["field", "launch", "--config", str(bad), "--out", str(tmp_path / "o")]) == 2
    assert "node 0 lists neighbour 2, but node 2 does not list 0" in capsys.readouterr().err
    bad.write_text(text.replace('protocol = "MH"', 'protocol = "XX"'))
    assert main(["node", "--config", str(bad), "--id", "0", "--out", str(tmp_path / "o")]) == 2
    assert "[algorithm]: key 'protocol' must be one of" in capsys.readouterr().err
    assert main(["node", "--config", str(net), "--id", "7", "--out", str(tmp_path / "o")]) == 2
    assert "--id 7: the description has nodes 0..2" in capsys.readouterr().err
    bad.write_text("version = 1\n[[node]]\nid = 0\naddress = 'udp://x'\nneighbours = []\n")
    assert main(["node", "--config", str(bad), "--id", "0", "--out", str(tmp_path / "o")]) == 2
    assert "id 0: key 'address' must look like tcp://HOST:PORT" in capsys.readouterr().err


def test_keys_writes_a_curve_description_and_never_overwrites(tmp_path: Path) -> None:
    net = write_loopback_network(tmp_path / "net", [(0, 1), (1, 2)], np.zeros((3, 1)))
    out = tmp_path / "curve"
    assert main(["field", "keys", "--config", str(net), "--out", str(out)]) == 0
    text = (out / "network.toml").read_text()
    assert 'security = "curve"' in text and text.count("public_key") == 3 and text.count("secret_key") == 3
    assert (out / "keys" / "node-1.key_secret").stat().st_mode & 0o077 == 0
    assert main(["field", "keys", "--config", str(net), "--out", str(out)]) == 2  # exists: never overwritten
    assert main(["field", "keys", "--config", str(net), "--out", str(net.parent)]) == 2  # its own input


def test_curve_network_runs_and_equals_the_plain_one(tmp_path: Path) -> None:
    g = _graph(5, seed=6)
    values = np.random.default_rng(7).normal(size=(5, 1))
    algo = {"name": "consensus", "rounds": 30, "protocol": "MH", "patience": 20}
    net = write_loopback_network(tmp_path / "net", g.links, values, LoopbackOptions(algorithm=algo, deadline_ms=20000))
    assert main(["field", "keys", "--config", str(net), "--out", str(tmp_path / "curve")]) == 0
    summary = launch(tmp_path / "curve" / "network.toml", tmp_path / "run", timeout_s=240, quiet=True)
    assert summary["finished"] == list(range(5)), summary["failed"]
    field = np.array([summary["nodes"][str(i)]["estimate"] for i in range(5)])
    assert np.array_equal(field, _last(iterate_average_consensus(values, graph=g, protocol="MH", rounds=30)))
    assert summary["refused"] == 0


def test_a_restarted_node_rejoins_and_its_data_count_again(tmp_path: Path) -> None:
    # rounds paced by 0-30 ms of injected latency (1,200 rounds: ≥ 15 s), so the node comes back after its neighbours
    # declared it lost (3 steps × 1 s) and before they finish, on an idle machine as under load
    g, dead, values, net = _crash_network(tmp_path, 1200, 1, 8, 1000, latency_max_ms=30.0)
    text = net.read_text().replace(
        f"{{ node = {dead}, round = 20 }}", f"{{ node = {dead}, round = 20, restart_after_s = 4.0 }}"
    )  # back after its neighbours have declared it lost (miss_limit 3 × deadline 1 s), on an idle machine too
    assert "restart_after_s" in text
    net.write_text(text)
    summary = launch(net, tmp_path / "run", timeout_s=300, quiet=True)
    assert summary["rejoined"] == [dead] and summary["finished"] == list(range(8)), summary["failed"]
    back = summary["nodes"][str(dead)]["rejoined_at_step"]
    assert 20 < back < 1200
    for i in g.neighbors(dead):  # its neighbours lost it, then took it back
        r = summary["nodes"][str(int(i))]
        assert str(dead) in r["readmitted_nodes"] and not r["lost_nodes"]
    # every node's data count again: the mean of all the data (numpy's), to 1e-6
    est = np.array([summary["nodes"][str(i)]["estimate"] for i in range(8)])
    assert np.abs(est - values.mean(axis=0)).max() <= 1e-6
