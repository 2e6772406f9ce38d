"""Real data: the APRIL lab DW1000 network (``../shared/data/uwb/april-dw1000-8node``), through ``uwb import-april``
and ``uwb solve``, against a centralized scipy fit with a common range offset written here from the folder's
PROVENANCE.md (independently of distnav's reader and solver); and the 2-known-node case flagged as ambiguous."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest
from scipy.optimize import least_squares

from distnav.cli import main

# PROVENANCE.md: hand-calibrated antenna delays (µs), c in m/µs, ground truth in feet
DELAY_US = {
    8: 0.515375,
    12: 0.515547,
    14: 0.515818,
    16: 0.515717,
    54: 0.515316,
    61: 0.515541,
    81: 0.515397,
    87: 0.515345,
}
C = 299.792458
TRUTH_FT = {8: (0, 0), 12: (15, 1), 14: (2, 9), 54: (20, 3), 61: (10, 0), 81: (17, 7), 87: (8, 8)}
KNOWN = (8, 12, 54, 87)


def _log(shared_data: Path, name: str = "dataset4.txt") -> Path:
    p = shared_data / "uwb" / "april-dw1000-8node" / name
    assert p.is_file(), f"{p} is missing from ../shared/data (see its PROVENANCE.md)"  # ../shared exists here
    return p


def _reference_fit(log: Path, loss: str) -> tuple[dict[int, np.ndarray], float]:
    """Medians of the positive ranges per pair, then scipy least_squares (``loss``, scale 0.3 m) over the unknown
    nodes' 2-D positions and one common range offset, started at the known nodes' centroid (+ a spread)."""
    raw = np.loadtxt(log, usecols=(0, 1, 2))
    nodes = set(TRUTH_FT)
    pairs: dict[tuple[int, int], list[float]] = {}
    for t, a, b in raw:
        a, b = int(a), int(b)
        if a not in nodes or b not in nodes:
            continue
        d = (t - 0.5 * (DELAY_US[a] + DELAY_US[b])) * C
        if d > 0:
            pairs.setdefault((min(a, b), max(a, b)), []).append(d)
    keys = sorted(pairs)
    med = np.array([np.median(pairs[k]) for k in keys])
    known = {k: 0.3048 * np.array(TRUTH_FT[k], float) for k in KNOWN}
    free = sorted(nodes - set(KNOWN))
    centre = np.mean(list(known.values()), axis=0)

    def unpack(x: np.ndarray) -> dict[int, np.ndarray]:
        pos = dict(known)
        for i, k in enumerate(free):
            pos[k] = x[2 * i : 2 * i + 2]
        return pos

    def resid(x: np.ndarray) -> np.ndarray:
        pos = unpack(x)
        return np.array([np.linalg.norm(pos[a] - pos[b]) for a, b in keys]) + x[-1] - med

    def one_sided(x: np.ndarray) -> np.ndarray:  # Σ f² = Σ (r² if r ≥ 0 else s² ln(1 + r²/s²)), s = 0.3 m
        r = resid(x)
        return np.where(r >= 0, r, -0.3 * np.sqrt(np.log1p((r / 0.3) ** 2)))

    x0 = np.concatenate([centre + [0.5 * (i - 1), 0.3 * (-1) ** i] for i in range(len(free))] + [[0.0]])
    if loss == "cauchy_long":  # distnav's one-sided loss as a plain least-squares problem on transformed residuals
        sol = least_squares(one_sided, x0, xtol=1e-12, ftol=1e-12, gtol=1e-12)
    else:
        sol = least_squares(resid, x0, loss=loss, f_scale=0.3, xtol=1e-12, ftol=1e-12, gtol=1e-12)
    pos = unpack(sol.x)
    return {k: pos[k] for k in free}, float(sol.x[-1])


def _positions(path: Path) -> dict[str, dict[str, str]]:
    with path.open() as f:
        return {r["id"]: r for r in csv.DictReader(f)}


@pytest.mark.parametrize("name", ["dataset4.txt", "dataset5.txt"])
def test_april_common_offset_matches_a_scipy_fit(shared_data, tmp_path, name):
    log = _log(shared_data, name)
    files = tmp_path / "april"
    assert main(["uwb", "import-april", str(log), "--out", str(files)]) == 0
    out = tmp_path / "out"
    assert main(
        [
            "uwb",
            "solve",
            "--ranges",
            str(files / "ranges.csv"),
            "--known",
            str(files / "known.csv"),
            "--truth",
            str(files / "truth.csv"),
            "--range-offsets",
            "common",
            "--out",
            str(out),
        ]
    ) in (0, 3)
    s = json.loads((out / "summary.json").read_text())
    got = _positions(out / "positions.csv")
    # distnav's default is the one-sided Cauchy loss at 0.3 m (ranges read long; the scatter here, 0.3–0.4 m, keeps
    # the scale at 0.3 m): the careful reference uses the same loss; the symmetric Cauchy and soft-L1 losses weigh
    # the large multipath residuals (0.4 m RMS) differently (looser tolerance)
    for loss, tol in (("cauchy_long", 0.05), ("cauchy", 0.2), ("soft_l1", 0.2)):
        ref, ref_offset = _reference_fit(log, loss)
        diff = [
            np.linalg.norm([float(got[str(k)]["x_m"]) - v[0], float(got[str(k)]["y_m"]) - v[1]]) for k, v in ref.items()
        ]
        print(name, loss, "max position difference [m]", round(max(diff), 4), "offset", s["offsets_m"][0], ref_offset)
        assert max(diff) < tol, (loss, diff, s["excluded_links"])
        assert s["offsets_m"][0] == pytest.approx(ref_offset, abs=tol)
    assert s["n_dropped_samples"] > 100 and s["dropped_samples"].keys() == {"negative"}  # clock-wrap garbage
    assert s["objective"] == "metres"
    # converged; with 0.2–0.4 m of multipath scatter the link tests find only biases of 2–3 m (Baarda's MDB), and one
    # that large, undetected, would move some of the 3 free nodes more than 0.3 m and 3σ: reported weak for that
    # reason only (external reliability), the positions as before
    assert s["status"] == "weakly_determined" and s["reliability"]["tested"] and s["weak_reasons"]
    assert all(r.startswith("reliability: ") for r in s["weak_reasons"].values())
    # with a common offset the fit is better than without (issue 13: 0.41 → 0.25 m on a centralized fit)
    plain = tmp_path / "plain"
    assert main(
        [
            "uwb",
            "solve",
            "--ranges",
            str(files / "ranges.csv"),
            "--known",
            str(files / "known.csv"),
            "--truth",
            str(files / "truth.csv"),
            "--range-offsets",
            "none",
            "--out",
            str(plain),
        ]
    ) in (0, 3)
    assert s["rmse_m"] < json.loads((plain / "summary.json").read_text())["rmse_m"]
    sig = [float(got[str(k)]["sx_m"]) for k in ref]
    assert all(0.0 < v < 1.0 for v in sig)


def test_april_two_known_nodes_are_flagged_ambiguous(shared_data, tmp_path, capsys):
    log = _log(shared_data)
    files = tmp_path / "april2"
    assert main(["uwb", "import-april", str(log), "--known", "8,54", "--out", str(files)]) == 0
    out = tmp_path / "out"
    code = main(
        [
            "uwb",
            "solve",
            "--ranges",
            str(files / "ranges.csv"),
            "--known",
            str(files / "known.csv"),
            "--truth",
            str(files / "truth.csv"),
            "--range-offsets",
            "common",
            "--out",
            str(out),
        ]
    )
    assert code == 4  # ambiguous
    err = capsys.readouterr().err
    assert "ambiguous" in err and "mirror image" in err
    s = json.loads((out / "summary.json").read_text())
    assert s["status"] == "ambiguous" and s["geometry"]["issues"][0]["kind"] == "mirror"
    rows = _positions(out / "positions.csv")
    assert {r["status"] for k, r in rows.items() if k not in ("8", "54")} == {"ambiguous"}


def test_april_default_estimates_the_common_offset(shared_data, tmp_path):
    """``--range-offsets auto`` (the default) is the common offset for LM: the same solution as asking for it."""
    log = _log(shared_data)
    files = tmp_path / "april"
    assert main(["uwb", "import-april", str(log), "--out", str(files)]) == 0
    runs = {}
    for name, extra in (("default", []), ("common", ["--range-offsets", "common"])):
        assert main(
            [
                "uwb",
                "solve",
                "--ranges",
                str(files / "ranges.csv"),
                "--known",
                str(files / "known.csv"),
                "--truth",
                str(files / "truth.csv"),
                *extra,
                "--out",
                str(tmp_path / name),
            ]
        ) in (0, 3)
        runs[name] = json.loads((tmp_path / name / "summary.json").read_text())
    assert runs["default"]["range_offsets"] == "common" and len(runs["default"]["offsets_m"]) == 1
    assert runs["default"]["offsets_m"] == runs["common"]["offsets_m"]
    assert runs["default"]["rmse_m"] == runs["common"]["rmse_m"]


def test_april_common_delays_with_the_estimated_prior(shared_data, tmp_path):
    """The README's example on the real DW1000 network: ``--range-offsets common_delays --estimate-offset-prior``
    gives a usable map (exit 0 or 3) as close to the truth as the common offset's (within 1 cm of its RMSE: the
    nodes' delays were hand-calibrated before the import, so little is left for them), a common offset near the
    common-offset run's (the delays' prior holds their mean at 0, so c = 2 × the anchors' mean total delay), and
    summary.json says the prior σ was estimated."""
    log = _log(shared_data)
    files = tmp_path / "april"
    assert main(["uwb", "import-april", str(log), "--out", str(files)]) == 0
    base = ["uwb", "solve", "--ranges", str(files / "ranges.csv"), "--known", str(files / "known.csv")]
    base += ["--truth", str(files / "truth.csv")]
    runs = {}
    for name, extra in (("common", ["--range-offsets", "common"]), ("delays", ["--range-offsets", "common_delays"])):
        more = ["--estimate-offset-prior"] if name == "delays" else []
        assert main([*base, *extra, *more, "--out", str(tmp_path / name)]) in (0, 3)
        runs[name] = json.loads((tmp_path / name / "summary.json").read_text())
    d, c = runs["delays"], runs["common"]
    assert d["range_offsets"] == "common_delays" and d["offset_prior_estimated"] is True
    assert abs(d["rmse_m"] - c["rmse_m"]) < 0.01
    assert abs(d["common_offset_m"] - c["offsets_m"][0]) < 0.05
    assert abs(np.mean(d["offsets_m"]) - d["common_offset_m"] / 2) < 0.01
