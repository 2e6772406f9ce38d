"""UWB objective in metres, per-anchor precision, per-link w-tests, range-offset calibration and link exclusion,
against scipy, a dense reference and Monte Carlo."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.optimize import least_squares

from distnav.algorithms.ranging.lm import solve_lm
from distnav.algorithms.ranging.objective import RangeObjective
from distnav.algorithms.ranging.qc import exclude_links
from distnav.algorithms.statistics import residual_covariance
from distnav.errors import ModelError
from distnav.models.uwb.problems import build_problem


def network(
    rng: np.random.Generator,
    *,
    sigma_m: float = 0.1,
    n: int = 30,
    dim: int = 3,
    offset_m: float = 0.0,
    delays_m: np.ndarray | None = None,
):
    """Anchors in a 30 m × 30 m × 8 m hall, links up to 16 m, rigid (every anchor ≥ dim + 2 links)."""
    for _ in range(100):
        t = rng.uniform(0.0, 30.0, (n, dim))
        if dim == 3:
            t[:, 2] = rng.uniform(0.0, 8.0, n)
        a, b = np.triu_indices(n, 1)
        d = np.linalg.norm(t[a] - t[b], axis=1)
        k = d < 16.0
        if np.bincount(np.concatenate([a[k], b[k]]), minlength=n).min() < dim + 2:
            continue
        a, b, d = a[k], b[k], d[k]
        bias = offset_m + (0.0 if delays_m is None else delays_m[a] + delays_m[b])
        r = d + bias + rng.normal(0, sigma_m, d.size)
        ids = [f"A{i}" for i in range(n)]
        return build_problem(
            ids,
            np.stack([a, b], 1),
            r,
            fixed={ids[i]: t[i] for i in range(4)},
            dim=dim,
            initial_m=t + rng.uniform(-1.0, 1.0, t.shape),
            truth_m=t,
        )
    raise AssertionError("no rigid network drawn")


def with_nlos(p, rng, count=5):
    r = p.range_m.copy()
    bad = np.sort(rng.choice(r.size, count, replace=False))
    r[bad] += rng.uniform(0.6, 2.4, count)
    return p.with_ranges(r), bad


def rmse(p, est):
    d = (est - p.truth_m)[p.estimated]
    return float(np.sqrt(np.mean(np.sum(d * d, axis=1))))


@pytest.mark.parametrize("loss", ["linear", "huber", "soft_l1", "cauchy"])
def test_metres_objective_matches_scipy_least_squares(loss):
    p, _ = with_nlos(network(np.random.default_rng(4)), np.random.default_rng(5))
    ours = solve_lm(p, objective="metres", sigma_m=0.1, loss=loss, loss_scale_m=0.2)
    assert ours.converged and ours.objective_kind == "metres"
    o = RangeObjective(p, "metres", 0.1)
    start = solve_lm(p, objective="metres", sigma_m=0.1).x  # scipy from the linear fit (our graduated start)
    ref = least_squares(
        o.residual,
        start,
        jac=lambda x: o.jacobian(x).toarray(),
        loss=loss,
        f_scale=0.2 / 0.1,
        method="trf",
        xtol=1e-15,
        ftol=1e-15,
        gtol=1e-15,
    )
    assert ours.objective == pytest.approx(2.0 * ref.cost, rel=1e-9)  # scipy's cost is ½ Σ s²ρ
    np.testing.assert_allclose(ours.x, ref.x, atol=1e-6)


def test_metres_residual_and_jacobian_by_finite_differences():
    p = network(np.random.default_rng(1), n=12)
    o = RangeObjective(p, "metres", np.linspace(0.05, 0.2, p.n_meas), "per_anchor", 0.3)
    x = o.x0(p.initial_m) + 0.01
    J = o.jacobian(x).toarray()
    num = np.empty_like(J)
    for c in range(x.size):
        e = np.zeros(x.size)
        e[c] = 1e-6
        num[:, c] = (o.residual(x + e) - o.residual(x - e)) / 2e-6
    np.testing.assert_allclose(J, num, atol=1e-6)


def test_w_tests_match_dense_residual_covariance():
    p = network(np.random.default_rng(2), n=15)
    res = solve_lm(p, objective="metres", sigma_m=0.1, test_scale="a-priori")
    o = RangeObjective(p, "metres", 0.1)
    A = o.jacobian(res.x).toarray()
    Qx = np.linalg.inv(A.T @ A)
    Qe = residual_covariance(A, np.eye(A.shape[0]), Qx)
    w_ref = o.residual(res.x) / np.sqrt(np.diag(Qe))
    np.testing.assert_allclose(res.tests.w, w_ref, rtol=1e-7, atol=1e-9)
    np.testing.assert_allclose(
        res.precision.covariance[~p.fixed],
        np.stack([Qx[3 * k : 3 * k + 3, 3 * k : 3 * k + 3] for k in range(p.n_anchors - 4)]),
        rtol=1e-8,
        atol=1e-14,
    )
    assert res.precision.kind == "centralized" and res.precision.redundancy == p.n_meas - p.n_free


def test_covariance_is_calibrated_by_monte_carlo():
    """2σ coverage of every estimated coordinate over noise draws: σ from σ̂² × (JᵀWJ)⁻¹ (a-posteriori)."""
    rng = np.random.default_rng(7)
    base = network(rng, n=20)
    d_true = np.linalg.norm(base.truth_m[base.meas_a] - base.truth_m[base.meas_b], axis=1)
    inside, total = 0, 0
    for _ in range(150):
        p = base.with_ranges(d_true + rng.normal(0, 0.1, d_true.size))
        res = solve_lm(p, objective="metres", sigma_m=0.1, initial_m=base.truth_m)
        std = res.precision.std(a_posteriori=True)
        err = np.abs(res.estimates - base.truth_m)
        f = p.free
        inside += int(np.sum(err[f] <= 2.0 * std[f]))
        total += int(f.sum())
    coverage = inside / total
    assert 0.90 <= coverage <= 0.98, coverage


def test_nlos_links_are_found_and_excluded():
    """Recall and false alarms of Cauchy fit + iterative exclusion over 6 draws (issue 13: ≥ 90 %, ≤ 5 %), heights
    held (2-D, as under a ceiling). In 3-D with free heights one of these draws leaves an NLOS link on an anchor
    whose height is weakly determined undetected (the bias moves the anchor instead of the residual)."""
    found = false = n_bad = n_good = 0
    ours, best = [], []
    for seed in range(6):
        p, bad = with_nlos(network(np.random.default_rng(100 + seed), dim=2), np.random.default_rng(200 + seed))
        fit = lambda q: solve_lm(q, objective="metres", sigma_m=0.1, loss="cauchy", loss_scale_m=0.2)
        res, sub, tests = exclude_links(p, fit)
        removed = set(tests.removed)
        found += len(removed & set(bad.tolist()))
        false += len(removed - set(bad.tolist()))
        n_bad += bad.size
        n_good += p.n_meas - bad.size
        assert sub.n_meas == p.n_meas - len(removed) and not tests.flagged.any()
        assert np.isnan(tests.w[sorted(removed)]).all()
        keep = np.ones(p.n_meas, bool)
        keep[bad] = False
        oracle = dataclasses.replace(p, meas_a=p.meas_a[keep], meas_b=p.meas_b[keep], range_m=p.range_m[keep])
        ours.append(rmse(p, res.estimates))
        best.append(rmse(p, solve_lm(oracle, objective="metres", sigma_m=0.1).estimates))
    assert found / n_bad >= 0.9 and false / n_good <= 0.05, (found, n_bad, false, n_good)
    assert np.mean(ours) <= 1.15 * np.mean(best), (ours, best)  # issue 13: ≤ 1.15 × the oracle (NLOS removed)


def test_common_range_offset_is_estimated():
    rng = np.random.default_rng(9)
    p = network(rng, offset_m=0.4)
    plain = solve_lm(p, objective="metres", sigma_m=0.1)
    cal = solve_lm(p, objective="metres", sigma_m=0.1, range_offsets="common")
    assert cal.offsets_m.shape == (1,) and abs(cal.offsets_m[0] - 0.4) < 3 * cal.offsets_std_m[0]
    assert cal.offsets_std_m[0] < 0.05
    assert rmse(p, cal.estimates) < 0.5 * rmse(p, plain.estimates)


def test_per_anchor_delays_with_prior():
    rng = np.random.default_rng(10)
    n = 30
    delays = rng.normal(0.0, 0.15, n)
    p = network(rng, n=n, delays_m=delays, sigma_m=0.05)
    plain = solve_lm(p, objective="metres", sigma_m=0.05)
    cal = solve_lm(p, objective="metres", sigma_m=0.05, range_offsets="per_anchor", offset_prior_sigma_m=0.3)
    assert cal.offsets_m.shape == (n,)
    z = (cal.offsets_m - delays) / cal.offsets_std_m
    assert np.mean(np.abs(z) <= 2.0) >= 0.85  # the delays within their stated 2σ
    assert rmse(p, cal.estimates) < rmse(p, plain.estimates)


def test_validation_of_the_new_options():
    p = network(np.random.default_rng(1), n=12)
    with pytest.raises(ModelError, match="objective"):
        solve_lm(p, objective="cubic")
    with pytest.raises(ModelError, match="range offsets"):
        solve_lm(p, range_offsets="common")
    with pytest.raises(ModelError, match="sigma_m"):
        solve_lm(p, objective="metres", sigma_m=0.0)
    with pytest.raises(ModelError, match="unknown loss"):
        solve_lm(p, objective="metres", loss="tukey")


class _Scripted:
    """A stand-in fit for exclude_links: the w of every original link is given; each call reports the kept ones
    (so the loop's choices can be checked by hand)."""

    def __init__(self, problem, w):
        self.problem, self.w, self.calls = problem, np.asarray(w, float), 0

    def __call__(self, sub):
        from types import SimpleNamespace

        from distnav.algorithms.result import ObservationTests

        self.calls += 1
        pairs = zip(self.problem.meas_a, self.problem.meas_b, strict=True)
        key = {(int(a), int(b)): k for k, (a, b) in enumerate(pairs)}
        w = np.array([self.w[key[(int(a), int(b))]] for a, b in zip(sub.meas_a, sub.meas_b, strict=True)])
        tests = ObservationTests(node=sub.meas_a, w=w, critical_value=3.29, level=0.001, flagged=np.abs(w) > 3.29)
        return SimpleNamespace(tests=tests, usable=True)


def _ring():
    """8 anchors around 2 known ones, every anchor with ≥ 5 links (2-D): room to exclude."""
    ids = [f"N{k}" for k in range(8)] + ["K0", "K1"]
    ang = np.linspace(0, 2 * np.pi, 8, endpoint=False)
    pos = np.vstack([np.column_stack([10 * np.cos(ang), 10 * np.sin(ang)]), [[0.0, 0.0], [3.0, 1.0]]])
    links = [(i, j) for i in range(10) for j in range(i + 1, 10) if np.linalg.norm(pos[i] - pos[j]) < 16]
    d = [float(np.linalg.norm(pos[i] - pos[j])) for i, j in links]
    return build_problem(
        ids,
        [(ids[i], ids[j]) for i, j in links],
        d,
        fixed={"K0": pos[8], "K1": pos[9]},
        dim=2,
        truth_m=pos,
        initial_m=pos,
    )


def test_exclusion_rounds_take_links_of_different_anchors_together():
    p = _ring()
    pair = {(int(a), int(b)): k for k, (a, b) in enumerate(zip(p.meas_a, p.meas_b, strict=True))}
    w = np.zeros(p.n_meas)
    w[pair[(0, 1)]], w[pair[(0, 2)]], w[pair[(4, 5)]] = -9.0, -8.0, -7.0  # two share anchor N0
    one = _Scripted(p, w)
    _, _, t1 = exclude_links(p, one)
    assert list(t1.removed) == [pair[(0, 1)], pair[(0, 2)], pair[(4, 5)]] and one.calls == 4
    for per_round in (4, None):  # a cap above the round's links, and no cap
        many = _Scripted(p, w)
        _, _, t2 = exclude_links(p, many, per_round=per_round)
        # round 1: N0-N1 and N4-N5 (no common anchor); N0-N2 waits for the re-fit (it shares N0); round 2: N0-N2
        assert list(t2.removed) == [pair[(0, 1)], pair[(4, 5)], pair[(0, 2)]] and many.calls == 3
        capped = _Scripted(p, w)
        _, _, t3 = exclude_links(p, capped, per_round=per_round, max_exclusions=1)
        assert list(t3.removed) == [pair[(0, 1)]]
    short = np.zeros(p.n_meas)
    short[pair[(4, 5)]] = +9.0  # measured short: never excluded one-sided, excluded two-sided
    assert exclude_links(p, _Scripted(p, short), one_sided=True)[2].removed == ()
    assert exclude_links(p, _Scripted(p, short))[2].removed == (pair[(4, 5)],)


@pytest.mark.parametrize("offsets", ["common", "per_anchor"])
def test_robust_w_tests_and_covariance_match_the_dense_formula(offsets):
    """IRLS weights (Cauchy), offset columns and prior rows: ``q_l`` of ``(I − JQJᵀW)(I − JQJᵀW)ᵀ`` and
    ``Q = (JᵀWJ)⁻¹`` formed densely, against :func:`centralized_quality` (chunked ``J Q Jᵀ``, ``potri``)."""
    from distnav.algorithms.ranging.losses import robust_weights
    from distnav.algorithms.ranging.qc import centralized_quality

    p = network(np.random.default_rng(4), n=18, offset_m=0.3)
    p = dataclasses.replace(p, range_m=p.range_m + np.where(np.arange(p.n_meas) % 17 == 0, 1.5, 0.0))  # NLOS
    o = RangeObjective(p, "metres", 0.1, offsets, 0.1)
    res = solve_lm(p, objective="metres", sigma_m=0.1, loss="cauchy", range_offsets=offsets)
    J = o.jacobian(res.x)
    r = o.residual(res.x)
    wt = robust_weights(r, o.loss_scale(0.3), "cauchy")[0]
    assert wt.min() < 0.1  # the NLOS links down-weighted
    _, tests, Q = centralized_quality(p, J, r, wt, p.n_meas, scale="a-priori")
    A = J.toarray()
    Q_ref = np.linalg.inv(A.T @ (wt[:, None] * A))
    R = np.eye(A.shape[0]) - A @ Q_ref @ A.T @ np.diag(wt)
    q_ref = np.diag(R @ R.T)[: p.n_meas]
    np.testing.assert_allclose(Q, Q_ref, rtol=1e-10, atol=1e-10 * np.abs(Q_ref).max())
    np.testing.assert_allclose(tests.w, r[: p.n_meas] / np.sqrt(q_ref), rtol=1e-10, atol=1e-10)


def test_loose_refits_decide_only_with_a_margin_and_end_with_the_full_fit():
    """exclude_links with ``loose`` (issue 27): the re-fits after an exclusion are the loose fit's; its choice is
    taken where it is decided with the margin, otherwise (and at the loop's end) the full fit decides — the same
    links are excluded as by the full fit alone, the loose fit's own order or threshold would have excluded others."""
    p = _ring()
    pair = {(int(a), int(b)): k for k, (a, b) in enumerate(zip(p.meas_a, p.meas_b, strict=True))}
    w = np.zeros(p.n_meas)
    w[pair[(0, 1)]], w[pair[(0, 2)]], w[pair[(4, 5)]], w[pair[(6, 7)]] = -9.0, -8.0, -7.0, -3.2
    alone = exclude_links(p, _Scripted(p, w))[2].removed
    assert alone == (pair[(0, 1)], pair[(0, 2)], pair[(4, 5)])
    # loose |w| far from each other and from 3.29: every choice decided loose
    near = w.copy()
    near[pair[(0, 2)]], near[pair[(4, 5)]], near[pair[(6, 7)]] = -7.95, -7.05, -2.0
    full, loose = _Scripted(p, w), _Scripted(p, near)
    assert exclude_links(p, full, loose=[(loose, 0.1)])[2].removed == alone
    assert (full.calls, loose.calls) == (2, 3)  # the first fit and the end; three loose re-fits
    # the loose fit ranks N4-N5 above N0-N2 (0.05 apart) and reads N6-N7 flagged (3.35, 0.06 above 3.29)
    swapped = w.copy()
    swapped[pair[(0, 2)]], swapped[pair[(4, 5)]], swapped[pair[(6, 7)]] = -7.0, -7.05, -3.35
    with_margin = exclude_links(p, _Scripted(p, w), loose=[(_Scripted(p, swapped), 0.1)])[2].removed
    assert with_margin == alone
    without = exclude_links(p, _Scripted(p, w), loose=[(_Scripted(p, swapped), 0.0)])[2].removed
    assert pair[(6, 7)] in without and without != alone  # what the margin prevents


def test_decided_swaps_only_what_changes_the_choice():
    """_decided: two close links of one anchor (only one can go per round) are undecided; two close links of
    different anchors both go whatever their order (decided); a |w| within the margin of the critical value is
    undecided."""
    from distnav.algorithms.ranging.qc import _decided

    a, b = np.array([0, 0, 4]), np.array([1, 2, 5])
    assert not _decided(6, np.array([7.0, 7.05, 5.0]), (a, b), 3, 3.29, 0.1)
    assert _decided(6, np.array([7.0, 5.0, 7.05]), (a, b), 3, 3.29, 0.1)
    assert _decided(6, np.array([7.0, 6.0, 5.0]), (a, b), 3, 3.29, 0.1)
    assert not _decided(6, np.array([7.0, 6.0, 3.3]), (a, b), 3, 3.29, 0.1)
    assert not _decided(6, np.array([7.0, 5.0, 7.05]), (a, b), 1, 3.29, 0.1)  # the cap of 1: the order decides


def test_a_near_critical_link_behind_a_pick_of_its_anchor_does_not_leave_the_choice_open():
    """_decided (issue 27, sixth session): a link whose |w| is within the margin of the critical value but shares an
    anchor with a pick that stays flagged and ahead of it whatever the margin is never picked this round — the
    choice is decided; not where the pick could fall behind it, nor for a near-critical link of other anchors."""
    from distnav.algorithms.ranging import qc

    a, b = np.array([0, 0, 4]), np.array([1, 2, 5])
    assert qc._decided(6, np.array([7.0, 3.3, 5.0]), (a, b), 3, 3.29, 0.1)
    assert not qc._decided(6, np.array([3.45, 3.3, 5.0]), (a, b), 3, 3.29, 0.1)  # 0.15 apart: the order may swap
    assert not qc._decided(6, np.array([7.0, 5.0, 3.3]), (a, b), 3, 3.29, 0.1)  # anchors 4, 5: nothing ahead
    # the picks are the same at either end of the margin: the blocked link goes neither way
    for w1 in (3.19, 3.39):
        assert qc._round_picks(6, np.array([7.0, w1, 5.0]), a, b, 3, 3.29) == [0, 2]
    assert qc._always_blocked(np.array([7.0, 3.3, 5.0]), a, b, [0, 2], 3.29, 0.1).tolist() == [False, True, False]


def _three_flagged():
    """The ring with three flagged links (N0-N1, N0-N2 of one anchor, N4-N5), the links the full fit alone excludes,
    and a loose fit's reading of them: N0-N2 and N4-N5 0.05 off, far from each other and from 3.29."""
    p = _ring()
    pair = {(int(a), int(b)): k for k, (a, b) in enumerate(zip(p.meas_a, p.meas_b, strict=True))}
    w = np.zeros(p.n_meas)
    w[pair[(0, 1)]], w[pair[(0, 2)]], w[pair[(4, 5)]] = -9.0, -8.0, -7.0
    alone = exclude_links(p, _Scripted(p, w))[2].removed
    near = w.copy()
    near[pair[(0, 2)]], near[pair[(4, 5)]] = -7.95, -7.05
    return p, pair, w, alone, near


def test_a_ladder_of_loose_fits_climbs_only_where_a_choice_is_open():
    """exclude_links with two loose rungs (issue 27, sixth session: 1 cm, then 3 mm): a choice the first rung leaves
    open goes to the second, which decides it with its smaller margin; where a decided choice ends the loop, the
    full fit confirms it at once (the second rung is not run there). The same links as the full fit alone."""
    p, pair, w, alone, near = _three_flagged()
    full, coarse, fine = _Scripted(p, w), _Scripted(p, near), _Scripted(p, near)
    assert exclude_links(p, full, loose=[(coarse, 0.1), (fine, 0.02)])[2].removed == alone
    assert (full.calls, coarse.calls, fine.calls) == (2, 3, 0)  # every choice decided by the coarse rung
    # the coarse rung reads N0-N2 and N4-N5 0.02 apart (open at its margin 0.1), the fine rung 0.9 apart (decided)
    blur = w.copy()
    blur[pair[(0, 2)]], blur[pair[(4, 5)]] = -7.06, -7.04
    full, coarse, fine = _Scripted(p, w), _Scripted(p, blur), _Scripted(p, near)
    assert exclude_links(p, full, loose=[(coarse, 0.1), (fine, 0.02)])[2].removed == alone
    assert fine.calls >= 1 and full.calls == 2  # the fine rung decided; the full fit: the first and the end


def test_an_opening_fit_starts_the_loop_at_the_first_rung():
    """exclude_links with ``opening`` (issue 27, seventh session: the workflow's last tightening fit, stopped at 1 cm
    and tested): the loop starts from it as from a loose re-fit — a decided choice is taken without a full fit of
    every link, an open one goes to the next fit — and excludes the same links as the full fit alone; without a
    loose rung the opening is not used (the full fit first, as before)."""
    p, pair, w, alone, near = _three_flagged()
    full, loose = _Scripted(p, w), _Scripted(p, near)
    opening = _Scripted(p, near)(p)
    assert exclude_links(p, full, loose=[(loose, 0.1)], opening=opening)[2].removed == alone
    assert (full.calls, loose.calls) == (1, 3)  # no full fit of every link (only the loop's end); three re-fits
    # the opening reads N4-N5 at 3.3, within the margin of 3.29: open, the full fit of every link decides
    blur = w.copy()
    blur[pair[(0, 2)]], blur[pair[(4, 5)]] = -7.95, -3.3
    full, loose = _Scripted(p, w), _Scripted(p, near)
    assert exclude_links(p, full, loose=[(loose, 0.1)], opening=_Scripted(p, blur)(p))[2].removed == alone
    assert full.calls == 2
    full = _Scripted(p, w)
    assert exclude_links(p, full, opening=_Scripted(p, blur)(p))[2].removed == alone
    assert full.calls == 4  # no loose rung: the opening is ignored (the first fit and three re-fits, all full)


def test_without_confirm_a_decided_loose_end_is_returned():
    """exclude_links with ``confirm=False`` (issue 27, seventh session): where a decided choice ends the loop on a loose
    re-fit, that fit is returned without a full fit to confirm it (the caller completes it where needed); the same
    links are excluded, and an open choice still goes to the full fit."""
    p, pair, w, alone, near = _three_flagged()
    full, loose = _Scripted(p, w), _Scripted(p, near)
    res, _, tests = exclude_links(p, full, loose=[(loose, 0.1)], confirm=False)
    assert tests.removed == alone
    assert (full.calls, loose.calls) == (1, 3)  # the first fit only: the loop ended on the third loose re-fit
    assert np.array_equal(res.tests.w, loose(_without(p, alone)).tests.w)
    blur = near.copy()
    blur[pair[(6, 7)]] = -3.3  # every loose re-fit reads N6-N7 within the margin of 3.29: open
    full = _Scripted(p, w)
    res, _, tests = exclude_links(p, full, loose=[(_Scripted(p, blur), 0.1)], confirm=False)
    assert tests.removed == alone
    assert full.calls == 4  # the first fit, then each open choice's: the loop ends on the full fit
    assert np.array_equal(res.tests.w, full(_without(p, alone)).tests.w)


class _Unusable(_Scripted):
    """A loose fit that fails (diverged / singular: unusable) on every subproblem but the whole one."""

    def __call__(self, sub):
        r = super().__call__(sub)
        r.usable = sub.n_meas == self.problem.n_meas
        return r


def test_without_confirm_an_unusable_loose_fit_does_not_end_the_loop():
    """exclude_links with ``confirm=False``: a loose re-fit that is unusable has no eligible link, so its (empty)
    choice is "decided" — it must not end the loop (review of issue 27, seventh session: it returned the unusable
    fit with one link excluded of three); the full fit continues, and the loop excludes what it alone excludes."""
    p, pair, w, alone, near = _three_flagged()
    full, loose = _Scripted(p, w), _Unusable(p, near)
    res, _, tests = exclude_links(p, full, loose=[(loose, 0.1)], confirm=False)
    assert res.usable
    assert tests.removed == alone
    assert np.array_equal(res.tests.w, full(_without(p, alone)).tests.w)


def _without(p, removed):
    keep = np.ones(p.n_meas, bool)
    keep[list(removed)] = False
    return dataclasses.replace(p, meas_a=p.meas_a[keep], meas_b=p.meas_b[keep], range_m=p.range_m[keep])


def _grid():
    """7 × 7 anchors 5 m apart (2-D), links up to 11 m (5–12 per anchor), the four corners known."""
    xy = np.array([(5.0 * i, 5.0 * j) for i in range(7) for j in range(7)])
    ids = [f"G{k}" for k in range(len(xy))]
    links = [(i, j) for i in range(len(xy)) for j in range(i + 1, len(xy)) if np.linalg.norm(xy[i] - xy[j]) < 11]
    d = [float(np.linalg.norm(xy[i] - xy[j])) for i, j in links]
    corners = {ids[k]: xy[k] for k in (0, 6, 42, 48)}
    return build_problem(ids, [(ids[i], ids[j]) for i, j in links], d, fixed=corners, dim=2, truth_m=xy, initial_m=xy)


def test_sure_picks_are_chosen_whatever_each_w_within_the_margin():
    """_sure_picks (issue 27, eighth session) against the round itself: on random rounds of the grid, every sure
    pick is chosen by :func:`_round_picks` of the |w| each moved by anything within the margin (random moves and
    moves to either end); by hand, a pick with a rival of its anchors within twice the margin, one within the margin
    of the critical value, or one the cap may stop is not sure."""
    from distnav.algorithms.ranging.qc import _round_picks, _sure_picks

    p, rng, margin, n_sure = _grid(), np.random.default_rng(27), 0.8, 0
    a, b = p.meas_a, p.meas_b
    for _ in range(40):
        aw = np.abs(rng.normal(0.0, 4.0, a.size))
        aw[rng.random(a.size) < 0.1] = -np.inf  # not eligible
        cap = int(rng.integers(2, 16))
        picks = _round_picks(p.n_anchors, aw, a, b, cap, 3.29)
        sure = _sure_picks(aw, (a, b), cap, 3.29, margin, picks)
        assert set(sure) <= set(picks)
        n_sure += len(sure)
        for k in range(60):
            move = rng.uniform(-margin, margin, a.size) if k % 2 else margin * rng.choice([-1.0, 1.0], a.size)
            assert set(sure) <= set(_round_picks(p.n_anchors, aw + move, a, b, cap, 3.29))
    assert n_sure > 40  # not vacuous: sure picks were checked
    a, b = np.array([0, 0, 4]), np.array([1, 2, 5])
    assert _sure_picks(np.array([7.0, 5.5, 5.0]), (a, b), 3, 3.29, 0.8, [0, 2]) == [2]  # 5.5 within 1.6 of 7.0
    assert _sure_picks(np.array([7.0, 5.3, 5.0]), (a, b), 3, 3.29, 0.8, [0, 2]) == [0, 2]
    assert _sure_picks(np.array([7.0, 5.3, 4.0]), (a, b), 3, 3.29, 0.8, [0, 2]) == [0]  # 4.0 within 0.8 of 3.29
    assert _sure_picks(np.array([7.0, 5.3, 6.0]), (a, b), 1, 3.29, 0.8, [0]) == []  # 6.0 may come first: cap 1
    assert _sure_picks(np.array([7.0, 5.3, 5.0]), (a, b), 1, 3.29, 0.8, [0]) == [0]


def _static_round_tests(rng, p, margin):
    """w of every grid link that does not depend on the round (a scripted full fit), with 22 links far above the
    critical value and 24 near it, no anchor holding more than 3 links above ``3.29 − margin`` (so none runs
    out of links: every anchor keeps more than its 3 needed), and a loose reading of them within ``margin``."""
    w = -np.abs(rng.normal(0.0, 1.0, p.n_meas))
    count = np.zeros(p.n_anchors, int)
    chosen = []
    for k in rng.permutation(p.n_meas):
        ends = [int(p.meas_a[k]), int(p.meas_b[k])]
        if len(chosen) < 46 and all(count[e] < 3 for e in ends):
            chosen.append(k)
            count[ends] += 1
    chosen = np.array(chosen)
    w[chosen[:22]] = -rng.uniform(5.0, 60.0, 22)
    w[chosen[22:]] = -rng.uniform(3.29 - margin, 3.29 + margin, chosen.size - 22)
    return w, w + rng.uniform(-0.95 * margin, 0.95 * margin, w.size)


def test_deferred_rounds_exclude_what_full_rounds_exclude_where_the_tests_do_not_move(monkeypatch):
    """exclude_links deferring an open round's undecided links (issue 27, eighth session) against the same loop with
    every round on the full fit: where each link's w stays the same from round to round (scripted) and no anchor
    runs out of links, Baarda's iteration ends with exactly the links the full fit flags, whatever the order — so
    deferral cannot change them. The same links on 6 draws, and fewer full fits than with every open round climbing
    (the seventh session's loop), which the gate (:data:`qc.DEFER_MIN_NEAR`) restores to
    the call."""
    from distnav.algorithms.ranging import qc

    p, rng, margin = _grid(), np.random.default_rng(8), 0.8
    monkeypatch.setattr(qc, "DEFER_MIN_ANCHORS", 0)  # the scale gate (tenth session) off: a 49-anchor grid
    for _ in range(6):
        w, coarse_w = _static_round_tests(rng, p, margin)
        fine_w = w + rng.uniform(-0.95 * margin / 4, 0.95 * margin / 4, w.size)
        alone = set(exclude_links(p, _Scripted(p, w), per_round=4)[2].removed)
        assert alone == set(np.flatnonzero(np.abs(w) > 3.29).tolist())
        calls = {}
        for defer, min_near, stays in ((True, 3, False), (True, 3, True), (False, 3, True), (True, 10**6, True)):
            monkeypatch.setattr(qc, "DEFER_OPEN", defer)
            monkeypatch.setattr(qc, "DEFER_MIN_NEAR", min_near)
            monkeypatch.setattr(qc, "DEFER_STAYS", stays)
            full, coarse, fine = _Scripted(p, w), _Scripted(p, coarse_w), _Scripted(p, fine_w)
            ladder = [(coarse, margin), (fine, margin / 4)]  # a 1 cm and a 3 mm rung, as the workflow's
            opening = _Scripted(p, coarse_w)(p)  # the loop opens on a loose fit of every link, as the workflow's
            removed = exclude_links(p, full, per_round=4, loose=ladder, opening=opening)[2].removed
            assert set(removed) == alone
            calls[defer, min_near, stays] = (full.calls, coarse.calls, fine.calls, removed)
        assert max(calls[True, 3, False][0], calls[True, 3, True][0]) < calls[False, 3, True][0]
        assert calls[True, 10**6, True] == calls[False, 3, True]  # gated off: the seventh session's, call for call
        monkeypatch.setattr(qc, "DEFER_MIN_ANCHORS", p.n_anchors + 1)  # the scale gate: below it, the same
        monkeypatch.setattr(qc, "DEFER_MIN_NEAR", 3)
        full, coarse, fine = _Scripted(p, w), _Scripted(p, coarse_w), _Scripted(p, fine_w)
        ladder = [(coarse, margin), (fine, margin / 4)]
        removed = exclude_links(p, full, per_round=4, loose=ladder, opening=_Scripted(p, coarse_w)(p))[2].removed
        assert (full.calls, coarse.calls, fine.calls, removed) == calls[False, 3, True]
        monkeypatch.setattr(qc, "DEFER_MIN_ANCHORS", 0)
