"""The held-out workflow end to end on files the test writes: RINEX 2.11 (C1/P1/P2/L1/L2) of two simulated
mid-latitude stations on two days, SP3 orbits, IONEX files with the AUX DCB block; `gnss ionosphere` on both days
in one command with `--l1-code C1W`, then `gnss compare` of the output folder against the IONEX files. The second
day's files are partly Unix-compressed (``.Z``, as in older IGS archives)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from distnav.cli import main
from distnav.models.gnss.constants import C_M_S, GPS_FREQUENCIES_HZ
from distnav.models.gnss.netsim import NetworkSimOptions, simulate_network
from distnav.models.gnss.orbits import datetime_from_gps_seconds, gps_seconds, synthetic_gps_constellation

STATIONS = {"SIMA": (49.14, 12.88, 650.0), "SIMB": (50.80, 10.20, 400.0)}
RX_DSB = {"SIMA": 4.0, "SIMB": -6.0}
DAYS = ("2024-01-10", "2024-01-11")


def _line(content: str, label: str) -> str:
    return f"{content:<60}{label}\n"


def _write_rinex2(path: Path, o: object, c1_minus_p1_ns: dict[str, float]) -> None:
    """RINEX 2.11 observation file: C1 P1 P2 L1 L2 (C1 = P1 + the satellite's C1−P1 bias)."""
    time = o.time  # type: ignore[attr-defined]
    svs = o.svs  # type: ignore[attr-defined]
    t0 = time[0].astype("datetime64[s]").item()
    xyz = o.position_ecef_m  # type: ignore[attr-defined]
    out = [
        _line("     2.11           OBSERVATION DATA    G (GPS)", "RINEX VERSION / TYPE"),
        _line("distnav test        distnav             20240110 000000 UTC", "PGM / RUN BY / DATE"),
        _line(o.station, "MARKER NAME"),  # type: ignore[attr-defined]
        _line("test                distnav", "OBSERVER / AGENCY"),
        _line("1                   TRIMBLE NETR9       5.45", "REC # / TYPE / VERS"),
        _line("1                   TRM59800.00     NONE", "ANT # / TYPE"),
        _line(f"{xyz[0]:14.4f}{xyz[1]:14.4f}{xyz[2]:14.4f}", "APPROX POSITION XYZ"),
        _line(f"{0.0:14.4f}{0.0:14.4f}{0.0:14.4f}", "ANTENNA: DELTA H/E/N"),
        _line("     1     1", "WAVELENGTH FACT L1/2"),
        _line("     5    C1    P1    P2    L1    L2", "# / TYPES OF OBSERV"),
        _line("    30.000", "INTERVAL"),
        _line(
            f"{t0.year:6d}{t0.month:6d}{t0.day:6d}{t0.hour:6d}{t0.minute:6d}{float(t0.second):13.7f}     GPS",
            "TIME OF FIRST OBS",
        ),
        _line("", "END OF HEADER"),
    ]
    p1, p2 = o.range_m[1], o.range_m[2]  # type: ignore[attr-defined]
    l1 = o.phase_m[1] / (C_M_S / GPS_FREQUENCIES_HZ[1])  # type: ignore[attr-defined]
    l2 = o.phase_m[2] / (C_M_S / GPS_FREQUENCIES_HZ[2])  # type: ignore[attr-defined]
    c1 = p1 + np.array([c1_minus_p1_ns[s] for s in svs]) * C_M_S * 1e-9
    for k, t in enumerate(time):
        up = [j for j in range(len(svs)) if np.isfinite(p1[k, j])]
        if not up:
            continue
        d = t.astype("datetime64[s]").item()
        head = (
            f" {d.year % 100:02d}{d.month:3d}{d.day:3d}{d.hour:3d}{d.minute:3d}{float(d.second):11.7f}  0{len(up):3d}"
        )
        names = "".join(svs[j] for j in up)
        out.append(head + names[:36] + "\n")
        for c in range(36, len(names), 36):
            out.append(" " * 32 + names[c : c + 36] + "\n")
        for j in up:
            out.append("".join(f"{v:14.3f}  " for v in (c1[k, j], p1[k, j], p2[k, j], l1[k, j], l2[k, j])) + "\n")
    path.write_text("".join(out))


def _write_sp3(path: Path, orbit: object, day: str) -> None:
    t = gps_seconds(np.datetime64(f"{day}T00:00:00")) + 900.0 * np.arange(96)
    svs = list(orbit.svs)  # type: ignore[attr-defined]
    pos = orbit.positions_ecef(t, svs) / 1e3  # type: ignore[attr-defined]
    d0 = np.asarray(datetime_from_gps_seconds(t[0])).astype("datetime64[s]").item()
    out = [
        f"#cP{d0.year:4d} {d0.month:2d} {d0.day:2d} {0:2d} {0:2d} {0.0:11.8f} {96:7d} ORBIT IGS14 FIT  TEST\n",
        "## 2296 259200.00000000   900.00000000 60319 0.0000000000000\n",
    ]
    ids = "".join(svs) + "  0" * (85 - len(svs))
    for row in range(5):
        chunk = ids[row * 51 : (row + 1) * 51]
        out.append((f"+   {len(svs):2d}   " if row == 0 else "+        ") + chunk + "\n")
    out += ["%c G  cc GPS ccc cccc cccc cccc cccc ccccc ccccc ccccc ccccc\n", "/* synthetic orbits written by a test\n"]
    for k, tk in enumerate(t):
        d = np.asarray(datetime_from_gps_seconds(tk)).astype("datetime64[s]").item()
        out.append(f"*  {d.year:4d} {d.month:2d} {d.day:2d} {d.hour:2d} {d.minute:2d} {float(d.second):11.8f}\n")
        for j, s in enumerate(svs):
            out.append(f"P{s}{pos[k, j, 0]:14.6f}{pos[k, j, 1]:14.6f}{pos[k, j, 2]:14.6f}{0.0:14.6f}\n")
    out.append("EOF\n")
    path.write_text("".join(out))


def _write_ionex(path: Path, sat_ns: dict[str, float], rx_ns: dict[str, float]) -> None:
    text = (
        _line("     1.0            IONOSPHERE MAPS     GPS", "IONEX VERSION / TYPE")
        + _line("DIFFERENTIAL CODE BIASES", "START OF AUX DATA")
        + "".join(_line(f"   {s}{v:10.3f}{0.010:10.3f}", "PRN / BIAS / RMS") for s, v in sat_ns.items())
        + "".join(_line(f"   G  {r} 00000M000{v:16.3f}{0.050:10.3f}", "STATION / BIAS / RMS") for r, v in rx_ns.items())
        + _line("DIFFERENTIAL CODE BIASES", "END OF AUX DATA")
        + _line("", "END OF HEADER")
    )
    path.write_text(text)


def _unix_compress(path: Path) -> Path:
    ncompress = pytest.importorskip("ncompress")
    out = path.with_name(path.name + ".Z")
    out.write_bytes(ncompress.compress(path.read_bytes()))
    path.unlink()
    return out


@pytest.fixture(scope="module")
def heldout(tmp_path_factory: pytest.TempPathFactory) -> dict[str, object]:
    d = tmp_path_factory.mktemp("heldout")
    orbit = synthetic_gps_constellation(epoch="2024-01-10T00:00:00")
    rng = np.random.default_rng(11)
    sat = {s: float(v) for s, v in zip(orbit.svs, rng.normal(0, 3, len(orbit.svs)), strict=True)}
    c1p1 = {s: float(v) for s, v in zip(orbit.svs, rng.normal(0, 1, len(orbit.svs)), strict=True)}
    files: dict[str, list[str]] = {"obs": [], "sp3": [], "ionex": []}
    for k, day in enumerate(DAYS):
        sim = simulate_network(
            orbit,
            day,
            NetworkSimOptions(hours=3.0),
            rng=np.random.default_rng([k, 3]),
            stations=STATIONS,
            satellite_dsb_ns=sat,
            receiver_dsb_ns=RX_DSB,
        )
        doy = int(str(np.datetime64(day) - np.datetime64("2024-01-01")).split()[0]) + 1
        for o in sim.observations:
            p = d / f"{o.station.lower()}{doy:03d}0.24o"
            _write_rinex2(p, o, c1p1)
            files["obs"].append(str(_unix_compress(p) if (k, o.station) == (1, "SIMB") else p))
        sp3 = d / f"IGS0OPSFIN_2024{doy:03d}0000_01D_15M_ORB.SP3"
        _write_sp3(sp3, orbit, day)
        if k == 1:  # older IGS archives: Unix compress (.Z)
            sp3 = _unix_compress(sp3)
        files["sp3"].append(str(sp3))
        # a product: the truth in its own zero-mean datum, with 0.05 ns of product noise
        noise = np.random.default_rng([k, 9]).normal(0, 0.05, len(sat))
        vals = {s: v + e for (s, v), e in zip(sat.items(), noise, strict=True)}
        mean = float(np.mean(list(vals.values())))
        ionex = d / f"codg{doy:03d}0.24i"
        _write_ionex(ionex, {s: v - mean for s, v in vals.items()}, {r: v + mean for r, v in RX_DSB.items()})
        files["ionex"].append(str(_unix_compress(ionex) if k == 1 else ionex))
    return {"dir": d, **files}


def test_two_days_of_rinex2_with_sp3_and_ionex(heldout: dict[str, object], capsys: pytest.CaptureFixture[str]) -> None:
    d = Path(str(heldout["dir"]))
    out = d / "run"
    rc = main(
        [
            "gnss",
            "ionosphere",
            "--obs",
            *heldout["obs"],
            "--sp3",
            *heldout["sp3"],  # type: ignore[misc]
            "--l1-code",
            "C1W",
            "--interval",
            "60",
            "--bias",
            *heldout["ionex"],
            "--out",
            str(out),
            "--compare-exclude",
            "G01",
            "--no-progress",
        ]
    )
    cap = capsys.readouterr()
    text = cap.out
    assert rc == 0, cap.out + cap.err
    assert "worst-fitting satellite: G01" in text
    multi = json.loads((out / "multiday.json").read_text())
    assert sorted(multi["days"]) == list(DAYS)
    assert multi["worst_fitting"]["satellite"] == "G01" and multi["worst_fitting"]["stands_out_days"] == 2
    assert "IONEX" in multi["worst_fitting_vs_product"]  # G01 left out there: another one
    assert "worst-fitting satellite over the days (own residuals): G01 (2 of 2 days, standing out on 2)" in text
    for day, doy in zip(DAYS, (10, 11), strict=True):
        s = json.loads((out / day / "summary.json").read_text())
        assert s["codes"] == {"L1": "C1W", "L2": "C2W"}
        assert s["satellite_fit"]["worst_fitting"]["satellite"] == "G01"
        assert s["satellite_fit"]["worst_fitting"]["stands_out"]  # robust z 7–21 (real data: ≤ 2.1)
        (name,) = [k for k in s["comparison"] if k.startswith("IONEX")]
        assert f"codg{doy:03d}0.24i" in name  # each day against its own product
        c = s["comparison"][name]["central"]
        # 3 h of two stations vs the truth; the default leaves out satellites tracked for under a quarter of the
        # best-tracked one's station-epochs (named in the notes), so 10 or more of them are compared
        assert c["n"] >= 10 and c["rms_zero_mean_ns"] < 0.6
        assert any("not estimated, fewer than" in note for note in s.get("notes", [])), s.get("notes")
        assert max(abs(v) for v in c["receivers"]["difference_ns"].values()) < 0.7
    # gnss compare of the whole output folder: each day against the IONEX file of that day
    rc = main(
        [
            "gnss",
            "compare",
            "--estimates",
            str(out),
            "--bias",
            *heldout["ionex"],  # type: ignore[misc]
            "--exclude",
            "G01",
            "--out",
            str(d / "cmp"),
        ]
    )
    cap = capsys.readouterr()
    text = cap.out
    assert rc == 0, cap.out + cap.err
    cmp = json.loads((d / "cmp" / "comparison.json").read_text())
    assert sorted(cmp["days"]) == list(DAYS)
    for day in DAYS:
        (prod,) = cmp["days"][day]["products"].values()
        assert prod["n"] >= 10 and prod["rms_zero_mean_ns"] < 0.6 and "G01" not in prod["difference_ns"]
    assert "median over 2 days" in text
    # a product of another day is refused for one day's solution unless told
    assert main(["gnss", "compare", "--estimates", str(out / DAYS[0]), "--bias", heldout["ionex"][1]]) == 2  # type: ignore[index]
