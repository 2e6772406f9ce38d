"""Range offsets in the distributed UWB solvers (issue 13 item 5): partial gradients against finite differences,
the distributed solution against LM's centralized one (positions and offsets), messages and bytes, options."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from distnav.algorithms.ranging.csg import solve, solve_line_search_pair, solve_nclm, solve_ncsg
from distnav.algorithms.ranging.lm import solve_lm
from distnav.algorithms.ranging.neighbourhood_offsets import NeighbourhoodOffsets, _linearize
from distnav.algorithms.ranging.options import NcsgOptions
from distnav.algorithms.ranging.plan import plan_neighbourhood
from distnav.errors import ModelError
from distnav.models.uwb.problems import rmse_m
from test_csg_metres import hall

SIGMA = 0.05


def biased(p, common=0.0, per=None):
    """The problem with every range ``common + per[a] + per[b]`` long."""
    r = p.range_m + common
    if per is not None:
        r = r + per[p.meas_a] + per[p.meas_b]
    return dataclasses.replace(p, range_m=r)


@pytest.mark.parametrize("mode", ["common", "per_anchor"])
@pytest.mark.parametrize("loss", ["linear", "cauchy"])
def test_offset_partial_gradient_matches_finite_differences(mode, loss):
    p = biased(hall(sigma_m=0.05, nlos={5: 2.0}), 0.2)
    plan, P, _ = plan_neighbourhood(
        p,
        NcsgOptions(
            objective="metres",
            sigma_m=SIGMA,
            loss=loss,
            loss_scale_m=0.1,
            range_offsets=mode,
            offset_prior_sigma_m=0.05,
        ),
        method="N-CSG-BLS",
    )
    off = NeighbourhoodOffsets(plan.nb, mode, 0.05)
    B = np.where(off.free, np.random.default_rng(1).normal(0, 0.1, off.free.shape), 0.0)
    k = plan.iterations  # after the graduated stage: the robust loss
    gB = _linearize(plan, off, P, B, k)[6]
    checked = 0
    for i, s in [(5, 0), (5, 2), (9, 1), (13, 3), (0, 0), (2, 1), (7, 0), (11, 0)]:
        if not off.free[i, s]:
            assert gB[i, s] == 0.0
            continue
        h = 1e-6
        Bp, Bm = B.copy(), B.copy()
        Bp[i, s] += h
        Bm[i, s] -= h
        fd = (_linearize(plan, off, P, Bp, k)[4][i] - _linearize(plan, off, P, Bm, k)[4][i]) / (2 * h)
        assert 2.0 * gB[i, s] == pytest.approx(fd, rel=1e-5, abs=1e-6), (i, s)  # gB is ½ ∇f⁽ⁱ⁾
        checked += 1
    assert checked >= (4 if mode == "common" else 7)


def test_common_offset_nclm_equals_lm_on_consistent_ranges():
    """Ranges all 0.4 m long, no noise: LM and N-CLM reach the same positions and offset (tight)."""
    p = biased(hall(seed=6, n=18), 0.4)
    lm = solve_lm(p, objective="metres", sigma_m=SIGMA, range_offsets="common")
    res = solve_nclm(p, iterations=3000, objective="metres", sigma_m=SIGMA, range_offsets="common")
    assert res.status == "converged" and res.iterations < 3000, res.message
    assert np.abs(res.estimates - lm.estimates).max() < 1e-4
    assert rmse_m(p, lm.estimates) < 1e-9 and lm.offsets_m[0] == pytest.approx(0.4, abs=1e-12)
    assert res.offsets_m.shape == (1,) and res.offsets_m[0] == pytest.approx(lm.offsets_m[0], abs=1e-6)
    # without the offset the same solver leaves the positions carrying it
    plain = solve_nclm(p, iterations=3000, objective="metres", sigma_m=SIGMA)
    assert rmse_m(p, plain.estimates) > 100 * rmse_m(p, res.estimates)


def test_per_anchor_offsets_approach_lm_on_noisy_ranges():
    rng = np.random.default_rng(3)
    delays = rng.normal(0, 0.05, 18)
    p = biased(hall(seed=6, n=18, sigma_m=0.02), per=delays)
    lm = solve_lm(p, objective="metres", sigma_m=SIGMA, range_offsets="per_anchor", offset_prior_sigma_m=0.05)
    res = solve(
        p,
        "N-CSG-TBLS",
        iterations=3000,
        objective="metres",
        sigma_m=SIGMA,
        range_offsets="per_anchor",
        offset_prior_sigma_m=0.05,
        monitor_every=10,
    )
    assert res.usable and res.offsets_m.shape == (18,)
    assert np.abs(res.estimates - lm.estimates).max() < 0.03
    assert np.abs(res.offsets_m - lm.offsets_m).max() < 0.01
    # the conditional σ (each anchor from its own links, neighbours held) is optimistic: never above LM's
    assert np.all(res.offsets_std_m > 0) and np.all(res.offsets_std_m <= lm.offsets_std_m * 1.05)


@pytest.mark.parametrize("mode", ["common", "per_anchor"])
def test_csg_estimates_offsets(mode):
    delays = np.random.default_rng(5).normal(0, 0.05, 16)
    p = biased(hall(), 0.3) if mode == "common" else biased(hall(sigma_m=0.01), per=delays)
    lm = solve_lm(p, objective="metres", sigma_m=SIGMA, range_offsets=mode, offset_prior_sigma_m=0.05)
    res = solve(
        p, "CSG", iterations=2000, objective="metres", sigma_m=SIGMA, range_offsets=mode, offset_prior_sigma_m=0.05
    )
    plain = solve(p, "CSG", iterations=2000, objective="metres", sigma_m=SIGMA)
    assert np.abs(res.offsets_m - lm.offsets_m).max() < 0.03
    assert rmse_m(p, res.estimates) < rmse_m(p, plain.estimates)


def test_offsets_cost_one_float_per_message_or_per_slot():
    p = biased(hall(), 0.3)
    kw = dict(iterations=20, objective="metres", sigma_m=SIGMA, stop=None, quality=False)
    runs = {m: solve_ncsg(p, line_search="TBLS", range_offsets=m, **kw) for m in ("none", "common", "per_anchor")}
    msgs = {m: r.comm.messages for m, r in runs.items()}
    assert msgs["none"] == msgs["common"] == msgs["per_anchor"] > 0  # no extra round
    per_msg = {m: r.comm.bytes / r.comm.messages for m, r in runs.items()}
    K = int(p.graph.degrees.max()) + 1
    assert per_msg["common"] - per_msg["none"] == 8  # the sender's copy of c
    assert per_msg["per_anchor"] - per_msg["none"] == 8 * K  # one offset per slot of the neighbourhood vector


def test_offset_options_are_validated():
    p = hall()
    with pytest.raises(ModelError, match="metres"):
        solve_nclm(p, iterations=2, range_offsets="common")  # squared objective
    with pytest.raises(ModelError, match="range offsets must be one of"):
        solve_ncsg(p, iterations=2, objective="metres", range_offsets="both")
    with pytest.raises(ModelError, match="offset_prior_sigma_m"):
        solve(p, "CSG", iterations=2, objective="metres", range_offsets="per_anchor", offset_prior_sigma_m=0.0)
    with pytest.raises(ModelError, match="no range offsets"):
        solve_line_search_pair(p, iterations=2, objective="metres", range_offsets="common")


def test_a_warm_fit_starts_from_the_carried_common_offset():
    """``initial_offset_m`` (issue 27): N-CLM with no iterations and no LM phase returns its start (0.25 m on every
    anchor; from none: 0); the LM phase from the carried offset and from 0 both end at LM's offset and positions
    (the same fixed point, independently computed)."""
    p = biased(hall(sigma_m=0.02), 0.3)
    kw = {"objective": "metres", "sigma_m": SIGMA, "range_offsets": "common", "quality": False}
    assert np.allclose(solve_nclm(p, iterations=0, refine=False, initial_offset_m=0.25, **kw).offsets_m, 0.25)
    assert np.allclose(solve_nclm(p, iterations=0, refine=False, **kw).offsets_m, 0.0)
    lm = solve_lm(p, objective="metres", sigma_m=SIGMA, range_offsets="common")
    for start in (0.25, None):
        r = solve_nclm(p, iterations=0, initial_offset_m=start, **kw)
        assert r.status == "converged"
        assert abs(r.offsets_m[0] - lm.offsets_m[0]) < 1e-3
        assert np.max(np.abs(r.estimates - lm.estimates)) < 1e-3
