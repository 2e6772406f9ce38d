"""Geometry and ambiguity checks before solving (issue 13, item 4): networks built so the answer is known by
construction (a mirror, a flip, a hinge, a cut-off part, a planar hall), and the checks must name it."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from distnav.errors import ModelError
from distnav.models.uwb.geometry import check_geometry, flexible_anchors
from distnav.models.uwb.hall import simulate_hall
from distnav.models.uwb.problems import build_problem


def _problem(
    pos: np.ndarray, links: list[tuple[int, int]], known: list[int], *, held_z: bool = False, initial: bool = True
):
    n, dim = pos.shape
    ids = [f"N{i}" for i in range(n)]
    d = [float(np.linalg.norm(pos[a] - pos[b])) for a, b in links]
    held = {ids[i]: {2: float(pos[i, 2])} for i in range(n) if i not in known} if held_z else None
    return build_problem(
        ids,
        links,
        d,
        fixed={ids[k]: pos[k] for k in known},
        dim=dim,
        held=held,
        truth_m=pos,
        initial_m=pos if initial else None,
        check_determined=False,
    )


def _complete(idx: list[int]) -> list[tuple[int, int]]:
    return list(itertools.combinations(idx, 2))


RNG = np.random.default_rng(7)
P2 = RNG.uniform(0, 20, (8, 2))
TETRA = np.array([[0.0, 0.0, 0.0], [10.0, 0.0, 1.0], [0.0, 10.0, 2.0], [5.0, 5.0, 9.0]])


def test_well_posed_2d_network_has_no_issue():
    rep = check_geometry(_problem(P2, _complete(list(range(8))), [0, 1, 2]))
    assert rep.issues == () and rep.status is None and rep.unsolved == ()


@pytest.mark.parametrize("known", [[0, 1], "collinear"])
def test_2d_mirror_with_two_or_collinear_known_anchors(known):
    pos = P2.copy()
    if known == "collinear":
        pos[:3] = [[0, 0], [5, 5], [12, 12]]
        known = [0, 1, 2]
    rep = check_geometry(_problem(pos, _complete(list(range(8))), known))
    assert rep.status == "ambiguous" and [i.kind for i in rep.issues] == ["mirror"]
    assert "lie on one line" in rep.issues[0].message


def test_flip_anchor_with_as_many_links_as_coordinates():
    links = _complete(list(range(7))) + [(7, 0), (7, 3)]  # anchor N7: 2 links in 2-D
    rep = check_geometry(_problem(P2, links, [0, 1, 2]))
    assert rep.status == "ambiguous" and [i.kind for i in rep.issues] == ["flip"]
    assert rep.issues[0].anchors == ("N7",) and rep.unsolved == ()


def test_single_link_and_hinged_part_are_not_rigid():
    a, b = list(range(5)), list(range(5, 10))
    pos = np.vstack([RNG.uniform(0, 10, (5, 2)), RNG.uniform(20, 30, (5, 2)), [[40.0, 40.0]]])
    hinge = _complete(a) + _complete(b) + [(5, 0), (6, 0)] + [(10, 9)]  # B turns about N0; N10 on one link
    rep = check_geometry(_problem(pos, hinge, [0, 1, 2]))
    assert set(rep.unsolved) == {f"N{i}" for i in [*b, 10]}
    assert all(i.kind == "non_rigid" for i in rep.issues)
    braced = check_geometry(_problem(pos, hinge + [(7, 1), (10, 8), (10, 7)], [0, 1, 2]))  # braced
    assert braced.unsolved == () and braced.status is None


def test_generic_rigidity_counts_in_3d():
    pos = RNG.uniform(0, 10, (7, 3))
    pos[:4] = TETRA
    base = _complete([0, 1, 2, 3, 4, 5])
    two = _problem(pos, base + [(6, 0), (6, 1)], [0, 1, 2, 3])  # two links: turns about their axis
    assert flexible_anchors(two).tolist() == [False] * 6 + [True]
    three = _problem(pos, base + [(6, 0), (6, 1), (6, 4)], [0, 1, 2, 3])
    assert not flexible_anchors(three).any()
    rep = check_geometry(three)
    assert [i.kind for i in rep.issues] == ["flip"]  # 3 links in 3-D: rigid but mirrored through them
    held = _problem(pos, base + [(6, 0), (6, 1)], [0, 1, 2, 3], held_z=True)  # height held: 2 links are enough
    assert not flexible_anchors(held).any()


def test_cut_off_part_is_unsolved_and_the_rest_solvable():
    pos = np.vstack([P2, P2[:4] + 100.0])
    links = _complete(list(range(8))) + _complete([8, 9, 10, 11])
    p = _problem(pos, links, [0, 1, 2])
    with pytest.raises(ModelError, match="no chain of measured links"):
        p.subset(np.ones(12, bool))
    rep = check_geometry(p)
    assert rep.unsolved == ("N8", "N9", "N10", "N11") and rep.issues[0].kind == "disconnected"
    sub = p.subset(rep.solvable)
    assert sub.n_anchors == 8 and sub.links.shape[0] == 28


def _hall_problem(known_z_span: float | None, *, held: bool = False, **hall):
    h = simulate_hall(np.random.default_rng(3), **hall)
    t = h.truth_m.copy()
    if known_z_span is not None:  # known anchors spanning this much height (a survey of posts, a mezzanine)
        t[h.known, 2] = h.config.ceiling_m - np.linspace(0, known_z_span, h.known.size)
    return _problem(t, [tuple(x) for x in h.links.tolist()], h.known.tolist(), held_z=held)


def test_planar_hall_in_3d_is_refused_even_with_known_anchors_spanning_2m():
    for span in (None, 2.0):
        rep = check_geometry(_hall_problem(span))
        kinds = [i.kind for i in rep.issues]
        assert "planar" in kinds and rep.refused, (span, rep.messages())
        with pytest.raises(ModelError, match="nearly planar.*--heights"):
            rep.raise_if_refused()
    asked = check_geometry(_hall_problem(2.0), allow_planar_3d=True)
    assert not asked.refused and asked.status == "weakly_determined"
    held = check_geometry(_hall_problem(None, held=True))
    assert held.issues == () and held.planarity_known is None


def test_three_known_anchors_with_free_heights_are_a_mirror():
    pos = np.column_stack([P2, RNG.uniform(0, 20, 8)])  # a volumetric network
    pos[:4] = TETRA * 2.0
    rep = check_geometry(_problem(pos, _complete(list(range(8))), [0, 1, 2]))
    assert [i.kind for i in rep.issues] == ["mirror"] and rep.status == "ambiguous"
    ok = check_geometry(_problem(pos, _complete(list(range(8))), [0, 1, 2, 3]))
    assert ok.issues == () and ok.planarity_known is not None and ok.planarity_known > 0.1


def test_nearly_coplanar_known_anchors_in_a_volumetric_network_are_weak():
    pos = np.column_stack([P2, RNG.uniform(0, 20, 8)])
    pos[:4] = TETRA * [2.0, 2.0, 0.05]  # known anchors within 0.9 m of one plane across 20 m
    rep = check_geometry(_problem(pos, _complete(list(range(8))), [0, 1, 2, 3]))
    assert [i.kind for i in rep.issues] == ["near_mirror"] and rep.status == "weakly_determined"
    assert rep.planarity_network is not None and rep.planarity_network > 0.1


def test_fast_rigidity_test_agrees_with_the_eigendecomposition():
    """The Cholesky shortcut (no eigenvalue of RᵀR below the threshold) against a dense eigh of the same matrix
    on random 2-D / 3-D networks, rigid and not (sparse links, hinged parts): the same flexible anchors."""
    import scipy.sparse as sp

    from distnav.models.uwb.geometry import NULL_TOL, _clearly_rigid, rigidity_matrix

    seen = {True: 0, False: 0}
    for seed in range(24):
        rng = np.random.default_rng(seed)
        dim, n = (2, 30) if seed % 2 else (3, 24)
        t = rng.uniform(0.0, 20.0, (n, dim))
        a, b = np.triu_indices(n, 1)
        k = np.linalg.norm(t[a] - t[b], axis=1) < rng.uniform(4.0, 12.0)
        ids = [f"A{i}" for i in range(n)]
        p = build_problem(
            ids,
            np.stack([a[k], b[k]], 1),
            np.ones(int(k.sum())),
            fixed={ids[i]: t[i] for i in range(dim + 1)},
            dim=dim,
            check_determined=False,
        )
        pos = np.random.default_rng(100 + seed).normal(0.0, 1.0, size=(n, dim))
        r = rigidity_matrix(p, pos)
        w, v = np.linalg.eigh((r.T @ r).toarray())
        null = v[:, w <= NULL_TOL * max(float(w[-1]), 1e-300)]
        energy = np.bincount(np.nonzero(p.free)[0], np.einsum("ij,ij->i", null, null), minlength=n)
        expected = energy > 1e-8
        got = flexible_anchors(p, np.random.default_rng(100 + seed))
        assert got.tolist() == expected.tolist(), seed
        fast = _clearly_rigid(sp.csr_matrix(r.T @ r))
        assert fast == (null.shape[1] == 0), seed
        seen[fast] += 1
    assert seen[True] >= 3 and seen[False] >= 3  # both outcomes drawn
