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
import csv
import importlib
import importlib.util
import json
import re
import sys
from pathlib import Path
from typing import Any

import numpy as np

from distnav.commands import add_backend_arguments, command_exchange
from distnav.errors import DataFileError, ModelError

__all__ = ["register", "load_edges", "default_graph", "compare_with_products"]

# modules adding more ``distnav gnss <verb>`` sub-commands: each defines ``add_parser(gnss_subparsers)``
_SUBCOMMAND_MODULES = ("distnav.commands.gnss_ionosphere",)


# ----------------------------------------------------------------------------------------------- helpers
def load_edges(path: Path, stations: list[str]) -> Any:
    """A graph from a CSV of station-name pairs (one link per line, ``#`` comments and a header allowed)."""
    from distnav.network.graph import Graph

    index = {s.upper(): k for k, s in enumerate(stations)}
    links: list[tuple[int, int]] = []
    if not path.exists():
        raise DataFileError(f"{path}: file not found")
    with path.open(newline="", encoding="utf-8") as fh:
        for no, row in enumerate(csv.reader(fh), start=1):
            cells = [c.strip() for c in row if c.strip()]
            if not cells or cells[0].startswith("#"):
                continue
            if len(cells) != 2:
                raise DataFileError(f"{path}, line {no}: expected two station names, got {row}")
            a, b = (c.upper()[:4] if c.upper() not in index else c.upper() for c in cells)
            if a not in index or b not in index:
                if no == 1:
                    continue  # header line
                unknown = [c for c in (a, b) if c not in index]
                raise DataFileError(
                    f"{path}, line {no}: unknown station {', '.join(unknown)} (stations: {', '.join(stations)})"
                )
            if a == b:
                raise DataFileError(f"{path}, line {no}: a link from {a} to itself")
            links.append((index[a], index[b]))
    if not links and len(stations) > 1:
        raise DataFileError(f"{path}: no links")
    graph = Graph.from_links(len(stations), links, names=stations, allow_duplicates=True)
    graph.require_connected(f"the graph of {path.name}")
    return graph


def default_graph(positions_ecef_m: np.ndarray, stations: list[str], k: int = 2) -> Any:
    """Minimum spanning tree of the stations (straight-line distance) plus links to each one's ``k`` nearest."""
    from scipy.sparse.csgraph import minimum_spanning_tree

    from distnav.network.graph import Graph

    n = len(stations)
    d = np.linalg.norm(positions_ecef_m[:, None] - positions_ecef_m[None], axis=-1)
    links: set[tuple[int, int]] = set()
    if n > 1:
        mst = minimum_spanning_tree(d + 1e-9 * (1 - np.eye(n))).tocoo()
        links |= {(min(i, j), max(i, j)) for i, j in zip(mst.row.tolist(), mst.col.tolist(), strict=True)}
        for i in range(n):
            for j in np.argsort(d[i])[1 : k + 1].tolist():
                links.add((min(i, j), max(i, j)))
    return Graph.from_links(n, sorted(links), names=stations)


def _parse_codes(text: str | None) -> dict[int, str]:
    if not text:
        return {}
    out: dict[int, str] = {}
    for item in text.split(","):
        key, _, code = item.partition("=")
        key = key.strip().upper()
        if key not in ("L1", "L2", "L5") or len(code.strip()) != 3:
            raise ModelError(f"--codes expects e.g. L1=C1C,L2=C2W,L5=C5X; got {item!r}")
        out[int(key[1])] = code.strip().upper()
    return out


# ----------------------------------------------------------------------------------------------- codebias
def _run_codebias(args: argparse.Namespace) -> int:
    from distnav.algorithms.lsq.admm import admm
    from distnav.algorithms.lsq.blue import blue
    from distnav.algorithms.lsq.gather_data import GATHER_DATA, node_data_bytes
    from distnav.algorithms.result import compare_with_gather
    from distnav.formats.gnss.rinex import read_code_observations, read_navigation, read_sp3
    from distnav.models.gnss.codebias import codebias_data_from_observations
    from distnav.models.gnss.constants import NS_TO_M
    from distnav.models.gnss.observables import codebias_coefficients, mu_coefficients
    from distnav.output import atomic_write_json, atomic_write_text

    _check_codebias_arguments(args)
    codes = _parse_codes(args.codes)
    tlim = tuple(args.tlim) if args.tlim else None
    obs = []
    for f in args.obs:
        o = read_code_observations(Path(f), bands=(1, 2, 5), codes=codes, tlim=tlim, interval_s=args.interval)
        _say(
            args,
            f"read {o.station}: {o.n_epochs} epochs, codes "
            f"{' '.join(o.codes[b] for b in (1, 2, 5))}, {len(o.satellites_with_all_bands())} satellites "
            f"with L1/L2/L5" + (f" ({'; '.join(o.notes)})" if o.notes else ""),
        )
        obs.append(o)
    if args.reference:
        names = [o.station for o in obs]
        ref = args.reference.upper()
        if ref not in names:
            raise ModelError(f"--reference {args.reference}: not one of the stations {', '.join(names)}")
        obs.insert(0, obs.pop(names.index(ref)))
    if args.nav and len(args.nav) > 1:
        raise ModelError("gnss codebias takes one --nav file")
    orbit = (
        read_navigation(Path(args.nav[0]), max_age_s=args.nav_max_age * 3600.0)
        if args.nav
        else read_sp3([Path(p) for p in args.sp3])
    )
    data = codebias_data_from_observations(
        obs, orbit, sigma0_m=args.sigma, weighting=args.weighting, mask_rad=np.deg2rad(args.mask)
    )
    if data.meta.get("no_orbit"):
        _say(args, f"no valid orbit (unhealthy or missing ephemeris) for {', '.join(data.meta['no_orbit'])}: not used")
    data.check()
    stations = list(data.stations)
    sol = data.centralized(check=False)
    assert data.positions_ecef_m is not None
    graph = load_edges(Path(args.graph), stations) if args.graph else default_graph(data.positions_ecef_m, stations)
    problem = data.linear_problem(per_epoch=True)
    x_blue = blue(problem).x
    admm_x = np.broadcast_to(sol.x_m, (len(stations), len(data.svs)))
    admm_info: dict[str, Any] = {"skipped": "a single station has no network to iterate over"}
    if len(stations) > 1:
        res = admm(
            problem,
            graph,
            W=args.rho,
            max_iterations=args.iterations,
            tol=0.0,
            reference=x_blue,
            record_nodes=False,
            exchange=command_exchange(args, graph),
        )
        dist_m = float(res.trace["max_distance_to_reference"][-1])
        admm_x = res.estimates
        admm_info = {
            "rho": args.rho,
            "rho_scale": "epoch",
            "iterations": res.iterations,
            "max_distance_to_centralized_ns": dist_m / NS_TO_M,
            "constraint_nodes": [stations[i] for i in res.constraint_nodes.nodes],
            "communication": compare_with_gather(
                res.comm,
                graph,
                node_data_bytes(problem),
                data=f"each station's data ({GATHER_DATA})",
                node_label="station",
                node_names=stations,
            ).as_dict(),
        }
    counts = data.observation_counts()
    c = codebias_coefficients()
    out = Path(args.out)
    rows = ["satellite,x_m,x_ns,sigma_ns,admm_max_dev_ns,n_obs"]
    admm_dev = np.abs(admm_x - sol.x_m[None]).max(axis=0) / NS_TO_M
    for k, sv in enumerate(data.svs):
        rows.append(f"{sv},{sol.x_m[k]:.4f},{sol.x_ns[k]:.4f},{sol.sigma_ns[k]:.4f},{admm_dev[k]:.3g},{int(counts[k])}")
    report: dict[str, Any] = {
        "stations": stations,
        "reference_station": stations[data.reference],
        "codes": data.meta["codes"],
        "notes": data.meta["notes"],
        "no_orbit": data.meta.get("no_orbit", []),
        "epochs": data.n_epochs,
        "first_epoch": str(np.asarray(obs[0].time)[0]) if obs[0].n_epochs else None,
        "mask_deg": args.mask,
        "sigma0_m": args.sigma,
        "weighting": args.weighting,
        "mu": mu_coefficients((1, 2, 5)).tolist(),
        "coefficients": c.tolist(),
        "definition": "x_s = b^s + b_ref with b = c1*d1 + c2*d2 + d3 = -c2*DSB(L1-L2) - DSB(L1-L5) "
        "(paper 000 eq. (24), S-basis of Sect. 5.1; additive code biases as in Bias-SINEX)",
        "satellites": list(data.svs),
        "x_ns": dict(zip(data.svs, sol.x_ns.tolist(), strict=True)),
        "sigma_ns": dict(zip(data.svs, sol.sigma_ns.tolist(), strict=True)),
        "n_obs": dict(zip(data.svs, counts.tolist(), strict=True)),
        "graph": {"links": [[stations[i], stations[j]] for i, j in graph.links.tolist()]},
        "admm": admm_info,
    }
    atomic_write_text(out / "codebias.csv", "\n".join(rows) + "\n")
    atomic_write_json(out / "codebias.json", report)
    msg = (
        f"{len(data.svs)} satellite code biases (reference {stations[data.reference]}), σ "
        f"{np.median(sol.sigma_ns):.3f} ns median"
    )
    if "iterations" in admm_info:
        msg += (
            f"; ADMM ({admm_info['iterations']} it., ρ = {args.rho}) within "
            f"{admm_info['max_distance_to_centralized_ns']:.2g} ns of the centralized solution"
        )
    _say(args, msg)
    if "communication" in admm_info:
        print("ADMM " + admm_info["communication"]["line"])
    print(f"written {out / 'codebias.csv'} and {out / 'codebias.json'}")
    if args.bias:
        summary = compare_with_products(report, [Path(b) for b in args.bias])
        _print_comparison(summary)
        atomic_write_json(out / "comparison.json", summary)
    return 0


# ----------------------------------------------------------------------------------------------- compare
def compare_with_products(estimates: dict[str, Any], bias_files: list[Path]) -> dict[str, Any]:
    """Compare estimated satellite code biases (``codebias.json`` content) with Bias-SINEX products.

    The product value of satellite s is ``b^s = −c₂·DSB(L1−L2) − DSB(L1−L5)`` with the reference station's codes,
    DSBs chained across the products by :func:`~distnav.formats.gnss.bias_sinex.resolve_dsb` (first product
    preferred). Datum alignment: ``zero_mean`` removes the mean of the differences over the common satellites;
    ``s_basis`` adds the product's DSB combination of the reference station (``x_s = b^s + b_ref``), when the
    product has it. Differences are estimate − product, in ns.
    """
    from distnav.formats.gnss.bias_sinex import read_bias_sinex, resolve_dsb

    products = [read_bias_sinex(p) for p in bias_files]
    c = np.asarray(estimates["coefficients"], dtype=float)
    ref = estimates["reference_station"]
    codes = estimates["codes"][ref]
    l1, l2, l5 = codes["L1"], codes["L2"], codes["L5"]
    x_ns = estimates["x_ns"]
    per_sat: dict[str, dict[str, Any]] = {}
    missing: dict[str, str] = {}
    for sv, x in x_ns.items():
        try:
            d12, ch12 = resolve_dsb(products, l1, l2, prn=sv)
            d15, ch15 = resolve_dsb(products, l1, l5, prn=sv)
        except ModelError as exc:
            missing[sv] = str(exc)
            continue
        per_sat[sv] = {"estimate_ns": x, "product_ns": float(-c[1] * d12 - d15), "chain": ch12 + ch15}
    if not per_sat:
        raise ModelError(
            f"no satellite in common between the estimates ({', '.join(x_ns)}) and "
            f"{', '.join(p.name for p in products)} for {l1}/{l2}/{l5}: " + "; ".join(list(missing.values())[:3])
        )
    svs = sorted(per_sat)
    diff = np.array([per_sat[s]["estimate_ns"] - per_sat[s]["product_ns"] for s in svs])
    zm = diff - diff.mean()
    out: dict[str, Any] = {
        "products": [str(p) for p in bias_files],
        "reference_station": ref,
        "codes": codes,
        "n_common": len(svs),
        "missing": missing,
        "zero_mean": {
            "offset_ns": float(diff.mean()),
            "differences_ns": dict(zip(svs, zm.tolist(), strict=True)),
            "rms_ns": float(np.sqrt(np.mean(zm**2))),
            "max_abs_ns": float(np.abs(zm).max()),
        },
        "satellites": per_sat,
    }
    other_codes = {s: v for s, v in estimates["codes"].items() if v != codes}
    if other_codes:
        out["warning"] = (
            f"stations track other codes than the reference ({other_codes}); the estimates mix their satellite biases"
        )
    try:
        r12, _ = resolve_dsb(products, l1, l2, station=ref)
        r15, _ = resolve_dsb(products, l1, l5, station=ref)
        b_ref = float(-c[1] * r12 - r15)
        sb = diff - b_ref
        out["s_basis"] = {
            "reference_bias_ns": b_ref,
            "differences_ns": dict(zip(svs, sb.tolist(), strict=True)),
            "rms_ns": float(np.sqrt(np.mean(sb**2))),
            "mean_ns": float(sb.mean()),
            "max_abs_ns": float(np.abs(sb).max()),
        }
    except ModelError as exc:
        out["s_basis"] = {"unavailable": str(exc)}
    return out


def _print_comparison(summary: dict[str, Any]) -> None:
    names = ", ".join(Path(p).name[:3] for p in summary["products"])
    codes = summary["codes"]
    print(
        f"\ncomparison with {names} ({codes['L1']}/{codes['L2']}/{codes['L5']}, reference "
        f"{summary['reference_station']}, {summary['n_common']} common satellites; estimate − product, ns)"
    )
    zm = summary["zero_mean"]["differences_ns"]
    sb = summary["s_basis"].get("differences_ns", {})
    print("  sat    zero-mean   S-basis")
    for s in sorted(zm):
        print(f"  {s}  {zm[s]:9.3f}  {sb[s]:9.3f}" if s in sb else f"  {s}  {zm[s]:9.3f}        -")
    print(
        f"  RMS    {summary['zero_mean']['rms_ns']:7.3f}  "
        + (f"{summary['s_basis']['rms_ns']:9.3f}" if sb else "        -")
    )
    if "warning" in summary:
        print(f"  note: {summary['warning']}")


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
    summary = compare_with_products(est, [Path(b) for b in args.bias])
    _print_comparison(summary)
    if args.out:
        atomic_write_json(Path(args.out) / "comparison.json", summary)
        print(f"written {Path(args.out) / 'comparison.json'}")
    return 0


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


def _say(args: argparse.Namespace, text: str) -> None:
    if not getattr(args, "no_progress", False):
        print(text, file=sys.stderr, flush=True)


# ----------------------------------------------------------------------------------------------- CLI
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
    parser.add_argument("--tlim", nargs=2, metavar=("START", "STOP"), help="time window, e.g. 2024-01-10T00:00 ...")
    parser.add_argument("--interval", type=float, default=None, help="keep epochs on this grid [s] (e.g. 60)")
    parser.add_argument("--mask", type=float, default=10.0, help="elevation mask [deg] (default 10)")


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


def _check_codebias_arguments(args: argparse.Namespace) -> None:
    check_data_arguments(args)
    for opt, value in (("--sigma", args.sigma), ("--rho", args.rho)):
        if not (np.isfinite(value) and value > 0.0):
            raise ModelError(f"{opt} {value:g}: must be a positive number")
    if args.iterations < 1:
        raise ModelError(f"--iterations must be ≥ 1, got {args.iterations}")
    if args.reference is not None and not args.reference.strip():
        raise ModelError("--reference is empty: give a station name (e.g. BELE)")
    _parse_codes(args.codes)


def register(subparsers: Any) -> None:
    """Add ``distnav gnss codebias`` and ``distnav gnss compare`` (and any modules of ``_SUBCOMMAND_MODULES``)."""
    gnss = subparsers.add_parser("gnss", help="real-data GNSS commands (code biases, ionosphere)")
    sub = gnss.add_subparsers(dest="gnss_command", required=True)

    cb = sub.add_parser(
        "codebias",
        help="satellite code biases from L1/L2/L5 RINEX code data (paper 000 §5)",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_data_arguments(cb, obs_note="; the first is the S-basis reference unless --reference")
    cb.add_argument("--out", default="distnav-codebias", help="output folder (default distnav-codebias)")
    add_backend_arguments(cb)
    cb.add_argument("--reference", metavar="STATION", help="station lumped into the satellite biases")
    cb.add_argument("--codes", metavar="L1=C1C,L2=C2W,L5=C5X", help="force the code used on a band")
    cb.add_argument("--sigma", type=float, default=0.20, help="zenith code σ [m] (default 0.20)")
    cb.add_argument("--weighting", choices=["euler-goad", "sin", "constant"], default="euler-goad")
    cb.add_argument("--rho", type=float, default=0.5, help="ADMM weight ρ, per-epoch scale (default 0.5)")
    cb.add_argument("--iterations", type=int, default=1000, help="ADMM iterations (default 1000)")
    cb.add_argument("--bias", nargs="+", metavar="FILE", help="also compare with these Bias-SINEX products")
    cb.add_argument("--no-progress", action="store_true")
    cb.set_defaults(func=_run_codebias)

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
    cmp_.add_argument("--out", help="write comparison.json here")
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
