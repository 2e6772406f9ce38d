"""distnav.formats.uwb: the UWB file formats live there and the UWB models write no file (issue 25, item 5)."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from distnav.formats.uwb.hall_files import HALL_FILES, hall_csv_texts
from distnav.formats.uwb.io import format_positions, read_heights, read_positions
from distnav.models.uwb.hall import simulate_hall

MODELS_UWB = Path(__file__).resolve().parents[1] / "src" / "distnav" / "models" / "uwb"
WRITES = re.compile(r"write_text\(|write_bytes\(|os\.replace\(|savefig\(|open\([^)]*['\"][wa]b?['\"]")


def test_uwb_models_write_no_file() -> None:
    offenders = [
        f"{p.name}:{n}"
        for p in sorted(MODELS_UWB.glob("*.py"))
        for n, line in enumerate(p.read_text(encoding="utf-8").splitlines(), 1)
        if WRITES.search(line)
    ]
    assert offenders == []


def test_the_pattern_sees_a_writer() -> None:  # the check above can fail
    assert WRITES.search('path.write_text("x")') and WRITES.search("open(p, 'w')") and not WRITES.search("open(p)")


def test_positions_round_trip(tmp_path: Path) -> None:
    pos = np.array([[1.0, 2.0, 3.0], [-4.25, 5.5, 0.125]])
    f = tmp_path / "p.csv"
    f.write_text(format_positions(["A", "B"], pos))
    back, dim = read_positions(f)
    assert dim == 3 and set(back) == {"A", "B"}
    np.testing.assert_allclose(back["B"], pos[1], atol=1e-6)


def test_hall_files_read_back(tmp_path: Path) -> None:
    h = simulate_hall(np.random.default_rng(3), n_anchors=12, length_m=20.0, width_m=10.0)
    texts = hall_csv_texts(h)
    assert tuple(texts) == HALL_FILES
    for stem, text in texts.items():
        (tmp_path / f"{stem}.csv").write_text(text)
    truth, _ = read_positions(tmp_path / "truth.csv")
    np.testing.assert_allclose(np.array([truth[k] for k in h.ids]), h.truth_m, atol=1e-4)
    z, _ = read_heights(tmp_path / "heights.csv")
    np.testing.assert_allclose([z[k] for k in h.ids], h.surveyed_z_m, atol=1e-4)
