"""GNSS ionosphere and DCB network by consensus Kalman filter: the Perth experiment of paper 003 §5.

Scenario (paper 003 §5.2, Fig. 8): 13 receivers around Perth (−32°, 116° E) with data links between receivers up to
4 km apart (receivers 1, 3, 13 with the fewest neighbours, 4, 7, 8, 9 with the most; 1 is linked to 2 and 6, and is
8 km from 3), tracking GPS from 08:00 to 24:00 Perth time on 2016-06-02 (00:00–16:00 GPS time) at Δ = 60 s
(960 epochs), 10° elevation mask, pivot PRN 10. The satellites come from the synthetic 31-satellite constellation of
:func:`distnav.models.gnss.orbits.synthetic_gps_constellation` (PRN 4 absent, as in the paper) — *not* the real
2016 geometry, so the satellite visibility differs from the paper's Fig. 10.

Model: :mod:`distnav.models.gnss.ionosphere` (eq. (49): vertical delay ν_o and gradients ν_φ, ν_ψ of a regional
single layer, between-satellite DCBs; σ = 65.6 cm/sin θ; random walk 1 mm/√s and 5 mm/rad/√s; constant DCBs).

Outputs (``DIR``):

* Fig. 11 (``fig11_central_vs_local.png``): standard deviations of the central and the single-receiver (receiver 1)
  solutions of ν_o, ν_φ, ν_ψ from one hour after the start, and their ratios; the initial ratio √13.
* Fig. 12 (``fig12_ckf_to_central.png``): CKF-to-central standard-deviation ratios per receiver from the Fig. 7
  recursion for δ = 15 s (k_n = 4) and δ = 5 s (k_n = 12); protocol 3.
* Fig. 13 (``fig13_dcb_time_boxplots.png``): box plots (min, p25, median, p75, max) of the time each
  between-satellite DCB needs to reach a standard deviation below 0.5 ns, central and per receiver, for
  δ = 15, 10, 5 s (k_n = 4, 6, 12). The time is counted from the first epoch at which the network tracks the
  satellite (the same origin for every filter), in minutes of data.
* ``ckf_truth.png``: one simulated realization run through the CKF (k_n = 4): estimates minus truth inside ±3σ.
* ``results.json`` with the headline numbers.

DCB units: ``dcb_ns`` = ``DSB^s − DSB^p`` of the L1−L2 code pair, i.e. the geometry-free bias divided by
``c/(μ₂−μ₁)`` (0.4634 m/ns) — the unit of the published DCB products. (Dividing by ``c`` instead, 0.2998 m/ns, is
also reported, as the paper does not say which it used.)
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from distnav.algorithms.consensus.averaging import consensus_product, consensus_schedule
from distnav.algorithms.kalman import DynamicModel, FilterSeries, central_filter, local_filters
from distnav.algorithms.kalman.ckf import ckf, ckf_error_variance, consensus_rounds
from distnav.errors import ModelError
from distnav.experiments.common import ExperimentContext, pyplot
from distnav.models.gnss.ionosphere import (
    GF_M_PER_DSB_NS,
    TECU_L1_M,
    GeometryFreeSeries,
    GeometryOptions,
    IonosphereGeometry,
    IonosphereStateLayout,
    geometry_free_series,
    ionosphere_dynamics,
    ionosphere_geometry,
    simulate_geometry_free,
)
from distnav.models.gnss.orbits import gps_seconds, synthetic_gps_constellation
from distnav.network.graph import Graph
from distnav.options import nonnegative_int, positive_int

NAME = "ckf-ionosphere"
TITLE = "GNSS ionosphere + DCB network by consensus Kalman filter, 13 receivers in Perth (paper 003 §5, Figs. 8-13)"

PERTH_LAT_DEG = -32.0
PERTH_LON_DEG = 116.0
PERTH_HEIGHT_M = 20.0
PERTH_EAST_NORTH_KM = np.array(
    [
        [0.00, 7.88],
        [0.03, 4.39],
        [8.00, 7.98],
        [6.20, 5.99],
        [8.09, 5.03],
        [3.35, 7.19],
        [3.38, 4.87],
        [5.17, 4.47],
        [4.62, 1.49],
        [1.32, 2.00],
        [7.55, 3.04],
        [3.39, -0.22],
        [4.75, -1.30],
    ]
)
"""Receiver layout (east, north) in km, receivers 1..13; chosen so that the 4-km link rule reproduces the
neighbourhood pattern described for the paper's Fig. 8 (degrees 2, 3, 2, 6, 4, 4, 6, 6, 6, 4, 4, 3, 2)."""
LINK_RANGE_KM = 4.0
START_GPS = "2016-06-02T00:00:00"  # 08:00 Perth local time (UTC+8)
CONSTELLATION_EPOCH = "2018-01-09T22:40:00"
"""Reference epoch of the synthetic constellation: 80 min before the library default, so that the pivot PRN 10
rises at the very start of the session (over Perth it then stays up for 5.9 h), as the paper's pivot must have
been; with the default epoch PRN 10 rises only 80 min into the session and no DCB is estimable before."""
INTERVAL_S = 60.0
N_EPOCHS = 960
QUICK_EPOCHS = 150
SENDING_INTERVALS_S = (15.0, 10.0, 5.0)
PIVOT = "G10"
MASK_DEG = 10.0
PROTOCOL = "P3"
DCB_THRESHOLD_NS = 0.5
STEADY_AFTER_MIN = 60.0
PAPER = {
    "local_to_central_initial": float(np.sqrt(13.0)),
    "local_to_central_vtec_range": (1.5, 3.0),
    "local_to_central_grad_lat": 2.0,
    "local_to_central_grad_lon": 2.5,
    "dcb_time_to_0.5ns_min_central": {"min": 7.0, "p25": 12.0, "median": 38.0, "p75": 63.0, "max": 84.0},
}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--epochs",
        type=positive_int,
        default=None,
        help=f"number of 60-s epochs (default {N_EPOCHS}; --quick {QUICK_EPOCHS})",
    )
    parser.add_argument(
        "--data-kn",
        type=nonnegative_int,
        default=4,
        help="consensus rounds of the CKF run on simulated data (default 4 = δ 15 s)",
    )


# ----------------------------------------------------------------------------------------------- scenario
def perth_positions(*, colocated: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Geodetic ``(lat_rad, lon_rad)`` of the 13 receivers (centroid at −32°, 116° E); ``colocated`` puts all 13
    at the centroid (equal normal matrices: the local-to-central ratio is exactly √13 at the start)."""
    en = PERTH_EAST_NORTH_KM * 1e3
    en = en - en.mean(axis=0)
    if colocated:
        en = np.zeros_like(en)
    lat0, lon0 = np.deg2rad(PERTH_LAT_DEG), np.deg2rad(PERTH_LON_DEG)
    r = 6_371_000.0
    return lat0 + en[:, 1] / r, lon0 + en[:, 0] / (r * np.cos(lat0))


def perth_network(link_range_km: float = LINK_RANGE_KM) -> Graph:
    """The communication graph of Fig. 8: links between receivers at most ``link_range_km`` apart."""
    en = PERTH_EAST_NORTH_KM
    d = np.linalg.norm(en[:, None] - en[None], axis=2)
    a, b = np.nonzero(np.triu(d <= link_range_km, 1))
    g = Graph.from_links(
        len(en), np.stack([a, b], axis=1), names=[str(i + 1) for i in range(len(en))], positions=en * 1e3
    )
    g.require_connected()
    return g


def perth_scenario(
    n_epochs: int = N_EPOCHS,
    *,
    colocated: bool = False,
) -> tuple[IonosphereGeometry, IonosphereStateLayout, GeometryFreeSeries, DynamicModel]:
    """Geometry, state layout (satellites tracked at least once; pivot PRN 10), variance-only measurement series
    and dynamic model of the Perth network over ``n_epochs`` one-minute epochs."""
    if n_epochs < 2:
        raise ModelError(f"the Perth scenario needs at least 2 epochs, got {n_epochs}")
    const = synthetic_gps_constellation(epoch=CONSTELLATION_EPOCH)
    t = float(gps_seconds(np.datetime64(START_GPS, "ns"))) + INTERVAL_S * np.arange(n_epochs)
    lat, lon = perth_positions(colocated=colocated)
    geo0 = ionosphere_geometry(
        const, t, lat_rad=lat, lon_rad=lon, height_m=PERTH_HEIGHT_M, options=GeometryOptions(mask_deg=MASK_DEG)
    )
    seen = np.asarray(geo0.tracked.any(axis=(0, 1))).tolist()
    svs = tuple(s for s, k in zip(geo0.svs, seen, strict=True) if k)
    geo = ionosphere_geometry(
        const, t, lat_rad=lat, lon_rad=lon, height_m=PERTH_HEIGHT_M, svs=svs, options=GeometryOptions(mask_deg=MASK_DEG)
    )
    pivot = PIVOT if PIVOT in svs else svs[int(np.argmax(geo.tracked.sum(axis=(0, 1))))]
    layout = IonosphereStateLayout(svs, pivot)
    return geo, layout, geometry_free_series(geo, layout), ionosphere_dynamics(layout, INTERVAL_S)


def first_tracked_epoch(series: GeometryFreeSeries) -> np.ndarray:
    """Per satellite of the layout, the first epoch at which some receiver tracks it (−1 if never)."""
    tr = series.tracked.any(axis=1)  # (T, S)
    first = np.where(tr.any(axis=0), tr.argmax(axis=0), -1)
    return first


def dcb_time_to_threshold(
    std_m: np.ndarray,
    layout: IonosphereStateLayout,
    start_epoch: np.ndarray,
    *,
    threshold_ns: float = DCB_THRESHOLD_NS,
    interval_s: float = INTERVAL_S,
    m_per_ns: float = GF_M_PER_DSB_NS,
) -> np.ndarray:
    """Minutes from a satellite's first tracked epoch until its DCB's standard deviation drops below
    ``threshold_ns`` (``std_m`` (T, k, p) in metres of the observable; ``inf`` if never). Returns (k, m−1) in the
    order of ``layout.dcb_svs``."""
    col = layout.dcb_column()
    sv_idx = np.flatnonzero(col >= 0)
    T, k, _ = std_m.shape
    out = np.full((k, sv_idx.size), np.inf)
    for j, s in enumerate(sv_idx):
        st = start_epoch[s]
        if st < 0:
            continue
        below = np.nan_to_num(std_m[:, :, col[s]] / m_per_ns, nan=np.inf) < threshold_ns  # (T, k)
        below[:st] = False
        hit = below.any(axis=0)
        out[hit, j] = (below.argmax(axis=0)[hit] - st) * interval_s / 60.0
    return out


def box_stats(minutes: np.ndarray) -> dict[str, Any]:
    """min, p25, median, p75, max of the finite values (linear-interpolation percentiles) and the count of DCBs
    that never reached the threshold."""
    v = np.asarray(minutes, dtype=float)
    fin = v[np.isfinite(v)]
    if fin.size == 0:
        return {"min": None, "p25": None, "median": None, "p75": None, "max": None, "n": 0, "never": int(v.size)}
    q = np.percentile(fin, [0, 25, 50, 75, 100])
    return {
        "min": float(q[0]),
        "p25": float(q[1]),
        "median": float(q[2]),
        "p75": float(q[3]),
        "max": float(q[4]),
        "n": int(fin.size),
        "never": int(v.size - fin.size),
    }


def initial_ratio(local: FilterSeries, central: FilterSeries, node: int = 0, param: int = 0) -> tuple[float, int]:
    """Local-to-central std ratio of ``param`` at the first epoch at which both are estimable, and that epoch."""
    ok = np.isfinite(local.std[:, node, param]) & np.isfinite(central.std[:, 0, param])
    if not ok.any():
        raise ModelError("the parameter never becomes estimable by both filters")
    t = int(np.argmax(ok))
    return float(local.std[t, node, param] / central.std[t, 0, param]), t


# ----------------------------------------------------------------------------------------------- run
@dataclass(frozen=True, eq=False)
class PrecisionAnalysis:
    """The variance-only part of the reproduction (what the benchmark times): scenario, the central and local
    filters, the Fig. 7 recursion for every k_n, and the DCB times to 0.5 ns (minutes, ``inf`` = never)."""

    graph: Graph
    geometry: IonosphereGeometry
    layout: IonosphereStateLayout
    series: GeometryFreeSeries
    dynamics: DynamicModel
    kns: list[int]
    central: FilterSeries
    local: FilterSeries
    ckf: dict[int, FilterSeries]
    dcb_minutes_central: np.ndarray
    dcb_minutes_local: np.ndarray
    dcb_minutes_ckf: dict[int, np.ndarray]


def precision_analysis(
    n_epochs: int = N_EPOCHS, *, progress: Callable[[int], object] | None = None
) -> PrecisionAnalysis:
    """Central, local and CKF (Fig. 7, k_n = 4, 6, 12, protocol 3) standard deviations of the Perth network and the
    DCB times to 0.5 ns (paper 003 §5.3–5.4)."""
    graph = perth_network()
    geo, layout, series, dyn = perth_scenario(n_epochs)
    sched = consensus_schedule(graph, PROTOCOL)
    kns = [consensus_rounds(INTERVAL_S, d) for d in SENDING_INTERVALS_S]
    products = [consensus_product(sched, k) for k in kns]
    central = central_filter(dyn, series).series
    if progress:
        progress(1)
    local = local_filters(dyn, series).series
    if progress:
        progress(1)
    ckf_series = {k: ckf_error_variance(dyn, series, L) for k, L in zip(kns, products, strict=True)}
    if progress:
        progress(1)
    start = first_tracked_epoch(series)
    return PrecisionAnalysis(
        graph,
        geo,
        layout,
        series,
        dyn,
        kns,
        central,
        local,
        ckf_series,
        dcb_time_to_threshold(central.std, layout, start)[0],
        dcb_time_to_threshold(local.std, layout, start),
        {k: dcb_time_to_threshold(s.std, layout, start) for k, s in ckf_series.items()},
    )


def run(ctx: ExperimentContext) -> dict[str, Any]:
    from distnav.algorithms.kalman.gather_data import RECORDS_DATA, record_bytes_per_node
    from distnav.algorithms.result import compare_with_gather

    n_epochs = int(ctx.option("epochs", QUICK_EPOCHS if ctx.quick else N_EPOCHS, minimum=1))
    data_kn = int(ctx.option("data_kn", 4, minimum=0))
    with ctx.progress.task("ckf-ionosphere: central, local and CKF (Fig. 7) variance recursions", total=3) as adv:
        pa = precision_analysis(n_epochs, progress=adv)
    graph, geo, layout, series, dyn, kns = pa.graph, pa.geometry, pa.layout, pa.series, pa.dynamics, pa.kns
    n = graph.n_nodes
    central, local, ckf_series = pa.central, pa.local, pa.ckf
    cs, ls = central.std, local.std
    steady = int(STEADY_AFTER_MIN * 60.0 / INTERVAL_S)
    if steady >= n_epochs:
        steady = n_epochs // 2
    with np.errstate(invalid="ignore", divide="ignore"):
        local_ratio = ls[:, :, :3] / cs[:, :, :3]
        ckf_ratio = {k: s.std[:, :, :3] / cs[:, :, :3] for k, s in ckf_series.items()}

    # initial local-to-central ratio: Perth network (receiver 1) and the co-located check (equal normals)
    r0, t0 = initial_ratio(local, central)
    _, _, s_col, d_col = perth_scenario(min(n_epochs, 5), colocated=True)
    c_col = central_filter(d_col, s_col).series
    l_col = local_filters(d_col, s_col).series
    r0_col, t0_col = initial_ratio(l_col, c_col)

    # DCB time to 0.5 ns
    t_central, t_local, t_ckf = pa.dcb_minutes_central, pa.dcb_minutes_local, pa.dcb_minutes_ckf
    t_central_c = dcb_time_to_threshold(cs, layout, first_tracked_epoch(series), m_per_ns=0.299792458)[0]

    # one realization with data through the CKF
    rng = ctx.rng(1)
    truth, obs, _ = simulate_geometry_free(geo, layout, INTERVAL_S, rng=rng)
    data_series = geometry_free_series(geo, layout, obs_m=obs)
    with ctx.progress.task(f"ckf-ionosphere: CKF with k_n = {data_kn} on simulated data", total=1) as adv:
        res = ckf(
            dyn,
            data_series,
            graph=graph,
            protocol=PROTOCOL,
            rounds=data_kn,
            exchange=ctx.exchange(graph),
            monitor=False,
        )
        adv(1)
    ds = res.series
    with np.errstate(invalid="ignore"):
        z = (ds.estimates - truth[:, None, :]) / ds.std
    zf = z[np.isfinite(z)]
    within3 = float(np.mean(np.abs(zf) <= 3.0))
    rms_z = float(np.sqrt(np.mean(zf**2)))

    def steady_range(r: np.ndarray) -> tuple[float, float]:
        v = r[steady:]
        return float(np.nanmin(v)), float(np.nanmax(v))

    degrees = graph.degrees
    kmax = {str(k): float(np.nanmax(ckf_ratio[k][steady:])) for k in kns}
    per_rx_vtec = {str(k): np.nanmax(ckf_ratio[k][steady:, :, 0], axis=0).tolist() for k in kns}
    dcb_central = box_stats(t_central)
    results: dict[str, Any] = {
        "scenario": {
            "receivers": n,
            "links": graph.links.tolist(),
            "degrees": degrees.tolist(),
            "layout_east_north_km": PERTH_EAST_NORTH_KM.tolist(),
            "n_epochs": n_epochs,
            "interval_s": INTERVAL_S,
            "start_gps": START_GPS,
            "constellation": "synthetic 31-satellite GPS (PRN 4 absent)",
            "satellites_tracked": list(layout.svs),
            "n_satellites": len(layout.svs),
            "pivot": layout.pivot,
            "mask_deg": MASK_DEG,
            "protocol": PROTOCOL,
            "kn": kns,
            "sending_intervals_s": list(SENDING_INTERVALS_S),
            "satellites_rising_twice": _rerising(series, layout),
            "visibility_epochs": _visibility(series, layout),
            "units": {
                "tec": f"metres of L1 delay (vertical); 1 TECU = {TECU_L1_M:.4f} m",
                "dcb": "ns of the L1-L2 DSB difference DSB^s - DSB^p (0.4634 m of observable per ns)",
            },
        },
        "initial_local_to_central_ratio": r0,
        "initial_local_to_central_epoch": t0,
        "initial_local_to_central_ratio_colocated": r0_col,
        "initial_local_to_central_epoch_colocated": t0_col,
        "sqrt_n": float(np.sqrt(n)),
        "local_to_central_after_1h": {
            "vtec": steady_range(local_ratio[:, 0, 0]),
            "grad_lat": steady_range(local_ratio[:, 0, 1]),
            "grad_lon": steady_range(local_ratio[:, 0, 2]),
            "median_receiver1": np.nanmedian(local_ratio[steady:, 0], axis=0).tolist(),
            "all_receivers_range": [float(np.nanmin(local_ratio[steady:])), float(np.nanmax(local_ratio[steady:]))],
        },
        "central_std_after_1h_m": {
            "vtec": steady_range(cs[:, 0, 0]),
            "grad_lat": steady_range(cs[:, 0, 1]),
            "grad_lon": steady_range(cs[:, 0, 2]),
        },
        "ckf_to_central_ratio_max": kmax,
        "ckf_to_central_ratio_max_note": "max over receivers, ν_o/ν_φ/ν_ψ and epochs from 1 h on (Fig. 7 recursion)",
        "ckf_to_central_vtec_max_per_receiver": per_rx_vtec,
        "dcb_time_to_0.5ns_min": {
            "central": dcb_central,
            "local": {graph.names[i]: box_stats(t_local[i]) for i in range(n)},
            "ckf": {str(k): {graph.names[i]: box_stats(t_ckf[k][i]) for i in range(n)} for k in kns},
            "central_if_ns_means_c": box_stats(t_central_c),
            "per_dcb_central": dict(zip(layout.dcb_svs, t_central.tolist(), strict=True)),
        },
        "ckf_simulated_data": {
            "kn": data_kn,
            "fraction_within_3sigma": within3,
            "rms_standardized_error": rms_z,
            "n_values": int(zf.size),
            "messages": res.comm.as_dict() if hasattr(res.comm, "as_dict") else None,
        },
        "communication_vs_gather": {
            f"CKF on simulated data, k_n = {data_kn}": compare_with_gather(
                res.comm, graph, record_bytes_per_node(data_series.tracked), data=RECORDS_DATA, node_label="receiver"
            ).as_dict()
        },
        "paper": PAPER,
    }
    worst = max(per_rx_vtec[str(kns[0])])
    results["headline"] = {
        "initial local/central std ratio ν_o (receiver 1; √13 = 3.606)": r0,
        "initial ratio, co-located receivers (equal normals)": r0_col,
        "local/central ν_o ratio after 1 h, receiver 1 (min)": results["local_to_central_after_1h"]["vtec"][0],
        "local/central ν_o ratio after 1 h, receiver 1 (max)": results["local_to_central_after_1h"]["vtec"][1],
        **{f"max CKF/central std ratio, k_n={k}": kmax[str(k)] for k in kns},
        f"worst receiver ν_o ratio k_n={kns[0]}": worst,
        "central DCB time to 0.5 ns, median [min]": dcb_central["median"],
        "central DCB time to 0.5 ns, max [min]": dcb_central["max"],
        f"CKF k_n={data_kn} errors within ±3σ (simulated)": within3,
    }
    ctx.write_json("results.json", results)
    if ctx.is_root:
        _figures(ctx, graph, geo, layout, central, local, ckf_ratio, local_ratio, t_central, t_ckf, ds, truth, steady)
    return results


def _rerising(series: GeometryFreeSeries, layout: IonosphereStateLayout) -> list[str]:
    tr = np.asarray(series.tracked.any(axis=1), dtype=np.int8)  # (T, S)
    rises = (np.diff(tr, axis=0) == 1).sum(axis=0) + tr[0]
    return [s for s, k in zip(layout.svs, rises, strict=True) if k >= 2]


def _visibility(series: GeometryFreeSeries, layout: IonosphereStateLayout) -> dict[str, int]:
    """Epochs at which each satellite is tracked by at least one receiver (Fig. 10, left)."""
    tr = np.asarray(series.tracked.any(axis=1))  # (T, S)
    return {s: int(k) for s, k in zip(layout.svs, tr.sum(axis=0), strict=True)}


def _figures(
    ctx: ExperimentContext,
    graph: Graph,
    geo: IonosphereGeometry,
    layout: IonosphereStateLayout,
    central: FilterSeries,
    local: FilterSeries,
    ckf_ratio: dict[int, np.ndarray],
    local_ratio: np.ndarray,
    t_central: np.ndarray,
    t_ckf: dict[int, np.ndarray],
    ds: FilterSeries,
    truth: np.ndarray,
    steady: int,
) -> None:
    plt = pyplot()
    T = central.std.shape[0]
    hours = 8.0 + np.arange(T) * INTERVAL_S / 3600.0  # Perth local time
    labels = ["ν_o [m]", "ν_φ [m/rad]", "ν_ψ [m/rad]"]
    n = graph.n_nodes
    # Fig. 8 + 10: network and visibility
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.5))
    pos = PERTH_EAST_NORTH_KM
    for i, j in graph.links:
        axes[0].plot(pos[[i, j], 0], pos[[i, j], 1], "r-", lw=1)
    axes[0].plot(pos[:, 0], pos[:, 1], "o", mfc="w", mec="k", ms=14)
    for i in range(n):
        axes[0].text(pos[i, 0], pos[i, 1], str(i + 1), ha="center", va="center", fontsize=8)
    axes[0].set_aspect("equal")
    axes[0].set_xlabel("east [km]")
    axes[0].set_ylabel("north [km]")
    axes[0].set_title("Perth network (links ≤ 4 km)")
    vis = np.asarray(geo.tracked.any(axis=1))
    for k in range(len(layout.svs)):
        tt = np.where(vis[:, k], hours, np.nan)
        axes[1].plot(tt, np.full(T, k), lw=4)
    axes[1].set_yticks(range(len(layout.svs)))
    axes[1].set_yticklabels([s[1:] for s in layout.svs], fontsize=6)
    axes[1].set_xlabel("Perth local time [h]")
    axes[1].set_ylabel("PRN")
    axes[1].set_title(f"visibility above {MASK_DEG:.0f}° (synthetic constellation)")
    ctx.save_figure(fig, "fig08_10_network_visibility.png")
    # Fig. 11
    sl = slice(min(steady, T - 1), T)
    fig, axes = plt.subplots(3, 2, figsize=(12, 8), sharex=True)
    for k in range(3):
        axes[k, 0].plot(hours[sl], central.std[sl, 0, k], "g", label="central")
        axes[k, 0].plot(hours[sl], local.std[sl, 0, k], "r", label="local (receiver 1)")
        axes[k, 0].set_ylabel(f"std {labels[k]}")
        axes[k, 1].plot(hours[sl], local_ratio[sl, 0, k], "k")
        axes[k, 1].set_ylabel("local / central")
        axes[k, 0].grid(alpha=0.3)
        axes[k, 1].grid(alpha=0.3)
    axes[0, 0].legend()
    axes[2, 0].set_xlabel("Perth local time [h]")
    axes[2, 1].set_xlabel("Perth local time [h]")
    fig.suptitle("Fig. 11: central vs single-receiver standard deviations, from 1 h after the start")
    ctx.save_figure(fig, "fig11_central_vs_local.png")
    # Fig. 12
    kshow = [k for k in ckf_ratio if k in (4, 12)] or list(ckf_ratio)[:2]
    fig, axes = plt.subplots(3, len(kshow), figsize=(6 * len(kshow), 8), sharex=True, squeeze=False)
    cmap = plt.get_cmap("tab20")
    for c, kn in enumerate(kshow):
        for k in range(3):
            for i in range(n):
                axes[k, c].plot(
                    hours[sl], ckf_ratio[kn][sl, i, k], color=cmap(i), lw=0.9, label=f"rx {i + 1}" if k == 0 else None
                )
            axes[k, c].set_ylabel(f"CKF/central {labels[k].split()[0]}")
            axes[k, c].grid(alpha=0.3)
        axes[0, c].set_title(f"k_n = {kn} (δ = {INTERVAL_S / kn:.0f} s)")
        axes[2, c].set_xlabel("Perth local time [h]")
    axes[0, -1].legend(fontsize=6, ncol=2)
    ctx.save_figure(fig, "fig12_ckf_to_central.png")
    # Fig. 13
    fig, axes = plt.subplots(len(t_ckf), 1, figsize=(11, 3.2 * len(t_ckf)), squeeze=False)
    for r, (kn, tt) in enumerate(t_ckf.items()):
        data = [t_central[np.isfinite(t_central)]] + [tt[i][np.isfinite(tt[i])] for i in range(n)]
        axes[r, 0].boxplot(data, whis=(0, 100), tick_labels=["Cen."] + [str(i + 1) for i in range(n)])
        axes[r, 0].set_ylabel("minutes to std < 0.5 ns")
        axes[r, 0].set_title(f"δ = {INTERVAL_S / kn:.0f} s (k_n = {kn})")
        axes[r, 0].grid(alpha=0.3)
    fig.tight_layout()
    ctx.save_figure(fig, "fig13_dcb_time_boxplots.png")
    # CKF on data
    fig, axes = plt.subplots(2, 1, figsize=(11, 6))
    err = ds.estimates[:, 0, 0] - truth[:, 0]
    sd = ds.std[:, 0, 0]
    axes[0].plot(hours, err / TECU_L1_M, "b", lw=0.8, label="estimate − truth, receiver 1")
    axes[0].fill_between(hours, -3 * sd / TECU_L1_M, 3 * sd / TECU_L1_M, color="0.8", label="±3σ (Fig. 7)")
    axes[0].set_ylim(-3 * np.nanmedian(sd) / TECU_L1_M * 4, 3 * np.nanmedian(sd) / TECU_L1_M * 4)
    axes[0].set_ylabel("ν_o error [TECU]")
    axes[0].legend(fontsize=8)
    axes[0].grid(alpha=0.3)
    p0 = layout.n_tec
    e_dcb = (ds.estimates[-1, :, p0:] - truth[-1, p0:]) / GF_M_PER_DSB_NS
    s_dcb = ds.std[-1, :, p0:] / GF_M_PER_DSB_NS
    xs = np.arange(e_dcb.shape[1])
    for i in range(n):
        axes[1].plot(xs + 0.03 * (i - n / 2), -e_dcb[i], ".", ms=3)
    axes[1].errorbar(
        xs,
        np.zeros_like(xs, dtype=float),
        yerr=3 * np.nanmax(s_dcb, axis=0),
        fmt="none",
        ecolor="k",
        capsize=2,
        label="±3σ (largest over receivers)",
    )
    axes[1].set_xticks(xs)
    axes[1].set_xticklabels([s[1:] for s in layout.dcb_svs], fontsize=6)
    axes[1].set_ylabel("DCB error at the end [ns]")
    axes[1].legend(fontsize=8)
    axes[1].grid(alpha=0.3)
    ctx.save_figure(fig, "ckf_truth.png")
