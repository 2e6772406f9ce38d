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
    assert out["combined_std_independent_ns"]["G01"] == pytest.approx(0.1 / np.sqrt(2))
    # the days agree far better than their σ: most of the daily variance repeats, so two days are not √2 better
    rep2 = np.mean([out["repeatability_ns"][k] ** 2 for k in ("G01", "G02", "G03")])
    share = 1.0 - rep2 / 0.1**2
    assert out["repeating_share"] == pytest.approx(share)
    assert out["combined_std_ns"]["G01"] == pytest.approx(np.sqrt(share * 0.01 + (1 - share) * 0.01 / 2))
    assert out["combined_ns"]["rx:BELE"] == pytest.approx(np.mean([v for v in out["daily_ns"]["rx:BELE"].values()]))
    with pytest.raises(ModelError, match="at least two"):
        combine_days({"2024-01-10": _summary(truth, rx, 0.1)})


@pytest.mark.parametrize("repeating_ns", [0.0, 0.3])
def test_combined_sigma_covers_repeating_satellite_offsets(repeating_ns: float) -> None:
    """Five days of 30 satellites whose error is a per-satellite offset repeating every day (σ_s) plus a daily
    one (σ_e = 0.2 ns), the daily σ stated as the realistic √(σ_s² + σ_e²): over 40 Monte Carlo networks the
    combined DSBs' error against the truth (in the combination's datum) over the combined σ has RMS in 0.7–1.3.
    The σ of independent days is 2× too small with the repeating offsets (the old combined σ)."""
    rng = np.random.default_rng(7)
    sigma_e, n_days, n_sat = 0.2, 5, 30
    svs = [f"G{k + 1:02d}" for k in range(n_sat)]
    daily_sd = float(np.hypot(repeating_ns, sigma_e))
    ratios, old = [], []
    for _ in range(40):
        truth = rng.normal(0.0, 3.0, n_sat)
        offset = rng.normal(0.0, repeating_ns, n_sat) if repeating_ns else np.zeros(n_sat)
        days = {}
        for d in range(n_days):
            est = truth + offset + rng.normal(0.0, sigma_e, n_sat) + rng.normal(0.0, 2.0)  # + a datum shift
            days[f"2024-01-{10 + d}"] = _summary(dict(zip(svs, est.tolist(), strict=True)), {}, daily_sd)
        out = combine_days(days)
        comb = np.array([out["combined_ns"][s] for s in svs])
        err = (comb - comb.mean()) - (truth - truth.mean())  # both in the zero-mean datum
        ratios.append(err / np.array([out["combined_std_ns"][s] for s in svs]))
        old.append(err / np.array([out["combined_std_independent_ns"][s] for s in svs]))
    rms = float(np.sqrt(np.mean(np.square(ratios))))
    assert 0.7 < rms < 1.3, rms
    rms_old = float(np.sqrt(np.mean(np.square(old))))
    if repeating_ns:
        assert rms_old > 1.6, rms_old  # the σ of independent days does not cover the repeating part
    else:
        assert 0.7 < rms_old < 1.3


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
