"""The field runtime on loopback (issue 26 targets): node processes vs the in-process run and vs bare pyzmq.

Rows:
* ``lockstep_consensus`` — N node processes (32; 8 with --quick), average consensus (MH) in lock-step: rounds per
  second (the slowest node, after start-up) and whether every node's result is bitwise the in-process one.
  Goal ≥ 1,000 rounds/s.
* ``round_overhead`` — seconds per round of the field run ÷ seconds per round of bare pyzmq exchanging frames of the
  same size between the same number of processes on the same graph (benchmarks/field_bare_node.py), both measured
  in this run. Goal ≤ 2.
* ``loss10_latency50`` — 10 % of messages dropped (seeded schedule) and 0–50 ms random latency injected on every
  message: the field run's final deviation from the mean vs the in-process run's with the same drops.
  Goal: the same precision (ratio ≤ 1).
The machine load (1-minute load average) is reported in every row: the machine is shared.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parent / "src"))

from _common import main_for  # noqa: E402
from distnav.algorithms.consensus.averaging import iterate_average_consensus  # noqa: E402
from distnav.commands.field import launch  # noqa: E402
from distnav.commands.field_processes import LoopbackOptions, write_loopback_network  # noqa: E402
from distnav.exchange import FaultSchedule, make_exchange  # noqa: E402
from distnav.network import builders  # noqa: E402


def _load() -> float:
    return float(os.getloadavg()[0])


def _final(values: np.ndarray, g: Any, rounds: int, faults: FaultSchedule | None = None) -> np.ndarray:
    ex = make_exchange(g, faults=faults)
    return list(iterate_average_consensus(values, graph=g, protocol="MH", rounds=rounds, exchange=ex))[-1].values


def _bare(net: Path, n: int, rounds: int, size: int, timeout_s: float) -> float:
    """Seconds per round of the bare pyzmq exchange (the slowest node)."""
    procs = [
        subprocess.Popen(
            [sys.executable, str(HERE / "field_bare_node.py"), str(net), str(i), str(rounds), str(size)],
            stdout=subprocess.PIPE,
            stderr=subprocess.DEVNULL,
            start_new_session=True,
        )
        for i in range(n)
    ]
    out = []
    try:
        for p in procs:
            stdout, _ = p.communicate(timeout=timeout_s)
            out.append(json.loads(stdout))
    finally:
        for p in procs:
            if p.poll() is None:
                os.killpg(p.pid, 9)
                p.wait()
    return max(r["seconds"] for r in out) / rounds


def run(quick: bool) -> list[dict[str, Any]]:
    n = 8 if quick else 32
    rounds = 200 if quick else 500
    g = builders.connected_random_geometric(n, mean_degree=5, rng=np.random.default_rng(11))
    values = np.random.default_rng(12).normal(size=(n, 1))
    rows: list[dict[str, Any]] = []
    algo = {"name": "consensus", "rounds": rounds, "protocol": "MH", "patience": 20}
    with tempfile.TemporaryDirectory() as tmp:
        net = write_loopback_network(
            Path(tmp) / "net", g.links, values, LoopbackOptions(algorithm=algo, deadline_ms=30000)
        )
        load0 = _load()
        t0 = time.perf_counter()
        summary = launch(net, Path(tmp) / "run", timeout_s=900, quiet=True)
        wall = time.perf_counter() - t0
        ok = summary["finished"] == list(range(n))
        ref = _final(values, g, rounds)
        field = np.array([summary["nodes"][str(i)]["estimate"] for i in range(n)]) if ok else None
        sec_round = max(summary["nodes"][str(i)]["seconds"] for i in range(n)) / rounds if ok else float("nan")
        rows.append(
            {
                "name": "lockstep_consensus",
                "n": n,
                "rounds": rounds,
                "rounds_per_s": 1.0 / sec_round,
                "bitwise_equal_inprocess": bool(ok and np.array_equal(field, ref)),
                "wire_bytes": summary["wire_bytes"],
                "launch_wall_s": wall,
                "load_1min": load0,
                "goal": "≥ 1000 rounds/s",
                "meets_goal": bool(1.0 / sec_round >= 1000),
            }
        )
        bare = _bare(net, n, rounds, 32 + 8 * values.shape[1], timeout_s=600)
        rows.append(
            {
                "name": "round_overhead",
                "n": n,
                "seconds": sec_round,
                "reference_seconds": bare,
                "ratio": sec_round / bare,
                "load_1min": _load(),
                "goal": "≤ 2",
                "meets_goal": bool(sec_round / bare <= 2),
            }
        )
        m = min(n, 16)
        g2 = builders.connected_random_geometric(m, mean_degree=5, rng=np.random.default_rng(13))
        v2 = np.random.default_rng(14).normal(size=(m, 1))
        r2 = 150 if quick else 300
        algo2 = {"name": "consensus", "rounds": r2, "protocol": "MH", "patience": 20}
        net2 = write_loopback_network(
            Path(tmp) / "net2",
            g2.links,
            v2,
            LoopbackOptions(algorithm=algo2, deadline_ms=2000, drop_probability=0.1, latency_max_ms=50, seed=5),
        )
        s2 = launch(net2, Path(tmp) / "run2", timeout_s=900, quiet=True)
        ok2 = s2["finished"] == list(range(m))
        ref2 = _final(v2, g2, r2, FaultSchedule(drop_probability=0.1, seed=5))
        dev_ref = float(np.abs(ref2 - v2.mean(axis=0)).max())
        field2 = np.array([s2["nodes"][str(i)]["estimate"] for i in range(m)]) if ok2 else np.full_like(ref2, np.nan)
        dev_field = float(np.abs(field2 - v2.mean(axis=0)).max())
        rows.append(
            {
                "name": "loss10_latency50",
                "n": m,
                "rounds": r2,
                "deviation_field": dev_field,
                "deviation_inprocess": dev_ref,
                "ratio": dev_field / dev_ref,
                "bitwise_equal_inprocess": bool(ok2 and np.array_equal(field2, ref2)),
                "late_refused": int(sum(r["refused"].get("late", 0) for r in s2["nodes"].values())),
                "load_1min": _load(),
                "goal": "ratio ≤ 1",
                "meets_goal": bool(dev_field <= dev_ref),
            }
        )
    return rows


if __name__ == "__main__":
    main_for(__file__, run)
