"""One BLAS thread per MPI rank unless the user chose otherwise (issue 17 item 4: MPI start-up).

OpenBLAS starts its thread pool (one thread per core) when numpy is imported. Under ``mpiexec`` the ranks already
fill the cores, so each rank's pool only oversubscribes them, and creating it is ≈ 0.1 s CPU of every rank's
numpy import (docs/scale.md, "Start-up"). :func:`one_blas_thread_under_mpi` runs from ``distnav/__init__`` — before
any distnav module imports numpy — and sets ``OPENBLAS_NUM_THREADS=1`` and ``OMP_NUM_THREADS=1`` when

* the process was started by an MPI launcher (one of :data:`MPI_LAUNCH_VARIABLES` is set: MPICH/Hydra, Intel MPI,
  Open MPI, PMIx), and
* the user has set none of :data:`THREAD_VARIABLES` (setting any of them, e.g. ``OPENBLAS_NUM_THREADS=2``, keeps
  the user's choice), and
* numpy is not imported yet (afterwards OpenBLAS has read its environment already; nothing is changed then).

The variables are set in ``os.environ``, so processes the rank starts inherit them.
"""

from __future__ import annotations

import os
import sys
from collections.abc import MutableMapping

MPI_LAUNCH_VARIABLES = ("PMI_RANK", "PMI_SIZE", "MPI_LOCALNRANKS", "OMPI_COMM_WORLD_SIZE", "PMIX_RANK")
THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "GOTO_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")
SET_TO_ONE = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS")


def one_blas_thread_under_mpi(
    environ: MutableMapping[str, str] | None = None, numpy_imported: bool | None = None
) -> bool:
    """Set :data:`SET_TO_ONE` to ``"1"`` in ``environ`` (``os.environ``) under an MPI launch when the user set
    no thread count and numpy is not imported yet; returns whether it did."""
    env = os.environ if environ is None else environ
    if numpy_imported is None:
        numpy_imported = "numpy" in sys.modules
    if numpy_imported or not any(v in env for v in MPI_LAUNCH_VARIABLES) or any(v in env for v in THREAD_VARIABLES):
        return False
    for v in SET_TO_ONE:
        env[v] = "1"
    return True
