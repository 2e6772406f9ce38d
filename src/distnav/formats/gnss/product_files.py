"""Reading published DSB products and distnav's own estimates for comparison.

:func:`product_dsbs` reads each product's satellite and station DSBs of one code pair (Bias-SINEX chained across
the given files by :func:`~distnav.formats.gnss.bias_sinex.resolve_dsb`; IONEX gives P1−P2 = C1W−C2W) as
:class:`~distnav.models.gnss.products.ProductDSB`; :func:`read_estimates` reads a ``distnav gnss ionosphere``
output or a Bias-SINEX file; :func:`product_day` gives the day a product is valid for, so a product of another day
can be refused; :func:`check_orbit_day` refuses orbits (navigation or SP3 files) of another day than the
observations; :func:`correct_c1` turns C1C into C1W with a product's C1C−C1W DSBs.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from distnav.errors import DataFileError, ModelError
from distnav.formats.gnss.bias_sinex import read_bias_sinex, read_ionex_dcb, resolve_dsb
from distnav.models.gnss.constants import C_M_S
from distnav.models.gnss.products import DSBEstimates, ProductDSB
from distnav.models.gnss.systems import SYSTEM_NAMES

__all__ = [
    "product_dsbs",
    "product_day",
    "check_orbit_day",
    "check_orbit_times",
    "read_estimates",
    "estimate_systems",
    "correct_c1",
    "satellite_svns",
]


def product_day(path: str | Path) -> np.datetime64 | None:
    """The day of a product or RINEX file from an IGS long file name (``..._YYYYDDDHHMM_01D_...``) or a short
    name (``codgDDD0.YYi``, ``dgarDDD0.YYo``/``.YYd``/``.YYn``); ``None`` when the name does not say."""
    import os
    import re

    if not isinstance(path, (str, os.PathLike)):
        raise DataFileError(f"product_day needs a file name, got {path!r} ({type(path).__name__})")
    name = Path(path).name
    m = re.search(r"_(\d{4})(\d{3})\d{4}_(?:(\d{2})([SMHDWLYU])_)?", name)
    if m:
        if m.group(3) is not None and _spans_days(int(m.group(3)), m.group(4)):
            return None  # a weekly, monthly or quarterly product (``_07D_``, ``_03L_``) is valid over its span
        return np.datetime64(f"{m.group(1)}-01-01") + np.timedelta64(int(m.group(2)) - 1, "D")
    m = re.match(r"^[a-zA-Z0-9]{4}(\d{3})[0-9a-xA-X]\.(\d{2})[iIoOdDnNgG]", name)
    if m:
        year = 2000 + int(m.group(2)) if int(m.group(2)) < 80 else 1900 + int(m.group(2))
        return np.datetime64(f"{year}-01-01") + np.timedelta64(int(m.group(1)) - 1, "D")
    return _bias_sinex_day(Path(path))


def _spans_days(count: int, unit: str) -> bool:
    """Whether an IGS long name's period field (``01D``, ``15M``, ``07D``, ``03L``; units S, M, H, D, W, L month,
    Y, U unspecified) spans more than one day: such a file has no one day (as a several-day Bias-SINEX header)."""
    return (unit == "D" and count > 1) or (unit == "H" and count > 24) or unit in "WLY"


def _bias_sinex_day(path: Path) -> np.datetime64 | None:
    """The day of a Bias-SINEX file whose name does not say it (renamed, e.g. ``mybias.bia``), from its first line
    (``%=BIA 1.00 AGC CREATED AGC START END ...``) when it spans one day at most; None otherwise (not a Bias-SINEX
    file, several days). Before, such a product of another day was compared without a word."""
    import gzip

    try:
        with path.open("rb") as fh:
            head = fh.read(2)
        opener = gzip.open if head == b"\x1f\x8b" else open
        with opener(path, "rb") as fh:
            first = fh.readline(200).decode("latin-1")
    except (OSError, EOFError, ValueError):  # ValueError: a name no file can have (a NUL byte)
        return None
    fields = first.split()
    if len(fields) < 7 or not fields[0].startswith("%=BIA"):
        return None
    start, end = _sinex_day(fields[5]), _sinex_day(fields[6])
    if start is None or end is None or end - start > np.timedelta64(1, "D"):
        return None
    return start


def _orbit_epochs(orbit: Any) -> tuple[np.ndarray, float, str] | None:
    """The epochs an orbit source holds (GPS seconds: an SP3 file's samples, a navigation file's times of
    ephemeris), how far from them it gives positions [s], and what kind of file it is; None for a source that is
    not read from a file (a simulated constellation)."""
    from distnav.models.gnss.orbits import BroadcastOrbit, SP3Orbit

    if isinstance(orbit, SP3Orbit):
        return np.asarray(orbit.t_gps_s, dtype=float), 0.0, "SP3 file"
    if isinstance(orbit, BroadcastOrbit):
        toe = [np.asarray(r["toe_abs_s"], dtype=float) for r in orbit.records.values()]
        return np.concatenate(toe) if toe else np.zeros(0), float(orbit.max_age_s), "navigation file"
    return None


def _days(t_gps_s: np.ndarray) -> list[str]:
    from distnav.models.gnss.orbits import datetime_from_gps_seconds

    return sorted({str(d) for d in datetime_from_gps_seconds(t_gps_s).astype("datetime64[D]")})


def check_orbit_day(orbit: Any, observations: Sequence[Any]) -> None:
    """Refuse orbits of another day than the observations (issue 29: a navigation or SP3 file of the wrong day
    used to end in "no satellite observed above the mask"), naming the orbit file, its day(s) and the observation
    file with its day(s), in GPS time. Refused when the orbits give a position at none of a file's epochs, or when
    they share no calendar day with it (a navigation file of the day before, whose last ephemerides still reach
    into the first hours, is a file of the wrong day all the same). ``observations``: :class:`~distnav.models.gnss.
    code_observations.CodeObservations` (``time``, ``path``); an orbit not read from a file is not checked."""
    from distnav.models.gnss.orbits import gps_seconds

    for o in observations:
        check_orbit_times(orbit, gps_seconds(o.time), Path(o.path).name)


def check_orbit_times(
    orbit: Any, t_gps_s: Any, name: str, *, verb: str = "observes", what: str = "observation epochs"
) -> None:
    """:func:`check_orbit_day` for the times ``t_gps_s`` [GPS s] of one file or option, ``name`` in the message
    (``"dgar0100.24o observes 2024-01-10"``, ``"--start 2021-01-01T00:00 is on 2021-01-01"`` with ``verb="is on"``);
    ``what`` the times are."""
    held = _orbit_epochs(orbit)
    t = np.atleast_1d(np.asarray(t_gps_s, dtype=float))
    if held is None or held[0].size == 0 or t.size == 0:
        return
    epochs, reach_s, kind = held
    orbit_days = _days(epochs)
    first, last = float(epochs.min()) - reach_s, float(epochs.max()) + reach_s
    covered = (t >= first) & (t <= last)
    days = _days(t)
    if covered.any() and set(days) & set(orbit_days):
        return
    source = getattr(orbit, "source", "") or f"the {kind}"
    if set(days) & set(orbit_days):
        raise DataFileError(
            f"{source}: its orbits reach {_minute(first)} to {_minute(last)} (GPS time), none of the {what} of "
            f"{name} ({_minute(float(t.min()))} to {_minute(float(t.max()))}): give orbits that cover them"
        )
    if t.size == 1:
        reach = "its orbits do not reach it"
    else:
        share = "none" if not covered.any() else f"only {int(covered.sum())} of {t.size}"
        reach = f"its orbits reach {share} of the {what}"
    article = "an" if kind.startswith("SP3") else "a"
    raise DataFileError(
        f"{source}: {article} {kind} of {' to '.join(dict.fromkeys([orbit_days[0], orbit_days[-1]]))} (GPS "
        f"time), but {name} {verb} {', '.join(days)}: {reach}; give the {kind} of {', '.join(days)}"
    )


def _minute(t_gps_s: float) -> str:
    from distnav.models.gnss.orbits import datetime_from_gps_seconds

    return str(datetime_from_gps_seconds(t_gps_s).astype("datetime64[m]")).replace("T", " ")


def product_dsbs(
    paths: Sequence[str | Path],
    svs: Sequence[str],
    stations: Sequence[str],
    obs1: str,
    obs2: str,
    *,
    station_codes: Mapping[str, tuple[str, str]] | None = None,
) -> list[ProductDSB]:
    """Satellite and station DSBs ``obs1 − obs2`` [ns] of each product file (Bias-SINEX or IONEX).

    ``station_codes``: a station's own code pair where it differs from the satellites' (a C1C station corrected
    to C1W with the satellites' C1C−C1W DSBs keeps its receiver's C1C in its bias: its DSB is C1C−C2W)."""
    kinds: list[tuple[str, Any, Path]] = []
    for p in paths:
        path = Path(p)
        try:
            kinds.append(("sinex", read_bias_sinex(path), path))
        except DataFileError as exc_sinex:
            try:
                kinds.append(("ionex", read_ionex_dcb(path), path))
            except DataFileError as exc_ionex:
                raise DataFileError(
                    f"{path}: neither a Bias-SINEX file ({exc_sinex}) nor an IONEX file with a DCB block ({exc_ionex})"
                ) from None
    sinex = [prod for kind, prod, _ in kinds if kind == "sinex"]
    system = svs[0][0] if svs else "G"  # the stations' DSBs of the satellites' system (E: Galileo receiver DSBs)
    out: list[ProductDSB] = []
    for kind, prod, path in kinds:
        sat: dict[str, float] = {}
        sta: dict[str, float] = {}
        notes: list[str] = []
        if kind == "sinex":
            order = [prod] + [q for q in sinex if q is not prod]
            for s in svs:
                try:
                    v, chain = resolve_dsb(order, obs1, obs2, prn=s)
                except ModelError:
                    continue
                sat[s] = v
                if len(chain) > 1 or (chain and not chain[0].endswith(f"{obs1}-{obs2}")):
                    notes.append(f"{s}: {' + '.join(chain)}")
            for r in stations:
                o1, o2 = (station_codes or {}).get(r, (obs1, obs2))
                try:
                    sta[r], chain = resolve_dsb(order, o1, o2, station=r, system=system)
                except ModelError:
                    continue
                if len(chain) > 1:
                    notes.append(f"{r}: {' + '.join(chain)}")
            name = f"{prod.name} {path.name}"
        else:
            sat = {s: prod.satellite[s][0] for s in svs if s in prod.satellite}
            sta = {
                r: prod.station[("G", r.upper())][0]
                for r in stations
                if ("G", r.upper()) in prod.station and (station_codes or {}).get(r, ("C1W", "C2W")) == ("C1W", "C2W")
            }
            name = f"IONEX {path.name}"
            if (obs1, obs2) != ("C1W", "C2W"):
                notes.append(
                    f"IONEX DCBs are P1-P2 (C1W-C2W); estimates are {obs1}-{obs2}: differences include "
                    f"the satellites' {obs1}-C1W biases"
                )
        out.append(
            ProductDSB(
                name, path, kind, sat, sta, notes, product_day(path), f"{obs1}-{obs2}" if kind == "sinex" else "C1W-C2W"
            )
        )
    return out


def read_estimates(path: str | Path, *, filter_label: str = "central", system: str | None = None) -> DSBEstimates:
    """The DSBs of a ``distnav gnss ionosphere`` output (its folder or ``summary.json``) or of a Bias-SINEX file
    (one code pair: the most frequent satellite pair of ``system`` in it; default GPS, else the first system with
    satellite DSBs: :func:`estimate_systems`)."""
    import json

    p = _estimates_file(path)
    if p.suffix == ".json":
        try:
            s = json.loads(p.read_text())
            vals = s["final_dsb_ns"][filter_label]
            codes = list(s["codes"].values())
            days = tuple(sorted({np.datetime64(s["first_epoch"], "D"), np.datetime64(s["last_epoch"], "D")}))
        except (ValueError, KeyError, TypeError) as exc:
            raise DataFileError(
                f"{p}: not a `distnav gnss ionosphere` summary.json with filter {filter_label!r} "
                f"({type(exc).__name__}: {exc})"
            ) from None
        return DSBEstimates(
            str(p),
            codes[0],
            codes[1],
            {k: v for k, v in vals.items() if not k.startswith("rx:")},
            {k[3:]: v for k, v in vals.items() if k.startswith("rx:")},
            days,
        )
    prod = read_bias_sinex(p)
    found = _sinex_systems(prod)
    if not found:
        raise DataFileError(f"{p}: no satellite DSB")
    sys_ = system or ("G" if "G" in found else found[0])
    pairs: dict[tuple[str, str], int] = {}
    for r in prod.records:
        if r.kind == "DSB" and r.prn.startswith(sys_):
            pairs[(r.obs1, r.obs2)] = pairs.get((r.obs1, r.obs2), 0) + 1
    if not pairs:
        raise DataFileError(f"{p}: no {SYSTEM_NAMES.get(sys_, sys_)} satellite DSB (systems: {' '.join(found)})")
    o1, o2 = max(pairs, key=lambda k: pairs[k])
    sat = {
        r.prn: r.value
        for r in prod.records
        if r.kind == "DSB" and r.prn.startswith(sys_) and (r.obs1, r.obs2) == (o1, o2)
    }
    sta = {
        r.station[:4].upper(): r.value
        for r in prod.records
        if r.kind == "DSB" and r.station and r.system == sys_ and (r.obs1, r.obs2) == (o1, o2)
    }
    starts = {r.start for r in prod.records if r.start}
    found_days = [_sinex_day(t) for t in starts]
    days = tuple(sorted({d for d in found_days if d is not None}))
    return DSBEstimates(str(p), o1, o2, sat, sta, days)


def _estimates_file(path: str | Path) -> Path:
    p = Path(path)
    if p.is_dir():
        p = p / "summary.json"
    if not p.exists():
        raise DataFileError(f"{p}: file not found")
    return p


def _sinex_systems(prod: Any) -> list[str]:
    """The system letters of a Bias-SINEX product's satellite DSBs, GPS first, then in file order."""
    found: list[str] = []
    for r in prod.records:
        if r.kind == "DSB" and r.prn and not r.station and r.prn[:1] not in found:
            found.append(r.prn[:1])
    return sorted(found, key=lambda s: (s != "G", found.index(s)))


def estimate_systems(path: str | Path, *, filter_label: str = "central") -> list[str]:
    """The satellite systems of an estimates file (:func:`read_estimates`), GPS first: one per ``gnss compare``
    table."""
    p = _estimates_file(path)
    if p.suffix == ".json":
        est = read_estimates(p, filter_label=filter_label)
        return sorted({s[:1] for s in est.satellite}, key=lambda s: (s != "G", s)) or ["G"]
    return _sinex_systems(read_bias_sinex(p)) or ["G"]


def _sinex_day(t: str) -> np.datetime64 | None:
    try:
        y, d, _ = t.split(":")
        year = int(y) + (2000 if len(y) == 2 else 0)
        return np.datetime64(f"{year:04d}-01-01") + np.timedelta64(int(d) - 1, "D")
    except ValueError:
        return None


def correct_c1(o: Any, product: str | Path) -> Any:
    """C1C corrected to C1W with the satellites' C1C−C1W DSBs of a Bias-SINEX product: ``P1 = C1C − c·DSB``
    (biases add to the observations). Satellites the product lacks lose their L1 code (noted)."""
    from dataclasses import replace

    if o.codes.get(1) != "C1C":
        raise ModelError(f"{o.path}: --c1-corrections needs C1C on L1, the file gives {o.codes.get(1)}")
    prod = read_bias_sinex(product)
    p1 = o.range_m[1].copy()
    missing = []
    for k, sv in enumerate(o.svs):
        dsb = prod.satellite_dsb_ns(sv, "C1C", "C1W")
        if dsb is None:
            p1[:, k] = np.nan
            missing.append(sv)
        else:
            p1[:, k] -= C_M_S * 1e-9 * dsb
    note = f"C1C corrected to C1W with {prod.name} C1C-C1W satellite DSBs" + (
        f" (none for {' '.join(missing)}: dropped)" if missing else ""
    )
    return replace(o, range_m={**o.range_m, 1: p1}, codes={**o.codes, 1: "C1W"}, notes=(*o.notes, note))


def satellite_svns(paths: Sequence[str | Path]) -> dict[str, str]:
    """PRN → SVN (``G01`` → ``G063``) from the satellite records of the Bias-SINEX files among ``paths`` (IONEX
    and unreadable files are passed over: the SVNs are a courtesy of the output, not a requirement)."""
    out: dict[str, str] = {}
    for p in paths:
        try:
            prod = read_bias_sinex(p)
        except DataFileError:
            continue
        for r in prod.records:
            if r.prn and len(r.svn) == 4 and r.svn[1:].isdigit():
                out.setdefault(r.prn, r.svn)
    return out
