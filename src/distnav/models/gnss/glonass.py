"""GLONASS broadcast orbits: the ephemeris state vectors (PZ-90 position, velocity, luni-solar acceleration at the
time t_b) integrated to any epoch by 4th-order Runge–Kutta with the J2 term, GLONASS ICD 5.1 Appendix A.3.1.2:

    dx/dt = v,   dv/dt = −GM r/|r|³ − 3/2 J₂ GM a_e² r/|r|⁵ (1 − 5z²/|r|², same, 3 − 5z²/|r|²) + ω²(x, y, 0)
                 + 2ω(v_y, −v_x, 0) + a_ls

with GM = 398 600.4418 km³/s², a_e = 6 378 136 m, J₂ = 1.0826257e-3, ω = 7.292115e-5 rad/s (PZ-90.11), steps of
at most 60 s. The broadcast t_b is UTC(SU) + 3 h in the message; RINEX gives it in UTC, so GPS time = UTC +
the leap seconds of the file (18 s since 2017). Positions are PZ-90.11 (≈ ITRF within centimetres). A record is
used within ``max_age_s`` (15 min: the interval it is broadcast for) of its t_b.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

__all__ = ["GlonassOrbit", "integrate_state"]

GM_PZ90_M3_S2 = 398_600.4418e9
A_E_PZ90_M = 6_378_136.0
J2_PZ90 = 1.0826257e-3
OMEGA_PZ90_RAD_S = 7.292115e-5
_MAX_STEP_S = 60.0


def _derivative(state: np.ndarray, accel: np.ndarray) -> np.ndarray:
    """d/dt of (x, y, z, vx, vy, vz) [m, m/s] for states (N, 6) and luni-solar accelerations (N, 3)."""
    x, y, z, vx, vy, vz = state.T
    r2 = x * x + y * y + z * z
    r = np.sqrt(r2)
    gm_r3 = GM_PZ90_M3_S2 / (r2 * r)
    j2 = 1.5 * J2_PZ90 * GM_PZ90_M3_S2 * A_E_PZ90_M**2 / (r2 * r2 * r)
    zz = 5.0 * z * z / r2
    w2 = OMEGA_PZ90_RAD_S**2
    ax = -gm_r3 * x - j2 * x * (1.0 - zz) + w2 * x + 2.0 * OMEGA_PZ90_RAD_S * vy + accel[:, 0]
    ay = -gm_r3 * y - j2 * y * (1.0 - zz) + w2 * y - 2.0 * OMEGA_PZ90_RAD_S * vx + accel[:, 1]
    az = -gm_r3 * z - j2 * z * (3.0 - zz) + accel[:, 2]
    return np.stack([vx, vy, vz, ax, ay, az], axis=1)


def integrate_state(state: np.ndarray, accel: np.ndarray, dt_s: np.ndarray) -> np.ndarray:
    """States (N, 6) integrated over ``dt_s`` (N,) seconds (either sign) by RK4, the same number of steps for all
    (each at most 60 s long)."""
    dt = np.asarray(dt_s, dtype=float)
    n = max(1, int(np.ceil(np.max(np.abs(dt), initial=0.0) / _MAX_STEP_S)))
    h = (dt / n)[:, None]
    s = np.array(state, dtype=float)
    for _ in range(n):
        k1 = _derivative(s, accel)
        k2 = _derivative(s + 0.5 * h * k1, accel)
        k3 = _derivative(s + 0.5 * h * k2, accel)
        k4 = _derivative(s + h * k3, accel)
        s = s + h / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
    return s


@dataclass(frozen=True)
class GlonassOrbit:
    """GLONASS broadcast ephemerides: per satellite ``tb_gps_s`` (K,), ``state`` (K, 6) [m, m/s], ``accel``
    (K, 3) [m/s²], ``channel`` (K,), ``clock_bias_s`` (K,) (−τ_n), ``health`` (K,); healthy records only."""

    records: dict[str, dict[str, np.ndarray]]
    max_age_s: float = 900.0
    source: str = ""

    @classmethod
    def from_records(
        cls, records: dict[str, dict[str, np.ndarray]], *, max_age_s: float = 900.0, source: str = ""
    ) -> GlonassOrbit:
        """From :func:`distnav.formats.gnss.rinex_nav.read_glonass_ephemerides`: the healthy records (health 0)
        with a finite state."""
        kept: dict[str, dict[str, np.ndarray]] = {}
        for sv, rec in records.items():
            ok = (rec["health"] == 0) & np.isfinite(rec["state"]).all(axis=1) & np.isfinite(rec["accel"]).all(axis=1)
            if ok.any():
                kept[sv] = {k: v[ok] for k, v in rec.items()}
        return cls(kept, max_age_s=max_age_s, source=source)

    @property
    def svs(self) -> tuple[str, ...]:
        return tuple(sorted(self.records))

    def channels(self) -> dict[str, int]:
        """The FDMA channel of each satellite (of its last record)."""
        return {sv: int(r["channel"][-1]) for sv, r in self.records.items()}

    def positions_ecef(self, t_gps_s: np.ndarray, svs: Sequence[str] | None = None) -> np.ndarray:
        """PZ-90 positions ``(T, S, 3)`` [m] at GPS times; NaN farther than ``max_age_s`` from every record."""
        t = np.atleast_1d(np.asarray(t_gps_s, dtype=float))
        names = list(self.svs) if svs is None else list(svs)
        out = np.full((t.size, len(names), 3), np.nan)
        for k, sv in enumerate(names):
            rec = self.records.get(sv)
            if rec is None:
                continue
            tb = rec["tb_gps_s"]
            j = np.argmin(np.abs(t[:, None] - tb[None, :]), axis=1)
            ok = np.abs(t - tb[j]) <= self.max_age_s
            if ok.any():
                jj = j[ok]
                out[ok, k] = integrate_state(rec["state"][jj], rec["accel"][jj], t[ok] - tb[jj])[:, :3]
        return out
