"""Receiver–satellite geometry: geodetic ↔ ECEF (WGS 84), azimuth/elevation, elevation mask, and the
ionospheric pierce point of a single thin layer with its zenith angle z'.

All angles are radians (``lat_rad``, ``lon_rad``, ``az_rad``, ``el_rad``), distances metres. Functions broadcast
over leading axes: a receiver ``(3,)`` against satellites ``(T, S, 3)`` gives ``(T, S)`` angles.

The single-layer model is that of paper 003 §5 (layer at 450 km above a sphere of radius 6378.137 km), used by
the ionosphere model (``a_o = 1/cos z'``) and for the pierce-point coordinates φ_IPP, ψ_IPP.
"""

from __future__ import annotations

import numpy as np

from distnav.errors import ModelError
from distnav.models.gnss.constants import IONO_EARTH_RADIUS_M, IONO_HEIGHT_M, WGS84_A_M, WGS84_E2

__all__ = [
    "geodetic_to_ecef",
    "ecef_to_geodetic",
    "enu_rotation",
    "ecef_to_enu",
    "azimuth_elevation",
    "elevation_mask",
    "pierce_point",
    "pierce_zenith_angle",
]


def geodetic_to_ecef(
    lat_rad: np.ndarray | float, lon_rad: np.ndarray | float, height_m: np.ndarray | float = 0.0
) -> np.ndarray:
    """WGS 84 geodetic latitude, longitude, ellipsoidal height → ECEF ``(..., 3)`` metres."""
    lat = np.asarray(lat_rad, dtype=float)
    lon = np.asarray(lon_rad, dtype=float)
    h = np.asarray(height_m, dtype=float)
    s, c = np.sin(lat), np.cos(lat)
    n = WGS84_A_M / np.sqrt(1.0 - WGS84_E2 * s * s)
    x = (n + h) * c * np.cos(lon)
    y = (n + h) * c * np.sin(lon)
    z = (n * (1.0 - WGS84_E2) + h) * s
    return np.stack(np.broadcast_arrays(x, y, z), axis=-1)


def ecef_to_geodetic(xyz_m: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """ECEF ``(..., 3)`` metres → WGS 84 ``(lat_rad, lon_rad, height_m)``.

    Bowring's initial value followed by fixed-point iterations on the latitude (converges to < 1e-12 rad in
    a few steps for any point above the Earth's centre region, including satellites).
    """
    xyz = np.asarray(xyz_m, dtype=float)
    if xyz.shape[-1] != 3:
        raise ModelError(f"ECEF coordinates need a last axis of length 3, got shape {xyz.shape}")
    x, y, z = xyz[..., 0], xyz[..., 1], xyz[..., 2]
    lon = np.arctan2(y, x)
    p = np.hypot(x, y)
    b = WGS84_A_M * np.sqrt(1.0 - WGS84_E2)
    ep2 = WGS84_E2 / (1.0 - WGS84_E2)
    theta = np.arctan2(z * WGS84_A_M, p * b)
    lat = np.arctan2(z + ep2 * b * np.sin(theta) ** 3, p - WGS84_E2 * WGS84_A_M * np.cos(theta) ** 3)
    for _ in range(5):
        s = np.sin(lat)
        n = WGS84_A_M / np.sqrt(1.0 - WGS84_E2 * s * s)
        lat = np.arctan2(z + WGS84_E2 * n * s, p)
    s, c = np.sin(lat), np.cos(lat)
    # height: stable form for all latitudes
    h = p * c + z * s - WGS84_A_M * np.sqrt(1.0 - WGS84_E2 * s * s)
    return lat, lon, h


def enu_rotation(lat_rad: np.ndarray | float, lon_rad: np.ndarray | float) -> np.ndarray:
    """Rotation ``(..., 3, 3)`` whose rows are the local east, north, up unit vectors in ECEF."""
    lat = np.asarray(lat_rad, dtype=float)
    lon = np.asarray(lon_rad, dtype=float)
    sl, cl = np.sin(lat), np.cos(lat)
    so, co = np.sin(lon), np.cos(lon)
    zero = np.zeros_like(sl * so)
    east = np.stack(np.broadcast_arrays(-so, co, zero), axis=-1)
    north = np.stack(np.broadcast_arrays(-sl * co, -sl * so, cl), axis=-1)
    up = np.stack(np.broadcast_arrays(cl * co, cl * so, sl), axis=-1)
    return np.stack([east, north, up], axis=-2)


def ecef_to_enu(target_ecef_m: np.ndarray, origin_ecef_m: np.ndarray) -> np.ndarray:
    """East/north/up ``(..., 3)`` of ``target`` seen from ``origin`` (geodetic local frame of the origin)."""
    origin = np.asarray(origin_ecef_m, dtype=float)
    lat, lon, _ = ecef_to_geodetic(origin)
    rot = enu_rotation(lat, lon)
    d = np.asarray(target_ecef_m, dtype=float) - origin
    return np.asarray(np.einsum("...ij,...j->...i", rot, d))


def azimuth_elevation(receiver_ecef_m: np.ndarray, satellite_ecef_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Azimuth (clockwise from north, in [0, 2π)) and elevation of satellites seen from a receiver, radians.

    ``receiver_ecef_m`` is ``(3,)`` (one receiver; satellites any ``(..., 3)``) or ``(..., 3)`` broadcasting
    against ``satellite_ecef_m``. NaN satellite positions give NaN angles.
    """
    rx = np.asarray(receiver_ecef_m, dtype=float)
    sat = np.asarray(satellite_ecef_m, dtype=float)
    lat, lon, _ = ecef_to_geodetic(rx)
    rot = enu_rotation(lat, lon)
    d = sat - rx
    enu = np.einsum("...ij,...j->...i", rot, d)
    e, n, u = enu[..., 0], enu[..., 1], enu[..., 2]
    az = np.mod(np.arctan2(e, n), 2.0 * np.pi)
    el = np.arctan2(u, np.hypot(e, n))
    return az, el


def elevation_mask(el_rad: np.ndarray, mask_rad: float) -> np.ndarray:
    """Boolean mask: finite elevation at or above ``mask_rad``."""
    el = np.asarray(el_rad, dtype=float)
    with np.errstate(invalid="ignore"):
        return np.asarray(np.isfinite(el) & (el >= mask_rad))


def pierce_zenith_angle(
    el_rad: np.ndarray | float, *, height_m: float = IONO_HEIGHT_M, radius_m: float = IONO_EARTH_RADIUS_M
) -> np.ndarray:
    """Zenith angle z' of the line of sight at the single-layer pierce point: sin z' = R/(R+H) · cos θ.

    Paper 003 §5 (layer height H = 450 km, R = 6378.137 km); the slant factor of the layer is 1/cos z'.
    """
    el = np.asarray(el_rad, dtype=float)
    return np.asarray(np.arcsin(radius_m / (radius_m + height_m) * np.cos(el)))


def pierce_point(
    lat_rad: np.ndarray | float,
    lon_rad: np.ndarray | float,
    az_rad: np.ndarray,
    el_rad: np.ndarray,
    *,
    height_m: float = IONO_HEIGHT_M,
    radius_m: float = IONO_EARTH_RADIUS_M,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Single-layer ionospheric pierce point: ``(lat_ipp_rad, lon_ipp_rad, zenith_ipp_rad)``.

    Spherical Earth of radius ``radius_m`` with the layer at ``height_m`` (paper 003 §5: 450 km, 6378.137 km).
    The Earth-central angle between receiver and pierce point is ψ = π/2 − θ − z' with sin z' = R/(R+H)·cos θ;
    the pierce point follows from the spherical direct problem along azimuth α:
    ``sin φ' = sin φ cos ψ + cos φ sin ψ cos α``, ``λ' = λ + atan2(sin ψ sin α cos φ, cos ψ − sin φ sin φ')``.
    The receiver latitude is used as a spherical latitude (the usual thin-shell approximation).
    """
    lat = np.asarray(lat_rad, dtype=float)
    lon = np.asarray(lon_rad, dtype=float)
    az = np.asarray(az_rad, dtype=float)
    el = np.asarray(el_rad, dtype=float)
    z = pierce_zenith_angle(el, height_m=height_m, radius_m=radius_m)
    psi = 0.5 * np.pi - el - z
    s_lat = np.sin(lat) * np.cos(psi) + np.cos(lat) * np.sin(psi) * np.cos(az)
    lat_ipp = np.arcsin(np.clip(s_lat, -1.0, 1.0))
    dlon = np.arctan2(np.sin(psi) * np.sin(az) * np.cos(lat), np.cos(psi) - np.sin(lat) * s_lat)
    lon_ipp = np.mod(lon + dlon + np.pi, 2.0 * np.pi) - np.pi
    return lat_ipp, lon_ipp, z
