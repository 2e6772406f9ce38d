"""The message economy of the distributed UWB phases (distnav.algorithms.ranging.wire, issue 27): the packed rounds
deliver exactly what the full rounds delivered, send fewer bytes for the stated reason, the float16 (shared
exponent) and float32 directions and the looser σ tolerance of the workflow stay within their stated distance of
LM's dense answers, and the per-phase split of the bytes adds up to the totals."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from distnav.algorithms.ranging import wire
from distnav.algorithms.ranging.covariance import ECONOMY_CG_RTOL, ECONOMY_WIRE_DTYPE, central_precision
from distnav.algorithms.ranging.csg import solve
from distnav.algorithms.ranging.inner import CGOptions, sit_out_plan
from distnav.algorithms.ranging.lm import solve_lm
from distnav.algorithms.ranging.neighbourhoods import half_measurements
from distnav.algorithms.ranging.refine import (
    Links,
    NormalSystem,
    block_preconditioner,
    jacobian_rows,
    pcg,
    refine,
)
from distnav.algorithms.ranging.wire import pack_half, unpack_half
from distnav.errors import ModelError, UsageError
from distnav.exchange import make_exchange
from distnav.experiments.uwb_field import hall_problem
from distnav.models.uwb.field import FieldOptions, prepare, solve_field, subset_measurements
from distnav.models.uwb.hall import PLANT_LIKE, HallConfig, simulate_hall
from distnav.network.graph import Graph

OPTS = {"objective": "metres", "sigma_m": 0.1, "loss": "cauchy", "loss_scale_m": 0.3, "range_offsets": "common"}


@pytest.fixture(scope="module")
def hall():
    """The plant-like 28-anchor hall [78, 0] (known anchors in the middle, heights held) and the NLOS truth."""
    h = simulate_hall(np.random.default_rng([78, 0]), HallConfig().with_(known="middle", **PLANT_LIKE))
    p, nlos = hall_problem(h)
    sub, geo = prepare(p)
    keep = geo.solvable
    return sub, geo, nlos[keep[p.meas_a] & keep[p.meas_b]]


def _exchange(p):
    return make_exchange(Graph.from_links(p.n_anchors, p.links))


def _rounds(p, values, vectors, plain, known=True):
    """The rows two rounds deliver (parameters twice, one CG vector) and the exchange's bytes and messages
    (``known``: the known coordinates from the problem, as the LM phase's :class:`Links`)."""
    saved = wire.PLAIN
    wire.PLAIN = plain
    try:
        ex = _exchange(p)
        links = Links(p, ex, known_from_problem=known)
        first = links.neighbours(values)
        moved = values.copy()
        moved[p.free[ex.nodes]] += 0.25  # an LM step moves the free coordinates only
        second = links.neighbours(moved)
        v = links.vectors(vectors)
        c = ex.comm_totals()
        return (first, second, v), c
    finally:
        wire.PLAIN = saved


def test_packed_rounds_deliver_exactly_what_full_rounds_did_for_fewer_bytes(hall):
    p = hall[0]
    rng = np.random.default_rng(3)
    values = p.initial_m.copy()
    vectors = rng.normal(size=(p.n_anchors, p.dim, 5)) * p.free[:, :, None]  # zero where not free (as CG's)
    packed, c_packed = _rounds(p, values, vectors, plain=False)
    full, c_full = _rounds(p, values, vectors, plain=True)
    for a, b in zip(packed, full, strict=True):
        assert np.array_equal(a, b)  # bit for bit
    links = 2 * p.links.shape[0]
    fixed = np.flatnonzero(~p.free.any(axis=1))
    from_fixed = int(np.isin(p.links, fixed).sum())  # directed edges whose sender has nothing free
    assert fixed.size == 4 and from_fixed > 0
    cols = int(np.any(p.free, axis=0).sum())  # heights held everywhere: x and y
    assert cols == 2
    assert c_full.bytes == links * 8 * p.dim * (2 + 5)
    # the first parameters too: the free columns from the anchors with a free parameter (wire.KNOWN_FROM_PROBLEM)
    assert c_packed.bytes == (links - from_fixed) * 8 * cols * (2 + 5)
    assert c_packed.messages == 3 * (links - from_fixed)


def test_first_parameters_in_full_without_known_from_problem(hall, monkeypatch):
    """With ``wire.KNOWN_FROM_PROBLEM`` off, or for a :class:`Links` that does not take the known coordinates from
    the problem (the central σ's, at any positions), the first parameters travel whole from every anchor (as
    before the fifth session), the same rows bit for bit."""
    p = hall[0]
    values = p.initial_m.copy()
    vectors = np.zeros((p.n_anchors, p.dim, 1))
    monkeypatch.setattr(wire, "KNOWN_FROM_PROBLEM", False)
    whole, c_whole = _rounds(p, values, vectors, plain=False)
    monkeypatch.setattr(wire, "KNOWN_FROM_PROBLEM", True)
    assert _rounds(p, values, vectors, plain=False, known=False)[1].bytes == c_whole.bytes
    known, c_known = _rounds(p, values, vectors, plain=False)
    for a, b in zip(whole, known, strict=True):
        assert np.array_equal(a, b)
    links = 2 * p.links.shape[0]
    from_fixed = int(np.isin(p.links, np.flatnonzero(~p.free.any(axis=1))).sum())
    assert c_whole.bytes - c_known.bytes == links * 8 * p.dim - (links - from_fixed) * 8 * 2


def test_a_lost_message_from_a_talking_anchor_is_still_an_error(hall):
    from distnav.errors import ModelError
    from distnav.exchange import FaultSchedule

    p = hall[0]
    g = Graph.from_links(p.n_anchors, p.links)
    ex = make_exchange(g, faults=FaultSchedule(drop_probability=0.5, seed=1))
    links = Links(p, ex)
    with pytest.raises(ModelError, match="lost"):
        for _ in range(3):
            links.vectors(np.ones((p.n_anchors, p.dim, 1)) * p.free[:, :, None])


@pytest.mark.parametrize("dtype", [np.float16, np.float32])
def test_reduced_precision_directions_reach_lms_solution(hall, dtype, monkeypatch):
    """The LM phase with float16 (shared exponent, the default) or float32 CG directions ends where LM (dense,
    float64) ends, as the float64 phase does; float16 sends 5 B per free anchor and link where float32 sent 8."""
    p = subset_measurements(hall[0], ~hall[2])
    lm = solve_lm(p, **OPTS)
    assert lm.status == "converged"
    sigma = lm.precision.std(a_posteriori=False)
    monkeypatch.setattr(wire, "CG_WIRE_DTYPE", dtype)
    res = solve(p, "N-CLM", iterations=0, **OPTS)
    assert res.status == "converged", res.message
    z = np.abs(res.estimates - lm.estimates)[p.free] / sigma[p.free]
    assert z.max() < 1e-3
    assert np.abs(res.estimates - lm.estimates).max() < 1e-4  # 0.1 mm


def test_half_rows_round_trip_to_11_bits_of_their_largest_entry():
    """pack_half / unpack_half: 2 B per entry and one exponent byte per row; every entry within 2⁻¹¹ of its row's
    largest magnitude (float16's 11 significant bits after the shared scaling), at any scale from 1e-30 to 1e30
    (a bare float16 flushes 1e-9 to 0 and overflows at 65504); zero rows stay zero, signs kept."""
    rng = np.random.default_rng(5)
    rows = rng.normal(size=(7, 6)) * np.array([1e-30, 1e-9, 1e-3, 1.0, 7e4, 1e30, 0.0])[:, None]
    packed = pack_half(rows)
    assert packed.dtype == np.uint8 and packed.shape == (7, 2 * 6 + 1)
    back = unpack_half(packed, 6)
    top = np.max(np.abs(rows), axis=1, keepdims=True)
    assert np.all(np.abs(back - rows) <= 2.0**-11 * top)
    assert np.all(back[6] == 0.0) and np.all(np.sign(back[:6]) == np.sign(rows[:6]))
    assert np.all(np.float16(rows[1]) == 0.0) and np.all(back[1] != 0.0)  # what the exponent is for
    with pytest.raises(ModelError, match="13 bytes"):
        unpack_half(packed[:, :-1], 6)


def test_half_directions_bytes_per_round(hall):
    """One CG round with float16 directions: 2 B per free column and 1 exponent byte, from every anchor with a free
    parameter, on every directed link it sends on."""
    p = hall[0]
    g = Graph.from_links(p.n_anchors, p.links)
    ex = make_exchange(g)
    links = Links(p, ex)
    v = np.random.default_rng(1).normal(size=(p.n_anchors, p.dim, 1)) * p.free[:, :, None]
    before = ex.comm_totals().snapshot()
    got = links.vectors(v, np.float16)
    c = ex.comm_totals().since(before)
    fixed = np.flatnonzero(~p.free.any(axis=1))
    talking = 2 * p.links.shape[0] - int(np.isin(p.links, fixed).sum())
    assert c.bytes == talking * (2 * 2 + 1) and c.messages == talking
    exact = links.vectors(v, np.float64)
    assert np.all(np.abs(got - exact) <= 2.0**-11 * np.max(np.abs(v)))


def test_economy_sigma_within_1e5_of_lms_dense_covariance(hall):
    p = subset_measurements(hall[0], ~hall[2])
    lm = solve_lm(p, **OPTS, initial_m=p.truth_m)
    f = p.free.any(axis=1)
    kw = {"offset_m": lm.offsets_m, "sigma_m": 0.1, "loss": "cauchy", "loss_scale_m": 0.3, "range_offsets": "common"}
    exact = central_precision(p, lm.estimates, **kw)
    cheap = central_precision(p, lm.estimates, **kw, rtol=ECONOMY_CG_RTOL, wire_dtype=ECONOMY_WIRE_DTYPE)
    want = lm.precision.covariance[f]
    np.testing.assert_allclose(cheap.precision.covariance[f], want, rtol=1e-5, atol=1e-12)
    assert exact.precision.comm is not None and cheap.precision.comm is not None
    assert cheap.precision.comm.bytes < 0.75 * exact.precision.comm.bytes


def test_phase_marks_gather_nothing_until_the_end(hall, monkeypatch):
    """The phase marks are each block's own counters, summed over the blocks by one all-reduction at the end: the
    network totals (every node's counters and the per-round totals, gathered: real traffic between field nodes)
    are taken once, for the result's ``comm``, not at every mark (the field demo's clean UWB run: −75 kB)."""
    from distnav.exchange.core import ExchangeCore

    calls = {"comm_totals": 0}
    real = ExchangeCore.comm_totals

    def counted(self: ExchangeCore) -> object:
        calls["comm_totals"] += 1
        return real(self)

    monkeypatch.setattr(ExchangeCore, "comm_totals", counted)
    sub, _, _ = hall
    r = solve(sub, "N-CLM", iterations=5, **OPTS)
    assert calls["comm_totals"] == 1  # the result's comm (it was 4: three marks and the result)
    phases = r.settings["comm_phases"]
    assert sum(v["bytes"] for v in phases.values()) == r.comm.bytes


def test_phases_add_up_to_the_totals(hall):
    sub, geo, _ = hall
    r = solve(sub, "N-CLM", iterations=5, **OPTS)
    phases = r.settings["comm_phases"]
    assert list(phases) == ["iterations", "refine", "quality"]
    assert phases["iterations"]["bytes"] > 0 and phases["refine"]["bytes"] > 0  # the QC may be local (0 here)
    assert sum(v["bytes"] for v in phases.values()) == r.comm.bytes
    assert sum(v["messages"] for v in phases.values()) == r.comm.messages
    sol = solve_field(sub, FieldOptions(solver="N-CLM"), geometry=geo)
    assert list(sol.comm_phases) == ["first_fit", "tighten", "exclusions", "polish", "precision", "reliability"]
    assert sol.comm_phases["reliability"]["bytes"] == sol.reliability["bytes"] > 0  # issue 28 item 5
    assert sum(v["bytes"] for v in sol.comm_phases.values()) == sol.bytes
    assert sum(v["messages"] for v in sol.comm_phases.values()) == sol.messages
    assert sol.comm_phases["precision"]["bytes"] == sol.precision_bytes


def test_lm_phase_reductions_are_counted_and_float32_scalars_halve_them(hall, monkeypatch):
    """The LM phase's network totals are charged as spanning-tree reductions (2(n − 1) messages each; at least
    two per CG iteration: the curvature and the residual); with float32 CG scalars their bytes are about half those
    of float64 (the costs and steps stay float64), with CG's dot products in float16 with an exponent per value
    (the default, 3 B) 0.5–0.8 of float32's, and the phase still ends within 0.1 mm of LM."""
    p = subset_measurements(hall[0], ~hall[2])
    lm = solve_lm(p, **OPTS)
    got = {}
    for dtype in (np.float64, np.float32, np.float16):
        monkeypatch.setattr(wire, "CG_SCALAR_DTYPE", np.float32 if dtype == np.float16 else dtype)
        monkeypatch.setattr(wire, "CG_DOT_DTYPE", dtype)
        res = solve(p, "N-CLM", iterations=0, **OPTS)
        assert res.status == "converged" and np.abs(res.estimates - lm.estimates).max() < 1e-4
        got[dtype] = ref = res.settings["refine"]
        assert ref["reductions"] >= 2 * ref["cg_iterations"]
        # 2(n − 1) messages each, but the first objective: up to the root only (refine.ROOT_DECIDES); n the anchors
        # with a free parameter: the known ones sit the phase out (refine.SIT_OUT, issue 27 item 37)
        tree = int(np.any(p.free, axis=1).sum())
        assert tree < p.n_anchors
        assert ref["reduction_messages"] == (ref["reductions"] * 2 - 1) * (tree - 1)
    per64 = got[np.float64]["reduction_bytes"] / got[np.float64]["reductions"]
    per32 = got[np.float32]["reduction_bytes"] / got[np.float32]["reductions"]
    per16 = got[np.float16]["reduction_bytes"] / got[np.float16]["reductions"]
    assert 0.5 <= per32 / per64 < 0.65
    assert 0.5 <= per16 / per32 < 0.8


def test_cg_dot_products_as_float16_with_an_exponent_per_value(monkeypatch):
    """``wire.pack_scalars``: 3 B a value, 11 significant bits whatever its magnitude (a bare float16 would flush
    1e-9 to zero and overflow 1e6); float16 dots only up to HALF_MAX_ANCHORS anchors, CG_SCALAR_DTYPE above."""
    vals = np.array([[1e-9, -3.7e6], [0.0, 123.456]])
    packed = wire.pack_scalars(vals)
    assert packed.shape == (4, 3) and packed.dtype == np.uint8
    back = wire.unpack_scalars(packed, vals.shape)
    assert np.all(np.abs(back - vals) <= np.abs(vals) * 2.0**-11)
    assert back[1, 0] == 0.0 and back[0, 0] != 0.0
    assert wire.cg_dot_dtype(wire.HALF_MAX_ANCHORS) == np.float16
    assert wire.cg_dot_dtype(wire.HALF_MAX_ANCHORS + 1) == wire.CG_SCALAR_DTYPE
    monkeypatch.setattr(wire, "CG_DOT_DTYPE", np.float32)
    assert wire.cg_dot_dtype(10) == wire.CG_SCALAR_DTYPE


def test_float16_directions_only_up_to_half_max_anchors(monkeypatch):
    """float16 directions up to HALF_MAX_ANCHORS anchors, float32 above (CG needed twice the iterations in float16
    at 3,000 and 10⁴ anchors); a float32 or float64 choice is kept at every size."""
    assert wire.cg_wire_dtype(wire.HALF_MAX_ANCHORS) == np.float16
    assert wire.cg_wire_dtype(wire.HALF_MAX_ANCHORS + 1) == np.float32
    monkeypatch.setattr(wire, "CG_WIRE_DTYPE", np.float64)
    assert wire.cg_wire_dtype(28) == np.float64 and wire.cg_wire_dtype(10**4) == np.float64


def _system(p, per, sigma_on_wire, dtype=np.float64, sit_out=None):
    """The LM phase's normal system on the hall at its start (random IRLS weights and sample σ), the exchange, and
    the dense ``JᵀWJ`` over every parameter built here from the positions (the reference); ``sit_out``: the
    known anchors sit out (``inner.SitOut``, no common offset here: the coordinates' rows are the same)."""
    ex = _exchange(p)
    links = Links(p, ex, per_anchor_offsets=per, sit_out=sit_out, known_from_problem=sit_out is not None)
    rng = np.random.default_rng(11)
    P, dim = p.dim + (1 if per else 0), p.dim
    x = np.zeros((p.n_anchors, P))
    x[:, :dim] = p.initial_m
    if per:
        x[:, dim] = rng.normal(scale=0.05, size=p.n_anchors)
    sig_s, w_s = rng.uniform(0.05, 0.2, p.n_meas), rng.uniform(0.2, 1.0, p.n_meas)
    free = np.ones((p.n_anchors, P), bool)
    free[:, :dim] = p.free
    free_nb = np.ones((links.samp.size, P), bool)
    free_nb[:, :dim] = p.free[links.other]
    nb = links.neighbours(x)
    sig = sig_s[links.samp]
    a, cn, e = jacobian_rows(x, nb, links.owner, sig, dim, per, False, free, free_nb)
    damp = np.zeros((p.n_anchors, P))
    system = NormalSystem(
        links,
        links.owner,
        a,
        cn,
        e,
        w_s[links.samp],
        damp,
        0.0,
        0.0,
        free,
        False,
        dtype,
        sig if sigma_on_wire else None,
        omega=None if sit_out is None else np.where(sit_out.listens[links.owner], 1.0, 0.0),
    )
    J = np.zeros((p.n_meas, p.n_anchors, P))
    d = x[p.meas_a, :dim] - x[p.meas_b, :dim]
    u = d / np.linalg.norm(d, axis=1)[:, None] / sig_s[:, None]
    rows = np.arange(p.n_meas)
    J[rows, p.meas_a, :dim] = u
    J[rows, p.meas_b, :dim] = -u
    if per:
        J[rows, p.meas_a, dim] = J[rows, p.meas_b, dim] = 1.0 / sig_s
    J = (J * free[None]).reshape(p.n_meas, -1)
    return ex, links, system, J.T @ (w_s[:, None] * J), free


@pytest.mark.parametrize("per", [False, True])
def test_projected_products_equal_the_dense_normal_matrix(hall, per):
    """The LM phase's matrix–vector product with every neighbour's product sent projected (one value per link and
    column, ``wire.PROJECTED``) equals the dense ``JᵀWJ v`` (built here from the positions, per-anchor offsets
    too) to rounding in float64, and to float16's 11 bits with the shared exponent; a projected round sends ``k``
    values per link from every anchor with a free parameter, ``2k + 1`` bytes in float16, where a direction's
    row was ``k`` values per free column (2 here: heights held). Every pair is ranged twice, once each way, with
    another σ: a link's product is sent once, its two samples' rows differ by their σ only."""
    h = hall[0]
    p = dataclasses.replace(
        h,
        meas_a=np.r_[h.meas_a, h.meas_b],
        meas_b=np.r_[h.meas_b, h.meas_a],
        range_m=np.r_[h.range_m, h.range_m + 0.01],
    )
    k = 3
    v = np.random.default_rng(2).normal(size=(p.n_anchors, p.dim + (1 if per else 0), k))
    fixed = np.flatnonzero(~p.free.any(axis=1))
    talking = 2 * h.links.shape[0] - (0 if per else int(np.isin(p.links, fixed).sum()))
    for dtype, itemsize, tol in ((np.float64, 8 * k, 1e-12), (np.float16, 2 * k + 1, 2.0**-10)):
        ex, links, system, N, free = _system(p, per, True, dtype)
        vf = v * free[:, :, None]
        want = (N @ vf.reshape(-1, k)).reshape(vf.shape)
        before = ex.comm_totals().snapshot()
        got = system.matvec(vf, np.zeros(k))[0]
        c = ex.comm_totals().since(before)
        assert c.messages == talking and c.bytes == talking * itemsize
        assert np.max(np.abs(got - want)) <= tol * np.max(np.abs(want))
        rows = _system(p, per, False)[2].matvec(vf, np.zeros(k))[0]  # the neighbours' rows sent instead
        assert np.max(np.abs(rows - want)) <= 1e-12 * np.max(np.abs(want))


def test_a_cg_runs_later_products_travel_on_the_held_exponent(hall, monkeypatch):
    """``wire.HELD_EXPONENT``: in one CG run (one normal system) the first projected round carries each link's
    exponent (``2k + 1`` bytes); a later product within float16's normal range on it (10 and 1,000 times smaller)
    travels without (``2k``), one 10⁶ times smaller or 10⁶ times larger again carries a new exponent; every one
    keeps float16's 11 bits against the dense ``JᵀWJ v``; with the switch off every round carries its exponent."""
    k = 2
    v = np.random.default_rng(5).normal(size=(hall[0].n_anchors, hall[0].dim, k))
    fixed = np.flatnonzero(~hall[0].free.any(axis=1))
    talking = 2 * hall[0].links.shape[0] - int(np.isin(hall[0].links, fixed).sum())
    for on in (True, False):
        monkeypatch.setattr(wire, "HELD_EXPONENT", on)
        ex, links, system, N, free = _system(hall[0], False, True, np.float16)
        vf = v * free[:, :, None]
        for scale, exponent in ((1.0, True), (0.1, False), (1e-3, False), (1e-9, True), (1e-3, True)):
            want = (N @ (scale * vf).reshape(-1, k)).reshape(vf.shape)
            before = ex.comm_totals().snapshot()
            got = system.matvec(scale * vf, np.zeros(k))[0]
            c = ex.comm_totals().since(before)
            assert c.messages == talking and c.bytes == talking * (2 * k + (1 if exponent or not on else 0))
            assert np.max(np.abs(got - want)) <= 2.0**-10 * np.max(np.abs(want))


def test_with_the_known_anchors_sitting_out_products_skip_them_and_recount(hall):
    """The shipped configuration's products (``refine.SIT_OUT``: ``Links(sit_out=…)``, review of item 37, finding
    8): a product goes only on the links from an anchor with a free parameter to another (none to a known anchor),
    ``2k + 1`` bytes with the link's exponent, ``2k`` on the held one (``wire.HELD_EXPONENT``), and every free
    anchor's row keeps float16's 11 bits against the dense ``JᵀWJ v``."""
    k, p = 2, hall[0]
    plan = sit_out_plan(p, np.asarray(p.free))
    assert plan is not None
    v = np.random.default_rng(5).normal(size=(p.n_anchors, p.dim, k))
    a, b = p.links[:, 0], p.links[:, 1]
    listening = int(np.sum(plan.listens[a] & plan.listens[b])) * 2
    ex, links, system, N, free = _system(p, False, True, np.float16, sit_out=plan)
    vf = v * free[:, :, None]
    rows = plan.listens
    for scale, exponent in ((1.0, True), (0.1, False), (1e-9, True)):
        want = (N @ (scale * vf).reshape(-1, k)).reshape(vf.shape)
        before = ex.comm_totals().snapshot()
        got = system.matvec(scale * vf, np.zeros(k))[0]
        c = ex.comm_totals().since(before)
        assert c.messages == listening and c.bytes == listening * (2 * k + (1 if exponent else 0))
        assert np.max(np.abs(got[rows] - want[rows])) <= 2.0**-10 * np.max(np.abs(want[rows]))
    assert np.all(ex.comm_totals().bytes_received[~plan.listens] == 0)


def _damped(p, dtype):
    """:func:`_system` damped by 1e-3 on every parameter, its block preconditioner and a right-hand side."""
    _, links, system, N, free = _system(p, False, True, dtype)
    damp = 1e-3 * np.ones_like(system.damp)
    system = NormalSystem(**{**system.__dict__, "damp": damp})
    P = free.shape[1]
    own_block = np.zeros((p.n_anchors, P, P))
    np.add.at(own_block, system.owner, np.einsum("h,ha,hb->hab", system.w, system.a, system.a))
    pre_inv = block_preconditioner(own_block, damp, free)
    b = np.random.default_rng(4).normal(size=(p.n_anchors, P, 1)) * free[:, :, None]
    return links, system, N, free, damp, pre_inv, b


def test_preconditioned_stop_drops_one_reduced_float_per_iteration(hall):
    """CG stopped on ``rᵀz`` (the LM phase's default) reduces one float less per column and iteration than
    stopped on ``rᵀr``, and it stops where the preconditioned residual, recomputed here from the dense matrix,
    is below ``rtol`` of its start (the damped system: one diagonal block per anchor as the preconditioner)."""
    p = hall[0]
    got = {}
    for stop in (True, False):
        links, system, N, free, damp, pre_inv, b = _damped(p, np.float64)
        P = free.shape[1]
        before = links.reduced_floats
        x, _, its = pcg(system, b, np.zeros(1), pre_inv, 1.0, links, 200, rtol=0.1, preconditioned_stop=stop)
        got[stop] = (links.reduced_floats - before, its)
        r = b.reshape(-1) - (N + np.diag(damp.reshape(-1) * free.reshape(-1))) @ x.reshape(-1)
        r = r * free.reshape(-1)
        z = np.einsum("nab,nb->na", pre_inv, r.reshape(p.n_anchors, P)).reshape(-1)
        z0 = np.einsum("nab,nb->na", pre_inv, b[:, :, 0]).reshape(-1)
        if stop:
            assert r @ z <= 0.1**2 * (b.reshape(-1) @ z0) * (1 + 1e-9)
        else:
            assert r @ r <= 0.1**2 * (b.reshape(-1) @ b.reshape(-1)) * (1 + 1e-9)
    for stop, (floats, its) in got.items():  # pᵀq alone: no common offset, no share of its row (seventh session)
        assert its > 3 and floats == its + (1 if stop else 2) * (its + 1)


def test_pcg_options_object_and_keywords_run_the_same(hall):
    """:func:`pcg`'s settings as one :class:`CGOptions` or as keywords: the same solution bit for bit (and a tighter
    ``rtol`` through either a different one, so the settings are not ignored); a misspelt keyword or a bad value is
    refused by name."""
    p = hall[0]
    runs = []
    for how in (
        {"rtol": 0.1, "preconditioned_stop": True},
        {"options": CGOptions(rtol=0.1, preconditioned_stop=True)},
        {"options": CGOptions(rtol=0.1), "preconditioned_stop": True},
        {"rtol": 1e-6},
    ):
        links, system, _, _, _, pre_inv, b = _damped(p, np.float64)
        runs.append(pcg(system, b, np.zeros(1), pre_inv, 1.0, links, 200, **how))
    for x, _, its in runs[1:3]:
        assert its == runs[0][2] and np.array_equal(x, runs[0][0])
    assert runs[3][2] > runs[0][2] and not np.array_equal(runs[3][0], runs[0][0])
    links, system, _, _, _, pre_inv, b = _damped(p, np.float64)
    with pytest.raises(UsageError, match="no option 'rtl'.*did you mean 'rtol'"):
        pcg(system, b, np.zeros(1), pre_inv, 1.0, links, 200, rtl=0.1)
    with pytest.raises(ModelError, match="rtol must be a finite number"):
        CGOptions(rtol=float("nan"))


def _refined(p, offsets):
    """The LM phase on ``p`` from its initial positions (σ 0.1 m, Cauchy at 0.3 m, offsets ``offsets``) and its
    exchange."""
    ex = _exchange(p)
    sigma = np.full(p.n_meas, 0.1)
    common = {"loss": "cauchy", "offset_prior_sigma_m": 0.1, "ftol": 1e-6, "xtol_m": 1e-4}
    ref = refine(
        p, ex, p.initial_m, np.zeros(p.n_anchors), sigma=sigma, scale=0.3 / sigma, range_offsets=offsets, **common
    )
    return ref, ex


@pytest.mark.parametrize("offsets", ["common", "per_anchor"])
def test_steps_leave_both_ends_with_the_same_parameters(hall, offsets, monkeypatch):
    """The LM phase's trials sent as steps from the accepted parameters (``wire.STEPS``, float32): every anchor's
    copy of each neighbour's parameters at the end is that neighbour's own, bit for bit (the sender moves by the
    rounded step), and the phase ends within 0.05 mm of the one that sends the float64 parameters each trial (half
    the stopping tolerance of 0.1 mm), both within 0.1 mm of LM, with fewer bytes."""
    p = subset_measurements(hall[0], ~hall[2])
    opts = {**OPTS, "range_offsets": offsets, "offset_prior_sigma_m": 0.1}
    lm = solve_lm(p, **opts)
    ex = _exchange(p)
    owner, other, _, _ = half_measurements(p, ex)
    out = {}
    for steps in (True, False):
        monkeypatch.setattr(wire, "STEPS", steps)
        ref, ex = _refined(p, offsets)
        assert ref.status == "converged"
        assert np.array_equal(ref.half_other_m, ref.own_m[other])
        if offsets == "per_anchor":
            assert ref.offset_m is not None and ref.half_offset_m is not None
            assert np.array_equal(ref.half_offset_m, ref.offset_m[owner] + ref.offset_m[other])
        out[steps] = (ref.own_m, ex.comm_totals().bytes)
    assert np.abs(out[True][0] - out[False][0]).max() < 5e-5
    assert max(np.abs(out[s][0] - lm.estimates).max() for s in out) < 1e-4
    assert out[True][1] < out[False][1]


def test_a_rounds_totals_travel_as_float32_but_the_objective(hall):
    """``Links.gathered`` with ``exact_columns``: the first columns arrive as sent (float64, 8 B each: the objective
    that decides acceptance), the others rounded to float32 (4 B each), every anchor's row."""
    p = hall[0]
    links = Links(p, _exchange(p))
    rows = np.random.default_rng(8).normal(size=(p.n_anchors, 3)) * np.array([1e3, 1e-3, 7.0])
    got = links.gathered(rows, np.float32, exact_columns=1)
    assert np.array_equal(got[:, 0], rows[:, 0])
    assert np.array_equal(got[:, 1:], rows[:, 1:].astype(np.float32).astype(float))
    assert not np.array_equal(got[:, 1:], rows[:, 1:])
    assert links.reductions == 1 and links.reduced_bytes == 8 + 2 * 4 and links.reduced_floats == 3


def _first_round(p, held_m=None):
    """The rows a fresh LM phase's :class:`Links` delivers in its first and second parameter rounds, and the bytes
    and messages of the first (``held_m``: what the receivers hold from the last fit, wire item 6)."""
    ex = _exchange(p)
    links = Links(p, ex, known_from_problem=True, held_m=held_m)
    values = np.where(p.free, p.initial_m, p.positions_m)  # the LM phase's start (refine._Refiner.start)
    first = links.neighbours(values)
    c = ex.comm_totals().snapshot()  # the live counters go on counting
    moved = values + 0.25 * p.free  # an LM step moves the free coordinates only
    return first, links.neighbours(moved), c


def test_a_warm_start_the_receivers_hold_sends_only_the_other_rows(hall):
    """wire item 6 (issue 27, item 23): an anchor whose start every ranged neighbour holds (``held_m`` not
    NaN) sends no first parameters; the receivers' rows are the full first broadcast's bit for bit, the next round
    is unchanged, and the first round's bytes are exactly the free columns from the anchors not held."""
    p = hall[0]
    full, full2, c_full = _first_round(p)
    start = np.where(p.free, p.initial_m, p.positions_m)
    held = start.copy()
    moved = np.flatnonzero(p.free.any(axis=1))[::3]  # every third free anchor: its receivers do not hold its start
    held[moved] = np.nan
    got, got2, c_got = _first_round(p, held)
    assert np.array_equal(got, full) and np.array_equal(got2, full2)  # bit for bit
    a, b = p.links[:, 0], p.links[:, 1]
    senders = np.r_[a, b]  # each link both ways: the sender of each directed edge
    from_moved = int(np.isin(senders, moved).sum())
    assert 0 < from_moved < senders.size
    assert c_got.messages == from_moved and c_got.bytes == from_moved * 8 * 2  # x and y, float64
    nothing, nothing2, c_none = _first_round(p, start)  # every start held: no first round at all
    assert np.array_equal(nothing, full) and np.array_equal(nothing2, full2)
    assert c_none.messages == 0 and c_none.bytes == 0


def test_a_start_that_differs_from_what_the_receivers_hold_is_refused(hall, monkeypatch):
    """The receivers would fill another row than the sender's start: a ModelError, not a silent difference; with
    ``wire.HELD_FROM_LAST_FIT`` off ``held_m`` is ignored (the full first round)."""
    p = hall[0]
    held = np.where(p.free, p.initial_m, p.positions_m)
    i = int(np.flatnonzero(p.free.any(axis=1))[0])
    held[i] = np.nextafter(held[i], np.inf)  # one bit off on the free coordinates
    with pytest.raises(ModelError, match="held_m"):
        _first_round(p, held)
    with pytest.raises(ModelError, match="shape"):
        _first_round(p, held[:-1])
    monkeypatch.setattr(wire, "HELD_FROM_LAST_FIT", False)
    assert _first_round(p, held)[2].bytes == _first_round(p)[2].bytes


def test_held_scalars_round_as_pack_scalars_and_say_which_keep_the_exponent():
    """``wire.held_scalars`` (``wire.HELD_DOTS``): every value rounds to :func:`wire.pack_scalars`'s float16 bit for
    bit whatever the held exponent; a value travels without an exponent (2 B) exactly where its own exponent
    (``frexp``) lies from 13 below to 15 above the one its slot carried last, zeros always, and a run's first
    values never."""
    rng = np.random.default_rng(9)
    held: list[np.ndarray] = []
    prev = None
    for scale in (1.0, 0.1, 1e-3, 1e-6, 1e4, 1.0, 3e4):
        v = rng.normal(size=(7, 3)) * scale * rng.choice([1.0, 1e-5, 1e5], size=(7, 3), p=[0.8, 0.1, 0.1])
        v[0, 0] = 0.0
        got, on = wire.held_scalars(v, held)
        want = wire.unpack_scalars(wire.pack_scalars(v), v.shape)
        assert np.array_equal(got, want)
        own = np.frexp(v)[1]
        if prev is None:
            assert not on.any()
            expect_e = own
        else:
            fits = (own >= prev - 13) & (own <= prev + 15) | (v == 0)
            assert np.array_equal(on, fits)
            expect_e = np.where(fits, prev, own)
        prev = expect_e  # a zero keeps its slot's exponent (frexp(0) is 0 at the run's start, as pack_half's)


def test_pcg_with_held_dot_exponents_is_the_same_solve_in_fewer_bytes(hall, monkeypatch):
    """CG of the LM phase (float16 dot products, stop on ``rᵀz``) with ``wire.HELD_DOTS`` on and off: the same
    iterations and solution bit for bit; a reduced value costs 3 B at a run's start (the initial ``rᵀz``, the
    first ``pᵀq``; no common offset here, so no share of its row) and where an anchor's share or the total left
    its held window (from 13 below to 15 above the exponent its slot carried last, recounted here by ``frexp``
    from the values reduced), 2 B otherwise — against 3 + 6 B per iteration with the switch off. The solution
    equals numpy's dense solve of the damped system within CG's tolerance:
    ``‖x − x*‖_A² = rᵀA⁻¹r ≤ rᵀM⁻¹r / λ_min(M⁻¹A)``, with ``rᵀM⁻¹r ≤ rtol² bᵀM⁻¹b``."""
    p = hall[0]
    got = {}
    calls: list[tuple[int, np.ndarray]] = []
    held_scalars = wire.held_scalars

    def recorded(values, held):
        calls.append((id(held), np.array(values, float)))
        return held_scalars(values, held)

    monkeypatch.setattr(wire, "held_scalars", recorded)
    for on in (True, False):
        monkeypatch.setattr(wire, "HELD_DOTS", on)
        links, system, N, free, damp, pre_inv, b = _damped(p, np.float16)
        P = free.shape[1]
        before = links.reduced_bytes
        x, _, its = pcg(
            system,
            b,
            np.zeros(1),
            pre_inv,
            1.0,
            links,
            200,
            rtol=0.1,
            scalar_dtype=np.float16,
            preconditioned_stop=True,
        )
        got[on] = (x, its, links.reduced_bytes - before)
    x, its, sent = got[True]
    assert its > 5 and its == got[False][1] and np.array_equal(x, got[False][0])
    last: dict[int, np.ndarray] = {}

    def fits(key, v):
        own = np.frexp(v)[1]
        e = last.get(key)
        ok = np.zeros(v.shape, bool) if e is None else (v == 0) | ((own >= e - 13) & (own <= e + 15))
        last[key] = own if e is None else np.where(ok, e, own)
        return ok

    want = 0
    for (k_share, shares), (k_total, total) in zip(calls[::2], calls[1::2], strict=True):
        two = np.all(fits(k_share, shares), axis=0) & fits(k_total, total)[0]
        want += int(np.sum(np.where(two, 2, 3)))
    assert len(calls) == 2 * (2 * its + 1) and sent == want and got[False][2] == 3 + 6 * its
    assert sent <= 3 + 3 + 2 + 4 * (its - 1) + its  # at most one value per iteration left its window
    keep = free.reshape(-1)
    A = (N + np.diag(damp.reshape(-1)))[np.ix_(keep, keep)]
    Minv = np.zeros((p.n_anchors * P, p.n_anchors * P))
    for i in range(p.n_anchors):
        Minv[i * P : (i + 1) * P, i * P : (i + 1) * P] = pre_inv[i]
    Minv = Minv[np.ix_(keep, keep)]
    bb = b.reshape(-1)[keep]
    exact = np.linalg.solve(A, bb)
    err = x.reshape(-1)[keep] - exact
    lam_min = np.min(np.real(np.linalg.eigvals(Minv @ A)))
    r = bb - A @ x.reshape(-1)[keep]
    assert r @ Minv @ r <= 0.1**2 * (bb @ Minv @ bb) * 1.001
    assert err @ A @ err <= (r @ Minv @ r) / lam_min * (1 + 1e-9)
    assert np.linalg.norm(err) < np.linalg.norm(exact)


def test_products_keep_their_exponents_from_one_cg_run_to_the_next(hall, monkeypatch):
    """``wire.HELD_ACROSS_RUNS``: the LM phase's products keep each link's exponent from one CG run (LM round) to
    the next of the fit. The phase is the same bit for bit (positions, objective, rounds, CG iterations, the
    reductions' bytes) and its broadcasts send fewer bytes: at most one byte per talking link and CG run after the
    first (a run's first product on a link without its exponent byte)."""
    p = subset_measurements(hall[0], ~hall[2])
    fixed = np.flatnonzero(~p.free.any(axis=1))
    talking = 2 * p.links.shape[0] - int(np.isin(p.links, fixed).sum())
    out = {}
    for on in (True, False):
        monkeypatch.setattr(wire, "HELD_ACROSS_RUNS", on)
        ref, ex = _refined(p, "common")
        out[on] = (ref, ex.comm_totals().bytes)
    (a, sent_on), (b, sent_off) = out[True], out[False]
    assert a.status == b.status == "converged" and a.rounds == b.rounds > 2 and a.cg_iterations == b.cg_iterations
    assert np.array_equal(a.own_m, b.own_m) and a.objective == b.objective and a.reduced == b.reduced
    assert 0 < sent_off - sent_on <= (a.rounds - 1) * talking
