"""BeiDou and GLONASS DSBs through the bias pipeline (issue 32 item 5): each satellite's own frequency pair in the
model stage (the DSB scale c·10⁻⁹/(μ − 1), the geometry-free → L1-TEC factor (f_L1/f_1)²), BeiDou's first code
on band 2 read as the models' first signal, GLONASS channels from the navigation file for RINEX 2.

Independent references: the ICDs' carrier frequencies typed here (BeiDou B1I 1561.098, B3I 1268.52 MHz; GLONASS
1602 + 0.5625 k, 1246 + 0.4375 k MHz), a simulated network whose ionosphere is the delay 40.3·TEC/f_1² on each
satellite's own f_1, georinex's parse of DGAR's GLONASS codes, and the CAS product of the shared day.
"""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np
import pytest

from distnav.cli import main
from distnav.formats.gnss.rinex import read_code_observations, read_stations
from distnav.models.gnss.geometry import geodetic_to_ecef
from distnav.models.gnss.gfnetwork import (
    BiasFilterOptions,
    BiasModelOptions,
    GeometryFreeNetwork,
    bias_network_model,
    run_bias_filters,
)
from distnav.models.gnss.ionosphere import GeometryOptions, ionosphere_geometry
from distnav.models.gnss.orbits import gps_seconds, synthetic_gps_constellation
from distnav.models.gnss.systems import signal_pair_frequencies_hz

IGS = "gnss/igs_2024010_bele_dgar"
BELE = f"{IGS}/BELE00BRA_R_20240100000_01D_30S_MO.crx.gz"
DGAR = f"{IGS}/dgar0100.24o.gz"
BRDC = f"{IGS}/BRDC00IGS_R_20240100000_01D_MN.rnx.gz"
CAS = f"{IGS}/CAS0OPSRAP_20240100000_01D_01D_DCB.BIA.gz"
C_NS_M = 0.299792458
NAMES = ["A", "B", "C"]


def test_frequency_pairs_from_the_icds() -> None:
    f1, f2 = signal_pair_frequencies_hz(["C20", "C30"], "C2I", "C7I")
    np.testing.assert_array_equal(f1, [1561.098e6] * 2)
    np.testing.assert_array_equal(f2, [1207.14e6] * 2)
    channels = {f"R{k:02d}": c for k, c in zip(range(1, 15), range(-7, 7), strict=True)}
    f1, f2 = signal_pair_frequencies_hz(sorted(channels), "C1P", "C2C", channels)
    k = np.array([channels[s] for s in sorted(channels)], float)
    np.testing.assert_allclose(f1, 1602e6 + 0.5625e6 * k, rtol=0, atol=1e-3)
    np.testing.assert_allclose(f2, 1246e6 + 0.4375e6 * k, rtol=0, atol=1e-3)
    np.testing.assert_allclose((f1 / f2) ** 2, (9 / 7) ** 2, rtol=1e-12)  # one μ for every channel
    assert np.isnan(signal_pair_frequencies_hz(["R26"], "C1C", "C2C", channels)[0]).all()  # no channel: NaN


def _glonass_like(seed: int, l1_per_satellite: bool) -> tuple[float, float]:
    """A 3-receiver network on GPS geometry whose satellites transmit on GLONASS channels: the geometry-free code
    carries the delay on each satellite's own f_1. Returns RMS((estimate − truth)/σ) of the zero-mean satellite and
    receiver DSBs and RMS of the satellites' error [ns]; ``l1_per_satellite=False`` tells the model one f_1."""
    rng = np.random.default_rng(seed)
    gps = synthetic_gps_constellation()
    t = gps_seconds(np.datetime64("2016-06-02T00:00")) + 60.0 * np.arange(40)
    xyz = geodetic_to_ecef(np.deg2rad([-1.4, -1.5, -1.0]), np.deg2rad([-48.5, -48.0, -48.2]), np.zeros(3))
    geo = ionosphere_geometry(gps, t, receivers_ecef_m=xyz, names=NAMES, options=GeometryOptions(mask_deg=10))
    T, n, S = geo.tracked.shape
    k = rng.integers(-7, 7, S).astype(float)
    f1, f2 = 1602e6 + 0.5625e6 * k, 1246e6 + 0.4375e6 * k
    scale = C_NS_M / ((9 / 7) ** 2 - 1)  # m of (P2 − P1)/(μ − 1) per ns of C1−C2 DSB
    d_rx, d_s = rng.normal(0, 5, n), rng.normal(0, 3, S)
    vtec_l1_m = 20.0  # an equatorial afternoon: ~120 TECU
    delay_f1 = geo.coefficients[..., 0] * vtec_l1_m * (1575.42e6 / f1) ** 2  # 40.3·TEC/f_1² on the own f_1
    sig = 0.01 / np.sin(np.where(geo.tracked, geo.el_rad, np.pi / 2))
    y = delay_f1 - scale * (d_rx[None, :, None] + d_s[None, None, :]) + sig * rng.standard_normal((T, n, S))
    y[~geo.tracked] = np.nan
    told = (f1, f2) if l1_per_satellite else (np.full(S, 1602e6), np.full(S, 1246e6))
    net = GeometryFreeNetwork(NAMES, t, xyz, y, list(gps.svs), frequencies_hz=told)
    data = bias_network_model(net, gps, BiasModelOptions(ionosphere="common", sigma_zenith_m=0.01))
    assert data.dsb_scale_m_per_ns == pytest.approx(scale, rel=1e-12)
    (c,), _ = run_bias_filters(data, BiasFilterOptions(datum="zero-mean", local=False))
    kept = [list(gps.svs).index(s) for s in data.layout.svs]
    truth = np.concatenate([d_rx + d_s[kept].mean(), d_s[kept] - d_s[kept].mean()])
    z = (c.dsb_ns[-1] - truth) / c.dsb_std_ns[-1]
    return float(np.sqrt(np.mean(z**2))), float(np.sqrt(np.mean((c.dsb_ns[-1, n:] - truth[n:]) ** 2)))


def test_glonass_channels_own_l1_factor_recovers_the_truth() -> None:
    """With each satellite's f_1 the DSBs match the truth within their σ; telling the model one f_1 for all
    channels leaves the channels' ±0.5 % of the slant delay (f_1 from 1598 to 1605 MHz) in the DSBs."""
    right = [_glonass_like(seed, True) for seed in range(6)]
    wrong = [_glonass_like(seed, False) for seed in range(6)]
    rms_z = float(np.sqrt(np.mean([r[0] ** 2 for r in right])))
    assert 0.6 < rms_z < 1.4
    assert np.median([w[1] for w in wrong]) > 4.0 * np.median([r[1] for r in right])


def test_mixed_frequency_ratios_are_refused() -> None:
    gps = synthetic_gps_constellation()
    t = gps_seconds(np.datetime64("2016-06-02T00:00")) + 60.0 * np.arange(5)
    xyz = geodetic_to_ecef(np.deg2rad([50.0]), np.deg2rad([10.0]), np.zeros(1))
    S = len(gps.svs)
    f2 = np.where(np.arange(S) % 2 == 0, 1268.52e6, 1207.14e6)  # B3I and B2I mixed
    net = GeometryFreeNetwork(
        ["A"], t, xyz, np.full((5, 1, S), 1.0), list(gps.svs), frequencies_hz=(np.full(S, 1561.098e6), f2)
    )
    with pytest.raises(Exception, match="frequency ratio"):
        bias_network_model(net, gps, BiasModelOptions(min_satellite_obs=1))


def test_beidou_first_code_on_band_2_is_the_first_signal(shared_data: Path) -> None:
    window = ("2024-01-10T03:00", "2024-01-10T03:30")
    (o,) = read_stations([shared_data / BELE], l1_code="C2I", l2_code="C6I", tlim=window, phases=True, system="C")
    raw = read_code_observations(shared_data / BELE, bands=(2, 6), tlim=window, phases=True, system="C")
    assert o.codes == {1: "C2I", 6: "C6I"}
    np.testing.assert_array_equal(o.range_m[1], raw.range_m[2])
    np.testing.assert_array_equal(o.phase_m[1], raw.phase_m[2])
    f1, f6 = o.frequencies_hz(6)
    np.testing.assert_array_equal(f1, 1561.098e6)
    np.testing.assert_array_equal(f6, 1268.52e6)
    # the B1I phase in metres follows the B1I code over 30 min (a wrong wavelength drifts by ~1 % of the range change)
    d = o.phase_m[1] - o.range_m[1]
    drift = np.nanmax(np.abs(d - np.nanmedian(d, axis=0)), axis=0)
    assert np.nanmedian(drift) < 10.0


def test_dgar_rinex2_glonass_equal_georinex_with_channels_from_navigation(shared_data: Path) -> None:
    gr = pytest.importorskip("georinex")
    from distnav.formats.gnss.rinex_nav import read_glonass_ephemerides
    from distnav.models.gnss.glonass import GlonassOrbit

    channels = GlonassOrbit.from_records(read_glonass_ephemerides(shared_data / BRDC)).channels()
    window = ("2024-01-10T06:00", "2024-01-10T06:10")
    o = read_code_observations(
        shared_data / DGAR, bands=(1, 2), tlim=window, phases=True, system="R", channels=channels
    )
    assert o.codes == {1: "C1C", 2: "C2C"} and not any("read as" in n for n in o.notes)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ref = gr.load(shared_data / DGAR, use="R", tlim=window, meas=["C1", "C2", "L1"])
    for j, sv in enumerate(o.svs):
        np.testing.assert_allclose(o.range_m[1][:, j], ref["C1"].sel(sv=sv).values, rtol=0, atol=1e-3)
        np.testing.assert_allclose(o.range_m[2][:, j], ref["C2"].sel(sv=sv).values, rtol=0, atol=1e-3)
        if sv not in channels:  # R25: no healthy record in the navigation file, so no channel: no phase in metres
            assert np.isnan(o.phase_m[1][:, j]).all()
            continue
        lam = 299792458.0 / (1602e6 + 0.5625e6 * channels[sv])
        np.testing.assert_allclose(o.phase_m[1][:, j], ref["L1"].sel(sv=sv).values * lam, rtol=1e-12, atol=1e-6)
    assert o.channels == {sv: channels[sv] for sv in o.svs if sv in channels}


@pytest.mark.parametrize(
    ("system", "codes", "stop", "max_rms_ns"),
    [("C", ("C2I", "C6I"), "08:00", 2.0), ("R", ("C1C", "C2C"), None, 3.0)],
)
def test_beidou_and_glonass_dsbs_from_bele_against_cas(
    shared_data: Path,
    tmp_path: Path,
    request: pytest.FixtureRequest,
    system: str,
    codes: tuple[str, str],
    stop: str | None,
    max_rms_ns: float,
) -> None:
    """End to end on BELE (BeiDou 8 h, GLONASS the day): the DSBs of the system's own code pair, compared with
    CAS's (datum-aligned; docs/gnss.md has the day's figures and what limits one station). GLONASS's day is the
    session's run (conftest.bele_glonass_day), which test_gnss_sigmaterms checks too."""
    if stop is None:
        out = request.getfixturevalue("bele_glonass_day")
    else:
        out = tmp_path / system
        args = ["gnss", "ionosphere", "--system", system, "--obs", str(shared_data / BELE)]
        args += ["--nav", str(shared_data / BRDC), "--l1-code", codes[0], "--l2-code", codes[1]]
        args += ["--tlim", "2024-01-10T00:00", f"2024-01-10T{stop}"]
        assert main([*args, "--bias", str(shared_data / CAS), "--out", str(out), "--no-progress", "--kn", "0"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["station_codes"]["BELE"] == list(codes)
    (cmp,) = summary["comparison"].values()
    central = cmp["central"]
    assert central["n"] >= 8 and all(s.startswith(system) for s in central["difference_ns"])
    assert central["rms_zero_mean_ns"] < max_rms_ns
    bia = (out / "distnav_dsb.bia").read_text()
    assert f" {codes[0]}  {codes[1]} " in bia
    if system == "R":  # BELE's C1C−C2C IFB pattern: the channel means carry most of the difference to CAS
        ch = central["glonass_channels"]
        assert ch["satellites"] == central["n"] and ch["channels"] <= central["n"]
        total = ch["channel_means_rms_ns"] ** 2 + ch["within_channel_rms_ns"] ** 2
        assert total == pytest.approx(central["rms_zero_mean_ns"] ** 2, rel=1e-9)  # the split is complete
        assert ch["channel_means_rms_ns"] > 2.0 * ch["within_channel_rms_ns"]


def test_channel_pattern_splits_by_channel() -> None:
    from distnav.models.gnss.products import channel_pattern

    f1 = {f"R{k:02d}": 1602e6 + 0.5625e6 * c for k, c in ((1, 1), (5, 1), (2, -4), (6, -4), (3, 5))}
    out = channel_pattern({"R01": 2.0, "R05": 1.0, "R02": -1.0, "R06": -2.0, "R03": 0.0}, f1)
    assert out["per_channel_ns"] == {-4: -1.5, 1: 1.5, 5: 0.0}
    assert out["within_channel_rms_ns"] == pytest.approx(np.sqrt(4 * 0.25 / 5))
    assert out["channel_means_rms_ns"] == pytest.approx(np.sqrt(4 * 2.25 / 5))
    assert channel_pattern({"G01": 1.0}, {}) == {}


@pytest.mark.parametrize(
    ("system", "args", "message"),
    [
        ("C", ["--l1-code", "C1C", "--l2-code", "C6I"], "--l1-code C1C: not a BeiDou B1I code"),
        ("C", ["--l1-code", "C2I", "--l2-code", "C2W"], "--l2-code C2W: not a BeiDou B3I or B2I code"),
        ("R", ["--l1-code", "C1C", "--l2-code", "C5Q"], "--l2-code C5Q: not a GLONASS G2 code"),
        ("R", ["--l1-code", "C1C", "--l2-code", "C2C", "--pivot", "R30", "--datum", "pivot"], "not a GLONASS sat"),
    ],
)
def test_beidou_and_glonass_options_checked_before_reading(
    shared_data: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str], system: str, args: list[str], message: str
) -> None:
    base = [
        "gnss",
        "ionosphere",
        "--system",
        system,
        "--obs",
        str(shared_data / BELE),
        "--nav",
        str(shared_data / BRDC),
    ]
    assert main([*base, *args, "--out", str(tmp_path / "x"), "--no-progress"]) == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "x").exists()
