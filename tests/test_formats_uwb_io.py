"""distnav.formats.uwb.io — real range logs in (issue 13, item 6): bad samples dropped and counted (``--strict``
refuses), an id typo that leaves an anchor with a single link reported, ranges in millimetres / centimetres / feet
caught."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np
import pytest

from distnav.cli import main
from distnav.errors import DataFileError
from distnav.experiments.uwb_field import write_hall
from distnav.formats.uwb.io import check_units, combine_ranges, read_positions, read_ranges, single_link_anchors
from distnav.models.uwb.hall import simulate_hall


def _hall(tmp_path: Path) -> dict[str, Path]:
    h = simulate_hall(
        np.random.default_rng(11), n_anchors=16, length_m=30.0, width_m=15.0, nlos_p1=0.0, antenna_delay_sd_m=0.0
    )
    return write_hall(h, tmp_path)


def _append(path: Path, rows: list[str]) -> None:
    path.write_text(path.read_text() + "\n".join(rows) + "\n")


def _solve(f: dict[str, Path], out: Path, *extra: str) -> int:
    return main(
        [
            "uwb",
            "solve",
            "--ranges",
            str(f["ranges"]),
            "--known",
            str(f["known"]),
            "--heights",
            str(f["heights"]),
            "--truth",
            str(f["truth"]),
            "--out",
            str(out),
            *extra,
        ]
    )


def test_bad_samples_are_dropped_counted_and_logged(tmp_path, caplog):
    f = _hall(tmp_path)
    n_good = len(f["ranges"].read_text().splitlines()) - 1
    _append(f["ranges"], ["A00,A01,-0.3", "A01,A02,0", "A02,A03,nan", "A03,A04,inf", "A04,A05,-inf", "A00,A01,0.0"])
    with caplog.at_level(logging.WARNING, logger="distnav.formats.uwb.io"):
        log = read_ranges(f["ranges"])
    assert log.range_m.size == n_good
    assert log.dropped == {"negative": 1, "zero": 2, "not finite": 3}
    assert log.dropped_lines == tuple(range(n_good + 2, n_good + 8))
    assert "dropped 6 bad range sample(s)" in caplog.text and f"lines {n_good + 2}" in caplog.text


def test_cli_drops_bad_samples_and_strict_refuses(tmp_path, capsys):
    f = _hall(tmp_path)
    _append(f["ranges"], ["A00,A01,-0.3", "A02,A03,nan"])
    assert _solve(f, tmp_path / "o") == 0
    err = capsys.readouterr().err
    assert "dropped 2 bad range sample(s)" in err
    s = json.loads((tmp_path / "o" / "summary.json").read_text())
    assert s["n_dropped_samples"] == 2 and s["dropped_samples"] == {"negative": 1, "not finite": 1}
    assert s["rmse_m"] < 0.1
    n_lines = len(f["ranges"].read_text().splitlines())
    assert _solve(f, tmp_path / "s", "--strict") == 2
    err = capsys.readouterr().err
    assert f"ranges.csv:{n_lines - 1}: negative range '-0.3' between 'A00' and 'A01'" in err
    assert not (tmp_path / "s").exists()


def test_id_typo_single_link_anchor_is_reported(tmp_path):
    f = _hall(tmp_path)
    _append(f["ranges"], ["A1O,A03,7.5", "A03,A1O,7.6"])  # letter O for zero
    warn = single_link_anchors(combine_ranges(read_ranges(f["ranges"])))
    assert len(warn) == 1 and "'A1O' has a single measured link (to 'A03')" in warn[0]
    assert "typo for 'A10'" in warn[0]
    good = single_link_anchors(combine_ranges(read_ranges(_hall(tmp_path / "g")["ranges"])))
    assert good == []


@pytest.mark.parametrize("factor, unit", [(1000.0, "millimetres"), (100.0, "centimetres"), (1 / 0.3048, "feet")])
def test_ranges_in_other_units_are_refused(tmp_path, capsys, factor, unit):
    f = _hall(tmp_path)
    log = read_ranges(f["ranges"])
    rows = ["a,b,range_m"] + [f"{a},{b},{r * factor:.1f}" for a, b, r in zip(log.a, log.b, log.range_m, strict=True)]
    f["ranges"].write_text("\n".join(rows) + "\n")
    known, _ = read_positions(f["known"])
    with pytest.raises(DataFileError, match=f"look like {unit}"):
        check_units(combine_ranges(read_ranges(f["ranges"])), known)
    assert _solve(f, tmp_path / "o") == 2
    assert f"look like {unit}" in capsys.readouterr().err


def test_known_positions_disagreeing_with_ranges_warn(tmp_path):
    f = _hall(tmp_path)
    known, _ = read_positions(f["known"])
    squeezed = {k: v * 0.4 for k, v in known.items()}  # ranges 2.5 × the known distances: a warning
    note, warn = check_units(combine_ranges(read_ranges(f["ranges"])), squeezed)
    assert warn is not None and "check the known positions" in warn


@pytest.mark.parametrize("factor", [0.15, 10.0, 1000.0 * 0.3048])  # ranges 6.7×, 0.1× (tenfold), 0.0033×
def test_known_positions_contradicting_ranges_beyond_threefold_are_refused(tmp_path, factor):
    """Issue 28, item 5: contradictions the small-unit factors do not name (ranges in km, positions in feet) were
    a warning and exit 0; refused like millimetres now."""
    f = _hall(tmp_path)
    known, _ = read_positions(f["known"])
    scaled = {k: v * factor for k, v in known.items()}
    with pytest.raises(DataFileError, match="not in the same unit"):
        check_units(combine_ranges(read_ranges(f["ranges"])), scaled)


def test_ranges_in_kilometres_without_known_pairs_are_refused(tmp_path):
    comb = combine_ranges(read_ranges(_hall(tmp_path)["ranges"]))
    km = type(comb)(comb.pairs, comb.range_m / 1000.0, comb.count, comb.mad_m)
    with pytest.raises(DataFileError, match="look like kilometres"):
        check_units(km, {})


def test_units_without_known_pairs_fall_back_to_plausible_reach(tmp_path):
    f = _hall(tmp_path)
    comb = combine_ranges(read_ranges(f["ranges"]))
    note, warn = check_units(comb, read_positions(f["known"])[0])
    assert "median of" in note and warn is None
    assert check_units(comb, {}) == ("", None)  # metres, no known pair: nothing to compare, nothing refused
    mm = type(comb)(comb.pairs, comb.range_m * 1000.0, comb.count, comb.mad_m)
    with pytest.raises(DataFileError, match="beyond UWB reach; the ranges look like millimetres"):
        check_units(mm, {})
