"""Each station screens its own code: gross errors injected at one station barely move the DCBs."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

IGS = "gnss/igs_2024010_bele_dgar"


def test_gross_errors_at_one_station_move_no_dcb_by_more_than_0_1_ns(shared_data: Path) -> None:
    from distnav.commands.gnss_ionosphere import NetworkOptions, network_from_observations
    from distnav.formats.gnss.rinex import read_navigation, read_stations
    from distnav.models.gnss.gfnetwork import BiasFilterOptions, run_bias_filters

    d = shared_data / IGS
    nav = read_navigation(d / "BRDC00IGS_R_20240100000_01D_MN.rnx.gz", max_age_s=4 * 3600.0)
    obs = read_stations(
        [d / "BELE00BRA_R_20240100000_01D_30S_MO.crx.gz", d / "dgar0100.24o.gz"],
        l1_code="C1C",
        l2_code="C2W",
        phases=True,
        tlim=("2024-01-10T06:00", "2024-01-10T08:00"),
    )
    rng = np.random.default_rng(7)
    dgar = obs[1]
    p1 = dgar.range_m[1].copy()
    ok = np.flatnonzero((np.isfinite(p1) & np.isfinite(dgar.range_m[2])).ravel())
    pick = rng.choice(ok, size=max(int(0.002 * ok.size), 8), replace=False)  # 0.2 % (at least 8)
    p1.ravel()[pick] += rng.choice([-1.0, 1.0], pick.size) * rng.uniform(3.0, 30.0, pick.size)
    bad = [obs[0], replace(dgar, range_m={1: p1, 2: dgar.range_m[2]})]

    def dsb(o: list, levelling: bool = True) -> tuple[dict[str, float], object]:
        data = network_from_observations(o, nav, NetworkOptions(interval_s=60, levelling=levelling))
        (c,), _ = run_bias_filters(data, BiasFilterOptions(local=False))
        keys = [f"rx:{r}" for r in data.stations] + list(data.layout.svs)
        return dict(zip(keys, c.dsb_ns[-1].tolist(), strict=True)), data

    clean, _ = dsb(obs)
    dirty, data = dsb(bad)
    moved = np.array([dirty[k] - clean[k] for k in clean if np.isfinite(clean[k])])
    assert np.abs(moved).max() < 0.1
    lev = data.levelled["DGAR"]
    t_bad, s_bad = np.unravel_index(pick, p1.shape)
    caught = lev.removed[t_bad, s_bad] | np.isnan(lev.gf_m[t_bad, s_bad])
    assert caught.mean() > 0.9  # removed by the MW outlier test or the w-test screening
    raw_clean, _ = dsb(obs, levelling=False)
    raw_dirty, _ = dsb(bad, levelling=False)
    raw_moved = np.array([raw_dirty[k] - raw_clean[k] for k in raw_clean if np.isfinite(raw_clean[k])])
    assert np.abs(raw_moved).max() > np.abs(moved).max()  # without levelling + screening they do move
