"""Global Levenberg–Marquardt (paper 002 eq. (8)) against scipy, noise-free truth, Koppanyi's published problem,
robust losses."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import least_squares

from distnav.algorithms.ranging.lm import levenberg_marquardt, solve_lm
from distnav.algorithms.ranging.losses import robust_weights
from distnav.errors import ModelError
from distnav.models.uwb.problems import build_problem, generate_problem, rmse_m


def well_posed(rng: np.random.Generator, *, sigma_m: float = 0.15, dim: int = 3, n: int = 40):
    """A dense random network in a 30 m × 30 m (× 15 m) box, links up to 15 m: rigid, no mirror ambiguities."""
    for _ in range(50):
        t = rng.uniform(0.0, 30.0, (n, dim))
        if dim == 3:
            t[:, 2] /= 2.0
        a, b = np.triu_indices(n, 1)
        d = np.linalg.norm(t[a] - t[b], axis=1)
        k = d < 15.0
        ids = [str(i) for i in range(n)]
        if np.bincount(np.concatenate([a[k], b[k]]), minlength=n).min() < dim + 2:
            continue
        return build_problem(
            ids,
            np.stack([a[k], b[k]], 1),
            np.abs(d[k] + rng.normal(0, sigma_m, k.sum())),
            fixed={ids[i]: t[i] for i in range(3)},
            dim=dim,
            initial_m=t + rng.uniform(-1.0, 1.0, t.shape),
            truth_m=t,
        )
    raise AssertionError("no well-posed network drawn")


@pytest.mark.parametrize("dim", [2, 3])
def test_lm_reaches_scipy_lm_cost(dim):
    p = well_posed(np.random.default_rng(11), dim=dim)
    ours = solve_lm(p)
    ref = least_squares(
        p.residual_vector,
        p.x0(),
        jac=lambda x: p.jacobian_of(x).toarray(),
        method="lm",
        xtol=1e-14,
        ftol=1e-14,
        gtol=1e-14,
    )
    ref_cost = float(ref.fun @ ref.fun)
    assert ours.converged
    assert ours.cost == pytest.approx(ref_cost, rel=1e-9)
    np.testing.assert_allclose(ours.x, ref.x, atol=1e-5)


def test_noise_free_lm_recovers_truth():
    p = well_posed(np.random.default_rng(3), sigma_m=0.0)
    res = solve_lm(p)
    assert rmse_m(p, res.estimates) < 1e-7
    assert res.trace["rmse_m"][0] > 0.5 and res.trace["rmse_m"][-1] < 1e-7
    assert res.trace["cost"].shape == res.trace["rmse_m"].shape == (res.iterations + 1,)


def test_dense_and_banded_paths_agree():
    p = well_posed(np.random.default_rng(5))
    fun = lambda x: p.residual_vector(x)
    sparse = levenberg_marquardt(fun, p.jacobian_of, p.x0())
    dense = levenberg_marquardt(fun, lambda x: p.jacobian_of(x).toarray(), p.x0())
    huge = levenberg_marquardt(fun, p.jacobian_of, p.x0(), dense_limit=0)
    csc = levenberg_marquardt(fun, lambda x: p.jacobian_of(x).tocsc(), p.x0())
    assert csc.cost == pytest.approx(dense.cost, rel=1e-10)
    assert sparse.cost == pytest.approx(dense.cost, rel=1e-10)
    assert huge.cost == pytest.approx(dense.cost, rel=1e-10)
    np.testing.assert_allclose(sparse.x, dense.x, atol=1e-6)
    np.testing.assert_allclose(huge.x, dense.x, atol=1e-6)


def test_koppanyi_published_problem_reaches_centralized_cost(shared_data):
    sio = pytest.importorskip("scipy.io")
    m = sio.loadmat(shared_data / "uwb" / "koppanyi-distrib-optim-synthetic" / "problem_0011c51.mat")
    meas, coors, sol = m["meas"], m["coors"], m["sol"]
    ref_res = float(np.asarray(m["chk_prob"]["res"][0, 0]).ravel()[0])  # ‖r‖ of the lsqnonlin solution
    assert ref_res == pytest.approx(18491.18, abs=0.01)
    ids = [str(i + 1) for i in range(coors.shape[0])]
    control = [int(v) for v in m["cont_agents"].ravel()]  # the two fixed "control" nodes (1-based)
    links = [(str(int(i)), str(int(j))) for i, j, _ in meas]
    # the file holds one negative range (noise on a short pair); the cost uses d², so |d| is the same problem
    with pytest.raises(ModelError, match="negative"):
        build_problem(ids, links, meas[:, 2], fixed={str(c): coors[c - 1] for c in control}, dim=2)
    p = build_problem(
        ids,
        links,
        np.abs(meas[:, 2]),
        fixed={str(c): coors[c - 1] for c in control},
        dim=2,
        initial_m=m["x0_mat"].T,
        truth_m=coors,
    )
    assert np.sqrt(p.cost(sol)) == pytest.approx(ref_res, rel=1e-12)  # same residual definition as theirs
    res = solve_lm(p)
    ours = np.sqrt(res.cost)
    assert ours <= ref_res * (1 + 1e-9)  # at least as low as the published centralized solution
    assert ours >= ref_res * (1 - 1e-6)  # ... and the same minimum
    np.testing.assert_allclose(res.estimates, sol, atol=0.1)  # units of the problem (≈ 0–1000)
    assert rmse_m(p, res.estimates) == pytest.approx(10.66, abs=0.01)  # PROVENANCE: RMSE(sol) = 10.66


def test_robust_loss_resists_an_nlos_range():
    rng = np.random.default_rng(8)
    p = well_posed(rng, sigma_m=0.02)
    k = 25
    bad = p.range_m.copy()
    bad[k] += 4.0  # one NLOS range, 4 m too long
    p_bad = p.with_ranges(bad)
    lin = solve_lm(p_bad)
    hub = solve_lm(p_bad, loss="huber", loss_scale_m=0.1)
    cau = solve_lm(p_bad, loss="cauchy", loss_scale_m=0.1)
    e_lin, e_hub, e_cau = (rmse_m(p, r.estimates) for r in (lin, hub, cau))
    assert e_hub < 0.5 * e_lin and e_cau < 0.5 * e_lin
    # the outlier keeps a large residual under the robust losses (it is not fitted)
    d_est = np.linalg.norm(cau.estimates[p.meas_a[k]] - cau.estimates[p.meas_b[k]])
    assert bad[k] - d_est > 3.0


def test_robust_weights_values():
    g = np.array([0.5, 2.0, -4.0])
    w, obj = robust_weights(g, 1.0, "huber")
    np.testing.assert_allclose(w, [1.0, 0.5, 0.25])
    assert obj == pytest.approx(0.25 + (2 * 2 - 1) + (2 * 4 - 1))
    w, obj = robust_weights(g, 2.0, "cauchy")
    np.testing.assert_allclose(w, 1 / (1 + (g / 2) ** 2))
    assert obj == pytest.approx(np.sum(4 * np.log1p((g / 2) ** 2)))


def test_one_sided_cauchy_weights_and_minimum():
    """``cauchy_long``: Cauchy where the range reads long (g < 0), linear where it reads short; LM (metres) lands
    where the gradient of that objective, written here independently and differentiated numerically, vanishes."""
    g = np.array([0.5, -2.0, 3.0, -0.0])
    w, obj = robust_weights(g, 2.0, "cauchy_long")
    np.testing.assert_allclose(w, [1.0, 1 / (1 + 1.0), 1.0, 1.0])
    assert obj == pytest.approx(0.25 + 4 * np.log1p(1.0) + 9.0)
    rng = np.random.default_rng(8)
    p = well_posed(rng, sigma_m=0.02)
    bad = p.range_m.copy()
    bad[[3, 25]] += [1.5, 2.0]  # two NLOS ranges, long
    p_bad = p.with_ranges(bad)
    r = solve_lm(p_bad, objective="metres", sigma_m=0.05, loss="cauchy_long", loss_scale_m=0.1, quality=False)
    s = 0.1 / 0.05

    def f(x: np.ndarray) -> float:
        e = (p_bad.distances(p_bad.to_positions(x)) - bad) / 0.05
        return float(np.sum(np.where(e < 0, s * s * np.log1p((e / s) ** 2), e * e)))

    x = p_bad.to_vector(r.estimates)
    grad = np.array([(f(x + h) - f(x - h)) / 2e-6 for h in np.eye(x.size) * 1e-6])
    assert np.max(np.abs(grad)) < 1e-3 * max(1.0, f(x))
    assert rmse_m(p, r.estimates) < 0.5 * rmse_m(p, solve_lm(p_bad, objective="metres", sigma_m=0.05).estimates)


def test_lm_validation_and_padding():
    p = generate_problem("GC", np.random.default_rng(0))
    with pytest.raises(ModelError, match="unknown loss"):
        solve_lm(p, loss="tukey")
    with pytest.raises(ModelError, match="loss_scale_m"):
        solve_lm(p, loss="huber", loss_scale_m=0.0)
    with pytest.raises(ModelError, match="initial guess"):
        solve_lm(
            p.__class__(
                **{
                    **{
                        f: getattr(p, f)
                        for f in ("ids", "dim", "positions_m", "free", "meas_a", "meas_b", "range_m", "truth_m", "name")
                    },
                    "initial_m": None,
                }
            )
        )
    res = solve_lm(p, max_iterations=30, pad_trace=True)
    assert res.trace["rmse_m"].shape == (31,) and res.comm.messages == 0


def test_bordered_path_with_a_dense_column_matches_scipy():
    """A common range offset (one column touching every range) on a long strip network: the band of the rest is
    narrow, the offset is eliminated by its Schur complement; the answer is scipy's."""
    import scipy.sparse as sp

    from distnav.algorithms.ranging.damped import DampedSolver as _DampedSolver

    rng = np.random.default_rng(8)
    n = 150
    t = np.column_stack([np.linspace(0.0, 300.0, n) + rng.uniform(-1, 1, n), rng.uniform(0.0, 25.0, n)])
    a, b = np.triu_indices(n, 1)
    d = np.linalg.norm(t[a] - t[b], axis=1)
    k = d < 16.0
    ids = [str(i) for i in range(n)]
    p = build_problem(
        ids,
        np.stack([a[k], b[k]], 1),
        d[k] + 0.4 + rng.normal(0, 0.05, k.sum()),
        fixed={ids[i]: t[i] for i in (0, 1, n // 2, n - 1)},
        dim=2,
        initial_m=t + rng.uniform(-0.5, 0.5, t.shape),
        truth_m=t,
    )

    def fun(x):
        return p.residual_vector(x[:-1]) - x[-1]

    def jac(x):
        return sp.hstack([p.jacobian_of(x[:-1]), sp.csr_matrix(-np.ones((p.n_meas, 1)))]).tocsr()

    x0 = np.concatenate([p.x0(), [0.0]])
    solver = _DampedSolver(jac(x0), 200)
    assert solver.mode == "bordered" and solver.dense_cols.tolist() == [x0.size - 1]
    tight = {"ftol": 1e-15, "xtol": 1e-15, "gtol": 1e-15}
    ours = levenberg_marquardt(fun, jac, x0, **tight)
    ref = least_squares(fun, x0, jac=lambda x: jac(x).toarray(), method="lm", xtol=1e-14, ftol=1e-14, gtol=1e-14)
    assert ours.converged
    assert ours.cost == pytest.approx(float(ref.fun @ ref.fun), rel=1e-9)
    np.testing.assert_allclose(ours.x, ref.x, atol=1e-6)
    huge = levenberg_marquardt(fun, lambda x: jac(x).toarray(), x0, **tight)  # dense path
    np.testing.assert_allclose(ours.x, huge.x, atol=1e-8)


def test_sparse_path_is_scipys_damped_solve_bit_for_bit():
    """The SuperLU path builds the damped CSC matrix from GᵀG's values on its pattern (no sparse product,
    addition or conversion per solve): the solution must be, bit for bit, spsolve of scipy's own
    ``(GᵀG + diags(λ max(d, floor))).tocsc()`` — also where an entry of GᵀG is exactly 0 (a height column
    whose Jacobian entries vanish: scipy's product leaves it out)."""
    import scipy.sparse as sp
    import scipy.sparse.linalg as spla

    from distnav.algorithms.ranging.damped import DampedSolver as _DampedSolver

    p = generate_problem("RC", np.random.default_rng([0, 7000]))  # `reproduce uwb`'s first RC instance
    x = p.x0()
    zero_heights = x.copy()
    zero_heights[2::3] = 0.0  # every free height equal: the z entries of G, and GᵀG's z block, are exactly 0
    for xv in (x, zero_heights):
        jac = p.jacobian_of(xv)
        g = p.residual_vector(xv)
        solver = _DampedSolver(jac, 200)
        assert solver.mode == "sparse"
        a, grad = solver.normal(jac, None, g)
        ref_a = sp.csr_matrix(jac.T @ jac)
        np.testing.assert_array_equal(grad, np.asarray(jac.T @ g).ravel())
        for lam in (1e-3, 0.7, 1e4):
            d = ref_a.diagonal()
            floor = 1e-12 * max(float(d.max(initial=0.0)), 1e-300)
            ref = spla.spsolve((ref_a + sp.diags(lam * np.maximum(d, floor))).tocsc(), -grad)
            ours = solver.solve(a, -grad, lam)
            assert ours is not None
            assert np.array_equal(ours.view(np.uint64), ref.view(np.uint64))
