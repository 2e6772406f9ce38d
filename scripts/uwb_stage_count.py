"""Where a whole N-CLM ``uwb solve`` workflow's bytes go, per stage (issue 27, docs/economy_uwb.md items 47-).

Usage: ``PYTHONPATH=src python scripts/uwb_stage_count.py hard|like SEED_K PLACEMENT [...]`` — one simulated hall
(``hard``: ``PLANT_HARD`` with seed ``[34, k]``; ``like``: ``PLANT_LIKE`` with ``[78, k]``), ``solve_field``'s
defaults. Every distributed fit is counted (bytes, messages, LM-phase rounds, CG iterations) under the stage that
called it: the first fit, the tightening, the exclusion loop, the per-anchor check's re-solves (``repair``), the
completion of an early-stopped fit (``complete``), the revert's reference fit, the polish; σ and reliability are the
rest of the solution's total. Monkeypatches ``solve_once`` in the modules that import it: a measurement, not a test.

``scaled N OUT`` (issue 27, tenth session): the whole solve of ``benchmarks/bench_uwb_economy.py`` section 3 on its
hall of ``N`` anchors (``_solve_row``'s set-up and per-anchor accounting: every fit's broadcasts plus its
reductions over the capped tree), split by step *and* by the fit's own stage (``seed``, ``refit`` — 1 cm —,
``rung`` — 3 mm —, ``full``): per step the network's bytes, the busiest anchor's (of the whole solve) and the
largest any anchor sent in it, LM rounds and CG iterations; the σ apart. ``OUT`` (``-``: none): a ``.npz`` with
every fit's step, per-anchor bytes, per-anchor move (end − start) and the links it fitted, for the regional study.
"""

from __future__ import annotations

import sys
from collections import defaultdict
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from distnav.experiments.uwb_field import hall_problem
from distnav.models.uwb import field, field_fits, field_run, field_steps
from distnav.models.uwb.field import FieldOptions, gather_cost, prepare, solve_field
from distnav.models.uwb.hall import PLANT_HARD, PLANT_LIKE, HallConfig, simulate_hall

_STAGE = ["other"]
_ROWS: dict[str, list[int]] = defaultdict(lambda: [0, 0, 0, 0])  # fits, bytes, rounds, CG iterations
#: ``scaled``: the benchmark module (its per-fit counters ``_FITS``) and one record per fit
_BENCH: list[Any] = [None]
_LOG: list[dict[str, Any]] = []


def _staged(name: str, fn: Callable[..., Any]) -> Callable[..., Any]:
    def wrapped(*args: Any, **kw: Any) -> Any:
        outer = _STAGE[0]
        _STAGE[0] = name
        try:
            return fn(*args, **kw)
        finally:
            _STAGE[0] = outer

    return wrapped


def _install() -> None:
    inner = field_fits.solve_once

    def counted(*args: Any, **kw: Any) -> Any:
        total = kw.get("total")
        before = total[2] if total is not None else 0
        fits_before = len(_BENCH[0]._FITS) if _BENCH[0] is not None else 0
        r = inner(*args, **kw)
        ref = (getattr(r, "settings", None) or {}).get("refine") or {}
        step = _STAGE[0] if kw.get("start") != "first" else "first_fit"
        row = _ROWS[step]
        row[0] += 1
        row[1] += (total[2] - before) if total is not None else 0
        row[2] += int(ref.get("rounds", 0))
        row[3] += int(ref.get("cg_iterations", 0))
        if _BENCH[0] is not None:
            problem = args[0]
            _LOG.append(
                {
                    "step": step,
                    "stage": kw.get("stage") or ("first" if kw.get("start") == "first" else "full"),
                    "bytes": (total[2] - before) if total is not None else 0,
                    "rounds": int(ref.get("rounds", 0)),
                    "cg": int(ref.get("cg_iterations", 0)),
                    "fits": (fits_before, len(_BENCH[0]._FITS)),
                    "move_m": np.linalg.norm(np.asarray(r.estimates) - problem.initial_m, axis=1).astype(np.float32),
                    "links": np.asarray(problem.links, np.int32),
                }
            )
        return r

    for mod in (field, field_fits, field_steps):
        mod.solve_once = counted  # type: ignore[attr-defined]
    field.tighten_scale = _staged("tighten", field.tighten_scale)  # type: ignore[attr-defined]
    field._exclusions = _staged("exclusion loop", field._exclusions)  # type: ignore[attr-defined]
    field._repair = _staged("repair", field._repair)  # type: ignore[attr-defined]
    field.polish_fit = _staged("polish", field.polish_fit)  # type: ignore[attr-defined]
    field.complete = _staged("complete", field.complete)  # type: ignore[attr-defined]
    field_run.complete = _staged("complete", field_run.complete)  # type: ignore[attr-defined]
    field.FieldRun.reference_ratio = _staged("revert ref", field.FieldRun.reference_ratio)  # type: ignore[method-assign]


def count(kind: str, k: int, place: str) -> None:
    _ROWS.clear()
    if kind == "hard":
        hall = simulate_hall(np.random.default_rng([34, k]), None, **PLANT_HARD, known=place)
    else:
        hall = simulate_hall(np.random.default_rng([78, k]), HallConfig().with_(known=place, **PLANT_LIKE))
    sub, geo = prepare(hall_problem(hall)[0])
    sol = solve_field(sub, FieldOptions(solver="N-CLM"), geometry=geo)
    yard = int(gather_cost(sub)["bytes"])
    print(f"{kind} [{34 if kind == 'hard' else 78},{k}] {place}: {sol.bytes / 1e3:.1f} kB = {sol.bytes / yard:.1f} x")
    print(f"  {'stage':15s} {'fits':>4s} {'kB':>7s} {'rounds':>6s} {'CG its':>6s}")
    fitted = 0
    for name, (n, b, rounds, cg) in _ROWS.items():
        fitted += b
        print(f"  {name:15s} {n:4d} {b / 1e3:7.1f} {rounds:6d} {cg:6d}")
    print(f"  {'σ + reliability':15s} {'':4s} {(sol.bytes - fitted) / 1e3:7.1f}")
    print(f"  excluded {int(np.sum(sol.excluded))} links; {sol.status}")


def scaled(n: int, out: str) -> None:
    """Section 3's whole solve at ``n`` anchors by step and stage, per anchor (module docstring)."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
    import bench_uwb_economy as bench
    from distnav.network.graph import Graph

    bench._counting()
    _BENCH[0] = bench
    _ROWS.clear()
    _LOG.clear()
    for kept in (bench._SENT, bench._FITS, bench._SIGMA, bench._TREES):
        kept.clear()
    p, start = bench._scaled_hall(n)
    sigma = "gathered" if n <= bench.GATHERED_SIGMA_MAX else "subnetwork"
    opts = FieldOptions(solver="N-CLM", distributed_precision=sigma, reliability_limit_m=0.0)
    sol = solve_field(p.with_initial(start), opts, geometry=None)
    tree = bench._tree_sends(Graph.from_links(n, p.links), "capped") / max(2 * (n - 1), 1)
    fits = [b + tree * reduced for b, reduced in bench._FITS]
    sigma_sent = np.sum(bench._SIGMA, axis=0) if bench._SIGMA else np.zeros(n)
    sent = np.sum(fits, axis=0) + sigma_sent
    busiest = int(np.argmax(sent))
    groups: dict[str, list[Any]] = {}
    for rec in _LOG:
        per = np.sum(fits[rec["fits"][0] : rec["fits"][1]], axis=0) if rec["fits"][1] > rec["fits"][0] else 0 * tree
        rec["sent"] = per.astype(np.float32)
        g = groups.setdefault(f"{rec['step']}: {rec['stage']}", [0, 0, 0 * tree, 0, 0])
        g[0] += 1
        g[1] += rec["bytes"]
        g[2] = g[2] + per
        g[3] += rec["rounds"]
        g[4] += rec["cg"]
    miss = (sol.positions_m - p.truth_m)[p.estimated]
    print(
        f"scaled {n}: {sol.bytes / 1e6:.2f} MB, {len(_LOG)} fits, busiest anchor {busiest}: {sent.max() / 1e3:.1f} kB"
    )
    print(f"  (median {np.median(sent) / 1e3:.1f} kB), excluded {int(sol.excluded.sum())}, {sol.status}")
    print(f"  RMSE {np.sqrt(np.mean(np.sum(miss * miss, axis=1))):.5f} m")
    print(f"  {'step: stage':28s} {'fits':>4s} {'MB':>9s} {'busiest kB':>10s} {'max kB':>7s} {'rounds':>6s} {'CG':>6s}")
    for name, (k, b, per, rounds, cg) in groups.items():
        print(
            f"  {name:28s} {k:4d} {b / 1e6:9.2f} {per[busiest] / 1e3:10.1f} {per.max() / 1e3:7.1f} {rounds:6d} {cg:6d}"
        )
    print(f"  {'σ':28s} {'':4s} {'':9s} {sigma_sent[busiest] / 1e3:10.1f} {sigma_sent.max() / 1e3:7.1f}")
    if out != "-":
        np.savez_compressed(
            out,
            steps=np.array([f"{r['step']}: {r['stage']}" for r in _LOG]),
            sent=np.array([r["sent"] for r in _LOG]),
            move_m=np.array([r["move_m"] for r in _LOG]),
            links=np.concatenate([r["links"] for r in _LOG]),
            link_counts=np.array([len(r["links"]) for r in _LOG]),
            sigma_sent=sigma_sent,
            positions_m=sol.positions_m,
            truth_m=p.truth_m,
            estimated=p.estimated,
            all_links=np.asarray(p.links),
            excluded=np.asarray(sol.excluded),
        )
    _BENCH[0] = None


if __name__ == "__main__":
    _install()
    args = sys.argv[1:]
    for i in range(0, len(args), 3):
        if args[i] == "scaled":
            scaled(int(args[i + 1]), args[i + 2])
        else:
            count(args[i], int(args[i + 1]), args[i + 2])
