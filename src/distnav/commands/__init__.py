"""Real-data command groups of the CLI (``distnav uwb ...``, ``distnav gnss ...``).

Commands that run a distributed algorithm take ``--backend inprocess|mpi`` and ``--ranks N``
(:func:`add_backend_arguments`) and build their exchange with :func:`command_exchange`. Under MPI the CLI lets only
rank 0 print and write files.
"""

from __future__ import annotations

import argparse

from distnav.exchange import Exchange, make_exchange
from distnav.network.graph import Graph


def add_backend_arguments(parser: argparse.ArgumentParser) -> None:
    """``--backend`` and ``--ranks`` as in ``distnav reproduce``."""
    parser.add_argument("--backend", choices=["inprocess", "mpi"], default="inprocess",
                        help="message transport of the distributed solver: in-process (default) or MPI "
                             "(launch with mpiexec -n N python -m mpi4py -m distnav ...)")
    parser.add_argument("--ranks", type=int, default=None,
                        help="with --backend mpi: the number of ranks launched (checked against MPI)")


def command_exchange(args: argparse.Namespace, graph: Graph) -> Exchange:
    """The exchange for a command's distributed solver on ``graph``, for ``args.backend``."""
    return make_exchange(graph, backend=getattr(args, "backend", "inprocess"))
