"""σ terms from elsewhere in the same data (distnav.models.gnss.sigmaterms, issue 32, gnss8): the GLONASS receivers'
channel biases as a consider term, and the arcs' factor borrowed from GPS.

Independent references: Monte Carlo draws of the channel biases (the variance formula, the analysis of variance),
the simulator's truth (a network whose receivers carry per-channel code biases), CAS's DSBs of the shared day
(never an input of the σ)."""

from __future__ import annotations

import gzip
import json
from pathlib import Path

import numpy as np
import pytest

from distnav.commands.gnss_ionosphere import NetworkOptions, network_from_observations
from distnav.models.gnss.biasmodel import BiasModelOptions
from distnav.models.gnss.gfnetwork import BiasFilterOptions, final_dsbs, run_bias_filters
from distnav.models.gnss.netsim import NetworkSimOptions, simulate_network, truth_product
from distnav.models.gnss.orbits import synthetic_gps_constellation
from distnav.models.gnss.products import compare_in_datum
from distnav.models.gnss.sigmaterms import (
    channel_ifb_sigma_ns,
    channel_ifb_variance_ns2,
    with_arc_factor,
    with_channel_ifb,
)

IGS = "gnss/igs_2024010_bele_dgar"
CHANNELS = [1, -4, 5, 6, 1, -4, 5, 6, -2, -7, 0, -1, -2, -7, 0, -1, 4, -3, 3, 2, 4, -3, 3, 2]


def test_channel_variance_equals_monte_carlo_of_the_zero_mean_datum() -> None:
    rng = np.random.default_rng(0)
    k = np.array(CHANNELS[:21], float)  # 21 satellites, three channels with one satellite only
    groups = np.unique(k)
    delta = rng.normal(0.0, 1.7, (40000, 2, groups.size))  # two receivers
    per_sat = delta.mean(axis=1)[:, np.searchsorted(groups, k)]  # the satellites take the receivers' mean
    err = per_sat - per_sat.mean(axis=1, keepdims=True)  # zero-mean datum over the 21
    np.testing.assert_allclose(err.var(axis=0), channel_ifb_variance_ns2(k, 1.7, 2), rtol=0.03)
    assert channel_ifb_variance_ns2([np.nan, 1.0], 1.0, 1)[0] == 0.0


def test_channel_sigma_by_analysis_of_variance_is_unbiased() -> None:
    rng = np.random.default_rng(1)
    k = np.array(CHANNELS, float)
    groups = np.unique(k)
    svs = [f"R{j + 1:02d}" for j in range(k.size)]
    est = []
    for _ in range(3000):
        d = rng.normal(0, 2.0, groups.size)[np.searchsorted(groups, k)] + rng.normal(0, 0.8, k.size)
        s, K, dof = channel_ifb_sigma_ns(dict(zip(svs, d, strict=True)), dict(zip(svs, k, strict=True)))
        est.append(s**2)
    assert (K, dof) == (12, 12)
    assert np.mean(est) == pytest.approx(4.0, rel=0.05)  # σ_c² (clipping at 0 is rare at this size)
    nan, K, dof = channel_ifb_sigma_ns({"R01": 1.0, "R02": 2.0}, {"R01": 1, "R02": 2})
    assert np.isnan(nan) and (K, dof) == (2, 0)


def _channel_network(seed: int, stations: dict[str, tuple[float, float, float]]) -> tuple[object, object, dict]:
    orbit = synthetic_gps_constellation(epoch="2024-01-10T00:00:00")
    channels = {s: j // 2 for j, s in enumerate(orbit.svs)}  # two satellites a channel, as GLONASS
    options = NetworkSimOptions(hours=12.0, interval_s=60.0, svn49=None, channels=channels, channel_ifb_ns=2.0)
    sim = simulate_network(orbit, "2024-01-10", options, rng=np.random.default_rng(seed), stations=stations)
    return orbit, sim, channels


def test_simulated_single_station_with_channel_biases_is_covered() -> None:
    """One receiver with per-channel code biases (σ 2 ns): its satellites' DSBs carry them, the σ without the
    term is several times too small, with it (the σ the simulator drew, as the prior) within 0.7–1.3."""
    with_term, without = [], []
    for seed in range(3):
        orbit, sim, channels = _channel_network(seed, {"SIMA": (49.14, 12.88, 650.0)})
        assert set(sim.channel_ifb_ns["SIMA"]) == set(channels.values())  # type: ignore[attr-defined]
        opts = NetworkOptions(l2_code="C2W", interval_s=60.0, model=BiasModelOptions(min_satellite_obs=30))
        data = network_from_observations(sim.observations, orbit, opts)  # type: ignore[attr-defined]
        (c,), _ = run_bias_filters(data, BiasFilterOptions(local=False))
        k = np.array([channels[s] for s in data.layout.svs], float)
        (c2,) = with_channel_ifb([c], 1, channel_ifb_variance_ns2(k, 2.0, 1), floor=False)
        for out, series in ((without, c), (with_term, c2)):
            sat, rx, sd = final_dsbs(data, series)
            r = compare_in_datum(sat, rx, truth_product(sim))  # type: ignore[arg-type]
            out.extend(d / sd[s] for s, d in r["difference_ns"].items())
    rms = lambda z: float(np.sqrt(np.mean(np.square(z))))  # noqa: E731
    assert rms(without) > 3.0
    assert 0.7 <= rms(with_term) <= 1.3


def test_simulated_receivers_measure_their_channel_biases() -> None:
    """Three receivers of a regional network: the σ of their channel biases from the differences of their
    single-station DSBs (each pair 2σ²) recovers the simulator's 2 ns."""
    from distnav.models.gnss.netsim import EUROPEAN_STATIONS

    orbit, sim, channels = _channel_network(11, dict(EUROPEAN_STATIONS))
    opts = NetworkOptions(l2_code="C2W", interval_s=60.0, model=BiasModelOptions(min_satellite_obs=30))
    data = network_from_observations(sim.observations, orbit, opts)  # type: ignore[attr-defined]
    series, _ = run_bias_filters(data, BiasFilterOptions(between_station_level=None, kn=0))
    local = [s for s in series if s.label.startswith("local:")]
    n = len(data.stations)
    est = []
    for a in range(3):
        for b in range(a + 1, 3):
            d = dict(zip(data.layout.svs, (local[a].dsb_ns[-1, n:] - local[b].dsb_ns[-1, n:]).tolist(), strict=True))
            est.append(channel_ifb_sigma_ns(d, channels)[0] ** 2 / 2)
    drawn = np.array([list(v.values()) for v in sim.channel_ifb_ns.values()])  # type: ignore[attr-defined]
    assert np.sqrt(np.mean(est)) == pytest.approx(float(drawn.std()), rel=0.35)


def test_simulated_system_with_too_few_arcs_borrows_the_receivers_gps_factor() -> None:
    """One receiver (realistic preset, one day): a 10-satellite "other system" has too few arcs for its own factor
    (as BeiDou from BELE), and its σ from the predicted residuals is ≈ 3× too small against the truth; with the
    factor of the same receiver's arcs of all 31 satellites (same multipath model) the pooled RMS(error/σ) over
    five draws of the day is 0.74 (per draw 0.37–1.01: ten satellites scatter)."""
    from distnav.models.gnss.netsim import REALISTIC

    own, borrowed = [], []
    mo = BiasModelOptions(min_satellite_obs=30)
    for seed in range(5):
        orbit = synthetic_gps_constellation(epoch="2024-01-10T00:00:00")
        opts = NetworkSimOptions(**{**REALISTIC, "interval_s": 30.0, "svn49": None})  # type: ignore[arg-type]
        sim = simulate_network(
            orbit, "2024-01-10", opts, rng=np.random.default_rng(seed), stations={"SIMA": (49.14, 12.88, 650.0)}
        )
        sub = list(orbit.svs)[seed % 3 :: 3][:10]
        rest = tuple(s for s in orbit.svs if s not in sub)
        other = network_from_observations(
            sim.observations, orbit, NetworkOptions(l2_code="C2W", interval_s=30.0, exclude=rest, model=mo)
        )
        gps = network_from_observations(
            sim.observations, orbit, NetworkOptions(l2_code="C2W", interval_s=30.0, model=mo)
        )
        (c,), _ = run_bias_filters(other, BiasFilterOptions(local=False, between_station_level=None))
        (g,), _ = run_bias_filters(gps, BiasFilterOptions(local=False, between_station_level=None))
        assert c.arc_variance_factor is None and g.arc_variance_factor is not None
        for out, series in ((own, c), (borrowed, with_arc_factor([c], g.arc_variance_factor)[0])):
            sat, rx, sd = final_dsbs(other, series)
            r = compare_in_datum(sat, rx, truth_product(sim))
            out.extend(d / sd[s] for s, d in r["difference_ns"].items())
    assert np.sqrt(np.mean(np.square(own))) > 2.0
    assert 0.6 <= np.sqrt(np.mean(np.square(borrowed))) <= 1.3


def test_borrowed_arc_factor_only_where_missing() -> None:
    from distnav.models.gnss.gfcollector import DatumSeries

    z = np.zeros((1, 3))
    own = DatumSeries("central", z, z, z, z + 1.0, 0.5, arc_variance_factor=4.0)
    none = DatumSeries("local:A", z, z, z, z + 1.0, 0.5, correlation_inflation=2.0)
    a, b = with_arc_factor([own, none], 9.0)
    assert a.realistic_factor == 2.0 and b.realistic_factor == 3.0


def _cas(path: Path, system: str, pair: tuple[str, str]) -> dict[str, float]:
    out = {}
    for line in gzip.open(path, "rt", encoding="latin-1"):
        t = line.split()
        if len(t) == 10 and t[0] == "DSB" and tuple(t[3:5]) == pair and t[2].startswith(system):
            out[t[2]] = float(t[8])
    return out


@pytest.mark.parametrize(
    ("system", "codes", "before"),
    [("C", ("C2I", "C6I"), 2.24), ("R", ("C1C", "C2C"), 3.11)],
)
def test_bele_alone_beidou_and_glonass_sigma_against_cas(
    shared_data: Path,
    tmp_path: Path,
    request: pytest.FixtureRequest,
    system: str,
    codes: tuple[str, str],
    before: float,
) -> None:
    """BELE alone, the full day: BeiDou's σ takes the GPS arcs' factor (RMS(error/σ) 2.24 → 1.35: nearer, still
    above 1.3), GLONASS C1C−C2C also the channel biases sized by BELE's own P pair (3.11 → 0.91). CAS only
    checks. GLONASS's day is the session's run (conftest.bele_glonass_day, the same arguments), which
    test_gnss_multisystem checks too."""
    d = shared_data / IGS
    cas = d / "CAS0OPSRAP_20240100000_01D_01D_DCB.BIA.gz"
    out = tmp_path
    if system == "R":
        out = request.getfixturevalue("bele_glonass_day")
    else:
        args = ["gnss", "ionosphere", "--system", system]
        args += ["--obs", str(d / "BELE00BRA_R_20240100000_01D_30S_MO.crx.gz")]
        args += ["--nav", str(d / "BRDC00IGS_R_20240100000_01D_MN.rnx.gz"), "--l1-code", codes[0]]
        from distnav.cli import main

        args += ["--l2-code", codes[1], "--bias", str(cas), "--out", str(out), "--kn", "0", "--no-progress"]
        assert main(args) == 0
    s = json.loads((out / "summary.json").read_text())
    est, sd = s["final_dsb_ns"]["central"], s["final_dsb_std_realistic_ns"]["central"]
    ref = _cas(cas, system, codes)
    sats = sorted(k for k in est if k in ref and est[k] is not None)
    e = np.array([est[k] - ref[k] for k in sats])
    ratio = float(np.sqrt(np.mean(((e - e.mean()) / np.array([sd[k] for k in sats])) ** 2)))
    terms = s["sigma_terms"]
    assert terms["arc_factor"]["factor"] > 1.0 and "GPS" in terms["arc_factor"]["source"]
    assert any("GPS C1C-C2W arcs" in n for n in s["notes"])
    if system == "C":
        assert 1.0 < ratio < 1.5 < before
    else:
        ifb = terms["glonass_channel_ifb"]  # BELE tracks the P pair too: the size from its C/A − P channel means
        assert ifb["source"] == "P pair of the same receiver" and ifb["channels"] >= 10 and ifb["sigma_ns"] > 1.5
        assert any("C/A minus P-pair" in n for n in s["notes"])
        assert 0.7 <= ratio <= 1.3


def test_the_command_chooses_the_channel_bias_source_and_applies_it_per_filter() -> None:
    """Two receivers: σ_ifb from their single-station DSBs (channel means of the difference, ANOVA), a floor,
    the single-station filters with their own receiver's share (n_r = 1), the network's with the mean's; a given
    --glonass-ifb-sigma-ns wins; a P pair of one receiver gets nothing by default."""
    from argparse import Namespace
    from types import SimpleNamespace

    from distnav.commands.gnss_sigma_terms import glonass_channel_ifb
    from distnav.models.gnss.gfcollector import DatumSeries

    k = np.array(CHANNELS, float)
    svs = [f"R{j + 1:02d}" for j in range(k.size)]
    f1 = 1602e6 + 0.5625e6 * k
    groups = np.unique(k)
    rng = np.random.default_rng(4)
    pattern = rng.normal(0, 3.0, groups.size)[np.searchsorted(groups, k)]
    S, n = k.size, 2
    tiny = np.full((1, n + S), 1e-3)

    def series(label: str, sats: np.ndarray) -> DatumSeries:
        dsb = np.concatenate([[0.0, 0.0], sats])[None]
        return DatumSeries(label, np.zeros((1, 3)), np.zeros((1, 3)), dsb, tiny, 1.0)

    data = SimpleNamespace(stations=["A", "B"], layout=SimpleNamespace(svs=svs), frequencies_hz=(f1, f1))
    filters = [series("central", pattern / 2), series("local:A", pattern), series("local:B", np.zeros(S))]
    args = Namespace(glonass_ifb_sigma_ns=None, l1_code="C1C", l2_code="C2C", obs=[], tlim=None)
    out, ifb = glonass_channel_ifb(args, data, None, None, filters)
    expected = channel_ifb_sigma_ns(dict(zip(svs, pattern, strict=True)), dict(zip(svs, k, strict=True)))[0] / np.sqrt(
        2
    )
    assert ifb.source == "between receivers" and ifb.mode == "floor" and ifb.sigma_ns == pytest.approx(expected)
    var_net = channel_ifb_variance_ns2(k, ifb.sigma_ns, 2)
    var_own = channel_ifb_variance_ns2(k, ifb.sigma_ns, 1)
    np.testing.assert_allclose(out[0].realistic_std_ns()[n:] ** 2, var_net, rtol=1e-6)
    np.testing.assert_allclose(out[1].realistic_std_ns()[n:] ** 2, var_own, rtol=1e-6)
    args.glonass_ifb_sigma_ns = 1.0
    assert glonass_channel_ifb(args, data, None, None, filters)[1].source == "given"
    one = SimpleNamespace(stations=["A"], layout=SimpleNamespace(svs=svs), frequencies_hz=(f1, f1))
    p = Namespace(glonass_ifb_sigma_ns=None, l1_code="C1P", l2_code="C2P", obs=[], tlim=None)
    assert glonass_channel_ifb(p, one, None, None, [series("central", pattern)])[1] is None
