"""RINEX observation reading: code selection per band, RINEX 2 ↔ 3 code names, values, time windows, errors."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from distnav.errors import DataFileError
from distnav.formats.gnss.rinex import read_code_observations

NL = "gnss/nl_2021001_short_network_snapshot"
IGS = "gnss/igs_2024010_bele_dgar"


def test_rinex2_values_match_the_file_text(shared_data: Path) -> None:
    """First epoch of zegv0010.21o (2021-01-01 00:00:00), read by eye from the file:
    G07: C1 24178026.635, P1 24178026.139, P2 24178024.181, no C5; G08: C5 21866747.537."""
    o = read_code_observations(shared_data / NL / "zegv0010.21o")
    assert o.station == "ZEGV"
    assert o.codes == {1: "C1C", 2: "C2W", 5: "C5Q"}  # Septentrio: RINEX 2 C5 = C5Q
    assert any("C5 read as C5Q" in n for n in o.notes)
    assert o.time[0] == np.datetime64("2021-01-01T00:00:00")
    g07, g08 = o.svs.index("G07"), o.svs.index("G08")
    assert o.range_m[1][0, g07] == pytest.approx(24178026.635, abs=1e-6)
    assert o.range_m[2][0, g07] == pytest.approx(24178024.181, abs=1e-6)
    assert np.isnan(o.range_m[5][0, g07])
    assert o.range_m[5][0, g08] == pytest.approx(21866747.537, abs=1e-6)
    assert o.n_epochs == 19
    assert np.linalg.norm(o.position_ecef_m) == pytest.approx(6.37e6, rel=0.01)
    forced = read_code_observations(shared_data / NL / "zegv0010.21o", codes={1: "C1W"})
    assert forced.codes[1] == "C1W"
    assert forced.range_m[1][0, g07] == pytest.approx(24178026.139, abs=1e-6)


def test_hatanaka_rinex2_and_two_bands(shared_data: Path) -> None:
    o = read_code_observations(shared_data / NL / "eijs0010.21d", bands=(1, 2))
    assert o.station == "EIJS" and o.codes == {1: "C1C", 2: "C2W"} and o.n_epochs == 79
    assert "SEPT" in o.receiver
    both = np.isfinite(o.range_m[1]) & np.isfinite(o.range_m[2])
    # C1 − P2 on the same satellite is a few metres (ionosphere + DCB), never kilometres
    assert np.abs(o.range_m[1][both] - o.range_m[2][both]).max() < 50.0


def test_rinex3_hatanaka_gzip_time_window(shared_data: Path) -> None:
    o = read_code_observations(
        shared_data / IGS / "BELE00BRA_R_20240100000_01D_30S_MO.crx.gz", tlim=("2024-01-10T00:00", "2024-01-10T00:20")
    )
    assert o.station == "BELE"
    assert o.codes == {1: "C1C", 2: "C2W", 5: "C5X"}
    assert o.rinex_version == pytest.approx(3.05)
    assert o.n_epochs == 41
    assert set(o.satellites_with_all_bands()) <= {
        "G01",
        "G03",
        "G04",
        "G06",
        "G08",
        "G09",
        "G10",
        "G11",
        "G14",
        "G18",
        "G23",
        "G24",
        "G25",
        "G26",
        "G28",
        "G30",
        "G32",
    }
    assert len(o.satellites_with_all_bands()) >= 5
    dec = read_code_observations(
        shared_data / IGS / "BELE00BRA_R_20240100000_01D_30S_MO.crx.gz",
        tlim=("2024-01-10T00:00", "2024-01-10T00:20"),
        interval_s=300,
    )
    assert dec.n_epochs == 5


def test_missing_band_names_file_and_types(shared_data: Path) -> None:
    with pytest.raises(DataFileError, match=r"delf0010\.21o: no L5 code observation.*types present"):
        read_code_observations(shared_data / NL / "delf0010.21o")
    with pytest.raises(DataFileError, match=r"BELE.*no L1 code observation \(C1W\)"):
        read_code_observations(
            shared_data / IGS / "BELE00BRA_R_20240100000_01D_30S_MO.crx.gz",
            codes={1: "C1W"},
            tlim=("2024-01-10T00:00", "2024-01-10T00:01"),
        )


def test_unreadable_files(tmp_path: Path) -> None:
    with pytest.raises(DataFileError, match="file not found"):
        read_code_observations(tmp_path / "nothing.21o")
    bad = tmp_path / "junk.21o"
    bad.write_text("garbage\n" * 5)
    with pytest.raises(DataFileError, match="junk.21o"):
        read_code_observations(bad)


def test_navigation_file_is_not_observations(shared_data: Path) -> None:
    with pytest.raises(DataFileError, match="not a RINEX observation file|no GPS observation"):
        read_code_observations(shared_data / NL / "CBW100NLD_R_20210010000_01D_MN.rnx")


def test_time_window_without_epochs(shared_data: Path) -> None:
    with pytest.raises(DataFileError, match=r"zegv0010\.21o: no GPS observation epochs"):
        read_code_observations(shared_data / NL / "zegv0010.21o", tlim=("2021-01-02T00:00", "2021-01-02T01:00"))
