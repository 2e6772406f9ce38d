"""``reproduce uwb-field``: the real-data workflow of ``uwb solve`` on simulated industrial halls (issue 13).

Each instance is one :func:`~distnav.models.uwb.hall.simulate_hall` network (28 anchors under a 9 m ceiling of a
60 m × 30 m hall, surveyed heights, NLOS links whose every sample is 0.5–2.5 m long, likelier with length,
per-node antenna offsets, multipath minority, 5–60 samples per link), solved exactly as ``uwb solve`` does
(median per pair, heights held, geometry checks, MDS start, objective in metres where the solver has it, Cauchy
loss — for LM the one-sided Cauchy loss, tightened (``FieldOptions.nlos_aware``) — link exclusion:
:mod:`distnav.models.uwb.field`), with the 4 known anchors in the middle and in a corner.

Two hall **scenarios**: ``dense`` (the :class:`~distnav.models.uwb.hall.HallConfig` defaults: ~130 links, 9.3
per anchor, 12 % NLOS) and ``plant`` (:data:`~distnav.models.uwb.hall.PLANT_LIKE`: ~105 links, 7.5 per anchor,
9 % NLOS, every anchor with ≥ 4 partners — the counts of issue 13's real plant).

Per solver: mean RMSE over the estimated anchors, NLOS recall (excluded NLOS links / NLOS links) and false alarms
(excluded LOS links / LOS links), 2σ coverage of the reported σ per axis (the Monte Carlo check of the
precision), status counts, messages and bytes. The **oracle** is LM on the same links with the NLOS ones removed
by the truth (plain least squares, no exclusion, started at the truth: what the LOS links support). The
**careful fit** is a second, independent reference written here (:func:`careful_fit`, no truth used): the
"20-line scipy fit" of issue 13 — classical MDS of the horizontal median ranges (shortest paths for missing
pairs), Procrustes onto the known anchors, then ``scipy.optimize.least_squares`` on the residual in metres,
linear first and then Cauchy (``f_scale`` 0.3 m). "RMSE without the weak anchors" leaves out the anchors the
solution itself reports weakly determined (``positions.csv`` status ``weak``). Targets (issue 13): RMSE ≤ 1.15 ×
the oracle's, recall ≥ 90 % with ≤ 5 % false alarms, coverage within 90–98 %. ``--quick``: 1 hall per scenario and
placement, LM and N-CSG-TBLS (200 it.).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import Any

import numpy as np
from scipy.linalg import orthogonal_procrustes
from scipy.optimize import least_squares
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import shortest_path

from distnav.algorithms.ranging.csg import SOLVERS
from distnav.experiments.common import ExperimentContext, pyplot
from distnav.formats.uwb.hall_files import hall_csv_texts
from distnav.formats.uwb.io import RangeLog, combine_ranges
from distnav.models.uwb.field import FieldOptions, gather_cost, prepare, solve_field, subset_measurements
from distnav.models.uwb.geometry import GeometryReport
from distnav.models.uwb.hall import PLANT_LIKE, HallConfig, HallNetwork, simulate_hall
from distnav.models.uwb.problems import RangingProblem, build_problem, rmse_m
from distnav.options import add_size_option, int_up_to
from distnav.output import atomic_write_text

NAME = "uwb-field"
TITLE = "UWB anchors in a simulated industrial hall: NLOS exclusion, precision, every solver vs the oracle"

TARGETS: dict[str, Any] = {
    "rmse_ratio_max": 1.15,
    "recall_min": 0.90,
    "false_alarm_max": 0.05,
    "coverage": (0.90, 0.98),
}
PLACEMENTS = ("middle", "corner")
#: Size limits, refused at parse time above them. Halls: hall ``k`` of a placement is drawn from seed
#: ``1000·scenario + 100·placement + k``, so more than 100 would repeat the next placement's halls. Anchors: the
#: quick run's cost, measured on the shared 2-core machine (docs/bad_input.md).
HALLS = int_up_to(
    100, "hall k of a placement is drawn from seed 1000·scenario + 100·placement + k: more would repeat halls"
)
ANCHORS = int_up_to(
    112,
    "4 × the default; the cost grows steeply: the quick run took 9.5 CPU-s at 28 anchors, 23 at 56, over 120 at 112, "
    "and the full run is ≈ 60 × the quick one",
    minimum=4,
)
ITERATIONS = int_up_to(20_000, "40 × the default 500, run by every distributed solver on every hall")
SCENARIOS: dict[str, dict[str, object]] = {"dense": {}, "plant": dict(PLANT_LIKE)}
CAREFUL_F_SCALE_M = 0.3
FIGURE_CAPTIONS = {
    "fig_uwb_field.png": "Simulated industrial halls: mean RMSE of each solver (uwb solve's workflow: metres "
    "objective, Cauchy loss, NLOS link exclusion) against the oracle that drops the NLOS links "
    "by the truth; right, the first hall with its NLOS links in red.",
}


def write_hall(net: HallNetwork, folder: str | Path) -> dict[str, Path]:
    """Write the CSV files of a simulated hall into ``folder`` (:mod:`distnav.formats.uwb.hall_files`: what
    ``uwb solve`` reads plus the truth labels); returns ``{stem: path}``."""
    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    files = {}
    for stem, text in hall_csv_texts(net).items():
        files[stem] = out / f"{stem}.csv"
        atomic_write_text(files[stem], text)
    return files


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_size_option(parser, "--instances", HALLS, default=None, help="halls per placement (default 20; --quick 1)")
    parser.add_argument(
        "--solvers",
        nargs="+",
        type=str.upper,
        choices=list(SOLVERS),
        default=None,
        help="solvers to run (default all; --quick LM and N-CSG-TBLS)",
    )
    add_size_option(
        parser,
        "--iterations",
        ITERATIONS,
        default=None,
        help="iterations of the distributed solvers (default 500; --quick 200)",
    )
    add_size_option(parser, "--anchors", ANCHORS, default=28, help="anchors per hall (default 28; at least 4)")


def hall_problem(h: HallNetwork, *, heights: bool = True) -> tuple[RangingProblem, np.ndarray]:
    """The problem ``uwb solve`` builds from the hall's files (median per pair, surveyed heights held), and the
    NLOS truth of each of its links."""
    a, b = h.sample_pairs()
    comb = combine_ranges(
        RangeLog(Path("simulated"), tuple(a), tuple(b), h.range_m, np.arange(h.range_m.size, dtype=np.int64))
    )
    known = set(h.known.tolist())
    held = {h.ids[i]: {2: float(h.surveyed_z_m[i])} for i in range(h.n_anchors) if i not in known} if heights else None
    p = build_problem(
        list(h.ids),
        list(comb.pairs),
        comb.range_m,
        fixed={h.ids[k]: h.truth_m[k] for k in known},
        dim=3,
        held=held,
        truth_m=h.truth_m,
        check_determined=False,
        name="hall",
    )
    label = {(h.ids[i], h.ids[j]): bool(f) for (i, j), f in zip(h.links.tolist(), h.nlos, strict=True)}
    nlos = np.array(
        [
            label.get((p.ids[x], p.ids[y]), label.get((p.ids[y], p.ids[x]), False))
            for x, y in zip(p.meas_a, p.meas_b, strict=True)
        ]
    )
    return p, nlos


def careful_fit(p: RangingProblem, f_scale_m: float = CAREFUL_F_SCALE_M) -> np.ndarray:
    """Issue 13's "careful centralized scipy fit", written independently of distnav's solvers (module docstring):
    positions ``(n, 3)`` of a heights-held hall problem (x, y free, z known for every anchor). No truth used."""
    if np.any(p.free[:, 2]) or not np.array_equal(p.free[:, 0], p.free[:, 1]):
        raise ValueError("careful_fit takes a problem with every height known (x, y free together)")
    n, i, j, d = p.n_anchors, p.meas_a, p.meas_b, p.range_m
    z = p.positions_m[:, 2]
    dh = np.sqrt(np.maximum(d * d - (z[i] - z[j]) ** 2, 0.0))
    dist = shortest_path(csr_matrix((np.r_[dh, dh], (np.r_[i, j], np.r_[j, i])), shape=(n, n)), directed=False)
    dist[~np.isfinite(dist)] = np.max(dist[np.isfinite(dist)])
    c = np.eye(n) - 1.0 / n
    val, vec = np.linalg.eigh(-0.5 * c @ dist**2 @ c)
    xy = vec[:, -2:] * np.sqrt(np.maximum(val[-2:], 0.0))
    k = np.flatnonzero(p.fixed)
    rot, _ = orthogonal_procrustes(xy[k] - xy[k].mean(0), p.positions_m[k, :2] - p.positions_m[k, :2].mean(0))
    xy = (xy - xy[k].mean(0)) @ rot + p.positions_m[k, :2].mean(0)
    est = ~p.fixed

    def pos(x: np.ndarray) -> np.ndarray:
        out = p.positions_m.copy()
        out[est, :2] = x.reshape(-1, 2)
        return out

    def res(x: np.ndarray) -> np.ndarray:
        q = pos(x)
        return np.asarray(np.linalg.norm(q[i] - q[j], axis=1) - d)

    lin = least_squares(res, xy[est].ravel(), method="trf")
    robust = least_squares(res, lin.x, loss="cauchy", f_scale=f_scale_m, method="trf")
    return pos(robust.x)


def _coverage(sub: RangingProblem, pos: np.ndarray, sigma: np.ndarray) -> tuple[int, int]:
    assert sub.truth_m is not None
    free = sub.free
    ok = np.isfinite(sigma) & free & (sigma > 0)
    err = np.abs(pos - sub.truth_m)
    return int(np.sum(err[ok] <= 2.0 * sigma[ok])), int(ok.sum())


def _solve(
    sub: RangingProblem, geo: GeometryReport, nlos: np.ndarray, solver: str, iterations: int, ctx: ExperimentContext
) -> dict[str, Any]:
    opts = FieldOptions(
        solver=solver, loss="linear" if solver == "CSG" else "cauchy", iterations=500 if solver == "LM" else iterations
    )
    t0 = time.process_time()
    sol = solve_field(sub, opts, geometry=geo, exchange=lambda p: ctx.exchange(p.graph) if solver != "LM" else None)
    dt = time.process_time() - t0
    ex = sol.excluded
    hit, n_cov = _coverage(sub, sol.positions_m, sol.sigma_m) if sol.usable else (0, 0)
    strong = np.where(np.isin(np.array(sub.ids), list(sol.weak))[:, None], np.nan, sol.sigma_m)
    hit_s, n_s = _coverage(sub, sol.positions_m, strong) if sol.usable else (0, 0)
    return {
        "rmse_m": rmse_m(sub, sol.positions_m) if sol.usable else float("nan"),
        "status": sol.status,
        "tp": int((ex & nlos).sum()),
        "fp": int((ex & ~nlos).sum()),
        "nlos": int(nlos.sum()),
        "los": int((~nlos).sum()),
        "cov_hit": hit,
        "cov_n": n_cov,
        "cov_hit_not_weak": hit_s,
        "cov_n_not_weak": n_s,
        "messages": sol.messages,
        "bytes": sol.bytes,
        "cpu_s": dt,
        "objective": sol.objective_used,
        "weak": len(sol.weak),
        "rmse_m_not_weak": _rmse_without(sub, sol) if sol.usable else float("nan"),
    }


def _rmse_without(sub: RangingProblem, sol: Any) -> float:
    """RMSE over the estimated anchors the solution does not call weakly determined."""
    keep = sub.estimated & ~np.isin(np.array(sub.ids), list(sol.weak))
    assert sub.truth_m is not None
    d = (sol.positions_m - sub.truth_m)[keep]
    return float(np.sqrt(np.mean(np.sum(d * d, axis=1)))) if keep.any() else float("nan")


def run(ctx: ExperimentContext) -> dict[str, Any]:
    n_inst = int(ctx.options.get("instances") or (1 if ctx.quick else 20))
    solvers = list(ctx.options.get("solvers") or (["LM", "N-CSG-TBLS"] if ctx.quick else SOLVERS))
    iterations = int(ctx.options.get("iterations") or (200 if ctx.quick else 500))
    n_anchors = int(ctx.options.get("anchors") or 28)
    if n_inst < 1 or iterations < 1:
        raise ValueError("--instances and --iterations must be ≥ 1")
    rows: list[dict[str, Any]] = []
    example: dict[str, Any] = {}
    for si, (scenario, changes) in enumerate(SCENARIOS.items()):
        for pi, placement in enumerate(PLACEMENTS):
            with ctx.progress.task(
                f"uwb-field: {scenario} {placement}, {n_inst} hall(s) × {len(solvers)} "
                "solver(s) + careful fit + oracle",
                total=n_inst,
            ):
                for inst in range(n_inst):
                    cfg = HallConfig().with_(n_anchors=n_anchors, known=placement, **changes)
                    h = simulate_hall(ctx.rng(1000 * si + 100 * (pi + 1) + inst), cfg)
                    rows += _instance(ctx, h, scenario, placement, inst, solvers, iterations, example)
    table = _aggregate(rows, solvers)
    results: dict[str, Any] = {
        "settings": {
            "instances_per_placement": n_inst,
            "solvers": solvers,
            "iterations": iterations,
            "anchors": n_anchors,
            "placements": list(PLACEMENTS),
            "scenarios": {k: dict(v) for k, v in SCENARIOS.items()},
            "options": "FieldOptions defaults (metres where available; LM: one-sided Cauchy 0.3 m "
            "tightened to max(0.05 m, 3 x scatter); exclusion at 0.001)",
        },
        "targets": {k: list(v) if isinstance(v, tuple) else v for k, v in TARGETS.items()},
        "table": table,
        "runs": rows,
    }
    results["headline"] = {
        f"{r['scenario']} {r['placement']} {r['solver']}: RMSE / oracle / careful fit [m]": [
            r["rmse_m"],
            r["oracle_rmse_m"],
            r["careful_rmse_m"],
        ]
        for r in table
    }
    ctx.write_json("results.json", results)
    ctx.write_text("table.md", _table_md(table))
    if ctx.is_root:
        _figure(ctx, table, example)
    return results


def _instance(
    ctx: ExperimentContext,
    h: HallNetwork,
    scenario: str,
    placement: str,
    inst: int,
    solvers: list[str],
    iterations: int,
    example: dict[str, Any],
) -> list[dict[str, Any]]:
    p, nlos_full = hall_problem(h)
    sub, geo = prepare(p)
    keep = geo.solvable
    nlos = nlos_full[keep[p.meas_a] & keep[p.meas_b]]
    assert sub.truth_m is not None
    oracle = solve_field(
        subset_measurements(sub, ~nlos).with_initial(sub.truth_m),
        FieldOptions(loss="linear", exclude=False, multi_start=False),
        geometry=geo,
    )
    base = {
        "scenario": scenario,
        "placement": placement,
        "instance": inst,
        "oracle_rmse_m": rmse_m(sub, oracle.positions_m),
        "careful_rmse_m": rmse_m(sub, careful_fit(sub)),
        "gather_bytes": gather_cost(sub)["bytes"],
        "links": sub.n_meas,
        "nlos_links": int(nlos.sum()),
    }
    if not example and ctx.is_root:
        example.update(
            {
                "truth": h.truth_m,
                "links": np.stack([sub.meas_a, sub.meas_b], 1),
                "nlos": nlos,
                "known": np.flatnonzero(sub.fixed),
            }
        )
    return [{**base, "solver": s, **_solve(sub, geo, nlos, s, iterations, ctx)} for s in solvers]


def _aggregate(rows: list[dict[str, Any]], solvers: list[str]) -> list[dict[str, Any]]:
    out = []
    for scenario, placement, s in ((c, p, s) for c in SCENARIOS for p in PLACEMENTS for s in solvers):
        rs = [r for r in rows if r["scenario"] == scenario and r["placement"] == placement and r["solver"] == s]
        if not rs:
            continue
        ok = [r for r in rs if r["status"] != "diverged"]
        rm = float(np.mean([r["rmse_m"] for r in ok])) if ok else float("nan")
        orc = float(np.mean([r["oracle_rmse_m"] for r in rs]))
        careful = float(np.mean([r["careful_rmse_m"] for r in rs]))
        nw = [r["rmse_m_not_weak"] for r in ok if np.isfinite(r["rmse_m_not_weak"])]
        not_weak = float(np.mean(nw)) if nw else float("nan")  # halls whose every anchor is weak: left out
        tp, nl = sum(r["tp"] for r in rs), sum(r["nlos"] for r in rs)
        fp, los = sum(r["fp"] for r in rs), sum(r["los"] for r in rs)
        ch, cn = sum(r["cov_hit"] for r in rs), sum(r["cov_n"] for r in rs)
        chs, cns = sum(r["cov_hit_not_weak"] for r in rs), sum(r["cov_n_not_weak"] for r in rs)
        statuses: dict[str, int] = {}
        for r in rs:
            statuses[r["status"]] = statuses.get(r["status"], 0) + 1
        ratio = rm / orc if orc > 0 else float("nan")
        cov = ch / cn if cn else None
        out.append(
            {
                "scenario": scenario,
                "placement": placement,
                "solver": s,
                "instances": len(rs),
                "rmse_m": rm,
                "rmse_m_median": float(np.median([r["rmse_m"] for r in ok])) if ok else float("nan"),
                "rmse_m_not_weak": not_weak,
                "weak_anchors": int(sum(r["weak"] for r in rs)),
                "oracle_rmse_m": orc,
                "rmse_ratio": ratio,
                "careful_rmse_m": careful,
                "rmse_vs_careful": rm / careful if careful > 0 else float("nan"),
                "rmse_ratio_not_weak": not_weak / orc if orc > 0 else float("nan"),
                "not_worse_than_careful": int(sum(r["rmse_m"] <= r["careful_rmse_m"] + 1e-3 for r in ok)),
                "recall": tp / nl if nl else None,
                "false_alarm": fp / los if los else None,
                "coverage_2sigma": cov,
                "coverage_2sigma_not_weak": chs / cns if cns else None,
                "statuses": statuses,
                "objective": rs[0]["objective"],
                "messages": float(np.mean([r["messages"] for r in rs])),
                "bytes": float(np.mean([r["bytes"] for r in rs])),
                "gather_bytes": float(np.mean([r["gather_bytes"] for r in rs])),
                "cpu_s_per_solve": float(np.mean([r["cpu_s"] for r in rs])),
                "meets": {
                    "rmse": bool(ratio <= TARGETS["rmse_ratio_max"]),
                    "recall": bool(nl and tp / nl >= TARGETS["recall_min"]),
                    "false_alarm": bool(los and fp / los <= TARGETS["false_alarm_max"]),
                    "coverage": None if cov is None else bool(TARGETS["coverage"][0] <= cov <= TARGETS["coverage"][1]),
                },
            }
        )
    return out


def _fmt(v: Any, spec: str) -> str:
    return "–" if v is None or (isinstance(v, float) and not np.isfinite(v)) else format(v, spec)


def _table_md(table: list[dict[str, Any]]) -> str:
    out = [
        "# uwb-field: simulated industrial halls (targets: RMSE ≤ 1.15 × oracle, recall ≥ 90 %, false alarms "
        "≤ 5 %, 2σ coverage 90–98 %)",
        "",
        "| scenario | known | solver | objective | RMSE [m] | careful scipy fit [m] | halls ≤ careful | "
        "oracle [m] | "
        "ratio | ratio without weak | recall | false alarms | 2σ coverage | 2σ coverage without weak | "
        "statuses | weak anchors | RMSE without them [m] | messages | bytes | gather bytes | CPU s |",
        "|---" * 21 + "|",
    ]
    for r in table:
        out.append(
            f"| {r['scenario']} | {r['placement']} | {r['solver']} | {r['objective']} | "
            f"{_fmt(r['rmse_m'], '.3f')} | {_fmt(r['careful_rmse_m'], '.3f')} | "
            f"{r['not_worse_than_careful']} of {r['instances']} | "
            f"{_fmt(r['oracle_rmse_m'], '.3f')} | {_fmt(r['rmse_ratio'], '.2f')} | "
            f"{_fmt(r['rmse_ratio_not_weak'], '.2f')} | {_fmt(r['recall'], '.3f')} | "
            f"{_fmt(r['false_alarm'], '.3f')} | {_fmt(r['coverage_2sigma'], '.3f')} | "
            f"{_fmt(r['coverage_2sigma_not_weak'], '.3f')} | "
            f"{', '.join(f'{k} {v}' for k, v in r['statuses'].items())} | {r['weak_anchors']} | "
            f"{_fmt(r['rmse_m_not_weak'], '.3f')} | {r['messages']:.0f} | "
            f"{r['bytes']:.0f} | {r['gather_bytes']:.0f} | {r['cpu_s_per_solve']:.2f} |"
        )
    return "\n".join(out) + "\n"


def _figure(ctx: ExperimentContext, table: list[dict[str, Any]], example: dict[str, Any]) -> None:
    plt = pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(13, 4.8))
    ax = axes[0]
    labels = [f"{r['solver']}\n{r['scenario']} {r['placement']}" for r in table]
    x = np.arange(len(table))
    ax.bar(x - 0.27, [r["rmse_m"] for r in table], 0.27, label="solver (with exclusion)")
    ax.bar(x, [r["careful_rmse_m"] for r in table], 0.27, label="careful scipy fit (no truth)")
    ax.bar(x + 0.27, [r["oracle_rmse_m"] for r in table], 0.27, label="oracle (NLOS removed by truth)")
    ax.set_xticks(x, labels, fontsize=7, rotation=35, ha="right")  # upright, the 8 labels ran into each other
    ax.set_yscale("log")
    ax.set_ylabel("mean RMSE [m]")
    ax.legend(fontsize=8)
    ax.set_title("RMSE vs the oracle")
    ax = axes[1]
    if example:
        t, lk, nl = example["truth"], example["links"], example["nlos"]
        for (i, j), f in zip(lk.tolist(), nl, strict=True):
            ax.plot(t[[i, j], 0], t[[i, j], 1], "-", color="tab:red" if f else "0.75", lw=1.4 if f else 0.6)
        ax.plot(t[:, 0], t[:, 1], "o", color="tab:blue", ms=4, label="anchor")
        k = example["known"]
        ax.plot(t[k, 0], t[k, 1], "^", color="k", ms=8, label="known anchor")
        ax.set_aspect("equal")
        ax.set_title(f"first hall: {int(nl.sum())} NLOS links (red) of {len(nl)}")
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
        ax.legend(fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.2), ncol=2)  # off the map
    ctx.save_figure(fig, "fig_uwb_field.png")
