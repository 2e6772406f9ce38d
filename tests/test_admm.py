"""ADMM with constraint nodes (paper 000 Fig. 6) against the centralized BLUE, and its nonlinear variants."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import least_squares

from distnav.algorithms.lsq.admm import (
    AdmmOptions,
    AdmmRunOptions,
    XUpdate,
    admm,
    admm_linearized,
    admm_nonlinear,
    gauss_newton,
    iterate_admm,
    range_positioning_problem,
)
from distnav.algorithms.lsq.blue import LinearProblem, blue, single_consensus_admm
from distnav.algorithms.lsq.nonlinear import LinearizedOptions, NonlinearOptions
from distnav.errors import ModelError, UsageError
from distnav.exchange import FaultSchedule, make_exchange
from distnav.network import builders
from distnav.network.constraint_nodes import choose_constraint_nodes
from distnav.network.graph import Graph


def singular_problem(rng: np.random.Generator, n: int, m: int, p: int, full_R: bool = True) -> LinearProblem:
    """Random problem with m < p rows per node (every N_i singular), full R_i, rank(A) = p."""
    A = rng.normal(size=(n, m, p))
    x = rng.normal(size=p)
    y = np.einsum("nmp,p->nm", A, x) + 0.1 * rng.normal(size=(n, m))
    R = None
    if full_R:
        M = rng.normal(size=(n, m, m))
        R = 0.1 * (M @ M.transpose(0, 2, 1)) + 0.05 * np.eye(m)
    prob = LinearProblem.from_stacked(A, y, R)
    assert all(np.linalg.matrix_rank(N) < p for N in prob.normal_equations[0])
    return prob


@pytest.fixture(scope="module")
def case():
    rng = np.random.default_rng(7)
    g = builders.connected_random_geometric(24, mean_degree=5, rng=rng)
    prob = singular_problem(rng, 24, 3, 6)
    return g, prob, blue(prob).x


@pytest.mark.parametrize("choice", ["all", "min_cover"])
def test_admm_equals_blue(case, choice):
    g, prob, xh = case
    res = admm(prob, g, constraint_nodes=choice, W=20.0, max_iterations=5000, tol=1e-12, reference=xh)
    assert res.converged and res.status == "converged"
    rel = np.linalg.norm(res.estimates - xh, axis=1).max() / np.linalg.norm(xh)
    assert rel < 1e-8
    # the constraint nodes' consensus states agree with x̂ too
    assert np.linalg.norm(res.z - xh, axis=1).max() / np.linalg.norm(xh) < 1e-8
    tr = res.trace
    assert tr["distance_to_reference"].shape == (res.iterations + 1, g.n_nodes)
    assert tr["primal_residual"].shape == (res.iterations + 1,)
    its = res.iterations_to
    assert its["0.0001"] <= its["1e-06"] <= its["1e-08"] <= res.iterations


def test_admm_with_spd_weight_matrix_and_other_seed():
    rng = np.random.default_rng(11)
    g = builders.connected_random_geometric(15, mean_degree=4, rng=rng)
    prob = singular_problem(rng, 15, 2, 4)
    xh = blue(prob).x
    M = rng.normal(size=(4, 4))
    W = M @ M.T + np.eye(4)
    res = admm(prob, g, W=W, max_iterations=8000, tol=1e-12, reference=xh)
    assert res.converged
    assert np.linalg.norm(res.estimates - xh, axis=1).max() / np.linalg.norm(xh) < 1e-8


def test_x_update_forms_agree(case):
    g, prob, _ = case
    C = choose_constraint_nodes(g, "min_cover")
    c = C.per_node_count.astype(float)
    W = np.diag([0.5, 1, 2, 1, 1, 3.0])
    rng = np.random.default_rng(0)
    lvals = rng.normal(size=(g.n_nodes, 6))
    # independent form: x = (N_i + c_i W)⁻¹ (r_i + c_i W l_i)
    N, r = prob.normal_equations
    ref = np.stack([np.linalg.solve(N[i] + c[i] * W, r[i] + c[i] * W @ lvals[i]) for i in range(g.n_nodes)])
    for method in ("normal", "observation", "cholesky"):
        np.testing.assert_allclose(XUpdate(prob, W, c, method)(lvals), ref, rtol=1e-10, atol=1e-12)
    assert XUpdate(prob, W, c, "auto").method == "observation"  # m = 3 < p = 6
    runs = {
        m: admm(prob, g, constraint_nodes=C, W=W, x_update=m, max_iterations=60, tol=0.0)
        for m in ("normal", "observation", "cholesky")
    }
    np.testing.assert_allclose(runs["normal"].estimates, runs["observation"].estimates, rtol=1e-9, atol=1e-11)
    np.testing.assert_allclose(runs["normal"].estimates, runs["cholesky"].estimates, rtol=1e-9, atol=1e-11)


def test_aggregated_messages_give_the_same_iterates(case):
    g, prob, xh = case
    a = admm(prob, g, W=1.0, max_iterations=200, tol=0.0, reference=xh)
    b = admm(prob, g, W=1.0, max_iterations=200, tol=0.0, reference=xh, messages="aggregated")
    np.testing.assert_allclose(a.estimates, b.estimates, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(a.trace["primal_residual"], b.trace["primal_residual"], rtol=1e-8, atol=1e-12)
    np.testing.assert_allclose(a.trace["dual_residual"], b.trace["dual_residual"], rtol=1e-8, atol=1e-12)
    # same messages per iteration (aggregated adds one initialization round)
    assert a.comm.messages_per_round[1:].tolist() == b.comm.messages_per_round[2:].tolist()


def test_aggregated_chunks_change_no_bit_and_residual_matches_the_pairs(case, monkeypatch):
    """The aggregated kernel's elementwise updates run a chunk of rows at a time and its pair residual fills a free
    buffer a chunk of pairs at a time: rows of 5 give bitwise the iterates of one pass, and the primal residual is
    ``sqrt(Σ_{s∈C} Σ_{i∈N_s} ‖x_i − z_s‖²)`` recomputed here from the graph (pairs of 16: the buffer path)."""
    import distnav.algorithms.lsq.aggregated as agg

    g, prob, _ = case
    C = choose_constraint_nodes(g, "min_cover")

    def run() -> list:
        ex = make_exchange(g, order="rcm")
        gen = iterate_admm(prob, g, constraint_nodes=C, W=2.0, exchange=ex, messages="aggregated")
        return [(ex, next(gen)) for _ in range(8)]

    base = run()
    monkeypatch.setattr(agg, "_ROW_CHUNK", 5)
    monkeypatch.setattr(agg, "_PAIR_CHUNK", 16)
    for (_, a), (ex, b) in zip(base, run(), strict=True):
        assert np.array_equal(a.x, b.x) and np.array_equal(a.z, b.z)
        assert a.dual_residual == b.dual_residual and a.u_norm == b.u_norm
        x, z = ex.gather_nodes(b.x), ex.gather_nodes(b.z)
        s, i = g.dst, g.src  # every directed edge i → s with s ∈ C is a pair, and (s, s) for s ∈ C
        on = C.mask[s]
        ref = np.sum((x[i[on & (i != s)]] - z[s[on & (i != s)]]) ** 2) + np.sum((x[C.mask] - z[C.mask]) ** 2)
        np.testing.assert_allclose(b.primal_residual, np.sqrt(ref), rtol=1e-12)


def test_message_counts_match_the_pairs(case):
    g, prob, _ = case
    C = choose_constraint_nodes(g, "min_cover")
    res = admm(prob, g, constraint_nodes=C, W=1.0, max_iterations=5, tol=0.0)
    # every pair (i, s), s ≠ i, is a link with s ∈ C; per iteration one message each way
    inC = C.mask
    links = g.links
    directed_pairs = int(inC[links[:, 0]].sum() + inC[links[:, 1]].sum())
    per_round = res.comm.messages_per_round
    assert per_round.size == 1 + 2 * 5
    assert per_round.tolist() == [directed_pairs] * per_round.size
    assert res.comm.bytes == per_round.sum() * 6 * 8


def test_fig6_reduces_to_single_consensus_admm_with_one_hub():
    """Complete graph, C = {0}: N_0 = all nodes, so Fig. 6 is eq. (16) with z = z_0 (an independent code path)."""
    rng = np.random.default_rng(3)
    prob = singular_problem(rng, 6, 2, 3)
    g = builders.complete(6)
    ref = single_consensus_admm(prob, W=0.7, iterations=15, z0=np.array([1.0, -2.0, 0.5]))
    states = iterate_admm(prob, g, constraint_nodes=[0], W=0.7, init=np.array([1.0, -2.0, 0.5]))
    xs = [next(states).x for _ in range(16)][1:]
    np.testing.assert_allclose(np.stack(xs), ref.trace["x"], rtol=1e-11, atol=1e-12)


def test_literal_fig6_weighting_is_biased_on_irregular_graphs_but_not_on_regular_ones(case):
    g, prob, xh = case
    lit = admm(prob, g, constraint_nodes="all", W=20.0, x_weight="fig6", max_iterations=6000, tol=1e-13)
    assert lit.converged  # it does converge ...
    assert np.linalg.norm(lit.estimates - xh, axis=1).max() / np.linalg.norm(xh) > 1e-4  # ... to another point
    # on a ring with C = all nodes every c_i = 3: the literal form is ADMM with pair weight W/3, unbiased
    rng = np.random.default_rng(5)
    prob_r = singular_problem(rng, 10, 2, 4)
    xr = blue(prob_r).x
    ring = admm(
        prob_r, builders.ring(10), constraint_nodes="all", W=1.0, x_weight="fig6", max_iterations=8000, tol=1e-13
    )
    assert np.linalg.norm(ring.estimates - xr, axis=1).max() / np.linalg.norm(xr) < 1e-8


def test_initial_values_given_and_previous_solution(case):
    g, prob, xh = case
    cold = admm(prob, g, W=20.0, max_iterations=5000, tol=0.0, stop_at_reference=1e-8, reference=xh)
    near = admm(prob, g, W=20.0, max_iterations=5000, tol=0.0, stop_at_reference=1e-8, reference=xh, init=xh + 1e-3)
    assert near.iterations < cold.iterations
    # warm start from a previous run's solution (§4.3): continues from where it stopped
    first = admm(prob, g, W=20.0, max_iterations=100, tol=0.0, reference=xh)
    again = admm(prob, g, W=20.0, max_iterations=0, tol=0.0, reference=xh, init=first)
    np.testing.assert_array_equal(again.estimates, first.estimates)
    warm = admm(prob, g, W=20.0, max_iterations=5000, tol=0.0, stop_at_reference=1e-8, reference=xh, init=first)
    assert warm.iterations < cold.iterations
    zero = admm(prob, g, W=20.0, max_iterations=3, tol=0.0, init="zero")
    zero2 = admm(prob, g, W=20.0, max_iterations=3, tol=0.0, init=np.zeros(6), z0=0.0)
    np.testing.assert_array_equal(zero.estimates, zero2.estimates)


def test_message_drops_still_converge_and_are_reproducible(case):
    g, prob, xh = case
    faults = FaultSchedule(drop_probability=0.2, seed=4)
    a = admm(prob, g, W=20.0, max_iterations=400, tol=0.0, reference=xh, faults=faults)
    b = admm(prob, g, W=20.0, max_iterations=400, tol=0.0, reference=xh, exchange=make_exchange(g, faults=faults))
    c = admm(
        prob, g, W=20.0, max_iterations=400, tol=0.0, reference=xh, faults=FaultSchedule(drop_probability=0.2, seed=5)
    )
    np.testing.assert_array_equal(a.estimates, b.estimates)
    assert not np.array_equal(a.estimates, c.estimates)
    assert a.comm.messages_dropped > 0.15 * a.comm.messages
    # the last value received stands in for a lost one; the fixed point is unchanged
    full = admm(prob, g, W=20.0, max_iterations=3000, tol=1e-12, reference=xh, faults=faults)
    assert full.converged
    assert np.linalg.norm(full.estimates - xh, axis=1).max() / np.linalg.norm(xh) < 1e-8
    with pytest.raises(ModelError, match="messages='aggregated' keeps multiplier sums"):
        admm(prob, g, W=20.0, max_iterations=5, messages="aggregated", faults=faults)


def test_silent_node_runs(case):
    g, prob, xh = case
    res = admm(prob, g, W=20.0, max_iterations=50, tol=0.0, reference=xh, faults=FaultSchedule(silent_nodes=((3, 10),)))
    assert np.all(np.isfinite(res.estimates))


@pytest.mark.parametrize(
    ("kwargs", "pattern"),
    [
        (dict(x_weight="paper"), "x_weight must be"),
        (dict(messages="edges"), "messages must be"),
        (dict(x_update="lu"), "unknown x-update method"),
        (dict(max_iterations=-1), "max_iterations must be"),
        (dict(tol=-1.0), "tol \\(relative tolerance\\) must be 0 or more"),
        (dict(reference=np.zeros(3)), "reference must be a length-6"),
        (dict(init="previous"), "init must be 'zero'"),
        (dict(init=np.zeros(5)), "init must be a scalar"),
        (dict(init=np.full(6, np.nan)), "non-finite"),
        (dict(z0=np.zeros((2, 6))), "z0 must be"),
        (dict(W=-1.0), "must be finite and > 0"),
        (dict(faults=FaultSchedule(drop_probability=0.1), exchange="x"), "either to the exchange"),
    ],
)
def test_admm_validation(case, kwargs, pattern):
    g, prob, _ = case
    with pytest.raises(ModelError, match=pattern):
        admm(prob, g, **{"max_iterations": 2, **kwargs})


def test_admm_validation_graph_mismatch(case):
    g, prob, _ = case
    with pytest.raises(ModelError, match="the problem has 24 nodes, the graph 10"):
        admm(prob, builders.ring(10))
    with pytest.raises(ModelError, match="chosen on a different graph"):
        admm(prob, g, constraint_nodes=choose_constraint_nodes(builders.ring(24), "all"))
    with pytest.raises(ModelError, match="exchange was built on a different graph"):
        admm(prob, g, exchange=make_exchange(builders.ring(24)))
    with pytest.raises(ModelError, match="monitor_every must be"):
        next(iterate_admm(prob, g, messages="aggregated", monitor_every=-1))


# ------------------------------------------------------------------------------------------ nonlinear
@pytest.fixture(scope="module")
def ranges():
    rng = np.random.default_rng(21)
    g = builders.connected_random_geometric(20, mean_degree=5, rng=rng, size=100.0)
    targets = np.array([[30.0, 60.0], [70.0, 25.0]])
    prob = range_positioning_problem(g.positions, targets, sigma_m=0.5, rng=rng)
    x0 = targets.ravel() + rng.uniform(-5, 5, 4)
    return g, prob, x0


def test_gauss_newton_matches_scipy(ranges):
    g, prob, x0 = ranges
    gn = gauss_newton(prob, x0)
    nodes = np.arange(g.n_nodes)
    ls = least_squares(
        lambda x: (prob.y - prob.model.predict(np.broadcast_to(x, (g.n_nodes, 4)), nodes)).ravel() / 0.5,
        x0,
        xtol=1e-15,
        ftol=1e-15,
        gtol=1e-15,
    )
    assert gn.converged
    np.testing.assert_allclose(gn.estimates[0], ls.x, atol=1e-7)


def test_linearized_admm_matches_gauss_newton(ranges):
    g, prob, x0 = ranges
    xg = gauss_newton(prob, x0).estimates[0]
    res = admm_linearized(prob, g, x0, W=1.0, reference=xg, inner_tol=1e-12)
    assert res.converged
    assert np.abs(res.estimates - xg).max() < 1e-6
    assert res.trace["spread"][-1] < 1e-8  # the nodes' approximate values stay identical (§4.3)
    assert res.comm.rounds > 0


def test_nonlinear_x_update_admm_matches_gauss_newton(ranges):
    g, prob, x0 = ranges
    xg = gauss_newton(prob, x0).estimates[0]
    res = admm_nonlinear(prob, g, x0, W=1.0, reference=xg, max_iterations=3000, tol=1e-11)
    assert res.converged
    assert np.abs(res.estimates - xg).max() < 1e-6
    with pytest.raises(ModelError, match="gn_steps must be"):
        admm_nonlinear(prob, g, x0, gn_steps=0)


def test_nonlinear_options_objects_and_keywords_run_the_same(ranges):
    """LinearizedOptions / NonlinearOptions in the house style: the object, keyword changes or both, bit for bit."""
    g, prob, x0 = ranges
    lin = admm_linearized(prob, g, x0, W=1.0, outer_iterations=2, inner_max_iterations=50)
    opts = LinearizedOptions(W=1.0, outer_iterations=2)
    lin_obj = admm_linearized(prob, g, x0, options=opts, inner_max_iterations=50)
    np.testing.assert_array_equal(lin_obj.estimates, lin.estimates)
    nl = admm_nonlinear(prob, g, x0, W=1.0, max_iterations=40, gn_steps=1)
    nl_obj = admm_nonlinear(prob, g, x0, options=NonlinearOptions(W=1.0, max_iterations=40, gn_steps=1))
    np.testing.assert_array_equal(nl_obj.estimates, nl.estimates)
    with pytest.raises(UsageError, match="NonlinearOptions has no option 'gn_step'.*'gn_steps'"):
        admm_nonlinear(prob, g, x0, gn_step=1)
    with pytest.raises(ModelError, match="max_iterations must be"):
        LinearizedOptions(inner_max_iterations=-1)


def test_range_model_validation():
    rng = np.random.default_rng(0)
    with pytest.raises(ModelError, match="sigma_m must be > 0"):
        range_positioning_problem(np.zeros((3, 2)), np.ones(2), sigma_m=0.0, rng=rng)
    with pytest.raises(ModelError, match="targets have 3 coordinates"):
        range_positioning_problem(np.zeros((3, 2)), np.ones(3), sigma_m=1.0, rng=rng)
    g = Graph.from_links(2, [(0, 1)])
    prob = range_positioning_problem(np.array([[0.0, 0.0], [1.0, 0.0]]), np.array([0.0, 0.0]), sigma_m=1.0, rng=rng)
    with pytest.raises(ModelError, match="coincides with a node position"):
        gauss_newton(prob, np.array([0.0, 0.0]))
    with pytest.raises(ModelError, match="x0 must be a length-2"):
        gauss_newton(prob, np.zeros(3))
    assert g.n_nodes == 2


def test_nonlinear_problem_validation():
    from distnav.algorithms.lsq.admm import NonlinearProblem, RangeModel

    with pytest.raises(ModelError, match="node positions must be"):
        RangeModel(np.zeros(3), 1)
    with pytest.raises(ModelError, match="n_targets must be"):
        RangeModel(np.zeros((3, 2)), 0)
    model = RangeModel(np.zeros((3, 2)), 1)
    with pytest.raises(ModelError, match="y must be"):
        NonlinearProblem(model, np.zeros((3, 1)), np.ones((3, 2, 2)))
    with pytest.raises(ModelError, match="node 1: observations are not finite"):
        NonlinearProblem(model, np.array([[1.0], [np.nan], [1.0]]), np.ones((3, 1, 1)))
    with pytest.raises(ModelError, match="node 2: R_i is not positive definite"):
        NonlinearProblem(model, np.ones((3, 1)), np.array([[[1.0]], [[1.0]], [[-1.0]]]))


def test_admm_equals_blue_with_approximate_cover(case):
    g, prob, xh = case
    C = choose_constraint_nodes(g, "min_cover", method="approx")
    assert C.optimal is False
    res = admm(prob, g, constraint_nodes=C, W=20.0, max_iterations=5000, tol=1e-12, reference=xh)
    assert res.converged
    assert np.linalg.norm(res.estimates - xh, axis=1).max() / np.linalg.norm(xh) < 1e-8


def test_monitor_every_checks_the_tolerance_on_monitored_iterations(case):
    g, prob, xh = case
    every = admm(prob, g, W=20.0, max_iterations=5000, tol=1e-10, reference=xh)
    sparse = admm(prob, g, W=20.0, max_iterations=5000, tol=1e-10, reference=xh, monitor_every=7)
    assert every.converged and sparse.converged
    assert sparse.iterations % 7 == 0 and every.iterations <= sparse.iterations < every.iterations + 7
    pr = sparse.trace["primal_residual"]
    assert np.isnan(pr[1]) and np.isfinite(pr[7])
    for mode in ("pairs", "aggregated"):
        never = admm(prob, g, W=20.0, max_iterations=50, tol=1e-3, monitor_every=0, messages=mode)
        assert not never.converged and never.iterations == 50


@pytest.mark.parametrize("method", ["normal", "observation", "cholesky"])
def test_uneven_rows_including_a_node_without_data(method):
    rng = np.random.default_rng(17)
    g = builders.connected_random_geometric(12, mean_degree=4, rng=rng)
    rows = [0, 1, 2, 3, 1, 2, 0, 3, 2, 1, 2, 2]
    p = 4
    A = [rng.normal(size=(m, p)) for m in rows]
    y = [rng.normal(size=m) for m in rows]
    R = [np.diag(rng.uniform(0.5, 2.0, m)) for m in rows]
    prob = LinearProblem.from_blocks(A, y, R)
    xh = blue(prob).x
    res = admm(prob, g, W=1.0, x_update=method, max_iterations=20000, tol=1e-12, reference=xh)
    assert res.converged
    assert np.linalg.norm(res.estimates - xh, axis=1).max() / np.linalg.norm(xh) < 1e-8


# ------------------------------------------------------------------------------------------ residuals, weighting
@pytest.mark.parametrize("messages", ["pairs", "aggregated"])
@pytest.mark.parametrize("weight", ["rho", "matrix"])
def test_dual_residual_against_an_independent_computation(case, messages, weight):
    """``dual_k = sqrt(Σ_s |N_s| ‖W (z_s^[k] − z_s^[k−1])‖²)`` from the yielded z and the graph, with ρ ≠ 1 (a
    residual scaled by ρ instead of ρ² fails here) and with a non-isotropic W."""
    g, prob, _ = case
    W = 2.5 if weight == "rho" else np.diag([0.5, 1.0, 2.0, 3.0, 1.5, 4.0])
    Wm = W * np.eye(6) if weight == "rho" else W
    C = choose_constraint_nodes(g, "min_cover")
    deg = np.bincount(g.links.ravel(), minlength=g.n_nodes)
    size = (deg + 1)[C.nodes]  # |N_s| counts s itself
    states = iterate_admm(prob, g, constraint_nodes=C, W=W, messages=messages)
    prev = next(states)
    for _ in range(6):
        st = next(states)
        dz = (st.z - prev.z)[C.nodes] @ Wm.T
        expected = np.sqrt(np.sum(size * np.einsum("sp,sp->s", dz, dz)))
        assert st.dual_residual == pytest.approx(expected, rel=1e-12)
        assert expected > 0
        prev = st


def test_inestimable_parameter_is_refused_not_reported_as_zero():
    """Issue 15: a parameter no node observes (and a pair only observed as a sum) must not converge to 0."""
    rng = np.random.default_rng(8)
    g = builders.ring(8)
    A = rng.normal(size=(8, 3, 4))
    A[:, :, 2] = 0.0  # nobody observes x[2]
    y = rng.normal(size=(8, 3))
    prob = LinearProblem.from_stacked(A, y)
    with pytest.raises(ModelError, match=r"inestimable directions: x\[2\]") as blue_err:
        blue(prob)
    with pytest.raises(ModelError, match=r"inestimable directions: x\[2\]; ADMM would converge") as admm_err:
        admm(prob, g, max_iterations=50)
    assert str(blue_err.value) in str(admm_err.value)
    with pytest.raises(ModelError, match=r"inestimable directions: x\[2\]"):
        next(iterate_admm(prob, g))
    B = rng.normal(size=(8, 3, 4))
    B[:, :, 1] = B[:, :, 0]  # x[0] and x[1] only through their sum
    with pytest.raises(ModelError, match=r"inestimable directions: x\[0\] − x\[1\]"):
        admm(LinearProblem.from_stacked(B, y), g, max_iterations=50)


@pytest.mark.parametrize("choice", ["all", "min_cover"])
def test_printed_fig6_x_update_with_a_1_over_c_weighted_z_update_converges_to_the_blue(case, choice):
    """Issue 16 item 4: keep Fig. 6's x-update, weight z_{i,s} by 1/c_i in the z-update: the ADMM of the Lagrangian
    with pair weights W/c_i, so the BLUE — where the plain-mean z-update (x_weight="fig6") is biased."""
    g, prob, xh = case
    rel = {}
    for xw in ("fig6", "fig6-zweighted"):
        res = admm(prob, g, constraint_nodes=choice, W=20.0, x_weight=xw, max_iterations=8000, tol=1e-13)
        assert res.converged and res.x_weight == xw
        rel[xw] = np.linalg.norm(res.estimates - xh, axis=1).max() / np.linalg.norm(xh)
    assert rel["fig6-zweighted"] < 1e-8
    assert rel["fig6"] > 1e-4
    with pytest.raises(ModelError, match="fig6-zweighted.*messages='pairs'"):
        admm(prob, g, x_weight="fig6-zweighted", messages="aggregated", max_iterations=2)


def test_unknown_option_is_a_project_error(case):
    g, prob, _ = case
    with pytest.raises(UsageError, match="AdmmRunOptions has no option 'rhoo'"):
        admm(prob, g, rhoo=3.0)
    with pytest.raises(UsageError, match="AdmmOptions has no option 'max_iterations'"):
        iterate_admm(prob, g, max_iterations=3)  # the generator has no stopping rule
    with pytest.raises(UsageError, match="options must be a AdmmRunOptions, got dict"):
        admm(prob, g, options={"W": 3.0})  # type: ignore[arg-type]


def test_options_object_and_keywords_run_the_same(case):
    """The house style (distnav._settings): one frozen options object, keyword changes to it, or both — the same
    run bit for bit; a kernel-only AdmmOptions gets admm()'s default stopping rule."""
    g, prob, _ = case
    by_keywords = admm(prob, g, W=20.0, x_weight="fig6", max_iterations=40, tol=0.0)
    by_object = admm(prob, g, options=AdmmRunOptions(W=20.0, x_weight="fig6", max_iterations=40, tol=0.0))
    mixed = admm(prob, g, options=AdmmOptions(W=20.0, x_weight="fig6"), max_iterations=40, tol=0.0)
    for res in (by_object, mixed):
        np.testing.assert_array_equal(res.estimates, by_keywords.estimates)
        np.testing.assert_array_equal(res.trace["primal_residual"], by_keywords.trace["primal_residual"])
    assert mixed.iterations == 40 and mixed.x_weight == "fig6"
    kernel = AdmmOptions(W=20.0)
    first = [s.x.copy() for s, _ in zip(iterate_admm(prob, g, options=kernel), range(4), strict=False)]
    again = [s.x.copy() for s, _ in zip(iterate_admm(prob, g, W=20.0), range(4), strict=False)]
    np.testing.assert_array_equal(np.stack(first), np.stack(again))
    with pytest.raises(ModelError, match="messages must be"):
        AdmmOptions(messages="edges")  # type: ignore[arg-type]
    with pytest.raises(ModelError, match="max_iterations must be"):
        AdmmRunOptions(max_iterations=-1)


def test_result_is_typed_and_warm_start_reads_z_nodes(case):
    g, prob, xh = case
    res = admm(prob, g, W=20.0, max_iterations=30, tol=0.0)
    C = res.constraint_nodes
    np.testing.assert_array_equal(res.z, res.z_nodes[C.nodes])
    assert np.all(res.z_nodes[~C.mask] == 0)
    assert res.pairs == int(C.per_node_count.sum()) and res.messages == "pairs" and res.x_update == "observation"
    assert res.precision is None and res.tests is None
    # a warm start from the result continues from its x and its z (§4.3)
    st0 = next(iterate_admm(prob, g, W=20.0, init=res))
    np.testing.assert_array_equal(st0.x, res.estimates)
    np.testing.assert_array_equal(st0.z, res.z_nodes)


def test_continuing_with_the_multipliers_equals_one_longer_run(case):
    g, prob, _ = case
    first = admm(prob, g, W=20.0, max_iterations=30, tol=0.0)
    assert first.multipliers is not None
    cont = admm(prob, g, W=20.0, max_iterations=30, tol=0.0, init=first, multipliers=first.multipliers)
    full = admm(prob, g, W=20.0, max_iterations=60, tol=0.0)
    np.testing.assert_allclose(cont.estimates, full.estimates, rtol=1e-12, atol=1e-13)
    np.testing.assert_allclose(cont.z_nodes, full.z_nodes, rtol=1e-12, atol=1e-13)
    reset = admm(prob, g, W=20.0, max_iterations=30, tol=0.0, init=first)  # u^[−1] = 0 (§4.3): another run
    assert np.abs(reset.estimates - full.estimates).max() > 1e-6
    with pytest.raises(ModelError, match="belong to another exchange block"):
        admm(prob, g, W=20.0, constraint_nodes="all", max_iterations=2, multipliers=first.multipliers)
    with pytest.raises(ModelError, match="only be continued with messages='pairs'"):
        admm(prob, g, W=20.0, messages="aggregated", max_iterations=2, multipliers=first.multipliers)
    assert admm(prob, g, W=20.0, messages="aggregated", max_iterations=2).multipliers is None
