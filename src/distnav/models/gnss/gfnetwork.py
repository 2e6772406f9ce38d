"""A receiver network's geometry-free code as one bias + ionosphere model, and the filters run in a chosen datum.

The stations' observations are read by :func:`distnav.formats.gnss.rinex.read_stations`; :func:`bias_network_model` puts
the stations' undifferenced geometry-free observations on the union of their epochs into the model of
:mod:`distnav.models.gnss.gfbias` (estimation basis: a reference receiver observing at the first epoch);
:func:`run_bias_filters` runs the central filter, the single-receiver filters (each in its own receiver's basis,
so its satellite DCBs are estimable from its own data) and the consensus Kalman filter, and S-transforms every
epoch's estimates and covariance into the output datum (:func:`~distnav.models.gnss.gfbias.datum_transform`).
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any, Literal

import numpy as np

from distnav.errors import DataFileError, ModelError
from distnav.models.gnss.arcprecision import arc_variance_factor, postfit_residuals
from distnav.models.gnss.gfbias import (
    TEC_RW_M_PER_SQRT_S,
    BiasGeometryFreeSeries,
    BiasStateLayout,
    bias_dynamics,
    gf_m_per_dsb_ns,
)
from distnav.models.gnss.gfcollector import Collector, DatumSeries

__all__ = [
    "BiasNetworkData",
    "DatumSeries",
    "SatelliteFit",
    "final_dsbs",
    "innovation_summary",
    "satellite_fit",
    "MIN_SATELLITE_OBS",
    "TEC_RW_M_PER_SQRT_S",
    "bias_network_model",
    "run_bias_filters",
]

log = logging.getLogger(__name__)

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


def bias_network_model(
    stations: list[str],
    t_gps_s: np.ndarray,
    xyz: np.ndarray,
    gf_m: np.ndarray,
    svs_all: Sequence[str],
    orbit: Any,
    *,
    band: int = 2,
    codes: dict[str, dict[int, str]] | None = None,
    mask_deg: float = 10.0,
    ionosphere: str = "auto",
    regional_km: float = 1000.0,
    sigma_zenith_m: float | None = None,
    weighting: str = "sin",
    reference: str | None = None,
    notes: list[str] | None = None,
    paths: list[str] | None = None,
    vtec_rw_m_per_sqrt_s: float = TEC_RW_M_PER_SQRT_S,
    min_satellite_obs: int | None = None,
    sigma_scale: np.ndarray | None = None,
    tec_order: int = 1,
    mapping: str = "slm",
    station_sigma: np.ndarray | None = None,
    station_weighting: str = "auto",
) -> BiasNetworkData:
    """The model from undifferenced geometry-free observations ``gf_m`` (T, n, S) [m] (NaN = not observed).

    ``sigma_zenith_m`` defaults to the paper's 65.6 cm scaled to the band (√2·30 cm/(μ_b − 1)). The estimation
    basis is the ``reference`` receiver (default: the station with the most observations among those observing
    at the first epoch). Raises :class:`~distnav.errors.ModelError` / :class:`~distnav.errors.DataFileError` when
    the orbit has no position at the epochs, a station keeps no observation above the mask, or the stations
    share no satellite.

    ``vtec_rw_m_per_sqrt_s``: random walk of the vertical delay (the gradients get 5× this per radian), by default
    10× paper 003's 1 mm/√s — see :data:`TEC_RW_M_PER_SQRT_S`. Satellites with fewer than ``min_satellite_obs``
    station-epochs (default: :data:`MIN_SATELLITE_OBS`' rule) are not estimated (a note names them): a
    satellite seen for a few minutes at low elevation
    at a session edge has a DCB of several ns σ that would only pull the zero-mean datum. ``sigma_scale``
    (T, n, S): factors on the elevation-dependent σ (the levelled code's arc correlation, see
    :func:`arc_sigma_scale`). ``tec_order`` 2: a second-order VTEC field per ionosphere (six parameters);
    ``mapping`` ``"mslm"``: the modified single-layer mapping (both off by default; docs/gnss.md, low latitudes).
    ``station_sigma`` (n,): per-station σ factors (:func:`~distnav.models.gnss.levelling.station_sigma_factors`),
    applied with ``station_weighting`` "on", or "auto" when the stations share one ionosphere (docs/gnss.md: with
    per-station layers each station's own ionosphere error, not its code noise, limits it).
    """
    from distnav.models.gnss.constants import mu
    from distnav.models.gnss.ionosphere import ionosphere_geometry
    from distnav.models.gnss.observables import elevation_sigma
    from distnav.models.gnss.orbits import datetime_from_gps_seconds

    notes = list(notes or [])
    paths = paths or list(stations)
    t_all = np.asarray(t_gps_s, dtype=float)
    gf = np.asarray(gf_m, dtype=float)
    T, n, S = gf.shape
    base_km = float(np.max(np.linalg.norm(xyz[:, None] - xyz[None], axis=-1))) / 1e3 if n > 1 else 0.0
    mode = ionosphere
    if mode == "auto":
        mode = "common" if base_km <= regional_km else "per-receiver"
        rule = "≤" if mode == "common" else ">"
        notes.append(
            f"model choice: ionosphere {mode}, because the longest baseline {base_km:.0f} km {rule} the regional "
            f"limit {regional_km:.0f} km (one VTEC field is valid within it); receiver DSBs depend on this choice "
            "(--ionosphere common|per-receiver fixes it)"
        )
    geo = ionosphere_geometry(
        orbit,
        t_all,
        receivers_ecef_m=xyz,
        names=stations,
        svs=svs_all,
        mask_deg=mask_deg,
        ionosphere=mode,
        tec_order=tec_order,
        mapping=mapping,
    )
    if not np.isfinite(geo.el_rad).any():
        span = f"{str(datetime_from_gps_seconds(t_all[0]))[:19]} – {str(datetime_from_gps_seconds(t_all[-1]))[:19]}"
        raise ModelError(
            f"the orbit gives no satellite position at the observation epochs ({span}): wrong navigation/SP3 file?"
        )
    no_orbit = [
        svs_all[k] for k in range(S) if np.isfinite(gf[:, :, k]).any() and not np.isfinite(geo.el_rad[:, :, k]).any()
    ]
    if no_orbit:
        notes.append(
            f"no orbit at the observation epochs for {' '.join(no_orbit)} (dropped; unhealthy or a sparse "
            f"broadcast file: try a larger --nav-max-age)"
        )
    geo = geo.with_tracked(np.isfinite(gf))
    for i in range(n):
        if not geo.tracked[:, i].any():
            raise DataFileError(
                f"{paths[i]}: no observation above the {mask_deg:g}° mask with both codes "
                f"(or no orbit for the satellites)"
            )
    if n > 1 and not (np.asarray(geo.tracked.any(axis=0)).sum(axis=0) >= 2).any():
        raise ModelError("no satellite is tracked by two or more stations: the stations share no parameter")
    n_obs = geo.tracked.sum(axis=(0, 1))
    if min_satellite_obs is None:
        min_satellite_obs = int(max(30, min(MIN_SATELLITE_OBS, 0.25 * float(n_obs.max()))))
    few = [svs_all[k] for k in range(S) if 0 < n_obs[k] < min_satellite_obs]
    if few:
        notes.append(
            f"not estimated, fewer than {min_satellite_obs} station-epochs: "
            + " ".join(f"{s} ({int(n_obs[svs_all.index(s)])})" for s in few)
        )
    keep = np.flatnonzero(n_obs >= max(min_satellite_obs, 1))
    if keep.size < 2:
        raise ModelError(f"fewer than two satellites with {min_satellite_obs} station-epochs or more")
    svs = tuple(svs_all[k] for k in keep.tolist())
    geo = replace(
        geo,
        svs=svs,
        el_rad=geo.el_rad[:, :, keep],
        az_rad=geo.az_rad[:, :, keep],
        tracked=geo.tracked[:, :, keep],
        coefficients=geo.coefficients[:, :, keep],
    )
    counts = geo.tracked.sum(axis=(0, 2))
    if reference is None:
        first = np.flatnonzero(
            geo.tracked.any(axis=2).any(axis=0) & geo.tracked[np.argmax(geo.tracked.any(axis=(1, 2)))].any(axis=1)
        )
        ref = stations[int(first[np.argmax(counts[first])])] if first.size else stations[int(np.argmax(counts))]
    else:
        ref = reference.upper()
        if ref not in stations:
            raise ModelError(f"reference receiver {reference}: not one of the stations {', '.join(stations)}")
    layout = BiasStateLayout(
        svs, tuple(stations), 1 if mode == "common" else n, "receiver", ref, 3 if tec_order == 1 else 6
    )
    sig0 = (np.sqrt(2.0) * 0.30 / (mu(band) - 1.0)) if sigma_zenith_m is None else float(sigma_zenith_m)
    el = np.where(geo.tracked, geo.el_rad, 0.5 * np.pi)
    sig = elevation_sigma(el, sig0, weighting)
    if sigma_scale is not None:
        sig = sig * np.where(geo.tracked, np.asarray(sigma_scale, float)[:, :, keep], 1.0)
    if station_sigma is not None and (station_weighting == "on" or (station_weighting == "auto" and mode == "common")):
        sig = sig * np.asarray(station_sigma, float)[None, :, None]
        why = "station weighting on" if station_weighting == "on" else "the stations share one ionosphere"
        notes.append(
            f"model choice: station σ factors from the levelling ({why}): "
            + ", ".join(
                f"{s} {f:.2f}" for s, f in zip(stations, np.asarray(station_sigma, float).tolist(), strict=True)
            )
        )
    obs = gf[:, :, keep]
    series = BiasGeometryFreeSeries(layout, geo.coefficients, sig, obs_m=obs, tracked=geo.tracked, groups=geo.groups)
    dt = np.concatenate([[np.nan], np.diff(t_all)]) if T > 1 else np.array([30.0])
    if not (np.isfinite(vtec_rw_m_per_sqrt_s) and vtec_rw_m_per_sqrt_s > 0):
        raise ModelError(f"the TEC random walk must be positive, got {vtec_rw_m_per_sqrt_s} m/√s")
    dyn = bias_dynamics(
        layout,
        dt if T > 1 else 30.0,
        vtec_std_m_per_sqrt_s=vtec_rw_m_per_sqrt_s,
        gradient_std_m_per_rad_sqrt_s=5.0 * vtec_rw_m_per_sqrt_s,
    )
    return BiasNetworkData(
        stations,
        dict(codes or {}),
        band,
        t_all,
        geo,
        layout,
        series,
        dyn,
        mode,
        np.asarray(xyz, float),
        obs,
        sig,
        notes,
    )


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


def final_dsbs(data: BiasNetworkData, s: DatumSeries) -> tuple[dict[str, float], dict[str, float], dict[str, float]]:
    """A filter's last-epoch DSBs [ns]: satellites (estimated ones), receivers, and the realistic σ of every
    object (``rx:STA`` or the PRN; formal σ × :attr:`DatumSeries.realistic_factor`)."""
    names = [f"rx:{r}" for r in data.stations] + list(data.layout.svs)
    sd = dict(zip(names, (s.dsb_std_ns[-1] * s.realistic_factor).tolist(), strict=True))
    fin = dict(zip(names, s.dsb_ns[-1].tolist(), strict=True))
    sat = {k: v for k, v in fin.items() if not k.startswith("rx:") and np.isfinite(v)}
    return sat, {k[3:]: v for k, v in fin.items() if k.startswith("rx:")}, sd


STANDS_OUT_Z = 3.5
"""The worst-fitting satellite *stands out* when its statistic lies more than this many robust standard
deviations (1.4826 · MAD) above the satellites' median and is more than :data:`STANDS_OUT_RATIO` times the median
(an empirical limit: on BELE, DGAR and ESBC the worst satellite lies 1.0–2.1 robust σ and 1.11–1.23× the median
above the others; the SVN49-like satellite of the simulated held-out workflow 7–21 σ and 1.35–1.42×)."""
STANDS_OUT_RATIO = 1.2


@dataclass(frozen=True, eq=False)
class SatelliteFit:
    """Per-satellite fit statistics. ``code_rms_m`` (S,): with carrier levelling, the RMS of the code minus the
    levelled phase within the arcs, weighted to the zenith (``(g_P − g_Φ − offset)·sin θ``), over all stations
    (each station computes its own sums); ``code_n`` their number. ``rms_m`` / ``rms_w`` (S,): post-fit residuals
    of the filter's observations with the final biases [m] and weighted (``e/σ``); ``n`` their number.

    The worst-fitting satellite is the one with the largest ``code_rms_m`` when levelled (the levelled code has
    the phase's shape, so an elevation-dependent code bias like SVN49's shows only in the code minus phase), else
    the largest ``rms_w``."""

    svs: tuple[str, ...]
    rms_m: np.ndarray
    rms_w: np.ndarray
    n: np.ndarray
    code_rms_m: np.ndarray | None = None
    code_n: np.ndarray | None = None

    def worst(self, *, min_residuals: int = 30) -> tuple[str, float] | None:
        """The worst-fitting satellite and its statistic (among those with ``min_residuals`` or more)."""
        stat, cnt = (
            (self.code_rms_m, self.code_n)
            if self.code_rms_m is not None and self.code_n is not None
            else (self.rms_w, self.n)
        )
        ok = (cnt >= min_residuals) & np.isfinite(stat)
        if not ok.any():
            return None
        k = int(np.argmax(np.where(ok, stat, -np.inf)))
        return self.svs[k], float(stat[k])

    def as_dict(self) -> dict[str, Any]:
        w = self.worst()
        stat = "code_minus_phase_rms_zenith_m" if self.code_rms_m is not None else "postfit_rms_weighted"
        per: dict[str, Any] = {}
        for k, s in enumerate(self.svs):
            row: dict[str, Any] = {
                "postfit_rms_m": float(self.rms_m[k]),
                "postfit_rms_weighted": float(self.rms_w[k]),
                "postfit_n": int(self.n[k]),
            }
            if self.code_rms_m is not None and self.code_n is not None:
                row.update({"code_minus_phase_rms_zenith_m": float(self.code_rms_m[k]), "code_n": int(self.code_n[k])})
            per[s] = row
        med = float(np.nanmedian(self.code_rms_m if self.code_rms_m is not None else self.rms_w))
        z = self.robust_z(w[1]) if w is not None else None
        return {
            "statistic": stat,
            "median": med,
            "worst_fitting": None
            if w is None
            else {
                "satellite": w[0],
                "value": w[1],
                "ratio_to_median": w[1] / med if med > 0 else None,
                "robust_z": z,
                "stands_out": bool(z is not None and z > STANDS_OUT_Z and med > 0 and w[1] / med > STANDS_OUT_RATIO),
            },
            "per_satellite": per,
        }

    def robust_z(self, value: float, *, min_residuals: int = 30) -> float | None:
        """``(value − median) / (1.4826 · MAD)`` over the satellites' statistics (those with ``min_residuals``
        or more): how far the worst satellite lies from the others in units of their robust spread."""
        stat, cnt = (
            (self.code_rms_m, self.code_n)
            if self.code_rms_m is not None and self.code_n is not None
            else (self.rms_w, self.n)
        )
        v = stat[(cnt >= min_residuals) & np.isfinite(stat)]
        if v.size < 5:
            return None
        med = float(np.median(v))
        mad = 1.4826 * float(np.median(np.abs(v - med)))
        return (value - med) / mad if mad > 0 else None


def satellite_fit(data: BiasNetworkData, final: DatumSeries) -> SatelliteFit:
    """How well each satellite fits the model with the filter's final biases: per epoch and ionosphere, the TEC
    parameters re-fitted by weighted least squares to the observations minus the final receiver + satellite
    biases (datum-free sums ``b_i + b^s``), and the residuals collected per satellite. A satellite whose code
    bias depends on the elevation (SVN49) fits worst: no constant DCB absorbs it, while the levelled code of the
    other satellites leaves only the arcs' level errors."""
    lay = data.layout
    S = data.obs_m.shape[2]
    e, w, use = postfit_residuals(data, final.dsb_ns[-1])
    cnt = use.sum(axis=(0, 1))
    with np.errstate(invalid="ignore", divide="ignore"):
        rms_m = np.sqrt(np.where(use, e**2, 0.0).sum(axis=(0, 1)) / cnt)
        rms_w = np.sqrt(np.where(use, w * e**2, 0.0).sum(axis=(0, 1)) / cnt)
    code_rms = code_n = None
    if data.levelled:
        wss = np.zeros(S)
        code_n = np.zeros(S, np.int64)
        for sta, lev in data.levelled.items():
            if lev.fit_wss is None or lev.fit_n is None:
                continue
            own = data.levelled_svs.get(sta, [])
            for k, sv in enumerate(own):
                if sv in lay.svs:
                    wss[lay.svs.index(sv)] += lev.fit_wss[k]
                    code_n[lay.svs.index(sv)] += lev.fit_n[k]
        with np.errstate(invalid="ignore", divide="ignore"):
            code_rms = np.where(code_n > 0, np.sqrt(wss / np.maximum(code_n, 1)), np.nan)
    return SatelliteFit(
        tuple(lay.svs), np.where(cnt > 0, rms_m, np.nan), np.where(cnt > 0, rms_w, np.nan), cnt, code_rms, code_n
    )


def innovation_summary(series: Sequence[DatumSeries], stations: Sequence[str]) -> dict[str, Any] | None:
    """What the CKF's innovation tests (``run_bias_filters(innovation_level=…)``) tested and removed per station."""
    it = next((s.innovation_tests for s in series if s.innovation_tests is not None), None)
    if it is None:
        return None
    rm = np.asarray(it.removed, np.int64)
    return {
        "level": it.level,
        "critical_value": it.critical_value,
        "per_station": {
            sta: {"tested": int((it.node == i).sum()), "removed": int((it.node[rm] == i).sum())}
            for i, sta in enumerate(stations)
        },
    }


def _with_arc_factor(s: DatumSeries, data: BiasNetworkData, nodes: list[int] | None) -> DatumSeries:
    """``s`` with the arcs' variance factor (:func:`~distnav.models.gnss.arcprecision.arc_variance_factor`) of
    its last epoch's biases over the arcs of ``nodes``, its precision payload's a-posteriori factor and redundancy
    those; unchanged where there is none (raw code, too few arcs)."""
    arc = arc_variance_factor(data, s.dsb_ns[-1], nodes)
    if arc is None:
        return s
    prec = None if s.precision is None else replace(s.precision, variance_factor=arc.factor, redundancy=arc.redundancy)
    return replace(s, arc_variance_factor=arc.factor, precision=prec)


def run_bias_filters(
    data: BiasNetworkData,
    *,
    datum: str = "zero-mean",
    pivot: str | None = None,
    reference: str | None = None,
    graph: Any = None,
    kn: int = 4,
    exchange: Any = None,
    local: bool = True,
    innovation_level: float | None = None,
    datum_satellites: Sequence[str] | None = None,
    datum_reference_ns: Mapping[str, float] | None = None,
) -> tuple[list[DatumSeries], Any]:
    """Central, single-receiver and CKF filters over the network, every epoch S-transformed into ``datum``.

    Returns the series (labels ``central``, ``local:STA``, ``ckf:STA``) and the communication totals of the CKF
    (``None`` without a graph). ``innovation_level``: in the CKF every receiver tests its own predicted residuals
    (w-tests at this level with its node-local "bound" precision, :mod:`distnav.algorithms.kalman.ckf_qc`) and rejects
    outliers before its normals enter the consensus; the tests (network-wide
    :class:`~distnav.algorithms.kalman.InnovationTests`) are on every ``ckf:STA`` series as ``innovation_tests``.
    ``datum_satellites`` / ``datum_reference_ns``: the zero-mean datum over a fixed set of satellites, held in a
    reference product's datum when its DSBs are given (:mod:`distnav.models.gnss.datum`).
    """
    from distnav.algorithms.kalman import iterate_information_filter
    from distnav.algorithms.kalman.ckf import iterate_ckf

    lay, T = data.layout, data.series.n_epochs
    scale = gf_m_per_dsb_ns(data.band)
    out: list[DatumSeries] = []
    opts: dict[str, Any] = {
        "datum": datum,
        "pivot": pivot,
        "reference": reference,
        "scale": scale,
        "datum_satellites": datum_satellites,
        "datum_reference_ns": datum_reference_ns,
    }
    everyone = np.arange(len(data.stations))
    c = Collector("central", T, lay, data.series, everyone, data.dynamics, **opts)
    for st in iterate_information_filter(data.dynamics, data.series, mode="central"):
        c.step(st.epoch, st.estimates[0], st.estimable[0], st.covariance[0])
    out.append(_with_arc_factor(c.done(), data, None))
    if local:
        for i, sta in enumerate(data.stations):
            si = data.series_for(sta)
            c = Collector(
                f"local:{sta}",
                T,
                si.layout,
                si,
                np.array([i]),
                data.dynamics,
                **{**opts, "reference": None if datum != "receiver" else sta},
            )
            for st in iterate_information_filter(data.dynamics, si, mode="central", nodes=[i]):
                c.step(st.epoch, st.estimates[0], st.estimable[0], st.covariance[0])
            out.append(_with_arc_factor(c.done(), data, [i]))
    comm = None
    if graph is not None:
        from distnav.exchange import make_exchange

        ex = exchange if exchange is not None else make_exchange(graph)
        cs = [
            Collector(f"ckf:{s}", T, lay, data.series, np.array([i]), data.dynamics, **opts)
            for i, s in enumerate(data.stations)
        ]
        tests = None
        if innovation_level is not None:
            from distnav.algorithms.kalman.ckf_qc import InnovationCollector
            from distnav.algorithms.statistics import critical_value

            tests = InnovationCollector(ex, len(data.stations), innovation_level, critical_value(innovation_level))
        for cst in iterate_ckf(
            data.dynamics,
            data.series,
            graph=graph,
            protocol="P3",
            rounds=kn,
            exchange=ex,
            monitor=False,
            local_precision=None if tests is None else "bound",
            test_level=innovation_level,
            transport=_ckf_transport(ex, graph, kn, data.series),
        ):
            if tests is not None:
                tests.add(cst.tests)
            x = ex.gather_nodes(cst.estimates)
            est = ex.gather_nodes(cst.estimable)
            P = ex.gather_nodes(cst.covariance) if cst.covariance is not None else None
            for i, col in enumerate(cs):
                col.step(cst.epoch, x[i], est[i], None if P is None else P[i])
        built = tests.build() if tests is not None else None
        out += [replace(col.done(), precision=None, innovation_tests=built) for col in cs]
        comm = ex.comm_totals()
    return out, comm


def _ckf_transport(ex: Any, graph: Any, kn: int, series: Any) -> Literal["matrices", "relay"]:
    """The CKF's transport, the cheaper in bytes (issue 27): relayed observation records (20 B each;
    :mod:`distnav.algorithms.kalman.relay`) or the mixed normals, computed from the records the run will send
    (innovation tests can only remove some). A fault schedule needs the matrices."""
    from distnav.algorithms.kalman.relay import MAX_RELAY_NODES, matrix_bytes, relay_bytes, relay_plan

    if ex.faults.active or graph.n_nodes > MAX_RELAY_NODES:
        return "matrices"
    records = np.asarray(series.tracked).sum(axis=2)  # (epochs, stations)
    relay = relay_bytes(relay_plan(graph, kn), records)
    return "relay" if relay < matrix_bytes(graph, kn, series.n_states, series.n_epochs) else "matrices"
