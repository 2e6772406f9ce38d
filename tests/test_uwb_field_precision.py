"""The distributed solvers' σ in the field workflow (distnav.models.uwb.field_precision): the gathered σ (LM's
covariance at one anchor, the default since issue 27) against the central σ by CG through the exchange (an
independent implementation), its cost against a hop count by networkx, and bad input."""

from __future__ import annotations

import networkx as nx
import numpy as np
import pytest

from distnav.algorithms.ranging.covariance import COVARIANCE_CG_RTOL, CentralPrecisionOptions, central_precision
from distnav.algorithms.ranging.lm import solve_lm
from distnav.errors import ModelError
from distnav.experiments.uwb_field import hall_problem
from distnav.models.uwb.communication import RANGE_RECORD_BYTES, gather_cost
from distnav.models.uwb.field import FieldOptions, prepare, solve_field, subset_measurements
from distnav.models.uwb.field_precision import distributed_sigma, gathered_cost
from distnav.models.uwb.hall import PLANT_LIKE, HallConfig, simulate_hall
from distnav.models.uwb.precision import DELAY_UPPER_Z


def _hall(known: str = "corner", seed: int = 1200):
    h = simulate_hall(np.random.default_rng(seed), HallConfig().with_(n_anchors=28, known=known, **PLANT_LIKE))
    p, nlos = hall_problem(h)
    sub, geo = prepare(p)
    keep = geo.solvable
    return sub, geo, nlos[keep[p.meas_a] & keep[p.meas_b]]


def _sigma(p, res, mode, offsets, delay_sigma_m):
    model = CentralPrecisionOptions(
        sigma_m=0.1,
        loss="cauchy_long",
        loss_scale_m=0.1,
        range_offsets=offsets,
        offset_prior_sigma_m=0.05,
        delay_sigma_m=delay_sigma_m,
        estimate_delays=delay_sigma_m > 0,
        variance_scale_m=0.3,
    )
    return distributed_sigma(p, res, model, exchange=None, objective="metres", mode=mode)


@pytest.mark.parametrize(("offsets", "delay_sigma_m"), [("common", 0.015), ("per_anchor", 0.0), ("none", 0.015)])
def test_gathered_sigma_equals_the_central_sigma_by_cg(offsets, delay_sigma_m):
    """At LM's solution on the LOS links: the gathered blocks (dense, LM's consider covariance) equal the central
    ones by CG over the exchange, for every offset model, delays considered and estimated, the variance factor at
    another loss scale than the weights'. Two references: the field workflow's own central mode (float32
    directions to ECONOMY_CG_RTOL, documented as σ within 1e-5 relative) and central_precision in float64 to
    COVARIANCE_CG_RTOL (1e-10), which must agree to 1e-7."""
    sub, _, nlos = _hall()
    p = subset_measurements(sub, ~nlos)
    lm = solve_lm(
        p, objective="metres", sigma_m=0.1, range_offsets=offsets, offset_prior_sigma_m=0.05, initial_m=p.truth_m
    )
    g = _sigma(p, lm, "gathered", offsets, delay_sigma_m)
    c = _sigma(p, lm, "central", offsets, delay_sigma_m)
    assert g.kind == "gathered" and c.kind == "central"
    f = p.free
    np.testing.assert_allclose(g.sigma_m[f], c.sigma_m[f], rtol=1e-5)
    np.testing.assert_allclose(g.covariance_m2, c.covariance_m2, rtol=1e-5, atol=1e-5 * np.max(c.covariance_m2))
    off = getattr(lm, "offsets_m", None)
    exact = central_precision(
        p,
        np.asarray(lm.estimates, float),
        offset_m=None if off is None else np.asarray(off, float),
        sigma_m=0.1,
        loss="cauchy_long",
        loss_scale_m=0.1,
        range_offsets=offsets,
        offset_prior_sigma_m=0.05,
        delay_sigma_m=delay_sigma_m,
        estimate_delays=delay_sigma_m > 0,
        variance_scale_m=0.3,
        delay_upper_z=DELAY_UPPER_Z,
        rtol=COVARIANCE_CG_RTOL,
    )
    np.testing.assert_allclose(g.sigma_m[f], exact.std(a_posteriori=True)[f], rtol=1e-7)
    assert np.all(g.sigma_m[~f] == 0.0)
    assert g.bytes * 100 < c.bytes  # the point of it (issue 27)


def test_gathered_cost_is_the_hop_bytes_of_a_shortest_path_tree():
    """What the anchors transmit adds up to Σ bytes × hops to the root (networkx BFS), up (range records and
    estimates) and down (packed blocks of the free coordinates), the root the anchor with the fewest up
    hop-bytes; one message per tree link each way."""
    sub, _, _ = _hall(known="middle")
    messages, sent = gathered_cost(sub)
    g = nx.Graph()
    g.add_nodes_from(range(sub.n_anchors))
    g.add_edges_from(map(tuple, sub.links))
    held = np.bincount(sub.links.min(axis=1), minlength=sub.n_anchors) * RANGE_RECORD_BYTES
    up = held + 8 * sub.dim
    nf = sub.free.sum(axis=1)
    down = 8 * nf * (nf + 1) // 2
    hops = dict(nx.all_pairs_shortest_path_length(g))
    up_cost = [sum(up[i] * hops[s][i] for i in g) for s in g]
    root = int(np.argmin(up_cost))
    want = up_cost[root] + sum(down[i] * hops[root][i] for i in g)
    assert messages == 2 * (sub.n_anchors - 1)
    assert sent.sum() == want
    assert sent.min() >= 0 and sent[root] == down.sum() - down[root]  # the root sends every block but its own
    # about the cost of gathering the ranges (what uwb solve compares with): 1–2 ×
    assert gather_cost(sub)["bytes"] < sent.sum() < 2 * gather_cost(sub)["bytes"]


def test_uwb_solve_default_sigma_is_gathered_and_equal_to_the_central_sigma():
    """uwb solve's workflow with N-CLM: the default σ (kind "gathered") equals the central σ by CG (the previous
    default, still reachable by distributed_precision="central") to 1e-5 relative, at the same positions and
    exclusions, for under 2 × the bytes of gathering the ranges (the central σ: thousands of times that)."""
    sub, geo, _ = _hall()
    d = solve_field(sub, FieldOptions(solver="N-CLM"), geometry=geo)
    c = solve_field(sub, FieldOptions(solver="N-CLM", distributed_precision="central"), geometry=geo)
    assert d.precision_kind == "gathered" and c.precision_kind == "central"
    assert np.array_equal(d.positions_m, c.positions_m) and np.array_equal(d.excluded, c.excluded)
    f = sub.free
    np.testing.assert_allclose(d.sigma_m[f], c.sigma_m[f], rtol=1e-5)
    assert d.status == c.status and d.weak == c.weak
    yard = gather_cost(sub)["bytes"]
    assert d.precision_bytes < 2 * yard < 1000 * yard < c.precision_bytes
    assert d.comm_phases["precision"]["bytes"] == d.precision_bytes


def test_gathered_precision_models_the_metres_objective_only():
    sub, _, nlos = _hall()
    p = subset_measurements(sub, ~nlos)
    lm = solve_lm(p, objective="metres", sigma_m=0.1, range_offsets="common", initial_m=p.truth_m)
    with pytest.raises(ModelError, match="'gathered' models the metres objective"):
        distributed_sigma(p, lm, CentralPrecisionOptions(), exchange=None, objective="squared", mode="gathered")
