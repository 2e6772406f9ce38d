"""``check_orbit_day`` (formats/gnss/product_files.py): orbits of another day than the observations are named and
refused (issue 29: they used to end in "no satellite observed above the mask"), by every GNSS command that reads
orbits; orbits of the same day pass."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from distnav.cli import main
from distnav.errors import DataFileError
from distnav.formats.gnss.product_files import check_orbit_day
from distnav.models.gnss.orbits import SP3Orbit, gps_seconds, synthetic_gps_constellation

NL = "gnss/nl_2021001_short_network_snapshot"
IGS = "gnss/igs_2024010_bele_dgar"
ESBC = "gnss/esbc_2020177_single_station_L5_sp3"


def _sp3(first: str, hours: float) -> SP3Orbit:
    t = gps_seconds(np.datetime64(first, "s")) + np.arange(0.0, hours * 3600.0 + 1.0, 900.0)
    return SP3Orbit(svs=("G01",), t_gps_s=t, positions_m=np.ones((t.size, 1, 3)), source="orbits.sp3")


def _obs(first: str, hours: float, name: str = "abcd1770.20o") -> SimpleNamespace:
    t = np.datetime64(first, "s") + np.arange(0, int(hours * 3600) + 1, 30).astype("timedelta64[s]")
    return SimpleNamespace(time=t.astype("datetime64[ns]"), path=Path(name))


def test_orbits_of_the_observations_day_pass() -> None:
    check_orbit_day(_sp3("2020-06-25T00:00", 23.75), [_obs("2020-06-25T00:00", 24)])
    # two SP3 days around midnight, observations of the second day's first hour
    check_orbit_day(_sp3("2020-06-24T00:00", 47.75), [_obs("2020-06-25T00:00", 1)])


@pytest.mark.parametrize(
    ("orbit_first", "obs_first", "share"),
    [
        ("2020-06-24T00:00", "2020-06-25T06:00", "none"),  # the day before: no epoch reached
        ("2020-06-26T00:00", "2020-06-25T00:00", "none"),  # the day after
    ],
)
def test_orbits_of_another_day_are_named(orbit_first: str, obs_first: str, share: str) -> None:
    with pytest.raises(DataFileError) as err:
        check_orbit_day(_sp3(orbit_first, 23.75), [_obs(obs_first, 2)])
    text = str(err.value)
    assert text.startswith("orbits.sp3: an SP3 file of " + orbit_first[:10])
    assert "abcd1770.20o observes 2020-06-25" in text and f"reach {share} of" in text
    assert "give the SP3 file of 2020-06-25" in text


def test_a_file_of_the_day_before_reaching_into_the_first_hours_is_refused() -> None:
    """Orbits that cover the first epochs but share no day with the observations are still the wrong day's."""
    orbit = _sp3("2020-06-24T00:00", 23.75)
    obs = _obs("2020-06-24T23:30", 0.5)  # spans midnight: 2020-06-24 and -25, covered until 23:45
    check_orbit_day(orbit, [obs])  # shares 2020-06-24: fine
    with pytest.raises(DataFileError, match=r"observes 2020-06-25: its orbits reach none"):
        check_orbit_day(orbit, [_obs("2020-06-25T00:00", 0.5)])


def test_orbits_of_the_same_day_that_reach_no_epoch_say_when_they_reach() -> None:
    with pytest.raises(DataFileError) as err:
        check_orbit_day(_sp3("2020-06-25T00:00", 2), [_obs("2020-06-25T12:00", 1)])
    assert str(err.value) == (
        "orbits.sp3: its orbits reach 2020-06-25 00:00 to 2020-06-25 02:00 (GPS time), none of the observation epochs "
        "of abcd1770.20o (2020-06-25 12:00 to 2020-06-25 13:00): give orbits that cover them"
    )


def test_a_simulated_constellation_is_not_checked() -> None:
    check_orbit_day(synthetic_gps_constellation(), [_obs("2020-06-25T00:00", 1)])


def test_every_observation_file_is_checked() -> None:
    with pytest.raises(DataFileError, match=r"efgh1780.20o observes 2020-06-26"):
        check_orbit_day(
            _sp3("2020-06-25T00:00", 23.75), [_obs("2020-06-25T00:00", 1), _obs("2020-06-26T00:00", 1, "efgh1780.20o")]
        )


# ---------------------------------------------------------------------------------------------- real files, CLI
@pytest.mark.parametrize(
    ("orbit_option", "orbit_file", "expected"),
    [
        ("--nav", f"{IGS}/brdc0110.24n.gz", "brdc0110.24n.gz: a navigation file of 2024-01-11 (GPS time)"),
        ("--sp3", f"{ESBC}/GRG0MGXFIN_20201770000_01D_15M_ORB.SP3.gz", "ORB.SP3.gz: an SP3 file of 2020-06-25 (GPS"),
    ],
)
def test_codebias_with_orbits_of_another_day(
    orbit_option: str,
    orbit_file: str,
    expected: str,
    shared_data: Path,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    obs = shared_data / NL / "zegv0010.21o"
    argv = ["gnss", "codebias", "--obs", str(obs), "--out", str(tmp_path / "out"), "--no-progress"]
    assert main([*argv, orbit_option, str(shared_data / orbit_file)]) == 2
    err = capsys.readouterr().err
    assert expected in err, err
    assert "zegv0010.21o observes 2021-01-01" in err and "file of 2021-01-01" in err
    assert "Traceback" not in err and not (tmp_path / "out" / "codebias.json").exists()


def test_ionosphere_with_a_navigation_file_of_another_day(
    shared_data: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    nl, igs = shared_data / NL, shared_data / IGS
    argv = ["gnss", "ionosphere", "--obs", str(nl / "zegv0010.21o"), str(nl / "rovn0010.21o")]
    rc = main([*argv, "--nav", str(igs / "brdc0110.24n.gz"), "--out", str(tmp_path / "out"), "--no-progress"])
    err = capsys.readouterr().err
    assert rc == 2 and "brdc0110.24n.gz: a navigation file of 2024-01-11" in err, err
    assert "observes 2021-01-01" in err


def test_the_right_days_files_pass(shared_data: Path) -> None:
    from distnav.formats.gnss.rinex import read_code_observations, read_navigation

    nl = shared_data / NL
    obs = read_code_observations(nl / "zegv0010.21o", bands=(1, 2, 5))
    check_orbit_day(read_navigation(nl / "cbw10010.21n.gz", max_age_s=24 * 3600.0), [obs])


def test_reproduce_codebias_with_a_start_the_navigation_file_does_not_reach(
    shared_data: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """``reproduce codebias --nav FILE --start ISO`` reads orbits too: a start on another day is named (it said "no
    satellite code bias is estimable from these data")."""
    nav = shared_data / IGS / "brdc0110.24n.gz"
    argv = ["reproduce", "codebias", "--quick", "--nav", str(nav), "--start", "2021-01-01T00:00"]
    assert main([*argv, "--out", str(tmp_path / "out"), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "brdc0110.24n.gz: a navigation file of 2024-01-11 (GPS time), but --start 2021-01-01T00:00 is on " in err
    assert "2021-01-01: its orbits do not reach it; give the navigation file of 2021-01-01" in err, err
