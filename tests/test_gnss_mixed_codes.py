"""A network whose stations track different L1 codes (one P1 = C1W, one C/A = C1C only): the satellites'
C1C−C1W biases from a product put the C1C station on C1W for the satellites, while its receiver DSB stays its
own C1C−C2W — compared with the product's receiver C1C−C2W and written to Bias-SINEX as such (issue 14 item 7)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from distnav.commands.gnss_ionosphere import NetworkOptions, network_from_observations
from distnav.formats.gnss.bias_sinex import read_bias_sinex, write_bias_sinex
from distnav.formats.gnss.product_files import correct_c1, product_dsbs
from distnav.models.gnss.constants import C_M_S
from distnav.models.gnss.gfnetwork import BiasFilterOptions, final_dsbs, run_bias_filters
from distnav.models.gnss.netsim import NetworkSimOptions, simulate_network
from distnav.models.gnss.orbits import synthetic_gps_constellation
from distnav.models.gnss.products import compare_in_datum

TWO = {"SIMA": (49.14, 12.88, 650.0), "SIMB": (50.80, 10.20, 400.0)}
RX_C1C_C1W_NS = 2.3  # SIMB's own C1C−C1W (as CAS gives DGAR 2.317 ns)


def _mixed_network(tmp_path: Path) -> tuple[object, list[object], Path, Path, dict[str, float]]:
    orbit = synthetic_gps_constellation(epoch="2024-01-10T00:00:00")
    rng = np.random.default_rng(5)
    sat = {s: float(v) for s, v in zip(orbit.svs, rng.normal(0, 3, len(orbit.svs)), strict=True)}
    c1c = {s: float(v) for s, v in zip(orbit.svs, rng.normal(0, 1.5, len(orbit.svs)), strict=True)}
    sim = simulate_network(
        orbit,
        "2024-01-10",
        NetworkSimOptions(hours=4.0, svn49=None),
        rng=np.random.default_rng(1),
        stations=TWO,
        satellite_dsb_ns=sat,
        receiver_dsb_ns={"SIMA": 4.0, "SIMB": -6.0},
    )
    a, b = sim.observations
    # SIMB records C/A only: C1C = C1W + DSB(C1C−C1W) of receiver and satellite (biases add to observations)
    add = C_M_S * 1e-9 * (RX_C1C_C1W_NS + np.array([c1c[s] for s in b.svs]))
    b = replace(b, range_m={**b.range_m, 1: b.range_m[1] + add[None, :]}, codes={**b.codes, 1: "C1C"})
    start, end = np.datetime64("2024-01-10T00:00:00"), np.datetime64("2024-01-11T00:00:00")
    corr = Path(
        write_bias_sinex(
            tmp_path / "c1c.bia",
            obs1="C1C",
            obs2="C1W",
            start=start,
            end=end,
            satellites={s: (v, 0.01) for s, v in c1c.items()},
            stations={"SIMB": (RX_C1C_C1W_NS, 0.01)},
        )
    )
    truth = Path(
        write_bias_sinex(
            tmp_path / "truth.bia",
            obs1="C1W",
            obs2="C2W",
            start=start,
            end=end,
            satellites={s: (v, 0.01) for s, v in sat.items()},
            stations={"SIMA": (4.0, 0.01), "SIMB": (-6.0, 0.01)},
        )
    )
    return orbit, [a, b], corr, truth, c1c


def _solve(orbit: object, obs: list[object]) -> tuple[list[str], dict[str, float], dict[str, float]]:
    data = network_from_observations(obs, orbit, NetworkOptions(interval_s=60.0))
    series, _ = run_bias_filters(data, BiasFilterOptions(local=False))
    sat, rx, _ = final_dsbs(data, series[0])
    return list(data.layout.svs), sat, rx


def test_receiver_dsb_of_a_corrected_c1c_station_is_its_own_c1c_c2w(tmp_path: Path) -> None:
    orbit, (a, b), corr, truth, _ = _mixed_network(tmp_path)
    bc = correct_c1(b, corr)
    svs, sat, rx = _solve(orbit, [a, bc])
    own = {"SIMA": ("C1W", "C2W"), "SIMB": ("C1C", "C2W")}
    prod = product_dsbs([truth, corr], svs, ["SIMA", "SIMB"], "C1W", "C2W", station_codes=own)[0]
    # the product chains SIMB's C1C−C2W = C1C−C1W + C1W−C2W = 2.3 − 6.0
    assert prod.station["SIMB"] == np.float64(RX_C1C_C1W_NS - 6.0)
    c = compare_in_datum(sat, rx, prod)
    assert c["rms_zero_mean_ns"] < 0.4  # 4 h of two stations (0.31 ns, G17 seen little)
    d = c["receivers"]["difference_ns"]
    assert abs(d["SIMA"]) < 0.35 and abs(d["SIMB"]) < 0.35, d  # 0.20, 0.26 ns
    # the comparison of the old code (every receiver against the satellites' C1W−C2W pair) is off by SIMB's own
    # C1C−C1W: the ns-level receiver error of mixing code definitions
    old = compare_in_datum(sat, rx, product_dsbs([truth, corr], svs, ["SIMA", "SIMB"], "C1W", "C2W")[0])
    assert abs(old["receivers"]["difference_ns"]["SIMB"] - RX_C1C_C1W_NS) < 0.35


def test_uncorrected_mixed_codes_bias_the_satellites(tmp_path: Path) -> None:
    """Without the C1C−C1W corrections the two stations see different satellite biases (C1C vs C1W, 1.5 ns spread
    here): the shared satellite DSBs fit neither; with them the fit is at the noise level."""
    orbit, (a, b), corr, truth, _ = _mixed_network(tmp_path)
    svs, sat, rx = _solve(orbit, [a, b])
    prod = product_dsbs([truth], svs, ["SIMA"], "C1W", "C2W")[0]
    mixed = compare_in_datum(sat, rx, prod)["rms_zero_mean_ns"]
    svs, sat, rx = _solve(orbit, [a, correct_c1(b, corr)])
    fixed = compare_in_datum(sat, rx, product_dsbs([truth], svs, ["SIMA"], "C1W", "C2W")[0])["rms_zero_mean_ns"]
    assert fixed < 0.4 and mixed > 0.6 and mixed > 2 * fixed  # 0.31 vs 0.75 ns


def test_bias_sinex_station_lines_carry_each_receivers_code_pair(tmp_path: Path) -> None:
    p = write_bias_sinex(
        tmp_path / "out.bia",
        obs1="C1W",
        obs2="C2W",
        start=np.datetime64("2024-01-10"),
        end=np.datetime64("2024-01-11"),
        satellites={"G02": (1.0, 0.1)},
        stations={"SIMA": (4.0, 0.1), "SIMB": (-3.7, 0.1)},
        station_codes={"SIMB": ("C1C", "C2W")},
    )
    recs = {(r.station[:4] or r.prn): (r.obs1, r.obs2, r.value) for r in read_bias_sinex(p).records}
    assert recs["G02"] == ("C1W", "C2W", 1.0)
    assert recs["SIMA"] == ("C1W", "C2W", 4.0)
    assert recs["SIMB"] == ("C1C", "C2W", -3.7)
    # an independent whitespace parse of the solution block says the same
    lines = [ln.split() for ln in Path(p).read_text().splitlines() if ln.startswith(" DSB ")]
    assert ["SIMB", "C1C", "C2W"] == [t for t in lines[-1] if t in ("SIMB", "C1C", "C2W")]
