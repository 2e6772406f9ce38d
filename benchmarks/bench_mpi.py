"""MPI exchange: per-round time vs a bare mpi4py Neighbor_allgather of the halo on the same rank graph.

Goal (issue 8): ≤ 2× the bare collective at 4, 8 and 16 ranks (2 cores here: 8 and 16 are oversubscribed).
Also rounds/s for 10^5 and 10^6 nodes partitioned over 2 and 4 ranks, and ADMM on 10^5 nodes over 2 and 4 ranks.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import main_for  # noqa: E402

HERE = Path(__file__).resolve().parent


def _launch(ranks: int, *args: int, script: str = "mpi_round.py") -> dict:
    mpiexec = Path(sys.executable).parent / "mpiexec"
    cmd = [str(mpiexec), "-n", str(ranks), sys.executable, "-m", "mpi4py", str(HERE / script), *map(str, args)]
    proc = subprocess.run(cmd, capture_output=True, text=True, stdin=subprocess.DEVNULL, timeout=900)
    if proc.returncode != 0:
        return {"ranks": ranks, "script": script, "error": proc.stderr[-300:]}
    return json.loads(proc.stdout.strip().splitlines()[-1])


def run(quick: bool) -> list[dict]:
    rows = []
    for ranks in (4, 8) if quick else (4, 8, 16):
        r = _launch(ranks, 20_000, 10, 50 if quick else 200)
        r["goal"] = "ratio ≤ 2"
        r["meets_goal"] = bool(r.get("ratio") is not None and r["ratio"] <= 2)
        rows.append(r)
    for n in (100_000,) if quick else (100_000, 1_000_000):
        for ranks in (2, 4):
            rows.append(_launch(ranks, n, 1, 20 if n > 100_000 else 50))
    if not quick:
        for ranks in (2, 4):  # ADMM on 10^5 nodes partitioned over ranks (scale-out, issue 8)
            rows.append(_launch(ranks, 100_000, 20, script="mpi_admm.py"))
    return rows


if __name__ == "__main__":
    main_for(__file__, run)
