"""Building :class:`~distnav.models.gnss.codebias.CodeBiasData`: the observable (24) of paper 000 §5 from simulated
code observations (:func:`simulate_codebias_data`, what :class:`CodeBiasSimulation` draws) or from real RINEX code
observations (:func:`codebias_data_from_observations`)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from distnav._checks import real_array, real_number, whole_number
from distnav.errors import ModelError
from distnav.models.gnss.code_observations import CodeObservations
from distnav.models.gnss.codebias import CodeBiasData, combination_sigma
from distnav.models.gnss.constants import NS_TO_M
from distnav.models.gnss.geometry import azimuth_elevation, elevation_mask
from distnav.models.gnss.observables import (
    codebias_coefficients,
    codebias_observable,
    elevation_sigma,
    mu_coefficients,
)
from distnav.models.gnss.orbits import SatelliteOrbit, gps_seconds

__all__ = ["CodeBiasSimulation", "simulate_codebias_data", "codebias_data_from_observations"]

WEIGHTINGS = ("euler-goad", "sin", "constant")


@dataclass(frozen=True, kw_only=True)
class CodeBiasSimulation:
    """What :func:`simulate_codebias_data` draws, checked once when built.

    ``sigma0_m`` zenith code σ [m] with the elevation ``weighting`` (Euler & Goad by default, σ₀ = 20 cm: paper
    000 §5.1), ``mask_rad`` the elevation mask [rad]; satellite and receiver per-frequency code biases drawn from
    N(0, σ²) with ``sat_dsb_sigma_ns`` / ``rx_dsb_sigma_ns`` [ns], or fixed by ``sat_biases_m`` (p, 3) /
    ``rx_biases_m`` (n, 3) [m]; ``stations`` names (default ``S001``...), ``reference`` the S-basis station."""

    sigma0_m: float = 0.20
    weighting: str = "euler-goad"
    mask_rad: float = float(np.deg2rad(10.0))
    sat_dsb_sigma_ns: float = 3.0
    rx_dsb_sigma_ns: float = 5.0
    sat_biases_m: Any = None
    rx_biases_m: Any = None
    stations: Sequence[str] | None = None
    reference: int = 0

    def __post_init__(self) -> None:
        real_number(self.sigma0_m, "sigma0_m", positive=True, unit="metres", error=ModelError)
        if self.weighting not in WEIGHTINGS:
            raise ModelError(f"unknown elevation weighting {self.weighting!r}; use {', '.join(map(repr, WEIGHTINGS))}")
        real_number(
            self.mask_rad, "mask_rad", minimum=0.0, below=np.pi / 2, unit="radians, not degrees", error=ModelError
        )
        for name in ("sat_dsb_sigma_ns", "rx_dsb_sigma_ns"):
            real_number(getattr(self, name), name, minimum=0.0, unit="ns", error=ModelError)
        whole_number(self.reference, "reference (a station index)", error=ModelError)


def _given_or_drawn(
    value: Any, shape: tuple[int, int], sigma_m: float, rng: np.random.Generator, name: str, rows: str
) -> np.ndarray:
    """The biases a caller gave (checked for shape), or a draw from N(0, sigma_m²) when ``value`` is None."""
    if value is None:
        return rng.normal(0.0, sigma_m, size=shape)
    out = np.asarray(value, dtype=float)
    if out.shape != shape:
        raise ModelError(f"{name} must be ({rows}, 3) = {shape}, got {out.shape}")
    return out


def simulate_codebias_data(
    positions_ecef_m: np.ndarray,
    orbit: SatelliteOrbit,
    t_gps_s: np.ndarray,
    svs: Sequence[str],
    *,
    rng: np.random.Generator,
    options: CodeBiasSimulation | None = None,
) -> CodeBiasData:
    """Simulate L1/L2/L5 code observations of a network and form the observable (24).

    Per station, epoch and visible satellite: ``ȳ_j = ρ + μ_j I + d_{r,j} + d^s_j + e_j`` with a geometric range
    plus receiver/satellite clock terms ``ρ``, a slant ionosphere ``I`` (1–30 m), per-frequency code biases
    ``d`` and ``e_j ~ N(0, σ(θ)²)`` (``options``: :class:`CodeBiasSimulation`, paper 000 §5.1). Everything but the
    biases and noise cancels in (24); ``truth_m`` holds the estimable ``x_s = b^s + b_ref``.
    """
    o = options if options is not None else CodeBiasSimulation()
    pos = real_array(positions_ecef_m, "positions_ecef_m", error=ModelError)
    t = real_array(t_gps_s, "t_gps_s", error=ModelError)
    if pos.ndim != 2 or pos.shape[1] != 3 or not np.isfinite(pos).all():
        raise ModelError(f"positions_ecef_m must be finite (stations, 3) ECEF metres, got shape {pos.shape}")
    if t.ndim != 1 or not np.isfinite(t).all():
        raise ModelError(f"t_gps_s must be a 1-D array of finite GPS seconds, got shape {t.shape}")
    n, p, T = pos.shape[0], len(svs), t.size
    if o.reference >= n:
        raise ModelError(f"reference {o.reference} is not one of the {n} stations")
    mus = mu_coefficients((1, 2, 5))
    sat = orbit.positions_ecef(t, list(svs))
    d_sat = _given_or_drawn(o.sat_biases_m, (p, 3), o.sat_dsb_sigma_ns * NS_TO_M, rng, "sat_biases_m", "satellites")
    d_rx = _given_or_drawn(o.rx_biases_m, (n, 3), o.rx_dsb_sigma_ns * NS_TO_M, rng, "rx_biases_m", "stations")
    clk_rx = rng.normal(0.0, 1e3, size=(n, T))
    clk_sat = rng.normal(0.0, 1e2, size=(T, p))
    y = np.full((n, T, p), np.nan)
    sig = np.full((n, T, p), np.nan)
    elev = np.empty((n, T, p))
    for i in range(n):
        _, el = azimuth_elevation(pos[i], sat)
        elev[i] = el
        vis = elevation_mask(el, o.mask_rad)
        rng_m = np.linalg.norm(sat - pos[i], axis=-1) + clk_rx[i][:, None] - clk_sat
        iono = rng.uniform(1.0, 30.0, size=(T, p))
        s_code = elevation_sigma(np.where(vis, el, np.pi / 2), o.sigma0_m, o.weighting)
        ybar = [
            rng_m + mus[j] * iono + d_rx[i, j] + d_sat[None, :, j] + rng.normal(size=(T, p)) * s_code for j in range(3)
        ]
        yi = codebias_observable(ybar[0], ybar[1], ybar[2], mus=mus)
        y[i] = np.where(vis, yi, np.nan)
        sig[i] = np.where(vis, combination_sigma(np.where(vis, el, np.pi / 2), o.sigma0_m, o.weighting, mus), np.nan)
    c = codebias_coefficients(mus)
    truth = d_sat @ c + d_rx[o.reference] @ c
    names = tuple(o.stations) if o.stations is not None else tuple(f"S{i + 1:03d}" for i in range(n))
    meta = {
        "sigma0_m": o.sigma0_m,
        "weighting": o.weighting,
        "mask_deg": float(np.rad2deg(o.mask_rad)),
        "sat_biases_m": d_sat,
        "rx_biases_m": d_rx,
    }
    return CodeBiasData(names, tuple(svs), t, y, sig, o.reference, elev, truth, pos, meta)


def _elevations(
    positions_ecef_m: np.ndarray, orbit: SatelliteOrbit, t_gps_s: np.ndarray, svs: Sequence[str]
) -> np.ndarray:
    sat = orbit.positions_ecef(t_gps_s, list(svs))  # (T, p, 3)
    out = np.empty((positions_ecef_m.shape[0], t_gps_s.size, len(svs)))
    for i, rx in enumerate(positions_ecef_m):
        _, el = azimuth_elevation(rx, sat)
        out[i] = el
    return out


def codebias_data_from_observations(
    observations: Sequence[CodeObservations],
    orbit: SatelliteOrbit,
    *,
    sigma0_m: float = 0.20,
    weighting: str = "euler-goad",
    mask_rad: float = np.deg2rad(10.0),
    reference: int = 0,
    svs: Sequence[str] | None = None,
) -> CodeBiasData:
    """Form the observable (24) of real RINEX code observations (:func:`~distnav.formats.gnss.rinex.
    read_code_observations` with bands 1, 2, 5) on the union of their epochs, with elevations from ``orbit`` at
    each file's approximate position. ``svs`` defaults to the satellites observed on all three bands above the
    mask by some station. Raises :class:`~distnav.errors.ModelError` for a missing band, a station without
    position, or no satellite in common."""
    _check_observations(observations)
    names = [o.station for o in observations]
    times = np.unique(np.concatenate([o.time for o in observations]))
    sats = list(svs) if svs is not None else sorted({s for o in observations for s in o.satellites_with_all_bands()})
    if not sats:
        raise ModelError("no satellite is observed on L1, L2 and L5 by any station")
    t_gps = gps_seconds(times)
    pos = np.stack([o.position_ecef_m for o in observations])
    elev = _elevations(pos, orbit, t_gps, sats)
    n, T, p = len(observations), times.size, len(sats)
    y = np.full((n, T, p), np.nan)
    sig = np.full((n, T, p), np.nan)
    for i, o in enumerate(observations):
        _station_observable(o, times, sats, elev[i], y[i], sig[i], sigma0_m, weighting, mask_rad)
    no_orbit = [s for k, s in enumerate(sats) if not np.isfinite(elev[..., k]).any()]
    if len(no_orbit) == len(sats):  # issue 29: said "no satellite observed above the mask" for an orbit of another day
        raise ModelError(
            f"the orbit file(s) give no position for any of the {len(sats)} observed satellites during the "
            f"observations ({str(times[0])[:16]} to {str(times[-1])[:16]}): a navigation or SP3 file of another "
            f"day? give the orbits of the observation day"
        )
    if svs is None:  # keep the satellites observed above the mask by some station
        keep = np.isfinite(y).any(axis=(0, 1))
        sats = [s for s, k in zip(sats, keep.tolist(), strict=True) if k]
        y, sig, elev = y[..., keep], sig[..., keep], elev[..., keep]
        if not sats:
            raise ModelError(f"no satellite observed on L1, L2 and L5 above the {np.rad2deg(mask_rad):.0f}° mask")
    seen = np.isfinite(y).any(axis=1)
    for i, o in enumerate(observations):
        if not seen[i].any():
            raise ModelError(
                f"{o.path}: no satellite observed on L1, L2 and L5 above the "
                f"{np.rad2deg(mask_rad):.0f}° mask (among {', '.join(sats[:8])}...)"
            )
    meta = {
        "sigma0_m": sigma0_m,
        "weighting": weighting,
        "mask_deg": float(np.rad2deg(mask_rad)),
        "codes": {o.station: {f"L{b}": c for b, c in o.codes.items()} for o in observations},
        "no_orbit": no_orbit,
        "notes": {o.station: list(o.notes) for o in observations},
    }
    return CodeBiasData(tuple(names), tuple(sats), t_gps, y, sig, reference, elev, None, pos, meta)


def _check_observations(observations: Sequence[CodeObservations]) -> None:
    """Every station has L1, L2 and L5 codes and a usable approximate position, and appears once."""
    if not observations:
        raise ModelError("no observation files given")
    for o in observations:
        missing = [b for b in (1, 2, 5) if b not in o.range_m]
        if missing:
            raise ModelError(
                f"{o.path}: the code-bias observable needs L1, L2 and L5 codes; missing "
                f"{', '.join('L' + str(b) for b in missing)}"
            )
        if not np.all(np.isfinite(o.position_ecef_m)) or np.linalg.norm(o.position_ecef_m) < 6.0e6:
            raise ModelError(f"{o.path}: no usable approximate position in the header ({o.position_ecef_m})")
    names = [o.station for o in observations]
    dup = {s for s in names if names.count(s) > 1}
    if dup:
        raise ModelError(f"station names appear twice: {', '.join(sorted(dup))}")


def _station_observable(
    o: CodeObservations,
    times: np.ndarray,
    svs: Sequence[str],
    elev: np.ndarray,
    y: np.ndarray,
    sig: np.ndarray,
    sigma0_m: float,
    weighting: str,
    mask_rad: float,
) -> None:
    """One station's observable (24) and its σ on the union of the epochs ``times`` (written into its rows ``y``,
    ``sig``: ``(T, p)``), NaN where a satellite is not observed on all three bands or below the mask."""
    mus = mu_coefficients((1, 2, 5))
    ti = np.searchsorted(times, o.time)
    cols = [o.svs.index(s) if s in o.svs else -1 for s in svs]
    have = np.array([c >= 0 for c in cols])
    if not have.any():
        return
    src = [c for c in cols if c >= 0]
    ybar = [o.range_m[b][:, src] for b in (1, 2, 5)]
    yi = codebias_observable(ybar[0], ybar[1], ybar[2], mus=mus)
    block = np.full((o.time.size, len(svs)), np.nan)
    block[:, have] = yi
    el = elev[ti]
    vis = elevation_mask(el, mask_rad) & np.isfinite(block)
    y[ti] = np.where(vis, block, np.nan)
    sig[ti] = np.where(vis, combination_sigma(np.where(vis, el, np.pi / 2), sigma0_m, weighting, mus), np.nan)
