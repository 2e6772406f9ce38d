"""The output files and console report of ``distnav gnss ionosphere`` (one day): ``tec_dcb_per_epoch.csv``,
``dcb_final.csv``, ``arcs.csv``, ``summary.json``, ``distnav_dsb.bia``, from the filters' series
(:func:`~distnav.models.gnss.gfnetwork.run_bias_filters`). Split from :mod:`.gnss_ionosphere` (issue 25: the
command wires, the stages write)."""

from __future__ import annotations

import argparse
import csv
import io
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from distnav.errors import ModelError

__all__ = ["write_results"]

Finals = dict[str, tuple[dict[str, float], dict[str, float]]]


def _iso(t_gps_s: float) -> str:
    from distnav.models.gnss.orbits import datetime_from_gps_seconds

    return str(datetime_from_gps_seconds(t_gps_s))[:19]


def write_results(
    args: argparse.Namespace,
    data: Any,
    series: Sequence[Any],
    comm: Any,
    *,
    l1: str,
    l2: str,
    pivot: str | None,
    graph: Any,
    fixed: Any,
) -> None:
    """Write every output of one day's run and print the report (datum, data, comparison, precision)."""
    from distnav.commands.gnss_report import print_data_report, print_summary, print_worst_own
    from distnav.commands.gnss_sinex_out import write_sinex
    from distnav.formats.gnss.product_files import satellite_svns
    from distnav.output import atomic_write_json

    stations, layout = data.stations, data.layout
    obj = [f"rx:{r}" for r in stations] + list(layout.svs)
    datum_text = _datum_text(args.datum, pivot, args.reference or layout.reference, series[0], layout, fixed)
    print(f"datum: {datum_text}")
    out = Path(args.out)
    times, tec_names = _write_epoch_csv(out, data, series, obj)
    finals: Finals = {
        s.label: (
            {o: float(v) for o, v in zip(obj, s.dsb_ns[-1].tolist(), strict=True)},
            {o: float(v) for o, v in zip(obj, s.dsb_std_ns[-1].tolist(), strict=True)},
        )
        for s in series
    }
    own = {sta: (c.get(1, l1), c.get(data.band, l2)) for sta, c in data.codes.items()}
    products, comparison = _compare(args, data, finals, own, l1, l2)
    _write_final_csv(out, obj, series, finals, products)
    summary = _summary(
        args, data, series, comm, finals, comparison, times, tec_names, obj, own, (l1, l2), pivot, graph, fixed
    )
    summary["dcb_convention"] += f", datum {datum_text}"
    summary["datum_statement"] = datum_text
    _levelling_outputs(out, data, summary)
    fac = series[0].realistic_factor
    realistic = {s.label: dict(zip(obj, s.realistic_std_ns().tolist(), strict=True)) for s in series}
    post = (finals["central"][0], realistic["central"])
    svns = satellite_svns([*(args.bias or []), *([args.datum_satellites] if fixed.reference_name else [])])
    summary["bias_sinex"] = str(
        write_sinex(out / "distnav_dsb.bia", data, post, l1, l2, args.datum, times, datum_text=datum_text, svns=svns)
    )
    atomic_write_json(out / "summary.json", summary)
    print_data_report(summary)
    if summary["communication"] is not None:
        print("CKF " + summary["communication"]["line"])
    print_summary(stations, comparison, finals, fac, realistic["central"])
    print_worst_own(summary["satellite_fit"])
    c0 = series[0]
    print(
        f"precision: variance factor {c0.variance_factor or float('nan'):.2f}, lag-1 correlation of the predicted "
        f"residuals {c0.lag1_correlation:.3f}: realistic σ = formal σ × {fac:.2f} (used in distnav_dsb.bia)"
    )
    if c0.between_station is not None:
        print(f"model choice: {c0.between_station.statement()}")
    print(f"written {out / 'tec_dcb_per_epoch.csv'}, {out / 'dcb_final.csv'}, {out / 'summary.json'}")


def _write_epoch_csv(out: Path, data: Any, series: Sequence[Any], obj: list[str]) -> tuple[list[str], list[str]]:
    """``tec_dcb_per_epoch.csv``: per epoch, filter and parameter the value and formal σ; returns the epochs (ISO)
    and the TEC parameter names."""
    from distnav.models.gnss.ionosphere import TEC_NAMES_QUADRATIC, TECU_L1_M
    from distnav.output import atomic_write_text

    stations, layout = data.stations, data.layout
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
    return times, tec_names


def _compare(
    args: argparse.Namespace, data: Any, finals: Finals, own: dict[str, tuple[str, str]], l1: str, l2: str
) -> tuple[list[Any], dict[str, Any]]:
    """The ``--bias`` products and every filter's datum-aligned comparison with each."""
    from distnav.formats.gnss.product_files import product_dsbs
    from distnav.models.gnss.products import channel_pattern, compare_in_datum

    stations, layout = data.stations, data.layout
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
            if data.frequencies_hz is not None and layout.svs[0].startswith("R"):
                f1 = dict(zip(layout.svs, data.frequencies_hz[0].tolist(), strict=True))
                diff = comparison[prod.name][label].get("difference_ns", {})
                comparison[prod.name][label]["glonass_channels"] = channel_pattern(diff, f1)
    return products, comparison


def _write_final_csv(out: Path, obj: list[str], series: Sequence[Any], finals: Finals, products: list[Any]) -> None:
    """``dcb_final.csv``: the last-epoch DSBs and σ of every filter and each product's."""
    from distnav.output import atomic_write_text

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


def _summary(
    args: argparse.Namespace,
    data: Any,
    series: Sequence[Any],
    comm: Any,
    finals: Finals,
    comparison: dict[str, Any],
    times: list[str],
    tec_names: list[str],
    obj: list[str],
    own: dict[str, tuple[str, str]],
    codes: tuple[str, str],
    pivot: str | None,
    graph: Any,
    fixed: Any,
) -> dict[str, Any]:
    """``summary.json`` of the settings and results (the levelling's parts: :func:`_levelling_outputs`)."""
    from distnav.models.gnss.gfnetwork import innovation_summary, satellite_fit

    stations, layout = data.stations, data.layout
    l1, l2 = codes
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
        "datum_statement": "",
        "datum_satellites": list(fixed.members) if fixed.members is not None else None,
        "datum_reference": fixed.reference_name,
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
        "dcb_convention": f"DSB {l1}-{l2} in ns (Bias-SINEX sign: biases add to the observations)",
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
            s.label: dict(zip(obj, s.realistic_std_ns().tolist(), strict=True)) for s in series
        },
        "comparison": comparison,
        "messages": comm.as_dict() if comm is not None else {},
        "communication": None if comm is None else _comm_comparison(comm, graph, data, stations).as_dict(),
        "first_estimable_epoch": {
            o: (times[int(np.argmax(np.isfinite(c.dsb_ns[:, k])))] if np.isfinite(c.dsb_ns[:, k]).any() else None)
            for k, o in enumerate(obj)
        },
    }
    summary["precision"] = {s.label: s.precision.summary() for s in series if s.precision is not None}
    summary["sigma_terms"] = data.sigma_terms
    if c.between_station is not None:
        summary["between_station_test"] = c.between_station.as_dict()
    if (tests := innovation_summary(series, stations)) is not None:
        summary["ckf_innovation_tests"] = tests
    fit = satellite_fit(data, series[0])
    summary["satellite_fit"] = fit.as_dict()
    return summary


def _levelling_outputs(out: Path, data: Any, summary: dict[str, Any]) -> None:
    """``arcs.csv`` and the levelling and screening summaries (with levelling only)."""
    from distnav.output import atomic_write_text

    if data.levelled:
        rows = [
            "station,satellite,first_epoch,last_epoch,n_epochs,start,offset_m,offset_std_m,code_rms_m,removed,"
            "removed_mw_outliers,dropped_short"
        ]
        for sta, lev in data.levelled.items():
            order = {sv: k for k, sv in enumerate(data.levelled_svs.get(sta, []))}
            arcs = sorted([*lev.arcs, *(lev.short_arcs or [])], key=lambda a: (order.get(a.sv, -1), a.first))
            for a in arcs:
                level = "" if a.dropped_short else f"{a.offset_m:.4f},{a.offset_std_m:.4f},{a.code_rms_m:.4f}"
                rows.append(
                    f"{sta},{a.sv},{a.first},{a.last},{a.n_epochs},{a.start_reason},"
                    f"{level if level else ',,'},{a.removed},{a.removed_mw},{a.dropped_short}"
                )
        atomic_write_text(out / "arcs.csv", "\n".join(rows) + "\n")
        summary["arcs"] = {sta: lev.arc_summary() for sta, lev in data.levelled.items()}
        summary["screening"] = {
            sta: lev.screening_summary(data.levelled_svs[sta], data.levelled_times.get(sta))
            for sta, lev in data.levelled.items()
        }


def _datum_text(datum: str, pivot: str | None, reference: str, central: Any, layout: Any, fixed: Any) -> str:
    """The datum in words with the satellites it runs over at the final epoch (console, summary, Bias-SINEX)."""
    from distnav.models.gnss.datum import datum_statement

    if datum == "pivot":
        return f"pivot satellite {pivot} (its DSB is zero)"
    if datum == "receiver":
        return f"reference receiver {reference} (its DSB is zero)"
    n = len(layout.receivers)
    present = [s for s, v in zip(layout.svs, central.dsb_ns[-1, n:].tolist(), strict=True) if np.isfinite(v)]
    return datum_statement(present, fixed.members, fixed.reference_name)


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


def _comm_comparison(comm: Any, graph: Any, data: Any, stations: list[str]) -> Any:
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
