"""``python -m distnav`` (also under ``mpiexec ... python -m mpi4py -m distnav``)."""

import sys

from distnav.cli import main

sys.exit(main())
