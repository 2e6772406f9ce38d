"""Baarda's reliability: redundancy numbers, minimal detectable bias, and the external reliability of a UWB solve.

References independent of the code under test: a levelling loop worked by hand, scipy.stats for the power of the
w-test, the w-statistic of :func:`distnav.algorithms.statistics.data_snooping` for the MDB's definition, a finite-
difference hat matrix and scipy ``least_squares`` re-fits with the bias added to the range for the UWB numbers.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats
from scipy.optimize import least_squares

from distnav.algorithms.statistics import (
    critical_value,
    data_snooping,
    minimal_detectable_bias,
    noncentrality,
    redundancy_numbers,
)
from distnav.models.uwb.problems import build_problem
from distnav.models.uwb.reliability import ReliabilityOptions, external_reliability, reliability_weak


def test_noncentrality_is_baardas_and_gives_the_stated_power():
    lam0 = noncentrality(0.001, 0.8)
    assert lam0 == pytest.approx(4.13**2, rel=2e-3)  # Baarda's δ0 = 4.13 for α = 0.001, β = 0.80
    k = critical_value(0.001)
    d = np.sqrt(lam0)
    power = stats.norm.sf(k - d) + stats.norm.cdf(-k - d)  # |N(δ0, 1)| > k, both tails
    assert power == pytest.approx(0.8, abs=1e-6)  # the far tail is ~1e-16
    with pytest.raises(Exception, match="power"):
        noncentrality(0.001, 1.5)


def test_levelling_loop_by_hand():
    """A closed loop A→B→C→A of three equal levelling lines, A known: every line has r = 1/3 (worked by hand:
    h = a Q aᵀ = 2/3 for each line), Σ r = 3 − 2, MDB = σ √(3 λ0)."""
    A = np.array([[1.0, 0.0], [-1.0, 1.0], [0.0, -1.0]])  # unknowns H_B, H_C; hAB, hBC, hCA
    sigma = 0.002
    p = np.full(3, 1.0 / sigma**2)
    Q = np.linalg.inv(A.T @ (p[:, None] * A))
    r = redundancy_numbers(A, p, Q)
    assert np.allclose(r, 1.0 / 3.0) and r.sum() == pytest.approx(1.0)
    lam0 = noncentrality(0.001, 0.8)
    assert np.allclose(minimal_detectable_bias(sigma, r, lam0), sigma * np.sqrt(3.0 * lam0))
    # an observation nothing checks (a spur line to a new point D): r = 0, MDB infinite
    A2 = np.vstack([np.c_[A, np.zeros(3)], [0.0, 1.0, 1.0]])  # hCD = H_D − H_C
    Q2 = np.linalg.inv(A2.T @ (np.full(4, 1 / sigma**2)[:, None] * A2))
    r2 = redundancy_numbers(A2, np.full(4, 1 / sigma**2), Q2)
    assert r2[3] == pytest.approx(0.0, abs=1e-12) and np.isinf(minimal_detectable_bias(sigma, r2, lam0)[3])


def test_mdb_moves_the_w_statistic_by_sqrt_lambda0_and_redundancy_sums_to_m_minus_n():
    rng = np.random.default_rng(7)
    A = rng.normal(size=(12, 4))
    sigma = rng.uniform(0.5, 2.0, 12)
    p = 1.0 / sigma**2
    Q = np.linalg.inv(A.T @ (p[:, None] * A))
    r = redundancy_numbers(A, p, Q)
    assert r.sum() == pytest.approx(12 - 4)
    import scipy.sparse as sp

    assert np.allclose(redundancy_numbers(sp.csr_matrix(A), p, Q), r)  # the sparse path
    lam0 = noncentrality(0.001, 0.8)
    mdb = minimal_detectable_bias(sigma, r, lam0)
    x = rng.normal(size=4)
    for i in (0, 5, 11):
        y = A @ x
        y[i] += mdb[i]  # noise-free data with the MDB on observation i
        out = data_snooping(A, y, sigma**2, level=0.001, max_removals=0)
        assert abs(out.w[i]) == pytest.approx(np.sqrt(lam0), rel=1e-9)


def _network(seed: int, noise_m: float = 0.03):
    """2-D: 4 known anchors on a 20 m square, 6 free anchors inside, every pair within 25 m ranged once."""
    rng = np.random.default_rng(seed)
    known = {"K0": [0.0, 0.0], "K1": [20.0, 0.0], "K2": [20.0, 20.0], "K3": [0.0, 20.0]}
    free = rng.uniform(2.0, 18.0, (6, 2))
    ids = [*known, *(f"F{k}" for k in range(6))]
    pos = np.vstack([np.array(list(known.values())), free])
    links = [
        (ids[i], ids[j])
        for i in range(10)
        for j in range(i + 1, 10)
        if (i >= 4 or j >= 4) and np.linalg.norm(pos[i] - pos[j]) < 25.0 and rng.random() < 0.9
    ]
    d = np.array([np.linalg.norm(pos[ids.index(a)] - pos[ids.index(b)]) for a, b in links])
    ranges = d + rng.normal(0.0, noise_m, d.size)
    return build_problem(ids, links, ranges, fixed=known, dim=2, truth_m=pos, initial_m=pos), pos


def _fit(p, ranges, start, offset: bool):
    """Independent least squares on the residual in metres (scipy), optionally with a common offset."""
    a, b = p.meas_a, p.meas_b
    free = np.flatnonzero(p.estimated)

    def res(v):
        q = p.truth_m.copy()
        q[free] = v[: 2 * free.size].reshape(-1, 2)
        return (np.linalg.norm(q[a] - q[b], axis=1) + (v[-1] if offset else 0.0) - ranges) / 0.1

    v0 = np.r_[start[free].ravel(), [0.0] if offset else []]
    return least_squares(res, v0, xtol=1e-15, ftol=1e-15, gtol=1e-15).x, res


@pytest.mark.parametrize("offset", [False, True])
def test_uwb_redundancy_mdb_and_shift_against_refits(offset):
    p, pos = _network(3)
    x, res = _fit(p, p.range_m, pos, offset)
    rel = external_reliability(p, x, ReliabilityOptions(sigma_m=0.1, offsets="common" if offset else "none"))
    assert rel is not None
    n_x = x.size
    # redundancy numbers against a finite-difference hat matrix of the independent residual function
    J = np.column_stack([(res(x + 1e-6 * e) - res(x - 1e-6 * e)) / 2e-6 for e in np.eye(n_x)])
    H = J @ np.linalg.solve(J.T @ J, J.T)
    assert np.allclose(rel.r, 1.0 - np.diag(H), atol=1e-6)
    assert rel.redundancy == pytest.approx(p.n_meas - n_x, abs=1e-6)
    # MDB = σ ŝ √(λ0 / r) with the linear loss
    assert rel.r.min() > 0.05  # every link checked in this network
    assert np.allclose(rel.mdb_m, 0.1 * rel.scale * np.sqrt(rel.lam0 / rel.r))
    # each free anchor's worst shift against re-fitting with that link's MDB added to its range
    free = np.flatnonzero(p.estimated)
    for i in free:
        k = int(rel.worst_link[i])
        biased = p.range_m.copy()
        biased[k] += rel.mdb_m[k]
        x2, _ = _fit(p, biased, p.truth_m, offset)
        col = 2 * int(np.flatnonzero(free == i)[0])
        moved = float(np.linalg.norm(x2[col : col + 2] - x[col : col + 2]))
        assert moved == pytest.approx(rel.shift_m[i], rel=0.01), (i, k)  # seen: ≤ 0.5 %
    assert np.all(rel.shift_m[~p.estimated] == 0.0)


def test_reliability_weak_names_the_link_and_the_shift():
    p, pos = _network(3)
    x, _ = _fit(p, p.range_m, pos, False)
    rel = external_reliability(p, x, ReliabilityOptions(sigma_m=0.1))
    assert rel is not None
    sigma = np.zeros((p.n_anchors, 2))
    top = int(np.argmax(rel.shift_m))
    limit = 0.5 * float(rel.shift_m[top])
    weak = reliability_weak(p, rel, sigma, limit_m=limit)
    assert p.ids[top] in weak
    assert set(weak) == {p.ids[i] for i in np.flatnonzero(rel.shift_m > limit)}
    k = int(rel.worst_link[top])
    text = weak[p.ids[top]]
    assert f"{p.ids[p.meas_a[k]]}-{p.ids[p.meas_b[k]]}" in text and f"{rel.shift_m[top]:.2f} m" in text
    # a σ larger than a third of the shift: σ already says so, not weak
    big = np.full((p.n_anchors, 2), float(rel.shift_m.max()))
    assert reliability_weak(p, rel, big, limit_m=limit) == {}


def test_an_unchecked_link_makes_its_anchor_weak():
    """F has exactly 2 links for 2 coordinates: nothing checks them (r = 0), the MDB is infinite."""
    known = {"K0": [0.0, 0.0], "K1": [10.0, 0.0], "K2": [10.0, 10.0], "K3": [0.0, 10.0]}
    g, f = np.array([4.0, 5.0]), np.array([14.0, 6.0])
    ids = [*known, "G", "F"]
    pos = np.vstack([np.array(list(known.values())), g, f])
    links = [("G", k) for k in known] + [("F", "K1"), ("F", "K2")]
    d = np.array([np.linalg.norm(pos[ids.index(a)] - pos[ids.index(b)]) for a, b in links])
    d[:4] += [0.02, -0.01, 0.015, -0.02]
    p = build_problem(ids, links, d, fixed=known, dim=2, truth_m=pos, initial_m=pos)
    x, _ = _fit(p, p.range_m, pos, False)
    rel = external_reliability(p, x, ReliabilityOptions(sigma_m=0.1))
    assert rel is not None
    assert np.all(np.isinf(rel.mdb_m[4:])) and np.all(np.isfinite(rel.mdb_m[:4]))
    assert np.isinf(rel.shift_m[ids.index("F")]) and np.isfinite(rel.shift_m[ids.index("G")])
    weak = reliability_weak(p, rel, np.zeros((6, 2)))
    assert "F" in weak and "checked by nothing" in weak["F"]
