"""GNSS code biases (issue 6): the 110-station experiment and RINEX reading.

* the 110-station, 300-epoch code-bias computation (simulation of the session, centralized solution, recursive
  solution, 4 ADMM runs of 1,000 iterations): goal ≤ 20 s (quick: 120 epochs, 300 iterations);
* reading a full day of 30-s RINEX 3 (BELE, Hatanaka + gzip, 2880 epochs) with distnav's reader against georinex
  alone on the same observation types: distnav should add little (quick: a 1-hour window);
* reading the merged broadcast file of the day (BRDC, RINEX 3, all systems) with distnav's reader against
  ``georinex.load(use="G")`` alone (imported beforehand): the own reader should be much faster;
* ``gnss ionosphere`` on a full day of 3 stations at 30 s (read, levelling + screening + model, central + local
  + CKF filters, CPU from the first read to the last filter output): goal ≤ 5 s CPU (issue 32; issue 14 asked
  ≤ 30 s), the filters also as a ratio to a bare Cholesky floor of the same run; and on a
  2-h session of the same (06–08 h): the filters within 150× a bare Cholesky floor (415–545× with OpenBLAS's
  threads in the eigen-decomposition fallback, 55–100× without; quick: the session);
* orbit evaluation: broadcast (IS-GPS-200) and SP3 (9th-order Lagrange) positions of 31 satellites at 2880 epochs.
Reading tests need ``../shared/data``; they are skipped (row with a note) when it is absent.
"""

from __future__ import annotations

import sys
import time
import warnings
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import best_time, main_for  # noqa: E402
from distnav.algorithms.lsq.admm import admm  # noqa: E402
from distnav.algorithms.lsq.blue import blue  # noqa: E402
from distnav.experiments.codebias import RHOS, _simulate, constellation, synthetic_igs_network  # noqa: E402
from distnav.models.gnss.constants import NS_TO_M  # noqa: E402
from distnav.models.gnss.orbits import gps_seconds  # noqa: E402
from distnav.network.constraint_nodes import choose_constraint_nodes  # noqa: E402

_REPO = Path(__file__).resolve().parents[1]
SHARED = next(
    (
        c / "data" / "gnss"
        for c in (_REPO.parent / "shared", _REPO.parent.parent / "shared")
        if (c / "data" / "gnss").exists()
    ),
    _REPO.parent / "shared" / "data" / "gnss",
)


def _codebias(epochs: int, iterations: int) -> dict[str, Any]:
    t0 = time.perf_counter()
    net = synthetic_igs_network(np.random.default_rng([0, 1]))
    C = choose_constraint_nodes(net.graph, "min_cover")
    sb = np.random.default_rng([0, 2]).normal(0, 3 * NS_TO_M, (12, 3))
    rb = np.random.default_rng([0, 4]).normal(0, 5 * NS_TO_M, (net.graph.n_nodes, 3))
    orbit, svs, t_start, _ = constellation()
    data = _simulate(net, orbit, svs, t_start, epochs, np.random.default_rng([0, 3]), sb, rb)
    data.check()
    sol = data.centralized(check=False)
    data.recursive_solution()
    problem = data.linear_problem(per_epoch=True)
    x_hat = blue(problem).x
    t_setup = time.perf_counter() - t0
    finals = []
    for rho in RHOS:
        res = admm(
            problem,
            net.graph,
            constraint_nodes=C,
            W=rho,
            max_iterations=iterations,
            tol=0.0,
            reference=x_hat,
            record_nodes=True,
        )
        finals.append(float(res.trace["max_distance_to_reference"][-1]))
    total = time.perf_counter() - t0
    assert np.allclose(sol.x_m, x_hat, atol=1e-9)
    return {
        "name": "codebias 110 stations",
        "epochs": epochs,
        "admm_runs": len(RHOS),
        "iterations": iterations,
        "setup_s": round(t_setup, 2),
        "seconds": total,
        "goal": "≤ 20 s",
        "meets_goal": bool(total <= 20.0),
        "max_dist_rho_0.5_m": finals[1],
    }


def _reading(quick: bool) -> list[dict[str, Any]]:
    f = SHARED / "igs_2024010_bele_dgar" / "BELE00BRA_R_20240100000_01D_30S_MO.crx.gz"
    if not f.exists():
        return [{"name": "read RINEX 3 day", "note": f"skipped: {f} absent"}]
    import georinex as gr

    from distnav.formats.gnss.rinex import read_code_observations

    tlim = ("2024-01-10T00:00", "2024-01-10T01:00") if quick else None
    kw = {"tlim": tlim} if tlim else {}

    def plain() -> None:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            gr.load(f, use="G", meas=["C1C", "C2W", "C5X"], **kw)

    def ours() -> None:
        read_code_observations(f, tlim=tlim)

    # interleaved, best of 2 (3 when quick): the machine is shared and its load changes over a minute
    t_ref = t_ours = float("inf")
    for _ in range(3 if quick else 2):
        t_ref = min(t_ref, best_time(plain, repeat=1))
        t_ours = min(t_ours, best_time(ours, repeat=1))
    return [
        {
            "name": "read RINEX 3 BELE " + ("1 h" if quick else "full day"),
            "epochs": 121 if quick else 2880,
            "seconds": t_ours,
            "reference_seconds": t_ref,
            "ratio": t_ours / t_ref,
            "goal": "≤ 1.2 × georinex",
            "meets_goal": bool(t_ours <= 1.2 * t_ref),
        },
        _reading_navigation(),
    ]


def _reading_navigation() -> dict[str, Any]:
    """The day's merged broadcast file: distnav's one-pass reader (format checks + GPS records) against
    ``georinex.load`` alone (imported before timing; the import itself is ≈ 1.5 s CPU more), CPU time."""
    import georinex as gr

    from distnav.formats.gnss.rinex import read_navigation

    f = SHARED / "igs_2024010_bele_dgar" / "BRDC00IGS_R_20240100000_01D_MN.rnx.gz"

    def plain() -> None:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            gr.load(f, use="G")

    t_ref = t_ours = float("inf")
    for _ in range(3):
        c0 = time.process_time()
        plain()
        c1 = time.process_time()
        read_navigation(f, max_age_s=4 * 3600.0)
        c2 = time.process_time()
        t_ref, t_ours = min(t_ref, c1 - c0), min(t_ours, c2 - c1)
    return {
        "name": "read RINEX 3 broadcast day (BRDC, all systems)",
        "seconds": t_ours,
        "cpu_s": t_ours,
        "reference_cpu_s": t_ref,
        "ratio": t_ours / t_ref,
        "goal": "≤ 0.5 × georinex.load",
        "meets_goal": bool(t_ours <= 0.5 * t_ref),
    }


def _ionosphere_day(quick: bool) -> list[dict[str, Any]]:
    """Full day, 3 stations at 30 s (BELE, DGAR and a clone of DGAR moved by 30 km): read, level + screen + model,
    central + local + CKF filters; and a 2-h session (06–08 h) of the same, the short-session case where the
    filters' information is singular for the first hour (eigen-decomposition fallbacks). Quick: the session only.
    Floor: one p×p Cholesky factorization per epoch and filter row in bare numpy, in the same run."""
    d = SHARED / "igs_2024010_bele_dgar"
    if not d.exists():
        return [{"name": "ionosphere day", "note": "skipped: shared data absent"}]
    rows = [] if quick else [_ionosphere_run(d, None, "full day", "≤ 5 s CPU (full day, issue 32)", 5.0)]
    rows.append(
        _ionosphere_run(
            d, ("2024-01-10T06:00", "2024-01-10T08:00"), "2-h session", "filters ≤ 150× floor (2-h session)", None
        )
    )
    return rows


def _ionosphere_run(
    d: Path, tlim: tuple[str, str] | None, label: str, goal: str, cpu_goal_s: float | None
) -> dict[str, Any]:
    from dataclasses import replace

    from distnav.commands.gnss import default_graph
    from distnav.commands.gnss_ionosphere import network_from_observations
    from distnav.formats.gnss.rinex import read_navigation, read_stations
    from distnav.models.gnss.gfnetwork import BiasFilterOptions, run_bias_filters

    t0, c0 = time.perf_counter(), time.process_time()
    obs = read_stations(
        [d / "BELE00BRA_R_20240100000_01D_30S_MO.crx.gz", d / "dgar0100.24o.gz"],
        l1_code="C1C",
        l2_code="C2W",
        phases=True,
        tlim=tlim,
    )
    obs.append(
        replace(
            read_stations([d / "dgar0100.24o.gz"], l1_code="C1C", l2_code="C2W", phases=True, tlim=tlim)[0],
            station="DGR2",
        )
    )
    obs[-1] = replace(obs[-1], position_ecef_m=obs[-1].position_ecef_m + np.array([3.0e4, 0.0, 0.0]))
    c_obs = time.process_time() - c0
    nav = read_navigation(d / "BRDC00IGS_R_20240100000_01D_MN.rnx.gz", max_age_s=4 * 3600.0)
    t_read, c_read = time.perf_counter() - t0, time.process_time() - c0
    t1, c1 = time.perf_counter(), time.process_time()
    data = network_from_observations(obs, nav)
    t_model, c_model = time.perf_counter() - t1, time.process_time() - c1
    t2, c2 = time.perf_counter(), time.process_time()
    series, _ = run_bias_filters(
        data, BiasFilterOptions(kn=4), graph=default_graph(data.positions_ecef_m, data.stations)
    )
    t_filt, c_filt = time.perf_counter() - t2, time.process_time() - c2
    total, c_total = time.perf_counter() - t0, time.process_time() - c0
    T, p, n_rows = data.series.n_epochs, data.layout.n_states, len(series)
    m = np.random.default_rng(0).standard_normal((p, p))
    info = m @ m.T
    t_floor = float("inf")
    for _ in range(3):  # best of 3: a 2-h session's floor is only ~20 ms of CPU, noisy on a loaded machine
        t3 = time.process_time()
        for _ in range(T * n_rows):
            np.linalg.cholesky(info)
        t_floor = min(t_floor, time.process_time() - t3)
    ratio = c_filt / t_floor
    return {
        "name": f"ionosphere 3 stations {label} at 30 s",
        "epochs": T,
        "states": p,
        "filters": n_rows,
        "read_s": round(t_read, 2),
        "level_model_s": round(t_model, 2),
        "filters_s": round(t_filt, 2),
        "seconds": total,
        "cpu_read_s": round(c_read, 2),
        "cpu_read_obs_s": round(c_obs, 2),
        "cpu_read_nav_s": round(c_read - c_obs, 2),
        "cpu_level_model_s": round(c_model, 2),
        "cpu_filters_s": round(c_filt, 2),
        "cpu_s": round(c_total, 2),
        "floor_cholesky_cpu_s": round(t_floor, 3),
        "filters_vs_floor": round(ratio, 1),
        "goal": goal,
        "meets_goal": bool(c_total <= cpu_goal_s) if cpu_goal_s is not None else bool(ratio <= 150.0),
    }


def _orbits() -> list[dict[str, Any]]:
    d = SHARED / "esbc_2020177_single_station_L5_sp3"
    if not d.exists():
        return [{"name": "orbits", "note": "skipped: shared data absent"}]
    from distnav.formats.gnss.rinex import read_navigation, read_sp3

    nav = read_navigation(d / "ESBC00DNK_R_20201770000_01D_MN.rnx.gz")
    sp3 = read_sp3([d / "GRG0MGXFIN_20201760000_01D_15M_ORB.SP3.gz", d / "GRG0MGXFIN_20201770000_01D_15M_ORB.SP3.gz"])
    t = gps_seconds(np.datetime64("2020-06-25T00:00")) + np.arange(2880) * 30.0
    svs = [s for s in sp3.svs if s.startswith("G")]
    tb = best_time(lambda: nav.positions_ecef(t, svs), repeat=3)
    ts = best_time(lambda: sp3.positions_ecef(t, svs), repeat=3)
    return [
        {"name": "broadcast positions", "satellites": len(svs), "epochs": 2880, "seconds": tb, "goal": "(no goal)"},
        {"name": "SP3 Lagrange positions", "satellites": len(svs), "epochs": 2880, "seconds": ts, "goal": "(no goal)"},
    ]


def run(quick: bool) -> list[dict[str, Any]]:
    rows = [_codebias(120, 300) if quick else _codebias(300, 1000)]
    rows += _reading(quick)
    rows += _ionosphere_day(quick)
    rows += _orbits()
    return rows


if __name__ == "__main__":
    main_for(__file__, run)
