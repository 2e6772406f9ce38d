"""What the field commands share to start node processes on this machine: a node's log, killing a node's process
group, free loopback ports, and writing a loopback network description (tests, benchmarks, demos)."""

from __future__ import annotations

import logging
import os
import signal
import socket
import subprocess
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from distnav.errors import UsageError
from distnav.formats.field_config import NetworkDescription, NodeEntry, format_description
from distnav.network.graph import Graph
from distnav.output import atomic_write_text

__all__ = [
    "LoopbackOptions",
    "free_loopback_ports",
    "kill_group",
    "removable_node",
    "setup_node_log",
    "wire_bytes_by_kind",
    "write_loopback_description",
    "write_loopback_network",
]


def setup_node_log(out_dir: Path, node_id: int) -> None:
    """Send the ``distnav.field`` log of this process to ``out_dir/node-ID.log``."""
    handler = logging.FileHandler(out_dir / f"node-{node_id}.log", encoding="utf-8")
    handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(message)s"))
    log = logging.getLogger("distnav.field")
    log.addHandler(handler)
    log.setLevel(logging.INFO)


def wire_bytes_by_kind(nodes: dict[str, Any]) -> dict[str, int]:
    """The bytes the nodes of a run sent, by wire kind (the sum of their ``wire_bytes_by_kind``)."""
    out: dict[str, int] = {}
    for r in nodes.values():
        for kind, n in r.get("wire_bytes_by_kind", {}).items():
            out[kind] = out.get(kind, 0) + int(n)
    return dict(sorted(out.items()))


def kill_group(p: subprocess.Popen[bytes]) -> None:
    """Kill a node process started with ``start_new_session=True`` and everything it started, and reap it."""
    try:
        os.killpg(p.pid, signal.SIGKILL)
    except ProcessLookupError:
        pass
    p.wait(timeout=10)


def removable_node(graph: Graph, *, skip: set[int] | None = None) -> int:
    """The highest-id node (not in ``skip``) whose loss leaves the others connected (the node a demo or benchmark
    kills)."""
    for v in range(graph.n_nodes - 1, -1, -1):
        if skip and v in skip:
            continue
        keep = [i for i in range(graph.n_nodes) if i != v]
        index = {k: n for n, k in enumerate(keep)}
        links = [(index[a], index[b]) for a, b in graph.links.tolist() if v not in (a, b)]
        if Graph.from_links(len(keep), links).is_connected:
            return v
    raise UsageError("no node can be removed without splitting the network")


def free_loopback_ports(count: int) -> list[int]:
    """``count`` TCP ports free on 127.0.0.1 right now (bound to port 0 and released; a race with other programs is
    possible but rare)."""
    socks, ports = [], []
    try:
        for _ in range(count):
            s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
            s.bind(("127.0.0.1", 0))
            socks.append(s)
            ports.append(int(s.getsockname()[1]))
    finally:
        for s in socks:
            s.close()
    return ports


@dataclass(frozen=True)
class LoopbackOptions:
    """The description's settings of a loopback network (documented defaults, checked once).

    name : the network's name. algorithm : the ``[algorithm]`` table (None: consensus, 200 rounds, MH).
    crash : node → the round at which it exits on purpose. deadline_ms, miss_limit, start_timeout_s : the lock-step
    timing.
    drop_probability, latency_max_ms, seed : injected losses and latency (the ``[faults]`` table).
    """

    name: str = "network"
    deadline_ms: float = 2000.0
    miss_limit: int = 3
    algorithm: dict[str, Any] | None = None
    drop_probability: float = 0.0
    latency_max_ms: float = 0.0
    seed: int = 0
    crash: dict[int, int] | None = None
    start_timeout_s: float = 60.0

    def __post_init__(self) -> None:
        if not self.deadline_ms > 0 or self.miss_limit < 1 or not self.start_timeout_s > 0:
            raise UsageError(
                "deadline_ms and start_timeout_s must be > 0 and miss_limit >= 1, got "
                f"{self.deadline_ms}, {self.start_timeout_s}, {self.miss_limit}"
            )
        if not 0 <= self.drop_probability < 1 or not self.latency_max_ms >= 0:
            raise UsageError(
                f"drop_probability must be in [0, 1) and latency_max_ms >= 0, got {self.drop_probability}, "
                f"{self.latency_max_ms}"
            )


def write_loopback_description(
    folder: Path, links: list[tuple[int, int]] | np.ndarray, data: list[Path], options: LoopbackOptions
) -> Path:
    """Write ``folder/network.toml``: ``len(data)`` nodes on 127.0.0.1 with free ports, node ``i`` reading
    ``data[i]``; returns its path."""
    folder.mkdir(parents=True, exist_ok=True)
    n = len(data)
    nbrs: list[set[int]] = [set() for _ in range(n)]
    for i, j in np.asarray(links, dtype=int).reshape(-1, 2).tolist():
        nbrs[i].add(j)
        nbrs[j].add(i)
    ports = free_loopback_ports(n)
    nodes = tuple(
        NodeEntry(id=i, address=f"tcp://127.0.0.1:{ports[i]}", neighbours=tuple(sorted(nbrs[i])), data=data[i])
        for i in range(n)
    )
    desc = NetworkDescription(
        nodes=nodes,
        name=options.name,
        deadline_ms=options.deadline_ms,
        miss_limit=options.miss_limit,
        start_timeout_s=options.start_timeout_s,
        algorithm=options.algorithm or {"name": "consensus", "rounds": 200, "protocol": "MH", "patience": 20},
        crash=options.crash or {},
        drop_probability=options.drop_probability,
        drop_seed=options.seed,
        latency_max_ms=options.latency_max_ms,
    )
    path = folder / "network.toml"
    atomic_write_text(path, format_description(desc, relative_to=folder))
    return path


def write_loopback_network(
    folder: Path,
    links: list[tuple[int, int]] | np.ndarray,
    values: np.ndarray,
    options: LoopbackOptions | None = None,
) -> Path:
    """A consensus network on loopback: one text data file per node (``values[i]``) and ``folder/network.toml``."""
    vals = np.asarray(values, dtype=float).reshape(len(values), -1)
    paths = []
    for i in range(vals.shape[0]):
        path = folder / "data" / f"node-{i}.txt"
        path.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_text(path, " ".join(repr(float(v)) for v in vals[i]) + "\n")
        paths.append(path)
    return write_loopback_description(folder, links, paths, options if options is not None else LoopbackOptions())
