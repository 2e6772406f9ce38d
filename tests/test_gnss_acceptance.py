"""Issue 14 acceptance audit: the gaps found running every Deliver item through the command line — the
worst-fitting satellite from a product comparison (and from the satellites' own residuals, with a robust
"stands out" test), the L1 code matched to a product that has only C1W DSBs (GFZ), and the comparison saying
when a product lacks the code pair or a receiver."""

from __future__ import annotations

import argparse
import json
import warnings
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from distnav.cli import main
from distnav.commands.gnss_report import choose_l1_code
from distnav.models.gnss.gfnetwork import SatelliteFit
from distnav.models.gnss.products import ProductDSB, compare_in_datum, worst_satellite

IGS = "gnss/igs_2024010_bele_dgar"
CAS = "CAS0OPSRAP_20240100000_01D_01D_DCB.BIA.gz"
GFZ = "GFZ0OPSRAP_20240100000_01D_01D_DCB.BIA.gz"


def test_worst_satellite_against_the_bonferroni_normal_limit() -> None:
    others = {f"G{k:02d}": (-1.0) ** k * 0.5 for k in range(2, 21)}  # 19 satellites, RMS 0.5 ns
    n = len(others) + 1
    k = stats.norm.ppf(1.0 - 0.05 / (2 * n))  # independent quantile: scipy
    for d, out in ((2.0, True), (1.2, False)):  # 4× and 2.4× the others' RMS
        w = worst_satellite({**others, "G01": d})
        assert w is not None and w["satellite"] == "G01" and w["n"] == n
        assert w["rms_others_ns"] == pytest.approx(0.5)
        assert w["ratio_to_rms_others"] == pytest.approx(d / 0.5)
        assert w["critical_ratio"] == pytest.approx(k, rel=1e-9)
        assert w["stands_out"] is out
    assert worst_satellite({"G01": 1.0, "G02": -1.0}) is None  # too few to say


def test_comparison_names_a_missing_pair_and_missing_receivers() -> None:
    empty = ProductDSB("GFZ", Path("GFZ.BIA"), "sinex", {}, {}, pair="C1C-C2W")
    r = compare_in_datum({"G01": 1.0}, {}, empty)
    assert r["n"] == 0 and "has no C1C-C2W satellite DSB" in r["note"]
    prod = ProductDSB(
        "CAS", Path("CAS.BIA"), "sinex", {"G01": 1.0, "G02": 2.0, "G03": -3.0}, {"BELE": 0.5}, pair="C1C-C2W"
    )
    r = compare_in_datum({"G01": 1.1, "G02": 1.9, "G03": -3.0}, {"BELE": 0.4, "DGAR": 1.0}, prod)
    assert r["receivers_not_in_product"] == ["DGAR"] and set(r["receivers"]["difference_ns"]) == {"BELE"}
    d = r["difference_ns"]
    assert r["worst_fitting"]["satellite"] == max(d, key=lambda s: abs(d[s]))


def test_satellite_fit_robust_z() -> None:
    code = np.array([0.30, 0.31, 0.29, 0.32, 0.30, 0.28, 0.31, 0.45])  # the last: SVN49-like
    fit = SatelliteFit(
        tuple(f"G{k:02d}" for k in range(1, 9)),
        np.zeros(8),
        np.zeros(8),
        np.full(8, 100),
        code_rms_m=code,
        code_n=np.full(8, 100),
    )
    med = np.median(code)
    mad = 1.4826 * np.median(np.abs(code - med))  # by hand
    w = fit.as_dict()["worst_fitting"]
    assert w["satellite"] == "G08" and w["robust_z"] == pytest.approx((0.45 - med) / mad)
    assert w["stands_out"] and w["ratio_to_median"] == pytest.approx(0.45 / med)
    mild = code.copy()
    mild[-1] = 0.35  # 1.17× the median: not flagged
    w = SatelliteFit(fit.svs, fit.rms_m, fit.rms_w, fit.n, code_rms_m=mild, code_n=fit.code_n).as_dict()
    assert w["worst_fitting"]["satellite"] == "G08" and not w["worst_fitting"]["stands_out"]


def test_satellite_fit_without_any_levelled_arc_warns_nothing() -> None:
    """With no arc long enough to level (``--min-arc`` above every arc) every code RMS is NaN: the fit's median is
    NaN and no numpy "All-NaN slice" warning reaches the console."""
    nan = np.full(3, np.nan)
    fit = SatelliteFit(
        ("G01", "G02", "G03"), np.ones(3), np.ones(3), np.full(3, 50), code_rms_m=nan, code_n=np.zeros(3)
    )
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        d = fit.as_dict()
    assert np.isnan(d["median"])


def _ns(bias: list[str] | None, l1: str | None = None) -> argparse.Namespace:
    return argparse.Namespace(l1_code=l1, l2_code="C2W", bias=bias)


def test_an_unreadable_product_is_named_not_taken_for_ionex(tmp_path: Path) -> None:
    """A --bias file that is neither Bias-SINEX nor IONEX must not switch the L1 code (it was taken for IONEX)."""
    from distnav.errors import DataFileError

    bad = tmp_path / "garbage.BIA"
    bad.write_text("this is not a bias product\n")
    with pytest.raises(DataFileError, match="garbage.BIA"):
        choose_l1_code(_ns([str(bad)]))


def test_l1_code_follows_the_products(shared_data: Path) -> None:
    d = shared_data / IGS
    cas, gfz = str(d / CAS), str(d / GFZ)
    assert choose_l1_code(_ns(None)) == ("C1C", None)
    assert choose_l1_code(_ns([cas])) == ("C1C", None)
    assert choose_l1_code(_ns([gfz, cas])) == ("C1C", None)  # GFZ C1W-C2W chained with CAS C1C-C1W
    code, note = choose_l1_code(_ns([gfz]))  # GFZ alone: only C1W-C2W
    assert code == "C1W" and note is not None and "GFZ" in note
    assert choose_l1_code(_ns([gfz], "c1c")) == ("C1C", None)  # given: kept


def test_cli_worst_fitting_vs_product_and_gfz_on_c1w(
    shared_data: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    d = shared_data / IGS
    common = [
        "gnss",
        "ionosphere",
        "--obs",
        str(d / "dgar0100.24o.gz"),
        "--nav",
        str(d / "brdc0100.24n.gz"),
        "--tlim",
        "2024-01-10T06:00",
        "2024-01-10T08:00",
        "--interval",
        "60",
        "--no-progress",
    ]
    assert main([*common, "--bias", str(d / CAS), "--out", str(tmp_path / "cas")]) == 0
    text = capsys.readouterr().out
    s = json.loads((tmp_path / "cas" / "summary.json").read_text())
    ((name, comp),) = s["comparison"].items()
    diff = comp["central"]["difference_ns"]
    worst = max(diff, key=lambda k: abs(diff[k]))
    assert comp["central"]["worst_fitting"]["satellite"] == worst
    assert f"worst-fitting satellite vs CAS: {worst} ({diff[worst]:+.2f} ns" in text
    assert "worst-fitting satellite: " in text and "own residuals" in text
    assert "realistic: formal ×" in text
    assert main(["gnss", "compare", "--estimates", str(tmp_path / "cas"), "--bias", str(d / CAS)]) == 0
    text = capsys.readouterr().out
    assert f"worst-fitting satellite vs CAS: {worst}" in text and "--compare-exclude" not in text
    # GFZ alone gives C1W-C2W only: the default L1 code follows it (DGAR tracks P1), and the run is compared
    assert main([*common, "--bias", str(d / GFZ), "--out", str(tmp_path / "gfz")]) == 0
    err = capsys.readouterr().err
    assert "--l1-code C1W chosen to match the products" in err and "WARNING: L1 code C1C" not in err
    s = json.loads((tmp_path / "gfz" / "summary.json").read_text())
    assert s["codes"]["L1"] == "C1W"
    (comp,) = s["comparison"].values()
    assert comp["central"]["n"] >= 8 and "DGAR" in comp["central"]["receivers"]["difference_ns"]


def _two_satellites(T: int = 40) -> tuple[np.ndarray, list[np.ndarray]]:
    """Noise-free codes and phases (metres) of two satellites with the same range and ionosphere, 30 s."""
    from distnav.models.gnss.constants import C_M_S, GPS_FREQUENCIES_HZ
    from distnav.models.gnss.observables import mu

    t = 30.0 * np.arange(T)
    rho, iono = 2.2e7 + 100.0 * t / 30.0, 3.0 + 0.001 * t
    p1, p2 = rho + iono, rho + mu(2) * iono
    phi1 = rho - iono + 1.0e6 * C_M_S / GPS_FREQUENCIES_HZ[1]
    phi2 = rho - mu(2) * iono + 1.1e6 * C_M_S / GPS_FREQUENCIES_HZ[2]
    return t, [np.stack([x, x], axis=1) for x in (p1, p2, phi1, phi2)]


def test_screening_report_tells_the_w_test_from_the_slip_detector() -> None:
    from distnav.models.gnss.levelling import LevellingOptions, level_station

    t, cols = _two_satellites(60)
    cols[0][30, 0] += 15.0  # one wild code value: an MW outlier, not a slip
    off = level_station(t, ("G01", "G02"), *cols, options=LevellingOptions(screen=False)).screening_summary(
        ["G01", "G02"]
    )
    assert off["removed"] == 1 and off["removed_mw_outliers"] == 1
    assert off["removed_w_test"] == 0 and off["w_tested"] == 0
    on = level_station(t, ("G01", "G02"), *cols, options=LevellingOptions(screen=True)).screening_summary(
        ["G01", "G02"]
    )
    assert on["removed_mw_outliers"] == 1 and on["w_tested"] == 2 * 60 - 1  # every other code value w-tested
    assert on["removed"] == on["removed_w_test"] + 1
    # with the epochs of the rows the report names the epoch of the wild value (issue 32: epochs, not only satellites)
    times = np.datetime64("2024-01-10T00:00:00") + (t * 1e9).astype("timedelta64[ns]")
    named = level_station(t, ("G01", "G02"), *cols, options=LevellingOptions(screen=False)).screening_summary(
        ["G01", "G02"], times
    )
    assert named["removed_epochs"] == {"2024-01-10T00:15:00": ["G01"]}
    assert named["epochs_with_removals"] == 1 and named["most_removed_epoch"] == "2024-01-10T00:15:00"


def test_raw_code_kept_where_no_arc_is_long_enough_is_counted() -> None:
    from distnav.models.gnss.levelling import LevellingOptions, level_station

    t, cols = _two_satellites()
    for c in cols:
        c[6:, 1] = np.nan  # G02: 6 epochs, shorter than the 10 kept
    for fallback, raw in ((True, 6), (False, 0)):
        lev = level_station(t, ("G01", "G02"), *cols, options=LevellingOptions(screen=False, fallback_raw=fallback))
        a = lev.arc_summary()
        assert a["arcs"] == 1 and a["dropped_short"] == 1 and a["raw_code_observations"] == raw


def test_every_removal_is_counted_on_its_arc() -> None:
    """Issue 32 item 6: per arc, the w-test removals, the one-epoch MW outliers in its span and a short arc dropped
    whole (its epochs), as arcs.csv lists them; the counts add up to the station's totals."""
    from distnav.models.gnss.levelling import LevellingOptions, level_station

    t, cols = _two_satellites(60)
    cols[0][30, 0] += 15.0  # G01: one wild code value inside its arc (an MW outlier)
    for c in cols:
        c[6:, 1] = np.nan  # G02: 6 epochs, an arc dropped as shorter than 10
    lev = level_station(t, ("G01", "G02"), *cols, options=LevellingOptions(screen=True))
    (g01,) = lev.arcs
    (g02,) = lev.short_arcs or []
    assert (g01.sv, g01.removed_mw, g01.dropped_short) == ("G01", 1, 0)
    assert (g02.sv, g02.n_epochs, g02.dropped_short, g02.removed) == ("G02", 6, 6, 0) and np.isnan(g02.offset_m)
    report = lev.screening_summary(["G01", "G02"])
    assert g01.removed + g01.removed_mw == report["removed"]
    assert lev.arc_summary()["dropped_short"] == 1


def test_console_names_a_ckf_node_without_estimates_and_prints_realistic_sigma(
    capsys: pytest.CaptureFixture[str],
) -> None:
    from distnav.commands.gnss_report import print_summary

    nan = float("nan")
    finals = {
        "central": (
            {"rx:A": 1.0, "rx:B": -1.0, "G01": 0.5, "G02": -0.5},
            {"rx:A": 0.1, "rx:B": 0.2, "G01": 0.1, "G02": 0.3},
        ),
        "ckf:A": (
            {"rx:A": 1.0, "rx:B": -1.0, "G01": 0.5, "G02": -0.5},
            {"rx:A": 0.1, "rx:B": 0.2, "G01": 0.1, "G02": 0.3},
        ),
        "ckf:B": ({"rx:A": nan, "rx:B": nan, "G01": nan, "G02": nan}, {k: nan for k in ("rx:A", "rx:B", "G01", "G02")}),
    }
    print_summary(["A", "B"], {}, finals, 3.0)
    out = capsys.readouterr().out
    assert "median σ 0.60 ns (realistic: formal × 3.00)" in out  # median(0.1, 0.3) × 3
    assert "A +1.00 ± 0.30, B -1.00 ± 0.60" in out
    assert "note: ckf:B has no final DSB estimate" in out and "note: ckf:A" not in out
