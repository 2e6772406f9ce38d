"""The GNSS bias pipeline's stage options (issue 25 item 4): each options object checks its values once, at
construction, with an error naming the option (the front doors' ``Examples`` run in test_docstring_examples)."""

from __future__ import annotations

import pytest

from distnav.commands.gnss_ionosphere_data import NetworkOptions
from distnav.errors import ModelError
from distnav.models.gnss.biasmodel import BiasModelOptions
from distnav.models.gnss.gfnetwork import BiasFilterOptions
from distnav.models.gnss.ionogeometry import GeometryOptions
from distnav.models.gnss.levelling import LevellingOptions


@pytest.mark.parametrize(
    ("make", "match"),
    [
        (lambda: BiasModelOptions(ionosphere="global"), "ionosphere must be one of"),
        (lambda: BiasModelOptions(weighting="cos"), "weighting must be one of"),
        (lambda: BiasModelOptions(station_weighting="yes"), "station_weighting must be one of"),
        (lambda: BiasModelOptions(mapping="flat"), "mapping must be one of"),
        (lambda: BiasModelOptions(tec_order=3), "tec_order must be one of"),
        (lambda: BiasModelOptions(band=1), "band 1 is the first frequency"),
        (lambda: BiasModelOptions(mask_deg=90.0), "elevation mask"),
        (lambda: BiasModelOptions(regional_km=0.0), "regional_km must be a positive number"),
        (lambda: BiasModelOptions(sigma_zenith_m=float("nan")), "sigma_zenith_m must be a (positive )?number"),
        (lambda: BiasModelOptions(vtec_rw_m_per_sqrt_s=0.0), "TEC random walk must be positive"),
        (lambda: BiasModelOptions(min_satellite_obs=0), "min_satellite_obs must be ≥ 1"),
        (lambda: BiasFilterOptions(datum="mean"), "datum must be one of"),
        (lambda: BiasFilterOptions(datum="pivot"), "needs a pivot satellite"),
        (lambda: BiasFilterOptions(kn=-1), "kn must be ≥ 0"),
        (lambda: BiasFilterOptions(innovation_level=0.7), "innovation_level must lie in"),
        (lambda: GeometryOptions(ionosphere="per-station"), "ionosphere must be"),
        (lambda: GeometryOptions(mask_deg=-1.0), "elevation mask"),
        (lambda: GeometryOptions(tec_order=0), "order must be 1"),
        (lambda: LevellingOptions(band=1), "band 1 is the first frequency"),
        (lambda: LevellingOptions(min_arc_epochs=1), "min_arc_epochs must be ≥ 2"),
        (lambda: LevellingOptions(max_gap_s=0.0), "max_gap_s must be > 0"),
        (lambda: LevellingOptions(gf_threshold_m=-0.05), "gf_threshold_m must be a positive number"),
        (lambda: LevellingOptions(level=0.5), "test level must lie in"),
        (lambda: NetworkOptions(l2_code="C1W"), "l2_code C1W: not a second code"),
        (lambda: NetworkOptions(interval_s=0.0), "interval_s must be a positive number"),
        (lambda: NetworkOptions(min_arc_epochs=1), "min_arc_epochs must be ≥ 2"),
        (lambda: NetworkOptions(gf_threshold_m=0.0), "gf_threshold_m must be a positive number"),
    ],
)
def test_every_options_rule_names_the_option(make: object, match: str) -> None:
    with pytest.raises(ModelError, match=match):
        make()  # type: ignore[operator]


def test_network_options_take_the_band_from_the_second_code() -> None:
    assert NetworkOptions().model_options.band == 2
    five = NetworkOptions(l2_code="c5q", exclude=("g01", "bele"), model=BiasModelOptions(mask_deg=15.0))
    assert five.model_options.band == 5 and five.model_options.mask_deg == 15.0
    assert five.exclude == ("G01", "BELE")
