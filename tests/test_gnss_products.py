"""Bias-SINEX out (read back by the project's reader and an independent parser), IONEX DCB blocks in,
`gnss compare` on ionosphere outputs with datum alignment and the day check."""

from __future__ import annotations

import gzip
import json
from pathlib import Path

import numpy as np
import pytest

from distnav.cli import main
from distnav.formats.gnss.bias_sinex import BiasSinexHeader, read_bias_sinex, sinex_time, write_bias_sinex
from distnav.formats.gnss.product_files import product_day, product_dsbs
from distnav.models.gnss.products import ProductDSB, compare_in_datum

SATS = {"G01": (-7.1874, 0.0123), "G05": (2.5, 0.02), "G32": (-0.0004, 0.3)}
STAS = {"BELE": (0.019, 0.15), "DGAR": (3.521, 0.0735)}


svn: dict[str, str] = {}  # the SVN field of each satellite line of the last parse


def _independent_parse(text: str) -> tuple[list[str], dict[str, tuple[float, float]], dict[str, tuple[float, float]]]:
    """A second parser: whitespace tokens only (10 = satellite line, 11 = station line), blocks by their labels."""
    lines = text.splitlines()
    head = lines[0].split()
    inside, sat, sta = False, {}, {}
    svn.clear()
    blocks = [ln[1:].strip() for ln in lines if ln[:1] == "+"]
    for ln in lines:
        if ln.startswith("+BIAS/SOLUTION"):
            inside = True
        elif ln.startswith("-BIAS/SOLUTION"):
            inside = False
        elif inside and not ln.startswith("*"):
            tok = ln.split()
            if len(tok) == 10:
                sat[tok[2]] = (float(tok[8]), float(tok[9]))
                svn[tok[2]] = tok[1]
            elif len(tok) == 11:
                assert tok[1] == tok[2] == "G", ln  # a station's GPS bias: system letter in SVN and PRN
                sta[tok[3]] = (float(tok[9]), float(tok[10]))
            else:
                raise AssertionError(f"unexpected line {ln!r}")
    return head + blocks, sat, sta


def test_bias_sinex_no_zero_sigma_svns_comments_session(tmp_path: Path) -> None:
    """Issue 32: a bias without σ is left out (never σ = 0) and named; SVNs from the given table in the format's
    ANNN field (the system letter and a note where unknown); comments wrapped at word boundaries, none cut; the
    header's OUTPUT line says a 6-h session is 6-hour, not daily."""
    long = "the datum is zero mean over the fixed set of satellites " + " ".join(f"G{k:02d}" for k in range(1, 33))
    text = write_bias_sinex(
        None,
        obs1="C1C",
        obs2="C2W",
        start="2024-01-10T06:00",
        end="2024-01-10T12:00",
        satellites={**SATS, "G07": (1.0, float("nan"))},
        stations=STAS,
        svns={"G01": "G063", "G05": "G050"},
        header=BiasSinexHeader(comments=[long]),
    )
    assert isinstance(text, str)
    _, sat, _ = _independent_parse(text)
    assert "G07" not in sat and all(sd > 0 for _, sd in sat.values())
    assert svn == {"G01": "G063", "G05": "G050", "G32": "G"}
    lines = text.splitlines()
    block = lines[lines.index("+FILE/COMMENT") + 1 : lines.index("-FILE/COMMENT")]
    assert all(len(ln) <= 80 for ln in block)
    words = " ".join(ln.strip() for ln in block).split()
    assert " ".join(words[: len(long.split())]) == long  # every word whole, in order
    assert "not estimated (left out, no value or sigma): G07" in " ".join(ln.strip() for ln in block)
    assert "SVN unknown" in " ".join(block) and "G32" in " ".join(block)
    output = next(ln for ln in lines if ln.startswith(" OUTPUT"))
    assert "6-hour" in output and "daily" not in output
    (tmp_path / "x.bia").write_text(text)
    prod = read_bias_sinex(tmp_path / "x.bia")  # the project's fixed-column reader agrees
    assert {r.prn: r.svn for r in prod.records if r.prn} == svn
    assert prod.satellite_dsb_ns("G07", "C1C", "C2W") is None


def test_bias_sinex_round_trip_two_parsers(tmp_path: Path) -> None:
    path = write_bias_sinex(
        tmp_path / "x.bia.gz",
        obs1="C1C",
        obs2="C2W",
        start="2024-01-10T00:00",
        end="2024-01-11T00:00",
        satellites=SATS,
        stations={**STAS, "XXXX": (np.nan, 1.0)},
        header=BiasSinexHeader(created="2024-01-12T13:45:56"),
    )
    text = gzip.decompress(path.read_bytes()).decode("ascii")
    first = text.splitlines()[0]
    assert first == "%=BIA 1.00 DNV 2024:012:49556 DNV 2024:010:00000 2024:011:00000 R 00000005"
    assert text.rstrip().endswith("%=ENDBIA")
    assert all(len(ln) <= 103 for ln in text.splitlines())
    info, sat, sta = _independent_parse(text)
    assert info[:2] == ["%=BIA", "1.00"] and int(info[8]) == 5
    assert {"FILE/REFERENCE", "FILE/COMMENT", "BIAS/DESCRIPTION", "BIAS/SOLUTION"} <= set(info)
    assert sat == {k: (round(v, 4), round(s, 4)) for k, (v, s) in SATS.items()}
    assert sta == STAS
    prod = read_bias_sinex(path)  # the project's fixed-column reader
    assert prod.agency == "DNV"
    for k, (v, _) in SATS.items():
        assert prod.satellite_dsb_ns(k, "C1C", "C2W") == pytest.approx(round(v, 4), abs=1e-12)
    assert prod.station_dsb_ns("DGAR", "C2W", "C1C") == pytest.approx(-3.521)
    assert [r.std for r in prod.records if r.prn == "G01"] == [0.0123]


def test_sinex_time_and_product_day() -> None:
    assert sinex_time("2024-01-10T06:00:30") == "2024:010:21630"
    assert sinex_time("2024-12-31T00:00") == "2024:366:00000"
    assert product_day("CAS0OPSRAP_20240100000_01D_01D_DCB.BIA.gz") == np.datetime64("2024-01-10")
    assert product_day("codg0110.24i") == np.datetime64("2024-01-11")
    assert product_day("mine.bia") is None


def _ionex(tmp_path: Path) -> Path:
    def line(content: str, label: str) -> str:
        return f"{content:<60}{label}\n"

    text = (
        line("     1.0            IONOSPHERE MAPS     GPS", "IONEX VERSION / TYPE")
        + line("DIFFERENTIAL CODE BIASES", "START OF AUX DATA")
        + line("   G01    -7.187     0.010", "PRN / BIAS / RMS")
        + line("   G05     2.500     0.012", "PRN / BIAS / RMS")
        + line("   G32    -1.000     0.011", "PRN / BIAS / RMS")
        + line("   G  BELE 41622M001         1.200     0.050", "STATION / BIAS / RMS")
        + line("DIFFERENTIAL CODE BIASES", "END OF AUX DATA")
        + line("", "END OF HEADER")
    )
    path = tmp_path / "codg0100.24i"
    path.write_text(text)
    return path


def test_ionex_aux_block_and_datum_alignment(tmp_path: Path) -> None:
    (prod,) = product_dsbs([_ionex(tmp_path)], ["G01", "G05", "G32", "G07"], ["BELE", "DGAR"], "C1W", "C2W")
    assert prod.kind == "ionex" and prod.notes == [] and prod.day == np.datetime64("2024-01-10")
    assert prod.satellite == {"G01": -7.187, "G05": 2.5, "G32": -1.0} and prod.station == {"BELE": 1.2}
    (c1c,) = product_dsbs([_ionex(tmp_path)], ["G01"], [], "C1C", "C2W")
    assert c1c.notes and "C1W-C2W" in c1c.notes[0]
    # estimates = product shifted by a datum constant c = 0.3 (satellites −c, receivers +c) plus small errors
    est_sat = {"G01": -7.187 - 0.3 + 0.05, "G05": 2.5 - 0.3 - 0.05, "G32": -1.0 - 0.3, "G07": 1.0}
    est_rx = {"BELE": 1.2 + 0.3 + 0.02}
    r = compare_in_datum(est_sat, est_rx, prod)
    assert r["n"] == 3 and r["datum_offset_ns"] == pytest.approx(-0.3)
    np.testing.assert_allclose(sorted(r["difference_ns"].values()), [-0.05, 0.0, 0.05], atol=1e-12)
    assert r["receivers"]["difference_ns"]["BELE"] == pytest.approx(0.02)
    assert r["rms_zero_mean_ns"] == pytest.approx(np.sqrt(2 * 0.05**2 / 3))
    assert compare_in_datum(est_sat, est_rx, prod, exclude=["G01", "G05", "G32"])["n"] == 0
    empty = ProductDSB("none", Path("x"), "sinex", {}, {})
    assert compare_in_datum(est_sat, est_rx, empty)["n"] == 0


def test_compare_command_on_ionosphere_output(
    shared_data: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    d = shared_data / "gnss/igs_2024010_bele_dgar"
    out = tmp_path / "iono"
    assert (
        main(
            [
                "gnss",
                "ionosphere",
                "--obs",
                str(d / "dgar0100.24o.gz"),
                "--nav",
                str(d / "brdc0100.24n.gz"),
                "--tlim",
                "2024-01-10T06:00",
                "2024-01-10T07:00",
                "--interval",
                "60",
                "--out",
                str(out),
                "--no-progress",
            ]
        )
        == 0
    )
    assert (out / "distnav_dsb.bia").exists()
    cas = d / "CAS0OPSRAP_20240100000_01D_01D_DCB.BIA.gz"
    summary = json.loads((out / "summary.json").read_text())
    for est in (out, out / "distnav_dsb.bia"):
        assert (
            main(
                [
                    "gnss",
                    "compare",
                    "--estimates",
                    str(est),
                    "--bias",
                    str(cas),
                    str(_ionex(tmp_path)),
                    "--out",
                    str(tmp_path / "cmp"),
                ]
            )
            == 0
        )
        res = json.loads((tmp_path / "cmp" / "comparison.json").read_text())
        r = res["products"][next(k for k in res["products"] if k.startswith("CAS"))]
        assert r["n"] >= 8 and "DGAR" in r["receivers"]["difference_ns"]
        ours = {k: v for k, v in summary["final_dsb_ns"]["central"].items() if not k.startswith("rx:")}
        common = [s for s in r["difference_ns"]]
        ref = np.array([r["reference_ns"][s] for s in common])
        back = np.array([ours[s] for s in common])
        np.testing.assert_allclose(
            back - ref - r["datum_offset_ns"], [r["difference_ns"][s] for s in common], atol=2e-4
        )  # the Bias-SINEX file rounds to 0.1 ps
    capsys.readouterr()
    other = d / "CAS0OPSRAP_20240110000_01D_01D_DCB.BIA.gz"
    assert main(["gnss", "compare", "--estimates", str(out), "--bias", str(other)]) == 2
    assert "a product of 2024-01-11" in capsys.readouterr().err
    assert main(["gnss", "compare", "--estimates", str(out), "--bias", str(other), "--allow-other-day"]) == 0
