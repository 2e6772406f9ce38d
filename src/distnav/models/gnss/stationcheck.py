"""Between-station cross-validation of the realistic σ: do the stations' single-receiver solutions agree within
their stated σ?

Each station's single-receiver filter (``local:STA``, :func:`~distnav.models.gnss.gfnetwork.run_bias_filters`)
estimates the satellite DSBs ``x_i^s`` from its own data only, in its own datum. If the realistic σ
(:mod:`~distnav.models.gnss.arcprecision`) were complete, the model ``x_i^s = t^s + c_i + e_i^s`` (a common value
per satellite, an offset per station for its datum, ``e ~ N(0, (σ_i^s)²)``), fitted by weighted least squares over
the satellites estimated by two or more stations, would leave

    ``χ² = Σ_i Σ_s (ê_i^s / σ_i^s)²``   on   ``m − S − (n − 1)``   degrees of freedom

(``m`` estimates of ``S`` satellites by ``n`` stations; two stations: the pairs' differences about their weighted
mean). On the shared BELE + DGAR day the stations' solutions differ by 1.88× their σ while the same σ cover
the scatter between the day's four 6-h sessions (1.0–1.3×): the σ miss an error that is
constant over a day and differs between stations (the single-layer model's error along each station's own
passes, receiver-dependent code biases; docs/gnss.md, "σ on real data"). Neither the arcs' variance factor nor
the session scatter can see it; only another station can.

When the one-sided χ² test rejects (``level``, default 5 %), each station's unmodelled error is taken as
proportional to its stated σ (one factor ``F = √(χ²/dof)`` for the network): a single-receiver filter's σ grows by
``F``, and every filter's satellite σ gets the floor that the stations' single-receiver solutions, with their σ so
corrected, combine to (:func:`variance_floor`):

    ``σ²_real = max(σ², F² / Σ_i (σ_i^s)⁻²)``   (``σ_i^s`` the single-receiver σ of the stations that estimate ``s``)

— a floor, not an addition: where the network filter's own σ (its arcs' variance factor) already covers the
stations' disagreement, as on the simulated networks, it stays. A departure from paper 003 (formal σ only), stated
in the console and ``summary.json``; receivers' σ are left as they are. ``F`` is estimated from the stations' own
disagreement, never from a reference product; the products are the check (docs/gnss.md). A single station has
no such check (``None``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import special

from distnav.errors import ModelError

__all__ = [
    "MIN_COMMON_SATELLITES",
    "BetweenStationTest",
    "between_station_test",
    "variance_floor",
]

MIN_COMMON_SATELLITES = 5
"""Fewest satellites two stations must both estimate for their pair to enter the test."""


@dataclass(frozen=True)
class BetweenStationTest:
    """The between-station χ² test: ``chi2`` on ``dof`` degrees of freedom, its ``critical`` value at ``level``,
    the station ``pairs`` with their common satellites, and the σ factor it implies (1 when not rejected)."""

    chi2: float
    dof: int
    critical: float
    level: float
    pairs: tuple[tuple[str, str, int], ...]

    @property
    def rejected(self) -> bool:
        return self.chi2 > self.critical

    @property
    def ratio(self) -> float:
        """``√(χ²/dof)``: the RMS of the standardized differences (1 when the σ are complete)."""
        return float(np.sqrt(self.chi2 / self.dof))

    @property
    def factor(self) -> float:
        """:attr:`ratio` when the test rejects, else 1 (a single-receiver filter's σ grows by this factor)."""
        return self.ratio if self.rejected else 1.0

    def statement(self) -> str:
        """One line: the test, its outcome and what it did (console and notes)."""
        pairs = ", ".join(f"{a}–{b} ({n} satellites)" for a, b, n in self.pairs)
        head = (
            f"between-station check of the realistic σ: the single-station solutions of {pairs} differ by "
            f"{self.ratio:.2f}× their σ (χ² = {self.chi2:.1f} on {self.dof} dof, critical {self.critical:.1f} at "
            f"{100 * self.level:g} %)"
        )
        if self.rejected:
            return (
                head
                + f": the single-station filters' σ × {self.factor:.2f}, and no satellite σ below what they combine "
                + "to (an error constant over the session that differs between stations)"
            )
        return head + ": accepted, σ unchanged"

    def as_dict(self) -> dict[str, Any]:
        numbers = {
            name: getattr(self, name) for name in ("chi2", "dof", "critical", "level", "ratio", "rejected", "factor")
        }
        return {
            **numbers,
            "pairs": [list(p) for p in self.pairs],
            "statement": self.statement(),
        }


def between_station_test(
    stations: Sequence[str],
    dsb_ns: np.ndarray,
    sigma_ns: np.ndarray,
    *,
    level: float = 0.05,
    min_common: int = MIN_COMMON_SATELLITES,
) -> BetweenStationTest | None:
    """The test (module doc) from each station's single-receiver satellite DSBs ``dsb_ns`` (n, S) and their
    realistic σ ``sigma_ns`` (n, S) [ns] (NaN: not estimated by that station); ``None`` when no pair of stations
    shares ``min_common`` satellites."""
    x, s = np.asarray(dsb_ns, float), np.asarray(sigma_ns, float)
    if x.shape != s.shape or x.ndim != 2 or x.shape[0] != len(stations):
        raise ModelError(f"one row of DSBs and σ per station: {x.shape}, {s.shape} for {len(stations)} stations")
    if not 0.0 < level < 0.5:
        raise ModelError(f"the between-station test's level must lie in (0, 0.5), got {level}")
    use = np.isfinite(x) & np.isfinite(s) & (s > 0)
    use &= use.sum(axis=0) >= 2  # a satellite estimated by one station only tells nothing of the others
    pairs = []
    for i in range(len(stations)):
        for j in range(i + 1, len(stations)):
            n = int((use[i] & use[j]).sum())
            if n >= min_common:
                pairs.append((stations[i], stations[j], n))
    if not pairs:
        return None
    chi2, dof = _two_way_fit(np.where(use, x, 0.0), np.where(use, s, 1.0), use)
    if dof <= 0:
        return None
    critical = float(special.chdtri(dof, level))
    return BetweenStationTest(chi2, dof, critical, level, tuple(pairs))


def _two_way_fit(x: np.ndarray, s: np.ndarray, use: np.ndarray) -> tuple[float, int]:
    """Weighted LS of ``x_i^s = t^s + c_i`` (``c_0 = 0``) over the entries ``use``: the weighted residual sum of
    squares and its degrees of freedom."""
    n, S = x.shape
    rows, cols = np.nonzero(use)
    m = rows.size
    A = np.zeros((m, S + n - 1))
    A[np.arange(m), cols] = 1.0
    station = rows > 0
    A[np.flatnonzero(station), S + rows[station] - 1] = 1.0
    w = 1.0 / s[rows, cols]
    keep = np.flatnonzero(use.any(axis=0))
    A = A[:, np.concatenate([keep, S + np.arange(n - 1)])]
    sol, *_ = np.linalg.lstsq(A * w[:, None], x[rows, cols] * w, rcond=None)
    r = (x[rows, cols] - A @ sol) * w
    return float(r @ r), int(m - np.linalg.matrix_rank(A))


def variance_floor(factor: float, sigma_ns: np.ndarray) -> np.ndarray:
    """(S,) the variance floor [ns²] of a satellite's DSB from the stations' single-receiver σ ``sigma_ns``
    (n, S) (NaN: not estimated there) with the between-station ``factor``: ``factor² / Σ_i σ_i⁻²`` (module doc);
    0 where no station estimates the satellite."""
    s = np.asarray(sigma_ns, float)
    good = np.isfinite(s) & (s > 0)
    info = np.where(good, 1.0 / np.where(good, s, 1.0) ** 2, 0.0).sum(axis=0)
    out: np.ndarray = np.where(info > 0, factor**2 / np.where(info > 0, info, 1.0), 0.0)
    return out
