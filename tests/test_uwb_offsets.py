"""``uwb solve`` with range offsets in the distributed solvers (issue 13 item 5): the APRIL lab logs against LM's
centralized common offset, and ``offsets.csv``."""

from __future__ import annotations

import csv
import json

import pytest

from distnav.cli import main
from test_uwb_april import _log


def _solve(files, out, *extra):
    assert main(["uwb", "solve", "--ranges", str(files / "ranges.csv"), "--known", str(files / "known.csv"),
                 "--truth", str(files / "truth.csv"), *extra, "--out", str(out)]) == 0
    return json.loads((out / "summary.json").read_text())


@pytest.mark.parametrize("name", ["dataset4.txt", "dataset5.txt"])
def test_april_distributed_common_offset_approaches_lm(shared_data, tmp_path, name):
    log = _log(shared_data, name)
    files = tmp_path / "april"
    assert main(["uwb", "import-april", str(log), "--out", str(files)]) == 0
    lm = _solve(files, tmp_path / "lm", "--range-offsets", "common")
    for solver, tol_m, tol_offset_m in (("N-CSG-TBLS", 0.03, 0.02), ("N-CLM", 0.06, 0.1)):
        s = _solve(files, tmp_path / solver, "--solver", solver)  # auto: the common offset
        print(name, solver, "RMSE", s["rmse_m"], "LM", lm["rmse_m"], "offset", s["offsets_m"], lm["offsets_m"])
        assert s["range_offsets"] == "common" and len(s["offsets_m"]) == 1
        assert s["rmse_m"] == pytest.approx(lm["rmse_m"], abs=tol_m)
        assert s["offsets_m"][0] == pytest.approx(lm["offsets_m"][0], abs=tol_offset_m)
        assert 0.0 < s["offsets_std_m"][0] < 0.2  # LM: 0.06–0.07 m
        rows = list(csv.DictReader((tmp_path / solver / "offsets.csv").open()))
        assert [r["id"] for r in rows] == ["common"]
        assert float(rows[0]["offset_m"]) == pytest.approx(s["offsets_m"][0], abs=1e-6)
        assert float(rows[0]["sigma_m"]) == pytest.approx(s["offsets_std_m"][0], abs=1e-6)


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
