"""GNSS bias product on the network simulator's "realistic" preset (issue 14): as ``bench_gnss_network.py``, with
:data:`distnav.models.gnss.netsim.REALISTIC` (larger, partly day-varying, station-dependent multipath, TIDs,
small-scale irregularities, a day-varying shell height), calibrated so that the first-wave model scores about
what it scored on the held-out IGS network (0.31–0.42 ns full day, 0.73 ns 6-h, 0.17 ns repeatability).
Rows: the new default and the first-wave model, then the new model with the curved TEC field options
(``--tec-field quadratic``, ``--mapping mslm``, both; issue 14: the truth's field is smooth and linear-ish, so
the quadratic one must not hurt). Quick: 2 days, sessions of the first day only."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import main_for  # noqa: E402
from bench_gnss_network import run as run_network  # noqa: E402

VARIANTS: tuple[tuple[str, dict[str, Any]], ...] = (
    ("--tec-field quadratic", {"tec_order": 2}),
    ("--mapping mslm", {"mapping": "mslm"}),
    ("--tec-field quadratic --mapping mslm", {"tec_order": 2, "mapping": "mslm"}),
)


def run(quick: bool) -> list[dict[str, Any]]:
    rows = run_network(quick, preset="realistic")
    for label, options in VARIANTS:
        rows += run_network(quick, preset="realistic", models=("new",), options=options, label=label)
    return rows


if __name__ == "__main__":
    main_for(__file__, run)
