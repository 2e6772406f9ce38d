"""The data stages of ``distnav gnss ionosphere``: read the stations' RINEX files, level the geometry-free code
to the carrier per arc and screen it (each station on its own data), and build the receiver + satellite bias
model (:func:`~distnav.models.gnss.gfnetwork.bias_network_model`). :func:`network_data` starts from files,
:func:`network_from_observations` from observations already read (simulated networks, benchmarks)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from distnav._checks import check_field_types
from distnav.errors import DataFileError, ModelError

if TYPE_CHECKING:
    from distnav.models.gnss.biasmodel import BiasModelOptions

__all__ = [
    "ARC_CORRELATION_S",
    "REGIONAL_KM",
    "NetworkOptions",
    "geometry_free_network",
    "network_data",
    "network_from_observations",
]

REGIONAL_KM = 1000.0
ARC_CORRELATION_S = 0.0
"""Correlation time [s] of the levelled code's error within an arc (σ per arc:
:func:`~distnav.models.gnss.gfnetwork.arc_sigma_scale`); 0 = off (independent epochs, the default)."""


@dataclass(frozen=True)
class NetworkOptions:
    """How :func:`network_data` / :func:`network_from_observations` prepare a network (defaults in brackets;
    checked once, here).

    ``l2_code`` [``"C2W"``]: the second code; its band (2, 5, …) is the model's (``model.band`` is set from it).
    ``interval_s`` [None: every epoch]: the filter's grid. ``exclude`` [()]: satellites (``G01``) and stations
    (``BELE``) left out. ``levelling`` [True]: carrier-to-code levelling per arc on the full-rate data
    (:func:`~distnav.models.gnss.levelling.level_station`, arcs shorter than ``min_arc_epochs`` [10] dropped,
    slips by the geometry-free phase from ``gf_threshold_m`` [0.05]); ``screen`` [True]: each station's w-test
    screening of its own code. ``arc_correlation_s`` [None: :data:`ARC_CORRELATION_S`]: the levelled code's σ per
    arc (:func:`~distnav.models.gnss.biasmodel.arc_sigma_scale`; 0: independent epochs). ``model``: the
    :class:`~distnav.models.gnss.biasmodel.BiasModelOptions` of the model stage."""

    l2_code: str = "C2W"
    interval_s: float | None = None
    exclude: tuple[str, ...] = ()
    levelling: bool = True
    min_arc_epochs: int = 10
    gf_threshold_m: float = 0.05
    screen: bool = True
    arc_correlation_s: float | None = None
    model: BiasModelOptions | None = None  # None: BiasModelOptions() (imported when used: the CLI starts light)

    def __post_init__(self) -> None:
        from distnav.models.gnss.biasmodel import BiasModelOptions

        check_field_types(self, error=ModelError)  # types first, naming the field (issue 29)
        code = self.l2_code.upper()
        if len(code) != 3 or code[0] != "C" or not code[1].isdigit() or code[1] == "1":
            raise ModelError(f"l2_code {self.l2_code}: not a second code (C2W, C2L, C5Q …)")
        if self.interval_s is not None and not (np.isfinite(self.interval_s) and self.interval_s > 0):
            raise ModelError(f"interval_s must be a positive number of seconds, got {self.interval_s}")
        if self.min_arc_epochs < 2:
            raise ModelError(f"min_arc_epochs must be ≥ 2, got {self.min_arc_epochs}")
        if not (np.isfinite(self.gf_threshold_m) and self.gf_threshold_m > 0):
            raise ModelError(f"gf_threshold_m must be a positive number, got {self.gf_threshold_m}")
        object.__setattr__(self, "exclude", tuple(e.upper() for e in self.exclude))
        object.__setattr__(self, "model", replace(self.model or BiasModelOptions(), band=int(code[1])))

    @property
    def model_options(self) -> BiasModelOptions:
        """The model stage's options (never None after construction; the band is the second code's)."""
        assert self.model is not None
        return self.model


def network_data(
    obs_files: Sequence[str | Path],
    orbit: Any,
    options: NetworkOptions = NetworkOptions(),
    *,
    l1_code: str = "C1C",
    tlim: tuple[str, str] | None = None,
    progress: Any = None,
    c1_corrections: str | None = None,
    system: str = "G",
) -> Any:
    """Read the stations (the read stage), then :func:`network_from_observations`. ``l1_code``: the first code;
    ``system``: the satellite system read (``G``; ``E`` Galileo, ``C`` BeiDou, ``R`` GLONASS, whose FDMA
    channels come from the header or, RINEX 2, from the orbit's navigation records);
    ``c1_corrections``: a Bias-SINEX product whose C1C−C1W DSBs are removed from C1C (the receivers' DSBs keep
    their own code pair). Errors name the file: unreadable files, missing code types, a station without any epoch
    with both codes; a navigation or SP3 file of another day is named, not left to the elevation mask."""
    from distnav.formats.gnss.product_files import check_orbit_day
    from distnav.formats.gnss.rinex import read_stations

    obs = read_stations(
        list(obs_files),
        l1_code=l1_code,
        l2_code=options.l2_code,
        tlim=tlim,
        interval_s=None if options.levelling else options.interval_s,
        phases=options.levelling,
        progress=progress,
        l1_fallback="C1W" if c1_corrections else None,
        system=system,
        channels=orbit.channels() if system == "R" and hasattr(orbit, "channels") else None,  # RINEX 2 has none
    )
    check_orbit_day(orbit, obs)  # another day's orbits: named (issue 29), not left to the mask
    own = {o.station: dict(o.codes) for o in obs}  # the receivers' own codes (their DSBs' code pair)
    if c1_corrections:
        from distnav.formats.gnss.product_files import correct_c1

        obs = [correct_c1(o, c1_corrections) if o.codes.get(1) == "C1C" else o for o in obs]
    data = network_from_observations(obs, orbit, options)
    return replace(data, codes={s: own[s] for s in data.stations})


def network_from_observations(obs: Sequence[Any], orbit: Any, options: NetworkOptions = NetworkOptions()) -> Any:
    """The pipeline from observations already read (:class:`~distnav.models.gnss.code_observations.
    CodeObservations` with phases when levelling; the full-rate data, ``interval_s`` selects the filter's grid):
    level and screen each station (:func:`_level`), put the stations on one grid (:func:`geometry_free_network`),
    build the model (:func:`~distnav.models.gnss.biasmodel.bias_network_model`) and attach the arcs."""
    from distnav.models.gnss.arcprecision import arc_ids_on_grid
    from distnav.models.gnss.biasmodel import bias_network_model

    excl = set(options.exclude)
    unknown = sorted(e for e in excl if len(e) == 4 and e not in {o.station for o in obs})  # satellites: 3 chars
    if unknown:
        raise DataFileError(
            f"--exclude {' '.join(unknown)}: no such station (stations: {', '.join(o.station for o in obs)})"
        )
    obs = [_without_unknown_frequencies(o, options.model_options.band) for o in obs if o.station not in excl]
    if not obs:
        raise DataFileError("every station is excluded")
    band = options.model_options.band
    levelled = {o.station: _level(o, orbit, band, options, i) for i, o in enumerate(obs)} if options.levelling else {}
    if options.levelling and options.interval_s:
        from distnav.formats.gnss.rinex_obs import on_grid

        grids = {o.station: on_grid(o.time, options.interval_s) for o in obs}
    else:
        grids = {o.station: np.ones(o.time.size, bool) for o in obs}
    network = geometry_free_network(obs, levelled, grids, options)
    data = replace(bias_network_model(network, orbit, options.model_options), network=network)
    arc_id = arc_ids_on_grid(obs, levelled, grids, data.t_gps_s, data.layout.svs) if options.levelling else None
    return replace(
        data,
        levelled=levelled,
        levelled_svs={o.station: list(o.svs) for o in obs},
        levelled_times={o.station: o.time for o in obs},
        arc_id=arc_id,
    )


def geometry_free_network(
    obs: Sequence[Any], levelled: dict[str, Any], grids: dict[str, np.ndarray], options: NetworkOptions
) -> Any:
    """The hand-over to the model stage (:class:`~distnav.models.gnss.biasmodel.GeometryFreeNetwork`): every
    station's levelled (or raw) geometry-free code on the union of their grid epochs, the arcs' σ factors, the
    stations' σ factors and the notes of the stages so far."""
    from distnav.models.gnss.biasmodel import GeometryFreeNetwork, arc_sigma_scale
    from distnav.models.gnss.gfbias import geometry_free_band_m
    from distnav.models.gnss.levelling import station_sigma_factors
    from distnav.models.gnss.orbits import gps_seconds

    band, excl = options.model_options.band, set(options.exclude)
    t_all = np.unique(np.concatenate([gps_seconds(o.time[grids[o.station]]) for o in obs]))
    svs_all = sorted({s for o in obs for s in o.svs} - excl)
    gf = np.full((t_all.size, len(obs), len(svs_all)), np.nan)
    freqs = _network_frequencies(obs, svs_all, band)
    corr_s = ARC_CORRELATION_S if options.arc_correlation_s is None else float(options.arc_correlation_s)
    scale = np.ones(gf.shape) if levelled and corr_s > 0 else None
    for i, o in enumerate(obs):
        keep_t = grids[o.station]
        ti = np.searchsorted(t_all, gps_seconds(o.time[keep_t]))
        cols = [k for k, sv in enumerate(o.svs) if sv not in excl]
        si = np.array([svs_all.index(o.svs[k]) for k in cols], dtype=np.int64)
        if levelled:
            full = levelled[o.station].gf_m
        else:
            f1, fb = o.frequencies_hz(band)
            full = geometry_free_band_m(o.range_m[1], o.range_m[band], band, mu_b=(f1 / fb) ** 2)
        gf[np.ix_(ti, np.array([i]), si)] = full[keep_t][:, cols][:, None, :]
        if scale is not None:
            arcs = levelled[o.station].arc[keep_t][:, cols]
            scale[np.ix_(ti, np.array([i]), si)] *= arc_sigma_scale(arcs, t_all[ti], corr_s)[:, None, :]
        if not (np.isfinite(o.range_m[1]) & np.isfinite(o.range_m[band])).any():
            raise DataFileError(
                f"{o.path}: no epoch with a GPS satellite on both {o.codes[1]} and {o.codes[band]} (missing frequency?)"
            )
    return GeometryFreeNetwork(
        [o.station for o in obs],
        t_all,
        np.stack([o.position_ecef_m for o in obs]),
        gf,
        svs_all,
        codes={o.station: dict(o.codes) for o in obs},
        notes=_stage_notes(obs, levelled, excl, options.min_arc_epochs),
        paths=[str(o.path) for o in obs],
        sigma_scale=scale,
        station_sigma=station_sigma_factors([levelled[o.station] for o in obs]) if levelled else None,
        frequencies_hz=freqs,
    )


def _network_frequencies(obs: Sequence[Any], svs: list[str], band: int) -> tuple[np.ndarray, np.ndarray] | None:
    """``(f_1, f_b)`` (S,) [Hz] of the network's satellites (their own codes' bands and GLONASS channels; NaN for
    a GLONASS satellite without a channel), or ``None`` for GPS/Galileo signals on GPS L1 and band ``band`` (the
    models' default: the same numbers)."""
    from distnav.models.gnss.constants import GPS_FREQUENCIES_HZ

    f1, fb = np.full(len(svs), np.nan), np.full(len(svs), np.nan)
    for o in obs:
        g1, gb = o.frequencies_hz(band)
        cols = [k for k, s in enumerate(o.svs) if s in svs]
        at = [svs.index(o.svs[k]) for k in cols]
        f1[at], fb[at] = g1[cols], gb[cols]
    if np.all(f1 == GPS_FREQUENCIES_HZ[1]) and band in GPS_FREQUENCIES_HZ and np.all(fb == GPS_FREQUENCIES_HZ[band]):
        return None
    return f1, fb


def _without_unknown_frequencies(o: Any, band: int) -> Any:
    """The station without the satellites whose carrier frequency is unknown (a GLONASS satellite whose FDMA
    channel neither the observation header nor the navigation file gives), with a note naming them."""
    f1, fb = o.frequencies_hz(band)
    bad = ~(np.isfinite(f1) & np.isfinite(fb))
    if not bad.any():
        return o
    keep = np.flatnonzero(~bad)
    named = " ".join(o.svs[k] for k in np.flatnonzero(bad).tolist())

    def cut(d: dict[int, np.ndarray]) -> dict[int, np.ndarray]:
        return {b: v[:, keep] for b, v in d.items()}

    return replace(
        o,
        svs=tuple(o.svs[k] for k in keep.tolist()),
        range_m=cut(o.range_m),
        phase_m=cut(o.phase_m),
        lli=cut(o.lli),
        notes=(*o.notes, f"no frequency channel for {named} (dropped)"),
    )


def _stage_notes(obs: Sequence[Any], levelled: dict[str, Any], excl: set[str], min_arc_epochs: int) -> list[str]:
    """What reading, exclusion, levelling and screening did, station by station."""
    notes = [f"{o.station}: {n}" for o in obs for n in o.notes]
    if excl:
        notes.append(f"excluded: {' '.join(sorted(excl))}")
    for sta, lev in levelled.items():
        n_rm = int(lev.removed.sum())
        notes.append(
            f"{sta}: levelled {len(lev.arcs)} arcs (starts: "
            f"{', '.join(f'{k} {v}' for k, v in sorted(lev.starts.items()))}; {lev.dropped_short} shorter "
            f"than {min_arc_epochs} epochs dropped); screening removed {n_rm} code observations"
        )
    return notes


def _level(o: Any, orbit: Any, band: int, options: NetworkOptions, node: int) -> Any:
    """Level one station's geometry-free code per arc (σ of the code from the elevation: σ₀/sin θ)."""
    from distnav.models.gnss.geometry import azimuth_elevation
    from distnav.models.gnss.levelling import LevellingOptions, level_station
    from distnav.models.gnss.orbits import gps_seconds

    if band not in o.phase_m or 1 not in o.phase_m:
        raise DataFileError(f"{o.path}: no carrier phase on L1 and L{band} for levelling (use --levelling none)")
    t = gps_seconds(o.time)
    svs = [s for s in o.svs if s in orbit.svs]
    el = np.full((t.size, len(o.svs)), np.nan)
    if svs:
        _, e = azimuth_elevation(o.position_ecef_m, orbit.positions_ecef(t, svs))
        el[:, [o.svs.index(s) for s in svs]] = e
    above = np.isfinite(el) & (el > np.deg2rad(options.model_options.mask_deg))
    p1, pb = np.where(above, o.range_m[1], np.nan), np.where(above, o.range_m[band], np.nan)
    sigma = 1.0 / np.sin(np.where(above, el, 0.5 * np.pi))
    lli = o.lli.get(1, np.zeros(p1.shape, np.int8)) | o.lli.get(band, np.zeros(p1.shape, np.int8))
    lev = LevellingOptions(
        band=band,
        frequencies_hz=_network_frequencies([o], list(o.svs), band),
        min_arc_epochs=options.min_arc_epochs,
        gf_threshold_m=options.gf_threshold_m,
        screen=options.screen,
        fallback_raw=True,
    )
    return level_station(
        t, o.svs, p1, pb, o.phase_m[1], o.phase_m[band], options=lev, lli=lli, sigma_m=sigma, node=node
    )
