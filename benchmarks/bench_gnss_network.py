"""GNSS bias product on the mid-latitude network simulator (issue 14): accuracy against the truth, old vs new.

Three receivers 200–520 km apart in central Europe (:data:`distnav.models.gnss.netsim.EUROPEAN_STATIONS`), the
synthetic 31-satellite constellation, a thick-shell VTEC field with a diurnal peak, a poleward gradient and a
travelling wave (day-to-day amplitude ±10 %), elevation-dependent code noise and multipath (the same pattern
every day), constant satellite and receiver DSBs (the same every day), an SVN49-like G01. Per simulated day:

* the **new** default (`gnss ionosphere`: levelling, screening, receiver + satellite DCBs, zero-mean datum) and
  the **first-wave** model (between-satellite differences, pivot, paper 003's random walk) on the same data;
* full day and four 6-h sessions: RMS of the satellite DSB errors after removing the mean (without G01, as the
  held-out test), the receiver DSB errors in the same datum, the worst-fitting satellite;
* over the days: the median per-satellite standard deviation (repeatability); the realistic σ against the error
  (truth; per day ``rms(error)/median(σ)`` and the RMS of error/σ) and against the day-to-day scatter
  (RMS over satellites of std-over-days/σ; blind to what the days share, e.g. the repeating multipath);
* one day again with 0.2 % gross P1 errors at one receiver: the largest DSB change.

Targets (issue 14, held-out network): full day ≤ 0.30 ns, 6-h ≤ 0.45 ns, receivers within 0.7 ns, repeatability
≤ 0.12 ns, gross errors move no DSB by more than 0.1 ns. Quick: 2 days, sessions of the first day only.
"""

from __future__ import annotations

import sys
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import main_for  # noqa: E402
from distnav.algorithms.kalman import iterate_information_filter  # noqa: E402
from distnav.commands.gnss_ionosphere import NetworkOptions, network_from_observations
from distnav.models.gnss.biasmodel import BiasModelOptions  # noqa: E402
from distnav.models.gnss.gfbias import gf_m_per_dsb_ns  # noqa: E402
from distnav.models.gnss.gfnetwork import BiasFilterOptions, final_dsbs, run_bias_filters, satellite_fit  # noqa: E402
from distnav.models.gnss.ionosphere import (  # noqa: E402
    GeometryFreeSeries,
    IonosphereStateLayout,
    ionosphere_dynamics,
)
from distnav.models.gnss.netsim import REALISTIC, NetworkSimOptions, VtecField, simulate_network, truth_product  # noqa: E402
from distnav.models.gnss.orbits import synthetic_gps_constellation  # noqa: E402
from distnav.models.gnss.products import compare_in_datum  # noqa: E402

SESSIONS = ((0, 6), (6, 12), (12, 18), (18, 24))
NEW_OPTIONS: dict[str, Any] = {}
"""Extra :class:`~distnav.models.gnss.biasmodel.BiasModelOptions` of the new default (none: the CLI defaults)."""
EXCLUDE = ("G01",)


def _cut(obs: list[Any], h0: float, h1: float) -> list[Any]:
    out = []
    for o in obs:
        s = (o.time - o.time[0]).astype("timedelta64[s]").astype(float)
        k = (s >= h0 * 3600.0) & (s < h1 * 3600.0)
        out.append(
            replace(
                o,
                time=o.time[k],
                range_m={b: v[k] for b, v in o.range_m.items()},
                phase_m={b: v[k] for b, v in o.phase_m.items()},
                lli={b: v[k] for b, v in o.lli.items()},
            )
        )
    return out


def _new(
    obs: list[Any], orbit: Any, options: dict[str, Any] | None = None
) -> tuple[dict[str, float], dict[str, float], dict[str, float], Any]:
    model = BiasModelOptions(**(NEW_OPTIONS if options is None else options))
    data = network_from_observations(obs, orbit, NetworkOptions(l2_code="C2W", interval_s=60.0, model=model))
    series, _ = run_bias_filters(data, BiasFilterOptions(local=False))
    sat, rx, sd = final_dsbs(data, series[0])
    return sat, rx, sd, (series[0], data)


def _old(obs: list[Any], orbit: Any) -> dict[str, float]:
    """The first-wave model on the same levelled data: between-satellite differences (receiver bias eliminated
    per epoch), pivot G10 or the most tracked satellite, paper 003's random walk (1 mm/√s), independent epochs, one σ
    for all stations."""
    data = network_from_observations(
        obs,
        orbit,
        NetworkOptions(
            l2_code="C2W", interval_s=60.0, arc_correlation_s=0.0, model=BiasModelOptions(station_weighting="off")
        ),
    )
    geo, svs = data.geometry, data.layout.svs
    piv = "G10" if "G10" in svs else svs[int(np.argmax(geo.tracked.sum(axis=(0, 1))))]
    lay = IonosphereStateLayout(svs, piv, data.layout.n_ionospheres)
    ser = GeometryFreeSeries(
        lay, geo.coefficients, data.sigma_m, obs_m=data.obs_m, tracked=geo.tracked, groups=geo.groups
    )
    dyn = ionosphere_dynamics(lay, np.concatenate([[np.nan], np.diff(data.t_gps_s)]))
    last = list(iterate_information_filter(dyn, ser, mode="central"))[-1]
    x, est, col = last.estimates[0], last.estimable[0], lay.dcb_column()
    scale = gf_m_per_dsb_ns(2)
    return {
        s: (0.0 if col[j] < 0 else -float(x[col[j]]) / scale) for j, s in enumerate(svs) if col[j] < 0 or est[col[j]]
    }


def _score(sat: dict[str, float], rx: dict[str, float], prod: Any) -> dict[str, Any]:
    c = compare_in_datum(sat, rx, prod, exclude=EXCLUDE)
    out = {
        "n": c["n"],
        "rms_ns": c["rms_zero_mean_ns"],
        "max_ns": c["max_abs_zero_mean_ns"],
        "worst": c["worst"],
        "difference_ns": c["difference_ns"],
    }
    if "receivers" in c:
        out["receivers_ns"] = c["receivers"]["difference_ns"]
    return out


def _z_rms(sc: dict[str, Any], sd: dict[str, float]) -> float:
    errs = np.array(list(sc["difference_ns"].values()))
    return float(np.sqrt(np.mean((errs / np.array([sd[s] for s in sc["difference_ns"]])) ** 2)))


def run(
    quick: bool,
    preset: str = "default",
    models: tuple[str, ...] = ("new", "old"),
    days: int | None = None,
    options: dict[str, Any] | None = None,
    label: str = "new default",
) -> list[dict[str, Any]]:
    """The rows of the table; ``preset`` "realistic" simulates with :data:`~distnav.models.gnss.netsim.REALISTIC`
    (``bench_gnss_realistic.py``), ``models`` / ``days`` narrow the run (calibration); ``options`` replace
    :data:`NEW_OPTIONS` of the new model (e.g. ``{"tec_order": 2}``), named ``label`` in the row."""
    knobs = dict(REALISTIC) if preset == "realistic" else {}
    orbit = synthetic_gps_constellation(epoch="2024-01-10T00:00:00")
    truth_rng = np.random.default_rng(2024)
    sat_truth = {s: float(v) for s, v in zip(orbit.svs, truth_rng.normal(0.0, 3.0, len(orbit.svs)), strict=True)}
    rx_truth = {"SIMA": 5.3, "SIMB": -7.1, "SIMC": 1.8}
    days = days or (2 if quick else 5)
    rows: list[dict[str, Any]] = []
    full: dict[str, list[dict[str, Any]]] = {"new": [], "old": []}
    sess: dict[str, list[float]] = {"new": [], "old": []}
    sess_n: dict[str, list[int]] = {"new": [], "old": []}
    rx_err: list[float] = []
    sigma_ratio: list[float] = []
    sigma_z: list[float] = []
    sess_z: list[float] = []
    sigmas: list[dict[str, float]] = []
    worst: list[str] = []
    t_start = time.perf_counter()
    for d in range(days):
        day = np.datetime64("2024-01-10") + np.timedelta64(d, "D")
        amp = 1.0 + 0.1 * np.random.default_rng([d, 99]).standard_normal()
        fld = VtecField(day_tecu=16.0 * amp, night_tecu=4.0 * amp)
        sim = simulate_network(
            orbit,
            day,
            NetworkSimOptions(field=fld, **knobs),
            rng=np.random.default_rng([d, 1]),
            satellite_dsb_ns=sat_truth,
            receiver_dsb_ns=rx_truth,
        )
        prod = truth_product(sim)
        if "new" in models:
            sat, rx, sd, (c, data) = _new(sim.observations, orbit, options)
            sc = _score(sat, rx, prod)
            sigma_z.append(_z_rms(sc, sd))
            sigmas.append(sd)
            full["new"].append(sc)
            rx_err += list(sc["receivers_ns"].values())
            errs = np.array(list(sc["difference_ns"].values()))
            sds = np.array([sd[s] for s in sc["difference_ns"]])
            sigma_ratio.append(float(np.sqrt(np.mean(errs**2)) / np.median(sds)))
            wf = satellite_fit(data, c).worst()
            worst.append(wf[0] if wf else "")
        if "old" in models:
            full["old"].append(_score(_old(sim.observations, orbit), {}, prod))
        if d == 0 or not quick:
            for h0, h1 in SESSIONS:
                part = _cut(sim.observations, h0, h1)
                scores = {}
                if "new" in models:
                    s_sat, s_rx, s_sd, _ = _new(part, orbit, options)
                    scores = {"new": _score(s_sat, s_rx, prod)}
                    sess_z.append(_z_rms(scores["new"], s_sd))
                if "old" in models:
                    scores["old"] = _score(_old(part, orbit), {}, prod)
                for m, sc_m in scores.items():
                    sess[m].append(sc_m["rms_ns"])
                    sess_n[m].append(int(sc_m["n"]))
        if d == 0 and "new" in models:
            dirty = simulate_network(
                orbit,
                day,
                NetworkSimOptions(field=fld, gross_fraction=0.002, **knobs),
                rng=np.random.default_rng([d, 1]),
                satellite_dsb_ns=sat_truth,
                receiver_dsb_ns=rx_truth,
            )
            g_sat, g_rx, _, _ = _new(dirty.observations, orbit, options)
            common = [s for s in sat if s in g_sat]
            gross_move = max(abs(g_sat[s] - sat[s]) for s in common)
            gross_move = max(gross_move, *(abs(g_rx[r] - rx[r]) for r in rx))
    seconds = time.perf_counter() - t_start
    for model in models:
        fr = [f["rms_ns"] for f in full[model]]
        common = sorted(set.intersection(*(set(f["difference_ns"]) for f in full[model])))
        spread = {s: float(np.std([f["difference_ns"][s] for f in full[model]], ddof=1)) for s in common}
        rep = np.median(list(spread.values()))
        row: dict[str, Any] = {
            "name": f"simulated network{' (realistic)' if knobs else ''}, "
            f"{label if model == 'new' else 'first-wave model'}",
            "days": days,
            "full_day_rms_ns": [round(v, 3) for v in fr],
            "six_hour_rms_ns": [round(v, 3) for v in sess[model]],
            "six_hour_median_ns": round(float(np.median(sess[model])), 3),
            "six_hour_satellites_compared": sess_n[model],
            "repeatability_median_ns": round(float(rep), 3),
        }
        if model == "new":
            scatter = np.sqrt(np.mean([(spread[s] / np.median([sd[s] for sd in sigmas])) ** 2 for s in common]))
            row.update(
                {
                    "receiver_dsb_error_ns": [round(v, 3) for v in rx_err],
                    "realistic_sigma_vs_truth_error": [round(v, 2) for v in sigma_ratio],
                    "error_over_sigma_rms": [round(v, 2) for v in sigma_z],
                    "six_hour_error_over_sigma_rms_median": round(float(np.median(sess_z)), 2),
                    "day_to_day_scatter_over_sigma_rms": round(float(scatter), 2),
                    "worst_fitting": worst,
                    "gross_errors_max_change_ns": round(float(gross_move), 4),
                    "seconds": round(seconds, 1),
                }
            )
            row["meets_goal"] = bool(
                max(fr) <= 0.30
                and np.median(sess[model]) <= 0.45
                and max(abs(v) for v in rx_err) <= 0.7
                and rep <= 0.12
                and gross_move <= 0.1
            )
            row["goal"] = "full ≤ 0.30, 6-h ≤ 0.45, receivers ≤ 0.7, repeatability ≤ 0.12, gross ≤ 0.1 ns"
        rows.append(row)
    return rows


if __name__ == "__main__":
    main_for(__file__, run)
