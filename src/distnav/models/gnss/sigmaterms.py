"""What a system's realistic σ cannot see in its own data, taken from elsewhere in the same data (issue 32, gnss8).

**The arcs' factor borrowed from GPS.** The realistic σ is the formal σ × √σ̂²_arc, the arcs' variance factor
(:mod:`~distnav.models.gnss.arcprecision`), which sees the levelling error constant over an arc. With too few
degrees of freedom beyond the biases (BeiDou's 15 MEO satellites from one equatorial station: about one beyond the
biases) it is not estimable and the filter falls back to the predicted residuals' factor, which does not see that
error (BELE's BeiDou σ 2.24× too small against CAS). The same receiver's GPS arcs in the same observation file go
through the same levelling, antenna and environment; their factor σ̂²_arc (the ratio of the arc-constant error's
variance to the white model's ``1/W_a``, whose code σ each pair scales by ``1/(μ − 1)``) is taken for the other
system's arcs (:func:`with_arc_factor`). The assumption — the other system's arcs err relative to that model as
the GPS arcs do — is a departure from paper 003 (formal σ only), stated on the console and checked against CAS
and the simulator (docs/gnss.md).

**GLONASS: the receivers' FDMA channel biases as a consider term.** Each GLONASS receiver has its own
inter-frequency code bias ``δ_{r,k}`` per FDMA channel *k*, shared by the channel's (two antipodal) satellites and
exactly inseparable from their DSBs. With ``δ_{r,k}`` independent N(0, σ_ifb²) per receiver and channel, a
satellite *s* on channel ``k(s)`` of a network of ``n_r`` receivers takes the receivers' mean ``δ̄_k`` (variance
``σ_ifb²/n_r``), and in the zero-mean datum over the S satellites its error is ``δ̄_{k(s)} − (1/S) Σ_t δ̄_{k(t)}``:

    ``Var = σ_ifb²/n_r · (1 − 2 n_{k(s)}/S + Σ_j n_j²/S²)``     (``n_j`` the satellites on channel *j*)

(:func:`channel_ifb_variance_ns2`; the receiver DSBs take the mean). The size ``σ_ifb`` comes from the data where
two or more receivers are there: the difference of two receivers' single-station satellite DSBs has per channel the
mean ``δ_{r,k} − δ_{r',k}`` (variance ``2σ_ifb²``) plus the estimation's errors, which the scatter within a
channel measures — a one-way random-effects analysis of variance (:func:`channel_ifb_sigma_ns`). One receiver
tracking both GLONASS pairs gives the same analysis of its C/A minus P-pair DSBs (the difference of the two pairs'
patterns); without either, a stated prior (``--glonass-ifb-sigma-ns``, docs/gnss.md).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace

import numpy as np

from distnav.models.gnss.gfcollector import DatumSeries
from distnav.models.gnss.systems import GLONASS_FDMA_HZ

__all__ = [
    "ChannelIfb",
    "channel_ifb_sigma_ns",
    "channel_ifb_variance_ns2",
    "channels_from_f1_hz",
    "with_arc_factor",
    "with_channel_ifb",
]

GLONASS_G1_HZ, GLONASS_G1_STEP_HZ = GLONASS_FDMA_HZ[1]
"""GLONASS G1 FDMA: f = 1602 MHz + k·0.5625 MHz (GLONASS ICD 5.1 §3.3.1.1; :data:`.systems.GLONASS_FDMA_HZ`)."""


@dataclass(frozen=True)
class ChannelIfb:
    """The consider term of the receivers' FDMA channel biases: ``sigma_ns`` σ_ifb per receiver and channel,
    ``source`` (``"between receivers"``, ``"P pair of the same receiver"``, ``"given"`` or ``"prior"``),
    ``channels`` and ``dof`` of the estimate (0 for a prior), ``receivers`` n_r and ``mode`` (``"added"``: one
    receiver; ``"floor"``: a network, whose arcs and between-station floor already see the receivers'
    differences)."""

    sigma_ns: float
    source: str
    receivers: int
    channels: int = 0
    dof: int = 0
    mode: str = "added"

    def as_dict(self) -> dict[str, object]:
        return {
            "sigma_ns": self.sigma_ns,
            "source": self.source,
            "receivers": self.receivers,
            "channels": self.channels,
            "dof": self.dof,
            "mode": self.mode,
        }

    def statement(self) -> str:
        where = {
            "between receivers": f"from the {self.receivers} receivers' single-station DSBs ({self.channels} "
            f"channels, {self.dof} dof)",
            "P pair of the same receiver": f"from the channel means of its C/A minus P-pair (C1P-C2P) DSBs "
            f"({self.channels} channels, {self.dof} dof; both pairs' patterns: an upper bound)",
            "given": "as given by --glonass-ifb-sigma-ns",
        }.get(self.source, "the prior of --glonass-ifb-sigma-ns (not estimable from these data; docs/gnss.md)")
        how = "added to" if self.mode == "added" else "a floor of"
        return (
            f"model choice: GLONASS FDMA channel biases of the receivers, σ {self.sigma_ns:.2f} ns per receiver and "
            f"channel {where}; their share in each satellite DSB (zero-mean datum, channel's satellites together) "
            f"is {how} its σ"
        )


def channels_from_f1_hz(f1_hz: Sequence[float] | np.ndarray) -> np.ndarray:
    """The FDMA channel numbers (S,) of GLONASS G1 frequencies [Hz] (NaN stays NaN).

    >>> from distnav.models.gnss.sigmaterms import channels_from_f1_hz
    >>> channels_from_f1_hz([1602.5625e6, 1598.0625e6])
    array([ 1., -7.])
    """
    k: np.ndarray = np.round((np.asarray(f1_hz, float) - GLONASS_G1_HZ) / GLONASS_G1_STEP_HZ)
    return k


def channel_ifb_variance_ns2(channels: Sequence[float] | np.ndarray, sigma_ns: float, receivers: int) -> np.ndarray:
    """Each satellite's variance [ns²] from the receivers' channel biases in the zero-mean datum over the given
    satellites (module doc): ``σ²/n_r · (1 − 2 n_k/S + Σ_j n_j²/S²)``; a satellite without a channel (NaN) gets 0.

    >>> from distnav.models.gnss.sigmaterms import channel_ifb_variance_ns2
    >>> channel_ifb_variance_ns2([1, 1, 2, 3], 2.0, 1)  # S = 4, n = (2, 1, 1): Σn²/S² = 6/16
    array([1.5, 1.5, 3.5, 3.5])
    """
    k = np.asarray(channels, float)
    ok = np.isfinite(k)
    out = np.zeros(k.size)
    if not ok.any():
        return out
    _, inv, counts = np.unique(k[ok], return_inverse=True, return_counts=True)
    S = float(ok.sum())
    out[ok] = sigma_ns**2 / receivers * (1.0 - 2.0 * counts[inv] / S + float((counts**2).sum()) / S**2)
    return out


def channel_ifb_sigma_ns(difference_ns: Mapping[str, float], channels: Mapping[str, float]) -> tuple[float, int, int]:
    """σ of the channel means of one receiver-pair difference of satellite DSBs, the estimation's scatter within
    the channels removed (one-way random effects: ``E[Σ_k n_k (m_k − m̄)²/(K − 1)] = n₀ σ_c² + σ_w²`` with
    ``n₀ = (S − Σ n_k²/S)/(K − 1)``, σ_w² the pooled within-channel variance on ``S − K`` dof); returns
    ``(σ_c, K, S − K)`` — σ_c² is ``2σ_ifb²`` for two independent receivers. ``(nan, K, dof)`` with fewer than
    two channels or no within-channel dof."""
    sats = [s for s in difference_ns if s in channels and np.isfinite(difference_ns[s]) and np.isfinite(channels[s])]
    d = np.array([difference_ns[s] for s in sats], float)
    k = np.array([channels[s] for s in sats], float)
    if d.size == 0:
        return float("nan"), 0, 0
    keys, inv, n = np.unique(k, return_inverse=True, return_counts=True)
    K, S = keys.size, d.size
    if K < 2 or S - K < 1:
        return float("nan"), K, max(S - K, 0)
    m = np.bincount(inv, weights=d) / n
    grand = d.mean()
    msb = float((n * (m - grand) ** 2).sum()) / (K - 1)
    msw = float(((d - m[inv]) ** 2).sum()) / (S - K)
    n0 = (S - float((n**2).sum()) / S) / (K - 1)
    return float(np.sqrt(max(msb - msw, 0.0) / n0)), K, S - K


def with_arc_factor(series: Sequence[DatumSeries], factor: float) -> list[DatumSeries]:
    """Every series without an arcs' variance factor gets ``factor`` (σ̂²_arc borrowed from another system's arcs
    of the same receivers, module doc); series with their own keep it."""
    return [s if s.arc_variance_factor is not None else replace(s, arc_variance_factor=factor) for s in series]


def with_channel_ifb(
    series: Sequence[DatumSeries], n_receivers: int, variance_ns2: np.ndarray, *, floor: bool
) -> list[DatumSeries]:
    """Every series with the satellites' channel-bias variance ``variance_ns2`` (S,) added (``floor=False``) or as
    a floor of their realistic variance (``floor=True``)."""
    out = []
    v = np.asarray(variance_ns2, float)
    for s in series:
        extra = np.zeros(s.dsb_ns.shape[1]) if s.extra_variance_ns2 is None else np.array(s.extra_variance_ns2, float)
        est = np.isfinite(s.dsb_ns[-1, n_receivers:])
        if floor:
            have = s.realistic_std_ns()[n_receivers:] ** 2
            add = np.maximum(v - np.where(np.isfinite(have), have, 0.0), 0.0)
        else:
            add = v
        extra[n_receivers:] += np.where(est, add, 0.0)
        out.append(replace(s, extra_variance_ns2=extra))
    return out
