"""Bias-SINEX and IONEX DCB readers against values quoted in the data PROVENANCE and hand-written files."""

from __future__ import annotations

import gzip
from pathlib import Path

import numpy as np
import pytest

from distnav.errors import DataFileError, ModelError
from distnav.formats.gnss.bias_sinex import read_bias_sinex, read_ionex_dcb, resolve_dsb

IGS = "gnss/igs_2024010_bele_dgar"


@pytest.fixture(scope="module")
def products(shared_data: Path):  # type: ignore[no-untyped-def]
    d = shared_data / IGS
    return (
        read_bias_sinex(d / "CAS0OPSRAP_20240100000_01D_01D_DCB.BIA.gz"),
        read_bias_sinex(d / "GFZ0OPSRAP_20240100000_01D_01D_DCB.BIA.gz"),
    )


def test_values_quoted_in_provenance(products) -> None:  # type: ignore[no-untyped-def]
    cas, gfz = products
    assert cas.name == "CAS" and gfz.name == "GFZ"
    assert cas.satellite_dsb_ns("G01", "C1W", "C2W") == pytest.approx(-7.187)
    assert gfz.satellite_dsb_ns("G01", "C1W", "C2W") == pytest.approx(-7.231, abs=5e-4)
    assert cas.satellite_dsb_ns("G04", "C1W", "C2W") == pytest.approx(-0.617)
    assert gfz.satellite_dsb_ns("G04", "C1W", "C2W") == pytest.approx(0.802, abs=5e-4)
    assert cas.station_dsb_ns("BELE", "C1C", "C5X") == pytest.approx(-8.026)
    assert cas.station_dsb_ns("DGAR", "C1C", "C5Q") == pytest.approx(10.898)
    # reversed order flips the sign; absent pairs give None
    assert cas.satellite_dsb_ns("G01", "C2W", "C1W") == pytest.approx(7.187)
    assert gfz.satellite_dsb_ns("G01", "C1C", "C5Q") is None
    assert len(cas.satellites("G")) == 31 and len(gfz.satellites("G")) == 31
    l5 = [s for s in cas.satellites("G") if cas.satellite_dsb_ns(s, "C1C", "C5X") is not None]
    assert len(l5) == 17


def test_cas_gfz_agreement_yardstick(products) -> None:  # type: ignore[no-untyped-def]
    """PROVENANCE: CAS and GFZ satellite C1W−C2W agree to about 0.05–1.4 ns (measured: RMS 0.75 ns, largest
    1.64 ns, G14). Both use a zero-mean satellite datum, so the mean difference vanishes."""
    cas, gfz = products
    diffs = np.array(
        [cas.satellite_dsb_ns(s, "C1W", "C2W") - gfz.satellite_dsb_ns(s, "C1W", "C2W") for s in cas.satellites("G")]
    )
    assert abs(diffs.mean()) < 1e-3
    assert 0.5 < np.sqrt(np.mean(diffs**2)) < 1.0
    assert 1.3 < np.abs(diffs).max() < 1.7


def test_resolve_dsb_chains(products) -> None:  # type: ignore[no-untyped-def]
    cas, gfz = products
    v, chain = resolve_dsb([cas], "C1C", "C2W", prn="G01")
    assert v == pytest.approx(-7.984) and chain == ["CAS C1C-C2W"]  # direct pair, one product
    v, chain = resolve_dsb([gfz, cas], "C1C", "C2W", prn="G01")
    assert chain == ["CAS C1C-C1W", "GFZ C1W-C2W"]  # GFZ used wherever it can be
    assert v == pytest.approx(-0.903 + -7.23137571560645)
    v, _ = resolve_dsb([cas], "C2W", "C5Q", station="DGAR")
    assert v == pytest.approx(cas.station_dsb_ns("DGAR", "C1C", "C5Q") - cas.station_dsb_ns("DGAR", "C1C", "C2W"))
    assert resolve_dsb([cas], "C1C", "C1C", prn="G01") == (0.0, [])
    with pytest.raises(ModelError, match="no C1C-C5X DSB for G01"):
        resolve_dsb([gfz], "C1C", "C5X", prn="G01")
    with pytest.raises(ModelError, match="exactly one of"):
        resolve_dsb([cas], "C1C", "C2W")


HEAD = (
    "%=BIA 1.00 TST 24:012:00000 TST 2024:010:00000 2024:011:00000 R 00000002\n"
    "+BIAS/SOLUTION\n"
    "*BIAS SVN_ PRN STATION__ OBS1 OBS2 BIAS_START____ BIAS_END______ UNIT __ESTIMATED_VALUE____ _STD_DEV___\n"
)
SAT = " DSB  G063 G01           C1C  C1W  2024:010:00000 2024:011:00000 ns                 -0.9030      0.0060\n"
STA = " DSB  G    G   DGAR      C1C  C1W  2024:010:00000 2024:011:00000 ns                  2.3170      0.0140\n"


def test_hand_written_file_plain_and_gzip(tmp_path: Path) -> None:
    text = HEAD + SAT + STA + "-BIAS/SOLUTION\n%=ENDBIA\n"
    plain = tmp_path / "t.bia"
    plain.write_text(text)
    gz = tmp_path / "t.bia.gz"
    gz.write_bytes(gzip.compress(text.encode()))
    for f in (plain, gz):
        prod = read_bias_sinex(f)
        assert prod.satellite_dsb_ns("G01", "C1C", "C1W") == pytest.approx(-0.903)
        assert prod.station_dsb_ns("DGAR", "C1C", "C1W") == pytest.approx(2.317)
        assert prod.records[0].line == 4 and prod.records[1].station == "DGAR"


def test_malformed_files(tmp_path: Path) -> None:
    f = tmp_path / "bad.bia"
    f.write_text(HEAD + SAT + " DSB  G063 G01           C1C  C1W  2024:010:00000 2024:011:00000 ns       x.yz\n")
    with pytest.raises(DataFileError, match=r"bad\.bia, line 5: malformed"):
        read_bias_sinex(f)
    f.write_text(HEAD + SAT.replace("C1W  2024", "C1W  extra 2024"))
    with pytest.raises(DataFileError, match="line 4"):
        read_bias_sinex(f)
    f.write_text("not a bias file\n")
    with pytest.raises(DataFileError, match="not a Bias-SINEX"):
        read_bias_sinex(f)
    f.write_text(HEAD.split("+BIAS")[0])
    with pytest.raises(DataFileError, match="no \\+BIAS/SOLUTION"):
        read_bias_sinex(f)
    with pytest.raises(DataFileError, match="file not found"):
        read_bias_sinex(tmp_path / "none.bia")
    f.write_text(HEAD + SAT)  # a truncated file: the block is never closed
    with pytest.raises(DataFileError, match=r"line 4: the \+BIAS/SOLUTION block of line 2 is not closed"):
        read_bias_sinex(f)
    f.write_text(HEAD + SAT.replace(" ns ", " cyc") + "-BIAS/SOLUTION\n")
    with pytest.raises(ModelError, match="not ns"):
        read_bias_sinex(f).satellite_dsb_ns("G01", "C1C", "C1W")


IONEX = """\
     1.0            IONOSPHERE MAPS     GPS                 IONEX VERSION / TYPE
DIFFERENTIAL CODE BIASES                                    START OF AUX DATA
Reference observables for GPS    : C1W-C2W                  COMMENT
   G01    -7.722     0.020                                  PRN / BIAS / RMS
   G32    -4.401     0.019                                  PRN / BIAS / RMS
   R01     1.250     0.030                                  PRN / BIAS / RMS
Reference observables for ALBH 40129M003 (G): C1W-C2W       COMMENT
   G  ALBH 40129M003          13.899     0.079              STATION / BIAS / RMS
   G  ALIC                    21.005     0.071              STATION / BIAS / RMS
DIFFERENTIAL CODE BIASES                                    END OF AUX DATA
                                                            END OF HEADER
"""


def test_ionex_dcb_block(tmp_path: Path) -> None:
    f = tmp_path / "codg0100.24i"
    f.write_text(IONEX)
    d = read_ionex_dcb(f)
    assert d.satellite["G01"] == (-7.722, 0.020)
    assert d.satellite["G32"] == (-4.401, 0.019) and d.satellite["R01"] == (1.25, 0.03)
    assert d.station[("G", "ALBH")] == (13.899, 0.079)
    assert d.station[("G", "ALIC")] == (21.005, 0.071)
    assert d.reference["GPS"] == "C1W-C2W"
    gz = tmp_path / "codg0100.24i.gz"
    gz.write_bytes(gzip.compress(IONEX.encode()))
    assert read_ionex_dcb(gz).satellite == d.satellite


def test_ionex_errors(tmp_path: Path) -> None:
    f = tmp_path / "x.24i"
    f.write_text(IONEX.replace("-7.722", "-7.7x2"))
    with pytest.raises(DataFileError, match=r"x\.24i, line 4: malformed IONEX DCB"):
        read_ionex_dcb(f)
    f.write_text("     1.0            IONOSPHERE MAPS     GPS                 IONEX VERSION / TYPE\n")
    with pytest.raises(DataFileError, match="no 'DIFFERENTIAL CODE BIASES"):
        read_ionex_dcb(f)


@pytest.mark.parametrize(
    ("header", "message"),
    [
        ({"agency": "TOOLONG"}, "agency is 1 to 3 ASCII characters, got 'TOOLONG'"),
        ({"agency": ""}, "agency is 1 to 3 ASCII characters"),
        ({"comments": "one line"}, "comments must be a list of lines, got one string"),
        ({"sampling_s": 0}, "sampling_s must be a positive number of s, got 0.0"),
        ({"sampling_s": "30"}, "sampling_s must be a positive number of s, got '30'"),
    ],
)
def test_bias_sinex_header_is_checked_when_built(header: dict[str, object], message: str) -> None:
    from distnav.formats.gnss.bias_sinex import BiasSinexHeader

    with pytest.raises(DataFileError, match=message):
        BiasSinexHeader(**header)  # type: ignore[arg-type]
