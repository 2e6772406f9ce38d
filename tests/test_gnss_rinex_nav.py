"""distnav's own navigation-file reader (``formats/gnss/rinex_nav``) against georinex, the reader it replaces.

On every shared RINEX 2 / 3 navigation file with GPS records: the same records (satellite, time of clock) and
every field of every GPS record equal to georinex's, and the broadcast orbit built from either identical. Then
the departures the module doc names, on hand-made files: a repeated record, a blank field, a short line.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest

from distnav.errors import DataFileError
from distnav.formats.gnss.rinex_nav import GPS_NAV_FIELDS, read_gps_ephemerides
from distnav.models.gnss.orbits import BroadcastOrbit, gps_seconds

NAV_FILES = (
    "gnss/igs_2024010_bele_dgar/BRDC00IGS_R_20240100000_01D_MN.rnx.gz",  # RINEX 3.04, merged multi-GNSS
    "gnss/igs_2024010_bele_dgar/brdc0100.24n.gz",  # RINEX 2, merged GPS
    "gnss/igs_2024010_bele_dgar/brdc0110.24n.gz",
    "gnss/esbc_2020177_single_station_L5_sp3/ESBC00DNK_R_20201770000_01D_MN.rnx.gz",  # one station, mixed
    "gnss/nl_2021001_short_network_snapshot/CBW100NLD_R_20210010000_01D_MN.rnx",
    "gnss/nl_2021001_short_network_snapshot/cbw10010.21n.gz",
)


def _georinex(path: Path) -> object:
    gr = pytest.importorskip("georinex")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return gr.load(path, use="G")


@pytest.mark.parametrize("name", NAV_FILES)
def test_every_gps_field_equals_georinex(shared_data: Path, name: str) -> None:
    path = shared_data / name
    ours = read_gps_ephemerides(path)
    nav = _georinex(path)
    svs = [str(s) for s in nav.sv.values]  # type: ignore[attr-defined]
    toc = gps_seconds(nav.time.values)  # type: ignore[attr-defined]
    fields = [f for f in GPS_NAV_FIELDS if f in nav.data_vars]  # type: ignore[attr-defined]
    assert len(fields) >= 27  # (RINEX 2 / 3: all but possibly the fit interval)
    table = np.stack([np.asarray(nav[f].values, float) for f in fields], axis=-1)  # type: ignore[index]
    n_records = 0
    for k, sv in enumerate(svs):
        assert "_" not in sv  # no repeated records in these files
        rows = np.flatnonzero(~np.isnan(table[:, k]).all(axis=1))
        n_records += rows.size
        assert sv in ours
        np.testing.assert_array_equal(ours[sv]["toc_s"], toc[rows])  # the same records, in order
        for j, f in enumerate(fields):
            np.testing.assert_array_equal(ours[sv][f], table[rows, k, j], err_msg=f"{name} {sv} {f}")
    assert set(ours) == set(svs)
    assert n_records > 0
    a = BroadcastOrbit.from_records(ours)
    b = BroadcastOrbit.from_dataset(nav)
    assert a.svs == b.svs
    for sv in a.svs:
        assert a.records[sv].keys() == b.records[sv].keys()
        for f in a.records[sv]:
            np.testing.assert_array_equal(a.records[sv][f], b.records[sv][f])


_HEADER3 = (
    "     3.04           N: GNSS NAV DATA    M: MIXED            RINEX VERSION / TYPE\n"
    "                                                            END OF HEADER\n"
)


def _record3(sv: str, hour: int, sqrt_a: str = " 5.153693731310D+03", short: bool = False) -> str:
    """A GPS record with field value = its index (+1), ``sqrtA`` as given; ``short``: the lines end after the
    last field (no trailing blanks)."""
    vals = [f"{k + 1:19.12E}".replace("E", "D") for k in range(31)]
    vals[GPS_NAV_FIELDS.index("sqrtA")] = sqrt_a
    vals[GPS_NAV_FIELDS.index("health")] = f"{0.0:19.12E}"
    lines = [f"{sv} 2024 01 10 {hour:02d} 00 00" + "".join(vals[:3])]
    for j in range(7):
        lines.append("    " + "".join(vals[3 + 4 * j : 7 + 4 * j]))
    if short:
        lines[-1] = lines[-1][: 4 + 2 * 19]  # TransTime, FitIntvl only
    return "\n".join(lines) + "\n"


def test_hand_made_file_values_and_departures(tmp_path: Path) -> None:
    p = tmp_path / "x.rnx"
    p.write_text(
        _HEADER3
        + _record3("G05", 2)
        + _record3("G05", 0)
        + _record3("G05", 2, sqrt_a=" 9.0D+03")
        + _record3("G07", 4, sqrt_a=" " * 19, short=True)
    )
    got = read_gps_ephemerides(p)
    assert sorted(got) == ["G05", "G07"]
    g5 = got["G05"]
    assert g5["toc_s"].tolist() == [
        gps_seconds(np.datetime64("2024-01-10T00:00"))[()],
        gps_seconds(np.datetime64("2024-01-10T02:00"))[()],
    ]  # sorted by time of clock
    assert g5["sqrtA"].tolist() == [5153.69373131, 5153.69373131]  # the repeated 02:00 record: the first kept
    assert g5["SVclockBias"][0] == 1.0 and g5["IODC"][0] == 27.0 and g5["FitIntvl"][0] == 29.0
    g7 = got["G07"]
    assert np.isnan(g7["sqrtA"][0])  # blank field: NaN (georinex 3 would drop the record)
    assert g7["TransTime"][0] == 28.0 and g7["FitIntvl"][0] == 29.0  # a short last line read at its columns
    orbit = BroadcastOrbit.from_records(got)
    assert orbit.svs == ("G05",)  # no usable orbit without √A


def test_bad_number_names_the_line(tmp_path: Path) -> None:
    p = tmp_path / "bad.rnx"
    p.write_text(_HEADER3 + _record3("G05", 2).replace("2.000000000000D+00", "2.0000x0000000D+00"))
    with pytest.raises(DataFileError, match=r"bad.rnx, line 3: columns 43-61"):
        read_gps_ephemerides(p)
