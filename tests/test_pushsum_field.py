"""Asynchronous push-sum in the field: 8 node processes on loopback, each on its own timer (one 3x slower), no
barrier; every node's estimate within 1e-6 of the numpy mean of the initial values."""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from distnav.network import builders

pytest.importorskip("zmq")
pytest.importorskip("tomli_w")


def _free_ports(n: int) -> list[int]:
    socks = [socket.socket() for _ in range(n)]
    try:
        for s in socks:
            s.bind(("127.0.0.1", 0))
        return [s.getsockname()[1] for s in socks]
    finally:
        for s in socks:
            s.close()


def _write_network(folder: Path, values: np.ndarray, graph, loss: float) -> Path:  # type: ignore[no-untyped-def]
    from distnav.formats.field_config import NetworkDescription, NodeEntry, format_description

    ports = _free_ports(graph.n_nodes)
    nodes = []
    for i in range(graph.n_nodes):
        data = folder / f"node-{i}.txt"
        data.write_text(" ".join(repr(float(v)) for v in values[i]) + "\n")
        nodes.append(
            NodeEntry(
                id=i,
                address=f"tcp://127.0.0.1:{ports[i]}",
                neighbours=tuple(int(j) for j in graph.neighbors(i)),
                data=data,
            )
        )
    path = folder / "net.toml"
    desc = NetworkDescription(
        nodes=tuple(nodes), name="pushsum-8", start_timeout_s=60.0, drop_probability=loss, drop_seed=5
    )
    path.write_text(format_description(desc, relative_to=folder))
    return path


@pytest.mark.parametrize("loss", [0.0, 0.2])
def test_eight_processes_one_slow_reach_the_mean(tmp_path: Path, loss: float) -> None:
    g = builders.connected_random_geometric(8, mean_degree=3, rng=np.random.default_rng(11))
    x = np.random.default_rng(12).normal(10.0, 4.0, size=(8, 2))
    net = _write_network(tmp_path, x, g, loss)
    slow = 3
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in sys.path if p)}
    procs = []
    try:
        for i in range(8):
            period = "30" if i == slow else "10"
            cmd = [
                sys.executable,
                "-m",
                "distnav",
                "field",
                "pushsum-node",
                "--config",
                str(net),
                "--id",
                str(i),
                "--out",
                str(tmp_path),
                "--period-ms",
                period,
                "--duration-s",
                "6",
            ]
            procs.append(subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE))
        outs = [p.communicate(timeout=400) for p in procs]
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
                p.wait()
    for i, (p, (_, err)) in enumerate(zip(procs, outs, strict=True)):
        assert p.returncode == 0, f"node {i}: {err.decode()[-2000:]}"
    res = [json.loads((tmp_path / f"node-{i}.json").read_text()) for i in range(8)]
    est = np.array([r["estimate"] for r in res])
    np.testing.assert_allclose(est, np.broadcast_to(x.mean(axis=0), (8, 2)), atol=1e-6, rtol=0)
    ticks = np.array([r["ticks"] for r in res])
    assert ticks[slow] < 0.6 * np.median(np.delete(ticks, slow)), ticks  # it really ticked slower
    assert all(r["wire"]["bytes_sent"] > 0 and not r["refused"] for r in res)
    received = sum(r["wire"]["frames_received"] for r in res)
    dropped = sum(r["dropped_on_purpose"] for r in res)
    assert (dropped == 0) if loss == 0 else (0.1 * received < dropped < 0.3 * received), (dropped, received)
