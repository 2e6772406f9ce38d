"""Geometry of paper 000 §5 / 003 §5 against independent references: pymap3d, hand values, vector geometry."""

from __future__ import annotations

import numpy as np
import pymap3d
import pytest

from distnav.errors import ModelError
from distnav.models.gnss.constants import mu
from distnav.models.gnss.geometry import (
    azimuth_elevation,
    ecef_to_enu,
    ecef_to_geodetic,
    elevation_mask,
    geodetic_to_ecef,
    pierce_point,
    pierce_zenith_angle,
)


def test_mu_hand_values() -> None:
    # (1575.42/1227.60)² = (154/120)², (1575.42/1176.45)² = (154/115)²
    assert mu(1) == 1.0
    assert mu(2) == pytest.approx((154 / 120) ** 2, rel=1e-12)
    assert mu(5) == pytest.approx((154 / 115) ** 2, rel=1e-12)
    # Galileo E5b (1207.14 MHz = 118 × 10.23) and E5 (1191.795 = 116.5 × 10.23): bands no GPS signal uses
    assert mu(7) == pytest.approx((154 / 118) ** 2, rel=1e-12)
    assert mu(8) == pytest.approx((154 / 116.5) ** 2, rel=1e-12)
    with pytest.raises(ValueError, match="unknown GPS band"):
        mu(6)  # E6 1278.75 MHz but BeiDou B3 1268.52 MHz: one number, two frequencies


def test_geodetic_ecef_against_pymap3d(rng: np.random.Generator) -> None:
    lat = rng.uniform(-89.9, 89.9, 200)
    lon = rng.uniform(-180, 180, 200)
    h = rng.uniform(-100, 25_000_000, 200)
    xyz = geodetic_to_ecef(np.deg2rad(lat), np.deg2rad(lon), h)
    ref = np.stack(pymap3d.geodetic2ecef(lat, lon, h), axis=-1)
    assert np.abs(xyz - ref).max() < 1e-6
    la, lo, hh = ecef_to_geodetic(xyz)
    assert np.abs(np.rad2deg(la) - lat).max() < 1e-9
    assert np.abs(np.rad2deg(lo) - lon).max() < 1e-9
    assert np.abs(hh - h).max() < 1e-4


def test_ecef_to_geodetic_bad_shape() -> None:
    with pytest.raises(ModelError, match="last axis of length 3"):
        ecef_to_geodetic(np.zeros((4, 2)))


def test_azimuth_elevation_against_pymap3d(rng: np.random.Generator) -> None:
    rx_lat, rx_lon, rx_h = 52.0, 4.4, 50.0
    rx = geodetic_to_ecef(np.deg2rad(rx_lat), np.deg2rad(rx_lon), rx_h)
    sats = geodetic_to_ecef(
        np.deg2rad(rng.uniform(-60, 80, (5, 7))), np.deg2rad(rng.uniform(-60, 70, (5, 7))), 20_200_000.0
    )
    az, el = azimuth_elevation(rx, sats)
    raz, rel, _ = pymap3d.ecef2aer(sats[..., 0], sats[..., 1], sats[..., 2], rx_lat, rx_lon, rx_h)
    assert az.shape == (5, 7)
    assert np.abs(np.rad2deg(el) - rel).max() < 1e-8
    d = np.abs(np.rad2deg(az) - raz)
    assert np.minimum(d, 360 - d).max() < 1e-8
    enu = ecef_to_enu(sats, rx)
    re, rn, ru = pymap3d.ecef2enu(sats[..., 0], sats[..., 1], sats[..., 2], rx_lat, rx_lon, rx_h)
    assert np.abs(enu - np.stack([re, rn, ru], -1)).max() < 1e-5


def test_zenith_and_horizon_hand_values() -> None:
    rx = geodetic_to_ecef(0.0, 0.0, 0.0)
    above = geodetic_to_ecef(0.0, 0.0, 20_000_000.0)
    north = rx + np.array([0.0, 0.0, 1000.0])
    east = rx + np.array([0.0, 1000.0, 0.0])
    az, el = azimuth_elevation(rx, np.stack([above, north, east]))
    assert np.rad2deg(el) == pytest.approx([90.0, 0.0, 0.0], abs=1e-9)
    assert np.rad2deg(az[1:]) == pytest.approx([0.0, 90.0], abs=1e-9)


def test_elevation_mask() -> None:
    el = np.deg2rad(np.array([5.0, 10.0, 45.0, np.nan, -3.0]))
    assert elevation_mask(el, np.deg2rad(10.0)).tolist() == [False, True, True, False, False]


def test_pierce_zenith_hand_values() -> None:
    # zenith: z' = 0; horizon: sin z' = R/(R+H) = 6378.137/6828.137
    assert pierce_zenith_angle(np.pi / 2) == pytest.approx(0.0, abs=1e-12)
    assert np.sin(pierce_zenith_angle(0.0)) == pytest.approx(6378.137 / 6828.137, rel=1e-12)
    lat, lon, z = pierce_point(0.3, 1.2, 0.7, np.pi / 2)
    assert (lat, lon, z) == pytest.approx((0.3, 1.2, 0.0), abs=1e-12)


def _ray_sphere_reference(lat: float, lon: float, az: float, el: float, R: float, H: float) -> tuple[float, ...]:
    """Independent vector construction: receiver on a sphere of radius R, line of sight from local az/el,
    intersected with the sphere R + H; zenith angle = angle between the ray and the radial at the hit."""
    up = np.array([np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)])
    east = np.array([-np.sin(lon), np.cos(lon), 0.0])
    north = np.cross(up, east)
    p0 = R * up
    d = np.cos(el) * (np.sin(az) * east + np.cos(az) * north) + np.sin(el) * up
    b = p0 @ d
    s = -b + np.sqrt(b * b - (p0 @ p0 - (R + H) ** 2))
    hit = p0 + s * d
    z = np.arccos(hit @ d / np.linalg.norm(hit))
    return float(np.arcsin(hit[2] / np.linalg.norm(hit))), float(np.arctan2(hit[1], hit[0])), float(z)


@pytest.mark.parametrize(
    "lat,lon,az,el",
    [(-32.0, 116.0, 30.0, 15.0), (52.0, 4.4, 200.0, 45.0), (80.0, -170.0, 10.0, 11.0), (-5.0, 179.5, 90.0, 20.0)],
)
def test_pierce_point_against_vector_geometry(lat: float, lon: float, az: float, el: float) -> None:
    R, H = 6_378_137.0, 450_000.0
    args = np.deg2rad([lat, lon, az, el])
    got = pierce_point(*args)
    ref = _ray_sphere_reference(*args, R, H)
    assert float(got[0]) == pytest.approx(ref[0], abs=1e-10)
    dlon = (float(got[1]) - ref[1] + np.pi) % (2 * np.pi) - np.pi
    assert abs(dlon) < 1e-10
    assert float(got[2]) == pytest.approx(ref[2], abs=1e-10)
