"""The distributed UWB solvers on the objective in metres: gradients, convergence with the stopping rule,
NLOS links found by the anchors themselves, local (conditional) precision against the centralized one, and
honest divergence."""

from __future__ import annotations

import numpy as np
import pytest

from distnav.algorithms.ranging.csg import SOLVERS, StopRule, solve, solve_csg, solve_ncsg
from distnav.algorithms.ranging.lm import solve_lm
from distnav.algorithms.ranging.neighbourhoods import Neighbourhoods
from distnav.errors import ModelError
from distnav.exchange import make_exchange
from distnav.models.uwb.problems import build_problem, rmse_m
from test_csg import check_partial_gradient


def hall(seed: int = 4, n: int = 16, sigma_m: float = 0.0, nlos: dict[int, float] | None = None, limit_m: float = 18.0):
    """Anchors at spread heights in a 24 m × 24 m × 10 m volume, links up to ``limit_m``."""
    rng = np.random.default_rng(seed)
    truth = np.column_stack([rng.uniform(0, 24, (n, 2)), rng.uniform(0, 10, n)])
    a, b = np.triu_indices(n, 1)
    d = np.linalg.norm(truth[a] - truth[b], axis=1)
    k = d < limit_m
    d = d[k] + rng.normal(0, sigma_m, int(k.sum())) if sigma_m else d[k]
    for s, bias in (nlos or {}).items():
        d[s] += bias
    ids = [str(i) for i in range(n)]
    return build_problem(
        ids,
        np.stack([a[k], b[k]], 1),
        d,
        fixed={ids[i]: truth[i] for i in range(4)},
        dim=3,
        initial_m=truth + rng.uniform(-1, 1, truth.shape),
        truth_m=truth,
    )


@pytest.mark.parametrize("loss", ["linear", "huber", "soft_l1", "cauchy"])
def test_metres_partial_gradient_matches_finite_differences(loss):
    p = hall(sigma_m=0.05, nlos={5: 2.0})
    nb = Neighbourhoods(p, make_exchange(p.graph), loss, 0.1, "metres", np.linspace(0.05, 0.1, p.n_meas))
    P = nb.initial(p.initial_m)
    diff, r = nb.geometry(P)
    w, _ = nb.rho(r)
    grad = nb.gradient(diff, r, None if loss == "linear" else w)  # Jᵀ W r = ½ ∇F⁽ⁱ⁾
    assert (
        check_partial_gradient(nb, P, grad, [(5, 0, 0), (5, 2, 1), (9, 1, 2), (13, 3, 0), (7, 0, 2)], abs_tol=1e-5) >= 3
    )


@pytest.mark.parametrize("solver", SOLVERS[1:])
def test_noise_free_metres_converges(solver):
    p = hall()
    res = solve(p, solver, iterations=3000, objective="metres", sigma_m=0.1)
    assert res.objective_kind == "metres" and res.usable
    if solver == "N-CLM":  # the local LM steps converge to the truth and the stopping rule says so
        assert res.status == "converged" and res.iterations < 3000, res.message
        assert rmse_m(p, res.estimates) < 1e-5
    else:  # the gradient steps are still closing in (linear rate) after 3000 iterations: not "converged"
        assert rmse_m(p, res.estimates) < 0.02, solver


def test_stop_rule_none_runs_every_iteration():
    p = hall()
    res = solve_ncsg(p, line_search="TBLS", iterations=300, objective="metres", stop=None)
    assert res.iterations == 300 and res.status == "max_iterations"


@pytest.mark.parametrize("solver", ["N-CSG", "N-CSG-BLS", "N-CSG-TBLS"])
def test_noisy_metres_stops_near_the_centralized_fit(solver):
    p = hall(seed=6, n=18, sigma_m=0.05)
    lm = solve_lm(p, objective="metres", sigma_m=0.05)
    res = solve(p, solver, iterations=3000, objective="metres", sigma_m=0.05, refine=False)
    if solver == "N-CSG":  # the fixed step closes in slowly: still moving after 3000 iterations, and says so
        assert res.status == "max_iterations", res.message
    else:
        assert res.status == "converged" and res.iterations < 3000, res.message
    assert np.abs(res.estimates - lm.estimates).max() < 0.05
    assert res.objective == pytest.approx(lm.objective, rel=1e-2)
    # the default final distributed LM phase (ranging_refine) reaches LM's solution, N-CSG too
    ref = solve(p, solver, iterations=3000, objective="metres", sigma_m=0.05)
    assert ref.status == "converged" and ref.settings["refine"]["status"] == "converged", ref.message
    assert np.abs(ref.estimates - lm.estimates).max() < 1e-3
    assert ref.objective == pytest.approx(lm.objective, rel=1e-7)


def test_distributed_cauchy_flags_the_nlos_links_locally():
    nlos = {3: 1.5, 17: 2.0, 40: 1.0}
    p = hall(seed=6, n=18, sigma_m=0.05, nlos=nlos)
    lm = solve_lm(p, objective="metres", sigma_m=0.05, loss="cauchy", loss_scale_m=0.15)
    assert set(np.flatnonzero(lm.tests.flagged).tolist()) == set(nlos)
    for solver, tol in (("N-CSG-TBLS", 0.1), ("N-CLM", 0.25)):
        res = solve(p, solver, iterations=3000, objective="metres", sigma_m=0.05, loss="cauchy", loss_scale_m=0.15)
        assert res.usable, res.message
        assert np.abs(res.estimates - lm.estimates).max() < tol, solver
        flagged = set(np.flatnonzero(res.tests.flagged).tolist())
        assert set(nlos) <= flagged, (solver, flagged)  # each NLOS range found by the anchor that holds it
        assert len(flagged - set(nlos)) <= 0.05 * p.n_meas, solver


def test_local_precision_is_conditional_and_never_larger_than_centralized():
    p = hall(seed=6, n=18, sigma_m=0.05)
    lm = solve_lm(p, objective="metres", sigma_m=0.05)
    res = solve(p, "N-CLM", iterations=3000, objective="metres", sigma_m=0.05)
    assert res.precision.kind == "conditional" and lm.precision.kind == "centralized"
    loc, cen = res.precision.covariance, lm.precision.covariance
    for i in np.flatnonzero(p.estimated):  # conditional ≤ marginal in the Loewner order (eigenvalues of the gap)
        assert np.linalg.eigvalsh(cen[i] - loc[i]).min() > -1e-9 * np.abs(cen[i]).max()
    e = p.estimated
    ratio = np.sqrt(np.trace(loc[e], axis1=1, axis2=2) / np.trace(cen[e], axis1=1, axis2=2))
    assert 0.2 < ratio.mean() < 1.0


def test_fixed_step_divergence_is_reported_without_estimates():
    p = hall(sigma_m=0.05)
    res = solve_csg(p, alpha=0.05, iterations=200)  # the squared form with a step far too large
    assert res.status == "diverged" and not res.usable and not res.converged
    assert np.isnan(res.estimates).all()
    assert "diverged" in res.message
    safe = solve_csg(p, iterations=200, objective="metres", sigma_m=0.05)  # the relative default step
    assert safe.usable and np.isfinite(safe.estimates).all()


def test_options_are_validated():
    p = hall()
    with pytest.raises(ModelError, match="objective"):
        solve_ncsg(p, objective="cubic")
    with pytest.raises(ModelError, match="sigma_m"):
        solve_ncsg(p, objective="metres", sigma_m=-1.0)
    with pytest.raises(ModelError, match="stopping rule"):
        StopRule(patience=0)
    with pytest.raises(ModelError, match="test_scale"):
        solve_ncsg(p, test_scale="mad")
    with pytest.raises(ModelError, match="graduated"):
        solve_ncsg(p, graduated=-1)


def test_exclusion_loop_with_a_distributed_fit():
    from distnav.algorithms.ranging.qc import exclude_links

    nlos = {3: 1.5, 17: 2.0, 40: 1.0}
    p = hall(seed=6, n=18, sigma_m=0.05, nlos=nlos)
    fit = lambda q: solve(
        q, "N-CLM", iterations=2000, objective="metres", sigma_m=0.05, loss="cauchy", loss_scale_m=0.15, refine=False
    )
    res, sub, tests = exclude_links(p, fit)
    assert set(nlos) <= set(tests.removed) and len(tests.removed) <= len(nlos) + 2
    # refined to LM's solution (the default): with the a-priori σ the local tests find exactly the NLOS links, as
    # LM's do; with the network robust scale (the default, the central test's statistic) one LOS link more (w 3.07
    # where LM's is 2.57 at the first fit: the one-end leverage, test_ranging_qc); each anchor's own robust scale
    # ("local": a median over its 5-8 links, residuals absorbed by the exact fit) is small at that solution and
    # adds 4 false exclusions here (docs/uwb.md, "Distributed solvers vs LM")
    for scale, extra in (("a-priori", 0), ("robust", 1), ("local", 4)):
        refined = lambda q, s=scale: solve(
            q,
            "N-CLM",
            iterations=2000,
            objective="metres",
            sigma_m=0.05,
            loss="cauchy",
            loss_scale_m=0.15,
            test_scale=s,
        )
        _, _, t2 = exclude_links(p, refined)
        assert set(nlos) <= set(t2.removed) and len(t2.removed) == len(nlos) + extra, (scale, t2.removed)
    assert res.usable and sub.n_meas == p.n_meas - len(tests.removed)
    assert np.isnan(tests.w[list(tests.removed)]).all()
