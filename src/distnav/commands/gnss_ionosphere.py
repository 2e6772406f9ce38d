"""``distnav gnss ionosphere``: TEC and between-satellite DCBs of a receiver network from real RINEX code data, by
the central filter, the single-receiver (local) filters and the consensus Kalman filter (paper 003 §5).

    distnav gnss ionosphere --obs FILE... (--nav FILE | --sp3 FILE...) [--graph EDGES.csv] [--kn K]
                            [--bias FILE...] [--out DIR]

Per station the geometry-free code ``(P2 − P1)/(μ2 − μ1)`` is formed from the chosen L1/L2 codes (default C1C and
C2W; RINEX 2 ``C1`` = C1C, ``P1`` = C1W, ``P2`` = C2W — use ``--l1-code C1W`` for P1/P2, the pair of IONEX DCBs);
the model is :mod:`distnav.models.gnss.ionosphere` (paper 003 eq. (49): vertical delay ν_o and gradients ν_φ, ν_ψ
of a regional single layer — one per receiver when the network spans more than ``--regional-km`` — plus
between-satellite DCBs relative to a pivot satellite, PRN 10 by default). Outputs in ``DIR``:

* ``tec_dcb_per_epoch.csv`` — per epoch, filter (``central``, ``local:STA``, ``ckf:STA``) and parameter: value
  and standard deviation (TEC in metres of L1 delay and in TECU, DCBs in ns of ``DSB^s − DSB^p``). The CKF
  standard deviations come from the error-variance recursion of paper 003 Fig. 7.
* ``dcb_final.csv`` — the last-epoch DCBs of every filter and, with ``--bias``, of each product aligned to the
  same pivot (``DSB^s − DSB^p`` of the same code pair), with the differences.
* ``summary.json`` — settings, stations, codes, pivot, graph, final TEC, comparison statistics (mean, RMS, RMS
  after removing the mean difference = a zero-mean datum, max) per filter and product.

``--bias`` accepts Bias-SINEX files (CAS/GFZ ``.BIA``; DSBs chained across files as in ``distnav gnss compare``)
and IONEX files whose header carries the DCB block between ``START OF AUX DATA`` and ``END OF AUX DATA``
(P1−P2, i.e. C1W−C2W satellite DCBs). Sign convention of both: biases add to the observations.
"""

from __future__ import annotations

import argparse
import csv
import io
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from distnav.commands import add_backend_arguments, command_exchange
from distnav.errors import DataFileError, ModelError

__all__ = ["add_ionosphere_parser", "add_parser", "IonosphereNetworkData", "network_data", "network_model",
           "run_ionosphere", "product_dcbs", "compare_dcbs"]

REGIONAL_KM = 500.0


@dataclass(frozen=True, eq=False)
class IonosphereNetworkData:
    """Everything the filters need from the real data: stations, epochs, geometry, model and series."""

    stations: list[str]
    codes: dict[int, str]
    t_gps_s: np.ndarray
    geometry: Any
    layout: Any
    series: Any
    dynamics: Any
    ionosphere: str
    positions_ecef_m: np.ndarray
    notes: list[str]


def _say(args: argparse.Namespace, text: str) -> None:
    if not getattr(args, "no_progress", False):
        print(text, file=sys.stderr, flush=True)


def network_data(obs_files: Sequence[str | Path], orbit: Any, *, l1_code: str = "C1C", l2_code: str = "C2W",
                 tlim: tuple[str, str] | None = None, interval_s: float | None = None, mask_deg: float = 10.0,
                 pivot: str | None = "G10", ionosphere: str = "auto", regional_km: float = REGIONAL_KM,
                 sigma_zenith_m: float | None = None, weighting: str = "sin") -> IonosphereNetworkData:
    """Read the stations, form the geometry-free observable on the union of their epochs, and build the model.

    Raises :class:`~distnav.errors.DataFileError` naming the file for unreadable files, missing code types or a
    station without any epoch with two satellites on both frequencies, and :class:`~distnav.errors.ModelError`
    when the orbit gives no position at the epochs or when no satellite is tracked by two stations.
    """
    from distnav.models.gnss.ionosphere import geometry_free_m
    from distnav.models.gnss.orbits import gps_seconds
    from distnav.models.gnss.rinex import read_code_observations

    if not obs_files:
        raise DataFileError("no observation file given")
    codes = {1: l1_code.upper(), 2: l2_code.upper()}
    obs = [read_code_observations(p, bands=(1, 2), codes=codes, tlim=tlim, interval_s=interval_s)
           for p in obs_files]
    stations = [o.station for o in obs]
    dup = sorted({s for s in stations if stations.count(s) > 1})
    if dup:
        twice = ", ".join(str(o.path) for o in obs if o.station == dup[0])
        raise DataFileError(f"station {dup[0]} is given twice ({twice})")
    notes = [f"{o.station}: {n}" for o in obs for n in o.notes]
    for o in obs:
        pos = o.position_ecef_m
        if not (np.all(np.isfinite(pos)) and np.linalg.norm(pos) > 6.0e6):
            raise DataFileError(f"{o.path}: no usable APPROX POSITION XYZ in the header ({pos.tolist()})")
    t_all = np.unique(np.concatenate([gps_seconds(o.time) for o in obs]))
    svs_all = sorted({s for o in obs for s in o.svs})
    T, n, S = t_all.size, len(obs), len(svs_all)
    gf = np.full((T, n, S), np.nan)
    for i, o in enumerate(obs):
        ti = np.searchsorted(t_all, gps_seconds(o.time))
        si = np.array([svs_all.index(s) for s in o.svs], dtype=np.int64)
        g = geometry_free_m(o.range_m[1], o.range_m[2])
        gf[np.ix_(ti, np.array([i]), si)] = g[:, None, :]
        both = np.isfinite(g).sum(axis=1) >= 2
        if not both.any():
            raise DataFileError(f"{o.path}: no epoch with two or more GPS satellites on both {codes[1]} and "
                                f"{codes[2]} (missing frequency?)")
    xyz = np.stack([o.position_ecef_m for o in obs])
    return network_model(stations, t_all, xyz, gf, svs_all, orbit, codes=codes, mask_deg=mask_deg, pivot=pivot,
                         ionosphere=ionosphere, regional_km=regional_km, sigma_zenith_m=sigma_zenith_m,
                         weighting=weighting, notes=notes, paths=[str(o.path) for o in obs])


def network_model(stations: list[str], t_gps_s: np.ndarray, xyz: np.ndarray, gf_m: np.ndarray,
                  svs_all: Sequence[str], orbit: Any, *, codes: dict[int, str] | None = None, mask_deg: float = 10.0,
                  pivot: str | None = "G10", ionosphere: str = "auto", regional_km: float = REGIONAL_KM,
                  sigma_zenith_m: float | None = None, weighting: str = "sin", notes: list[str] | None = None,
                  paths: list[str] | None = None) -> IonosphereNetworkData:
    """The model of :func:`network_data` from arrays: undifferenced geometry-free observations ``gf_m``
    (T, n, S) [m] (NaN = not observed) at ``t_gps_s`` for stations at ``xyz`` (n, 3)."""
    from distnav.models.gnss.ionosphere import (
        GF_SIGMA_ZENITH_M,
        IonosphereStateLayout,
        choose_pivot,
        geometry_free_series,
        ionosphere_dynamics,
        ionosphere_geometry,
    )

    codes = codes or {1: "C1C", 2: "C2W"}
    notes = list(notes or [])
    paths = paths or list(stations)
    t_all = np.asarray(t_gps_s, dtype=float)
    gf = np.asarray(gf_m, dtype=float)
    T, n, S = gf.shape
    base_km = float(np.max(np.linalg.norm(xyz[:, None] - xyz[None], axis=-1))) / 1e3 if n > 1 else 0.0
    mode = ionosphere
    if mode == "auto":
        mode = "common" if base_km <= regional_km else "per-receiver"
        notes.append(f"ionosphere: {mode} (longest baseline {base_km:.0f} km, regional limit {regional_km:.0f} km)")
    geo = ionosphere_geometry(orbit, t_all, receivers_ecef_m=xyz, names=stations, svs=svs_all, mask_deg=mask_deg,
                              ionosphere=mode)
    if not np.isfinite(geo.el_rad).any():
        raise ModelError(f"the orbit gives no satellite position at the observation epochs "
                         f"({_iso(t_all[0])} – {_iso(t_all[-1])}): wrong navigation/SP3 file?")
    no_orbit = [svs_all[k] for k in range(S)
                if np.isfinite(gf[:, :, k]).any() and not np.isfinite(geo.el_rad[:, :, k]).any()]
    if no_orbit:
        notes.append(f"no orbit at the observation epochs for {' '.join(no_orbit)} (dropped; a sparse broadcast file "
                     f"may need a larger --nav-max-age)")
    geo = geo.with_tracked(np.isfinite(gf))
    pair = geo.tracked.sum(axis=2, keepdims=True) >= 2
    geo = geo.with_tracked(np.broadcast_to(pair, geo.tracked.shape))
    for i in range(n):
        if not geo.tracked[:, i].any():
            raise DataFileError(f"{paths[i]}: no epoch with two or more satellites above the {mask_deg:g}° mask with "
                                f"{codes[1]} and {codes[2]} (or no orbit for them)")
    seen = np.asarray(geo.tracked.any(axis=(0, 1)))
    if n > 1 and not (np.asarray(geo.tracked.any(axis=0)).sum(axis=0) >= 2).any():
        raise ModelError("no satellite is tracked by two or more stations: the stations share no parameter")
    keep = [k for k in range(S) if seen[k]]
    svs = tuple(svs_all[k] for k in keep)
    geo = ionosphere_geometry(orbit, t_all, receivers_ecef_m=xyz, names=stations, svs=svs, mask_deg=mask_deg,
                              ionosphere=mode).with_tracked(geo.tracked[:, :, keep])
    piv = choose_pivot(svs, geo.tracked, pivot)
    if pivot is not None and piv != pivot:
        notes.append(f"pivot {pivot} not tracked: {piv} (tracked longest) used instead")
    layout = IonosphereStateLayout(svs, piv, n_ionospheres=1 if mode == "common" else n)
    sig = GF_SIGMA_ZENITH_M if sigma_zenith_m is None else float(sigma_zenith_m)
    series = geometry_free_series(geo, layout, obs_m=gf[:, :, keep], sigma_zenith_m=sig, weighting=weighting)
    dt = np.concatenate([[np.nan], np.diff(t_all)]) if T > 1 else np.array([30.0])
    dyn = ionosphere_dynamics(layout, dt if T > 1 else 30.0)
    return IonosphereNetworkData(stations, codes, t_all, geo, layout, series, dyn, mode, xyz, notes)


def _iso(t_gps_s: float) -> str:
    from distnav.models.gnss.orbits import datetime_from_gps_seconds

    return str(datetime_from_gps_seconds(t_gps_s))[:19]


# ----------------------------------------------------------------------------------------------- products
def product_dcbs(paths: Sequence[str | Path], svs: Sequence[str], obs1: str, obs2: str,
                 ) -> list[tuple[str, dict[str, float], list[str]]]:
    """Satellite DSBs ``obs1 − obs2`` [ns] of each product: ``[(name, {sv: dsb_ns}, notes)]``.

    Bias-SINEX files are read with :func:`~distnav.models.gnss.bias_sinex.read_bias_sinex` and DSBs chained across
    all given Bias-SINEX files (the file itself first); IONEX files give their P1−P2 satellite DCBs (C1W−C2W): a
    C1C−C2W comparison against them carries the satellites' C1C−C1W biases (noted).
    """
    from distnav.models.gnss.bias_sinex import read_bias_sinex, read_ionex_dcb, resolve_dsb

    sinex: list[Any] = []
    out: list[tuple[str, dict[str, float], list[str]]] = []
    kinds: list[tuple[str, Any]] = []
    for p in paths:
        path = Path(p)
        try:
            prod = read_bias_sinex(path)
            sinex.append(prod)
            kinds.append(("sinex", prod))
        except DataFileError as exc_sinex:
            try:
                kinds.append(("ionex", read_ionex_dcb(path)))
            except DataFileError as exc_ionex:
                raise DataFileError(f"{path}: neither a Bias-SINEX file ({exc_sinex}) nor an IONEX file with a DCB "
                                    f"block ({exc_ionex})") from None
    for kind, prod in kinds:
        values: dict[str, float] = {}
        notes: list[str] = []
        if kind == "sinex":
            order = [prod] + [q for q in sinex if q is not prod]
            for s in svs:
                try:
                    v, chain = resolve_dsb(order, obs1, obs2, prn=s)
                except ModelError:
                    continue
                values[s] = v
                if len(chain) > 1 or (chain and not chain[0].endswith(f"{obs1}-{obs2}")):
                    notes.append(f"{s}: {' + '.join(chain)}")
            name = f"{prod.name} {Path(prod.path).name}"
        else:
            for s in svs:
                if s in prod.satellite:
                    values[s] = prod.satellite[s][0]
            name = f"IONEX {Path(prod.path).name}"
            if (obs1, obs2) != ("C1W", "C2W"):
                notes.append(f"IONEX DCBs are P1-P2 (C1W-C2W); estimates are {obs1}-{obs2}: differences include "
                             f"the satellites' {obs1}-C1W biases")
        out.append((name, values, notes))
    return out


def compare_dcbs(estimate_ns: dict[str, float], product_ns: dict[str, float], pivot: str) -> dict[str, Any]:
    """Compare between-satellite DCBs ``DSB^s − DSB^p`` with a product aligned to the same pivot.

    Returns per-satellite reference and difference and the statistics of the differences: mean, RMS, RMS after
    removing the mean (zero-mean datum: insensitive to the pivot's own product value), max |·|, count.
    """
    if pivot not in product_ns:
        return {"n": 0, "note": f"the product has no DCB for the pivot {pivot}"}
    ref = {s: product_ns[s] - product_ns[pivot] for s in estimate_ns if s in product_ns and s != pivot}
    diff = {s: estimate_ns[s] - ref[s] for s in ref if np.isfinite(estimate_ns[s])}
    d = np.array(list(diff.values()))
    if d.size == 0:
        return {"n": 0, "note": "no satellite in common"}
    return {"n": int(d.size), "mean_ns": float(d.mean()), "rms_ns": float(np.sqrt(np.mean(d**2))),
            "rms_zero_mean_ns": float(np.std(d)), "max_abs_ns": float(np.max(np.abs(d))),
            "reference_ns": ref, "difference_ns": diff}


# ----------------------------------------------------------------------------------------------- command
def run_ionosphere(args: argparse.Namespace) -> int:
    """Handler of ``distnav gnss ionosphere``."""
    from distnav.algorithms.ckf import ckf
    from distnav.algorithms.kalman import central_filter, local_filters
    from distnav.models.gnss.ionosphere import GF_M_PER_DSB_NS, TEC_NAMES, TECU_L1_M, dcb_ns_from_gf_m
    from distnav.models.gnss.rinex import read_navigation, read_sp3
    from distnav.output import atomic_write_json, atomic_write_text

    if args.kn < 0:
        raise ModelError(f"--kn must be ≥ 0, got {args.kn}")
    orbit = (read_navigation(args.nav, max_age_s=args.nav_max_age * 3600.0) if args.nav else read_sp3(args.sp3))
    tlim = tuple(args.tlim) if args.tlim else None
    _say(args, f"reading {len(args.obs)} observation file(s)")
    data = network_data(args.obs, orbit, l1_code=args.l1_code, l2_code=args.l2_code, tlim=tlim,  # type: ignore[arg-type]
                        interval_s=args.interval, mask_deg=args.mask, pivot=args.pivot, ionosphere=args.ionosphere,
                        regional_km=args.regional_km, sigma_zenith_m=args.sigma, weighting=args.weighting)
    stations, layout, series, dyn = data.stations, data.layout, data.series, data.dynamics
    n = len(stations)
    if args.graph:
        from distnav.commands.gnss import load_edges

        graph = load_edges(Path(args.graph), stations)
    else:
        graph = _default_graph(data.positions_ecef_m, stations)
    _say(args, f"{n} station(s), {series.n_epochs} epochs, {len(layout.svs)} satellites, pivot {layout.pivot}, "
               f"ionosphere {data.ionosphere}; graph links {[(stations[i], stations[j]) for i, j in graph.links]}")
    central = central_filter(dyn, series).series
    local = local_filters(dyn, series).series
    res = ckf(dyn, series, graph=graph, protocol="P3", rounds=args.kn, monitor=False,
              exchange=command_exchange(args, graph))
    ck = res.series

    names = layout.state_names(stations)
    n_tec = layout.n_tec
    filters = [("central", central, 0)] + [(f"local:{s}", local, i) for i, s in enumerate(stations)] + \
              [(f"ckf:{s}", ck, i) for i, s in enumerate(stations)]
    out = Path(args.out)
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["time_gps", "filter", "parameter", "value", "std"])
    times = [_iso(t) for t in data.t_gps_s]
    dcb_names = [f"dcb_ns:{s}-{layout.pivot}" for s in layout.dcb_svs]
    for t, tt in enumerate(times):
        for label, s, row in filters:
            x, sd = s.estimates[t, row], s.std[t, row]
            for k in range(n_tec):
                if np.isfinite(x[k]):
                    w.writerow([tt, label, names[k], f"{x[k]:.5f}", f"{sd[k]:.5f}"])
                    if k % 3 == 0:
                        base = names[k].replace("vtec_m", "vtec_tecu")
                        w.writerow([tt, label, base, f"{x[k] / TECU_L1_M:.4f}", f"{sd[k] / TECU_L1_M:.4f}"])
            xd = dcb_ns_from_gf_m(x[n_tec:])
            sdd = sd[n_tec:] / GF_M_PER_DSB_NS
            for k, nm in enumerate(dcb_names):
                if np.isfinite(xd[k]):
                    w.writerow([tt, label, nm, f"{xd[k]:.4f}", f"{sdd[k]:.4f}"])
    atomic_write_text(out / "tec_dcb_per_epoch.csv", buf.getvalue())

    # final DCBs and comparison with products
    scale = 1.0 / GF_M_PER_DSB_NS

    def final(s: Any, row: int) -> tuple[dict[str, float], dict[str, float]]:
        xd = dcb_ns_from_gf_m(s.estimates[-1, row, n_tec:])
        sd = s.std[-1, row, n_tec:] * scale
        return (dict(zip(layout.dcb_svs, xd.tolist(), strict=True)),
                dict(zip(layout.dcb_svs, sd.tolist(), strict=True)))

    finals = {label: final(s, row) for label, s, row in filters}
    products = product_dcbs(args.bias, layout.svs, data.codes[1], data.codes[2]) if args.bias else []
    comparison: dict[str, Any] = {}
    for pname, values, pnotes in products:
        comparison[pname] = {"notes": pnotes,
                             **{label: compare_dcbs(est, values, layout.pivot) for label, (est, _) in finals.items()}}
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    head = ["satellite"]
    for label, _, _ in filters:
        head += [f"{label} dcb_ns", f"{label} std_ns"]
    head += [f"{p} dcb_ns" for p, _, _ in products]
    w.writerow(head)
    for s in layout.dcb_svs:
        row_out = [f"{s}-{layout.pivot}"]
        for label, _, _ in filters:
            v, sd = finals[label][0][s], finals[label][1][s]
            row_out += [f"{v:.4f}" if np.isfinite(v) else "", f"{sd:.4f}" if np.isfinite(sd) else ""]
        for _, values, _ in products:
            ref = values.get(s, np.nan) - values.get(layout.pivot, np.nan)
            row_out.append(f"{ref:.4f}" if np.isfinite(ref) else "")
        w.writerow(row_out)
    atomic_write_text(out / "dcb_final.csv", buf.getvalue())

    tec_final = {label: {names[k]: (float(s.estimates[-1, row, k]), float(s.std[-1, row, k]))
                         for k in range(n_tec)} for label, s, row in filters}
    summary: dict[str, Any] = {
        "stations": stations, "codes": {f"L{b}": c for b, c in data.codes.items()},
        "epochs": series.n_epochs, "first_epoch": times[0], "last_epoch": times[-1],
        "satellites": list(layout.svs), "pivot": layout.pivot, "ionosphere": data.ionosphere,
        "tec_parameters": list(TEC_NAMES), "graph_links": [[stations[i], stations[j]] for i, j in graph.links],
        "kn": args.kn, "protocol": "P3", "mask_deg": args.mask, "notes": data.notes,
        "dcb_convention": "dcb_ns = DSB^s - DSB^p of the code pair (Bias-SINEX sign: biases add to observations)",
        "final_tec_m": tec_final, "comparison": comparison,
        "messages": res.comm.as_dict(),
    }
    atomic_write_json(out / "summary.json", summary)
    _print_summary(stations, layout, comparison, finals)
    print(f"written {out / 'tec_dcb_per_epoch.csv'}, {out / 'dcb_final.csv'}, {out / 'summary.json'}")
    return 0


def _default_graph(xyz: np.ndarray, stations: list[str]) -> Any:
    try:
        from distnav.commands.gnss import default_graph

        return default_graph(xyz, stations)
    except ImportError:  # pragma: no cover - the gnss command group is absent
        from distnav.network.graph import Graph

        n = len(stations)
        return Graph.from_links(n, [(i, i + 1) for i in range(n - 1)], names=stations)


def _print_summary(stations: list[str], layout: Any, comparison: dict[str, Any],
                   finals: dict[str, tuple[dict[str, float], dict[str, float]]]) -> None:
    c = finals["central"]
    est = np.array([v for v in c[0].values() if np.isfinite(v)])
    sd = np.array([v for v in c[1].values() if np.isfinite(v)])
    print(f"central filter: {est.size} DCBs relative to {layout.pivot}; median std {np.median(sd):.2f} ns")
    for pname, comp in comparison.items():
        print(f"vs {pname}:")
        for label in ["central"] + [f"ckf:{s}" for s in stations] + [f"local:{s}" for s in stations]:
            r = comp.get(label, {})
            if r.get("n"):
                print(f"  {label:<12} n={r['n']:2d}  mean {r['mean_ns']:+7.2f}  RMS {r['rms_ns']:6.2f}  "
                      f"RMS (zero-mean) {r['rms_zero_mean_ns']:6.2f}  max {r['max_abs_ns']:6.2f} ns")
            else:
                print(f"  {label:<12} {r.get('note', 'no comparison')}")


def add_ionosphere_parser(gnss_subparsers: Any) -> argparse.ArgumentParser:
    """Add ``distnav gnss ionosphere`` to the ``gnss`` sub-command group (``set_defaults(func=run_ionosphere)``)."""
    p = gnss_subparsers.add_parser(
        "ionosphere", help="TEC and between-satellite DCBs by central, local and consensus Kalman filters "
                           "(paper 003 §5)", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    from distnav.commands.gnss import add_data_arguments  # gnss.py registers this module: import lazily

    add_data_arguments(p)
    p.add_argument("--kn", type=int, default=4, help="consensus rounds per epoch (default 4 = δ 15 s at Δ 60 s)")
    p.add_argument("--bias", nargs="+", metavar="FILE",
                   help="published products to compare with: Bias-SINEX (.BIA) and/or IONEX with a DCB block")
    p.add_argument("--out", default="distnav-ionosphere", help="output folder (default distnav-ionosphere)")
    add_backend_arguments(p)
    p.add_argument("--l1-code", default="C1C", help="L1 code (C1C = RINEX 2 C1, C1W = P1; default C1C)")
    p.add_argument("--l2-code", default="C2W", help="L2 code (default C2W = RINEX 2 P2)")
    p.add_argument("--pivot", default="G10", help="pivot satellite (default G10; the longest tracked if absent)")
    p.add_argument("--ionosphere", choices=["auto", "common", "per-receiver"], default="auto",
                   help="one regional ionosphere for all stations, one per station, or auto (by --regional-km)")
    p.add_argument("--regional-km", type=float, default=REGIONAL_KM,
                   help=f"auto: one common ionosphere if the longest baseline is below this (default {REGIONAL_KM:g})")
    p.add_argument("--sigma", type=float, default=None,
                   help="zenith σ of the geometry-free code [m] (default 0.656, paper 003 §5.1)")
    p.add_argument("--weighting", choices=["sin", "euler-goad", "constant"], default="sin",
                   help="elevation weighting (default sin: σ/sin θ)")
    p.add_argument("--no-progress", action="store_true")
    p.set_defaults(func=run_ionosphere)
    return p


add_parser = add_ionosphere_parser
"""Alias used by :mod:`distnav.commands.gnss` (``_SUBCOMMAND_MODULES``)."""

