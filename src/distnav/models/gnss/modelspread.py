"""The ionosphere model's share of a station's DSB error where each station has its own layer (issue 32 item 1).

A single station's satellite DSBs carry the error of its single-layer ionosphere along its own passes: constant
over the day, the same in every epoch's residuals, so neither the formal σ nor the arcs' variance factor sees it,
and without a second station the between-station test (:mod:`~distnav.models.gnss.stationcheck`) cannot either.
Its size is estimated here from the data alone, by the model's own uncertainty: the same station and epochs are
solved with the other of the two ionosphere fields distnav has (linear field + thin-shell mapping ↔ second-order
field + modified mapping, docs/gnss.md), and the satellites' zero-mean DSBs of the two solutions differ by
``d_s``. Each satellite's variance gets the pooled ``mean_s d_s²`` added (one number: the per-satellite ``d_s²`` is
itself one noisy draw). This is a departure from paper 003 (one model, formal σ); it is checked, never tuned,
against CAS on the shared days (docs/gnss.md) — no product enters the computation.

The same holds for a network whose stations each have their own ionosphere (``per-receiver``, stations far apart:
the satellites are all that ties them): every station's layer errs along its own passes, and in a 6-h session
the between-station test has too few common satellites to see it (5–6 degrees of freedom on BELE + DGAR; it
accepted three of the four sessions whose σ were 1.3–2.0× too small against CAS and GFZ). The spread is then
taken from the network's central filters of the two models and added on top of the between-station floor (the
two overlap: on the full day the σ is conservative, RMS(error/σ) 0.78 / 0.95 against CAS / GFZ, docs/gnss.md).
A network sharing one layer (nearby stations) is left as it is: there the stations see the same ionosphere and
the arcs' and between-station checks measure its error.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from distnav.models.gnss.biasmodel import BiasModelOptions, BiasNetworkData, bias_network_model
from distnav.models.gnss.gfcollector import DatumSeries
from distnav.models.gnss.gfnetwork import BiasFilterOptions, run_bias_filters

__all__ = [
    "ModelSpread",
    "alternative_model",
    "model_spread",
    "sigma_limits",
    "spread_of_own_layers",
    "with_model_spread",
]


@dataclass(frozen=True)
class ModelSpread:
    """The pooled variance ``variance_ns2`` [ns²] added to every satellite, from ``satellites`` satellites,
    and the alternative model it came from (``alternative``: a name for the console)."""

    variance_ns2: float
    satellites: int
    alternative: str
    stations: int = 1

    @property
    def rms_ns(self) -> float:
        return float(np.sqrt(self.variance_ns2))

    def statement(self) -> str:
        why = (
            "one station, so no between-station check"
            if self.stations == 1
            else f"{self.stations} stations, each with its own ionosphere layer"
        )
        return (
            f"model choice: {why}; each satellite's σ includes the ionosphere "
            f"model spread {self.rms_ns:.2f} ns (RMS difference of the zero-mean satellite DSBs from the "
            f"{self.alternative} over {self.satellites} satellites; --model-spread off leaves it out)"
        )


def alternative_model(options: BiasModelOptions) -> tuple[BiasModelOptions, str]:
    """The other ionosphere field: linear + thin shell ↔ second order + modified mapping (any mix → linear + thin
    shell's opposite, the second-order field + MSLM), with its name."""
    if options.tec_order == 2 and options.mapping == "mslm":
        return replace(options, tec_order=1, mapping="slm"), "linear field with the thin-shell mapping"
    return replace(options, tec_order=2, mapping="mslm"), "second-order field with the modified mapping"


def model_spread(central: dict[str, float], alternative: dict[str, float], name: str) -> ModelSpread:
    """The pooled ``mean_s d_s²`` of two solutions' satellite DSBs (satellite → ns; the satellites both
    estimate, each solution's mean over them removed).

    >>> from distnav.models.gnss.modelspread import model_spread
    >>> model_spread({"G01": 1.0, "G02": -1.0, "G03": 0.5}, {"G01": 3.0, "G02": 1.0, "G04": 9.0}, "other").rms_ns
    0.0
    """
    common = sorted(k for k in central if k in alternative and np.isfinite(central[k]) and np.isfinite(alternative[k]))
    if len(common) < 2:
        return ModelSpread(0.0, len(common), name)
    a, b = np.array([central[k] for k in common]), np.array([alternative[k] for k in common])
    d = (a - a.mean()) - (b - b.mean())
    return ModelSpread(float(np.mean(d**2)), len(common), name)


def with_model_spread(series: Sequence[DatumSeries], n_receivers: int, spread: ModelSpread) -> list[DatumSeries]:
    """Every series with ``spread.variance_ns2`` added to its estimated satellites' variance (on top of any
    variance added before)."""
    out = []
    for s in series:
        q = s.dsb_ns.shape[1]
        extra = np.zeros(q) if s.extra_variance_ns2 is None else np.array(s.extra_variance_ns2, float)
        extra[n_receivers:] += np.where(np.isfinite(s.dsb_ns[-1, n_receivers:]), spread.variance_ns2, 0.0)
        out.append(replace(s, extra_variance_ns2=extra))
    return out


def spread_of_own_layers(
    data: BiasNetworkData, orbit: Any, series: Sequence[DatumSeries], options: BiasModelOptions
) -> tuple[list[DatumSeries], ModelSpread | None]:
    """For a network whose every station has its own ionosphere layer — one station, or stations far apart with
    per-receiver layers (:attr:`BiasNetworkData.network` kept by the data stage): the alternative model's central
    filter, the spread, and the series with it; networks sharing a layer are returned unchanged."""
    if data.network is None or data.layout.n_ionospheres != len(data.stations):
        return list(series), None
    alt_options, name = alternative_model(options)
    alt = bias_network_model(data.network, orbit, alt_options)
    (alt_central,), _ = run_bias_filters(alt, BiasFilterOptions(local=False, between_station_level=None))
    central = next(s for s in series if s.label == "central")
    n = len(data.stations)
    spread = model_spread(
        dict(zip(data.layout.svs, central.dsb_ns[-1, n:].tolist(), strict=True)),
        dict(zip(alt.layout.svs, alt_central.dsb_ns[-1, n:].tolist(), strict=True)),
        name,
    )
    spread = replace(spread, stations=len(data.stations))
    return with_model_spread(series, len(data.stations), spread), spread


def sigma_limits(
    series: Sequence[DatumSeries], n_receivers: int, system: str, levelled: bool, channel_ifb: bool = False
) -> list[str]:
    """What the central filter's realistic σ cannot contain, one console note each (gnss5, measured against CAS on
    BELE 2024-01-10, docs/gnss.md): the arcs' variance factor missing (too few degrees of freedom beyond the
    biases: BeiDou's MEO satellites from one equatorial station, RMS(error/σ) 2.24), and for GLONASS the receivers'
    FDMA channel biases, which one receiver cannot separate from the satellites of a channel (C1C−C2C: 3.11),
    unless ``channel_ifb``: their consider term is in the σ (:mod:`~distnav.models.gnss.sigmaterms`)."""
    central = next((s for s in series if s.label == "central"), None)
    notes = []
    if central is not None and levelled and central.arc_variance_factor is None:
        notes.append(
            "precision: the arcs' variance factor is not estimable (fewer than 8 degrees of freedom beyond the "
            "biases: few satellites in view per epoch or few arcs), so the realistic σ is the formal σ × the "
            "predicted residuals' factor, which misses the levelling errors constant over an arc: expect it too small"
        )
    if system == "R" and not channel_ifb:
        who = (
            "one receiver: its channel biases go into the satellite DSBs, not separable from them and not in their σ"
            if n_receivers == 1
            else f"{n_receivers} receivers: the satellite DSBs take the receivers' mean per channel; the σ contains "
            "their differences only through the between-station check"
        )
        notes.append(
            "GLONASS: each FDMA channel has its own receiver inter-frequency bias, shared by the channel's two "
            f"satellites; with {who} (GLONASS channels: docs/gnss.md)"
        )
    return notes
