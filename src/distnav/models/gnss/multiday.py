"""Several days of DSB solutions: a combined solution and the day-to-day repeatability.

Each day's solution is in its own zero-mean satellite datum (over that day's satellites). The days are first
brought to one datum — the S-transformation shifting every satellite by ``−c_d`` and every receiver by ``+c_d``
with ``c_d`` the day's mean over the satellites common to all days — then combined per object by the weighted
mean with the days' (realistic) σ; the repeatability is the standard deviation of the aligned daily values about
their mean (``ddof = 1``), the usual measure of a bias product's precision.

**Combined σ with a repeating part (issue 32).** A DSB's daily error is ``s_k + e_{k,d}``: a part ``s_k`` that
repeats every day (the satellite's multipath at the same stations, the same sidereal geometry, the ionosphere
model's error at the same passes) and a part ``e`` that does not. Averaging N days reduces only ``e``; the σ of
independent days, ``(Σ_d σ_d⁻²)^-1/2``, stated 0.052 ns where the 5-day error was 0.19 ns. The repeatability
measures ``e`` alone (``E[rep²] = σ_e²``), the daily (realistic) σ both, so the share of the daily variance that
repeats is estimated, pooled over the satellites estimated on every day,

    ``ρ = clip(1 − Σ_k rep_k² / Σ_k mean_d σ_{k,d}², 0, 1)``,

and each object's combined variance is ``ρ · mean_d σ_d² + (1 − ρ) / Σ_d σ_d⁻²`` (one ρ for satellites and
receivers). This assumes the daily σ is realistic (it is checked against the truth on the simulated network,
docs/gnss.md); it adds nothing the days do not show about an error that is *constant* and also absent from the
daily σ. ``combined_std_independent_ns`` keeps the σ of independent days for comparison.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from distnav.errors import ModelError

__all__ = ["combine_days"]


def combine_days(
    summaries: Mapping[str, Mapping[str, Any]],
    *,
    filter_label: str = "central",
    std_key: str = "final_dsb_std_realistic_ns",
) -> dict[str, Any]:
    """Combine the final DSBs of several ``gnss ionosphere`` summaries (``{day: summary}``)."""
    if len(summaries) < 2:
        raise ModelError("combining days needs at least two")
    days = sorted(summaries)
    vals = {d: summaries[d]["final_dsb_ns"][filter_label] for d in days}
    sds = {d: summaries[d].get(std_key, summaries[d]["final_dsb_std_ns"])[filter_label] for d in days}
    sats = [
        k for k in vals[days[0]] if not k.startswith("rx:") and all(np.isfinite(vals[d].get(k, np.nan)) for d in days)
    ]
    if not sats:
        raise ModelError(f"no satellite is estimated on all of {', '.join(days)}")
    shift = {d: float(np.mean([vals[d][k] for k in sats])) for d in days}
    objects = sorted({k for d in days for k, v in vals[d].items() if np.isfinite(v)})
    aligned: dict[str, dict[str, float]] = {}
    for k in objects:
        sign = 1.0 if k.startswith("rx:") else -1.0
        aligned[k] = {d: vals[d][k] + sign * shift[d] for d in days if np.isfinite(vals[d].get(k, np.nan))}
    comb, indep_sd, mean_var, rep = {}, {}, {}, {}
    for k, per in aligned.items():
        v = np.array(list(per.values()))
        s = np.array([sds[d].get(k, np.nan) for d in per])
        w = np.where(np.isfinite(s) & (s > 0), 1.0 / np.where(s > 0, s, 1.0) ** 2, 0.0)
        comb[k] = float((w * v).sum() / w.sum()) if w.sum() > 0 else float(v.mean())
        indep_sd[k] = float(np.sqrt(1.0 / w.sum())) if w.sum() > 0 else float("nan")
        mean_var[k] = float(np.mean(np.square(s[w > 0]))) if w.sum() > 0 else float("nan")
        rep[k] = float(np.std(v, ddof=1)) if v.size > 1 else None
    pooled = [(r**2, mean_var[k]) for k in sats if (r := rep[k]) is not None and np.isfinite(mean_var[k])]
    share = float(np.clip(1.0 - sum(r for r, _ in pooled) / sum(m for _, m in pooled), 0.0, 1.0)) if pooled else 0.0
    comb_sd = {k: float(np.sqrt(share * mean_var[k] + (1.0 - share) * indep_sd[k] ** 2)) for k in aligned}
    sat_rep = [v for k, v in rep.items() if v is not None and not k.startswith("rx:")]
    sat_sd = [float(np.median([sds[d].get(k, np.nan) for d in days])) for k in sats]
    return {
        "days": days,
        "filter": filter_label,
        "common_satellites": sats,
        "datum_shift_ns": shift,
        "daily_ns": aligned,
        "combined_ns": comb,
        "combined_std_ns": comb_sd,
        "combined_std_independent_ns": indep_sd,
        "repeating_share": share,
        "repeatability_ns": rep,
        "median_satellite_repeatability_ns": float(np.median(sat_rep)) if sat_rep else None,
        "median_satellite_daily_std_ns": float(np.nanmedian(sat_sd)) if sat_sd else None,
    }
