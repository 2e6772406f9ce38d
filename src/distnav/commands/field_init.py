"""``distnav field init``: write a field network description (TOML) from what a user has.

* ``--ranges ranges.csv`` — a UWB range log (``a,b,range_m``, :mod:`distnav.formats.uwb.io`): one node per anchor,
  neighbours are the anchors it ranged with (a link when at least ``--min-ranges`` samples of the pair were read);
* ``--rinex FILE ...`` — one RINEX observation file per GNSS station: one node per station, placed at its
  ``APPROX POSITION XYZ``, neighbours are the ``--k`` nearest stations (symmetrised: a link when either picks the
  other);
* ``--simulate codebias|ckf|hall --nodes N`` — a simulated network for ADMM, the CKF or N-CLM
  (:mod:`distnav.commands.field_scenarios`), one ``.npz`` data file per node holding only that node's data
  (:mod:`distnav.formats.field_data`) in ``data-NAME/`` beside the description.

Node ids are ``0..n-1`` in the order of the anchors' ids (numerically when they are numbers) or of the files given;
a comment block at the top of the file names each node. Addresses are ``tcp://127.0.0.1:PORT`` with
``PORT = --base-port + id`` unless ``--hosts`` gives one host for all nodes or one per node. Each node's ``data``
is the file it was made from. A network that is not connected is refused with its components named (consensus
over it cannot reach one answer); an existing output file is never overwritten.
"""

from __future__ import annotations

import argparse
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from distnav.errors import DataFileError, UsageError
from distnav.formats.field_config import NetworkDescription, NodeEntry, format_description
from distnav.network import builders
from distnav.network.graph import Graph
from distnav.options import existing_file, positive_int, seed
from distnav.output import atomic_write_text

__all__ = ["InitPlan", "plan_from_ranges", "plan_from_rinex", "plan_from_simulation", "describe", "register"]

_HOST = re.compile(r"^[A-Za-z0-9]([A-Za-z0-9.\-]*[A-Za-z0-9])?$|^\[[0-9A-Fa-f:]+\]$")


@dataclass(frozen=True, eq=False)
class InitPlan:
    """The network read from the user's files: node names, their links and each node's data file."""

    names: tuple[str, ...]
    graph: Graph
    data: tuple[Path, ...]
    source: str


def _id_order(ids: set[str]) -> list[str]:
    if all(i.lstrip("-").isdigit() for i in ids):
        return sorted(ids, key=int)
    return sorted(ids)


def plan_from_ranges(path: Path, *, min_ranges: int = 1) -> InitPlan:
    """Anchors and who ranges with whom, from a range log (see the module docstring)."""
    from distnav.formats.uwb.io import read_ranges

    log = read_ranges(path)
    if log.range_m.size == 0:
        raise DataFileError(f"{path}: the range log holds no usable range")
    names = _id_order(set(log.a) | set(log.b))
    index = {n: k for k, n in enumerate(names)}
    pairs: dict[tuple[int, int], int] = {}
    for a, b in zip(log.a, log.b, strict=True):
        i, j = sorted((index[a], index[b]))
        pairs[(i, j)] = pairs.get((i, j), 0) + 1
    links = [p for p, count in pairs.items() if count >= min_ranges]
    alone = sorted(set(range(len(names))) - {i for p in links for i in p})
    if alone:
        raise DataFileError(
            f"{path}: anchors {[names[i] for i in alone]} have no partner with at least {min_ranges} range(s)"
        )
    graph = Graph.from_links(len(names), np.asarray(sorted(links), dtype=np.int64).reshape(-1, 2))
    return InitPlan(tuple(names), graph, (path,) * len(names), f"UWB range log {path}")


def plan_from_rinex(paths: list[Path], *, k: int = 3) -> InitPlan:
    """Stations at their approximate positions, each linked to its ``k`` nearest (see the module docstring)."""
    from distnav.formats.gnss.rinex_obs import read_header

    if len(paths) < 2:
        raise UsageError(f"--rinex needs at least 2 station files for a network, got {len(paths)}")
    names, pos = [], []
    for p in paths:
        head = read_header(p)
        if head.file_type.upper() != "O":
            raise DataFileError(f"{p}: not a RINEX observation file (file type {head.file_type!r})")
        if not np.all(np.isfinite(head.position_ecef_m)) or not np.any(head.position_ecef_m):
            raise DataFileError(f"{p}: no APPROX POSITION XYZ in the header: the station cannot be placed")
        names.append((head.marker or p.name[:4]).split()[0].upper()[:9])
        pos.append(head.position_ecef_m)
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        shown = {n: [str(p) for p, m in zip(paths, names, strict=True) if m == n] for n in twice}
        raise DataFileError(f"stations given twice (one file per station): {shown}")
    if not 1 <= k < len(paths):
        raise UsageError(f"--k must be in 1..{len(paths) - 1} for {len(paths)} stations, got {k}")
    graph = builders.k_nearest(np.asarray(pos), k)
    return InitPlan(tuple(names), graph, tuple(paths), f"{len(paths)} RINEX observation files")


def _addresses(n: int, hosts: list[str] | None, base_port: int) -> list[str]:
    if base_port + n - 1 > 65535:
        raise UsageError(f"--base-port {base_port} + {n} nodes passes port 65535")
    if hosts is None:
        hosts = ["127.0.0.1"]
    if len(hosts) not in (1, n):
        raise UsageError(f"--hosts gives {len(hosts)} hosts for {n} nodes: give one for all or one per node")
    return [f"tcp://{hosts[0] if len(hosts) == 1 else hosts[i]}:{base_port + i}" for i in range(n)]


def describe(
    plan: InitPlan,
    *,
    hosts: list[str] | None,
    base_port: int,
    out: Path,
    name: str,
    algorithm: dict[str, Any] | None = None,
) -> str:
    """The TOML text for ``plan`` (a comment block naming the nodes, then the description; ``algorithm`` the
    ``[algorithm]`` table, default the runtime's)."""
    g = plan.graph
    if not g.is_connected:
        comps = _components(g)
        shown = "; ".join(", ".join(plan.names[i] for i in c) for c in comps)
        raise DataFileError(f"{plan.source}: the network is not connected ({len(comps)} parts: {shown})")
    addresses = _addresses(g.n_nodes, hosts, base_port)
    nodes = tuple(
        NodeEntry(id=i, address=addresses[i], neighbours=tuple(int(j) for j in g.neighbors(i)), data=plan.data[i])
        for i in range(g.n_nodes)
    )
    desc = NetworkDescription(nodes=nodes, name=name)
    if algorithm is not None:
        desc = NetworkDescription(nodes=nodes, name=name, algorithm=algorithm)
    text = format_description(desc, relative_to=out.parent)
    head = [
        f"# written by `distnav field init` from {plan.source}",
        "# [algorithm] is the runtime's default: set it for what the nodes should compute with these data files."
        if algorithm is None
        else "# every node's data file holds only that node's data (copy node-ID.npz to node ID's host only)",
        "# node id = name:",
    ]
    head += [f"#   {i} = {n}" for i, n in enumerate(plan.names)]
    return "\n".join(head) + "\n\n" + text


def _components(g: Graph) -> list[list[int]]:
    import scipy.sparse.csgraph as csg

    _, label = csg.connected_components(g.adjacency(), directed=False)
    return [np.flatnonzero(label == c).tolist() for c in range(int(label.max()) + 1)]


def _hosts(text: str) -> list[str]:
    hosts = [h.strip() for h in text.split(",")]
    bad = [h for h in hosts if not _HOST.match(h)]
    if bad:
        raise argparse.ArgumentTypeError(f"not a host name or address: {', '.join(repr(b) for b in bad)}")
    return hosts


def _port(text: str) -> int:
    value = positive_int(text)
    if not 1024 <= value <= 65535:
        raise argparse.ArgumentTypeError(f"must be a port in 1024..65535, got {value}")
    return value


_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.\-]{0,63}")


def _network_name(text: str) -> str:
    """A network's name: an identifier-like word of at most 64 characters (it goes into logs, file comments and
    reports; a 100,000-character or multi-line name was taken before)."""
    if not _NAME.fullmatch(text):
        shown = repr(text) if len(text) <= 40 else f"{text[:40]!r}... ({len(text):,} characters)"
        raise argparse.ArgumentTypeError(
            "must be a non-empty printable name of 1-64 letters, digits, '_', '.' or '-' (starting with a letter or "
            f"digit), got {shown}"
        )
    return text


def _new_file(text: str) -> Path:
    p = Path(text)
    if p.exists():
        raise argparse.ArgumentTypeError(f"{p} exists: field init never overwrites a file (remove it or pick another)")
    if not p.parent.is_dir():
        raise argparse.ArgumentTypeError(f"folder {p.parent} does not exist")
    return p


def register(field_sub: Any) -> None:
    """Add ``init`` to the ``distnav field`` sub-commands."""
    p = field_sub.add_parser("init", help="write a network description (TOML) from a UWB range log or RINEX files")
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--ranges", type=existing_file, help="UWB range log a,b,range_m: who ranges with whom")
    src.add_argument("--rinex", type=existing_file, nargs="+", help="one RINEX observation file per GNSS station")
    src.add_argument(
        "--simulate",
        choices=("codebias", "ckf", "hall"),
        help="a simulated network with one data file per node: ADMM on paper 000's code biases, the CKF of paper "
        "003 §4, or N-CLM on a UWB hall (paper 002); files in DIR/data-NAME/ beside --out",
    )
    p.add_argument("--nodes", type=positive_int, default=8, help="--simulate: nodes (anchors) of the network (8)")
    p.add_argument("--seed", type=seed, default=0, help="--simulate: the simulation's seed (0)")
    p.add_argument("--k", type=positive_int, default=3, help="GNSS: link each station to its k nearest (default 3)")
    p.add_argument("--min-ranges", type=positive_int, default=1, help="UWB: samples a pair needs for a link")
    p.add_argument("--hosts", type=_hosts, help="comma-separated hosts: one for all nodes or one per node")
    p.add_argument("--base-port", type=_port, default=47000, help="node i listens on base port + i (default 47000)")
    p.add_argument("--name", type=_network_name, default="network", help="the network's name in the description")
    p.add_argument("--out", type=_new_file, required=True, help="the description file to write (must not exist)")
    p.set_defaults(func=_handler)


def plan_from_simulation(kind: str, n_nodes: int, seed_value: int, folder: Path) -> tuple[InitPlan, dict[str, Any]]:
    """Simulate a network (:mod:`distnav.commands.field_scenarios`), write one data file per node into ``folder``
    (which must not exist) and return the plan and the ``[algorithm]`` table."""
    from distnav.commands.field_scenarios import SCENARIOS
    from distnav.formats.field_data import write_node_arrays

    if n_nodes < (4 if kind == "hall" else 2):
        raise UsageError(f"--nodes {n_nodes}: a {kind} network needs at least {4 if kind == 'hall' else 2} nodes")
    if folder.exists():
        raise UsageError(f"{folder} exists: field init never overwrites (remove it or pick another --out)")
    sc = SCENARIOS[kind](n_nodes, seed_value)
    paths = tuple(folder / f"node-{i}.npz" for i in range(n_nodes))
    for i, path in enumerate(paths):
        write_node_arrays(path, sc.kind, i, n_nodes, sc.node_arrays(i))
    names = tuple(sc.graph.names) if sc.graph.names is not None else tuple(str(i) for i in range(n_nodes))
    return InitPlan(names, sc.graph, paths, f"a simulated {kind} network of {n_nodes} nodes (seed {seed_value})"), {
        **sc.algorithm
    }


def _handler(args: argparse.Namespace) -> int:
    algorithm = None
    if args.ranges is not None:
        plan = plan_from_ranges(args.ranges, min_ranges=args.min_ranges)
    elif args.rinex is not None:
        plan = plan_from_rinex(list(args.rinex), k=args.k)
    else:
        folder = args.out.parent / f"data-{args.out.stem}"
        plan, algorithm = plan_from_simulation(args.simulate, args.nodes, args.seed, folder)
    text = describe(plan, hosts=args.hosts, base_port=args.base_port, out=args.out, name=args.name, algorithm=algorithm)
    if args.out.exists():  # made while we read the inputs
        raise UsageError(f"{args.out} exists: field init never overwrites a file")
    atomic_write_text(args.out, text)
    print(f"wrote {args.out}: {plan.graph.n_nodes} nodes, {len(plan.graph.links)} links from {plan.source}")
    return 0
