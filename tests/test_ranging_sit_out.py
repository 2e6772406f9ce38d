"""The anchors without a free parameter sit the distributed LM phase out (issue 27, eighth session, item 37:
``refine.SIT_OUT``, ``inner.sit_out_plan``): the plan by hand, then the LM phase on a plant-like corner hall with
and without them — the same objective at the same start (their terms are evaluated by the other ends and the
delegates), the same fixed point, no byte received by a known anchor, the reductions over a tree of the others."""

from __future__ import annotations

import numpy as np
import pytest

from distnav.algorithms.ranging import refine as refine_mod
from distnav.algorithms.ranging import wire
from distnav.algorithms.ranging.inner import sit_out_plan
from distnav.algorithms.ranging.refine import refine
from distnav.errors import ModelError
from distnav.exchange import make_exchange
from distnav.exchange.faults import FaultSchedule
from distnav.experiments.uwb_field import hall_problem
from distnav.models.uwb.field import prepare
from distnav.models.uwb.hall import PLANT_LIKE, HallConfig, simulate_hall
from distnav.models.uwb.problems import build_problem
from distnav.network.graph import Graph

FIT = {"loss": "cauchy", "range_offsets": "common", "offset_prior_sigma_m": 0.1}


def _small(links):
    """Six anchors on a 2-D line of triangles: 0, 1, 2 known, 3, 4, 5 free; ``links`` by index."""
    pos = np.array([[0.0, 0.0], [4.0, 0.0], [8.0, 0.0], [0.0, 3.0], [4.0, 3.0], [8.0, 3.0]])
    ids = [f"A{i}" for i in range(6)]
    d = [float(np.linalg.norm(pos[a] - pos[b])) for a, b in links]
    fixed = {ids[i]: pos[i] for i in range(3)}
    return build_problem(ids, links, d, fixed=fixed, dim=2, check_determined=False)


def _free(p):
    return np.asarray(p.free)


def test_the_plan_by_hand():
    """Known 0, 1, 2 listen to nothing; the samples 0–1 and 1–2 (both ends known) go to the lowest-numbered free
    neighbour of their first end (3 for anchor 0 and for anchor 1), handed over by that end; no plan where the free
    anchors' range graph is cut (the tree would need a known anchor), where a sample between known anchors has no
    free neighbour at either end, or where every anchor (or none) has a free parameter."""
    links = [(0, 1), (1, 2), (0, 3), (1, 3), (1, 4), (2, 5), (3, 4), (4, 5), (0, 4)]
    p = _small(links)
    plan = sit_out_plan(p, _free(p))
    assert plan is not None
    assert plan.listens.tolist() == [False, False, False, True, True, True]
    assert plan.kk_samples.tolist() == [0, 1]
    assert plan.kk_delegate.tolist() == [3, 3] and plan.kk_sender.tolist() == [0, 1]
    cut = _small([(0, 1), (1, 2), (0, 3), (1, 4), (2, 5), (3, 4)])  # 5 reaches 3 and 4 only through known 2
    assert sit_out_plan(cut, _free(cut)) is None
    lone = _small([(0, 1), (1, 2), (1, 4), (3, 4), (4, 5), (3, 1), (5, 1)])  # 0 ranges with known 1 only...
    plan = sit_out_plan(lone, _free(lone))
    assert plan is not None and plan.kk_delegate.tolist() == [3, 3]  # ... so 0–1 goes to 1's free neighbour 3
    stray = _small([(0, 2), (1, 3), (1, 4), (1, 5), (3, 4), (4, 5)])  # 0–2: neither end has a free neighbour
    assert sit_out_plan(stray, _free(stray)) is None
    assert sit_out_plan(p, np.ones_like(_free(p))) is None
    assert sit_out_plan(p, np.zeros_like(_free(p))) is None


@pytest.fixture(scope="module")
def corner():
    h = simulate_hall(np.random.default_rng([78, 0]), HallConfig().with_(known="corner", **PLANT_LIKE))
    sub, _ = prepare(hall_problem(h)[0])
    return sub


def _refined(p, monkeypatch, on, **options):
    monkeypatch.setattr(refine_mod, "SIT_OUT", on)
    ex = make_exchange(Graph.from_links(p.n_anchors, p.links))
    sigma = np.full(p.n_meas, 0.1)
    kw = {"ftol": 1e-6, "xtol_m": 1e-4, "offset_start_m": 0.0, **options}
    ref = refine(p, ex, p.initial_m, np.zeros(p.n_anchors), sigma=sigma, scale=0.3 / sigma, **FIT, **kw)
    return ref, ex


def test_the_same_objective_at_the_start_and_the_same_fixed_point(corner, monkeypatch):
    """No round (``max_rounds=0``): the objective of the start is the same sum with the known anchors sitting out
    (their terms counted at the other ends, the samples between two known anchors by the delegates) to rounding —
    a wrong weight or a lost sample would move it by whole terms; run to a tight stop, both phases end at the same
    positions and offset (the same gradient's zero)."""
    known = ~np.any(corner.free, axis=1)
    a, b = corner.meas_a, corner.meas_b
    assert known.sum() == 4 and np.any(known[a] & known[b])  # samples between two known anchors exist
    start = [_refined(corner, monkeypatch, on, max_rounds=0)[0].objective for on in (False, True)]
    assert start[1] == pytest.approx(start[0], rel=1e-12)
    tight = {"ftol": 1e-14, "xtol_m": 1e-9, "max_rounds": 200}
    off, on = (_refined(corner, monkeypatch, s, **tight)[0] for s in (False, True))
    assert off.status == on.status == "converged"
    assert np.max(np.abs(on.own_m - off.own_m)) < 1e-6
    assert on.offset_m[0] == pytest.approx(off.offset_m[0], abs=1e-7)
    assert on.objective == pytest.approx(off.objective, rel=1e-10)
    assert np.max(np.abs(on.half_other_m - off.half_other_m)) < 1e-6  # a known anchor's halves: its neighbours


def test_no_byte_reaches_a_known_anchor_and_the_tree_spans_the_others(corner, monkeypatch):
    """With the known anchors sitting out the phase sends nothing to them (only the records of the samples between
    two known anchors leave them, once, 16 B a sample, to their delegates), its reductions run over a tree of the 24
    others (``Reductions.tree_nodes``, ``wire.reductions_cost``) and it sends fewer bytes in all; without, every
    anchor receives and the tree spans all 28."""
    known = ~np.any(corner.free, axis=1)
    a, b = corner.meas_a, corner.meas_b
    kk = int(np.sum(known[a] & known[b]))
    out = {}
    for on in (False, True):
        ref, ex = _refined(corner, monkeypatch, on)
        c = ex.comm_totals()
        out[on] = ref, c, wire.reductions_cost(corner.n_anchors, ref.reduced)
    (ref_off, c_off, cost_off), (ref_on, c_on, cost_on) = out[False], out[True]
    assert np.all(c_off.bytes_received[known] > 0) and ref_off.reduced.tree_nodes == 0
    assert np.all(c_on.bytes_received[known] == 0) and ref_on.reduced.tree_nodes == 24
    assert int(np.sum(c_on.bytes_sent[known])) == 16 * kk
    r = ref_on.reduced
    assert cost_on[0] == (r.count - r.decided) * 2 * 23 + r.decided_directions * 23
    assert c_on.bytes + cost_on[1] < c_off.bytes + cost_off[1]


def test_without_a_plan_a_warm_start_is_sent_to_the_anchors_that_may_have_sat_out(monkeypatch):
    """A warm fit whose known anchors cannot sit out (anchor 5 reaches the others only through known anchors): its
    first rows are held by the receivers of the last fit (``held_m``, ``field_fits.CARRY_HELD``), but a known anchor
    may have sat that fit out and holds none (``inner.held_by_all``): every anchor that ranges with a known one sends
    its first row (16 B on each of its 8 links here), and each known anchor receives the common offset and the
    damping (16 B, ``inner.hand_over``, review finding 2): the same solve bit for bit as without ``SIT_OUT``."""
    links = [(0, 1), (1, 2), (0, 3), (1, 3), (1, 4), (0, 4), (3, 4), (2, 5), (1, 5)]
    p = _small(links)
    assert sit_out_plan(p, _free(p)) is None
    rng = np.random.default_rng(3)
    start = np.array(p.positions_m, float)
    start[3:] = [[0.0, 3.0], [4.0, 3.0], [8.0, 3.0]] + rng.normal(0, 0.05, (3, 2))
    out = {}
    for on in (False, True):
        monkeypatch.setattr(refine_mod, "SIT_OUT", on)
        ex = make_exchange(Graph.from_links(p.n_anchors, p.links))
        sigma = np.full(p.n_meas, 0.1)
        ref = refine(
            p, ex, start, np.zeros(p.n_anchors), sigma=sigma, scale=0.3 / sigma, **FIT, ftol=1e-6, xtol_m=1e-4,
            offset_start_m=0.0, held_m=start,
        )  # fmt: skip
        out[on] = ref, ex.comm_totals().bytes
    (off, b_off), (on, b_on) = out[False], out[True]
    assert np.array_equal(on.own_m, off.own_m) and on.objective == off.objective and on.rounds == off.rounds
    assert b_on - b_off == 8 * 16 + 3 * 16


def _six(links):
    p = _small(links)
    rng = np.random.default_rng(3)
    start = np.array(p.positions_m, float)
    start[3:] += rng.normal(0, 0.05, (3, 2))
    return p, start


def _run(p, start, offset_m, faults=None, **kw):
    ex = make_exchange(Graph.from_links(p.n_anchors, p.links), faults=faults)
    sigma = np.full(p.n_meas, 0.1)
    base = {"ftol": 1e-6, "xtol_m": 1e-4, "offset_start_m": 0.0, **kw}
    ref = refine(p, ex, start, offset_m, sigma=sigma, scale=0.3 / sigma, **FIT, **base)
    return ref, ex.comm_totals()


def test_a_lost_record_is_an_error(monkeypatch):
    """Review finding 1 (its s3 case): the known anchors 0–2 silent from round 0, so the records of the samples
    0–1 and 1–2 never reach their delegate 3 — a ModelError naming the lost record, as ``Wire`` raises for a lost
    message (before the fix the delegate used them and the phase converged)."""
    monkeypatch.setattr(refine_mod, "SIT_OUT", True)
    p, start = _six([(0, 1), (1, 2), (0, 3), (1, 3), (1, 4), (2, 5), (3, 4), (4, 5), (0, 4)])
    silent = FaultSchedule(silent_nodes=((0, 0), (1, 0), (2, 0)))
    with pytest.raises(ModelError, match="record of the sample A0-A1 .delegated to A3. was lost"):
        _run(p, start, np.zeros(p.n_anchors), faults=silent)
    ref, _ = _run(p, start, np.zeros(p.n_anchors))  # without the faults: the plan applies and converges
    assert ref.status == "converged"


def test_differing_copies_start_from_their_network_mean(monkeypatch):
    """Review finding 4 (s2): copies of the common offset other than ``offset_start_m``: the start is the mean of
    every anchor's copy, the known anchors' too (the plan does not apply then), as without ``SIT_OUT`` — before the
    fix the mean of the free anchors' copies only (0.50 instead of 0.35 here)."""
    p, start = _six([(0, 1), (1, 2), (0, 3), (1, 3), (1, 4), (2, 5), (3, 4), (4, 5), (0, 4)])
    copies = np.linspace(0.0, 0.7, p.n_anchors)
    out = {}
    for on in (False, True):
        monkeypatch.setattr(refine_mod, "SIT_OUT", on)
        out[on] = _run(p, start, copies, max_rounds=0)[0]
    assert out[True].offset_m[0] == out[False].offset_m[0] == pytest.approx(np.mean(copies), abs=1e-15)
    assert out[True].objective == out[False].objective


def test_no_plan_when_known_coordinates_are_sent(monkeypatch):
    """Review finding 6 (s4): with ``wire.KNOWN_FROM_PROBLEM`` False the first broadcast sends every anchor's row,
    the known anchors' included: no plan (the tree spans every anchor), the bytes of the phase without ``SIT_OUT``
    (before the fix the known anchors received that broadcast and the tree left them out)."""
    p, start = _six([(0, 1), (1, 2), (0, 3), (1, 3), (1, 4), (2, 5), (3, 4), (4, 5), (0, 4)])
    monkeypatch.setattr(wire, "KNOWN_FROM_PROBLEM", False)
    out = {}
    for on in (False, True):
        monkeypatch.setattr(refine_mod, "SIT_OUT", on)
        out[on] = _run(p, start, np.zeros(p.n_anchors))
    assert out[True][0].reduced.tree_nodes == 0
    assert np.array_equal(out[True][1].bytes_received, out[False][1].bytes_received)
    assert np.array_equal(out[True][0].own_m, out[False][0].own_m)


def test_a_warm_fit_without_a_plan_gives_the_known_anchors_the_start(monkeypatch):
    """Review finding 2: a known anchor that sat the last fit out holds no copy of the common offset (its copy here:
    99 m, not the fit's start). A warm fit where the plan does not apply hands it the start and the damping
    (``inner.hand_over``, 16 B to each of the 3 known anchors): the same solve, bit for bit, as where every copy is
    the start (before the fix its stale copy made the start the network mean, 49.5 m)."""
    monkeypatch.setattr(refine_mod, "SIT_OUT", True)
    p, start = _six([(0, 1), (1, 2), (0, 3), (1, 3), (1, 4), (0, 4), (3, 4), (2, 5), (1, 5)])
    assert sit_out_plan(p, _free(p)) is None
    stale = np.zeros(p.n_anchors)
    stale[:3] = 99.0
    got, c_got = _run(p, start, stale, held_m=start)
    want, c_want = _run(p, start, np.zeros(p.n_anchors), held_m=start)
    assert np.array_equal(got.own_m, want.own_m) and got.offset_m[0] == want.offset_m[0] == got.offset_m[-1]
    assert np.array_equal(c_got.bytes_received[:3], c_want.bytes_received[:3]) and c_got.bytes == c_want.bytes
    monkeypatch.setattr(refine_mod, "SIT_OUT", False)  # 16 B hand-over + first rows (inner.held_by_all)
    base, c_base = _run(p, start, np.zeros(p.n_anchors), held_m=start)
    assert np.array_equal(base.own_m, want.own_m)
    assert c_want.bytes_received[:3].tolist() == (c_base.bytes_received[:3] + 16 + 16 * np.array([2, 3, 1])).tolist()


def test_local_test_scale_counts_the_known_anchors_final_rows(corner, monkeypatch):
    """Review finding 3: the local QC tests each link at its lower-indexed anchor, often a known one that sat the LM
    phase out; with ``test_scale="local"`` its own scale needs its neighbours' final coordinates and the common
    offset, now one counted round (``refine.rows_for_local_tests``): (dim + 1) · 8 B on each link from an anchor that
    took part to a known one, and the same positions as with the robust scale (the round's rows are checked equal to
    the halves ``refine`` gives, inside ``rows_for_local_tests``); none with the robust scale."""
    from distnav.algorithms.ranging.csg import solve_nclm

    monkeypatch.setattr(refine_mod, "SIT_OUT", True)
    known = ~np.any(corner.free, axis=1)
    a, b = corner.meas_a, corner.meas_b
    pairs = np.unique(np.sort(np.c_[a, b], axis=1), axis=0)
    to_known = int(np.sum(known[pairs[:, 0]] != known[pairs[:, 1]]))
    kw = {"objective": "metres", "sigma_m": 0.1, "range_offsets": "common", "quality": True, "iterations": 0}
    got = {s: solve_nclm(corner, test_scale=s, **kw) for s in ("local", "robust")}
    assert got["local"].settings["refine"]["tree_nodes"] == int((~known).sum())
    extra = got["local"].comm.bytes - got["robust"].comm.bytes
    assert extra == to_known * (corner.dim + 1) * 8 and to_known > 0
    assert np.array_equal(got["local"].estimates, got["robust"].estimates)
    assert int(np.sum(got["local"].comm.bytes_received[known])) == extra
    assert np.any(np.isfinite(got["local"].tests.w))
