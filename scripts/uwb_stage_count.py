"""Where a whole N-CLM ``uwb solve`` workflow's bytes go, per stage (issue 27, docs/economy_uwb.md items 47-).

Usage: ``PYTHONPATH=src python scripts/uwb_stage_count.py hard|like SEED_K PLACEMENT [...]`` — one simulated hall
(``hard``: ``PLANT_HARD`` with seed ``[34, k]``; ``like``: ``PLANT_LIKE`` with ``[78, k]``), ``solve_field``'s
defaults. Every distributed fit is counted (bytes, messages, LM-phase rounds, CG iterations) under the stage that
called it: the first fit, the tightening, the exclusion loop, the per-anchor check's re-solves (``repair``), the
completion of an early-stopped fit (``complete``), the revert's reference fit, the polish; σ and reliability are the
rest of the solution's total. Monkeypatches ``solve_once`` in the modules that import it: a measurement, not a test.
"""

from __future__ import annotations

import sys
from collections import defaultdict
from collections.abc import Callable
from typing import Any

import numpy as np

from distnav.experiments.uwb_field import hall_problem
from distnav.models.uwb import field, field_fits, field_run, field_steps
from distnav.models.uwb.field import FieldOptions, gather_cost, prepare, solve_field
from distnav.models.uwb.hall import PLANT_HARD, PLANT_LIKE, HallConfig, simulate_hall

_STAGE = ["other"]
_ROWS: dict[str, list[int]] = defaultdict(lambda: [0, 0, 0, 0])  # fits, bytes, rounds, CG iterations


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
        r = inner(*args, **kw)
        ref = (getattr(r, "settings", None) or {}).get("refine") or {}
        row = _ROWS[_STAGE[0] if kw.get("start") != "first" else "first_fit"]
        row[0] += 1
        row[1] += (total[2] - before) if total is not None else 0
        row[2] += int(ref.get("rounds", 0))
        row[3] += int(ref.get("cg_iterations", 0))
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


if __name__ == "__main__":
    _install()
    args = sys.argv[1:]
    for i in range(0, len(args), 3):
        count(args[i], int(args[i + 1]), args[i + 2])
