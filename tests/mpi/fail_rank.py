"""Run ``distnav reproduce consensus --backend mpi`` with rank ``argv[1]`` made to fail (``raise`` or ``die``).

mpiexec -n 4 python -m mpi4py tests/mpi/fail_rank.py RANK MODE OUT_DIR
"""

from __future__ import annotations

import os
import signal
import sys

from mpi4py import MPI

import distnav.experiments.consensus as experiment
from distnav.cli import main

bad_rank, mode, out_dir = int(sys.argv[1]), sys.argv[2], sys.argv[3]
if MPI.COMM_WORLD.Get_rank() == bad_rank:
    real = experiment.average_consensus

    def broken(*args, **kwargs):
        if mode == "die":
            os.kill(os.getpid(), signal.SIGKILL)
        raise RuntimeError("injected failure for the test")

    experiment.average_consensus = broken  # type: ignore[assignment]
sys.exit(main(["reproduce", "consensus", "--backend", "mpi", "--out", out_dir, "--quick", "--no-progress"]))
