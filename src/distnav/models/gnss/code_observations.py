"""The code (and phase) observations of one receiver as the GNSS models take them: read from RINEX by
:func:`distnav.formats.gnss.rinex.read_code_observations`, or simulated by :mod:`distnav.models.gnss.netsim`."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from distnav.models.gnss.systems import signal_pair_frequencies_hz

__all__ = ["CodeObservations", "ProgressCallback"]

ProgressCallback = Callable[[str, float], None]
"""``progress(what, fraction_done)``: called by readers while they work."""


@dataclass(frozen=True)
class CodeObservations:
    """GPS code observations of one receiver on up to three bands.

    ``time`` (T,) ``datetime64[ns]`` (GPS time), ``svs`` (S,) ``"G01"``..., ``codes[band]`` the RINEX 3 code
    used for the band (e.g. ``{1: "C1C", 2: "C2W", 5: "C5X"}``), ``range_m[band]`` (T, S) pseudo-ranges in
    metres with NaN where not observed, ``position_ecef_m`` the header's approximate position. With
    ``phases=True``: ``phase_m[band]`` (T, S) carrier phase in metres (cycles × λ; NaN where the code is missing),
    ``lli[band]`` its loss-of-lock indicators, ``phase_types[band]`` the phase type read. Another system's first
    code (BeiDou ``C2I``) is kept under key 1 by :func:`~distnav.formats.gnss.rinex.read_stations` (``codes[1]``
    names its real band; :meth:`frequencies_hz` gives the carrier frequencies).
    """

    station: str
    path: Path
    time: np.ndarray
    svs: tuple[str, ...]
    codes: dict[int, str]
    range_m: dict[int, np.ndarray]
    position_ecef_m: np.ndarray
    receiver: str = ""
    rinex_version: float = 0.0
    notes: tuple[str, ...] = field(default_factory=tuple)
    phase_m: dict[int, np.ndarray] = field(default_factory=dict)
    lli: dict[int, np.ndarray] = field(default_factory=dict)
    phase_types: dict[int, str] = field(default_factory=dict)
    time_system: str = "GPS"
    channels: dict[str, int] = field(default_factory=dict)
    """GLONASS FDMA channel per satellite (``{"R01": 1}``; the header's ``GLONASS SLOT / FRQ #``)."""

    @property
    def n_epochs(self) -> int:
        return int(self.time.size)

    def frequencies_hz(self, band: int) -> tuple[np.ndarray, np.ndarray]:
        """``(f_1, f_b)`` [Hz] per satellite of the first code and the code of ``band`` (their own RINEX bands and
        system, GLONASS channels from :attr:`channels`)."""
        return signal_pair_frequencies_hz(self.svs, self.codes[1], self.codes[band], self.channels)

    def satellites_with_all_bands(self) -> tuple[str, ...]:
        """Satellites observed on every band at one epoch at least."""
        have = np.ones((self.time.size, len(self.svs)), dtype=bool)
        for arr in self.range_m.values():
            have &= np.isfinite(arr)
        return tuple(s for s, h in zip(self.svs, np.asarray(have.any(axis=0)).tolist(), strict=True) if h)
