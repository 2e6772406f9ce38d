"""Scale past one machine (issue 30): ranks that build only their part, per-rank memory, and a scaling model.

Each row is one ``mpiexec -n R python -m mpi4py benchmarks/mpi_scale.py N …`` job: every rank builds its part of a
tiled random geometric graph (mean degree 8, equal id ranges), weights, exchange and mixer, and times consensus rounds
of 1 float against the floor — one scipy CSR product of the same rank's rows, RCM-ordered, written in the job from
the part (goal ≤ 1.2× at 10⁷ nodes). Per rank: set-up CPU seconds (goal ≤ 10 s at 10⁷ nodes, 4 ranks) and peak
resident memory after the set-up (``VmHWM``, imports included; goal ∝ n/ranks).

Rows ``ADMM (aggregated) on graph parts`` (issue 30 item 3): the ``admm`` job of ``mpi_scale.py`` (an 8-neighbour
grid, p = 10, m_i = 5) at 1, 2 and 4 ranks: set-up CPU per rank (goal ≤ 10 s), peak memory per rank, the iteration
against the rank's bare products; a memory model (imports + kB per owned node, fitted on those rows) predicts 10⁷
nodes on 4 ranks against this machine's memory, and ``DISTNAV_SCALE_BIG=1`` runs that job only if it fits with 3 GB
to spare.

Sizes: ``--quick`` 10⁵ nodes; default 10⁶ at 1, 2 and 4 ranks; ``DISTNAV_SCALE_BIG=1`` adds 10⁷ nodes at 2 and 4 ranks
(≈ 3 GB per rank at 4 ranks; minutes; run it once, niced). ``DISTNAV_SCALE_ONLY=admm`` runs the ADMM rows alone.

**The scaling model** (rows ``scaling model …``, docs/scale.md): a lock-step round on ``R`` ranks costs

    t(R) = s · c_e · E/R  +  k · α  +  2 · 8 · h(R) / B

with ``c_e`` the seconds per in-edge of the rank's CSR product measured on one rank (one core to itself), ``s =
max(1, ranks per host / cores per host)`` (oversubscription), ``k`` neighbour ranks, ``h(R) = a·√(n/R)`` halo nodes
per rank (``a`` fitted to the halos measured at 2 and 4 ranks: the boundary of a compact region), ``α`` and ``B`` the
latency and bandwidth of a ping-pong between two ranks (measured here; stated for a cluster network). It is
checked against the measured round at 1, 2 and 4 ranks (goal: within 25 %) and then predicts strong scaling (10⁸
nodes) and weak scaling (10⁶ nodes per rank) for 2–64 hosts × 16 ranks on a stated network.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import main_for  # noqa: E402

HERE = Path(__file__).resolve().parent

#: the stated cluster network of the predictions: 100 Gb/s InfiniBand (EDR) between hosts, one adapter per host
CLUSTER = {"latency_s": 2.0e-6, "host_bandwidth_Bps": 12.0e9, "ranks_per_host": 16, "cores_per_host": 16}


def _launch(ranks: int, n: int, rounds: int, repeats: int, *, admm: bool = False) -> dict[str, Any]:
    mpiexec = Path(sys.executable).parent / "mpiexec"
    cmd = [str(mpiexec), "-n", str(ranks), sys.executable, "-m", "mpi4py", str(HERE / "mpi_scale.py")]
    cmd += ["admm"] * admm + [str(n), str(rounds), str(repeats)]
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, stdin=subprocess.DEVNULL, timeout=3600)
    if proc.returncode != 0:
        return {"ranks": ranks, "n_nodes": n, "error": proc.stderr[-400:]}
    out: dict[str, Any] = json.loads(proc.stdout.strip().splitlines()[-1])
    out["wall_s"] = time.perf_counter() - t0
    return out


def _row(job: dict[str, Any], load: float) -> dict[str, Any]:
    if "error" in job:
        return {"name": "consensus on graph parts", **job}
    per = job["per_rank"]
    slow = max(per, key=lambda r: r["round_ms"])
    return {
        "name": "consensus on graph parts",
        "n_nodes": job["n_nodes"],
        "ranks": job["ranks"],
        "distnav_ms": slow["round_ms"],
        "floor_ms": slow["floor_ms"],
        "floor": "scipy CSR product of the same rank's rows, RCM-ordered (no transport)",
        "ratio_min": min(r["ratio_min"] for r in per),
        "ratio_median": max(r["ratio_median"] for r in per),
        "goal": "≤ 1.2 (10⁷ nodes)",
        "meets_goal": bool(max(r["ratio_median"] for r in per) <= 1.2),
        "halo_ms": max(r["halo_ms"] for r in per),
        "setup_s_max": max(r["setup_s"] for r in per),
        "part_s_max": max(r["part_s"] for r in per),
        "exchange_s_max": max(r["exchange_s"] for r in per),
        "setup_peak_mb_max": max(r["setup_mb"] for r in per),
        "import_mb": per[0]["import_mb"],
        "owned_max": max(r["owned"] for r in per),
        "in_edges_max": max(r["in_edges"] for r in per),
        "halo_nodes_max": max(r["halo_nodes"] for r in per),
        "neighbour_ranks_max": max(r["neighbour_ranks"] for r in per),
        "latency_s": per[0].get("latency_s"),
        "bandwidth_Bps": per[0].get("bandwidth_Bps"),
        "job_wall_s": job["wall_s"],
        "load": load,
        "per_rank": per,
    }


def round_model(
    n: int, ranks: int, c_edge: float, mean_in: float, halo_a: float, k: int, net: dict[str, float]
) -> dict[str, float]:
    """Predicted seconds of one round (see the module docstring) and its parts."""
    over = max(1.0, min(ranks, net["ranks_per_host"]) / net["cores_per_host"])
    compute = over * c_edge * mean_in * n / ranks
    halo = 0.0 if ranks == 1 else float(halo_a * np.sqrt(n / ranks))
    per_rank_bw = net["bandwidth_Bps"] / max(1.0, min(ranks, net["ranks_per_host"]) / 2)
    comm = 0.0 if ranks == 1 else k * net["latency_s"] + 2 * 8 * halo / per_rank_bw
    return {"compute_s": compute, "comm_s": comm, "round_s": compute + comm, "halo_nodes": halo}


def model_rows(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Fit the model's inputs on the smallest size measured at 1 rank and more, check it on every measured row (rows
    of other sizes are predictions the fit never saw), then predict the cluster."""
    ok = [r for r in rows if "error" not in r]
    cores = os.cpu_count() or 1
    fit_n = min(
        (n for n in {r["n_nodes"] for r in ok} if {1, 2} <= {r["ranks"] for r in ok if r["n_nodes"] == n}), default=None
    )
    if fit_n is None:
        return []
    one = next(r for r in ok if r["n_nodes"] == fit_n and r["ranks"] == 1)
    multi = [r for r in ok if r["n_nodes"] == fit_n and r["ranks"] > 1]
    c_edge = one["floor_ms"] * 1e-3 / one["in_edges_max"]
    mean_in = one["in_edges_max"] / fit_n
    halo_a = float(np.mean([r["halo_nodes_max"] / np.sqrt(fit_n / r["ranks"]) for r in multi]))
    latency = float(np.median([r["latency_s"] for r in multi if r.get("latency_s") is not None]))
    bandwidth = float(np.median([r["bandwidth_Bps"] for r in multi if r.get("bandwidth_Bps")]))
    here = {"latency_s": latency, "bandwidth_Bps": bandwidth, "ranks_per_host": 1e9, "cores_per_host": cores}
    out: list[dict[str, Any]] = []
    for r in sorted(ok, key=lambda r: (r["n_nodes"], r["ranks"])):
        n, ranks = r["n_nodes"], r["ranks"]
        pred = round_model(n, ranks, c_edge, mean_in, halo_a, r["neighbour_ranks_max"], here)
        err = pred["round_s"] * 1e3 / r["distnav_ms"] - 1
        out.append(
            {
                "name": "scaling model vs measured round",
                "n_nodes": n,
                "ranks": ranks,
                "fitted_on": f"n = {fit_n}" + (" (this run)" if n == fit_n else " (a prediction)"),
                "predicted_ms": pred["round_s"] * 1e3,
                "measured_ms": r["distnav_ms"],
                "relative_error": err,
                "goal": "within 25 %",
                "meets_goal": bool(abs(err) <= 0.25),
                "c_edge_ns": c_edge * 1e9,
                "halo_a": halo_a,
                "latency_us": latency * 1e6,
                "bandwidth_GBps": bandwidth / 1e9,
                "cores": cores,
                "load": r["load"],
            }
        )
    return out + _predictions(c_edge, mean_in, halo_a)


def _predictions(c_edge: float, mean_in: float, halo_a: float) -> list[dict[str, Any]]:
    """Strong (10⁸ nodes) and weak (10⁶ nodes per rank) scaling on 2–64 hosts × 16 ranks, the stated network."""
    rph = CLUSTER["ranks_per_host"]
    net = {
        "latency_s": CLUSTER["latency_s"],
        "bandwidth_Bps": CLUSTER["host_bandwidth_Bps"] * 2 / rph,  # the host's link shared by its ranks
        "ranks_per_host": rph,
        "cores_per_host": CLUSTER["cores_per_host"],
    }
    out = []
    for kind, n_of in (("strong, 10⁸ nodes", lambda r: 10**8), ("weak, 10⁶ nodes per rank", lambda r: 10**6 * r)):
        base = round_model(n_of(rph), rph, c_edge, mean_in, halo_a, 8, net)["round_s"]
        for hosts in (1, 2, 4, 8, 16, 32, 64):
            ranks = hosts * int(rph)
            p = round_model(n_of(ranks), ranks, c_edge, mean_in, halo_a, 8, net)
            speed = base / p["round_s"] * (ranks / rph if kind.startswith("weak") else 1)
            out.append(
                {
                    "name": f"scaling model prediction ({kind})",
                    "hosts": hosts,
                    "ranks": ranks,
                    "n_nodes": n_of(ranks),
                    "predicted_round_ms": p["round_s"] * 1e3,
                    "compute_ms": p["compute_s"] * 1e3,
                    "comm_ms": p["comm_s"] * 1e3,
                    "halo_nodes_per_rank": p["halo_nodes"],
                    "speedup_vs_1_host": speed,
                    "efficiency": speed / hosts,
                    "network": "InfiniBand EDR: 2 µs, 12 GB/s per host, 16 ranks per host",
                }
            )
    return out


def _admm_row(job: dict[str, Any], load: float) -> dict[str, Any]:
    name = "ADMM (aggregated) on graph parts"
    if "error" in job:
        return {"name": name, **job}
    per = job["per_rank"]
    keys = ("iteration_ms", "floor_ms", "ratio_median", "setup_s", "admm_setup_s", "setup_mb", "iterations_mb", "owned")
    top = {k: max(r[k] for r in per) for k in keys}  # the largest over the ranks
    return {
        "name": name,
        "n_nodes": job["n_nodes"],
        "ranks": job["ranks"],
        "distnav_ms": top["iteration_ms"],
        "floor_ms": top["floor_ms"],
        "floor": "the rank's two 0/1 CSR products (p columns) and batched x-update products (no transport)",
        "ratio_min": min(r["ratio_min"] for r in per),
        "ratio_median": top["ratio_median"],
        **{f"{k}_max": top[k] for k in ("setup_s", "admm_setup_s", "owned")},
        "setup_peak_mb_max": top["setup_mb"],
        "iterations_peak_mb_max": top["iterations_mb"],
        "import_mb": per[0]["import_mb"],
        # per owned node above the imports, with and without the caller's problem data (A, y) the peak includes
        "kb_per_owned_node": max((r["iterations_mb"] - r["import_mb"]) / r["owned"] for r in per) * 1.048576e3,
        "kb_per_owned_node_without_problem": max(
            (r["iterations_mb"] - r["import_mb"] - r.get("problem_mb", 0.0)) / r["owned"] for r in per
        )
        * 1.048576e3,
        "mmap_threshold": per[0].get("mmap_threshold"),
        "max_err_vs_central": per[0].get("max_err_vs_central"),
        "max_link_disagreement": per[0].get("max_link_disagreement"),
        "goal": "set-up ≤ 10 s per rank; memory ∝ n/ranks",
        "meets_goal": bool(top["setup_s"] <= 10.0),
        "job_wall_s": job["wall_s"],
        "load": load,
        "per_rank": per,
    }


#: memory left free beside a predicted job before it is started (other sessions share this machine)
MARGIN_MB = 3072.0


def admm_memory_model(rows: list[dict[str, Any]], n: int = 10**7, ranks: int = 4) -> list[dict[str, Any]]:
    """Per-rank peak = imports + ``b`` × owned nodes, ``b`` fitted (least squares) on the measured ADMM rows; the
    prediction for ``n`` nodes on ``ranks`` ranks against this machine's memory: it fits when the predicted total
    and :data:`MARGIN_MB` are available."""
    ok = [r for r in rows if r.get("name", "").startswith("ADMM") and "error" not in r]
    if not ok:
        return []
    owned = np.array([r["owned_max"] for r in ok], float)
    above = np.array([r["iterations_peak_mb_max"] - r["import_mb"] for r in ok])
    b_mb = float(owned @ above / (owned @ owned))
    per_rank_mb = float(np.mean([r["import_mb"] for r in ok])) + b_mb * n / ranks
    with open("/proc/meminfo") as fh:
        mem = {line.split(":")[0]: int(line.split()[1]) / 1024.0 for line in fh}
    total = per_rank_mb * ranks
    return [
        {
            "name": "ADMM on graph parts: memory model (prediction)",
            "n_nodes": n,
            "ranks": ranks,
            "fitted_on": sorted({(r["n_nodes"], r["ranks"]) for r in ok}),
            "kb_per_owned_node": b_mb * 1e3,
            "residuals_mb": [float(a - b_mb * o) for a, o in zip(above, owned, strict=True)],
            "predicted_per_rank_mb": per_rank_mb,
            "predicted_total_mb": total,
            "machine_total_mb": mem["MemTotal"],
            "machine_available_mb": mem["MemAvailable"],
            "margin_mb": MARGIN_MB,
            "fits": bool(total + MARGIN_MB <= mem["MemAvailable"]),
            "short_by_mb": max(0.0, total + MARGIN_MB - mem["MemAvailable"]),
        }
    ]


def run(quick: bool) -> list[dict[str, Any]]:
    sizes = [(10**5, (1, 2, 4))] if quick else [(10**6, (1, 2, 4))]
    if os.environ.get("DISTNAV_SCALE_BIG") == "1" and not quick:  # ≈ 2.1 GB per rank at 4 ranks, 4.3 GB at 2
        sizes.append((10**7, (2, 4)))
    rows: list[dict[str, Any]] = []
    only_admm = os.environ.get("DISTNAV_SCALE_ONLY") == "admm"  # the ADMM rows and their model alone
    for n, rank_counts in [] if only_admm else sizes:
        for ranks in rank_counts:
            load = os.getloadavg()[0]
            rows.append(_row(_launch(ranks, n, rounds=10 if n <= 10**6 else 5, repeats=7), load))
    admm_rows = []
    for ranks in (1, 2, 4):  # ADMM on parts (issue 30 item 3): the 10⁷ row only where the model says it fits
        load = os.getloadavg()[0]
        admm_rows.append(_admm_row(_launch(ranks, sizes[0][0], 3, 5, admm=True), load))
    model = admm_memory_model(admm_rows)
    if os.environ.get("DISTNAV_SCALE_BIG") == "1" and not quick and model and model[0]["fits"]:
        admm_rows.append(_admm_row(_launch(4, 10**7, 3, 3, admm=True), os.getloadavg()[0]))
    return rows + (model_rows(rows) if rows else []) + admm_rows + model


if __name__ == "__main__":
    main_for(__file__, run)
