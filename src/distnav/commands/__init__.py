"""Real-data command groups of the CLI (``distnav uwb ...``, ``distnav gnss ...``).

Commands that run a distributed algorithm take ``--backend inprocess|mpi`` and ``--ranks N``
(:func:`add_backend_arguments`) and build their exchange with :func:`command_exchange`. Under MPI the CLI lets only
rank 0 print and write files.
"""

from __future__ import annotations

import argparse

from distnav.exchange import Exchange, make_exchange
from distnav.network.graph import Graph
from distnav.options import positive_int


def add_backend_arguments(parser: argparse.ArgumentParser) -> None:
    """``--backend`` and ``--ranks``, the same for ``distnav reproduce``, ``demo`` and the commands (the CLI checks
    that ``--ranks`` comes with ``--backend mpi`` and that the ``mpi`` extra is installed before any work)."""
    parser.add_argument(
        "--backend",
        choices=["inprocess", "mpi"],
        default="inprocess",
        help="message transport: in-process simulator (default) or MPI "
        "(launch with mpiexec -n N python -m mpi4py -m distnav ...)",
    )
    parser.add_argument(
        "--ranks",
        type=positive_int,
        default=None,
        help="with --backend mpi: the number of ranks you launched; distnav stops if MPI reports "
        "another (a mismatched mpiexec silently starts N one-process jobs)",
    )


def command_exchange(args: argparse.Namespace, graph: Graph) -> Exchange:
    """The exchange for a command's distributed solver on ``graph``, for ``args.backend``."""
    return make_exchange(graph, backend=getattr(args, "backend", "inprocess"))
