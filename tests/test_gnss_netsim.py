"""The mid-latitude network simulator (models/gnss/netsim) and the bias model on it: truth recovered, SVN49 found."""

from __future__ import annotations

import numpy as np
import pytest

from distnav.commands.gnss_ionosphere import NetworkOptions, network_from_observations
from distnav.errors import ModelError
from distnav.models.gnss.biasmodel import BiasModelOptions
from distnav.models.gnss.constants import mu
from distnav.models.gnss.gfnetwork import BiasFilterOptions, final_dsbs, run_bias_filters, satellite_fit
from distnav.models.gnss.netsim import (
    REALISTIC,
    TECU_L1_M,
    NetworkSimOptions,
    VtecField,
    simulate_network,
    truth_product,
)
from distnav.models.gnss.orbits import synthetic_gps_constellation
from distnav.models.gnss.products import compare_in_datum

TWO = {"SIMA": (49.14, 12.88, 650.0), "SIMB": (50.80, 10.20, 400.0)}


def _sim(**kw: object) -> object:
    """Two stations, 4 h, fixed DSBs; ``kw``: :class:`NetworkSimOptions` fields (and ``stations``)."""
    orbit = synthetic_gps_constellation(epoch="2024-01-10T00:00:00")
    rng = np.random.default_rng(5)
    sat = {s: float(v) for s, v in zip(orbit.svs, rng.normal(0, 3, len(orbit.svs)), strict=True)}
    stations = kw.pop("stations", TWO)
    options = NetworkSimOptions(**{"hours": 4.0, **kw})  # type: ignore[arg-type]
    return orbit, simulate_network(
        orbit,
        "2024-01-10",
        options,
        rng=np.random.default_rng(1),
        stations=stations,  # type: ignore[arg-type]
        satellite_dsb_ns=sat,
        receiver_dsb_ns={"SIMA": 4.0, "SIMB": -6.0},
    )


def test_observables_carry_the_ionosphere_and_the_biases() -> None:
    """Independent of the estimation code: the geometry-free phase follows the slant TEC (its epoch-to-epoch
    change equals the code's up to noise), and the mean of (P2 − P1)/(μ2 − 1) − (geometry-free phase) over an arc
    is the arc's ambiguity term plus −c·DSB/(μ2 − 1) of receiver + satellite."""
    orbit, sim = _sim(multipath_m=0.0, code_sigma_m=(0.01, 0.01), svn49=None)
    o = sim.observations[0]
    f = mu(2) - 1.0
    gp = (o.range_m[2] - o.range_m[1]) / f
    gphi = (o.phase_m[1] - o.phase_m[2]) / f
    j = int(np.argmax(np.isfinite(gp).sum(axis=0)))  # the longest-tracked satellite
    ok = np.isfinite(gp[:, j])
    d_code, d_phase = np.diff(gp[ok, j]), np.diff(gphi[ok, j])
    run = np.diff(np.flatnonzero(ok)) == 1
    assert np.median(np.abs(d_code[run] - d_phase[run])) < 0.05  # 1 cm code noise (/sin θ) …
    assert np.abs(d_code[run] - d_phase[run]).max() < 1.0  # … and no cycle slip within the arc
    assert np.abs(gp[ok, j]).max() > 0.3  # the ionosphere is there (metres of L1 delay)
    # the slant delay stays within the VTEC field's range × the largest slant factor (≈ 3 at 5°)
    fld = VtecField()
    assert (
        np.nanmax(gp[:, j] + 1e-9 * 299792458.0 * (sim.satellite_dsb_ns[o.svs[j]] + 4.0) / f)
        < 3.1 * (fld.night_tecu + fld.day_tecu) * TECU_L1_M * 1.2
    )


def test_bias_model_recovers_the_truth_and_flags_svn49() -> None:
    orbit, sim = _sim()
    # the default (here a quarter of the best-tracked satellite's 480 station-epochs: 120) leaves out the
    # satellites seen briefly in these 4 h and names them
    strict = network_from_observations(sim.observations, orbit, NetworkOptions(l2_code="C2W", interval_s=60.0))
    named = [n for n in strict.notes if n.startswith("not estimated, fewer than 120 ")]
    assert len(named) == 1 and len(strict.layout.svs) >= 10
    data = network_from_observations(
        sim.observations,
        orbit,
        NetworkOptions(l2_code="C2W", interval_s=60.0, model=BiasModelOptions(min_satellite_obs=30)),
    )
    assert set(strict.layout.svs) < set(data.layout.svs)
    assert all(s in named[0] for s in set(data.layout.svs) - set(strict.layout.svs))
    assert data.ionosphere == "common"  # 200 km apart: one regional layer
    series, _ = run_bias_filters(data, BiasFilterOptions(local=False))
    c = series[0]
    sat, rx, sd = final_dsbs(data, c)
    names = [f"rx:{r}" for r in data.stations] + list(data.layout.svs)
    r = compare_in_datum(sat, rx, truth_product(sim), exclude=["G01"])
    assert r["n"] >= 12
    assert r["rms_zero_mean_ns"] < 0.6  # 4 h, two receivers
    assert max(abs(v) for v in r["receivers"]["difference_ns"].values()) < 0.7
    z = np.array([d / sd[s] for s, d in r["difference_ns"].items()])
    assert np.sqrt(np.mean(z**2)) < 3.0  # the realistic σ is not wildly optimistic
    # the Precision payload: its diagonal is the formal σ², the a-posteriori σ the realistic one, and the
    # zero-mean datum makes the sum of the satellite DSBs a constant (no variance)
    prec = c.precision
    assert prec is not None and prec.kind == "centralized" and prec.covariance.shape == (1, len(names), len(names))
    np.testing.assert_allclose(prec.std()[0], c.dsb_std_ns[-1], rtol=1e-9, equal_nan=True)
    np.testing.assert_allclose(
        prec.std(a_posteriori=True)[0], c.dsb_std_ns[-1] * c.realistic_factor, rtol=1e-9, equal_nan=True
    )
    C = prec.covariance[0][len(data.stations) :, len(data.stations) :]
    ok = np.isfinite(np.diag(C))
    assert abs(C[np.ix_(ok, ok)].sum()) < 1e-9 * np.trace(C[np.ix_(ok, ok)])
    worst = satellite_fit(data, c).worst()
    assert worst is not None and worst[0] == "G01"
    # without the elevation-dependent bias G01 is an ordinary satellite, below the median
    orbit, clean = _sim(svn49=None)
    data = network_from_observations(
        clean.observations,
        orbit,
        NetworkOptions(l2_code="C2W", interval_s=60.0, model=BiasModelOptions(min_satellite_obs=30)),
    )
    fit = satellite_fit(data, run_bias_filters(data, BiasFilterOptions(local=False))[0][0])
    assert fit.code_rms_m is not None
    g01 = float(fit.code_rms_m[data.layout.svs.index("G01")])
    assert g01 < 0.8 * worst[1] and g01 < np.nanmedian(fit.code_rms_m) * 1.1
    assert fit.as_dict()["worst_fitting"]["satellite"] != "G01"


def test_gross_errors_are_injected_and_screened() -> None:
    orbit, sim = _sim(gross_fraction=0.01, gross_station="SIMB")
    assert sim.gross_errors["SIMB"] > 20 and "SIMA" not in sim.gross_errors
    data = network_from_observations(sim.observations, orbit, NetworkOptions(l2_code="C2W", interval_s=60.0))
    removed = int(data.levelled["SIMB"].removed.sum())
    assert removed >= 0.9 * sim.gross_errors["SIMB"]


def test_bad_options() -> None:
    orbit = synthetic_gps_constellation()
    with pytest.raises(ModelError, match="gross_fraction"):
        simulate_network(orbit, "2024-01-10", NetworkSimOptions(gross_fraction=0.7), rng=np.random.default_rng(0))
    with pytest.raises(ModelError, match="no DSB given"):
        simulate_network(
            orbit, "2024-01-10", NetworkSimOptions(hours=1), rng=np.random.default_rng(0), receiver_dsb_ns={"SIMA": 1.0}
        )


def test_ckf_receivers_screen_their_own_innovations() -> None:
    """Raw code (no levelling, no per-arc screening) with 1 % gross P1 errors at one receiver: with
    ``innovation_level`` every CKF node w-tests its own predicted residuals and rejects them before the consensus;
    the injected errors are found at that receiver and the DSBs come closer to the truth."""
    from distnav.commands.gnss import default_graph

    orbit, sim = _sim(hours=2.0, gross_fraction=0.01, gross_station="SIMB", svn49=None)
    data = network_from_observations(
        sim.observations, orbit, NetworkOptions(l2_code="C2W", interval_s=60.0, levelling=False, screen=False)
    )
    graph = default_graph(data.positions_ecef_m, data.stations)
    truth = truth_product(sim)
    rms = {}
    for level in (None, 0.001):
        series, _ = run_bias_filters(data, BiasFilterOptions(local=False, kn=20, innovation_level=level), graph=graph)
        ckf = series[1]
        assert ckf.label == "ckf:SIMA"
        sat, rx, _ = final_dsbs(data, ckf)
        rms[level] = compare_in_datum(sat, rx, truth)["rms_zero_mean_ns"]
        if level is not None:
            it = ckf.innovation_tests
            removed = it.node[np.asarray(it.removed, np.int64)]
            assert (removed == 1).sum() >= 5  # found at SIMB, which holds the errors …
            assert (removed == 1).sum() > 3 * (removed == 0).sum()  # … far more than at the clean SIMA
    assert rms[0.001] < rms[None]


def _arc_gf_rms_m(o: object) -> float:
    """Median over arcs of the RMS of (geometry-free code − geometry-free phase − its arc mean): what multipath
    and code noise leave after levelling (computed here from the observations, not by the levelling code)."""
    f = mu(2) - 1.0
    d = (o.range_m[2] - o.range_m[1]) / f - (o.phase_m[1] - o.phase_m[2]) / f  # type: ignore[attr-defined]
    out = []
    for j in range(d.shape[1]):
        ok = np.isfinite(d[:, j])
        edges = np.flatnonzero(np.diff(np.concatenate([[0], ok.astype(int), [0]])))
        for a, b in zip(edges[::2], edges[1::2], strict=True):
            if b - a >= 60:
                out.append(np.std(d[a:b, j]))
    return float(np.median(out))


def test_realistic_preset_is_noisier_but_consistent() -> None:
    """The realistic preset: the TIDs and irregularities are ionosphere (the geometry-free code follows the phase
    epoch to epoch as before, no slips), the multipath left after levelling is larger, the second station's
    (×1.4) larger than the first's, and part of the multipath differs from one day to the next."""
    orbit, plain = _sim(code_sigma_m=(0.0, 0.0), svn49=None)  # multipath only
    _, real = _sim(**{**REALISTIC, "code_sigma_m": (0.0, 0.0), "svn49": None})
    o = real.observations[0]
    f = mu(2) - 1.0
    gp, gphi = (o.range_m[2] - o.range_m[1]) / f, (o.phase_m[1] - o.phase_m[2]) / f
    step = np.diff(gp - gphi, axis=0)
    assert np.nanmedian(np.abs(step)) < 1.0 and np.nanmax(np.abs(np.diff(gphi, axis=0))) < 0.5
    rms_plain = [_arc_gf_rms_m(x) for x in plain.observations]
    rms_real = [_arc_gf_rms_m(x) for x in real.observations]
    assert rms_real[0] > 1.2 * rms_plain[0] and rms_real[1] > 1.2 * rms_real[0]
    # the multipath of two "days" (different rng) with noise off: identical with f = 0, different with f = 0.6
    quiet = {"code_sigma_m": (0.0, 0.0), "svn49": None, "multipath_el_scale_deg": 20.0}

    def code(seed: int, fraction: float) -> np.ndarray:
        s = simulate_network(
            orbit,
            "2024-01-10",
            NetworkSimOptions(hours=1.0, multipath_day_fraction=fraction, **quiet),
            rng=np.random.default_rng(seed),
            stations=TWO,
            satellite_dsb_ns=dict.fromkeys(orbit.svs, 0.0),
            receiver_dsb_ns={"SIMA": 0, "SIMB": 0},
        )
        return s.observations[0].range_m[1]

    assert np.nanmax(np.abs(code(1, 0.0) - code(2, 0.0))) < 1e-9
    assert np.nanmedian(np.abs(code(1, 0.6) - code(2, 0.6))) > 0.01
    with pytest.raises(ModelError, match="multipath_day_fraction"):
        simulate_network(
            orbit, "2024-01-10", NetworkSimOptions(hours=1, multipath_day_fraction=1.5), rng=np.random.default_rng(0)
        )


def test_arc_sigma_scale_counts_effective_observations() -> None:
    """One arc of 60 epochs over 59 min with a 10-min correlation holds 5.9 effective observations: σ × √(60/5.9);
    an arc shorter than the correlation time is one observation (σ × √n); no arc (−1) or no correlation: 1."""
    from distnav.models.gnss.gfnetwork import arc_sigma_scale

    t = 60.0 * np.arange(70)
    arc = np.full((70, 2), -1)
    arc[:60, 0] = 0
    arc[60:65, 1] = 1
    sc = arc_sigma_scale(arc, t, 600.0)
    np.testing.assert_allclose(sc[:60, 0], np.sqrt(60 / 5.9))
    np.testing.assert_allclose(sc[60:65, 1], np.sqrt(5.0))
    assert (sc[arc < 0] == 1.0).all() and (arc_sigma_scale(arc, t, 0.0) == 1.0).all()


def test_station_weights_follow_the_stations_noise() -> None:
    """SIMB with 2× the code noise and multipath of SIMA: with one common ionosphere ("auto") its σ factor from its
    own levelling residuals is larger (the ratio near 2); "off" or per-station ionospheres ("auto") leave the σ."""
    from distnav.commands.gnss_ionosphere import NetworkOptions, network_from_observations
    from distnav.models.gnss.biasmodel import BiasModelOptions

    orbit, sim = _sim(hours=2.0, station_noise_scale=(1.0, 2.0))
    on = network_from_observations(sim.observations, orbit, NetworkOptions(l2_code="C2W", interval_s=60.0))
    off = network_from_observations(
        sim.observations,
        orbit,
        NetworkOptions(l2_code="C2W", interval_s=60.0, model=BiasModelOptions(station_weighting="off")),
    )
    per = network_from_observations(
        sim.observations,
        orbit,
        NetworkOptions(l2_code="C2W", interval_s=60.0, model=BiasModelOptions(ionosphere="per-receiver")),
    )
    ratio = on.sigma_m / off.sigma_m
    tr = on.geometry.tracked
    fa, fb = float(np.median(ratio[:, 0][tr[:, 0]])), float(np.median(ratio[:, 1][tr[:, 1]]))
    assert 1.6 < fb / fa < 2.4 and abs(fa * fb - 1.0) < 1e-9  # geometric mean 1
    assert any(n.startswith("model choice: station σ factors") for n in on.notes)
    assert not any(n.startswith("model choice: station σ factors") for n in off.notes + per.notes)
    np.testing.assert_array_equal(per.sigma_m, off.sigma_m)
