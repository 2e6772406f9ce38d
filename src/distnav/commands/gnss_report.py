"""Console report of ``distnav gnss ionosphere`` and ``gnss compare``: the L1 code matched to the comparison
products, the C1C warning, the filters' DSBs with their realistic σ, the product comparisons and the
worst-fitting satellite (from each product comparison and from the satellites' own residuals)."""

from __future__ import annotations

import argparse
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

__all__ = [
    "C1C_WARNING",
    "choose_l1_code",
    "print_data_report",
    "print_summary",
    "print_worst_vs_product",
    "print_worst_own",
    "worst_over_days",
]

C1C_WARNING = (
    "WARNING: L1 code C1C (RINEX 2 C1). The satellites' C1C-C1W biases (up to 1-2 ns) go into the DCBs: "
    "compare only with C1C-{l2} products (CAS), not with P1-P2 / C1W-{l2} ones (IONEX, GFZ), or use "
    "--l1-code C1W where every station tracks P1."
)


def choose_l1_code(args: argparse.Namespace) -> tuple[str, str | None]:
    """The L1 code: given (``--l1-code``), else the one the comparison products are on — C1W (P1) when no
    ``--bias`` product gives a C1C−L2 satellite DSB, even chained (IONEX DCBs, GFZ's C1W−C2W alone), else C1C.
    Returns the code and a note saying why (None when given or C1C by default)."""
    from distnav.errors import DataFileError, ModelError
    from distnav.formats.gnss.bias_sinex import read_bias_sinex, read_ionex_dcb, resolve_dsb

    if args.l1_code:
        return str(args.l1_code).upper(), None
    if not args.bias:
        return "C1C", None
    l2 = str(args.l2_code).upper()
    sinex = []
    ionex = []
    for b in args.bias:
        try:
            sinex.append(read_bias_sinex(b))
        except DataFileError:
            read_ionex_dcb(b)  # not Bias-SINEX: IONEX, or a DataFileError naming the file before any choice
            ionex.append(Path(b).name)

    def gives(l1: str) -> bool:
        for p in sinex:
            for prn in p.satellites("G"):
                try:
                    resolve_dsb([p, *[q for q in sinex if q is not p]], l1, l2, prn=prn)
                    return True
                except ModelError:
                    pass
        return False

    if gives("C1C"):
        return "C1C", None
    if ionex and l2 == "C2W" or gives("C1W"):
        names = ", ".join([p.name for p in sinex] + ionex)
        return "C1W", (
            f"--l1-code C1W chosen to match the products ({names}: C1W-{l2} DSBs, no C1C-{l2}); a "
            f"station without P1 needs --l1-code C1C with --c1-corrections CAS…BIA"
        )
    return "C1C", None


def print_summary(
    stations: Sequence[str],
    comparison: Mapping[str, Any],
    finals: Mapping[str, tuple[dict[str, float], dict[str, float]]],
    realistic_factor: float,
    realistic_std_ns: Mapping[str, float] | None = None,
) -> None:
    """The central filter's DSBs (σ realistic: formal × the a-posteriori factor, or ``realistic_std_ns`` when
    given: with the between-station term, :mod:`distnav.models.gnss.stationcheck`) and every product comparison."""
    c = finals["central"]
    f = realistic_factor if np.isfinite(realistic_factor) and realistic_factor > 0 else 1.0
    real = realistic_std_ns if realistic_std_ns is not None else {k: v * f for k, v in c[1].items()}
    sd = np.array([v for k, v in real.items() if not k.startswith("rx:") and np.isfinite(v)])
    rx = ", ".join(f"{k[3:]} {v:+.2f} ± {real[k]:.2f}" for k, v in c[0].items() if k.startswith("rx:"))
    print(
        f"central filter: {sd.size} satellite DSBs, median σ {np.median(sd):.2f} ns (realistic: formal × "
        f"{f:.2f}); receivers: {rx} ns"
    )
    for label, (val, _) in finals.items():
        if label.startswith("ckf:") and not any(np.isfinite(v) for v in val.values()):
            print(
                f"note: {label} has no final DSB estimate: its data and those of the stations within --kn "
                f"consensus rounds do not determine them (raise --kn, or add links with --graph)"
            )
    for pname, comp in comparison.items():
        print(f"vs {pname}:")
        for label in ["central"] + [f"ckf:{s}" for s in stations] + [f"local:{s}" for s in stations]:
            r = comp.get(label, {})
            if r.get("n"):
                line = (
                    f"  {label:<12} n={r['n']:2d}  offset {r['datum_offset_ns']:+7.2f}  RMS (zero-mean) "
                    f"{r['rms_zero_mean_ns']:5.2f}  max {r['max_abs_zero_mean_ns']:5.2f} ns ({r['worst']})"
                )
                if "receivers" in r:
                    line += "; receivers " + ", ".join(
                        f"{k} {v:+.2f}" for k, v in r["receivers"]["difference_ns"].items()
                    )
                if r.get("receivers_not_in_product"):
                    line += "; no receiver DSB in the product for " + " ".join(r["receivers_not_in_product"])
                print(line)
                ch = r.get("glonass_channels") if label == "central" else None
                if ch:
                    print(
                        f"  GLONASS channels: one mean per channel ({ch['channels']} channels) "
                        f"{ch['channel_means_rms_ns']:.2f} ns RMS, within channels {ch['within_channel_rms_ns']:.2f} "
                        "ns (the receivers' per-channel inter-frequency biases go into their satellites' DSBs)"
                    )
            elif label in comp:
                print(f"  {label:<12} {r.get('note', 'no comparison')}")
        print_worst_vs_product(pname, comp.get("central", {}))


def print_worst_vs_product(pname: str, r: Mapping[str, Any], *, exclude_option: str = "--compare-exclude") -> None:
    """``worst-fitting satellite vs PRODUCT: G01 (+1.52 ns, 5.1× the RMS 0.30 ns of the other 29: it stands
    out ...)`` from a :func:`~distnav.models.gnss.products.compare_in_datum` result."""
    w = r.get("worst_fitting")
    if not w:
        return
    short = pname.split()[0]
    verdict = (
        f"it stands out (> {w['critical_ratio']:.2f}×, the {100 * w['level']:g} % outlier limit for "
        f"{w['n']} satellites); {exclude_option} {w['satellite']} leaves it out of the statistics"
        if w["stands_out"]
        else f"within the {100 * w['level']:g} % outlier limit {w['critical_ratio']:.2f}× for {w['n']} satellites"
    )
    print(
        f"worst-fitting satellite vs {short}: {w['satellite']} ({w['difference_ns']:+.2f} ns, "
        f"{w['ratio_to_rms_others']:.2f}× the RMS {w['rms_others_ns']:.2f} ns of the other {w['n'] - 1}: "
        f"{verdict})"
    )


def print_worst_own(fit: Mapping[str, Any]) -> None:
    """The worst-fitting satellite from the satellites' own residuals (no product needed)."""
    wf = fit.get("worst_fitting")
    if wf is None:
        return
    ratio = wf["ratio_to_median"] or float("nan")
    z = wf.get("robust_z")
    tail = (
        f"it stands out, e.g. an elevation-dependent code bias as SVN49's; --compare-exclude {wf['satellite']} "
        "leaves it out of the comparison"
        if wf.get("stands_out")
        else "none stands out"
    )
    zs = f", {z:.1f} robust σ above them" if z is not None else ""
    print(
        f"worst-fitting satellite: {wf['satellite']} (own residuals: {fit['statistic']} {wf['value']:.3f}, "
        f"{ratio:.2f}× the median satellite{zs}: {tail})"
    )


def print_data_report(summary: Mapping[str, Any]) -> None:
    """What each station's levelling and screening did (arcs, slips by detector, short arcs dropped, the w-test
    removals and the satellites most affected), the CKF's innovation-test rejections and the remaining notes
    (exclusions, satellites not estimated, the ionosphere choice) — the report of what was removed."""
    arcs, scr = summary.get("arcs") or {}, summary.get("screening") or {}
    for sta, a in arcs.items():
        starts = ", ".join(f"{k} {v}" for k, v in sorted(a["starts"].items()) if k != "first")
        s = scr.get(sta, {})
        top = sorted((s.get("removed_per_satellite") or {}).items(), key=lambda kv: (-kv[1], kv[0]))[:3]
        most = f" (most removed: {', '.join(f'{k} {v}' for k, v in top)})" if top else ""
        if s.get("most_removed_epoch"):
            ep = s["most_removed_epoch"]
            most += (
                f"; removals at {s['epochs_with_removals']} epochs, most at {ep} ({' '.join(s['removed_epochs'][ep])})"
            )
        raw = (
            f"; {a['raw_code_observations']} raw (unlevelled) code observations used where no arc was long enough"
            if a.get("raw_code_observations")
            else ""
        )
        mw = (
            f", {s['removed_mw_outliers']} code outliers at the Melbourne–Wübbena test"
            if s.get("removed_mw_outliers")
            else ""
        )
        wt = (
            f"w-test removed {s.get('removed_w_test', s.get('removed', 0))} of {s.get('w_tested', 0)} levelled "
            f"code observations"
            if s.get("w_tested")
            else "no w-test screening"
        )
        print(
            f"{sta}: {a['arcs']} levelled arcs, median {a['median_epochs']:.0f} epochs (new arcs: "
            f"{starts or 'none'}; {a['dropped_short']} short arcs dropped{raw}); {wt}{mw}{most}"
        )
    if tests := summary.get("ckf_innovation_tests"):
        per = ", ".join(f"{k} {v['removed']} of {v['tested']}" for k, v in tests["per_station"].items())
        print(
            f"CKF innovation test at {tests['level']:g} (|w| > {tests['critical_value']:.2f}), each receiver on its "
            f"own predicted residuals: rejected {per}"
        )
    for note in summary.get("notes") or []:
        if ": levelled " not in note:
            print(f"note: {note}")


def worst_over_days(result: dict[str, Any], summaries: Mapping[str, Mapping[str, Any]]) -> None:
    """The worst-fitting satellite over several days, from the satellites' own residuals and from each product
    comparison (the satellite named most often; ``result["worst_fitting"]``, ``["worst_fitting_vs_product"]``)."""
    wf = {d: (s.get("satellite_fit") or {}).get("worst_fitting") for d, s in summaries.items()}
    names = [w["satellite"] for w in wf.values() if w]
    if names:
        top = max(sorted(set(names)), key=names.count)
        out_own = sum(bool(w.get("stands_out")) for w in wf.values() if w and w["satellite"] == top)
        result["worst_fitting"] = {
            "satellite": top,
            "days": names.count(top),
            "stands_out_days": out_own,
            "per_day": wf,
        }
        print(
            f"worst-fitting satellite over the days (own residuals): {top} ({names.count(top)} of "
            f"{len(summaries)} days, standing out on {out_own})"
        )
    vs: dict[str, list[tuple[str, bool]]] = {}
    for s in summaries.values():
        for pname, comp in (s.get("comparison") or {}).items():
            if w := (comp.get("central") or {}).get("worst_fitting"):
                vs.setdefault(pname.split()[0], []).append((w["satellite"], bool(w["stands_out"])))
    for pname, hits in vs.items():
        names_p = [h[0] for h in hits]
        top = max(sorted(set(names_p)), key=names_p.count)
        out_n = sum(h[1] for h in hits if h[0] == top)
        result.setdefault("worst_fitting_vs_product", {})[pname] = {
            "satellite": top,
            "days": names_p.count(top),
            "stands_out_days": out_n,
        }
        print(
            f"worst-fitting satellite vs {pname} over the days: {top} ({names_p.count(top)} of {len(hits)} days, "
            f"standing out on {out_n})"
        )
