"""Regional single-layer ionosphere + between-satellite DCB model (paper 003 §5.1, eq. (49))."""

from __future__ import annotations

import numpy as np
import pytest

from distnav.algorithms.kalman import central_filter, kalman_filter, local_filters
from distnav.errors import ModelError
from distnav.models.gnss.constants import C_M_S, F_L1_HZ, F_L2_HZ
from distnav.models.gnss.geometry import pierce_zenith_angle
from distnav.models.gnss.ionosphere import (
    GF_M_PER_DSB_NS,
    GF_SIGMA_ZENITH_M,
    TECU_L1_M,
    GeometryFreeSeries,
    GeometryOptions,
    IonosphereStateLayout,
    choose_pivot,
    dcb_ns_from_gf_m,
    differenced_observations,
    geometry_free_m,
    geometry_free_series,
    gf_m_from_dcb_ns,
    ionosphere_coefficients,
    ionosphere_dynamics,
    ionosphere_geometry,
    simulate_geometry_free,
)
from distnav.models.gnss.orbits import gps_seconds, synthetic_gps_constellation

LAT0, LON0 = np.deg2rad(-32.0), np.deg2rad(116.0)


def _geometry(
    n_epochs: int = 12, n_rx: int = 3, spread_km: float = 5.0, ionosphere: str = "common", step_s: float = 60.0
):
    const = synthetic_gps_constellation()
    t = float(gps_seconds(np.datetime64("2016-06-02T00:00:00", "ns"))) + step_s * np.arange(n_epochs)
    off = np.linspace(-spread_km, spread_km, n_rx) * 1e3 / 6.371e6
    geo = ionosphere_geometry(
        const,
        t,
        lat_rad=LAT0 + off,
        lon_rad=LON0 + off[::-1],
        options=GeometryOptions(mask_deg=10.0, ionosphere=ionosphere),
    )
    seen = np.asarray(geo.tracked.any(axis=(0, 1))).tolist()
    svs = tuple(s for s, k in zip(geo.svs, seen, strict=True) if k)
    geo = ionosphere_geometry(
        const,
        t,
        lat_rad=LAT0 + off,
        lon_rad=LON0 + off[::-1],
        svs=svs,
        options=GeometryOptions(mask_deg=10.0, ionosphere=ionosphere),
    )
    return geo


# ----------------------------------------------------------------------------------------------- constants, units
def test_paper_sigma_is_geometry_free_of_30cm_code():
    # paper 003 §5.1: 65.6 cm is the zenith std of the GPS geometry-free code; σ_P = 30 cm on each of P1, P2
    mu2 = (F_L1_HZ / F_L2_HZ) ** 2
    assert GF_SIGMA_ZENITH_M == pytest.approx(np.sqrt(2) * 0.30 / (mu2 - 1), rel=2e-3)


def test_unit_conversions():
    assert TECU_L1_M == pytest.approx(0.1624, abs=1e-4)
    mu2 = (F_L1_HZ / F_L2_HZ) ** 2
    assert GF_M_PER_DSB_NS == pytest.approx(C_M_S * 1e-9 / (mu2 - 1))
    assert dcb_ns_from_gf_m(gf_m_from_dcb_ns(3.7)) == pytest.approx(3.7)
    # sign: a satellite DSB C1−C2 of +1 ns (OSB1 − OSB2, biases add to the observations) lowers P2 − P1
    p1, p2 = 2.0e7 + C_M_S * 1e-9 * 1.0, 2.0e7
    assert geometry_free_m(p1, p2) == pytest.approx(gf_m_from_dcb_ns(1.0))


def test_coefficients_zenith_and_north():
    # eq. (49): zenith line of sight at the reference point → a_o = 1, gradients 0
    a = ionosphere_coefficients(LAT0, LON0, 0.0, LAT0, LON0)
    np.testing.assert_allclose(a, [1.0, 0.0, 0.0])
    # a pierce point north-east of the reference with zenith angle z': (Δφ/cos z', Δψ/cos z')
    z = float(pierce_zenith_angle(np.deg2rad(30.0)))
    a = ionosphere_coefficients(LAT0 + 0.01, LON0 + 0.02, z, LAT0, LON0)
    np.testing.assert_allclose(a, np.array([1.0, 0.01, 0.02]) / np.cos(z))
    # longitude difference across the date line is wrapped
    a = ionosphere_coefficients(0.0, np.pi - 0.01, 0.0, 0.0, -np.pi + 0.01)
    assert a[2] == pytest.approx(-0.02)


def test_geometry_mask_and_coefficients_consistent():
    geo = _geometry()
    el = geo.el_rad[geo.tracked]
    assert np.all(el >= np.deg2rad(10.0))
    a = geo.coefficients[geo.tracked]
    z = pierce_zenith_angle(el)
    np.testing.assert_allclose(a[:, 0], 1.0 / np.cos(z))
    assert np.all(geo.coefficients[~geo.tracked] == 0.0)
    # pierce points lie towards the satellite's azimuth: sign(a_φ) = sign(cos az), sign(a_ψ) = sign(sin az)
    # (hundreds of km of offset at these elevations against a 5-km receiver spread)
    az = geo.az_rad[geo.tracked]
    ns, ew = np.abs(np.cos(az)) > 0.2, np.abs(np.sin(az)) > 0.2
    assert ns.sum() > 10 and ew.sum() > 10
    np.testing.assert_array_equal(np.sign(a[ns, 1]), np.sign(np.cos(az[ns])))
    np.testing.assert_array_equal(np.sign(a[ew, 2]), np.sign(np.sin(az[ew])))


# ----------------------------------------------------------------------------------------------- normals
def _random_series(rng, with_obs=True, pivot_seen=True, per_receiver=False):
    T, n, S = 4, 3, 7
    svs = tuple(f"G{k:02d}" for k in range(1, S + 1))
    layout = IonosphereStateLayout(svs, "G03", n_ionospheres=3 if per_receiver else 1)
    coef = rng.normal(size=(T, n, S, 3))
    sig = rng.uniform(0.5, 3.0, size=(T, n, S))
    tracked = rng.random((T, n, S)) < 0.7
    tracked[:, :, :2] = True
    tracked[1, 2] = False
    tracked[1, 2, 5] = True  # one satellite alone: no difference
    if not pivot_seen:
        tracked[:, :, 2] = False
    else:
        tracked[2, 0, 2] = False  # pivot not tracked by node 0 at epoch 2
    obs = rng.normal(size=(T, n, S)) * 5 if with_obs else None
    groups = np.array([2, 0, 1]) if per_receiver else None
    return GeometryFreeSeries(layout, coef, sig, obs_m=obs, tracked=tracked, groups=groups), layout


@pytest.mark.parametrize(("reference", "per_receiver"), [("pivot", False), ("first", False), ("pivot", True)])
def test_closed_form_normals_equal_explicit_differences(rng, reference, per_receiver):
    ser, _ = _random_series(rng, per_receiver=per_receiver)
    ref = differenced_observations(ser, reference=reference)
    for t in range(ser.n_epochs):
        N, r = ser.normals(t)
        N2, r2 = ref.normals(t)
        np.testing.assert_allclose(N, N2, atol=1e-10)
        np.testing.assert_allclose(r, r2, atol=1e-10)
        # the whitened rows reproduce the same normals
        A, y, node = ser.observations(t)
        for i in range(ser.n_nodes):
            k = node == i
            np.testing.assert_allclose(A[k].T @ A[k], N[i], atol=1e-10)
            np.testing.assert_allclose(A[k].T @ y[k], r[i], atol=1e-10)
    # node 2 at epoch 1 tracks one satellite: nothing
    assert np.all(ser.normals(1)[0][2] == 0)


def test_normals_of_a_node_subset(rng):
    ser, _ = _random_series(rng)
    N, r = ser.normals(2)
    N1, r1 = ser.normals(2, np.array([2, 0]))
    np.testing.assert_array_equal(N1, N[[2, 0]])
    np.testing.assert_array_equal(r1, r[[2, 0]])


def test_receiver_bias_is_eliminated(rng):
    ser, layout = _random_series(rng)
    y = rng.normal(size=(4, 3, 7))
    s1 = GeometryFreeSeries(
        layout, ser._a, 1 / np.sqrt(np.where(ser._w > 0, ser._w, 1.0)), obs_m=y, tracked=ser.tracked
    )
    s2 = GeometryFreeSeries(
        layout,
        ser._a,
        1 / np.sqrt(np.where(ser._w > 0, ser._w, 1.0)),
        obs_m=y + np.array([10.0, -3.0, 7.0])[None, :, None],
        tracked=ser.tracked,
    )
    for t in range(4):
        np.testing.assert_allclose(s1.normals(t)[1], s2.normals(t)[1], atol=1e-9)


# ----------------------------------------------------------------------------------------------- dynamics, filters
def test_dynamics_random_walk_and_constant_dcbs():
    layout = IonosphereStateLayout(("G01", "G02", "G10"), "G10")
    dyn = ionosphere_dynamics(layout, 60.0)
    S = dyn.noise_cov_at(1)
    np.testing.assert_allclose(np.diag(S), [1e-6 * 60, 25e-6 * 60, 25e-6 * 60, 0, 0])
    assert np.count_nonzero(S - np.diag(np.diag(S))) == 0
    assert layout.state_names()[3:] == ["dcb_gf_m:G01-G10", "dcb_gf_m:G02-G10"]
    assert ionosphere_dynamics(IonosphereStateLayout(("G01", "G02"), "G01", n_ionospheres=2), 30.0).n_states == 7


def test_central_information_filter_equals_covariance_form_on_differences():
    geo = _geometry(n_epochs=10, n_rx=3)
    layout = IonosphereStateLayout(geo.svs, choose_pivot(geo.svs, geo.tracked))
    rng = np.random.default_rng(3)
    truth, obs, _ = simulate_geometry_free(geo, layout, 60.0, rng=rng)
    ser = geometry_free_series(geo, layout, obs_m=obs)
    dyn = ionosphere_dynamics(layout, 60.0)
    info = central_filter(dyn, ser).series
    cov = kalman_filter(dyn, differenced_observations(ser)).series
    last = info.estimable[-1, 0]
    assert last[:3].all()
    np.testing.assert_allclose(info.estimates[-1, 0, last], cov.estimates[-1, 0, last], rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(info.std[-1, 0, last], cov.std[-1, 0, last], rtol=1e-6)


def test_colocated_receivers_start_sqrt_n_better():
    # paper 003 §5.3: equal normals → the central std is √n times smaller at the start
    geo = _geometry(n_epochs=3, n_rx=5, spread_km=0.0)
    layout = IonosphereStateLayout(geo.svs, choose_pivot(geo.svs, geo.tracked))
    ser = geometry_free_series(geo, layout)
    dyn = ionosphere_dynamics(layout, 60.0)
    c = central_filter(dyn, ser).series.std
    loc = local_filters(dyn, ser).series.std
    t = int(np.argmax(np.isfinite(loc[:, 0, 0])))
    np.testing.assert_allclose(loc[t, :, :3] / c[t, 0, :3], np.sqrt(5), rtol=1e-3)


def test_simulated_errors_consistent_with_std():
    # Monte Carlo: standardized central-filter errors over independent realizations have unit variance
    geo = _geometry(n_epochs=40, n_rx=3, step_s=120.0)
    layout = IonosphereStateLayout(geo.svs, choose_pivot(geo.svs, geo.tracked))
    dyn = ionosphere_dynamics(layout, 120.0)
    z = []
    for seed in range(40):
        truth, obs, dsb = simulate_geometry_free(geo, layout, 120.0, rng=np.random.default_rng(seed))
        s = central_filter(dyn, geometry_free_series(geo, layout, obs_m=obs)).series
        est = s.estimable[-1, 0]
        z.append(((s.estimates[-1, 0] - truth[-1]) / s.std[-1, 0])[est][:8])
        # truth DCBs are the satellite DSB differences
        col = layout.dcb_column()
        k = int(np.flatnonzero(col >= 0)[0])
        assert dcb_ns_from_gf_m(truth[0, col[k]]) == pytest.approx(dsb[k] - dsb[layout.pivot_index])
    zz = np.concatenate(z)
    assert 0.7 < zz.var() < 1.35  # 320 values: 5σ band of the variance ≈ ±0.4
    assert abs(zz.mean()) < 0.3


def test_per_receiver_ionospheres():
    geo = _geometry(n_epochs=4, n_rx=2, ionosphere="per-receiver")
    np.testing.assert_array_equal(geo.groups, [0, 1])
    layout = IonosphereStateLayout(geo.svs, geo.svs[0], n_ionospheres=2)
    ser = geometry_free_series(geo, layout)
    N, _ = ser.normals(1)
    assert np.all(N[0, 3:6, :] == 0) and np.all(N[1, 0:3, :] == 0)
    assert np.any(N[0, 0:3, 0:3] != 0) and np.any(N[1, 3:6, 3:6] != 0)


# ----------------------------------------------------------------------------------------------- validation
def test_choose_pivot():
    tracked = np.zeros((2, 1, 3), bool)
    tracked[:, 0, 1] = True
    assert choose_pivot(("G01", "G10", "G12"), tracked) == "G10"
    tracked[:, 0, 1] = False
    tracked[0, 0, 2] = True
    assert choose_pivot(("G01", "G10", "G12"), tracked) == "G12"
    with pytest.raises(ModelError, match="no satellite is tracked"):
        choose_pivot(("G01", "G10"), np.zeros((2, 1, 2), bool))


def test_validation_errors():
    with pytest.raises(ModelError, match="pivot satellite G10"):
        IonosphereStateLayout(("G01", "G02"), "G10")
    with pytest.raises(ModelError, match="at least two satellites"):
        IonosphereStateLayout(("G01",), "G01")
    layout = IonosphereStateLayout(("G01", "G02", "G03"), "G01")
    with pytest.raises(ModelError, match="coefficients must have shape"):
        GeometryFreeSeries(layout, np.zeros((2, 1, 3)), np.ones((2, 1, 3)))
    with pytest.raises(ModelError, match="coefficients for 4 satellites"):
        GeometryFreeSeries(layout, np.zeros((2, 1, 4, 3)), np.ones((2, 1, 4)))
    with pytest.raises(ModelError, match="sigma_m must have shape"):
        GeometryFreeSeries(layout, np.zeros((2, 1, 3, 3)), np.ones((2, 3)))
    with pytest.raises(ModelError, match="obs_m must have shape"):
        GeometryFreeSeries(layout, np.zeros((2, 1, 3, 3)), np.ones((2, 1, 3)), obs_m=np.ones(3))
    with pytest.raises(ModelError, match="tracked must have shape"):
        GeometryFreeSeries(layout, np.zeros((2, 1, 3, 3)), np.ones((2, 1, 3)), tracked=np.ones(3, bool))
    with pytest.raises(ModelError, match="groups must be"):
        GeometryFreeSeries(layout, np.zeros((2, 1, 3, 3)), np.ones((2, 1, 3)), groups=np.array([1]))
    with pytest.raises(ModelError, match="sampling interval must be positive"):
        ionosphere_dynamics(layout, 0.0)
    const = synthetic_gps_constellation()
    with pytest.raises(ModelError, match="'common' or 'per-receiver'"):
        ionosphere_geometry(const, [0.0], lat_rad=[0.0], lon_rad=[0.0], options=GeometryOptions(ionosphere="global"))
    with pytest.raises(ModelError, match="elevation mask"):
        ionosphere_geometry(const, [0.0], lat_rad=[0.0], lon_rad=[0.0], options=GeometryOptions(mask_deg=95.0))
    with pytest.raises(ModelError, match="receiver ZZZZ: position"):
        ionosphere_geometry(const, [0.0], receivers_ecef_m=np.zeros((1, 3)), names=["ZZZZ"])
    with pytest.raises(ModelError, match="lat_rad/lon_rad or receivers_ecef_m"):
        ionosphere_geometry(const, [0.0])
    with pytest.raises(ModelError, match="reference must be"):
        differenced_observations(
            GeometryFreeSeries(layout, np.zeros((1, 1, 3, 3)), np.ones((1, 1, 3))), reference="best"
        )


def test_docs_example_runs(capsys):
    import re
    from pathlib import Path

    text = (Path(__file__).resolve().parents[1] / "docs" / "ionosphere.md").read_text(encoding="utf-8")
    blocks = re.findall(r"```python\n(.*?)```", text, flags=re.S)
    assert blocks
    for block in blocks:
        exec(compile(block, "docs/ionosphere.md", "exec"), {})  # noqa: S102 - our own documentation example
    assert capsys.readouterr().out.strip()
