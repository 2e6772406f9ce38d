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
   (``distnav field pushsum-node``); reference: numpy's mean → ``pushsum_max_abs_diff_vs_mean``;
4. **UWB network, clean** — ``N`` anchors of paper 002's problem RC (2-D, 3 known anchors), one process each
   (``distnav field demo-uwb-node``), N-CSG-TBLS over the field exchange; reference: the same solve in-process →
   ``uwb_max_abs_diff_vs_inprocess_m``. Every process rebuilds the simulated problem from its seed; the solver reads
   only its own node's rows (as under MPI) and learns the rest from messages.

5. **UWB hall, one anchor killed** — ``max(N, 6)`` anchors of a well-connected simulated hall
   (:func:`~distnav.commands.field_scenarios.hall_scenario`, every pair within 40 m measured), each ``distnav node``
   holding only its own ranges, N-CLM with the metres objective; the highest free anchor whose loss keeps the rest
   connected exits at step 20, the others agree on it and solve again on their own data
   (:mod:`distnav.commands.field_uwb`); reference: LM on the remaining data (the dead anchor's ranges dropped) →
   ``uwb_killed_lost_nodes`` and ``uwb_killed_max_abs_diff_vs_central_of_remaining_m``.

``DIR/results.json`` holds those numbers, ``wire_bytes`` (real bytes sent on the wire by all runs), ``vs_gather``
(per run, its wire bytes beside what gathering the nodes' data at one node by multi-hop relaying would cost:
:func:`~distnav.algorithms.result.compare_with_gather`, also printed), ``verdicts`` and each run's summary. Each
run's folder keeps the description, the nodes' results and logs. Every process is bounded by ``--timeout`` and
killed (process group) on failure or Ctrl-C. ``distnav demo --out D`` adds a section for ``D/field/results.json``
to its report when that file exists.
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
from typing import TYPE_CHECKING, Any

import numpy as np

from distnav.commands.field_async import add_node_program, open_node
from distnav.commands.field_processes import (
    LoopbackOptions,
    kill_group,
    removable_node,
    wire_bytes_by_kind,
    write_loopback_network,
)
from distnav.errors import UsageError
from distnav.network import builders
from distnav.network.graph import Graph
from distnav.options import output_folder, positive_float, positive_int, seed
from distnav.output import atomic_write_json

if TYPE_CHECKING:
    from distnav.algorithms.result import CommComparison

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
    uwb_iterations : N-CSG-TBLS iterations of the UWB run.
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
    uwb_iterations: int = 30

    def __post_init__(self) -> None:
        if self.nodes < 4:
            raise UsageError(
                f"--nodes must be at least 4 (one is killed, the rest must stay a network), got {self.nodes}"
            )
        if self.nodes > 64:
            raise UsageError(f"--nodes at most 64 on one machine, got {self.nodes}")
        if not 1 <= self.kill_round < self.rounds:
            raise UsageError(f"--kill-round must be in 1..{self.rounds - 1} (below --rounds), got {self.kill_round}")


def launch_async(
    desc_path: Path, out_dir: Path, *, periods_ms: list[float], duration_s: float, timeout_s: float
) -> dict[str, Any]:
    """Start one ``distnav field pushsum-node`` process per node (node ``i`` ticking every ``periods_ms[i]``),
    bounded by ``timeout_s``, and collect their ``node-ID.json``."""
    commands = [["field", "pushsum-node", "--period-ms", str(p), "--duration-s", str(duration_s)] for p in periods_ms]
    return _launch_nodes(desc_path, out_dir, commands, timeout_s)


def _uwb_problem(n: int, seed: int) -> Any:
    """The demo's UWB network: paper 002 problem RC (random anchors, 3 known), ``n`` anchors in 2-D, seeded."""
    from distnav.models.uwb.problems import generate_problem

    return generate_problem("RC", np.random.default_rng([seed, 2002]), n_anchors=n, dim=2)


def _solve_uwb(problem: Any, iterations: int, backend: str) -> np.ndarray:
    """N-CSG-TBLS (paper 002) on ``backend``: every node's position estimate (metres)."""
    from distnav.algorithms.ranging.csg import solve_ncsg
    from distnav.exchange import make_exchange

    res = solve_ncsg(
        problem, line_search="TBLS", iterations=iterations, exchange=make_exchange(problem.graph, backend=backend)
    )
    return np.asarray(res.estimates, dtype=float)


def _uwb_node(args: argparse.Namespace) -> int:
    """One anchor of the demo's UWB network as its own process: the solver's node code over the field exchange.

    The simulated problem is rebuilt from its seed in every process; the solver reads only this node's rows through
    the exchange (as under MPI), and everything else it learns arrives in messages."""
    from distnav.commands.field_node import load_keys
    from distnav.exchange.field import Transport
    from distnav.exchange.field.session import field_session
    from distnav.exchange.field.startup import StartCheck, handshake

    desc = open_node(args)
    problem = _uwb_problem(desc.n_nodes, args.seed)
    entry = desc.node(args.id)
    transport = Transport(
        args.id,
        entry.address,
        desc.peers(args.id, everyone=True),
        options=desc.transport_options(),
        keys=load_keys(desc, args.id),
    )
    try:
        depth = min(1, desc.n_nodes - 1)  # every node greets every other: all within one hop
        missing = handshake(transport, check=StartCheck(desc.fingerprint(), 0, depth)).missing
        t0 = time.monotonic()
        with field_session(args.id, transport):
            est = _solve_uwb(problem, args.iterations, "field")
        atomic_write_json(
            args.out / f"node-{args.id}.json",
            {
                "node": args.id,
                "algorithm": "N-CSG-TBLS",
                "estimate": est[args.id],
                "all_estimates": est,
                "seconds": time.monotonic() - t0,
                "missing_at_start": missing,
                "wire": transport.wire_counts(),
                "wire_bytes_by_kind": transport.bytes_by_kind(),
                "refused": transport.refusal_counts(),
                "lost_nodes": {str(k): v for k, v in transport.lost.items()},
            },
        )
    finally:
        transport.close()
    return 0


def _launch_nodes(desc_path: Path, out_dir: Path, commands: list[list[str]], timeout_s: float) -> dict[str, Any]:
    """Start one process per ``commands[i]`` (``distnav`` arguments for node ``i``), wait at most ``timeout_s`` (then
    kill the rest, process group and all) and collect their ``node-ID.json``."""
    out_dir.mkdir(parents=True, exist_ok=True)
    env = dict(os.environ)
    src = str(Path(__file__).resolve().parents[2])
    env["PYTHONPATH"] = src + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    procs: list[subprocess.Popen[bytes]] = []
    t0 = time.monotonic()
    codes: list[int | None] = []
    try:
        for i, args in enumerate(commands):
            cmd = [
                sys.executable,
                "-m",
                "distnav",
                *args,
                "--config",
                str(desc_path),
                "--id",
                str(i),
                "--out",
                str(out_dir),
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
                kill_group(p)
    nodes = {str(i): json.loads((out_dir / f"node-{i}.json").read_text()) for i, c in enumerate(codes) if c == 0}
    return {
        "finished": [i for i, c in enumerate(codes) if c == 0],
        "failed": [{"node": i, "exit_code": c, "timed_out": c is None} for i, c in enumerate(codes) if c != 0],
        "seconds": time.monotonic() - t0,
        "wire_bytes": int(sum(r["wire"]["bytes_sent"] for r in nodes.values())),
        "wire_bytes_by_kind": wire_bytes_by_kind(nodes),
        "nodes": nodes,
    }


def _estimates(summary: dict[str, Any], ids: list[int]) -> np.ndarray:
    return np.array([summary["nodes"][str(i)]["estimate"] for i in ids], dtype=float).reshape(len(ids), -1)


def run_field_demo(opts: DemoOptions, out: Path) -> dict[str, Any]:
    """The runs of the module docstring; writes and returns ``out/results.json``'s content."""
    rng = np.random.default_rng(opts.seed)
    graph = builders.connected_random_geometric(opts.nodes, mean_degree=min(4, opts.nodes - 1), rng=rng)
    values = rng.normal(10.0, 3.0, size=(opts.nodes, 2))
    runs: dict[str, Any] = {
        "consensus_clean": _clean_run(opts, graph, values, out),
        "consensus_killed": _killed_run(opts, graph, values, out),
        "pushsum_async": _pushsum_run(opts, graph, values, out),
        "uwb_clean": _uwb_run(opts, out),
        "uwb_killed": _uwb_killed_run(opts, out),
    }
    clean_diff = runs["consensus_clean"]["max_abs_diff_vs_inprocess"]
    killed = runs["consensus_killed"]
    killed_diff, victim = killed["max_abs_diff_vs_central_of_remaining"], killed["killed_node"]
    ps_diff = runs["pushsum_async"]["max_abs_diff_vs_mean"]
    uwb_diff = runs["uwb_clean"]["max_abs_diff_vs_inprocess_m"]
    uwb_killed = runs["uwb_killed"]
    uwb_killed_diff = uwb_killed["max_abs_diff_vs_central_of_remaining_m"]
    failed = {k: r["failed"] for k, r in runs.items() if r["failed"]}
    verdicts = {
        "clean run bitwise equal to in-process": clean_diff == 0.0,
        "killed node noticed, no live node declared lost": killed["lost_nodes"] == [victim],
        "killed run within 1e-6 of the mean of the remaining data": killed_diff is not None and killed_diff <= 1e-6,
        "async push-sum within 1e-6 of the mean": ps_diff is not None and ps_diff <= 1e-6,
        "UWB network (N-CSG-TBLS) bitwise equal to in-process": uwb_diff == 0.0,
        "UWB anchor killed: noticed at every remaining anchor": uwb_killed["lost_nodes"] == [uwb_killed["killed_node"]],
        "UWB anchor killed: within 1 mm of LM on the remaining data": uwb_killed_diff is not None
        and uwb_killed_diff <= 1e-3,
        "every node finished (but the killed one)": not failed,
    }
    wire = int(sum(r["wire_bytes"] for r in runs.values()))
    vs_gather = _versus_gather(runs, graph, values, _uwb_problem(opts.nodes, opts.seed))
    vs_gather["uwb_killed"] = _gather_of(uwb_killed, _uwb_hall(opts).ranging)
    results: dict[str, Any] = {
        "nodes": opts.nodes,
        "links": graph.links.tolist(),
        "max_abs_diff_vs_inprocess": clean_diff,
        "lost_nodes": killed["lost_nodes"],
        "killed_node": victim,
        "max_abs_diff_vs_central_of_remaining": killed_diff,
        "pushsum_max_abs_diff_vs_mean": ps_diff,
        "uwb_max_abs_diff_vs_inprocess_m": uwb_diff,
        "uwb_killed_node": uwb_killed["killed_node"],
        "uwb_killed_lost_nodes": uwb_killed["lost_nodes"],
        "uwb_killed_max_abs_diff_vs_central_of_remaining_m": uwb_killed_diff,
        "wire_bytes": wire,
        "vs_gather": {k: c.as_dict() for k, c in vs_gather.items()},
        "false_losses": sorted(set(killed["lost_nodes"]) - {victim}),
        "verdicts": verdicts,
        "failed": failed,
        "runs": runs,
        "headline": {
            "consensus clean: max |field - in-process|": clean_diff,
            f"node {victim} killed at round {opts.kill_round}: lost nodes noticed": killed["lost_nodes"],
            "killed run: max |x_i - mean of remaining data|": killed_diff,
            "async push-sum (node 0 3x slower): max |x_i - mean|": ps_diff,
            "UWB network, N-CSG-TBLS: max |field - in-process| (m)": uwb_diff,
            f"UWB hall, anchor {uwb_killed['killed_node']} killed at step 20: lost nodes named": uwb_killed[
                "lost_nodes"
            ],
            "UWB hall, anchor killed: max |field - LM of remaining data| (m)": uwb_killed_diff,
            "wire bytes, all runs": wire,
            **{f"{k}: wire bytes ÷ gathering the data at one node": c.ratio_bytes for k, c in vs_gather.items()},
        },
    }
    atomic_write_json(out / "results.json", results)
    return results


def _clean_run(opts: DemoOptions, graph: Graph, values: np.ndarray, out: Path) -> dict[str, Any]:
    """Lock-step MH consensus on node processes; reference: the same rounds in-process."""
    from distnav.algorithms.consensus.averaging import iterate_average_consensus
    from distnav.commands.field import launch
    from distnav.formats.field_config import read_description

    algo = {"name": "consensus", "rounds": opts.rounds, "protocol": "MH", "patience": 5}
    folder = out / "consensus_clean"
    net = write_loopback_network(
        folder, graph.links, values, LoopbackOptions(name="demo-clean", algorithm=algo, deadline_ms=20000)
    )
    run = launch(net, folder, timeout_s=opts.timeout_s, quiet=True)
    ref = values
    for state in iterate_average_consensus(
        values, graph=read_description(net).graph(), protocol="MH", rounds=opts.rounds
    ):
        ref = state.values
    ok = run["finished"]
    diff = float(np.abs(_estimates(run, ok) - ref[ok]).max()) if ok else None
    return {**_short(run), "max_abs_diff_vs_inprocess": diff}


def _killed_run(opts: DemoOptions, graph: Graph, values: np.ndarray, out: Path) -> dict[str, Any]:
    """Flow consensus with one node exiting at ``kill_round``; reference: numpy's mean of the others' data."""
    from distnav.commands.field import launch

    victim = removable_node(graph)
    algo = {"name": "consensus_flows", "rounds": opts.rounds, "protocol": "MH", "patience": 5}
    folder = out / "consensus_killed"
    killed = LoopbackOptions(
        name="demo-killed", algorithm=algo, crash={victim: opts.kill_round}, deadline_ms=opts.deadline_ms
    )
    net = write_loopback_network(folder, graph.links, values, killed)
    run = launch(net, folder, timeout_s=opts.timeout_s, quiet=True)
    keep = np.arange(opts.nodes) != victim
    ok = run["finished"]
    diff = float(np.abs(_estimates(run, ok) - values[keep].mean(axis=0)).max()) if ok else None
    return {
        **_short(run),
        "killed_node": victim,
        "killed_at_round": opts.kill_round,
        "lost_nodes": run.get("lost_nodes", []),
        "max_abs_diff_vs_central_of_remaining": diff,
    }


def _pushsum_run(opts: DemoOptions, graph: Graph, values: np.ndarray, out: Path) -> dict[str, Any]:
    """Asynchronous push-sum, node 0 ticking every 30 ms and the others every 10 ms; reference: numpy's mean."""
    folder = out / "pushsum_async"
    net = write_loopback_network(folder, graph.links, values, LoopbackOptions(name="demo-pushsum"))
    periods = [30.0] + [10.0] * (opts.nodes - 1)
    run = launch_async(net, folder, periods_ms=periods, duration_s=opts.pushsum_seconds, timeout_s=opts.timeout_s)
    ok = run["finished"]
    diff = float(np.abs(_estimates(run, ok) - values.mean(axis=0)).max()) if ok else None
    ticks = [run["nodes"][str(i)]["ticks"] for i in ok]
    return {**_short(run), "periods_ms": periods, "ticks": ticks, "max_abs_diff_vs_mean": diff}


def _uwb_run(opts: DemoOptions, out: Path) -> dict[str, Any]:
    """N anchors of a UWB network (paper 002 problem RC), one process each, N-CSG-TBLS over the field exchange;
    reference: the same solve in-process."""
    problem = _uwb_problem(opts.nodes, opts.seed)
    folder = out / "uwb_clean"
    uwb = LoopbackOptions(name="demo-uwb", deadline_ms=60000)
    net = write_loopback_network(folder, problem.graph.links, np.zeros((opts.nodes, 1)), uwb)
    cmd = ["field", "demo-uwb-node", "--seed", str(opts.seed), "--iterations", str(opts.uwb_iterations)]
    run = _launch_nodes(net, folder, [cmd] * opts.nodes, opts.timeout_s)
    ref = _solve_uwb(problem, opts.uwb_iterations, "inprocess")
    ok = run["finished"]
    diff = float(np.abs(_estimates(run, ok) - ref[ok]).max()) if ok else None
    return {
        **_short(run),
        "anchors": opts.nodes,
        "iterations": opts.uwb_iterations,
        "max_abs_diff_vs_inprocess_m": diff,
    }


_WELL_CONNECTED = {"link_loss": 0.0, "range_limit_m": 40.0}


def _uwb_hall(opts: DemoOptions) -> Any:
    from distnav.commands.field_scenarios import hall_scenario

    n = max(opts.nodes, 6)  # 4 known corner anchors and at least 2 free ones
    return hall_scenario(n, opts.seed, iterations=300, objective="metres", hall=_WELL_CONNECTED)


def _uwb_killed_run(opts: DemoOptions, out: Path) -> dict[str, Any]:
    """A UWB hall on ``distnav node`` processes, one free anchor exiting at step 20 (module docstring); reference:
    LM on the remaining data."""
    from distnav.algorithms.ranging.csg import solve
    from distnav.commands.field import launch
    from distnav.commands.field_scenarios import remaining_data, write_scenario

    sc = _uwb_hall(opts)
    problem = sc.ranging
    victim = removable_node(problem.graph, skip=set(np.flatnonzero(problem.fixed).tolist()))
    folder = out / "uwb_killed"
    options = LoopbackOptions(name="demo-uwb-killed", deadline_ms=opts.deadline_ms, crash={victim: 20})
    run = launch(write_scenario(folder, sc, options), folder, timeout_s=opts.timeout_s, quiet=True)
    rest = [i for i in range(problem.n_anchors) if i != victim]
    lm = solve(remaining_data(problem, victim), "LM", iterations=500, objective="metres").estimates
    ok = run["finished"]
    diff = None
    if ok and set(ok) <= set(rest):
        diff = float(np.abs(_estimates(run, ok) - lm[[rest.index(i) for i in ok]]).max())
    return {
        **_short(run),
        "anchors": problem.n_anchors,
        "killed_node": victim,
        "lost_nodes": run.get("lost_nodes", []),
        "statuses": sorted({r["status"] for r in run["nodes"].values()}),
        "max_abs_diff_vs_central_of_remaining_m": diff,
    }


def _gather_of(run: dict[str, Any], problem: Any) -> CommComparison:
    """The killed UWB run's wire bytes beside gathering every anchor's range samples at one anchor."""
    from distnav.algorithms.result import compare_with_gather

    per_anchor = 8 * np.bincount(problem.meas_a, minlength=problem.n_anchors)
    what = "the anchor's range samples (float64)"
    return compare_with_gather((run["wire_bytes"], run["wire_frames"]), problem.graph, per_anchor, data=what)


def _short(summary: dict[str, Any]) -> dict[str, Any]:
    out: dict[str, Any] = {
        k: summary[k] for k in ("finished", "failed", "seconds", "wire_bytes", "wire_bytes_by_kind") if k in summary
    }
    out["wire_frames"] = int(sum(r["wire"]["frames_sent"] for r in summary.get("nodes", {}).values()))
    return out


def _versus_gather(runs: dict[str, Any], graph: Graph, values: np.ndarray, uwb: Any) -> dict[str, CommComparison]:
    """Each run's real wire bytes beside what gathering its data at one node by multi-hop relaying would cost
    (:func:`~distnav.algorithms.result.compare_with_gather`): consensus nodes hold their values (float64), UWB
    anchors the ranges they logged first (one float64 per sample, each sample once)."""
    from distnav.algorithms.result import compare_with_gather

    per_node = np.full(graph.n_nodes, 8 * values.shape[1])
    uwb_bytes = 8 * np.bincount(uwb.meas_a, minlength=uwb.n_anchors)
    data = {
        "consensus_clean": (graph, per_node, "the node's values (float64)"),
        "consensus_killed": (graph, per_node, "the node's values (float64)"),
        "pushsum_async": (graph, per_node, "the node's values (float64)"),
        "uwb_clean": (uwb.graph, uwb_bytes, "the anchor's range samples (float64)"),
    }
    return {
        name: compare_with_gather((runs[name]["wire_bytes"], runs[name]["wire_frames"]), g, b, data=what)
        for name, (g, b, what) in data.items()
        if name in runs
    }


#: The printed table's rows: (label, run, key of the lost nodes or None, key of the max |diff|, what it is against).
_TABLE_ROWS = (
    ("consensus, clean", "consensus_clean", None, "max_abs_diff_vs_inprocess", "in-process run"),
    (
        "consensus, 1 killed",
        "consensus_killed",
        "lost_nodes",
        "max_abs_diff_vs_central_of_remaining",
        "mean of remaining data",
    ),
    ("push-sum, async", "pushsum_async", None, "pushsum_max_abs_diff_vs_mean", "mean of all data"),
    ("UWB N-CSG-TBLS, clean", "uwb_clean", None, "uwb_max_abs_diff_vs_inprocess_m", "in-process run (m)"),
    (
        "UWB N-CLM, 1 killed",
        "uwb_killed",
        "uwb_killed_lost_nodes",
        "uwb_killed_max_abs_diff_vs_central_of_remaining_m",
        "LM of remaining data (m)",
    ),
)


def _print_table(res: dict[str, Any]) -> None:
    print(f"{'run':<22}{'finished':>9}{'lost':>8}{'max |diff|':>12}  {'against':<24}{'wire bytes':>12}{'s':>7}")
    for name, run, lost_key, diff_key, ref in _TABLE_ROWS:
        r, diff = res["runs"][run], res[diff_key]
        lost = "-" if lost_key is None else str(res[lost_key])
        d = "n/a" if diff is None else f"{diff:.2g}"
        print(
            f"{name:<22}{len(r['finished']):>5}/{r.get('anchors', res['nodes']):<3}{lost:>8}{d:>12}  {ref:<24}"
            f"{r['wire_bytes']:>12,}{r['seconds']:>7.1f}"
        )
    for name, c in res["vs_gather"].items():
        print(f"  {name}: {c['line']}")
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
    p.add_argument("--uwb-iterations", type=positive_int, default=30, help="N-CSG-TBLS iterations (default 30)")
    p.add_argument("--deadline-ms", type=positive_float, default=5000.0, help="killed run's step deadline (5000)")
    p.add_argument("--out", type=output_folder, required=True, help="folder for results.json and every run's files")
    p.set_defaults(func=_handler)
    uwb_options = [
        ("--seed", seed, 0, "the simulated network's seed (as field demo's)"),
        ("--iterations", positive_int, 30, "N-CSG-TBLS iterations"),
    ]
    add_node_program(field_sub, "demo-uwb-node", "one anchor of field demo's UWB network", _uwb_node, uwb_options)


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
