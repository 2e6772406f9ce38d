"""The data stages of ``distnav gnss ionosphere``: read the stations' RINEX files, level the geometry-free code
to the carrier per arc and screen it (each station on its own data), and build the receiver + satellite bias
model (:func:`~distnav.models.gnss.gfnetwork.bias_network_model`). :func:`network_data` starts from files,
:func:`network_from_observations` from observations already read (simulated networks, benchmarks)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from distnav.errors import DataFileError

__all__ = ["ARC_CORRELATION_S", "REGIONAL_KM", "network_data", "network_from_observations"]

REGIONAL_KM = 1000.0
ARC_CORRELATION_S = 0.0
"""Correlation time [s] of the levelled code's error within an arc (σ per arc:
:func:`~distnav.models.gnss.gfnetwork.arc_sigma_scale`); 0 = off (independent epochs, the default)."""


def network_data(
    obs_files: Sequence[str | Path],
    orbit: Any,
    *,
    l1_code: str = "C1C",
    l2_code: str = "C2W",
    tlim: tuple[str, str] | None = None,
    interval_s: float | None = None,
    mask_deg: float = 10.0,
    ionosphere: str = "auto",
    regional_km: float = REGIONAL_KM,
    sigma_zenith_m: float | None = None,
    weighting: str = "sin",
    reference: str | None = None,
    progress: Any = None,
    exclude: Sequence[str] = (),
    levelling: bool = True,
    min_arc_epochs: int = 10,
    gf_threshold_m: float = 0.05,
    screen: bool = True,
    c1_corrections: str | None = None,
    tec_rw_m_per_sqrt_s: float | None = None,
    min_satellite_obs: int | None = None,
    system: str = "G",
    **model: Any,
) -> Any:
    """Read the stations, form the geometry-free code on the union of their epochs and build the bias model
    (:func:`distnav.models.gnss.gfnetwork.bias_network_model`). ``exclude``: satellites (``G01``) and stations
    (``BELE``) left out. ``levelling``: carrier-to-code levelling per arc on the full-rate data, then the
    ``interval_s`` grid (:func:`~distnav.models.gnss.levelling.level_station`; ``screen`` runs each station's
    w-test screening of its own code). ``system``: the satellite system read (``G``, or ``E`` Galileo).
    Errors name the file: unreadable files, missing code types, a station
    without any epoch with both codes."""
    from distnav.formats.gnss.rinex import read_stations

    obs = read_stations(
        list(obs_files),
        l1_code=l1_code,
        l2_code=l2_code,
        tlim=tlim,
        interval_s=None if levelling else interval_s,
        phases=levelling,
        progress=progress,
        l1_fallback="C1W" if c1_corrections else None,
        system=system,
    )
    own = {o.station: dict(o.codes) for o in obs}  # the receivers' own codes (their DSBs' code pair)
    if c1_corrections:
        from distnav.formats.gnss.product_files import correct_c1

        obs = [correct_c1(o, c1_corrections) if o.codes.get(1) == "C1C" else o for o in obs]
    data = network_from_observations(
        obs,
        orbit,
        l2_code=l2_code,
        interval_s=interval_s,
        mask_deg=mask_deg,
        ionosphere=ionosphere,
        regional_km=regional_km,
        sigma_zenith_m=sigma_zenith_m,
        weighting=weighting,
        reference=reference,
        exclude=exclude,
        levelling=levelling,
        min_arc_epochs=min_arc_epochs,
        gf_threshold_m=gf_threshold_m,
        screen=screen,
        tec_rw_m_per_sqrt_s=tec_rw_m_per_sqrt_s,
        min_satellite_obs=min_satellite_obs,
        **model,
    )
    return replace(data, codes={s: own[s] for s in data.stations})


def network_from_observations(
    obs: Sequence[Any],
    orbit: Any,
    *,
    l2_code: str = "C2W",
    interval_s: float | None = None,
    mask_deg: float = 10.0,
    ionosphere: str = "auto",
    regional_km: float = REGIONAL_KM,
    sigma_zenith_m: float | None = None,
    weighting: str = "sin",
    reference: str | None = None,
    exclude: Sequence[str] = (),
    levelling: bool = True,
    min_arc_epochs: int = 10,
    gf_threshold_m: float = 0.05,
    screen: bool = True,
    tec_rw_m_per_sqrt_s: float | None = None,
    min_satellite_obs: int | None = None,
    arc_correlation_s: float | None = None,
    tec_order: int = 1,
    mapping: str = "slm",
    station_weights: str = "auto",
) -> Any:
    """:func:`network_data` from observations already read
    (:class:`~distnav.models.gnss.code_observations.CodeObservations` with phases when ``levelling``; the
    full-rate data, ``interval_s`` selects the filter's grid).
    ``arc_correlation_s``: the levelled code's σ per arc from :func:`~distnav.models.gnss.gfnetwork.arc_sigma_scale`
    (default :data:`ARC_CORRELATION_S`; 0: independent epochs). ``station_weights`` "auto" | "on" | "off": σ
    factors from each station's levelling residuals ("auto": with a common ionosphere only; bias_network_model)."""
    from distnav.models.gnss.arcprecision import arc_ids_on_grid
    from distnav.models.gnss.gfbias import geometry_free_band_m
    from distnav.models.gnss.gfnetwork import (
        TEC_RW_M_PER_SQRT_S,
        arc_sigma_scale,
        bias_network_model,
    )
    from distnav.models.gnss.levelling import station_sigma_factors
    from distnav.models.gnss.orbits import gps_seconds

    band = int(l2_code[1])
    excl = {e.upper() for e in exclude}
    obs = [o for o in obs if o.station not in excl]
    if not obs:
        raise DataFileError("every station is excluded")
    stations = [o.station for o in obs]
    notes = [f"{o.station}: {n}" for o in obs for n in o.notes]
    levelled = (
        {
            o.station: _level(o, orbit, band, mask_deg, min_arc_epochs, gf_threshold_m, screen, i)
            for i, o in enumerate(obs)
        }
        if levelling
        else {}
    )
    if levelling and interval_s:
        from distnav.formats.gnss.rinex_obs import on_grid

        grids = {o.station: on_grid(o.time, interval_s) for o in obs}
    else:
        grids = {o.station: np.ones(o.time.size, bool) for o in obs}
    t_all = np.unique(np.concatenate([gps_seconds(o.time[grids[o.station]]) for o in obs]))
    svs_all = sorted({s for o in obs for s in o.svs} - excl)
    T, n, S = t_all.size, len(obs), len(svs_all)
    gf = np.full((T, n, S), np.nan)
    corr_s = ARC_CORRELATION_S if arc_correlation_s is None else float(arc_correlation_s)
    scale = np.ones((T, n, S)) if levelling and corr_s > 0 else None
    for i, o in enumerate(obs):
        keep_t = grids[o.station]
        ti = np.searchsorted(t_all, gps_seconds(o.time[keep_t]))
        cols = [k for k, sv in enumerate(o.svs) if sv not in excl]
        si = np.array([svs_all.index(o.svs[k]) for k in cols], dtype=np.int64)
        full = levelled[o.station].gf_m if levelling else geometry_free_band_m(o.range_m[1], o.range_m[band], band)
        g = full[keep_t][:, cols]
        gf[np.ix_(ti, np.array([i]), si)] = g[:, None, :]
        if scale is not None and corr_s > 0:
            arcs = levelled[o.station].arc[keep_t][:, cols]
            scale[np.ix_(ti, np.array([i]), si)] *= arc_sigma_scale(arcs, t_all[ti], corr_s)[:, None, :]
        if not (np.isfinite(o.range_m[1]) & np.isfinite(o.range_m[band])).any():
            raise DataFileError(
                f"{o.path}: no epoch with a GPS satellite on both {o.codes[1]} and {o.codes[band]} (missing frequency?)"
            )
    if excl:
        notes.append(f"excluded: {' '.join(sorted(excl))}")
    codes = {o.station: dict(o.codes) for o in obs}
    xyz = np.stack([o.position_ecef_m for o in obs])
    for sta, lev in levelled.items():
        n_rm = int(lev.removed.sum())
        notes.append(
            f"{sta}: levelled {len(lev.arcs)} arcs (starts: "
            f"{', '.join(f'{k} {v}' for k, v in sorted(lev.starts.items()))}; {lev.dropped_short} shorter "
            f"than {min_arc_epochs} epochs dropped); screening removed {n_rm} code observations"
        )
    data = bias_network_model(
        stations,
        t_all,
        xyz,
        gf,
        svs_all,
        orbit,
        band=band,
        codes=codes,
        mask_deg=mask_deg,
        ionosphere=ionosphere,
        regional_km=regional_km,
        sigma_zenith_m=sigma_zenith_m,
        weighting=weighting,
        reference=reference,
        notes=notes,
        paths=[str(o.path) for o in obs],
        vtec_rw_m_per_sqrt_s=TEC_RW_M_PER_SQRT_S if tec_rw_m_per_sqrt_s is None else tec_rw_m_per_sqrt_s,
        min_satellite_obs=min_satellite_obs,
        sigma_scale=scale,
        tec_order=tec_order,
        mapping=mapping,
        station_weighting=station_weights,
        station_sigma=station_sigma_factors([levelled[o.station] for o in obs]) if levelling else None,
    )
    arc_id = arc_ids_on_grid(obs, levelled, grids, data.t_gps_s, data.layout.svs) if levelling else None
    return replace(
        data,
        levelled=levelled,
        levelled_svs={o.station: list(o.svs) for o in obs},
        levelled_times={o.station: o.time for o in obs},
        arc_id=arc_id,
    )


def _level(
    o: Any, orbit: Any, band: int, mask_deg: float, min_arc_epochs: int, gf_threshold_m: float, screen: bool, node: int
) -> Any:
    """Level one station's geometry-free code per arc (σ of the code from the elevation: σ₀/sin θ)."""
    from distnav.models.gnss.geometry import azimuth_elevation
    from distnav.models.gnss.levelling import level_station
    from distnav.models.gnss.orbits import gps_seconds

    if band not in o.phase_m or 1 not in o.phase_m:
        raise DataFileError(f"{o.path}: no carrier phase on L1 and L{band} for levelling (use --levelling none)")
    t = gps_seconds(o.time)
    svs = [s for s in o.svs if s in orbit.svs]
    el = np.full((t.size, len(o.svs)), np.nan)
    if svs:
        _, e = azimuth_elevation(o.position_ecef_m, orbit.positions_ecef(t, svs))
        el[:, [o.svs.index(s) for s in svs]] = e
    above = np.isfinite(el) & (el > np.deg2rad(mask_deg))
    p1, pb = np.where(above, o.range_m[1], np.nan), np.where(above, o.range_m[band], np.nan)
    sigma = 1.0 / np.sin(np.where(above, el, 0.5 * np.pi))
    lli = o.lli.get(1, np.zeros(p1.shape, np.int8)) | o.lli.get(band, np.zeros(p1.shape, np.int8))
    return level_station(
        t,
        o.svs,
        p1,
        pb,
        o.phase_m[1],
        o.phase_m[band],
        band=band,
        lli=lli,
        sigma_m=sigma,
        min_arc_epochs=min_arc_epochs,
        gf_threshold_m=gf_threshold_m,
        screen=screen,
        fallback_raw=True,
        node=node,
    )
