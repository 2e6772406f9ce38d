"""MPI exchange against bare mpi4py kernels of the same work (``mpi_round.py``, launched under ``mpiexec``).

Rows: the halo transport alone (persistent ``Neighbor_alltoallv_init`` where the library has it) against a bare
``Neighbor_alltoallv`` with the same counts and preallocated buffers, goal ≤ 1.3× (issue 17 item 4); the full
consensus round against that collective plus one scipy CSR product of the rank's block; set-up and peak memory per
rank reported separately (docs/scale.md fits bytes per node and per link from them). The machine has 2 cores:
more ranks than that are oversubscribed and their ratios say little.

Start-up (launch + import, issue 17 item 4; rows written by ``bench_mpi_startup.py``): wall time of
``mpiexec -n R python -m mpi4py -c CODE`` where CODE imports what a distnav MPI job needs (the MPI exchange,
consensus and ADMM) and meets at a barrier, against an empty mpi4py job (import ``mpi4py.MPI``, barrier);
interleaved launches, the added seconds as min–median of the per-repeat differences. Goal ≤ 0.3 s over the empty
job. A job importing only numpy shows how much of that is
distnav's own. scipy.sparse is imported on first use since issue 17 (the first set-up or round pays it, not the
start-up); a job importing numpy and scipy.sparse says how much that is (``scipy_sparse_on_first_use_s_median``).
Every job reads its bytecode from one cache, as an installed package does (``PYTHONPYCACHEPREFIX`` set to a fresh
folder, written by a warm-up launch): with ``PYTHONDONTWRITEBYTECODE=1`` and no ``__pycache__`` next to the
sources, every launch would compile distnav again (≈ 0.2 s more, docs/scale.md).
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import main_for  # noqa: E402

HERE = Path(__file__).resolve().parent


def _launch(ranks: int, *args: int, script: str = "mpi_round.py") -> dict[str, Any]:
    mpiexec = Path(sys.executable).parent / "mpiexec"
    cmd = [str(mpiexec), "-n", str(ranks), sys.executable, "-m", "mpi4py", str(HERE / script), *map(str, args)]
    proc = subprocess.run(cmd, capture_output=True, text=True, stdin=subprocess.DEVNULL, timeout=1800)
    if proc.returncode != 0:
        return {"ranks": ranks, "script": script, "error": proc.stderr[-300:]}
    out: dict[str, Any] = json.loads(proc.stdout.strip().splitlines()[-1])
    return out


def _rows(r: dict[str, Any]) -> list[dict[str, Any]]:
    if "error" in r:
        return [r]
    per_rank = r.pop("per_rank")
    peak = max(p["end_mb"] for p in per_rank)
    common = {"n_nodes": r["n_nodes"], "ranks": r["ranks"], "payload_floats": r["payload_floats"]}
    return [
        {
            "name": "MPI halo transport",
            **common,
            "distnav_ms": r["transport_ms"],
            "floor_ms": r["bare_alltoallv_ms"],
            "floor": "bare mpi4py Neighbor_alltoallv",
            "ratio_min": r["transport_ratio_min"],
            "ratio_median": r["transport_ratio_median"],
            "goal": "≤ 1.3",
            "meets_goal": bool(r["transport_ratio_median"] <= 1.3),
            "persistent": r["persistent"],
            "setup_s": r["setup_s"],
        },
        {
            "name": "MPI consensus round",
            **common,
            "distnav_ms": r["round_ms"],
            "floor_ms": r["bare_round_ms"],
            "floor": "bare Neighbor_alltoallv + scipy CSR product of the block",
            "ratio_min": r["round_ratio_min"],
            "ratio_median": r["round_ratio_median"],
            "goal": "≤ 1.2",
            "meets_goal": bool(r["round_ratio_median"] <= 1.2),
            "setup_s": r["setup_s"],
            "graph_build_s": r["graph_s"],
            "peak_rss_mb_per_rank": peak,
            "cut_edges_fraction": r["cut_edges_fraction"],
            "per_rank": per_rank,
        },
    ]


_EMPTY_JOB = "from mpi4py import MPI; MPI.COMM_WORLD.Barrier()"
_NUMPY_JOB = "from mpi4py import MPI; import numpy; MPI.COMM_WORLD.Barrier()"
_SPARSE_JOB = "from mpi4py import MPI; import numpy, scipy.sparse; MPI.COMM_WORLD.Barrier()"
_DISTNAV_JOB = (
    "from mpi4py import MPI; from distnav.exchange.mpi import MPIExchange; "
    "from distnav.algorithms.consensus.averaging import average_consensus; "
    "from distnav.algorithms.lsq.admm import admm; "
    "MPI.COMM_WORLD.Barrier()"
)


def _launch_seconds(ranks: int, code: str, env: dict[str, str]) -> float:
    mpiexec = Path(sys.executable).parent / "mpiexec"
    t0 = time.perf_counter()
    subprocess.run(
        [str(mpiexec), "-n", str(ranks), sys.executable, "-m", "mpi4py", "-c", code],
        check=True,
        stdin=subprocess.DEVNULL,
        capture_output=True,
        timeout=120,
        env=env,
    )
    return time.perf_counter() - t0


def run(quick: bool) -> list[dict[str, Any]]:
    rows: list[dict[str, Any]] = []  # start-up: bench_mpi_startup.py
    cases = [(2, 100_000, 1, 50), (2, 100_000, 10, 30)]
    if not quick:
        cases += [(4, 100_000, 10, 30), (2, 1_000_000, 1, 30)]  # 10⁶ once: the machine is shared
    for ranks, n, payload, rounds in cases:
        rows += _rows(_launch(ranks, n, payload, rounds))
    if not quick:
        for ranks in (2, 4):  # ADMM on 10^5 nodes partitioned over ranks (scale-out, issue 8)
            rows.append(_launch(ranks, 100_000, 20, script="mpi_admm.py"))
    return rows


if __name__ == "__main__":
    main_for(__file__, run)
