"""``distnav gnss ...``: real-data GNSS commands.

    distnav gnss codebias --obs FILE... (--nav FILE | --sp3 FILE...) [--graph EDGES.csv] [--out DIR]
    distnav gnss compare --estimates DIR/codebias.json --bias FILE [FILE...] [--out DIR]

``codebias`` reads RINEX 2.11/3.x observation files (Hatanaka/gzip too), forms the triple-frequency code-bias
observable of paper 000 eq. (24) per station (L1/L2/L5 codes chosen per :data:`~distnav.formats.gnss.rinex.
CODE_PREFERENCE`), estimates the satellite code biases in the S-basis of §5.1 (the first station's bias lumped into
the satellites) centrally and by ADMM over the given (or a default nearest-neighbour) graph, and writes
``codebias.csv`` and ``codebias.json``. ``compare`` turns the DSBs of published Bias-SINEX products into the same
combination ``b = −c₂·DSB(L1−L2) − DSB(L1−L5)`` and reports per-satellite differences and their RMS in ns with
two datum alignments: *zero-mean* (the mean difference over the common satellites removed: compares the satellite
biases only) and *S-basis* (the product's own station DSBs of the reference station added: absolute comparison).

The ionosphere command of issue 7 adds itself to the same ``gnss`` group through :func:`register` (see
``_SUBCOMMAND_MODULES``).
"""

from __future__ import annotations

import argparse
import importlib
import importlib.util
import json
import re
from pathlib import Path
from typing import Any

import numpy as np

from distnav.commands import add_backend_arguments
from distnav.commands.gnss_codebias import compare_with_products, print_comparison, run_codebias
from distnav.commands.gnss_common import (
    add_data_arguments,
    check_data_arguments,
    default_graph,
    documented_parser,
    load_edges,
)
from distnav.errors import DataFileError, ModelError, UsageError
from distnav.options import add_size_option, int_up_to, output_folder

__all__ = [
    "register",
    "load_edges",
    "default_graph",
    "compare_with_products",
    "add_data_arguments",
    "check_data_arguments",
]

# modules adding more ``distnav gnss <verb>`` sub-commands: each defines ``add_parser(gnss_subparsers)``
_SUBCOMMAND_MODULES = ("distnav.commands.gnss_ionosphere",)


#: The most ``codebias --iterations`` (refused at parse time above it).
ADMM_ITERATIONS = int_up_to(
    100_000, "100 × the default; every iteration is one exchange round of every station's normal equations"
)
_FILTER = re.compile(r"^(central|(ckf|local):[A-Za-z0-9]{4})$")
_SATELLITE = re.compile(r"^G(0[1-9]|[12][0-9]|3[0-2])$")


def _run_compare(args: argparse.Namespace) -> int:
    from distnav.output import atomic_write_json

    if not _FILTER.match(args.filter):
        raise ModelError(f"--filter {args.filter}: expected central, ckf:STATION or local:STATION (e.g. ckf:BELE)")
    for sat in args.exclude or []:
        if not _SATELLITE.match(sat.upper()):
            raise ModelError(f"--exclude {sat}: not a GPS satellite (G01 … G32)")
    path = Path(args.estimates)
    for b in args.bias:
        if path.is_file() and Path(b).is_file() and path.resolve() == Path(b).resolve():
            raise UsageError(f"--estimates {args.estimates} is also given as --bias: a product compared with itself")
    if path.is_dir() and (path / "multiday.json").exists():
        return _run_compare_days(args, path)
    if (
        (path.is_dir() and (path / "summary.json").exists())
        or path.name == "summary.json"
        or ".bia" in path.name.lower()
        or ".bsx" in path.name.lower()
    ):
        return _run_compare_dsb(args, path)
    if path.is_dir():
        path = path / "codebias.json"
    if not path.exists():
        raise DataFileError(f"{path}: file not found (run `distnav gnss codebias --out DIR` first)")
    try:
        est = json.loads(path.read_text())
        _ = est["x_ns"], est["codes"], est["reference_station"], est["coefficients"]
    except (ValueError, KeyError, TypeError) as exc:
        raise DataFileError(f"{path}: not a distnav codebias.json ({type(exc).__name__}: {exc})") from None
    est = _codebias_to_compare(args, path, est)
    summary = compare_with_products(est, [Path(b) for b in args.bias])
    print_comparison(summary)
    if args.out:
        atomic_write_json(Path(args.out) / "comparison.json", summary)
        print(f"written {Path(args.out) / 'comparison.json'}")
    return 0


def _codebias_to_compare(args: argparse.Namespace, path: Path, est: dict[str, Any]) -> dict[str, Any]:
    """A ``codebias.json`` for :func:`compare_with_products`: a product of another day than its epochs refused
    unless ``--allow-other-day``, the ``--exclude`` satellites left out (both were ignored for codebias estimates
    before: a wrong day's product gave "no satellite in common", excluded satellites stayed in the RMS)."""
    from distnav.formats.gnss.product_files import product_day

    if args.filter != "central":  # a codebias.json holds one solution: the option was ignored before
        raise UsageError(f"--filter {args.filter} applies to a `gnss ionosphere` output, not to {path}")
    first, last = est.get("first_epoch"), est.get("last_epoch") or est.get("first_epoch")
    if first and not args.allow_other_day:
        days = np.arange(np.datetime64(str(first)[:10]), np.datetime64(str(last)[:10]) + np.timedelta64(1, "D"))
        for b in args.bias:
            day = product_day(b)
            if day is not None and day not in days:
                raise ModelError(
                    f"{Path(b).name}: a product of {day}, the estimates ({path}) are of "
                    f"{', '.join(str(d) for d in days)} (--allow-other-day to compare anyway)"
                )
    exclude = {e.upper() for e in args.exclude or []}
    if not exclude:
        return est
    kept = {sv: x for sv, x in est["x_ns"].items() if sv.upper() not in exclude}
    if not kept:
        raise ModelError(f"--exclude leaves no satellite of {path} ({', '.join(est['x_ns'])}) to compare")
    return {**est, "x_ns": kept}


def _run_compare_days(args: argparse.Namespace, path: Path) -> int:
    """``gnss compare`` of a several-day ``gnss ionosphere`` output: each day's solution against the products of
    that day (a product whose name tells no day is used for every day)."""
    from distnav.formats.gnss.product_files import product_day
    from distnav.output import atomic_write_json

    days = sorted(p.name for p in path.iterdir() if p.is_dir() and (p / "summary.json").exists())
    if not days:
        raise DataFileError(f"{path}: multiday.json but no day folder with a summary.json")
    result: dict[str, Any] = {"estimates": str(path), "filter": args.filter, "days": {}}
    rms: dict[str, list[float]] = {}
    for day in days:
        bias = [b for b in args.bias if product_day(b) in (None, np.datetime64(day))]
        print(f"\n=== {day} ===")
        if not bias:
            print(f"  no product of {day} among --bias")
            continue
        r = _compare_dsb(args, path / day, bias)
        result["days"][day] = r
        for name, c in r["products"].items():
            if c.get("n"):
                rms.setdefault(name.split()[0], []).append(c["rms_zero_mean_ns"])
    result["median_rms_zero_mean_ns"] = {k: float(np.median(v)) for k, v in rms.items()}
    for k, v in rms.items():
        print(
            f"{k}: RMS (zero-mean) median over {len(v)} days {np.median(v):.3f} ns (range {min(v):.3f} – {max(v):.3f})"
        )
    if args.out:
        atomic_write_json(Path(args.out) / "comparison.json", result)
        print(f"written {Path(args.out) / 'comparison.json'}")
    return 0


def _run_compare_dsb(args: argparse.Namespace, path: Path) -> int:
    """``gnss compare`` of receiver/satellite DSBs (ionosphere output or a Bias-SINEX file) with products."""
    from distnav.output import atomic_write_json

    result = _compare_dsb(args, path, args.bias)
    if args.out:
        atomic_write_json(Path(args.out) / "comparison.json", result)
        print(f"written {Path(args.out) / 'comparison.json'}")
    return 0


def _compare_dsb(args: argparse.Namespace, path: Path, bias: list[str]) -> dict[str, Any]:
    """Each satellite system of the estimates against the products (GPS first): the first system's comparison,
    with every system's under ``systems`` when there are several."""
    from distnav.formats.gnss.product_files import estimate_systems

    systems = estimate_systems(path, filter_label=args.filter)
    results = {s: _compare_system(args, path, bias, s, len(systems) > 1) for s in systems}
    first = dict(results[systems[0]])
    if len(systems) > 1:
        first["systems"] = results
    return first


def _compare_system(args: argparse.Namespace, path: Path, bias: list[str], system: str, named: bool) -> dict[str, Any]:
    from distnav.commands.gnss_report import print_worst_vs_product
    from distnav.formats.gnss.product_files import product_dsbs, read_estimates
    from distnav.models.gnss.products import compare_in_datum
    from distnav.models.gnss.systems import SYSTEM_NAMES

    est = read_estimates(path, filter_label=args.filter, system=system)
    products = product_dsbs(bias, sorted(est.satellite), sorted(est.station), est.obs1, est.obs2)
    if named:
        print(f"\n--- {SYSTEM_NAMES.get(system, system)} ({len(est.satellite)} satellites) ---")
    result: dict[str, Any] = {
        "estimates": est.source,
        "codes": [est.obs1, est.obs2],
        "filter": args.filter,
        "products": {},
    }
    for prod in products:
        if prod.day is not None and est.days and prod.day not in est.days and not args.allow_other_day:
            raise ModelError(
                f"{prod.path.name}: a product of {prod.day}, the estimates are of "
                f"{', '.join(str(d) for d in est.days)} (--allow-other-day to compare anyway)"
            )
        r = compare_in_datum(est.satellite, est.station, prod, exclude=[e.upper() for e in args.exclude or []])
        r["notes"] = prod.notes
        result["products"][prod.name] = r
        print(
            f"\n{est.obs1}-{est.obs2} DSBs vs {prod.name} (estimate − product after aligning the datum over "
            f"{r.get('n', 0)} common satellites, ns)"
        )
        if not r.get("n"):
            print(f"  {r.get('note')}")
            continue
        for sv, d in sorted(r["difference_ns"].items()):
            print(f"  {sv}  {d:+8.3f}")
        print(
            f"  datum offset {r['datum_offset_ns']:+.3f}   RMS {r['rms_zero_mean_ns']:.3f}   max "
            f"{r['max_abs_zero_mean_ns']:.3f} ({r['worst']})"
        )
        for sta, d in r.get("receivers", {}).get("difference_ns", {}).items():
            print(f"  receiver {sta}  {d:+8.3f}")
        if r.get("receivers_not_in_product"):
            print(f"  no receiver DSB in the product for {' '.join(r['receivers_not_in_product'])}")
        print_worst_vs_product(prod.name, r, exclude_option="--exclude")
    return result


def register(subparsers: Any) -> None:
    """Add ``distnav gnss codebias`` and ``distnav gnss compare`` (and any modules of ``_SUBCOMMAND_MODULES``)."""
    gnss = subparsers.add_parser("gnss", help="real-data GNSS commands (code biases, ionosphere)")
    sub = gnss.add_subparsers(dest="gnss_command", required=True)

    cb = documented_parser(
        sub, "codebias", "satellite code biases from L1/L2/L5 RINEX code data (paper 000 §5)", __doc__
    )
    add_data_arguments(cb, obs_note="; the first is the S-basis reference unless --reference")
    cb.add_argument(
        "--out", type=output_folder, default="distnav-codebias", help="output folder (default distnav-codebias)"
    )
    add_backend_arguments(cb)
    cb.add_argument("--reference", metavar="STATION", help="station lumped into the satellite biases")
    cb.add_argument("--codes", metavar="L1=C1C,L2=C2W,L5=C5X", help="force the code used on a band")
    cb.add_argument("--sigma", type=float, default=0.20, help="zenith code σ [m] (default 0.20)")
    cb.add_argument("--weighting", choices=["euler-goad", "sin", "constant"], default="euler-goad")
    cb.add_argument("--rho", type=float, default=0.5, help="ADMM weight ρ, per-epoch scale (default 0.5)")
    add_size_option(cb, "--iterations", ADMM_ITERATIONS, default=1000, help="ADMM iterations (default 1000)")
    cb.add_argument(
        "--admm-messages",
        choices=["ternary", "pairs"],
        default=None,
        help="ternary (default without faults): per-pair messages as 2-bit deltas with error feedback, the same "
        "fixed point for ~13x fewer bytes (docs/economy.md); pairs: float64 as paper 000 Fig. 6 (default under faults)",
    )
    cb.add_argument("--bias", nargs="+", metavar="FILE", help="also compare with these Bias-SINEX products")
    cb.add_argument("--no-progress", action="store_true")
    cb.set_defaults(func=run_codebias)

    cmp_ = sub.add_parser("compare", help="compare estimated code biases with Bias-SINEX products")
    cmp_.add_argument(
        "--estimates",
        required=True,
        help="codebias.json (or its folder) of `distnav gnss codebias`, the output folder or "
        "summary.json of `distnav gnss ionosphere`, or a Bias-SINEX file (e.g. its distnav_dsb.bia)",
    )
    cmp_.add_argument(
        "--bias",
        nargs="+",
        required=True,
        metavar="FILE",
        help="Bias-SINEX files (.BIA/.BSX, gzip ok) or IONEX files with a DCB block; DSBs missing "
        "from the first are taken from the next (e.g. GFZ C1W-C2W completed with CAS C1C-C1W)",
    )
    cmp_.add_argument("--out", type=output_folder, help="write comparison.json here")
    cmp_.add_argument(
        "--filter",
        default="central",
        help="which filter of a `gnss ionosphere` output to compare (central, ckf:STA, local:STA)",
    )
    cmp_.add_argument("--exclude", nargs="+", metavar="SAT", help="satellites left out of the statistics (e.g. G01)")
    cmp_.add_argument("--allow-other-day", action="store_true", help="compare with a product of another day")
    cmp_.set_defaults(func=_run_compare)

    # ---- room for more gnss sub-commands (issue 7: ``distnav gnss ionosphere``) ----
    for modname in _SUBCOMMAND_MODULES:
        if importlib.util.find_spec(modname) is not None:
            importlib.import_module(modname).add_parser(sub)
