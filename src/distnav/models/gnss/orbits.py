"""GPS satellite positions: broadcast ephemerides (IS-GPS-200), precise SP3 orbits, and a synthetic constellation.

Every orbit source has the same interface (:class:`SatelliteOrbit`): ``svs`` (satellite ids ``"G01"`` ...)
and ``positions_ecef(t_gps_s, svs=None) -> (T, S, 3)`` metres in the Earth-fixed frame at the epochs
``t_gps_s`` (seconds of GPS time since 1980-01-06 00:00:00; :func:`gps_seconds` converts ``datetime64``).
Where a source has no valid position (no ephemeris record close enough, satellite absent from the SP3 file,
outside the SP3 time span) the position is NaN; downstream code treats NaN as "not visible".

* :class:`BroadcastOrbit` — Keplerian propagation of the broadcast elements, IS-GPS-200 Table 20-IV, from a
  navigation file (:func:`distnav.formats.gnss.rinex.read_navigation`) or a georinex dataset.
* :class:`SP3Orbit` — Lagrange interpolation (order 9 = 10 samples, the usual choice for 15-min samples).
* :class:`SyntheticConstellation` — circular orbits from nominal GPS elements (a ≈ 26,560 km, i = 55°, six
  planes), 31 satellites with GPS PRN numbers and the 12 block IIF (L1/L2/L5) satellites marked, so every
  simulated experiment runs without data (paper 000 §5: "GPS block IIF satellites, currently 12").
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from distnav.errors import DataFileError, ModelError
from distnav.models.gnss.constants import (
    F_REL_S_SQRT_M,
    GM_M3_S2,
    GPS_EPOCH,
    OMEGA_E_RAD_S,
    SECONDS_PER_WEEK,
)
from distnav.models.gnss.systems import ORBIT_CONSTANTS, SYSTEM_NAMES, is_beidou_geo

__all__ = [
    "SatelliteOrbit",
    "gps_seconds",
    "datetime_from_gps_seconds",
    "BroadcastOrbit",
    "SP3Orbit",
    "SyntheticConstellation",
    "synthetic_gps_constellation",
    "lagrange_interpolate",
    "BLOCK_IIF_PRNS",
]

BLOCK_IIF_PRNS: tuple[int, ...] = (1, 3, 6, 8, 9, 10, 24, 25, 26, 27, 30, 32)
"""PRNs of the twelve GPS block IIF satellites (the L5-capable satellites of paper 000 §5, January 2018)."""

_EPOCH64 = np.datetime64(GPS_EPOCH, "ns")


def gps_seconds(t: Any) -> np.ndarray:
    """Seconds of GPS time since 1980-01-06 00:00:00 for ``datetime64`` values (or ISO strings).

    Float arrays are returned unchanged (already GPS seconds). RINEX/SP3 epochs in the GPS time system map
    directly; no leap seconds are involved.
    """
    arr = np.asarray(t)
    if np.issubdtype(arr.dtype, np.number):
        return arr.astype(float)
    arr = arr.astype("datetime64[ns]")
    return (arr - _EPOCH64).astype("timedelta64[ns]").astype(np.int64) / 1e9


def datetime_from_gps_seconds(t_gps_s: Any) -> np.ndarray:
    """Inverse of :func:`gps_seconds` (nanosecond resolution)."""
    return _EPOCH64 + (np.round(np.asarray(t_gps_s, dtype=float) * 1e9)).astype("timedelta64[ns]")


class SatelliteOrbit(Protocol):
    """What experiments and models need from an orbit source."""

    @property
    def svs(self) -> tuple[str, ...]: ...

    def positions_ecef(self, t_gps_s: np.ndarray, svs: Sequence[str] | None = None) -> np.ndarray: ...


def _select_svs(known: Sequence[str], svs: Sequence[str] | None, what: str) -> list[int]:
    if svs is None:
        return list(range(len(known)))
    index = {s: k for k, s in enumerate(known)}
    out = []
    for s in svs:
        if s not in index:
            out.append(-1)
        else:
            out.append(index[s])
    if all(k < 0 for k in out) and len(out) > 0:
        raise ModelError(f"none of the satellites {list(svs)[:6]} is in the {what}")
    return out


# ----------------------------------------------------------------------------------------------- broadcast
_NAV_FIELDS = (
    "Toe",
    "GPSWeek",
    "sqrtA",
    "Eccentricity",
    "M0",
    "DeltaN",
    "omega",
    "Omega0",
    "OmegaDot",
    "Io",
    "IDOT",
    "Cuc",
    "Cus",
    "Crc",
    "Crs",
    "Cic",
    "Cis",
    "SVclockBias",
    "SVclockDrift",
    "SVclockDriftRate",
    "TGD",
    "health",
)


def _kepler_position(
    p: dict[str, np.ndarray], tk: np.ndarray, toe_s: np.ndarray, system: str = "G", geo: bool = False
) -> tuple[np.ndarray, np.ndarray]:
    """IS-GPS-200 Table 20-IV: ECEF position at ``toe + tk``; also the eccentric anomaly (for the clock).

    Galileo and BeiDou use the same algorithm with their own GM and Ω_E (:data:`~distnav.models.gnss.systems.
    ORBIT_CONSTANTS`); a BeiDou GEO satellite (``geo``) is computed in its inertial-like frame and then rotated
    by −5° about x and Ω_E·tk about z (BeiDou ICD B1I v3.0, Table 5-11)."""
    gm, omega_e = ORBIT_CONSTANTS[system]
    a = p["sqrtA"] ** 2
    n0 = np.sqrt(gm / a**3)
    n = n0 + p["DeltaN"]
    m = p["M0"] + n * tk
    e = p["Eccentricity"]
    ecc = m.copy()
    ecc = _kepler_newton(m, e)
    nu = np.arctan2(np.sqrt(1.0 - e * e) * np.sin(ecc), np.cos(ecc) - e)
    phi = nu + p["omega"]
    s2, c2 = np.sin(2.0 * phi), np.cos(2.0 * phi)
    u = phi + p["Cus"] * s2 + p["Cuc"] * c2
    r = a * (1.0 - e * np.cos(ecc)) + p["Crs"] * s2 + p["Crc"] * c2
    inc = p["Io"] + p["Cis"] * s2 + p["Cic"] * c2 + p["IDOT"] * tk
    xp, yp = r * np.cos(u), r * np.sin(u)
    om = p["Omega0"] + (p["OmegaDot"] - (0.0 if geo else omega_e)) * tk - omega_e * toe_s
    co, so, ci, si = np.cos(om), np.sin(om), np.cos(inc), np.sin(inc)
    pos = np.stack([xp * co - yp * ci * so, xp * so + yp * ci * co, yp * si], axis=-1)
    if geo:
        pos = _beidou_geo_rotation(pos, omega_e * tk)
    return pos, ecc


def _kepler_newton(m: np.ndarray, e: np.ndarray, steps: int = 12) -> np.ndarray:
    """``steps`` Newton steps on ``E − e sin E = M`` from ``E = M``, elementwise. Within 3–4 steps every element
    either stops changing or alternates between two neighbouring doubles; once step ``k + 1`` equals step
    ``k − 1`` everywhere the sequence has period 2 from there, so the result of all ``steps`` is known without the
    rest (the same bits, ~60 % fewer sines and cosines)."""
    prev, ecc = m, m.copy()
    for k in range(steps):
        nxt = ecc - (ecc - e * np.sin(ecc) - m) / (1.0 - e * np.cos(ecc))
        if k > 0 and np.array_equal(nxt, prev):
            return nxt if (steps - k - 1) % 2 == 0 else ecc
        prev, ecc = ecc, nxt
    return ecc


_GEO_TILT_RAD = np.deg2rad(-5.0)

GALILEO_AHEAD_S = 600.0
"""How far before its time of ephemeris a Galileo record is still used (:meth:`BroadcastOrbit._pick`)."""


def _beidou_geo_rotation(pos: np.ndarray, angle_rad: np.ndarray) -> np.ndarray:
    """``R_z(Ω_E tk) R_x(−5°)`` applied to GEO positions in their frame (BeiDou ICD B1I v3.0, Table 5-11)."""
    cx, sx = np.cos(_GEO_TILT_RAD), np.sin(_GEO_TILT_RAD)
    x, y, z = pos[..., 0], pos[..., 1], pos[..., 2]
    y1, z1 = cx * y + sx * z, -sx * y + cx * z
    cz, sz = np.cos(angle_rad), np.sin(angle_rad)
    return np.stack([cz * x + sz * y1, -sz * x + cz * y1, z1], axis=-1)


@dataclass(frozen=True)
class BroadcastOrbit:
    """GPS, Galileo and BeiDou broadcast ephemerides: one table of records per satellite (IS-GPS-200 Keplerian
    elements; the other systems' constants and BeiDou GEO rotation in :func:`_kepler_position`).

    Build with :meth:`from_dataset` (a georinex navigation dataset) or
    :func:`distnav.formats.gnss.rinex.read_navigation`. For each epoch the healthy record with the nearest
    time of ephemeris within ``max_age_s`` is used (default 4 h, the curve-fit interval of the IGS merged files).
    """

    svs: tuple[str, ...]
    records: dict[str, dict[str, np.ndarray]]
    max_age_s: float = 4 * 3600.0
    source: str = ""

    @classmethod
    def from_dataset(cls, nav: Any, *, max_age_s: float = 4 * 3600.0, source: str = "") -> BroadcastOrbit:
        missing = [f for f in _NAV_FIELDS if f not in nav.data_vars]
        if missing:
            raise DataFileError(
                f"{source or 'navigation dataset'}: not a GPS navigation file (missing fields {missing[:5]})"
            )
        svs = [str(s) for s in nav.sv.values if str(s).startswith("G")]
        if not svs:
            raise DataFileError(f"{source or 'navigation dataset'}: no GPS ephemeris records")
        toc = gps_seconds(nav.time.values)
        columns: dict[str, dict[str, np.ndarray]] = {}
        for sv in svs:
            sub = nav.sel(sv=sv)
            columns[sv] = {f: np.asarray(sub[f].values, dtype=float) for f in _NAV_FIELDS}
            columns[sv]["toc_s"] = toc
        return cls.from_records(columns, max_age_s=max_age_s, source=source)

    @classmethod
    def from_records(
        cls, columns: dict[str, dict[str, np.ndarray]], *, max_age_s: float = 4 * 3600.0, source: str = ""
    ) -> BroadcastOrbit:
        """From per-satellite columns (the fields of ``_NAV_FIELDS`` and ``toc_s``, in time-of-clock order; NaN rows
        are skipped), as :func:`distnav.formats.gnss.rinex_nav.read_gps_ephemerides` gives them: the healthy
        records with a complete orbit, ordered by the time of ephemeris."""
        records: dict[str, dict[str, np.ndarray]] = {}
        for sv, cols in columns.items():
            ok = np.isfinite(cols["sqrtA"]) & np.isfinite(cols["Toe"]) & np.isfinite(cols["GPSWeek"])
            ok &= cols["health"] == 0
            if not ok.any():
                continue
            rec = {f: cols[f][ok] for f in _NAV_FIELDS}
            rec["toc_s"] = cols["toc_s"][ok]
            # the time of ephemeris in GPS seconds (a BeiDou Toe is BDT: 14 s behind)
            toe_abs = rec["GPSWeek"] * SECONDS_PER_WEEK + rec["Toe"] - cols.get("time_offset_s", np.zeros(ok.size))[ok]
            # the week of Toe may differ from the week of Toc near a week boundary: bring Toe within ±½ week
            toe_abs += SECONDS_PER_WEEK * np.round((rec["toc_s"] - toe_abs) / SECONDS_PER_WEEK)
            rec["toe_abs_s"] = toe_abs
            order = np.argsort(toe_abs, kind="stable")
            records[sv] = {f: v[order] for f, v in rec.items()}
        if not records:
            names = "/".join(sorted({SYSTEM_NAMES.get(sv[0], sv[0]) for sv in columns}))
            raise DataFileError(f"{source or 'navigation dataset'}: no healthy {names or 'GPS'} ephemeris record")
        return cls(svs=tuple(sorted(records)), records=records, max_age_s=max_age_s, source=source)

    def _pick(self, sv: str, t: np.ndarray) -> tuple[dict[str, np.ndarray], np.ndarray]:
        """The record used at each ``t``: the nearest time of ephemeris (GPS: toe is mid-fit), for Galileo the
        latest toe up to :data:`GALILEO_AHEAD_S` after ``t`` (its ephemerides are fitted forward: against GRG final
        SP3 a record is 0.9 m RMS from toe on, 8 m RMS 1–2 h before its toe), else the nearest."""
        rec = self.records[sv]
        toe = rec["toe_abs_s"]
        j = np.clip(np.searchsorted(toe, t), 1, len(toe)) if len(toe) > 1 else np.zeros(t.shape, int)
        if len(toe) > 1:
            left = j - 1
            right = np.minimum(j, len(toe) - 1)
            j = np.where(np.abs(t - toe[left]) <= np.abs(t - toe[right]), left, right)
            if sv[0] == "E":
                latest = np.searchsorted(toe, t + GALILEO_AHEAD_S, side="right") - 1
                j = np.where(latest >= 0, latest, j)
        sel = {f: v[j] for f, v in rec.items()}
        valid = np.abs(t - sel["toe_abs_s"]) <= self.max_age_s
        return sel, valid

    def positions_ecef(self, t_gps_s: np.ndarray, svs: Sequence[str] | None = None) -> np.ndarray:
        """ECEF positions ``(T, S, 3)`` [m] at GPS times ``t_gps_s`` (Earth-fixed frame at the same epoch)."""
        t = np.atleast_1d(np.asarray(t_gps_s, dtype=float))
        names = list(self.svs) if svs is None else list(svs)
        out = np.full((t.size, len(names), 3), np.nan)
        for k, _, valid, pos, _ in self._kepler_per_satellite(t, names):
            pos[~valid] = np.nan
            out[:, k] = pos
        return out

    def _kepler_per_satellite(
        self, t: np.ndarray, names: Sequence[str]
    ) -> Iterator[tuple[int, dict[str, np.ndarray], np.ndarray, np.ndarray, np.ndarray]]:
        """For every named satellite with records: its column, the records picked for ``t``, their validity, and
        the Kepler position and eccentric anomaly at ``t``."""
        for k, sv in enumerate(names):
            if sv not in self.records:
                continue
            sel, valid = self._pick(sv, t)
            pos, ecc = _kepler_position(sel, t - sel["toe_abs_s"], sel["Toe"], sv[0], is_beidou_geo(sv))
            yield k, sel, valid, pos, ecc

    def clock_offsets_s(
        self,
        t_gps_s: np.ndarray,
        svs: Sequence[str] | None = None,
        *,
        relativistic: bool = True,
        include_tgd: bool = False,
    ) -> np.ndarray:
        """Satellite clock offsets ``(T, S)`` [s]: the broadcast polynomial, plus the periodic relativistic term
        ``F e √A sin E`` (IS-GPS-200 20.3.3.3.3.1; omit it to compare with IGS/SP3 clocks, which exclude it),
        minus TGD for single-frequency L1 P(Y) users when ``include_tgd``."""
        t = np.atleast_1d(np.asarray(t_gps_s, dtype=float))
        names = list(self.svs) if svs is None else list(svs)
        out = np.full((t.size, len(names)), np.nan)
        for k, sel, valid, _, ecc in self._kepler_per_satellite(t, names):
            dt = t - sel["toc_s"]
            clk = sel["SVclockBias"] + sel["SVclockDrift"] * dt + sel["SVclockDriftRate"] * dt**2
            if relativistic:
                clk = clk + F_REL_S_SQRT_M * sel["Eccentricity"] * sel["sqrtA"] * np.sin(ecc)
            if include_tgd:
                clk = clk - sel["TGD"]
            clk[~valid] = np.nan
            out[:, k] = clk
        return out


# ----------------------------------------------------------------------------------------------- SP3
def lagrange_interpolate(t_nodes: np.ndarray, values: np.ndarray, t: np.ndarray, order: int = 9) -> np.ndarray:
    """Lagrange interpolation of ``values`` (N, ...) sampled at sorted ``t_nodes`` (N,) at times ``t`` (T,).

    Uses ``order + 1`` samples centred on each ``t`` (shifted inwards at the ends). Returns ``(T, ...)``;
    times outside ``[t_nodes[0], t_nodes[-1]]`` give NaN (no extrapolation).
    """
    tn = np.asarray(t_nodes, dtype=float)
    v = np.asarray(values, dtype=float)
    tq = np.atleast_1d(np.asarray(t, dtype=float))
    npts = order + 1
    if tn.size < npts:
        raise ModelError(f"Lagrange interpolation of order {order} needs {npts} samples, got {tn.size}")
    i0 = np.searchsorted(tn, tq) - (npts // 2)
    i0 = np.clip(i0, 0, tn.size - npts)
    idx = i0[:, None] + np.arange(npts)[None, :]  # (T, npts)
    tt = tn[idx]
    scale = max(float(np.median(np.diff(tn))), 1e-9)
    x = (tq[:, None] - tt) / scale  # (T, npts)  t − t_j
    xj = (tt[:, :, None] - tt[:, None, :]) / scale  # (T, k, j)  t_k − t_j
    eye = np.eye(npts, dtype=bool)[None]
    num = np.where(eye, 1.0, x[:, None, :])  # ∏_{j≠k} (t − t_j)
    den = np.where(eye, 1.0, xj)
    w = np.prod(num, axis=2) / np.prod(den, axis=2)  # (T, npts)
    out = np.einsum("tk,tk...->t...", w, v[idx])
    outside = (tq < tn[0]) | (tq > tn[-1])
    out[outside] = np.nan
    return np.asarray(out)


@dataclass(frozen=True)
class SP3Orbit:
    """Precise orbits from SP3 files (15-min samples), interpolated with a 9th-order Lagrange polynomial.

    ``t_gps_s`` (N,) sample epochs, ``positions_m`` (N, S, 3) ECEF metres with NaN for missing samples.
    Build with :meth:`from_datasets` (georinex SP3 datasets, several days concatenated) or
    :func:`distnav.formats.gnss.rinex.read_sp3`.
    """

    svs: tuple[str, ...]
    t_gps_s: np.ndarray
    positions_m: np.ndarray
    order: int = 9
    source: str = ""

    @classmethod
    def from_datasets(cls, datasets: Sequence[Any], *, system: str = "G", order: int = 9, source: str = "") -> SP3Orbit:
        if not datasets:
            raise DataFileError("no SP3 file given")
        svs = sorted({str(s) for ds in datasets for s in ds.sv.values if str(s).startswith(system)})
        if not svs:
            raise DataFileError(f"{source or 'SP3'}: no satellites of system {system!r}")
        times: list[np.ndarray] = []
        blocks: list[np.ndarray] = []
        for ds in datasets:
            t = gps_seconds(ds.time.values)
            pos = np.full((t.size, len(svs), 3), np.nan)
            have = [str(s) for s in ds.sv.values]
            for k, sv in enumerate(svs):
                if sv in have:
                    pos[:, k] = np.asarray(ds["position"].sel(sv=sv).values, dtype=float) * 1e3
            times.append(t)
            blocks.append(pos)
        t_all = np.concatenate(times)
        p_all = np.concatenate(blocks)
        order_idx = np.argsort(t_all, kind="stable")
        t_all, p_all = t_all[order_idx], p_all[order_idx]
        keep = np.concatenate([[True], np.diff(t_all) > 1e-6])
        t_all, p_all = t_all[keep], p_all[keep]
        bad = ~np.isfinite(p_all).all(axis=-1) | (np.abs(p_all).sum(axis=-1) < 1.0)  # SP3 writes 0.0 for "no value"
        p_all[bad] = np.nan
        return cls(svs=tuple(svs), t_gps_s=t_all, positions_m=p_all, order=order, source=source)

    def positions_ecef(self, t_gps_s: np.ndarray, svs: Sequence[str] | None = None) -> np.ndarray:
        """ECEF positions ``(T, S, 3)`` [m]; NaN outside the file span or where a needed sample is missing."""
        cols = _select_svs(self.svs, svs, "SP3 file")
        t = np.atleast_1d(np.asarray(t_gps_s, dtype=float))
        out = np.full((t.size, len(cols), 3), np.nan)
        valid_cols = [k for k, c in enumerate(cols) if c >= 0]
        if valid_cols:
            src = self.positions_m[:, [cols[k] for k in valid_cols]]
            out[:, valid_cols] = lagrange_interpolate(self.t_gps_s, src, t, order=self.order)
        return out


# ----------------------------------------------------------------------------------------------- synthetic
@dataclass(frozen=True)
class SyntheticConstellation:
    """Circular Keplerian orbits (no perturbations) in an Earth-fixed frame that coincides with the inertial
    frame at ``epoch_gps_s``.

    Per satellite: semi-major axis ``a_m``, inclination ``inc_rad``, right ascension of the ascending node
    ``raan_rad`` (inertial, at the epoch) and argument of latitude ``u0_rad`` at the epoch. ``iif`` marks the
    block IIF (L1/L2/L5) satellites.
    """

    svs: tuple[str, ...]
    a_m: np.ndarray
    inc_rad: np.ndarray
    raan_rad: np.ndarray
    u0_rad: np.ndarray
    iif: np.ndarray
    epoch_gps_s: float
    plane: np.ndarray = field(default_factory=lambda: np.zeros(0, int))

    @property
    def l5_svs(self) -> tuple[str, ...]:
        """The block IIF (L5-capable) satellites."""
        return tuple(s for s, f in zip(self.svs, self.iif, strict=True) if f)

    def subset(self, svs: Sequence[str]) -> SyntheticConstellation:
        idx = _select_svs(self.svs, svs, "synthetic constellation")
        if any(k < 0 for k in idx):
            raise ModelError(f"unknown satellites {[s for s, k in zip(svs, idx, strict=True) if k < 0]}")
        return SyntheticConstellation(
            tuple(self.svs[k] for k in idx),
            self.a_m[idx],
            self.inc_rad[idx],
            self.raan_rad[idx],
            self.u0_rad[idx],
            self.iif[idx],
            self.epoch_gps_s,
            self.plane[idx] if self.plane.size else self.plane,
        )

    def positions_ecef(self, t_gps_s: np.ndarray, svs: Sequence[str] | None = None) -> np.ndarray:
        cols = _select_svs(self.svs, svs, "synthetic constellation")
        t = np.atleast_1d(np.asarray(t_gps_s, dtype=float))[:, None] - self.epoch_gps_s
        k = np.array([c if c >= 0 else 0 for c in cols], dtype=int)
        a, inc, raan, u0 = self.a_m[k], self.inc_rad[k], self.raan_rad[k], self.u0_rad[k]
        n = np.sqrt(GM_M3_S2 / a**3)
        u = u0 + n * t  # (T, S)
        om = raan - OMEGA_E_RAD_S * t  # node longitude in the rotating frame
        xp, yp = a * np.cos(u), a * np.sin(u)
        ci, si = np.cos(inc), np.sin(inc)
        co, so = np.cos(om), np.sin(om)
        pos = np.stack([xp * co - yp * ci * so, xp * so + yp * ci * co, yp * si * np.ones_like(co)], axis=-1)
        missing = np.array([c < 0 for c in cols])
        pos[:, missing] = np.nan
        return pos


def synthetic_gps_constellation(
    *,
    epoch: str | np.datetime64 = "2018-01-10T00:00:00",
    a_m: float | None = None,
    inc_deg: float = 55.0,
    raan0_deg: float = 0.0,
    plane_phase_deg: float = 15.0,
) -> SyntheticConstellation:
    """A 31-satellite GPS-like constellation from nominal elements: six planes 60° apart in node (55°
    inclination), 6 + 5 × 5 satellites evenly spaced in each plane, adjacent planes shifted by ``plane_phase_deg``
    in argument of latitude. ``a_m`` defaults to the Keplerian semi-major axis of a period of exactly half a
    sidereal day (≈ 26,561.7 km), so the ground tracks repeat daily as GPS's do.

    PRNs 1–32 without PRN 4 (vacant in January 2018, the date of paper 000's data). The twelve block IIF PRNs
    (:data:`BLOCK_IIF_PRNS`) are spread two per plane, half a plane apart, as a synthetic stand-in for their
    real slots. The default epoch is 2018-01-10 00:00 GPS time (paper 000, Fig. 8).
    """
    per_plane = [6, 5, 5, 5, 5, 5]
    prns = [p for p in range(1, 33) if p != 4]
    iif = list(BLOCK_IIF_PRNS)
    others = [p for p in prns if p not in iif]
    svs: list[str] = []
    planes: list[int] = []
    raan: list[float] = []
    u0: list[float] = []
    flags: list[bool] = []
    for pl, count in enumerate(per_plane):
        # slots 0 and count//2 get the plane's two IIF satellites
        for slot in range(count):
            if slot in (0, count // 2):
                prn = iif.pop(0)
                flag = True
            else:
                prn = others.pop(0)
                flag = False
            svs.append(f"G{prn:02d}")
            planes.append(pl)
            raan.append(np.deg2rad(raan0_deg + 60.0 * pl))
            u0.append(np.deg2rad(plane_phase_deg * pl + 360.0 * slot / count))
            flags.append(flag)
    order = np.argsort(svs)
    t0 = float(gps_seconds(np.array(epoch, dtype="datetime64[ns]")))
    if a_m is None:
        half_sidereal_day_s = np.pi / OMEGA_E_RAD_S
        a_m = float((GM_M3_S2 * (half_sidereal_day_s / (2 * np.pi)) ** 2) ** (1.0 / 3.0))
    n = len(svs)
    return SyntheticConstellation(
        svs=tuple(svs[k] for k in order),
        a_m=np.full(n, a_m),
        inc_rad=np.full(n, np.deg2rad(inc_deg)),
        raan_rad=np.asarray(raan)[order],
        u0_rad=np.asarray(u0)[order],
        iif=np.asarray(flags)[order],
        epoch_gps_s=t0,
        plane=np.asarray(planes)[order],
    )
