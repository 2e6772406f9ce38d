"""``distnav field demo --nodes N --out DIR``: the field runtime shown end to end on this machine (issue 26 item 8).

Every run starts ``N`` node processes on loopback (each its own program, holding only its own data) and compares what
they computed with an independent reference:

1. **consensus, clean** — lock-step average consensus (MH weights) over ZeroMQ; reference: the same rounds
   in-process (:func:`~distnav.algorithms.consensus.averaging.iterate_average_consensus`) →
   ``max_abs_diff_vs_inprocess`` (0 means bitwise equal);
2. **consensus, one node killed** — flow consensus, one node (chosen so the others stay connected) exits at round
   ``--kill-round``; reference: numpy's mean of the data of the nodes that remain →
   ``lost_nodes`` (as noticed by their neighbours) and ``max_abs_diff_vs_central_of_remaining``;
3. **push-sum, asynchronous** — every node on its own timer, node 0 three times slower, no barrier
   (``distnav field pushsum-node``); reference: numpy's mean → ``pushsum_max_abs_diff_vs_mean``.

``DIR/results.json`` holds those numbers, ``wire_bytes`` (real bytes sent on the wire by all runs), each run's
summary, and a ``uwb_hall`` entry saying whether a UWB hall was run (the field runtime has no UWB node program yet, so
it says so instead of inventing a number). Each run's folder keeps the description, the nodes' results and logs.
Every process is bounded by ``--timeout`` and killed (process group) on failure or Ctrl-C. ``distnav demo --out
D`` adds a section for ``D/field/results.json`` to its report when that file exists.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from distnav.errors import UsageError
from distnav.network import builders
from distnav.network.graph import Graph
from distnav.options import output_folder, positive_float, positive_int, seed
from distnav.output import atomic_write_json

__all__ = ["DemoOptions", "run_field_demo", "launch_async", "register"]


@dataclass(frozen=True)
class DemoOptions:
    """What ``distnav field demo`` runs (documented defaults, checked once).

    nodes : node processes per run (≥ 4, so one can die and the rest stay a network).
    rounds : lock-step rounds of both consensus runs.
    kill_round : the round at which the killed run's node exits (< rounds).
    pushsum_seconds : how long the asynchronous nodes tick (the fast ones every 10 ms, node 0 every 30 ms).
    timeout_s : every run's processes are killed after this many seconds.
    seed : the network and its values.
    deadline_ms : the killed run's step deadline; a neighbour silent for 3 deadlines is declared lost. Generous by
        default: on a loaded machine a live node that misses 3 short deadlines is declared lost too, and its flows
        are dropped (the demo then reports it under ``false_losses`` and fails).
    """

    nodes: int = 8
    rounds: int = 300
    kill_round: int = 20
    pushsum_seconds: float = 6.0
    timeout_s: float = 300.0
    seed: int = 0
    deadline_ms: float = 5000.0

    def __post_init__(self) -> None:
        if self.nodes < 4:
            raise UsageError(
                f"--nodes must be at least 4 (one is killed, the rest must stay a network), got {self.nodes}"
            )
        if self.nodes > 64:
            raise UsageError(f"--nodes at most 64 on one machine, got {self.nodes}")
        if not 1 <= self.kill_round < self.rounds:
            raise UsageError(f"--kill-round must be in 1..{self.rounds - 1} (below --rounds), got {self.kill_round}")


def _victim(graph: Graph) -> int:
    """The highest-id node whose loss leaves the others connected."""
    for v in range(graph.n_nodes - 1, -1, -1):
        keep = [i for i in range(graph.n_nodes) if i != v]
        links = [(a, b) for a, b in graph.links.tolist() if v not in (a, b)]
        index = {k: n for n, k in enumerate(keep)}
        sub = Graph.from_links(len(keep), [(index[a], index[b]) for a, b in links])
        if sub.is_connected:
            return v
    raise UsageError("no node can be removed without splitting the network")  # unreachable for our graphs


def launch_async(
    desc_path: Path, out_dir: Path, *, periods_ms: list[float], duration_s: float, timeout_s: float
) -> dict[str, Any]:
    """Start one ``distnav field pushsum-node`` process per node (node ``i`` ticking every ``periods_ms[i]``),
    wait at most ``timeout_s`` (then kill the rest, process group and all) and collect their ``node-ID.json``."""
    from distnav.commands.field import _kill_group

    out_dir.mkdir(parents=True, exist_ok=True)
    env = dict(os.environ)
    src = str(Path(__file__).resolve().parents[2])
    env["PYTHONPATH"] = src + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    procs: list[subprocess.Popen[bytes]] = []
    t0 = time.monotonic()
    codes: list[int | None] = []
    try:
        for i, period in enumerate(periods_ms):
            cmd = [
                sys.executable,
                "-m",
                "distnav",
                "field",
                "pushsum-node",
                "--config",
                str(desc_path),
                "--id",
                str(i),
                "--out",
                str(out_dir),
                "--period-ms",
                str(period),
                "--duration-s",
                str(duration_s),
            ]
            with open(out_dir / f"node-{i}.stderr", "wb") as err:
                procs.append(
                    subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=err, env=env, start_new_session=True)
                )
        for p in procs:
            try:
                codes.append(p.wait(timeout=max(0.1, timeout_s - (time.monotonic() - t0))))
            except subprocess.TimeoutExpired:
                codes.append(None)
    finally:
        for p in procs:
            if p.poll() is None:
                _kill_group(p)
    nodes = {str(i): json.loads((out_dir / f"node-{i}.json").read_text()) for i, c in enumerate(codes) if c == 0}
    return {
        "finished": [i for i, c in enumerate(codes) if c == 0],
        "failed": [{"node": i, "exit_code": c, "timed_out": c is None} for i, c in enumerate(codes) if c != 0],
        "seconds": time.monotonic() - t0,
        "wire_bytes": int(sum(r["wire"]["bytes_sent"] for r in nodes.values())),
        "nodes": nodes,
    }


def _estimates(summary: dict[str, Any], ids: list[int]) -> np.ndarray:
    return np.array([summary["nodes"][str(i)]["estimate"] for i in ids], dtype=float).reshape(len(ids), -1)


def run_field_demo(opts: DemoOptions, out: Path) -> dict[str, Any]:
    """The three runs of the module docstring; writes and returns ``out/results.json``'s content."""
    from distnav.algorithms.consensus.averaging import iterate_average_consensus
    from distnav.commands.field import launch, write_loopback_network
    from distnav.formats.field_config import read_description

    rng = np.random.default_rng(opts.seed)
    graph = builders.connected_random_geometric(opts.nodes, mean_degree=min(4, opts.nodes - 1), rng=rng)
    values = rng.normal(10.0, 3.0, size=(opts.nodes, 2))
    n = opts.nodes
    runs: dict[str, Any] = {}

    algo = {"name": "consensus", "rounds": opts.rounds, "protocol": "MH", "patience": 5}
    net = write_loopback_network(
        out / "consensus_clean", graph.links, values, name="demo-clean", algorithm=algo, deadline_ms=20000
    )
    clean = launch(net, out / "consensus_clean", timeout_s=opts.timeout_s, quiet=True)
    ref = values
    for state in iterate_average_consensus(
        values, graph=read_description(net).graph(), protocol="MH", rounds=opts.rounds
    ):
        ref = state.values
    ok = clean["finished"]
    clean_diff = float(np.abs(_estimates(clean, ok) - ref[ok]).max()) if ok else None
    runs["consensus_clean"] = {**_short(clean), "max_abs_diff_vs_inprocess": clean_diff}

    victim = _victim(graph)
    flows = {**algo, "name": "consensus_flows"}
    net = write_loopback_network(
        out / "consensus_killed",
        graph.links,
        values,
        name="demo-killed",
        algorithm=flows,
        crash={victim: opts.kill_round},
        deadline_ms=opts.deadline_ms,
        miss_limit=3,
    )
    killed = launch(net, out / "consensus_killed", timeout_s=opts.timeout_s, quiet=True)
    keep = np.arange(n) != victim
    ok = killed["finished"]
    killed_diff = float(np.abs(_estimates(killed, ok) - values[keep].mean(axis=0)).max()) if ok else None
    runs["consensus_killed"] = {
        **_short(killed),
        "killed_node": victim,
        "killed_at_round": opts.kill_round,
        "lost_nodes": killed.get("lost_nodes", []),
        "max_abs_diff_vs_central_of_remaining": killed_diff,
    }

    net = write_loopback_network(out / "pushsum_async", graph.links, values, name="demo-pushsum")
    periods = [30.0] + [10.0] * (n - 1)
    ps = launch_async(
        net, out / "pushsum_async", periods_ms=periods, duration_s=opts.pushsum_seconds, timeout_s=opts.timeout_s
    )
    ok = ps["finished"]
    ps_diff = float(np.abs(_estimates(ps, ok) - values.mean(axis=0)).max()) if ok else None
    ticks = [ps["nodes"][str(i)]["ticks"] for i in ok]
    runs["pushsum_async"] = {**_short(ps), "periods_ms": periods, "ticks": ticks, "max_abs_diff_vs_mean": ps_diff}

    failed = {k: r["failed"] for k, r in runs.items() if r["failed"]}
    false_losses = sorted(set(runs["consensus_killed"]["lost_nodes"]) - {victim})
    verdicts = {
        "clean run bitwise equal to in-process": clean_diff == 0.0,
        "killed node noticed, no live node declared lost": runs["consensus_killed"]["lost_nodes"] == [victim],
        "killed run within 1e-6 of the mean of the remaining data": killed_diff is not None and killed_diff <= 1e-6,
        "async push-sum within 1e-6 of the mean": ps_diff is not None and ps_diff <= 1e-6,
        "every node finished (but the killed one)": not failed,
    }
    results: dict[str, Any] = {
        "nodes": n,
        "links": graph.links.tolist(),
        "max_abs_diff_vs_inprocess": clean_diff,
        "lost_nodes": runs["consensus_killed"]["lost_nodes"],
        "killed_node": victim,
        "max_abs_diff_vs_central_of_remaining": killed_diff,
        "pushsum_max_abs_diff_vs_mean": ps_diff,
        "wire_bytes": int(sum(r["wire_bytes"] for r in runs.values())),
        "false_losses": false_losses,
        "verdicts": verdicts,
        "uwb_hall": "not run: the field runtime has no UWB node program yet (issue 26 item 3)",
        "failed": failed,
        "runs": runs,
        "headline": {
            "consensus clean: max |field - in-process|": clean_diff,
            f"node {victim} killed at round {opts.kill_round}: lost nodes noticed": runs["consensus_killed"][
                "lost_nodes"
            ],
            "killed run: max |x_i - mean of remaining data|": killed_diff,
            "async push-sum (node 0 3x slower): max |x_i - mean|": ps_diff,
            "wire bytes, all runs": int(sum(r["wire_bytes"] for r in runs.values())),
        },
    }
    atomic_write_json(out / "results.json", results)
    return results


def _short(summary: dict[str, Any]) -> dict[str, Any]:
    return {k: summary[k] for k in ("finished", "failed", "seconds", "wire_bytes") if k in summary}


def _print_table(res: dict[str, Any]) -> None:
    runs = res["runs"]
    rows = [
        ("consensus, clean", runs["consensus_clean"], "-", res["max_abs_diff_vs_inprocess"], "in-process run"),
        (
            "consensus, 1 killed",
            runs["consensus_killed"],
            str(res["lost_nodes"]),
            res["max_abs_diff_vs_central_of_remaining"],
            "mean of remaining data",
        ),
        ("push-sum, async", runs["pushsum_async"], "-", res["pushsum_max_abs_diff_vs_mean"], "mean of all data"),
    ]
    print(f"{'run':<22}{'finished':>9}{'lost':>8}{'max |diff|':>12}  {'against':<24}{'wire bytes':>12}{'s':>7}")
    for name, r, lost, diff, ref in rows:
        d = "n/a" if diff is None else f"{diff:.2g}"
        print(
            f"{name:<22}{len(r['finished']):>5}/{res['nodes']:<3}{lost:>8}{d:>12}  {ref:<24}{r['wire_bytes']:>12,}"
            f"{r['seconds']:>7.1f}"
        )
    print(f"UWB hall: {res['uwb_hall']}")
    for text, ok in res["verdicts"].items():
        print(f"  {'ok  ' if ok else 'FAIL'} {text}")


def register(field_sub: Any) -> None:
    """Add ``demo`` to the ``distnav field`` sub-commands."""
    p = field_sub.add_parser("demo", help="launch N node processes on loopback: clean, one killed, asynchronous")
    p.add_argument("--nodes", type=positive_int, default=8, help="node processes per run, 4..64 (default 8)")
    p.add_argument("--rounds", type=positive_int, default=300, help="lock-step consensus rounds (default 300)")
    p.add_argument("--kill-round", type=positive_int, default=20, help="round at which a node is killed (20)")
    p.add_argument("--pushsum-seconds", type=positive_float, default=6.0, help="async run length (default 6 s)")
    p.add_argument(
        "--timeout",
        dest="timeout_s",
        type=positive_float,
        default=300.0,
        help="seconds before a run's nodes are killed",
    )
    p.add_argument("--seed", type=seed, default=0, help="the network and its values (default 0)")
    p.add_argument("--deadline-ms", type=positive_float, default=5000.0, help="killed run's step deadline (5000)")
    p.add_argument("--out", type=output_folder, required=True, help="folder for results.json and every run's files")
    p.set_defaults(func=_handler)


def _handler(args: argparse.Namespace) -> int:
    opts = DemoOptions(**{f.name: getattr(args, f.name) for f in dataclasses.fields(DemoOptions)})
    require_field()
    args.out.mkdir(parents=True, exist_ok=True)
    try:
        res = run_field_demo(opts, args.out)
    except KeyboardInterrupt:  # every run's processes were killed on the way out (launch's finally)
        print("interrupted: the node processes were stopped; no results.json written", file=sys.stderr)
        return 130
    _print_table(res)
    print(f"-> {args.out / 'results.json'}")
    return 0 if all(res["verdicts"].values()) else 1


def require_field() -> None:
    """The field extra (pyzmq, tomli-w) before any process is started."""
    from distnav._optional import require

    require("zmq", "field")
    require("tomli_w", "field")
