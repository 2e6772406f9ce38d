"""The satellite systems distnav reads: carrier frequencies per RINEX band, the constants of their broadcast orbits,
and their time scales.

Sources: GPS IS-GPS-200; Galileo OS SIS ICD issue 2.0 (§5.1.1 GM = 3.986004418e14 m³/s², Ω_E = 7.2921151467e-5
rad/s; E1 1575.42, E5a 1176.45, E5b 1207.14, E5 1191.795, E6 1278.75 MHz); BeiDou ICD B1I/B3I v3.0 (§5.2.4:
GM = 3.986004418e14, Ω_E = 7.2921150e-5; B1I 1561.098, B3I 1268.52, B2I/B2b 1207.14, B1C 1575.42, B2a 1176.45 MHz;
BDT = GPS time − 14 s; BDT week 0 begins at GPS week 1356; GEO satellites C01–C05 and C59–C63 use the rotation of
Table 5-11); GLONASS ICD 5.1 (FDMA: G1 1602 + k·0.5625 MHz, G2 1246 + k·0.4375 MHz, channel k = −7…+6).
The RINEX 3.05 band numbers name the frequencies (Table 4: BeiDou 2 = B1I, 6 = B3I, 7 = B2I/B2b).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from distnav.errors import DataFileError

__all__ = [
    "SYSTEM_NAMES",
    "CARRIER_FREQUENCIES_HZ",
    "GLONASS_FDMA_HZ",
    "ORBIT_CONSTANTS",
    "BDT_MINUS_GPST_S",
    "BDT_WEEK_IN_GPS_WEEKS",
    "BEIDOU_GEO_PRNS",
    "carrier_frequencies_hz",
    "is_beidou_geo",
    "signal_pair_frequencies_hz",
]

SYSTEM_NAMES: dict[str, str] = {
    "G": "GPS",
    "E": "Galileo",
    "C": "BeiDou",
    "R": "GLONASS",
    "J": "QZSS",
    "S": "SBAS",
    "I": "NavIC",
}
"""RINEX 3 system letters and the systems' names (RINEX 3.05 §3.5)."""

CARRIER_FREQUENCIES_HZ: dict[str, dict[int, float]] = {
    "G": {1: 1575.42e6, 2: 1227.60e6, 5: 1176.45e6},
    "E": {1: 1575.42e6, 5: 1176.45e6, 7: 1207.14e6, 8: 1191.795e6, 6: 1278.75e6},
    "C": {2: 1561.098e6, 6: 1268.52e6, 7: 1207.14e6, 1: 1575.42e6, 5: 1176.45e6, 8: 1191.795e6},
    "J": {1: 1575.42e6, 2: 1227.60e6, 5: 1176.45e6, 6: 1278.75e6},
}
"""Carrier frequency [Hz] per system letter and RINEX band number (code-division systems)."""

GLONASS_FDMA_HZ: dict[int, tuple[float, float]] = {1: (1602.0e6, 0.5625e6), 2: (1246.0e6, 0.4375e6)}
"""GLONASS FDMA bands: (base frequency, channel spacing) [Hz]; f = base + k·spacing (GLONASS ICD 5.1, §3.3.1.1)."""

ORBIT_CONSTANTS: dict[str, tuple[float, float]] = {
    "G": (3.986005e14, 7.2921151467e-5),
    "E": (3.986004418e14, 7.2921151467e-5),
    "C": (3.986004418e14, 7.2921150e-5),
    "J": (3.986005e14, 7.2921151467e-5),
}
"""(GM [m³/s²], Earth rotation rate Ω_E [rad/s]) of each system's broadcast Keplerian ephemeris."""

BDT_MINUS_GPST_S = -14.0
"""BeiDou time minus GPS time [s] (BDT started 2006-01-01 00:00:00 UTC, 14 leap seconds behind GPS time)."""

BDT_WEEK_IN_GPS_WEEKS = 1356
"""The GPS week in which BDT week 0 begins."""

BEIDOU_GEO_PRNS: frozenset[int] = frozenset((1, 2, 3, 4, 5, 59, 60, 61, 62, 63))
"""BeiDou geostationary satellites (their broadcast orbit needs the GEO rotation of the BeiDou ICD)."""


def is_beidou_geo(sv: str) -> bool:
    """``True`` for a BeiDou GEO satellite id (``C01``–``C05``, ``C59``–``C63``)."""
    return sv[:1] == "C" and int(sv[1:]) in BEIDOU_GEO_PRNS


def carrier_frequencies_hz(
    system: str, band: int, svs: Sequence[str], channels: Mapping[str, int] | None = None
) -> np.ndarray:
    """The carrier frequency [Hz] of ``band`` for each satellite of ``svs`` (S,): one value for a code-division
    system, the FDMA channel's for GLONASS (``channels``: ``{"R01": 1, …}`` from the observation header's
    ``GLONASS SLOT / FRQ #`` or the navigation file; a GLONASS satellite without a channel is NaN)."""
    if system == "R":
        if band not in GLONASS_FDMA_HZ:
            raise DataFileError(f"GLONASS band {band}: only the FDMA bands 1 and 2 are supported")
        base, step = GLONASS_FDMA_HZ[band]
        k = np.array([(channels or {}).get(s, np.nan) for s in svs], dtype=float)
        out: np.ndarray = base + k * step
        return out
    table = CARRIER_FREQUENCIES_HZ.get(system)
    if table is None or band not in table:
        known = ", ".join(f"{s}: {sorted(t)}" for s, t in CARRIER_FREQUENCIES_HZ.items())
        raise DataFileError(f"no carrier frequency for system {system!r} band {band} (known bands: {known})")
    return np.full(len(svs), table[band])


def signal_pair_frequencies_hz(
    svs: Sequence[str], first_code: str, second_code: str, channels: Mapping[str, int] | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """``(f_1, f_2)`` [Hz] per satellite of ``svs`` (S,) for two RINEX 3 codes (``C2I``/``C6I``: the band digit of
    each code, the system letter of each satellite): the frequency pair of the geometry-free combination,
    ``μ = (f_1/f_2)²`` (per satellite for GLONASS, whose FDMA channel sets both; NaN without a channel).

    >>> from distnav.models.gnss.systems import signal_pair_frequencies_hz
    >>> f1, f2 = signal_pair_frequencies_hz(["C08"], "C2I", "C6I")
    >>> float(f1[0]) / 1e6, float(f2[0]) / 1e6
    (1561.098, 1268.52)
    >>> f1, f2 = signal_pair_frequencies_hz(["R01", "R26"], "C1C", "C2C", {"R01": 1})
    >>> f1 / 1e6, f2 / 1e6
    (array([1602.5625,       nan]), array([1246.4375,       nan]))
    """
    f1, f2 = np.full(len(svs), np.nan), np.full(len(svs), np.nan)
    for system in sorted({s[:1] for s in svs}):
        idx = [k for k, s in enumerate(svs) if s[:1] == system]
        names = [svs[k] for k in idx]
        f1[idx] = carrier_frequencies_hz(system, int(first_code[1]), names, channels)
        f2[idx] = carrier_frequencies_hz(system, int(second_code[1]), names, channels)
    return f1, f2
