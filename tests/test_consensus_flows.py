"""distnav.algorithms.consensus.flows: bad counts are named by the generator (the flow consensus itself is checked
against the network average under faults in tests/test_field_launch.py)."""

from __future__ import annotations

import numpy as np
import pytest

from distnav.algorithms.consensus.flows import iterate_flow_consensus
from distnav.errors import WeightsError
from distnav.network import builders


@pytest.mark.parametrize(
    ("changes", "match"),
    [
        ({"rounds": 2.5}, "rounds must be a whole number, got 2.5"),  # was a bare TypeError of range
        ({"rounds": -1}, "rounds must be ≥ 0, got -1"),
        ({"patience": 0}, "patience must be ≥ 1, got 0"),
        ({"patience": 1.5}, "patience must be a whole number"),
    ],
)
def test_bad_counts_are_named(changes: dict[str, object], match: str) -> None:
    args: dict[str, object] = {"graph": builders.ring(4), "rounds": 3, **changes}
    with pytest.raises(WeightsError, match=match):
        next(iterate_flow_consensus(np.arange(4.0), **args))  # type: ignore[arg-type]


def test_rounds_as_a_whole_float_run_the_same() -> None:
    a = [s.values for s in iterate_flow_consensus(np.arange(4.0), graph=builders.ring(4), rounds=5)]
    b = [s.values for s in iterate_flow_consensus(np.arange(4.0), graph=builders.ring(4), rounds=5.0)]  # type: ignore[arg-type]
    assert len(a) == len(b) == 6
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(x, y)
    np.testing.assert_allclose(a[-1].sum(), np.arange(4.0).sum())  # flows keep the sum (module docstring)
