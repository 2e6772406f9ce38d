"""The distributed UWB solvers' hand-over to the final LM phase: a loose iteration stopping rule must not loosen the
LM phase (``StopRule.refine_ftol`` / ``refine_xtol_m``). Reference: centralized LM (``solve_lm``) on the same
problem. Before the two were separate, ``StopRule(ftol=1e-2, xtol_m=0.5)`` made the phase say ``converged`` metres
from LM's solution on a long grid (32 × 32: 6.5 m)."""

from __future__ import annotations

import numpy as np
import pytest

from distnav.algorithms.ranging.csg import StopRule, solve
from distnav.algorithms.ranging.lm import solve_lm
from distnav.models.uwb.problems import build_problem, generate_layout


def _grid(side: int) -> object:
    rng = np.random.default_rng(0)
    pos, links = generate_layout("G", n_anchors=side * side)
    truth = np.column_stack([pos, np.zeros(side * side)])
    d = np.linalg.norm(truth[links[:, 0]] - truth[links[:, 1]], axis=1) + rng.normal(0, 0.15, links.shape[0])
    ids = [str(i) for i in range(side * side)]
    fixed = (0, 1, side)  # one corner: the far corner is weakly tied, the slow mode of the consensus iterations
    start = truth + np.column_stack([rng.uniform(-1, 1, (side * side, 2)), np.zeros(side * side)])
    return build_problem(
        ids,
        links,
        d,
        fixed={ids[i]: truth[i] for i in fixed},
        dim=3,
        held={ids[i]: {2: 0.0} for i in range(side * side) if i not in fixed},
        initial_m=start,
        truth_m=truth,
    )


@pytest.mark.parametrize("solver", ["N-CSG-TBLS", "N-CLM"])
def test_loose_handover_keeps_the_lm_phase_tight(solver: str) -> None:
    q = _grid(16)
    lm = solve_lm(q, objective="metres")
    assert lm.status == "converged"
    tight = solve(q, solver, iterations=500, objective="metres")
    loose = solve(q, solver, iterations=500, objective="metres", stop=StopRule(ftol=1e-2, xtol_m=0.5))
    assert loose.iterations < tight.iterations / 3  # the hand-over comes much earlier ...
    for res in (tight, loose):
        assert res.status == "converged" and res.settings["refine"]["status"] == "converged"
        assert np.abs(res.estimates - lm.estimates).max() < 5e-3  # ... and both end at LM's solution


def test_refine_thresholds_checked() -> None:
    from distnav.errors import ModelError

    with pytest.raises(ModelError):
        StopRule(refine_ftol=-1.0)


def test_phase_tolerances_follow_a_tighter_rule_only() -> None:
    assert StopRule().phase_tolerances == (1e-6, 1e-4)
    assert StopRule(ftol=1e-2, xtol_m=0.5).phase_tolerances == (1e-6, 1e-4)  # a loose hand-over: the phase stays
    assert StopRule(ftol=1e-9, xtol_m=1e-6).phase_tolerances == (1e-9, 1e-6)  # a tighter rule tightens it
    assert StopRule(ftol=1e-2, refine_ftol=1e-3, refine_xtol_m=1e-2).phase_tolerances == (1e-3, 1e-2)
