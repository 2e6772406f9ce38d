"""``distnav gnss codebias``: satellite code biases from L1/L2/L5 RINEX code data (paper 000 §5).

The command wires its options to one stage each: read the stations' code observations
(:func:`read_observations`), read the orbits and check they are of the observations' day (:func:`read_orbit`),
form the code-bias observable of paper 000 eq. (24) (:func:`codebias_data`), solve centrally and by ADMM over the
station graph (:func:`solve`), then write ``codebias.csv`` / ``codebias.json`` (:func:`write_outputs`) and
compare with Bias-SINEX products (:func:`compare_with_products`) when ``--bias`` is given.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from distnav.commands import command_exchange
from distnav.commands.gnss_common import (
    CODE_SIGMA_WHY,
    MAX_CODE_SIGMA_M,
    check_data_arguments,
    default_graph,
    load_edges,
    say,
)
from distnav.errors import ModelError

__all__ = ["run_codebias", "compare_with_products", "parse_codes"]


def parse_codes(text: str | None) -> dict[int, str]:
    """``--codes L1=C1C,L2=C2W,L5=C5X``: the code forced on each named band."""
    if not text:
        return {}
    out: dict[int, str] = {}
    for item in text.split(","):
        key, _, code = item.partition("=")
        key = key.strip().upper()
        if key not in ("L1", "L2", "L5") or len(code.strip()) != 3:
            raise ModelError(f"--codes expects e.g. L1=C1C,L2=C2W,L5=C5X; got {item!r}")
        band, code = int(key[1]), code.strip().upper()
        if band in out:
            raise ModelError(f"--codes names {key} twice ({key}={out[band]}, {item.strip()}): give one code per band")
        if code[:2] != f"C{band}":  # a code of another frequency would be used with this band's coefficient
            raise ModelError(f"--codes {item.strip()}: {code} is not an {key} code (e.g. C{band}C)")
        out[band] = code
    return out


def check_codebias_arguments(args: argparse.Namespace) -> None:
    """The option values of ``gnss codebias``, before any file is read (errors name the option)."""
    check_data_arguments(args)
    for opt, value in (("--sigma", args.sigma), ("--rho", args.rho)):
        if not (np.isfinite(value) and value > 0.0):
            raise ModelError(f"{opt} {value:g}: must be a positive number")
    if args.iterations < 1:
        raise ModelError(f"--iterations must be ≥ 1, got {args.iterations}")
    if args.sigma > MAX_CODE_SIGMA_M:
        raise ModelError(f"--sigma {args.sigma:g}: at most {MAX_CODE_SIGMA_M:g} ({CODE_SIGMA_WHY})")
    if args.reference is not None and not args.reference.strip():
        raise ModelError("--reference is empty: give a station name (e.g. BELE)")
    parse_codes(args.codes)


def run_codebias(args: argparse.Namespace) -> int:
    """Handler of ``distnav gnss codebias``: the stages, wired to the options."""
    check_codebias_arguments(args)
    obs = read_observations(args)
    orbit = read_orbit(args, obs)
    data = codebias_data(args, obs, orbit)
    solution = solve(args, data)
    report = write_outputs(args, data, obs, solution)
    if args.bias:
        from distnav.output import atomic_write_json

        summary = compare_with_products(report, [Path(b) for b in args.bias])
        print_comparison(summary)
        atomic_write_json(Path(args.out) / "comparison.json", summary)
    return 0


def read_observations(args: argparse.Namespace) -> list[Any]:
    """Every ``--obs`` file's L1/L2/L5 code observations, the ``--reference`` station first (the S-basis)."""
    from distnav.formats.gnss.rinex import read_code_observations

    codes = parse_codes(args.codes)
    tlim = tuple(args.tlim) if args.tlim else None
    obs = []
    for f in args.obs:
        o = read_code_observations(Path(f), bands=(1, 2, 5), codes=codes, tlim=tlim, interval_s=args.interval)
        say(
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
    return obs


def read_orbit(args: argparse.Namespace, obs: list[Any]) -> Any:
    """The ``--nav`` (one file) or ``--sp3`` orbits, refused when they are of another day than the observations
    (:func:`~distnav.formats.gnss.product_files.check_orbit_day`)."""
    from distnav.formats.gnss.product_files import check_orbit_day
    from distnav.formats.gnss.rinex import read_navigation, read_sp3

    if args.nav and len(args.nav) > 1:
        raise ModelError("gnss codebias takes one --nav file")
    orbit = (
        read_navigation(Path(args.nav[0]), max_age_s=args.nav_max_age * 3600.0)
        if args.nav
        else read_sp3([Path(p) for p in args.sp3])
    )
    check_orbit_day(orbit, obs)
    return orbit


def codebias_data(args: argparse.Namespace, obs: list[Any], orbit: Any) -> Any:
    """The code-bias observable of every station (paper 000 eq. (24)), checked to determine the biases."""
    from distnav.models.gnss.codebias_build import codebias_data_from_observations

    data = codebias_data_from_observations(
        obs, orbit, sigma0_m=args.sigma, weighting=args.weighting, mask_rad=np.deg2rad(args.mask)
    )
    if data.meta.get("no_orbit"):
        say(args, f"no valid orbit (unhealthy or missing ephemeris) for {', '.join(data.meta['no_orbit'])}: not used")
    data.check()
    return data


@dataclass(frozen=True)
class CodeBiasRun:
    """What :func:`solve` computed: the centralized solution, the station graph, ADMM's estimates per station
    (the centralized ones with a single station) and what ADMM reports."""

    solution: Any
    graph: Any
    admm_x_m: np.ndarray
    admm_info: dict[str, Any]


def solve(args: argparse.Namespace, data: Any) -> CodeBiasRun:
    """The centralized solution and ADMM over the ``--graph`` (or default) station graph, with its distance to the
    centralized BLUE and its messages beside a fusion centre's."""
    from distnav.algorithms.lsq.blue import blue

    stations = list(data.stations)
    sol = data.centralized(check=False)
    assert data.positions_ecef_m is not None
    graph = load_edges(Path(args.graph), stations) if args.graph else default_graph(data.positions_ecef_m, stations)
    admm_x = np.broadcast_to(sol.x_m, (len(stations), len(data.svs)))
    admm_info: dict[str, Any] = {"skipped": "a single station has no network to iterate over"}
    if len(stations) > 1:
        problem = data.linear_problem(per_epoch=True)
        admm_x, admm_info = _admm(args, problem, graph, stations, blue(problem).x)
    return CodeBiasRun(solution=sol, graph=graph, admm_x_m=admm_x, admm_info=admm_info)


def _admm(
    args: argparse.Namespace, problem: Any, graph: Any, stations: list[str], x_blue: np.ndarray
) -> tuple[np.ndarray, dict[str, Any]]:
    from distnav.algorithms.lsq.admm import admm
    from distnav.algorithms.lsq.gather_data import GATHER_DATA, node_data_bytes
    from distnav.algorithms.result import compare_with_gather
    from distnav.models.gnss.constants import NS_TO_M

    ex = command_exchange(args, graph)
    res = admm(
        problem,
        graph,
        W=args.rho,
        max_iterations=args.iterations,
        tol=0.0,
        reference=x_blue,
        record_nodes=False,
        exchange=ex,
        messages=args.admm_messages or ("pairs" if ex.faults.active else "ternary"),
    )
    dist_m = float(res.trace["max_distance_to_reference"][-1])
    return res.estimates, {
        "rho": args.rho,
        "rho_scale": "epoch",
        "messages": res.messages,
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


def write_outputs(args: argparse.Namespace, data: Any, obs: list[Any], run: CodeBiasRun) -> dict[str, Any]:
    """``codebias.csv`` and ``codebias.json`` in ``--out``, and the summary lines; returns the JSON's content."""
    from distnav.models.gnss.constants import NS_TO_M
    from distnav.output import atomic_write_json, atomic_write_text

    sol, stations, admm_info = run.solution, list(data.stations), run.admm_info
    counts = data.observation_counts()
    out = Path(args.out)
    rows = ["satellite,x_m,x_ns,sigma_ns,admm_max_dev_ns,n_obs"]
    admm_dev = np.abs(run.admm_x_m - sol.x_m[None]).max(axis=0) / NS_TO_M
    for k, sv in enumerate(data.svs):
        rows.append(f"{sv},{sol.x_m[k]:.4f},{sol.x_ns[k]:.4f},{sol.sigma_ns[k]:.4f},{admm_dev[k]:.3g},{int(counts[k])}")
    report = _report(args, data, obs, run)
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
    say(args, msg)
    if "communication" in admm_info:
        print("ADMM " + admm_info["communication"]["line"])
    print(f"written {out / 'codebias.csv'} and {out / 'codebias.json'}")
    return report


def _report(args: argparse.Namespace, data: Any, obs: list[Any], run: CodeBiasRun) -> dict[str, Any]:
    """The content of ``codebias.json``."""
    from distnav.models.gnss.observables import codebias_coefficients, mu_coefficients

    sol, stations = run.solution, list(data.stations)
    counts = data.observation_counts()
    return {
        "stations": stations,
        "reference_station": stations[data.reference],
        "codes": data.meta["codes"],
        "notes": data.meta["notes"],
        "no_orbit": data.meta.get("no_orbit", []),
        "epochs": data.n_epochs,
        "first_epoch": str(np.asarray(obs[0].time)[0]) if obs[0].n_epochs else None,
        "last_epoch": str(max(np.asarray(o.time)[-1] for o in obs if o.n_epochs)) if obs[0].n_epochs else None,
        "mask_deg": args.mask,
        "sigma0_m": args.sigma,
        "weighting": args.weighting,
        "mu": mu_coefficients((1, 2, 5)).tolist(),
        "coefficients": codebias_coefficients().tolist(),
        "definition": "x_s = b^s + b_ref with b = c1*d1 + c2*d2 + d3 = -c2*DSB(L1-L2) - DSB(L1-L5) "
        "(paper 000 eq. (24), S-basis of Sect. 5.1; additive code biases as in Bias-SINEX)",
        "satellites": list(data.svs),
        "x_ns": dict(zip(data.svs, sol.x_ns.tolist(), strict=True)),
        "sigma_ns": dict(zip(data.svs, sol.sigma_ns.tolist(), strict=True)),
        "n_obs": dict(zip(data.svs, counts.tolist(), strict=True)),
        "graph": {"links": [[stations[i], stations[j]] for i, j in run.graph.links.tolist()]},
        "admm": run.admm_info,
    }


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


def print_comparison(summary: dict[str, Any]) -> None:
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
