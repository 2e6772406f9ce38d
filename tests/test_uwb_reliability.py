"""External reliability (redundancy numbers, MDB, the worst undetected shift) for the distributed solvers of
``uwb solve`` (issue 28, item 5), computed by every anchor from its neighbourhood's link records
(:data:`~distnav.models.uwb.reliability.LOCAL_HOPS` hops, which span this 16-anchor hall): the same numbers as LM's
where the network and the solution are the same."""

from __future__ import annotations

import numpy as np
import pytest

from distnav.commands.uwb import solve_range_log
from distnav.experiments.uwb_field import write_hall
from distnav.models.uwb.field import FieldOptions
from distnav.models.uwb.hall import simulate_hall


@pytest.mark.parametrize("solver", ["N-CLM", "N-CSG-TBLS"])
def test_distributed_reliability_equals_lms_on_the_same_network(tmp_path, solver) -> None:
    h = simulate_hall(
        np.random.default_rng([31, 4]),
        n_anchors=16,
        length_m=30.0,
        width_m=15.0,
        nlos_p1=0.0,
        antenna_delay_sd_m=0.0,
        known="spread",
    )
    f = write_hall(h, tmp_path / "hall")
    runs = {}
    for name in ("LM", solver):
        sol, _, s = solve_range_log(
            f["ranges"], f["known"], heights=f["heights"], options=FieldOptions(solver=name, iterations=800)
        )
        runs[name] = (sol, s)
    (lm, s_lm), (dist, s_d) = runs["LM"], runs[solver]
    assert np.array_equal(lm.excluded, dist.excluded)  # the same network
    assert np.max(np.abs(lm.positions_m - dist.positions_m)) < 1e-3  # the same solution (the final LM phase)
    a, b = s_lm["reliability"], s_d["reliability"]
    assert a["tested"] and b["tested"] and "neighbourhood" in b["computed"] and b["bytes"] > 0
    assert b["largest_subnetwork"] == int(dist.problem.estimated.sum())  # a neighbourhood spans the network
    assert set(a["shift_m"]) == set(b["shift_m"])
    for k, v in a["shift_m"].items():
        assert (v is None) == (b["shift_m"][k] is None)
        if v is not None:
            assert b["shift_m"][k] == pytest.approx(v, rel=1e-2, abs=1e-3)
    assert b["max_shift_m"] == pytest.approx(a["max_shift_m"], rel=1e-2)
    assert b["weak"] == a["weak"]
