"""``distnav gnss ionosphere``: TEC and receiver + satellite DCBs of a receiver network from real RINEX code data, by
the central filter, the single-receiver (local) filters and the consensus Kalman filter (paper 003 §5).

    distnav gnss ionosphere --obs FILE... (--nav FILE | --sp3 FILE...) [--graph EDGES.csv] [--kn K]
                            [--bias FILE...] [--out DIR]

Per station the geometry-free code ``(P_b − P_1)/(μ_b − 1)`` is formed from the chosen codes (default C1C and C2W,
or C1W when no ``--bias`` product gives C1C DSBs; RINEX 2 ``C1`` = C1C, ``P1`` = C1W, ``P2`` = C2W; C5Q/C5X use
the L5 factor), levelled to the carrier per arc (slips by geometry-free phase and Melbourne–Wübbena) and
w-tested by each station on its own data. The model (:mod:`distnav.models.gnss.gfbias`, docs/ionosphere.md):
a regional single-layer VTEC field per ionosphere (one per receiver when the network spans more than
``--regional-km``) plus receiver *and* satellite DSBs, output in the ``--datum`` S-basis (zero-mean satellites by
default; a ``--pivot`` satellite; a ``--reference`` receiver). Outputs in ``DIR``:

* ``tec_dcb_per_epoch.csv`` — per epoch, filter (``central``, ``local:STA``, ``ckf:STA``) and parameter: value
  and formal standard deviation (TEC in metres of L1 delay and in TECU, DSBs in ns).
* ``dcb_final.csv`` — the last-epoch DSBs of every filter and, with ``--bias``, each product's.
* ``arcs.csv`` — every levelled arc (start reason, offset, code RMS, removed observations).
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
import csv
import io
import json
import re
import sys
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from distnav.commands import add_backend_arguments, command_exchange
from distnav.errors import DataFileError, ModelError

if TYPE_CHECKING:
    from distnav.algorithms.result import CommComparison
    from distnav.exchange.core import CommTotals
    from distnav.models.gnss.gfnetwork import BiasNetworkData
    from distnav.network.graph import Graph

__all__ = ["add_ionosphere_parser", "add_parser", "network_data", "run_ionosphere", "validate_arguments"]

REGIONAL_KM = 1000.0
ARC_CORRELATION_S = 0.0
"""Correlation time [s] of the levelled code's error within an arc (σ per arc:
:func:`~distnav.models.gnss.gfnetwork.arc_sigma_scale`); 0 = off (independent epochs, the default)."""


def _say(args: argparse.Namespace, text: str) -> None:
    if not getattr(args, "no_progress", False):
        print(text, file=sys.stderr, flush=True)


_PRN = re.compile(r"^G(0[1-9]|[12][0-9]|3[0-2])$")
_L1_CODE = re.compile(r"^C1[CSLXPWYMN]$")
_LB_CODE = re.compile(r"^C(2[CDSLXPWYMN]|5[IQX])$")


def validate_arguments(args: argparse.Namespace) -> None:
    """Check every option value before any file is read (errors name the option; the CLI exits with 2)."""
    if args.pivot is not None and not _PRN.match(str(args.pivot).upper()):
        raise ModelError(f"--pivot {args.pivot}: not a GPS satellite (G01 … G32)")
    if args.datum == "pivot" and args.pivot is None:
        raise ModelError("--datum pivot needs --pivot PRN (e.g. --pivot G10)")
    if args.pivot is not None and args.datum != "pivot":
        raise ModelError(
            f"--pivot {args.pivot} is the pivot of --datum pivot; the datum is {args.datum} (add "
            f"--datum pivot, or leave --pivot out)"
        )
    if args.l1_code is not None and not _L1_CODE.match(args.l1_code.upper()):
        raise ModelError(f"--l1-code {args.l1_code}: not a GPS L1 code (C1C, C1W, C1L, C1X …)")
    if not _LB_CODE.match(args.l2_code.upper()):
        raise ModelError(f"--l2-code {args.l2_code}: not a GPS L2 or L5 code (C2W, C2L, C2X, C5Q, C5X …)")
    for opt, value in (("--sigma", args.sigma), ("--regional-km", args.regional_km), ("--tec-rw", args.tec_rw)):
        if value is not None and not (np.isfinite(value) and value > 0.0):
            raise ModelError(f"{opt} {value:g}: must be a positive number")
    if args.kn < 0:
        raise ModelError(f"--kn must be ≥ 0, got {args.kn}")
    if args.innovation_test is not None and not 0.0 < args.innovation_test < 0.5:
        raise ModelError(f"--innovation-test {args.innovation_test:g}: a test level in (0, 0.5), e.g. 0.001")
    if args.min_satellite_obs is not None and args.min_satellite_obs < 1:
        raise ModelError(f"--min-satellite-obs must be ≥ 1, got {args.min_satellite_obs}")
    if args.min_arc < 2:
        raise ModelError(f"--min-arc must be ≥ 2 epochs, got {args.min_arc}")
    if not (np.isfinite(args.gf_threshold) and args.gf_threshold > 0.0):
        raise ModelError(f"--gf-threshold {args.gf_threshold:g}: must be a positive number of metres")
    for e in (args.exclude or []) + (args.compare_exclude or []):
        if not (_PRN.match(e.upper()) or re.match(r"^[A-Za-z0-9]{4}$", e)):
            raise ModelError(f"--exclude {e}: neither a GPS satellite (G01 … G32) nor a 4-character station")
    if getattr(args, "c1_corrections", None):
        if args.l1_code is not None and args.l1_code.upper() != "C1C":
            raise ModelError(f"--c1-corrections applies to --l1-code C1C, not {args.l1_code}")
        if not Path(args.c1_corrections).exists():
            raise DataFileError(f"--c1-corrections {args.c1_corrections}: file not found")
    if args.reference is not None and not re.match(r"^[A-Za-z0-9]{4}$", args.reference):
        raise ModelError(f"--reference {args.reference}: not a 4-character station name")
    from distnav.commands.gnss import check_data_arguments  # gnss.py registers this module: import lazily

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


def network_data(
    obs_files: Sequence[str | Path],
    orbit: Any,
    *,
    l1_code: str = "C1C",
    l2_code: str = "C2W",
    tlim: tuple[str, str] | None = None,
    interval_s: float | None = None,
    mask_deg: float = 10.0,
    ionosphere: str = "auto",
    regional_km: float = REGIONAL_KM,
    sigma_zenith_m: float | None = None,
    weighting: str = "sin",
    reference: str | None = None,
    progress: Any = None,
    exclude: Sequence[str] = (),
    levelling: bool = True,
    min_arc_epochs: int = 10,
    gf_threshold_m: float = 0.05,
    screen: bool = True,
    c1_corrections: str | None = None,
    tec_rw_m_per_sqrt_s: float | None = None,
    min_satellite_obs: int | None = None,
    **model: Any,
) -> Any:
    """Read the stations, form the geometry-free code on the union of their epochs and build the bias model
    (:func:`distnav.models.gnss.gfnetwork.bias_network_model`). ``exclude``: satellites (``G01``) and stations
    (``BELE``) left out. ``levelling``: carrier-to-code levelling per arc on the full-rate data, then the
    ``interval_s`` grid (:func:`~distnav.models.gnss.levelling.level_station`; ``screen`` runs each station's
    w-test screening of its own code). Errors name the file: unreadable files, missing code types, a station
    without any epoch with both codes."""
    from distnav.formats.gnss.rinex import read_stations

    obs = read_stations(
        list(obs_files),
        l1_code=l1_code,
        l2_code=l2_code,
        tlim=tlim,
        interval_s=None if levelling else interval_s,
        phases=levelling,
        progress=progress,
        l1_fallback="C1W" if c1_corrections else None,
    )
    own = {o.station: dict(o.codes) for o in obs}  # the receivers' own codes (their DSBs' code pair)
    if c1_corrections:
        from distnav.formats.gnss.product_files import correct_c1

        obs = [correct_c1(o, c1_corrections) if o.codes.get(1) == "C1C" else o for o in obs]
    data = network_from_observations(
        obs,
        orbit,
        l2_code=l2_code,
        interval_s=interval_s,
        mask_deg=mask_deg,
        ionosphere=ionosphere,
        regional_km=regional_km,
        sigma_zenith_m=sigma_zenith_m,
        weighting=weighting,
        reference=reference,
        exclude=exclude,
        levelling=levelling,
        min_arc_epochs=min_arc_epochs,
        gf_threshold_m=gf_threshold_m,
        screen=screen,
        tec_rw_m_per_sqrt_s=tec_rw_m_per_sqrt_s,
        min_satellite_obs=min_satellite_obs,
        **model,
    )
    return replace(data, codes={s: own[s] for s in data.stations})


def network_from_observations(
    obs: Sequence[Any],
    orbit: Any,
    *,
    l2_code: str = "C2W",
    interval_s: float | None = None,
    mask_deg: float = 10.0,
    ionosphere: str = "auto",
    regional_km: float = REGIONAL_KM,
    sigma_zenith_m: float | None = None,
    weighting: str = "sin",
    reference: str | None = None,
    exclude: Sequence[str] = (),
    levelling: bool = True,
    min_arc_epochs: int = 10,
    gf_threshold_m: float = 0.05,
    screen: bool = True,
    tec_rw_m_per_sqrt_s: float | None = None,
    min_satellite_obs: int | None = None,
    arc_correlation_s: float | None = None,
    tec_order: int = 1,
    mapping: str = "slm",
    station_weights: str = "auto",
) -> Any:
    """:func:`network_data` from observations already read
    (:class:`~distnav.models.gnss.code_observations.CodeObservations` with phases when ``levelling``; the
    full-rate data, ``interval_s`` selects the filter's grid).
    ``arc_correlation_s``: the levelled code's σ per arc from :func:`~distnav.models.gnss.gfnetwork.arc_sigma_scale`
    (default :data:`ARC_CORRELATION_S`; 0: independent epochs). ``station_weights`` "auto" | "on" | "off": σ
    factors from each station's levelling residuals ("auto": with a common ionosphere only; bias_network_model)."""
    from distnav.models.gnss.arcprecision import arc_ids_on_grid
    from distnav.models.gnss.gfbias import geometry_free_band_m
    from distnav.models.gnss.gfnetwork import (
        TEC_RW_M_PER_SQRT_S,
        arc_sigma_scale,
        bias_network_model,
    )
    from distnav.models.gnss.levelling import station_sigma_factors
    from distnav.models.gnss.orbits import gps_seconds

    band = int(l2_code[1])
    excl = {e.upper() for e in exclude}
    obs = [o for o in obs if o.station not in excl]
    if not obs:
        raise DataFileError("every station is excluded")
    stations = [o.station for o in obs]
    notes = [f"{o.station}: {n}" for o in obs for n in o.notes]
    levelled = (
        {
            o.station: _level(o, orbit, band, mask_deg, min_arc_epochs, gf_threshold_m, screen, i)
            for i, o in enumerate(obs)
        }
        if levelling
        else {}
    )
    if levelling and interval_s:
        from distnav.formats.gnss.rinex_obs import on_grid

        grids = {o.station: on_grid(o.time, interval_s) for o in obs}
    else:
        grids = {o.station: np.ones(o.time.size, bool) for o in obs}
    t_all = np.unique(np.concatenate([gps_seconds(o.time[grids[o.station]]) for o in obs]))
    svs_all = sorted({s for o in obs for s in o.svs} - excl)
    T, n, S = t_all.size, len(obs), len(svs_all)
    gf = np.full((T, n, S), np.nan)
    corr_s = ARC_CORRELATION_S if arc_correlation_s is None else float(arc_correlation_s)
    scale = np.ones((T, n, S)) if levelling and corr_s > 0 else None
    for i, o in enumerate(obs):
        keep_t = grids[o.station]
        ti = np.searchsorted(t_all, gps_seconds(o.time[keep_t]))
        cols = [k for k, sv in enumerate(o.svs) if sv not in excl]
        si = np.array([svs_all.index(o.svs[k]) for k in cols], dtype=np.int64)
        full = levelled[o.station].gf_m if levelling else geometry_free_band_m(o.range_m[1], o.range_m[band], band)
        g = full[keep_t][:, cols]
        gf[np.ix_(ti, np.array([i]), si)] = g[:, None, :]
        if scale is not None and corr_s > 0:
            arcs = levelled[o.station].arc[keep_t][:, cols]
            scale[np.ix_(ti, np.array([i]), si)] *= arc_sigma_scale(arcs, t_all[ti], corr_s)[:, None, :]
        if not (np.isfinite(o.range_m[1]) & np.isfinite(o.range_m[band])).any():
            raise DataFileError(
                f"{o.path}: no epoch with a GPS satellite on both {o.codes[1]} and {o.codes[band]} (missing frequency?)"
            )
    if excl:
        notes.append(f"excluded: {' '.join(sorted(excl))}")
    codes = {o.station: dict(o.codes) for o in obs}
    xyz = np.stack([o.position_ecef_m for o in obs])
    for sta, lev in levelled.items():
        n_rm = int(lev.removed.sum())
        notes.append(
            f"{sta}: levelled {len(lev.arcs)} arcs (starts: "
            f"{', '.join(f'{k} {v}' for k, v in sorted(lev.starts.items()))}; {lev.dropped_short} shorter "
            f"than {min_arc_epochs} epochs dropped); screening removed {n_rm} code observations"
        )
    data = bias_network_model(
        stations,
        t_all,
        xyz,
        gf,
        svs_all,
        orbit,
        band=band,
        codes=codes,
        mask_deg=mask_deg,
        ionosphere=ionosphere,
        regional_km=regional_km,
        sigma_zenith_m=sigma_zenith_m,
        weighting=weighting,
        reference=reference,
        notes=notes,
        paths=[str(o.path) for o in obs],
        vtec_rw_m_per_sqrt_s=TEC_RW_M_PER_SQRT_S if tec_rw_m_per_sqrt_s is None else tec_rw_m_per_sqrt_s,
        min_satellite_obs=min_satellite_obs,
        sigma_scale=scale,
        tec_order=tec_order,
        mapping=mapping,
        station_weighting=station_weights,
        station_sigma=station_sigma_factors([levelled[o.station] for o in obs]) if levelling else None,
    )
    arc_id = arc_ids_on_grid(obs, levelled, grids, data.t_gps_s, data.layout.svs) if levelling else None
    return replace(data, levelled=levelled, levelled_svs={o.station: list(o.svs) for o in obs}, arc_id=arc_id)


def _level(
    o: Any, orbit: Any, band: int, mask_deg: float, min_arc_epochs: int, gf_threshold_m: float, screen: bool, node: int
) -> Any:
    """Level one station's geometry-free code per arc (σ of the code from the elevation: σ₀/sin θ)."""
    from distnav.models.gnss.geometry import azimuth_elevation
    from distnav.models.gnss.levelling import level_station
    from distnav.models.gnss.orbits import gps_seconds

    if band not in o.phase_m or 1 not in o.phase_m:
        raise DataFileError(f"{o.path}: no carrier phase on L1 and L{band} for levelling (use --levelling none)")
    t = gps_seconds(o.time)
    svs = [s for s in o.svs if s in orbit.svs]
    el = np.full((t.size, len(o.svs)), np.nan)
    if svs:
        _, e = azimuth_elevation(o.position_ecef_m, orbit.positions_ecef(t, svs))
        el[:, [o.svs.index(s) for s in svs]] = e
    above = np.isfinite(el) & (el > np.deg2rad(mask_deg))
    p1, pb = np.where(above, o.range_m[1], np.nan), np.where(above, o.range_m[band], np.nan)
    sigma = 1.0 / np.sin(np.where(above, el, 0.5 * np.pi))
    lli = o.lli.get(1, np.zeros(p1.shape, np.int8)) | o.lli.get(band, np.zeros(p1.shape, np.int8))
    return level_station(
        t,
        o.svs,
        p1,
        pb,
        o.phase_m[1],
        o.phase_m[band],
        band=band,
        lli=lli,
        sigma_m=sigma,
        min_arc_epochs=min_arc_epochs,
        gf_threshold_m=gf_threshold_m,
        screen=screen,
        fallback_raw=True,
        node=node,
    )


def _iso(t_gps_s: float) -> str:
    from distnav.models.gnss.orbits import datetime_from_gps_seconds

    return str(datetime_from_gps_seconds(t_gps_s))[:19]


def run_ionosphere(args: argparse.Namespace) -> int:
    """Handler of ``distnav gnss ionosphere``."""
    from distnav.commands.gnss_report import (
        C1C_WARNING,
        choose_l1_code,
        print_data_report,
        print_summary,
        print_worst_own,
    )
    from distnav.commands.gnss_sinex_out import write_sinex
    from distnav.formats.gnss.product_files import product_dsbs
    from distnav.formats.gnss.rinex import read_navigation, read_sp3
    from distnav.models.gnss.gfnetwork import innovation_summary, run_bias_filters, satellite_fit
    from distnav.models.gnss.ionosphere import TEC_NAMES_QUADRATIC, TECU_L1_M
    from distnav.models.gnss.products import compare_in_datum
    from distnav.output import atomic_write_json, atomic_write_text

    validate_arguments(args)
    days = _split_days(args)
    if len(days) > 1:
        return _run_days(args, days)
    l1, l1_note = choose_l1_code(args)
    l2 = args.l2_code.upper()
    if l1_note:
        print(f"NOTE: {l1_note}", file=sys.stderr, flush=True)
    if l1 == "C1C" and not args.c1_corrections:
        print(C1C_WARNING.format(l2=l2), file=sys.stderr, flush=True)
    if args.bias:
        for b in args.bias:
            if not Path(b).exists():
                raise DataFileError(f"{b}: file not found")
    if args.nav and len(args.nav) > 1:
        raise ModelError(f"{len(args.nav)} --nav files for one day of observations: give one")
    orbit = read_navigation(args.nav[0], max_age_s=args.nav_max_age * 3600.0) if args.nav else read_sp3(args.sp3)
    tlim = tuple(args.tlim) if args.tlim else None

    def progress(label: str, fraction: float) -> None:
        _say(args, f"reading {label}: {100 * fraction:3.0f} %")

    try:
        data = network_data(
            args.obs,
            orbit,
            l1_code=l1,
            l2_code=l2,
            tlim=tlim,
            interval_s=args.interval,
            mask_deg=args.mask,
            ionosphere=args.ionosphere,
            regional_km=args.regional_km,
            sigma_zenith_m=args.sigma,
            weighting=args.weighting,
            reference=args.reference,
            progress=progress,
            exclude=args.exclude or (),
            levelling=args.levelling == "arc",
            min_arc_epochs=args.min_arc,
            gf_threshold_m=args.gf_threshold,
            screen=not args.no_screening,
            c1_corrections=args.c1_corrections,
            tec_rw_m_per_sqrt_s=args.tec_rw,
            min_satellite_obs=args.min_satellite_obs,
            mapping=args.mapping,
            tec_order=2 if args.tec_field == "quadratic" else 1,
        )
    except DataFileError as exc:
        if l1_note and f"({l1})" in str(exc):
            raise DataFileError(f"{exc} ({l1_note})") from None
        raise
    if args.c1_corrections:
        l1 = "C1W"
    stations, layout = data.stations, data.layout
    pivot = args.pivot.upper() if args.pivot else None
    if args.datum == "pivot":
        if pivot not in layout.svs:
            raise ModelError(
                f"--pivot {pivot}: not tracked above the mask by any station (tracked: {' '.join(layout.svs)})"
            )
    n = len(stations)
    if args.graph:
        from distnav.commands.gnss import load_edges

        graph = load_edges(Path(args.graph), stations)
    else:
        graph = _default_graph(data.positions_ecef_m, stations)
    _say(
        args,
        f"{n} station(s), {data.series.n_epochs} epochs, {len(layout.svs)} satellites, datum {args.datum}, "
        f"estimation basis: receiver {layout.reference}; ionosphere {data.ionosphere}; graph links "
        f"{[(stations[i], stations[j]) for i, j in graph.links]}",
    )
    series, comm = run_bias_filters(
        data,
        datum=args.datum,
        pivot=pivot,
        reference=args.reference,
        graph=graph,
        kn=args.kn,
        exchange=command_exchange(args, graph),
        innovation_level=args.innovation_test,
    )
    obj = [f"rx:{r}" for r in stations] + list(layout.svs)
    out = Path(args.out)
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["time_gps", "filter", "parameter", "value", "std"])
    times = [_iso(t) for t in data.t_gps_s]
    nt = layout.n_tec_terms
    tec_names = [
        nm
        for g in range(layout.n_ionospheres)
        for nm in ((f"{stations[g]}:" if layout.n_ionospheres > 1 else "") + t for t in TEC_NAMES_QUADRATIC[:nt])
    ]
    for t, tt in enumerate(times):
        for s in series:
            for k, nm in enumerate(tec_names):
                x, sd = s.tec[t, k], s.tec_std[t, k]
                if np.isfinite(x):
                    w.writerow([tt, s.label, nm, f"{x:.5f}", f"{sd:.5f}"])
                    if k % nt == 0:
                        w.writerow(
                            [
                                tt,
                                s.label,
                                nm.replace("vtec_m", "vtec_tecu"),
                                f"{x / TECU_L1_M:.4f}",
                                f"{sd / TECU_L1_M:.4f}",
                            ]
                        )
            for k, nm in enumerate(obj):
                x, sd = s.dsb_ns[t, k], s.dsb_std_ns[t, k]
                if np.isfinite(x):
                    w.writerow([tt, s.label, f"dsb_ns:{nm}", f"{x:.4f}", f"{sd:.4f}"])
    atomic_write_text(out / "tec_dcb_per_epoch.csv", buf.getvalue())

    finals = {
        s.label: (
            {o: float(v) for o, v in zip(obj, s.dsb_ns[-1].tolist(), strict=True)},
            {o: float(v) for o, v in zip(obj, s.dsb_std_ns[-1].tolist(), strict=True)},
        )
        for s in series
    }
    own = {sta: (c.get(1, l1), c.get(data.band, l2)) for sta, c in data.codes.items()}
    products = product_dsbs(args.bias, layout.svs, stations, l1, l2, station_codes=own) if args.bias else []
    _check_days(products, data.t_gps_s, args.allow_other_day)
    comparison: dict[str, Any] = {}
    excl = [e.upper() for e in (args.compare_exclude or [])]
    for prod in products:
        comparison[prod.name] = {"notes": prod.notes}
        for label, (val, _) in finals.items():
            sat = {k: v for k, v in val.items() if not k.startswith("rx:")}
            rx = {k[3:]: v for k, v in val.items() if k.startswith("rx:")}
            comparison[prod.name][label] = compare_in_datum(sat, rx, prod, exclude=excl)
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(
        ["object"]
        + [f"{s.label} {q}" for s in series for q in ("dsb_ns", "std_ns")]
        + [f"{p.name} dsb_ns" for p in products]
    )
    for o in obj:
        row_out = [o]
        for s in series:
            v, sd = finals[s.label][0][o], finals[s.label][1][o]
            row_out += [f"{v:.4f}" if np.isfinite(v) else "", f"{sd:.4f}" if np.isfinite(sd) else ""]
        for p in products:
            ref = p.station.get(o[3:]) if o.startswith("rx:") else p.satellite.get(o)
            row_out.append(f"{ref:.4f}" if ref is not None else "")
        w.writerow(row_out)
    atomic_write_text(out / "dcb_final.csv", buf.getvalue())

    c = series[0]
    summary: dict[str, Any] = {
        "stations": stations,
        "codes": {"L1": l1, f"L{data.band}": l2},
        "band": data.band,
        "epochs": data.series.n_epochs,
        "first_epoch": times[0],
        "last_epoch": times[-1],
        "satellites": list(layout.svs),
        "datum": args.datum,
        "pivot": pivot,
        "estimation_basis": layout.reference,
        "ionosphere": data.ionosphere,
        "tec_parameters": tec_names,
        "graph_links": [[stations[i], stations[j]] for i, j in graph.links],
        "kn": args.kn,
        "protocol": "P3",
        "mask_deg": args.mask,
        "notes": data.notes,
        "station_codes": own,
        "dcb_convention": f"DSB {l1}-{l2} in ns (Bias-SINEX sign: biases add to the observations), datum {args.datum}",
        "final_tec_m": {
            s.label: {nm: (float(s.tec[-1, k]), float(s.tec_std[-1, k])) for k, nm in enumerate(tec_names)}
            for s in series
        },
        "final_dsb_ns": {label: v for label, (v, _) in finals.items()},
        "final_dsb_std_ns": {label: sd for label, (_, sd) in finals.items()},
        "variance_factor": {s.label: s.variance_factor for s in series},
        "innovations": {s.label: s.n_innovations for s in series},
        "lag1_correlation": {s.label: s.lag1_correlation for s in series},
        "final_dsb_std_realistic_ns": {
            s.label: {k: v * s.realistic_factor for k, v in finals[s.label][1].items()} for s in series
        },
        "comparison": comparison,
        "messages": comm.as_dict() if comm is not None else {},
        "communication": None if comm is None else _comm_comparison(comm, graph, data, stations).as_dict(),
        "first_estimable_epoch": {
            o: (times[int(np.argmax(np.isfinite(c.dsb_ns[:, k])))] if np.isfinite(c.dsb_ns[:, k]).any() else None)
            for k, o in enumerate(obj)
        },
    }
    if data.levelled:
        rows = ["station,satellite,first_epoch,last_epoch,n_epochs,start,offset_m,offset_std_m,code_rms_m,removed"]
        for sta, lev in data.levelled.items():
            for a in lev.arcs:
                rows.append(
                    f"{sta},{a.sv},{a.first},{a.last},{a.n_epochs},{a.start_reason},{a.offset_m:.4f},"
                    f"{a.offset_std_m:.4f},{a.code_rms_m:.4f},{a.removed}"
                )
        atomic_write_text(out / "arcs.csv", "\n".join(rows) + "\n")
        summary["arcs"] = {sta: lev.arc_summary() for sta, lev in data.levelled.items()}
        summary["screening"] = {
            sta: lev.screening_summary(data.levelled_svs[sta]) for sta, lev in data.levelled.items()
        }
    summary["precision"] = {s.label: s.precision.summary() for s in series if s.precision is not None}
    if (tests := innovation_summary(series, stations)) is not None:
        summary["ckf_innovation_tests"] = tests
    fit = satellite_fit(data, series[0])
    summary["satellite_fit"] = fit.as_dict()
    fac = series[0].realistic_factor
    post = (finals["central"][0], {k: v * fac for k, v in finals["central"][1].items()})
    summary["bias_sinex"] = str(write_sinex(out / "distnav_dsb.bia", data, post, l1, l2, args.datum, times))
    atomic_write_json(out / "summary.json", summary)
    print_data_report(summary)
    if summary["communication"] is not None:
        print("CKF " + summary["communication"]["line"])
    print_summary(stations, comparison, finals, fac)
    print_worst_own(summary["satellite_fit"])
    c0 = series[0]
    print(
        f"precision: variance factor {c0.variance_factor or float('nan'):.2f}, lag-1 correlation of the predicted "
        f"residuals {c0.lag1_correlation:.3f}: realistic σ = formal σ × {fac:.2f} (used in distnav_dsb.bia)"
    )
    print(f"written {out / 'tec_dcb_per_epoch.csv'}, {out / 'dcb_final.csv'}, {out / 'summary.json'}")
    return 0


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
    write_combined_sinex(out / "distnav_dsb_combined.bia", result, summaries)
    rep = result["repeatability_ns"]
    med = np.nanmedian([v for v in rep.values() if v is not None]) if rep else float("nan")
    rx = ", ".join(f"{k[3:]} {v:.3f}" for k, v in sorted(rep.items()) if k.startswith("rx:") and v is not None)
    print(
        f"combined {len(summaries)} days: {len(result['combined_ns'])} DSBs; day-to-day repeatability (std) median "
        f"{med:.3f} ns over the satellites"
        + (f", receivers {rx} ns" if rx else "")
        + f"; written {out / 'multiday.json'}, {out / 'distnav_dsb_combined.bia'}"
    )
    return 0


def _check_days(products: Sequence[Any], t_gps_s: np.ndarray, allow: bool) -> None:
    from distnav.models.gnss.orbits import datetime_from_gps_seconds

    days = {
        np.asarray(datetime_from_gps_seconds(float(t))).astype("datetime64[D]")[()] for t in (t_gps_s[0], t_gps_s[-1])
    }
    for p in products:
        if p.day is not None and p.day not in days and not allow:
            raise ModelError(
                f"{p.path.name}: a product of {p.day}, the data are of "
                f"{', '.join(str(d) for d in sorted(days))} (--allow-other-day to compare anyway)"
            )


def _default_graph(xyz: np.ndarray, stations: list[str]) -> Any:
    from distnav.commands.gnss import default_graph

    return default_graph(xyz, stations)


def add_ionosphere_parser(gnss_subparsers: Any) -> argparse.ArgumentParser:
    """Add ``distnav gnss ionosphere`` to the ``gnss`` sub-command group (``set_defaults(func=run_ionosphere)``)."""
    p = gnss_subparsers.add_parser(
        "ionosphere",
        help="TEC and receiver + satellite DCBs by central, local and consensus Kalman filters (paper 003 §5)",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    from distnav.commands.gnss import add_data_arguments  # gnss.py registers this module: import lazily

    add_data_arguments(p)
    p.add_argument("--kn", type=int, default=4, help="consensus rounds per epoch (default 4 = δ 15 s at Δ 60 s)")
    p.add_argument(
        "--bias",
        nargs="+",
        metavar="FILE",
        help="published products to compare with: Bias-SINEX (.BIA) and/or IONEX with a DCB block",
    )
    p.add_argument("--out", default="distnav-ionosphere", help="output folder (default distnav-ionosphere)")
    add_backend_arguments(p)
    p.add_argument(
        "--l1-code",
        default=None,
        help="L1 code (C1C = RINEX 2 C1, C1W = P1; default C1C, or C1W when every --bias is IONEX)",
    )
    p.add_argument(
        "--l2-code", default="C2W", help="second code (default C2W = RINEX 2 P2; C5Q/C5X use the L5 frequency factor)"
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
        "--reference",
        default=None,
        metavar="STATION",
        help="reference receiver (--datum receiver; also the estimation basis; default: the station "
        "observing at the first epoch)",
    )
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
    p.add_argument(
        "--tec-field",
        choices=["linear", "quadratic"],
        default="linear",
        help="VTEC field of each ionosphere: paper 003's ν and two gradients, or second order too "
        "(low-latitude stations: docs/gnss.md)",
    )
    p.add_argument(
        "--mapping",
        choices=["slm", "mslm"],
        default="slm",
        help="single-layer mapping: 450-km thin shell (paper 003) or modified (506.7 km, α = 0.9782)",
    )
    p.add_argument(
        "--levelling",
        choices=["arc", "none"],
        default="arc",
        help="carrier-to-code levelling per continuous arc (default) or raw code",
    )
    p.add_argument(
        "--min-arc",
        type=int,
        default=10,
        metavar="EPOCHS",
        help="shortest arc kept for levelling, in epochs of the file (default 10)",
    )
    p.add_argument(
        "--gf-threshold",
        type=float,
        default=0.05,
        metavar="M",
        help="smallest cycle-slip limit on the geometry-free phase [m] (default 0.05; raised to 4x "
        "the satellite's recent prediction-error RMS where the ionosphere is noisier)",
    )
    p.add_argument("--no-screening", action="store_true", help="no w-test screening of each station's code")
    p.add_argument("--allow-other-day", action="store_true", help="compare with a product of another day than the data")
    p.add_argument(
        "--ionosphere",
        choices=["auto", "common", "per-receiver"],
        default="auto",
        help="one regional ionosphere for all stations, one per station, or auto (by --regional-km)",
    )
    p.add_argument(
        "--regional-km",
        type=float,
        default=REGIONAL_KM,
        help=f"auto: one common ionosphere if the longest baseline is below this (default {REGIONAL_KM:g})",
    )
    p.add_argument(
        "--sigma",
        type=float,
        default=None,
        help="zenith σ of the geometry-free code [m] (default 0.656, paper 003 §5.1)",
    )
    p.add_argument(
        "--weighting",
        choices=["sin", "euler-goad", "constant"],
        default="sin",
        help="elevation weighting (default sin: σ/sin θ)",
    )
    p.add_argument(
        "--tec-rw",
        type=float,
        default=None,
        metavar="M_PER_SQRT_S",
        help="random walk of the vertical L1 delay [m/√s] (gradients 5× per radian; default 0.01, "
        "10× paper 003's: docs/ionosphere.md)",
    )
    p.add_argument(
        "--min-satellite-obs",
        type=int,
        default=None,
        metavar="N",
        help="satellites with fewer station-epochs (filter grid) are not estimated and named in the "
        "notes (default 240 = 4 station-hours at 60 s, at most a quarter of the best-tracked "
        "satellite's, at least 30)",
    )
    p.add_argument(
        "--innovation-test",
        type=float,
        default=None,
        metavar="LEVEL",
        help="CKF: each receiver w-tests its own predicted residuals at this level and rejects outliers "
        "before the consensus (e.g. 0.001)",
    )
    p.add_argument("--no-progress", action="store_true")
    p.set_defaults(func=run_ionosphere)
    parser: argparse.ArgumentParser = p
    return parser


add_parser = add_ionosphere_parser
"""Alias used by :mod:`distnav.commands.gnss` (``_SUBCOMMAND_MODULES``)."""


def _comm_comparison(comm: CommTotals, graph: Graph, data: BiasNetworkData, stations: list[str]) -> CommComparison:
    """The consensus filters' traffic beside gathering every epoch's observations at one station (issue 27)."""
    from distnav.algorithms.kalman.gather_data import RECORDS_DATA, record_bytes_per_node
    from distnav.algorithms.result import compare_with_gather

    return compare_with_gather(
        comm,
        graph,
        record_bytes_per_node(data.series.tracked),
        data=RECORDS_DATA,
        node_label="station",
        node_names=stations,
    )
