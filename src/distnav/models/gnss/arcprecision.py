"""Arc-level precision of the bias filters: post-fit residuals and a variance factor from the levelled arcs.

Carrier-levelled geometry-free code ``ḡ = g_Φ + ⟨g_P − g_Φ⟩_arc`` has the phase's shape and the code's level: its
error is, to first order, **one constant per arc** — the levelling error, the arc's multipath and code noise
averaged over the arc — shared by every epoch of the arc. The filters treat the epochs as independent with the
code's σ (paper 003's white-noise model), so their formal σ and the epoch-wise variance factor (predicted
residuals, lag-1 correlation; :class:`~distnav.models.gnss.gfnetwork.DatumSeries`) see the arc error only in
part: on the realistic simulator preset the epoch-wise realistic σ is 2.7–3.0× smaller than the error (docs/gnss.md).

Here the arcs are the units of information on the biases. With the filter's final receiver + satellite biases
``b_i + b^s`` (datum-free sums), the TEC parameters are re-fitted per epoch by weighted least squares
(:func:`postfit_residuals`), and each arc ``a`` of station *i* gets its weighted mean residual
``ē_a = Σ_k w_k e_k / W_a`` (``W_a = Σ_k w_k``: the information of the arc's level under the white model, so
``ē_a`` has the formal variance ``1/W_a``). The **arc variance factor**

    ``σ̂²_arc = Σ_a W_a ē_a² / (n_arcs − n_biases)``,     ``n_biases = n_receivers + n_satellites − 1``,

compares the arcs' scatter about the fitted biases with what the white model predicts: ≈ 1 for data following
the model, the ratio of the arc error's variance to ``1/W_a`` when the arcs carry constant errors. The realistic
σ is the formal σ × ``√σ̂²_arc`` (a departure from paper 003, which reports formal σ only). The redundancy is
that of the biases estimated from the arc levels: arcs of different stations and of successive passes of a
satellite; a single station with one pass per satellite has none (then ``None``: the epoch-wise factor is used).

**Robust form (the default).** The arcs' standardized errors are heavy-tailed: once the levelling keeps whole
passes (adaptive slip test, :mod:`~distnav.models.gnss.levelling`), on the realistic simulator preset five of
≈ 215 arcs of a day carry 29 % of ``Σ W_a ē_a²`` (the mean is 5× the median), and the ratio above makes the
realistic σ 1.3–1.9× the true error. The default takes the median instead: ``σ̂²_arc = median_a(W_a ē_a² /
(1 − h̄_a)) / 0.455 × Σ_a(1 − h̄_a) / redundancy`` (0.455 the median of χ²₁, so both agree for white data;
the last factor for the biases fitted); ``estimator="mean"`` keeps the ratio (docs/gnss.md for the numbers).
It is an empirical choice, checked against the truth of the preset only: with Gaussian arc-constant errors
(the test's Monte Carlo) ``W_a ē_a²`` grows with ``W_a`` and the median gives 0.71–0.81 of the mean's factor.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from distnav.errors import ModelError

__all__ = [
    "ARC_FACTOR_ESTIMATOR",
    "ArcVarianceFactor",
    "MIN_ARC_REDUNDANCY",
    "arc_ids_on_grid",
    "arc_variance_factor",
    "postfit_residuals",
]

MIN_ARC_REDUNDANCY = 8
"""Fewest degrees of freedom (arcs − biases) for an arc variance factor; below it the epoch-wise one is used."""
ARC_FACTOR_ESTIMATOR = "median"
"""How σ̂²_arc is taken from the arcs (module doc): "median" (robust) or "mean" (``Σ W_a ē_a² / redundancy``)."""
CHI2_1_MEDIAN = 0.4549364231195724
"""Median of χ² with one degree of freedom (``scipy.stats.chi2(1).median()``)."""


@dataclass(frozen=True)
class ArcVarianceFactor:
    """``factor`` σ̂²_arc (module doc) from ``n_arcs`` arcs with ``redundancy`` = arcs − biases; ``ssr`` is
    ``Σ W_a ē_a²``. The redundancy counts each arc as ``1 − h̄_a`` (``h̄_a`` the arc's weighted mean leverage
    in the per-epoch TEC re-fit, which absorbs part of an arc's level)."""

    factor: float
    n_arcs: int
    redundancy: float
    ssr: float


def arc_ids_on_grid(
    obs: Sequence[Any],
    levelled: Mapping[str, Any],
    grids: Mapping[str, np.ndarray],
    t_gps_s: np.ndarray,
    svs: Sequence[str],
) -> np.ndarray:
    """The levelled arc (per station: :attr:`~distnav.models.gnss.levelling.LevelledStation.arc`, −1 = raw code)
    of every observation of the filter's grid (T, n, S): stations ``obs`` (``CodeObservations``), ``grids`` the
    full-rate epochs each keeps, the filter's epochs ``t_gps_s`` and satellites ``svs``."""
    from distnav.models.gnss.orbits import gps_seconds

    out = np.full((np.asarray(t_gps_s).size, len(obs), len(svs)), -1, np.int64)
    for i, o in enumerate(obs):
        keep_t = grids[o.station]
        ti = np.searchsorted(t_gps_s, gps_seconds(o.time[keep_t]))
        arc = levelled[o.station].arc[keep_t]
        for j, sv in enumerate(svs):
            if sv in o.svs:
                out[ti, i, j] = arc[:, o.svs.index(sv)]
    return out


def postfit_residuals(data: Any, dsb_ns: np.ndarray, nodes: Any = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    e, w, use, _ = _refit(data, dsb_ns, nodes)
    return e, w, use


def _refit(data: Any, dsb_ns: np.ndarray, nodes: Any = None) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Residuals ``e`` (T, n, S) [m] of the observations minus the biases ``dsb_ns`` (receivers then satellites,
    a filter's last epoch in any datum) minus the TEC re-fitted per epoch and ionosphere by weighted least
    squares; the weights ``w`` (T, n, S) and the mask ``use`` of the residuals computed (observed, biases
    finite, the epoch's TEC determined). ``nodes``: only these stations' observations (a single-receiver filter).
    """
    geo, lay = data.geometry, data.layout
    T, n, S = data.obs_m.shape
    dsb = np.asarray(dsb_ns, float)
    b_m = -(dsb[:n, None] + dsb[None, n:]) * data.dsb_scale_m_per_ns  # (n, S) b_i + b^s [m]
    ok = geo.tracked & np.isfinite(data.obs_m) & np.isfinite(b_m)[None]
    if nodes is not None:
        sel = np.zeros(n, bool)
        sel[np.asarray(nodes, np.int64)] = True
        ok &= sel[None, :, None]
    w = np.where(ok, 1.0 / np.where(ok, data.sigma_m, 1.0) ** 2, 0.0)
    y = np.where(ok, data.obs_m - np.where(np.isfinite(b_m), b_m, 0.0)[None], 0.0)
    a = np.where(ok[..., None], geo.coefficients, 0.0)  # (T, n, S, 3 or 6)
    groups = np.asarray(geo.groups, np.int64)
    onehot = np.eye(lay.n_ionospheres)[groups]  # (n, G)
    aw_t = np.swapaxes(a * w[..., None], -1, -2)  # (T, n, k, S): batched products, not a 4-operand einsum
    N = np.einsum("ng,tnkl->tgkl", onehot, aw_t @ a)
    r = np.einsum("ng,tnk->tgk", onehot, (aw_t @ y[..., None])[..., 0])
    if a.shape[-1] == 3:
        good = np.linalg.det(N) > 1e-12 * np.maximum(np.einsum("tgkk->tg", N), 1e-300) ** 3
    else:  # the curvature terms are small (Δφ² ≪ 1): judge by the eigenvalue spread
        ev = np.linalg.eigvalsh(N)
        good = ev[..., 0] > 1e-12 * np.maximum(ev[..., -1], 1e-300)
    nu = np.zeros(r.shape)
    if good.any():
        nu[good] = np.linalg.solve(N[good], r[good][..., None])[..., 0]
    e = y - np.einsum("tnsk,tnk->tns", a, nu[:, groups])
    use = ok & good[:, groups][..., None]
    Ninv = np.zeros(N.shape)
    if good.any():
        Ninv[good] = np.linalg.inv(N[good])
    h = w * ((a @ Ninv[:, groups]) * a).sum(axis=-1)  # the TEC fit's leverage a_sᵀ N⁻¹ a_s
    return e, w, use, np.where(use, h, 0.0)


def arc_variance_factor(
    data: Any,
    dsb_ns: np.ndarray,
    nodes: Any = None,
    *,
    min_redundancy: int = MIN_ARC_REDUNDANCY,
    estimator: str = ARC_FACTOR_ESTIMATOR,
) -> ArcVarianceFactor | None:
    """σ̂²_arc of the module doc for the biases ``dsb_ns`` (a filter's last epoch) over the arcs of ``nodes``
    (default all stations); ``None`` without arcs (no levelling: ``data.arc_id`` is ``None``) or with fewer than
    ``min_redundancy`` degrees of freedom. Each station's sums are its own (arcs do not span stations).
    ``estimator`` "median" (default, :data:`ARC_FACTOR_ESTIMATOR`) or "mean" (the module doc's ratio)."""
    if estimator not in ("median", "mean"):
        raise ModelError(f"arc factor estimator {estimator!r}: use 'median' or 'mean'")
    arc_id = getattr(data, "arc_id", None)
    if arc_id is None:
        return None
    e, w, use, h = _refit(data, dsb_ns, nodes)
    T, n, S = e.shape
    kept = 0.0
    arcs = np.where(use, np.asarray(arc_id, np.int64), -1)
    ssr = 0.0
    n_arcs = 0
    scaled: list[np.ndarray] = []  # W_a ē_a² / (1 − h̄_a)
    for i in range(n):
        a = arcs[:, i].ravel()
        k = a >= 0
        if not k.any():
            continue
        ids, inv = np.unique(a[k], return_inverse=True)
        W = np.bincount(inv, weights=w[:, i].ravel()[k], minlength=ids.size)
        we = np.bincount(inv, weights=(w[:, i] * e[:, i]).ravel()[k], minlength=ids.size)
        fine = W > 0
        ssr += float((we[fine] ** 2 / W[fine]).sum())  # Σ W_a ē_a²
        wh = np.bincount(inv, weights=(w[:, i] * h[:, i]).ravel()[k], minlength=ids.size)
        kept += float((1.0 - wh[fine] / W[fine]).sum())  # 1 − the arc's mean leverage
        n_arcs += int(fine.sum())
        scaled.append(we[fine] ** 2 / W[fine] / np.maximum(1.0 - wh[fine] / W[fine], 1e-6))
    seen = np.asarray(np.asarray(use, bool).sum(axis=0) > 0)  # (n, S)
    n_biases = int(seen.any(axis=1).sum() + seen.any(axis=0).sum()) - 1
    red = kept - n_biases
    if red < min_redundancy:
        return None
    if estimator == "median":
        med = float(np.median(np.concatenate(scaled))) / CHI2_1_MEDIAN
        return ArcVarianceFactor(med * kept / red, n_arcs, red, ssr)
    return ArcVarianceFactor(ssr / red, n_arcs, red, ssr)
