"""Regional single-layer ionosphere and between-satellite DCBs from geometry-free code — paper 003 §5.1.

Observable (paper 003 eq. (49) and the coefficients after it; papers README, "Ionosphere model"): receiver ``i``
forms, per epoch ``t`` and tracked satellite ``s``, the geometry-free code combination

    ``y_i^s = (P_2 − P_1)/(μ_2 − μ_1)``   [m]  (the slant ionospheric delay on L1 plus code biases),

and the between-satellite differences ``y_i^{qs} = y_i^s − y_i^q`` follow the model

    ``y_i^{qs} = Σ_{k∈{o,φ,ψ}} (a_{i,k}^s − a_{i,k}^q) ν_k + b^{ps} − b^{pq} + ε_i^{qs}``   (b^{pp} = 0),

with the single-layer coefficients of the pierce point (IPP) of the line of sight on a 450 km layer over a sphere
of radius 6378.137 km (:func:`distnav.models.gnss.geometry.pierce_point`)

    ``a_o = 1/cos z'``,  ``a_φ = (φ_IPP − φ_o)/cos z'``,  ``a_ψ = (ψ_IPP − ψ_o)/cos z'``,

about a reference point ``(φ_o, ψ_o)`` (default: the receivers' centroid; see :class:`IonosphereGeometry`).

Units (all states in metres of the L1 observable, as in the paper):

* ``ν_o``: vertical ionospheric delay on L1 at the reference point [m] (``vtec_m``; 1 TECU = :data:`TECU_L1_M`
  = 0.1624 m); ``ν_φ``, ``ν_ψ``: its south-to-north and west-to-east gradients [m/rad].
* ``b^{ps}`` [m of the geometry-free observable]: the between-satellite bias relative to the *pivot* satellite
  ``p`` (paper: PRN 10). With the Bias-SINEX sign convention (biases add to the observations),
  ``b^{ps} = −c (DSB^s − DSB^p)/(μ_2 − μ_1)`` where ``DSB = OSB(C1) − OSB(C2)`` (e.g. C1C−C2W): 1 ns of DSB is
  :data:`GF_M_PER_DSB_NS` = 0.4634 m of ``b``. :func:`dcb_ns_from_gf_m` converts (``dcb_ns = DSB^s − DSB^p``).

The observations need not be differenced against the pivot: the parameters are always ``b^{ps}`` (S-basis of the
pivot) while the differences may use any tracked satellite ``q`` — satellites rise and set, the pivot among them,
and the model is invariant to the choice of ``q``. Noise: the undifferenced ``y_i^s`` are uncorrelated with
``σ_s = σ / sin θ_s`` (σ = 65.6 cm at zenith, the geometry-free code of 30 cm code noise: √2·0.30/0.647), so the
differences have the full covariance ``D_mᵀ diag(σ_s²) D_m``. :class:`GeometryFreeSeries` gives the normals of the
differenced model with that full covariance in closed form (they equal the normals of the undifferenced model
with the receiver bias eliminated), for any subset of nodes, epoch by epoch — the input of
:mod:`distnav.algorithms.kalman` and :mod:`distnav.algorithms.kalman.ckf`. :func:`differenced_observations` builds the
explicit differences and their covariance (the reference of the tests).

Dynamic model (paper 003 eqs. (52)–(53)): random walk on ``ν_o`` (1 mm/√s) and on ``ν_φ, ν_ψ`` (5 mm/rad/√s),
constant DCBs, i.e. a singular system noise ``S = H S̃ Hᵀ`` with ``H`` the TEC columns
(:func:`ionosphere_dynamics`). For a network spanning continents one regional model is meaningless; the series
then accept one ionosphere (3 TEC parameters about the receiver's own zenith) per receiver ("per-receiver"
mode), the DCBs staying common.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from distnav.algorithms.kalman import DynamicModel, MeasurementSeries, ObservationSeries, simulate_states
from distnav.errors import ModelError
from distnav.models.gnss.constants import C_M_S, F_L1_HZ, mu
from distnav.models.gnss.ionogeometry import (
    MSLM_ALPHA,
    MSLM_HEIGHT_M,
    GeometryOptions,
    IonosphereGeometry,
    ionosphere_coefficients,
    ionosphere_geometry,
)
from distnav.models.gnss.observables import elevation_sigma
from distnav.typing import ArrayLike, BoolArray, FloatArray, IntArray

__all__ = [
    "TECU_L1_M",
    "SeriesArrays",
    "GF_M_PER_DSB_NS",
    "GF_SIGMA_ZENITH_M",
    "VTEC_RW_STD_M_PER_SQRT_S",
    "GRADIENT_RW_STD_M_PER_RAD_SQRT_S",
    "TEC_NAMES",
    "dcb_ns_from_gf_m",
    "gf_m_from_dcb_ns",
    "geometry_free_m",
    "ionosphere_coefficients",
    "GeometryOptions",
    "IonosphereGeometry",
    "MSLM_ALPHA",
    "MSLM_HEIGHT_M",
    "ionosphere_geometry",
    "IonosphereStateLayout",
    "ionosphere_dynamics",
    "GeometryFreeSeries",
    "geometry_free_series",
    "differenced_observations",
    "simulate_geometry_free",
    "choose_pivot",
]

TECU_L1_M = 40.3e16 / F_L1_HZ**2
"""Metres of L1 ionospheric delay per TEC unit (1e16 el/m²): 40.3e16/f₁² ≈ 0.1624 m."""

GF_M_PER_DSB_NS = C_M_S * 1e-9 / (mu(2) - 1.0)
"""Metres of the geometry-free observable ``(P2 − P1)/(μ2 − μ1)`` per ns of an L1−L2 DSB (≈ 0.4634 m/ns)."""

GF_SIGMA_ZENITH_M = 0.656
"""Zenith standard deviation of the undifferenced geometry-free code observable, paper 003 §5.1 (65.6 cm)."""

VTEC_RW_STD_M_PER_SQRT_S = 1e-3
"""Random-walk spectral density of ν_o, paper 003 §5.1: 1 mm/√s."""

GRADIENT_RW_STD_M_PER_RAD_SQRT_S = 5e-3
"""Random-walk spectral density of ν_φ and ν_ψ, paper 003 §5.1: 5 mm/rad/√s."""

TEC_NAMES = ("vtec_m", "vtec_grad_lat_m_per_rad", "vtec_grad_lon_m_per_rad")
"""Names (with units) of the three TEC parameters ν_o, ν_φ, ν_ψ of one ionosphere."""

TEC_NAMES_QUADRATIC = (
    *TEC_NAMES,
    "vtec_curv_lat_m_per_rad2",
    "vtec_curv_latlon_m_per_rad2",
    "vtec_curv_lon_m_per_rad2",
)
"""The six TEC parameters of a second-order field (``tec_order=2``): ν_o, the gradients, then the coefficients of
Δφ², Δφ·Δψ and Δψ² — a departure from paper 003's linear field, for low-latitude stations (docs/gnss.md)."""


def dcb_ns_from_gf_m(b_m: np.ndarray | float) -> np.ndarray:
    """Between-satellite DCB ``DSB^s − DSB^p`` [ns] from the geometry-free bias ``b^{ps}`` [m] (sign: Bias-SINEX)."""
    return -np.asarray(b_m, dtype=float) / GF_M_PER_DSB_NS


def gf_m_from_dcb_ns(dcb_ns: np.ndarray | float) -> np.ndarray:
    """Inverse of :func:`dcb_ns_from_gf_m`."""
    return -np.asarray(dcb_ns, dtype=float) * GF_M_PER_DSB_NS


def geometry_free_m(p1_m: np.ndarray, p2_m: np.ndarray) -> np.ndarray:
    """The geometry-free code combination ``(P2 − P1)/(μ2 − μ1)`` [m] (L1 slant delay + biases); NaN propagates."""
    return np.asarray((np.asarray(p2_m, dtype=float) - np.asarray(p1_m, dtype=float)) / (mu(2) - 1.0))


# ----------------------------------------------------------------------------------------------- state + dynamics
@dataclass(frozen=True)
class IonosphereStateLayout:
    """State vector of paper 003 eq. (52): ``3 × n_ionospheres`` TEC parameters, then the DCBs ``b^{ps}`` of
    every satellite but the pivot (in the order of ``svs``)."""

    svs: tuple[str, ...]
    pivot: str
    n_ionospheres: int = 1

    def __post_init__(self) -> None:
        if self.pivot not in self.svs:
            raise ModelError(f"pivot satellite {self.pivot} is not among the satellites {list(self.svs)[:8]}...")
        if len(self.svs) < 2:
            raise ModelError("the between-satellite model needs at least two satellites")
        if self.n_ionospheres < 1:
            raise ModelError("n_ionospheres must be ≥ 1")

    @property
    def n_tec(self) -> int:
        return 3 * self.n_ionospheres

    @property
    def n_states(self) -> int:
        return self.n_tec + len(self.svs) - 1

    @property
    def dcb_svs(self) -> tuple[str, ...]:
        return tuple(s for s in self.svs if s != self.pivot)

    @property
    def pivot_index(self) -> int:
        return self.svs.index(self.pivot)

    def dcb_column(self) -> np.ndarray:
        """State column of each satellite's DCB (``-1`` for the pivot), aligned with ``svs``."""
        col = np.full(len(self.svs), -1, np.int64)
        k = self.n_tec
        for j, s in enumerate(self.svs):
            if s != self.pivot:
                col[j] = k
                k += 1
        return col

    def state_names(self, receiver_names: Sequence[str] | None = None) -> list[str]:
        names: list[str] = []
        for g in range(self.n_ionospheres):
            pre = "" if self.n_ionospheres == 1 else f"{receiver_names[g] if receiver_names else g}:"
            names += [pre + t for t in TEC_NAMES]
        return names + [f"dcb_gf_m:{s}-{self.pivot}" for s in self.dcb_svs]


def ionosphere_dynamics(
    layout: IonosphereStateLayout,
    interval_s: float | np.ndarray,
    *,
    vtec_std_m_per_sqrt_s: float = VTEC_RW_STD_M_PER_SQRT_S,
    gradient_std_m_per_rad_sqrt_s: float = GRADIENT_RW_STD_M_PER_RAD_SQRT_S,
) -> DynamicModel:
    """Paper 003 eq. (53): ``Φ = I``; random walk on every ionosphere's ν_o, ν_φ, ν_ψ with variances
    ``q² Δ`` per epoch (q = 1 mm/√s, 5 mm/rad/√s), DCBs constant. ``S = H S̃ Hᵀ`` with ``H`` the TEC columns
    (eq. (20)): the system noise is singular.

    ``interval_s`` is the sampling interval Δ, or one interval per epoch (entry ``t`` = time from epoch ``t−1`` to
    ``t``; entry 0 unused) for an irregular epoch grid (real data with gaps).
    """
    q2 = (
        np.tile(
            [vtec_std_m_per_sqrt_s, gradient_std_m_per_rad_sqrt_s, gradient_std_m_per_rad_sqrt_s], layout.n_ionospheres
        )
        ** 2
    )
    p = layout.n_states
    H = np.eye(p)[:, : layout.n_tec]
    dt = np.asarray(interval_s, dtype=float)
    if dt.ndim == 0:
        if not (np.isfinite(dt) and dt > 0):
            raise ModelError(f"the sampling interval must be positive, got {interval_s} s")
        return DynamicModel(p, noise_map=H, noise_reduced_cov=np.diag(q2 * float(dt)))
    if dt.ndim != 1 or dt.size < 1:
        raise ModelError(f"interval_s must be a number or one interval per epoch, got shape {dt.shape}")
    steps = dt[1:]
    if not np.all(np.isfinite(steps) & (steps > 0)):
        bad = int(np.flatnonzero(~(np.isfinite(steps) & (steps > 0)))[0]) + 1
        raise ModelError(f"the interval before epoch {bad} is {dt[bad]} s; intervals must be positive")
    dts = np.concatenate([[steps[0] if steps.size else 1.0], steps])
    return DynamicModel(p, noise_map=[H] * dt.size, noise_reduced_cov=[np.diag(q2 * d) for d in dts])


def choose_pivot(svs: Sequence[str], tracked: np.ndarray, preferred: str | None = "G10") -> str:
    """The pivot satellite: ``preferred`` (paper 003 §5.2: PRN 10) when it is tracked at all, else the satellite
    tracked at the most receiver-epochs. ``tracked`` is (T, n, S)."""
    counts = np.asarray(tracked, dtype=bool).sum(axis=(0, 1))
    if preferred is not None and preferred in svs and counts[list(svs).index(preferred)] > 0:
        return preferred
    if counts.max(initial=0) == 0:
        raise ModelError("no satellite is tracked by any receiver: no pivot")
    return svs[int(np.argmax(counts))]


# ----------------------------------------------------------------------------------------------- measurements
def series_inputs(
    coefficients: ArrayLike,
    sigma_m: ArrayLike,
    obs_m: ArrayLike | None,
    tracked: ArrayLike | None,
    groups: ArrayLike | None,
    n_ionospheres: int,
    n_terms: int = 3,
) -> tuple[FloatArray, FloatArray, BoolArray, FloatArray | None, IntArray]:
    """Check the inputs of a geometry-free series: ``coefficients`` (T epochs, n nodes, S satellites, 3);
    ``sigma_m``, ``obs_m`` and ``tracked`` (T, n, S); ``groups`` (n,) ionosphere indices. Returns ``(coefficients,
    σ, usable mask, y or None, groups)``; a value is usable where σ > 0 and everything is finite and tracked."""
    a = np.asarray(coefficients, dtype=float)
    if a.ndim != 4 or a.shape[-1] != n_terms:
        raise ModelError(f"coefficients must have shape (epochs, nodes, satellites, {n_terms}), got {a.shape}")
    T, n, S, _ = a.shape
    sig = np.asarray(sigma_m, dtype=float)
    if sig.shape != (T, n, S):
        raise ModelError(f"sigma_m must have shape {(T, n, S)}, got {sig.shape}")
    ok = np.isfinite(sig) & (sig > 0) & np.isfinite(a).all(axis=-1)
    if tracked is not None:
        tr = np.asarray(tracked, dtype=bool)
        if tr.shape != (T, n, S):
            raise ModelError(f"tracked must have shape {(T, n, S)}, got {tr.shape}")
        ok &= tr
    y = None
    if obs_m is not None:
        y = np.asarray(obs_m, dtype=float)
        if y.shape != (T, n, S):
            raise ModelError(f"obs_m must have shape {(T, n, S)}, got {y.shape}")
        ok &= np.isfinite(y)
    g = np.zeros(n, np.int64) if groups is None else np.asarray(groups, dtype=np.int64)
    if g.shape != (n,) or g.min() < 0 or g.max() >= n_ionospheres:
        raise ModelError(f"groups must be {n} ionosphere indices in 0..{n_ionospheres - 1}, got shape {g.shape}")
    return a, sig, ok, y, g


class SeriesArrays(MeasurementSeries):
    """The arrays the geometry-free series share (:class:`GeometryFreeSeries`, :class:`~distnav.models.gnss.gfbias.
    BiasGeometryFreeSeries`): inputs over (T epochs, n nodes, S satellites) checked by :func:`series_inputs` —
    ``coefficients`` (T, n, S, terms), ``sigma_m``, ``obs_m`` (NaN = not observed), ``tracked`` (T, n, S),
    ``groups`` (n,) — kept as TEC coefficients ``_a``, weights ``_w = 1/σ²`` and values ``_y``, zero where not
    usable (:meth:`_usable`, each model's rule); :meth:`_setup` adds the model's own columns."""

    def __init__(
        self,
        layout: Any,
        coefficients: np.ndarray,
        sigma_m: np.ndarray,
        *,
        obs_m: np.ndarray | None = None,
        tracked: np.ndarray | None = None,
        groups: np.ndarray | None = None,
    ) -> None:
        terms = getattr(layout, "n_tec_terms", 3)
        a, sig, ok, y, g = series_inputs(coefficients, sigma_m, obs_m, tracked, groups, layout.n_ionospheres, terms)
        self.layout = layout
        ok = self._usable(a, ok)
        T, n, S, _ = a.shape
        self.n_epochs, self.n_nodes, self.n_states, self.n_satellites = T, n, layout.n_states, S
        self._a = np.where(ok[..., None], a, 0.0)
        self._w = np.where(ok, 1.0 / np.where(ok, sig, 1.0) ** 2, 0.0)
        self._y = None if y is None else np.where(ok, y, 0.0)
        self._groups = g
        self.tracked = ok
        self._setup()

    def _usable(self, a: np.ndarray, ok: np.ndarray) -> np.ndarray:
        """The observations the model uses of those tracked (and the shape checks against the layout)."""
        return ok

    def _setup(self) -> None:
        """The model's own state columns (after the arrays)."""


class GeometryFreeSeries(SeriesArrays):
    """Per-node, per-epoch normals of the between-satellite geometry-free model (paper 003 eqs. (49)–(51)).

    Inputs over (T epochs, n nodes, S satellites): ``coefficients`` (T, n, S, 3), ``sigma_m`` (T, n, S) standard
    deviations of the undifferenced observable (``inf``/NaN or ``tracked`` False = not observed), optional
    undifferenced observations ``obs_m`` (T, n, S) (NaN = not observed), ``groups`` (n,) the ionosphere of each
    node. The normals of the differenced observations with full covariance ``Dᵀ Q D`` are formed without
    choosing a reference satellite: with weights ``w_s = 1/σ_s²`` and ``Ā`` the undifferenced design rows
    ``[a_s (in the node's TEC block), e_{col(s)}]``,

        ``N = Āᵀ W Ā − (Āᵀ w)(wᵀ Ā)/Σw``,   ``r = Āᵀ W y − (Āᵀ w)(wᵀ y)/Σw``,

    the identity ``D(DᵀQD)⁻¹Dᵀ = Q⁻¹ − Q⁻¹e(eᵀQ⁻¹e)⁻¹eᵀQ⁻¹`` (for ``Dᵀe = 0``) — the receiver's own bias is
    eliminated. A node tracking fewer than two satellites contributes nothing.
    """

    layout: IonosphereStateLayout

    def _usable(self, a: np.ndarray, ok: np.ndarray) -> np.ndarray:
        """The satellites of the layout; a node-epoch with one satellite alone gives no between-satellite
        difference."""
        S = a.shape[2]
        if S != len(self.layout.svs):
            raise ModelError(f"coefficients for {S} satellites, the state layout has {len(self.layout.svs)}")
        out: np.ndarray = ok & (ok.sum(axis=2, keepdims=True) >= 2)
        return out

    def _setup(self) -> None:
        self._col = self.layout.dcb_column()
        self._sv = np.flatnonzero(self._col >= 0)  # satellites with a DCB column, in column order

    def design(self, epoch: int, nodes: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Undifferenced design rows ``Ā`` (k, S, p) and weights ``w`` (k, S) (zero where not tracked)."""
        t = self._epoch(epoch)
        idx = self._nodes(nodes)
        k, S, p = idx.size, self.n_satellites, self.n_states
        A = np.zeros((k, S, p))
        a = self._a[t, idx]
        for j, gi in enumerate(self._groups[idx]):
            A[j, :, 3 * gi : 3 * gi + 3] = a[j]
        sv = np.flatnonzero(self._col >= 0)
        A[:, sv, self._col[sv]] = 1.0
        return A, self._w[t, idx]

    def normals(self, epoch: int, nodes: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """``N = Āᵀ P Ā``, ``r = Āᵀ P y`` with ``P = W − w wᵀ/Σw`` (class doc), assembled block by block in
        satellite space (TEC block ``aᵀPa``, cross block ``aᵀP``, DCB block ``P`` without the pivot)."""
        t = self._epoch(epoch)
        idx = self._nodes(nodes)
        k, p, n_tec = idx.size, self.n_states, self.layout.n_tec
        a = self._a[t, idx]  # (k, S, 3)
        w = self._w[t, idx]  # (k, S)
        sw = w.sum(axis=1)
        inv_sw = np.where(sw > 0, 1.0 / np.where(sw > 0, sw, 1.0), 0.0)[:, None]
        aw = a * w[..., None]
        awT = np.swapaxes(aw, 1, 2)  # (k, 3, S)
        ua = aw.sum(axis=1)  # aᵀw (k, 3)
        sv = self._sv
        ntt = awT @ a - ua[:, :, None] * (ua * inv_sw)[:, None, :]
        ntb = awT[:, :, sv] - ua[:, :, None] * (w[:, sv] * inv_sw)[:, None, :]
        wv = w[:, sv]
        nbb = -wv[:, :, None] * (wv * inv_sw)[:, None, :]
        d = np.arange(sv.size)
        nbb[:, d, d] += wv
        N = np.zeros((k, p, p))
        N[:, n_tec:, n_tec:] = nbb
        off = 3 * self._groups[idx]
        if np.all(off == off[0]):
            o = int(off[0])
            N[:, o : o + 3, o : o + 3] = ntt
            N[:, o : o + 3, n_tec:] = ntb
            N[:, n_tec:, o : o + 3] = np.swapaxes(ntb, 1, 2)
        else:
            rows = np.arange(k)[:, None, None]
            tec = (off[:, None] + np.arange(3)[None, :])[:, :, None]
            dcb = (n_tec + d)[None, None, :]
            N[rows, tec, np.swapaxes(tec, 1, 2)] = ntt
            N[rows, tec, dcb] = ntb
            N[rows, np.swapaxes(dcb, 1, 2), np.swapaxes(tec, 1, 2)] = np.swapaxes(ntb, 1, 2)
        if self._y is None:
            return N, np.zeros((k, p))
        y = self._y[t, idx]
        wy = w * y
        m = wy.sum(axis=1, keepdims=True) * inv_sw  # weighted mean of y
        r = np.zeros((k, p))
        r[:, n_tec:] = wy[:, sv] - wv * m
        rt = (awT @ y[..., None])[..., 0] - ua * m
        if np.all(off == off[0]):
            r[:, int(off[0]) : int(off[0]) + 3] = rt
        else:
            r[np.arange(k)[:, None], off[:, None] + np.arange(3)[None, :]] = rt
        return N, r

    def observations(self, epoch: int, nodes: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Whitened rows with the same normals: ``W^{1/2}(I − e wᵀ/Σw)Ā`` (rank m−1 in m rows; see class doc)."""
        A, w = self.design(epoch, nodes)
        idx = self._nodes(nodes)
        t = self._epoch(epoch)
        y = np.zeros(w.shape) if self._y is None else self._y[t, idx]
        sw = np.where(w.sum(axis=1) > 0, w.sum(axis=1), 1.0)
        Ac = A - (np.einsum("ks,ksp->kp", w, A) / sw[:, None])[:, None, :]
        yc = y - ((w * y).sum(axis=1) / sw)[:, None]
        sq = np.sqrt(w)
        keep = w > 0
        rows_A = (Ac * sq[..., None])[keep]
        rows_y = (yc * sq)[keep]
        node = np.broadcast_to(idx[:, None], w.shape)[keep]
        return rows_A, rows_y, node.astype(np.int64)


def geometry_free_series(
    geometry: IonosphereGeometry,
    layout: IonosphereStateLayout,
    *,
    sigma_zenith_m: float = GF_SIGMA_ZENITH_M,
    weighting: str = "sin",
    obs_m: np.ndarray | None = None,
) -> GeometryFreeSeries:
    """:class:`GeometryFreeSeries` of a geometry: ``σ_s = elevation_sigma(θ_s, σ)`` (``"sin"``: σ/sin θ as in the
    papers README; ``"euler-goad"`` or ``"constant"`` also), tracked = the geometry's mask."""
    if tuple(layout.svs) != tuple(geometry.svs):
        raise ModelError("the state layout and the geometry list different satellites")
    el = np.where(geometry.tracked, geometry.el_rad, 0.5 * np.pi)
    sig = elevation_sigma(el, sigma_zenith_m, weighting)
    return GeometryFreeSeries(
        layout, geometry.coefficients, sig, obs_m=obs_m, tracked=geometry.tracked, groups=geometry.groups
    )


def differenced_observations(series: GeometryFreeSeries, *, reference: str = "pivot") -> ObservationSeries:
    """The explicit between-satellite differences ``y^{qs}`` with full covariance ``D_mᵀ diag(σ²) D_m``
    (paper 003 eq. (49)–(51)) as an :class:`~distnav.algorithms.kalman.ObservationSeries`.

    The reference ``q`` is the pivot when the node tracks it, else its first tracked satellite
    (``reference="pivot"``), or always the first tracked satellite (``"first"``). Independent of the closed-form
    normals of :class:`GeometryFreeSeries` (it is their test reference) and of the reference choice.
    """
    if reference not in ("pivot", "first"):
        raise ModelError(f"reference must be 'pivot' or 'first', got {reference!r}")
    piv = series.layout.pivot_index
    epochs = []
    for t in range(series.n_epochs):
        A_all, w_all = series.design(t)
        y_all = np.zeros(w_all.shape) if series._y is None else series._y[t]
        row: list[tuple[np.ndarray, np.ndarray, np.ndarray] | None] = []
        for i in range(series.n_nodes):
            vis = np.flatnonzero(w_all[i] > 0)
            if vis.size < 2:
                row.append(None)
                continue
            q = piv if (reference == "pivot" and piv in vis) else int(vis[0])
            others = vis[vis != q]
            A = A_all[i, others] - A_all[i, q]
            y = y_all[i, others] - y_all[i, q]
            var = 1.0 / np.where(w_all[i] > 0, w_all[i], 1.0)
            R = np.diag(var[others]) + var[q]
            row.append((A, R, y))
        epochs.append(row)
    return ObservationSeries(series.n_states, epochs)


def simulate_geometry_free(
    geometry: IonosphereGeometry,
    layout: IonosphereStateLayout,
    interval_s: float,
    *,
    rng: np.random.Generator,
    sigma_zenith_m: float = GF_SIGMA_ZENITH_M,
    weighting: str = "sin",
    vtec0_m: float = 2.0,
    satellite_dsb_std_ns: float = 3.0,
    receiver_dsb_std_ns: float = 10.0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Simulate undifferenced geometry-free observations of the model (paper 003 eqs. (49), (53)).

    Truth: TEC parameters start at ``(vtec0_m, 0, 0)`` per ionosphere and follow the random walk; satellite DSBs
    ``~ N(0, satellite_dsb_std_ns²)`` and receiver DSBs (eliminated by the differencing) ``~ N(0, ...)``.
    ``y_i^s = a_i^s·ν + b_i,r + b^s + ε`` (``b`` in metres of the observable, ``b^{ps} = b^s − b^p``),
    ``ε ~ N(0, σ_s²)`` independent. Returns ``(truth (T, p), obs_m (T, n, S) with NaN where not tracked,
    satellite DSB ns (S,))``.
    """
    dyn = ionosphere_dynamics(layout, interval_s)
    T, n, S = geometry.tracked.shape
    x0 = np.zeros(layout.n_states)
    x0[0 : layout.n_tec : 3] = vtec0_m
    sat_dsb_ns = rng.normal(0.0, satellite_dsb_std_ns, S)
    b_sat_m = gf_m_from_dcb_ns(sat_dsb_ns)
    col = layout.dcb_column()
    piv = layout.pivot_index
    for j in range(S):
        if col[j] >= 0:
            x0[col[j]] = b_sat_m[j] - b_sat_m[piv]
    truth = simulate_states(dyn, T, rng=rng, initial_state=x0)
    b_rx_m = gf_m_from_dcb_ns(rng.normal(0.0, receiver_dsb_std_ns, n))
    el = np.where(geometry.tracked, geometry.el_rad, 0.5 * np.pi)
    sig = elevation_sigma(el, sigma_zenith_m, weighting)
    tec = truth[:, : layout.n_tec].reshape(T, layout.n_ionospheres, 3)[:, geometry.groups]  # (T, n, 3)
    iono = np.einsum("tnsk,tnk->tns", geometry.coefficients, tec)
    y = iono + b_rx_m[None, :, None] + b_sat_m[None, None, :] + sig * rng.standard_normal((T, n, S))
    y[~geometry.tracked] = np.nan
    return truth, y, np.asarray(sat_dsb_ns)
