"""Issue 28, sixth session: where the default ``uwb solve`` loses accuracy on :data:`PLANT_HARD` halls — the headroom
between the default and oracles that know what a real run cannot (docs/uwb.md, "Where the hard plant's accuracy is
lost").

Per hall (``[34, k]``, the fifth session's 50 halls, each solved with the four known anchors in the middle and in a
corner; the command's own path, :func:`distnav.commands.uwb.solve_range_log`, heights given) the default's RMSE
against LM fits (:func:`distnav.algorithms.ranging.lm.solve_lm`, no exclusions, started at the truth so that no
start or basin is in the comparison) on link sets and ranges that peel one error source off at a time:

1. ``kept``: the default's own kept links, the default's final loss (one-sided Cauchy at 0.3 m, a common offset);
2. ``kept_minus_missed``: those without the NLOS links the default missed (what the missed ones cost);
3. ``oracle_nlos`` (a): every LOS link, no NLOS link (what the false exclusions cost: 2 → 3);
4. ``oracle_nlos_linear``: (a) with the linear loss (what the one-sided Cauchy loss costs: 3 → 4);
5. ``oracle_offsets`` (b): (a) linear, the ranges corrected by the true antenna delays, no offset estimated;
6. ``oracle_noise``: (b) with the LOS links' own range biases removed too: the sample noise alone.

and the linearized predictions at the truth (c), from the simulator's error model per link (the LOS bias
N(0, ``los_bias_sd_m``²), the per-node delays ``(δ_a + δ_b)/2`` with ``δ ~ N(c, antenna_delay_sd_m²)``, the median
of ``n`` samples of N(0, σ²): variance ``πσ²/(2n)``), covariance ``C`` of the LOS links' errors, Jacobian ``J`` of the
free coordinates (and the common offset):

* ``crlb_common_lsq``: the sandwich ``(JᵀJ)⁻¹JᵀCJ(JᵀJ)⁻¹`` — what (a) linear should give;
* ``crlb_gls``: ``(JᵀC⁻¹J)⁻¹`` — the bound of any unbiased estimator that knew ``C`` (the delays as random effects);
* ``crlb_offsets``: ``C`` without the delays, no offset column — what (b) should give;
* ``crlb_noise``: the sample noise alone — what ``oracle_noise`` should give;
* ``default_sigma``: the default run's own σ (``√(mean σx² + σy²)``, the formal precision it reports).

Every figure is ``√(mean over the estimated anchors of ‖x̂ − x‖²)``, then the median and the 90th percentile over the
halls of a placement and the RMS over them; a prediction's median and 90th percentile are those of its Monte Carlo
draws (:data:`DRAWS` per hall, ``e ~ N(0, C)`` through the linearized estimator, pooled over the halls), its RMS the
analytic ``√(tr GCGᵀ / n)`` (the held heights' survey error counted in both).

    python benchmarks/bench_uwb_headroom.py [--quick]      # quick: 2 halls per placement (default 50)
"""

from __future__ import annotations

import dataclasses
import json
import os
import sys
import tempfile
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import RESULTS, main_for  # noqa: E402
from distnav.algorithms.ranging.lm import solve_lm  # noqa: E402
from distnav.commands.uwb import solve_range_log  # noqa: E402
from distnav.experiments.uwb_field import write_hall  # noqa: E402
from distnav.models.uwb.field_options import subset_measurements  # noqa: E402
from distnav.models.uwb.hall import PLANT_HARD, HallNetwork, simulate_hall  # noqa: E402
from distnav.models.uwb.problems import RangingProblem  # noqa: E402

PLACEMENTS = ("middle", "corner")
FITS = ("kept", "kept_minus_missed", "oracle_nlos", "oracle_nlos_linear", "oracle_offsets", "oracle_noise")
PREDICTIONS = ("crlb_common_lsq", "crlb_gls", "crlb_offsets", "crlb_noise", "default_sigma")
DRAWS = 200  # Monte Carlo draws of the linearized estimators per hall
GOALS_M = {"middle": 0.18, "corner": 0.50}  # the held-out plant's targets (issue 28)


def link_truth(p: RangingProblem, h: HallNetwork) -> dict[str, np.ndarray]:
    """Per measurement of ``p`` (its ids matched to the hall's): NLOS label, the delays' part ``(δ_a + δ_b)/2``, the
    LOS bias, the true distance and the sample count (the simulator's labels: no run has them)."""
    at = {(h.ids[a], h.ids[b]): k for k, (a, b) in enumerate(h.links)}
    k = np.array(
        [
            at.get((p.ids[a], p.ids[b]), at.get((p.ids[b], p.ids[a]), -1))
            for a, b in zip(p.meas_a, p.meas_b, strict=True)
        ]
    )
    if np.any(k < 0):
        raise AssertionError("a measured pair that the hall did not simulate")
    off = dict(zip(h.ids, h.offset_m, strict=True))
    los_bias = h.los_bias_m if h.los_bias_m is not None else np.zeros(h.links.shape[0])
    return {
        "nlos": h.nlos[k],
        "delay_m": np.array([0.5 * (off[p.ids[a]] + off[p.ids[b]]) for a, b in zip(p.meas_a, p.meas_b, strict=True)]),
        "los_bias_m": los_bias[k],
        "distance_m": h.distance_m[k],
        "samples": h.samples_per_link[k],
    }


def _rmse(p: RangingProblem, pos: np.ndarray) -> float:
    assert p.truth_m is not None
    est = p.estimated
    return float(np.sqrt(np.mean(np.sum((pos[est] - p.truth_m[est]) ** 2, axis=1))))


def _fit(p: RangingProblem, keep: np.ndarray, loss: str, offsets: str, ranges_m: np.ndarray | None = None) -> float:
    """LM on the links ``keep`` (ranges replaced by ``ranges_m`` if given), started at the truth, no exclusions."""
    q = subset_measurements(p if ranges_m is None else _with_ranges(p, ranges_m), keep)
    res = solve_lm(
        q,
        initial_m=p.truth_m,
        objective="metres",
        sigma_m=0.1,
        range_offsets=offsets,
        loss=loss,
        loss_scale_m=0.3,
        quality=False,
    )
    return _rmse(p, np.asarray(res.estimates, float))


def _with_ranges(p: RangingProblem, ranges_m: np.ndarray) -> RangingProblem:
    return dataclasses.replace(p, range_m=np.asarray(ranges_m, float))


def _jacobian(p: RangingProblem, keep: np.ndarray, common: bool) -> np.ndarray:
    """∂‖x_a − x_b‖/∂(free coordinates of the estimated anchors) at the truth, rows ``keep`` (+ a column of ones)."""
    assert p.truth_m is not None
    a, b = p.meas_a[keep], p.meas_b[keep]
    u = p.truth_m[a] - p.truth_m[b]
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    col = -np.ones(p.free.shape, np.int64)
    col[p.free] = np.arange(int(p.free.sum()))
    J = np.zeros((a.size, int(p.free.sum()) + int(common)))
    rows = np.arange(a.size)
    for d in range(p.dim):
        for end, sign in ((a, 1.0), (b, -1.0)):
            c = col[end, d]
            ok = c >= 0
            np.add.at(J, (rows[ok], c[ok]), sign * u[ok, d])
    if common:
        J[:, -1] = 1.0
    return J


def error_covariances(p: RangingProblem, h: HallNetwork, t: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """The covariance of the LOS links' range errors by the simulator's model: ``noise`` (the median of ``n``
    samples), ``los_bias`` (one draw per link), ``delays`` (``(δ_a + δ_b)/2``, the common part left out: it is
    estimated)."""
    cfg = h.config
    keep = ~t["nlos"]
    a, b = p.meas_a[keep], p.meas_b[keep]
    A = np.zeros((a.size, p.n_anchors))
    A[np.arange(a.size), a] = 0.5
    A[np.arange(a.size), b] = 0.5
    return {
        "noise": np.diag(0.5 * np.pi * cfg.sigma_m**2 / t["samples"][keep]),
        "los_bias": cfg.los_bias_sd_m**2 * np.eye(a.size),
        "delays": cfg.antenna_delay_sd_m**2 * A @ A.T,
    }


def linear_estimators(p: RangingProblem, h: HallNetwork, t: dict[str, np.ndarray]) -> dict[str, tuple[Any, Any]]:
    """Per prediction (module docstring): ``(G, C)`` — the linearized estimator's error ``δx = G e`` (the free
    coordinates' rows) and the covariance ``C`` of the LOS links' errors ``e`` it sees."""
    keep = ~t["nlos"]
    c = error_covariances(p, h, t)
    full = c["noise"] + c["los_bias"] + c["delays"]
    J1 = _jacobian(p, keep, common=True)
    J0 = _jacobian(p, keep, common=False)
    n_free = int(p.free.sum())
    lsq1 = np.linalg.solve(J1.T @ J1, J1.T)[:n_free]
    ci_j = np.linalg.solve(full, J1)
    gls = np.linalg.solve(J1.T @ ci_j, ci_j.T)[:n_free]
    lsq0 = np.linalg.solve(J0.T @ J0, J0.T)
    return {
        "crlb_common_lsq": (lsq1, full),
        "crlb_gls": (gls, full),
        "crlb_offsets": (lsq0, c["noise"] + c["los_bias"]),
        "crlb_noise": (lsq0, c["noise"]),
    }


def predictions(
    p: RangingProblem, h: HallNetwork, t: dict[str, np.ndarray], rng: np.random.Generator, draws: int
) -> dict[str, Any]:
    """Per linearized estimator: its RMS error ``√(tr GCGᵀ / n + s²)`` (``s`` the held heights' survey sd) and
    ``draws`` Monte Carlo RMSE values of the hall (``e ~ N(0, C)``, the held heights' survey errors drawn too), so
    that the halls' pooled draws give the predicted median and 90th percentile."""
    n_est = int(p.estimated.sum())
    held = int(np.sum(~p.free[p.estimated]))
    s = h.config.height_survey_sd_m
    out: dict[str, Any] = {}
    for name, (G, C) in linear_estimators(p, h, t).items():
        out[name] = float(np.sqrt((np.trace(G @ C @ G.T) + held * s**2) / n_est))
        L = np.linalg.cholesky(C + 1e-15 * np.eye(C.shape[0]))
        dx = G @ (L @ rng.standard_normal((C.shape[0], draws)))
        sq = np.sum(dx**2, axis=0) + s**2 * np.sum(rng.standard_normal((held, draws)) ** 2, axis=0)
        out[f"{name}_draws"] = np.sqrt(sq / n_est).tolist()
    return out


def hall(job: tuple[int, str], draws: int = DRAWS) -> dict[str, Any]:
    """One PLANT_HARD hall ``[34, seed]`` with the known anchors at ``placement``: the default and every oracle."""
    seed, placement = job
    h = simulate_hall(np.random.default_rng([34, seed]), None, **PLANT_HARD, known=placement)
    with tempfile.TemporaryDirectory() as d:
        f = write_hall(h, d)
        sol, _, _ = solve_range_log(f["ranges"], f["known"], heights=f["heights"], truth=f["truth"])
    p = sol.problem
    t = link_truth(p, h)
    nlos, excl = t["nlos"], np.asarray(sol.excluded, bool)
    kept, missed = ~excl, nlos & ~excl
    corrected = p.range_m - t["delay_m"]
    out: dict[str, Any] = {
        "seed": seed,
        "placement": placement,
        "default": _rmse(p, sol.positions_m) if sol.usable else float("nan"),
        "kept": _fit(p, kept, "cauchy_long", "common"),
        "kept_minus_missed": _fit(p, kept & ~missed, "cauchy_long", "common"),
        "oracle_nlos": _fit(p, ~nlos, "cauchy_long", "common"),
        "oracle_nlos_linear": _fit(p, ~nlos, "linear", "common"),
        "oracle_offsets": _fit(p, ~nlos, "linear", "none", corrected),
        "oracle_noise": _fit(p, ~nlos, "linear", "none", corrected - t["los_bias_m"]),
        **predictions(p, h, t, np.random.default_rng([35, seed, PLACEMENTS.index(placement)]), draws),
        "nlos_links": int(nlos.sum()),
        "nlos_named": int((nlos & excl).sum()),
        "nlos_missed": int(missed.sum()),
        "false_named": int((~nlos & excl).sum()),
    }
    est = p.estimated
    sig = np.asarray(sol.sigma_m, float)[est][:, :2]
    out["default_sigma"] = float(np.sqrt(np.mean(np.sum(sig**2, axis=1)))) if sol.usable else float("nan")
    return out


def run(quick: bool) -> list[dict[str, Any]]:
    n = 2 if quick else 50
    jobs = [(s, place) for s in range(n) for place in PLACEMENTS]
    workers = int(os.environ.get("DISTNAV_BENCH_WORKERS", min(2, os.cpu_count() or 1)))
    with ProcessPoolExecutor(max_workers=workers) as pool:
        runs = list(pool.map(hall, jobs))
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "uwb_headroom_runs.json").write_text(json.dumps(runs, indent=1, default=float) + "\n")
    return headroom_rows(runs)


def headroom_rows(runs: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per placement and figure: the median and 90th percentile RMSE over the halls (a prediction: over its pooled
    Monte Carlo draws), the RMS over the halls (a prediction: of its analytic values) and the halls where a fit is
    at most the default's."""
    rows = []
    for place in PLACEMENTS:
        r = [x for x in runs if x["placement"] == place]
        base = np.array([x["default"] for x in r])
        for key in ("default", *FITS, *PREDICTIONS):
            v = np.array([x[key] for x in r])
            pooled = np.concatenate([x[f"{key}_draws"] for x in r]) if f"{key}_draws" in r[0] else v
            row: dict[str, Any] = {
                "name": f"{place}: {key}",
                "halls": len(r),
                "median_m": float(np.nanmedian(pooled)),
                "p90_m": float(np.nanpercentile(pooled, 90)),
                "rms_m": float(np.sqrt(np.nanmean(v**2))),
            }
            if key in FITS:
                row["le_default"] = int(np.sum(v <= base + 1e-12))
            rows.append(row)
        rows.append(
            {
                "name": f"{place}: NLOS named / missed / false",
                "halls": len(r),
                "nlos": sum(x["nlos_links"] for x in r),
                "named": sum(x["nlos_named"] for x in r),
                "missed": sum(x["nlos_missed"] for x in r),
                "false": sum(x["false_named"] for x in r),
                "goal": f"default median ≤ {GOALS_M[place]} m (the held-out plant's target)",
                "meets_goal": bool(np.nanmedian(base) <= GOALS_M[place]),
            }
        )
    return rows


if __name__ == "__main__":
    main_for(__file__, run)
