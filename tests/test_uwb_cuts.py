"""The cut test (:mod:`distnav.models.uwb.cuts`): a part of the network that the exclusions cut off is weak.

References: the cut links of a constructed network counted by hand; a clean simulated hall (no NLOS) must not get a
``cut`` reason; the stress bench's NLOS-20 % hall with a cluster of anchors shifted 1.0-1.5 m (truth known) must get
one for every anchor of that cluster (on the code before it, 6 of them were plainly ``estimated``).
"""

from __future__ import annotations

import numpy as np

from distnav.commands.uwb import solve_range_log
from distnav.experiments.uwb_field import hall_problem, write_hall
from distnav.models.uwb.cuts import cut_parts, cut_weak
from distnav.models.uwb.field import FieldOptions, prepare, solve_field
from distnav.models.uwb.hall import PLANT_LIKE, HallConfig, simulate_hall
from distnav.models.uwb.problems import build_problem

CUT = [
    ("S0", "R0"),
    ("S0", "R3"),
    ("S0", "R4"),
    ("S1", "R0"),
    ("S1", "R1"),
    ("S1", "R5"),
    ("S2", "R2"),
    ("S2", "R3"),
    ("S2", "R6"),
]


def _network(excluded_cut: set[tuple[str, str]]):
    """Outer ring: 4 known corners of a 20 m square and 8 estimated anchors along its sides, densely linked (every
    pair within 12 m). A part S of 3 estimated anchors near the centre, linked among themselves, has 9 links to
    the ring (:data:`CUT`, each S anchor to 3 ring anchors); those in ``excluded_cut`` are excluded."""
    known = {"K0": [0.0, 0.0], "K1": [20.0, 0.0], "K2": [20.0, 20.0], "K3": [0.0, 20.0]}
    ring = {
        "R0": [10.0, 0.0],
        "R1": [20.0, 10.0],
        "R2": [10.0, 20.0],
        "R3": [0.0, 10.0],
        "R4": [5.0, 0.0],
        "R5": [20.0, 15.0],
        "R6": [15.0, 20.0],
        "R7": [0.0, 5.0],
    }
    part = {"S0": [9.0, 9.0], "S1": [11.0, 9.5], "S2": [10.0, 11.0]}
    pos_d = {**known, **ring, **part}
    ids = list(pos_d)
    pos = np.array(list(pos_d.values()))
    outer = [*known, *ring]
    links = [
        (u, v)
        for i, u in enumerate(outer)
        for v in outer[i + 1 :]
        if np.linalg.norm(pos[ids.index(u)] - pos[ids.index(v)]) <= 12.0
    ]
    links += [("S0", "S1"), ("S0", "S2"), ("S1", "S2"), *CUT]
    d = np.array([np.linalg.norm(pos[ids.index(a)] - pos[ids.index(b)]) for a, b in links])
    p = build_problem(ids, links, d, fixed=known, dim=2, truth_m=pos, initial_m=pos)
    excluded = np.array([lk in excluded_cut for lk in links])
    assert excluded.sum() == len(excluded_cut)
    return p, excluded


def _parts(p, ex):
    return {tuple(p.ids[i] for i in np.flatnonzero(m)): (e, k) for m, e, k in cut_parts(p, ex)}


def test_a_part_cut_off_by_excluded_links_is_weak_with_the_counts_by_hand():
    # 6 of the 9 cut links excluded: k = 3 kept, redundancy 3 - 3 = 0 < e = 6 -> the 3 anchors of S are weak
    p, ex = _network({("S0", "R0"), ("S0", "R3"), ("S1", "R0"), ("S1", "R1"), ("S2", "R2"), ("S2", "R3")})
    weak = cut_weak(p, ex)
    assert set(weak) == {"S0", "S1", "S2"}
    assert "placed by 3 kept links" in weak["S0"] and "6 of its links to the rest were excluded" in weak["S0"]
    assert _parts(p, ex)[("S0", "S1", "S2")] == (6, 3)


def test_only_the_anchors_that_can_move_together_are_weak():
    # S0's 3 and S1's R0, R1 links excluded, S2's ring links all kept: {S0, S1} can move (its cut: S0-S2, S1-S2,
    # S1-R5 kept, 5 excluded: 5 > 3 - 3), S2 is held by its 3 kept ring links and is not reported
    p, ex = _network({("S0", "R0"), ("S0", "R3"), ("S0", "R4"), ("S1", "R0"), ("S1", "R1")})
    assert set(cut_weak(p, ex)) == {"S0", "S1"}
    assert _parts(p, ex)[("S0", "S1")] == (5, 3)


def test_the_boundary_is_the_cuts_redundancy():
    # one ring link of each S anchor excluded: the part S has e = 3, k = 6, redundancy 3 = e: a majority of the
    # cut's checks still decided -> not weak
    p, ex = _network({("S0", "R0"), ("S1", "R1"), ("S2", "R2")})
    assert _parts(p, ex)[("S0", "S1", "S2")] == (3, 6)
    assert cut_weak(p, ex) == {}
    # no exclusion at all: nothing to test
    p, ex = _network(set())
    assert cut_parts(p, ex) == [] and cut_weak(p, ex) == {}


def test_a_single_anchor_is_left_to_the_other_rules():
    # all 3 ring links of S2 excluded and S0, S1 untouched: the part grown from S2 is S2 alone (adding S0 or S1
    # lowers e / k) — one anchor's redundancy is the thin / reliability rules' business
    p, ex = _network({("S2", "R2"), ("S2", "R3"), ("S2", "R6")})
    assert _parts(p, ex)[("S2",)] == (3, 2)
    assert cut_weak(p, ex) == {}


def test_no_cut_reason_on_clean_halls():
    """Halls without NLOS (the plant-like link graph, nlos_p1 = 0): the exclusions take few links, never a part."""
    for k in range(3):
        h = simulate_hall(np.random.default_rng([31, k]), HallConfig().with_(**{**PLANT_LIKE, "nlos_p1": 0.0}))
        prob, _ = hall_problem(h)
        sub, geo = prepare(prob)
        sol = solve_field(sub, FieldOptions(), geometry=geo)
        assert not any(r.startswith("cut:") for r in sol.weak_reasons.values()), (k, sol.weak_reasons)


def test_the_shifted_cluster_of_the_nlos_20_hall_is_reported_weak(tmp_path):
    """Stress bench row NLOS 20 %, middle, hall 2 (seed [2026, 2, 0, 2]): a cluster of anchors shifted 1.0-1.5 m,
    every kept link fitting to 0.07 m or better. Every anchor more than 0.3 m and 3σ off is weak, the cluster by the
    cut test; with ``cut_test=False`` six of them are plainly estimated (the code before it)."""
    cfg = HallConfig().with_(**{**PLANT_LIKE, "known": "middle", "nlos_p1": 0.33})
    h = simulate_hall(np.random.default_rng([2026, 2, 0, 2]), cfg)
    f = write_hall(h, tmp_path / "hall")
    silent = {}
    for on in (True, False):
        sol, _, _ = solve_range_log(
            f["ranges"], f["known"], heights=f["heights"], truth=f["truth"], options=FieldOptions(cut_test=on)
        )
        ids = list(h.ids)
        idx = np.array([ids.index(x) for x in sol.problem.ids])
        err = np.linalg.norm(sol.positions_m - h.truth_m[idx], axis=1)
        sig = np.hypot(sol.sigma_m[:, 0], sol.sigma_m[:, 1])
        off = (err > 0.3) & (err > 3 * sig) & sol.problem.estimated
        silent[on] = {sol.problem.ids[i] for i in np.flatnonzero(off) if sol.problem.ids[i] not in sol.weak}
        if on:
            cut = {k for k, r in sol.weak_reasons.items() if r.startswith("cut:")}
            assert {"A05", "A12", "A19", "A13", "A20", "A27"} <= cut
    assert silent[True] == set() and len(silent[False]) == 6
