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


def test_the_extrapolated_tail_keeps_the_answer_for_fewer_bytes(monkeypatch):
    """``refine.EXTRAPOLATE`` (issue 27, sixth session), the whole ``uwb solve`` workflow with N-CLM on the plant-like
    hall ``[78, 0]``: with the known anchors in a corner it ends where LM's does (within 0.1 mm, the same links
    excluded) with and without it; in the middle, whose exclusion loop's fits have linear IRLS tails (the largest
    move shrinking by 0.75 a round), it sends at least 10 % fewer bytes for the same links and positions within
    0.05 mm."""
    from distnav.algorithms.ranging import refine as refine_module
    from distnav.experiments.uwb_field import hall_problem
    from distnav.models.uwb.field import FieldOptions, prepare, solve_field

    p = corner_hall()
    h = simulate_hall(np.random.default_rng([78, 0]), HallConfig().with_(known="middle", **PLANT_LIKE))
    middle, _ = prepare(hall_problem(h)[0])
    lm = solve_field(p, FieldOptions(solver="LM"))
    on = [solve_field(q, FieldOptions(solver="N-CLM")) for q in (p, middle)]
    monkeypatch.setattr(refine_module, "EXTRAPOLATE", None)
    off = [solve_field(q, FieldOptions(solver="N-CLM")) for q in (p, middle)]
    for sol in (on[0], off[0]):
        assert np.array_equal(sol.excluded, lm.excluded)
        assert np.max(np.abs(sol.positions_m - lm.positions_m)) < 1e-4
    assert np.array_equal(on[1].excluded, off[1].excluded) and on[1].status == off[1].status
    assert np.max(np.abs(on[1].positions_m - off[1].positions_m)) < 5e-5
    assert on[1].bytes < 0.9 * off[1].bytes, (on[1].bytes, off[1].bytes)


def test_a_steady_tail_is_told_from_an_unsteady_one():
    from distnav.algorithms.ranging.refine import _steady

    tail: list[float] = []
    assert not any(_steady(tail, m) for m in (8.0, 4.0))  # two steps: no ratio change to judge yet
    assert _steady(tail, 2.0)  # 0.5 twice
    assert not _steady([8.0, 4.0], 3.9)  # 0.5 then 0.975: beyond the range
    assert not _steady([8.0, 7.0], 2.0)  # 0.875 then 0.29: not steady
    assert not _steady([8.0, 4.0], 2.4)  # 0.5 then 0.6: more than 10 % apart


def test_the_forcing_term_follows_eisenstat_walker_choice_2_with_its_safeguard():
    """Hand-computed ``η_k = γ (‖g_k‖/‖g_{k−1}‖)^α`` (γ 0.9, α 2), the safeguard ``γ η_{k−1}^α`` where it exceeds
    0.1, the bounds [0.1, 0.9], η₀ 0.5 first, a round's η kept for its retries, and no stop on a step solved looser than
    CG_RTOL (after which η stays at most CG_RTOL)."""
    from distnav.algorithms.ranging.inner import Forcing

    f = Forcing(0.9, 2.0, 0.5, 0.1, 0.9)
    assert f.rtol(10.0) == 0.5  # the first round: η₀
    assert f.rtol(3.0) == 0.5  # a retry on the same linearization keeps its η
    f.linearized()
    assert f.rtol(1.0) == pytest.approx(0.9 * 0.5**2)  # raw 0.9·0.1² = 0.009 < the safeguard 0.9·0.5² = 0.225
    f.linearized()
    assert f.rtol(0.1) == 0.1  # raw 0.009, safeguard 0.9·0.225² = 0.046 < 0.1 is off: the floor
    f.linearized()
    assert f.rtol(0.1) == 0.9  # no decrease: raw 0.9, the ceiling
    f.linearized()
    assert f.rtol(0.05) == pytest.approx(0.9 * 0.9**2)  # raw 0.225 below the safeguard 0.729
    assert not f.settled()  # a step solved to 0.729 does not stop the phase (STOP_ETA = CG_RTOL)
    f.linearized()
    assert f.rtol(0.05) == 0.1  # from then on at most CG_RTOL (raw 0.9, safeguard 0.478)
    assert f.settled()


def test_the_forcing_term_stops_a_fit_only_on_a_step_solved_tightly(monkeypatch):
    """Item 33's experiment (issue 27, seventh session; off by default), expressed through the workflow's one switch:
    ``field_fits.STAGE_FORCING = FORCING_TRIED`` over ``FORCING_STAGES = EARLY_STAGES`` (every early-stopped fit),
    on the folded plant corner #0 of ``reproduce uwb-field`` with N-CLM's workflow: the workflow keeps LM's links,
    within 1 mm of LM's positions, with a stop only on a step solved to ``STOP_ETA = CG_RTOL``
    (:meth:`Forcing.settled`) and also with a stop allowed on any step (stop η 0.9, the sixth entry). The latter
    excluded a link LM keeps (14.8 mm from LM, measured) until the per-anchor check completed the early-stopped
    fits it compares (``field._repair``, the review's fix of items 24–25); the bytes of the two differ (the stop rule
    is in force), and differ from the default's (the term runs in the seed fits too)."""
    from distnav.algorithms.ranging.inner import FORCING_TRIED
    from distnav.models.uwb import field_fits
    from distnav.models.uwb.field import FieldOptions, solve_field
    from test_uwb_distributed_field import _hall

    sub, geo, _ = _hall("corner", 0)
    lm = solve_field(sub, FieldOptions(), geometry=geo)
    default = solve_field(sub, FieldOptions(solver="N-CLM"), geometry=geo)
    monkeypatch.setattr(field_fits, "FORCING_STAGES", field_fits.EARLY_STAGES)
    monkeypatch.setattr(field_fits, "STAGE_FORCING", FORCING_TRIED)
    settled = solve_field(sub, FieldOptions(solver="N-CLM"), geometry=geo)
    monkeypatch.setattr(field_fits, "STAGE_FORCING", (*FORCING_TRIED, 0.9))
    loose = solve_field(sub, FieldOptions(solver="N-CLM"), geometry=geo)
    for run in (settled, loose):
        assert np.array_equal(run.excluded, lm.excluded)
        assert np.max(np.abs(run.positions_m - lm.positions_m)) < 1e-3
    assert len({loose.bytes, settled.bytes, default.bytes}) == 3


def test_the_forcing_term_runs_only_in_the_fits_of_its_stages(monkeypatch):
    """``field_fits.STAGE_FORCING`` over ``FORCING_STAGES`` (the one switch, issue 27 items 33 and 36): with item
    33's expression (``FORCING_TRIED`` over ``EARLY_STAGES``) a fit of stage "seed" (stopped at 1 cm) runs the term
    (another count of CG iterations); with the default stages ("refit", "rung") the seed fit runs to ``CG_RTOL``
    (the same bits as off) and a "refit" fit runs the term. (A fit without a stage never reads the switch:
    ``field_fits.solve_once``; no test of it here, it could not fail.)"""
    from distnav.algorithms.ranging.inner import FORCING_TRIED
    from distnav.models.uwb import field_fits

    p = corner_hall()
    kw = {"objective": "metres", "sigma_m": 0.1, "range_offsets": "common", "quality": False}

    def fit(stage):
        return field_fits.solve_once(p, "N-CLM", dict(kw), 0, stage=stage)

    def cg(r):
        return r.settings["refine"]["cg_iterations"]

    monkeypatch.setattr(field_fits, "STAGE_FORCING", None)
    seed_off, refit_off = fit("seed"), fit("refit")
    monkeypatch.setattr(field_fits, "STAGE_FORCING", FORCING_TRIED)
    monkeypatch.setattr(field_fits, "FORCING_STAGES", field_fits.EARLY_STAGES)
    seed_on = fit("seed")
    assert cg(seed_on) != cg(seed_off)
    monkeypatch.setattr(field_fits, "FORCING_STAGES", ("refit", "rung"))
    seed_default, refit_default = fit("seed"), fit("refit")
    assert np.array_equal(seed_default.estimates, seed_off.estimates) and cg(seed_default) == cg(seed_off)
    assert cg(refit_default) != cg(refit_off)


def test_a_forcing_term_given_runs_in_any_fit_and_may_allow_any_stop():
    """``RunOptions.refine_forcing`` (issue 27, item 36; how ``field_fits.STAGE_FORCING`` reaches a fit's LM
    phase): given, it runs whatever the fit's tolerance (another count of CG iterations than the fixed CG_RTOL in
    a fit to 0.1 mm); its sixth entry is the
    loosest η whose step may stop the phase (:meth:`Forcing.settled`, hand-checked); a malformed one is refused by
    name."""
    from distnav.algorithms.ranging.csg import solve_nclm
    from distnav.algorithms.ranging.inner import FORCING_TRIED, Forcing
    from distnav.errors import ModelError

    f = Forcing(0.9, 2.0, 0.5, 0.1, 0.9, 0.9)
    assert f.rtol(10.0) == 0.5 and f.settled()  # 0.5 ≤ stop_η 0.9 (with STOP_ETA = CG_RTOL it would not stop)
    g = Forcing(0.9, 2.0, 0.5, 0.1, 0.9)
    g.rtol(10.0)
    assert not g.settled()
    p = corner_hall()
    kw = {"iterations": 0, "objective": "metres", "sigma_m": 0.1, "range_offsets": "common", "quality": False}
    fixed, given = solve_nclm(p, **kw), solve_nclm(p, **kw, refine_forcing=(*FORCING_TRIED, 0.9))
    assert given.settings["refine"]["cg_iterations"] != fixed.settings["refine"]["cg_iterations"]
    assert np.max(np.abs(given.estimates - fixed.estimates)) < 1e-3  # both stopped at 0.1 mm steps
    for bad, what in (((0.9, 2.0, 0.5), "refine_forcing must be"), ((0.9, 2.0, 0.5, 0.6, 0.4), "η values")):
        with pytest.raises(ModelError, match=what):
            solve_nclm(p, **kw, refine_forcing=bad)
    with pytest.raises(ModelError, match="refine_forcing_gamma"):
        solve_nclm(p, **kw, refine_forcing=(0.0, 2.0, 0.5, 0.1, 0.9))
