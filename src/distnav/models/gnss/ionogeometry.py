"""Receiver–satellite geometry of the single-layer ionosphere: elevations, pierce points and the coefficients of
paper 003 eq. (49) for every receiver–satellite pair at every epoch (:func:`ionosphere_geometry`); the model and
the filters' series are in :mod:`distnav.models.gnss.ionosphere` (which re-exports these names)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from distnav._checks import check_field_types
from distnav.errors import ModelError
from distnav.models.gnss.constants import IONO_EARTH_RADIUS_M
from distnav.models.gnss.geometry import (
    azimuth_elevation,
    ecef_to_geodetic,
    elevation_mask,
    geodetic_to_ecef,
    pierce_point,
)
from distnav.models.gnss.orbits import SatelliteOrbit
from distnav.typing import ArrayLike

__all__ = [
    "MSLM_ALPHA",
    "MSLM_HEIGHT_M",
    "GeometryOptions",
    "IonosphereGeometry",
    "ionosphere_coefficients",
    "ionosphere_geometry",
]

MSLM_HEIGHT_M = 506.7e3
MSLM_ALPHA = 0.9782
"""Modified single-layer mapping (CODE): ``sin z' = R/(R + 506.7 km) · sin(0.9782 · (π/2 − θ))``."""


def ionosphere_coefficients(
    lat_ipp_rad: np.ndarray,
    lon_ipp_rad: np.ndarray,
    zenith_ipp_rad: np.ndarray,
    ref_lat_rad: np.ndarray | float,
    ref_lon_rad: np.ndarray | float,
    *,
    order: int = 1,
) -> np.ndarray:
    """Coefficients ``(a_o, a_φ, a_ψ)`` of paper 003 eq. (49) on a new last axis.

    ``a_o = 1/cos z'``, ``a_φ = (φ_IPP − φ_o)/cos z'``, ``a_ψ = (ψ_IPP − ψ_o)/cos z'`` (radians; the longitude
    difference is wrapped to (−π, π]). Inputs broadcast. ``order=2`` appends ``Δφ²``, ``Δφ·Δψ``, ``Δψ²`` over
    cos z' (:data:`TEC_NAMES_QUADRATIC`).
    """
    inv_cos = 1.0 / np.cos(np.asarray(zenith_ipp_rad, dtype=float))
    dlat = np.asarray(lat_ipp_rad, dtype=float) - np.asarray(ref_lat_rad, dtype=float)
    dlon = np.asarray(lon_ipp_rad, dtype=float) - np.asarray(ref_lon_rad, dtype=float)
    dlon = np.mod(dlon + np.pi, 2.0 * np.pi) - np.pi
    terms = [inv_cos, dlat * inv_cos, dlon * inv_cos]
    if order == 2:
        terms += [dlat**2 * inv_cos, dlat * dlon * inv_cos, dlon**2 * inv_cos]
    elif order != 1:
        raise ModelError(f"the TEC field's order must be 1 (linear) or 2 (quadratic), got {order}")
    return np.stack(np.broadcast_arrays(*terms), axis=-1)


# ----------------------------------------------------------------------------------------------- geometry
@dataclass(frozen=True, eq=False)
class IonosphereGeometry:
    """Receiver–satellite geometry of a network over time, with the single-layer coefficients.

    ``t_gps_s`` (T,), ``svs`` (S,), receivers ``names`` (n,) at ``lat_rad``/``lon_rad``/``height_m`` (n,);
    ``el_rad``, ``az_rad`` (T, n, S) (NaN where the satellite position is unknown); ``tracked`` (T, n, S) the
    elevation-mask (and data) visibility; ``coefficients`` (T, n, S, 3) = ``(a_o, a_φ, a_ψ)`` of eq. (49) about the
    reference point of each receiver's ionosphere (``ref_lat_rad``/``ref_lon_rad`` (n,)); ``groups`` (n,) the
    ionosphere each receiver belongs to (all 0 for one regional ionosphere).
    """

    t_gps_s: np.ndarray
    svs: tuple[str, ...]
    names: tuple[str, ...]
    lat_rad: np.ndarray
    lon_rad: np.ndarray
    height_m: np.ndarray
    el_rad: np.ndarray
    az_rad: np.ndarray
    tracked: np.ndarray
    coefficients: np.ndarray
    ref_lat_rad: np.ndarray
    ref_lon_rad: np.ndarray
    groups: np.ndarray
    mask_rad: float

    @property
    def n_epochs(self) -> int:
        return int(self.t_gps_s.size)

    @property
    def n_receivers(self) -> int:
        return len(self.names)

    def with_tracked(self, tracked: np.ndarray) -> IonosphereGeometry:
        """The same geometry with a narrower visibility (e.g. the epochs and satellites that have data)."""
        tr = np.asarray(tracked, dtype=bool)
        if tr.shape != self.tracked.shape:
            raise ModelError(f"tracked mask of shape {tr.shape}, geometry has {self.tracked.shape}")
        return IonosphereGeometry(
            self.t_gps_s,
            self.svs,
            self.names,
            self.lat_rad,
            self.lon_rad,
            self.height_m,
            self.el_rad,
            self.az_rad,
            self.tracked & tr,
            self.coefficients,
            self.ref_lat_rad,
            self.ref_lon_rad,
            self.groups,
            self.mask_rad,
        )


@dataclass(frozen=True)
class GeometryOptions:
    """What :func:`ionosphere_geometry` computes (defaults in brackets; checked once, here): ``mask_deg`` [10]:
    elevation mask (paper 003: 10°); ``ionosphere`` [``"common"``]: one regional ionosphere about the receivers'
    centroid (paper 003 §5) or ``"per-receiver"`` (each receiver its own ν_o, ν_φ, ν_ψ about its own zenith);
    ``tec_order`` [1]: 2 adds the second-order coefficients; ``mapping`` [``"slm"``]: paper 003's 450-km thin
    shell or ``"mslm"``, the modified single-layer mapping (:data:`MSLM_HEIGHT_M`, :data:`MSLM_ALPHA`)."""

    mask_deg: float = 10.0
    ionosphere: str = "common"
    tec_order: int = 1
    mapping: str = "slm"

    def __post_init__(self) -> None:
        check_field_types(self, error=ModelError)  # types first, naming the field (issue 29)
        if self.mapping not in ("slm", "mslm"):
            raise ModelError(f"mapping must be 'slm' or 'mslm', got {self.mapping!r}")
        if self.ionosphere not in ("common", "per-receiver"):
            raise ModelError(f"ionosphere must be 'common' or 'per-receiver', got {self.ionosphere!r}")
        if not 0.0 <= self.mask_deg < 90.0:
            raise ModelError(f"elevation mask must lie in [0°, 90°), got {self.mask_deg}°")
        if self.tec_order not in (1, 2):
            raise ModelError(f"the TEC field's order must be 1 (linear) or 2 (quadratic), got {self.tec_order}")


def ionosphere_geometry(
    orbit: SatelliteOrbit,
    t_gps_s: ArrayLike,
    *,
    lat_rad: ArrayLike | None = None,
    lon_rad: ArrayLike | None = None,
    height_m: ArrayLike = 0.0,
    receivers_ecef_m: ArrayLike | None = None,
    names: Sequence[str] | None = None,
    svs: Sequence[str] | None = None,
    options: GeometryOptions = GeometryOptions(),
) -> IonosphereGeometry:
    """Elevations, pierce points and eq.-(49) coefficients of every receiver–satellite pair at every epoch.

    Receivers by geodetic ``lat_rad``/``lon_rad``/``height_m`` or by ``receivers_ecef_m`` (n, 3); ``options``:
    :class:`GeometryOptions`. Satellites below the mask or without a position are not tracked.

    Examples
    --------
    >>> import numpy as np
    >>> from distnav.models.gnss.ionogeometry import GeometryOptions, ionosphere_geometry
    >>> from distnav.models.gnss.orbits import synthetic_gps_constellation
    >>> geo = ionosphere_geometry(synthetic_gps_constellation(), [0.0, 60.0], lat_rad=[0.9], lon_rad=[0.2],
    ...                           options=GeometryOptions(mask_deg=15.0))
    >>> geo.coefficients.shape[-1], bool((np.rad2deg(geo.el_rad[geo.tracked]) > 15.0).all())
    (3, True)
    """
    lat, lon, h, xyz = _receiver_sites(lat_rad, lon_rad, height_m, receivers_ecef_m, names)
    n = lat.size
    rx_names = tuple(str(s) for s in names) if names is not None else tuple(str(i + 1) for i in range(n))
    if len(rx_names) != n:
        raise ModelError(f"{len(rx_names)} receiver names for {n} receivers")
    t = np.atleast_1d(np.asarray(t_gps_s, dtype=float))
    sv_names = tuple(orbit.svs) if svs is None else tuple(svs)
    sat = orbit.positions_ecef(t, list(sv_names))  # (T, S, 3)
    T, S = t.size, len(sv_names)
    el = np.empty((T, n, S))
    az = np.empty((T, n, S))
    for i in range(n):
        az[:, i], el[:, i] = azimuth_elevation(xyz[i], sat)
    mask = np.deg2rad(options.mask_deg)
    tracked = elevation_mask(el, mask)
    groups, ref_lat, ref_lon = _reference_points(lat, lon, options.ionosphere)
    coef = _coefficients(lat, lon, az, el, tracked, ref_lat, ref_lon, options)
    return IonosphereGeometry(
        t, sv_names, rx_names, lat, lon, h, el, az, tracked, coef, ref_lat, ref_lon, groups, float(mask)
    )


def _receiver_sites(
    lat_rad: ArrayLike | None,
    lon_rad: ArrayLike | None,
    height_m: ArrayLike,
    receivers_ecef_m: ArrayLike | None,
    names: Sequence[str] | None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Latitude, longitude, height and ECEF position of each receiver, from either description (checked)."""
    if receivers_ecef_m is not None:
        xyz = np.asarray(receivers_ecef_m, dtype=float).reshape(-1, 3)
        if not np.all(np.isfinite(xyz)) or np.any(np.linalg.norm(xyz, axis=1) < 6.0e6):
            bad = int(np.flatnonzero(~np.isfinite(xyz).all(axis=1) | (np.linalg.norm(xyz, axis=1) < 6.0e6))[0])
            who = names[bad] if names is not None else str(bad)
            raise ModelError(f"receiver {who}: position {xyz[bad].tolist()} m is not on the Earth's surface")
        lat, lon, h = ecef_to_geodetic(xyz)
        return lat, lon, h, xyz
    if lat_rad is None or lon_rad is None:
        raise ModelError("give the receivers as lat_rad/lon_rad or receivers_ecef_m")
    lat = np.atleast_1d(np.asarray(lat_rad, dtype=float))
    lon = np.atleast_1d(np.asarray(lon_rad, dtype=float))
    h = np.broadcast_to(np.asarray(height_m, dtype=float), lat.shape).copy()
    return lat, lon, h, geodetic_to_ecef(lat, lon, h)


def _reference_points(lat: np.ndarray, lon: np.ndarray, ionosphere: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each receiver's ionosphere (group) and its reference point: the receivers' centroid on the sphere (mean
    unit vector) for one common ionosphere, each receiver's own zenith otherwise."""
    n = lat.size
    if ionosphere == "common":
        u = np.stack([np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)], axis=1).mean(axis=0)
        ref_lat = np.full(n, np.arctan2(u[2], np.hypot(u[0], u[1])))
        ref_lon = np.full(n, np.arctan2(u[1], u[0]))
        return np.zeros(n, np.int64), ref_lat, ref_lon
    return np.arange(n, dtype=np.int64), lat.copy(), lon.copy()


def _coefficients(
    lat: np.ndarray,
    lon: np.ndarray,
    az: np.ndarray,
    el: np.ndarray,
    tracked: np.ndarray,
    ref_lat: np.ndarray,
    ref_lon: np.ndarray,
    options: GeometryOptions,
) -> np.ndarray:
    """The eq.-(49) coefficients at the pierce points of the chosen mapping (zero where not tracked)."""
    el_safe = np.where(tracked, el, 0.5 * np.pi)
    az_safe = np.where(tracked, az, 0.0)
    if options.mapping == "mslm":
        lat_ipp, lon_ipp, _ = pierce_point(
            lat[None, :, None], lon[None, :, None], az_safe, el_safe, height_m=MSLM_HEIGHT_M
        )
        z_ipp = np.arcsin(
            IONO_EARTH_RADIUS_M / (IONO_EARTH_RADIUS_M + MSLM_HEIGHT_M) * np.sin(MSLM_ALPHA * (0.5 * np.pi - el_safe))
        )
    else:
        lat_ipp, lon_ipp, z_ipp = pierce_point(lat[None, :, None], lon[None, :, None], az_safe, el_safe)
    coef = ionosphere_coefficients(
        lat_ipp, lon_ipp, z_ipp, ref_lat[None, :, None], ref_lon[None, :, None], order=options.tec_order
    )
    coef[~tracked] = 0.0
    return coef
