"""The distributed solvers' final LM phase (algorithms/ranging_refine.py): it reaches LM's least-squares solution
where the consensus iterations stop short (plant-like hall, known anchors in a corner), with every offset mode and
robust loss, says ``converged`` only when it is, and is not run in the paper's mode."""

from __future__ import annotations

import numpy as np
import pytest

from distnav.algorithms.ranging.csg import solve
from distnav.algorithms.ranging.lm import solve_lm
from distnav.algorithms.ranging.objective import range_sigma
from distnav.algorithms.ranging.refine import refine
from distnav.exchange import make_exchange
from distnav.models.uwb.hall import PLANT_LIKE, HallConfig, simulate_hall
from distnav.models.uwb.problems import build_problem

OPTS = {
    "objective": "metres",
    "sigma_m": 0.1,
    "loss": "cauchy",
    "loss_scale_m": 0.3,
    "range_offsets": "common",
    "offset_prior_sigma_m": 0.1,
}


def corner_hall():
    """A plant-like hall with the known anchors in a corner (seed [78, 0] of docs/uwb.md's Monte Carlo), heights
    held, median ranges, the MDS start of ``uwb solve``."""
    from distnav.experiments.uwb_field import hall_problem
    from distnav.models.uwb.field import prepare

    h = simulate_hall(np.random.default_rng([78, 0]), HallConfig().with_(known="corner", **PLANT_LIKE))
    p, _ = hall_problem(h)
    sub, _ = prepare(p)
    return sub


@pytest.mark.parametrize("solver", ["N-CLM", "N-CSG-TBLS"])
def test_corner_hall_reaches_lm_where_the_iterations_stopped_short(solver):
    p = corner_hall()
    lm = solve_lm(p, **OPTS)  # from the same start, graduated (linear, then Cauchy) as the distributed solvers
    assert lm.status == "converged"
    sigma = lm.precision.std(a_posteriori=False)
    res = solve(p, solver, iterations=500, **OPTS)
    # before the refinement phase: 'max_iterations' 1.7–2.4 m from LM's solution (up to 11 σ) on this hall
    assert res.status == "converged", res.message
    z = np.abs(res.estimates - lm.estimates)[p.free] / sigma[p.free]
    assert z.max() < 0.2, (z.max(), res.message)
    assert res.objective == pytest.approx(lm.objective, rel=1e-6)
    assert res.offsets_m == pytest.approx(lm.offsets_m, abs=1e-4)


@pytest.mark.parametrize(("offsets", "loss"), [("none", "linear"), ("common", "huber"), ("per_anchor", "cauchy")])
def test_refinement_matches_lm_for_every_offset_mode(offsets, loss):
    rng = np.random.default_rng(5)
    n = 14
    truth = np.column_stack([rng.uniform(0, 20, (n, 2)), rng.uniform(0, 6, n)])
    a, b = np.triu_indices(n, 1)
    d = np.linalg.norm(truth[a] - truth[b], axis=1)
    k = d < 15.0
    delays = rng.normal(0.0, 0.05, n)
    rng_m = d[k] + rng.normal(0, 0.05, int(k.sum())) + 0.2 + delays[a[k]] + delays[b[k]]
    rng_m[3] += 1.2  # one NLOS link
    ids = [str(i) for i in range(n)]
    p = build_problem(
        ids,
        np.stack([a[k], b[k]], 1),
        rng_m,
        fixed={ids[i]: truth[i] for i in range(4)},
        dim=3,
        initial_m=truth + rng.uniform(-1, 1, truth.shape),
        truth_m=truth,
    )
    opts = {**OPTS, "loss": loss, "sigma_m": 0.05, "range_offsets": offsets}
    lm = solve_lm(p, **opts)
    res = solve(p, "N-CSG-TBLS", iterations=20, **opts)  # 20 iterations: far from the solution
    early = solve(p, "N-CSG-TBLS", iterations=20, refine=False, **opts)
    assert np.abs(early.estimates - lm.estimates).max() > 0.05
    assert res.status == "converged" and res.settings["refine"]["status"] == "converged", res.message
    assert np.abs(res.estimates - lm.estimates).max() < 1e-3
    if offsets != "none":
        assert np.asarray(res.offsets_m) == pytest.approx(np.asarray(lm.offsets_m), abs=1e-3)
    # the messages of the refinement are counted: more than the 20 iterations alone
    assert res.comm.messages > early.comm.messages


def test_refinement_says_max_iterations_when_its_rounds_run_out():
    p = corner_hall()
    ex = make_exchange(p.graph)
    sigma = range_sigma(p, 0.1)
    assert p.initial_m is not None
    out = refine(
        p,
        ex,
        p.initial_m[ex.nodes],
        np.zeros(ex.n_local),
        sigma=sigma,
        scale=0.3 / sigma,
        loss="cauchy",
        range_offsets="common",
        offset_prior_sigma_m=0.1,
        ftol=1e-6,
        xtol_m=1e-4,
        max_rounds=1,
    )
    assert out.status == "max_iterations" and out.rounds == 1
    full = refine(
        p,
        ex,
        p.initial_m[ex.nodes],
        np.zeros(ex.n_local),
        sigma=sigma,
        scale=0.3 / sigma,
        loss="cauchy",
        range_offsets="common",
        offset_prior_sigma_m=0.1,
        ftol=1e-6,
        xtol_m=1e-4,
    )
    assert full.status == "converged" and full.objective < out.objective


def test_paper_mode_and_squared_objective_do_not_refine():
    p = corner_hall()
    for kw in ({"objective": "metres", "sigma_m": 0.1, "stop": None}, {"objective": "squared"}):
        res = solve(p, "N-CLM", iterations=30, **kw)
        assert "refine" not in res.settings and "distributed LM" not in res.message


def test_the_lm_phase_reports_its_final_damping_and_starts_from_a_given_one():
    """``settings["refine"]["mu"]`` is the phase's damping at the end (divided by 3 per accepted step from MU0);
    ``refine_mu0`` starts it there: from the truth's neighbourhood both reach LM's solution (issue 27)."""
    from distnav.algorithms.ranging.csg import solve_nclm
    from distnav.algorithms.ranging.lm import solve_lm
    from distnav.algorithms.ranging.refine import MU0
    from test_csg_metres import hall

    p = hall(sigma_m=0.02)
    lm = solve_lm(p, objective="metres", sigma_m=0.1)
    a = solve_nclm(p, iterations=0, objective="metres", sigma_m=0.1, quality=False)
    mu = a.settings["refine"]["mu"]
    assert 0 < mu < MU0
    b = solve_nclm(p, iterations=0, objective="metres", sigma_m=0.1, quality=False, refine_mu0=mu)
    for r in (a, b):
        assert r.status == "converged" and np.max(np.abs(r.estimates - lm.estimates)) < 1e-3
    assert b.settings["refine"]["mu"] < mu


def test_the_extrapolated_tail_keeps_lms_answer_for_fewer_bytes(monkeypatch):
    """``refine.EXTRAPOLATE`` (issue 27, sixth session): on the plant-like corner hall ``[78, 0]`` the whole
    ``uwb solve`` workflow with N-CLM ends where LM's does (within 0.1 mm, the same links excluded, as without it)
    and sends fewer bytes than with it off — its fits' IRLS tails shrink by a steady ratio there."""
    from distnav.algorithms.ranging import refine as refine_module
    from distnav.models.uwb.field import FieldOptions, solve_field

    p = corner_hall()
    lm = solve_field(p, FieldOptions(solver="LM"))
    on = solve_field(p, FieldOptions(solver="N-CLM"))
    monkeypatch.setattr(refine_module, "EXTRAPOLATE", None)
    off = solve_field(p, FieldOptions(solver="N-CLM"))
    for sol in (on, off):
        assert np.array_equal(sol.excluded, lm.excluded)
        assert np.max(np.abs(sol.positions_m - lm.positions_m)) < 1e-4
    assert on.bytes < 0.97 * off.bytes, (on.bytes, off.bytes)


def test_a_steady_tail_is_told_from_an_unsteady_one():
    from distnav.algorithms.ranging.refine import _steady

    tail: list[float] = []
    assert not any(_steady(tail, m) for m in (8.0, 4.0))  # two steps: no ratio change to judge yet
    assert _steady(tail, 2.0)  # 0.5 twice
    assert not _steady([8.0, 4.0], 3.9)  # 0.5 then 0.975: beyond the range
    assert not _steady([8.0, 7.0], 2.0)  # 0.875 then 0.29: not steady
    assert not _steady([8.0, 4.0], 2.4)  # 0.5 then 0.6: more than 10 % apart
