"""Comparing estimated receiver and satellite DSBs with published products (Bias-SINEX, IONEX DCB blocks).

A product's DSBs of one code pair are a :class:`ProductDSB` (read by
:func:`distnav.formats.gnss.product_files.product_dsbs`); :func:`compare_in_datum` aligns the datum — the
S-transformation that makes the product's satellites zero-mean over the satellites common with the estimates, i.e.
a shift ``c`` subtracted from every satellite and added to every receiver — and reports mean, RMS, max and
per-object differences.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from distnav.models.gnss.systems import GLONASS_FDMA_HZ

__all__ = [
    "channel_pattern",
    "ProductDSB",
    "compare_in_datum",
    "DSBEstimates",
    "worst_satellite",
    "WORST_LEVEL",
]

NsByName = dict[str, float]
"""DSBs [ns] by satellite (``G01``) or station (``BELE``)."""

WORST_LEVEL = 0.05
"""Family-wise level of :func:`worst_satellite`'s "stands out" flag (Bonferroni over the compared satellites)."""


@dataclass(frozen=True)
class ProductDSB:
    """One product's DSBs ``obs1 − obs2`` [ns]: ``satellite[prn]``, ``station[site]``, plus notes."""

    name: str
    path: Path
    kind: str
    satellite: dict[str, float]
    station: dict[str, float]
    notes: list[str] = field(default_factory=list)
    day: np.datetime64 | None = None
    pair: str = ""


def _stats(d: np.ndarray) -> dict[str, float]:
    return {"mean_ns": float(d.mean()), "rms_ns": float(np.sqrt(np.mean(d**2))), "max_abs_ns": float(np.abs(d).max())}


def worst_satellite(difference_ns: Mapping[str, float], *, level: float = WORST_LEVEL) -> dict[str, Any] | None:
    """The worst-fitting satellite of a product comparison: the largest |d| of the datum-aligned differences
    ``difference_ns``, set against the RMS of the *other* satellites' differences. It ``stands_out`` when
    ``|d| > k · RMS(others)`` with ``k`` the two-sided normal quantile at ``level`` divided over the n satellites
    (Bonferroni: ``k = Φ⁻¹(1 − level/(2n))``, 3.14 for n = 30 at 5 %) — the outlier test of the largest of n
    normal differences whose σ is estimated from the others. None with fewer than 3 satellites."""
    from statistics import NormalDist

    names = [k for k, v in difference_ns.items() if np.isfinite(v)]
    if len(names) < 3:
        return None
    d = np.array([difference_ns[k] for k in names])
    j = int(np.argmax(np.abs(d)))
    others = np.delete(d, j)
    rms_others = float(np.sqrt(np.mean(others**2)))
    k = NormalDist().inv_cdf(1.0 - level / (2.0 * len(names)))
    ratio = float(abs(d[j]) / rms_others) if rms_others > 0 else float("inf")
    return {
        "satellite": names[j],
        "difference_ns": float(d[j]),
        "rms_others_ns": rms_others,
        "ratio_to_rms_others": ratio,
        "critical_ratio": float(k),
        "stands_out": bool(ratio > k),
        "level": level,
        "n": len(names),
    }


def compare_in_datum(
    sat_ns: dict[str, float], rx_ns: dict[str, float], product: ProductDSB, *, exclude: Sequence[str] = ()
) -> dict[str, Any]:
    """Estimate − product after aligning the product's datum to the estimates' over the common satellites.

    Satellites: ``d^s = est^s − prod^s − c`` with ``c`` the mean of ``est^s − prod^s`` over the common satellites
    (not in ``exclude``): RMS after removing the mean is the RMS of ``d^s``. Receivers: ``d_i = est_i − prod_i +
    c`` (the same S-transformation moves the receivers the other way). ``worst`` names the satellite with the
    largest |d|.
    """
    common = sorted(s for s in sat_ns if s in product.satellite and np.isfinite(sat_ns[s]) and s not in exclude)
    if not common:
        what = (
            f"{product.name} has no {product.pair} satellite DSB"
            if not product.satellite and product.pair
            else f"no satellite in common with {product.name}"
        )
        return {"n": 0, "note": what}
    raw = np.array([sat_ns[s] - product.satellite[s] for s in common])
    c = float(raw.mean())
    d = raw - c
    out: dict[str, Any] = {
        "n": len(common),
        "datum_offset_ns": c,
        **_stats(raw),
        "rms_zero_mean_ns": float(np.sqrt(np.mean(d**2))),
        "max_abs_zero_mean_ns": float(np.abs(d).max()),
        "worst": common[int(np.argmax(np.abs(d)))],
        "difference_ns": dict(zip(common, d.tolist(), strict=True)),
        "reference_ns": {s: product.satellite[s] for s in common},
    }
    out["worst_fitting"] = worst_satellite(out["difference_ns"])
    rx = {r: rx_ns[r] - product.station[r] + c for r in rx_ns if r in product.station and np.isfinite(rx_ns[r])}
    if rx:
        out["receivers"] = {
            "difference_ns": rx,
            "reference_ns": {r: product.station[r] for r in rx},
            **_stats(np.array(list(rx.values()))),
        }
    missing = sorted(r for r in rx_ns if r not in product.station and np.isfinite(rx_ns[r]))
    if missing:
        out["receivers_not_in_product"] = missing
    return out


@dataclass(frozen=True)
class DSBEstimates:
    """Estimated DSBs to compare: ``satellite``/``station`` [ns] of ``obs1 − obs2``, the days of the data."""

    source: str
    obs1: str
    obs2: str
    satellite: NsByName
    station: NsByName
    days: tuple[np.datetime64, ...]


def channel_pattern(difference_ns: Mapping[str, float], f1_hz: Mapping[str, float]) -> dict[str, Any]:
    """The GLONASS FDMA channels' share of a comparison (docs/gnss.md): the datum-aligned differences
    ``difference_ns`` (satellite → ns) split into one mean per channel (from each satellite's G1 frequency
    ``f1_hz``, channel ``k = (f_1 − 1602 MHz)/0.5625 MHz``) and the rest. A receiver's inter-frequency bias per
    channel is inseparable from the DSBs of that channel's (two antipodal) satellites, so a network of few
    receivers carries their pattern in the per-channel means.

    >>> from distnav.models.gnss.products import channel_pattern
    >>> out = channel_pattern({"R01": 1.0, "R05": 1.2, "R02": -1.0}, {"R01": 1602.5625e6, "R05": 1602.5625e6,
    ...                                                             "R02": 1599.75e6})
    >>> out["per_channel_ns"], round(out["within_channel_rms_ns"], 3)
    ({-4: -1.0, 1: 1.1}, 0.082)
    """
    groups: dict[int, list[float]] = {}
    for sv, d in difference_ns.items():
        f = f1_hz.get(sv)
        if f is not None and np.isfinite(f) and np.isfinite(d):
            groups.setdefault(int(round((f - GLONASS_FDMA_HZ[1][0]) / GLONASS_FDMA_HZ[1][1])), []).append(float(d))
    if not groups:
        return {}
    means = {k: float(np.mean(v)) for k, v in sorted(groups.items())}
    rest = np.concatenate([np.asarray(v) - means[k] for k, v in groups.items()])
    every = np.concatenate([np.full(len(v), means[k]) for k, v in groups.items()])
    return {
        "channels": len(means),
        "satellites": int(rest.size),
        "per_channel_ns": {k: round(v, 4) for k, v in means.items()},
        "channel_means_rms_ns": float(np.sqrt(np.mean(every**2))),
        "within_channel_rms_ns": float(np.sqrt(np.mean(rest**2))),
    }
