"""``distnav node`` and ``distnav field launch|keys``: run a field network (every node its own program).

* ``distnav node --config NET --id ID --out DIR`` — one node (:mod:`distnav.commands.field_node`);
* ``distnav field launch --config NET --out DIR`` — every node of NET on this machine as separate processes,
  bounded in time; collects the nodes' results into ``DIR/results.json`` and their logs;
* ``distnav field keys --config NET --out DIR`` — a CURVE key pair per node (secret keys in ``DIR/keys/``, mode
  0600) and ``DIR/network.toml``: the description with ``security = "curve"`` and the keys filled in.

docs/field.md describes the description file, the wire format and how to run nodes on separate hosts.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from distnav._optional import require
from distnav.commands.field_processes import kill_group, setup_node_log, wire_bytes_by_kind
from distnav.errors import UsageError
from distnav.formats.field_config import NetworkDescription, format_description, read_description
from distnav.options import existing_file, node_output_files, nonnegative_int, output_folder, positive_float
from distnav.output import atomic_write_json, atomic_write_text

__all__ = ["register", "launch"]


def register(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    node = sub.add_parser("node", help="run one node of a field network (its own program)")
    node.add_argument("--config", type=existing_file, required=True, help="the network description (TOML)")
    node.add_argument("--id", type=nonnegative_int, required=True, help="this node's id in the description")
    node.add_argument("--out", type=output_folder, required=True, help="folder for node-ID.json and node-ID.log")
    node.add_argument(
        "--rejoin", action="store_true", help="a restarted node: join the running network at its neighbours' step"
    )
    node.set_defaults(func=_node, node_files=node_output_files)

    field = sub.add_parser("field", help="field networks: launch every node on this machine, make keys")
    fsub = field.add_subparsers(dest="field_command", required=True)
    la = fsub.add_parser("launch", help="start every node of a description as its own process and collect results")
    la.add_argument("--config", type=existing_file, required=True, help="the network description (TOML)")
    la.add_argument("--out", type=output_folder, required=True, help="folder for results.json and the nodes' files")
    la.add_argument(
        "--timeout", type=positive_float, default=300.0, help="seconds after which remaining nodes are killed (300)"
    )
    la.set_defaults(func=_launch)
    keys = fsub.add_parser("keys", help="make a CURVE key pair per node and a description that uses them")
    keys.add_argument("--config", type=existing_file, required=True, help="the network description (TOML)")
    keys.add_argument(
        "--out",
        type=output_folder,
        required=True,
        help="folder for network.toml (the description using the keys) and keys/",
    )
    keys.set_defaults(func=_keys)
    # registered here by the asynchronous mode and the demo when present (distnav.commands.field_*)
    for name in ("field_init", "field_demo", "field_async"):
        try:
            mod = __import__(f"distnav.commands.{name}", fromlist=["register"])
        except ModuleNotFoundError:
            continue
        mod.register(fsub)


def _description(path: Path) -> NetworkDescription:
    return read_description(path)


def _node(args: argparse.Namespace) -> int:
    from distnav.commands.field_node import check_node_id, run_node

    desc = _description(args.config)
    check_node_id(desc, args.id)
    setup_node_log(args.out, args.id)
    return run_node(desc, args.id, args.out, rejoin=args.rejoin)


def launch(desc_path: Path, out_dir: Path, *, timeout_s: float = 300.0, quiet: bool = False) -> dict[str, Any]:
    """Start every node of the description at ``desc_path`` as its own process (``python -m distnav node``),
    wait at most ``timeout_s`` (then kill the rest, process group and all), and collect ``DIR/results.json``."""
    desc = _description(desc_path)
    out_dir.mkdir(parents=True, exist_ok=True)
    procs: dict[int, subprocess.Popen[bytes]] = {}
    from distnav.commands.field_node import CRASH_EXIT

    env = dict(os.environ)
    src = str(Path(__file__).resolve().parents[2])  # the distnav this process runs, first on the children's path
    env["PYTHONPATH"] = src + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    t0 = time.monotonic()

    def start(node_id: int, *extra: str) -> subprocess.Popen[bytes]:
        cmd = [sys.executable, "-m", "distnav", "node", "--config", str(desc_path), "--id", str(node_id)]
        with open(out_dir / f"node-{node_id}.stderr", "ab") as err:
            return subprocess.Popen(
                [*cmd, "--out", str(out_dir), *extra],
                stdout=subprocess.DEVNULL,
                stderr=err,
                env=env,
                start_new_session=True,
            )

    codes: dict[int, int | None] = {}
    rejoined: list[int] = []
    restart_at: dict[int, float] = {}
    previous = _terminate_as_interrupt()
    try:
        for n in desc.nodes:  # one at a time: a Ctrl-C between two starts leaves the started ones to the finally
            procs[n.id] = start(n.id)
        while len(codes) < len(procs) and time.monotonic() - t0 < timeout_s:
            for node_id, p in procs.items():
                if node_id in codes or p.poll() is None:
                    continue
                if p.returncode == CRASH_EXIT and node_id in desc.restart_after_s and node_id not in rejoined:
                    restart_at.setdefault(node_id, time.monotonic() + desc.restart_after_s[node_id])
                    if time.monotonic() >= restart_at[node_id]:  # the crashed node comes back and rejoins
                        procs[node_id] = start(node_id, "--rejoin")
                        rejoined.append(node_id)
                    continue
                codes[node_id] = p.returncode
            time.sleep(0.05)
        codes.update({i: None for i in procs if i not in codes})  # still running at the timeout
    finally:
        for p in procs.values():
            if p.poll() is None:
                kill_group(p)
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)
    elapsed = time.monotonic() - t0
    return _collect(desc, out_dir, codes, elapsed, quiet=quiet, rejoined=rejoined)


def _terminate_as_interrupt() -> Any:
    """SIGTERM (``kill``, a batch system's stop) raises KeyboardInterrupt as Ctrl-C does, so that :func:`launch`
    kills its node processes on the way out (their own sessions: without this they outlived a terminated launcher);
    returns the previous handler (None off the main thread, where no handler can be set)."""
    if threading.current_thread() is not threading.main_thread():
        return None

    def interrupt(signum: int, frame: Any) -> None:
        raise KeyboardInterrupt(f"signal {signum}")

    return signal.signal(signal.SIGTERM, interrupt)


def _collect(
    desc: NetworkDescription,
    out_dir: Path,
    codes: dict[int, int | None],
    elapsed: float,
    *,
    quiet: bool,
    rejoined: list[int],
) -> dict[str, Any]:
    import json

    from distnav.commands.field_node import CRASH_EXIT, STOPPED_EXIT, node_values

    nodes: dict[str, Any] = {}
    finished, crashed, failed, stopped = [], [], [], []
    for node_id, code in sorted(codes.items()):
        f = out_dir / f"node-{node_id}.json"
        if code == 0 and f.exists():
            nodes[str(node_id)] = json.loads(f.read_text(encoding="utf-8"))
            finished.append(node_id)
        elif code == STOPPED_EXIT and f.exists():  # ended on purpose without an answer, its reason in its file
            nodes[str(node_id)] = json.loads(f.read_text(encoding="utf-8"))
            stopped.append(node_id)
        elif code == CRASH_EXIT and node_id in desc.crash:
            crashed.append(node_id)
        else:
            failed.append({"node": node_id, "exit_code": code, "timed_out": code is None})
    summary: dict[str, Any] = {
        "network": desc.name,
        "algorithm": desc.algorithm,
        "n_nodes": desc.n_nodes,
        "finished": finished,
        "crashed_on_purpose": crashed,
        "stopped": stopped,
        "rejoined": rejoined,
        "failed": failed,
        "seconds": elapsed,
        "wire_bytes": int(sum(r["wire"]["bytes_sent"] for r in nodes.values())),
        "wire_bytes_by_kind": wire_bytes_by_kind(nodes),
        "refused": int(sum(sum(r["refused"].values()) for r in nodes.values())),
    }
    consensus = desc.algorithm["name"] in ("consensus", "consensus_flows")
    if nodes:
        summary["lost_nodes"] = sorted({int(k) for r in nodes.values() for k in r["lost_nodes"]})
        summary["rounds_per_second_min"] = min(r["rounds_per_second"] or 0.0 for r in nodes.values())
    if finished and consensus:
        est = np.array([nodes[str(i)]["estimate"] for i in finished])
        data = np.array([node_values(desc, i) for i in range(desc.n_nodes) if i not in crashed])
        summary["central_mean_of_remaining"] = data.mean(axis=0)
        summary["max_abs_diff_vs_central_of_remaining"] = float(np.abs(est - data.mean(axis=0)).max())
    if nodes:
        summary["vs_gather"] = _versus_gather(desc, nodes)
    summary["nodes"] = nodes
    atomic_write_json(out_dir / "results.json", summary)
    if not quiet:
        print(
            f"{desc.name}: {len(finished)} of {desc.n_nodes} nodes finished in {elapsed:.1f} s"
            + (f", {len(crashed)} crashed on purpose {crashed}" if crashed else "")
            + (f", {len(failed)} FAILED {[f['node'] for f in failed]}" if failed else "")
            + (f", {len(stopped)} stopped without an answer {stopped}" if stopped else "")
        )
        if stopped:
            print(f"  node {stopped[0]}: {nodes[str(stopped[0])]['message']}")
        if finished:
            central = (
                f"max |x_i - mean of remaining data| = {summary['max_abs_diff_vs_central_of_remaining']:.3g}; "
                if consensus
                else f"status of node {finished[0]}: {nodes[str(finished[0])]['status']}; "
            )
            print(
                f"  lost nodes noticed: {summary['lost_nodes']}; {central}wire bytes {summary['wire_bytes']:,}; "
                f"refused messages {summary['refused']}"
            )
        if "vs_gather" in summary:
            print(f"  {summary['vs_gather']['line']}")
        print(f"  -> {out_dir / 'results.json'}")
    return summary


def _versus_gather(desc: NetworkDescription, nodes: dict[str, Any]) -> dict[str, Any]:
    """The run's real wire bytes and frames beside gathering every node's data file at one node over the same graph
    (:func:`~distnav.algorithms.result.compare_with_gather`; a node without a data file counts 0 bytes)."""
    from distnav.algorithms.result import compare_with_gather

    files = [desc.node(i).data for i in range(desc.n_nodes)]
    sizes = [f.stat().st_size if f is not None and f.exists() else 0 for f in files]
    sent = (
        int(sum(r["wire"]["bytes_sent"] for r in nodes.values())),
        int(sum(r["wire"]["frames_sent"] for r in nodes.values())),
    )
    return compare_with_gather(sent, desc.graph(), sizes, data="each node's data file").as_dict()


def _launch(args: argparse.Namespace) -> int:
    try:
        summary = launch(args.config, args.out, timeout_s=args.timeout)
    except KeyboardInterrupt:  # Ctrl-C or SIGTERM: launch has killed every node process on the way out
        print("interrupted: every node process stopped; no results.json", file=sys.stderr)
        return 130
    return 1 if summary["failed"] else 3 if summary["stopped"] else 0


def _keys(args: argparse.Namespace) -> int:
    desc = _description(args.config)
    out_dir: Path = args.out
    out, key_dir = out_dir / "network.toml", out_dir / "keys"
    if out.resolve() == Path(args.config).resolve():
        raise UsageError(f"--out {out_dir}: would overwrite the input description {out}")
    for existing in (out, key_dir):
        if existing.exists():
            raise UsageError(f"--out {out_dir}: {existing} exists; choose a new folder (keys are never overwritten)")
    auth = require("zmq.auth", "field")
    out_dir.mkdir(parents=True, exist_ok=True)
    key_dir.mkdir(mode=0o700)
    nodes = []
    for n in desc.nodes:
        public_file, secret_file = auth.create_certificates(str(key_dir), f"node-{n.id}")
        os.chmod(secret_file, 0o600)
        public, _ = auth.load_certificate(public_file)
        data = None if n.data is None else n.data.resolve()  # the data stay where they are
        nodes.append(dataclasses.replace(n, public_key=public.decode(), secret_key=Path(secret_file), data=data))
    new = dataclasses.replace(desc, nodes=tuple(nodes), security="curve")
    atomic_write_text(out, format_description(new, relative_to=out_dir))
    print(
        f"{len(nodes)} key pairs in {key_dir} (secret keys mode 0600: copy each to its node's host only); "
        f'description with security = "curve" -> {out}'
    )
    return 0
