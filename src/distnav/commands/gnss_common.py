"""What the real-data GNSS commands share: their data options (``--obs``, ``--nav | --sp3``, ``--graph``, ...)
and the checks of their values before any file is read, the station graph (a CSV of links or the default
nearest-neighbour graph), and the progress line.

``distnav gnss codebias`` (:mod:`distnav.commands.gnss_codebias`) and ``distnav gnss ionosphere``
(:mod:`distnav.commands.gnss_ionosphere`) use them; :mod:`distnav.commands.gnss` registers both.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

import numpy as np

from distnav.errors import DataFileError, ModelError
from distnav.formats.text import csv_rows, plain_text
from distnav.options import iso_datetime

__all__ = ["load_edges", "default_graph", "add_data_arguments", "check_data_arguments", "say"]


def load_edges(path: Path, stations: list[str]) -> Any:
    """A graph from a CSV of station-name pairs (one link per line, ``#`` comments and a header allowed)."""
    from distnav.network.graph import Graph

    index = {s.upper(): k for k, s in enumerate(stations)}
    links: list[tuple[int, int]] = []
    if not path.is_file():
        raise DataFileError(f"{path}: file not found" if not path.exists() else f"{path}: not a file")
    raw = path.read_bytes()
    text = plain_text(
        path,
        raw,
        encoding="utf-8",
        expected="a CSV of station-name pairs",
        undecodable="UTF-8 text: expected a CSV of station-name pairs",
    )
    header = ""
    for no, row in csv_rows(path, text.splitlines()):
        cells = [c.strip() for c in row if c.strip()]
        if not cells or cells[0].startswith("#"):
            continue
        if len(cells) != 2:
            raise DataFileError(f"{path}, line {no}: expected two station names, got {row}")
        a, b = (c.upper()[:4] if c.upper() not in index else c.upper() for c in cells)
        if a not in index or b not in index:
            if no == 1 and a not in index and b not in index:
                header = ",".join(cells)
                continue  # a header line (it names no station)
            unknown = [c for c in (a, b) if c not in index]
            raise DataFileError(
                f"{path}, line {no}: unknown station {', '.join(unknown)} (stations: {', '.join(stations)})"
            )
        if a == b:
            raise DataFileError(f"{path}, line {no}: a link from {a} to itself")
        links.append((index[a], index[b]))
    if not links and header:
        raise DataFileError(
            f"{path}: no links (line 1, {header!r}, names none of the stations {', '.join(stations)} and was taken "
            f"as a header)"
        )
    if not links and len(stations) > 1:
        raise DataFileError(f"{path}: no links")
    graph = Graph.from_links(len(stations), links, names=stations, allow_duplicates=True)
    graph.require_connected(f"the graph of {path.name}")
    return graph


def default_graph(positions_ecef_m: np.ndarray, stations: list[str], k: int = 2) -> Any:
    """Minimum spanning tree of the stations (straight-line distance) plus links to each one's ``k`` nearest."""
    from distnav.network.graph import Graph

    n = len(stations)
    d = np.linalg.norm(positions_ecef_m[:, None] - positions_ecef_m[None], axis=-1)
    links: set[tuple[int, int]] = set()
    if n > 1:
        links |= {(min(i, j), max(i, j)) for i, j in _spanning_tree(d + 1e-9 * (1 - np.eye(n)))}
        for i in range(n):
            others = np.where(np.arange(n) == i, np.inf, d[i])  # not [1:]: a station at the same point may sort first
            for j in np.argsort(others)[: min(k, n - 1)].tolist():
                links.add((min(i, j), max(i, j)))
    return Graph.from_links(n, sorted(links), names=stations)


def _spanning_tree(w: np.ndarray) -> list[tuple[int, int]]:
    """The links of ``scipy.sparse.csgraph.minimum_spanning_tree(w)`` for a dense ``w`` (zero: no link), without
    importing scipy.sparse and scipy.linalg (0.04 s CPU of the 4.5-s full-day run, issue 32): Kruskal's algorithm
    as scipy runs it — the finite entries in row-major order, stably sorted by weight, each kept when it joins two
    components — so ties are broken the same way; like scipy's dense input (``numpy.ma.masked_values``: ``isclose``
    to 0) an entry within 1e-8 of zero is no link (``tests/test_gnss_commands.py`` checks the two against each
    other, ties and coincident stations included)."""
    i, j = np.nonzero(np.isfinite(w) & (np.abs(w) > 1e-8))
    parent = list(range(w.shape[0]))

    def root(a: int) -> int:
        while parent[a] != a:
            parent[a] = parent[parent[a]]
            a = parent[a]
        return a

    out: list[tuple[int, int]] = []
    for e in np.argsort(w[i, j], kind="stable").tolist():
        ra, rb = root(int(i[e])), root(int(j[e]))
        if ra != rb:
            parent[ra] = rb
            out.append((int(i[e]), int(j[e])))
    return out


def say(args: argparse.Namespace, text: str) -> None:
    """A progress line on stderr, unless ``--no-progress``."""
    if not getattr(args, "no_progress", False):
        print(text, file=sys.stderr, flush=True)


def add_data_arguments(parser: argparse.ArgumentParser, *, obs_note: str = "") -> None:
    """The data options every real-data GNSS command shares: --obs, --nav | --sp3, --nav-max-age, --graph,
    --tlim, --interval, --mask."""
    parser.add_argument(
        "--obs",
        nargs="+",
        required=True,
        metavar="FILE",
        help=f"RINEX 2.11/3.x observation files (.o/.d/.crx, gzip ok), one per station{obs_note}",
    )
    orbit = parser.add_mutually_exclusive_group(required=True)
    orbit.add_argument(
        "--nav",
        nargs="+",
        metavar="FILE",
        help="RINEX navigation file (broadcast ephemerides); one per day for several days",
    )
    orbit.add_argument("--sp3", nargs="+", metavar="FILE", help="SP3 orbit files")
    parser.add_argument(
        "--nav-max-age",
        type=float,
        default=4.0,
        metavar="HOURS",
        help="use a broadcast record up to this far from its toe (default 4 h; elevations only need "
        "km accuracy, so a sparse station nav file may need more)",
    )
    parser.add_argument("--graph", metavar="EDGES.csv", help="links as station-name pairs (default: MST + 2 nearest)")
    parser.add_argument(
        "--tlim",
        nargs=2,
        type=iso_datetime,  # also refuses a time zone: times are GPS time (options.py)
        metavar=("START", "STOP"),
        help="time window (GPS time, no time zone), e.g. 2024-01-10T00:00 ...",
    )
    parser.add_argument("--interval", type=float, default=None, help="keep epochs on this grid [s] (e.g. 60)")
    parser.add_argument("--mask", type=float, default=10.0, help="elevation mask [deg] (default 10)")


#: The largest zenith code σ (m) ``--sigma`` takes (``gnss codebias``, ``gnss ionosphere``): beyond it nothing is
#: modelled (``--sigma 1e308`` ran on with "invalid value encountered in scalar divide" and exit 0)
MAX_CODE_SIGMA_M = 100.0
CODE_SIGMA_WHY = "a zenith code σ over 100 m is no code observation"


def check_data_arguments(args: argparse.Namespace) -> None:
    """Check the values of the shared data options (:func:`add_data_arguments`) before any file is read; errors
    name the option (the CLI exits with 2)."""
    for opt, value in (("--interval", args.interval), ("--nav-max-age", args.nav_max_age)):
        if value is not None and not (np.isfinite(value) and value > 0.0):
            raise ModelError(f"{opt} {value:g}: must be a positive number")
    if not 0.0 <= args.mask < 90.0:
        raise ModelError(f"--mask {args.mask:g}: the elevation mask must lie in [0, 90) degrees")
    if args.tlim:
        try:
            t0, t1 = (np.datetime64(t, "s") for t in args.tlim)
        except ValueError:
            raise ModelError(f"--tlim {' '.join(args.tlim)}: not ISO date/times (e.g. 2024-01-10T06:00)") from None
        if not t0 < t1:
            raise ModelError(f"--tlim {' '.join(args.tlim)}: the start must be before the stop")
    for opt, files in (
        ("--obs", args.obs),
        ("--nav", args.nav),
        ("--sp3", args.sp3),
        ("--graph", [args.graph] if args.graph else None),
        ("--bias", getattr(args, "bias", None)),
    ):
        for f in files or []:
            if not Path(f).is_file():
                raise DataFileError(f"{opt} {f}: file not found")
    out = getattr(args, "out", None)
    if out is not None and Path(out).exists() and not Path(out).is_dir():
        raise DataFileError(f"--out {out}: exists and is not a folder")


def documented_parser(subparsers: Any, name: str, help_text: str, doc: str | None) -> argparse.ArgumentParser:
    """A ``distnav gnss <name>`` sub-command whose ``--help`` shows the module docstring ``doc`` as written."""
    parser: argparse.ArgumentParser = subparsers.add_parser(
        name, help=help_text, description=doc, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    return parser
