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
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from distnav.errors import GraphError, ModelError
from distnav.experiments.codebias_figures import figures
from distnav.experiments.common import ExperimentContext
from distnav.models.gnss.codebias import CodeBiasData
from distnav.models.gnss.codebias_build import CodeBiasSimulation, simulate_codebias_data
from distnav.models.gnss.constants import NS_TO_M
from distnav.models.gnss.geometry import geodetic_to_ecef
from distnav.models.gnss.orbits import (
    BLOCK_IIF_PRNS,
    datetime_from_gps_seconds,
    gps_seconds,
    synthetic_gps_constellation,
)
from distnav.network.graph import Graph
from distnav.options import add_size_option, existing_file, int_up_to, iso_datetime
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
#: Size limits of ``--epochs`` / ``--iterations`` (docs/claims.md: the full run, 300 epochs and 1,000 iterations with
#: its ρ sweep, ≈ 13 CPU-s): refused at parse time above them.
EPOCHS = int_up_to(2_880, "one day of 30-s epochs, the span of a daily bias product (≈ 10 × the default session)")
ITERATIONS = int_up_to(100_000, "100 × the default: the full run with its ρ sweep then takes up to ≈ 20 CPU-minutes")
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
    add_size_option(
        parser,
        "--iterations",
        ITERATIONS,
        default=None,
        help="ADMM iterations per run (default 1000; 300 with --quick)",
    )
    add_size_option(
        parser,
        "--epochs",
        EPOCHS,
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
    from distnav.formats.gnss.product_files import check_orbit_times
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
        check_orbit_times(orbit, t0, f"--start {start}", verb="is on")
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
        options=CodeBiasSimulation(
            sat_biases_m=sat_biases_m,
            rx_biases_m=rx_biases_m,
            stations=net.graph.names,
            reference=int(net.hubs[0]),
        ),
    )


@dataclass(frozen=True)
class Sessions:
    """The simulated sessions of :func:`run` and their centralized solutions: this session's ``data`` (its
    ``problem`` in the ρ scale asked for, its BLUE ``x_hat`` and recursive solution ``x_rec``/``s_rec``) and the
    adjacent session's solution ``x_prev`` (Fig. 10's "previous experiment")."""

    net: StationNetwork
    constraint_nodes: Any
    orbit_text: str
    t0_gps_s: float
    data: CodeBiasData
    solution: Any
    x_prev: np.ndarray
    problem: Any
    x_hat: np.ndarray
    x_rec: np.ndarray
    s_rec: np.ndarray


@dataclass(frozen=True)
class AdmmRuns:
    """The ADMM runs of :func:`run`: per ρ (Fig. 9), per initial value at ρ = 0.5 (Fig. 10), the iterations to
    1 mm with ρ against the other scale's information, and the per-node tracks of the ``best`` and ``worst``
    observed satellites (Fig. 11)."""

    by_rho: dict[str, Any]
    by_init: dict[str, Any]
    other_scale: str
    other: dict[str, int | None]
    tracks: np.ndarray
    best: int
    worst: int


def run(ctx: ExperimentContext) -> dict[str, Any]:
    epochs = int(ctx.option("epochs", 120 if ctx.quick else SESSION_EPOCHS, minimum=1))
    rho_scale = str(ctx.options.get("rho_scale") or "epoch")
    iterations = int(ctx.option("iterations", 300 if ctx.quick else 1000, minimum=1))
    sessions = _sessions(ctx, epochs, rho_scale)
    runs = _admm_runs(ctx, sessions, iterations, rho_scale)
    results = _results(sessions, runs, iterations=iterations, epochs=epochs, rho_scale=rho_scale)
    ctx.write_json("results.json", results)
    if ctx.is_root:
        figures(ctx, sessions, runs, THRESHOLD_M)
    return results


def _sessions(ctx: ExperimentContext, epochs: int, rho_scale: str) -> Sessions:
    """Simulate this session and the adjacent one on the 110 stations and solve both centrally."""
    from distnav.algorithms.lsq.blue import blue
    from distnav.network.constraint_nodes import choose_constraint_nodes

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
    return Sessions(net, C, orbit_text, t0, data, sol, x_prev, problem, bl.x, x_rec, s_rec)


def _admm(
    ctx: ExperimentContext,
    s: Sessions,
    problem: Any,
    *,
    rho: float,
    init: Any,
    iterations: int,
    record_nodes: bool = True,
) -> Any:
    """One ADMM run of :func:`run` on the station graph, tracked against the centralized ``x̂``."""
    from distnav.algorithms.lsq.admm import admm

    graph = s.net.graph
    return admm(
        problem,
        graph,
        constraint_nodes=s.constraint_nodes,
        W=rho,
        init=init,
        max_iterations=iterations,
        tol=0.0,
        reference=s.x_hat,
        record_nodes=record_nodes,
        exchange=ctx.exchange(graph),
    )


def _admm_runs(ctx: ExperimentContext, s: Sessions, iterations: int, rho_scale: str) -> AdmmRuns:
    """Figs. 9–11's ADMM runs (and the other ρ scale's, at full size)."""
    data = s.data
    counts = data.observation_counts()
    best, worst = int(np.argmax(counts)), int(np.argmin(counts))
    runs: dict[str, Any] = {}
    with ctx.progress.task(f"codebias: ADMM, ρ ∈ {list(RHOS)}, {iterations} iterations", total=len(RHOS)) as adv:
        for rho in RHOS:
            runs[f"{rho:g}"] = _admm(ctx, s, s.problem, rho=rho, init="zero", iterations=iterations)
            adv(1)
    other_scale = "session" if rho_scale == "epoch" else "epoch"
    problem_other = data.linear_problem(per_epoch=other_scale == "epoch")
    other: dict[str, int | None] = {}
    with ctx.progress.task(f"codebias: ADMM with ρ against the {other_scale}'s information", total=len(RHOS)) as adv:
        for rho in [] if ctx.quick else RHOS:
            r_o = _admm(ctx, s, problem_other, rho=rho, init="zero", iterations=iterations, record_nodes=False)
            other[f"{rho:g}"] = _iterations_to(r_o.trace["max_distance_to_reference"], THRESHOLD_M)
            adv(1)
    inits: dict[str, np.ndarray] = {
        "0": np.zeros(data.n_sats),
        "+5 m": np.full(data.n_sats, 5.0),
        "-5 m": np.full(data.n_sats, -5.0),
        "prev.": s.x_prev,
    }
    init_runs: dict[str, Any] = {}
    with ctx.progress.task("codebias: ADMM ρ = 0.5 from different initial values", total=len(inits)) as adv:
        for label, x0 in inits.items():
            # x⁰ = 0 is identical to the ρ = 0.5 run of Fig. 9
            init_runs[label] = (
                runs["0.5"] if label == "0" else _admm(ctx, s, s.problem, rho=0.5, init=x0, iterations=iterations)
            )
            adv(1)
    with ctx.progress.task("codebias: per-node tracks of two satellites (ρ = 0.5, x⁰ = prev.)"):
        tracks = _tracks(s.problem, s.net.graph, s.constraint_nodes, s.x_prev, iterations, [best, worst], ctx)
    return AdmmRuns(runs, init_runs, other_scale, other, tracks, best, worst)


def _results(s: Sessions, r: AdmmRuns, *, iterations: int, epochs: int, rho_scale: str) -> dict[str, Any]:
    """results.json of :func:`run`."""
    data, graph, C, sol, x_hat = s.data, s.net.graph, s.constraint_nodes, s.solution, s.x_hat
    runs, best, worst = r.by_rho, r.best, r.worst
    counts = data.observation_counts()
    per_sat = {
        data.svs[k]: _iterations_to(np.abs(r.tracks[:, :, c] - x_hat[k]).max(axis=1), THRESHOLD_M)
        for c, k in enumerate((best, worst))
    }
    it_rho = _iterations_of(runs, THRESHOLD_M)
    it_init = _iterations_of(r.by_init, THRESHOLD_M)
    it_init_cm = _iterations_of(r.by_init, 1e-2)
    it_rho_cm = _iterations_of(runs, 1e-2)
    final_rho = {k: float(v.trace["max_distance_to_reference"][-1]) for k, v in runs.items()}
    truth = data.truth_m
    assert truth is not None
    err = sol.x_m - truth
    chi2 = float(err @ np.linalg.solve(sol.cov_m2, err)) / data.n_sats
    vs_gather = {k: _vs_gather(v.comm, graph, s.problem).as_dict() for k, v in runs.items()}
    return {
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
        f"iterations_to_1e-3_rho_scale_{r.other_scale}": r.other,
        "final_max_distance_m": final_rho,
        "iterations": iterations,
        "epochs": epochs,
        "epoch_s": EPOCH_S,
        "satellites": list(data.svs),
        "constellation": s.orbit_text,
        "session_start": str(datetime_from_gps_seconds(np.array(s.t0_gps_s))),
        "reference_station": data.stations[data.reference],
        "observation_counts": dict(zip(data.svs, counts.tolist(), strict=True)),
        "well_visible": data.svs[best],
        "poorly_visible": data.svs[worst],
        "centralized_m": dict(zip(data.svs, x_hat.tolist(), strict=True)),
        "centralized_sigma_m": dict(zip(data.svs, sol.sigma_m.tolist(), strict=True)),
        "fig8_recursive_sigma": _sigma_shrink(s.s_rec, data.svs),
        "model_vs_lsq_blue_max_abs_m": float(np.abs(sol.x_m - x_hat).max()),
        "truth_m": dict(zip(data.svs, truth.tolist(), strict=True)),
        "chi2_per_dof_vs_truth": chi2,
        "previous_session_offset_max_m": float(np.abs(s.x_prev - x_hat).max()),
        "network": {
            "lat_deg": s.net.lat_deg.tolist(),
            "lon_deg": s.net.lon_deg.tolist(),
            "links": graph.links.tolist(),
            "hubs": s.net.hubs.tolist(),
        },
        "communication": {k: v.comm.as_dict() for k, v in runs.items()},
        "communication_vs_gather": vs_gather,
        "paper": {
            **PAPER,
            "finding": "ρ = 5 converges very slowly from 0; ρ = 0.5 fastest; smaller ρ not faster; "
            "a previous solution as initial value converges fastest; the well-tracked "
            "satellite (PRN 1) converges faster than the poorly tracked one (PRN 24)",
        },
        "headline": _headline(s, r, iterations, it_rho, it_init, it_init_cm, vs_gather),
    }


def _iterations_of(runs: dict[str, Any], threshold_m: float) -> dict[str, int | None]:
    return {k: _iterations_to(v.trace["max_distance_to_reference"], threshold_m) for k, v in runs.items()}


def _headline(
    s: Sessions,
    r: AdmmRuns,
    iterations: int,
    it_rho: dict[str, int | None],
    it_init: dict[str, int | None],
    it_init_cm: dict[str, int | None],
    vs_gather: dict[str, Any],
) -> dict[str, Any]:
    from distnav.algorithms.result import format_ratio

    svs, sigma_m, best, worst = s.data.svs, s.solution.sigma_m, r.best, r.worst
    return {
        "links / constraint nodes (paper 118 / 9)": f"{s.net.graph.n_links} / {s.constraint_nodes.size}",
        **{f"iterations to 1 mm, ρ = {k}": (v if v is not None else f"> {iterations}") for k, v in it_rho.items()},
        "iterations to 1 mm, ρ = 0.5, x⁰ = prev.": it_init["prev."],
        "iterations to 1 cm, ρ = 0.5, x⁰ = 0 / prev.": f"{it_init_cm['0']} / {it_init_cm['prev.']}",
        "ADMM bytes ÷ gathering the stations' data at one, ρ = 0.5": format_ratio(vs_gather["0.5"]["ratio_bytes"]),
        f"σ of x̂ {svs[best]} / {svs[worst]} [cm]": (f"{100 * sigma_m[best]:.2f} / {100 * sigma_m[worst]:.2f}"),
    }


def _sigma_shrink(s_rec: np.ndarray, svs: Sequence[str]) -> dict[str, Any]:
    """Fig. 8's claim on the recursive centralized σ (``s_rec``: epochs × satellites, NaN while not estimable):
    per satellite the σ of its first estimable epoch and of the last, and the epochs at which σ grew (by more than
    1e-9 relative: the intervals shrink as epochs accumulate when there are none)."""
    first, last, grew = {}, {}, {}
    for k, sv in enumerate(svs):
        col = s_rec[:, k][np.isfinite(s_rec[:, k])]
        first[sv] = float(col[0]) if col.size else None
        last[sv] = float(col[-1]) if col.size else None
        grew[sv] = int((np.diff(col) > 1e-9 * col[:-1]).sum()) if col.size > 1 else 0
    return {"first_epoch_m": first, "last_epoch_m": last, "epochs_where_sigma_grew": grew}


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
