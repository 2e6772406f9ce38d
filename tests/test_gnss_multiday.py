"""Several days: per-day solutions combined in one datum, day-to-day repeatability; day grouping of files."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from distnav.cli import main
from distnav.errors import ModelError
from distnav.models.gnss.multiday import combine_days


def _summary(sat: dict[str, float], rx: dict[str, float], sd: float) -> dict[str, object]:
    vals = {**{f"rx:{k}": v for k, v in rx.items()}, **sat}
    return {
        "final_dsb_ns": {"central": vals},
        "final_dsb_std_realistic_ns": {"central": {k: sd for k in vals}},
        "final_dsb_std_ns": {"central": {k: sd / 4 for k in vals}},
    }


def test_combination_aligns_datums_and_gives_repeatability() -> None:
    truth = {"G01": -1.0, "G02": 0.5, "G03": 0.5}
    rx = {"BELE": 2.0}
    # day 2: the same biases in a datum shifted by c = 0.7 (satellites −c, receiver +c), one satellite +0.2 off,
    # and an extra satellite seen that day only
    day2 = {"G01": -1.7, "G02": -0.2 + 0.2, "G03": -0.2, "G04": 3.0}
    out = combine_days({"2024-01-10": _summary(truth, rx, 0.1), "2024-01-11": _summary(day2, {"BELE": 2.7}, 0.1)})
    assert out["common_satellites"] == ["G01", "G02", "G03"]
    # after alignment (each day zero-mean over the common satellites) the days agree except G02's 0.2 ns
    d = {k: v["2024-01-11"] - v["2024-01-10"] for k, v in out["daily_ns"].items() if len(v) == 2}
    assert d["G02"] - d["G01"] == pytest.approx(0.2) and d["G03"] == pytest.approx(d["G01"])
    assert out["repeatability_ns"]["G02"] == pytest.approx(abs(d["G02"]) / np.sqrt(2))
    assert out["repeatability_ns"]["G04"] is None and np.isfinite(out["combined_ns"]["G04"])
    assert out["combined_std_ns"]["G01"] == pytest.approx(0.1 / np.sqrt(2))
    assert out["combined_ns"]["rx:BELE"] == pytest.approx(np.mean([v for v in out["daily_ns"]["rx:BELE"].values()]))
    with pytest.raises(ModelError, match="at least two"):
        combine_days({"2024-01-10": _summary(truth, rx, 0.1)})


def test_days_need_their_navigation_file(shared_data: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    d = shared_data / "gnss/igs_2024010_bele_dgar"
    days = [str(d / "BELE00BRA_R_20240100000_01D_30S_MO.crx.gz"), str(d / "BELE00BRA_R_20240110000_01D_30S_MO.crx.gz")]
    rc = main(
        [
            "gnss",
            "ionosphere",
            "--obs",
            *days,
            "--nav",
            str(d / "brdc0100.24n.gz"),
            str(d / "BRDC00IGS_R_20240100000_01D_MN.rnx.gz"),
            "--out",
            str(tmp_path),
            "--no-progress",
        ]
    )
    assert rc == 2 and "no --nav file of 2024-01-11" in capsys.readouterr().err
    rc = main(
        [
            "gnss",
            "ionosphere",
            "--obs",
            *days,
            "--nav",
            str(d / "brdc0100.24n.gz"),
            "--tlim",
            "2024-01-10T00:00",
            "2024-01-10T01:00",
            "--out",
            str(tmp_path),
            "--no-progress",
        ]
    )
    assert rc == 2 and "--tlim selects a window of one day" in capsys.readouterr().err
    rc = main(
        [
            "gnss",
            "ionosphere",
            "--obs",
            *days,
            "--nav",
            str(d / "brdc0100.24n.gz"),
            str(d / "brdc0110.24n.gz"),
            str(d / "BRDC00IGS_R_20240100000_01D_MN.rnx.gz"),
            "--out",
            str(tmp_path),
            "--no-progress",
        ]
    )
    assert rc == 2 and "two --nav files of the same day" in capsys.readouterr().err
