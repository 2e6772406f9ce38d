"""``range_offsets="common_delays"`` (issue 28): a common range offset without a prior plus per-anchor antenna delays
about it with the prior N(0, σ_b²), range model ``‖x_a − x_b‖ + c + b_a + b_b``
(:mod:`distnav.algorithms.ranging.objective`). Checked against scipy ``least_squares`` on the same objective
written here, and by Monte Carlo: the errors of the positions, the common offset and the delays together have the
covariance of the one normal matrix LM reports them from."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import least_squares

from distnav.algorithms.ranging import csg
from distnav.algorithms.ranging.data import RangingData
from distnav.algorithms.ranging.lm import solve_lm
from distnav.algorithms.ranging.objective import FitOptions, RangeObjective
from distnav.errors import ModelError

SIGMA_M = 0.05
PRIOR_M = 0.1
COMMON_M = 0.35


def _network(n: int = 8, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A 2-D network: 4 known anchors at the corners of a 12 m × 9 m room, ``n − 4`` free inside, every pair
    ranged once; returns (truth, free mask, pair ends a, b)."""
    rng = np.random.default_rng(seed)
    corners = np.array([[0.0, 0.0], [12.0, 0.0], [12.0, 9.0], [0.0, 9.0]])
    truth = np.vstack([corners, rng.uniform([2.0, 2.0], [10.0, 7.0], (n - 4, 2))])
    free = np.zeros((n, 2), bool)
    free[4:] = True
    a, b = np.triu_indices(n, 1)
    return truth, free, a, b


def _problem(truth: np.ndarray, free: np.ndarray, a: np.ndarray, b: np.ndarray, range_m: np.ndarray) -> RangingData:
    n = truth.shape[0]
    return RangingData(
        ids=tuple(f"A{i}" for i in range(n)),
        dim=2,
        positions_m=np.where(free, 0.0, truth),
        free=free,
        meas_a=a,
        meas_b=b,
        range_m=range_m,
        truth_m=truth,
        initial_m=truth + np.where(free, 0.3, 0.0),
    )


def _ranges(truth, a, b, delays_m, rng) -> np.ndarray:
    d = np.linalg.norm(truth[a] - truth[b], axis=1)
    return d + COMMON_M + delays_m[a] + delays_m[b] + rng.normal(0.0, SIGMA_M, a.size)


def test_lm_equals_a_scipy_fit_of_the_same_objective():
    """The objective written out here (whitened range rows, prior rows b_i/σ_b on the delays only, the common
    offset free) and minimised by scipy's trust-region reflective: the same positions, offset and delays."""
    truth, free, a, b = _network()
    rng = np.random.default_rng(1)
    delays = rng.normal(0.0, PRIOR_M, truth.shape[0])
    p = _problem(truth, free, a, b, _ranges(truth, a, b, delays, rng))
    res = solve_lm(p, objective="metres", sigma_m=SIGMA_M, range_offsets="common_delays", offset_prior_sigma_m=PRIOR_M)
    n, est = truth.shape[0], free.any(axis=1)

    def residual(v: np.ndarray) -> np.ndarray:
        pos = truth.copy()
        pos[est] = v[: 2 * est.sum()].reshape(-1, 2)
        c, dl = v[2 * est.sum()], v[2 * est.sum() + 1 :]
        r = (np.linalg.norm(pos[a] - pos[b], axis=1) + c + dl[a] + dl[b] - p.range_m) / SIGMA_M
        return np.concatenate([r, dl / PRIOR_M])

    v0 = np.concatenate([p.initial_m[est].ravel(), np.zeros(1 + n)])
    ref = least_squares(residual, v0, method="trf", xtol=1e-14, ftol=1e-14, gtol=1e-14).x
    ref_pos = ref[: 2 * est.sum()].reshape(-1, 2)
    assert np.max(np.abs(res.estimates[est] - ref_pos)) < 1e-6
    assert res.settings["common_offset_m"] == pytest.approx(ref[2 * est.sum()], abs=1e-6)
    # offsets_m: every anchor's total delay c/2 + b_i (a range reads δ_a + δ_b long)
    assert np.max(np.abs(res.offsets_m - (ref[2 * est.sum()] / 2 + ref[2 * est.sum() + 1 :]))) < 1e-6
    assert res.offsets_m.shape == res.offsets_std_m.shape == (n,)
    # and the fit found what the ranges carry: the common offset within 3 of its σ, every total delay within 3σ
    assert (
        abs(res.settings["common_offset_m"] - (COMMON_M + 2 * delays.mean()))
        < 3 * res.settings["common_offset_std_m"] + 0.02
    )
    assert res.settings["common_offset_std_m"] > 0


def test_monte_carlo_covariance_of_positions_offset_and_delays_is_the_normal_matrixs():
    """300 draws of the delays (N(0, σ_b²), the prior's distribution) and the range noise on one network: the
    joint errors of [positions, c, b] against the inverse of the normal matrix at the fit (the one LM reports σ
    from): the mean of eᵀQ⁻¹e is the number of unknowns (χ² mean) and every reported σ (positions' blocks,
    ``offsets_std_m`` over √σ̂²) matches the spread of its errors."""
    truth, free, a, b = _network(7, seed=3)
    n, est = truth.shape[0], free.any(axis=1)
    rng = np.random.default_rng(4)
    errs, chi2, pos_var, off_var = [], [], [], []
    for _ in range(300):
        delays = rng.normal(0.0, PRIOR_M, n)
        p = _problem(truth, free, a, b, _ranges(truth, a, b, delays, rng))
        r = solve_lm(
            p, objective="metres", sigma_m=SIGMA_M, range_offsets="common_delays", offset_prior_sigma_m=PRIOR_M
        )
        obj = RangeObjective(p, "metres", SIGMA_M, "common_delays", PRIOR_M)
        x = np.asarray(r.x)
        J = obj.jacobian(x).toarray()
        Q = np.linalg.inv(J.T @ J)
        e = x - np.concatenate([truth[free], [COMMON_M], delays])
        errs.append(e)
        chi2.append(float(e @ np.linalg.solve(Q, e)))
        s2 = r.precision.variance_factor
        pos_var.append(np.array([r.precision.covariance[i][k, k] for i in np.flatnonzero(est) for k in range(2)]))
        off_var.append(r.offsets_std_m**2 / s2)
    errs_a = np.array(errs)
    nf = int(free.sum())
    assert np.mean(chi2) == pytest.approx(x.size, rel=0.12)  # sd of the mean: √(2·14/300) / 14 = 2.2 %
    emp_pos = errs_a[:, :nf].var(axis=0)
    np.testing.assert_allclose(emp_pos, np.mean(pos_var, axis=0), rtol=0.25)  # sd of a variance: 8 %
    totals = 0.5 * errs_a[:, nf : nf + 1] + errs_a[:, nf + 1 :]  # the reported offsets: c/2 + b_i
    np.testing.assert_allclose(totals.var(axis=0), np.mean(off_var, axis=0), rtol=0.25)


def test_options_refuse_a_bad_prior_and_the_distributed_solvers_refuse_the_mode():
    with pytest.raises(ModelError, match="offset_prior_sigma_m must be positive"):
        FitOptions(objective="metres", range_offsets="common_delays", offset_prior_sigma_m=0.0)
    with pytest.raises(ModelError, match="metres"):
        FitOptions(range_offsets="common_delays")
    truth, free, a, b = _network()
    p = _problem(truth, free, a, b, np.linalg.norm(truth[a] - truth[b], axis=1))
    for solver in ("CSG", "N-CSG", "N-CLM"):
        with pytest.raises(ModelError, match="common_delays.*LM's only"):
            csg.solve(p, solver, objective="metres", range_offsets="common_delays", iterations=5)


def test_uwb_solve_common_delays_on_a_hard_hall(tmp_path):
    """``uwb solve --range-offsets common_delays`` on a PLANT_HARD hall (common offset 0.35 m, delays sd 0.1 m):
    the common offset in summary.json near the simulator's (the delays' mean moves it: within 0.15 m), every
    anchor's total delay in offsets.csv (c/2 + b_i: they average to c/2 + mean b), a usable map; N-CLM refuses the
    mode with exit 2 before any work."""
    import csv
    import json

    from distnav.cli import main
    from distnav.experiments.uwb_field import write_hall
    from distnav.models.uwb.hall import PLANT_HARD, simulate_hall

    h = simulate_hall(np.random.default_rng([34, 1]), None, **PLANT_HARD, known="middle")
    f = write_hall(h, tmp_path / "hall")
    base = ["uwb", "solve", "--ranges", str(f["ranges"]), "--known", str(f["known"]), "--heights", str(f["heights"])]
    base += ["--truth", str(f["truth"])]
    assert main([*base, "--range-offsets", "common_delays", "--out", str(tmp_path / "o")]) in (0, 3)
    s = json.loads((tmp_path / "o" / "summary.json").read_text())
    assert s["range_offsets"] == "common_delays"
    assert abs(s["common_offset_m"] - PLANT_HARD["common_offset_m"]) < 0.15  # type: ignore[operator]
    rows = list(csv.DictReader((tmp_path / "o" / "offsets.csv").open()))
    assert len(rows) == h.n_anchors
    total = np.array([float(r["offset_m"]) for r in rows])
    assert abs(total.mean() - s["common_offset_m"] / 2) < 0.05  # the delays' prior holds their mean near 0
    assert all(float(r["sigma_m"]) > 0 for r in rows)
    assert s["offset_prior_sigma_m"] == 0.1 and s["offset_prior_estimated"] is False  # the given prior, said
    est = ["--range-offsets", "common_delays", "--estimate-offset-prior", "--out", str(tmp_path / "e")]
    assert main([*base, *est]) in (0, 3)
    e = json.loads((tmp_path / "e" / "summary.json").read_text())
    assert e["offset_prior_estimated"] is True and e["offset_prior_sigma_m"] != 0.1  # the estimate, written
    assert main([*base, "--range-offsets", "common_delays", "--solver", "N-CLM", "--out", str(tmp_path / "n")]) == 2
    assert not (tmp_path / "n").exists()


@pytest.mark.parametrize("true_m", [0.03, 0.1])
def test_estimated_prior_sigma_finds_the_delays_spread(true_m):
    """``estimate_offset_prior``: Förstner's variance components started from a 0.1 m prior; over 30 draws of the
    delays (N(0, true²)) and the noise on a 10-anchor network the median estimate is within 20 % of the spread the
    delays were drawn with (its own scatter over the draws: ±40 % at 0.03 m, ±30 % at 0.1 m)."""
    truth, free, a, b = _network(10, seed=5)
    got = []
    for k in range(30):
        rng = np.random.default_rng([7, k])
        p = _problem(truth, free, a, b, _ranges(truth, a, b, rng.normal(0.0, true_m, truth.shape[0]), rng))
        r = solve_lm(
            p,
            objective="metres",
            sigma_m=SIGMA_M,
            range_offsets="common_delays",
            offset_prior_sigma_m=PRIOR_M,
            estimate_offset_prior=True,
        )
        assert r.settings["offset_prior_estimated"] is True
        got.append(r.settings["offset_prior_sigma_m"])
    assert np.median(got) == pytest.approx(true_m, rel=0.2)


def test_estimated_prior_needs_delays():
    with pytest.raises(ModelError, match="estimate_offset_prior.*range_offsets must be one of per_anchor"):
        solve_lm(
            _problem(*_network(), np.ones(28)), objective="metres", range_offsets="common", estimate_offset_prior=True
        )


def test_lms_reliability_takes_the_mode_the_neighbourhoods_refuse_it():
    """The external reliability of an LM ``common_delays`` fit (central: :class:`RangeObjective`'s layout) gives
    finite MDBs; the anchors' neighbourhood reliability (the distributed solvers') refuses the mode by name."""
    from distnav.algorithms.ranging.reliability import ReliabilityOptions, external_reliability, local_reliability

    truth, free, a, b = _network()
    rng = np.random.default_rng(8)
    p = _problem(truth, free, a, b, _ranges(truth, a, b, rng.normal(0.0, PRIOR_M, truth.shape[0]), rng))
    r = solve_lm(p, objective="metres", sigma_m=SIGMA_M, range_offsets="common_delays", offset_prior_sigma_m=PRIOR_M)
    opts = ReliabilityOptions(sigma_m=SIGMA_M, offsets="common_delays", offset_prior_sigma_m=PRIOR_M)
    rel = external_reliability(p, np.asarray(r.x), opts)
    assert rel is not None and np.all(np.isfinite(rel.mdb_m)) and np.all(rel.r > 0)
    with pytest.raises(ModelError, match="not common_delays"):
        local_reliability(p, r.estimates, opts, offsets_m=r.offsets_m)
