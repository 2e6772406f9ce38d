"""The Perth ionosphere/DCB reproduction (paper 003 §5, Figs. 8-13)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from distnav.algorithms.kalman import central_filter, local_filters
from distnav.algorithms.kalman.ckf import ckf
from distnav.experiments import ckf_ionosphere as exp
from distnav.experiments.common import ExperimentContext, Progress
from distnav.models.gnss.ionosphere import (
    GF_M_PER_DSB_NS,
    IonosphereStateLayout,
    geometry_free_series,
    simulate_geometry_free,
)


def test_perth_network_matches_fig8_description():
    g = exp.perth_network()
    assert g.n_nodes == 13 and g.is_connected
    deg = dict(zip(range(1, 14), g.degrees.tolist(), strict=True))
    fewest, most = min(deg.values()), max(deg.values())
    assert {k for k, v in deg.items() if v == fewest} == {1, 3, 13}
    assert {k for k, v in deg.items() if v == most} == {4, 7, 8, 9}
    assert sorted(int(j) + 1 for j in g.neighbors(0)) == [2, 6]  # "receiver 1 ... to receivers 2 and 6"
    en = exp.PERTH_EAST_NORTH_KM
    assert np.linalg.norm(en[0] - en[2]) == pytest.approx(8.0, abs=0.1)  # "1 and 3 about 8 km"
    d = np.linalg.norm(en[g.links[:, 0]] - en[g.links[:, 1]], axis=1)
    assert d.max() <= 4.0
    lat, lon = exp.perth_positions()
    assert np.rad2deg(lat.mean()) == pytest.approx(-32.0, abs=1e-3)
    assert np.rad2deg(lon.mean()) == pytest.approx(116.0, abs=1e-3)


def test_scenario_pivot_and_visibility():
    geo, layout, series, dyn = exp.perth_scenario(30)
    assert layout.pivot == "G10"
    assert series.n_nodes == 13 and series.n_epochs == 30 and dyn.n_states == 3 + len(layout.svs) - 1
    assert np.all(geo.el_rad[geo.tracked] >= np.deg2rad(10.0))


def test_initial_ratio_sqrt13():
    # equal normals (co-located receivers): exactly √13 up to the tiny system noise of one epoch
    _, _, s, d = exp.perth_scenario(3, colocated=True)
    r, t = exp.initial_ratio(local_filters(d, s).series, central_filter(d, s).series)
    assert r == pytest.approx(np.sqrt(13.0), rel=1e-3)
    # the real Perth layout: all receivers track the same satellites at the start, ratio close to √13
    _, _, s, d = exp.perth_scenario(3)
    assert (s.tracked[0] == s.tracked[0, 0]).all()
    r, _ = exp.initial_ratio(local_filters(d, s).series, central_filter(d, s).series)
    assert r == pytest.approx(np.sqrt(13.0), rel=0.06)


def test_dcb_time_to_threshold_and_box_stats():
    layout = IonosphereStateLayout(("G01", "G02", "G03"), "G02")
    T = 6
    std = np.full((T, 2, 5), np.nan)
    k = GF_M_PER_DSB_NS
    # G01 (column 3) first tracked at epoch 1: node 0 reaches 0.4 ns at epoch 4, node 1 never
    std[1:, 0, 3] = np.array([5.0, 2.0, 0.6, 0.4, 0.3]) * k
    std[1:, 1, 3] = 0.6 * k
    # G03 (column 4) first tracked at epoch 0 and precise at once at epoch 2
    std[:, :, 4] = np.array([9.0, 1.0, 0.1, 0.1, 0.1, 0.1])[:, None] * k
    start = np.array([1, 0, 0])
    out = exp.dcb_time_to_threshold(std, layout, start, interval_s=60.0)
    np.testing.assert_array_equal(out, [[3.0, 2.0], [np.inf, 2.0]])
    st = exp.box_stats(np.array([1.0, 2.0, 3.0, 4.0, 5.0, np.inf]))
    assert (st["min"], st["p25"], st["median"], st["p75"], st["max"], st["never"]) == (1, 2, 3, 4, 5, 1)


def test_ckf_with_many_rounds_equals_central_on_perth_data():
    geo, layout, _, dyn = exp.perth_scenario(15)
    truth, obs, _ = simulate_geometry_free(geo, layout, exp.INTERVAL_S, rng=np.random.default_rng(5))
    ser = geometry_free_series(geo, layout, obs_m=obs)
    g = exp.perth_network()
    c = central_filter(dyn, ser).series
    k = ckf(dyn, ser, graph=g, rounds=300, monitor=False).series
    est = c.estimable[-1, 0]
    np.testing.assert_allclose(
        k.estimates[-1][:, est], np.broadcast_to(c.estimates[-1, 0, est], (13, est.sum())), rtol=1e-6, atol=1e-6
    )
    np.testing.assert_allclose(k.std[-1][:, est], np.broadcast_to(c.std[-1, 0, est], (13, est.sum())), rtol=1e-6)


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("iono")
    ctx = ExperimentContext(out_dir=out, quick=True, progress=Progress(enabled=False), options={"epochs": 90})
    return out, exp.run(ctx)


def test_fig12_ckf_claims(quick_run):
    """Fig. 12: at k_n = 12 the CKF is very close to the central filter (≤ 1.1 × its std), and at k_n = 4 the
    receivers with the fewest neighbours, 1, 3 and 13, are the worst. The maxima fall in the first 1.5 h, so the
    quick length gives the full run's values (1.053; 1, 3, 13)."""
    _, res = quick_run
    assert res["ckf_to_central_ratio_max"]["12"] <= 1.1
    per = np.asarray(res["ckf_to_central_vtec_max_per_receiver"]["4"])
    assert sorted(np.argsort(-per)[:3] + 1) == [1, 3, 13]


def test_quick_reproduction(quick_run):
    tmp_path, res = quick_run
    data = json.loads((tmp_path / "results.json").read_text())
    assert data["initial_local_to_central_ratio"] == pytest.approx(res["initial_local_to_central_ratio"])
    assert data["initial_local_to_central_ratio_colocated"] == pytest.approx(np.sqrt(13), rel=1e-3)
    kmax = data["ckf_to_central_ratio_max"]
    assert set(kmax) == {"4", "6", "12"}
    # more consensus rounds → closer to central; never better than central (eq. (48))
    assert 1.0 <= kmax["12"] <= kmax["6"] <= kmax["4"]
    # the worst receivers under k_n = 4 are among the least connected (1, 3, 13, 12)
    per = np.asarray(data["ckf_to_central_vtec_max_per_receiver"]["4"])
    assert int(np.argmax(per)) + 1 in {1, 3, 12, 13}
    assert int(np.argmin(per)) + 1 in {4, 7, 8, 9}
    central = data["dcb_time_to_0.5ns_min"]["central"]
    assert set(central) >= {"min", "p25", "median", "p75", "max"}
    assert data["ckf_simulated_data"]["fraction_within_3sigma"] > 0.99
    assert "headline" in data
    for f in ("fig11_central_vs_local.png", "fig12_ckf_to_central.png", "fig13_dcb_time_boxplots.png", "ckf_truth.png"):
        assert (tmp_path / f).stat().st_size > 1000
