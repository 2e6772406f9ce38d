"""Carrier-to-code levelling of the geometry-free code per continuous arc, cycle-slip detection, arc screening.

Per receiver and satellite, with code ``P_1, P_b`` and phase ``Φ_1, Φ_b`` (metres) on L1 and band ``b``:

* geometry-free code  ``g_P = (P_b − P_1)/(μ_b − 1) = I + (code biases) + noise`` (decimetres, multipath);
* geometry-free phase ``g_Φ = (Φ_1 − Φ_b)/(μ_b − 1) = I + (ambiguities, phase biases)`` (millimetres),
  constant offset per continuous arc;
* levelled code ``ḡ = g_Φ + ⟨g_P − g_Φ⟩_arc``: the phase's precision, the code's level.

Arcs end at a data gap longer than ``max_gap_s``, a loss-of-lock indicator (bit 0), or a cycle slip:

* geometry-free phase: ``|g_Φ,k − (2g_Φ,k−1 − g_Φ,k−2)| > max(gf_threshold_m, gf_sigmas·s)`` (a linear
  ionosphere predicted over the two previous epochs; 0.05 m catches the L1 = L2 one-cycle slip of 0.083 m on L2,
  0.071 m on L5; ``s`` the RMS of the satellite's recent prediction errors, so that ionospheric irregularities
  at low elevation, several cm per 30 s, do not cut the arcs every few minutes — a slip smaller than 4·s with
  equal cycles on both bands goes unseen there, one with unequal cycles still changes the wide-lane);
* Melbourne–Wübbena wide-lane ``N_w = (Φ_1/λ_1 − Φ_b/λ_b) − (f_1P_1 + f_bP_b)/((f_1 + f_b)λ_w)`` [cycles]:
  a jump of more than ``max(mw_sigmas × σ, mw_min_cycles)`` from the arc's running mean, confirmed by the next
  epoch (an unconfirmed jump is an outlier of one epoch and is removed instead).

Arcs shorter than ``min_arc_epochs`` are dropped (their offset would carry the code noise of a few epochs).
Screening (quality control on the station's own data): within an arc the model ``g_P − g_Φ = offset + e`` with
``σ_k`` of the geometry-free code is tested observation by observation (w-test of
:func:`distnav.algorithms.statistics.w_statistics`, critical value :func:`~distnav.algorithms.statistics.
critical_value`), the largest rejected one removed and the offset re-estimated until none is rejected — Baarda's
iterative data snooping for a one-parameter model, the same as :func:`~distnav.algorithms.statistics.
data_snooping` (a test compares them). The test uses the arc's own a-posteriori σ̂ (variance factor of the arc)
with ``scale="arc"`` since real multipath makes the a-priori σ of the code only approximate.

The levelling error is common to an arc: the levelled observations are given the code's σ (not the phase's) so
that an arc's total information on its level equals that of its code (Σ 1/σ² over the arc).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from distnav._checks import check_field_types
from distnav.algorithms.result import ObservationTests
from distnav.algorithms.statistics import critical_value, w_statistics
from distnav.errors import ModelError
from distnav.models.gnss.constants import C_M_S, GPS_FREQUENCIES_HZ

__all__ = [
    "ArcStatistics",
    "band_frequencies_hz",
    "LevelledStation",
    "LevellingOptions",
    "geometry_free_phase_m",
    "melbourne_wubbena_cycles",
    "find_arcs",
    "level_station",
    "screen_arc",
    "station_sigma_factors",
]


@dataclass(frozen=True)
class ArcStatistics:
    """One continuous arc: satellite, first/last epoch index, epochs, why it started, offset (m) and its σ,
    RMS of code minus levelled phase after screening [m], and every removal by reason: ``removed`` by the
    screening's w-tests, ``removed_mw`` one-epoch Melbourne–Wübbena outliers within the arc's span, and
    ``dropped_short`` (the arc's epochs, when the whole arc was shorter than the minimum and dropped; then no
    offset: NaN)."""

    sv: str
    first: int
    last: int
    n_epochs: int
    start_reason: str
    offset_m: float
    offset_std_m: float
    code_rms_m: float
    removed: int
    removed_mw: int = 0
    dropped_short: int = 0


@dataclass(frozen=True, eq=False)
class LevelledStation:
    """Levelled geometry-free code ``gf_m`` (T, S) (NaN outside kept arcs), ``arc`` (T, S) arc index (−1 none),
    ``arcs`` their statistics, ``removed`` (T, S) True where the screening removed the code, counts of arc
    starts by reason; ``tests`` the station's w-tests (:class:`~distnav.algorithms.result.ObservationTests`, owner
    ``node``; ``removed`` indexes the tested observations in (epoch, satellite) order; computed by the station on
    its own data: no messages); ``fit_wss`` / ``fit_n`` (S,) per satellite the sum of squared weighted residuals
    ``((g_P − g_Φ − offset)/σ)²`` of the kept levelled observations and their number — the code's misfit within
    the arcs, where an elevation-dependent code bias (SVN49) shows and which the levelled code hides."""

    gf_m: np.ndarray
    arc: np.ndarray
    arcs: list[ArcStatistics]
    removed: np.ndarray
    starts: dict[str, int]
    dropped_short: int
    tests: ObservationTests | None = None
    fit_wss: np.ndarray | None = None
    fit_n: np.ndarray | None = None
    mw_outlier: np.ndarray | None = None
    short_arcs: list[ArcStatistics] | None = None
    """The arcs dropped as too short (their epochs counted in ``dropped_short``), for ``arcs.csv``."""

    def arc_summary(self) -> dict[str, Any]:
        """Counts of arcs, starts by reason, short arcs dropped, median arc length and code RMS, and the raw
        (unlevelled) code observations kept where no arc was long enough (``fallback_raw``)."""
        n = np.array([a.n_epochs for a in self.arcs])
        rms = np.array([a.code_rms_m for a in self.arcs])
        return {
            "arcs": len(self.arcs),
            "starts": self.starts,
            "dropped_short": self.dropped_short,
            "median_epochs": float(np.median(n)) if n.size else 0.0,
            "median_code_rms_m": float(np.median(rms)) if rms.size else float("nan"),
            "removed_by_screening": int(self.removed.sum()),
            "raw_code_observations": int(((self.arc < 0) & np.isfinite(self.gf_m)).sum()),
        }

    def screening_summary(self, svs: Sequence[str], times: np.ndarray | None = None) -> dict[str, Any]:
        """What the station's own screening removed (per satellite; with ``times`` (T,) the epochs of the rows,
        also per epoch: ``removed_epochs`` {ISO time: satellites}, and the epoch with most removals, where a
        receiver problem of one epoch shows) and its w-test summary."""
        per_sat: dict[str, int] = {}
        rows, cols = np.nonzero(self.removed)
        for s in cols.tolist():
            per_sat[svs[s]] = per_sat.get(svs[s], 0) + 1
        per_epoch: dict[str, list[str]] = {}
        if times is not None and len(times) == self.removed.shape[0]:
            for r, s in zip(rows.tolist(), cols.tolist(), strict=True):
                per_epoch.setdefault(str(np.datetime64(times[r], "s")), []).append(svs[s])
        tests = self.tests.summary() if self.tests is not None else {}
        tests.pop("removed", None)
        mw = int(self.mw_outlier.sum()) if self.mw_outlier is not None else 0
        w_tested = int(np.isfinite(self.tests.w).sum()) if self.tests is not None else 0
        return {
            "tested": int(self.tests.w.size) if self.tests is not None else 0,
            "removed": int(self.removed.sum()),
            "removed_per_satellite": per_sat,
            **(
                {
                    "removed_epochs": per_epoch,
                    "epochs_with_removals": len(per_epoch),
                    "most_removed_epoch": max(per_epoch, key=lambda k: (len(per_epoch[k]), k)) if per_epoch else None,
                }
                if times is not None
                else {}
            ),
            "w_tested": w_tested,
            "removed_w_test": int(self.removed.sum()) - mw,
            "removed_mw_outliers": mw,
            **tests,
        }


GF_SIGMAS = 4.0
"""Multiple of the recent RMS GF prediction error above which the geometry-free test flags a slip (when larger
than ``gf_threshold_m``): ionospheric irregularities make the prediction error of a low satellite several cm
per 30 s, a fixed 5 cm then cuts arcs every few minutes (docs/gnss.md). 0 = the fixed threshold alone."""
GF_WINDOW_EPOCHS = 40
"""Epochs of the exponentially weighted mean square GF prediction error (20 min at 30 s)."""
GF_MIN_ERRORS = 10
"""A satellite's first prediction errors (slips or not) whose median starts the mean square; the adaptive limit
is used from the third one on (before it: the fixed threshold)."""


def band_frequencies_hz(band: int, frequencies_hz: tuple[Any, Any] | None = None) -> tuple[Any, Any]:
    """``(f_1, f_b)`` [Hz]: the GPS frequencies of L1 and ``band``, or ``frequencies_hz`` — scalars or (S,)
    arrays, one per satellite column (another system's signals, GLONASS FDMA channels), broadcast over epochs."""
    if frequencies_hz is None:
        return GPS_FREQUENCIES_HZ[1], GPS_FREQUENCIES_HZ[band]
    f1, fb = (np.asarray(f, float) for f in frequencies_hz)
    if not (np.all(f1 > 0) and np.all(fb > 0) and np.all(f1 != fb)):
        raise ModelError("levelling: frequencies must be positive and differ between the two signals")
    return f1, fb


def geometry_free_phase_m(
    phi1_m: np.ndarray, phib_m: np.ndarray, band: int = 2, *, frequencies_hz: tuple[Any, Any] | None = None
) -> np.ndarray:
    """``(Φ_1 − Φ_b)/(μ_b − 1)`` [m]: the L1 ionospheric delay plus a constant per arc (``μ_b = (f_1/f_b)²``,
    :func:`band_frequencies_hz`)."""
    f1, fb = band_frequencies_hz(band, frequencies_hz)
    out: np.ndarray = (np.asarray(phi1_m, float) - np.asarray(phib_m, float)) / ((f1 / fb) ** 2 - 1.0)
    return out


def melbourne_wubbena_cycles(
    p1_m: np.ndarray,
    pb_m: np.ndarray,
    phi1_m: np.ndarray,
    phib_m: np.ndarray,
    band: int = 2,
    *,
    frequencies_hz: tuple[Any, Any] | None = None,
) -> np.ndarray:
    """Melbourne–Wübbena wide-lane [cycles of ``λ_w = c/(f_1 − f_b)``]: constant per arc up to code noise."""
    f1, fb = band_frequencies_hz(band, frequencies_hz)
    lw = C_M_S / (f1 - fb)
    l1, lb = C_M_S / f1, C_M_S / fb
    phase_wl = np.asarray(phi1_m, float) / l1 - np.asarray(phib_m, float) / lb
    code_nl = (f1 * np.asarray(p1_m, float) + fb * np.asarray(pb_m, float)) / ((f1 + fb) * lw)
    out: np.ndarray = phase_wl - code_nl
    return out


def find_arcs(
    t_s: np.ndarray,
    gf_phase_m: np.ndarray,
    mw_cycles: np.ndarray,
    lli: np.ndarray | None = None,
    *,
    max_gap_s: float = 90.0,
    gf_threshold_m: float = 0.05,
    mw_sigmas: float = 4.0,
    mw_min_cycles: float = 1.0,
    gf_sigmas: float = GF_SIGMAS,
    gf_window_epochs: int = GF_WINDOW_EPOCHS,
) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """Split one satellite's series into arcs. Returns ``arc`` (T,) (−1 where no data), ``outlier`` (T,) one-epoch
    MW outliers, and the start reason of every arc (``first``, ``gap``, ``lli``, ``gf``, ``mw``).

    The geometry-free test's limit is ``max(gf_threshold_m, gf_sigmas × s)``, ``s`` the RMS of the satellite's
    recent prediction errors (exponentially weighted over ``gf_window_epochs``, slips excluded; module doc);
    ``gf_sigmas`` 0: the fixed threshold alone."""
    arc, outlier, idx, t, g, w, lli_bits, err_at = _scan_inputs(t_s, gf_phase_m, mw_cycles, lli)
    reasons: list[str] = []
    cur = -1
    hist: list[int] = []  # epochs of the current arc
    last_pos = prev_pos = -9  # positions in idx of hist[-1], hist[-2]
    nh = 0  # len(hist); the conditionals below are max() as Python evaluates it (the same floats, fewer calls)
    mw_sum = mw_sq = 0.0
    gf_ms = 0.0  # the satellite's recent mean square GF prediction error (kept across arcs)
    warm: list[float] = []
    lam = 1.0 / max(int(gf_window_epochs), 1)
    for pos, k in enumerate(idx):
        reason = ""
        if cur < 0:
            reason = "first"
        elif t[k] - t[hist[-1]] > max_gap_s:
            reason = "gap"
        elif lli_bits is not None and lli_bits[k]:
            reason = "lli"
        else:
            if nh >= 2:
                if last_pos == pos - 1 and prev_pos == pos - 2:
                    err = err_at[pos]
                else:  # an outlier between: from the arc's last two epochs
                    err = _gf_prediction_error(t, g, k, hist[-1], hist[-2])
                lim_gf = gf_threshold_m
                n_warm = len(warm)
                if gf_sigmas > 0 and n_warm >= 3:
                    s_gf = gf_sigmas * math.sqrt(gf_ms)
                    lim_gf = s_gf if s_gf > gf_threshold_m else gf_threshold_m
                if abs(err) > lim_gf:
                    reason = "gf"
                if n_warm < GF_MIN_ERRORS:  # the first errors, slips or not: a robust start (median)
                    warm.append(err * err)
                    gf_ms = float(np.median(warm)) / 0.455  # median of χ²₁ = 0.455
                elif not reason:
                    gf_ms += lam * (err * err - gf_ms)
            if not reason and nh >= 3:
                m = mw_sum / nh
                var = mw_sq / nh - m * m
                sd = math.sqrt(0.0 if 0.0 > var else var)
                lim = mw_sigmas * sd
                lim = mw_min_cycles if mw_min_cycles > lim else lim
                if abs(w[k] - m) > lim:
                    if not _mw_jump_confirmed(w, idx, pos, m, lim):
                        outlier[k] = True
                        continue
                    reason = "mw"
        if reason:
            cur = len(reasons)
            reasons.append(reason)
            hist = []
            nh = 0
            mw_sum = mw_sq = 0.0
        arc[k] = cur
        hist.append(k)
        prev_pos, last_pos = last_pos, pos
        nh += 1
        mw_sum += w[k]
        mw_sq += w[k] ** 2
    return arc, outlier, reasons


def _scan_inputs(
    t_s: np.ndarray, gf_phase_m: np.ndarray, mw_cycles: np.ndarray, lli: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray, list[int], list[float], list[float], list[float], list[int] | None, list[float]]:
    """:func:`find_arcs`' ``arc`` (−1), ``outlier`` (False) and its scan's inputs: the data epochs (GF, MW finite);
    times, GF, MW and LLI bit 0 as Python floats and ints (the scan is sequential: they round as numpy's float64
    scalars, the same IEEE operations, ``** 2`` through the same ``pow``, at a fraction of the cost); every data
    epoch's :func:`_gf_prediction_error` from the two previous data epochs at once (same operations, same order)."""
    g_arr, w_arr, t_arr = (np.asarray(a, float) for a in (gf_phase_m, mw_cycles, t_s))
    ia = np.flatnonzero(np.isfinite(g_arr) & np.isfinite(w_arr))
    ta, ga = t_arr[ia], g_arr[ia]
    dt_a = ta[1:-1] - ta[:-2]
    pred_a = ga[1:-1] + (ga[1:-1] - ga[:-2]) * (ta[2:] - ta[1:-1]) / np.where(1e-9 > dt_a, 1e-9, dt_a)
    err_at: list[float] = [0.0, 0.0, *(ga[2:] - pred_a).tolist()]
    lli_bits: list[int] | None = None if lli is None else (np.asarray(lli).astype(np.int64) & 1).tolist()
    arc, outlier = np.full(g_arr.size, -1, np.int64), np.zeros(g_arr.size, bool)
    return arc, outlier, ia.tolist(), t_arr.tolist(), g_arr.tolist(), w_arr.tolist(), lli_bits, err_at


def _gf_prediction_error(t: list[float], g: list[float], k: int, k1: int, k2: int) -> float:
    """Epoch ``k``'s GF minus its linear prediction from epochs ``k1`` (the last) and ``k2`` [m] (module doc)."""
    dt = t[k1] - t[k2]
    return g[k] - (g[k1] + (g[k1] - g[k2]) * (t[k] - t[k1]) / (1e-9 if 1e-9 > dt else dt))


def _mw_jump_confirmed(w: list[float], idx: list[int], pos: int, mean: float, lim: float) -> bool:
    """Whether the next data epoch confirms the MW jump at ``idx[pos]`` (a slip; else an outlier of one epoch)."""
    nxt = idx[pos + 1] if pos + 1 < len(idx) else -1
    return nxt >= 0 and abs(w[nxt] - mean) > lim and abs(w[nxt] - w[idx[pos]]) < lim


def screen_arc(
    d_m: np.ndarray, sigma_m: np.ndarray, *, level: float = 0.001, scale: str = "arc", max_fraction: float = 0.2
) -> tuple[np.ndarray, float, float, np.ndarray]:
    """Iterative w-test screening of ``d = g_P − g_Φ = offset + e`` over one arc (module doc).

    Returns (kept mask, offset [m], σ of the offset [m], w of every observation in the final solution — NaN
    for removed ones). ``scale="arc"`` tests with the arc's a-posteriori
    variance factor (robust to a wrong a-priori σ), ``"apriori"`` with ``sigma_m`` as given. At most
    ``max_fraction`` of the arc is removed.
    """
    d = np.asarray(d_m, float)
    s2 = np.asarray(sigma_m, float) ** 2
    if scale not in ("arc", "apriori"):
        raise ModelError(f"scale must be 'arc' or 'apriori', got {scale!r}")
    keep = np.isfinite(d) & np.isfinite(s2) & (s2 > 0)
    k_crit = critical_value(level)
    limit = int(max_fraction * keep.sum())
    w_out = np.full(d.shape, np.nan)
    for _ in range(limit + 1):
        wts = np.where(keep, 1.0 / np.where(keep, s2, 1.0), 0.0)
        sw = wts.sum()
        if sw <= 0 or keep.sum() < 3:
            break
        off = float((wts * np.where(keep, d, 0.0)).sum() / sw)
        e = np.where(keep, d - off, 0.0)
        var_e = np.where(keep, s2 - 1.0 / sw, 0.0)  # Q_ê of a weighted mean: σ_k² − 1/Σw
        factor = 1.0
        if scale == "arc":
            r = keep.sum() - 1
            factor = max(float((wts * e**2).sum() / r), 1e-12) if r > 0 else 1.0
        w_signed = w_statistics(e, var_e * factor)
        w_out = np.where(keep, w_signed, np.nan)
        w = np.where(keep, np.abs(np.nan_to_num(w_signed)), 0.0)
        worst = int(np.argmax(w))
        if w[worst] <= k_crit or (~keep).sum() - (~np.isfinite(d)).sum() >= limit:
            break
        keep[worst] = False
    wts = np.where(keep, 1.0 / np.where(keep, s2, 1.0), 0.0)
    sw = wts.sum()
    if sw <= 0:
        return keep, float("nan"), float("nan"), w_out
    off = float((wts * np.where(keep, d, 0.0)).sum() / sw)
    r = keep.sum() - 1
    s0 = float((wts * np.where(keep, d - off, 0.0) ** 2).sum() / r) if r > 0 and scale == "arc" else 1.0
    return keep, off, float(np.sqrt(s0 / sw)), w_out


@dataclass(frozen=True)
class LevellingOptions:
    """How :func:`level_station` levels and screens one station's code (defaults in brackets).

    ``band`` [2]: the second frequency's RINEX band (2, 5). ``min_arc_epochs`` [10]: shortest arc kept.
    ``max_gap_s`` [None: 3 × the median sampling interval]: a longer gap ends an arc. ``gf_threshold_m`` [0.05] /
    ``gf_sigmas`` [:data:`GF_SIGMAS`]: the geometry-free slip limit of :func:`find_arcs`. ``screen`` [True]: the
    arcs' w-test screening at ``level`` [0.001]. ``fallback_raw`` [False]: epochs outside any kept arc keep the
    raw code (instead of NaN). ``frequencies_hz`` [None: GPS L1 and ``band``]: ``(f_1, f_b)`` [Hz], scalars or
    (S,) arrays per satellite column — the hook for other systems and GLONASS's FDMA channels. Checked once,
    here."""

    band: int = 2
    min_arc_epochs: int = 10
    max_gap_s: float | None = None
    gf_threshold_m: float = 0.05
    gf_sigmas: float = GF_SIGMAS
    screen: bool = True
    level: float = 0.001
    fallback_raw: bool = False
    frequencies_hz: tuple[Any, Any] | None = None

    def __post_init__(self) -> None:
        check_field_types(self, error=ModelError)  # types first, naming the field (issue 29)
        if self.band == 1:
            raise ModelError("levelling: band 1 is the first frequency; the second is 2, 5, …")
        if self.min_arc_epochs < 2:
            raise ModelError(f"levelling: min_arc_epochs must be ≥ 2, got {self.min_arc_epochs}")
        if self.max_gap_s is not None and not self.max_gap_s > 0:
            raise ModelError(f"levelling: max_gap_s must be > 0, got {self.max_gap_s}")
        if not (np.isfinite(self.gf_threshold_m) and self.gf_threshold_m > 0):
            raise ModelError(f"levelling: gf_threshold_m must be a positive number, got {self.gf_threshold_m}")
        if not 0.0 < self.level < 0.5:
            raise ModelError(f"levelling: the test level must lie in (0, 0.5), got {self.level}")


@dataclass
class _Accumulator:
    """What :func:`level_station` collects over the satellites (filled by :func:`_level_satellite`)."""

    out: np.ndarray
    arc_id: np.ndarray
    removed: np.ndarray
    mw_out: np.ndarray
    w_all: np.ndarray
    fit_wss: np.ndarray
    fit_n: np.ndarray
    arcs: list[ArcStatistics]
    starts: dict[str, int]
    dropped: int = 0
    short: list[ArcStatistics] | None = None

    @classmethod
    def empty(cls, T: int, S: int) -> _Accumulator:
        return cls(
            np.full((T, S), np.nan),
            np.full((T, S), -1, np.int64),
            np.zeros((T, S), bool),
            np.zeros((T, S), bool),
            np.full((T, S), np.nan),
            np.zeros(S),
            np.zeros(S, np.int64),
            [],
            {},
            0,
            [],
        )


def level_station(
    t_s: np.ndarray,
    svs: tuple[str, ...],
    p1_m: np.ndarray,
    pb_m: np.ndarray,
    phi1_m: np.ndarray,
    phib_m: np.ndarray,
    *,
    options: LevellingOptions = LevellingOptions(),
    lli: np.ndarray | None = None,
    sigma_m: np.ndarray | None = None,
    node: int = 0,
) -> LevelledStation:
    """Level one station's geometry-free code (T, S) per arc (module doc). ``sigma_m`` (T, S) σ of the code
    ``g_P`` (default 1: equal weights); ``options``: :class:`LevellingOptions`; ``node``: the station's node id in
    the screening's :class:`~distnav.algorithms.result.ObservationTests`.

    Examples
    --------
    >>> import numpy as np
    >>> from distnav.models.gnss.constants import C_M_S, GPS_FREQUENCIES_HZ, mu
    >>> from distnav.models.gnss.levelling import LevellingOptions, level_station
    >>> t = np.arange(60) * 30.0
    >>> iono = 2.0 + 0.001 * t[:, None]
    >>> rho = 2e7 + 100.0 * t[:, None]
    >>> p1, pb = rho + iono, rho + mu(2) * iono
    >>> phi1, phib = rho - iono + 5 * C_M_S / GPS_FREQUENCIES_HZ[1], rho - mu(2) * iono
    >>> lev = level_station(t, ("G01",), p1, pb, phi1, phib, options=LevellingOptions(screen=False))
    >>> len(lev.arcs), bool(np.allclose(lev.gf_m, iono))
    (1, True)
    """
    t = np.asarray(t_s, float)
    if t.ndim != 1 or np.any(np.diff(t) <= 0):
        raise ModelError("epoch times must be one increasing series")
    band, freqs = options.band, options.frequencies_hz
    f1, fb = band_frequencies_hz(band, freqs)
    gp = (np.asarray(pb_m, float) - np.asarray(p1_m, float)) / ((f1 / fb) ** 2 - 1.0)
    gphi = geometry_free_phase_m(phi1_m, phib_m, band, frequencies_hz=freqs)
    mw = melbourne_wubbena_cycles(p1_m, pb_m, phi1_m, phib_m, band, frequencies_hz=freqs)
    sig = np.ones_like(gp) if sigma_m is None else np.asarray(sigma_m, float)
    gap = (
        options.max_gap_s
        if options.max_gap_s is not None
        else 3.0 * float(np.median(np.diff(t)))
        if t.size > 1
        else 90.0
    )
    acc = _Accumulator.empty(*gp.shape)
    for s in range(gp.shape[1]):
        _level_satellite(acc, s, svs[s], t, gp, gphi, mw, sig, lli, gap, options)
    if options.fallback_raw:
        raw = np.isnan(acc.out) & np.isfinite(gp) & ~acc.removed
        acc.out[raw] = gp[raw]
    tested = np.isfinite(acc.w_all) | acc.removed
    k = critical_value(options.level)
    flat_w = acc.w_all[tested]
    tests = ObservationTests(
        node=np.full(flat_w.size, node, np.int64),
        w=flat_w,
        critical_value=k,
        level=options.level,
        flagged=np.abs(np.nan_to_num(flat_w)) > k,
        removed=tuple(np.flatnonzero(acc.removed[tested]).tolist()),
    )
    return LevelledStation(
        acc.out,
        acc.arc_id,
        acc.arcs,
        acc.removed,
        acc.starts,
        acc.dropped,
        tests,
        acc.fit_wss,
        acc.fit_n,
        acc.mw_out,
        acc.short,
    )


def _level_satellite(
    acc: _Accumulator,
    s: int,
    sv: str,
    t: np.ndarray,
    gp: np.ndarray,
    gphi: np.ndarray,
    mw: np.ndarray,
    sig: np.ndarray,
    lli: np.ndarray | None,
    gap: float,
    options: LevellingOptions,
) -> None:
    """One satellite's column: find its arcs, level and screen each kept arc, record it in ``acc``."""
    ok = np.isfinite(gp[:, s]) & np.isfinite(gphi[:, s])
    a, outl, reasons = find_arcs(
        t,
        np.where(ok, gphi[:, s], np.nan),
        np.where(ok, mw[:, s], np.nan),
        None if lli is None else lli[:, s],
        max_gap_s=gap,
        gf_threshold_m=options.gf_threshold_m,
        gf_sigmas=options.gf_sigmas,
    )
    acc.removed[:, s] |= outl
    acc.mw_out[:, s] = outl
    for j, why in enumerate(reasons):
        acc.starts[why] = acc.starts.get(why, 0) + 1
        ep = np.flatnonzero(a == j)
        mw_in = int(outl[ep[0] : ep[-1] + 1].sum()) if ep.size else 0
        if ep.size < options.min_arc_epochs:
            acc.dropped += 1
            if ep.size and acc.short is not None:
                nan = float("nan")
                acc.short.append(
                    ArcStatistics(sv, int(ep[0]), int(ep[-1]), int(ep.size), why, nan, nan, nan, 0, mw_in, int(ep.size))
                )
            continue
        d = gp[ep, s] - gphi[ep, s]
        if options.screen:
            keep, off, off_sd, w_arc = screen_arc(d, sig[ep, s], level=options.level)
            acc.w_all[ep, s] = w_arc
        else:
            keep = np.ones(ep.size, bool)
            wts = 1.0 / sig[ep, s] ** 2
            off = float((wts * d).sum() / wts.sum())
            off_sd = float(np.sqrt(1.0 / wts.sum()))
        acc.removed[ep[~keep], s] = True
        acc.out[ep, s] = gphi[ep, s] + off
        acc.fit_wss[s] += float((((d[keep] - off) / sig[ep, s][keep]) ** 2).sum())
        acc.fit_n[s] += int(keep.sum())
        acc.arc_id[ep, s] = len(acc.arcs)
        acc.arcs.append(
            ArcStatistics(
                sv,
                int(ep[0]),
                int(ep[-1]),
                int(ep.size),
                why,
                off,
                off_sd,
                float(np.sqrt(np.mean((d[keep] - off) ** 2))),
                int((~keep).sum()),
                mw_in,
            )
        )


def station_sigma_factors(levelled: Sequence[LevelledStation]) -> np.ndarray:
    """Relative σ factors of the stations' levelled code (n,): each station's RMS of the weighted code minus
    levelled phase within its arcs, ``√(Σ fit_wss / Σ fit_n)`` (its own code noise and multipath, from its own
    data), over their geometric mean. Stations without levelled arcs get 1; the factors keep the network's
    overall σ (their geometric mean is 1), so only the stations' relative weights change."""
    rms = np.array(
        [
            np.sqrt(float(lev.fit_wss.sum()) / float(lev.fit_n.sum()))
            if lev.fit_wss is not None and lev.fit_n is not None and lev.fit_n.sum() > 0
            else np.nan
            for lev in levelled
        ]
    )
    ok = np.isfinite(rms) & (rms > 0)
    out = np.ones(rms.size)
    if ok.sum() >= 2:
        out[ok] = rms[ok] / np.exp(np.mean(np.log(rms[ok])))
    return out
