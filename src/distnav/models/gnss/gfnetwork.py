"""The filter stage of the bias pipeline: the filters run on a network's bias model in a chosen datum.

The pipeline, one way: read (:func:`distnav.formats.gnss.rinex.read_stations`) → collect arcs, level and screen
(:mod:`distnav.models.gnss.levelling`) → model (:mod:`distnav.models.gnss.biasmodel`, re-exported here) → filter
(here) → datum (:mod:`distnav.models.gnss.gfcollector`, :mod:`distnav.models.gnss.datum`) → product
(:mod:`distnav.models.gnss.products`, the writers in :mod:`distnav.formats.gnss`). :func:`run_bias_filters` runs
the central filter, the single-receiver filters (each in its own receiver's basis, so its satellite DCBs are
estimable from its own data) and the consensus Kalman filter, and S-transforms every
epoch's estimates and covariance into the output datum (:func:`~distnav.models.gnss.gfbias.datum_transform`).
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any, Literal

import numpy as np

from distnav._checks import check_field_types
from distnav.errors import ModelError
from distnav.models.gnss.arcprecision import arc_variance_factor, postfit_residuals
from distnav.models.gnss.biasmodel import (
    MIN_SATELLITE_OBS,
    BiasModelOptions,
    BiasNetworkData,
    GeometryFreeNetwork,
    arc_sigma_scale,
    bias_network_model,
)
from distnav.models.gnss.gfbias import TEC_RW_M_PER_SQRT_S
from distnav.models.gnss.gfcollector import Collector, DatumSeries

__all__ = [  # the model stage's names are re-exported (their home: distnav.models.gnss.biasmodel)
    "BiasModelOptions",
    "BiasFilterOptions",
    "BiasNetworkData",
    "GeometryFreeNetwork",
    "arc_sigma_scale",
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


def final_dsbs(data: BiasNetworkData, s: DatumSeries) -> tuple[dict[str, float], dict[str, float], dict[str, float]]:
    """A filter's last-epoch DSBs [ns]: satellites (estimated ones), receivers, and the realistic σ of every
    object (``rx:STA`` or the PRN; :meth:`DatumSeries.realistic_std_ns`)."""
    names = [f"rx:{r}" for r in data.stations] + list(data.layout.svs)
    sd = dict(zip(names, s.realistic_std_ns().tolist(), strict=True))
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
        stats = np.asarray(self.code_rms_m if self.code_rms_m is not None else self.rms_w, dtype=float)
        finite = stats[np.isfinite(stats)]  # no levelled arc anywhere: every code RMS is NaN
        med = float(np.median(finite)) if finite.size else float("nan")
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


DATUMS = ("zero-mean", "pivot", "receiver")


@dataclass(frozen=True)
class BiasFilterOptions:
    """How :func:`run_bias_filters` runs (defaults in brackets; checked once, here).

    ``between_station_level`` [0.05]: the level of the between-station test of the realistic σ
    (:mod:`~distnav.models.gnss.stationcheck`; with the single-receiver filters of two or more stations; None: off).
    ``datum`` [``"zero-mean"``]: the output S-basis, ``"zero-mean"`` satellites, a ``"pivot"`` satellite
    (``pivot``) or a ``"receiver"`` (``reference``). ``datum_satellites`` / ``datum_reference_ns`` [None]: the
    zero-mean datum over a fixed set of satellites, held in a reference product's datum when its DSBs are given
    (:mod:`distnav.models.gnss.datum`). ``kn`` [4]: the CKF's consensus rounds per epoch. ``local`` [True]: the
    single-receiver filters too. ``innovation_level`` [None]: the CKF receivers w-test their own predicted
    residuals at this level (:mod:`distnav.algorithms.kalman.ckf_qc`)."""

    datum: str = "zero-mean"
    pivot: str | None = None
    reference: str | None = None
    kn: int = 4
    local: bool = True
    innovation_level: float | None = None
    datum_satellites: Sequence[str] | None = None
    datum_reference_ns: Mapping[str, float] | None = None
    between_station_level: float | None = 0.05

    def __post_init__(self) -> None:
        check_field_types(self, error=ModelError)  # types first, naming the field (issue 29)
        if self.between_station_level is not None and not 0.0 < self.between_station_level < 0.5:
            raise ModelError(f"between_station_level must lie in (0, 0.5), got {self.between_station_level}")
        if self.datum not in DATUMS:
            raise ModelError(f"datum must be one of {', '.join(DATUMS)}; got {self.datum!r}")
        if self.datum == "pivot" and self.pivot is None:
            raise ModelError("the pivot datum needs a pivot satellite")
        if self.kn < 0:
            raise ModelError(f"kn must be ≥ 0, got {self.kn}")
        if self.innovation_level is not None and not 0.0 < self.innovation_level < 0.5:
            raise ModelError(f"innovation_level must lie in (0, 0.5), got {self.innovation_level}")


def run_bias_filters(
    data: BiasNetworkData,
    options: BiasFilterOptions = BiasFilterOptions(),
    *,
    graph: Any = None,
    exchange: Any = None,
) -> tuple[list[DatumSeries], Any]:
    """Central, single-receiver and CKF filters over the network, every epoch S-transformed into the datum.

    Returns the series (labels ``central``, ``local:STA``, ``ckf:STA``) and the communication totals of the CKF
    (``None`` without a ``graph``); ``options``: :class:`BiasFilterOptions`. With an ``innovation_level`` every CKF
    receiver tests its own predicted residuals (w-tests at this level with its node-local "bound" precision) and
    rejects outliers before its normals enter the consensus; the tests (network-wide
    :class:`~distnav.algorithms.kalman.InnovationTests`) are on every ``ckf:STA`` series as ``innovation_tests``.
    """
    opts: dict[str, Any] = {
        "datum": options.datum,
        "pivot": options.pivot,
        "reference": options.reference,
        "scale": data.dsb_scale_m_per_ns,
        "datum_satellites": options.datum_satellites,
        "datum_reference_ns": options.datum_reference_ns,
    }
    out = [_central_filter(data, opts)]
    if options.local:
        out += [_local_filter(data, i, opts, options.datum) for i in range(len(data.stations))]
    comm = None
    if graph is not None:
        ckf, comm = _ckf_filters(data, opts, options, graph, exchange)
        out += ckf
    test = _between_stations(data, out, options.between_station_level) if options.local else None
    if test is not None:
        out = _with_station_constant_errors(data, out, test)
    return out, comm


def _with_station_constant_errors(data: BiasNetworkData, series: list[DatumSeries], test: Any) -> list[DatumSeries]:
    """Every series with the test attached and, when it rejects, its satellites' realistic σ raised to the floor
    the single-receiver solutions imply (:func:`~distnav.models.gnss.stationcheck.variance_floor`)."""
    from distnav.models.gnss.stationcheck import variance_floor

    n = len(data.stations)
    local = {s.label[len("local:") :]: s.realistic_std_ns()[n:] for s in series if s.label.startswith("local:")}
    every = np.stack([local[sta] for sta in data.stations if sta in local])
    out = []
    for s in series:
        if not test.rejected:
            out.append(replace(s, between_station=test))
            continue
        sta = s.label[len("local:") :] if s.label.startswith("local:") else None
        floor = variance_floor(test.factor, every if sta is None else local[sta][None, :])
        own = s.realistic_std_ns()[n:]
        extra = np.zeros(n + len(data.layout.svs))
        extra[n:] = np.where(np.isfinite(own), np.maximum(floor - own**2, 0.0), 0.0)
        out.append(replace(s, between_station=test, extra_variance_ns2=extra))
    return out


def _between_stations(data: BiasNetworkData, series: Sequence[DatumSeries], level: float | None) -> Any:
    """The between-station test (:mod:`~distnav.models.gnss.stationcheck`) on the single-receiver filters' last
    satellite DSBs and realistic σ; None when off, with one station, or when no pair shares enough satellites."""
    from distnav.models.gnss.stationcheck import between_station_test

    local = [s for s in series if s.label.startswith("local:")]
    if level is None or len(local) < 2:
        return None
    n = len(data.stations)
    dsb = np.stack([s.dsb_ns[-1, n:] for s in local])
    sigma = np.stack([s.realistic_std_ns()[n:] for s in local])
    return between_station_test([s.label[len("local:") :] for s in local], dsb, sigma, level=level)


def _central_filter(data: BiasNetworkData, opts: dict[str, Any]) -> DatumSeries:
    """The central filter over every station's data."""
    from distnav.algorithms.kalman import iterate_information_filter

    c = Collector(
        "central", data.series.n_epochs, data.layout, data.series, np.arange(len(data.stations)), data.dynamics, **opts
    )
    for st in iterate_information_filter(data.dynamics, data.series, mode="central"):
        c.step(st.epoch, st.estimates[0], st.estimable[0], st.covariance[0])
    return _with_arc_factor(c.done(), data, None)


def _local_filter(data: BiasNetworkData, i: int, opts: dict[str, Any], datum: str) -> DatumSeries:
    """Station ``i``'s single-receiver filter, in its own receiver's basis (so its satellite DCBs are estimable
    from its own data)."""
    from distnav.algorithms.kalman import iterate_information_filter

    sta = data.stations[i]
    si = data.series_for(sta)
    own = {**opts, "reference": None if datum != "receiver" else sta}
    c = Collector(f"local:{sta}", data.series.n_epochs, si.layout, si, np.array([i]), data.dynamics, **own)
    for st in iterate_information_filter(data.dynamics, si, mode="central", nodes=[i]):
        c.step(st.epoch, st.estimates[0], st.estimable[0], st.covariance[0])
    return _with_arc_factor(c.done(), data, [i])


def _ckf_filters(
    data: BiasNetworkData, opts: dict[str, Any], options: BiasFilterOptions, graph: Any, exchange: Any
) -> tuple[list[DatumSeries], Any]:
    """The consensus Kalman filter (paper 003, P3 with ``kn`` rounds), one series per receiver, and its
    communication totals."""
    from distnav.algorithms.kalman.ckf import iterate_ckf
    from distnav.exchange import make_exchange

    T, level = data.series.n_epochs, options.innovation_level
    ex = exchange if exchange is not None else make_exchange(graph)
    cs = [
        Collector(f"ckf:{s}", T, data.layout, data.series, np.array([i]), data.dynamics, **opts)
        for i, s in enumerate(data.stations)
    ]
    tests = None
    if level is not None:
        from distnav.algorithms.kalman.ckf_qc import InnovationCollector
        from distnav.algorithms.statistics import critical_value

        tests = InnovationCollector(ex, len(data.stations), level, critical_value(level))
    for cst in iterate_ckf(
        data.dynamics,
        data.series,
        graph=graph,
        protocol="P3",
        rounds=options.kn,
        exchange=ex,
        monitor=False,
        local_precision=None if tests is None else "bound",
        test_level=level,
        transport=_ckf_transport(ex, graph, options.kn, data.series),
    ):
        if tests is not None:
            tests.add(cst.tests)
        x = ex.gather_nodes(cst.estimates)
        est = ex.gather_nodes(cst.estimable)
        P = ex.gather_nodes(cst.covariance) if cst.covariance is not None else None
        for i, col in enumerate(cs):
            col.step(cst.epoch, x[i], est[i], None if P is None else P[i])
    built = tests.build() if tests is not None else None
    return [replace(col.done(), precision=None, innovation_tests=built) for col in cs], ex.comm_totals()


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
