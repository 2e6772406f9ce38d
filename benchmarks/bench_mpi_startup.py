"""MPI start-up (launch + import, issue 17 item 4) at 1, 2 and 4 ranks, split into its parts.

Four jobs are launched interleaved as ``mpiexec -n R python -m mpi4py -c CODE``, each a superset of the one before:

* ``empty``: ``from mpi4py import MPI``, a barrier — the launch itself (mpiexec, R interpreters, MPI init);
* ``numpy``: ``empty`` + ``import numpy`` — the floor of any numpy library;
* ``numpy_1thread``: ``numpy`` with ``OPENBLAS_NUM_THREADS=1`` — numpy's import without OpenBLAS's thread pool;
* ``distnav``: ``empty`` + the imports of a distnav MPI job (the MPI exchange, consensus and ADMM), numpy with them;
  ``import distnav`` sets one BLAS thread under an MPI launch (:mod:`distnav._threads`);
* ``distnav_pool``: ``distnav`` with ``OPENBLAS_NUM_THREADS`` = the core count set by the job (OpenBLAS's own
  default, what a distnav job paid before it chose one thread) — the before/after of that choice in one run;
* ``setup``: ``distnav`` + an MPI exchange built on a 1,000-node ring and one broadcast round (what the first
  set-up pays on top of the imports, scipy.sparse among it: it is imported on first use).

The parts are differences of jobs (launch, numpy import, the BLAS pool = numpy − numpy_1thread, distnav's own
import = distnav − numpy_1thread, exchange set-up),
as medians of the per-repeat differences, in **CPU seconds** of everything launched (``RUSAGE_CHILDREN`` around
``mpiexec``: the launcher and every rank; the machine's 2 cores are shared, so wall time says more about the
neighbours) and in wall seconds. Goal: ≤ 0.3 s added over the empty job (wall, as the issue states it; the CPU
figure is given too) — and where the remainder is numpy's own import, that is the floor a numpy library reaches.

Bytecode: an installed package has its bytecode compiled (pip does so by default); this sandbox sets
``PYTHONDONTWRITEBYTECODE=1`` and keeps no ``__pycache__`` next to the sources, so every launch would compile
distnav again (≈ 0.2 s). The benchmark therefore **precompiles** distnav with ``compileall`` into a fresh
``PYTHONPYCACHEPREFIX`` folder, which every launch then reads (the stdlib and site-packages are written there by
one warm-up launch of each job).
"""

from __future__ import annotations

import compileall
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import main_for  # noqa: E402

SRC = Path(__file__).resolve().parents[1] / "src"
_MPI = "from mpi4py import MPI; "
_END = "; MPI.COMM_WORLD.Barrier()"
_DISTNAV_IMPORTS = (
    "from distnav.exchange.mpi import MPIExchange; "
    "from distnav.algorithms.consensus.averaging import average_consensus; "
    "from distnav.algorithms.lsq.admm import admm"
)
_SETUP = (
    "; import numpy as np; from distnav.network.graph import Graph; from distnav.exchange import make_exchange; "
    "n = 1000; g = Graph.from_links(n, [(i, (i + 1) % n) for i in range(n)]); "
    "ex = make_exchange(g, backend='mpi'); ex.broadcast(np.ones(ex.n_local))"
)
_ONE = "import os; os.environ.update(OPENBLAS_NUM_THREADS='1', OMP_NUM_THREADS='1'); "
_POOL = "import os; os.environ['OPENBLAS_NUM_THREADS'] = str(os.cpu_count()); "  # OpenBLAS's own default
JOBS = {
    "empty": _MPI + "pass" + _END,
    "numpy": _MPI + "import numpy" + _END,
    "numpy_1thread": _MPI + _ONE + "import numpy" + _END,
    "distnav": _MPI + _DISTNAV_IMPORTS + _END,
    "distnav_pool": _MPI + _POOL + _DISTNAV_IMPORTS + _END,
    "setup": _MPI + _DISTNAV_IMPORTS + _SETUP + _END,
}
PARTS = (
    ("launch", None, "empty"),
    ("numpy import", "empty", "numpy"),
    ("BLAS pool", "numpy_1thread", "numpy"),
    ("distnav import", "numpy_1thread", "distnav"),
    ("exchange set-up", "distnav", "setup"),
)


def _env(cache: Path) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    env["PYTHONPYCACHEPREFIX"] = str(cache)
    env["PYTHONPATH"] = os.pathsep.join([str(SRC), *filter(None, [os.environ.get("PYTHONPATH")])])
    return env


def _precompile(cache: Path) -> None:
    """distnav's bytecode into ``cache`` (``compileall`` writes where ``sys.pycache_prefix`` points)."""
    before = sys.pycache_prefix
    sys.pycache_prefix = str(cache)
    try:
        compileall.compile_dir(str(SRC / "distnav"), quiet=1)
    finally:
        sys.pycache_prefix = before


def _launch(ranks: int, code: str, env: dict[str, str]) -> tuple[float, float]:
    """``(cpu_s, wall_s)`` of one launch: CPU of mpiexec and every rank (all waited-for descendants)."""
    mpiexec = Path(sys.executable).parent / "mpiexec"
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    subprocess.run(
        [str(mpiexec), "-n", str(ranks), sys.executable, "-m", "mpi4py", "-c", code],
        check=True,
        stdin=subprocess.DEVNULL,
        capture_output=True,
        timeout=120,
        env=env,
    )
    wall = time.perf_counter() - t0
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    return (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime), wall


def startup_rows(ranks: tuple[int, ...] = (1, 2, 4), repeat: int = 5) -> list[dict[str, Any]]:
    """One row per rank count: the jobs' medians, the parts, the ratios to the empty and the numpy-only job."""
    rows: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory(prefix="distnav-pyc-") as tmp:
        _precompile(Path(tmp))
        env = _env(Path(tmp))
        for r in ranks:
            for code in JOBS.values():  # warm-up: the file cache, and the stdlib's/numpy's bytecode
                _launch(r, code, env)
            cpu: dict[str, list[float]] = {k: [] for k in JOBS}
            wall: dict[str, list[float]] = {k: [] for k in JOBS}
            for _ in range(repeat):
                for k, code in JOBS.items():
                    c, w = _launch(r, code, env)
                    cpu[k].append(c)
                    wall[k].append(w)
            C = {k: np.asarray(v) for k, v in cpu.items()}
            Wl = {k: np.asarray(v) for k, v in wall.items()}
            parts = {name: float(np.median(C[hi] - (C[lo] if lo else 0.0))) for name, lo, hi in PARTS}
            parts_wall = {name: float(np.median(Wl[hi] - (Wl[lo] if lo else 0.0))) for name, lo, hi in PARTS}
            added_wall = Wl["distnav"] - Wl["empty"]
            added_cpu = C["distnav"] - C["empty"]
            pool_wall = Wl["distnav_pool"] - Wl["empty"]
            load = os.getloadavg()[0]
            med = {k: float(np.median(v)) for k, v in Wl.items()}
            medc = {k: float(np.median(v)) for k, v in C.items()}
            rows.append(
                {
                    "name": "MPI start-up (launch + import), seconds over an empty mpi4py job",
                    "ranks": r,
                    "distnav_s": med["distnav"],
                    "bare_setup_s": med["empty"],
                    "floor": "empty mpi4py job (import mpi4py.MPI, barrier); bytecode precompiled (compileall)",
                    "added_s_min": float(added_wall.min()),
                    "added_s_median": float(np.median(added_wall)),
                    "added_cpu_s_median": float(np.median(added_cpu)),
                    "numpy_job_s": med["numpy"],
                    "added_over_numpy_s_median": float(np.median(Wl["distnav"] - Wl["numpy"])),
                    "added_with_pool_s_min": float(pool_wall.min()),
                    "added_with_pool_s_median": float(np.median(pool_wall)),
                    "added_with_pool_cpu_s_median": float(np.median(C["distnav_pool"] - C["empty"])),
                    **{f"{k}_job_cpu_s": v for k, v in medc.items()},
                    **{f"{name.replace(' ', '_').replace('-', '')}_cpu_s": v for name, v in parts.items()},
                    **{f"{name.replace(' ', '_').replace('-', '')}_wall_s": v for name, v in parts_wall.items()},
                    "ratio": med["distnav"] / med["empty"],
                    "ratio_to_numpy_job": med["distnav"] / med["numpy"],
                    "cpu_ratio": medc["distnav"] / medc["empty"],
                    "cpu_ratio_to_numpy_job": medc["distnav"] / medc["numpy"],
                    "repeats": repeat,
                    "load_1min": load,
                    "goal": "≤ 0.3 s added",
                    "meets_goal": bool(np.median(added_wall) <= 0.3),
                    "note": (
                        f"added {added_wall.min():.2f}–{np.median(added_wall):.2f} s wall (min–median), "
                        f"{np.median(added_cpu):.2f} s CPU: numpy import {parts['numpy import']:.2f} of which BLAS "
                        f"pool {parts['BLAS pool']:.2f}, distnav's own {parts['distnav import']:.2f} (CPU s); "
                        f"with the BLAS pool {pool_wall.min():.2f}–{np.median(pool_wall):.2f} s wall; "
                        f"×{med['distnav'] / med['numpy']:.2f} the numpy-only job; load {load:.1f} on "
                        f"{os.cpu_count()} cores"
                    ),
                }
            )
    return rows


def run(quick: bool) -> list[dict[str, Any]]:
    return startup_rows((1, 2, 4), repeat=3 if quick else 5)


if __name__ == "__main__":
    main_for(__file__, run)
