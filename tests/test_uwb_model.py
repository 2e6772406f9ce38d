"""UWB ranging model (paper 002 eqs. (2)-(6), (9), (14), (23)-(24)), its validation rules and the problem generators."""

from __future__ import annotations

import numpy as np
import pytest

from distnav.errors import ModelError
from distnav.models.uwb.problems import (
    PAPER_PROBLEMS,
    build_problem,
    generate_layout,
    generate_problem,
    rmse_m,
    select_fixed,
)


def small_problem(dim: int = 2) -> tuple:
    truth = np.array([[0.0, 0.0], [10.0, 0.0], [0.0, 10.0], [10.0, 10.0], [5.0, 14.0]])
    if dim == 3:
        truth = np.column_stack([truth, [0.0, 1.0, 2.0, 3.0, 1.5]])
    ids = ["a", "b", "c", "d", "e"]
    links = [("a", "b"), ("a", "c"), ("b", "d"), ("c", "d"), ("a", "d"), ("c", "e"), ("d", "e"), ("d", "e")]
    rng = np.random.default_rng(0)
    ranges = np.array([np.linalg.norm(truth[ids.index(p)] - truth[ids.index(q)]) for p, q in links])
    ranges = ranges + rng.normal(0, 0.1, ranges.size)
    fixed = {k: truth[ids.index(k)] for k in (["a", "b"] if dim == 2 else ["a", "b", "c"])}
    init = truth + rng.uniform(-1, 1, truth.shape)
    return build_problem(ids, links, ranges, fixed=fixed, dim=dim, initial_m=init, truth_m=truth), truth, ranges, links


def test_residual_cost_by_hand():
    p, truth, ranges, links = small_problem()
    x = p.initial_m
    ids = list(p.ids)
    by_hand = []
    for (u, v), d in zip(links, ranges, strict=True):
        diff = x[ids.index(u)] - x[ids.index(v)]
        by_hand.append(diff @ diff - d * d)  # eq. (6): no square root
    np.testing.assert_allclose(p.residuals(x), by_hand, rtol=1e-12)
    assert p.cost(x) == pytest.approx(sum(r * r for r in by_hand), rel=1e-12)
    # a pair measured twice gives two residuals (links with many samples)
    assert p.n_meas == 8 and p.links.shape[0] == 7


@pytest.mark.parametrize("dim", [2, 3])
def test_jacobian_matches_finite_differences(dim):
    p, *_ = small_problem(dim)
    x = p.x0()
    J = p.jacobian_of(x).toarray()
    eps = 1e-6
    num = np.column_stack(
        [(p.residual_vector(x + eps * e) - p.residual_vector(x - eps * e)) / (2 * eps) for e in np.eye(x.size)]
    )
    np.testing.assert_allclose(J, num, rtol=1e-6, atol=1e-5)
    assert p.jacobian_of(x).nnz <= 2 * dim * p.n_meas  # sparse: two blocks per row


def test_partial_costs_sum_to_twice_the_cost():
    p, *_ = small_problem(3)
    pc = p.partial_costs(p.initial_m)  # eq. (14)
    assert pc.sum() == pytest.approx(2 * p.cost(p.initial_m), rel=1e-12)


def test_held_coordinates_are_not_unknowns():
    truth = np.array([[0, 0, 3.0], [10, 0, 3.0], [0, 10, 2.5], [10, 10, 2.8]])
    ids = ["0", "1", "2", "3"]
    links = [("0", "1"), ("0", "2"), ("1", "3"), ("2", "3"), ("0", "3"), ("1", "2")]
    d = [np.linalg.norm(truth[int(a)] - truth[int(b)]) for a, b in links]
    # 3-D with only two fixed anchors is allowed when every estimated height is held
    p = build_problem(
        ids, links, d, fixed={"0": truth[0], "1": truth[1]}, dim=3, held={"2": {2: 2.5}, "3": {2: 2.8}}, truth_m=truth
    )
    assert p.n_free == 4
    pos = p.to_positions(np.array([1.0, 2.0, 3.0, 4.0]))
    np.testing.assert_allclose(pos[2], [1, 2, 2.5])
    np.testing.assert_allclose(pos[3], [3, 4, 2.8])
    np.testing.assert_allclose(p.to_vector(truth), [0, 10, 10, 10])


def test_rmse_eq24():
    p, truth, *_ = small_problem()
    est = truth.copy()
    est[2] += [3.0, 4.0]  # 5 m on one of three estimated anchors
    assert rmse_m(p, est) == pytest.approx(np.sqrt(25.0 / 3.0))
    est[0] += 100.0  # fixed anchors do not count
    assert rmse_m(p, est) == pytest.approx(np.sqrt(25.0 / 3.0))


# ---------------------------------------------------------------------- validation rules
IDS = ["a", "b", "c", "d"]
FIX2 = {"a": [0.0, 0.0], "b": [10.0, 0.0]}


@pytest.mark.parametrize(
    "links, ranges, kwargs, match",
    [
        ([("a", "x")], [5.0], {"fixed": FIX2, "dim": 2}, "anchor 'x'"),
        ([("a", 7)], [5.0], {"fixed": FIX2, "dim": 2}, "index 7"),
        ([("a", "a")], [5.0], {"fixed": FIX2, "dim": 2}, "to itself"),
        ([("a", "c"), ("b", "c")], [5.0, -1.0], {"fixed": FIX2, "dim": 2}, "negative"),
        ([("a", "c"), ("b", "c")], [5.0, np.nan], {"fixed": FIX2, "dim": 2}, "not finite"),
        ([("a", "c"), ("b", "c")], [np.inf, 3.0], {"fixed": FIX2, "dim": 2}, "not finite"),
        ([("a", "c"), ("b", "c")], [5.0], {"fixed": FIX2, "dim": 2}, "2 links but 1 ranges"),
        ([("a", "c")], [5.0], {"fixed": {"a": [0.0, 0.0]}, "dim": 2}, "at least 2 fixed"),
        (
            [("a", "c"), ("b", "c")],
            [5.0, 5.0],
            {"fixed": {"a": [0, 0, 0], "b": [1, 0, 0]}, "dim": 3},
            "3 non-collinear",
        ),
        (
            [("a", "d"), ("b", "d")],
            [5.0, 5.0],
            {"fixed": {"a": [0, 0, 0], "b": [1, 0, 0], "c": [2, 0, 0]}, "dim": 3},
            "collinear",
        ),
        ([("a", "c"), ("b", "c")], [5.0, 5.0], {"fixed": FIX2, "dim": 2}, "'d'"),  # d has no link to fixed
        ([("a", "c")], [5.0], {"fixed": {"a": [0.0, 0.0], "z": [1.0, 1.0]}, "dim": 2}, "fixed anchor 'z'"),
        ([("a", "c")], [5.0], {"fixed": {"a": [0.0, 0.0], "b": [np.nan, 1.0]}, "dim": 2}, "finite coordinates"),
        ([("a", "c")], [5.0], {"fixed": {"a": [0.0, 0.0], "b": [1.0, 1.0, 1.0]}, "dim": 2}, "2 finite"),
        ([("a", "c")], [5.0], {"fixed": FIX2, "dim": 4}, "dim must be 2 or 3"),
        ([], [], {"fixed": FIX2, "dim": 2}, "no ranges"),
    ],
)
def test_validation_rules(links, ranges, kwargs, match):
    with pytest.raises(ModelError, match=match):
        build_problem(IDS, links, ranges, **kwargs)


def test_disconnected_estimated_anchors_are_named():
    links = [("a", "b"), ("c", "d")]
    with pytest.raises(ModelError, match=r"'c', 'd' have no chain of measured links"):
        build_problem(IDS, links, [10.0, 4.0], fixed=FIX2, dim=2)


def test_duplicate_ids_and_bad_held_coordinate():
    with pytest.raises(ModelError, match="used twice"):
        build_problem(["a", "a", "b"], [("a", "b")], [1.0], fixed=FIX2, dim=2)
    with pytest.raises(ModelError, match="held coordinate"):
        build_problem(
            IDS, [("a", "c"), ("b", "c"), ("c", "d")], [5.0, 5.0, 5.0], fixed=FIX2, dim=2, held={"c": {2: 1.0}}
        )
    with pytest.raises(ModelError, match="held coordinate of anchor 'q'"):
        build_problem(
            IDS, [("a", "c"), ("b", "c"), ("c", "d")], [5.0, 5.0, 5.0], fixed=FIX2, dim=2, held={"q": {0: 1.0}}
        )


def test_bad_initial_guess_and_positions_shape():
    p, *_ = small_problem()
    with pytest.raises(ModelError, match="shape"):
        p.with_initial(np.zeros((4, 2)))
    bad = p.initial_m.copy()
    bad[3, 0] = np.nan
    with pytest.raises(ModelError, match="'d' is not finite"):
        p.with_initial(bad)
    with pytest.raises(ModelError, match="negative"):
        p.with_ranges(-np.ones(p.n_meas))


# ---------------------------------------------------------------------- generators (paper 002 §4)
def test_grid_class_G():
    pos, links = generate_layout("G")
    assert pos.shape == (100, 2)
    length = np.linalg.norm(pos[links[:, 0]] - pos[links[:, 1]], axis=1)
    np.testing.assert_allclose(np.unique(np.round(length, 6)), [10.0, np.round(np.hypot(10, 10), 6)])
    deg = np.bincount(links.ravel(), minlength=100)
    assert deg.max() == 8 and deg.min() == 3
    assert links.shape[0] == 2 * 9 * 10 + 2 * 9 * 9  # rows, columns, two diagonals


def test_ladder_class_L():
    pos, links = generate_layout("L")
    assert np.unique(pos[:, 1]).size == 2 and np.unique(pos[:, 0]).size == 50
    deg = np.bincount(links.ravel(), minlength=100)
    assert deg.max() == 5
    # every link joins the same or adjacent columns
    dx = np.abs(pos[links[:, 0], 0] - pos[links[:, 1], 0])
    assert set(np.round(dx, 6)) == {0.0, 10.0}


def test_random_class_R(rng):
    pos, links = generate_layout("R", rng)
    d = np.linalg.norm(pos[:, None] - pos[None], axis=2)
    a, b = np.triu_indices(100, 1)
    linked = set(map(tuple, links.tolist()))
    should = {(int(i), int(j)) for i, j in zip(a, b, strict=True) if d[i, j] < 18.0}
    assert linked == should


def test_fixed_selections():
    pos, _ = generate_layout("G")
    c = pos[select_fixed(pos, "C")]
    assert {tuple(v) for v in c} == {(0.0, 0.0), (10.0, 0.0), (0.0, 10.0)}
    o = pos[select_fixed(pos, "O")]
    assert sum(1 for v in o if v[0] >= 80 and v[1] <= 10) == 2 and sum(1 for v in o if v[0] == 0 and v[1] == 90) == 1
    m = pos[select_fixed(pos, "M")]
    assert np.all(np.abs(m - 45.0) <= 5.0 + 1e-9)
    with pytest.raises(ModelError, match="selection"):
        select_fixed(pos, "X")
    with pytest.raises(ModelError, match="unknown problem"):
        generate_problem("RO", np.random.default_rng(0))


def test_generated_noise_and_initial_guess_statistics():
    rng = np.random.default_rng(2024)
    layout = generate_layout("G")
    errs, offs = [], []
    for _ in range(20):
        p = generate_problem("GC", rng, layout=layout)
        truth = p.truth_m
        d_true = np.linalg.norm(truth[p.meas_a] - truth[p.meas_b], axis=1)
        errs.append(p.range_m - d_true)
        offs.append((p.initial_m - truth)[p.estimated])
        np.testing.assert_array_equal(p.initial_m[p.fixed], truth[p.fixed])
        assert p.fixed.sum() == 3 and p.dim == 3 and np.all(truth[:, 2] == 0)
    e = np.concatenate(errs)
    o = np.concatenate(offs)
    assert e.size == 20 * 342
    assert abs(e.std() - 0.15) < 0.01 and abs(e.mean()) < 0.01  # N(0, 0.15²)
    assert np.all(np.abs(o) <= 5.0) and o.max() > 4.9 and o.min() < -4.9  # U(−5, 5) per coordinate
    assert abs(o.std() - 10 / np.sqrt(12)) < 0.05


def test_generator_is_seeded_and_all_paper_problems_build():
    for name in PAPER_PROBLEMS:
        p1 = generate_problem(name, np.random.default_rng(5))
        p2 = generate_problem(name, np.random.default_rng(5))
        np.testing.assert_array_equal(p1.range_m, p2.range_m)
        np.testing.assert_array_equal(p1.initial_m, p2.initial_m)
        assert p1.n_anchors == 100 and int(p1.fixed.sum()) == 3 and p1.name == name
    r1 = generate_problem("RC", np.random.default_rng(1))
    r2 = generate_problem("RC", np.random.default_rng(2))
    assert not np.allclose(r1.truth_m, r2.truth_m)  # class R: a new placement per instance


def test_hold_heights_option():
    p = generate_problem("GC", np.random.default_rng(0), hold_heights=True)
    assert p.n_free == 2 * 97
    np.testing.assert_array_equal(p.initial_m[:, 2], p.truth_m[:, 2])  # heights start (and stay) at the truth
    q = generate_problem("GC", np.random.default_rng(0))
    np.testing.assert_array_equal(p.range_m, q.range_m)  # same random draws
    with pytest.raises(ModelError, match="dim=3"):
        generate_problem("GC", np.random.default_rng(0), hold_heights=True, dim=2)
