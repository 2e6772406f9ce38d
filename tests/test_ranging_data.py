"""distnav.algorithms.ranging.data: the arrays of a sub-problem of kept anchors (``RangingData.kept_arrays``), which
``RangingProblem.subset`` and the field demo's ``remaining_data`` both build on."""

from __future__ import annotations

import numpy as np
import pytest

from distnav.algorithms.ranging.data import RangingData
from distnav.commands.field_scenarios import remaining_data
from distnav.errors import ModelError
from distnav.models.uwb.problems import build_problem


def _four() -> RangingData:
    """Anchors a, b, c, d (a, b fixed) with ranges a–c, b–c, c–d, b–d, a–d and a second a–c sample."""
    pos = np.array([[0.0, 0.0], [4.0, 0.0], [4.0, 3.0], [0.0, 3.0]])
    return RangingData(
        ids=("a", "b", "c", "d"),
        dim=2,
        positions_m=np.where([[1, 1], [1, 1], [0, 0], [0, 0]], pos, 0.0),
        free=np.array([[False, False], [False, False], [True, True], [True, True]]),
        meas_a=np.array([0, 1, 2, 1, 0, 0]),
        meas_b=np.array([2, 2, 3, 3, 3, 2]),
        range_m=np.array([5.0, 3.0, 4.0, 5.0, 3.0, 5.1]),
        truth_m=pos,
        initial_m=pos + 0.5,
    )


def test_kept_arrays_renumbers_the_ranges_between_kept_anchors() -> None:
    data = _four()
    kept = data.kept_arrays(np.array([True, False, True, True]))  # drop b: its ranges b–c and b–d go with it
    assert kept["ids"] == ("a", "c", "d")
    assert kept["meas_a"].tolist() == [0, 1, 0, 0]  # a–c, c–d, a–d, a–c again, in their order, a=0 c=1 d=2
    assert kept["meas_b"].tolist() == [1, 2, 2, 1]
    assert kept["range_m"].tolist() == [5.0, 4.0, 3.0, 5.1]
    assert kept["free"].tolist() == [[False, False], [True, True], [True, True]]
    assert kept["truth_m"].tolist() == [[0.0, 0.0], [4.0, 3.0], [0.0, 3.0]]
    assert kept["initial_m"].tolist() == [[0.5, 0.5], [4.5, 3.5], [0.5, 3.5]]
    assert kept["positions_m"].tolist() == [[0.0, 0.0], [0.0, 0.0], [0.0, 0.0]]


def test_remaining_data_and_subset_agree_with_kept_arrays() -> None:
    data = _four()
    rest = remaining_data(data, 1)
    assert rest.ids == ("a", "c", "d") and rest.dim == 2
    assert rest.meas_a.tolist() == [0, 1, 0, 0] and rest.range_m.tolist() == [5.0, 4.0, 3.0, 5.1]
    problem = build_problem(
        ["a", "b", "c", "d"],
        [("a", "c"), ("b", "c"), ("c", "d"), ("b", "d"), ("a", "d"), ("c", "b")],
        [5.0, 3.0, 4.0, 5.0, 3.0, 3.1],
        fixed={"a": (0.0, 0.0), "b": (4.0, 0.0), "d": (0.0, 3.0)},
        dim=2,
    )
    sub = problem.subset(np.array([False, True, True, True]))  # drop a
    assert sub.ids == ("b", "c", "d") and sub.info["subset_of"] == [1, 2, 3]
    assert list(zip(sub.meas_a.tolist(), sub.meas_b.tolist(), strict=True)) == [(0, 1), (1, 2), (0, 2), (1, 0)]
    assert sub.range_m.tolist() == [3.0, 4.0, 5.0, 3.1]
    with pytest.raises(ModelError, match="no range between them"):
        problem.subset(np.array([True, True, False, False]))
