"""``distnav gnss ionosphere``: TEC and receiver + satellite DCBs of a receiver network from real RINEX code data, by
the central filter, the single-receiver (local) filters and the consensus Kalman filter (paper 003 §5).

    distnav gnss ionosphere --obs FILE... (--nav FILE | --sp3 FILE...) [--graph EDGES.csv] [--kn K]
                            [--bias FILE...] [--datum-satellites LIST|PRODUCT] [--out DIR]

Per station the geometry-free code ``(P_b − P_1)/(μ_b − 1)`` is formed from the chosen codes (default C1C and C2W,
or C1W when no ``--bias`` product gives C1C DSBs; RINEX 2 ``C1`` = C1C, ``P1`` = C1W, ``P2`` = C2W; C5Q/C5X use
the L5 factor), levelled to the carrier per arc (slips by geometry-free phase and Melbourne–Wübbena) and
w-tested by each station on its own data. The model (:mod:`distnav.models.gnss.gfbias`, docs/ionosphere.md):
a regional single-layer VTEC field per ionosphere (one per receiver when the network spans more than
``--regional-km``) plus receiver *and* satellite DSBs, output in the ``--datum`` S-basis (zero-mean satellites by
default, over the satellites estimated or a fixed ``--datum-satellites`` set; a ``--pivot`` satellite; a
``--reference`` receiver; the datum and its satellites are printed and written). Outputs in ``DIR``:

* ``tec_dcb_per_epoch.csv`` — per epoch, filter (``central``, ``local:STA``, ``ckf:STA``) and parameter: value
  and formal standard deviation (TEC in metres of L1 delay and in TECU, DSBs in ns).
* ``dcb_final.csv`` — the last-epoch DSBs of every filter and, with ``--bias``, each product's.
* ``arcs.csv`` — every arc (start reason, offset, code RMS) with every removal by reason: ``removed`` (w-test
  screening), ``removed_mw_outliers`` (one-epoch Melbourne–Wübbena outliers in its span), ``dropped_short`` (the
  whole arc, shorter than ``--min-arc``: no offset).
* ``distnav_dsb.bia`` — Bias-SINEX 1.00 of the central filter (realistic σ).
* ``summary.json`` — settings, codes, arcs, screening, precision, the satellites' fit, and per filter and product
  the datum-aligned comparison (mean, RMS, max, per satellite and receiver, the worst-fitting satellite).

Files of several days (IGS names) give one folder per day, ``multiday.json`` (combined, repeatability) and
``distnav_dsb_combined.bia``. ``--bias`` takes Bias-SINEX (CAS/GFZ ``.BIA``; DSBs chained across the files as in
``distnav gnss compare``) and IONEX files with a DCB block (``START OF AUX DATA``, P1−P2 = C1W−C2W); a product of
another day is refused unless ``--allow-other-day``. Sign convention of both: biases add to the observations.
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from distnav.commands import add_backend_arguments, command_exchange
from distnav.commands.gnss_common import CODE_SIGMA_WHY, MAX_CODE_SIGMA_M
from distnav.commands.gnss_ionosphere_data import REGIONAL_KM, NetworkOptions, network_data, network_from_observations
from distnav.errors import DataFileError, ModelError
from distnav.options import nonnegative_float, output_folder

__all__ = [
    "NetworkOptions",
    "add_ionosphere_parser",
    "filter_options",
    "network_options",
    "add_parser",
    "network_data",  # the data stages (gnss_ionosphere_data), re-exported
    "network_from_observations",
    "run_ionosphere",
    "validate_arguments",
]


#: the most consensus rounds per epoch ``--kn`` takes: each round is one message per link, every epoch runs them
#: all (2,880 epochs of a day at 30 s), so 10⁸ (a typo) would run for days; the paper's networks converge within
#: tens of rounds (paper 003 §5: 4, δ = 15 s at Δ = 60 s)
MAX_KN = 10_000


def _say(args: argparse.Namespace, text: str) -> None:
    if not getattr(args, "no_progress", False):
        print(text, file=sys.stderr, flush=True)


_SYSTEM_TABLE = {  # --system: satellite ids, first code, second code (patterns; then the same in words)
    "G": r"^G(0[1-9]|[12][0-9]|3[0-2])$ ^C1[CSLXPWYMN]$ ^C(2[CDSLXPWYMN]|5[IQX])$",
    "E": r"^E(0[1-9]|[1-3][0-9])$ ^C1[ABCXZ]$ ^C[578][IQX]$",
    "C": r"^C(0[1-9]|[1-5][0-9]|6[0-3])$ ^C2[IQX]$ ^C[67][IQX]$",
    "R": r"^R(0[1-9]|1[0-9]|2[0-7])$ ^C1[CP]$ ^C2[CP]$",
}
_SYSTEM_WORDS = {
    "G": "a GPS satellite (G01 … G32);GPS L1 code (C1C, C1W, C1L, C1X …);GPS L2 or L5 code (C2W, C2L, C2X, C5Q, C5X …)",
    "E": "a Galileo satellite (E01 … E36);Galileo E1 code (C1C, C1X …);Galileo E5a, E5b or E5 code (C5Q, C5X, C7Q …)",
    "C": "a BeiDou satellite (C01 … C63);BeiDou B1I code (C2I, C2X …);BeiDou B3I or B2I code (C6I, C7I …)",
    "R": "a GLONASS satellite (R01 … R27);GLONASS G1 code (C1C, C1P);GLONASS G2 code (C2C, C2P)",
}


_SYSTEM_CODES = {  # --system: the default codes (first, second) where --l1-code / --l2-code are not given
    "G": (None, "C2W"),  # the first code: C1C, or C1W when the comparison products are on P1 (choose_l1_code)
    "E": ("C1X", "C5X"),
    "C": ("C2I", "C6I"),
    "R": ("C1C", "C2C"),
}


#: Upper limits of the model's σ options: beyond them nothing is modelled, and the run broke (``--tec-rw 1e30``: a
#: singular matrix, a traceback; ``--sigma 1e308``: "invalid value encountered in scalar divide", exit 0)
_UPPER_LIMITS = (
    ("--sigma", "sigma", MAX_CODE_SIGMA_M, CODE_SIGMA_WHY),
    ("--tec-rw", "tec_rw", 1e3, "10⁵ × the default: over one 60-s epoch the vertical delay could change by km"),
)


def validate_arguments(args: argparse.Namespace) -> None:
    """Check every option value before any file is read (errors name the option; the CLI exits with 2); codes not
    given take the system's defaults (:data:`_SYSTEM_CODES`)."""
    system = getattr(args, "system", "G")
    first, second = _SYSTEM_CODES[system]
    if args.l1_code is None and first is not None:
        args.l1_code = first
    if args.l2_code is None:
        args.l2_code = second
    prn, l1_code, lb_code = (re.compile(p) for p in _SYSTEM_TABLE[system].split())
    sat_words, l1_words, lb_words = _SYSTEM_WORDS[system].split(";")
    if args.pivot is not None and not prn.match(str(args.pivot).upper()):
        raise ModelError(f"--pivot {args.pivot}: not {sat_words}")
    if args.datum == "pivot" and args.pivot is None:
        raise ModelError("--datum pivot needs --pivot PRN (e.g. --pivot G10)")
    if args.pivot is not None and args.datum != "pivot":
        raise ModelError(
            f"--pivot {args.pivot} is the pivot of --datum pivot; the datum is {args.datum} (add "
            f"--datum pivot, or leave --pivot out)"
        )
    if args.l1_code is not None and not l1_code.match(args.l1_code.upper()):
        raise ModelError(f"--l1-code {args.l1_code}: not a {l1_words}")
    if not lb_code.match(args.l2_code.upper()):
        raise ModelError(f"--l2-code {args.l2_code}: not a {lb_words}")
    for opt, value in (("--sigma", args.sigma), ("--regional-km", args.regional_km), ("--tec-rw", args.tec_rw)):
        if value is not None and not (np.isfinite(value) and value > 0.0):
            raise ModelError(f"{opt} {value:g}: must be a positive number")
    for opt, value, most, why in _UPPER_LIMITS:
        if getattr(args, value) is not None and getattr(args, value) > most:
            raise ModelError(f"{opt} {getattr(args, value):g}: at most {most:g} ({why})")
    if not 0 <= args.kn <= MAX_KN:
        raise ModelError(
            f"--kn must lie in 0 … {MAX_KN:,} consensus rounds per epoch, got {args.kn:,} (every epoch runs them "
            f"all: a day at 30 s is 2,880 epochs)"
        )
    if args.between_station_level != 0 and not 0.0 < args.between_station_level < 0.5:
        raise ModelError(
            f"--between-station-level {args.between_station_level:g}: a test level in (0, 0.5), or 0 (off)"
        )
    if args.innovation_test is not None and not 0.0 < args.innovation_test < 0.5:
        raise ModelError(f"--innovation-test {args.innovation_test:g}: a test level in (0, 0.5), e.g. 0.001")
    if args.min_satellite_obs is not None and args.min_satellite_obs < 1:
        raise ModelError(f"--min-satellite-obs must be ≥ 1, got {args.min_satellite_obs}")
    if args.min_arc < 2:
        raise ModelError(f"--min-arc must be ≥ 2 epochs, got {args.min_arc}")
    if not (np.isfinite(args.gf_threshold) and args.gf_threshold > 0.0):
        raise ModelError(f"--gf-threshold {args.gf_threshold:g}: must be a positive number of metres")
    for e in (args.exclude or []) + (args.compare_exclude or []):
        if not (prn.match(e.upper()) or re.match(r"^[A-Za-z0-9]{4}$", e)):
            raise ModelError(f"--exclude {e}: neither {sat_words} nor a 4-character station")
    if getattr(args, "c1_corrections", None):
        if args.l1_code is not None and args.l1_code.upper() != "C1C":
            raise ModelError(f"--c1-corrections applies to --l1-code C1C, not {args.l1_code}")
        if not Path(args.c1_corrections).exists():
            raise DataFileError(f"--c1-corrections {args.c1_corrections}: file not found")
    if args.reference is not None and not re.match(r"^[A-Za-z0-9]{4}$", args.reference):
        raise ModelError(f"--reference {args.reference}: not a 4-character station name")
    from distnav.commands.gnss import check_data_arguments  # gnss.py registers this module: import lazily
    from distnav.commands.gnss_datum import check_datum_option

    check_datum_option(args)
    check_data_arguments(args)  # the shared data options, then whether the named files exist
    _check_tlim_days(args)


def _check_tlim_days(args: argparse.Namespace) -> None:
    """``--tlim`` against the days the observation files' names give (IGS long or short names), before any
    file is read: a window outside every file's day is an error, not a read of the whole files."""
    from distnav.formats.gnss.product_files import product_day

    if not args.tlim:
        return
    days = [product_day(f) for f in args.obs]
    if any(d is None for d in days):
        return  # a name without a day: the reader finds out
    t0, t1 = (np.datetime64(t, "s") for t in args.tlim)
    if not any(t0 < d + np.timedelta64(1, "D") and t1 > d for d in days if d is not None):
        raise ModelError(
            f"--tlim {' '.join(args.tlim)}: outside the day(s) of the --obs files "
            f"({', '.join(sorted({str(d) for d in days}))})"
        )


def _iso(t_gps_s: float) -> str:
    from distnav.models.gnss.orbits import datetime_from_gps_seconds

    return str(datetime_from_gps_seconds(t_gps_s))[:19]


def run_ionosphere(args: argparse.Namespace) -> int:
    """Handler of ``distnav gnss ionosphere``: wires the options to the stages — read and prepare the network
    (:func:`network_data`), the filters in the chosen datum (:func:`~distnav.models.gnss.gfnetwork.
    run_bias_filters`), the outputs (:func:`~distnav.commands.gnss_ionosphere_out.write_results`)."""
    from distnav.commands.gnss_datum import check_datum_tracked, datum_choice
    from distnav.commands.gnss_ionosphere_out import write_results
    from distnav.models.gnss.gfnetwork import run_bias_filters

    validate_arguments(args)
    days = _split_days(args)
    if len(days) > 1:
        return _run_days(args, days)
    l1, l1_note = _first_code(args)
    orbit = _read_orbit(args)
    try:
        data = network_data(
            args.obs,
            orbit,
            network_options(args),
            l1_code=l1,
            tlim=tuple(args.tlim) if args.tlim else None,
            progress=lambda label, fraction: _say(args, f"reading {label}: {100 * fraction:3.0f} %"),
            c1_corrections=args.c1_corrections,
            system=getattr(args, "system", "G"),
        )
    except DataFileError as exc:
        if l1_note and f"({l1})" in str(exc):
            raise DataFileError(f"{exc} ({l1_note})") from None
        raise
    l1 = "C1W" if args.c1_corrections else l1
    stations, layout = data.stations, data.layout
    pivot = _pivot(args, layout.svs)
    graph = _network_graph(args, data)
    fixed = datum_choice(args, l1, args.l2_code.upper())
    check_datum_tracked(fixed, layout.svs)
    _say(
        args,
        f"{len(stations)} station(s), {data.series.n_epochs} epochs, {len(layout.svs)} satellites, datum "
        f"{args.datum}, estimation basis: receiver {layout.reference}; ionosphere {data.ionosphere}; graph links "
        f"{[(stations[i], stations[j]) for i, j in graph.links]}",
    )
    series, comm = run_bias_filters(
        data, filter_options(args, pivot, fixed), graph=graph, exchange=command_exchange(args, graph)
    )
    from dataclasses import replace

    from distnav.models.gnss.modelspread import sigma_limits, spread_of_own_layers

    if getattr(args, "model_spread", "auto") == "auto":
        series, spread = spread_of_own_layers(data, orbit, series, network_options(args).model_options)
        if spread is not None:
            data = replace(data, notes=[*data.notes, spread.statement()])
    from distnav.commands.gnss_sigma_terms import sigma_terms

    data, series = sigma_terms(args, data, orbit, network_options(args), series)
    ifb = "glonass_channel_ifb" in data.sigma_terms
    limits = sigma_limits(series, len(stations), getattr(args, "system", "G"), args.levelling == "arc", ifb)
    data = replace(data, notes=[*data.notes, *limits])
    write_results(args, data, series, comm, l1=l1, l2=args.l2_code.upper(), pivot=pivot, graph=graph, fixed=fixed)
    return 0


def network_options(args: argparse.Namespace) -> NetworkOptions:
    """The data and model stages' options from the command line."""
    from distnav.models.gnss.biasmodel import BiasModelOptions
    from distnav.models.gnss.gfbias import TEC_RW_M_PER_SQRT_S

    model = BiasModelOptions(
        mask_deg=args.mask,
        ionosphere=args.ionosphere,
        regional_km=args.regional_km,
        sigma_zenith_m=args.sigma,
        weighting=args.weighting,
        reference=args.reference,
        vtec_rw_m_per_sqrt_s=TEC_RW_M_PER_SQRT_S if args.tec_rw is None else args.tec_rw,
        min_satellite_obs=args.min_satellite_obs,
        tec_order=2 if args.tec_field == "quadratic" else 1,
        mapping=args.mapping,
    )
    return NetworkOptions(
        l2_code=args.l2_code.upper(),
        interval_s=args.interval,
        exclude=tuple(args.exclude or ()),
        levelling=args.levelling == "arc",
        min_arc_epochs=args.min_arc,
        gf_threshold_m=args.gf_threshold,
        screen=not args.no_screening,
        model=model,
    )


def filter_options(args: argparse.Namespace, pivot: str | None, fixed: Any) -> Any:
    """The filter stage's options (:class:`~distnav.models.gnss.gfnetwork.BiasFilterOptions`) from the command
    line, the checked pivot and the fixed datum set (:func:`~distnav.commands.gnss_datum.datum_choice`)."""
    from distnav.models.gnss.gfnetwork import BiasFilterOptions

    return BiasFilterOptions(
        datum=args.datum,
        pivot=pivot,
        reference=args.reference,
        kn=args.kn,
        innovation_level=args.innovation_test,
        datum_satellites=fixed.members,
        datum_reference_ns=fixed.reference_ns,
        between_station_level=None if args.between_station_level == 0 else args.between_station_level,
    )


def _first_code(args: argparse.Namespace) -> tuple[str, str | None]:
    """The L1 code and why it was chosen (printed, with the C1C warning), after the product files are checked."""
    from distnav.commands.gnss_report import C1C_WARNING, choose_l1_code

    l1, l1_note = choose_l1_code(args)
    if l1_note:
        print(f"NOTE: {l1_note}", file=sys.stderr, flush=True)
    if l1 == "C1C" and not args.c1_corrections and getattr(args, "system", "G") == "G":
        print(C1C_WARNING.format(l2=args.l2_code.upper()), file=sys.stderr, flush=True)
    for b in args.bias or []:
        if not Path(b).exists():
            raise DataFileError(f"{b}: file not found")
    return l1, l1_note


def _read_orbit(args: argparse.Namespace) -> Any:
    """The broadcast (one ``--nav`` file of the day) or SP3 orbits."""
    from distnav.formats.gnss.rinex import read_navigation, read_sp3

    if args.nav and len(args.nav) > 1:
        raise ModelError(f"{len(args.nav)} --nav files for one day of observations: give one")
    system = getattr(args, "system", "G")
    if args.nav and system == "R":
        from distnav.formats.gnss.rinex_nav import read_glonass_ephemerides
        from distnav.models.gnss.glonass import GlonassOrbit

        records = read_glonass_ephemerides(args.nav[0])
        if not records:
            raise DataFileError(f"{args.nav[0]}: no GLONASS navigation records")
        return GlonassOrbit.from_records(records, source=str(args.nav[0]))
    if args.nav:
        return read_navigation(args.nav[0], max_age_s=args.nav_max_age * 3600.0, systems=(system,))
    return read_sp3(args.sp3, system=system)


def _pivot(args: argparse.Namespace, svs: Sequence[str]) -> str | None:
    """The ``--pivot`` satellite, which the pivot datum needs tracked."""
    pivot = args.pivot.upper() if args.pivot else None
    if args.datum == "pivot" and pivot not in svs:
        raise ModelError(f"--pivot {pivot}: not tracked above the mask by any station (tracked: {' '.join(svs)})")
    return pivot


def _network_graph(args: argparse.Namespace, data: Any) -> Any:
    """The CKF's communication graph: ``--graph`` or the default (:func:`~distnav.commands.gnss.default_graph`)."""
    if args.graph:
        from distnav.commands.gnss import load_edges

        return load_edges(Path(args.graph), data.stations)
    return _default_graph(data.positions_ecef_m, data.stations)


def _split_days(args: argparse.Namespace) -> dict[str, list[str]]:
    """Observation files by day (from the IGS file names; a name without a day goes with the first)."""
    from distnav.formats.gnss.product_files import product_day

    by: dict[str, list[str]] = {}
    for f in args.obs:
        d = product_day(f)
        by.setdefault(str(d) if d is not None else "", []).append(f)
    if "" in by and len(by) > 1:
        raise ModelError(f"cannot tell the day of {', '.join(by[''])}: use IGS file names or one day per run")
    return by


def _run_days(args: argparse.Namespace, days: dict[str, list[str]]) -> int:
    """Several days: one solution per day (``DIR/YYYY-MM-DD/``), the combined one and the day-to-day
    repeatability (``DIR/multiday.json``, ``DIR/distnav_dsb_combined.bia``)."""
    from distnav.commands.gnss_report import worst_over_days
    from distnav.commands.gnss_sinex_out import write_combined_sinex
    from distnav.formats.gnss.product_files import product_day
    from distnav.models.gnss.multiday import combine_days
    from distnav.output import atomic_write_json

    if args.tlim:
        raise ModelError("--tlim selects a window of one day; with files of several days leave it out")
    navs: dict[str, str] = {}
    for f in args.nav or []:
        navs.setdefault(str(product_day(f)), f)
    if args.nav and (len(args.nav) > 1 or all(product_day(f) is not None for f in args.nav)):
        missing = [d for d in days if d not in navs]
        if missing:  # a broadcast file of another day leaves most satellites out
            raise DataFileError(
                f"no --nav file of {', '.join(missing)} (navigation files: {', '.join(args.nav)}): give one per day"
            )
        if len(navs) < len(args.nav):
            raise DataFileError(f"two --nav files of the same day among {', '.join(args.nav)}")
    out = Path(args.out)
    summaries = {}
    for day, files in sorted(days.items()):
        sub = argparse.Namespace(**vars(args))
        sub.obs, sub.out = files, str(out / day)
        if args.nav:
            sub.nav = [navs.get(day, args.nav[0])]
        if args.bias:
            sub.bias = [b for b in args.bias if product_day(b) in (None, np.datetime64(day))] or None
        print(f"=== {day}: {len(files)} station file(s) ===")
        rc = run_ionosphere(sub)
        if rc != 0:
            return rc
        summaries[day] = json.loads((out / day / "summary.json").read_text())
    result = combine_days(summaries)
    worst_over_days(result, summaries)
    atomic_write_json(out / "multiday.json", result)
    from distnav.formats.gnss.product_files import satellite_svns

    svns = satellite_svns([*(args.bias or []), *([args.datum_satellites] if args.datum_satellites else [])])
    write_combined_sinex(out / "distnav_dsb_combined.bia", result, summaries, svns)
    rep = result["repeatability_ns"]
    med = np.nanmedian([v for v in rep.values() if v is not None]) if rep else float("nan")
    rx = ", ".join(f"{k[3:]} {v:.3f}" for k, v in sorted(rep.items()) if k.startswith("rx:") and v is not None)
    print(
        f"combined {len(summaries)} days: {len(result['combined_ns'])} DSBs; day-to-day repeatability (std) median "
        f"{med:.3f} ns over the satellites"
        + (f", receivers {rx} ns" if rx else "")
        + f"; {100 * result['repeating_share']:.0f} % of the daily variance repeats (kept in the combined σ)"
        + f"; written {out / 'multiday.json'}, {out / 'distnav_dsb_combined.bia'}"
    )
    return 0


def _default_graph(xyz: np.ndarray, stations: list[str]) -> Any:
    from distnav.commands.gnss import default_graph

    return default_graph(xyz, stations)


def add_ionosphere_parser(gnss_subparsers: Any) -> argparse.ArgumentParser:
    """Add ``distnav gnss ionosphere`` to the ``gnss`` sub-command group (``set_defaults(func=run_ionosphere)``)."""
    from distnav.commands.gnss_common import add_data_arguments, documented_parser

    what = "TEC and receiver + satellite DCBs by central, local and consensus Kalman filters (paper 003 §5)"
    p = documented_parser(gnss_subparsers, "ionosphere", what, __doc__)

    add_data_arguments(p)
    p.add_argument("--kn", type=int, default=4, help="consensus rounds per epoch (default 4 = δ 15 s at Δ 60 s)")
    p.add_argument(
        "--bias",
        nargs="+",
        metavar="FILE",
        help="published products to compare with: Bias-SINEX (.BIA) and/or IONEX with a DCB block",
    )
    p.add_argument(
        "--out", type=output_folder, default="distnav-ionosphere", help="output folder (default distnav-ionosphere)"
    )
    add_backend_arguments(p)
    _add_code_and_datum_arguments(p)
    _add_selection_arguments(p)
    _add_tec_field_arguments(p)
    _add_levelling_arguments(p)
    _add_model_arguments(p)
    p.add_argument(
        "--system",
        choices=sorted(_SYSTEM_TABLE),
        default="G",
        help="satellite system: G (GPS, default), E (Galileo: RINEX 3 or RINEX 2.11 mixed observations, e.g. "
        "--l1-code C1X --l2-code C5X), C (BeiDou, RINEX 3: --l1-code C2I --l2-code C6I or C7I) or R (GLONASS: "
        "--l1-code C1C --l2-code C2C, or C1P/C2P; FDMA channels from the header or the --nav file); orbits from "
        "a mixed --nav file or a multi-GNSS --sp3",
    )
    p.add_argument("--no-progress", action="store_true")
    p.set_defaults(func=run_ionosphere)
    parser: argparse.ArgumentParser = p
    return parser


def _add_code_and_datum_arguments(p: argparse.ArgumentParser) -> None:
    """The codes and the output datum (S-basis, pivot, fixed satellite set, reference receiver)."""
    p.add_argument(
        "--l1-code",
        default=None,
        help="first code (GPS: C1C = RINEX 2 C1, C1W = P1; default C1C, or C1W when every --bias is IONEX; "
        "Galileo C1X, BeiDou C2I, GLONASS C1C by default)",
    )
    p.add_argument(
        "--l2-code",
        default=None,
        help="second code (GPS: default C2W = RINEX 2 P2, C5Q/C5X use the L5 frequency factor; Galileo C5X, "
        "BeiDou C6I, GLONASS C2C by default)",
    )
    p.add_argument(
        "--datum",
        choices=["zero-mean", "pivot", "receiver"],
        default="zero-mean",
        help="S-basis of the output DSBs: zero-mean satellites (IGS products; default), a pivot "
        "satellite (--pivot) or a reference receiver (--reference)",
    )
    p.add_argument("--pivot", default=None, help="pivot satellite of --datum pivot (e.g. G10)")
    p.add_argument(
        "--datum-satellites",
        default=None,
        metavar="LIST|PRODUCT",
        help="fixed satellite set of the zero-mean datum: G01,G02,... or a Bias-SINEX product (its satellites; a "
        "missing one is held at the product's value, so it moves no other; output in the product's datum)",
    )
    p.add_argument(
        "--reference",
        default=None,
        metavar="STATION",
        help="reference receiver (--datum receiver; also the estimation basis; default: the station "
        "observing at the first epoch)",
    )


def _add_selection_arguments(p: argparse.ArgumentParser) -> None:
    """What is left out of the estimation and of the comparison, and the C1 corrections."""
    p.add_argument("--exclude", nargs="+", metavar="SAT|STA", help="satellites (G01) or stations (BELE) left out")
    p.add_argument(
        "--compare-exclude",
        nargs="+",
        metavar="SAT",
        help="satellites left out of the product comparison statistics (e.g. G01)",
    )
    p.add_argument(
        "--c1-corrections",
        metavar="BIA",
        help="with --l1-code C1C: remove each satellite's C1C-C1W DSB of this Bias-SINEX product from C1C "
        "(satellites then refer to C1W, the P1 of IONEX/GFZ; a file without C1C uses its C1W; each "
        "receiver's DSB stays C1C-C2W, compared and written as such)",
    )


_HELP = {  # the model, levelling and screening options' help texts (the calls below stay one line each)
    "tec-field": "VTEC field of each ionosphere: paper 003's ν and two gradients, or second order too (low-latitude "
    "stations: docs/gnss.md)",
    "mapping": "single-layer mapping: 450-km thin shell (paper 003) or modified (506.7 km, α = 0.9782)",
    "between-station-level": "level of the χ² test whether the stations' single-receiver solutions agree within "
    "their realistic σ; when rejected every σ grows by √(χ²/dof) (default 0.05; 0: off; docs/gnss.md)",
    "ionosphere": "one regional ionosphere for all stations, one per station, or auto (by --regional-km)",
    "regional-km": f"auto: one common ionosphere if the longest baseline is below this (default {REGIONAL_KM:g})",
    "sigma": "zenith σ of the geometry-free code [m] (default 0.656, paper 003 §5.1)",
    "weighting": "elevation weighting (default sin: σ/sin θ)",
    "tec-rw": "random walk of the vertical L1 delay [m/√s] (gradients 5× per radian; default 0.01, 10× paper "
    "003's: docs/ionosphere.md)",
    "min-satellite-obs": "satellites with fewer station-epochs (filter grid) are not estimated and named in the "
    "notes (default 240 = 4 station-hours at 60 s, at most a quarter of the best-tracked satellite's, at least 30)",
    "innovation-test": "CKF: each receiver w-tests its own predicted residuals at this level and rejects outliers "
    "before the consensus (e.g. 0.001)",
    "levelling": "carrier-to-code levelling per continuous arc (default) or raw code",
    "min-arc": "shortest arc kept for levelling, in epochs of the file (default 10)",
    "gf-threshold": "smallest cycle-slip limit on the geometry-free phase [m] (default 0.05; raised to 4x the "
    "satellite's recent prediction-error RMS where the ionosphere is noisier)",
    "glonass-ifb": "GLONASS: σ of the receivers' FDMA channel biases per channel [ns], used as given (0: off); not "
    "given, estimated from two or more receivers' single-station DSBs or from one receiver's C/A minus P-pair "
    "channel means, else 2.0 for a C/A pair and none for C1P-C2P (docs/gnss.md)",
    "model-spread": "one station, or stations each with its own ionosphere layer: add to each satellite's σ the "
    "RMS difference of its DSBs under the other "
    "ionosphere field (linear/thin shell vs second order/modified mapping; docs/gnss.md); off: the filter's σ alone",
}


def _add_tec_field_arguments(p: argparse.ArgumentParser) -> None:
    """The model stage's VTEC field and single-layer mapping."""
    p.add_argument("--tec-field", choices=["linear", "quadratic"], default="linear", help=_HELP["tec-field"])
    p.add_argument("--mapping", choices=["slm", "mslm"], default="slm", help=_HELP["mapping"])


def _add_model_arguments(p: argparse.ArgumentParser) -> None:
    """The model stage: ionospheres, σ and weighting, random walk, satellites estimated, the CKF's innovation
    tests and the between-station test of the realistic σ."""
    p.add_argument(
        "--between-station-level", type=float, default=0.05, metavar="LEVEL", help=_HELP["between-station-level"]
    )
    p.add_argument("--ionosphere", choices=["auto", "common", "per-receiver"], default="auto", help=_HELP["ionosphere"])
    p.add_argument("--regional-km", type=float, default=REGIONAL_KM, help=_HELP["regional-km"])
    p.add_argument("--sigma", type=float, default=None, help=_HELP["sigma"])
    p.add_argument("--weighting", choices=["sin", "euler-goad", "constant"], default="sin", help=_HELP["weighting"])
    p.add_argument("--tec-rw", type=float, default=None, metavar="M_PER_SQRT_S", help=_HELP["tec-rw"])
    p.add_argument("--min-satellite-obs", type=int, default=None, metavar="N", help=_HELP["min-satellite-obs"])
    p.add_argument("--innovation-test", type=float, default=None, metavar="LEVEL", help=_HELP["innovation-test"])
    p.add_argument(
        "--glonass-ifb-sigma-ns", type=nonnegative_float, default=None, metavar="NS", help=_HELP["glonass-ifb"]
    )


def _add_levelling_arguments(p: argparse.ArgumentParser) -> None:
    """The levelling and screening stage, and the comparison with products of another day."""
    p.add_argument("--levelling", choices=["arc", "none"], default="arc", help=_HELP["levelling"])
    p.add_argument("--min-arc", type=int, default=10, metavar="EPOCHS", help=_HELP["min-arc"])
    p.add_argument("--gf-threshold", type=float, default=0.05, metavar="M", help=_HELP["gf-threshold"])
    p.add_argument("--no-screening", action="store_true", help="no w-test screening of each station's code")
    p.add_argument("--model-spread", choices=["auto", "off"], default="auto", help=_HELP["model-spread"])
    p.add_argument("--allow-other-day", action="store_true", help="compare with a product of another day than the data")


add_parser = add_ionosphere_parser
"""Alias used by :mod:`distnav.commands.gnss` (``_SUBCOMMAND_MODULES``)."""
