"""The per-epoch outputs of the bias filters of :mod:`~distnav.models.gnss.gfnetwork`, computed in blocks.

A :class:`Collector` keeps each epoch's filter state (estimates, estimable entries, covariance) and the epoch's
design rows, and every :data:`BLOCK` epochs computes, for all of them at once, (a) the predicted residuals
``v = y − A x̂_{t−1}`` with ``Q_v = R + A (P_{t−1} + S_t) Aᵀ`` (paper 003 §3, the filter's own innovations: σ̂²,
the lag-1 correlation of the standardized residuals) and (b) the S-transformed DSBs ``T x`` and their σ
``sqrt diag(T P Tᵀ)`` (:func:`~distnav.models.gnss.gfbias.datum_transform`, one ``T`` per estimable pattern).
The same quantities as an epoch-by-epoch computation (equal to rounding: the sums run in another order); the
batching only removes the per-epoch overhead of small numpy calls (issue 14, time target).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from distnav.errors import ModelError
from distnav.models.gnss.datum import datum_offset_ns
from distnav.models.gnss.gfbias import BiasGeometryFreeSeries, BiasStateLayout, datum_transform

__all__ = ["BLOCK", "Collector", "DatumSeries"]

BLOCK = 256
"""Epochs kept before a block is computed (memory: one p×p covariance and the design rows per epoch)."""


@dataclass(frozen=True, eq=False)
class DatumSeries:
    """One filter's per-epoch outputs in the output datum: ``tec`` / ``tec_std`` (T, n_tec) [m],
    ``dsb_ns`` / ``dsb_std_ns`` (T, n + S) DSBs ``C1 − C_b`` [ns] of the receivers then the satellites (formal:
    σ² = 1); ``variance_factor`` σ̂² from the filter's own predicted residuals (``Σ vᵀQ_v⁻¹v / Σ m``, each
    filter on the observations it uses: a local quantity in the CKF too) and the number of them;
    ``lag1_correlation`` ρ of the standardized predicted residuals of the same receiver–satellite pair at
    consecutive epochs and the inflation ``(1 + ρ)/(1 − ρ)`` it implies for the variance of constant parameters.
    ``precision``: a :class:`~distnav.algorithms.result.Precision` of the last epoch's DSBs ``[receivers, satellites]``
    [ns²] in the output datum (one block: the filter's own state), ``variance_factor`` = σ̂²·(1 + ρ)/(1 − ρ) so that
    ``precision.std(a_posteriori=True)`` is the realistic σ (a departure from the plain σ̂² of the payload: the
    AR(1) inflation is folded in), ``redundancy`` = predicted residuals − states — with levelled arcs both are the
    arcs' (``arc_variance_factor`` σ̂²_arc, :mod:`~distnav.models.gnss.arcprecision`); ``None`` for the CKF (its
    covariance comes from the Fig. 7 recursion of one node's view, not a centralized one)."""

    label: str
    tec: np.ndarray
    tec_std: np.ndarray
    dsb_ns: np.ndarray
    dsb_std_ns: np.ndarray
    variance_factor: float | None = None
    n_innovations: int = 0
    lag1_correlation: float = 0.0
    correlation_inflation: float = 1.0
    precision: Any = None
    innovation_tests: Any = None
    arc_variance_factor: float | None = None
    between_station: Any = None
    """The between-station test of the network's single-receiver solutions
    (:class:`~distnav.models.gnss.stationcheck.BetweenStationTest`), when it ran."""
    extra_variance_ns2: np.ndarray | None = None
    """(n + S,) variance [ns²] added to the last epoch's realistic variance: what raises it to the floor of the
    between-station test (:func:`~distnav.models.gnss.stationcheck.variance_floor`) and, for one station, the
    ionosphere model's spread (:mod:`~distnav.models.gnss.modelspread`); None: none."""

    @property
    def realistic_factor(self) -> float:
        """The formal σ times this is the realistic σ (before :attr:`extra_variance_ns2`): ``√σ̂²_arc`` (the arcs'
        variance factor, :mod:`~distnav.models.gnss.arcprecision`: the levelling error is common to all epochs of
        an arc) where the filter has one, else ``√(σ̂² (1 + ρ)/(1 − ρ))`` (the misfit and the epoch-to-epoch
        correlation ``ρ`` of the standardized predicted residuals: variance of a mean of AR(1) errors)."""
        if self.arc_variance_factor is not None:
            return float(np.sqrt(self.arc_variance_factor))
        return float(np.sqrt((self.variance_factor or 1.0) * self.correlation_inflation))

    def realistic_std_ns(self) -> np.ndarray:
        """(n + S,) the last epoch's realistic σ [ns]: formal σ × :attr:`realistic_factor`, with the
        :attr:`extra_variance_ns2` added (the between-station floor)."""
        sd: np.ndarray = self.dsb_std_ns[-1] * self.realistic_factor
        if self.extra_variance_ns2 is None:
            return sd
        out: np.ndarray = np.sqrt(sd**2 + self.extra_variance_ns2)
        return out


@dataclass(frozen=True, eq=False)
class _DatumRows:
    """An S-transformation prepared once per estimable pattern: ``T`` with NaN rows zeroed, and those rows."""

    T: np.ndarray
    Tz: np.ndarray
    bad: np.ndarray
    offset_ns: np.ndarray | None = None

    @classmethod
    def of(cls, T: np.ndarray, offset_ns: np.ndarray | None = None) -> _DatumRows:
        return cls(T, np.where(np.isfinite(T), T, 0.0), ~np.isfinite(T).all(axis=1), offset_ns)


class Collector:
    """One filter's outputs (:class:`DatumSeries`) from its states, fed epoch by epoch with :meth:`step`.

    ``series`` / ``nodes``: the measurements the filter uses (its basis and its nodes: the predicted residuals are
    those of these nodes' observations, jointly — they share the state); ``datum`` / ``pivot`` / ``reference``:
    the output datum; ``scale``: metres of geometry-free code per ns of DSB. ``datum_satellites``: the fixed set
    the zero-mean datum runs over (default: the satellites estimable at the epoch); ``datum_reference_ns``: a
    reference product's DSBs of its members, which puts the estimates in the product's datum
    (:mod:`distnav.models.gnss.datum`).
    """

    def __init__(
        self,
        label: str,
        n_epochs: int,
        layout: BiasStateLayout,
        series: BiasGeometryFreeSeries,
        nodes: np.ndarray,
        dynamics: Any,
        *,
        datum: str,
        pivot: str | None,
        reference: str | None,
        scale: float,
        datum_satellites: Sequence[str] | None = None,
        datum_reference_ns: Mapping[str, float] | None = None,
    ) -> None:
        self.mean_over = None if datum_satellites is None else tuple(datum_satellites)
        self.fill_ns = datum_reference_ns
        self.label, self.layout, self.series, self.dynamics = label, layout, series, dynamics
        self.nodes = np.asarray(nodes, np.int64)
        self.datum, self.pivot, self.reference, self.scale = datum, pivot, reference, scale
        nt, q = layout.n_tec, len(layout.receivers) + len(layout.svs)
        self.ssr = self.zz = self.zlag = 0.0
        self.m = 0
        self._buf: list[tuple[int, np.ndarray, np.ndarray, np.ndarray | None]] = []
        self._prev: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None  # x, est, P of the last state with P
        self._z_last: tuple[int, np.ndarray] | None = None  # epoch and standardized residuals (NaN: none)
        self._rows: dict[bytes, _DatumRows | None] = {}
        self.last: tuple[np.ndarray, np.ndarray] | None = None  # T, P of the last epoch with both
        self.n_states = 0
        self.tec = np.full((n_epochs, nt), np.nan)
        self.tec_std = np.full((n_epochs, nt), np.nan)
        self.dsb = np.full((n_epochs, q), np.nan)
        self.dsb_std = np.full((n_epochs, q), np.nan)

    def step(self, t: int, x: np.ndarray, est: np.ndarray, P: np.ndarray | None) -> None:
        """The filter's state after the measurement update of epoch ``t``, kept as given, not copied: the filters
        of :mod:`~distnav.models.gnss.gfnetwork` hand out new arrays every epoch (a caller that reuses its arrays
        must pass copies)."""
        self._buf.append((t, x, est, P))
        if len(self._buf) >= BLOCK:
            self._flush()

    def _flush(self) -> None:
        buf, self._buf = self._buf, []
        if not buf:
            return
        # the states with P, the last one before the block first: stacked once for both computations
        head: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = [] if self._prev is None else [self._prev]
        states = head + [(b[1], b[2], b[3]) for b in buf if b[3] is not None]
        prev_row: list[int] = []  # each epoch's previous state with P: its row in `states` (-1: none)
        row = len(head) - 1
        for t, _, _, P in buf:
            prev_row.append(row if t > 0 else -1)
            if P is not None:
                row += 1
        if states:
            self._prev = states[-1]
        stacked = tuple(np.stack([st[i] for st in states]) for i in range(3)) if states else None
        self._innovations(buf, prev_row, stacked)
        self._outputs(buf, None if stacked is None else stacked[2][len(head) :])

    def _innovations(self, buf: list[Any], prev_row: list[int], stacked: tuple[np.ndarray, ...] | None) -> None:
        """Accumulate the predicted residuals of the block's epochs over the observations whose parameters were
        all estimable before the epoch (``P⁻ = P_{t−1} + S_t``), and their lag-1 products; ``prev_row``: each
        epoch's previous state with P, a row of ``stacked`` (x, estimable, P), or -1."""
        ts = np.array([b[0] for b in buf], np.int64)
        jj = [j for j, r in enumerate(prev_row) if r >= 0]
        kS = self.nodes.size * self.series.n_satellites
        Z = np.full((len(buf), kS), np.nan)
        if jj:
            t_in = ts[jj]
            A, w = self.series.design_block(t_in, self.nodes)  # the design rows of these epochs in one array
            A, w = A.reshape(len(jj), kS, -1), w.reshape(len(jj), kS)
            ser = self.series
            y = np.zeros(w.shape) if ser._y is None else ser._y[t_in][:, self.nodes].reshape(len(jj), kS)
            assert stacked is not None
            rows_in = [prev_row[j] for j in jj]
            if rows_in == list(range(rows_in[0], rows_in[0] + len(rows_in))):  # consecutive: views, no copies
                xp, ep, Pp = (a[rows_in[0] : rows_in[0] + len(rows_in)] for a in stacked)
            else:
                xp, ep, Pp = (a[rows_in] for a in stacked)
            every = bool(ep.all())  # every entry estimable before every epoch (most blocks): no masks needed
            # the rows with no coefficient on an inestimable entry
            rows = (w > 0) if every else (w > 0) & ~((A != 0) & ~ep[:, None, :]).any(axis=2)
            M = int(rows.sum(axis=1).max())
            if M:
                order = np.argsort(~rows, axis=1, kind="stable")[:, :M]  # each epoch's rows first, padded
                kept = np.take_along_axis(rows, order, axis=1)
                Ar = np.take_along_axis(A, order[..., None], axis=1) * kept[..., None]
                wr = np.take_along_axis(w, order, axis=1)
                yr = np.take_along_axis(y, order, axis=1)
                Sn = self.dynamics.noise_cov_block(t_in)
                Pm = Pp + Sn if every else np.where(ep[:, :, None] & ep[:, None, :], Pp + Sn, 0.0)
                v = np.where(kept, yr - (Ar @ (xp if every else np.where(ep, xp, 0.0))[..., None])[..., 0], 0.0)
                Qv = Ar @ Pm @ Ar.swapaxes(1, 2)
                dq = np.arange(M)
                Qv[:, dq, dq] += np.where(kept, 1.0 / np.where(kept, wr, 1.0), 1.0)  # R + A P⁻ Aᵀ (padding: 1)
                self.ssr += float((v * np.linalg.solve(Qv, v[..., None])[..., 0]).sum())
                self.m += int(kept.sum())
                z = np.where(kept, v / np.sqrt(Qv[:, dq, dq]), np.nan)
                Zi = np.full((len(jj), kS), np.nan)
                np.put_along_axis(Zi, order, z, axis=1)  # padding rows write NaN onto unused rows
                Z[jj] = Zi
        zf = np.where(np.isnan(Z), 0.0, Z)
        self.zz += float((zf * zf).sum())
        if self._z_last is not None:
            t_all = np.concatenate([[self._z_last[0]], ts])
            Zp = np.concatenate([np.where(np.isnan(self._z_last[1]), 0.0, self._z_last[1])[None], zf])
        else:
            t_all, Zp = ts, zf
        follows = np.diff(t_all) == 1  # the same pair at consecutive epochs
        self.zlag += float((Zp[1:][follows] * Zp[:-1][follows]).sum())
        self._z_last = (int(ts[-1]), Z[-1])

    def _outputs(self, buf: list[Any], Ps: np.ndarray | None) -> None:
        """TEC and their σ; DSBs ``T x`` and σ ``sqrt diag(T P Tᵀ)`` in the output datum (NaN rows of ``T``: NaN)."""
        nt = self.layout.n_tec
        ts = np.array([b[0] for b in buf], np.int64)
        X = np.stack([b[1] for b in buf])
        E = np.stack([b[2] for b in buf])
        self.tec[ts] = np.where(E[:, :nt], X[:, :nt], np.nan)
        hasP = np.array([b[3] is not None for b in buf])  # Ps: the P of these epochs, stacked by _flush
        at = np.cumsum(hasP) - 1  # epoch j's row in Ps (where hasP)
        if hasP.any():
            assert Ps is not None
            d = Ps.diagonal(axis1=1, axis2=2)
            self.tec_std[ts[hasP]] = np.where(E[hasP, :nt], np.sqrt(np.maximum(d[:, :nt], 0.0)), np.nan)
        groups: dict[bytes, list[int]] = {}
        for j, b in enumerate(buf):
            groups.setdefault(b[2].tobytes(), []).append(j)
        last_j, last_rows = -1, None
        Xz = np.where(np.isfinite(X), X, 0.0)
        for key, js in groups.items():
            if key not in self._rows:
                try:
                    T = datum_transform(
                        self.layout,
                        self.datum,
                        estimable=E[js[0]],
                        pivot=self.pivot,
                        reference=self.reference,
                        mean_over=self.mean_over,
                    )
                except ModelError:  # e.g. the pivot not estimable yet: no DSBs at these epochs
                    self._rows[key] = None
                else:
                    off = None
                    if self.fill_ns is not None and self.mean_over is not None:
                        off = datum_offset_ns(self.layout, E[js[0]], self.mean_over, self.fill_ns)
                    self._rows[key] = _DatumRows.of(T, off)
            rows = self._rows[key]
            if rows is None:
                continue
            val = Xz[js] @ rows.Tz.T
            sd = np.full(val.shape, np.nan)
            withP = [j for j in js if hasP[j]]
            if withP:
                assert Ps is not None
                Pz = Ps if len(withP) == Ps.shape[0] else Ps[at[withP]]  # (not changed below: np.where copies)
                if not np.isfinite(Pz).all():  # (else the same numbers without a copy)
                    Pz = np.where(np.isfinite(Pz), Pz, 0.0)
                sd[hasP[js]] = np.sqrt(np.maximum(((rows.Tz @ Pz) * rows.Tz).sum(axis=2), 0.0))  # diag(T P Tᵀ)
                if withP[-1] > last_j:
                    last_j, last_rows = withP[-1], rows
            val[:, rows.bad] = np.nan
            sd[:, rows.bad] = np.nan
            self.dsb[ts[js]] = -val / self.scale + (0.0 if rows.offset_ns is None else rows.offset_ns)
            self.dsb_std[ts[js]] = sd / self.scale
        if last_rows is not None:
            P_last = buf[last_j][3]
            assert P_last is not None
            self.last = (last_rows.T, P_last)
            self.n_states = self.layout.n_states

    def done(self) -> DatumSeries:
        from distnav.algorithms.statistics import variance_factor

        self._flush()
        vf = variance_factor(self.ssr, self.m) if self.m else None
        rho = min(max(self.zlag / self.zz, 0.0), 0.999) if self.zz > 0 else 0.0
        precision = None
        if self.last is not None:
            from distnav.algorithms.result import Precision

            T, P = self.last
            bad = ~np.isfinite(T).all(axis=1)
            Tz = np.where(np.isfinite(T), T, 0.0)
            cov = Tz @ np.where(np.isfinite(P), P, 0.0) @ Tz.T / self.scale**2
            cov[bad] = np.nan
            cov[:, bad] = np.nan
            inflation = (1.0 + rho) / (1.0 - rho)
            precision = Precision(
                covariance=cov[None],
                variance_factor=None if vf is None else vf * inflation,
                redundancy=float(self.m - self.n_states),
                kind="centralized",
            )
        return DatumSeries(
            self.label,
            self.tec,
            self.tec_std,
            self.dsb,
            self.dsb_std,
            vf,
            self.m,
            rho,
            (1.0 + rho) / (1.0 - rho),
            precision,
        )
