"""MPI start-up (launch + import, issue 17 item 4) alone: ``bench_mpi.startup_rows`` at 1, 2 and 4 ranks.

Kept apart from ``bench_mpi`` (the transport and round rows, up to 10⁶ nodes) so it can be re-run in a minute;
see ``bench_mpi`` for what is launched and how the figures are formed. Goal ≤ 0.3 s over an empty mpi4py job.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import main_for  # noqa: E402
from bench_mpi import startup_rows  # noqa: E402


def run(quick: bool) -> list[dict[str, Any]]:
    return startup_rows((1, 2, 4), repeat=3 if quick else 5)


if __name__ == "__main__":
    main_for(__file__, run)
