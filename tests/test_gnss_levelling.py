"""Carrier-to-code levelling: arcs, cycle slips (geometry-free phase, Melbourne–Wübbena), screening, real data."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from distnav.algorithms.statistics import data_snooping
from distnav.errors import ModelError
from distnav.models.gnss.constants import C_M_S, F_L1_HZ, F_L2_HZ, mu
from distnav.models.gnss.levelling import (
    LevellingOptions,
    find_arcs,
    level_station,
    melbourne_wubbena_cycles,
    screen_arc,
)

L1, L2 = C_M_S / F_L1_HZ, C_M_S / F_L2_HZ


def _one_satellite(rng: np.random.Generator, T: int = 240, code_sigma: float = 0.3):
    """Range, a smooth ionosphere, codes with noise, phases with ambiguities (metres) for one satellite, 30 s."""
    t = 30.0 * np.arange(T)
    rho = 2.2e7 + 500.0 * np.sin(t / 3000.0)
    iono = 3.0 + 1.5 * np.sin(t / 5000.0)  # L1 slant delay [m]
    p1 = rho + iono + 1.0 + code_sigma * rng.standard_normal(T)
    p2 = rho + mu(2) * iono - 2.0 + code_sigma * rng.standard_normal(T)
    n1, n2 = np.full(T, 1.0e6 * L1), np.full(T, 1.1e6 * L2)
    return t, rho, iono, p1, p2, n1, n2


@pytest.mark.parametrize("slip", [(1, 0), (0, 1), (1, 1), (9, 7)])
def test_slips_start_new_arcs(rng: np.random.Generator, slip: tuple[int, int]) -> None:
    t, rho, iono, p1, p2, n1, n2 = _one_satellite(rng)
    k = 120
    n1[k:] += slip[0] * L1
    n2[k:] += slip[1] * L2
    phi1 = rho - iono + n1 + 0.002 * rng.standard_normal(t.size)
    phi2 = rho - mu(2) * iono + n2 + 0.002 * rng.standard_normal(t.size)
    lev = level_station(
        t, ("G01",), p1[:, None], p2[:, None], phi1[:, None], phi2[:, None], options=LevellingOptions(screen=False)
    )
    assert len(lev.arcs) == 2 and lev.arcs[1].first == k and lev.arcs[1].start_reason in ("gf", "mw")
    # each arc's level equals the code's: the levelled observable is the ionosphere + the code bias (−3 m/(μ−1))
    truth = iono + (-2.0 - 1.0) / (mu(2) - 1.0)
    err = lev.gf_m[:, 0] - truth
    for a in lev.arcs:
        seg = err[a.first : a.last + 1]
        assert abs(seg.mean()) < 4 * a.offset_std_m + 1e-3 and seg.std() < 0.01


def test_no_false_slips_gaps_and_lli(rng: np.random.Generator) -> None:
    t, rho, iono, p1, p2, n1, n2 = _one_satellite(rng)
    phi1, phi2 = rho - iono + n1, rho - mu(2) * iono + n2
    g = (phi1 - phi2) / (mu(2) - 1.0)
    mw = melbourne_wubbena_cycles(p1, p2, phi1, phi2)
    arc, outlier, reasons = find_arcs(t, g, mw)
    assert reasons == ["first"] and (arc == 0).all() and not outlier.any()
    g2 = g.copy()
    g2[100:110] = np.nan  # a 5-minute gap
    lli = np.zeros(t.size, np.int8)
    lli[200] = 1
    arc, _, reasons = find_arcs(t, g2, mw, lli)
    assert reasons == ["first", "gap", "lli"] and arc[110] == 1 and arc[200] == 2


def test_short_arcs_dropped_and_mw_outlier_removed(rng: np.random.Generator) -> None:
    t, rho, iono, p1, p2, n1, n2 = _one_satellite(rng, T=60)
    phi1, phi2 = rho - iono + n1, rho - mu(2) * iono + n2
    p1[30] += 15.0  # one wild code value: an MW outlier, not a slip
    lev = level_station(
        t, ("G01",), p1[:, None], p2[:, None], phi1[:, None], phi2[:, None], options=LevellingOptions(screen=False)
    )
    assert len(lev.arcs) == 1 and lev.removed[30, 0] and np.isnan(lev.gf_m[30, 0])
    lev = level_station(t[:8], ("G01",), p1[:8, None], p2[:8, None], phi1[:8, None], phi2[:8, None])
    assert lev.arcs == [] and lev.dropped_short == 1 and np.isnan(lev.gf_m).all()


def test_screening_equals_centralized_data_snooping(rng: np.random.Generator) -> None:
    """One arc's screening (a weighted mean with w-tests, a-priori σ) removes what the centralized reference
    data_snooping of distnav.algorithms.statistics removes, and gives its offset."""
    m = 150
    sigma = 0.3 / np.sin(np.linspace(0.3, 1.4, m))
    d = 2.0 + sigma * rng.standard_normal(m)
    bad = [10, 77, 140]
    d[bad] += np.array([6.0, -5.0, 8.0]) * sigma[bad]
    keep, off, off_sd, w = screen_arc(d, sigma, scale="apriori")
    ref = data_snooping(np.ones((m, 1)), d, sigma**2, level=0.001)
    assert sorted(ref.removed) == sorted(np.flatnonzero(~keep).tolist())
    assert set(bad) <= set(ref.removed)
    assert off == pytest.approx(float(ref.x[0]), abs=1e-10)
    assert off_sd == pytest.approx(np.sqrt(ref.covariance[0, 0]), rel=1e-8)
    np.testing.assert_allclose(w[keep], ref.w[keep], rtol=1e-8)
    assert np.isnan(w[~keep]).all()


def test_real_rinex_levelled_noise_far_below_raw(shared_data: Path) -> None:
    from distnav.formats.gnss.rinex import read_code_observations
    from distnav.models.gnss.orbits import gps_seconds

    o = read_code_observations(
        shared_data / "gnss/igs_2024010_bele_dgar/dgar0100.24o.gz",
        bands=(1, 2),
        phases=True,
        tlim=("2024-01-10T06:00", "2024-01-10T09:00"),
    )
    lev = level_station(
        gps_seconds(o.time), o.svs, o.range_m[1], o.range_m[2], o.phase_m[1], o.phase_m[2], lli=o.lli[1] | o.lli[2]
    )
    raw = (o.range_m[2] - o.range_m[1]) / (mu(2) - 1.0)
    step_raw = np.sqrt(np.nanmean(np.diff(raw, axis=0) ** 2))
    step_lev = np.sqrt(np.nanmean(np.diff(lev.gf_m, axis=0) ** 2))
    assert step_lev < step_raw / 10  # measured: 0.02–0.04 m vs ≈ 0.9 m
    assert len(lev.arcs) >= 10 and np.isfinite(lev.gf_m).sum() > 0.8 * np.isfinite(raw).sum()
    # the level of each arc is the code's: levelled minus raw averages to ~0 per arc
    for a in lev.arcs:
        diff = (lev.gf_m - raw)[a.first : a.last + 1, o.svs.index(a.sv)]
        assert abs(np.nanmean(diff)) < 5 * a.code_rms_m / np.sqrt(a.n_epochs) + 0.05


def test_station_sigma_factors_recover_the_noise_ratio(rng: np.random.Generator) -> None:
    """Three stations whose code noise is 0.2, 0.4 and 0.2 m: the factors from their own levelling residuals are
    their noise over the geometric mean (0.794, 1.587, 0.794) within 5 %; one station alone gets 1."""
    from distnav.models.gnss.levelling import station_sigma_factors

    levs = []
    for sigma in (0.2, 0.4, 0.2):
        t, rho, iono, p1, p2, n1, n2 = _one_satellite(rng, T=2000, code_sigma=sigma)
        phi1 = rho - iono + n1 + 0.002 * rng.standard_normal(t.size)
        phi2 = rho - mu(2) * iono + n2 + 0.002 * rng.standard_normal(t.size)
        levs.append(level_station(t, ("G01",), p1[:, None], p2[:, None], phi1[:, None], phi2[:, None]))
    truth = np.array([0.2, 0.4, 0.2]) / np.exp(np.mean(np.log([0.2, 0.4, 0.2])))
    np.testing.assert_allclose(station_sigma_factors(levs), truth, rtol=0.05)
    assert station_sigma_factors(levs[:1]).tolist() == [1.0]


def _irregular_satellite(rng: np.random.Generator, T: int = 480, irr_m: float = 0.06):
    """As :func:`_one_satellite`, plus small-scale ionospheric irregularities: an AR(1) process (600 s, ``irr_m``
    of L1 delay, in code and phase alike) whose GF prediction error is ≈ 0.44·irr_m per 30-s epoch."""
    from scipy.signal import lfilter

    t, rho, iono, p1, p2, n1, n2 = _one_satellite(rng, T=T)
    a = np.exp(-30.0 / 600.0)
    irr = lfilter([1.0], [1.0, -a], irr_m * np.sqrt(1 - a * a) * rng.standard_normal(T))
    return t, rho, iono + irr, p1 + irr, p2 + mu(2) * irr, n1, n2


def test_gf_limit_follows_the_ionosphere_noise() -> None:
    """Irregularities with a 2.6-cm GF prediction error: the fixed 5-cm threshold (``gf_sigmas=0``) cuts the
    arc many times (measured 30–37 starts), the adaptive limit (4 × the recent RMS) keeps it whole after the
    first few epochs (before the noise is known the fixed threshold applies: measured 0–2 starts before epoch
    13 in 12 seeds); a (3, 3)-cycle slip (0.25 m, no wide-lane change) in the same data is still found, at its
    epoch."""
    for seed in range(6):
        rng = np.random.default_rng(seed)
        t, rho, iono, p1, p2, n1, n2 = _irregular_satellite(rng)
        phi1 = rho - iono + n1 + 0.002 * rng.standard_normal(t.size)
        phi2 = rho - mu(2) * iono + n2 + 0.002 * rng.standard_normal(t.size)
        g = (phi1 - phi2) / (mu(2) - 1.0)
        mw = melbourne_wubbena_cycles(p1, p2, phi1, phi2)
        _, _, fixed = find_arcs(t, g, mw, gf_sigmas=0.0)
        assert fixed.count("gf") >= 10
        arc, _, reasons = find_arcs(t, g, mw)
        early = len(reasons) - 1
        assert early <= 2 and set(reasons[1:]) <= {"gf"} and (arc[15:] == early).all()
        k = 300
        slip = 3 * (L1 - L2) / (mu(2) - 1.0)
        arc, _, reasons = find_arcs(t, g + np.where(np.arange(t.size) >= k, slip, 0.0), mw)
        assert reasons[-1] == "gf" and len(reasons) == early + 2
        assert (arc[15:k] == early).all() and (arc[k:] == early + 1).all()


def test_per_satellite_frequencies_level_each_column_to_its_own_l1_delay() -> None:
    """The hook for other systems (issue 32 item 5): GLONASS-like FDMA channels, each satellite column with its own
    (f_1, f_2); the levelled code of each column is that satellite's L1 delay (data written from the physics:
    I_b = (f_1/f_b)² I_1), and the GPS constants instead would not give it."""
    from distnav.models.gnss.constants import C_M_S

    k = np.array([-4.0, 0.0, 5.0])  # channel numbers
    f1, f2 = 1602e6 + k * 0.5625e6, 1246e6 + k * 0.4375e6
    t = 30.0 * np.arange(80)
    iono = 2.0 + 0.002 * t[:, None] + np.array([0.0, 0.5, 1.0])
    rho = 2.1e7 + 50.0 * t[:, None]
    m = (f1 / f2) ** 2
    p1, p2 = rho + iono, rho + m * iono
    phi1 = rho - iono + 1000.0 * C_M_S / f1
    phi2 = rho - m * iono - 700.0 * C_M_S / f2
    freqs = (f1, f2)
    lev = level_station(t, ("R01", "R02", "R03"), p1, p2, phi1, phi2, options=LevellingOptions(frequencies_hz=freqs))
    assert len(lev.arcs) == 3 and lev.starts == {"first": 3}
    np.testing.assert_allclose(lev.gf_m, iono, atol=1e-6)
    gps = level_station(t, ("R01", "R02", "R03"), p1, p2, phi1, phi2, options=LevellingOptions(screen=False))
    assert np.nanmax(np.abs(gps.gf_m - iono)) > 0.05  # the GPS factor: 1 % of the delay off, 7 cm here
    with pytest.raises(ModelError, match="frequencies must be positive"):
        level_station(t, ("R01",), p1, p2, phi1, phi2, options=LevellingOptions(frequencies_hz=(f1, f1)))
