"""Run every case of ``cases.py`` with the MPI backend; rank 0 writes the arrays to the .npz given as argv[1].

mpiexec -n 4 python -m mpi4py tests/mpi/run_cases.py OUT.npz [case ...]
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from cases import CASES  # noqa: E402
from mpi4py import MPI  # noqa: E402

out = Path(sys.argv[1])
names = sys.argv[2:] or list(CASES)
arrays: dict[str, np.ndarray] = {}
for name in names:
    for key, value in CASES[name]("mpi").items():
        arrays[f"{name}/{key}"] = np.asarray(value)
if MPI.COMM_WORLD.Get_rank() == 0:
    tmp = out.with_suffix(".tmp.npz")
    np.savez(tmp, **arrays)
    tmp.replace(out)
