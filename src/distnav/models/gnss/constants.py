"""Physical constants of GPS and the Earth used across :mod:`distnav.models.gnss`.

Values follow IS-GPS-200 (speed of light, GM, Earth rotation rate, carrier frequencies, relativistic clock
constant) and WGS 84 (ellipsoid). The single-layer ionosphere (450 km, Earth radius 6378.137 km) is the one of
paper 003 §5 and of the papers README.
"""

from __future__ import annotations

import math

__all__ = [
    "C_M_S",
    "GM_M3_S2",
    "OMEGA_E_RAD_S",
    "F_REL_S_SQRT_M",
    "WGS84_A_M",
    "WGS84_F",
    "WGS84_E2",
    "F_L1_HZ",
    "F_L2_HZ",
    "F_L5_HZ",
    "GPS_FREQUENCIES_HZ",
    "IONO_HEIGHT_M",
    "IONO_EARTH_RADIUS_M",
    "GPS_EPOCH",
    "SECONDS_PER_WEEK",
    "NS_TO_M",
    "mu",
]

C_M_S = 299_792_458.0
"""Speed of light in vacuum [m/s] (IS-GPS-200)."""

GM_M3_S2 = 3.986005e14
"""WGS 84 Earth gravitational constant as used by the GPS broadcast ephemeris [m³/s²] (IS-GPS-200)."""

OMEGA_E_RAD_S = 7.2921151467e-5
"""WGS 84 Earth rotation rate [rad/s] (IS-GPS-200)."""

F_REL_S_SQRT_M = -4.442807633e-10
"""Relativistic clock-correction constant F = −2√GM/c² [s/√m] (IS-GPS-200, 20.3.3.3.3.1)."""

WGS84_A_M = 6_378_137.0
"""WGS 84 semi-major axis [m]."""

WGS84_F = 1.0 / 298.257223563
"""WGS 84 flattening."""

WGS84_E2 = WGS84_F * (2.0 - WGS84_F)
"""WGS 84 first eccentricity squared."""

F_L1_HZ = 1575.42e6
F_L2_HZ = 1227.60e6
F_L5_HZ = 1176.45e6
GPS_FREQUENCIES_HZ: dict[int, float] = {1: F_L1_HZ, 2: F_L2_HZ, 5: F_L5_HZ, 7: 1207.14e6, 8: 1191.795e6}
"""Carrier frequencies by RINEX band number (1 = L1, 2 = L2, 5 = L5) of GPS, and of Galileo, whose E1 and E5a are
GPS's L1 and L5 and whose E5b (7) and E5 (8) no GPS signal uses: each of these band numbers means one
frequency in both systems, so the GPS-band models (μ, levelling) serve Galileo unchanged. The BeiDou and GLONASS
frequencies differ per band number: :mod:`distnav.models.gnss.systems`."""

IONO_HEIGHT_M = 450e3
"""Height of the single ionospheric layer [m] (paper 003 §5)."""

IONO_EARTH_RADIUS_M = 6_378_137.0
"""Mean Earth radius of the single-layer model [m] (paper 003 §5: 6378.137 km)."""

GPS_EPOCH = "1980-01-06T00:00:00"
"""Origin of GPS time (week 0, second 0)."""

SECONDS_PER_WEEK = 604_800.0

NS_TO_M = C_M_S * 1e-9
"""Metres of range per nanosecond of delay (≈ 0.2998 m/ns)."""


def mu(band: int, reference_band: int = 1) -> float:
    """The ionospheric coefficient μ_j = (f₁/f_j)² of paper 000, §5.1 (eq. (25) and after).

    ``band`` and ``reference_band`` are RINEX band numbers (GPS 1, 2, 5; Galileo 1, 5, 7, 8). μ₁ = 1 by definition.
    """
    try:
        return (GPS_FREQUENCIES_HZ[reference_band] / GPS_FREQUENCIES_HZ[band]) ** 2
    except KeyError as exc:
        raise ValueError(
            f"unknown GPS band {exc.args[0]!r} (or Galileo band); use one of {sorted(GPS_FREQUENCIES_HZ)}"
        ) from None


# a quick self-consistency guard (module import fails loudly if a constant is mistyped)
assert math.isclose(mu(2), 1.6469444, rel_tol=1e-6)
