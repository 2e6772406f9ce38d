"""The second-order VTEC field and the modified single-layer mapping (``--tec-field quadratic``, ``--mapping
mslm``): coefficients against their formulas, and a curved field (as under an equatorial-anomaly crest) whose
curvature the linear field puts into the receiver bias while the second-order field recovers it."""

from __future__ import annotations

import numpy as np
import pytest

from distnav.errors import ModelError
from distnav.models.gnss.geometry import geodetic_to_ecef
from distnav.models.gnss.gfbias import gf_m_per_dsb_ns
from distnav.models.gnss.gfnetwork import (
    BiasFilterOptions,
    BiasModelOptions,
    GeometryFreeNetwork,
    bias_network_model,
    final_dsbs,
    run_bias_filters,
    satellite_fit,
)
from distnav.models.gnss.ionosphere import GeometryOptions, ionosphere_coefficients, ionosphere_geometry
from distnav.models.gnss.orbits import gps_seconds, synthetic_gps_constellation


def test_second_order_coefficients_and_mslm_mapping() -> None:
    c = ionosphere_coefficients(np.array([0.1]), np.array([0.3]), np.array([0.5]), 0.05, 0.2, order=2)[0]
    m = 1.0 / np.cos(0.5)
    np.testing.assert_allclose(c, [m, 0.05 * m, 0.1 * m, 0.0025 * m, 0.005 * m, 0.01 * m])
    with pytest.raises(ModelError, match="order"):
        ionosphere_coefficients(np.array([0.1]), np.array([0.3]), np.array([0.5]), 0.0, 0.0, order=3)
    orbit = synthetic_gps_constellation(epoch="2024-01-10T00:00:00")
    t = gps_seconds(np.datetime64("2024-01-10T00:00")) + 600.0 * np.arange(6)
    xyz = geodetic_to_ecef(np.deg2rad([-7.3]), np.deg2rad([72.4]), 0.0)
    g = ionosphere_geometry(
        orbit,
        t,
        receivers_ecef_m=xyz,
        options=GeometryOptions(mask_deg=10.0, ionosphere="per-receiver", mapping="mslm"),
    )
    el = g.el_rad[g.tracked]
    z = np.arcsin(6378.137 / (6378.137 + 506.7) * np.sin(0.9782 * (np.pi / 2 - el)))  # CODE's MSLM
    np.testing.assert_allclose(g.coefficients[g.tracked][:, 0], 1.0 / np.cos(z), rtol=1e-12)
    with pytest.raises(ModelError, match="mapping"):
        ionosphere_geometry(orbit, t, receivers_ecef_m=xyz, options=GeometryOptions(mapping="flat"))


def test_curved_field_biases_the_linear_receiver_dsb_not_the_quadratic() -> None:
    orbit = synthetic_gps_constellation(epoch="2024-01-10T00:00:00")
    t = gps_seconds(np.datetime64("2024-01-10T00:00")) + 120.0 * np.arange(360)  # 12 h
    lat, lon = np.deg2rad([-7.3, -1.4]), np.deg2rad([72.4, -48.5])
    xyz = geodetic_to_ecef(lat, lon, 0.0)
    svs = list(orbit.svs)
    g = ionosphere_geometry(
        orbit,
        t,
        receivers_ecef_m=xyz,
        svs=svs,
        options=GeometryOptions(mask_deg=10.0, ionosphere="per-receiver", tec_order=2),
    )
    # VTEC 8 m (≈ 50 TECU) at each station, a crest: −60 m/rad² in latitude (−1.8 TECU at 2° off), none in lon
    truth = np.array([8.0, 0.3, -0.2, -60.0, 0.0, -20.0])
    rng = np.random.default_rng(3)
    sat_ns = rng.normal(0.0, 3.0, len(svs))
    sat_ns -= sat_ns.mean()
    rx_ns = np.array([4.0, -2.0])
    k = gf_m_per_dsb_ns(2)
    gf = g.coefficients @ truth - k * (rx_ns[None, :, None] + sat_ns[None, None, :])
    gf = np.where(g.tracked, gf + rng.normal(0.0, 0.02, gf.shape), np.nan)
    err = {}
    for order in (1, 2):
        data = bias_network_model(
            GeometryFreeNetwork(["DGAR", "BELE"], t, xyz, gf, svs),
            orbit,
            BiasModelOptions(ionosphere="per-receiver", tec_order=order, min_satellite_obs=30),
        )
        series, _ = run_bias_filters(data, BiasFilterOptions(local=False))
        sat, rx, _ = final_dsbs(data, series[0])
        c = np.mean([sat[s] - sat_ns[svs.index(s)] for s in sat])  # datum offset over the satellites
        err[order] = np.array([rx["DGAR"] - rx_ns[0] + c, rx["BELE"] - rx_ns[1] + c])
        fit = satellite_fit(data, series[0])  # the per-satellite fit works on six TEC terms too
        assert fit.worst() is not None and np.isfinite(fit.rms_m).any()
    assert np.abs(err[2]).max() < 0.1, err
    assert np.abs(err[1]).max() > 0.5, err
