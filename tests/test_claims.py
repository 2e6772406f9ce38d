"""Claims that need their own experiment: when N-CSG-BLS and N-CSG-TBLS differ (paper 002 §3.3, §5)."""

from __future__ import annotations

import numpy as np
import pytest

from distnav.algorithms.ranging.csg import solve
from distnav.models.uwb.problems import generate_problem


@pytest.fixture(scope="module")
def ladder():
    # a small 2-D ladder started far from the truth (±30 m): the partial costs are far from quadratic
    return generate_problem("LC", np.random.default_rng(2), n_anchors=20, dim=2, init_halfwidth_m=30.0)


def _pair(problem, **options):
    bls = solve(problem, "N-CSG-BLS", iterations=30, **options)
    tbls = solve(problem, "N-CSG-TBLS", iterations=30, **options)
    steps = np.asarray(bls.trace["step_size"]), np.asarray(tbls.trace["step_size"])
    return np.asarray(bls.estimates), np.asarray(tbls.estimates), steps


def test_bls_and_tbls_are_identical_with_the_papers_armijo_constant(ladder):
    """γ = 1/2: every accepted α ≤ f⁽ⁱ⁾/(γ‖d‖²) (f ≥ 0), and there the Armijo set was one interval, so both pick
    the same α₀βᵏ at every iteration and the runs are identical (docs/claims.md)."""
    xb, xt, (sb, st) = _pair(ladder, gamma=0.5)
    assert np.array_equal(sb, st) and np.array_equal(xb, xt)


def test_bls_and_tbls_differ_with_a_small_armijo_constant(ladder):
    """γ = 1e-4 admits steps across a second valley of the quartic partial cost: the accepted set splits and
    TBLS (climbing from the previous α, stopping at the first failure) picks a smaller step than BLS."""
    xb, xt, (sb, st) = _pair(ladder, gamma=1e-4)
    first = int(np.argmax(sb != st))
    assert np.any(sb != st) and 0 < first < 30
    assert st[first] < sb[first]  # same iterate, TBLS stopped below the gap that BLS jumped over
    assert np.abs(xb - xt).max() > 0.5  # metres


def test_claims_table_reads_the_horizontal_start_run_after_uwb(tmp_path):
    """``RUN_DIR/uwb-horizontal`` (``reproduce uwb --start horizontal``) adds its "< 60 cm" row after uwb's; a
    run without the setting is not mistaken for it."""
    import json

    from distnav.experiments.claims_table import collect

    checks = {"mean_line_search_RMSE_by_class_m": {"G": 0.35, "L": 0.8, "R": 0.5}}
    for folder, start in (("uwb-horizontal", "horizontal"), ("other", None)):
        (tmp_path / folder).mkdir()
        settings = {"iterations": 500, "instances": {"G": 1}, **({"start": start} if start else {})}
        (tmp_path / folder / "results.json").write_text(json.dumps({"settings": settings, "checks": checks}))
    rows = collect(tmp_path)
    assert [r["experiment"] for r in rows] == ["uwb-horizontal", "uwb-horizontal"]  # < 60 cm, then < 50 cm
    assert rows[1]["verdict"] == "not checkable" and "results.json lacks 'table'" in rows[1]["why"]
    assert rows[0]["verdict"] == "agree" and rows[0]["distnav_value"] == "G: 0.35 m, L: 0.80 m, R: 0.50 m"
    (tmp_path / "uwb-horizontal" / "results.json").write_text(json.dumps({"settings": {}, "checks": checks}))
    assert collect(tmp_path)[0]["verdict"] == "not checkable"
