"""Simulated networks for the field runtime's algorithm nodes: what ``distnav field init --simulate`` writes.

* :func:`codebias_scenario` — paper 000's simulation on ``n`` stations: L1/L2/L5 code observations of the L5-capable
  satellites of the synthetic GPS constellation (σ₀ = 20 cm, Euler–Goad weighting, 10° mask), stations scattered
  over Europe and linked to their nearest neighbours, the compressed per-epoch linear problem of the code biases
  (:meth:`~distnav.models.gnss.codebias.CodeBiasData.linear_problem`, ρ against one epoch's information);
* :func:`ckf_scenario` — paper 003 §4's generic CKF network on ``n`` nodes: three random-walk states and constant
  biases, each node observing a random ~70 % of the biases at every epoch (normals per node and epoch).

* :func:`rinex_ckf_scenario` — the CKF of ``distnav gnss ionosphere`` on real RINEX stations (the NL network);
* :func:`hall_scenario` — a simulated hall (:func:`~distnav.models.uwb.hall.simulate_hall`) of ``n`` anchors, 3-D,
  the known corner anchors fixed and the surveyed heights held, every range sample kept (no median per pair); the
  initial guess is the MDS one of ``uwb solve``, made centrally at set-up and written into every anchor's file.

Each returns the graph and what the in-process front door takes, so a test runs the same problem in-process and as
node programs; :func:`write_scenario` writes one data file per node (:mod:`distnav.formats.field_data`) and the
description.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from distnav.network import builders
from distnav.network.graph import Graph

if TYPE_CHECKING:
    from distnav.algorithms.kalman.dynamics import DynamicModel
    from distnav.algorithms.kalman.measurements import MeasurementSeries
    from distnav.algorithms.lsq.blue import LinearProblem
    from distnav.algorithms.ranging.data import RangingData
    from distnav.commands.field_processes import LoopbackOptions

__all__ = [
    "Scenario",
    "SCENARIOS",
    "codebias_scenario",
    "ckf_scenario",
    "hall_scenario",
    "remaining_data",
    "rinex_ckf_scenario",
    "write_scenario",
]

EPOCH_S = 30.0


@dataclass(frozen=True, eq=False)
class Scenario:
    """A simulated network: its graph, the algorithm table, and per kind the inputs of the front door."""

    graph: Graph
    kind: str
    algorithm: dict[str, Any]
    problem: LinearProblem | None = None
    dynamics: DynamicModel | None = None
    series: MeasurementSeries | None = None
    ranging: RangingData | None = None

    def node_arrays(self, node_id: int) -> dict[str, np.ndarray]:
        from distnav.formats.field_data import admm_node_arrays, ckf_node_arrays, uwb_node_arrays

        if self.kind == "admm":
            assert self.problem is not None
            return admm_node_arrays(self.problem, node_id)
        if self.kind == "uwb":
            assert self.ranging is not None
            return uwb_node_arrays(self.ranging, node_id)
        assert self.dynamics is not None and self.series is not None
        return ckf_node_arrays(self.dynamics, self.series, node_id)


def _station_graph(n: int, rng: np.random.Generator) -> tuple[np.ndarray, Graph]:
    """``n`` stations over Europe (lat 36–66°, lon −10–30°) at sea level, ECEF, each linked to its 3 nearest (more
    when that leaves the network in parts)."""
    from distnav.models.gnss.geometry import geodetic_to_ecef

    lat = rng.uniform(36.0, 66.0, n)
    lon = rng.uniform(-10.0, 30.0, n)
    xyz = np.asarray(geodetic_to_ecef(np.deg2rad(lat), np.deg2rad(lon), 0.0), float)  # (n, 3)
    k = min(3, n - 1)
    graph = builders.k_nearest(xyz, k)
    while not graph.is_connected:  # a far cluster: more neighbours each until the network is one
        k += 1
        graph = builders.k_nearest(xyz, k)
    return xyz, graph


def codebias_scenario(n_nodes: int, seed: int = 0, *, epochs: int = 20, rho: float = 0.5) -> Scenario:
    """Paper 000's code-bias network on ``n_nodes`` stations (module docstring)."""
    from distnav.models.gnss.codebias_build import CodeBiasSimulation, simulate_codebias_data
    from distnav.models.gnss.orbits import synthetic_gps_constellation

    rng = np.random.default_rng([seed, 26000])
    xyz, graph = _station_graph(n_nodes, rng)
    sc = synthetic_gps_constellation()
    orbit = sc.subset(sc.l5_svs)
    t = sc.epoch_gps_s + EPOCH_S * np.arange(epochs)
    data = simulate_codebias_data(
        xyz, orbit, t, orbit.svs, rng=rng, options=CodeBiasSimulation(reference=0)
    ).estimable_subset()
    data.check()
    algo = {"name": "admm", "rho": rho, "max_iterations": 400, "tol": 1e-10}
    return Scenario(graph, "admm", algo, problem=data.linear_problem(per_epoch=True))


def ckf_scenario(n_nodes: int, seed: int = 0, *, epochs: int = 30, n_biases: int = 6, kn: int = 4) -> Scenario:
    """Paper 003 §4's generic CKF network on ``n_nodes`` nodes (module docstring)."""
    from distnav.algorithms.kalman.dynamics import DynamicModel
    from distnav.algorithms.kalman.measurements import NormalSeries

    rng = np.random.default_rng([seed, 26003])
    graph = builders.connected_random_geometric(n_nodes, mean_degree=min(6, n_nodes - 1), rng=rng)
    p = 3 + n_biases
    sees = rng.random((n_nodes, n_biases)) < 0.7
    sees[:, rng.integers(n_biases)] = True  # every bias seen somewhere; the random walk by every node
    A = np.zeros((epochs, n_nodes, n_biases, p))
    A[..., :3] = rng.normal(size=(epochs, n_nodes, n_biases, 3))
    A[..., 3:] = np.eye(n_biases)
    A *= sees[None, :, :, None]
    y = rng.normal(size=(epochs, n_nodes, n_biases)) * sees[None]
    N = np.einsum("tnmp,tnmq->tnpq", A, A)
    r = np.einsum("tnmp,tnm->tnp", A, y)
    dyn = DynamicModel.random_walk(np.r_[np.full(3, 0.1), np.zeros(n_biases)])
    algo = {"name": "ckf", "rounds": kn, "protocol": "P3"}
    return Scenario(graph, "ckf", algo, dynamics=dyn, series=NormalSeries(N, r))


def hall_scenario(
    n_nodes: int = 28,
    seed: int = 0,
    *,
    iterations: int = 100,
    objective: str = "squared",
    hall: dict[str, Any] | None = None,
) -> Scenario:
    """A simulated hall of ``n_nodes`` anchors for the UWB solvers (module docstring); ``objective`` goes to the
    solver (paper 002's ``squared`` or ``metres``), ``hall`` changes further :class:`HallConfig` fields (e.g.
    ``{"link_loss": 0.0, "range_limit_m": 40.0}``: every pair in range measured, a well-connected hall)."""
    from distnav.models.uwb.hall import HallConfig, simulate_hall
    from distnav.models.uwb.initial import mds_initial_guess
    from distnav.models.uwb.problems import build_problem

    config = HallConfig().with_(n_anchors=n_nodes, known="corner", **(hall or {}))
    h = simulate_hall(np.random.default_rng([seed, 26002]), config)
    a, b = h.links[h.sample_link, 0], h.links[h.sample_link, 1]
    known = set(h.known.tolist())
    held = {h.ids[i]: {2: float(h.surveyed_z_m[i])} for i in range(h.n_anchors) if i not in known}
    problem = build_problem(
        list(h.ids),
        np.stack([a, b], axis=1),
        h.range_m,
        fixed={h.ids[k]: h.truth_m[k] for k in known},
        held=held,
        truth_m=h.truth_m,
        name="hall",
    )
    problem = problem.with_initial(mds_initial_guess(problem))  # central, at set-up: written into every file
    algo: dict[str, Any] = {"name": "uwb", "solver": "N-CLM", "iterations": iterations}
    if objective != "squared":
        algo["objective"] = objective
    return Scenario(problem.graph, "uwb", algo, ranging=problem)


def remaining_data(problem: RangingData, dead: int) -> RangingData:
    """``problem`` without anchor ``dead``: its row and every range sample with it as an end dropped, the rest
    renumbered in their order (the data a UWB field run that lost ``dead`` goes on with; the reference problem of
    the demo and the benchmark)."""
    from distnav.algorithms.ranging.data import RangingData

    return RangingData(dim=problem.dim, **problem.kept_arrays(np.arange(problem.n_anchors) != dead))


def rinex_ckf_scenario(obs_files: list[Path], nav_file: Path, *, kn: int = 4) -> Scenario:
    """The CKF of ``distnav gnss ionosphere`` on real stations (e.g. the five Dutch stations of the NL snapshot):
    the command's bias model and default graph (:func:`~distnav.commands.gnss_ionosphere_data.network_data`
    with its defaults and a TEC random walk of 1 mm/√s, as ``benchmarks/bench_comm.py`` runs it), so each station's
    file holds its own normals of every epoch and the common dynamic model."""
    from distnav.commands.gnss import default_graph
    from distnav.commands.gnss_ionosphere_data import NetworkOptions, network_data
    from distnav.formats.gnss.rinex import read_navigation
    from distnav.models.gnss.biasmodel import BiasModelOptions

    orbit = read_navigation(nav_file, max_age_s=24 * 3600.0)
    data = network_data(obs_files, orbit, NetworkOptions(model=BiasModelOptions(vtec_rw_m_per_sqrt_s=0.001)))
    graph = default_graph(data.positions_ecef_m, data.stations)
    algo = {"name": "ckf", "rounds": kn, "protocol": "P3"}
    return Scenario(graph, "ckf", algo, dynamics=data.dynamics, series=data.series)


SCENARIOS: dict[str, Callable[[int, int], Scenario]] = {
    "codebias": codebias_scenario,
    "ckf": ckf_scenario,
    "hall": hall_scenario,
}


def write_scenario(folder: Path, scenario: Scenario, options: LoopbackOptions | None = None) -> Path:
    """``folder/network.toml`` on loopback (free ports) and ``folder/data/node-ID.npz`` per node; the path of the
    description."""
    from dataclasses import replace

    from distnav.commands.field_processes import LoopbackOptions, write_loopback_description
    from distnav.formats.field_data import write_node_arrays

    n = scenario.graph.n_nodes
    paths = [folder / "data" / f"node-{i}.npz" for i in range(n)]
    for i, path in enumerate(paths):
        write_node_arrays(path, scenario.kind, i, n, scenario.node_arrays(i))
    opts = options if options is not None else LoopbackOptions()
    opts = replace(opts, algorithm={**scenario.algorithm, **(opts.algorithm or {})})
    return write_loopback_description(folder, scenario.graph.links, paths, opts)
