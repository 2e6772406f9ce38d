"""The distributed solvers in ``uwb solve``'s real-data workflow (issue 13): their link tests against LM's central
ones, and the causes of their gap to LM on simulated halls (docs/uwb.md, "Distributed solvers in the workflow")."""

from __future__ import annotations

import numpy as np
import pytest

from distnav.algorithms.ranging.csg import solve
from distnav.models.uwb.problems import build_problem


def _star(seed: int = 2, sigma_m: float = 0.05):
    """4 free anchors (ids 0-3), each ranged only to the 6 known ones (ids 4-9), 2-D; one NLOS link."""
    rng = np.random.default_rng(seed)
    known = np.array([[20 * np.cos(t), 20 * np.sin(t)] for t in np.linspace(0, 2 * np.pi, 7)[:-1]])
    free = rng.uniform(-8.0, 8.0, (4, 2))
    t = np.vstack([free, known])
    links = [(i, k) for i in range(4) for k in range(4, 10)]
    r = np.array([np.linalg.norm(t[i] - t[k]) for i, k in links]) + rng.normal(0.0, sigma_m, len(links))
    r[7] += 1.2  # anchor 1's link to anchor 5 reads long
    ids = [f"A{i}" for i in range(10)]
    return build_problem(
        ids,
        links,
        list(r),
        fixed={ids[k]: t[k] for k in range(4, 10)},
        dim=2,
        truth_m=t,
        initial_m=t + rng.uniform(-0.5, 0.5, t.shape),
    )


@pytest.mark.parametrize("solver", ["N-CLM", "N-CSG-TBLS"])
def test_distributed_link_tests_equal_the_central_ones_where_the_blocks_are_exact(solver):
    """Every link joins a free anchor (the lower index: it tests the link) to a known one, so each anchor's
    conditional covariance *is* its block of LM's (JᵀJ)⁻¹ and, with the linear loss, its one-end q = 1 − h is
    LM's: with the network robust scale (the default) the distributed w equal LM's; with each anchor's own scale
    ("local", the earlier default) they do not."""
    p = _star()
    kw = dict(objective="metres", sigma_m=0.05, loss="linear")
    central = solve(p, "LM", **kw)
    assert central.tests is not None
    for scale in ("robust", "local"):
        res = solve(p, solver, iterations=300, test_scale=scale, **kw)
        assert res.tests is not None and res.converged
        assert np.max(np.abs(res.estimates - central.estimates)) < 1e-5  # the final LM phase: LM's solution
        diff = float(np.max(np.abs(res.tests.w - central.tests.w)))
        if scale == "robust":
            assert diff < 1e-3, diff
            assert np.array_equal(res.tests.flagged, central.tests.flagged) and res.tests.flagged[7]
        else:
            assert diff > 0.3, diff  # each anchor's own 6 links: another scale


def _hall(placement: str, inst: int):
    """The plant-like hall ``reproduce uwb-field`` draws as instance ``inst`` (seed 0), prepared, NLOS truth."""
    from distnav.experiments.uwb_field import PLACEMENTS, SCENARIOS, hall_problem
    from distnav.models.uwb.field import prepare
    from distnav.models.uwb.hall import HallConfig, simulate_hall

    pi = PLACEMENTS.index(placement)
    cfg = HallConfig().with_(n_anchors=28, known=placement, **SCENARIOS["plant"])
    h = simulate_hall(np.random.default_rng([0, 1000 + 100 * (pi + 1) + inst]), cfg)
    p, nlos = hall_problem(h)
    sub, geo = prepare(p)
    return sub, geo, nlos[geo.solvable[p.meas_a] & geo.solvable[p.meas_b]]


def test_network_scale_finds_the_nlos_links_an_anchors_own_scale_masks():
    """Regression (plant corner #1): an anchor with 2 NLOS links among its few partners standardized its tests by
    its own robust scale, inflated by them, and passed both (w ≈ −1.8, −1.3; LM's central test: −37, −24): the
    distributed exclusions missed them. With the network robust scale N-CLM flags the 10 NLOS links LM flags."""
    from distnav.exchange import make_exchange
    from distnav.models.uwb.field import FieldOptions, _solver_kwargs

    sub, _, nlos = _hall("corner", 1)
    kw = _solver_kwargs(FieldOptions(solver="N-CLM", nlos_loss=False))  # the first robust fit: Cauchy at 0.3 m
    lm = solve(sub, "LM", **kw)
    assert lm.tests is not None
    k = lm.tests.critical_value
    assert np.array_equal(lm.tests.w < -k, nlos)  # LM flags exactly the 10 NLOS links
    flagged = {}
    for scale in ("robust", "local"):
        res = solve(sub, "N-CLM", iterations=500, exchange=make_exchange(sub.graph), **{**kw, "test_scale": scale})
        assert res.tests is not None and np.max(np.abs(res.estimates - lm.estimates)) < 1e-3
        flagged[scale] = res.tests.w < -k
    assert np.array_equal(flagged["robust"], nlos)
    assert int((nlos & ~flagged["local"]).sum()) == 2 and not (flagged["local"] & ~nlos).any()


def test_distributed_workflow_reaches_lms_answer_on_a_folded_hall(monkeypatch):
    """Regression (plant corner #0, the folded hall): with LM's steps (one-sided loss tightened, polish) and warm
    re-fits that are the distributed LM phase from the solution, N-CLM's answer is LM's (same links excluded,
    positions within 1 mm). With 500 consensus iterations in every warm re-fit (the drift away from the solution)
    it lands in another basin (0.45 m RMSE against LM's 0.35 m)."""
    from distnav.exchange import make_exchange
    from distnav.models.uwb import field_fits
    from distnav.models.uwb.field import FieldOptions, solve_field
    from distnav.models.uwb.problems import rmse_m

    sub, geo, nlos = _hall("corner", 0)
    lm = solve_field(sub, FieldOptions(), geometry=geo)
    ex = lambda q: make_exchange(q.graph)  # noqa: E731
    d = solve_field(sub, FieldOptions(solver="N-CLM"), geometry=geo, exchange=ex)
    assert np.array_equal(d.excluded, lm.excluded) and d.excluded[nlos].sum() == 7
    assert np.max(np.abs(d.positions_m - lm.positions_m)) < 1e-3
    assert rmse_m(sub, lm.positions_m) == pytest.approx(0.354, abs=0.005)
    monkeypatch.setattr(field_fits, "WARM_ITERATIONS", 500)
    drift = solve_field(sub, FieldOptions(solver="N-CLM"), geometry=geo, exchange=ex)
    assert np.max(np.abs(drift.positions_m - lm.positions_m)) > 0.5
    assert rmse_m(sub, drift.positions_m) > rmse_m(sub, lm.positions_m) + 0.05
