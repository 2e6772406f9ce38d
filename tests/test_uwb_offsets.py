"""``uwb solve`` with range offsets in the distributed solvers (issue 13 item 5): the APRIL lab logs against an
independent centralized fit with a common offset, and ``offsets.csv``."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from distnav.cli import main
from test_uwb_april import _log, _reference_fit


def _solve(files, out, *extra):
    assert (
        main(
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
                str(out),
            ]
        )
        in (0, 3)  # 3: a usable map whose anchors miss --required-accuracy-m (APRIL: 0.3 m)
    )
    return json.loads((out / "summary.json").read_text())


@pytest.mark.parametrize("name", ["dataset4.txt", "dataset5.txt"])
def test_april_distributed_common_offset_matches_a_scipy_fit(shared_data, tmp_path, name):
    """The distributed solvers with their default common offset (one-sided Cauchy 0.3 m, as LM's: the scatter here
    keeps the scale at 0.3 m) against the independent centralized scipy fit of the same objective (medians, one
    common offset, one-sided Cauchy 0.3 m: test_uwb_april's reference)."""
    log = _log(shared_data, name)
    files = tmp_path / "april"
    assert main(["uwb", "import-april", str(log), "--out", str(files)]) == 0
    ref, ref_offset = _reference_fit(log, "cauchy_long")
    plain = _solve(files, tmp_path / "plain", "--solver", "N-CLM", "--range-offsets", "none")
    # the reference fits every link; uwb solve excludes one on dataset5 (54–8, as LM). There the distributed link
    # tests (one-end leverage, 3 free nodes: their |w| up to 1.7 × LM's) also exclude 14–81 (LM's w −1.88), which
    # moves the solution 0.097 m from the reference (RMSE 0.253 m, LM's 0.321 m); on dataset4 they equal LM's
    tol = 0.05 if name == "dataset4.txt" else 0.12
    for solver, tol_m, tol_offset_m in (("N-CSG-TBLS", tol, 0.02), ("N-CLM", tol, 0.02)):  # N-CLM was 0.14 m off
        s = _solve(files, tmp_path / solver, "--solver", solver, "--loss", "cauchy")  # auto: the common offset
        got = {r["id"]: r for r in csv.DictReader((tmp_path / solver / "positions.csv").open())}
        diff = max(
            float(np.hypot(float(got[str(k)]["x_m"]) - v[0], float(got[str(k)]["y_m"]) - v[1])) for k, v in ref.items()
        )
        print(
            name,
            solver,
            "max position difference [m]",
            round(diff, 4),
            "offset",
            s["offsets_m"],
            ref_offset,
            "RMSE",
            s["rmse_m"],
        )
        assert s["range_offsets"] == "common" and len(s["offsets_m"]) == 1
        assert diff < tol_m
        assert s["offsets_m"][0] == pytest.approx(ref_offset, abs=tol_offset_m)
        assert 0.0 < s["offsets_std_m"][0] < 0.2  # LM: 0.06–0.07 m
        rows = list(csv.DictReader((tmp_path / solver / "offsets.csv").open()))
        assert [r["id"] for r in rows] == ["common"]
        assert float(rows[0]["offset_m"]) == pytest.approx(s["offsets_m"][0], abs=1e-6)
        assert float(rows[0]["sigma_m"]) == pytest.approx(s["offsets_std_m"][0], abs=1e-6)
        if solver == "N-CLM":  # the offset improves N-CLM on both datasets (0.422 → 0.318, 0.472 → 0.426 m)
            assert s["rmse_m"] < plain["rmse_m"]


def test_per_anchor_offsets_csv_and_none_writes_no_file(shared_data, tmp_path):
    files = tmp_path / "april"
    assert main(["uwb", "import-april", str(_log(shared_data)), "--out", str(files)]) == 0
    s = _solve(files, tmp_path / "per", "--solver", "N-CLM", "--range-offsets", "per_anchor")
    rows = list(csv.DictReader((tmp_path / "per" / "offsets.csv").open()))
    assert len(rows) == len(s["offsets_m"]) == s["n_solved"] == 7
    # a-posteriori: the prior σ 0.1 m (× the variance factor's root) bounds every conditional σ
    bound = 0.1 * s["variance_factor"] ** 0.5
    assert all(0.0 < float(r["sigma_m"]) <= bound * (1 + 1e-9) for r in rows), (bound, rows)
    _solve(files, tmp_path / "none", "--solver", "N-CLM", "--range-offsets", "none")
    assert not (tmp_path / "none" / "offsets.csv").exists()
