"""The linearized predictions of benchmarks/bench_uwb_headroom.py (issue 28, sixth session): the Jacobian against
finite differences of the distances, and the predicted RMS error against LM re-fits of range errors drawn the way
the simulator draws them (the median of the samples, a bias per LOS link, per-node delays), not from the covariance
the prediction assembles."""

from __future__ import annotations

import dataclasses
import tempfile

import numpy as np
import pytest

from distnav.algorithms.ranging.lm import solve_lm
from distnav.commands.uwb import solve_range_log
from distnav.experiments.uwb_field import write_hall
from distnav.models.uwb.field_options import subset_measurements
from distnav.models.uwb.hall import PLANT_HARD, simulate_hall
from test_benchmark_runner import _load


@pytest.fixture(scope="module")
def hard_hall():
    h = simulate_hall(np.random.default_rng([34, 3]), None, **PLANT_HARD, known="middle")
    with tempfile.TemporaryDirectory() as d:
        f = write_hall(h, d)
        sol, _, _ = solve_range_log(f["ranges"], f["known"], heights=f["heights"], truth=f["truth"])
    return h, sol.problem


def test_jacobian_is_the_derivative_of_the_distances(hard_hall):
    bench = _load("bench_uwb_headroom")
    h, p = hard_hall
    keep = ~bench.link_truth(p, h)["nlos"]
    J = bench._jacobian(p, keep, common=True)
    x0 = p.truth_m[p.free]
    assert np.all(J[:, -1] == 1.0)

    def dist(x: np.ndarray) -> np.ndarray:
        q = p.truth_m.copy()
        q[p.free] = x
        return np.linalg.norm(q[p.meas_a[keep]] - q[p.meas_b[keep]], axis=1)

    step = 1e-6
    fd = np.stack([(dist(x0 + step * e) - dist(x0 - step * e)) / (2 * step) for e in np.eye(x0.size)], axis=1)
    assert np.max(np.abs(J[:, :-1] - fd)) < 1e-6


def test_predicted_rms_error_matches_lm_refits_of_simulated_errors(hard_hall):
    """200 draws of the LOS links' errors as :func:`simulate_hall` makes them (median of the link's samples of
    N(0, σ²), a bias N(0, los_bias_sd²) per link; with the delays: per-node N(0, sd²) as (δ_a + δ_b)/2 and a common
    0.35 m), each fitted by LM (linear loss, from the truth; a common offset where the delays are in): the RMS error
    over the draws within 12 % of the analytic prediction (its sampling error over 200 draws: about 3–5 %)."""
    bench = _load("bench_uwb_headroom")
    h, p = hard_hall
    t = bench.link_truth(p, h)
    keep = ~t["nlos"]
    cfg = h.config
    rng = np.random.default_rng(9)
    q0 = subset_measurements(p, keep)
    a, b, n = q0.meas_a, q0.meas_b, t["samples"][keep]
    surveyed = ~p.free & p.estimated[:, None]
    held = int(surveyed.sum())
    pred = bench.predictions(p, h, t, np.random.default_rng(1), 10)
    for name, delays in (("crlb_offsets", False), ("crlb_common_lsq", True)):
        sq = []
        for _ in range(200):
            noise = np.array([np.median(rng.normal(0.0, cfg.sigma_m, k)) for k in n])
            e = noise + rng.normal(0.0, cfg.los_bias_sd_m, a.size)
            if delays:
                d = 0.35 + rng.normal(0.0, cfg.antenna_delay_sd_m, p.n_anchors)
                e = e + 0.5 * (d[a] + d[b])
            pos = p.positions_m.copy()  # the held heights as surveyed (with their error)
            pos[surveyed] = p.truth_m[surveyed] + rng.normal(0.0, cfg.height_survey_sd_m, int(surveyed.sum()))
            r = np.linalg.norm(p.truth_m[a] - p.truth_m[b], axis=1) + e
            q = dataclasses.replace(q0, range_m=r, positions_m=pos)
            res = solve_lm(
                q,
                initial_m=np.where(p.free, p.truth_m, pos),
                objective="metres",
                sigma_m=0.1,
                range_offsets="common" if delays else "none",
                quality=False,
            )
            err = np.asarray(res.estimates) - p.truth_m
            sq.append(np.mean(np.sum(err[p.estimated] ** 2, axis=1)))
        assert held > 0
        assert np.sqrt(np.mean(sq)) == pytest.approx(pred[name], rel=0.12), name
