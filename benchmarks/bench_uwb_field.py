"""Timing of the real-data workflow (issue 13): one ``uwb solve`` with QC on the APRIL network and on a 28-anchor
simulated hall, and a 1,000-anchor hall, against a bare scipy floor measured in the same run (one
``scipy.optimize.least_squares`` Cauchy fit of the same problem from the same start, no QC; on the 1,000-anchor
hall with the analytic sparse Jacobian).

    python benchmarks/bench_uwb_field.py [--big] [--profile] [--out bench_uwb_field.json]

``--profile`` (with ``--big``): the 1,000-anchor case under cProfile (CPU clock), its time split into the parts
of the QC pipeline (LM's linear solves, the covariance and w-tests, the rigidity test, the per-anchor check, the
MDS start) in the table and the JSON.

Prints a table; CPU time (``time.process_time``) is listed beside wall time because the machine is shared.
"""

from __future__ import annotations

import argparse
import cProfile
import json
import pstats
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
from scipy.optimize import least_squares

from distnav.experiments.uwb_field import hall_problem
from distnav.models.uwb.field import FieldOptions, prepare, solve_field
from distnav.models.uwb.hall import PLANT_LIKE, HallConfig, simulate_hall
from distnav.models.uwb.problems import RangingProblem

_REPO = Path(__file__).resolve().parents[1]
APRIL = next(
    (
        c / "shared" / "data" / "uwb" / "april-dw1000-8node" / "dataset4.txt"
        for c in (_REPO.parent, _REPO.parent.parent)
        if (c / "shared" / "data").is_dir()
    ),
    Path("absent"),
)


SPARSE_FLOOR_ANCHORS = 200


def _timed(fn: Any) -> tuple[Any, float, float]:
    w0, c0 = time.perf_counter(), time.process_time()
    out = fn()
    return out, time.perf_counter() - w0, time.process_time() - c0


def _scipy_floor(p: RangingProblem) -> float:
    """CPU seconds of one scipy Cauchy fit of the same residuals (metres) from the same start."""
    assert p.initial_m is not None
    x0 = p.to_vector(p.initial_m)

    def resid(x: np.ndarray) -> np.ndarray:
        pos = p.to_positions(x)
        return np.asarray(np.linalg.norm(pos[p.meas_a] - pos[p.meas_b], axis=1) - p.range_m)

    if p.n_anchors <= SPARSE_FLOOR_ANCHORS:
        _, _, cpu = _timed(lambda: least_squares(resid, x0, loss="cauchy", f_scale=0.3, method="trf"))
        return cpu
    # a large network: the analytic sparse Jacobian (trf with LSMR), as anyone fitting 1,000 anchors would; the
    # default finite-difference dense Jacobian and its SVD take minutes there and floor nothing

    def jac(x: np.ndarray) -> Any:
        return p.jacobian_m(p.to_positions(x))

    _, _, cpu = _timed(lambda: least_squares(resid, x0, jac=jac, loss="cauchy", f_scale=0.3, method="trf"))
    return cpu


PARTS = {  # part of the pipeline -> (file suffix, function name) whose cumulative CPU time it is
    "lm_linear_solves": ("nlsq.py", "solve"),
    "covariance_w_tests": ("ranging_qc.py", "centralized_quality"),
    "rigidity": ("geometry.py", "flexible_anchors"),
    "per_anchor_check": ("local.py", "repair_exclusions"),
    "mds_start": ("initial.py", "mds_initial_guess"),
}


def _split(prof: cProfile.Profile) -> dict[str, float]:
    """Cumulative CPU seconds of the :data:`PARTS` functions in a profile."""
    stats: dict[Any, Any] = vars(pstats.Stats(prof))["stats"]  # {(file, line, name): (cc, nc, tt, ct, callers)}
    out = dict.fromkeys(PARTS, 0.0)
    for (fname, _, func), (_, _, _, ct, _) in stats.items():
        for part, (suffix, name) in PARTS.items():
            if fname.endswith(suffix) and func == name:
                out[part] += ct
    return out


def _row(name: str, p: RangingProblem, profile: bool = False) -> dict[str, Any]:
    prof = cProfile.Profile(time.process_time) if profile else None
    if prof is not None:
        prof.enable()
    (sub, geo), w_prep, c_prep = _timed(lambda: prepare(p))
    sol, w_sol, c_sol = _timed(lambda: solve_field(sub, FieldOptions(), geometry=geo))
    if prof is not None:
        prof.disable()
    floor = _scipy_floor(sub)
    return {
        "case": name,
        "anchors": p.n_anchors,
        "links": p.n_meas,
        "wall_s": w_prep + w_sol,
        "cpu_s": c_prep + c_sol,
        "cpu_prepare_s": c_prep,
        "cpu_solve_qc_s": c_sol,
        "scipy_floor_cpu_s": floor,
        "ratio_to_floor": (c_prep + c_sol) / max(floor, 1e-9),
        "excluded": int(sol.excluded.sum()),
        "status": sol.status,
        **({"profiled_cpu_s": _split(prof)} if prof is not None else {}),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--big", action="store_true", help="also the 1,000-anchor hall (tens of seconds)")
    ap.add_argument("--profile", action="store_true", help="with --big: the big case under cProfile, split by part")
    ap.add_argument("--out", type=Path, default=Path("bench_uwb_field.json"))
    args = ap.parse_args()
    rows = []
    if APRIL.is_file():
        from distnav.commands.uwb import solve_range_log, write_april_csvs

        with tempfile.TemporaryDirectory() as d:
            f = write_april_csvs(APRIL, d, known=[8, 12, 54, 87])
            (_, _, s), w, c = _timed(
                lambda: solve_range_log(f["ranges"], f["known"], options=FieldOptions(range_offsets="common"))
            )
            rows.append(
                {
                    "case": "APRIL dataset4, uwb solve incl. reading 21,504 samples",
                    "anchors": 7,
                    "links": s["n_pairs"],
                    "wall_s": w,
                    "cpu_s": c,
                    "status": s["status"],
                    "excluded": s["n_excluded"],
                }
            )
    rows.append(_row("hall, 28 anchors (middle), dense", hall_problem(simulate_hall(np.random.default_rng(1)))[0]))
    for seed in (1, 2, 3):
        plant = simulate_hall(np.random.default_rng(seed), HallConfig().with_(**PLANT_LIKE))
        rows.append(_row(f"hall, 28 anchors (middle), plant-like #{seed}", hall_problem(plant)[0]))
    if args.big:
        big = simulate_hall(np.random.default_rng(2), n_anchors=1000, length_m=400.0, width_m=200.0)
        rows.append(_row("hall, 1000 anchors (400 m × 200 m), heights held", hall_problem(big)[0], args.profile))
    args.out.write_text(json.dumps(rows, indent=2) + "\n")
    print(f"{'case':55s} {'wall s':>8s} {'CPU s':>8s} {'floor CPU s':>12s} {'ratio':>7s}")
    for r in rows:
        fl = r.get("scipy_floor_cpu_s")
        print(
            f"{r['case']:55s} {r['wall_s']:8.2f} {r['cpu_s']:8.2f} {fl if fl is not None else float('nan'):12.3f} "
            f"{r.get('ratio_to_floor', float('nan')):7.1f}"
        )
        for part, cpu in r.get("profiled_cpu_s", {}).items():
            print(f"    {part:51s} {'':8s} {cpu:8.2f}  (under cProfile)")


if __name__ == "__main__":
    main()
