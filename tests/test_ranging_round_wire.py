"""The LM rounds' own messages (issue 27, seventh session: ``wire.STEP_HELD``, ``refine.FIRST_MOVE_KNOWN``,
``refine.OFFSET_START_HELD``): the same values bit for bit, the bytes recounted from what was sent."""

from __future__ import annotations

import numpy as np
import pytest

from distnav.algorithms.ranging import refine as refine_mod
from distnav.algorithms.ranging import wire
from distnav.algorithms.ranging.inner import Links, sit_out_plan
from distnav.algorithms.ranging.refine import refine
from distnav.algorithms.ranging.wire import pack_steps, unpack_steps
from distnav.exchange import make_exchange
from distnav.experiments.uwb_field import hall_problem
from distnav.models.uwb.field import FieldOptions, prepare, solve_field, subset_measurements
from distnav.models.uwb.hall import PLANT_LIKE, HallConfig, simulate_hall
from distnav.network.graph import Graph

FIT = {"loss": "cauchy", "range_offsets": "common", "offset_prior_sigma_m": 0.1, "ftol": 1e-6, "xtol_m": 1e-4}
SWITCHES = [
    (wire, "STEP_HELD"),
    (refine_mod, "FIRST_MOVE_KNOWN"),
    (refine_mod, "OFFSET_START_HELD"),
    (refine_mod, "ROOT_DECIDES"),
    (refine_mod, "SCALED_TRIAL_KNOWN"),
]


def _hall(k, place):
    h = simulate_hall(np.random.default_rng([78, k]), HallConfig().with_(known=place, **PLANT_LIKE))
    p, nlos = hall_problem(h)
    sub, geo = prepare(p)
    return sub, geo, nlos[geo.solvable[p.meas_a] & geo.solvable[p.meas_b]]


@pytest.fixture(scope="module")
def hall():
    return _hall(0, "middle")


@pytest.fixture(autouse=True)
def _every_anchor_takes_part(monkeypatch):
    """These recounts assume a message on every edge from an anchor with a free parameter: the anchors without one
    take part in the phase here (``refine.SIT_OUT`` off; issue 27 item 37 is tested in test_ranging_sit_out.py, and
    its message sizes recounted in ``test_with_the_known_anchors_sitting_out_the_steps_recount``)."""
    monkeypatch.setattr(refine_mod, "SIT_OUT", False)


def _expected_size(rows32, held):
    """A step's bytes by the rule of ``pack_steps``, from the values (``np.frexp``, not the bit fields): 28 bits an
    entry where every entry is zero or a normal float32 within 7 binades of its held exponent, else 4 B an entry;
    and the exponents held after it (float32's biased exponent, the held one at a zero)."""
    v = rows32.astype(float)
    e = np.frexp(v)[1] - 1 + 127  # the biased float32 exponent of a normal value
    zero = v == 0
    normal = np.abs(v) >= 2.0**-126
    near = normal & (held > 0) & (np.abs(e - held) <= 7)
    coded = np.all(zero | near, axis=1)
    m = v.shape[1]
    return np.where(coded, -(-28 * m // 8), 4 * m), np.where(zero, held, np.where(normal, e, 0))


@pytest.mark.parametrize("m", [2, 3])
def test_steps_round_trip_bit_for_bit_and_their_sizes_recount(m):
    """``pack_steps`` / ``unpack_steps``: every float32 entry (zeros of either sign, subnormals, wide exponents)
    arrives bit for bit; a row is 28 bits an entry only where the rule of the values says so, both ends then hold
    the same exponents."""
    rng = np.random.default_rng(27)
    n = 400
    rows = (rng.normal(size=(n, m)) * 2.0 ** rng.integers(-40, 10, size=(n, m))).astype(np.float32)
    rows[::7, 0] = 0.0
    rows[::11, -1] = -0.0
    rows[::13, 0] = np.float32(1e-42)  # subnormal
    held = np.where(rng.random((n, m)) < 0.1, 0, ((rows.view(np.uint32) >> 23) & 0xFF) + rng.integers(-9, 10, (n, m)))
    held = np.clip(held, 0, 254).astype(np.int64)
    packed, sizes, held_tx = pack_steps(rows, held)
    values, held_rx = unpack_steps(packed, held, m)
    assert np.array_equal(values.astype(np.float32).view(np.uint32), rows.view(np.uint32))  # -0.0 too
    want, want_held = _expected_size(rows, held)
    assert np.array_equal(sizes, want) and np.array_equal(held_tx, want_held) and np.array_equal(held_rx, want_held)
    assert 0.3 * n < np.sum(sizes < 4 * m) < n  # both kinds occur


def _refined(p, **options):
    ex = make_exchange(Graph.from_links(p.n_anchors, p.links))
    sigma = np.full(p.n_meas, 0.1)
    ref = refine(p, ex, p.initial_m, np.zeros(p.n_anchors), sigma=sigma, scale=0.3 / sigma, **FIT, **options)
    return ref, ex


def _record_steps(monkeypatch):
    """Every step ``wire.pack_steps`` packs from now on, with the exponents it was packed on (a list filled in)."""
    sent: list[tuple[np.ndarray, np.ndarray]] = []
    pack = wire.pack_steps

    def recorded(rows, held):
        sent.append((np.array(rows), np.array(held)))
        return pack(rows, held)

    monkeypatch.setattr(wire, "pack_steps", recorded)
    return sent


def _same(a, b):
    return (
        np.array_equal(a.own_m, b.own_m)
        and np.array_equal(a.half_other_m, b.half_other_m)
        and np.array_equal(a.offset_m, b.offset_m)
        and a.objective == b.objective
        and (a.rounds, a.cg_iterations, a.status, a.mu) == (b.rounds, b.cg_iterations, b.status, b.mu)
    )


def test_lm_phase_with_the_rounds_economy_is_the_same_solve_in_the_bytes_recounted(hall, monkeypatch):
    """The LM phase with the four switches on and off: the same solution, rounds, CG iterations and damping bit for
    bit; the broadcasts differ by exactly what the steps' sizes recount from the rows sent (each on every active
    edge of its sender), the reductions by the offset's start mean (8 B: every copy is 0, ``offset_start_m=0``),
    the first evaluation's largest move and the totals the root decides on (``ROOT_DECIDES``)."""
    p = subset_measurements(hall[0], ~hall[2])
    sent = _record_steps(monkeypatch)
    for mod, name in SWITCHES:
        monkeypatch.setattr(mod, name, False)
    off, ex_off = _refined(p, offset_start_m=0.0)
    for mod, name in SWITCHES:
        monkeypatch.setattr(mod, name, True)
    on, ex_on = _refined(p, offset_start_m=0.0)
    assert _same(on, off) and on.status == "converged"
    a, b = p.links[:, 0], p.links[:, 1]
    edges = np.bincount(np.r_[a, b], minlength=p.n_anchors) * p.free.any(axis=1)  # a talking sender's out-edges
    saved = 0
    for rows, held in sent:
        size, _ = _expected_size(rows, held)
        saved += int(np.sum((8 - size) * edges))
    assert len(sent) == on.rounds and saved > 0  # every trial's step (no first one: the start is a broadcast)
    assert ex_off.comm_totals().bytes - ex_on.comm_totals().bytes == saved
    assert ex_off.comm_totals().messages == ex_on.comm_totals().messages
    # the reductions: the start's mean (8 B) gone, the first objective (8 B) up only, every trial's objective and
    # largest move (8 + 4 B) up and a 1 B decision down — the rest (the offset's rows, CG's totals) as before
    trials = on.rounds
    assert on.reduced.count == off.reduced.count - 1 and on.reduced.decided == 1 + trials
    assert on.reduced.bytes == off.reduced.bytes - 8 - (8 + 4) - 12 * trials
    assert on.reduced.decided_directions == 1 + 2 * trials and on.reduced.decided_bytes == 8 + 13 * trials
    edges = p.n_anchors - 1
    saved_tree = edges * (2 * (8 + 12 + 12 * trials) - (8 + 13 * trials))
    assert wire.reductions_cost(p.n_anchors, off.reduced)[1] - wire.reductions_cost(p.n_anchors, on.reduced)[1] == (
        saved_tree
    )


def test_with_the_known_anchors_sitting_out_the_steps_recount(hall, monkeypatch):
    """The shipped configuration (``refine.SIT_OUT`` on, the plan applies): the held steps (``wire.STEP_HELD``) on
    and off give the same solve bit for bit, and the bytes differ by exactly what the steps' sizes recount from the
    rows sent, each on the edges from its (talking) sender to the anchors that listen (``Wire(listens=)``) — not on
    every edge of the sender (review of item 37, finding 8); no byte reaches a known anchor."""
    monkeypatch.setattr(refine_mod, "SIT_OUT", True)
    p = subset_measurements(hall[0], ~hall[2])
    listens = p.free.any(axis=1)
    assert sit_out_plan(p, np.asarray(p.free)) is not None and not listens.all()
    monkeypatch.setattr(wire, "STEP_HELD", False)
    off, ex_off = _refined(p, offset_start_m=0.0)
    monkeypatch.setattr(wire, "STEP_HELD", True)
    sent = _record_steps(monkeypatch)
    on, ex_on = _refined(p, offset_start_m=0.0)
    assert _same(on, off) and on.status == "converged" and on.reduced.tree_nodes == int(listens.sum())
    a, b = p.links[:, 0], p.links[:, 1]
    to_listeners = (np.bincount(a, listens[b], p.n_anchors) + np.bincount(b, listens[a], p.n_anchors)) * listens
    every_edge = np.bincount(np.r_[a, b], minlength=p.n_anchors) * listens
    saved = saved_every = 0
    for rows, held in sent:
        size, _ = _expected_size(rows, held)
        saved += int(np.sum((4 * rows.shape[1] - size) * to_listeners))
        saved_every += int(np.sum((4 * rows.shape[1] - size) * every_edge))
    assert len(sent) == on.rounds and 0 < saved < saved_every  # the mask matters here
    assert ex_off.comm_totals().bytes - ex_on.comm_totals().bytes == saved
    for ex in (ex_off, ex_on):
        assert np.all(ex.comm_totals().bytes_received[~listens] == 0)


def test_an_offset_start_that_is_not_every_copy_is_reduced_as_before(hall, monkeypatch):
    """``offset_start_m`` that some anchor's copy does not hold: the mean is reduced as without it (the same solve
    and bytes); without the switch the given value is not used at all."""
    p = subset_measurements(hall[0], ~hall[2])
    plain, _ = _refined(p)
    wrong, _ = _refined(p, offset_start_m=0.25)
    assert _same(wrong, plain) and wrong.reduced == plain.reduced
    monkeypatch.setattr(refine_mod, "OFFSET_START_HELD", False)
    unused, _ = _refined(p, offset_start_m=0.0)
    assert _same(unused, plain) and unused.reduced == plain.reduced


@pytest.mark.parametrize("place", ["middle", "corner"])
def test_a_whole_solve_is_the_same_bit_for_bit_in_fewer_bytes(place, monkeypatch):
    """``uwb solve``'s workflow (``solve_field``, N-CLM) on a plant-like hall with the switches off and on: positions,
    σ, links excluded, status and the RMSE the same bit for bit, fewer bytes."""
    sub, geo, _ = _hall(1, place)
    got = {}
    for on in (False, True):
        for mod, name in SWITCHES:
            monkeypatch.setattr(mod, name, on)
        got[on] = solve_field(sub, FieldOptions(solver="N-CLM"), geometry=geo)
    a, b = got[False], got[True]
    assert np.array_equal(a.positions_m, b.positions_m, equal_nan=True)
    assert np.array_equal(a.sigma_m, b.sigma_m, equal_nan=True)
    assert np.array_equal(a.excluded, b.excluded) and a.status == b.status
    assert b.bytes < 0.98 * a.bytes


def test_a_scaled_step_is_the_senders_rounding_without_a_message(hall):
    """``Wire.scaled``: every receiver's rows moved by ``factor`` × the last step it received, rounded as the sender
    rounds ``factor`` × its own step — bit for bit what sending that step delivers — and nothing sent."""
    p = hall[0]
    rng = np.random.default_rng(9)
    got = []
    for send in (True, False):
        ex = make_exchange(Graph.from_links(p.n_anchors, p.links))
        links = Links(p, ex, known_from_problem=True)
        first = links.neighbours(np.where(p.free, p.initial_m, p.positions_m))
        step = links.wire.rounded(np.where(p.free, rng.normal(size=p.free.shape) * 1e-3, 0.0))
        nb = links.wire.stepped(first, step)
        before = ex.comm_totals().snapshot()
        factor = 2.9 / 1.3
        nb2 = links.wire.stepped(nb, links.wire.rounded(step * factor)) if send else links.wire.scaled(nb, factor)
        sent = ex.comm_totals().bytes - before.bytes
        got.append((nb2, sent))
        rng = np.random.default_rng(9)
    assert np.array_equal(got[0][0], got[1][0]) and got[0][1] > 0 and got[1][1] == 0


def test_an_extrapolated_trial_is_the_same_solve_without_its_broadcast(hall, monkeypatch):
    """With a trigger that fires (``EXTRAPOLATE`` loosened), the LM phase with the switches on and off: the same
    solution bit for bit, one step message fewer per extrapolated trial."""
    p = subset_measurements(hall[0], ~hall[2])
    monkeypatch.setattr(refine_mod, "EXTRAPOLATE", (0.05, 0.999, 0.9))
    calls = []
    extrapolate = refine_mod._Refiner.extrapolate

    def counted(self, *args):
        calls.append(1)
        return extrapolate(self, *args)

    monkeypatch.setattr(refine_mod._Refiner, "extrapolate", counted)
    out = {}
    for on in (False, True):
        for mod, name in SWITCHES:
            monkeypatch.setattr(mod, name, on)
        calls.clear()
        ref, ex = _refined(p, offset_start_m=0.0)
        out[on] = (ref, ex.comm_totals().messages, len(calls))
    assert out[True][2] == out[False][2] > 0
    assert _same(out[True][0], out[False][0])
    edges = int(np.sum(np.bincount(p.links.ravel(), minlength=p.n_anchors) * p.free.any(axis=1)))
    assert out[False][1] - out[True][1] == edges * out[True][2]  # no step message in an extrapolated trial
