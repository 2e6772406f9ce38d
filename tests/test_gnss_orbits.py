"""Satellite orbits: broadcast (IS-GPS-200) against precise SP3, Lagrange interpolation, synthetic constellation."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest

from distnav.errors import DataFileError, ModelError
from distnav.formats.gnss.rinex import read_navigation, read_sp3
from distnav.models.gnss.constants import GM_M3_S2
from distnav.models.gnss.geometry import ecef_to_geodetic
from distnav.models.gnss.orbits import (
    BLOCK_IIF_PRNS,
    BroadcastOrbit,
    SP3Orbit,
    datetime_from_gps_seconds,
    gps_seconds,
    lagrange_interpolate,
    synthetic_gps_constellation,
)

ESBC = "gnss/esbc_2020177_single_station_L5_sp3"
IGS = "gnss/igs_2024010_bele_dgar"


def test_gps_seconds_hand_values() -> None:
    assert gps_seconds(np.datetime64("1980-01-06T00:00:00")) == 0.0
    # 2020-06-25 00:00 GPS = week 2111, day 4 (Thursday): 2111·604800 + 4·86400
    assert gps_seconds(np.datetime64("2020-06-25T00:00:00")) == 2111 * 604800 + 4 * 86400
    t = np.array([1.5e9, 1.5e9 + 30.0])
    assert np.array_equal(gps_seconds(datetime_from_gps_seconds(t)), t)


def test_lagrange_exact_for_polynomials(rng: np.random.Generator) -> None:
    tn = np.arange(20) * 900.0
    coef = rng.normal(size=10)
    x = (tn - 5000.0) / 9000.0
    vals = np.polynomial.polynomial.polyval(x, coef)
    tq = rng.uniform(0, tn[-1], 50)
    got = lagrange_interpolate(tn, vals, tq, order=9)
    ref = np.polynomial.polynomial.polyval((tq - 5000.0) / 9000.0, coef)
    assert np.abs(got - ref).max() < 1e-9 * np.abs(ref).max()
    assert np.isnan(lagrange_interpolate(tn, vals, np.array([-1.0, tn[-1] + 1]))).all()
    with pytest.raises(ModelError, match="needs 10 samples"):
        lagrange_interpolate(tn[:5], vals[:5], tq)


def test_synthetic_constellation_nominal_elements() -> None:
    sc = synthetic_gps_constellation()
    assert len(sc.svs) == 31 and "G04" not in sc.svs
    assert sc.l5_svs == tuple(f"G{p:02d}" for p in BLOCK_IIF_PRNS)
    assert np.bincount(sc.plane).tolist() == [6, 5, 5, 5, 5, 5]
    assert np.bincount(sc.plane[sc.iif]).tolist() == [2] * 6
    t = sc.epoch_gps_s + np.arange(0, 86400, 300.0)
    pos = sc.positions_ecef(t)
    r = np.linalg.norm(pos, axis=-1)
    assert np.allclose(r, r[0, 0], rtol=1e-12)
    assert r[0, 0] == pytest.approx(26_560e3, abs=5e3)
    lat, _, _ = ecef_to_geodetic(pos)
    assert np.rad2deg(np.abs(lat)).max() == pytest.approx(55.0, abs=0.3)  # geodetic vs geocentric
    # period ≈ 11 h 58 min (half a sidereal day): the inertial angle advances 2π in 2π/n
    period = 2 * np.pi / np.sqrt(GM_M3_S2 / r[0, 0] ** 3)
    assert period / 3600 == pytest.approx(11.967, abs=0.001)
    # after one sidereal day (86164.0905 s) the Earth-fixed positions repeat
    sid = 86164.0905
    p0 = sc.positions_ecef(np.array([sc.epoch_gps_s, sc.epoch_gps_s + sid]))
    assert np.linalg.norm(p0[0] - p0[1], axis=-1).max() < 50.0


def test_synthetic_subset_and_unknown() -> None:
    sc = synthetic_gps_constellation()
    sub = sc.subset(["G24", "G01"])
    assert sub.svs == ("G24", "G01")
    assert np.allclose(
        sub.positions_ecef(np.array([sc.epoch_gps_s])), sc.positions_ecef(np.array([sc.epoch_gps_s]), ["G24", "G01"])
    )
    with pytest.raises(ModelError, match="unknown satellites"):
        sc.subset(["G01", "G99"])
    assert np.isnan(sc.positions_ecef(np.array([sc.epoch_gps_s]), ["G01", "G99"])[0, 1]).all()


@pytest.fixture(scope="module")
def esbc_orbits(shared_data: Path) -> tuple[BroadcastOrbit, SP3Orbit]:
    d = shared_data / ESBC
    nav = read_navigation(d / "ESBC00DNK_R_20201770000_01D_MN.rnx.gz")
    sp3 = read_sp3([d / "GRG0MGXFIN_20201760000_01D_15M_ORB.SP3.gz", d / "GRG0MGXFIN_20201770000_01D_15M_ORB.SP3.gz"])
    return nav, sp3


def test_broadcast_against_sp3_metres(esbc_orbits: tuple[BroadcastOrbit, SP3Orbit]) -> None:
    """IS-GPS-200 propagation of the ESBC broadcast file vs GRGS final SP3, 2020-06-25, within the ±2 h fit
    interval. Broadcast orbits refer to the antenna phase centre, SP3 to the centre of mass (≈1 m apart) and
    the broadcast orbit error is ~1 m: metres-level agreement expected."""
    nav, sp3 = esbc_orbits
    t = gps_seconds(
        np.arange(np.datetime64("2020-06-25T00:00"), np.datetime64("2020-06-25T23:50"), np.timedelta64(7, "m"))
    )
    gps = [s for s in sp3.svs if s.startswith("G")]
    d = np.linalg.norm(nav.positions_ecef(t, gps) - sp3.positions_ecef(t, gps), axis=-1)
    ok = np.isfinite(d)
    assert ok.sum() > 3000  # most satellite-epochs have a record within 2 h
    rms = float(np.sqrt(np.mean(d[ok] ** 2)))
    assert 0.3 < rms < 2.5
    assert d[ok].max() < 6.0
    # a wrong propagation (e.g. Earth rotation omitted) would be off by kilometres:
    assert np.median(d[ok]) < 2.0


def test_broadcast_clock_against_sp3(shared_data: Path, esbc_orbits: tuple[BroadcastOrbit, SP3Orbit]) -> None:
    import georinex as gr

    nav, _ = esbc_orbits
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ds = gr.load(shared_data / ESBC / "GRG0MGXFIN_20201770000_01D_15M_ORB.SP3.gz")
    t = gps_seconds(ds.time.values)
    svs = [s for s in ds.sv.values.tolist() if s.startswith("G")]
    clk_sp3 = np.asarray(ds["clock"].sel(sv=svs).values) * 1e-6  # µs → s
    clk_brd = nav.clock_offsets_s(t, svs, relativistic=False)  # IGS clocks exclude the periodic term
    diff = clk_brd - clk_sp3
    ok = np.isfinite(diff) & (np.abs(clk_sp3) < 1e-2)
    # SP3 clocks and broadcast clocks differ by a constellation-wide datum offset plus ~ns errors
    per_epoch = diff - np.nanmedian(np.where(ok, diff, np.nan), axis=1, keepdims=True)
    assert ok.sum() > 1000
    assert np.sqrt(np.mean(per_epoch[ok] ** 2)) < 5e-9
    # the periodic relativistic term is F·e·√A·sin E: tens of ns for e ≈ 0.01 (hand formula, amplitude bound)
    rel = nav.clock_offsets_s(t, svs) - clk_brd
    rec = nav.records["G01"]
    amp = 4.442807633e-10 * rec["Eccentricity"][0] * rec["sqrtA"][0]
    assert np.nanmax(np.abs(rel[:, svs.index("G01")])) == pytest.approx(amp, rel=0.05)


def test_rinex2_and_rinex3_navigation_agree(shared_data: Path) -> None:
    d = shared_data / IGS
    n3 = read_navigation(d / "BRDC00IGS_R_20240100000_01D_MN.rnx.gz")
    n2 = read_navigation(d / "brdc0100.24n.gz")
    t = gps_seconds(
        np.arange(np.datetime64("2024-01-10T01:00"), np.datetime64("2024-01-10T23:00"), np.timedelta64(10, "m"))
    )
    common = [s for s in n2.svs if s in n3.svs]
    assert len(common) >= 28
    p2, p3 = n2.positions_ecef(t, common), n3.positions_ecef(t, common)
    both = np.isfinite(p2).all(-1) & np.isfinite(p3).all(-1)
    assert both.mean() > 0.9
    # the merged RINEX 3 file may hold extra (e.g. later) records: agreement within the broadcast accuracy
    assert np.median(np.linalg.norm(p2 - p3, axis=-1)[both]) < 0.01
    assert np.linalg.norm(p2 - p3, axis=-1)[both].max() < 5.0


def test_navigation_errors(tmp_path: Path) -> None:
    with pytest.raises(DataFileError, match="file not found"):
        read_navigation(tmp_path / "missing.rnx")
    bad = tmp_path / "bad.rnx"
    bad.write_text("this is not a RINEX file\n")
    with pytest.raises(DataFileError, match="bad.rnx"):
        read_navigation(bad)
    with pytest.raises(DataFileError, match="file not found"):
        read_sp3(tmp_path / "missing.sp3")
    with pytest.raises(DataFileError, match="bad.rnx"):
        read_sp3(bad)


def test_sp3_outside_span_is_nan(esbc_orbits: tuple[BroadcastOrbit, SP3Orbit]) -> None:
    _, sp3 = esbc_orbits
    assert np.isnan(sp3.positions_ecef(np.array([sp3.t_gps_s[-1] + 3600.0]), ["G01"])).all()


def test_orbit_validation_errors(esbc_orbits: tuple[BroadcastOrbit, SP3Orbit]) -> None:
    import xarray as xr

    nav, sp3 = esbc_orbits
    t = np.array([nav.records["G01"]["toe_abs_s"][0]])
    with pytest.raises(ModelError, match="none of the satellites"):
        sp3.positions_ecef(t, ["G99", "E99"])
    # BroadcastOrbit: missing fields, no GPS satellite, no healthy record
    ds = xr.Dataset(
        {"sqrtA": (("time", "sv"), np.ones((1, 1)))},
        coords={"time": [np.datetime64("2020-06-25T00:00")], "sv": ["G01"]},
    )
    with pytest.raises(DataFileError, match="not a GPS navigation file"):
        BroadcastOrbit.from_dataset(ds, source="x.nav")
    fields = {
        f: (("time", "sv"), np.ones((1, 1)))
        for f in (
            "Toe",
            "GPSWeek",
            "sqrtA",
            "Eccentricity",
            "M0",
            "DeltaN",
            "omega",
            "Omega0",
            "OmegaDot",
            "Io",
            "IDOT",
            "Cuc",
            "Cus",
            "Crc",
            "Crs",
            "Cic",
            "Cis",
            "SVclockBias",
            "SVclockDrift",
            "SVclockDriftRate",
            "TGD",
            "health",
        )
    }
    sick = xr.Dataset(fields, coords={"time": [np.datetime64("2020-06-25T00:00")], "sv": ["G01"]})
    with pytest.raises(DataFileError, match="no healthy GPS ephemeris"):
        BroadcastOrbit.from_dataset(sick, source="x.nav")
    glo = sick.assign_coords(sv=["R01"])
    with pytest.raises(DataFileError, match="no GPS ephemeris records"):
        BroadcastOrbit.from_dataset(glo, source="x.nav")
    with pytest.raises(DataFileError, match="no SP3 file"):
        SP3Orbit.from_datasets([])


def test_kepler_newton_shortcut_is_bitwise_the_twelve_steps() -> None:
    """The period-2 shortcut of the Kepler iteration gives the same bits as 12 plain Newton steps (random
    anomalies and eccentricities up to 0.3, with and without NaN)."""
    from distnav.models.gnss.orbits import _kepler_newton

    rng = np.random.default_rng(11)
    for trial in range(40):
        m = rng.uniform(-20.0, 20.0, 2000)
        e = rng.uniform(0.0, 0.3 if trial % 2 else 0.02, 2000)
        m[::97] = np.nan
        ref = m.copy()
        for _ in range(12):
            ref = ref - (ref - e * np.sin(ref) - m) / (1.0 - e * np.cos(ref))
        assert np.array_equal(_kepler_newton(m, e), ref, equal_nan=True)
        ok = np.isfinite(m)
        assert np.array_equal(_kepler_newton(m[ok], e[ok]), ref[ok])
