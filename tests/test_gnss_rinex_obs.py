"""The own RINEX observation reader (distnav.formats.gnss.rinex_obs) against georinex, latin-1 headers, progress."""

from __future__ import annotations

import gzip
import warnings
from pathlib import Path

import numpy as np
import pytest

from distnav.errors import DataFileError
from distnav.formats.gnss.rinex import read_code_observations
from distnav.formats.gnss.rinex_obs import read_observation_types

IGS = "gnss/igs_2024010_bele_dgar"
NL = "gnss/nl_2021001_short_network_snapshot"
WINDOW = (np.datetime64("2024-01-10T03:00"), np.datetime64("2024-01-10T03:30"))


@pytest.mark.parametrize(
    "name,types",
    [
        ("BELE00BRA_R_20240100000_01D_30S_MO.crx.gz", ["C1C", "C2W", "C5X", "L1C", "L2W"]),  # RINEX 3, Hatanaka
        ("dgar0100.24o.gz", ["C1", "P1", "P2", "C5", "L1", "L2"]),  # RINEX 2.11, mixed
    ],
)
def test_values_equal_georinex(shared_data: Path, name: str, types: list[str]) -> None:
    gr = pytest.importorskip("georinex")
    path = shared_data / IGS / name
    ours = read_observation_types(path, types, tlim=WINDOW)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ref = gr.load(path, use="G", meas=types, tlim=tuple(str(t) for t in WINDOW))
    assert np.array_equal(ref.time.values.astype("datetime64[ns]"), ours.time)
    assert set(ours.svs) <= {str(s) for s in ref.sv.values}
    for t in types:
        theirs = ref[t].sel(sv=list(ours.svs)).values
        assert np.array_equal(np.isfinite(theirs), np.isfinite(ours.values[t]))
        np.testing.assert_array_equal(theirs[np.isfinite(theirs)], ours.values[t][np.isfinite(theirs)])


@pytest.mark.parametrize(
    "name,system,types",
    [
        ("BELE00BRA_R_20240100000_01D_30S_MO.crx.gz", "E", ["C1X", "C5X", "C7X", "L1X", "L5X"]),
        ("BELE00BRA_R_20240100000_01D_30S_MO.crx.gz", "C", ["C2I", "C6I", "C7I", "L2I"]),
        ("BELE00BRA_R_20240100000_01D_30S_MO.crx.gz", "R", ["C1C", "C1P", "C2C", "L1C"]),
        ("dgar0100.24o.gz", "E", ["C1", "C5", "C7", "L1", "L5"]),  # RINEX 2.11 mixed: Galileo shares the types
    ],
)
def test_other_systems_equal_georinex(shared_data: Path, name: str, system: str, types: list[str]) -> None:
    """Galileo, BeiDou and GLONASS lines of the mixed BELE file (and DGAR's RINEX 2 Galileo): every value and
    every satellite as georinex."""
    gr = pytest.importorskip("georinex")
    path = shared_data / IGS / name
    ours = read_observation_types(path, types, tlim=WINDOW, system=system)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ref = gr.load(path, use=system, meas=types, tlim=tuple(str(t) for t in WINDOW))
    assert np.array_equal(ref.time.values.astype("datetime64[ns]"), ours.time)
    assert set(ours.svs) == {str(s) for s in ref.sv.values} and all(s[0] == system for s in ours.svs)
    for t in types:
        theirs = ref[t].sel(sv=list(ours.svs)).values
        assert np.isfinite(theirs).sum() > 100
        assert np.array_equal(np.isfinite(theirs), np.isfinite(ours.values[t]))
        np.testing.assert_array_equal(theirs[np.isfinite(theirs)], ours.values[t][np.isfinite(theirs)])


def test_glonass_channels_and_phase_wavelengths(shared_data: Path) -> None:
    """The header's GLONASS SLOT / FRQ # channels (BELE: R01 +1, R02 −4, R10 −7) scale each satellite's phase:
    code and phase in metres then move together over half an hour (Galileo too, with its E5a wavelength)."""
    path = shared_data / IGS / "BELE00BRA_R_20240100000_01D_30S_MO.crx.gz"
    from distnav.formats.gnss.rinex_obs import read_header
    from distnav.models.gnss.systems import carrier_frequencies_hz

    hdr = read_header(path)
    assert (hdr.glonass_channels["R01"], hdr.glonass_channels["R02"], hdr.glonass_channels["R10"]) == (1, -4, -7)
    assert len(hdr.glonass_channels) == 24 and hdr.types_of("C") == (
        "C2I",
        "C6I",
        "C7I",
        "L2I",
        "L6I",
        "L7I",
        "S2I",
        "S6I",
        "S7I",
    )
    for system, bands, codes in (("E", (1, 5), {1: "C1X", 5: "C5X"}), ("R", (1, 2), {1: "C1C", 2: "C2C"})):
        o = read_code_observations(path, bands=bands, system=system, phases=True, tlim=WINDOW)
        assert o.codes == codes and o.phase_types == {b: "L" + c[1:] for b, c in codes.items()}
        for b in bands:  # code minus carrier: 2× the ionosphere's change and code noise, metres
            d = o.range_m[b] - o.phase_m[b]
            spread = np.nanstd(d[:, np.isfinite(d).sum(axis=0) > 1], axis=0)  # satellites seen at two epochs or more
            assert np.isfinite(o.phase_m[b]).sum() > 100 and np.nanmedian(spread) < 2.0, (system, b, spread)
    # the same GLONASS phases with every channel one too high: the range change × 3.5e-4 shows (tens of metres)
    f_right = carrier_frequencies_hz("R", 1, o.svs, hdr.glonass_channels)
    f_wrong = carrier_frequencies_hz("R", 1, o.svs, {s: k + 1 for s, k in hdr.glonass_channels.items()})
    wrong = o.range_m[1] - o.phase_m[1] * f_right / f_wrong
    assert np.nanmedian(np.nanstd(wrong[:, np.isfinite(wrong).sum(axis=0) > 1], axis=0)) > 20.0
    with pytest.raises(DataFileError, match="BeiDou observations are read from RINEX 3 files only"):
        read_observation_types(shared_data / IGS / "dgar0100.24o.gz", ["C1"], system="C")
    # RINEX 2 GLONASS (DGAR) is read since issue 32: values against georinex in tests/test_gnss_multisystem.py
    # RINEX 2 Galileo of a Septentrio: C1/C5/C7 are the pilots C1C/C5Q/C7Q (CAS: DGAR C1C−C5Q, C1C−C7Q)
    dgar = read_code_observations(shared_data / IGS / "dgar0100.24o.gz", bands=(1, 5, 7), system="E", tlim=WINDOW)
    assert dgar.codes == {1: "C1C", 5: "C5Q", 7: "C7Q"} and "RINEX 2 C5 read as C5Q (receiver SEPT)" in dgar.notes
    assert len(dgar.svs) >= 5 and all(sv[0] == "E" for sv in dgar.svs)


def test_latin1_byte_in_header_is_accepted(shared_data: Path, tmp_path: Path) -> None:
    text = (shared_data / NL / "zegv0010.21o").read_bytes()
    marker = b"END OF HEADER"
    k = text.index(marker)
    line_start = text.rindex(b"\n", 0, k) + 1
    comment = b"Messstation J\xe4ger (latin-1 byte 0xE4)".ljust(60) + b"COMMENT\n"
    bad = text[:line_start] + comment + text[line_start:]
    path = tmp_path / "zegv0010.21o.gz"
    path.write_bytes(gzip.compress(bad))
    o = read_code_observations(path)
    ref = read_code_observations(shared_data / NL / "zegv0010.21o")
    assert o.n_epochs == ref.n_epochs == 19
    np.testing.assert_array_equal(o.range_m[1], ref.range_m[1])


def test_progress_callback_and_phases(shared_data: Path) -> None:
    seen: list[tuple[str, float]] = []
    o = read_code_observations(
        shared_data / NL / "zegv0010.21o", phases=True, progress=lambda label, f: seen.append((label, f))
    )
    assert seen and seen[-1] == ("ZEGV", 1.0) and all(0 <= f <= 1 for _, f in seen)
    assert o.phase_types == {1: "L1", 2: "L2", 5: "L5"}
    # geometry-free phase and code of the same satellite agree up to a constant of metres, never kilometres
    g = (o.phase_m[1] - o.phase_m[2]) - (o.range_m[2] - o.range_m[1])
    ok = np.isfinite(g)
    assert ok.sum() > 50
    per_sat = np.nanstd(np.where(ok, g, np.nan), axis=0)
    assert np.nanmax(per_sat) < 2.0


def test_bad_records_name_the_line(tmp_path: Path) -> None:
    head = (
        "     3.04           OBSERVATION DATA    G                   RINEX VERSION / TYPE\n"
        "G    2 C1C C2W                                              SYS / # / OBS TYPES\n"
        "                                                            END OF HEADER\n"
    )
    p = tmp_path / "bad.rnx"
    p.write_text(head + "> 2024 01 10 00 00 xx.0000000  0  1\nG01  22000000.000    22000001.000\n")
    with pytest.raises(DataFileError, match=r"bad\.rnx, line 4: the epoch: expected year month day"):
        read_observation_types(p, ["C1C"])
    with pytest.raises(DataFileError, match=r"types L1C not in the header"):
        read_observation_types(p, ["L1C"])
    p.write_text("garbage\n")
    with pytest.raises(DataFileError, match="no END OF HEADER"):
        read_observation_types(p, ["C1C"])


@pytest.mark.parametrize(
    "types", [["C1", "P1", "P2", "L1", "L2"], ["C1", "P1", "P2", "L1", "L2", "S1", "S2", "C2", "C5", "L5"]]
)
def test_rinex2_types_stop_at_the_label(tmp_path: Path, types: list[str]) -> None:
    """5 or 10 RINEX 2 types (a full last line): the header label is not read as an extra type (it was: '# /',
    and every record of the file was then misaligned by one line per satellite)."""

    def line(content: str, label: str) -> str:
        return f"{content:<60}{label}\n"

    rows = [types[i : i + 9] for i in range(0, len(types), 9)]
    head = line("     2.11           OBSERVATION DATA    G (GPS)", "RINEX VERSION / TYPE")
    for k, row in enumerate(rows):
        head += line(
            (f"{len(types):6d}" if k == 0 else " " * 6) + "".join(f"{t:>6}" for t in row), "# / TYPES OF OBSERV"
        )
    head += line("", "END OF HEADER")
    n_lines = (len(types) + 4) // 5
    rec = ""
    for base in (21e6, 22e6):  # G01, G07
        vals = [base + 10.0 * j for j in range(len(types))]
        fields = "".join(f"{v:14.3f}  " for v in vals)
        rec += "".join(fields[80 * i : 80 * (i + 1)] + "\n" for i in range(n_lines))
    p = tmp_path / "site0100.24o"
    p.write_text(
        head + " 24  1 10  0  0  0.0000000  0  2G01G07\n" + rec + " 24  1 10  0  0 30.0000000  0  2G01G07\n" + rec
    )
    o = read_code_observations(p, bands=(1, 2), codes={1: "C1W", 2: "C2W"})
    assert o.n_epochs == 2 and o.svs[:2] == ("G01", "G07")
    np.testing.assert_allclose(o.range_m[1][:, 0], 21e6 + 10.0)  # P1 is the 2nd type
    np.testing.assert_allclose(o.range_m[2][:, 1], 22e6 + 20.0)  # P2 the 3rd


def test_fast_fields_match_python_float_and_refuse_what_the_line_reader_refuses() -> None:
    """``parse_fields`` (all lines at once) gives Python's ``float`` of every ``F14.3`` field and its loss-of-lock
    digit; blank or cut-off-blank fields are absent; anything the line-by-line reader would reject gives ``None``."""
    from distnav.formats.gnss.rinex_fields import parse_fields

    rng = np.random.default_rng(7)
    vals = rng.uniform(-3e7, 3e7, (200, 3)).round(3)
    lines = []
    for i, row in enumerate(vals):
        f = [f"{v:14.3f}{i % 8 if i % 3 else ' '} " for v in row]
        if i % 7 == 0:
            f[1] = " " * 16  # a blank field
        lines.append("G01" + "".join(f) if i % 11 else ("G01" + "".join(f[:2])).rstrip())  # 3rd past the end
    starts = (3, 19, 35)
    got = parse_fields(lines, starts)
    assert got is not None
    values, lli, present = got
    for i, line in enumerate(lines):
        for j, a in enumerate(starts):
            text = line[a : a + 14]
            assert present[i, j] == bool(text.strip())
            if present[i, j]:
                assert values[i, j] == float(text)  # bitwise
                assert lli[i, j] == (int(line[a + 14]) if line[a + 14 : a + 15].strip() else 0)
    assert parse_fields(lines, (3, -1, 35)) is not None
    for bad in ("  2200000.12 3", "  22000000123 ", " 2200000.123x", "  22000000.1", "  22000a00.123"):
        assert parse_fields([*lines[:5], "G01" + bad], starts[:1]) is None, bad


def test_a_bad_field_is_named_by_its_line_before_a_later_bad_epoch(tmp_path: Path) -> None:
    """The fast path parses fields after the walk; a malformed field still gives the first problem's line."""
    head = (
        "     3.04           OBSERVATION DATA    G                   RINEX VERSION / TYPE\n"
        "G    2 C1C C2W                                              SYS / # / OBS TYPES\n"
        "                                                            END OF HEADER\n"
    )
    ok = "> 2024 01 10 00 00  0.0000000  0  1\nG01  22000000.000    22000001.000\n"
    p = tmp_path / "bad.rnx"
    p.write_text(
        head
        + ok
        + "> 2024 01 10 00 00 30.0000000  0  1\nG01  2200000x.000    22000001.000\n"
        + ok.replace(" 0.0", "xx.0")
    )
    with pytest.raises(DataFileError, match=r"bad\.rnx, line 7 \(epoch 2024-01-10T00:00:30\): C1C of G01"):
        read_observation_types(p, ["C1C"])
    p.write_text(head + ok + ok.replace(" 0.0", "30.0"))
    assert read_observation_types(p, ["C1C", "C2W"]).values["C2W"].tolist() == [[22000001.0], [22000001.0]]


def test_epoch_time_is_numpys_parse_of_the_minute() -> None:
    """The reader's epoch (issue 32, gnss9: the hour parsed once, minute and seconds added in ns) is the
    datetime64 numpy parses from each epoch's minute plus the seconds, and refuses what that parse refuses."""
    from distnav.formats.gnss.rinex_fields import epoch_time as _epoch_time

    def parsed(y: int, mo: int, d: int, h: int, mi: int, sec: float) -> np.datetime64:
        base = np.datetime64(f"{y:04d}-{mo:02d}-{d:02d}T{h:02d}:{mi:02d}", "ns")
        return base + np.timedelta64(int(round(sec * 1e9)), "ns")

    rng = np.random.default_rng(32)
    for _ in range(3000):
        y, mo, d, h, mi = (int(rng.integers(a, b)) for a, b in ((1980, 2090), (1, 13), (1, 29), (0, 24), (0, 60)))
        sec = float(np.round(rng.uniform(-1.0, 61.0), 7))
        got, want = _epoch_time(y, mo, d, h, mi, sec), parsed(y, mo, d, h, mi, sec)
        assert got == want and got.dtype == want.dtype
    for bad in ((2024, 13, 1, 0, 0, 0.0), (2023, 2, 29, 0, 0, 0.0), (2024, 1, 1, 24, 0, 0.0), (2024, 1, 1, 0, 60, 0.0)):
        with pytest.raises(ValueError):
            parsed(*bad)
        with pytest.raises(ValueError):
            _epoch_time(*bad)
