"""The bias filters' outputs computed in blocks (``models/gnss/gfcollector``) against an epoch-by-epoch reference.

The reference is written here from the definitions, one epoch at a time: DSBs and σ by ``gfbias.in_datum`` with
the S-transformation of the epoch's estimable pattern, the predicted residuals ``v = y − A x̂_{t−1}`` of the
observations whose parameters were all estimable, ``Q_v = R + A (P_{t−1} + S_t) Aᵀ`` over the observed parameters
only, σ̂² = Σ vᵀQ_v⁻¹v / Σ m and the lag-1 correlation of the standardized residuals of a receiver–satellite pair
at consecutive epochs. Blocks of 7 epochs make the comparison cross many block boundaries.
"""

from __future__ import annotations

import numpy as np
import pytest

from distnav.algorithms.kalman import iterate_information_filter
from distnav.models.gnss import gfcollector
from distnav.models.gnss.geometry import geodetic_to_ecef
from distnav.models.gnss.gfbias import datum_transform, gf_m_per_dsb_ns, in_datum
from distnav.models.gnss.gfnetwork import (
    BiasFilterOptions,
    BiasModelOptions,
    GeometryFreeNetwork,
    bias_network_model,
    run_bias_filters,
)
from distnav.models.gnss.ionosphere import GeometryOptions, ionosphere_geometry
from distnav.models.gnss.orbits import gps_seconds, synthetic_gps_constellation

NAMES = ["A", "B", "C"]


def _data(epochs: int = 60) -> object:
    rng = np.random.default_rng(11)
    gps = synthetic_gps_constellation()
    t = gps_seconds(np.datetime64("2016-06-02T00:00")) + 60.0 * np.arange(epochs)
    xyz = geodetic_to_ecef(np.deg2rad([-31.9, -32.0, -31.5]), np.deg2rad([115.8, 116.2, 115.9]), np.zeros(3))
    geo = ionosphere_geometry(gps, t, receivers_ecef_m=xyz, names=NAMES, options=GeometryOptions(mask_deg=10))
    T, n, S = geo.tracked.shape
    tec = 2.0 + np.cumsum(rng.normal(0, 1e-3 * np.sqrt(60.0), T))
    sig = 0.3 / np.sin(np.where(geo.tracked, geo.el_rad, np.pi / 2))
    e = rng.standard_normal((T, n, S))
    for k in range(1, T):  # AR(1) errors (ρ = 0.8): a positive lag-1 correlation
        e[k] = 0.8 * e[k - 1] + 0.6 * e[k]
    y = (
        geo.coefficients[..., 0] * tec[:, None, None]
        + rng.normal(0, 3, n)[None, :, None]
        + rng.normal(0, 1.5, S)[None, None, :]
        + sig * e
    )
    y[~geo.tracked] = np.nan
    y[: T // 3, 2] = np.nan  # station C joins later: inestimable entries early on
    return bias_network_model(
        GeometryFreeNetwork(NAMES, t, xyz, y, list(gps.svs)),
        gps,
        BiasModelOptions(ionosphere="common", sigma_zenith_m=0.3, reference="A", min_satellite_obs=1),
    )


def _reference(data: object, datum: str) -> dict[str, object]:
    """Epoch-by-epoch outputs of the central filter (the definitions of the module doc)."""
    ser, dyn, lay = data.series, data.dynamics, data.layout  # type: ignore[attr-defined]
    scale = gf_m_per_dsb_ns(data.band)  # type: ignore[attr-defined]
    T, nt = ser.n_epochs, lay.n_tec
    nodes = np.arange(ser.n_nodes)
    out = {
        k: np.full((T, w), np.nan)
        for k, w in (
            ("tec", nt),
            ("tec_std", nt),
            ("dsb", ser.n_nodes + len(lay.svs)),
            ("dsb_std", ser.n_nodes + len(lay.svs)),
        )
    }
    ssr, m, zz, zlag = 0.0, 0, 0.0, 0.0
    z_prev: dict[tuple[int, int], tuple[int, float]] = {}
    prev = None
    for st in iterate_information_filter(dyn, ser, mode="central"):
        t, x, est, P = st.epoch, st.estimates[0], st.estimable[0], st.covariance[0]
        if prev is not None:
            xp, ep, Pp = prev
            A, w = ser.design(t, nodes)
            y = ser._y[t]
            keep = [
                (i, s)
                for i in range(A.shape[0])
                for s in range(A.shape[1])
                if w[i, s] > 0 and not (A[i, s][~ep] != 0).any()
            ]
            if keep:
                Ar = np.array([A[i, s] for i, s in keep])
                used = np.flatnonzero(Ar.any(axis=0))
                Ar = Ar[:, used]
                Pm = (Pp + dyn.noise_cov_at(t))[np.ix_(used, used)]
                v = np.array([y[i, s] for i, s in keep]) - Ar @ xp[used]
                Qv = Ar @ Pm @ Ar.T + np.diag([1.0 / w[i, s] for i, s in keep])
                ssr += float(v @ np.linalg.solve(Qv, v))
                m += len(keep)
                z = v / np.sqrt(np.diag(Qv))
                for (i, s), zi in zip(keep, z.tolist(), strict=True):
                    zz += zi * zi
                    last = z_prev.get((i, s))
                    if last is not None and last[0] == t - 1:
                        zlag += zi * last[1]
                    z_prev[(i, s)] = (t, zi)
        prev = (x.copy(), est.copy(), P.copy())
        out["tec"][t] = np.where(est[:nt], x[:nt], np.nan)
        out["tec_std"][t] = np.where(est[:nt], np.sqrt(np.maximum(np.diag(P)[:nt], 0.0)), np.nan)
        Tm = datum_transform(lay, datum, estimable=est)
        val, sd = in_datum(Tm, x, P)
        out["dsb"][t], out["dsb_std"][t] = -val / scale, sd / scale
    out["variance_factor"] = ssr / m
    out["rho"] = min(max(zlag / zz, 0.0), 0.999)
    out["m"] = m
    return out


@pytest.mark.parametrize("datum", ["zero-mean", "receiver"])
def test_block_outputs_equal_the_epoch_by_epoch_reference(monkeypatch: pytest.MonkeyPatch, datum: str) -> None:
    data = _data()
    monkeypatch.setattr(gfcollector, "BLOCK", 7)
    series, _ = run_bias_filters(data, BiasFilterOptions(datum=datum, local=False))
    got, ref = series[0], _reference(data, datum)
    assert np.isnan(ref["dsb"][:10, 2]).all() and np.isfinite(ref["dsb"][-1]).all()  # C inestimable at first
    for name, a, b in (
        ("tec", got.tec, ref["tec"]),
        ("tec_std", got.tec_std, ref["tec_std"]),
        ("dsb", got.dsb_ns, ref["dsb"]),
        ("dsb_std", got.dsb_std_ns, ref["dsb_std"]),
    ):
        np.testing.assert_array_equal(np.isnan(a), np.isnan(b), err_msg=name)
        np.testing.assert_allclose(a, b, rtol=1e-11, atol=1e-12, err_msg=name)
    assert got.n_innovations == ref["m"] > 0
    assert got.variance_factor == pytest.approx(ref["variance_factor"], rel=1e-11)
    assert got.lag1_correlation == pytest.approx(ref["rho"], rel=1e-11)
    assert 0.0 < got.lag1_correlation < 0.999
