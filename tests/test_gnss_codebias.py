"""Satellite code-bias model of paper 000 §5: normals vs the explicit eqs. (24)/(26), S-basis, BLUE vs truth
(Monte Carlo), recursive solution, compressed form, estimability errors, real RINEX input."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from distnav.errors import ModelError
from distnav.formats.gnss.rinex import read_code_observations, read_navigation
from distnav.models.gnss.codebias import CodeBiasData, combination_sigma, sat_bias_combination
from distnav.models.gnss.codebias_build import (
    CodeBiasSimulation,
    codebias_data_from_observations,
    simulate_codebias_data,
)
from distnav.models.gnss.geometry import geodetic_to_ecef
from distnav.models.gnss.observables import codebias_coefficients
from distnav.models.gnss.orbits import synthetic_gps_constellation


def _network(rng: np.random.Generator, n: int = 5, epochs: int = 60, lat_span: float = 40.0) -> CodeBiasData:
    sc = synthetic_gps_constellation()
    lat = np.deg2rad(rng.uniform(-lat_span, lat_span, n))
    lon = np.deg2rad(rng.uniform(-30, 30, n))
    t = sc.epoch_gps_s + np.arange(epochs) * 30.0
    return simulate_codebias_data(geodetic_to_ecef(lat, lon, 0.0), sc, t, sc.l5_svs, rng=rng)


def _visible_only(d: CodeBiasData) -> CodeBiasData:
    keep = np.nonzero(d.observed.any(axis=(0, 1)))[0]
    return CodeBiasData(
        d.stations,
        tuple(d.svs[k] for k in keep),
        d.t_gps_s,
        d.y_m[..., keep],
        d.sigma_m[..., keep],
        d.reference,
        None,
        None if d.truth_m is None else d.truth_m[keep],
        d.positions_ecef_m,
    )


def test_normals_equal_explicit_design_eq24_26(rng: np.random.Generator) -> None:
    d = _network(rng)
    N, r = d.node_normals()
    for i in range(d.n_stations):
        A, R, y = d.node_system(i)
        W = np.linalg.inv(R)
        assert np.allclose(A.T @ W @ A, N[i], atol=1e-9)
        assert np.allclose(A.T @ W @ y, r[i], atol=1e-6)
    # the reference station is undifferenced (rows of I_p), the others are differenced (rows sum to 0)
    A0, _, _ = d.node_system(d.reference)
    A1, _, _ = d.node_system(1)
    assert np.all(A0.sum(axis=1) == 1) and np.allclose(A1.sum(axis=1), 0)


def test_pivot_choice_does_not_matter(rng: np.random.Generator) -> None:
    d = _network(rng, n=3, epochs=20)
    N, r = d.node_normals()
    i = 1
    Nl = np.zeros_like(N[i])
    rl = np.zeros_like(r[i])
    for t in range(d.n_epochs):
        vis = np.nonzero(d.observed[i, t])[0]
        if vis.size < 2:
            continue
        m = vis.size  # last visible satellite as pivot: rows e_k − e_last
        Dt = np.hstack([np.eye(m - 1), -np.ones((m - 1, 1))])
        A = Dt @ np.eye(d.n_sats)[vis]
        R = Dt @ np.diag(d.sigma_m[i, t, vis] ** 2) @ Dt.T
        Nl += A.T @ np.linalg.solve(R, A)
        rl += A.T @ np.linalg.solve(R, Dt @ d.y_m[i, t, vis])
    assert np.allclose(Nl, N[i], atol=1e-9) and np.allclose(rl, r[i], atol=1e-6)


def test_blue_against_truth_monte_carlo() -> None:
    """x̂ − x_true normalized by the formal σ: mean square ≈ 1 over replicas (χ²/dof), the S-basis truth being
    x_s = b^s + b_ref (satellite combination plus the reference receiver's)."""
    rng = np.random.default_rng(7)
    z2: list[float] = []
    for _ in range(25):
        d = _visible_only(_network(rng, n=6, epochs=40, lat_span=50.0))
        sol = d.centralized()
        assert d.truth_m is not None
        z2.extend(((sol.x_m - d.truth_m) / sol.sigma_m) ** 2)
    assert 0.75 < float(np.mean(z2)) < 1.3


def test_sbasis_truth_definition(rng: np.random.Generator) -> None:
    d = _network(rng, n=2, epochs=2)
    c = codebias_coefficients()
    assert np.allclose(d.truth_m, d.meta["sat_biases_m"] @ c + d.meta["rx_biases_m"][0] @ c)
    # DSB form: b = −c₂(d₁ − d₂) − (d₁ − d₃) equals c·d for any d
    dd = rng.normal(size=(10, 3))
    assert np.allclose(sat_bias_combination(dd[:, 0] - dd[:, 1], dd[:, 0] - dd[:, 2]), dd @ c)


def test_recursive_solution_ends_at_centralized(rng: np.random.Generator) -> None:
    d = _visible_only(_network(rng, n=6, epochs=80))
    x, s = d.recursive_solution()
    sol = d.centralized()
    assert np.allclose(x[-1], sol.x_m, atol=1e-9) and np.allclose(s[-1], sol.sigma_m, atol=1e-12)
    ok = np.isfinite(s[10]) & np.isfinite(s[-1])
    assert np.all(s[-1][ok] < s[10][ok])  # precision improves with epochs
    assert sol.x_ns == pytest.approx(sol.x_m / 0.299792458)
    # the first 40 epochs alone give the recursive solution after epoch 40
    w = d.window(slice(0, 40))
    xw, sw = w.recursive_solution()
    assert np.allclose(xw[-1], x[39], equal_nan=True) and np.allclose(sw[-1], s[39], equal_nan=True)


def test_compressed_problem_is_equivalent(rng: np.random.Generator) -> None:
    d = _network(rng, n=4, epochs=30)
    N, r = d.node_normals()
    A, y = d.compressed_problem()
    assert A.shape == (4, d.n_sats, d.n_sats)
    assert np.allclose(np.einsum("nmp,nmq->npq", A, A), N, atol=1e-8)
    assert np.allclose(np.einsum("nmp,nm->np", A, y), r, atol=1e-6)


def test_combination_sigma_is_propagated() -> None:
    c = codebias_coefficients()
    assert combination_sigma(np.pi / 2, 0.2, "constant") == pytest.approx(0.2 * np.sqrt(c @ c))
    assert np.sqrt(c @ c) == pytest.approx(1.6, abs=0.01)


def _data(y: np.ndarray, ref: int = 0) -> CodeBiasData:
    n, T, p = y.shape
    return CodeBiasData(
        tuple(f"R{i}" for i in range(n)),
        tuple(f"G{k + 1:02d}" for k in range(p)),
        np.arange(T, dtype=float),
        y,
        np.where(np.isfinite(y), 0.3, np.nan),
        ref,
    )


def test_estimability_errors_name_the_culprit() -> None:
    nan = np.nan
    # station R2 sees only G03/G04, nobody else does: it shares no satellites with the network
    y = np.array([[[1, 2, nan, nan]], [[1, 2, nan, nan]], [[nan, nan, 3, 4]]], dtype=float)
    with pytest.raises(ModelError, match="station R2 shares no satellites"):
        _data(y).check()
    # R2 sees a single satellite at every epoch: no between-satellite difference at all
    y = np.array(
        [
            [[1, 2, nan, nan]],
            [[nan, 2, 3, nan]],
            [
                [nan, 2, nan, nan],
            ],
        ],
        dtype=float,
    )
    with pytest.raises(ModelError, match="station R2 never observes two satellites"):
        _data(y).check()
    # nobody observes G04: its bias is not estimable, and the message names it
    y = np.array([[[1, 2, nan, nan]], [[nan, 2, 3, nan]]], dtype=float)
    with pytest.raises(ModelError, match="not estimable.*G04"):
        _data(y).centralized()
    assert _data(y).unestimable() == ["G04"]
    sub = _data(y).estimable_subset()
    assert sub.svs == ("G01", "G02", "G03") and sub.y_m.shape == (2, 1, 3)
    sub.check()
    y = np.array([[[nan, nan, nan, nan]], [[nan, 2, 3, nan]]], dtype=float)
    with pytest.raises(ModelError, match="reference station R0 has no observation"):
        _data(y).check()


def test_data_validation() -> None:
    y = np.ones((2, 3, 4))
    with pytest.raises(ModelError, match="stations, epochs, satellites"):
        CodeBiasData(("a",), ("G01",), np.arange(3.0), y, y)
    with pytest.raises(ModelError, match="reference station index 5"):
        CodeBiasData(("a", "b"), tuple(f"G{k}" for k in range(4)), np.arange(3.0), y, y, 5)
    s = y.copy()
    s[1, 2, 3] = np.nan
    with pytest.raises(ModelError, match="station b, epoch 2, G3: observation without a positive"):
        CodeBiasData(("a", "b"), tuple(f"G{k}" for k in range(4)), np.arange(3.0), y, s)
    with pytest.raises(ModelError, match="station index 9"):
        _data(y).node_system(9)


def test_real_rinex_zegv_rovn(shared_data: Path) -> None:
    d = shared_data / "gnss/nl_2021001_short_network_snapshot"
    obs = [read_code_observations(d / "zegv0010.21o"), read_code_observations(d / "rovn0010.21o")]
    nav = read_navigation(d / "cbw10010.21n.gz", max_age_s=4 * 3600)
    data = codebias_data_from_observations(obs, nav)
    assert data.stations == ("ZEGV", "ROVN")
    assert data.meta["codes"]["ZEGV"] == {"L1": "C1C", "L2": "C2W", "L5": "C5Q"}
    assert data.observed.any()
    el = data.elevation_rad
    assert el is not None and np.nanmax(el) <= np.pi / 2 and np.nanmin(np.where(data.observed, el, 1.0)) >= 0.17
    # the observable is the bias combination: metres at most, not the ~2e7 m of the ranges
    assert np.nanmax(np.abs(data.y_m)) < 30.0
    with pytest.raises(ModelError, match="needs L1, L2 and L5"):
        codebias_data_from_observations([read_code_observations(d / "delf0010.21o", bands=(1, 2))], nav)
    with pytest.raises(ModelError, match="no observation files"):
        codebias_data_from_observations([], nav)
    with pytest.raises(ModelError, match="appear twice"):
        codebias_data_from_observations([obs[0], obs[0]], nav)


def test_simulation_and_building_validation(rng: np.random.Generator, shared_data: Path) -> None:
    sc = synthetic_gps_constellation()
    pos = geodetic_to_ecef(np.zeros(2), np.zeros(2), 0.0)
    t = sc.epoch_gps_s + np.arange(3) * 30.0
    with pytest.raises(ModelError, match=r"sat_biases_m must be \(satellites, 3\)"):
        simulate_codebias_data(
            pos, sc, t, sc.l5_svs, rng=rng, options=CodeBiasSimulation(sat_biases_m=np.zeros((3, 3)))
        )
    with pytest.raises(ModelError, match=r"rx_biases_m must be \(stations, 3\)"):
        simulate_codebias_data(pos, sc, t, sc.l5_svs, rng=rng, options=CodeBiasSimulation(rx_biases_m=np.zeros((5, 3))))
    nan = np.nan
    with pytest.raises(ModelError, match="no satellite code bias is estimable"):
        _data(np.array([[[nan, nan]], [[1.0, 2.0]]])).estimable_subset()
    d = shared_data / "gnss/nl_2021001_short_network_snapshot"
    obs = read_code_observations(d / "zegv0010.21o")
    nav = read_navigation(d / "cbw10010.21n.gz", max_age_s=24 * 3600)
    with pytest.raises(ModelError, match="no satellite observed on L1, L2 and L5 above the 89° mask"):
        codebias_data_from_observations([obs], nav, mask_rad=np.deg2rad(89.0))
    from dataclasses import replace

    with pytest.raises(ModelError, match="no usable approximate position"):
        codebias_data_from_observations([replace(obs, position_ecef_m=np.full(3, np.nan))], nav)


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"sigma0_m": 0.0}, "sigma0_m must be a positive number of metres"),
        ({"sigma0_m": float("nan")}, "sigma0_m must be a positive number"),
        ({"weighting": "elevation"}, "unknown elevation weighting 'elevation'"),
        ({"mask_rad": 10.0}, r"mask_rad must be below 1.5708 \(radians, not degrees\), got 10.0"),
        ({"mask_rad": -0.1}, r"mask_rad must be 0 or more"),
        ({"sigma0_m": 0.2 + 1j}, r"sigma0_m must be a positive number of metres, got \(0.2\+1j\) \(complex\)"),
        ({"sigma0_m": "0.2"}, r"sigma0_m must be a positive number of metres, got '0.2' \(str\)"),
        ({"sat_dsb_sigma_ns": None}, "sat_dsb_sigma_ns must be a number of ns, got None"),
        ({"rx_dsb_sigma_ns": -1.0}, "rx_dsb_sigma_ns must be 0 or more"),
        ({"reference": 1.5}, r"reference \(a station index\) must be a whole number, got 1.5"),
        ({"reference": True}, r"reference \(a station index\) must be a whole number, got True \(a bool\)"),
    ],
)
def test_simulation_options_are_checked_when_built(options: dict[str, object], message: str) -> None:
    with pytest.raises(ModelError, match=message):
        CodeBiasSimulation(**options)  # type: ignore[arg-type]


def test_simulation_times_and_positions_are_checked(rng: np.random.Generator) -> None:
    sc = synthetic_gps_constellation()
    pos = geodetic_to_ecef(np.zeros(2), np.zeros(2), 0.0)
    t = sc.epoch_gps_s + np.zeros(1)
    with pytest.raises(ModelError, match="t_gps_s are complex numbers"):
        simulate_codebias_data(pos, sc, t + 1j, sc.l5_svs, rng=rng)
    with pytest.raises(ModelError, match="t_gps_s must be a 1-D array of finite GPS seconds"):
        simulate_codebias_data(pos, sc, t + np.inf, sc.l5_svs, rng=rng)
    with pytest.raises(ModelError, match=r"positions_ecef_m must be finite \(stations, 3\) ECEF metres"):
        simulate_codebias_data(pos[:, :2], sc, t, sc.l5_svs, rng=rng)


def test_simulation_reference_must_be_a_station(rng: np.random.Generator) -> None:
    sc = synthetic_gps_constellation()
    pos = geodetic_to_ecef(np.zeros(2), np.zeros(2), 0.0)
    with pytest.raises(ModelError, match="reference 2 is not one of the 2 stations"):
        simulate_codebias_data(
            pos, sc, sc.epoch_gps_s + np.zeros(1), sc.l5_svs, rng=rng, options=CodeBiasSimulation(reference=2)
        )
