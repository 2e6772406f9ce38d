"""The bias model of a receiver network: every station's undifferenced geometry-free code on the union of
their epochs (the hand-over :class:`GeometryFreeNetwork` from levelling and screening) put into the receiver +
satellite DSB model of :mod:`distnav.models.gnss.gfbias` (paper 003 eq. (49), undifferenced; estimation basis: a
reference receiver observing at the first epoch). The next stage, :mod:`distnav.models.gnss.gfnetwork`, runs the
filters on the :class:`BiasNetworkData` built here."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from distnav._checks import check_field_types
from distnav.errors import DataFileError, ModelError
from distnav.models.gnss.constants import C_M_S
from distnav.models.gnss.gfbias import (
    TEC_RW_M_PER_SQRT_S,
    BiasGeometryFreeSeries,
    BiasStateLayout,
    bias_dynamics,
    gf_m_per_dsb_ns,
)

__all__ = [
    "MIN_SATELLITE_OBS",
    "BiasModelOptions",
    "BiasNetworkData",
    "GeometryFreeNetwork",
    "arc_sigma_scale",
    "bias_network_model",
]

MIN_SATELLITE_OBS = 240
"""Fewest station-epochs (at the filter's sampling) for a satellite to be estimated by default: 240 = 4
station-hours on a 60-s grid, but at most a quarter of the best-tracked satellite's count and at least 30 (so
short snapshots keep the old threshold, 30). Was 30 throughout; raised on the realistic simulator preset
(docs/ionosphere.md), where satellites seen for
less than about an hour per station in a 6-h session carry DCB errors of ~1 ns that dominate the session's RMS
(the note "not estimated, fewer than …" names them; a full day excludes none)."""


@dataclass(frozen=True, eq=False)
class BiasNetworkData:
    """Stations, epochs, geometry, layout (estimation basis), series and dynamics of a network."""

    stations: list[str]
    codes: dict[str, dict[int, str]]
    band: int
    t_gps_s: np.ndarray
    geometry: Any
    layout: BiasStateLayout
    series: BiasGeometryFreeSeries
    dynamics: Any
    ionosphere: str
    positions_ecef_m: np.ndarray
    obs_m: np.ndarray
    sigma_m: np.ndarray
    notes: list[str] = field(default_factory=list)
    levelled: dict[str, Any] = field(default_factory=dict)
    levelled_svs: dict[str, list[str]] = field(default_factory=dict)
    levelled_times: dict[str, np.ndarray] = field(default_factory=dict)
    """Per station the epochs (``datetime64``) of the levelled rows (screening reports name them)."""
    arc_id: np.ndarray | None = None
    """(T, n, S) the levelled arc of every observation (per station; −1: raw code), ``None`` without levelling
    (:mod:`~distnav.models.gnss.arcprecision`)."""
    frequencies_hz: tuple[np.ndarray, np.ndarray] | None = None
    """``(f_1, f_2)`` (S,) of the estimated satellites (``layout.svs``); ``None``: GPS L1 and ``band``."""
    network: GeometryFreeNetwork | None = None
    """The hand-over this model was built from (kept by the data stage: another model of the same data,
    :mod:`~distnav.models.gnss.modelspread`)."""
    m_per_dsb_ns: float | None = None
    """Metres of the geometry-free observable per ns of DSB, ``c·10⁻⁹/(μ − 1)`` of the network's signal pair
    (``None``: GPS L1 and ``band``, :func:`~distnav.models.gnss.gfbias.gf_m_per_dsb_ns`)."""
    sigma_terms: dict[str, Any] = field(default_factory=dict)
    """The σ terms another part of the same data supplied (``summary.json`` ``sigma_terms``;
    :mod:`~distnav.models.gnss.sigmaterms`)."""

    @property
    def dsb_scale_m_per_ns(self) -> float:
        """Metres of the observable per ns of a DSB (the DSBs' scale, whatever the system)."""
        return gf_m_per_dsb_ns(self.band) if self.m_per_dsb_ns is None else self.m_per_dsb_ns

    def series_for(self, reference: str) -> BiasGeometryFreeSeries:
        """The same data in the basis of another reference receiver."""
        lay = BiasStateLayout(
            self.layout.svs,
            self.layout.receivers,
            self.layout.n_ionospheres,
            "receiver",
            reference,
            self.layout.n_tec_terms,
        )
        return BiasGeometryFreeSeries(
            lay,
            self.geometry.coefficients,
            self.sigma_m,
            obs_m=self.obs_m,
            tracked=self.geometry.tracked,
            groups=self.geometry.groups,
        )


IONOSPHERE_MODES = ("auto", "common", "per-receiver")
WEIGHTINGS = ("sin", "euler-goad", "constant")
STATION_WEIGHTINGS = ("auto", "on", "off")


@dataclass(frozen=True)
class BiasModelOptions:
    """How :func:`bias_network_model` builds the model (defaults in brackets; checked once, here).

    ``band`` [2]: the second code's RINEX band (2, 5). ``mask_deg`` [10]: elevation mask. ``ionosphere``
    [``"auto"``]: ``"common"``, ``"per-receiver"`` or ``"auto"`` (common when the longest baseline is within
    ``regional_km`` [1000]; the choice is printed with its reason). ``sigma_zenith_m`` [None: paper 003's 65.6 cm
    scaled to the band, √2·30 cm/(μ_b − 1)] with ``weighting`` [``"sin"``]. ``reference`` [None: the station with
    the most observations among those observing at the first epoch]: the estimation basis.
    ``vtec_rw_m_per_sqrt_s`` [:data:`TEC_RW_M_PER_SQRT_S`]: random walk of the vertical delay (gradients 5× per
    radian). ``min_satellite_obs`` [None: :data:`MIN_SATELLITE_OBS`' rule]. ``tec_order`` [1] / ``mapping``
    [``"slm"``]: the VTEC field and the single-layer mapping (docs/gnss.md, low latitudes). ``station_weighting``
    [``"auto"``]: per-station σ factors from the levelling ``"on"``, ``"off"`` or ``"auto"`` (with a common
    ionosphere only)."""

    band: int = 2
    mask_deg: float = 10.0
    ionosphere: str = "auto"
    regional_km: float = 1000.0
    sigma_zenith_m: float | None = None
    weighting: str = "sin"
    reference: str | None = None
    vtec_rw_m_per_sqrt_s: float = TEC_RW_M_PER_SQRT_S
    min_satellite_obs: int | None = None
    tec_order: int = 1
    mapping: str = "slm"
    station_weighting: str = "auto"

    def __post_init__(self) -> None:
        check_field_types(self, error=ModelError)  # types first, naming the field (issue 29)
        for name, value, allowed in (
            ("ionosphere", self.ionosphere, IONOSPHERE_MODES),
            ("weighting", self.weighting, WEIGHTINGS),
            ("station_weighting", self.station_weighting, STATION_WEIGHTINGS),
            ("mapping", self.mapping, ("slm", "mslm")),
            ("tec_order", self.tec_order, (1, 2)),
        ):
            if value not in allowed:
                raise ModelError(f"{name} must be one of {', '.join(map(str, allowed))}; got {value!r}")
        if self.band == 1:
            raise ModelError("band 1 is the first frequency; the second code's band is 2, 5, …")
        if not 0.0 <= self.mask_deg < 90.0:
            raise ModelError(f"elevation mask must lie in [0°, 90°), got {self.mask_deg}°")
        for quantity, number in (("regional_km", self.regional_km), ("sigma_zenith_m", self.sigma_zenith_m)):
            if number is not None and not (np.isfinite(number) and number > 0):
                raise ModelError(f"{quantity} must be a positive number, got {number}")
        if not (np.isfinite(self.vtec_rw_m_per_sqrt_s) and self.vtec_rw_m_per_sqrt_s > 0):
            raise ModelError(f"the TEC random walk must be positive, got {self.vtec_rw_m_per_sqrt_s} m/√s")
        if self.min_satellite_obs is not None and self.min_satellite_obs < 1:
            raise ModelError(f"min_satellite_obs must be ≥ 1, got {self.min_satellite_obs}")


@dataclass(frozen=True, eq=False)
class GeometryFreeNetwork:
    """The hand-over from levelling and screening to the model: every station's geometry-free code ``gf_m``
    (T, n, S) [m] (NaN = not observed) on the union of their epochs ``t_gps_s``, the stations' ECEF positions
    ``positions_ecef_m`` (n, 3) and the satellites ``svs`` (S). ``codes`` per station its code types, ``notes``
    what the stages before said, ``paths`` the files (errors name them; default the station names),
    ``sigma_scale`` (T, n, S) factors on the elevation-dependent σ (:func:`arc_sigma_scale`), ``station_sigma``
    (n,) the stations' σ factors (:func:`~distnav.models.gnss.levelling.station_sigma_factors`)."""

    stations: list[str]
    t_gps_s: np.ndarray
    positions_ecef_m: np.ndarray
    gf_m: np.ndarray
    svs: Sequence[str]
    codes: dict[str, dict[int, str]] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    paths: list[str] | None = None
    sigma_scale: np.ndarray | None = None
    station_sigma: np.ndarray | None = None
    frequencies_hz: tuple[np.ndarray, np.ndarray] | None = None
    """``(f_1, f_2)`` (S,) [Hz] of each satellite's two signals (BeiDou B1I/B3I, GLONASS per FDMA channel);
    ``None``: GPS L1 and the options' ``band`` (GPS, Galileo E1/E5a/E5b/E5)."""


def bias_network_model(
    network: GeometryFreeNetwork, orbit: Any, options: BiasModelOptions = BiasModelOptions()
) -> BiasNetworkData:
    """The receiver + satellite bias model (:mod:`~distnav.models.gnss.gfbias`, paper 003 eq. (49) undifferenced)
    of a network's geometry-free code, in the basis of a reference receiver; ``options``:
    :class:`BiasModelOptions`.

    Raises :class:`~distnav.errors.ModelError` / :class:`~distnav.errors.DataFileError` when the orbit has no
    position at the epochs, a station keeps no observation above the mask, or the stations share no satellite.
    Satellites with fewer than ``min_satellite_obs`` station-epochs are not estimated (a note names them): a
    satellite seen for a few minutes at low elevation at a session edge has a DCB of several ns σ that would only
    pull the zero-mean datum. Per-station σ factors apply with ``station_weighting`` "on", or "auto" when the
    stations share one ionosphere (docs/gnss.md: with per-station layers each station's own ionosphere error, not
    its code noise, limits it).

    Examples
    --------
    >>> import numpy as np
    >>> from distnav.models.gnss.biasmodel import BiasModelOptions, GeometryFreeNetwork, bias_network_model
    >>> from distnav.models.gnss.geometry import geodetic_to_ecef
    >>> from distnav.models.gnss.orbits import gps_seconds, synthetic_gps_constellation
    >>> gps = synthetic_gps_constellation()
    >>> t = gps_seconds(np.datetime64("2016-06-02T00:00")) + 60.0 * np.arange(120)
    >>> xyz = geodetic_to_ecef(np.deg2rad([50.0, 51.0]), np.deg2rad([10.0, 12.0]), np.zeros(2))
    >>> gf = np.full((t.size, 2, len(gps.svs)), 5.0)
    >>> net = GeometryFreeNetwork(["A", "B"], t, xyz, gf, list(gps.svs))
    >>> data = bias_network_model(net, gps, BiasModelOptions(min_satellite_obs=30))
    >>> data.ionosphere, data.layout.receivers, len(data.layout.svs) >= 4
    ('common', ('A', 'B'), True)
    """
    notes = list(network.notes)
    t_all = np.asarray(network.t_gps_s, dtype=float)
    xyz = np.asarray(network.positions_ecef_m, float)
    gf = np.asarray(network.gf_m, dtype=float)
    mode = _ionosphere_mode(xyz, options, notes)
    geo = _tracked_geometry(network, orbit, mode, options, notes)
    keep = _estimated_satellites(geo.tracked, list(network.svs), options.min_satellite_obs, notes)
    mu_pair, l1_factor = _signal_pair(network, keep, options.band)
    geo = replace(
        geo,
        svs=tuple(network.svs[k] for k in keep.tolist()),
        el_rad=geo.el_rad[:, :, keep],
        az_rad=geo.az_rad[:, :, keep],
        tracked=geo.tracked[:, :, keep],
        coefficients=geo.coefficients[:, :, keep] if l1_factor is None else geo.coefficients[:, :, keep] * l1_factor,
    )
    ref = _reference_receiver(geo.tracked, network.stations, options.reference)
    layout = BiasStateLayout(
        geo.svs,
        tuple(network.stations),
        1 if mode == "common" else len(network.stations),
        "receiver",
        ref,
        3 if options.tec_order == 1 else 6,
    )
    sig = _observation_sigma(network, geo, keep, mode, options, notes, mu_pair)
    obs = gf[:, :, keep]
    series = BiasGeometryFreeSeries(layout, geo.coefficients, sig, obs_m=obs, tracked=geo.tracked, groups=geo.groups)
    T = t_all.size
    dt = np.concatenate([[np.nan], np.diff(t_all)]) if T > 1 else np.array([30.0])
    dyn = bias_dynamics(
        layout,
        dt if T > 1 else 30.0,
        vtec_std_m_per_sqrt_s=options.vtec_rw_m_per_sqrt_s,
        gradient_std_m_per_rad_sqrt_s=5.0 * options.vtec_rw_m_per_sqrt_s,
    )
    return BiasNetworkData(
        network.stations,
        dict(network.codes),
        options.band,
        t_all,
        geo,
        layout,
        series,
        dyn,
        mode,
        xyz,
        obs,
        sig,
        notes,
        frequencies_hz=None if network.frequencies_hz is None else tuple(f[keep] for f in network.frequencies_hz),
        m_per_dsb_ns=None if network.frequencies_hz is None else C_M_S * 1e-9 / (mu_pair - 1.0),
    )


def _signal_pair(network: GeometryFreeNetwork, keep: np.ndarray, band: int) -> tuple[float, np.ndarray | None]:
    """``μ = (f_1/f_2)²`` of the estimated satellites' signal pair and the factor ``(f_L1/f_1)²`` (1, 1, S, 1)
    that makes their geometry-free code's TEC coefficients those of the L1 delay the state holds (the
    observable is the delay on the satellite's own f_1: 40.3·TEC/f_1²); ``None`` for GPS/Galileo on L1.

    One μ for all satellites: a DSB of ``d`` ns is ``d·c·10⁻⁹/(μ − 1)`` metres of every satellite's observable,
    so a receiver bias is one parameter. GLONASS channels change f_1 and f_2 in the same ratio 9/7 (1602/1246 =
    0.5625/0.4375), so their μ is one; a mix of ratios is refused."""
    from distnav.models.gnss.constants import F_L1_HZ, mu

    if network.frequencies_hz is None:
        return mu(band), None
    f1, f2 = (np.asarray(f, float)[keep] for f in network.frequencies_hz)
    mus = (f1 / f2) ** 2
    if not np.allclose(mus, mus[0], rtol=1e-9, atol=0.0):
        odd = [network.svs[k] for k, m in zip(keep.tolist(), mus.tolist(), strict=True) if abs(m - mus[0]) > 1e-9]
        raise ModelError(f"the satellites' signal pairs differ in frequency ratio ({' '.join(odd)}): one DSB scale")
    return float(mus[0]), ((F_L1_HZ / f1) ** 2)[None, None, :, None]


def _ionosphere_mode(xyz: np.ndarray, options: BiasModelOptions, notes: list[str]) -> str:
    """``options.ionosphere``, or the automatic choice by the longest baseline, noted with its test and reason."""
    n = xyz.shape[0]
    base_km = float(np.max(np.linalg.norm(xyz[:, None] - xyz[None], axis=-1))) / 1e3 if n > 1 else 0.0
    mode = options.ionosphere
    if mode == "auto":
        mode = "common" if base_km <= options.regional_km else "per-receiver"
        rule = "≤" if mode == "common" else ">"
        notes.append(
            f"model choice: ionosphere {mode}, because the longest baseline {base_km:.0f} km {rule} the regional "
            f"limit {options.regional_km:.0f} km (one VTEC field is valid within it); receiver DSBs depend on this "
            "choice (--ionosphere common|per-receiver fixes it)"
        )
    return mode


def _tracked_geometry(
    network: GeometryFreeNetwork, orbit: Any, mode: str, options: BiasModelOptions, notes: list[str]
) -> Any:
    """The pierce-point geometry of every station–satellite pair, tracked where the code was observed above the
    mask; errors when the orbit gives nothing, a station keeps nothing, or the stations share no satellite."""
    from distnav.models.gnss.ionosphere import GeometryOptions, ionosphere_geometry
    from distnav.models.gnss.orbits import datetime_from_gps_seconds

    t_all = np.asarray(network.t_gps_s, dtype=float)
    gf = np.asarray(network.gf_m, dtype=float)
    svs_all, paths = list(network.svs), network.paths or list(network.stations)
    geo = ionosphere_geometry(
        orbit,
        t_all,
        receivers_ecef_m=np.asarray(network.positions_ecef_m, float),
        names=network.stations,
        svs=svs_all,
        options=GeometryOptions(
            mask_deg=options.mask_deg, ionosphere=mode, tec_order=options.tec_order, mapping=options.mapping
        ),
    )
    if not np.isfinite(geo.el_rad).any():
        span = f"{str(datetime_from_gps_seconds(t_all[0]))[:19]} – {str(datetime_from_gps_seconds(t_all[-1]))[:19]}"
        raise ModelError(
            f"the orbit gives no satellite position at the observation epochs ({span}): wrong navigation/SP3 file?"
        )
    no_orbit = [
        svs_all[k]
        for k in range(len(svs_all))
        if np.isfinite(gf[:, :, k]).any() and not np.isfinite(geo.el_rad[:, :, k]).any()
    ]
    if no_orbit:
        notes.append(
            f"no orbit at the observation epochs for {' '.join(no_orbit)} (dropped; unhealthy or a sparse "
            f"broadcast file: try a larger --nav-max-age)"
        )
    geo = geo.with_tracked(np.isfinite(gf))
    for i in range(len(network.stations)):
        if not geo.tracked[:, i].any():
            raise DataFileError(
                f"{paths[i]}: no observation above the {options.mask_deg:g}° mask with both codes "
                f"(or no orbit for the satellites)"
            )
    if len(network.stations) > 1 and not (np.asarray(geo.tracked.any(axis=0)).sum(axis=0) >= 2).any():
        raise ModelError("no satellite is tracked by two or more stations: the stations share no parameter")
    return geo


def _estimated_satellites(
    tracked: np.ndarray, svs_all: list[str], min_satellite_obs: int | None, notes: list[str]
) -> np.ndarray:
    """Indices of the satellites with enough station-epochs to be estimated (the others named in a note)."""
    n_obs = tracked.sum(axis=(0, 1))
    if min_satellite_obs is None:
        min_satellite_obs = int(max(30, min(MIN_SATELLITE_OBS, 0.25 * float(n_obs.max()))))
    few = [svs_all[k] for k in range(len(svs_all)) if 0 < n_obs[k] < min_satellite_obs]
    if few:
        notes.append(
            f"not estimated, fewer than {min_satellite_obs} station-epochs: "
            + " ".join(f"{s} ({int(n_obs[svs_all.index(s)])})" for s in few)
        )
    keep = np.flatnonzero(n_obs >= max(min_satellite_obs, 1))
    if keep.size < 2:
        raise ModelError(f"fewer than two satellites with {min_satellite_obs} station-epochs or more")
    return keep


def _reference_receiver(tracked: np.ndarray, stations: list[str], reference: str | None) -> str:
    """The estimation basis: ``reference``, or the station with the most observations among those observing at
    the first epoch."""
    if reference is not None:
        ref = reference.upper()
        if ref not in stations:
            raise ModelError(f"reference receiver {reference}: not one of the stations {', '.join(stations)}")
        return ref
    counts = tracked.sum(axis=(0, 2))
    first = np.flatnonzero(tracked.any(axis=2).any(axis=0) & tracked[np.argmax(tracked.any(axis=(1, 2)))].any(axis=1))
    return stations[int(first[np.argmax(counts[first])])] if first.size else stations[int(np.argmax(counts))]


def _observation_sigma(
    network: GeometryFreeNetwork,
    geo: Any,
    keep: np.ndarray,
    mode: str,
    options: BiasModelOptions,
    notes: list[str],
    mu_pair: float,
) -> np.ndarray:
    """σ (T, n, S) of every observation: the elevation weighting (zenith σ √2·30 cm/(μ − 1) of the signal pair
    ``mu_pair`` unless given), the arcs' factors and the stations' factors (the latter noted as a model choice
    with its reason)."""
    from distnav.models.gnss.observables import elevation_sigma

    sig0 = (np.sqrt(2.0) * 0.30 / (mu_pair - 1.0)) if options.sigma_zenith_m is None else float(options.sigma_zenith_m)
    el = np.where(geo.tracked, geo.el_rad, 0.5 * np.pi)
    sig = elevation_sigma(el, sig0, options.weighting)
    if network.sigma_scale is not None:
        sig = sig * np.where(geo.tracked, np.asarray(network.sigma_scale, float)[:, :, keep], 1.0)
    weighting = options.station_weighting
    if network.station_sigma is not None and (weighting == "on" or (weighting == "auto" and mode == "common")):
        factors = np.asarray(network.station_sigma, float)
        sig = sig * factors[None, :, None]
        why = "station weighting on" if weighting == "on" else "the stations share one ionosphere"
        notes.append(
            f"model choice: station σ factors from the levelling ({why}): "
            + ", ".join(f"{s} {f:.2f}" for s, f in zip(network.stations, factors.tolist(), strict=True))
        )
    return sig


def arc_sigma_scale(arc_id: np.ndarray, t_s: np.ndarray, correlation_s: float) -> np.ndarray:
    """σ factors (T, S) for levelled code whose error is mostly the arc's levelling offset, common to the arc.

    An arc of ``n`` epochs over ``D`` seconds determines its offset only to about σ²/n_eff with
    ``n_eff = max(1, D / correlation_s)`` (multipath and the levelling error are correlated over
    ``correlation_s``), not σ²/n as independent epochs would: each epoch's σ is scaled by ``√(n / n_eff)`` so that
    the arc carries n_eff observations' worth of information. A departure from paper 003 (raw code, white noise);
    ``arc_id`` −1 (no arc, e.g. raw code kept) gets 1.
    """
    out = np.ones(arc_id.shape)
    if correlation_s <= 0:
        return out
    for a in np.unique(arc_id[arc_id >= 0]).tolist():
        where = arc_id == a
        ti = np.nonzero(where)[0]
        n = ti.size
        n_eff = max(1.0, float(t_s[ti.max()] - t_s[ti.min()]) / correlation_s)
        out[where] = np.sqrt(max(1.0, n / n_eff))
    return out
