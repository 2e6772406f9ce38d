"""A realistic simulator of a small mid-latitude receiver network: RINEX-like code and phase observations.

The observations are :class:`~distnav.models.gnss.code_observations.CodeObservations` (P1 = C1W, P2 = C2W and the L1/L2
phases), so everything downstream — carrier levelling, screening, the bias model, the filters, the comparison
with a product — runs exactly as on real files. What is simulated, per receiver *i*, satellite *s*, band *k*
(μ₁ = 1, μ₂ = (f₁/f₂)²):

    ``P_k = ρ + μ_k I + c·(B_k,i + B_k^s) + m_k(θ, α) + e_k``,     ``Φ_k = ρ − μ_k I + λ_k N_k + ε_k``

* ``I`` the L1 slant delay of a **thick ionosphere**: the vertical TEC of a smooth field (:class:`VtecField`:
  night level, a diurnal peak at 14 h local time, a poleward decrease, a slow travelling wave) integrated over
  three shells (300/400/550 km, weights 0.3/0.45/0.25) — the estimation model's single 450 km layer is then
  an approximation, as it is for real data; one field for all receivers (not per-station independent);
* code biases ``B``: only the DSB ``C1W − C2W`` matters (Bias-SINEX sign: biases add to the observations);
  satellites ~ N(0, 3 ns), receivers ~ N(0, 8 ns) unless given;
* multipath ``m_k``: a function of the satellite's elevation θ and azimuth α per receiver–satellite pair
  (repeats with the geometry, so day after day), amplitude ``multipath_m·exp(−θ/15°)`` (0.5 m, P2 × 1.3);
* white code noise ``σ_k/sin θ`` (0.15 m P1, 0.18 m P2; with the multipath the geometry-free code of an arc
  has a median RMS of ≈ 0.8 m, as DGAR's 0.70 m and BELE's 1.0 m on 2024-01-10), phase noise 2 mm, a random
  integer ambiguity per arc;
* an **SVN49-like satellite** (``svn49``, default G01): an elevation-dependent code bias
  ``0.9 m·cos²θ`` on P1 and ``−0.3 m·cos²θ`` on P2 (the reflection in its antenna), which no constant DCB
  fits — it should be the worst-fitting satellite;
* optional gross errors: a fraction of one receiver's P1 values off by ±5…50 m;
* optional **receiver channel biases** (GLONASS-like FDMA inter-frequency biases, gnss8): ``channels`` puts the
  satellites in groups (a channel each) and every receiver gets one code bias per group, N(0, ``channel_ifb_ns``)
  on P1, shared by the group's satellites — inseparable from their DSBs, which the truth leaves out.

**Realism knobs** (all off by default, so the default simulation is unchanged; :data:`REALISTIC` sets them,
calibrated so that the first-wave model scores on it about what it scored on the held-out IGS network):

* ``multipath_el_scale_deg``: the e-folding elevation of the multipath amplitude (15°; larger = multipath
  reaching higher elevations);
* ``multipath_day_fraction`` *f*: the multipath is ``√(1 − f²)·(repeating pattern) + f·(pattern of this day)``
  (real multipath repeats only in part: wet ground, snow, changes near the antenna, the orbit's drift);
* ``station_noise_scale``: per-station factors (by station order, cycled) on code noise and multipath;
* ``tid_tecu``: ``n_tid`` travelling ionospheric disturbances per day (plane waves of random direction,
  wavelength 150–400 km, period 15–60 min, drawn from ``rng``), common to all receivers, which no smooth layer
  fits;
* ``irregularity_tecu`` / ``irregularity_tau_s``: small-scale irregularities per ray, an AR(1) process in the
  vertical TEC (time constant τ) times the slant factor — in code and phase alike (it is ionosphere);
* ``shell_jitter_km``: the three shells' heights shifted by one N(0, jitter) per day — the thin 450-km layer's
  mapping error at low elevation then changes from day to day.

Receivers record above ``record_mask_deg`` (5°); an arc is a continuous pass. :func:`simulate_network` returns
the observations and the truth (DSBs in ns and the VTEC field) for comparisons; :func:`truth_product` wraps the
truth as a :class:`~distnav.models.gnss.products.ProductDSB` so that
:func:`~distnav.models.gnss.products.compare_in_datum` aligns datums as for a real product.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from dataclasses import field as dataclass_field
from pathlib import Path
from typing import Any

import numpy as np

from distnav._checks import check_field_types
from distnav.errors import ModelError
from distnav.models.gnss.code_observations import CodeObservations
from distnav.models.gnss.constants import C_M_S, GPS_FREQUENCIES_HZ, mu
from distnav.models.gnss.geometry import azimuth_elevation, geodetic_to_ecef, pierce_point

__all__ = [
    "EUROPEAN_STATIONS",
    "REALISTIC",
    "NetworkSimOptions",
    "VtecField",
    "SimulatedNetwork",
    "simulate_network",
    "truth_product",
]

TECU_L1_M = 40.3e16 / GPS_FREQUENCIES_HZ[1] ** 2
"""L1 delay of 1 TECU [m] (0.1624 m)."""

EUROPEAN_STATIONS: dict[str, tuple[float, float, float]] = {
    "SIMA": (49.14, 12.88, 650.0),
    "SIMB": (50.80, 10.20, 400.0),
    "SIMC": (48.10, 16.40, 200.0),
}
"""Three mid-latitude receivers (degrees, metres) 200–450 km apart, about the layout of a small central-European
IGS cluster."""

_SHELLS_M = ((300e3, 0.30), (400e3, 0.45), (550e3, 0.25))

REALISTIC: dict[str, Any] = {
    "multipath_m": 0.9,
    "multipath_el_scale_deg": 20.0,
    "multipath_day_fraction": 0.6,
    "station_noise_scale": (1.0, 1.4, 0.8),
    "tid_tecu": 0.5,
    "n_tid": 3,
    "irregularity_tecu": 0.15,
    "irregularity_tau_s": 600.0,
    "shell_jitter_km": 40.0,
}
"""Fields of :class:`NetworkSimOptions` for the "realistic" preset (module doc; the calibration is in
``docs/ionosphere.md``): ``simulate_network(orbit, day, NetworkSimOptions(**REALISTIC), rng=rng)``."""


@dataclass(frozen=True)
class VtecField:
    """A smooth vertical TEC field [TECU] over latitude, longitude and time (mid-latitude winter-like default).

    ``VTEC = (night + day·D(LT)) · (1 + lat_gradient·(φ − φ_ref)) + wave``, ``D`` a cosine bump of half-width
    ``width_h`` around ``peak_local_h`` (zero at night, smooth at its edges), LT = UT + λ/15°, and a travelling
    wave of ``wave_tecu`` with wavelength ``wave_km`` moving southwards with period ``wave_period_s``.
    """

    night_tecu: float = 4.0
    day_tecu: float = 16.0
    peak_local_h: float = 13.5
    width_h: float = 7.0
    ref_lat_deg: float = 49.0
    lat_gradient_per_deg: float = -0.03
    wave_tecu: float = 0.4
    wave_km: float = 400.0
    wave_period_s: float = 3000.0

    def tecu(self, lat_rad: np.ndarray, lon_rad: np.ndarray, t_gps_s: np.ndarray) -> np.ndarray:
        lat, lon, t = np.broadcast_arrays(
            np.asarray(lat_rad, float), np.asarray(lon_rad, float), np.asarray(t_gps_s, float)
        )
        lt_h = np.mod(t / 3600.0 + np.rad2deg(lon) / 15.0, 24.0)
        dh = np.mod(lt_h - self.peak_local_h + 12.0, 24.0) - 12.0
        bump = np.where(np.abs(dh) < self.width_h, np.cos(0.5 * np.pi * dh / self.width_h) ** 2, 0.0)
        lat_term = 1.0 + self.lat_gradient_per_deg * (np.rad2deg(lat) - self.ref_lat_deg)
        dist_km = np.rad2deg(lat) * 111.2
        wave = self.wave_tecu * np.sin(2 * np.pi * (dist_km / self.wave_km + t / self.wave_period_s))
        out: np.ndarray = (self.night_tecu + self.day_tecu * bump) * lat_term + wave
        return out


@dataclass(frozen=True, eq=False)
class SimulatedNetwork:
    """Simulated observations of every receiver and the truth: ``satellite_dsb_ns`` / ``receiver_dsb_ns``
    (C1W − C2W, ns, as given or drawn), ``gross_errors`` (receiver → number of P1 values corrupted)."""

    observations: list[CodeObservations]
    satellite_dsb_ns: dict[str, float]
    receiver_dsb_ns: dict[str, float]
    field: VtecField
    svn49: str | None
    gross_errors: dict[str, int] = dataclass_field(default_factory=dict)
    channel_ifb_ns: dict[str, dict[int, float]] = dataclass_field(default_factory=dict)
    """Receiver → channel group → its code bias [ns] (``NetworkSimOptions.channels``; not in the DSB truth)."""


def _given_or_drawn(
    names: Sequence[str], given: Mapping[str, float] | None, std: float, rng: np.random.Generator
) -> dict[str, float]:
    if given is not None:
        missing = [n for n in names if n not in given]
        if missing:
            raise ModelError(f"no DSB given for {', '.join(missing)}")
        return {n: float(given[n]) for n in names}
    return {n: float(v) for n, v in zip(names, rng.normal(0.0, std, len(names)), strict=True)}


@dataclass(frozen=True)
class NetworkSimOptions:
    """What :func:`simulate_network` simulates (module doc; defaults in brackets, checked once, here).

    ``interval_s`` [30] / ``hours`` [24]: sampling and length from 00:00 GPS. ``field`` [:class:`VtecField`]: the
    smooth VTEC. ``svn49`` [``"G01"``]: the satellite with an SVN49-like elevation-dependent code bias (None:
    none). ``code_sigma_m`` [(0.15, 0.18)] / ``phase_sigma_m`` [0.002]: white noise of P1/P2 and the phases.
    ``multipath_m`` [0.5] · e^(−θ/``multipath_el_scale_deg`` [15]): multipath per receiver–satellite pair whose
    pattern ``multipath_seed`` [7] fixes (the same every day) and of which ``multipath_day_fraction`` [0] is new
    each day. ``record_mask_deg`` [5]. ``gross_fraction`` [0] of ``gross_station``'s [the last] P1 ± 5–50 m.
    ``station_noise_scale`` [(1,)]: per station (cycled) factors on noise and multipath. ``tid_tecu`` [0] ×
    ``n_tid`` [3] travelling disturbances, ``irregularity_tecu`` [0] AR(1) irregularities of correlation time
    ``irregularity_tau_s`` [600], ``shell_jitter_km`` [0] per-day shift of the shells (the realistic preset,
    :data:`REALISTIC`). ``channels`` [None] satellite → channel group and ``channel_ifb_ns`` [0]: the receivers'
    per-group code bias σ (module doc)."""

    interval_s: float = 30.0
    hours: float = 24.0
    field: VtecField | None = None
    svn49: str | None = "G01"
    code_sigma_m: tuple[float, float] = (0.15, 0.18)
    multipath_m: float = 0.5
    phase_sigma_m: float = 0.002
    record_mask_deg: float = 5.0
    gross_fraction: float = 0.0
    gross_station: str | None = None
    multipath_seed: int = 7
    multipath_el_scale_deg: float = 15.0
    multipath_day_fraction: float = 0.0
    station_noise_scale: Sequence[float] = (1.0,)
    tid_tecu: float = 0.0
    n_tid: int = 3
    irregularity_tecu: float = 0.0
    irregularity_tau_s: float = 600.0
    shell_jitter_km: float = 0.0
    channels: Mapping[str, int] | None = None
    channel_ifb_ns: float = 0.0

    def __post_init__(self) -> None:
        check_field_types(self, error=ModelError)  # types first, naming the field (issue 29)
        if not (np.isfinite(self.interval_s) and self.interval_s > 0) or not 0 < self.hours <= 24:
            raise ModelError(f"interval {self.interval_s} s / {self.hours} h: must be positive (at most 24 h)")
        if not 0.0 <= self.gross_fraction < 0.5:
            raise ModelError(f"gross_fraction {self.gross_fraction}: must lie in [0, 0.5)")
        if not 0.0 <= self.multipath_day_fraction <= 1.0:
            raise ModelError(f"multipath_day_fraction {self.multipath_day_fraction}: must lie in [0, 1]")
        if (
            not self.station_noise_scale
            or min(self.station_noise_scale) <= 0
            or self.irregularity_tau_s <= 0
            or self.multipath_el_scale_deg <= 0
        ):
            raise ModelError("station_noise_scale, irregularity_tau_s and multipath_el_scale_deg must be positive")
        if not (np.isfinite(self.channel_ifb_ns) and self.channel_ifb_ns >= 0):
            raise ModelError(f"channel_ifb_ns {self.channel_ifb_ns}: must be a non-negative number")


@dataclass(frozen=True, eq=False)
class _Day:
    """What every station of one simulated day shares: epochs, satellite positions, biases, shells, TIDs."""

    t: np.ndarray
    time: np.ndarray
    svs: list[str]
    sat_xyz: np.ndarray
    sat_dsb: dict[str, float]
    rx_dsb: dict[str, float]
    field: VtecField
    shells: list[tuple[float, float]]
    tids: list[tuple[float, float, float, float, float]]
    channel_ifb_ns: dict[str, dict[int, float]] = dataclass_field(default_factory=dict)


def simulate_network(
    orbit: Any,
    day: str | np.datetime64,
    options: NetworkSimOptions = NetworkSimOptions(),
    *,
    rng: np.random.Generator,
    stations: Mapping[str, tuple[float, float, float]] | None = None,
    satellite_dsb_ns: Mapping[str, float] | None = None,
    receiver_dsb_ns: Mapping[str, float] | None = None,
) -> SimulatedNetwork:
    """Simulate a day (or ``options.hours`` of it from 00:00 GPS) of the network (module doc) with ``orbit``
    (``positions_ecef(t, svs)``, e.g. :func:`~distnav.models.gnss.orbits.synthetic_gps_constellation`);
    ``stations`` name → (lat °, lon °, height m) [:data:`EUROPEAN_STATIONS`]; ``options``:
    :class:`NetworkSimOptions`. ``rng`` draws the noise, ambiguities, gross errors and any DSB not given
    (satellites σ 3 ns, receivers σ 8 ns), and the day's share of the multipath, the TIDs, irregularities and
    shell shift.

    Examples
    --------
    >>> import numpy as np
    >>> from distnav.models.gnss.netsim import NetworkSimOptions, simulate_network
    >>> from distnav.models.gnss.orbits import synthetic_gps_constellation
    >>> orbit = synthetic_gps_constellation(epoch="2024-01-10T00:00:00")
    >>> sim = simulate_network(orbit, "2024-01-10", NetworkSimOptions(hours=0.5), rng=np.random.default_rng(0))
    >>> [o.station for o in sim.observations], sim.observations[0].time.size
    (['SIMA', 'SIMB', 'SIMC'], 60)
    """
    from distnav.models.gnss.orbits import datetime_from_gps_seconds, gps_seconds

    sta = dict(EUROPEAN_STATIONS if stations is None else stations)
    names, svs = list(sta), list(orbit.svs)
    t0 = float(gps_seconds(np.datetime64(str(day)[:10] + "T00:00:00")))
    t = t0 + options.interval_s * np.arange(int(round(options.hours * 3600.0 / options.interval_s)))
    sat_xyz = orbit.positions_ecef(t, svs)
    sat_dsb = _given_or_drawn(svs, satellite_dsb_ns, 3.0, rng)
    rx_dsb = _given_or_drawn(names, receiver_dsb_ns, 8.0, rng)
    time = np.asarray(datetime_from_gps_seconds(t)).astype("datetime64[ns]")
    jitter = options.shell_jitter_km
    shells = [
        (height + 1e3 * jitter * rng.standard_normal() if jitter > 0 else height, weight)
        for height, weight in _SHELLS_M
    ]
    tids = _draw_tids(rng, options.tid_tecu, options.n_tid)
    ifb: dict[str, dict[int, float]] = {}
    if options.channels is not None and options.channel_ifb_ns > 0:
        groups = sorted(set(options.channels.values()))
        ifb = {
            n: dict(zip(groups, rng.normal(0.0, options.channel_ifb_ns, len(groups)).tolist(), strict=True))
            for n in names
        }
    shared = _Day(t, time, svs, sat_xyz, sat_dsb, rx_dsb, options.field or VtecField(), shells, tids, ifb)
    gross_at = options.gross_station or names[-1]
    obs: list[CodeObservations] = []
    gross: dict[str, int] = {}
    for ri, name in enumerate(names):
        o, n_gross = _station(shared, ri, name, sta[name], name == gross_at, options, rng)
        obs.append(o)
        if n_gross is not None:
            gross[name] = n_gross
    svn49 = options.svn49 if options.svn49 in svs else None
    return SimulatedNetwork(obs, sat_dsb, rx_dsb, shared.field, svn49, gross, ifb)


def _station(
    day: _Day,
    ri: int,
    name: str,
    site: tuple[float, float, float],
    gross_here: bool,
    options: NetworkSimOptions,
    rng: np.random.Generator,
) -> tuple[CodeObservations, int | None]:
    """One receiver's code and phase on both bands (and the number of its gross errors, if it gets them)."""
    lat, lon = np.deg2rad(site[0]), np.deg2rad(site[1])
    xyz = np.asarray(geodetic_to_ecef(lat, lon, site[2]), float).reshape(3)
    az, el = azimuth_elevation(xyz, day.sat_xyz)  # (T, S)
    up = el > np.deg2rad(options.record_mask_deg)
    el_s = np.where(up, el, 0.5 * np.pi)
    az_s = np.where(up, az, 0.0)
    iono = _slant_ionosphere_m(day, lat, lon, az_s, el_s, options, rng)
    scale = float(options.station_noise_scale[ri % len(options.station_noise_scale)])
    rho = np.linalg.norm(day.sat_xyz - xyz, axis=-1)
    unit = _multipath(np.random.default_rng([options.multipath_seed, ri]), len(day.svs), el_s, az_s)
    if options.multipath_day_fraction > 0:
        f = options.multipath_day_fraction
        today = _multipath(rng, len(day.svs), el_s, az_s)
        unit = [np.sqrt(1.0 - f**2) * u + f * v for u, v in zip(unit, today, strict=True)]
    amp = scale * options.multipath_m * np.exp(-np.rad2deg(el_s) / options.multipath_el_scale_deg)
    ranges: dict[int, np.ndarray] = {}
    phases: dict[int, np.ndarray] = {}
    for k, band in enumerate((1, 2)):
        p, phi = _band(day, name, band, rho, iono, (1.0 + 0.3 * k) * amp * unit[k], scale, up, el_s, options, rng)
        ranges[band], phases[band] = np.where(up, p, np.nan), np.where(up, phi, np.nan)
    if name in day.channel_ifb_ns and options.channels is not None:
        own = day.channel_ifb_ns[name]
        ranges[1] = ranges[1] + C_M_S * 1e-9 * np.array([own.get(options.channels.get(s, -99), 0.0) for s in day.svs])
    n_gross = None
    if options.gross_fraction > 0 and gross_here:
        idx = np.flatnonzero(up.ravel())
        hit = rng.choice(idx, int(round(options.gross_fraction * idx.size)), replace=False)
        flat = ranges[1].ravel()
        flat[hit] += rng.choice([-1.0, 1.0], hit.size) * rng.uniform(5.0, 50.0, hit.size)
        ranges[1] = flat.reshape(el.shape)
        n_gross = int(hit.size)
    obs = CodeObservations(
        name,
        Path(f"simulated-{name}"),
        day.time,
        tuple(day.svs),
        {1: "C1W", 2: "C2W"},
        ranges,
        xyz,
        receiver="SIMULATED",
        rinex_version=2.11,
        notes=("simulated by distnav.models.gnss.netsim",),
        phase_m=phases,
        lli={b: np.zeros(el.shape, np.int8) for b in (1, 2)},
        phase_types={1: "L1W", 2: "L2W"},
    )
    return obs, n_gross


def _slant_ionosphere_m(
    day: _Day,
    lat: float,
    lon: float,
    az_s: np.ndarray,
    el_s: np.ndarray,
    options: NetworkSimOptions,
    rng: np.random.Generator,
) -> np.ndarray:
    """The slant L1 delay [m] integrated over the three shells (VTEC field + TIDs), plus the irregularities."""
    iono = np.zeros(el_s.shape)
    for height, weight in day.shells:
        la, lo, z = pierce_point(lat, lon, az_s, el_s, height_m=height)
        iono += (
            weight * (day.field.tecu(la, lo, day.t[:, None]) + _tid_tecu(day.tids, la, lo, day.t[:, None])) / np.cos(z)
        )
    if options.irregularity_tecu > 0:
        _, _, z = pierce_point(lat, lon, az_s, el_s, height_m=450e3)
        step = options.interval_s / options.irregularity_tau_s
        iono += options.irregularity_tecu * _ar1(rng, el_s.shape, step) / np.cos(z)
    out: np.ndarray = iono * TECU_L1_M
    return out


def _band(
    day: _Day,
    name: str,
    band: int,
    rho: np.ndarray,
    iono: np.ndarray,
    multipath: np.ndarray,
    scale: float,
    up: np.ndarray,
    el_s: np.ndarray,
    options: NetworkSimOptions,
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray]:
    """Code and phase [m] of one band: range, ionosphere, DSBs (on P1), multipath, noise, the SVN49-like bias,
    and a new integer ambiguity per pass."""
    mu_k = 1.0 if band == 1 else mu(2)
    k = 0 if band == 1 else 1
    dsb_part = np.array([day.sat_dsb[s] for s in day.svs]) + day.rx_dsb[name] if band == 1 else 0.0
    noise = scale * options.code_sigma_m[k] / np.sin(el_s) * rng.standard_normal(el_s.shape)
    p = rho + mu_k * iono + C_M_S * 1e-9 * dsb_part + multipath + noise
    if options.svn49 in day.svs:
        j = day.svs.index(options.svn49)
        p[:, j] += (0.9 if band == 1 else -0.3) * np.cos(el_s[:, j]) ** 2
    ambiguity = np.zeros(el_s.shape)
    for j in range(len(day.svs)):  # a new integer ambiguity per pass
        starts = np.flatnonzero(np.diff(np.concatenate([[False], up[:, j]]).astype(int)) == 1)
        if starts.size == 0:
            continue
        for a, b in zip(starts, np.concatenate([starts[1:], [el_s.shape[0]]]), strict=True):
            ambiguity[a:b, j] = rng.integers(-5000, 5000)
    lam = C_M_S / GPS_FREQUENCIES_HZ[band]
    phi = rho - mu_k * iono + lam * ambiguity + options.phase_sigma_m * rng.standard_normal(el_s.shape)
    return p, phi


def _multipath(g: np.random.Generator, n_sv: int, el: np.ndarray, az: np.ndarray) -> list[np.ndarray]:
    """Unit multipath patterns of both bands per satellite: a sinusoid in elevation and one in azimuth whose
    periods and phases ``g`` draws."""
    lam_el = np.deg2rad(g.uniform(4.0, 12.0, (2, n_sv)))
    ph = g.uniform(0, 2 * np.pi, (4, n_sv))
    n_az = g.integers(1, 4, n_sv)
    return [np.sin(el / lam_el[k] + ph[k]) + 0.5 * np.sin(n_az * az + ph[2 + k]) for k in (0, 1)]


def _draw_tids(rng: np.random.Generator, tecu: float, n: int) -> list[tuple[float, float, float, float, float]]:
    """``n`` plane waves (amplitude TECU, direction rad, wavelength km, period s, phase) or none."""
    if tecu <= 0 or n <= 0:
        return []
    return [
        (
            tecu * rng.uniform(0.5, 1.0),
            rng.uniform(0, 2 * np.pi),
            rng.uniform(150.0, 400.0),
            rng.uniform(900.0, 3600.0),
            rng.uniform(0, 2 * np.pi),
        )
        for _ in range(n)
    ]


def _tid_tecu(
    tids: Sequence[tuple[float, float, float, float, float]], lat: np.ndarray, lon: np.ndarray, t: np.ndarray
) -> np.ndarray | float:
    if not tids:
        return 0.0
    north_km = np.rad2deg(lat) * 111.2
    east_km = np.rad2deg(lon) * 111.2 * np.cos(lat)
    out: np.ndarray = sum(
        a * np.sin(2 * np.pi * ((np.cos(d) * north_km + np.sin(d) * east_km) / lam_km - t / period_s) + ph)
        for a, d, lam_km, period_s, ph in tids
    )
    return out


def _ar1(rng: np.random.Generator, shape: tuple[int, ...], step: float) -> np.ndarray:
    """A unit-variance AR(1) process along axis 0 with correlation ``exp(−step)`` between rows."""
    from scipy.signal import lfilter

    a = float(np.exp(-step))
    e = rng.standard_normal(shape) * np.sqrt(1.0 - a * a)
    e[0] = rng.standard_normal(shape[1:])
    out: np.ndarray = lfilter([1.0], [1.0, -a], e, axis=0)
    return out


def truth_product(sim: SimulatedNetwork, day: str | np.datetime64 | None = None) -> Any:
    """The truth as a product (C1W − C2W DSBs) for :func:`~distnav.models.gnss.products.compare_in_datum`."""
    from distnav.models.gnss.products import ProductDSB

    return ProductDSB(
        "truth",
        Path("simulation"),
        "truth",
        dict(sim.satellite_dsb_ns),
        dict(sim.receiver_dsb_ns),
        [],
        None if day is None else np.datetime64(str(day)[:10]),
    )
