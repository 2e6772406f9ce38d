"""Galileo and BeiDou broadcast orbits (models/gnss/systems, orbits, formats/gnss/rinex_nav) on the shared day.

Independent references: georinex's parse of the same navigation records; the published slots of the BeiDou
GEO satellites (geostationary: 42,164 km, latitude within the ~2° inclination, longitude fixed over the day);
and BELE's own ionosphere-free pseudo-ranges, which the broadcast orbit and clock must reproduce within the
troposphere's metres (a 14-s BDT slip would put a satellite ~40 km off, a missed GEO rotation thousands).
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from distnav.formats.gnss.rinex import read_code_observations, read_navigation, read_sp3
from distnav.formats.gnss.rinex_nav import read_ephemerides
from distnav.models.gnss.constants import C_M_S
from distnav.models.gnss.geometry import azimuth_elevation, ecef_to_geodetic
from distnav.models.gnss.orbits import _kepler_position, gps_seconds
from distnav.models.gnss.systems import ORBIT_CONSTANTS, carrier_frequencies_hz, is_beidou_geo

IGS = "gnss/igs_2024010_bele_dgar"
BRDC = f"{IGS}/BRDC00IGS_R_20240100000_01D_MN.rnx.gz"
BELE = f"{IGS}/BELE00BRA_R_20240100000_01D_30S_MO.crx.gz"
KEPLER = ("sqrtA", "Eccentricity", "M0", "DeltaN", "omega", "Omega0", "OmegaDot", "Io", "IDOT", "Cuc", "Cus")
KEPLER += ("Crc", "Crs", "Cic", "Cis", "SVclockBias", "SVclockDrift", "Toe")


@pytest.mark.parametrize("system", ["E", "C"])
def test_records_equal_georinex(shared_data: Path, system: str) -> None:
    gr = pytest.importorskip("georinex")
    path = shared_data / BRDC
    ours = read_ephemerides(path, systems=(system,))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        nav = gr.load(path, use=system)
    toc = gps_seconds(nav.time.values) + (14.0 if system == "C" else 0.0)  # BDT time of clock → GPS seconds
    n = 0
    for sv, cols in ours.items():
        sub = nav.sel(sv=sv)  # georinex's first record per time of clock (Galileo I/NAV + F/NAV: E05, E05_1 …)
        table = np.stack([sub[f].values for f in KEPLER], axis=-1)
        rows = np.flatnonzero(~np.isnan(table).all(axis=1))
        np.testing.assert_array_equal(cols["toc_s"], toc[rows])
        for j, f in enumerate(KEPLER):
            np.testing.assert_array_equal(cols[f], table[rows, j], err_msg=f"{sv} {f}")
        n += rows.size
    assert len(ours) >= 25 and n > 1000
    assert all(s[0] == system for s in ours)


def test_beidou_geo_at_their_slots(shared_data: Path) -> None:
    orbit = read_navigation(shared_data / BRDC, systems=("C",), max_age_s=4 * 3600.0)
    geo = ["C01", "C02", "C03", "C04", "C05"]
    assert all(is_beidou_geo(s) for s in geo) and not is_beidou_geo("C11")
    t = gps_seconds(np.datetime64("2024-01-10T00:00")) + 1800.0 * np.arange(48)
    pos = orbit.positions_ecef(t, geo)
    lat, lon, _ = ecef_to_geodetic(pos.reshape(-1, 3))
    lat_deg, lon_deg = np.rad2deg(lat).reshape(48, 5), np.rad2deg(lon).reshape(48, 5)
    assert np.all(np.abs(np.linalg.norm(pos, axis=-1) - 42_164e3) < 60e3)
    assert np.all(np.abs(lat_deg) < 2.5)
    # published slots (CSNO): C01 140° E (drifted to ~144.5°), C02 84° E, C03 110.5° E, C04 160° E, C05 58.75° E
    slots = np.array([144.5, 84.0, 110.5, 160.0, 58.75])
    assert np.all(np.abs(lon_deg - slots) < 0.6)
    # the MEO formula on the same GEO records (no −5° tilt, no GEO rotation) puts them thousands of km off
    rec = orbit.records["C03"]
    sel = {k: v[:1] for k, v in rec.items()}
    tk = np.array([600.0])
    right, _ = _kepler_position(sel, tk, sel["Toe"], "C", geo=True)
    wrong, _ = _kepler_position(sel, tk, sel["Toe"], "C", geo=False)
    assert np.linalg.norm(right - wrong) > 1000e3


@pytest.mark.parametrize("system,bands", [("E", (1, 5)), ("C", (2, 6)), ("G", (1, 2))])
def test_broadcast_orbits_reproduce_bele_pseudoranges(shared_data: Path, system: str, bands: tuple[int, int]) -> None:
    """Ionosphere-free code − geometric range (signal travel time, Earth rotation) + satellite clock, minus the
    receiver clock (median over the satellites of each epoch): within 15 m above 20° (troposphere, multipath)."""
    window = (np.datetime64("2024-01-10T03:00"), np.datetime64("2024-01-10T03:10"))  # 8 BeiDou in view
    o = read_code_observations(shared_data / BELE, bands=bands, system=system, tlim=window)
    orbit = read_navigation(shared_data / BRDC, systems=(system,), max_age_s=4 * 3600.0)
    f1 = carrier_frequencies_hz(system, bands[0], o.svs)
    f2 = carrier_frequencies_hz(system, bands[1], o.svs)
    p_if = (f1**2 * o.range_m[bands[0]] - f2**2 * o.range_m[bands[1]]) / (f1**2 - f2**2)
    t = gps_seconds(o.time)
    svs = [s for s in o.svs if s in orbit.records]
    cols = [o.svs.index(s) for s in svs]
    p_if = p_if[:, cols]
    pos_at = lambda tt, k: orbit.positions_ecef(tt, [svs[k]])[:, 0]  # noqa: E731 - small local adapters
    clk_at = lambda tt, k: orbit.clock_offsets_s(tt, [svs[k]])[:, 0]  # noqa: E731
    res = _code_residuals_m(p_if, t, o.position_ecef_m, pos_at, clk_at, ORBIT_CONSTANTS[system][1])
    n = np.isfinite(res).sum(axis=0)
    assert (n > 10).sum() >= 4, f"{system}: too few satellites above 20°"
    assert np.nanmax(np.abs(res)) < 15.0, dict(zip(svs, np.nanmax(np.abs(res), axis=0).round(1), strict=True))


def _whitespace_dsbs(path: Path, obs1: str, obs2: str) -> tuple[dict[str, float], dict[tuple[str, str], float]]:
    """A second parser of a Bias-SINEX file (gzip too): whitespace tokens of +BIAS/SOLUTION only (10 tokens =
    satellite line, 11 = station line); satellite and (station, system) DSBs ``obs1 − obs2`` [ns]."""
    import gzip

    raw = path.read_bytes()
    text = (gzip.decompress(raw) if raw[:2] == b"\x1f\x8b" else raw).decode("latin-1")
    inside, sat, sta = False, {}, {}
    for ln in text.splitlines():
        if ln.startswith("+BIAS/SOLUTION"):
            inside = True
        elif ln.startswith("-BIAS/SOLUTION"):
            inside = False
        elif inside and ln.startswith(" DSB"):
            tok = ln.split()
            if len(tok) == 10 and (tok[3], tok[4]) == (obs1, obs2):
                sat[tok[2]] = float(tok[8])
            elif len(tok) == 11 and (tok[4], tok[5]) == (obs1, obs2):
                sta[(tok[3], tok[1])] = float(tok[9])
    return sat, sta


def _rms_zero_mean(a: dict[str, float], b: dict[str, float]) -> tuple[float, int]:
    common = sorted(set(a) & set(b))
    d = np.array([a[s] - b[s] for s in common])
    return float(np.sqrt(np.mean((d - d.mean()) ** 2))), len(common)


def test_compare_reports_each_system(shared_data: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``gnss compare`` of CAS day 010 against CAS day 011: one table per system, each RMS as the whitespace
    parser's (CAS's own day-to-day repeatability: Galileo C1C−C5Q 0.18 ns, BeiDou C2I−C6I 0.11 ns)."""
    import json

    from distnav.cli import main

    cas10, cas11 = (shared_data / IGS / f"CAS0OPSRAP_202401{d}0000_01D_01D_DCB.BIA.gz" for d in ("0", "1"))
    rc = main(
        ["gnss", "compare", "--estimates", str(cas10), "--bias", str(cas11), "--allow-other-day"]
        + ["--out", str(tmp_path)]
    )
    assert rc == 0
    out = capsys.readouterr().out
    assert "--- Galileo (25 satellites) ---" in out and "--- BeiDou (42 satellites) ---" in out
    result = json.loads((tmp_path / "comparison.json").read_text())
    assert list(result["systems"]) == ["G", "R", "E", "C", "J"]
    for system, (o1, o2) in {"E": ("C1C", "C5Q"), "C": ("C2I", "C6I"), "R": ("C1C", "C1P")}.items():
        r = result["systems"][system]
        assert r["codes"] == [o1, o2]
        (cmp,) = r["products"].values()
        a, b = (
            {k: v for k, v in _whitespace_dsbs(f, o1, o2)[0].items() if k[0] == system} for f in (cas10, cas11)
        )  # (GPS satellites have C1C−C5Q DSBs too)
        ref, n = _rms_zero_mean(a, b)
        assert cmp["n"] == n and cmp["rms_zero_mean_ns"] == pytest.approx(ref, abs=1e-9)
    assert result["codes"] == result["systems"]["G"]["codes"]  # the first table stays GPS's, as before


def test_galileo_dsbs_from_bele(shared_data: Path, tmp_path: Path) -> None:
    """``gnss ionosphere --system E`` on BELE (8 h): Galileo C1X−C5X satellite and receiver DSBs, written with the
    receiver's system letter E, compared with CAS by our own whitespace parse. One equatorial station: the
    ionosphere and the DSBs separate poorly (GPS C1C−C5X from BELE alone: 2.2 ns RMS vs CAS on the full day),
    so the bound is loose; a wrong frequency factor (E5b's) or a sign error gives ≥ 5 ns."""
    from distnav.cli import main
    from distnav.formats.gnss.product_files import read_estimates

    cas = shared_data / IGS / "CAS0OPSRAP_20240100000_01D_01D_DCB.BIA.gz"
    rc = main(
        ["gnss", "ionosphere", "--system", "E", "--obs", str(shared_data / BELE), "--nav", str(shared_data / BRDC)]
        + ["--l1-code", "C1X", "--l2-code", "C5X", "--tlim", "2024-01-10T00:00", "2024-01-10T08:00"]
        + ["--out", str(tmp_path / "gal"), "--no-progress", "--kn", "0"]
    )
    assert rc == 0
    sat_cas, sta_cas = _whitespace_dsbs(cas, "C1X", "C5X")
    ours_sat, ours_sta = _whitespace_dsbs(tmp_path / "gal" / "distnav_dsb.bia", "C1X", "C5X")
    assert set(ours_sat) and all(s.startswith("E") for s in ours_sat)
    assert set(ours_sta) == {("BELE", "E")}  # the receiver's Galileo DSB, system letter E
    rms, n = _rms_zero_mean(ours_sat, sat_cas)
    assert n >= 8 and rms < 2.5, (n, rms)
    est = read_estimates(tmp_path / "gal" / "distnav_dsb.bia", system="E")
    assert (est.obs1, est.obs2) == ("C1X", "C5X") and est.satellite == pytest.approx(ours_sat, abs=1e-4)
    # the receiver DSB after the same datum shift as the satellites: within a few ns of CAS's +9.97 ns
    common = sorted(set(ours_sat) & set(sat_cas))
    shift = float(np.mean([ours_sat[s] - sat_cas[s] for s in common]))
    assert abs(ours_sta[("BELE", "E")] + shift - sta_cas[("BELE", "E")]) < 7.0


def test_system_option_checks_codes_first(
    shared_data: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from distnav.cli import main

    base = ["gnss", "ionosphere", "--system", "E", "--obs", str(shared_data / BELE), "--nav", str(shared_data / BRDC)]
    assert main([*base, "--l2-code", "C2W", "--out", str(tmp_path / "x")]) == 2
    assert "--l2-code C2W: not a Galileo E5a, E5b or E5 code" in capsys.readouterr().err
    assert main([*base, "--l2-code", "C5X", "--exclude", "G05", "--out", str(tmp_path / "x")]) == 2
    assert "--exclude G05: neither a Galileo satellite" in capsys.readouterr().err
    assert not (tmp_path / "x").exists()


def test_galileo_broadcast_against_precise_orbits(shared_data: Path) -> None:
    """Galileo broadcast orbits of ESBC 2020-177's mixed navigation file against GRGS's final multi-GNSS SP3 (an
    independent product; centre of mass vs the broadcast antenna phase centre ≈ 1 m): 1.0 m RMS when each
    record is used from its time of ephemeris on; 2.6 m (8 m 1–2 h before toe) with the nearest record, as GPS."""
    d = shared_data / "gnss/esbc_2020177_single_station_L5_sp3"
    nav = read_navigation(d / "ESBC00DNK_R_20201770000_01D_MN.rnx.gz", systems=("E",), max_age_s=2 * 3600.0)
    sp3 = read_sp3([d / f"GRG0MGXFIN_2020{day}0000_01D_15M_ORB.SP3.gz" for day in ("176", "177")], system="E")
    t = gps_seconds(np.datetime64("2020-06-25T00:00")) + 300.0 * np.arange(288)
    svs = [s for s in nav.svs if s in sp3.svs]
    dist = np.linalg.norm(nav.positions_ecef(t, svs) - sp3.positions_ecef(t, svs), axis=-1)
    ok = np.isfinite(dist)
    assert len(svs) >= 20 and ok.sum() > 3000
    assert np.sqrt(np.mean(dist[ok] ** 2)) < 1.3
    assert np.percentile(dist[ok], 99) < 5.0


def test_glonass_state_vectors_integrated(shared_data: Path) -> None:
    """GLONASS records (RINEX 2 ``brdc0100.24g`` and the RINEX 3 mixed file give the same records): each one
    integrated 30 min to the next record's t_b lands within 10 m of it (an independent broadcast state), and
    BELE's ionosphere-free GLONASS pseudo-ranges (each satellite's FDMA frequencies) are reproduced within 15 m
    above 20° after the receiver clock (Earth rotation, satellite clock −τ_n; a wrong leap second would be 50 m)."""
    from distnav.formats.gnss.rinex_nav import read_glonass_ephemerides
    from distnav.models.gnss.glonass import OMEGA_PZ90_RAD_S, GlonassOrbit, integrate_state

    r2 = read_glonass_ephemerides(shared_data / IGS / "brdc0100.24g.gz")
    r3 = read_glonass_ephemerides(shared_data / BRDC)
    assert len(r2) >= 22 and set(r2) == set(r3)
    common = np.intersect1d(r2["R01"]["tb_gps_s"], r3["R01"]["tb_gps_s"])
    assert common.size > 40
    i2, i3 = (np.searchsorted(r["R01"]["tb_gps_s"], common) for r in (r2, r3))
    np.testing.assert_allclose(r2["R01"]["state"][i2], r3["R01"]["state"][i3], rtol=0, atol=1e-3)
    worst = 0.0
    orbit = GlonassOrbit.from_records(r2)
    for rec in orbit.records.values():
        dt = np.diff(rec["tb_gps_s"])
        nxt = dt == 1800.0
        s = integrate_state(rec["state"][:-1][nxt], rec["accel"][:-1][nxt], dt[nxt])
        worst = max(worst, float(np.max(np.linalg.norm(s[:, :3] - rec["state"][1:][nxt, :3], axis=1))))
    assert worst < 10.0, worst

    window = (np.datetime64("2024-01-10T03:00"), np.datetime64("2024-01-10T03:10"))
    o = read_code_observations(shared_data / BELE, bands=(1, 2), system="R", tlim=window)
    from distnav.formats.gnss.rinex_obs import read_header

    channels = read_header(shared_data / BELE).glonass_channels
    f1, f2 = (carrier_frequencies_hz("R", b, o.svs, channels) for b in (1, 2))
    p_if = (f1**2 * o.range_m[1] - f2**2 * o.range_m[2]) / (f1**2 - f2**2)
    t = gps_seconds(o.time)
    orbit = GlonassOrbit.from_records(r2)

    def pos_at(tt: np.ndarray, k: int) -> np.ndarray:
        return orbit.positions_ecef(tt, [o.svs[k]])[:, 0]

    def clk_at(tt: np.ndarray, k: int) -> np.ndarray:
        rec = r2.get(o.svs[k])
        return np.full(tt.size, np.nan) if rec is None else np.interp(tt, rec["tb_gps_s"], rec["clock_bias_s"])

    res = _code_residuals_m(p_if, t, o.position_ecef_m, pos_at, clk_at, OMEGA_PZ90_RAD_S)
    assert (np.isfinite(res).sum(axis=0) > 10).sum() >= 4
    assert np.nanmax(np.abs(res)) < 15.0, np.nanmax(np.abs(res), axis=0).round(1)


def _code_residuals_m(
    p_if: np.ndarray,
    t: np.ndarray,
    rx: np.ndarray,
    position_at: Callable[[np.ndarray, int], np.ndarray],
    clock_at: Callable[[np.ndarray, int], np.ndarray],
    omega_e: float,
) -> np.ndarray:
    """Ionosphere-free code (T, S) − geometric range at the transmission time (the Earth turning by ω_E τ while
    the signal travels) + c × satellite clock, minus the per-epoch median (the receiver clock); NaN below 20°."""
    tau = np.where(np.isfinite(p_if), p_if, 2.2e7) / C_M_S
    pos = np.stack([position_at(t - tau[:, k], k) for k in range(p_if.shape[1])], axis=1)
    clk = np.stack([clock_at(t - tau[:, k], k) for k in range(p_if.shape[1])], axis=1)
    ang = omega_e * tau
    x = np.cos(ang) * pos[..., 0] + np.sin(ang) * pos[..., 1]
    y = -np.sin(ang) * pos[..., 0] + np.cos(ang) * pos[..., 1]
    rho = np.linalg.norm(np.stack([x, y, pos[..., 2]], axis=-1) - rx, axis=-1)
    _, el = azimuth_elevation(rx, pos)
    res = p_if - rho + C_M_S * clk
    res[~(el > np.deg2rad(20.0))] = np.nan
    out: np.ndarray = res - np.nanmedian(res, axis=1, keepdims=True)
    return out
