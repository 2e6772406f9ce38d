"""Receiver and satellite DCBs with the ionosphere in one undifferenced geometry-free model, with a choice of datum.

Observable (paper 003 eq. (49) before differencing; papers README): receiver ``i``, satellite ``s``, epoch ``t``,

    ``y_i^s = (P_b − P_1)/(μ_b − 1) = Σ_k a_{i,k}^s ν_k + b_i + b^s + ε_i^s``,   [m]

with ``b`` the second code's band (2 or 5: the frequency factor ``μ_b = (f₁/f_b)²`` comes from the band of the
code, so ``C5X`` uses L5's), ``ν`` the single-layer ionosphere of :mod:`distnav.models.gnss.ionosphere`, and
``b_i``, ``b^s`` the receiver and satellite biases in metres of the observable. A DSB ``C1−C_b`` of ``d`` ns (the
Bias-SINEX sign: biases add to the observations) is ``b = −d·c·10⁻⁹/(μ_b − 1)`` (:func:`gf_m_per_dsb_ns`).

**S-basis.** The design ``[a, e_i, e^s]`` has one rank defect: a constant added to every receiver bias and
subtracted from every satellite bias changes nothing. The filters estimate in one of two bases (a choice of the
``n + S − 1`` bias parameters, Teunissen's S-system), both estimable from the first epoch at which the named
object observes:

* ``basis="receiver"`` (default): the reference receiver ``r`` is lumped into the satellites,
  ``x^s = b^s + b_r`` and ``x_j = b_j − b_r``. Chosen as the station observing at the first epoch, so every DCB
  is estimable from the first epoch whatever satellites are up.
* ``basis="pivot"``: the pivot satellite ``p`` is lumped into the receivers, ``x^s = b^s − b^p``,
  ``x_j = b_j + b^p`` (paper 003's choice; nothing is estimable before ``p`` rises).

Any other datum is an S-transformation of the estimates (:func:`datum_transform`): *zero-mean satellites*
(``Σ_s b̃^s = 0`` over the estimable satellites: the IGS convention of the products), *pivot satellite* or
*reference receiver*. Estimable functions — differences between satellites, between receivers, and
``b_i + b^s`` — are the same in every datum; only the datum-defining part differs.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from distnav.algorithms.kalman import DynamicModel
from distnav.errors import ModelError
from distnav.models.gnss.constants import C_M_S, mu
from distnav.models.gnss.ionosphere import TEC_NAMES, TEC_NAMES_QUADRATIC, VTEC_RW_STD_M_PER_SQRT_S, SeriesArrays

__all__ = [
    "DATUMS",
    "TEC_RW_M_PER_SQRT_S",
    "gf_m_per_dsb_ns",
    "geometry_free_band_m",
    "BiasStateLayout",
    "BiasGeometryFreeSeries",
    "bias_dynamics",
    "datum_transform",
    "in_datum",
]

TEC_RW_M_PER_SQRT_S = 10.0 * VTEC_RW_STD_M_PER_SQRT_S
"""Default random walk of the vertical L1 delay in the bias model, 0.01 m/√s (gradients: 5× per radian): 10×
paper 003's 1 mm/√s. With carrier-levelled data weighted by the code's σ (their arc-constant error keeps the
code's information on the level), 1 mm/√s (0.37 TECU per hour) is far stiffer than the diurnal rise and fall of the TEC
(5–10 TECU/h at mid-latitudes in the morning, more near the equator): the lag of ν̂ goes into the receiver bias and,
through the elevation dependence of the mapping function, into the satellite DCBs (6-h sessions several times
worse than the full day; measured in docs/ionosphere.md, "Why the 6-h sessions got worse")."""

NORMALS_BLOCK = 64
"""Epochs whose normals :meth:`BiasGeometryFreeSeries.normals` computes at once (one batched product)."""

DATUMS = ("zero-mean", "pivot", "receiver")
"""Output datums: zero-mean satellites (IGS products), pivot satellite, reference receiver."""


def gf_m_per_dsb_ns(band: int = 2) -> float:
    """Metres of the geometry-free observable ``(P_b − P_1)/(μ_b − 1)`` per ns of a ``C1−C_b`` DSB (L2: 0.4634,
    L5: 0.3779)."""
    return C_M_S * 1e-9 / (mu(band) - 1.0)


def geometry_free_band_m(
    p1_m: np.ndarray, pb_m: np.ndarray, band: int = 2, *, mu_b: float | np.ndarray | None = None
) -> np.ndarray:
    """``(P_b − P_1)/(μ_b − 1)`` [m] with the frequency factor of the second code's GPS band, or ``mu_b`` (scalar
    or (S,) per satellite column: another system's pair, GLONASS channels); NaN propagates."""
    factor = (mu(band) if mu_b is None else np.asarray(mu_b, dtype=float)) - 1.0
    out: np.ndarray = (np.asarray(pb_m, dtype=float) - np.asarray(p1_m, dtype=float)) / factor
    return out


@dataclass(frozen=True)
class BiasStateLayout:
    """State vector: ``3 × n_ionospheres`` TEC parameters, the receiver biases but the reference one (basis
    "receiver") or all (basis "pivot"), then the satellite biases but the pivot (basis "pivot") or all."""

    svs: tuple[str, ...]
    receivers: tuple[str, ...]
    n_ionospheres: int = 1
    basis: str = "receiver"
    reference: str = ""
    n_tec_terms: int = 3
    """TEC parameters per ionosphere: 3 (paper 003's ν_o and gradients) or 6 (second-order field)."""

    def __post_init__(self) -> None:
        if self.basis not in ("receiver", "pivot"):
            raise ModelError(f"basis must be 'receiver' or 'pivot', got {self.basis!r}")
        pool = self.receivers if self.basis == "receiver" else self.svs
        if self.reference not in pool:
            what = "receiver" if self.basis == "receiver" else "pivot satellite"
            raise ModelError(f"reference {what} {self.reference!r} is not one of {', '.join(pool)}")
        if self.n_tec_terms not in (3, 6):
            raise ModelError(f"n_tec_terms must be 3 or 6, got {self.n_tec_terms}")
        if not self.svs or not self.receivers or self.n_ionospheres < 1:
            raise ModelError("the bias model needs satellites, receivers and at least one ionosphere")

    @property
    def n_tec(self) -> int:
        return self.n_tec_terms * self.n_ionospheres

    def receiver_column(self) -> np.ndarray:
        """State column of each receiver's bias (``-1`` for the reference receiver in basis "receiver")."""
        lumped = self.reference if self.basis == "receiver" else None
        return self._columns("_rcol", self.receivers, lumped, self.n_tec)

    def satellite_column(self) -> np.ndarray:
        """State column of each satellite's bias (``-1`` for the pivot in basis "pivot")."""
        lumped = self.reference if self.basis == "pivot" else None
        return self._columns("_scol", self.svs, lumped, self.n_tec + int((self.receiver_column() >= 0).sum()))

    def _columns(self, key: str, names: Sequence[str], lumped: str | None, first: int) -> np.ndarray:
        """Consecutive state columns from ``first`` for ``names``, ``-1`` for the one lumped into the others
        (computed once, a copy returned)."""
        cached = self.__dict__.get(key)
        if cached is None:
            cached = np.full(len(names), -1, np.int64)
            free = [j for j, name in enumerate(names) if name != lumped]
            cached[free] = first + np.arange(len(free))
            object.__setattr__(self, key, cached)
        return np.asarray(cached).copy()

    @property
    def n_states(self) -> int:
        return self.n_tec + len(self.receivers) + len(self.svs) - 1

    def state_names(self) -> list[str]:
        names: list[str] = []
        for g in range(self.n_ionospheres):
            pre = "" if self.n_ionospheres == 1 else f"{self.receivers[g]}:"
            names += [pre + t for t in (TEC_NAMES if self.n_tec_terms == 3 else TEC_NAMES_QUADRATIC)]
        names += [f"rx_gf_m:{r}" for r, c in zip(self.receivers, self.receiver_column(), strict=True) if c >= 0]
        return names + [f"sat_gf_m:{s}" for s, c in zip(self.svs, self.satellite_column(), strict=True) if c >= 0]


def bias_dynamics(
    layout: BiasStateLayout,
    interval_s: float | np.ndarray,
    *,
    vtec_std_m_per_sqrt_s: float = TEC_RW_M_PER_SQRT_S,
    gradient_std_m_per_rad_sqrt_s: float = 5.0 * TEC_RW_M_PER_SQRT_S,
) -> DynamicModel:
    """Paper 003 eq. (53) for this layout: random walk on the TEC parameters, constant receiver and satellite
    biases — the form of :func:`~distnav.models.gnss.ionosphere.ionosphere_dynamics`, but by default 10× its
    random walk (:data:`TEC_RW_M_PER_SQRT_S`: why)."""
    per = [vtec_std_m_per_sqrt_s, gradient_std_m_per_rad_sqrt_s, gradient_std_m_per_rad_sqrt_s]
    if layout.n_tec_terms == 6:  # curvature [m/rad²]: 5× the gradients' random walk per radian, as they to ν_o
        per += [5.0 * gradient_std_m_per_rad_sqrt_s] * 3
    q2 = np.tile(per, layout.n_ionospheres) ** 2
    H = np.eye(layout.n_states)[:, : layout.n_tec]
    dt = np.asarray(interval_s, dtype=float)
    if dt.ndim == 0:
        if not (np.isfinite(dt) and dt > 0):
            raise ModelError(f"the sampling interval must be positive, got {interval_s} s")
        return DynamicModel(layout.n_states, noise_map=H, noise_reduced_cov=np.diag(q2 * float(dt)))
    steps = dt[1:]
    if not np.all(np.isfinite(steps) & (steps > 0)):
        raise ModelError("epoch intervals must be positive (epochs sorted, no duplicates)")
    dts = np.concatenate([[steps[0] if steps.size else 1.0], steps])
    return DynamicModel(layout.n_states, noise_map=[H] * dt.size, noise_reduced_cov=[np.diag(q2 * d) for d in dts])


class BiasGeometryFreeSeries(SeriesArrays):
    """Per-node, per-epoch normals ``N = Āᵀ W Ā``, ``r = Āᵀ W y`` of the undifferenced model (module doc) with
    design rows ``Ā = [a_s (node's TEC block), e_{col(i)}, e_{col(s)}]`` and weights ``w = 1/σ²``.

    Inputs over (T epochs, n nodes, S satellites) as for :class:`~distnav.models.gnss.ionosphere.
    GeometryFreeSeries`: ``coefficients`` (T, n, S, 3), ``sigma_m`` (T, n, S), ``obs_m`` (T, n, S) (NaN = not
    observed), ``tracked`` (T, n, S), ``groups`` (n,).
    """

    layout: BiasStateLayout

    def _usable(self, a: np.ndarray, ok: np.ndarray) -> np.ndarray:
        """Every tracked observation, on the layout's receivers and satellites."""
        _, n, S, _ = a.shape
        if S != len(self.layout.svs) or n != len(self.layout.receivers):
            raise ModelError(
                f"coefficients for {n} receivers × {S} satellites, the layout has "
                f"{len(self.layout.receivers)} × {len(self.layout.svs)}"
            )
        return ok

    def _setup(self) -> None:
        layout, n, S = self.layout, self.n_nodes, self.n_satellites
        self._rcol = layout.receiver_column()
        self._scol = layout.satellite_column()
        self._last_design: tuple[tuple[int, bytes], np.ndarray, np.ndarray] | None = None
        self._epoch_cache: tuple[int, np.ndarray, np.ndarray] | None = None
        self._normals_block: tuple[bytes, int, np.ndarray, np.ndarray] | None = None
        self._static = np.zeros((n, S, layout.n_states))
        for i in range(n):
            if self._rcol[i] >= 0:
                self._static[i, :, self._rcol[i]] = 1.0
        sv = np.flatnonzero(self._scol >= 0)
        self._static[:, sv, self._scol[sv]] = 1.0

    def design(self, epoch: int, nodes: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Design rows ``Ā`` (k, S, p) and weights ``w`` (k, S) (zero where not tracked)."""
        t = self._epoch(epoch)
        idx = self._nodes(nodes)
        key = (t, idx.tobytes())
        if self._last_design is not None and self._last_design[0] == key:
            return self._last_design[1], self._last_design[2]
        if idx.size == self.n_nodes and np.array_equal(idx, np.arange(self.n_nodes)):
            A, w = self._epoch_design(t)
        elif self._epoch_cache is not None and self._epoch_cache[0] == t:
            A, w = self._epoch_cache[1][idx], self._epoch_cache[2][idx]
        else:  # a single-receiver filter's rows: only its nodes'
            A, w = self._rows_design(t, idx), self._w[t][idx]
        self._last_design = (key, A, w)  # the filter and the residual statistics ask twice per epoch
        return A, w

    def _epoch_design(self, t: int) -> tuple[np.ndarray, np.ndarray]:
        """All nodes' design rows and weights at epoch ``t`` (cached for the last epoch asked: the CKF's nodes
        and the residual statistics of each node ask for their rows of the same epoch)."""
        if self._epoch_cache is not None and self._epoch_cache[0] == t:
            return self._epoch_cache[1], self._epoch_cache[2]
        A = self._rows_design(t, np.arange(self.n_nodes))
        self._epoch_cache = (t, A, self._w[t])
        return A, self._w[t]

    def _rows_design(self, t: int, idx: np.ndarray) -> np.ndarray:
        """The design rows of nodes ``idx`` at epoch ``t``: the constant receiver and satellite columns and each
        node's TEC block (``nt`` contiguous columns), zero on the satellites it does not track."""
        tracked = (self._w[t][idx] > 0)[..., None]
        A: np.ndarray = self._static[idx] * tracked
        nt = self.layout.n_tec_terms
        a = self._a[t]
        for j, i in enumerate(idx.tolist()):
            g = int(self._groups[i])
            A[j, :, nt * g : nt * (g + 1)] = a[i] * tracked[j]
        return A

    def normals(self, epoch: int, nodes: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Every node's ``N = Āᵀ W Ā``, ``r = Āᵀ W y`` at ``epoch`` (k, p, p), (k, p): computed for
        :data:`NORMALS_BLOCK` epochs of these nodes at once (the filters walk the epochs in order) and handed out
        as read-only views."""
        t, idx = self._epoch(epoch), self._nodes(nodes)
        key = idx.tobytes()
        blk = self._normals_block
        if blk is None or blk[0] != key or not blk[1] <= t < blk[1] + blk[2].shape[0]:
            blk = self._normals_block = (key, t, *self._block_normals(t, idx))
        return blk[2][t - blk[1]], blk[3][t - blk[1]]

    def _block_normals(self, t0: int, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The normals of the nodes ``idx`` at epochs ``t0 … t0 + NORMALS_BLOCK − 1`` (B, k, p, p), (B, k, p): the
        design rows of :meth:`_epoch_design` for the block in one array, then one batched product."""
        A, w = self.design_block(np.arange(t0, min(t0 + NORMALS_BLOCK, self.n_epochs)), idx)
        ts = np.arange(t0, min(t0 + NORMALS_BLOCK, self.n_epochs))
        Aw = A * w[..., None]
        N = Aw.swapaxes(-1, -2) @ A
        r = np.zeros(N.shape[:-1]) if self._y is None else np.einsum("bksp,bks->bkp", Aw, self._y[ts][:, idx])
        N.flags.writeable = r.flags.writeable = False  # handed out as views: a caller copies before changing them
        return N, r

    def design_block(self, epochs: np.ndarray, nodes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`design` of the nodes ``nodes`` at several ``epochs`` in one array each: ``(B, k, S, p)``,
        ``(B, k, S)`` (the normals of a block and the filter outputs' predicted residuals)."""
        ts = np.asarray(epochs, np.int64)
        idx = np.asarray(nodes, np.int64)
        nt = self.layout.n_tec_terms
        A = self._static[idx][None].repeat(ts.size, axis=0)
        for j, i in enumerate(idx.tolist()):
            g = int(self._groups[i])
            A[:, j, :, nt * g : nt * (g + 1)] = self._a[ts, i]
        w = self._w[ts][:, idx]
        A *= (w > 0)[..., None]
        return A, w

    def records(self, epoch: int, nodes: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Per node and satellite the observation (m) and its weight ``1/σ²`` (0: not tracked), (k, S) each: the
        20-byte records (value, weight, satellite) of the CKF's relay transport."""
        t, idx = self._epoch(epoch), self._nodes(nodes)
        y = np.zeros((idx.size, self.n_satellites)) if self._y is None else self._y[t, idx].copy()
        return y, self._w[t, idx].copy()

    def record_slots(self, epoch: int, nodes: np.ndarray | None = None) -> np.ndarray:
        """The satellite of each row of :meth:`observations` (node-major, satellites ascending: the tracked ones)."""
        _, slot = np.nonzero(self._w[self._epoch(epoch), self._nodes(nodes)] > 0)
        return slot.astype(np.int64)

    def normals_from_records(
        self, epoch: int, node: int, values: np.ndarray, weights: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """``node``'s normals from its records alone: the design rows follow from the geometry (orbits and the
        station's position), the weights and values from the records."""
        N, r = self.normals_from_records_of(epoch, np.array([int(node)]), np.asarray(values)[None], weights[None])
        return N[0], r[0]

    def normals_from_records_of(
        self, epoch: int, nodes: np.ndarray, values: np.ndarray, weights: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`normals_from_records` of several nodes in one batched product, ``(k, p, p)``, ``(k, p)``."""
        A_all, _ = self._epoch_design(self._epoch(epoch))
        w = np.asarray(weights, float)
        A = A_all[np.asarray(nodes, np.int64)] * (w > 0)[..., None]
        return _weighted_normals(A, w, None if self._y is None else np.asarray(values, float))

    def observations(self, epoch: int, nodes: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Whitened rows ``W^{1/2} Ā``, ``W^{1/2} y`` and their node of the tracked observations."""
        A, w = self.design(epoch, nodes)
        idx = self._nodes(nodes)
        y = np.zeros(w.shape) if self._y is None else self._y[self._epoch(epoch), idx]
        keep = w > 0
        sq = np.sqrt(w)
        node = np.broadcast_to(idx[:, None], w.shape)[keep]
        return (A * sq[..., None])[keep], (y * sq)[keep], node.astype(np.int64)


def _weighted_normals(A: np.ndarray, w: np.ndarray, y: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """``N = Āᵀ W Ā`` (k, p, p) and ``r = Āᵀ W y`` (k, p; zeros without observations) of design rows ``A`` (k, S, p)."""
    Aw = A * w[..., None]
    N = Aw.swapaxes(1, 2) @ A
    if y is None:
        return N, np.zeros(N.shape[:2])
    return N, np.einsum("ksp,ks->kp", Aw, y)


def datum_transform(
    layout: BiasStateLayout,
    datum: str,
    *,
    estimable: np.ndarray | None = None,
    pivot: str | None = None,
    reference: str | None = None,
    mean_over: Sequence[str] | None = None,
) -> np.ndarray:
    """The S-transformation ``T`` (n + S, p) from the state to ``[b̃_receivers (n), b̃^s (S)]`` in ``datum``.

    ``datum``: ``"zero-mean"`` (mean of the satellites in ``mean_over`` — default: those ``estimable`` — is zero),
    ``"pivot"`` (``b̃^{pivot} = 0``), ``"receiver"`` (``b̃_{reference} = 0``). ``estimable`` (p,) marks the state
    entries with finite estimates (default all). Rows of inestimable outputs are NaN.
    """
    if datum not in DATUMS:
        raise ModelError(f"datum must be one of {', '.join(DATUMS)}, got {datum!r}")
    n, S, p = len(layout.receivers), len(layout.svs), layout.n_states
    est = np.ones(p, bool) if estimable is None else np.asarray(estimable, bool)
    rcol, scol = layout.receiver_column(), layout.satellite_column()
    # the state's own S-basis: rows give b_j (receivers) and b^s (satellites) with the basis object's bias = 0
    B = np.zeros((n + S, p))
    ok = np.ones(n + S, bool)
    for j in range(n):
        if rcol[j] >= 0:
            B[j, rcol[j]] = 1.0
            ok[j] = est[rcol[j]]
    for s in range(S):
        if scol[s] >= 0:
            B[n + s, scol[s]] = 1.0
            ok[n + s] = est[scol[s]]
    # a shift c: b_j += c, b^s −= c keeps every observation; choose c by the datum
    sat_ok = ok[n:]
    if datum == "zero-mean":
        members = sat_ok.copy() if mean_over is None else np.isin(np.array(layout.svs), list(mean_over)) & sat_ok
        if not members.any():
            return np.full((n + S, p), np.nan)
        shift = B[n:][members].mean(axis=0)  # c = mean of the satellites → b̃^s = b^s − c
        defined = np.ones(n + S, bool)
    elif datum == "pivot":
        name = pivot or (layout.reference if layout.basis == "pivot" else "")
        if name not in layout.svs:
            raise ModelError(f"pivot satellite {name!r} is not one of the satellites")
        k = layout.svs.index(name)
        shift = B[n + k]
        defined = np.full(n + S, bool(ok[n + k]))
    else:
        name = reference or (layout.reference if layout.basis == "receiver" else "")
        if name not in layout.receivers:
            raise ModelError(f"reference receiver {name!r} is not one of {', '.join(layout.receivers)}")
        k = layout.receivers.index(name)
        shift = -B[k]  # b̃_k = b_k − b_k = 0 → c = −b_k
        defined = np.full(n + S, bool(ok[k]))
    T = B.copy()
    T[:n] += shift
    T[n:] -= shift
    T[~(ok & defined)] = np.nan
    return T


def in_datum(T: np.ndarray, x: np.ndarray, P: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """Values ``T x`` and standard deviations ``sqrt diag(T P Tᵀ)`` (NaN rows of ``T`` give NaN)."""
    bad = ~np.isfinite(T).all(axis=1)
    Tz = np.where(np.isfinite(T), T, 0.0)
    xz = np.where(np.isfinite(x), x, 0.0)
    val = Tz @ xz
    if P is None:
        sd = np.full(val.shape, np.nan)
    else:
        Pz = np.where(np.isfinite(P), P, 0.0)
        sd = np.sqrt(np.maximum(np.einsum("ij,jk,ik->i", Tz, Pz, Tz), 0.0))
    val[bad] = np.nan
    sd[bad] = np.nan
    return val, sd
