"""A receiver network's geometry-free code as one bias + ionosphere model, and the filters run in a chosen datum.

:func:`read_stations` reads the RINEX files (codes, and phases for levelling); :func:`bias_network_model` puts
the stations' undifferenced geometry-free observations on the union of their epochs into the model of
:mod:`distnav.models.gnss.gfbias` (estimation basis: a reference receiver observing at the first epoch);
:func:`run_bias_filters` runs the central filter, the single-receiver filters (each in its own receiver's basis,
so its satellite DCBs are estimable from its own data) and the consensus Kalman filter, and S-transforms every
epoch's estimates and covariance into the output datum (:func:`~distnav.models.gnss.gfbias.datum_transform`).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from distnav.errors import DataFileError, ModelError
from distnav.models.gnss.gfbias import (
    BiasGeometryFreeSeries,
    BiasStateLayout,
    bias_dynamics,
    datum_transform,
    gf_m_per_dsb_ns,
    in_datum,
)
from distnav.models.gnss.rinex import CodeObservations
from distnav.models.gnss.rinex_obs import ProgressCallback

__all__ = ["BiasNetworkData", "DatumSeries", "read_stations", "bias_network_model", "run_bias_filters"]

log = logging.getLogger(__name__)


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

    def series_for(self, reference: str) -> BiasGeometryFreeSeries:
        """The same data in the basis of another reference receiver."""
        lay = BiasStateLayout(self.layout.svs, self.layout.receivers, self.layout.n_ionospheres, "receiver",
                              reference)
        return BiasGeometryFreeSeries(lay, self.geometry.coefficients, self.sigma_m, obs_m=self.obs_m,
                                      tracked=self.geometry.tracked, groups=self.geometry.groups)


def read_stations(paths: Sequence[str | Path], *, l1_code: str, l2_code: str, tlim: tuple[str, str] | None = None,
                  interval_s: float | None = None, phases: bool = False,
                  progress: ProgressCallback | None = None) -> list[CodeObservations]:
    """Read the L1 and second-band codes (band from ``l2_code``: ``C5X`` → L5) of every station."""
    from distnav.models.gnss.rinex import read_code_observations

    if not paths:
        raise DataFileError("no observation file given")
    band = int(l2_code[1])
    codes = {1: l1_code.upper(), band: l2_code.upper()}
    obs = [read_code_observations(p, bands=(1, band), codes=codes, tlim=tlim, interval_s=interval_s,
                                  phases=phases, progress=progress) for p in paths]
    stations = [o.station for o in obs]
    dup = sorted({s for s in stations if stations.count(s) > 1})
    if dup:
        twice = ", ".join(str(o.path) for o in obs if o.station == dup[0])
        raise DataFileError(f"station {dup[0]} is given twice ({twice})")
    for o in obs:
        pos = o.position_ecef_m
        if not (np.all(np.isfinite(pos)) and np.linalg.norm(pos) > 6.0e6):
            raise DataFileError(f"{o.path}: no usable APPROX POSITION XYZ in the header ({pos.tolist()})")
    return obs


def bias_network_model(stations: list[str], t_gps_s: np.ndarray, xyz: np.ndarray, gf_m: np.ndarray,
                       svs_all: Sequence[str], orbit: Any, *, band: int = 2,
                       codes: dict[str, dict[int, str]] | None = None, mask_deg: float = 10.0,
                       ionosphere: str = "auto", regional_km: float = 500.0, sigma_zenith_m: float | None = None,
                       weighting: str = "sin", reference: str | None = None, notes: list[str] | None = None,
                       paths: list[str] | None = None) -> BiasNetworkData:
    """The model from undifferenced geometry-free observations ``gf_m`` (T, n, S) [m] (NaN = not observed).

    ``sigma_zenith_m`` defaults to the paper's 65.6 cm scaled to the band (√2·30 cm/(μ_b − 1)). The estimation
    basis is the ``reference`` receiver (default: the station with the most observations among those observing
    at the first epoch). Raises :class:`~distnav.errors.ModelError` / :class:`~distnav.errors.DataFileError` when
    the orbit has no position at the epochs, a station keeps no observation above the mask, or the stations
    share no satellite.
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
        notes.append(f"ionosphere: {mode} (longest baseline {base_km:.0f} km, regional limit {regional_km:.0f} km)")
    geo = ionosphere_geometry(orbit, t_all, receivers_ecef_m=xyz, names=stations, svs=svs_all, mask_deg=mask_deg,
                              ionosphere=mode)
    if not np.isfinite(geo.el_rad).any():
        span = f"{str(datetime_from_gps_seconds(t_all[0]))[:19]} – {str(datetime_from_gps_seconds(t_all[-1]))[:19]}"
        raise ModelError(f"the orbit gives no satellite position at the observation epochs ({span}): "
                         f"wrong navigation/SP3 file?")
    no_orbit = [svs_all[k] for k in range(S)
                if np.isfinite(gf[:, :, k]).any() and not np.isfinite(geo.el_rad[:, :, k]).any()]
    if no_orbit:
        notes.append(f"no orbit at the observation epochs for {' '.join(no_orbit)} (dropped; unhealthy or a sparse "
                     f"broadcast file: try a larger --nav-max-age)")
    geo = geo.with_tracked(np.isfinite(gf))
    for i in range(n):
        if not geo.tracked[:, i].any():
            raise DataFileError(f"{paths[i]}: no observation above the {mask_deg:g}° mask with both codes "
                                f"(or no orbit for the satellites)")
    if n > 1 and not (np.asarray(geo.tracked.any(axis=0)).sum(axis=0) >= 2).any():
        raise ModelError("no satellite is tracked by two or more stations: the stations share no parameter")
    keep = np.flatnonzero(geo.tracked.any(axis=(0, 1)))
    svs = tuple(svs_all[k] for k in keep.tolist())
    geo = replace(geo, svs=svs, el_rad=geo.el_rad[:, :, keep], az_rad=geo.az_rad[:, :, keep],
                  tracked=geo.tracked[:, :, keep], coefficients=geo.coefficients[:, :, keep])
    counts = geo.tracked.sum(axis=(0, 2))
    if reference is None:
        first = np.flatnonzero(geo.tracked.any(axis=2).any(axis=0) & geo.tracked[np.argmax(
            geo.tracked.any(axis=(1, 2)))].any(axis=1))
        ref = stations[int(first[np.argmax(counts[first])])] if first.size else stations[int(np.argmax(counts))]
    else:
        ref = reference.upper()
        if ref not in stations:
            raise ModelError(f"reference receiver {reference}: not one of the stations {', '.join(stations)}")
    layout = BiasStateLayout(svs, tuple(stations), 1 if mode == "common" else n, "receiver", ref)
    sig0 = (np.sqrt(2.0) * 0.30 / (mu(band) - 1.0)) if sigma_zenith_m is None else float(sigma_zenith_m)
    el = np.where(geo.tracked, geo.el_rad, 0.5 * np.pi)
    sig = elevation_sigma(el, sig0, weighting)
    obs = gf[:, :, keep]
    series = BiasGeometryFreeSeries(layout, geo.coefficients, sig, obs_m=obs, tracked=geo.tracked,
                                    groups=geo.groups)
    dt = np.concatenate([[np.nan], np.diff(t_all)]) if T > 1 else np.array([30.0])
    dyn = bias_dynamics(layout, dt if T > 1 else 30.0)
    return BiasNetworkData(stations, dict(codes or {}), band, t_all, geo, layout, series, dyn, mode,
                           np.asarray(xyz, float), obs, sig, notes)


@dataclass(frozen=True, eq=False)
class DatumSeries:
    """One filter's per-epoch outputs in the output datum: ``tec`` / ``tec_std`` (T, n_tec) [m],
    ``dsb_ns`` / ``dsb_std_ns`` (T, n + S) DSBs ``C1 − C_b`` [ns] of the receivers then the satellites (formal:
    σ² = 1); ``variance_factor`` σ̂² from the filter's own predicted residuals (``Σ vᵀQ_v⁻¹v / Σ m``, each
    filter on the observations it uses: a local quantity in the CKF too) and the number of them;
    ``lag1_correlation`` ρ of the standardized predicted residuals of the same receiver–satellite pair at
    consecutive epochs and the inflation ``(1 + ρ)/(1 − ρ)`` it implies for the variance of constant parameters."""

    label: str
    tec: np.ndarray
    tec_std: np.ndarray
    dsb_ns: np.ndarray
    dsb_std_ns: np.ndarray
    variance_factor: float | None = None
    n_innovations: int = 0
    lag1_correlation: float = 0.0
    correlation_inflation: float = 1.0

    @property
    def realistic_factor(self) -> float:
        """``√(σ̂² (1 + ρ)/(1 − ρ))``: the formal σ times this accounts for the misfit and for the epoch-to-epoch
        correlation ``ρ`` of the standardized predicted residuals (variance of a mean of AR(1) errors)."""
        return float(np.sqrt((self.variance_factor or 1.0) * self.correlation_inflation))


class _Collector:
    def __init__(self, label: str, T: int, n_tec: int, q: int) -> None:
        self.label = label
        self.ssr = 0.0
        self.m = 0
        self.zt: np.ndarray | None = None       # (nodes, S) epoch of the last standardized residual
        self.zv: np.ndarray | None = None       # (nodes, S) its value
        self.zz = self.zlag = 0.0
        self.T_cache: dict[bytes, np.ndarray] = {}
        self.prev: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        self.tec = np.full((T, n_tec), np.nan)
        self.tec_std = np.full((T, n_tec), np.nan)
        self.dsb = np.full((T, q), np.nan)
        self.dsb_std = np.full((T, q), np.nan)

    def add(self, t: int, layout: BiasStateLayout, x: np.ndarray, est: np.ndarray, P: np.ndarray | None,
            datum: str, pivot: str | None, reference: str | None, scale: float) -> None:
        nt = layout.n_tec
        self.tec[t] = np.where(est[:nt], x[:nt], np.nan)
        if P is not None:
            self.tec_std[t] = np.where(est[:nt], np.sqrt(np.maximum(np.diag(P)[:nt], 0.0)), np.nan)
        key = est.tobytes()
        T = self.T_cache.get(key)
        if T is None:
            try:
                T = datum_transform(layout, datum, estimable=est, pivot=pivot, reference=reference)
            except ModelError:
                return
            self.T_cache[key] = T
        v, s = in_datum(T, x, P)
        self.dsb[t] = -v / scale
        self.dsb_std[t] = s / scale

    def innovations(self, t: int, series: BiasGeometryFreeSeries, nodes: np.ndarray, dynamics: Any,
                    x: np.ndarray, est: np.ndarray, P: np.ndarray | None) -> None:
        """Accumulate the predicted residuals ``v = y − A x̂_{t−1}`` of ``nodes`` with ``Q_v = R + A P⁻ Aᵀ``
        (``P⁻ = P_{t−1} + S_t``; all the nodes' observations jointly: they share the state) over the observations
        whose parameters were all estimable before epoch ``t``."""
        if self.prev is not None and t > 0:
            xp, ep, Pp = self.prev
            A, w = series.design(t, nodes)
            y = series._y[t, nodes] if series._y is not None else np.zeros(w.shape)
            rows = (w > 0) & ~((np.abs(A) > 0) & ~ep[None, None, :]).any(axis=2)
            if rows.any():
                Pm = np.where(np.outer(ep, ep), Pp, 0.0) + dynamics.noise_cov_at(t)
                xz = np.where(ep, xp, 0.0)
                kk, ss = np.nonzero(rows)                    # all observations of all nodes together
                Ar = A[kk, ss]
                v = y[kk, ss] - Ar @ xz
                Qv = np.diag(1.0 / w[kk, ss]) + Ar @ Pm @ Ar.T
                self.ssr += float(v @ np.linalg.solve(Qv, v))
                self.m += int(kk.size)
                z = v / np.sqrt(np.diag(Qv))
                if self.zt is None or self.zv is None:
                    self.zt = np.full((series.n_nodes, series.n_satellites), -2, np.int64)
                    self.zv = np.zeros((series.n_nodes, series.n_satellites))
                node = np.asarray(nodes)[kk]
                follows = self.zt[node, ss] == t - 1
                self.zlag += float((z[follows] * self.zv[node, ss][follows]).sum())
                self.zz += float(z @ z)
                self.zt[node, ss] = t
                self.zv[node, ss] = z
        if P is not None:
            self.prev = (x.copy(), est.copy(), P.copy())

    def done(self) -> DatumSeries:
        from distnav.algorithms.statistics import variance_factor

        vf = variance_factor(self.ssr, self.m) if self.m else None
        rho = min(max(self.zlag / self.zz, 0.0), 0.999) if self.zz > 0 else 0.0
        return DatumSeries(self.label, self.tec, self.tec_std, self.dsb, self.dsb_std, vf, self.m, rho,
                           (1.0 + rho) / (1.0 - rho))


def run_bias_filters(data: BiasNetworkData, *, datum: str = "zero-mean", pivot: str | None = None,
                     reference: str | None = None, graph: Any = None, kn: int = 4, exchange: Any = None,
                     local: bool = True) -> tuple[list[DatumSeries], Any]:
    """Central, single-receiver and CKF filters over the network, every epoch S-transformed into ``datum``.

    Returns the series (labels ``central``, ``local:STA``, ``ckf:STA``) and the communication totals of the CKF
    (``None`` without a graph).
    """
    from distnav.algorithms.ckf import iterate_ckf
    from distnav.algorithms.kalman import iterate_information_filter

    lay, T = data.layout, data.series.n_epochs
    q = len(lay.receivers) + len(lay.svs)
    scale = gf_m_per_dsb_ns(data.band)
    out: list[DatumSeries] = []
    c = _Collector("central", T, lay.n_tec, q)
    everyone = np.arange(len(data.stations))
    for st in iterate_information_filter(data.dynamics, data.series, mode="central"):
        c.innovations(st.epoch, data.series, everyone, data.dynamics, st.estimates[0], st.estimable[0],
                      st.covariance[0])
        c.add(st.epoch, lay, st.estimates[0], st.estimable[0], st.covariance[0], datum, pivot, reference, scale)
    out.append(c.done())
    if local:
        for i, sta in enumerate(data.stations):
            si = data.series_for(sta)
            c = _Collector(f"local:{sta}", T, lay.n_tec, q)
            for st in iterate_information_filter(data.dynamics, si, mode="central", nodes=[i]):
                c.innovations(st.epoch, si, np.array([i]), data.dynamics, st.estimates[0], st.estimable[0],
                              st.covariance[0])
                c.add(st.epoch, si.layout, st.estimates[0], st.estimable[0], st.covariance[0], datum, pivot,
                      None if datum != "receiver" else sta, scale)
            out.append(c.done())
    comm = None
    if graph is not None:
        from distnav.exchange import make_exchange

        ex = exchange if exchange is not None else make_exchange(graph)
        cs = [_Collector(f"ckf:{s}", T, lay.n_tec, q) for s in data.stations]
        for cst in iterate_ckf(data.dynamics, data.series, graph=graph, protocol="P3", rounds=kn, exchange=ex,
                               monitor=False):
            x = ex.gather_nodes(cst.estimates)
            est = ex.gather_nodes(cst.estimable)
            P = ex.gather_nodes(cst.covariance) if cst.covariance is not None else None
            for i, col in enumerate(cs):
                col.innovations(cst.epoch, data.series, np.array([i]), data.dynamics, x[i], est[i],
                                None if P is None else P[i])
                col.add(cst.epoch, lay, x[i], est[i], None if P is None else P[i], datum, pivot, reference, scale)
        out += [col.done() for col in cs]
        comm = ex.comm_totals()
    return out, comm
