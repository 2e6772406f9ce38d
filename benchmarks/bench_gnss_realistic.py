"""GNSS bias product on the network simulator's "realistic" preset (issue 14): as ``bench_gnss_network.py``, with
:data:`distnav.models.gnss.netsim.REALISTIC` (larger, partly day-varying, station-dependent multipath, TIDs,
small-scale irregularities, a day-varying shell height), calibrated so that the first-wave model scores about
what it scored on the held-out IGS network (0.31–0.42 ns full day, 0.73 ns 6-h, 0.17 ns repeatability).
Quick: 2 days, sessions of the first day only."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import main_for  # noqa: E402
from bench_gnss_network import run as run_network  # noqa: E402


def run(quick: bool) -> list[dict[str, Any]]:
    return run_network(quick, preset="realistic")


if __name__ == "__main__":
    main_for(__file__, run)
