"""`distnav gnss ionosphere` on real RINEX: outputs, datum, CKF = central, products, option validation."""

from __future__ import annotations

import argparse
import csv
import json
from pathlib import Path

import numpy as np
import pytest

from distnav.cli import main
from distnav.formats.gnss.bias_sinex import read_bias_sinex

IGS = "gnss/igs_2024010_bele_dgar"


def _parser() -> argparse.ArgumentParser:
    from distnav.commands.gnss_ionosphere import add_ionosphere_parser

    ap = argparse.ArgumentParser(prog="distnav gnss")
    add_ionosphere_parser(ap.add_subparsers())
    return ap


def _nl(shared_data: Path) -> tuple[Path, list[str]]:
    d = shared_data / "gnss" / "nl_2021001_short_network_snapshot"
    obs = [str(d / f) for f in ("delf0010.21o", "eijs0010.21d", "wsra0010.21o", "zegv0010.21o", "rovn0010.21o")]
    return d, obs


def test_dutch_network_ckf_equals_central(shared_data: Path, tmp_path: Path) -> None:
    d, obs = _nl(shared_data)
    edges = tmp_path / "edges.csv"
    edges.write_text("a,b\nDELF,EIJS\nEIJS,ZEGV\nZEGV,WSRA\nWSRA,ROVN\n")  # a path: 4 hops end to end
    args = _parser().parse_args(
        [
            "ionosphere",
            "--obs",
            *obs,
            "--nav",
            str(d / "cbw10010.21n.gz"),
            "--nav-max-age",
            "24",
            "--kn",
            "60",
            "--graph",
            str(edges),
            "--out",
            str(tmp_path),
            "--no-progress",
            "--tec-rw",
            "0.001",
        ]
    )
    # 52 minutes of data: paper 003's stiff random walk; the default 0.01 m/√s (made for full days) leaves
    # ν_o ± 0.6 m after 52 minutes, not enough to tell night-time TEC from the receiver biases
    assert args.func(args) == 0
    s = json.loads((tmp_path / "summary.json").read_text())
    assert sorted(map(sorted, s["graph_links"])) == [
        ["DELF", "EIJS"],
        ["EIJS", "ZEGV"],
        ["ROVN", "WSRA"],
        ["WSRA", "ZEGV"],
    ]
    assert s["stations"] == ["DELF", "EIJS", "WSRA", "ZEGV", "ROVN"]
    assert s["datum"] == "zero-mean" and s["ionosphere"] == "common" and s["codes"] == {"L1": "C1C", "L2": "C2W"}
    v = s["final_tec_m"]["central"]["vtec_m"]
    assert 0.0 < v[0] < 3.0  # night-time winter TEC over the Netherlands: a few TECU (0.16 m/TECU)
    for sta in s["stations"]:
        np.testing.assert_allclose(s["final_tec_m"][f"ckf:{sta}"]["vtec_m"][0], v[0], rtol=1e-4)
        for k, x in s["final_dsb_ns"]["central"].items():
            if np.isfinite(x):
                assert s["final_dsb_ns"][f"ckf:{sta}"][k] == pytest.approx(x, abs=1e-3)
    sats = [x for k, x in s["final_dsb_ns"]["central"].items() if not k.startswith("rx:") and np.isfinite(x)]
    assert abs(np.mean(sats)) < 1e-6  # zero-mean datum
    with (tmp_path / "dcb_final.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == len(s["stations"]) + len(s["satellites"]) and rows[0]["object"] == "rx:DELF"


def test_bele_dgar_receivers_and_satellites_against_cas(shared_data: Path, tmp_path: Path) -> None:
    d = shared_data / IGS
    args = _parser().parse_args(
        [
            "ionosphere",
            "--obs",
            str(d / "BELE00BRA_R_20240100000_01D_30S_MO.crx.gz"),
            str(d / "dgar0100.24o.gz"),
            "--nav",
            str(d / "BRDC00IGS_R_20240100000_01D_MN.rnx.gz"),
            "--tlim",
            "2024-01-10T00:00",
            "2024-01-10T03:00",
            "--interval",
            "120",
            "--bias",
            str(d / "CAS0OPSRAP_20240100000_01D_01D_DCB.BIA.gz"),
            "--out",
            str(tmp_path),
            "--no-progress",
        ]
    )
    assert args.func(args) == 0
    s = json.loads((tmp_path / "summary.json").read_text())
    assert s["ionosphere"] == "per-receiver" and s["graph_links"] == [["BELE", "DGAR"]]
    comp = next(iter(s["comparison"].values()))["central"]
    assert comp["n"] >= 15 and set(comp["receivers"]["difference_ns"]) == {"BELE", "DGAR"}
    ref = np.array([comp["reference_ns"][k] for k in comp["difference_ns"]])
    est = ref + np.array(list(comp["difference_ns"].values()))
    assert np.corrcoef(ref, est)[0, 1] > 0.6  # three hours of code: the DCBs follow CAS's (spread ≈ 5 ns)
    # no pivot to wait for: the receivers and every satellite tracked at the start are estimable from the second
    # epoch (at the first, one epoch of per-receiver ionospheres and biases is rank deficient)
    first = s["first_estimable_epoch"]
    assert first["rx:BELE"] == first["rx:DGAR"] == "2024-01-10T00:02:00"
    assert sum(v == "2024-01-10T00:02:00" for v in first.values()) >= 15


def test_pivot_datum_and_day_check(shared_data: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    d = shared_data / IGS
    common = [
        "gnss",
        "ionosphere",
        "--obs",
        str(d / "dgar0100.24o.gz"),
        "--nav",
        str(d / "brdc0100.24n.gz"),
        "--tlim",
        "2024-01-10T00:00",
        "2024-01-10T00:30",
        "--no-progress",
    ]
    assert main([*common, "--datum", "pivot", "--pivot", "G10", "--out", str(tmp_path / "p")]) == 0
    s = json.loads((tmp_path / "p" / "summary.json").read_text())
    assert s["final_dsb_ns"]["central"]["G10"] == pytest.approx(0.0, abs=1e-9)
    assert main([*common, "--datum", "pivot", "--pivot", "G30", "--out", str(tmp_path / "q")]) == 2
    assert "--pivot G30: not tracked" in capsys.readouterr().err
    other = d / "CAS0OPSRAP_20240110000_01D_01D_DCB.BIA.gz"
    assert main([*common, "--bias", str(other), "--out", str(tmp_path / "r")]) == 2
    assert "a product of 2024-01-11" in capsys.readouterr().err
    assert main([*common, "--bias", str(other), "--allow-other-day", "--out", str(tmp_path / "r")]) == 0


def test_datum_satellites_from_a_product(shared_data: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``--datum-satellites PRODUCT``: the datum is stated (console, summary, Bias-SINEX), the estimates are in the
    product's datum (mean over the present members = the product's mean over them), SVNs come from the product."""
    d = shared_data / IGS
    cas = d / "CAS0OPSRAP_20240100000_01D_01D_DCB.BIA.gz"
    argv = ["gnss", "ionosphere", "--obs", str(d / "dgar0100.24o.gz"), "--nav", str(d / "brdc0100.24n.gz")]
    argv += ["--tlim", "2024-01-10T00:00", "2024-01-10T00:30", "--no-progress", "--l1-code", "C1W"]
    assert main([*argv, "--datum-satellites", str(cas), "--out", str(tmp_path / "f")]) == 0
    out = capsys.readouterr().out
    s = json.loads((tmp_path / "f" / "summary.json").read_text())
    assert "datum: zero mean over the fixed set of" in out and "aligned to CAS" in out
    assert s["datum_statement"] in out and "missing" in s["datum_statement"]  # 30 min: most members not up
    members = s["datum_satellites"]
    prod = read_bias_sinex(cas)
    final = s["final_dsb_ns"]["central"]
    here = [m for m in members if np.isfinite(final.get(m, np.nan))]
    assert 3 <= len(here) < len(members)
    ref = [prod.satellite_dsb_ns(m, "C1W", "C2W") for m in here]
    assert np.mean([final[m] for m in here]) == pytest.approx(np.mean(ref), abs=1e-6)
    bia = (tmp_path / "f" / "distnav_dsb.bia").read_text()
    assert " DSB  G063 G01 " in bia or "G01" not in here
    assert "aligned to CAS" in " ".join(bia.split())
    assert " 0.0000\n" not in bia  # no σ = 0
    assert main([*argv, "--out", str(tmp_path / "z")]) == 0  # the default datum says what it runs over
    assert "datum: zero mean over the " in capsys.readouterr().out


@pytest.mark.parametrize(
    "option,message",
    [
        (["--pivot", "hello"], "--pivot hello: not a GPS satellite"),
        (["--pivot", "G99"], "--pivot G99: not a GPS satellite"),
        (["--sigma", "0"], "--sigma 0: must be a positive number"),
        (["--interval", "0"], "--interval 0: must be a positive number"),
        (["--tlim", "2024-01-10T03:00", "2024-01-10T01:00"], "the start must be before the stop"),
        (["--tlim", "yesterday", "2024-01-10T01:00"], "argument --tlim: expected an ISO date and time"),
        (["--l2-code", "C9X"], "--l2-code C9X: not a GPS L2 or L5 code"),
        (["--l1-code", "C2W"], "--l1-code C2W: not a GPS L1 code"),
        (["--exclude", "G1"], "--exclude G1: neither"),
        (["--mask", "95"], "--mask 95"),
        (["--datum-satellites", "G01,G99"], "--datum-satellites: G99 not GPS satellites"),
        (["--datum-satellites", "G01"], "at least two satellites"),
        (["--datum-satellites", "nofile.bia"], "neither a list of satellites"),
        (["--datum", "receiver", "--datum-satellites", "G01,G02"], "fixes the set of the zero-mean datum"),
    ],
)
def test_options_validated_before_reading(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], option: list[str], message: str
) -> None:
    argv = ["gnss", "ionosphere", "--obs", str(tmp_path / "absent.24o"), "--nav", str(tmp_path / "absent.nav")]
    try:
        rc = main([*argv, *option, "--out", str(tmp_path / "o")])
    except SystemExit as exc:  # refused by the parser (--tlim's type)
        rc = exc.code
    assert rc == 2
    err = capsys.readouterr().err
    assert message in err and "absent" not in err  # failed on the option, not on the (missing) files


def test_l5_code_and_c1c_warning(shared_data: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    d = shared_data / IGS
    rc = main(
        [
            "gnss",
            "ionosphere",
            "--obs",
            str(d / "dgar0100.24o.gz"),
            "--nav",
            str(d / "brdc0100.24n.gz"),
            "--tlim",
            "2024-01-10T00:00",
            "2024-01-10T00:30",
            "--l2-code",
            "C5Q",
            "--out",
            str(tmp_path),
        ]
    )
    assert rc == 0
    err = capsys.readouterr().err
    assert "WARNING: L1 code C1C" in err and "reading DGAR:" in err
    s = json.loads((tmp_path / "summary.json").read_text())
    assert s["band"] == 5 and s["codes"] == {"L1": "C1C", "L5": "C5Q"}
    vals = [v for k, v in s["final_dsb_ns"]["central"].items() if not k.startswith("rx:")]
    assert len(vals) >= 5 and all(np.isfinite(vals))  # L5 satellites only, no NaN
    assert all(abs(v) < 60 for v in vals)


def test_single_station_with_sp3(shared_data: Path, tmp_path: Path) -> None:
    d = shared_data / "gnss" / "esbc_2020177_single_station_L5_sp3"
    args = _parser().parse_args(
        [
            "ionosphere",
            "--obs",
            str(d / "ESBC00DNK_R_20201770000_01D_30S_MO.crx.gz"),
            "--sp3",
            str(d / "GRG0MGXFIN_20201770000_01D_15M_ORB.SP3.gz"),
            "--tlim",
            "2020-06-25T10:00",
            "2020-06-25T10:20",
            "--out",
            str(tmp_path),
            "--no-progress",
        ]
    )
    assert args.func(args) == 0
    s = json.loads((tmp_path / "summary.json").read_text())
    assert s["stations"] == ["ESBC"] and s["epochs"] == 41
    v, sd = s["final_tec_m"]["central"]["vtec_m"]
    assert 0.0 < v < 5.0 and sd > 0
    assert s["final_tec_m"]["ckf:ESBC"]["vtec_m"][0] == pytest.approx(v, rel=1e-9)
    assert s["final_tec_m"]["local:ESBC"]["vtec_m"][0] == pytest.approx(v, rel=1e-9)


def test_errors_name_the_file(shared_data: Path, tmp_path: Path) -> None:
    from distnav.commands.gnss_ionosphere import NetworkOptions, network_data
    from distnav.errors import DataFileError
    from distnav.formats.gnss.rinex import read_navigation

    d, obs = _nl(shared_data)
    nav = read_navigation(d / "cbw10010.21n.gz", max_age_s=24 * 3600.0)
    with pytest.raises(DataFileError, match="delf0010.21o: no L2 code observation"):
        network_data(obs[:1], nav, NetworkOptions(l2_code="C2L"))
    bad = tmp_path / "junk0010.21o"
    bad.write_text("this is not RINEX\n")
    with pytest.raises(DataFileError, match="junk0010.21o"):
        network_data([str(bad)], nav)
    with pytest.raises(DataFileError, match="station DELF is given twice"):
        network_data([obs[0], obs[0]], nav)
    bele_nav = read_navigation(shared_data / IGS / "brdc0100.24n.gz")
    with pytest.raises(DataFileError, match="a navigation file of 2024-01-10 .* delf0010.21o observes 2021-01-01"):
        network_data(obs[:1], bele_nav)  # another day's orbits: named (issue 29), not left to the mask


def test_c1_corrections_from_a_product(shared_data: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from distnav.formats.gnss.bias_sinex import read_bias_sinex
    from distnav.formats.gnss.product_files import correct_c1
    from distnav.formats.gnss.rinex import read_code_observations

    d = shared_data / IGS
    cas = d / "CAS0OPSRAP_20240100000_01D_01D_DCB.BIA.gz"
    o = read_code_observations(d / "dgar0100.24o.gz", bands=(1, 2), tlim=("2024-01-10T06:00", "2024-01-10T06:10"))
    c = correct_c1(o, cas)
    assert c.codes[1] == "C1W" and "C1C corrected to C1W" in c.notes[-1]
    k = o.svs.index("G01")
    dsb = read_bias_sinex(cas).satellite_dsb_ns("G01", "C1C", "C1W")  # CAS: −0.903 ns
    assert dsb == pytest.approx(-0.903)
    np.testing.assert_allclose(o.range_m[1][:, k] - c.range_m[1][:, k], 0.299792458 * dsb, atol=1e-6)
    rc = main(
        [
            "gnss",
            "ionosphere",
            "--obs",
            str(d / "dgar0100.24o.gz"),
            "--nav",
            str(d / "brdc0100.24n.gz"),
            "--tlim",
            "2024-01-10T06:00",
            "2024-01-10T06:30",
            "--c1-corrections",
            str(cas),
            "--out",
            str(tmp_path),
            "--no-progress",
        ]
    )
    assert rc == 0
    assert "WARNING: L1 code C1C" not in capsys.readouterr().err
    assert (
        main(
            [
                "gnss",
                "ionosphere",
                "--obs",
                str(d / "dgar0100.24o.gz"),
                "--nav",
                str(d / "brdc0100.24n.gz"),
                "--l1-code",
                "C1W",
                "--c1-corrections",
                str(cas),
                "--out",
                str(tmp_path),
            ]
        )
        == 2
    )


@pytest.mark.parametrize(
    ("system", "codes"), [("G", (None, "C2W")), ("E", ("C1X", "C5X")), ("C", ("C2I", "C6I")), ("R", ("C1C", "C2C"))]
)
def test_each_system_has_default_codes_that_pass_its_own_check(
    system: str, codes: tuple[str | None, str], tmp_path: Path
) -> None:
    """`gnss ionosphere --system S` without --l1-code/--l2-code takes the system's usual pair (GPS keeps its
    product-driven choice of the first code) and they pass the system's own code check."""
    from distnav.cli import build_parser
    from distnav.commands.gnss_ionosphere import validate_arguments

    obs, nav = tmp_path / "a.rnx", tmp_path / "b.rnx"
    obs.touch()
    nav.touch()
    words = [
        "gnss",
        "ionosphere",
        "--obs",
        str(obs),
        "--nav",
        str(nav),
        "--out",
        str(tmp_path / "o"),
        "--system",
        system,
    ]
    args = build_parser(words).parse_args(words)
    validate_arguments(args)
    assert (args.l1_code, args.l2_code) == codes
    given = build_parser(words).parse_args([*words, "--l2-code", "C7I" if system == "C" else codes[1]])
    validate_arguments(given)
    assert given.l2_code == ("C7I" if system == "C" else codes[1])
