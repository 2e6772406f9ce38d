"""The field runtime's network description (TOML): nodes, addresses, neighbours, data files, keys, the algorithm.

Read with :func:`read_description` (every rule checked once, errors name the file, the node and the key), written
with :func:`format_description` (a string; the command writes it atomically). The format, version 1::

    version = 1

    [network]
    name = "ring-8"
    security = "none"          # or "curve": every node lists public_key, and its own host has secret_key
    deadline_ms = 2000         # a message later than this within a step is lost
    miss_limit = 3             # steps without a message after which a neighbour is declared lost
    start_timeout_s = 60       # how long a node waits for its neighbours at start-up

    [algorithm]
    name = "consensus"         # or "consensus_flows" (survives dead nodes): the average of the data files
    rounds = 200
    protocol = "MH"            # consensus weights (P1..P4, MH)
    patience = 20              # consensus_flows: rounds of silence after which a neighbour's flow is dropped
    # name = "admm": rho = 1.0, max_iterations = 1000, tol = 1e-10, constraint_nodes = "min_cover",
    #   messages = "pairs" (paper 000 Fig. 6 on each node's observation block, data = node-ID.npz)
    # name = "ckf": rounds = 4 (k_n), protocol = "P3" (paper 003 Fig. 6 on each node's normals, data = node-ID.npz)
    # name = "uwb": solver = "N-CLM", iterations = 200, objective = "squared" (paper 002 on each anchor's own ranges,
    #   data = node-ID.npz)

    [[node]]
    id = 0
    address = "tcp://127.0.0.1:47000"
    neighbours = [1, 7]
    data = "data/node-0.txt"   # relative paths are relative to the description file
    public_key = "…40 Z85 characters…"      # with security = "curve"
    secret_key = "keys/node-0.key_secret"   # this node's secret key file (needed only on its own host)

    [faults]                   # for tests and demos: node 3 crashes (exits at once) at round 20 (admm/ckf/uwb: step),
    crash = [{ node = 3, round = 20 }]     # add restart_after_s = 2 to restart it (it rejoins)
    drop_probability = 0.1     # each message dropped (the simulator's seeded FaultSchedule: the same drops)
    seed = 0
    latency_max_ms = 50        # each received message held back Uniform(0, 50) ms

Node ids are ``0..n-1``; neighbour lists must be symmetric; addresses distinct.
"""

from __future__ import annotations

import os
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from distnav._optional import require
from distnav.errors import DataFileError
from distnav.exchange.field.transport import Peer, TransportOptions
from distnav.network.graph import Graph

__all__ = [
    "ALGORITHMS",
    "FORMAT_VERSION",
    "NetworkDescription",
    "NodeEntry",
    "format_description",
    "read_description",
    "read_node_values",
]

FORMAT_VERSION = 1
ALGORITHMS = ("consensus", "consensus_flows", "admm", "ckf", "uwb")
_SECURITY = ("none", "curve")
_Z85_KEY_LEN = 40


@dataclass(frozen=True)
class NodeEntry:
    """One ``[[node]]`` table."""

    id: int
    address: str
    neighbours: tuple[int, ...]
    data: Path | None = None
    public_key: str | None = None
    secret_key: Path | None = None


@dataclass(frozen=True)
class NetworkDescription:
    """A checked description (see the module docstring); ``path`` is where it was read from (or None)."""

    nodes: tuple[NodeEntry, ...]
    name: str = "network"
    security: str = "none"
    deadline_ms: float = 2000.0
    miss_limit: int = 3
    start_timeout_s: float = 60.0
    algorithm: dict[str, Any] = field(
        default_factory=lambda: {"name": "consensus", "rounds": 200, "protocol": "MH", "patience": 20}
    )
    crash: dict[int, int] = field(default_factory=dict)
    restart_after_s: dict[int, float] = field(default_factory=dict)
    drop_probability: float = 0.0
    drop_seed: int = 0
    latency_max_ms: float = 0.0
    path: Path | None = None

    @property
    def n_nodes(self) -> int:
        return len(self.nodes)

    def graph(self) -> Graph:
        links = sorted({(min(n.id, j), max(n.id, j)) for n in self.nodes for j in n.neighbours})
        return Graph.from_links(self.n_nodes, links)

    def node(self, node_id: int) -> NodeEntry:
        if not 0 <= node_id < self.n_nodes:
            raise DataFileError(f"{self._where()}: no node {node_id} (ids 0..{self.n_nodes - 1})")
        return self.nodes[node_id]

    def peers(self, node_id: int, *, everyone: bool = False) -> list[Peer]:
        """The processes node ``node_id`` talks to: its neighbours (or every other node)."""
        me = self.node(node_id)
        ids = [n.id for n in self.nodes if n.id != node_id] if everyone else sorted(me.neighbours)
        keys = {n.id: None if n.public_key is None else n.public_key.encode() for n in self.nodes}
        return [Peer(i, self.nodes[i].address, keys[i]) for i in ids]

    def transport_options(self) -> TransportOptions:
        return TransportOptions(
            deadline_s=self.deadline_ms / 1000.0,
            miss_limit=self.miss_limit,
            start_timeout_s=self.start_timeout_s,
            latency_max_s=self.latency_max_ms / 1000.0,
            latency_seed=self.drop_seed,
        )

    def fingerprint(self) -> int:
        """A 63-bit digest of what every node of the network must agree on (the ``[network]``, ``[algorithm]`` and
        ``[faults]`` tables, every node's id, address, neighbours and public key), without what is local to a host
        (data and secret key paths); a node's start-up hello carries it (:mod:`distnav.exchange.field.startup`)."""
        import hashlib

        shared = (
            FORMAT_VERSION,
            self.name,
            self.security,
            float(self.deadline_ms),
            self.miss_limit,
            float(self.start_timeout_s),
            sorted((k, repr(v)) for k, v in self.algorithm.items()),
            sorted(self.crash.items()),
            sorted(self.restart_after_s.items()),
            float(self.drop_probability),
            self.drop_seed,
            float(self.latency_max_ms),
            [(n.id, n.address, sorted(n.neighbours), n.public_key) for n in self.nodes],
        )
        digest = hashlib.blake2b(repr(shared).encode(), digest_size=8).digest()
        return int.from_bytes(digest, "little") >> 1 or 1

    def _where(self) -> str:
        return str(self.path) if self.path is not None else "network description"


def _fail(where: str, text: str) -> DataFileError:
    return DataFileError(f"{where}: {text}")


def _get(table: dict[str, Any], key: str, kind: type | tuple[type, ...], where: str, default: Any = ...) -> Any:
    if key not in table:
        if default is ...:
            raise _fail(where, f"missing key '{key}'")
        return default
    value = table[key]
    if isinstance(value, bool) and kind is not bool:
        raise _fail(where, f"key '{key}' must be {_kind_name(kind)}, got {value!r}")
    if not isinstance(value, kind):
        raise _fail(where, f"key '{key}' must be {_kind_name(kind)}, got {value!r}")
    return value


def _kind_name(kind: type | tuple[type, ...]) -> str:
    names = {int: "an integer", float: "a number", str: "a string", list: "a list", dict: "a table", bool: "true/false"}
    if isinstance(kind, tuple):
        return " or ".join(names.get(k, k.__name__) for k in kind)
    return names.get(kind, kind.__name__)


def _positive(value: float, key: str, where: str) -> float:
    if not value > 0:
        raise _fail(where, f"key '{key}' must be > 0, got {value!r}")
    return value


def read_description(path: str | Path) -> NetworkDescription:
    """Read and check a description file (:class:`DataFileError` names the file, the node and the key)."""
    p = Path(path)
    try:
        raw = tomllib.loads(p.read_text(encoding="utf-8-sig"))
    except OSError as exc:
        raise DataFileError(f"{p}: cannot read the network description ({exc.strerror or exc})") from None
    except UnicodeDecodeError:
        raise DataFileError(f"{p}: not a text file (a network description is TOML)") from None
    except tomllib.TOMLDecodeError as exc:
        raise DataFileError(f"{p}: not valid TOML ({exc})") from None
    return parse_description(raw, path=p)


def parse_description(raw: dict[str, Any], *, path: Path | None = None) -> NetworkDescription:
    """Check a parsed TOML document (see :func:`read_description`)."""
    where = str(path) if path is not None else "network description"
    version = _get(raw, "version", int, where, FORMAT_VERSION)
    if version != FORMAT_VERSION:
        raise _fail(where, f"format version {version}; this distnav reads version {FORMAT_VERSION}")
    unknown = set(raw) - {"version", "network", "algorithm", "node", "faults"}
    if unknown:
        raise _fail(where, f"unknown top-level keys {sorted(unknown)}")
    net = _get(raw, "network", dict, where, {})
    w = f"{where} [network]"
    security = _get(net, "security", str, w, "none")
    if security not in _SECURITY:
        raise _fail(w, f"key 'security' must be one of {list(_SECURITY)}, got {security!r}")
    deadline_ms = _positive(float(_get(net, "deadline_ms", (int, float), w, 2000.0)), "deadline_ms", w)
    miss_limit = _get(net, "miss_limit", int, w, 3)
    if miss_limit < 1:
        raise _fail(w, f"key 'miss_limit' must be >= 1, got {miss_limit}")
    start_timeout = _positive(float(_get(net, "start_timeout_s", (int, float), w, 60.0)), "start_timeout_s", w)
    algorithm = _algorithm(_get(raw, "algorithm", dict, where, {}), f"{where} [algorithm]")
    tables = _get(raw, "node", list, where)
    base = path.parent if path is not None else Path.cwd()
    nodes = [_node(t, k, len(tables), base, f"{where} [[node]] #{k + 1}", security) for k, t in enumerate(tables)]
    _check_network(nodes, where)
    faults = _get(raw, "faults", dict, where, {})
    wf = f"{where} [faults]"
    crash, restart = _crashes(faults, len(nodes), wf)
    unknown_f = set(faults) - {"crash", "drop_probability", "seed", "latency_max_ms"}
    if unknown_f:
        raise _fail(wf, f"unknown keys {sorted(unknown_f)}")
    drop = float(_get(faults, "drop_probability", (int, float), wf, 0.0))
    if not 0.0 <= drop < 1.0:
        raise _fail(wf, f"key 'drop_probability' must be in [0, 1), got {drop!r}")
    latency = float(_get(faults, "latency_max_ms", (int, float), wf, 0.0))
    if not latency >= 0.0:
        raise _fail(wf, f"key 'latency_max_ms' must be >= 0, got {latency!r}")
    drop_seed = _get(faults, "seed", int, wf, 0)
    return NetworkDescription(
        nodes=tuple(sorted(nodes, key=lambda n: n.id)),
        name=_get(net, "name", str, w, "network"),
        security=security,
        deadline_ms=deadline_ms,
        miss_limit=miss_limit,
        start_timeout_s=start_timeout,
        algorithm=algorithm,
        crash=crash,
        restart_after_s=restart,
        drop_probability=drop,
        drop_seed=drop_seed,
        latency_max_ms=latency,
        path=path,
    )


def _algorithm(table: dict[str, Any], where: str) -> dict[str, Any]:
    name = _get(table, "name", str, where, "consensus")
    if name not in ALGORITHMS:
        raise _fail(where, f"key 'name': unknown algorithm {name!r}; choose one of {list(ALGORITHMS)}")
    allowed = {"name", *_SETTINGS[name]}
    unknown = sorted(set(table) - allowed)
    if unknown:
        raise _fail(where, f"keys {unknown} mean nothing to {name!r} (its keys: {sorted(allowed)})")
    out: dict[str, Any] = {"name": name}
    for key, (kind, default, check, rule) in _SETTINGS[name].items():
        value = _get(table, key, kind, where, default)
        if not check(value):
            raise _fail(where, f"key '{key}' must be {rule}, got {value!r}")
        out[key] = float(value) if kind == (int, float) else value
    return out


_PROTOCOLS = ("P1", "P2", "P3", "P4", "MH")
_UWB_SOLVERS = ("N-CLM", "N-CSG", "N-CSG-BLS", "N-CSG-TBLS", "CSG")
_ROUNDS = (int, 200, lambda v: v >= 1, ">= 1")
_CONSENSUS = {
    "rounds": _ROUNDS,
    "protocol": (str, "MH", lambda v: v in _PROTOCOLS, "one of P1, P2, P3, P4, MH"),
    "patience": (int, 20, lambda v: v >= 1, ">= 1"),
}
#: every algorithm's keys: (type, default, check, the rule in words)
_SETTINGS: dict[str, dict[str, tuple[Any, Any, Any, str]]] = {
    "consensus": _CONSENSUS,
    "consensus_flows": _CONSENSUS,
    "admm": {
        "rho": ((int, float), 1.0, lambda v: v > 0, "> 0 (the ADMM weight ρ, W = ρ I)"),
        "max_iterations": (int, 1000, lambda v: v >= 1, ">= 1"),
        "tol": ((int, float), 1e-10, lambda v: v >= 0, ">= 0"),
        "constraint_nodes": (str, "min_cover", lambda v: v in ("min_cover", "all"), "'min_cover' or 'all'"),
        "messages": (str, "pairs", lambda v: v in ("pairs", "ternary"), "'pairs' or 'ternary'"),
    },
    "uwb": {
        "solver": (str, "N-CLM", lambda v: v in _UWB_SOLVERS, f"one of {list(_UWB_SOLVERS)}"),
        "iterations": (int, 200, lambda v: v >= 1, ">= 1"),
        "objective": (str, "squared", lambda v: v in ("squared", "metres"), "'squared' or 'metres' (paper 002)"),
    },
    "ckf": {
        "rounds": (int, 4, lambda v: v >= 1, ">= 1 (k_n, consensus rounds per epoch)"),
        "protocol": (str, "P3", lambda v: v in _PROTOCOLS, "one of P1, P2, P3, P4, MH"),
    },
}


def _node(t: Any, k: int, n: int, base: Path, where: str, security: str) -> NodeEntry:
    if not isinstance(t, dict):
        raise _fail(where, "must be a table")
    node_id = _get(t, "id", int, where)
    where = f"{where.rsplit('#', 1)[0]}id {node_id}"
    if not 0 <= node_id < n:
        raise _fail(where, f"key 'id' must be in 0..{n - 1} (the ids of the {n} nodes), got {node_id}")
    address = _get(t, "address", str, where)
    if not address.startswith("tcp://") or ":" not in address[6:]:
        raise _fail(where, f"key 'address' must look like tcp://HOST:PORT, got {address!r}")
    port = address.rsplit(":", 1)[1]
    if not port.isdigit() or not 0 < int(port) < 65536:
        raise _fail(where, f"key 'address': port {port!r} is not in 1..65535")
    nbrs = _get(t, "neighbours", list, where)
    if not all(isinstance(j, int) and not isinstance(j, bool) for j in nbrs):
        raise _fail(where, f"key 'neighbours' must list node ids, got {nbrs!r}")
    bad = [j for j in nbrs if not 0 <= j < n or j == node_id]
    if bad:
        raise _fail(where, f"key 'neighbours': {bad} are not other nodes' ids (0..{n - 1})")
    if len(set(nbrs)) != len(nbrs):
        raise _fail(where, f"key 'neighbours' lists a node twice: {nbrs}")
    data = _get(t, "data", str, where, None)
    public = _get(t, "public_key", str, where, None)
    secret = _get(t, "secret_key", str, where, None)
    if security == "curve" and public is None:
        raise _fail(where, "key 'public_key' is needed with security = \"curve\" (make keys with `distnav field keys`)")
    if public is not None and len(public) != _Z85_KEY_LEN:
        raise _fail(where, f"key 'public_key' must be {_Z85_KEY_LEN} Z85 characters, got {len(public)}")
    return NodeEntry(
        id=node_id,
        address=address,
        neighbours=tuple(sorted(nbrs)),
        data=None if data is None else Path(os.path.normpath(base / data)),
        public_key=public,
        secret_key=None if secret is None else Path(os.path.normpath(base / secret)),
    )


def _check_network(nodes: list[NodeEntry], where: str) -> None:
    if not nodes:
        raise _fail(where, "no [[node]] tables")
    ids = [n.id for n in nodes]
    dup = sorted({i for i in ids if ids.count(i) > 1})
    if dup:
        raise _fail(where, f"node ids {dup} are used twice")
    addr: dict[str, int] = {}
    for n in nodes:
        if n.address in addr:
            raise _fail(where, f"nodes {addr[n.address]} and {n.id} share the address {n.address}")
        addr[n.address] = n.id
    by_id = {n.id: n for n in nodes}
    for n in nodes:
        for j in n.neighbours:
            if n.id not in by_id[j].neighbours:
                raise _fail(where, f"node {n.id} lists neighbour {j}, but node {j} does not list {n.id}")


def _crashes(table: dict[str, Any], n: int, where: str) -> tuple[dict[int, int], dict[int, float]]:
    entries = _get(table, "crash", list, where, [])
    out: dict[int, int] = {}
    restart: dict[int, float] = {}
    for e in entries:
        if not isinstance(e, dict):
            raise _fail(where, f"key 'crash': entries are tables {{ node = N, round = R }}, got {e!r}")
        node, rnd = _get(e, "node", int, where), _get(e, "round", int, where)
        if not 0 <= node < n or rnd < 0:
            raise _fail(where, f"key 'crash': node {node} round {rnd} (node in 0..{n - 1}, round >= 0)")
        out[node] = rnd
        after = _get(e, "restart_after_s", (int, float), where, None)
        if after is not None:
            if not after >= 0:
                raise _fail(where, f"key 'crash': node {node}: restart_after_s must be >= 0, got {after!r}")
            restart[node] = float(after)
    return out, restart


def format_description(desc: NetworkDescription, *, relative_to: Path | None = None) -> str:
    """The TOML text of ``desc`` (paths written relative to ``relative_to``, with ``..`` when they lie beside it,
    so that a copy of the description and its files keeps working on another host; absolute when the two share no
    folder but the root, or lie on different drives)."""
    tomli_w = require("tomli_w", "field")

    def rel(p: Path | None) -> str | None:
        if p is None:
            return None
        if relative_to is not None:
            full, base = p.resolve(), relative_to.resolve()
            try:
                shared = Path(os.path.commonpath([full, base]))
            except ValueError:  # another drive (Windows)
                return str(full)
            return os.path.relpath(full, base) if shared != Path(shared.anchor) else str(full)
        return str(p)

    nodes = []
    for n in desc.nodes:
        t: dict[str, Any] = {"id": n.id, "address": n.address, "neighbours": list(n.neighbours)}
        for key, value in (("data", rel(n.data)), ("public_key", n.public_key), ("secret_key", rel(n.secret_key))):
            if value is not None:
                t[key] = value
        nodes.append(t)
    doc: dict[str, Any] = {
        "version": FORMAT_VERSION,
        "network": {
            "name": desc.name,
            "security": desc.security,
            "deadline_ms": desc.deadline_ms,
            "miss_limit": desc.miss_limit,
            "start_timeout_s": desc.start_timeout_s,
        },
        "algorithm": dict(desc.algorithm),
        "node": nodes,
    }
    faults: dict[str, Any] = {}
    if desc.crash:
        faults["crash"] = [
            {
                "node": k,
                "round": v,
                **({"restart_after_s": desc.restart_after_s[k]} if k in desc.restart_after_s else {}),
            }
            for k, v in sorted(desc.crash.items())
        ]
    if desc.drop_probability:
        faults.update(drop_probability=desc.drop_probability, seed=desc.drop_seed)
    if desc.latency_max_ms:
        faults.update(latency_max_ms=desc.latency_max_ms, seed=desc.drop_seed)
    if faults:
        doc["faults"] = faults
    return str(tomli_w.dumps(doc))


def read_node_values(path: Path, node_id: int) -> np.ndarray:
    """A node's data for consensus: whitespace- or comma-separated finite numbers (a vector), ``#`` comments."""
    try:
        text = path.read_text(encoding="utf-8-sig")
    except OSError as exc:
        raise DataFileError(f"{path}: node {node_id}: cannot read its data file ({exc.strerror or exc})") from None
    except UnicodeDecodeError:
        raise DataFileError(f"{path}: node {node_id}: not a text file of numbers (consensus reads text)") from None
    tokens = [
        (line_no, tok)
        for line_no, line in enumerate(text.splitlines(), 1)
        for tok in line.split("#", 1)[0].replace(",", " ").split()
    ]
    if not tokens:
        raise DataFileError(f"{path}: node {node_id}: the data file holds no numbers")
    try:
        values = np.array([tok for _, tok in tokens], dtype=float)
    except ValueError:
        line_no, tok = next((n, t) for n, t in tokens if not _is_number(t))
        raise DataFileError(f"{path}:{line_no}: node {node_id}: {tok!r} is not a number") from None
    bad = np.flatnonzero(~np.isfinite(values))
    if bad.size:
        line_no, tok = tokens[int(bad[0])]
        raise DataFileError(f"{path}:{line_no}: node {node_id}: {tok!r} is not finite")
    return values


def _is_number(token: str) -> bool:
    try:
        float(token)
    except ValueError:
        return False
    return True
