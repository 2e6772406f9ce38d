"""The ranging family's options objects (``distnav.algorithms.ranging.options`` and the front doors' own: LM,
precision, refinement, problems): an object, keywords, or both run bit for bit the same; unknown or foreign
names are refused by name; values are checked when the object is made; the documented defaults."""

from __future__ import annotations

import numpy as np
import pytest

from distnav.algorithms.ranging.covariance import CentralPrecisionOptions, central_precision
from distnav.algorithms.ranging.csg import solve_csg, solve_nclm, solve_ncsg
from distnav.algorithms.ranging.lm import LMOptions, LMSolveOptions, levenberg_marquardt, solve_lm
from distnav.algorithms.ranging.neighbourhood import iterate_neighbourhood
from distnav.algorithms.ranging.objective import FitOptions
from distnav.algorithms.ranging.options import (
    CsgOptions,
    NclmOptions,
    NcsgOptions,
    NeighbourhoodOptions,
    RunOptions,
)
from distnav.algorithms.ranging.precision import PrecisionOptions, neighbourhood_precision
from distnav.errors import ModelError, UsageError
from distnav.models.uwb.problems import PaperProblemOptions, ProblemOptions, build_problem, generate_problem

SIGMA_M = 0.15


def grid(seed: int = 1):
    return generate_problem("GC", np.random.default_rng(seed), n_anchors=16, dim=2, sigma_m=SIGMA_M)


def _same(a, b) -> None:
    np.testing.assert_array_equal(a.estimates, b.estimates)
    for key in a.trace.keys():
        np.testing.assert_array_equal(a.trace[key], b.trace[key])
    assert a.message == b.message and a.settings == b.settings


@pytest.mark.parametrize(
    ("solver", "options_type", "kw"),
    [
        (solve_csg, CsgOptions, {}),
        (solve_ncsg, NcsgOptions, {"loss": "cauchy", "alpha0": 1.0}),
        (solve_nclm, NclmOptions, {"loss": "huber", "lambda0": 0.01}),
    ],
)
def test_an_object_keywords_or_both_run_the_same(solver, options_type, kw):
    p = grid()
    settings = {"objective": "metres", "sigma_m": SIGMA_M, "iterations": 40, **kw}
    by_keywords = solver(p, **settings)
    by_object = solver(p, options=options_type(**settings))
    both = solver(p, options=options_type(**{**settings, "iterations": 7}), iterations=40)
    _same(by_keywords, by_object)
    _same(by_keywords, both)
    assert by_keywords.iterations > 0


def test_unknown_and_foreign_names_are_refused_by_name():
    p = grid()
    with pytest.raises(UsageError, match="NclmOptions has no option 'lamda0' \\(did you mean 'lambda0'\\?\\)"):
        solve_nclm(p, lamda0=0.1)
    with pytest.raises(UsageError, match="NcsgOptions has no option 'lambda0'"):
        solve_ncsg(p, lambda0=0.1)  # N-CLM's damping, not N-CSG's
    with pytest.raises(UsageError, match="CsgOptions has no option 'loss'"):
        solve_csg(p, loss="huber")  # CSG has no robust loss
    with pytest.raises(UsageError, match="options must be a NclmOptions, got NcsgOptions"):
        solve_nclm(p, options=NcsgOptions())
    with pytest.raises(UsageError, match="options must be a NclmOptions"):
        next(iterate_neighbourhood(p, method="N-CLM", options=NcsgOptions()))
    with pytest.raises(UsageError, match="LMSolveOptions has no option 'max_iteration'"):
        solve_lm(p, max_iteration=3)


@pytest.mark.parametrize(
    ("make", "match"),
    [
        (lambda: NcsgOptions(beta=1.5), "beta and gamma"),
        (lambda: NcsgOptions(armijo_slope="exact"), "armijo_slope"),
        (lambda: NcsgOptions(alpha0=0.0), "alpha0 must be positive"),
        (lambda: NclmOptions(damping="marquardt"), "damping"),
        (lambda: NclmOptions(lambda_min=0.0), "lambda_min must be positive"),
        (lambda: CsgOptions(alpha=-1.0), "alpha must be positive"),
        (lambda: RunOptions(monitor_every=-1), "monitor_every"),
        (lambda: RunOptions(refine_mu0=0.0), "refine_mu0 must be positive"),
        (lambda: RunOptions(test_scale="mad"), "test_scale"),
        (lambda: RunOptions(range_offsets="common"), "objective='metres' only"),
        (lambda: NeighbourhoodOptions(loss="tukey"), "unknown loss"),
        (lambda: NeighbourhoodOptions(graduated=-1), "graduated"),
        (lambda: NeighbourhoodOptions(objective="metres", range_offsets="per_anchor", initial_offset_m=0.3), "common"),
        (lambda: NeighbourhoodOptions(initial_offset_m=0.3), "common offset's start"),
        (lambda: LMOptions(max_iterations=-1), "max_iterations"),
        (lambda: LMSolveOptions(loss="tukey"), "unknown loss"),
        (lambda: LMSolveOptions(range_offsets="common"), "objective='metres' only"),  # the shared FitOptions
        (lambda: FitOptions(objective="cubic"), "objective must be 'squared' or 'metres'"),
        # issue 29: σ was unchecked and ignored with the squared objective
        (lambda: FitOptions(sigma_m=0.1), "used by objective='metres' only"),
        (lambda: NclmOptions(sigma_m=np.full(3, 0.1)), "used by objective='metres' only"),
        (lambda: LMSolveOptions(objective="metres", sigma_m=-0.1), "sigma_m must be finite and positive"),
        (lambda: RunOptions(objective="metres", sigma_m=np.nan), "sigma_m must be finite and positive"),
        (lambda: PrecisionOptions(hops=3), "hops"),
        (lambda: CentralPrecisionOptions(range_offsets="both"), "range_offsets"),
        (lambda: PaperProblemOptions(sigma_m=-1.0), "init_halfwidth_m"),
    ],
)
def test_values_are_checked_when_the_object_is_made(make, match):
    with pytest.raises(ModelError, match=match):
        make()


def test_the_documented_defaults():
    """The steps and phases the front doors' docstrings give (paper 002's for the squared objective)."""
    assert NcsgOptions().steps() == (1e-3, 1e-2)
    assert NcsgOptions(objective="metres").steps() == (0.8, 2.0)
    assert NcsgOptions(objective="metres", alpha=0.5).steps() == (0.5, 2.0)
    assert CsgOptions().step() == 1e-3 and CsgOptions(objective="metres").step() == 0.8
    assert NeighbourhoodOptions(objective="metres", loss="cauchy", iterations=400).graduated_iterations() == 100
    assert NeighbourhoodOptions(objective="metres", iterations=400).graduated_iterations() == 0
    assert NeighbourhoodOptions(objective="metres", loss="cauchy", graduated=3).graduated_iterations() == 3
    assert RunOptions(objective="metres").refines
    assert not RunOptions(objective="metres", stop=None).refines
    assert not RunOptions().refines and RunOptions(refine=True).refines


def test_lm_takes_its_options_object():
    p = grid()
    by_keywords = solve_lm(p, objective="metres", sigma_m=SIGMA_M, loss="cauchy", max_iterations=6, ftol=1e-9)
    o = LMSolveOptions(objective="metres", sigma_m=SIGMA_M, loss="cauchy", max_iterations=6, ftol=1e-9)
    _same(by_keywords, solve_lm(p, options=o))
    assert by_keywords.settings["ftol"] == 1e-9
    x0 = np.array([3.0, -2.0])

    def fun(x):
        return np.array([x[0] - 1.0, 10.0 * (x[1] - x[0] ** 2)])

    def jac(x):
        return np.array([[1.0, 0.0], [-20.0 * x[0], 10.0]])

    a = levenberg_marquardt(fun, jac, x0, max_iterations=4)
    b = levenberg_marquardt(fun, jac, x0, options=LMOptions(max_iterations=4))
    assert a.iterations == b.iterations == 4 and np.array_equal(a.x, b.x)


def test_precision_takes_its_options_object():
    p = grid()
    kw = {"objective": "metres", "sigma_m": SIGMA_M, "hops": 2, "delay_sigma_m": 0.02}
    a = neighbourhood_precision(p, p.truth_m, **kw)
    b = neighbourhood_precision(p, p.truth_m, options=PrecisionOptions(**kw))
    np.testing.assert_array_equal(a.covariance(), b.covariance())
    c = central_precision(p, p.truth_m, sigma_m=SIGMA_M)
    d = central_precision(p, p.truth_m, options=CentralPrecisionOptions(sigma_m=SIGMA_M))
    np.testing.assert_array_equal(c.precision.covariance, d.precision.covariance)


def test_problems_take_their_options_objects():
    a = generate_problem("LM", np.random.default_rng(5), n_anchors=20, dim=2, sigma_m=0.1)
    b = generate_problem("LM", np.random.default_rng(5), options=PaperProblemOptions(n_anchors=20, dim=2, sigma_m=0.1))
    np.testing.assert_array_equal(a.range_m, b.range_m)
    np.testing.assert_array_equal(a.initial_m, b.initial_m)
    ids = ["A", "B", "C"]
    pos = np.array([[0.0, 0.0], [4.0, 0.0], [0.0, 3.0]])
    links = [("A", "B"), ("A", "C"), ("B", "C")]
    d = [4.0, 3.0, 5.0]
    fixed = {"A": pos[0], "B": pos[1]}
    x = build_problem(ids, links, d, fixed=fixed, dim=2, name="triangle")
    y = build_problem(ids, links, d, options=ProblemOptions(fixed=fixed, dim=2, name="triangle"))
    assert x.name == y.name == "triangle"
    np.testing.assert_array_equal(x.free, y.free)
    np.testing.assert_array_equal(x.positions_m, y.positions_m)
    with pytest.raises(UsageError, match="ProblemOptions has no option 'fixd'"):
        build_problem(ids, links, d, fixd=fixed, dim=2)
