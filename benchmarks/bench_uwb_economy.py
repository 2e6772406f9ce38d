"""Bytes of the distributed UWB solves against a fusion centre (issue 27): where they go, what the economy saved,
and how both grow with the network.

    python benchmarks/bench_uwb_economy.py [--quick] [--plot docs/economy_uwb.png]

1. **The plant-like 28-anchor hall** (``PLANT_LIKE``, seed ``[78, 0]``, known anchors in the middle and in a
   corner; ``uwb solve``'s workflow with ``--solver N-CLM``): messages and bytes per phase (first fit, tightening
   of the one-sided loss, exclusion loop, polish, σ), in three configurations measured in the same run with the
   same accounting (the broadcasts, and the LM phase's network totals as spanning-tree all-reductions):
   *before* issue 27 (:func:`configured` ``"before"``: 500 consensus iterations in the first fit, every row sent in
   full in float64, float64 CG scalars, the central σ by CG to ``1e-10``, every re-fit from offset 0 and the initial
   damping, the tightening by halvings, no extrapolated tail, every warm fit's first parameters broadcast, the loop
   opened and ended by full fits), *today* (the defaults at the seventh session's start: items 1–23 of
   docs/economy_uwb.md, every item of the seventh session switched off (:data:`SESSION_ITEMS`: the exclusion loop
   opened by a full fit of every link and ended by a full fit of the kept links, items 24–25; CG's dot products and
   the products' exponents not held, items 26–27; the LM rounds' own messages as before, items 28–32; no forcing
   term in the loop's re-fits, item 36; every anchor in the LM phase, item 37 of the eighth session) and *after*
   (the defaults: items 24–32, 36 and 37);
   the positions, their largest difference from *today*'s, the σ ratio to *today*'s; the yardstick: every range
   gathered at one anchor
   (:func:`distnav.models.uwb.communication.gather_cost`, what ``summary.json`` reports) and the busiest relay
   of that gather over the range graph (:func:`distnav.network.gather.gather_cost`). Per anchor: what each
   anchor's broadcasts and the gathered σ's tree sent, the reductions spread evenly (2 messages per anchor and
   reduction on average; a leaf of the tree sends 1).
2. **Bytes against network size** (halls of 10²…10⁴ anchors at the plant's anchor density, 4 known anchors in the
   middle, heights held): one warm distributed LM fit (the final phase every re-fit of the workflow runs:
   N-CLM with 0 consensus iterations, one-sided Cauchy at 0.3 m, common offset, no QC) from the truth displaced by
   N(0, 0.2 m) — the total, the busiest and the median anchor's bytes sent (its broadcasts, and its messages
   up and down a BFS spanning tree from the graph's centre for every network total) — against gathering every anchor's
   range records (16 B each, held by the lower-numbered anchor of the link) at one sink over the same graph
   (total hop-bytes, busiest relay). The crossing point is where the busiest anchor of the distributed fit
   sends less than the busiest relay of the gather. The reductions' tree (:func:`_tree_parents`) caps every
   anchor's children (the fifth session: at most 2, 1 for anchors of more than the median degree, so no anchor
   sends more than 3 messages per total); ``*_balanced_tree``: the third session's BFS tree with balanced parents,
   whose root sends every total to all its neighbours; ``*_bfs_tree``: scipy's BFS tree (the second session's).
3. **A whole solve against network size** (the halls of 2., from the same displaced start, ``uwb solve``'s
   workflow with N-CLM: first fit, tightening, exclusion loop, per-anchor check, polish): the bytes each anchor
   sends over all the fits (its broadcasts, and its messages up and down the capped tree of 2. for every
   network total of every fit) and for the σ after the fits (gathered at one anchor up to
   :data:`GATHERED_SIGMA_MAX` anchors, the 2-hop sub-network σ above, to keep the run short; ``sigma_bytes`` in
   all, ``busiest_anchor_sigma_bytes``) against the gather's busiest relay, and the number of fits
   (``busiest_anchor``: what the busiest anchor sent, by kind; ``busiest_anchor_fit_bytes_*_tree``: the fits
   alone over each tree); no reliability test (``reliability_limit_m=0``).

Goals (issue 27): the 28-anchor hall's total bytes ≤ 100 × the gather, median per-anchor traffic ≤ 20 kB; at 10⁴
anchors the busiest anchor below the busiest relay. Printed as one table; JSON in benchmarks/results/uwb_economy.json.
"""

from __future__ import annotations

import argparse
import contextlib
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
from scipy.sparse.csgraph import breadth_first_order

import distnav.models.uwb.field_fits as field_fits
import distnav.models.uwb.field_precision as field_precision
from _common import print_table, write_json
from distnav.algorithms.ranging import csg, qc, refine, wire
from distnav.algorithms.ranging.covariance import COVARIANCE_CG_RTOL
from distnav.experiments.uwb_field import hall_problem
from distnav.models.uwb.field import FieldOptions, prepare, solve_field
from distnav.models.uwb.field import gather_cost as range_gather_cost
from distnav.models.uwb.hall import PLANT_LIKE, HallConfig, simulate_hall
from distnav.network.gather import gather_cost
from distnav.network.graph import Graph

HALL_SEED = [78, 0]
SIZES = (100, 300, 1000, 3000, 10000)
QUICK_SIZES = (100, 300)
SOLVE_SIZES = (100, 300, 1000, 3000, 10000)  # section 3 (a whole solve: about 10 to 40 fits)
GATHERED_SIGMA_MAX = 3000
QUICK_SOLVE_SIZES = (100,)
RECORD_BYTES = 16  # two int32 ids + one float64 range (models/uwb/communication.py)
GOAL_RATIO = 100.0
GOAL_MEDIAN_BYTES = 20_000
TREE_CHILDREN = 2  # the capped reduction tree: at most this many children per anchor (_tree_parents)


LABELS = ("before", "today", "after")
#: the module switches of each configuration (module docstring); FieldOptions in :data:`OPTIONS`
SWITCHES: dict[str, dict[tuple[Any, str], Any]] = {
    "before": {
        (field_fits, "FIRST_ITERATIONS"): 10**9,
        (field_precision, "ECONOMY_CG_RTOL"): COVARIANCE_CG_RTOL,
        (wire, "PLAIN"): True,
        (wire, "CG_SCALAR_DTYPE"): np.float64,
        (wire, "CG_DOT_DTYPE"): np.float64,
        (field_fits, "CARRY_OFFSET"): False,
        (field_fits, "CARRY_DAMPING"): False,
        (field_fits, "TIGHTEN_JUMP"): False,
        (refine, "EXTRAPOLATE"): None,
        (qc, "BLOCKED_NEAR"): False,
        (field_fits, "CARRY_HELD"): False,
    },
    "today": {},  # every item of the seventh session off (items 24–32, 36): SESSION_ITEMS
    "after": {},
}
#: the seventh session's items 24–32 and 36, each switched off in *today* (the defaults at the session's start)
SESSION_ITEMS: dict[tuple[Any, str], Any] = {
    (field_fits, "TIGHTEN_OPENS_LOOP"): False,  # item 24
    (field_fits, "LOOP_ENDS_LOOSE"): False,  # item 25
    (wire, "HELD_DOTS"): False,  # item 26
    (wire, "HELD_ACROSS_RUNS"): False,  # item 27
    (wire, "STEP_HELD"): False,  # items 28–32: the LM rounds' own messages
    (refine, "FIRST_MOVE_KNOWN"): False,
    (refine, "OFFSET_START_HELD"): False,
    (refine, "ROOT_DECIDES"): False,
    (refine, "SCALED_TRIAL_KNOWN"): False,
    (field_fits, "STAGE_FORCING"): None,  # item 36: the forcing term in the loop's re-fits
    (refine, "SIT_OUT"): False,  # item 37 (eighth session): the known anchors sit the LM phase out
}
SWITCHES["today"].update(SESSION_ITEMS)
SWITCHES["before"].update(SESSION_ITEMS)
OPTIONS = {
    "before": {"distributed_precision": "central", "staged_tolerances": False},
    "today": {},
    "after": {},
}


@contextlib.contextmanager
def configured(label: str) -> Iterator[None]:
    """The module switches of configuration ``label`` (module docstring), restored afterwards."""
    saved = {key: getattr(*key) for key in SWITCHES[label]}
    for (mod, name), value in SWITCHES[label].items():
        setattr(mod, name, value)
    try:
        yield
    finally:
        for (mod, name), value in saved.items():
            setattr(mod, name, value)


def _hall_rows() -> list[dict[str, Any]]:
    rows = []
    for place in ("middle", "corner"):
        h = simulate_hall(np.random.default_rng(HALL_SEED), HallConfig().with_(known=place, **PLANT_LIKE))
        sub, geo = prepare(hall_problem(h)[0])
        yard = range_gather_cost(sub)
        graph = Graph.from_links(sub.n_anchors, sub.links)
        own = np.bincount(sub.links.min(axis=1), minlength=sub.n_anchors) * RECORD_BYTES
        relay = gather_cost(graph, own).busiest_relay_bytes
        got = {}
        for label in LABELS:
            with configured(label):
                t0 = time.process_time()
                sol = solve_field(sub, FieldOptions(solver="N-CLM", **OPTIONS[label]), geometry=geo)
                cpu = time.process_time() - t0
            got[label] = sol
            d = (sol.positions_m - sub.truth_m)[sub.estimated]
            per_anchor = _per_anchor_bytes(sub, sol)
            row: dict[str, Any] = {
                "name": f"hall 28 {place}, {label}",
                "n_anchors": sub.n_anchors,
                "bytes": sol.bytes,
                "messages": sol.messages,
                **{f"bytes_{k}": v["bytes"] for k, v in sol.comm_phases.items()},
                "gather_bytes": yard["bytes"],
                "gather_busiest_relay_bytes": relay,
                "ratio_to_gather": sol.bytes / yard["bytes"],
                "median_anchor_bytes": float(np.median(per_anchor)),
                "busiest_anchor_bytes": float(np.max(per_anchor)),
                "rmse_m": float(np.sqrt(np.mean(np.sum(d**2, axis=1)))),
                "status": sol.status,
                "sigma_kind": sol.precision_kind,
                "cpu_s": cpu,
            }
            if label != "today" and "today" in got:
                b = got["today"]
                ratio = sol.sigma_m[sub.free] / b.sigma_m[sub.free]
                row["max_position_change_m"] = float(np.max(np.abs(sol.positions_m - b.positions_m)))
                row["sigma_ratio_min"], row["sigma_ratio_max"] = float(np.min(ratio)), float(np.max(ratio))
                row["same_exclusions"] = bool(np.array_equal(sol.excluded, b.excluded))
                row["bytes_saved_x"] = b.bytes / sol.bytes
                row["bytes_saved_x_vs_before"] = got["before"].bytes / sol.bytes
            if label == "after":
                row["goal"] = f"≤ {GOAL_RATIO:g}× gather, median ≤ {GOAL_MEDIAN_BYTES} B"
                row["meets_goal"] = bool(
                    row["ratio_to_gather"] <= GOAL_RATIO and row["median_anchor_bytes"] <= GOAL_MEDIAN_BYTES
                )
            rows.append(row)
    return rows


_SENT: list[np.ndarray] = []
_FITS: list[tuple[np.ndarray, float]] = []  # every distributed fit's bytes per anchor and reduced bytes (section 3)
_SIGMA: list[np.ndarray] = []  # the gathered or sub-network σ's bytes per anchor (section 3)
_TREES: list[tuple[np.ndarray, float]] = []  # every LM phase's reduction bytes and the anchors of its tree


def _per_anchor_bytes(sub: Any, sol: Any) -> np.ndarray:
    """Bytes each anchor sent over the whole workflow (the exchanges' per-node counters, summed by
    :func:`_counting`); each LM phase's reductions spread evenly over the anchors of its tree (those with a free
    parameter where the known ones sit out, ``refine.SIT_OUT``), the central σ's over all (spanning-tree sums)."""
    sent = np.sum(_SENT, axis=0) if _SENT else np.zeros(sub.n_anchors)
    for tree, reduced in _TREES:
        sent = sent + np.where(tree, reduced / max(int(tree.sum()), 1), 0.0)
    _SENT.clear()
    _FITS.clear()
    _SIGMA.clear()
    _TREES.clear()
    extra = sol.bytes - float(np.sum(sent))
    return np.asarray(sent + extra / sub.n_anchors)


def _counting() -> None:
    """Record every distributed solve's per-anchor bytes (``RangingResult.comm``) and every central, gathered or
    sub-network σ's."""
    solve, central, gathered = csg.solve, field_precision.central_precision, field_precision.gathered_precision
    subnetwork = field_precision._subnetwork

    def counted_solve(*args: Any, **kw: Any) -> Any:
        r = solve(*args, **kw)
        if r.comm is not None and r.comm.bytes_sent.size:
            _SENT.append(np.asarray(r.comm.bytes_sent, float))
            reduced = float((r.settings.get("refine") or {}).get("reduction_bytes", 0))
            _FITS.append((np.asarray(r.comm.bytes_sent, float), reduced))
            tree_nodes = int((r.settings.get("refine") or {}).get("tree_nodes", 0))
            tree = (
                np.any(kw.get("problem", args[0] if args else None).free, axis=1)
                if tree_nodes
                else np.ones(r.comm.bytes_sent.size, bool)
            )
            assert not tree_nodes or int(tree.sum()) == tree_nodes  # the plan's tree: the anchors with a free one
            _TREES.append((tree, reduced))
        return r

    def counted_central(*args: Any, **kw: Any) -> Any:
        out = central(*args, **kw)
        if out.precision.comm is not None:
            _SENT.append(np.asarray(out.precision.comm.bytes_sent, float))
        return out

    def counted_gathered(*args: Any, **kw: Any) -> Any:
        out = gathered(*args, **kw)
        if out is not None and out.bytes_sent is not None:
            _SENT.append(np.asarray(out.bytes_sent, float))
            _SIGMA.append(np.asarray(out.bytes_sent, float))
        return out

    def counted_subnetwork(*args: Any, **kw: Any) -> Any:
        out = subnetwork(*args, **kw)
        if out.bytes_sent is not None:
            _SENT.append(np.asarray(out.bytes_sent, float))
            _SIGMA.append(np.asarray(out.bytes_sent, float))
        return out

    field_fits.csg.solve = counted_solve  # type: ignore[assignment]
    field_precision.central_precision = counted_central
    field_precision.gathered_precision = counted_gathered
    field_precision._subnetwork = counted_subnetwork


TREE_KINDS = ("capped", "balanced", "bfs")


def _tree_sends(graph: Graph, kind: str = "capped") -> np.ndarray:
    """Messages each anchor sends in one all-reduction over a spanning tree: one up (all but the root), one down to
    each child (:func:`_tree_parents` makes the tree)."""
    parent, root = _tree_parents(graph, kind)
    children = np.bincount(parent[parent >= 0], minlength=graph.n_nodes)
    return np.asarray(children + (np.arange(graph.n_nodes) != root), float)


def _tree_parents(graph: Graph, kind: str = "capped") -> tuple[np.ndarray, int]:
    """Every anchor's parent (−1 at the root) and the root of the reductions' spanning tree of ``kind``:

    - ``"capped"`` (fifth session): from the centre (the sink of a gather of one unit per anchor), the anchors in
      BFS order, each taking as parent the shallowest anchor already in the tree among its neighbours that still
      has room — at most :data:`TREE_CHILDREN` children, 1 for an anchor of more than the median degree (its
      broadcasts already load it: one message per link and round); an anchor none of whose tree neighbours has room
      waits for the next pass, and a pass that places none gives one more child to the emptiest tree neighbour of
      the first waiting anchor. On the benchmark's halls every anchor then sends at most 3 messages per
      all-reduction (an anchor capped at 1 child 2, unless a stuck pass gave it one more), the tree deeper than a
      BFS tree (latency, not bytes);
    - ``"balanced"`` (third session): a BFS tree rooted at the anchor of the lowest degree within two hops of the
      centre, every anchor's parent the neighbour one level nearer the root with the fewest children so far
      (anchors with the fewest such neighbours placed first): the root sends every total to all its neighbours;
    - ``"bfs"`` (second session): scipy's BFS tree from the centre."""
    root = gather_cost(graph, np.ones(graph.n_nodes)).sink
    adj = graph.adjacency().tocsr()
    if kind == "capped":
        return _capped_parents(adj, root), root
    if kind == "balanced":
        near = breadth_first_order(adj, root, directed=False, return_predecessors=True)
        hops = np.full(graph.n_nodes, np.iinfo(np.int64).max)
        hops[root] = 0
        for v in near[0][1:]:
            hops[v] = hops[near[1][v]] + 1
        degree = np.diff(adj.indptr)
        cand = np.flatnonzero(hops <= 2)
        root = int(cand[np.lexsort((cand, hops[cand], degree[cand]))[0]])
    order, pred = breadth_first_order(adj, root, directed=False, return_predecessors=True)
    if kind == "balanced":
        level = np.zeros(graph.n_nodes, np.int64)
        for v in order[1:]:
            level[v] = level[pred[v]] + 1
        kids = np.zeros(graph.n_nodes, np.int64)
        for lv in range(1, int(level.max(initial=0)) + 1):
            here = np.flatnonzero(level == lv)
            ups = [adj.indices[adj.indptr[v] : adj.indptr[v + 1]] for v in here]
            ups = [u[level[u] == lv - 1] for u in ups]
            for i in sorted(range(here.size), key=lambda i: (ups[i].size, here[i])):
                best = ups[i][np.argmin(kids[ups[i]])]
                pred[here[i]] = best
                kids[best] += 1
    return np.where(pred >= 0, pred, -1), root


def _capped_parents(adj: Any, root: int) -> np.ndarray:
    """The ``"capped"`` tree of :func:`_tree_parents` over the CSR adjacency ``adj``."""
    n = adj.shape[0]
    degree = np.diff(adj.indptr)
    room = np.where(degree > np.median(degree), 1, TREE_CHILDREN)
    parent = np.full(n, -1, np.int64)
    kids = np.zeros(n, np.int64)
    depth = np.full(n, -1, np.int64)
    depth[root] = 0
    waiting = list(breadth_first_order(adj, root, directed=False, return_predecessors=False)[1:])
    while waiting:
        left = []
        for v in waiting:
            nb = adj.indices[adj.indptr[v] : adj.indptr[v + 1]]
            nb = nb[depth[nb] >= 0]
            ok = nb[kids[nb] < room[nb]]
            if ok.size == 0:
                left.append(v)
                continue
            u = ok[np.lexsort((kids[ok], depth[ok]))[0]]
            parent[v], depth[v] = u, depth[u] + 1
            kids[u] += 1
        if len(left) == len(waiting):  # stuck: one more child for the emptiest tree neighbour of the first
            nb = adj.indices[adj.indptr[left[0]] : adj.indptr[left[0] + 1]]
            nb = nb[depth[nb] >= 0]
            room[nb[np.argmin(kids[nb])]] += 1
        waiting = left
    return parent


def _scaled_hall(n: int) -> tuple[Any, np.ndarray]:
    """The hall of ``n`` anchors at the plant's density (sections 2 and 3) and the start: the truth displaced by
    N(0, 0.2 m)."""
    scale = np.sqrt(n / 28.0)
    cfg = HallConfig().with_(**{**PLANT_LIKE, "n_anchors": n, "length_m": 60.0 * scale, "width_m": 30.0 * scale})
    h = simulate_hall(np.random.default_rng([78, n]), cfg)
    p = hall_problem(h)[0]
    rng = np.random.default_rng([27, n])
    start = np.where(p.free, p.truth_m + rng.normal(0.0, 0.2, p.truth_m.shape), p.positions_m)
    return p, start


def _scaling_row(n: int) -> dict[str, Any]:
    p, start = _scaled_hall(n)
    t0 = time.process_time()
    r = csg.solve(
        p.with_initial(start),
        "N-CLM",
        iterations=0,
        objective="metres",
        sigma_m=0.1,
        loss="cauchy_long",
        loss_scale_m=0.3,
        range_offsets="common",
        quality=False,
    )
    cpu = time.process_time() - t0
    graph = Graph.from_links(p.n_anchors, p.links)
    own = np.bincount(p.links.min(axis=1), minlength=p.n_anchors) * RECORD_BYTES
    g = gather_cost(graph, own)
    ref = r.settings.get("refine", {})
    per_reduction = ref.get("reduction_bytes", 0) / max(2 * (n - 1), 1)  # Σ reduced bytes per message
    sends = {
        kind: np.asarray(r.comm.bytes_sent, float) + _tree_sends(graph, kind) * per_reduction for kind in TREE_KINDS
    }
    sent = sends["capped"]
    d = (r.estimates - p.truth_m)[p.estimated]
    return {
        "name": f"one distributed LM fit, {n} anchors",
        "n_anchors": n,
        "links": int(p.links.shape[0]),
        "bytes": r.comm.bytes + ref.get("reduction_bytes", 0),
        "reduction_bytes": ref.get("reduction_bytes", 0),
        "busiest_anchor_bytes": float(sent.max()),
        "median_anchor_bytes": float(np.median(sent)),
        "gather_total_hop_bytes": g.total_hop_bytes,
        "gather_busiest_relay_bytes": g.busiest_relay_bytes,
        "gather_median_bytes": g.median_node_bytes,
        "busiest_vs_relay": float(sent.max()) / max(g.busiest_relay_bytes, 1),
        **{f"busiest_anchor_bytes_{k}_tree": float(sends[k].max()) for k in TREE_KINDS[1:]},
        **{f"busiest_vs_relay_{k}_tree": float(sends[k].max()) / max(g.busiest_relay_bytes, 1) for k in TREE_KINDS[1:]},
        "broadcast_busiest_anchor_bytes": float(np.max(r.comm.bytes_sent)),
        "refine": r.settings.get("refine", {}),
        "status": r.status,
        "rmse_m": float(np.sqrt(np.mean(np.sum(d**2, axis=1)))),
        "cpu_s": cpu,
    }


def _solve_row(n: int) -> dict[str, Any]:
    """Section 3: a whole ``uwb solve`` workflow (N-CLM) on the hall of :func:`_scaling_row`, per-anchor bytes of
    all its fits (broadcasts + capped-tree messages of every fit's reductions) and of its σ against the gather's
    busiest relay; the RMSE of the estimated anchors against the truth (issue 27, eighth session: the answer must
    stay as good where the exclusion loop changes)."""
    p, start = _scaled_hall(n)
    _SENT.clear()
    _FITS.clear()
    _SIGMA.clear()
    _TREES.clear()
    t0 = time.process_time()
    sigma = "gathered" if n <= GATHERED_SIGMA_MAX else "subnetwork"  # a dense σ of 2n unknowns up to there
    opts = FieldOptions(solver="N-CLM", distributed_precision=sigma, reliability_limit_m=0.0)
    sol = solve_field(p.with_initial(start), opts, geometry=None)
    cpu = time.process_time() - t0
    graph = Graph.from_links(p.n_anchors, p.links)
    reduced = sum(r for _, r in _FITS)
    broadcast = np.sum([b for b, _ in _FITS], axis=0)
    sigma_sent = np.sum(_SIGMA, axis=0) if _SIGMA else np.zeros(n)
    fit_sent = {k: broadcast + _tree_sends(graph, k) / max(2 * (n - 1), 1) * reduced for k in TREE_KINDS}
    sent = fit_sent["capped"] + sigma_sent
    fits = len(_FITS)
    _SENT.clear()
    _FITS.clear()
    _SIGMA.clear()
    _TREES.clear()
    own = np.bincount(p.links.min(axis=1), minlength=p.n_anchors) * RECORD_BYTES
    g = gather_cost(graph, own)
    phases = sol.comm_phases
    fit_bytes = sum(v["bytes"] for k, v in phases.items() if k not in ("precision", "reliability"))
    miss = (sol.positions_m - p.truth_m)[p.estimated]
    return {
        "name": f"whole solve, {n} anchors",
        "n_anchors": n,
        "fits": fits,
        "bytes": sol.bytes,
        "fit_bytes": fit_bytes,
        "sigma_bytes": sol.bytes - fit_bytes,
        "busiest_anchor_bytes": float(sent.max()),
        "median_anchor_bytes": float(np.median(sent)),
        "gather_busiest_relay_bytes": g.busiest_relay_bytes,
        "busiest_vs_relay": float(sent.max()) / max(g.busiest_relay_bytes, 1),
        "busiest_anchor": _anatomy(sent, broadcast, fit_sent["capped"] - broadcast, sigma_sent),
        **{f"busiest_anchor_fit_bytes_{k}_tree": float(v.max()) for k, v in fit_sent.items()},
        "busiest_anchor_sigma_bytes": float(sigma_sent.max()),
        "excluded_links": int(sol.excluded.sum()),
        "rmse_m": float(np.sqrt(np.mean(np.sum(miss * miss, axis=1)))),
        "status": sol.status,
        "cpu_s": cpu,
    }


def _anatomy(sent: np.ndarray, broadcast: np.ndarray, tree: np.ndarray, sigma: np.ndarray) -> dict[str, float]:
    """The busiest anchor's bytes by kind: the fits' broadcasts, its reduction-tree messages, the σ's."""
    i = int(np.argmax(sent))
    return {"anchor": i, "broadcasts": float(broadcast[i]), "reductions": float(tree[i]), "sigma": float(sigma[i])}


def crossing(rows: list[dict[str, Any]]) -> float | None:
    """The network size (log-log interpolation) above which the busiest anchor sends less than the busiest relay."""
    ns = np.array([r["n_anchors"] for r in rows], float)
    q = np.log(np.array([r["busiest_vs_relay"] for r in rows], float))
    for k in range(1, ns.size):
        if q[k - 1] > 0 >= q[k]:
            t = q[k - 1] / (q[k - 1] - q[k])
            return float(np.exp(np.log(ns[k - 1]) + t * (np.log(ns[k]) - np.log(ns[k - 1]))))
    return None if q[0] > 0 else float(ns[0])


def plot(rows: list[dict[str, Any]], path: Path, solves: list[dict[str, Any]] | None = None) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ns = [r["n_anchors"] for r in rows]
    fig, ax = plt.subplots(figsize=(7, 4.5))
    ax.loglog(ns, [r["bytes"] for r in rows], "o-", color="C0", label="one warm distributed LM fit: total")
    ax.loglog(ns, [r["busiest_anchor_bytes"] for r in rows], "s-", color="C0", alpha=0.6, label="… busiest anchor")
    if solves:
        sn = [r["n_anchors"] for r in solves]
        ax.loglog(
            sn, [r["busiest_anchor_bytes"] for r in solves], "^-", color="C2", label="whole solve: busiest anchor"
        )
    ax.loglog(ns, [r["gather_total_hop_bytes"] for r in rows], "o--", color="C3", label="gather at one anchor: total")
    relay = [r["gather_busiest_relay_bytes"] for r in rows]
    ax.loglog(ns, relay, "s--", color="C3", alpha=0.6, label="… busiest relay")
    x = crossing(rows)
    if x is not None:
        ax.axvline(x, color="grey", lw=0.8)
        ax.text(x, ax.get_ylim()[0] * 2, f"one fit's busiest < relay: {x:.0f} anchors ", color="grey", ha="right")
    ax.set_xlabel("anchors (plant-like density, 4 known)")
    ax.set_ylabel("bytes sent")
    ax.set_title("UWB: distributed N-CLM vs gathering every range (multi-hop)")
    ax.legend(fontsize=8)
    ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def run(quick: bool, plot_path: Path | None = None) -> list[dict[str, Any]]:
    _counting()
    rows = _hall_rows()
    scaling = [_scaling_row(n) for n in (QUICK_SIZES if quick else SIZES)]
    x = crossing(scaling)
    for r in scaling:
        r["crossing_anchors"] = x
    if not quick:
        big = scaling[-1]
        big["goal"] = "busiest anchor < busiest relay at 10⁴"
        big["meets_goal"] = bool(big["busiest_vs_relay"] < 1.0)
    solves = [_solve_row(n) for n in (QUICK_SOLVE_SIZES if quick else SOLVE_SIZES)]
    if not quick:
        big = solves[-1]
        big["goal"] = "busiest anchor of a whole solve < busiest relay at 10⁴"
        big["meets_goal"] = bool(big["busiest_vs_relay"] < 1.0)
    if plot_path is not None:
        plot(scaling, plot_path, solves)
    return rows + scaling + solves


def main() -> None:
    ap = argparse.ArgumentParser(description="distnav benchmark: uwb_economy")
    ap.add_argument("--quick", action="store_true", help="sizes 100 and 300 only")
    ap.add_argument("--plot", type=Path, default=None, help="write the bytes-vs-size figure (PNG) here")
    args = ap.parse_args()
    rows = run(args.quick, args.plot)
    print_table("uwb_economy", [{k: v for k, v in r.items() if k not in ("refine", "busiest_anchor")} for r in rows])
    print(f"\nwritten {write_json('uwb_economy', rows)}")


if __name__ == "__main__":
    main()
