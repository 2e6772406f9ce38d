"""Stress test of ``distnav uwb solve``'s default workflow (issue 13) on simulated halls unlike the simulator's
defaults: each variation changes :class:`~distnav.models.uwb.hall.HallConfig` on top of ``PLANT_LIKE`` (one at a
time, then a few combined), with the 4 known anchors in the middle and in a corner, heights given.

Per hall: the hall is written to files (``HallNetwork.write``) and solved by the command's own path
(:func:`distnav.commands.uwb.solve_range_log`, default options, ``--heights``), beside two references written
independently of distnav's solvers:

* the **careful fit** (issue 13's "careful centralized scipy fit", ``experiments.uwb_field.careful_fit``, the one
  ``reproduce uwb-field`` uses; bit-identical to the copy this bench first had): medians per pair, classical MDS of the
  horizontal ranges (shortest paths for missing pairs), Procrustes (SVD, reflection allowed) onto the known
  anchors, ``scipy.optimize.least_squares`` on the residual in metres, linear then Cauchy ``f_scale`` 0.3 m;
* the **oracle**: the LOS links only (NLOS removed by the truth), linear least squares with one common range
  offset, started at the truth.

Reported per variation and placement: mean RMSE of distnav / careful / oracle, halls where distnav is worse than
the careful fit by > 1 cm, NLOS recall and false alarms of the exclusions, 2σ coverage, anchors reported weak,
and **silent misses**: anchors > 0.3 m and > 3 × their horizontal σ off that distnav reports as plainly
``estimated`` (a wrong answer that looks right).

    python benchmarks/bench_uwb_stress.py [--quick] [--halls N] [--seed-base K] [--only NAME ...] [--jobs J]
                                          [--out FILE.json]

``--delay-sigma-m``: ``uwb solve --delay-sigma-m`` instead of its default. ``--quick``: 3 halls per variation and
placement (default 12). ``--seed-base K``: halls ``K … K+N−1`` of each row (seed ``[2026, variation, placement,
hall]``; default 0, the bench seeds; 100 with ``--halls 6`` gives the held-out seeds rules are checked on). CPU
time per solve is listed (shared machine).
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np
from scipy.optimize import least_squares

from distnav._blas import single_threaded_blas
from distnav.commands.uwb import solve_range_log
from distnav.experiments import uwb_field
from distnav.experiments.uwb_field import write_hall
from distnav.models.uwb.field import FieldOptions
from distnav.models.uwb.hall import PLANT_LIKE, HallConfig, HallNetwork, simulate_hall

BAD_M = 0.3  # an anchor this far off counts as wrong
PLACEMENTS = ("middle", "corner")


def _scaled(n: int) -> dict[str, object]:
    f = float(np.sqrt(n / 28.0))
    return {"n_anchors": n, "length_m": 60.0 * f, "width_m": 30.0 * f}


VARIATIONS: dict[str, dict[str, object]] = {
    "baseline (plant-like)": {},
    "NLOS 5 %": {"nlos_p1": 0.08},
    "NLOS 20 %": {"nlos_p1": 0.33},
    "NLOS excess 0.3-0.6 m": {"nlos_bias_m": (0.3, 0.6)},
    "NLOS excess 0.3-3 m": {"nlos_bias_m": (0.3, 3.0)},
    "NLOS bimodal (50 % of samples long)": {"nlos_long_fraction": 0.5},
    "NLOS bimodal (70 % of samples long)": {"nlos_long_fraction": 0.7},
    "heights surveyed ±2 cm": {"height_survey_sd_m": 0.02},
    "heights surveyed ±5 cm": {"height_survey_sd_m": 0.05},
    "delays 5 cm": {"antenna_delay_sd_m": 0.05},
    "delays 10 cm": {"antenna_delay_sd_m": 0.10},
    "delays 10 cm + common 0.3 m": {"antenna_delay_sd_m": 0.10, "common_offset_m": 0.3},
    "short session (3-10 samples)": {"attempts": 10, "min_samples": 3},
    "noise 0.15 m per sample": {"sigma_m": 0.15},
    "gross samples (10 % of links, 3 × ±2-5 m)": {"gross_link_fraction": 0.1},
    "asymmetric pairs (a→b − b→a ~ N(0, 0.2²) m)": {"asymmetry_sd_m": 0.2},
    "narrow hall 120 × 14 m (2 rows)": {"length_m": 120.0, "width_m": 14.0},
    "known anchors along one wall (near-collinear)": {"known_on_wall": True},
    "20 anchors": _scaled(20),
    "40 anchors": _scaled(40),
    "combined: NLOS 20 % + bimodal + short": {
        "nlos_p1": 0.33,
        "nlos_long_fraction": 0.7,
        "attempts": 10,
        "min_samples": 3,
    },
    "combined: delays 10 cm + 0.3 m + heights 5 cm + noise 0.1": {
        "antenna_delay_sd_m": 0.10,
        "common_offset_m": 0.3,
        "height_survey_sd_m": 0.05,
        "sigma_m": 0.10,
    },
    "combined: gross + asymmetric + excess 0.3-3 m": {
        "gross_link_fraction": 0.1,
        "asymmetry_sd_m": 0.2,
        "nlos_bias_m": (0.3, 3.0),
    },
}


def _medians(h: HallNetwork) -> np.ndarray:
    """Median of every link's samples (both directions pooled), in ``h.links`` order."""
    order = np.argsort(h.sample_link, kind="stable")
    cuts = np.cumsum(h.samples_per_link)[:-1]
    return np.array([np.median(g) for g in np.split(h.range_m[order], cuts)])


def _heights(h: HallNetwork) -> np.ndarray:
    z = h.surveyed_z_m.copy()
    z[h.known] = h.truth_m[h.known, 2]  # known.csv carries the true position of the known anchors
    return z


def careful_fit(h: HallNetwork) -> np.ndarray:
    """Issue 13's careful centralized fit (``experiments.uwb_field.careful_fit``, written independently of distnav's
    solvers) on the problem ``uwb solve`` builds from the hall's files; positions ``(n, 3)``, surveyed heights held."""
    return uwb_field.careful_fit(uwb_field.hall_problem(h)[0])


def oracle_fit(h: HallNetwork) -> np.ndarray:
    """LOS links only (the truth's labels), linear least squares with a common offset, from the truth."""
    los = ~h.nlos
    (i, j), d = h.links[los].T, _medians(h)[los]
    z = _heights(h)
    est = np.setdiff1d(np.arange(h.n_anchors), h.known)

    def pos(x: np.ndarray) -> np.ndarray:
        out = np.column_stack([h.truth_m[:, :2], z])
        out[est, :2] = x[:-1].reshape(-1, 2)
        return out

    def res(x: np.ndarray) -> np.ndarray:
        q = pos(x)
        return np.asarray(np.linalg.norm(q[i] - q[j], axis=1) + x[-1] - d)

    return pos(least_squares(res, np.r_[h.truth_m[est, :2].ravel(), 0.0], method="trf").x)


def _rmse(h: HallNetwork, pos: np.ndarray, rows: np.ndarray) -> float:
    e = pos[rows] - h.truth_m[rows]
    return float(np.sqrt(np.mean(np.sum(e * e, axis=1))))


def one_hall(job: tuple[str, str, int, float | None]) -> dict[str, Any]:
    """Solve one hall of variation ``name`` with ``placement`` known by distnav, the careful fit and the oracle."""
    with single_threaded_blas():  # two workers on 2 shared cores: OpenBLAS threads only cost CPU here
        return _one_hall(job)


def _one_hall(job: tuple[str, str, int, float | None]) -> dict[str, Any]:
    name, placement, k, delay_sigma_m = job
    opts = FieldOptions() if delay_sigma_m is None else FieldOptions(delay_sigma_m=delay_sigma_m)
    vi = list(VARIATIONS).index(name)
    cfg = HallConfig().with_(**{**PLANT_LIKE, "known": placement, **VARIATIONS[name]})
    h = simulate_hall(np.random.default_rng([2026, vi, PLACEMENTS.index(placement), k]), cfg)
    est = np.setdiff1d(np.arange(h.n_anchors), h.known)
    with tempfile.TemporaryDirectory() as d:
        f = write_hall(h, d)
        c0 = time.process_time()
        try:
            sol, _, summ = solve_range_log(
                f["ranges"], f["known"], heights=f["heights"], truth=f["truth"], options=opts
            )
        except Exception as err:  # a refused geometry is an answer too (exit 2): count it, keep going
            return {
                "variation": name,
                "placement": placement,
                "hall": k,
                "error": f"{type(err).__name__}: {err}",
                "careful_rmse_m": _rmse(h, careful_fit(h), est),
                "oracle_rmse_m": _rmse(h, oracle_fit(h), est),
            }
        cpu = time.process_time() - c0
    ids = list(h.ids)
    pos = np.full((h.n_anchors, 3), np.nan)
    sig = np.full((h.n_anchors, 3), np.nan)
    p = sol.problem
    idx = np.array([ids.index(x) for x in p.ids])
    if sol.usable:
        pos[idx], sig[idx] = sol.positions_m, sol.sigma_m
    amb = set(sol.geometry.ambiguous_anchors())
    marked = np.array([x in sol.weak or x in amb or x not in p.ids for x in ids])
    err = np.linalg.norm(pos - h.truth_m, axis=1)
    link_of = {
        (min(ids.index(p.ids[a]), ids.index(p.ids[b])), max(ids.index(p.ids[a]), ids.index(p.ids[b]))): m
        for m, (a, b) in enumerate(zip(p.meas_a, p.meas_b, strict=True))
    }
    nlos = np.array(
        [bool(h.nlos[np.flatnonzero((h.links[:, 0] == a) & (h.links[:, 1] == b))[0]]) for (a, b) in link_of]
    )
    ex = np.array([bool(sol.excluded[m]) for m in link_of.values()])
    solved = np.isfinite(err) & ~np.isin(np.arange(h.n_anchors), h.known)
    ok = solved[:, None] & (sig > 0) & np.isfinite(sig)
    ok[:, 2] = False  # heights held
    hit = np.abs(pos - h.truth_m) <= 2.0 * sig
    sig_h = np.nan_to_num(np.hypot(sig[:, 0], sig[:, 1]), nan=0.0)
    careful, oracle = careful_fit(h), oracle_fit(h)
    return {
        "variation": name,
        "placement": placement,
        "hall": k,
        "status": sol.status,
        "cpu_s": cpu,
        "rmse_m": _rmse(h, pos, est) if sol.usable else float("nan"),
        "careful_rmse_m": _rmse(h, careful, est),
        "oracle_rmse_m": _rmse(h, oracle, est),
        "links": int(h.links.shape[0]),
        "nlos": int(h.nlos.sum()),
        "tp": int((ex & nlos).sum()),
        "fp": int((ex & ~nlos).sum()),
        "cov_hit": int(hit[ok].sum()),
        "cov_n": int(ok.sum()),
        "weak": int(marked[est].sum()),
        "bad": int((err[est] > BAD_M).sum()),
        "silent_bad": int(((err > BAD_M) & (err > 3.0 * sig_h) & ~marked)[est].sum()),
        "unsolved": len(ids) - len(p.ids),
        "excluded": int(summ["n_excluded"]),
    }


def aggregate(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    out = []
    for name in VARIATIONS:
        for pl in PLACEMENTS:
            g = [r for r in rows if r["variation"] == name and r["placement"] == pl]
            if not g:
                continue
            ok = [r for r in g if "error" not in r]

            def mean(key: str, rs: list[dict[str, Any]] = ok) -> float:
                v = [r[key] for r in rs if np.isfinite(r[key])]
                return float(np.mean(v)) if v else float("nan")

            nl, los = sum(r["nlos"] for r in ok), sum(r["links"] - r["nlos"] for r in ok)
            out.append(
                {
                    "variation": name,
                    "placement": pl,
                    "halls": len(g),
                    "refused": len(g) - len(ok),
                    "rmse_m": mean("rmse_m"),
                    "careful_rmse_m": mean("careful_rmse_m", g),
                    "oracle_rmse_m": mean("oracle_rmse_m", g),
                    "worse_than_careful": sum(r["rmse_m"] > r["careful_rmse_m"] + 0.01 for r in ok),
                    "recall": sum(r["tp"] for r in ok) / max(nl, 1),
                    "false_alarm": sum(r["fp"] for r in ok) / max(los, 1),
                    "coverage_2s": sum(r["cov_hit"] for r in ok) / max(sum(r["cov_n"] for r in ok), 1),
                    "weak": sum(r["weak"] for r in ok),
                    "bad": sum(r["bad"] for r in ok),
                    "silent_bad": sum(r["silent_bad"] for r in ok),
                    "cpu_s": mean("cpu_s"),
                }
            )
    return out


def table(agg: list[dict[str, Any]]) -> str:
    head = (
        "| variation | known | distnav RMSE [m] | careful fit [m] | oracle [m] | ratio to oracle | halls worse "
        "than careful (> 1 cm) | recall | false alarms | 2σ coverage | weak | anchors > 0.3 m off | of them "
        "silent | CPU s |"
    )
    lines = [head, "|" + "---|" * 14]
    for r in agg:
        lines.append(
            f"| {r['variation']} | {r['placement']} | {r['rmse_m']:.3f} | {r['careful_rmse_m']:.3f} | "
            f"{r['oracle_rmse_m']:.3f} | {r['rmse_m'] / max(r['oracle_rmse_m'], 1e-9):.2f} | "
            f"{r['worse_than_careful']} of {r['halls']}"
            + (f" ({r['refused']} refused)" if r["refused"] else "")
            + f" | {r['recall']:.2f} | {r['false_alarm']:.3f} | {r['coverage_2s']:.2f} | {r['weak']} | "
            f"{r['bad']} | {r['silent_bad']} | {r['cpu_s']:.2f} |"
        )
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="3 halls per variation and placement")
    ap.add_argument("--halls", type=int, default=None, help="halls per variation and placement (default 12)")
    ap.add_argument(
        "--seed-base", type=int, default=0, help="first hall seed of each row (default 0; held-out checks: 100)"
    )
    ap.add_argument("--only", nargs="+", default=None, help="variations whose name starts with one of these")
    ap.add_argument(
        "--delay-sigma-m", type=float, default=None, help="uwb solve's --delay-sigma-m (default: its own default)"
    )
    ap.add_argument("--jobs", type=int, default=min(2, os.cpu_count() or 1))
    ap.add_argument("--out", type=Path, default=Path("bench_uwb_stress.json"))
    args = ap.parse_args()
    n = args.halls or (3 if args.quick else 12)
    names = [v for v in VARIATIONS if not args.only or any(v.startswith(o) for o in args.only)]
    seeds = range(args.seed_base, args.seed_base + n)
    jobs = [(v, pl, k, args.delay_sigma_m) for v in names for pl in PLACEMENTS for k in seeds]
    c0, w0 = time.process_time(), time.perf_counter()
    if args.jobs > 1:
        with ProcessPoolExecutor(args.jobs) as pool:
            rows = list(pool.map(one_hall, jobs, chunksize=2))
    else:
        rows = [one_hall(j) for j in jobs]
    agg = aggregate(rows)
    args.out.write_text(
        json.dumps(
            {
                "halls_per_group": n,
                "seed_base": args.seed_base,
                "bad_m": BAD_M,
                "table": agg,
                "runs": rows,
                "wall_s": time.perf_counter() - w0,
                "cpu_s_main": time.process_time() - c0,
                "load_average": os.getloadavg(),
            },
            indent=1,
        )
        + "\n"
    )
    print(table(agg))


if __name__ == "__main__":
    main()
