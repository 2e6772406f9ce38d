"""Reproduction of paper 000 §5, Figs. 7–11: GNSS satellite code-bias determination by ADMM on 110 stations.

* network (Fig. 7): 110 synthetic IGS-like stations in nine regional clusters over the globe; each station links to
  its cluster's hub, the hubs are joined by a minimum spanning tree plus the shortest extra hub–hub links, and a few
  stations also link to a second hub, for 118 links in all; the fewest constraint nodes covering every link are then
  the nine hubs (the paper needed 9);
* data: the 12 GPS block IIF satellites (L1/L2/L5) of the synthetic constellation, 2.5 h of 30-s epochs, 10° mask,
  σ = 20 cm at zenith with Euler & Goad (1991) weighting; observable (24), S-basis of §5.1 (station 1 lumped);
* Fig. 8: centralized (recursive) solutions with 3σ bands for the best- and the least-observed satellite;
* Fig. 9: ``‖x_i^[k] − x̂‖`` of all 110 nodes for ρ ∈ {5, 0.5, 0.05, 0.005}, ``x_i^[0] = z_s^[0] = 0``;
* Fig. 10: the same for ρ = 0.5 and different initial values, including the solution of a previous 2.5-h session;
* Fig. 11: per-node differences ``x_i^[k] − x̂`` of the two satellites with the 3σ band of x̂.

The ADMM is :func:`distnav.algorithms.lsq.admm.admm` (constraint nodes, Fig. 6) on the compressed per-station normal
equations (:meth:`~distnav.models.gnss.codebias.CodeBiasData.linear_problem`).

**Scale of ρ.** ADMM's speed depends on ``W = ρI`` relative to the stations' normal matrices, and the paper does not
say in which scale its ρ values apply. Summed over 2.5 h (300 epochs) our ``N_i`` have eigenvalues of hundreds to
thousands (m⁻²), against which every ρ ∈ {5, …, 0.005} is tiny; one epoch's ``N_i`` has eigenvalues of about 0.6–9,
the range in which the paper's finding (ρ = 0.5 best, ρ = 5 slow, smaller ρ not faster) makes sense. By default
(``--rho-scale epoch``) ρ is therefore measured against one epoch's information: the ADMM runs on ``N_i/T``,
``r_i/T`` (same x̂; equivalently ``W = ρ·T·I`` on the session's normals). ``--rho-scale session`` runs ρ on the
session's normals; ``results.json`` always reports the iteration counts of both scales.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from distnav.errors import GraphError, ModelError
from distnav.experiments.common import ExperimentContext, pyplot
from distnav.models.gnss.codebias import CodeBiasData, simulate_codebias_data
from distnav.models.gnss.constants import NS_TO_M
from distnav.models.gnss.geometry import geodetic_to_ecef
from distnav.models.gnss.orbits import (
    BLOCK_IIF_PRNS,
    datetime_from_gps_seconds,
    gps_seconds,
    synthetic_gps_constellation,
)
from distnav.network.graph import Graph
from distnav.options import existing_file, iso_datetime, positive_int
from distnav.typing import FloatArray

if TYPE_CHECKING:
    from distnav.algorithms.lsq.blue import LinearProblem
    from distnav.algorithms.result import CommComparison
    from distnav.exchange.core import CommTotals

NAME = "codebias"
TITLE = "GNSS satellite code biases by ADMM on 110 stations (paper 000 Figs. 7-11)"

N_STATIONS = 110
N_LINKS = 118
RHOS = (5.0, 0.5, 0.05, 0.005)
THRESHOLD_M = 1e-3
EPOCH_S = 30.0
SESSION_EPOCHS = 300  # 2.5 h of 30-s data
PAPER = {"n_links": 118, "n_constraint_nodes": 9}

# IGS-like regional clusters: (name, lat°, lon°, stations, spread°)
REGIONS: tuple[tuple[str, float, float, int, float], ...] = (
    ("Europe", 50.0, 10.0, 25, 8.0),
    ("N-America E", 40.0, -80.0, 14, 7.0),
    ("N-America W", 42.0, -118.0, 12, 7.0),
    ("S-America", -15.0, -55.0, 12, 10.0),
    ("Africa", 0.0, 22.0, 10, 12.0),
    ("East Asia", 35.0, 120.0, 12, 9.0),
    ("Australia", -28.0, 135.0, 12, 8.0),
    ("Pacific", -15.0, -160.0, 6, 15.0),
    ("Antarctica", -72.0, 60.0, 7, 5.0),
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--iterations", type=positive_int, default=None, help="ADMM iterations per run (default 1000; 300 with --quick)"
    )
    parser.add_argument(
        "--epochs",
        type=positive_int,
        default=None,
        help="30-s epochs of the session (default 300 = 2.5 h; 120 with --quick)",
    )
    parser.add_argument(
        "--nav",
        type=existing_file,
        default=None,
        metavar="FILE",
        help="use the block IIF satellites of this RINEX navigation file instead of the synthetic constellation",
    )
    parser.add_argument(
        "--start",
        type=iso_datetime,
        default=None,
        metavar="ISO",
        help="session start (GPS time), e.g. 2024-01-10T06:00 (default: synthetic epoch, or one hour "
        "after the navigation file's first ephemeris)",
    )
    parser.add_argument(
        "--rho-scale",
        choices=["epoch", "session"],
        default="epoch",
        help="W = ρI against the information of one epoch (default: normals divided by the number "
        "of epochs) or of the whole session",
    )


def _great_circle(
    lat1: FloatArray | float, lon1: FloatArray | float, lat2: FloatArray | float, lon2: FloatArray | float
) -> FloatArray:
    a = np.deg2rad
    c = np.sin(a(lat1)) * np.sin(a(lat2)) + np.cos(a(lat1)) * np.cos(a(lat2)) * np.cos(a(lon1 - lon2))
    angle: FloatArray = np.arccos(np.clip(c, -1.0, 1.0))
    return angle


@dataclass(frozen=True)
class StationNetwork:
    """Synthetic IGS-like network: geodetic positions (deg), ECEF (m), regional hub per station, graph."""

    lat_deg: np.ndarray
    lon_deg: np.ndarray
    positions_ecef_m: np.ndarray
    region: np.ndarray
    hubs: np.ndarray
    graph: Graph


def synthetic_igs_network(
    rng: np.random.Generator,
    *,
    n_links: int = N_LINKS,
    regions: tuple[tuple[str, float, float, int, float], ...] = REGIONS,
    extra_hub_links: int = 4,
) -> StationNetwork:
    """110 stations in the regional clusters of :data:`REGIONS`, hub-and-spoke links (see the module docstring).

    ``n_links`` = (stations − hubs) spokes + (hubs − 1) tree links + ``extra_hub_links`` + second-hub spokes.
    """
    lats, lons, reg = [], [], []
    for k, (_, la, lo, count, spread) in enumerate(regions):
        dlat = rng.normal(0.0, spread, count)
        dlon = rng.normal(0.0, spread, count) / max(np.cos(np.deg2rad(la)), 0.2)
        lats.append(np.clip(la + dlat, -85.0, 85.0))
        lons.append((lo + dlon + 180.0) % 360.0 - 180.0)
        reg.append(np.full(count, k))
    lat = np.concatenate(lats)
    lon = np.concatenate(lons)
    region = np.concatenate(reg)
    n = lat.size
    n_reg = len(regions)
    hubs = np.empty(n_reg, dtype=int)
    for k, (_, la, lo, _, _) in enumerate(regions):
        members = np.flatnonzero(region == k)
        hubs[k] = members[np.argmin(_great_circle(lat[members], lon[members], la, lo))]
    links: set[tuple[int, int]] = set()
    for i in range(n):
        h = hubs[region[i]]
        if i != h:
            links.add((min(i, h), max(i, h)))
    # hub tree (Prim) + shortest extra hub links
    dh = _great_circle(lat[hubs][:, None], lon[hubs][:, None], lat[hubs][None, :], lon[hubs][None, :])
    in_tree = {0}
    tree: list[tuple[int, int]] = []
    while len(in_tree) < n_reg:
        best = min((dh[a, b], a, b) for a in in_tree for b in range(n_reg) if b not in in_tree)
        tree.append((best[1], best[2]))
        in_tree.add(best[2])
    for a, b in tree:
        links.add((min(hubs[a], hubs[b]), max(hubs[a], hubs[b])))
    pairs = sorted((dh[a, b], a, b) for a in range(n_reg) for b in range(a + 1, n_reg))
    added = 0
    for _, a, b in pairs:
        if added >= extra_hub_links:
            break
        key = (min(hubs[a], hubs[b]), max(hubs[a], hubs[b]))
        if key not in links:
            links.add(key)
            added += 1
    # remaining links: non-hub stations closest to another region's hub get a second spoke
    is_hub = np.zeros(n, bool)
    is_hub[hubs] = True
    cand = []
    for i in np.flatnonzero(~is_hub).tolist():
        others = [k for k in range(n_reg) if k != region[i]]
        d = _great_circle(lat[i], lon[i], lat[hubs[others]], lon[hubs[others]])
        j = int(np.argmin(d))
        cand.append((float(d[j]), i, int(hubs[others[j]])))
    for _, i, h in sorted(cand):
        if len(links) >= n_links:
            break
        links.add((min(i, h), max(i, h)))
    if len(links) != n_links:
        raise GraphError(f"could not build {n_links} links (got {len(links)}) for {n} stations")
    pos = geodetic_to_ecef(np.deg2rad(lat), np.deg2rad(lon), 0.0)
    names = [f"{regions[region[i]][0][:2].upper()}{i:03d}" for i in range(n)]
    graph = Graph.from_links(n, sorted(links), names=names, positions=np.stack([lon, lat], axis=1))
    graph.require_connected("the station network")
    return StationNetwork(lat, lon, pos, region, hubs, graph)


def _iterations_to(trace_max: np.ndarray, threshold: float) -> int | None:
    hit = np.flatnonzero(np.asarray(trace_max) < threshold)
    return int(hit[0]) if hit.size else None


def constellation(nav: str | None = None, start: str | None = None) -> tuple[Any, tuple[str, ...], float, str]:
    """The block IIF satellites: ``(orbit, svs, t0_gps_s, description)`` of the synthetic constellation (default)
    or of a real broadcast navigation file (``nav``; healthy IIF PRNs, start at ``start`` or one hour after the
    file's first ephemeris)."""
    if nav is None:
        sc = synthetic_gps_constellation()
        l5 = sc.subset(sc.l5_svs)
        t0 = sc.epoch_gps_s if start is None else float(gps_seconds(np.array(start, dtype="datetime64[ns]")))
        return l5, l5.svs, t0, "synthetic constellation (nominal elements)"
    from distnav.formats.gnss.rinex import read_navigation

    orbit = read_navigation(Path(nav), max_age_s=4 * 3600.0)
    svs = tuple(f"G{p:02d}" for p in BLOCK_IIF_PRNS if f"G{p:02d}" in orbit.svs)
    if len(svs) < 2:
        raise ModelError(f"{nav}: fewer than two healthy block IIF satellites ({', '.join(svs) or 'none'})")
    if start is None:
        first = min(float(r["toe_abs_s"].min()) for r in orbit.records.values())
        t0 = float(np.ceil(first / 3600.0) * 3600.0 + 3600.0)
    else:
        t0 = float(gps_seconds(np.array(start, dtype="datetime64[ns]")))
    return orbit, svs, t0, f"broadcast ephemerides of {Path(nav).name}"


def _simulate(
    net: StationNetwork,
    orbit: Any,
    svs: tuple[str, ...],
    t0: float,
    epochs: int,
    rng: np.random.Generator,
    sat_biases_m: np.ndarray,
    rx_biases_m: np.ndarray,
) -> CodeBiasData:
    t = t0 + np.arange(epochs) * EPOCH_S
    return simulate_codebias_data(
        net.positions_ecef_m,
        orbit,
        t,
        svs,
        rng=rng,
        sat_biases_m=sat_biases_m,
        rx_biases_m=rx_biases_m,
        stations=net.graph.names,
        reference=int(net.hubs[0]),
    )


def run(ctx: ExperimentContext) -> dict[str, Any]:
    from distnav.algorithms.lsq.admm import admm
    from distnav.algorithms.lsq.blue import blue
    from distnav.algorithms.result import format_ratio
    from distnav.network.constraint_nodes import choose_constraint_nodes

    epochs = int(ctx.option("epochs", 120 if ctx.quick else SESSION_EPOCHS, minimum=1))
    rho_scale = str(ctx.options.get("rho_scale") or "epoch")
    iterations = int(ctx.option("iterations", 300 if ctx.quick else 1000, minimum=1))
    net = synthetic_igs_network(ctx.rng(1))
    graph = net.graph
    C = choose_constraint_nodes(graph, "min_cover")
    # code biases per frequency [m]: satellites 3 ns, receivers 5 ns (1σ); the same in both sessions
    orbit, svs, t0, orbit_text = constellation(ctx.options.get("nav"), ctx.options.get("start"))
    sat_biases = ctx.rng(2).normal(0.0, 3.0 * NS_TO_M, size=(len(svs), 3))
    rx_biases = ctx.rng(4).normal(0.0, 5.0 * NS_TO_M, size=(graph.n_nodes, 3))
    # the "previous experiment" of Fig. 10: the session before (after, when a navigation file starts too late)
    t_other = t0 - epochs * EPOCH_S
    if ctx.options.get("nav") and not np.isfinite(orbit.positions_ecef(np.array([t_other]), list(svs))).any():
        t_other = t0 + epochs * EPOCH_S
    with ctx.progress.task(f"codebias: simulate {N_STATIONS} stations × {epochs} epochs (this and previous session)"):
        data = _simulate(net, orbit, svs, t0, epochs, ctx.rng(3), sat_biases, rx_biases)
        prev = _simulate(net, orbit, svs, t_other, epochs, ctx.rng(5), sat_biases, rx_biases)
        data = data.estimable_subset()
        prev = prev.estimable_subset()
        if prev.svs != data.svs:
            raise ModelError(f"the adjacent session does not determine the same satellites ({prev.svs} vs {data.svs})")
        data.check()
        sol = data.centralized()
        x_prev = prev.centralized().x_m
        problem = data.linear_problem(per_epoch=rho_scale == "epoch")
        bl = blue(problem)
        x_rec, s_rec = data.recursive_solution()
    x_hat = bl.x
    counts = data.observation_counts()
    best, worst = int(np.argmax(counts)), int(np.argmin(counts))

    runs: dict[str, Any] = {}
    with ctx.progress.task(f"codebias: ADMM, ρ ∈ {list(RHOS)}, {iterations} iterations", total=len(RHOS)) as adv:
        for rho in RHOS:
            runs[f"{rho:g}"] = admm(
                problem,
                graph,
                constraint_nodes=C,
                W=rho,
                init="zero",
                max_iterations=iterations,
                tol=0.0,
                reference=x_hat,
                exchange=ctx.exchange(graph),
            )
            adv(1)
    other_scale = "session" if rho_scale == "epoch" else "epoch"
    problem_other = data.linear_problem(per_epoch=other_scale == "epoch")
    other: dict[str, int | None] = {}
    with ctx.progress.task(f"codebias: ADMM with ρ against the {other_scale}'s information", total=len(RHOS)) as adv:
        for rho in [] if ctx.quick else RHOS:
            r_o = admm(
                problem_other,
                graph,
                constraint_nodes=C,
                W=rho,
                init="zero",
                max_iterations=iterations,
                tol=0.0,
                reference=x_hat,
                record_nodes=False,
                exchange=ctx.exchange(graph),
            )
            other[f"{rho:g}"] = _iterations_to(r_o.trace["max_distance_to_reference"], THRESHOLD_M)
            adv(1)
    inits: dict[str, np.ndarray] = {
        "0": np.zeros(data.n_sats),
        "+5 m": np.full(data.n_sats, 5.0),
        "-5 m": np.full(data.n_sats, -5.0),
        "prev.": x_prev,
    }
    init_runs: dict[str, Any] = {}
    with ctx.progress.task("codebias: ADMM ρ = 0.5 from different initial values", total=len(inits)) as adv:
        for label, x0 in inits.items():
            if label == "0":  # identical to the ρ = 0.5 run of Fig. 9
                init_runs[label] = runs["0.5"]
                adv(1)
                continue
            init_runs[label] = admm(
                problem,
                graph,
                constraint_nodes=C,
                W=0.5,
                init=x0,
                max_iterations=iterations,
                tol=0.0,
                reference=x_hat,
                exchange=ctx.exchange(graph),
            )
            adv(1)

    with ctx.progress.task("codebias: per-node tracks of two satellites (ρ = 0.5, x⁰ = prev.)"):
        tracks = _tracks(problem, graph, C, x_prev, iterations, [best, worst], ctx)
    per_sat = {
        data.svs[k]: _iterations_to(np.abs(tracks[:, :, c] - x_hat[k]).max(axis=1), THRESHOLD_M)
        for c, k in enumerate((best, worst))
    }
    it_rho = {k: _iterations_to(r.trace["max_distance_to_reference"], THRESHOLD_M) for k, r in runs.items()}
    it_init = {k: _iterations_to(r.trace["max_distance_to_reference"], THRESHOLD_M) for k, r in init_runs.items()}
    it_init_cm = {k: _iterations_to(r.trace["max_distance_to_reference"], 1e-2) for k, r in init_runs.items()}
    it_rho_cm = {k: _iterations_to(r.trace["max_distance_to_reference"], 1e-2) for k, r in runs.items()}
    final_rho = {k: float(r.trace["max_distance_to_reference"][-1]) for k, r in runs.items()}
    truth = data.truth_m
    assert truth is not None
    err = sol.x_m - truth
    chi2 = float(err @ np.linalg.solve(sol.cov_m2, err)) / data.n_sats
    vs_gather = {k: _vs_gather(r.comm, graph, problem).as_dict() for k, r in runs.items()}
    results: dict[str, Any] = {
        "n_nodes": graph.n_nodes,
        "n_links": graph.n_links,
        "n_constraint_nodes": C.size,
        "constraint_nodes": [graph.names[i] for i in C.nodes],
        "constraint_nodes_optimal": C.optimal,
        "iterations_to_1e-3": it_rho,
        "iterations_to_1e-2": it_rho_cm,
        "iterations_to_1e-3_by_init_rho_0.5": it_init,
        "iterations_to_1e-2_by_init_rho_0.5": it_init_cm,
        "iterations_to_1e-3_per_satellite_prev_init": per_sat,
        "rho_scale": rho_scale,
        f"iterations_to_1e-3_rho_scale_{other_scale}": other,
        "final_max_distance_m": final_rho,
        "iterations": iterations,
        "epochs": epochs,
        "epoch_s": EPOCH_S,
        "satellites": list(data.svs),
        "constellation": orbit_text,
        "session_start": str(datetime_from_gps_seconds(np.array(t0))),
        "reference_station": data.stations[data.reference],
        "observation_counts": dict(zip(data.svs, counts.tolist(), strict=True)),
        "well_visible": data.svs[best],
        "poorly_visible": data.svs[worst],
        "centralized_m": dict(zip(data.svs, x_hat.tolist(), strict=True)),
        "centralized_sigma_m": dict(zip(data.svs, sol.sigma_m.tolist(), strict=True)),
        "model_vs_lsq_blue_max_abs_m": float(np.abs(sol.x_m - x_hat).max()),
        "truth_m": dict(zip(data.svs, truth.tolist(), strict=True)),
        "chi2_per_dof_vs_truth": chi2,
        "previous_session_offset_max_m": float(np.abs(x_prev - x_hat).max()),
        "network": {
            "lat_deg": net.lat_deg.tolist(),
            "lon_deg": net.lon_deg.tolist(),
            "links": graph.links.tolist(),
            "hubs": net.hubs.tolist(),
        },
        "communication": {k: r.comm.as_dict() for k, r in runs.items()},
        "communication_vs_gather": vs_gather,
        "paper": {
            **PAPER,
            "finding": "ρ = 5 converges very slowly from 0; ρ = 0.5 fastest; smaller ρ not faster; "
            "a previous solution as initial value converges fastest; the well-tracked "
            "satellite (PRN 1) converges faster than the poorly tracked one (PRN 24)",
        },
        "headline": {
            "links / constraint nodes (paper 118 / 9)": f"{graph.n_links} / {C.size}",
            **{f"iterations to 1 mm, ρ = {k}": (v if v is not None else f"> {iterations}") for k, v in it_rho.items()},
            "iterations to 1 mm, ρ = 0.5, x⁰ = prev.": it_init["prev."],
            "iterations to 1 cm, ρ = 0.5, x⁰ = 0 / prev.": f"{it_init_cm['0']} / {it_init_cm['prev.']}",
            "ADMM bytes ÷ gathering the stations' data at one, ρ = 0.5": format_ratio(vs_gather["0.5"]["ratio_bytes"]),
            f"σ of x̂ {data.svs[best]} / {data.svs[worst]} [cm]": (
                f"{100 * sol.sigma_m[best]:.2f} / {100 * sol.sigma_m[worst]:.2f}"
            ),
        },
    }
    ctx.write_json("results.json", results)
    if ctx.is_root:
        _figures(ctx, net, C.nodes, data, x_rec, s_rec, runs, init_runs, tracks, x_hat, sol.sigma_m, best, worst)
    return results


def _tracks(
    problem: Any, graph: Graph, C: Any, x0: np.ndarray, iterations: int, cols: list[int], ctx: ExperimentContext
) -> np.ndarray:
    """``x_i^[k]`` of every node for the satellites ``cols``: ``(iterations + 1, n, len(cols))``."""
    from distnav.algorithms.lsq.admm import iterate_admm

    ex = ctx.exchange(graph)
    out = np.empty((iterations + 1, graph.n_nodes, len(cols)))
    gen = iterate_admm(problem, graph, constraint_nodes=C, W=0.5, init=x0, exchange=ex)
    for state in gen:
        out[state.iteration] = ex.gather_nodes(state.x[:, cols])
        if state.iteration >= iterations:
            break
    close = getattr(gen, "close", None)
    if close is not None:
        close()
    return out


def _curves(ax: Any, values: np.ndarray, colour: str | None) -> tuple[float, float]:
    """One line per node (columns of ``values`` against the iteration) as a single LineCollection (fast).
    Returns the (min, max) of the finite plotted values (positive ones on a log axis) for the caller's limits."""
    from matplotlib.collections import LineCollection

    d = np.asarray(values, dtype=float)
    if ax.get_yscale() == "log":
        d = np.where(d > 0, d, np.nan)
    k = np.arange(d.shape[0], dtype=float)
    segs = np.stack([np.broadcast_to(k[:, None], d.shape), d], axis=-1).transpose(1, 0, 2)
    if colour is None:
        colors: Any = pyplot().get_cmap("tab20")(np.arange(d.shape[1]) % 20)
        ax.add_collection(LineCollection(list(segs), colors=colors, linewidths=0.4))
    else:
        ax.add_collection(LineCollection(list(segs), colors=colour, linewidths=0.4, alpha=0.5))
    ax.set_xlim(0, k[-1])
    finite = d[np.isfinite(d)]
    return (float(finite.min()), float(finite.max())) if finite.size else (1.0, 1.0)


def _set_ylim(ax: Any, bounds: list[tuple[float, float]], log: bool) -> None:
    lo = min(b[0] for b in bounds)
    hi = max(b[1] for b in bounds)
    if log:
        ax.set_ylim(max(lo, 1e-12) / 2, hi * 2)
    else:
        pad = 0.05 * (hi - lo) + 1e-12
        ax.set_ylim(lo - pad, hi + pad)


def _figures(
    ctx: ExperimentContext,
    net: StationNetwork,
    cnodes: np.ndarray,
    data: CodeBiasData,
    x_rec: np.ndarray,
    s_rec: np.ndarray,
    runs: dict[str, Any],
    init_runs: dict[str, Any],
    tracks: np.ndarray,
    x_hat: np.ndarray,
    sigma: np.ndarray,
    best: int,
    worst: int,
) -> None:
    plt = pyplot()
    g = net.graph
    # Fig. 7: network
    fig, ax = plt.subplots(figsize=(10, 5))
    for i, j in g.links:
        lo = net.lon_deg[[i, j]]
        if abs(lo[0] - lo[1]) > 180:
            continue
        ax.plot(lo, net.lat_deg[[i, j]], "-", color="tab:blue", lw=0.7)
    ax.plot(net.lon_deg, net.lat_deg, "k.", ms=4)
    ax.plot(net.lon_deg[cnodes], net.lat_deg[cnodes], "r^", ms=8, label=f"{cnodes.size} constraint nodes")
    ax.set_xlim(-180, 180)
    ax.set_ylim(-90, 90)
    ax.set_xlabel("longitude [°]")
    ax.set_ylabel("latitude [°]")
    ax.set_title(f"{g.n_nodes} stations, {g.n_links} links")
    ax.legend(loc="lower left")
    ctx.save_figure(fig, "fig7_network.png")
    # Fig. 8: recursive centralized solutions
    hours = (np.asarray(data.t_gps_s) - data.t_gps_s[0]) / 3600.0
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    for ax, k, what in zip(axes, (best, worst), ("best observed", "least observed"), strict=True):
        ax.plot(hours, x_rec[:, k], "k-", lw=1, label="x̂(t)")
        ax.plot(hours, x_rec[:, k] + 3 * s_rec[:, k], "k--", lw=0.8, label="±3σ")
        ax.plot(hours, x_rec[:, k] - 3 * s_rec[:, k], "k--", lw=0.8)
        if data.truth_m is not None:
            ax.axhline(data.truth_m[k], color="tab:green", lw=0.8, label="truth")
        ax.set_title(f"{data.svs[k]} ({what})")
        ax.set_xlabel("time [h]")
        ax.set_ylabel("code bias [m]")
        ax.legend(fontsize=7)
    ctx.save_figure(fig, "fig8_centralized.png")
    # Fig. 9: convergence for ρ
    colours = ["tab:red", "tab:green", "tab:blue", "tab:orange"]
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.5))
    axes[0].set_yscale("log")
    bounds = []
    for (rho, res), c in zip(runs.items(), colours, strict=True):
        bounds.append(_curves(axes[0], res.trace["distance_to_reference"], c))
        axes[0].plot([], [], color=c, label=f"ρ = {rho}")
        axes[1].semilogy(res.trace["max_distance_to_reference"], color=c, label=f"ρ = {rho}")
    _set_ylim(axes[0], bounds, log=True)
    for ax in axes:
        ax.axhline(THRESHOLD_M, color="k", ls=":", lw=0.8)
        ax.set_xlabel("iteration k")
        ax.legend(fontsize=8)
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("‖x_i^[k] − x̂‖ [m], 110 nodes")
    axes[1].set_ylabel("max_i ‖x_i^[k] − x̂‖ [m]")
    ctx.save_figure(fig, "fig9_rho.png")
    # Fig. 10: initial values
    fig, ax = plt.subplots(figsize=(7, 4.5))
    ax.set_yscale("log")
    bounds = []
    for (label, res), c in zip(init_runs.items(), colours, strict=True):
        bounds.append(_curves(ax, res.trace["distance_to_reference"], c))
        ax.plot([], [], color=c, label=f"x⁰ = {label}")
    _set_ylim(ax, bounds, log=True)
    ax.axhline(THRESHOLD_M, color="k", ls=":", lw=0.8)
    ax.set_xlabel("iteration k")
    ax.set_ylabel("‖x_i^[k] − x̂‖ [m]  (ρ = 0.5)")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    ctx.save_figure(fig, "fig10_init.png")
    # Fig. 11: per-node differences, init prev., for the two satellites
    fig, axes = plt.subplots(1, 2, figsize=(11, 4), sharey=True)
    for col, (ax, k) in enumerate(zip(axes, (best, worst), strict=True)):
        b = _curves(ax, tracks[:, :, col] - x_hat[k], None)
        _set_ylim(ax, [b, (-3 * sigma[k], 3 * sigma[k])], log=False)
        ax.axhline(3 * sigma[k], color="k", ls="--", lw=0.8)
        ax.axhline(-3 * sigma[k], color="k", ls="--", lw=0.8)
        ax.set_title(f"{data.svs[k]}: x_i^[k] − x̂ (ρ = 0.5, x⁰ = prev.)")
        ax.set_xlim(0, min(tracks.shape[0] - 1, 300))
        ax.set_xlabel("iteration k")
    axes[0].set_ylabel("[m]")
    ctx.save_figure(fig, "fig11_per_node.png")


def _vs_gather(comm: CommTotals, graph: Graph, problem: LinearProblem) -> CommComparison:
    """ADMM's traffic beside gathering every station's data at one station (issue 27)."""
    from distnav.algorithms.lsq.gather_data import GATHER_DATA, node_data_bytes
    from distnav.algorithms.result import compare_with_gather

    return compare_with_gather(
        comm,
        graph,
        node_data_bytes(problem),
        data=f"each station's data ({GATHER_DATA})",
        node_label="station",
        node_names=graph.names,
    )
